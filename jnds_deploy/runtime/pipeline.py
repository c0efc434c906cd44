"""The frame-recurrent pipeline: ONNX Runtime for the network graphs, numpy/opencv for
the filter stage, and the history between frames.

``Pipeline(PipelineConfig(artifacts=DIR))`` needs nothing but the artifact directory
(its ``manifest.json``). Each call takes one frame's input layers as read by
``jnds_deploy.io`` (HWC float32) and returns the output colour (HWC float32, linear, at
target resolution) and the time of every stage in milliseconds.

History is reset on the first frame, on a camera cut and on a change of resolution;
odd sizes are padded (edge replicate) to the network's multiple and cropped back.
"""
from __future__ import annotations

import copy
import ctypes
import functools
import json
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import JndsError
from ..export import ARTIFACT_FORMAT
from ..export.prune import variant_key
from ..layout import CURRENT, HISTORY
from . import filters as F
from .reformat import LIMITS, to_chw, to_hwc

HISTORY_LAYERS = tuple(n for n, _ in HISTORY)  # diffuse, specular, albedo, normal
# albedo then normal: adjacent and at the same channels in the current inputs and the
# history (whose layout is the current inputs' first 12 channels), filtered in one pass
_OFFSET = dict(zip([n for n, _ in CURRENT], np.cumsum([0] + [c for _, c in CURRENT])))
AUX = slice(int(_OFFSET["albedo"]), int(_OFFSET["normal"]) + 3)
RADIANCE = ("diffuse", "specular")
# the float16 filter stage filters radiance at most this bright; brighter frames are scaled
# down by a power of two (exact in floating point) and back up after filtering. 65504 (the
# largest half) / 32: headroom for the kernels' gain (diffuse/specular weights are in
# [-1, 1], 9 taps per filter)
FP16_SAFE_MAX = 2048.0
# history rejection: a tile of REJECT_TILE^2 pixels whose warped diffuse (or specular)
# history is brighter than REJECT_RATIO x (the current frame's tile mean + REJECT_FLOOR x
# the current frame's mean) restarts that signal from the current frame, as after a cut (a
# signal that vanished from the whole frame, a light switched off, drops its history). The
# shipped checkpoint's recurrence has a loop gain above 1 in places (temporal kernels summing to
# ~2.3, trained on 6-frame unrolls): without this, 2 of 6 validation sequences looped to
# 1000 frames grew without bound (benchmarks/results/stability.md)
# adaptive tile skipping: tiles of TILE^2 native pixels that see no geometry and a
# background varying by at most TILE_FLAT x its brightness (runtime.filters.empty_tiles)
# pass through the filter stage (the current frame's values, bilinearly upsampled) and
# the upsample block runs only on the bounding box of the other tiles, with a margin of
# UPSAMPLE_HALO native pixels (its bilinear upsampling and 3x3 convolution reach 1 native
# pixel; 2 keep the box's inside equal to the whole frame's)
TILE = 16
TILE_FLAT = 0.1
UPSAMPLE_HALO = 2
# each history channel is clamped after warping (bicubic overshoots) to its input layer's
# valid range (reformat.LIMITS)
HISTORY_LO = np.array([LIMITS[n][0] for n, c in HISTORY for _ in range(c)], np.float32)
HISTORY_HI = np.array([LIMITS[n][1] for n, c in HISTORY for _ in range(c)], np.float32)
# history values smaller than this are set to 0. The recurrence (temporal blend x history)
# shrinks a signal that left a pixel geometrically, frame after frame, until it reaches
# float32's denormals (below 1.2e-38), which the CPU computes with microcode assists:
# 57231 of 11 million history values after 8 frames of the 720p sample, and the warp
# took 56.5 ms on that history against 35.1 ms with them zeroed (same process, 7 runs).
# 1e-30 leaves headroom for the kernels' weights; radiance this small is black in any format
HISTORY_FLUSH = 1e-30
REJECT_TILE = 32
REJECT_RATIO = 8.0
REJECT_FLOOR = 0.1


class ArtifactError(JndsError):
    """The artifact directory is missing files or has an unsupported manifest."""


class FrameError(JndsError):
    """A frame handed to the pipeline lacks a layer or has the wrong shape."""


INPUT_CHANNELS = dict(CURRENT, motion=2)


def check_layers(layers: dict) -> tuple[int, int]:
    """The frame's (H, W), or FrameError naming the missing or misshapen layer."""
    missing = [n for n in INPUT_CHANNELS if n not in layers]
    if missing:
        raise FrameError(f"frame: missing layer(s) {', '.join(missing)}")
    h, w = np.shape(layers["diffuse"])[:2]
    for n, c in INPUT_CHANNELS.items():
        shape, dtype = np.shape(layers[n]), np.asarray(layers[n]).dtype
        if len(shape) != 3 or shape[2] != c:
            raise FrameError(f"frame: layer {n!r} has shape {shape}, expected (H, W, {c})")
        if shape[:2] != (h, w):
            raise FrameError(f"frame: layer {n!r} is {shape[1]}x{shape[0]}, diffuse is {w}x{h}")
        if dtype.kind != "f":
            raise FrameError(f"frame: layer {n!r} has dtype {dtype}, expected float")
    if h < 1 or w < 1:
        raise FrameError(f"frame: empty image {w}x{h}")
    return h, w


@dataclass(frozen=True)
class PipelineConfig:
    artifacts: str
    precision: str = "fp32"  # fp32 | int8 (graphs written by `jnds calibrate`)
    filter_dtype: str = "float32"  # float32 | float16 (the paper's filter precision)
    threads: int = 2
    int8_method: str | None = None  # which calibration's int8 graphs; None: the last calibrated
    # graphs that stay fp32 when precision is int8. The upsample block's int8 graph is
    # slower on this CPU (kernel at 2560x1440: 494 ms int8, 398 ms fp32 in benchmarks/
    # results/calibration.md): its 11-channel QLinearConv is 2x the fp32 Conv (ORT profiler)
    fp32_graphs: tuple[str, ...] = ("upsample",)
    # skip work a frame does not need, where the result is the same (see Pipeline.decisions)
    adaptive: bool = True
    # denoise only: output at the input resolution, the upsample block (and the network's
    # features for it) not computed -- for a renderer that already renders at display size
    native_output: bool = False
    # with adaptive: pass empty background tiles through the filter stage (approximate; off by
    # default: finding the tiles and putting them back costs about what the smaller upsample
    # box saves, 0.84-1.16x and 0.85-1.09x in benchmarks/results/adaptive.md runs)
    tile_skip: bool = False
    # let malloc reuse freed memory (process-wide, see keep_freed_memory): each frame's
    # large arrays then skip the kernel's page faults
    keep_freed_memory: bool = True

    def __post_init__(self):
        if self.precision not in ("fp32", "int8"):
            raise ValueError(f"precision must be fp32 or int8, got {self.precision!r}")
        if self.filter_dtype not in ("float32", "float16"):
            raise ValueError(f"filter_dtype must be float32 or float16, got {self.filter_dtype!r}")


def reject_history(current: np.ndarray, warped: np.ndarray) -> int:
    """Restart (in place) the tiles of the warped diffuse or specular history that are far
    brighter than the current frame there (see REJECT_RATIO); returns how many tiles."""
    h, w = current.shape[1:]
    t = REJECT_TILE
    rows, cols = np.minimum(t, h - t * np.arange(-(-h // t))), np.minimum(t, w - t * np.arange(-(-w // t)))
    pixels = np.outer(rows, cols)  # per tile (the last row and column partial)
    rejected = 0
    for c in (0, 3):  # diffuse, specular
        cur, his = F.tile_sums(current, c, t), F.tile_sums(warped, c, t)
        bad = his / pixels > REJECT_RATIO * (cur / pixels + REJECT_FLOOR * cur.sum() / (h * w))
        for ty, tx in np.argwhere(bad):
            tile = (slice(c, c + 3), slice(ty * t, (ty + 1) * t), slice(tx * t, (tx + 1) * t))
            warped[tile] = current[tile]
        rejected += int(bad.sum())
    return rejected


@functools.cache
def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed blocks for reuse instead of handing them back to the
    kernel (process-wide; returns False where there is no glibc). By default a block over
    ~32 MB is always a fresh mmap and smaller ones are trimmed when freed, so every frame's
    arrays (11 MB per 720p RGB layer, 44 MB at 2560x1440) come back as new pages that the
    kernel faults in and zeroes on first write: 12.1 -> 5.9 ms for one 44 MB
    channels-last pass at 1280x720 (9 runs each). The price: the process keeps its peak
    memory."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3
        return bool(libc.mallopt(m_mmap_threshold, 1 << 30) and libc.mallopt(m_trim_threshold, 1 << 31))
    except (OSError, AttributeError):
        return False


class Timer:
    def __init__(self):
        self.ms: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        yield
        self.ms[stage] = self.ms.get(stage, 0.0) + 1000 * (time.perf_counter() - t0)


class Pipeline:
    def __init__(self, cfg: PipelineConfig):
        import onnxruntime as ort

        self.cfg = cfg
        root = Path(cfg.artifacts)
        mpath = root / "manifest.json"
        if not mpath.is_file():
            raise ArtifactError(f"{mpath}: missing; run `jnds export --out {root}` first")
        self.manifest = json.loads(mpath.read_text())
        if self.manifest.get("format") != ARTIFACT_FORMAT:
            raise ArtifactError(f"{mpath}: format {self.manifest.get('format')!r}, expected {ARTIFACT_FORMAT!r}; "
                                "re-run `jnds export` (and `jnds calibrate`) with this version")
        self.scale = int(self.manifest["scale"])
        self.out_scale = 1 if cfg.native_output else self.scale  # output size / input size
        self.multiple = int(self.manifest["pad_multiple"])
        self.levels = int(self.manifest["filter_paths"]["levels"])
        # the upsample filter's interpolation (model.ModelConfig.upsample_root; artifacts of
        # checkpoints from before it was a choice have no entry: linear)
        self.upsample_root = self.manifest["model_config"].get("upsample_root", 1)
        if self.upsample_root not in (1, 2, 4, 8):  # model.UPSAMPLE_ROOTS (the runtime has no torch)
            raise ArtifactError(f"{mpath}: model_config.upsample_root is {self.upsample_root!r}, "
                                "expected 1, 2, 4 or 8")
        self.dtype = np.dtype(cfg.filter_dtype)
        if cfg.keep_freed_memory:
            keep_freed_memory()
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = cfg.threads
        opts.inter_op_num_threads = 1
        # ORT's idle threads spin after each run by default and then compete with the
        # numba filter stage for the cores: 160x90 int8, 74.1 ms/frame median (p90
        # 147.9) with spinning, 29.5 ms (p90 39.7) without, same machine and frames
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self._opts = opts
        # graph name -> {frozenset of dropped output groups: file}; frozenset() is the full graph
        self.graph_files, self.graph_precision, self.variant_files = {}, {}, {}
        for name, g in self.manifest["graphs"].items():
            if cfg.precision == "fp32" or name in cfg.fp32_graphs:
                entry = g
            else:
                method = cfg.int8_method or next((m for m, e in g.get("int8", {}).items()
                                                  if e.get("file") == g.get("int8_file")), None)
                entry = g.get("int8", {}).get(method, {}) if method else {}
            file = entry.get("file")
            if not file or not (root / file).is_file():
                what = f"int8 ({cfg.int8_method})" if cfg.int8_method else cfg.precision
                raise ArtifactError(f"{root}: no {what} graph for {name!r}"
                                    + ("; run `jnds calibrate`" if cfg.precision == "int8" else ""))
            self.graph_files[name] = root / file
            self.graph_precision[name] = "fp32" if file == g["file"] else "int8"
            self.variant_files[name] = {frozenset(): root / file}
            for v in entry.get("variants", {}).values():
                if (root / v["file"]).is_file():
                    self.variant_files[name][frozenset(v["drops"])] = root / v["file"]
        # sessions are created when first needed (a pruned variant only when a frame skips
        # what it drops); shared with fork()ed pipelines
        self.sessions: dict[str, object] = {}
        self._variant_sessions: dict[tuple[str, frozenset], object] = {}
        self._sessions_lock = threading.Lock()
        for name in self.graph_files:
            if name != "upsample" or self.out_scale > 1:
                self.sessions[name] = self._session(name)
        # called as on_feeds(graph name, {input name: array}) before every graph runs:
        # how calibration records the inputs the network really sees, history included
        self.on_feeds = None
        self.nonfinite: dict[str, int] = {}  # per input layer, NaN/Inf met in the last frame
        self.rejected = 0  # history tiles restarted from the current frame in the last frame
        self.disoccluded = 0  # history pixels replaced by the current inputs (filters.disoccluded)
        # what adaptive execution decided for the last frame (all False with adaptive off):
        # static: zero motion everywhere, the history is used as it is (no resampling);
        # skip_diffuse / skip_specular: that signal is zero in the frame and its history, so
        # its filter path, whose output would be exactly zero, is not run, nor the network's
        # kernels for it; network_graph: the pruned network variant that ran (export.prune);
        # empty_tiles: background tiles passed through the filter stage (TILE)
        self.decisions: dict[str, bool] = {}
        self.reset()

    def _radiance_scale(self, current: np.ndarray, warped: np.ndarray) -> float:
        """1, or for the float16 filter stage a power of two bringing the frame's radiance
        (current and history) under FP16_SAFE_MAX."""
        if self.dtype != np.float16:
            return 1.0
        peak = max(float(current[:6].max()), float(warped[:6].max()))
        if peak <= FP16_SAFE_MAX:
            return 1.0
        return float(2.0 ** -np.ceil(np.log2(peak / FP16_SAFE_MAX)))

    def _variant(self, name: str, drops: frozenset) -> frozenset:
        return max((d for d in self.variant_files[name] if d <= drops), key=len)

    def _session(self, name: str, drops: frozenset = frozenset()):
        """The ONNX Runtime session of graph ``name`` without the output groups ``drops``
        (export.prune): the smallest variant on disk that drops a subset of them."""
        import onnxruntime as ort

        best = self._variant(name, drops)
        with self._sessions_lock:
            sess = self._variant_sessions.get((name, best))
            if sess is None:
                sess = ort.InferenceSession(str(self.variant_files[name][best]), self._opts,
                                            providers=["CPUExecutionProvider"])
                self._variant_sessions[(name, best)] = sess
        return sess

    def _upsample_kernel(self, feeds: dict, tiles) -> np.ndarray:
        """The upsample block's kernel in phase layout (s*s*9, H, W) (the graph runs at
        native resolution, export.convert); with empty tiles, computed only on the bounding
        box of the others (plus UPSAMPLE_HALO), the rest left zero (not read)."""
        sess = self.sessions["upsample"]
        if tiles is None:
            return sess.run(None, feeds)[0][0]
        _, _, h, w = feeds["composite"].shape
        kernel = np.zeros((self.scale * self.scale * 9, h, w), np.float32)
        rows, cols = np.flatnonzero(~tiles.all(1)), np.flatnonzero(~tiles.all(0))
        if rows.size == 0:
            return kernel
        y0, y1 = max(rows[0] * TILE - UPSAMPLE_HALO, 0), min((rows[-1] + 1) * TILE + UPSAMPLE_HALO, h)
        x0, x1 = max(cols[0] * TILE - UPSAMPLE_HALO, 0), min((cols[-1] + 1) * TILE + UPSAMPLE_HALO, w)
        if (y1 - y0) * (x1 - x0) == h * w:
            return sess.run(None, feeds)[0][0]
        box = {k: np.ascontiguousarray(v[:, :, y0:y1, x0:x1]) for k, v in feeds.items()}
        kernel[:, y0:y1, x0:x1] = sess.run(None, box)[0][0]
        return kernel

    def fork(self) -> "Pipeline":
        """Another pipeline over the same ONNX Runtime sessions (their ``run`` is
        thread-safe) with its own history: one per stream in ``jnds serve``."""
        other = copy.copy(self)
        other.on_feeds = None
        other.nonfinite = {}
        other.reset()
        return other

    def reset(self) -> None:
        self.history: np.ndarray | None = None  # (Hp, Wp, 12) filtered outputs of the last frame, channels last (the warp's layout)
        self.size: tuple[int, int] | None = None

    def __call__(self, layers: dict, camera_cut: bool = False) -> tuple[np.ndarray, dict[str, float]]:
        t = Timer()
        h, w = check_layers(layers)
        with t("reformat"):
            # NaN/Inf replaced and counted, values clamped into range (reformat.LIMITS)
            self.nonfinite = {}
            padded = (h + (-h) % self.multiple, w + (-w) % self.multiple)
            current = to_chw(layers, [n for n, _ in CURRENT], padded, self.nonfinite)
            motion = to_chw(layers, ["motion"], padded, self.nonfinite)
        if camera_cut or self.history is None or self.size != (w, h):
            self.history = None
        self.rejected = self.disoccluded = 0
        adaptive = self.cfg.adaptive
        self.decisions = {"static": False, "skip_diffuse": False, "skip_specular": False}
        with t("warp"):
            if self.history is None:
                warped = current[:12].copy()
            else:
                if adaptive and not motion.any():  # bicubic resampling at zero motion is the identity
                    self.decisions["static"] = True
                    warped = np.empty(current[:12].shape, np.float32)
                    np.clip(self.history.transpose(2, 0, 1), HISTORY_LO[:, None, None], HISTORY_HI[:, None, None], out=warped)
                    self.disoccluded = F.reject_disoccluded(current, warped)
                else:  # with the geometric rejection fused into the warp's pass
                    warped, self.disoccluded = F.warp_channels_last(self.history, motion, HISTORY_LO, HISTORY_HI,
                                                                    current)
                self.rejected = reject_history(current, warped)
        # a signal that is zero in the frame and its history has a zero filter path: the
        # network variant without its kernels runs, and the path is not filtered
        for c0, path in ((0, "diffuse"), (3, "specular")):
            self.decisions[f"skip_{path}"] = bool(adaptive and not current[c0:c0 + 3].any()
                                                  and not warped[c0:c0 + 3].any())
        drops = frozenset([p for p in RADIANCE if self.decisions[f"skip_{p}"]]
                          + (["features"] if self.out_scale == 1 else []))
        feeds = {"current": current[None], "history": warped[None]}
        if self.on_feeds:
            self.on_feeds("network", feeds)
        sess = self.sessions["network"]
        if drops:
            sess = self._session("network", drops)
            if variant := self._variant("network", drops):
                self.decisions["network_graph"] = variant_key(variant)
        with t("network"):
            outs = sess.run(None, feeds)
        with t("reformat"):
            rs = self._radiance_scale(current, warped)
            net = {o.name: a[0].astype(self.dtype, copy=False) for o, a in zip(sess.get_outputs(), outs)}

            def part(a, name):  # a layer in the filter stage's dtype (radiance scaled)
                return (a * rs if rs != 1 and name in RADIANCE else a).astype(self.dtype, copy=False)

            cur = {n: part(current[i:i + c], n) for (n, c), i in zip(CURRENT, np.cumsum([0] + [c for _, c in CURRENT]))}
            hist = {n: part(warped[3 * i:3 * i + 3], n) for i, n in enumerate(HISTORY_LAYERS)}
        tiles = None
        if adaptive and self.cfg.tile_skip and self.dtype == np.float32:
            with t("tile_skip"):
                tiles = F.empty_tiles(current, warped, TILE, TILE_FLAT)
                self.decisions["empty_tiles"] = int(tiles.sum())
                if not tiles.any():
                    tiles = None
        sk = {"skip": tiles, "tile": TILE}
        filtered = {}
        for path in RADIANCE:
            if self.decisions[f"skip_{path}"]:
                filtered[path] = np.zeros_like(cur[path])
                continue
            with t(f"filter_{path}"):
                native = {k: net[f"{path}.{k}"] for k in ("spatial", "temporal", "blend", "up", "up_blend")
                          if f"{path}.{k}" in net}
                levels = [{k: net[f"{path}.level{lv}.{k}"] for k in ("down", "up", "up_blend")
                           if f"{path}.level{lv}.{k}" in net} for lv in range(1, self.levels + 1)]
                filtered[path] = F.filter_path(cur[path], hist[path], native, levels, **sk)
        with t("filter_auxiliary"):
            # albedo and normals in one pass over their 6 adjacent channels. The kernels are
            # normalized (taps >= 0, summing to 1) and the blend convex, so filtering the
            # normals as n * 0.5 + 0.5 and mapping back (the model) equals filtering n, and
            # the ReLU never acts (albedo in [0, 1]): no ReLU and no remapping passes
            ks, kt, b = net["aux.spatial"], net["aux.temporal"], net["aux.blend"]
            aux = F.spatiotemporal(current[AUX].astype(self.dtype, copy=False),
                                   warped[AUX].astype(self.dtype, copy=False), ks, kt, b, relu=False, **sk)
            filtered["albedo"], filtered["normal"] = aux[:3], aux[3:]
        with t("composite"):
            comp = F.composite(filtered["albedo"], filtered["diffuse"], filtered["specular"])
        if self.out_scale > 1:
            feeds = {"composite": (comp[None] / rs if rs != 1 else comp[None]).astype(np.float32, copy=False),
                     "features": net["features"][None].astype(np.float32, copy=False)}
            if self.on_feeds:
                self.on_feeds("upsample", feeds)
            with t("upsample_kernel"):
                kernel = self._upsample_kernel(feeds, tiles)
            with t("upsample_filter"):
                out = F.upsample_filter(comp, kernel.astype(self.dtype, copy=False), self.scale, **sk,
                                        root=self.upsample_root)
        else:
            out = comp
        with t("reformat"):
            self.history = F.channels_last(*[filtered[n] for n in HISTORY_LAYERS], flush=HISTORY_FLUSH)
            if rs != 1:
                self.history[..., :6] /= rs
                out = out.astype(np.float32) / rs
            self.size = (w, h)
            result = to_hwc(out, h * self.out_scale, w * self.out_scale)
            # last line of defence: nothing non-finite reaches the history or the output
            for name, a in (("history", self.history), ("output", result)):
                if not np.isfinite(a).all():
                    self.nonfinite[name] = int(a.size - np.isfinite(a).sum())
                    np.nan_to_num(a, copy=False, nan=0.0, posinf=F.HDR_MAX, neginf=0.0)
        t.ms["total"] = sum(t.ms.values())
        return result, t.ms
