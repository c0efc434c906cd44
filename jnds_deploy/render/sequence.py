"""Render one camera-animated sequence in the ``jnds-sequence/1`` format.

Per frame:
- inputs at native resolution: ``spp_input`` paths (1 by default) through the frame's
  Halton-jittered sample position; diffuse radiance demodulated by the albedo of that
  same sample, specular with emission/background; G-buffer of the first vertex;
- motion vectors: the pixel-centre surface point (or, for background, direction)
  reprojected into the previous frame's camera; on an object that moves (scene kind
  ``moving``), the point carried back with the object's own motion first;
- reference at ``scale`` x native resolution: ``spp`` paths per target pixel at
  uniformly random positions inside it (box filter), converged colour and components.

Frames are written atomically and ``sequence.json`` last, so an interrupted render
resumes where it stopped (frames already on disk and readable are kept).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..blender.scenes import CYCLES_SCENE_KINDS
from ..errors import JndsError, RenderError
from ..io import (
    INPUT_LAYERS,
    OPTIONAL_INPUT_LAYERS,
    OPTIONAL_REFERENCE_LAYERS,
    REFERENCE_LAYERS,
    FrameInfo,
    SequenceWriter,
    read_layers,
)
from ..options import option, parse_size, show_size
from ..sampling import jitter
from .camera import CAMERA_PATHS, Camera, camera_path
from .scene import EXTENT, OBJECT_PREFIX, SCENE_KINDS, build_scene, object_motion

ALBEDO_EPS = 1e-3  # below this albedo, demodulated diffuse is written as 0 (format contract)
MAX_LANES = 1 << 21  # paths traced per Mitsuba call: bounds memory, amortizes tracing


ENGINES = ("mitsuba", "cycles")


@dataclass(frozen=True)
class RenderConfig:
    scene: str | None = option(
        None,
        f"one of the engine's scene kinds (default: {SCENE_KINDS[0]} with mitsuba, {CYCLES_SCENE_KINDS[0]} "
        f"with cycles)",
        choices=SCENE_KINDS + CYCLES_SCENE_KINDS,
    )
    seed: int = option(0, "scene, camera path and noise seed")
    camera: str = option("orbit", "the camera path", choices=CAMERA_PATHS)
    frames: int = option(8, "frames of the sequence")
    size: tuple[int, int] = option((160, 90), "native size WxH", type=parse_size, show=show_size)
    scale: int = option(2, "reference size = scale x native")
    spp: int = option(64, "reference samples per target pixel")
    spp_input: int = option(1, "input samples per native pixel, all at the jittered position")
    max_depth: int = option(5, "path vertices, the first included")
    reference: bool = option(True, "render the reference frames too (off: inputs only)")
    variant: str | None = option(
        None, "Mitsuba variant (default: llvm_ad_rgb if LLVM 19 is installed, else scalar_rgb)"
    )
    engine: str = option(
        "mitsuba",
        "mitsuba: this package's path tracer; cycles: Blender (its environment, .venv-blender; blender.render)",
        choices=ENGINES,
    )

    def __post_init__(self):
        if self.engine not in ENGINES:
            raise RenderError(f"--engine {self.engine!r}: expected one of {', '.join(ENGINES)}")
        if self.scene is None:
            object.__setattr__(self, "scene", (CYCLES_SCENE_KINDS if self.engine == "cycles" else SCENE_KINDS)[0])
        kinds = CYCLES_SCENE_KINDS if self.engine == "cycles" else SCENE_KINDS
        if self.scene not in kinds:
            raise RenderError(f"--scene {self.scene!r} (engine {self.engine}): expected one of {', '.join(kinds)}")
        if self.camera not in CAMERA_PATHS:
            raise RenderError(f"--camera {self.camera!r}: expected one of {', '.join(CAMERA_PATHS)}")
        if self.frames < 1:
            raise RenderError(f"--frames must be >= 1, got {self.frames}")
        w, h = self.size
        if w < 1 or h < 1:
            raise RenderError(f"--size must be positive, got {w}x{h}")
        for name in ("scale", "spp", "spp_input", "max_depth"):
            if getattr(self, name) < 1:
                raise RenderError(f"{name} must be >= 1, got {getattr(self, name)}")

    @property
    def target_size(self) -> tuple[int, int]:
        return (self.size[0] * self.scale, self.size[1] * self.scale)


def _seed(*parts) -> int:
    return int.from_bytes(hashlib.sha256(repr(parts).encode()).digest()[:6], "little")


def _pixel_grid(w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    y, x = np.mgrid[0:h, 0:w]
    return x.ravel().astype(np.float64), y.ravel().astype(np.float64)


def motion_vectors(tracer, cam: Camera, prev: Camera, size: tuple[int, int], moved: dict | None = None) -> np.ndarray:
    """(H, W, 2) offsets from each pixel centre to where its surface point was in ``prev``.

    ``moved``: {shape id: (centre now (3,), its move since the previous frame (3,), its
    turn about the vertical axis through the centre since then, degrees)}; a point on such
    a shape is first carried back to where it was on the shape in the previous frame."""
    w, h = size
    x, y = _pixel_grid(w, h)
    o, d = cam.rays(x + 0.5, y + 0.5, size)
    t, shape = tracer.intersect(o, d, shapes=True)
    points = np.where(np.isfinite(t)[:, None], o + np.where(np.isfinite(t), t, 0)[:, None] * d, np.nan)
    for name, (centre, move, turn) in (moved or {}).items():
        on = shape == tracer.shape_names.index(name) if name in tracer.shape_names else np.zeros(len(t), bool)
        if on.any():
            points[on] = _turn_y(points[on] - centre, -turn) + centre - move
    pos, front = prev.project(points, size, directions=d)
    # behind the previous camera: point the vector well off-screen (a disocclusion)
    pos = np.where(front[:, None], pos, -4.0 * max(w, h))
    mv = pos - np.stack([x + 0.5, y + 0.5], axis=1)
    return mv.reshape(h, w, 2).astype(np.float32)


def _turn_y(v: np.ndarray, degrees: float) -> np.ndarray:
    """Rows of ``v`` turned about +y as Mitsuba's ``rotate([0, 1, 0], degrees)`` turns them."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[:, 0] + s * v[:, 2], v[:, 1], -s * v[:, 0] + c * v[:, 2]], axis=1)


def _centre(shape: dict) -> np.ndarray:
    if "center" in shape:
        return np.asarray(shape["center"], np.float64)
    return np.asarray(shape["to_world"].matrix, np.float64)[:3, 3]


def moved_objects(scene_now: dict, scene_prev: dict, motion: dict) -> dict:
    """``motion_vectors``' ``moved`` for two consecutive frames' scene dicts."""
    out = {}
    for name, m in motion.items():
        c, p = _centre(scene_now[name]), _centre(scene_prev[name])
        out[name] = (c, c - p, 0.0 if scene_now[name]["type"] == "sphere" else m.spin)
    return out


def _demodulate(radiance: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    ok = albedo > ALBEDO_EPS
    return np.where(ok, radiance / np.where(ok, albedo, 1.0), 0.0).astype(np.float32)


def render_inputs(tracer, cfg: RenderConfig, cam: Camera, jit: tuple[float, float], seed: int) -> dict:
    w, h = cfg.size
    x, y = _pixel_grid(w, h)
    o, d = cam.rays(x + 0.5 + jit[0], y + 0.5 + jit[1], cfg.size)
    n = cfg.spp_input
    s = tracer.trace(np.repeat(o, n, 0), np.repeat(d, n, 0), seed)
    mean = lambda a: a.reshape(h * w, n, -1).mean(1)  # noqa: E731
    first = lambda a: a.reshape(h * w, n, -1)[:, 0]  # noqa: E731
    albedo = first(s.albedo)
    layers = {
        "diffuse": _demodulate(mean(s.diffuse), albedo),
        "specular": mean(s.specular),
        "albedo": albedo,
        "normal": first(s.normal),
        "roughness": first(s.roughness),
        "depth": first(s.depth),
    }
    return {k: v.reshape(h, w, -1).astype(np.float32) for k, v in layers.items()}


def render_reference(tracer, cfg: RenderConfig, cam: Camera, seed: int) -> dict:
    tw, th = cfg.target_size
    n_pix = tw * th
    per_pass = max(1, min(cfg.spp, MAX_LANES // n_pix))
    X, Y = _pixel_grid(tw, th)
    rng = np.random.default_rng(seed)
    sums = {k: np.zeros((n_pix, 3)) for k in ("diffuse", "specular", "albedo")}
    done = 0
    while done < cfg.spp:
        k = min(per_pass, cfg.spp - done)
        u = rng.random((n_pix, k))
        v = rng.random((n_pix, k))
        px = ((X[:, None] + u) / cfg.scale).ravel()
        py = ((Y[:, None] + v) / cfg.scale).ravel()
        o, d = cam.rays(px, py, cfg.size)
        s = tracer.trace(o, d, _seed(seed, done))
        for key in sums:
            sums[key] += getattr(s, key).reshape(n_pix, k, 3).sum(1)
        done += k
    mean = {k: v / cfg.spp for k, v in sums.items()}
    layers = {
        "color": mean["diffuse"] + mean["specular"],
        "diffuse": _demodulate(mean["diffuse"], mean["albedo"]),
        "specular": mean["specular"],
        "albedo": mean["albedo"],
    }
    return {k: v.reshape(th, tw, 3).astype(np.float32) for k, v in layers.items()}


def _frame_done(out: Path, i: int, cfg: RenderConfig) -> bool:
    try:
        read_layers(out / "inputs" / f"{i:04d}.exr", cfg.size, INPUT_LAYERS, OPTIONAL_INPUT_LAYERS)
        if cfg.reference:
            read_layers(
                out / "reference" / f"{i:04d}.exr", cfg.target_size, REFERENCE_LAYERS, OPTIONAL_REFERENCE_LAYERS
            )
    except JndsError:
        return False
    return True


def render_sequence(cfg: RenderConfig, out: str | Path, progress: bool = True) -> dict:
    """Render ``cfg`` into ``out``; resumes a directory that holds the same config.

    Returns timing statistics: seconds per frame for inputs (+ motion) and reference.
    """
    if cfg.engine == "cycles":
        from ..blender.render import render_sequence as render_cycles

        return render_cycles(cfg, out, progress)
    from .integrator import SplitPathTracer, load_mitsuba

    out = Path(out)
    cfg_json = json.dumps(asdict(cfg), sort_keys=True)
    marker = out / "render.json"
    if marker.exists() and json.loads(marker.read_text()).get("config") != json.loads(cfg_json):
        raise RenderError(f"{out}: holds a render of another configuration; use a new --out")
    writer = SequenceWriter(out, cfg.size, cfg.target_size if cfg.reference else None)
    mi, dr = load_mitsuba(cfg.variant)
    marker.write_text(json.dumps({"config": json.loads(cfg_json), "variant": mi.variant()}, indent=1))

    motion = object_motion(
        cfg.seed, cfg.scene, [k for k in build_scene(mi, cfg.seed, cfg.scene)[0] if k.startswith(OBJECT_PREFIX)]
    )

    def scene_at(i):
        return build_scene(mi, cfg.seed, cfg.scene, i, cfg.frames)

    scene_dict, materials = scene_at(0)
    tracer = SplitPathTracer(mi, dr, scene_dict, materials, cfg.max_depth)
    cams, cuts = camera_path(cfg.camera, cfg.frames, np.random.default_rng(_seed("camera", cfg.seed)), extent=EXTENT)
    frames = [FrameInfo(i, jitter(i), cuts[i]) for i in range(cfg.frames)]

    from tqdm import tqdm

    times = {"inputs": [], "reference": []}
    for i in tqdm(range(cfg.frames), desc=f"render {out.name}", unit="frame", disable=not progress):
        if _frame_done(out, i, cfg):
            continue
        t0 = time.perf_counter()
        moved = None
        if motion and i > 0:  # the objects moved: this frame's scene (mi.load_dict consumes a dict)
            scene_dict, materials = scene_at(i)
            moved = moved_objects(scene_dict, scene_at(i - 1)[0], motion)
            tracer = SplitPathTracer(mi, dr, scene_dict, materials, cfg.max_depth)
        layers = render_inputs(tracer, cfg, cams[i], frames[i].jitter, _seed(cfg.seed, i, "inputs"))
        if i == 0 or cuts[i]:
            layers["motion"] = np.zeros((cfg.size[1], cfg.size[0], 2), np.float32)
        else:
            layers["motion"] = motion_vectors(tracer, cams[i], cams[i - 1], cfg.size, moved)
        t1 = time.perf_counter()
        times["inputs"].append(t1 - t0)
        if cfg.reference:
            ref = render_reference(tracer, cfg, cams[i], _seed(cfg.seed, i, "reference"))
            writer.write_reference(i, ref)
            times["reference"].append(time.perf_counter() - t1)
        writer.write_inputs(i, layers)

    cameras = [{"origin": list(c.origin), "target": list(c.target), "fov_y": c.fov_y} for c in cams]
    writer.close(
        frames,
        {
            "renderer": {
                "config": json.loads(cfg_json),
                "variant": mi.variant(),
                "cameras": cameras,
                "moving_objects": {k: asdict(m) for k, m in motion.items()},
            }
        },
    )
    return {k: float(np.median(v)) if v else None for k, v in times.items()}
