"""Training data in memory: whole sequences as NCHW-ready arrays, and random patches of
consecutive frames drawn from them."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ..errors import TrainError
from ..io import find_sequences, open_sequence
from ..layout import CURRENT, GUIDE, RADIANCE, channels

REFERENCE_COMPONENTS = ("color", "diffuse", "specular", "albedo")


@dataclass
class SequenceArrays:
    """One sequence in memory, NCHW-ready float32: current (T, 13, H, W) in
    ``layout.CURRENT`` order, motion (T, 2, H, W), reference components (T, 3, sH, sW),
    camera cuts; the guide albedo (T, 3, H, W) where every frame has one (``layout.GUIDE``),
    else None."""

    name: str
    current: np.ndarray
    motion: np.ndarray
    ref: Mapping[str, np.ndarray]  # a dict, or ``Recomposed`` for a cleaned reference
    cuts: list[bool]
    renderer: str = "unknown"  # render.json's engine (mitsuba, cycles) where the sequence has one
    guide: np.ndarray | None = None

    @property
    def scale(self) -> int:
        # from the albedo where the colour is computed on reading (``Recomposed``)
        ref = self.ref["albedo"] if isinstance(self.ref, Recomposed) else self.ref["color"]
        return ref.shape[-1] // self.current.shape[-1]


def load_sequence(path: str | Path, clean: str | None = None) -> SequenceArrays:
    """A sequence with references in memory: the reference components it has (colour
    always; training needs diffuse, specular and albedo too, ``PatchSampler`` checks).
    ``clean="oidn"``: the references denoised (``clean_references``)."""
    if clean is not None:
        if clean != "oidn":
            raise TrainError(f"clean references: unknown method {clean!r} (known: oidn)")
        return clean_references(load_sequence(path), path)
    seq = open_sequence(path)
    # a sequence of inputs only (``jnds dataset --no-reference``) has no component: what a
    # teacher-distilled run trains on
    present = seq.reference(0) if len(seq) and seq.has_reference else {}
    cur, mot, guide, refs = [], [], [], {k: [] for k in REFERENCE_COMPONENTS if k in present}
    for i in range(len(seq)):
        a = seq.inputs(i)
        cur.append(np.concatenate([a[n] for n, _ in CURRENT], -1).transpose(2, 0, 1))
        mot.append(a["motion"].transpose(2, 0, 1))
        if GUIDE.name in a:
            guide.append(a[GUIDE.name].transpose(2, 0, 1))
        r = seq.reference(i) if refs else {}
        for k in refs:
            refs[k].append(r[k].transpose(2, 0, 1))
    return SequenceArrays(
        Path(path).name,
        np.stack(cur),
        np.stack(mot),
        {k: np.stack(v) for k, v in refs.items()},
        [f.camera_cut for f in seq.frames],
        _renderer(Path(path)),
        np.stack(guide) if len(guide) == len(cur) else None,
    )


def _renderer(path: Path) -> str:
    """The engine named by the render marker ``jnds render`` / ``jnds dataset`` leave
    beside the sequence (``render.json``; mitsuba where it predates the field), else by
    sequence.json's ``renderer.engine`` (``jnds import cycles``), else "unknown" (a
    sequence made elsewhere: its own group for ``balance_renderers``)."""
    try:
        return str(json.loads((path / "render.json").read_text())["config"].get("engine", "mitsuba"))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    try:
        return str(json.loads((path / "sequence.json").read_text())["renderer"]["engine"])
    except (OSError, ValueError, KeyError, TypeError):
        return "unknown"


def load_split(root: str | Path, limit: int | None = None, clean: str | None = None) -> list[SequenceArrays]:
    """Every sequence under ``root`` (e.g. data/train), or TrainError if there is none."""
    paths = find_sequences(root)[:limit]
    if not paths:
        raise TrainError(f"{root}: no sequences found; run `jnds dataset --out {Path(root).parent}` first")
    return [load_sequence(p, clean) for p in paths]


CLEAN_CACHE = ".cache/reference-oidn.npz"  # beside a sequence's reference/, like Cycles' .cycles/


def clean_references(seq: SequenceArrays, path: str | Path) -> SequenceArrays:
    """``seq`` with its reference's diffuse and specular components denoised by OIDN
    (``high``, HDR, no guides: the components are lighting without the albedo's texture)
    and its colour recomposed from them (Eq. 2: albedo * diffuse + specular); albedo
    unchanged. Why: the renders' 64-spp references keep noise as strong as the model's
    own error, which the losses may teach it to keep (docs/model-gap.md, "The references
    keep noise").
    Cached in ``<sequence>/.cache/reference-oidn.npz``, redone when a reference frame is
    newer than the cache or OIDN's version differs; without a writable sequence directory
    it is recomputed at every load."""
    try:
        import pyoidn
    except ImportError as e:
        raise TrainError(f"cleaning the references needs pyoidn (pip install -e .[bench]): {e}") from e
    for c in ("diffuse", "specular", "albedo"):
        if c not in seq.ref:
            raise TrainError(f"{path}: cleaning the references needs their {c} component")
    path = Path(path)
    cache = path / CLEAN_CACHE
    version = oidn_version()
    newest = max((p.stat().st_mtime for p in (path / "reference").glob("*.exr")), default=0.0)
    if cache.is_file() and cache.stat().st_mtime >= newest:
        try:
            with np.load(cache) as z:
                if str(z["oidn"]) == version and z["diffuse"].shape == seq.ref["diffuse"].shape:
                    return _recomposed(seq, z["diffuse"], z["specular"])
        except (OSError, ValueError, KeyError, EOFError):
            pass  # an unreadable cache (a copy cut short, say) is made again
    clean = {}
    for c in ("diffuse", "specular"):
        frames = []
        for x in seq.ref[c]:  # (3, H, W) each
            hwc = np.ascontiguousarray(x.transpose(1, 2, 0), np.float32)
            out = np.asarray(pyoidn.denoise(hwc, None, None, hdr=True, quality="high"), np.float32)
            frames.append(np.maximum(out, 0.0).transpose(2, 0, 1))
        clean[c] = np.stack(frames)
    try:
        cache.parent.mkdir(exist_ok=True)
        tmp = cache.with_name(cache.name + ".tmp.npz")
        np.savez_compressed(tmp, oidn=np.array(version), **clean)
        tmp.replace(cache)
    except OSError:
        pass
    return _recomposed(seq, clean["diffuse"], clean["specular"])


def oidn_version() -> str:
    """The installed pyoidn's version (the cleaned-reference cache's key)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pyoidn")
    except PackageNotFoundError:
        return "unknown"


def _recomposed(seq: SequenceArrays, diffuse: np.ndarray, specular: np.ndarray) -> SequenceArrays:
    return replace(seq, ref=Recomposed(seq.ref["albedo"], diffuse, specular))


class Recomposed(Mapping):
    """A cleaned reference's components: albedo, diffuse and specular held, the colour (Eq. 2:
    albedo * diffuse + specular) computed where it is read rather than held: a quarter of
    the reference's memory and a good share of a Cycles sequence's (a training run holds
    every sequence in memory). ``window`` gives a component's frames and crop, the colour
    computed on those pixels alone: the same float32 values, element by element, as the
    whole array's."""

    def __init__(self, albedo: np.ndarray, diffuse: np.ndarray, specular: np.ndarray):
        self._parts = {"albedo": albedo, "diffuse": diffuse, "specular": specular}

    def window(self, name: str, index) -> np.ndarray:
        """``self[name][index]``, without computing the whole colour."""
        if name != "color":
            return self._parts[name][index]
        a, d, s = (self._parts[c][index] for c in ("albedo", "diffuse", "specular"))
        return (a * d + s).astype(np.float32)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.window(name, ...) if name == "color" else self._parts[name]

    def __contains__(self, name) -> bool:
        return name in REFERENCE_COMPONENTS

    def __iter__(self):
        return iter(REFERENCE_COMPONENTS)

    def __len__(self) -> int:
        return len(REFERENCE_COMPONENTS)


def _window(ref: Mapping, name: str, index) -> np.ndarray:
    """``ref[name][index]``: a ``Recomposed`` reference computes only the window's colour."""
    return ref.window(name, index) if isinstance(ref, Recomposed) else ref[name][index]


@dataclass(frozen=True)
class Augment:
    """What the renderers cannot give cheaply, applied per sample (all frames of its
    window alike): ``exposure`` multiplies every radiance (inputs and reference) of half
    the samples by 2^u, u uniform in (lo, hi) stops (the other half keep the renderer's
    exposure, so the brightness the scenes were made with stays as common as before);
    ``rotate_normals`` turns the world frame of the normals
    by a uniformly random rotation (a Z-up renderer must look like a Y-up one);
    ``flips`` mirrors the patch horizontally and/or vertically (each with probability
    1/2), negating the motion component across the mirror; ``colours`` gives half the
    samples other colours: one random permutation of R, G and B for every colour (radiance
    and albedo, inputs and reference), and the radiance tinted by a gain of 2^u per channel,
    u uniform in (-1/2, 1/2) (lights of another colour). Both are the same scene rendered
    otherwise by an RGB renderer, whose channels are independent and linear in the lights.
    Off by default: the sampler then draws exactly what it drew before augmentations existed."""

    exposure: tuple[float, float] | None = None
    rotate_normals: bool = False
    flips: bool = False
    colours: bool = False

    def __bool__(self) -> bool:
        return bool(self.exposure) or self.rotate_normals or self.flips or self.colours

    def __call__(self, sample: dict[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
        """``sample``: current (T, 13, p, p), motion (T, 2, p, p), the reference components
        (T, 3, kp, kp) and perhaps the guide albedo (T, 3, p, p); returns new arrays, never
        views of the sequence."""
        out = {k: v.copy() for k, v in sample.items()}
        if self.exposure and rng.random() < 0.5:
            gain = np.float32(2.0 ** rng.uniform(*self.exposure))
            for name in RADIANCE:
                out["current"][:, channels(name)] *= gain
            for name in ("color", "diffuse", "specular"):
                if name in out:  # a sample without reference (PatchSampler(references=False))
                    out[name] *= gain
        if self.colours and rng.random() < 0.5:
            perm = rng.permutation(3)
            tint = (2.0 ** rng.uniform(-0.5, 0.5, size=(1, 3, 1, 1))).astype(np.float32)
            for name in (*RADIANCE, "albedo"):
                c = channels(name)
                out["current"][:, c] = out["current"][:, c][:, perm] * (tint if name in RADIANCE else 1)
            if "guide" in out:  # an albedo: permuted, not tinted
                out["guide"] = np.ascontiguousarray(out["guide"][:, perm])
            for name in (
                c for c in REFERENCE_COMPONENTS if c in out
            ):  # color = albedo * diffuse + specular: tinted too
                out[name] = np.ascontiguousarray(out[name][:, perm] * (1 if name == "albedo" else tint))
        if self.rotate_normals:
            n = channels("normal")
            out["current"][:, n] = np.einsum("ij,tjhw->tihw", random_rotation(rng), out["current"][:, n])
        if self.flips:
            for axis, component in ((-1, 0), (-2, 1)):  # mirror x, then y
                if rng.random() < 0.5:
                    out = {k: np.flip(v, axis) for k, v in out.items()}
                    out["motion"][:, component] *= -1
        return out


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix drawn uniformly from SO(3): the Q of a Gaussian matrix's QR
    decomposition, signs fixed so that the distribution is uniform (Mezzadri 2007), and
    made proper (det +1)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q.astype(np.float32)


class PatchSampler:
    """Random (sequence, window, crop) samples; ``augment`` applied to each sample. Windows
    never cross a camera cut, or with ``cross_cuts`` they may: the batch's ``cut`` (T, N)
    marks the frames where a sample's history restarts (``run_unroll``). A sequence cut
    halfway has no window of 8 frames without a cut: crossing, it trains the frame after a
    cut, which the evaluation sets have. With ``balance_renderers`` the windows of each
    renderer (``SequenceArrays.renderer``) together are drawn as often as another's: the
    evaluation sets are half Cycles, the training data a third. ``references=False``
    draws the inputs only (a teacher-distilled run's targets are the teacher's outputs).
    ``guide``: the batches hold the guide albedo too (``SequenceArrays.guide``, the albedo
    where a sequence has none), for a model that reads it (``ModelConfig.guide_albedo``)."""

    def __init__(
        self,
        seqs: list[SequenceArrays],
        patch: int,
        unroll: int,
        rng: np.random.Generator,
        augment: Augment = Augment(),
        cross_cuts: bool = False,
        balance_renderers: bool = False,
        references: bool = True,
        guide: bool = False,
    ):
        self.seqs, self.patch, self.unroll, self.rng, self.augment = seqs, patch, unroll, rng, augment
        self.guide = guide
        self.components = REFERENCE_COMPONENTS if references else ()
        for s in seqs:
            if missing := [c for c in self.components if c not in s.ref]:
                raise TrainError(
                    f"{s.name}: the reference has no {', '.join(missing)}; training needs every "
                    "component (the renderers write them)"
                )
        self.windows = []
        for si, s in enumerate(seqs):
            starts = [0] + ([] if cross_cuts else [t for t, c in enumerate(s.cuts) if c]) + [len(s.cuts)]
            for a, b in zip(starts[:-1], starts[1:]):
                self.windows += [(si, t) for t in range(a, b - unroll + 1)]
        if not self.windows:
            raise TrainError(f"no window of {unroll} frames without a cut in the training data")
        self.p = None
        if balance_renderers:
            group = [seqs[si].renderer for si, _ in self.windows]
            count = {g: group.count(g) for g in set(group)}
            self.p = np.array([1.0 / (count[g] * len(count)) for g in group])
            self.p /= self.p.sum()

    def window(self) -> tuple[int, int]:
        """A random (sequence index, first frame)."""
        n = len(self.windows)
        return self.windows[self.rng.integers(n) if self.p is None else self.rng.choice(n, p=self.p)]

    def batch(self, n: int, device: str | torch.device = "cpu", burn_in: int = 0) -> dict[str, torch.Tensor]:
        """Tensors (T, N, C, H, W): current, motion (native patch), with ``guide`` the guide
        albedo (native patch), reference color, diffuse, specular, albedo (target patch); ``cut`` (T, N) bool: the history restarts
        at that frame (a camera cut inside the window). ``burn_in`` frames precede each
        window (T = burn_in + unroll): the sequence's frames before it, where it has them;
        before its first frame, that frame repeated, the history restarting at the real one."""
        out = {k: [] for k in ("current", "motion", *(("guide",) if self.guide else ()), *self.components)}
        cuts = []
        for _ in range(n):
            si, t = self.window()
            s = self.seqs[si]
            h, w = s.current.shape[-2:]
            p = self.patch
            y = int(self.rng.integers(0, h - p + 1))
            x = int(self.rng.integers(0, w - p + 1))
            sl = np.maximum(np.arange(t - burn_in, t + self.unroll), 0)
            cuts.append([False] + [bool(s.cuts[b]) or a == b for a, b in zip(sl[:-1], sl[1:])])
            sample = {
                "current": s.current[sl, :, y : y + p, x : x + p],
                "motion": s.motion[sl, :, y : y + p, x : x + p],
            }
            if self.guide:
                g = s.guide if s.guide is not None else s.current[:, channels("albedo")]
                sample["guide"] = g[sl, :, y : y + p, x : x + p]
            for c in self.components:
                k = s.scale
                sample[c] = _window(s.ref, c, (sl, slice(None), slice(k * y, k * (y + p)), slice(k * x, k * (x + p))))
            if self.augment:
                sample = self.augment(sample, self.rng)
            for key, value in sample.items():
                out[key].append(value)
        batch = {k: torch.from_numpy(np.ascontiguousarray(np.stack(v, 1))).to(device) for k, v in out.items()}
        batch["cut"] = torch.tensor(cuts, dtype=torch.bool).T.contiguous().to(device)
        return batch
