"""Read and write frame sequences in the ``jnds-sequence/1`` format.

The format is specified in docs/sequence-format.md; this module is its reference reader
and writer. Frames are loaded lazily: opening a sequence checks ``sequence.json`` and the
frame files' presence; each frame's pixels are read (and checked) when asked for.

Array contract: every layer is a float32 HWC array, linear values as stored, pixel
(0, 0) top-left. Single-channel layers keep a trailing axis of 1.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np
import OpenEXR

from .errors import (
    ChannelError,
    ConfigError,
    ExrReadError,
    FrameCountError,
    ImageSizeError,
    SequenceFormatError,
)
from .layout import GUIDE, LAYERS

FORMAT = "jnds-sequence/1"

# layer name -> channel suffixes, in the order they are stacked on the last axis
INPUT_LAYERS: dict[str, tuple[str, ...]] = {layer.name: layer.suffixes for layer in LAYERS}
# ``denoising_albedo`` (layout.GUIDE): the guide albedo a single-frame denoiser takes, a
# metal's tint and what lies behind glass included (Cycles' Denoising Albedo pass); the OIDN
# baseline reads it (docs/dataset.md, "What a sequence holds"), and a network trained
# with it (ModelConfig.guide_albedo)
OPTIONAL_INPUT_LAYERS: dict[str, tuple[str, ...]] = {"depth": ("",), GUIDE.name: GUIDE.suffixes}
REFERENCE_LAYERS: dict[str, tuple[str, ...]] = {"color": ("R", "G", "B")}
OPTIONAL_REFERENCE_LAYERS: dict[str, tuple[str, ...]] = {
    "diffuse": ("R", "G", "B"),
    "specular": ("R", "G", "B"),
    "albedo": ("R", "G", "B"),
}
OUTPUT_LAYERS = REFERENCE_LAYERS
# how `jnds run` and `jnds batch` store output frames: {name: (layers stored as half,
# compression)}. float: 32-bit, uncompressed (ZIP took several times as long to write and
# saved little on a denoised frame: benchmarks/results/exr_write.md); half: 16-bit, PIZ
# (lossless for half data), a quarter of float ZIP's size
OUTPUT_FORMATS = {
    "float": (frozenset(), OpenEXR.NO_COMPRESSION),
    "half": (frozenset({"color"}), OpenEXR.PIZ_COMPRESSION),
}

_FRAME_RE = re.compile(r"^(\d{4,})\.exr$")


def channel_names(layer: str, suffixes: tuple[str, ...]) -> list[str]:
    return [layer if s == "" else f"{layer}.{s}" for s in suffixes]


Layers = dict[str, np.ndarray]


# ---------------------------------------------------------------------------------------
# EXR files


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """Read every channel of an EXR file, of every part, as ``{full channel name: (H, W) float32}``."""
    path = Path(path)
    if not path.is_file():
        raise ExrReadError(path, "file does not exist")
    return _read_exr(str(path), path)


def read_exr_bytes(data: bytes, name: str = "<frame>") -> dict[str, np.ndarray]:
    """``read_exr`` of an EXR file held in memory (a request body); ``name`` for errors."""
    import io

    return _read_exr(io.BytesIO(data), name)


def _read_exr(source, name) -> dict[str, np.ndarray]:
    try:
        exr = OpenEXR.File(source, separate_channels=True)
        # every part: ``File.channels()`` is the first one only, and a multi-part file
        # (Blender 5 writes one part per pass) would lose the rest. The binding drops a
        # part whose pixels it cannot read (with a warning), so the parts read are
        # counted against the parts the header declares
        if hasattr(source, "seek"):
            source.seek(0)
        declared = len(OpenEXR.File(source, header_only=True).parts)
        if len(exr.parts) < max(declared, 1):
            raise ExrReadError(
                name, f"unreadable or truncated OpenEXR file ({len(exr.parts)} of {declared} parts readable)"
            )
        channels = {c: ch for part in exr.parts for c, ch in part.channels.items()}
        out = {}
        for cname, ch in channels.items():
            px = ch.pixels
            if px.dtype not in (np.float16, np.float32):
                raise ExrReadError(name, f"channel {cname!r} is stored as {px.dtype}, expected half or float")
            out[cname] = px.astype(np.float32, copy=False)
    except ExrReadError:
        raise
    except Exception as exc:  # OpenEXR raises RuntimeError for truncated/corrupt files
        raise ExrReadError(name, f"unreadable or truncated OpenEXR file ({exc})") from exc
    return out


def exr_bytes(
    layers: Mapping[str, np.ndarray],
    suffixes: Mapping[str, tuple[str, ...]],
    half: set[str] = frozenset(),
    compression=None,
) -> bytes:
    """``write_exr`` into memory; ``compression`` an ``OpenEXR`` constant (default ZIP)."""
    import io

    buf = io.BytesIO()
    _exr_file(layers, suffixes, half, compression).write(buf)
    return buf.getvalue()


def read_layers(
    path: str | Path,
    size: tuple[int, int],
    required: Mapping[str, tuple[str, ...]],
    optional: Mapping[str, tuple[str, ...]] = {},
) -> Layers:
    """Read an EXR file into named HWC float32 layers, checking channels and size (W, H)."""
    return channels_to_layers(read_exr(path), path, size, required, optional)


def channels_to_layers(
    raw: dict[str, np.ndarray],
    path: str | Path,
    size: tuple[int, int] | None,
    required: Mapping[str, tuple[str, ...]],
    optional: Mapping[str, tuple[str, ...]] = {},
) -> Layers:
    """EXR channels into named HWC layers, checking channels and size (W, H); ``size``
    None takes the size of the first required channel. ``path`` names the file in errors."""
    missing = [c for layer, sfx in required.items() for c in channel_names(layer, sfx) if c not in raw]
    if missing:
        raise ChannelError(path, f"missing channel(s) {', '.join(missing)}")
    if size is None:
        first = channel_names(*next(iter(required.items())))[0]
        size = raw[first].shape[::-1]
    w, h = size
    layers: Layers = {}
    for layer, sfx in {**required, **optional}.items():
        names = channel_names(layer, sfx)
        if not all(n in raw for n in names):
            continue
        for n in names:
            if raw[n].shape != (h, w):
                got = raw[n].shape
                raise ImageSizeError(path, f"channel {n!r} is {got[1]}x{got[0]}, expected {w}x{h}")
        layers[layer] = np.stack([raw[n] for n in names], axis=-1)
    return layers


def write_exr(
    path: str | Path,
    layers: Mapping[str, np.ndarray],
    suffixes: Mapping[str, tuple[str, ...]],
    half: set[str] = frozenset(),
    compression=None,
) -> None:
    """Write HWC layers as an EXR file, atomically (temp file, then rename).

    Layers named in ``half`` are stored as 16-bit half (values clamped to the half
    range so nothing becomes Inf); the others as 32-bit float. ``compression``: an
    ``OpenEXR`` constant (default ZIP).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    _exr_file(layers, suffixes, half, compression).write(str(tmp))
    os.replace(tmp, path)


def write_output(path: str | Path, color: np.ndarray, fmt: str = "float") -> None:
    """An output frame (HWC RGB) in one of ``OUTPUT_FORMATS``, atomically."""
    if fmt not in OUTPUT_FORMATS:
        raise ConfigError(f"output format {fmt!r}: expected one of {', '.join(OUTPUT_FORMATS)}")
    half, compression = OUTPUT_FORMATS[fmt]
    write_exr(path, {"color": color}, OUTPUT_LAYERS, half, compression)


def exr_threads(n: int) -> None:
    """OpenEXR compresses and decompresses with ``n`` threads (process-wide; 0: in the
    calling thread, OpenEXR's default). Writing a 2x output frame takes longer than
    computing it without (benchmarks/results/exr_write.md): `jnds run`, `jnds batch`'s workers and
    `jnds serve` set it to their thread count."""
    OpenEXR.set_global_thread_count(max(0, int(n)))


def _exr_file(layers, suffixes, half, compression=None) -> OpenEXR.File:
    channels = {}
    for layer, arr in layers.items():
        arr = np.asarray(arr)
        if arr.ndim == 2:
            arr = arr[..., None]
        sfx = suffixes[layer]
        if arr.shape[-1] != len(sfx):
            raise ValueError(f"layer {layer!r} has {arr.shape[-1]} channels, expected {len(sfx)}")
        for i, n in enumerate(channel_names(layer, sfx)):
            c = arr[..., i]
            if layer in half:
                c = np.clip(c, -65504.0, 65504.0).astype(np.float16)
            else:
                c = c.astype(np.float32)
            channels[n] = np.ascontiguousarray(c)
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION if compression is None else compression,
        "type": OpenEXR.scanlineimage,
    }
    return OpenEXR.File(header, channels)


# ---------------------------------------------------------------------------------------
# sequences


@dataclass(frozen=True)
class FrameInfo:
    index: int
    jitter: tuple[float, float] = (0.0, 0.0)
    camera_cut: bool = False


@dataclass
class Sequence:
    """An opened, structurally valid sequence. Frames load lazily."""

    path: Path
    native_size: tuple[int, int]  # (W, H)
    target_size: tuple[int, int] | None
    frames: list[FrameInfo]
    has_reference: bool
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frames)

    def input_path(self, i: int) -> Path:
        return self.path / "inputs" / f"{i:04d}.exr"

    def reference_path(self, i: int) -> Path:
        return self.path / "reference" / f"{i:04d}.exr"

    def inputs(self, i: int) -> Layers:
        """Layers of input frame ``i``: diffuse, specular, albedo, normal (H, W, 3),
        roughness (H, W, 1), motion (H, W, 2); depth (H, W, 1) and denoising_albedo
        (H, W, 3) if present."""
        self._check_index(i)
        return read_layers(self.input_path(i), self.native_size, INPUT_LAYERS, OPTIONAL_INPUT_LAYERS)

    def reference(self, i: int) -> Layers:
        """Layers of reference frame ``i`` at target size: color, and the optional
        diffuse, specular, albedo components."""
        self._check_index(i)
        if not self.has_reference:
            raise FrameCountError(self.path / "reference", "sequence has no reference frames")
        return read_layers(self.reference_path(i), self.target_size, REFERENCE_LAYERS, OPTIONAL_REFERENCE_LAYERS)

    def __iter__(self) -> Iterator[Layers]:
        for i in range(len(self)):
            yield self.inputs(i)

    def _check_index(self, i: int) -> None:
        if not 0 <= i < len(self.frames):
            raise IndexError(f"frame {i} out of range 0..{len(self.frames) - 1}")


def _size(path: Path, meta: dict, key: str) -> tuple[int, int] | None:
    v = meta.get(key)
    if v is None:
        return None
    if (
        not isinstance(v, list)
        or len(v) != 2
        or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in v)
    ):
        raise SequenceFormatError(path, f"{key!r} must be [W, H] with positive integers, got {v!r}")
    return (v[0], v[1])


def _frame_files(directory: Path) -> list[int]:
    if not directory.is_dir():
        return []
    found = []
    for p in directory.iterdir():
        m = _FRAME_RE.match(p.name)
        if m:
            found.append(int(m.group(1)))
        elif p.suffix.lower() == ".exr":
            raise FrameCountError(p, "frame file name must be a 4-digit frame number, e.g. 0000.exr")
    return sorted(found)


def _check_frame_files(directory: Path, count: int) -> None:
    found = _frame_files(directory)
    expected = set(range(count))
    missing = sorted(expected - set(found))
    extra = sorted(set(found) - expected)
    if missing:
        listed = ", ".join(f"{i:04d}.exr" for i in missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise FrameCountError(directory, f"missing frame(s) {listed} (frame_count is {count})")
    if extra:
        listed = ", ".join(f"{i:04d}.exr" for i in extra[:5]) + (" ..." if len(extra) > 5 else "")
        raise FrameCountError(directory, f"extra frame(s) {listed} beyond frame_count {count}")


def find_sequences(root: str | Path) -> list[Path]:
    """The sequences directly inside ``root`` (directories holding a sequence.json), sorted."""
    return sorted(p.parent for p in Path(root).glob("*/sequence.json"))


def expand_sequences(paths) -> list[Path]:
    """Each path is a sequence, or a directory of sequences (expanded, sorted)."""
    out = []
    for p in map(Path, paths):
        if (p / "sequence.json").is_file():
            out.append(p)
        elif found := find_sequences(p):
            out.extend(found)
        else:
            raise SequenceFormatError(p / "sequence.json", "missing sequence.json, and no sequences inside")
    return out


def open_sequence(path: str | Path) -> Sequence:
    """Open a sequence directory, checking ``sequence.json`` and the frame files."""
    path = Path(path)
    meta_path = path / "sequence.json"
    if not meta_path.is_file():
        raise SequenceFormatError(meta_path, "missing sequence.json")
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SequenceFormatError(meta_path, f"not valid JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise SequenceFormatError(meta_path, "top level must be a JSON object")
    if meta.get("format") != FORMAT:
        raise SequenceFormatError(meta_path, f"format is {meta.get('format')!r}, expected {FORMAT!r}")
    native = _size(meta_path, meta, "native_size")
    if native is None:
        raise SequenceFormatError(meta_path, "missing 'native_size'")
    target = _size(meta_path, meta, "target_size")
    count = meta.get("frame_count")
    if not isinstance(count, int) or isinstance(count, bool) or count < 1:
        raise SequenceFormatError(meta_path, f"'frame_count' must be a positive integer, got {count!r}")
    frames = _parse_frames(meta_path, meta.get("frames"), count)

    _check_frame_files(path / "inputs", count)
    has_reference = (path / "reference").is_dir() and any((path / "reference").glob("*.exr"))
    if has_reference:
        if target is None:
            raise SequenceFormatError(meta_path, "reference frames present but no 'target_size'")
        _check_frame_files(path / "reference", count)
    return Sequence(path, native, target, frames, has_reference, meta)


def _parse_frames(meta_path: Path, frames, count: int) -> list[FrameInfo]:
    if frames is None:
        return [FrameInfo(i) for i in range(count)]
    if not isinstance(frames, list) or len(frames) != count:
        n = len(frames) if isinstance(frames, list) else type(frames).__name__
        raise SequenceFormatError(meta_path, f"'frames' must list {count} entries, got {n}")
    out = []
    for i, f in enumerate(frames):
        if not isinstance(f, dict) or f.get("index", i) != i:
            raise SequenceFormatError(meta_path, f"frames[{i}] must be an object with index {i}")
        jitter = f.get("jitter", [0.0, 0.0])
        if (
            not isinstance(jitter, list)
            or len(jitter) != 2
            or not all(isinstance(j, (int, float)) and -0.5 <= j <= 0.5 for j in jitter)
        ):
            raise SequenceFormatError(meta_path, f"frames[{i}].jitter must be [jx, jy] in [-0.5, 0.5], got {jitter!r}")
        cut = f.get("camera_cut", False)
        if not isinstance(cut, bool):
            raise SequenceFormatError(meta_path, f"frames[{i}].camera_cut must be true or false, got {cut!r}")
        out.append(FrameInfo(i, (float(jitter[0]), float(jitter[1])), cut))
    return out


# ---------------------------------------------------------------------------------------
# validation


@dataclass
class ValidationReport:
    """Result of reading every frame: non-finite values per file kind and channel."""

    path: Path
    frame_count: int
    nonfinite: dict[str, dict[str, dict[int, int]]]  # kind -> channel -> {frame: count}

    @property
    def clean(self) -> bool:
        return not any(self.nonfinite.values())

    def summary(self) -> str:
        lines = [f"{self.path}: {self.frame_count} frames, all files readable"]
        if self.clean:
            lines.append("no NaN or Inf in any channel")
        for kind, per_channel in self.nonfinite.items():
            for ch, frames in sorted(per_channel.items()):
                total = sum(frames.values())
                worst = ", ".join(f"{i:04d}: {n}" for i, n in sorted(frames.items())[:5])
                lines.append(f"{kind} {ch}: {total} non-finite value(s) in {len(frames)} frame(s) ({worst})")
        return "\n".join(lines)


def count_nonfinite(layers: Layers, suffixes: Mapping[str, tuple[str, ...]]) -> dict[str, int]:
    """Number of NaN/Inf values per full channel name, only channels that have any."""
    out = {}
    for layer, arr in layers.items():
        bad = (~np.isfinite(arr)).sum(axis=(0, 1))
        for n, b in zip(channel_names(layer, suffixes[layer]), bad):
            if b:
                out[n] = int(b)
    return out


def check_headers(seq: Sequence, reference: bool = False) -> None:
    """Every input frame's (with ``reference``, every reference frame's) EXR header read:
    the file opens as OpenEXR, has the layers' channels and the sequence's size. Raises the
    first error, naming the file; reads no pixels, so a run can check a whole sequence
    before it writes anything (``validate`` reads every pixel)."""
    kinds = [(seq.input_path, INPUT_LAYERS, seq.native_size)]
    if reference and seq.has_reference:
        kinds.append((seq.reference_path, REFERENCE_LAYERS, seq.target_size))
    for i in range(len(seq)):
        for path_of, required, (w, h) in kinds:
            path = path_of(i)
            try:
                parts = OpenEXR.File(str(path), header_only=True).parts
            except Exception as exc:
                raise ExrReadError(path, f"unreadable OpenEXR header ({exc})") from exc
            names = {c.name for part in parts for c in part.header.get("channels", [])}
            missing = [c for layer, sfx in required.items() for c in channel_names(layer, sfx) if c not in names]
            if missing:
                raise ChannelError(path, f"missing channel(s) {', '.join(missing)}")
            for part in parts:
                lo, hi = part.header["dataWindow"]
                if (int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)) != (w, h):
                    raise ImageSizeError(path, f"is {hi[0] - lo[0] + 1}x{hi[1] - lo[1] + 1}, expected {w}x{h}")


def validate(path: str | Path) -> ValidationReport:
    """Open a sequence and read every frame; raise the first structural error found."""
    seq = open_sequence(path)
    nonfinite: dict[str, dict[str, dict[int, int]]] = {"inputs": {}, "reference": {}}
    for i in range(len(seq)):
        kinds = [("inputs", seq.inputs, {**INPUT_LAYERS, **OPTIONAL_INPUT_LAYERS})]
        if seq.has_reference:
            kinds.append(("reference", seq.reference, {**REFERENCE_LAYERS, **OPTIONAL_REFERENCE_LAYERS}))
        for kind, load, sfx in kinds:
            for ch, n in count_nonfinite(load(i), sfx).items():
                nonfinite[kind].setdefault(ch, {})[i] = n
    return ValidationReport(seq.path, len(seq), nonfinite)


# ---------------------------------------------------------------------------------------
# writing


class SequenceWriter:
    """Write a sequence frame by frame; ``sequence.json`` is written last by ``close``.

    A directory without ``sequence.json`` is an unfinished sequence: readers reject it,
    and a renderer can resume it frame by frame.
    """

    HALF_INPUTS = {"albedo", "normal", "roughness", "denoising_albedo"}
    HALF_REFERENCE = {"color", "diffuse", "specular", "albedo"}

    def __init__(self, path: str | Path, native_size: tuple[int, int], target_size: tuple[int, int] | None = None):
        self.path = Path(path)
        self.native_size = tuple(native_size)
        self.target_size = tuple(target_size) if target_size else None
        (self.path / "inputs").mkdir(parents=True, exist_ok=True)
        if self.target_size:
            (self.path / "reference").mkdir(parents=True, exist_ok=True)

    def write_inputs(self, i: int, layers: Layers) -> None:
        self._check(layers, self.native_size, "inputs")
        write_exr(
            self.path / "inputs" / f"{i:04d}.exr", layers, {**INPUT_LAYERS, **OPTIONAL_INPUT_LAYERS}, self.HALF_INPUTS
        )

    def write_reference(self, i: int, layers: Layers) -> None:
        self._check(layers, self.target_size, "reference")
        write_exr(
            self.path / "reference" / f"{i:04d}.exr",
            layers,
            {**REFERENCE_LAYERS, **OPTIONAL_REFERENCE_LAYERS},
            self.HALF_REFERENCE,
        )

    def close(self, frames: list[FrameInfo], extra: dict | None = None) -> Path:
        meta = {"format": FORMAT, "native_size": list(self.native_size)}
        if self.target_size:
            meta["target_size"] = list(self.target_size)
        meta["frame_count"] = len(frames)
        meta["frames"] = [
            {"index": f.index, "jitter": [float(f.jitter[0]), float(f.jitter[1])], "camera_cut": bool(f.camera_cut)}
            for f in frames
        ]
        meta.update(extra or {})
        out = self.path / "sequence.json"
        tmp = out.with_name(".sequence.json.tmp")
        tmp.write_text(json.dumps(meta, indent=1))
        os.replace(tmp, out)
        return out

    @staticmethod
    def _check(layers: Layers, size, kind: str) -> None:
        if size is None:
            raise ValueError(f"writer has no size for {kind}")
        w, h = size
        for name, arr in layers.items():
            if arr.shape[:2] != (h, w):
                raise ValueError(f"{kind} layer {name!r} is {arr.shape[1]}x{arr.shape[0]}, expected {w}x{h}")
