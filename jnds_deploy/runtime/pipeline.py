"""The frame-recurrent pipeline: ONNX Runtime for the network graphs, numpy/numba for
the filter stage, and the history between frames.

``Pipeline(PipelineConfig(artifacts=DIR))`` needs nothing but the artifact directory
(its ``manifest.json``, ``artifacts.Manifest``, and the int8 graphs of ``jnds calibrate``
unless ``precision="fp32"``). Each call takes one frame's input layers
as read by ``jnds_deploy.io`` (HWC float32) and returns a ``FrameResult``: the output
colour (HWC float32, linear, at target resolution), the time of every stage in
milliseconds, and what the frame met and decided.

A frame goes through the paper's stages in order: reformat (and sanitize) the inputs,
warp the history, the network (input block, feature extractor, output block) in ONNX
Runtime, the filter paths, the composite, the upsample block and its filter, and the
filtered signals are stored as the next frame's history. History is reset on the first
frame, on a camera cut and on a change of resolution; odd sizes are padded (edge
replicate) to the network's multiple and cropped back.
"""

from __future__ import annotations

import copy
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..artifacts import Manifest, variant_key
from ..errors import ArtifactError, FrameError
from ..layout import CURRENT, GUIDE, HISTORY, INPUT_CHANNELS, RADIANCE, channels, guide_of
from ..process import keep_freed_memory, shared_arena_registered
from . import filters as F
from .config import PipelineConfig
from .head import Coded
from .history import History, Warped, replace_nonfinite
from .network import quiet, run_network
from .reformat import to_chw, to_hwc

# albedo then normal: adjacent and at the same channels in the current inputs and the
# history (whose layout is the current inputs' first 12 channels), filtered in one pass
AUX = slice(channels("albedo").start, channels("normal").stop)
# the float16 filter stage filters radiance at most this bright; brighter frames are scaled
# down by a power of two (exact in floating point) and back up after filtering. 65504 (the
# largest half) / 32: headroom for the kernels' gain (diffuse/specular weights are in
# [-1, 1], 9 taps per filter)
FP16_SAFE_MAX = 2048.0
# adaptive tile skipping: tiles of TILE^2 native pixels that see no geometry and a
# background varying by at most TILE_FLAT x its brightness (runtime.filters.empty_tiles)
# pass through the filter stage (the current frame's values, bilinearly upsampled) and
# the upsample block runs only on the bounding box of the other tiles, with a margin of
# UPSAMPLE_HALO native pixels (its bilinear upsampling and 3x3 convolution reach 1 native
# pixel; 2 keep the box's inside equal to the whole frame's)
TILE = 16
TILE_FLAT = 0.1
UPSAMPLE_HALO = 2
KERNEL_PARTS = ("spatial", "temporal", "blend", "up", "up_blend")
LEVEL_PARTS = ("down", "up", "up_blend")


def check_layers(layers: dict, guide: bool = False) -> tuple[int, int]:
    """The frame's (H, W), or FrameError naming the missing or misshapen layer (with
    ``guide``, the guide albedo's too where the frame has one)."""
    missing = [n for n in INPUT_CHANNELS if n not in layers]
    if missing:
        raise FrameError(f"frame: missing layer(s) {', '.join(missing)}")
    h, w = np.shape(layers["diffuse"])[:2]
    expected = dict(INPUT_CHANNELS, **({GUIDE.name: GUIDE.channels} if guide and GUIDE.name in layers else {}))
    for n, c in expected.items():
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


@dataclass
class FrameResult:
    output: np.ndarray  # (H * out_scale, W * out_scale, 3) float32, linear
    ms: dict[str, float]  # per stage, and "total"
    nonfinite: dict[str, int] = field(default_factory=dict)  # NaN/Inf replaced, per input layer (and
    # "history"/"output" if something upstream broke)
    # what adaptive execution decided (all False with adaptive off): static: zero motion
    # everywhere, the history is used as it is (no resampling); skip_diffuse / skip_specular:
    # that signal is zero in the frame and its history, so its filter path, whose output
    # would be exactly zero, is not run, nor the network's kernels for it; network_graph:
    # the pruned network variant that ran (export.prune); empty_tiles: background tiles
    # passed through the filter stage (TILE)
    decisions: dict[str, bool | int | str] = field(default_factory=dict)
    disoccluded: int = 0  # history pixels replaced by the current inputs (filter_spec.history_rejected)
    rejected: int = 0  # history tiles restarted from the current frame (history.reject_history)
    clamped: int = 0  # current diffuse/specular pixel values clamped as fireflies (filters.clamp_fireflies)
    filled: int = 0  # current diffuse pixels filled from their neighbours' (filters.fill_diffuse_holes)


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
        self.cfg = cfg
        root = Path(cfg.artifacts)
        self.manifest = Manifest.load(root)
        if cfg.precision == "int8" and not any(g.int8 for g in self.manifest.graphs.values()):
            raise ArtifactError(
                f"{root}: no int8 graphs, and precision is int8 (the default): run `jnds calibrate "
                f"--artifacts {root} --data SEQUENCES` first, or choose precision fp32 "
                f"(`--precision fp32`)"
            )
        self.scale = self.manifest.scale
        self.out_scale = 1 if cfg.native_output else self.scale  # output size / input size
        self.multiple = self.manifest.pad_multiple
        self.levels = self.manifest.filter_levels
        self.upsample_root = self.manifest.upsample_root
        self.firefly_clamp = self.manifest.firefly_clamp if cfg.firefly_clamp is None else cfg.firefly_clamp
        self.diffuse_fill = self.manifest.diffuse_fill if cfg.diffuse_fill is None else cfg.diffuse_fill
        self.albedo_at_holes = self.manifest.albedo_at_holes if cfg.albedo_at_holes is None else cfg.albedo_at_holes
        self.guide_albedo = self.manifest.guide_albedo  # a weight: the graph's input, no switch
        # a model with one fixed upsample kernel has no upsample graph (Manifest.load checks the
        # kernel); at 2x it runs as one fused pass into the output (filters.upsample_fixed_hwc)
        self._fixed_kernel = None if "upsample" in self.manifest.graphs else self.manifest.upsample_kernel
        self._fused_upsample = self._fixed_kernel is not None and self.out_scale == 2
        self.dtype = np.dtype(cfg.filter_dtype)
        if cfg.keep_freed_memory:
            keep_freed_memory()
        opts = quiet()  # errors only: a cut int8 graph's entries are warned about (runtime.network.quiet)
        opts.intra_op_num_threads = cfg.threads
        opts.inter_op_num_threads = 1
        # memory (docs/architecture.md, "The process"): no per-session pre-planned block,
        # and, where the process opted into one (process.shared_arena: `jnds run`, `serve`,
        # `batch`), the one arena of the process that grows by what is asked: the graphs'
        # intermediates then reuse the same memory instead of each session keeping its peak
        opts.enable_mem_pattern = False
        if shared_arena_registered():
            opts.add_session_config_entry("session.use_env_allocators", "1")
        # ORT's idle threads spin after each run by default and then compete with the
        # numba filter stage for the cores (docs/architecture.md, "The process")
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self._opts = opts
        self.graphs = {}
        for name in self.manifest.graphs:
            precision = "fp32" if cfg.precision == "fp32" or name in cfg.fp32_graphs else "int8"
            self.graphs[name] = self.manifest.choose(root, name, precision, cfg.int8_method)
        # sessions are created when first needed (a pruned variant only when a frame skips
        # what it drops); shared with fork()ed pipelines
        self.sessions: dict[str, object] = {}
        self._variant_sessions: dict[tuple[str, frozenset], object] = {}
        self._sessions_lock = threading.Lock()
        for name in self.graphs:
            if name != "upsample" or self.out_scale > 1:
                self.sessions[name] = self._session(name)
        # called as on_feeds(graph name, {input name: array}) before every graph runs:
        # how calibration records the inputs the network really sees, history included
        self.on_feeds = None
        self.history = History()
        self._edges: dict = {}  # runtime.network.Edges of each network session (u8 inputs, u8 head)

    # -- sessions --------------------------------------------------------------------------

    def _variant(self, name: str, drops: frozenset) -> frozenset:
        return max((d for d in self.graphs[name].variants if d <= drops), key=len)

    def _session(self, name: str, drops: frozenset = frozenset()):
        """The ONNX Runtime session of graph ``name`` without the output groups ``drops``
        (export.prune): the smallest variant on disk that drops a subset of them."""
        import onnxruntime as ort

        best = self._variant(name, drops)
        with self._sessions_lock:
            sess = self._variant_sessions.get((name, best))
            if sess is None:
                sess = ort.InferenceSession(
                    str(self.graphs[name].variants[best]),
                    self._opts,
                    providers=["CPUExecutionProvider"],
                    disabled_optimizers=self.disabled_optimizers(name) or None,
                )
                self._variant_sessions[(name, best)] = sess
        return sess

    def disabled_optimizers(self, name: str) -> list[str]:
        """ONNX Runtime graph optimizers the session of graph ``name`` runs without. int8
        graphs: no NCHWc layout. Their only fp32 convolution (the output block's head)
        would run in it, and reordering its 85 output channels back costs more than the
        layout gains (docs/architecture.md, "The int8 graph")."""
        return ["NchwcTransformer"] if self.graphs[name].precision == "int8" else []

    def fork(self) -> "Pipeline":
        """Another pipeline over the same ONNX Runtime sessions (their ``run`` is
        thread-safe) with its own history: one per stream in ``jnds serve``."""
        other = copy.copy(self)
        other.on_feeds = None
        other.history = History()
        return other

    @property
    def graph_precision(self) -> dict[str, str]:
        """{graph: the precision it runs at} (int8 pipelines keep ``fp32_graphs`` in fp32)."""
        return {name: choice.precision for name, choice in self.graphs.items()}

    def reset(self) -> None:
        """Drop the history: the next frame is a first frame."""
        self.history.reset()

    # -- one frame -----------------------------------------------------------------------

    def __call__(self, layers: dict, camera_cut: bool = False) -> FrameResult:
        t = Timer()
        h, w = check_layers(layers, self.guide_albedo)
        nonfinite: dict[str, int] = {}
        with t("reformat"):  # NaN/Inf replaced and counted, values clamped into range
            padded = (h + (-h) % self.multiple, w + (-w) % self.multiple)
            current = to_chw(layers, [n for n, _ in CURRENT], padded, nonfinite)
            motion = to_chw(layers, ["motion"], padded, nonfinite)
            # the guide albedo (layout.guide_of: the albedo where the frame has none, whose
            # non-finite values are counted once, as the albedo's)
            guide = None
            if self.guide_albedo:
                guide = to_chw(
                    {GUIDE.name: guide_of(layers)}, [GUIDE.name], padded, nonfinite if GUIDE.name in layers else None
                )
        filled, holes = 0, None
        if self.diffuse_fill or self.albedo_at_holes:
            with t("diffuse_fill"):  # finding the holes (one pass), then filling them
                holes = F.diffuse_holes(current)
                if self.diffuse_fill:
                    filled = F.fill_diffuse_holes(current, holes)
        if camera_cut:
            self.history.reset()
        with t("warp"):
            warped = self.history.warp(current, motion, (w, h), self.cfg.adaptive)
        clamped = 0
        if self.firefly_clamp and warped.valid:  # without a history every pixel bounds itself
            with t("firefly_clamp"):
                clamped = F.clamp_fireflies(current, warped.signals, self.firefly_clamp)
        decisions = self._decide(current, warped)
        net = self._network(current, warped.signals, guide, decisions, t)
        with t("reformat"):
            rs = self._radiance_scale(current, warped.signals)
            cur, hist, net = self._filter_inputs(current, warped.signals, net, rs)
        tiles = self._empty_tiles(current, warped.signals, decisions, t)
        filtered = self._filter_paths(current, warped.signals, cur, hist, net, decisions, tiles, t)
        with t("composite"):
            comp = F.composite(filtered["albedo"], filtered["diffuse"], filtered["specular"])
        if self.albedo_at_holes:  # the composite again where holes lie scattered
            with t("albedo_at_holes"):
                F.albedo_at_holes(comp, filtered["albedo"], filtered["diffuse"], filtered["specular"], holes)
        if self._fused_upsample:
            # one fixed kernel at 2x: upsampling, kernel, layout and the non-finite check in one pass
            with t("upsample_filter"):
                result, bad_out = F.upsample_fixed_hwc(comp, self._fixed_kernel, self.upsample_root, h, w)
            out = None
        else:
            out = self._upsample(comp, net, rs, tiles, t) if self.out_scale > 1 else comp
        with t("reformat"):
            if bad := self.history.store(filtered, (w, h), rs):
                nonfinite["history"] = bad
            if out is not None:
                if rs != 1:
                    out = out.astype(np.float32) / rs
                result = to_hwc(out, h * self.out_scale, w * self.out_scale)
                # last line of defence: nothing non-finite reaches the output
                bad_out = replace_nonfinite(result)
            elif rs != 1:
                result /= np.float32(rs)
            if bad_out:
                nonfinite["output"] = bad_out
        t.ms["total"] = sum(t.ms.values())
        return FrameResult(result, t.ms, nonfinite, decisions, warped.disoccluded, warped.rejected, clamped, filled)

    def _decide(self, current: np.ndarray, warped: Warped) -> dict:
        """What this frame can skip: a signal that is zero in the frame and its history has
        a zero filter path (the network variant without its kernels runs, and the path is
        not filtered)."""
        adaptive = self.cfg.adaptive
        decisions = {"static": warped.static}
        for path in RADIANCE:
            c = channels(path)
            decisions[f"skip_{path}"] = bool(adaptive and not current[c].any() and not warped.signals[c].any())
        return decisions

    def _network(
        self, current: np.ndarray, warped: np.ndarray, guide: np.ndarray | None, decisions: dict, t: Timer
    ) -> dict:
        """Input block, feature extractor and output block: {output name: (C, H, W)}."""
        drops = frozenset(
            [p for p in RADIANCE if decisions[f"skip_{p}"]] + (["features"] if self.out_scale == 1 else [])
        )
        feeds = {"current": current[None], "history": warped[None]}
        if guide is not None:
            feeds["guide"] = guide[None]
        if self.on_feeds:
            self.on_feeds("network", feeds)
        sess = self.sessions["network"]
        if drops:
            sess = self._session("network", drops)
            if variant := self._variant("network", drops):
                decisions["network_graph"] = variant_key(variant)
        with t("network"):
            outs = run_network(sess, feeds, self._edges, coded=True)
        return {k: a if isinstance(a, Coded) else a[0] for k, a in outs.items()}

    def _radiance_scale(self, current: np.ndarray, warped: np.ndarray) -> float:
        """1, or for the float16 filter stage a power of two bringing the frame's radiance
        (current and history) under FP16_SAFE_MAX."""
        if self.dtype != np.float16:
            return 1.0
        radiance = slice(0, channels("specular").stop)
        peak = max(float(current[radiance].max()), float(warped[radiance].max()))
        if peak <= FP16_SAFE_MAX:
            return 1.0
        return float(2.0 ** -np.ceil(np.log2(peak / FP16_SAFE_MAX)))

    def _filter_inputs(self, current: np.ndarray, warped: np.ndarray, net: dict, rs: float):
        """The current and history layers and the network outputs in the filter stage's
        dtype (radiance scaled by ``rs``)."""

        def part(a, name):
            return (a * rs if rs != 1 and name in RADIANCE else a).astype(self.dtype, copy=False)

        cur = {n: part(current[channels(n)], n) for n, _ in CURRENT}
        hist = {n: part(warped[channels(n, HISTORY)], n) for n, _ in HISTORY}
        # the int8 head's outputs stay coded for the float32 filter loops (runtime.head)
        net = {
            k: a
            if isinstance(a, Coded) and self.dtype == np.float32
            else (a.decode() if isinstance(a, Coded) else a).astype(self.dtype, copy=False)
            for k, a in net.items()
        }
        return cur, hist, net

    def _empty_tiles(self, current: np.ndarray, warped: np.ndarray, decisions: dict, t: Timer):
        if not (self.cfg.adaptive and self.cfg.tile_skip and self.dtype == np.float32):
            return None
        with t("tile_skip"):
            tiles = F.empty_tiles(current, warped, TILE, TILE_FLAT)
            decisions["empty_tiles"] = int(tiles.sum())
        return tiles if tiles.any() else None

    def _filter_paths(self, current, warped, cur, hist, net, decisions, tiles, t: Timer) -> dict:
        """The diffuse and specular filter paths and the auxiliary (albedo, normal) filter:
        {layer: (C, H, W) filtered}."""
        sk = {"skip": tiles, "tile": TILE}
        filtered = {}
        for path in RADIANCE:
            if decisions[f"skip_{path}"]:
                filtered[path] = np.zeros_like(cur[path])
                continue
            with t(f"filter_{path}"):
                native = {k: net[f"{path}.{k}"] for k in KERNEL_PARTS if f"{path}.{k}" in net}
                levels = [
                    {k: net[f"{path}.level{lv}.{k}"] for k in LEVEL_PARTS if f"{path}.level{lv}.{k}" in net}
                    for lv in range(1, self.levels + 1)
                ]
                filtered[path] = F.filter_path(cur[path], hist[path], native, levels, **sk)
        with t("filter_auxiliary"):
            # albedo and normals in one pass over their 6 adjacent channels. The kernels are
            # normalized (taps >= 0, summing to 1) and the blend convex, so filtering the
            # normals as n * 0.5 + 0.5 and mapping back (the model) equals filtering n, and
            # the ReLU never acts (albedo in [0, 1]): no ReLU and no remapping passes
            aux = F.spatiotemporal(
                current[AUX].astype(self.dtype, copy=False),
                warped[AUX].astype(self.dtype, copy=False),
                net["aux.spatial"],
                net["aux.temporal"],
                net["aux.blend"],
                relu=False,
                **sk,
            )
            filtered["albedo"], filtered["normal"] = aux[:3], aux[3:]
        return filtered

    def _upsample(self, comp: np.ndarray, net: dict, rs: float, tiles, t: Timer) -> np.ndarray:
        """The upsample block (its graph) and the upsample filter: (3, sH, sW). With one
        fixed kernel (no upsample graph) every target pixel gets it, empty tiles too."""
        if self._fixed_kernel is not None:
            with t("upsample_filter"):
                return F.upsample_fixed(comp, self._fixed_kernel, self.scale, root=self.upsample_root)
        feeds = {
            "composite": (comp[None] / rs if rs != 1 else comp[None]).astype(np.float32, copy=False),
            "features": net["features"][None].astype(np.float32, copy=False),
        }
        if self.on_feeds:
            self.on_feeds("upsample", feeds)
        with t("upsample_kernel"):
            kernel = self._upsample_kernel(feeds, tiles)
        with t("upsample_filter"):
            return F.upsample_filter(
                comp, kernel.astype(self.dtype, copy=False), self.scale, skip=tiles, tile=TILE, root=self.upsample_root
            )

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
