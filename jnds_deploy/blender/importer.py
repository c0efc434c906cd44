"""``jnds import cycles``: Blender Cycles renders into ``jnds-sequence/1``.

Reads the multilayer EXRs Blender writes (``<prefix>NNNN.exr``, any frame range; Blender 5
writes one EXR part per pass) after ``jnds_deploy.blender.configure``, and maps Cycles'
passes onto the paper's split:

- albedo = Diffuse Color (Cycles' diffuse light passes are already divided by it);
- diffuse = Diffuse Direct + Diffuse Indirect;
- specular = Glossy Color (Glossy Direct + Indirect) + Transmission Color (Direct +
  Indirect) + Volume Direct + Volume Indirect + Emission + Environment, so that
  albedo * diffuse + specular = Combined;
- normal = Normal (world space; Blender's world is Z-up, kept as is). A camera ray that
  scattered in a volume before reaching any surface leaves Normal, Depth and Vector at 0,
  as on the background, though its radiance is as noisy as any surface's; Cycles' Denoising
  Normal marks it (the view direction, (0, 0, -1) in camera space). Such a pixel gets the
  direction back to the camera (``jnds.json``'s ``toward_camera``), as Cycles gives its own
  denoiser, so the pipeline accumulates it over frames like a surface facing the camera
  rather than passing it through as exact background (docs/model-gap.md, "Volumes");
  depth stays 0 there and roughness 1, and its motion is that of the surfaces around it
  (``volume_motion``): Vector has none, and the light a medium scatters moves with the
  view much as the surfaces behind it do;
- roughness = the ``Roughness`` AOV squared (Blender's perceptual roughness to the
  microfacet alpha, the format's convention); depth = Depth, 0 on the background;
- motion = (Vector.X, -Vector.Y): Vector.xy is the previous-frame position minus the
  current in Blender's y-up raster. Cycles computes it without the keyed lens shift: the
  Vector pass of a jittered render equals an unjittered render's (tests/blender/test_blender.py,
  ``test_motion_vectors_warp_the_previous_frame``), i.e. it describes the pixel centre's
  point, as the format wants; 0 on the background.
- denoising_albedo (optional) = Denoising Albedo where the render has it: not the
  model's input, but the guide a Cycles user gives OIDN, which the OIDN baseline takes.

A reference (``--reference``: the same frames rendered by ``blender.configure_reference``)
gives ``color`` = Combined and the converged components by the same mapping.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import SequenceError
from ..io import FrameInfo, SequenceWriter, read_exr, validate
from . import CYCLES_PASSES, DENOISING_PASSES, PASSES, ROUGHNESS_AOV, SIDECAR  # names only: no bpy at import

SETTINGS = {  # pass -> the Blender setting that enables it
    "Combined": "View Layer Properties > Passes > Data > Combined",
    "Diffuse Direct": "Passes > Light > Diffuse > Direct",
    "Diffuse Indirect": "Passes > Light > Diffuse > Indirect",
    "Diffuse Color": "Passes > Light > Diffuse > Color",
    "Glossy Direct": "Passes > Light > Glossy > Direct",
    "Glossy Indirect": "Passes > Light > Glossy > Indirect",
    "Glossy Color": "Passes > Light > Glossy > Color",
    "Transmission Direct": "Passes > Light > Transmission > Direct",
    "Transmission Indirect": "Passes > Light > Transmission > Indirect",
    "Transmission Color": "Passes > Light > Transmission > Color",
    "Volume Direct": "Passes > Light > Volume > Direct",
    "Volume Indirect": "Passes > Light > Volume > Indirect",
    "Emission": "Passes > Light > Other > Emission",
    "Environment": "Passes > Light > Other > Environment",
    "Normal": "Passes > Data > Normal",
    "Vector": "Passes > Data > Vector (with Render Properties > Motion Blur off)",
    "Depth": "Passes > Data > Z",
    ROUGHNESS_AOV: f"Passes > Shader AOV: a Value AOV named {ROUGHNESS_AOV!r} and an AOV Output node in each material",
}
INPUT_PASSES = [p for p in [*PASSES.values(), *CYCLES_PASSES.values(), ROUGHNESS_AOV] if p != "Combined"]
REFERENCE_PASSES = [p for p in [*PASSES.values(), *CYCLES_PASSES.values()] if p not in ("Normal", "Vector", "Depth")]
VOLUME_MARK = DENOISING_PASSES[0]  # Denoising Normal: non-zero where Normal is 0 marks volume scattering
GUIDE_ALBEDO = DENOISING_PASSES[1]  # Denoising Albedo: the format's optional denoising_albedo
_FRAME = re.compile(r"^(.*?)(\d+)\.exr$")


def read_passes(path: Path) -> dict[str, np.ndarray]:
    """Every pass of a Blender multilayer EXR as (H, W, C) float32, channels in the order
    R, G, B (X, Y, Z, W; A dropped); pass names without the view layer
    (``ViewLayer.Diffuse Color.R`` -> ``Diffuse Color``)."""
    grouped: dict[str, dict[str, np.ndarray]] = {}
    for name, pixels in read_exr(path).items():
        layer, _, comp = name.rpartition(".")
        grouped.setdefault(layer.split(".", 1)[-1], {})[comp] = pixels
    order = "RGBXYZW"
    out = {}
    for name, comps in grouped.items():
        keys = sorted((k for k in comps if k in order), key=order.index)
        if keys:
            out[name] = np.stack([comps[k] for k in keys], -1)
    return out


def _require(passes: dict, names, path: Path) -> None:
    missing = [n for n in names if n not in passes]
    if missing:
        raise SequenceError(
            path,
            "missing Cycles pass(es): "
            + "; ".join(f"{n} ({SETTINGS[n]})" for n in missing)
            + ". `jnds_deploy.blender.configure(scene)` enables them all",
        )


def components(passes: dict) -> dict[str, np.ndarray]:
    """albedo, diffuse (demodulated), specular of a frame's passes (the paper's split)."""

    def rgb(n):
        return passes[n][..., :3]

    specular = (
        rgb("Glossy Color") * (rgb("Glossy Direct") + rgb("Glossy Indirect"))
        + rgb("Transmission Color") * (rgb("Transmission Direct") + rgb("Transmission Indirect"))
        + rgb("Volume Direct")
        + rgb("Volume Indirect")
        + rgb("Emission")
        + rgb("Environment")
    )
    return {
        "albedo": np.clip(rgb("Diffuse Color"), 0.0, 1.0),
        "diffuse": rgb("Diffuse Direct") + rgb("Diffuse Indirect"),
        "specular": specular,
    }


def input_layers(passes: dict, path: Path, toward_camera=None) -> dict[str, np.ndarray]:
    """The format's input layers (HWC float32) from one frame's passes; ``toward_camera``:
    the frame's direction back to the camera (world space), the normal of the pixels whose
    camera ray scattered in a volume (module docstring)."""
    _require(passes, INPUT_PASSES, path)
    layers = components(passes)
    vec = passes["Vector"]
    motion = np.stack([vec[..., 0], -vec[..., 1]], -1)  # y up -> y down
    normal = passes["Normal"][..., :3]
    no_surface = ~np.any(normal != 0, axis=-1, keepdims=True)
    volume = np.zeros_like(no_surface)
    if VOLUME_MARK in passes:
        volume = no_surface & np.any(passes[VOLUME_MARK][..., :3] != 0, axis=-1, keepdims=True)
    if volume.any():
        if toward_camera is None:
            raise SequenceError(
                path,
                f"{int(volume.sum())} pixels scattered in a volume, and {SIDECAR} beside "
                "the frames has no 'toward_camera' to give them a normal; render with "
                "`jnds_deploy.blender.configure`, which writes it",
            )
        normal = np.where(volume, np.asarray(toward_camera, np.float32), normal)
    motion = np.where(no_surface, 0.0, motion).astype(np.float32)  # no surface, no motion: as Blender's
    motion = volume_motion(motion, volume[..., 0], ~no_surface[..., 0])
    depth = np.where(no_surface[..., 0], 0.0, passes["Depth"][..., 0])[..., None]
    roughness = np.clip(passes[ROUGHNESS_AOV][..., :1], 0.0, 1.0) ** 2
    roughness = np.where(no_surface, 1.0, roughness)
    out = {
        **layers,
        "normal": normal.astype(np.float32),
        "roughness": roughness.astype(np.float32),
        "motion": motion,
        "depth": depth.astype(np.float32),
    }
    if GUIDE_ALBEDO in passes:  # what a Cycles user gives OIDN (the baseline), not the model
        out["denoising_albedo"] = np.clip(passes[GUIDE_ALBEDO][..., :3], 0.0, 1.0).astype(np.float32)
    return out


VOLUME_MOTION_SIGMA = 1 / 32  # of the frame's width: the reach of volume_motion's average
VOLUME_MOTION_WEIGHT = 0.05  # less surface than this around a volume pixel: its motion stays 0


def volume_motion(motion: np.ndarray, volume: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """``motion`` (H, W, 2) with each ``volume`` pixel's replaced by the Gaussian-weighted mean
    of the ``surface`` pixels' around it (sigma: VOLUME_MOTION_SIGMA of the width), where
    they weigh at least VOLUME_MOTION_WEIGHT; 0 elsewhere (a frame all medium). Under a
    camera that turns, every pixel moves alike whatever lies along it; under one that
    translates this is the nearby surfaces' motion, not the medium's own, which has none.
    Chosen on `media` training sequences with the shipped model (docs/model-gap.md)."""
    if not volume.any() or not surface.any():
        return motion
    import cv2

    sigma = VOLUME_MOTION_SIGMA * motion.shape[1]
    weight = cv2.GaussianBlur(surface.astype(np.float32), (0, 0), sigma)
    out = motion.copy()
    fill = volume & (weight >= VOLUME_MOTION_WEIGHT)
    for c in range(motion.shape[2]):
        mean = cv2.GaussianBlur(np.where(surface, motion[..., c], 0).astype(np.float32), (0, 0), sigma)
        out[..., c][fill] = mean[fill] / weight[fill]
    return out


def unmarked_volume_pixels(passes: dict) -> int:
    """Pixels with no surface but light scattered in a volume, in a render without the
    Denoising Data passes: they import as background (exact radiance), which they are not."""
    if VOLUME_MARK in passes:
        return 0
    no_surface = ~np.any(passes["Normal"][..., :3] != 0, axis=-1)
    light = passes["Volume Direct"][..., :3].sum(-1) + passes["Volume Indirect"][..., :3].sum(-1)
    return int((no_surface & (light > 0)).sum())


def reference_layers(passes: dict, path: Path) -> dict[str, np.ndarray]:
    _require(passes, REFERENCE_PASSES, path)
    return {"color": passes["Combined"][..., :3], **components(passes)}


def find_frames(raw: Path) -> dict[int, Path]:
    """{frame number: file} of Blender's ``<prefix>NNNN.exr`` in ``raw`` (one prefix)."""
    if not raw.is_dir():
        raise SequenceError(raw, "no such directory of Blender frames")
    found: dict[str, dict[int, Path]] = {}
    for p in raw.iterdir():
        if not p.name.startswith(".") and (m := _FRAME.match(p.name)):
            found.setdefault(m.group(1), {})[int(m.group(2))] = p
    if not found:
        raise SequenceError(raw, "no <prefix>NNNN.exr frames")
    if len(found) > 1:
        raise SequenceError(
            raw, f"frames with several prefixes ({', '.join(repr(k) for k in found)}); one per directory"
        )
    frames = next(iter(found.values()))
    numbers = sorted(frames)
    gaps = sorted(set(range(numbers[0], numbers[-1] + 1)) - set(numbers))
    if gaps:
        raise SequenceError(raw, f"frames missing in {numbers[0]}..{numbers[-1]}: {gaps[:10]}")
    return {n: frames[n] for n in numbers}


def _sidecar(raw: Path, numbers: list[int]) -> tuple[dict[int, tuple[float, float]], set[int]]:
    """Per frame the jitter ``blender.configure`` keyed (0 without its ``jnds.json``), and
    the frames that are camera cuts (``blender.scenes`` records them)."""
    side = raw / SIDECAR
    data = json.loads(side.read_text()) if side.is_file() else {}
    jit = {int(k): tuple(v) for k, v in data.get("jitter", {}).items()}
    toward = {int(k): v for k, v in data.get("toward_camera", {}).items()}
    return {n: jit.get(n, (0.0, 0.0)) for n in numbers}, set(data.get("cuts", [])), toward


def import_cycles(raw: str | Path, out: str | Path, reference: str | Path | None = None, progress: bool = True):
    """Write the jnds-sequence/1 of Blender frames ``raw`` (and reference ``reference``) to
    ``out``; returns ``io.validate``'s report."""
    from tqdm import tqdm

    raw, out = Path(raw), Path(out)
    frames = find_frames(raw)
    numbers = list(frames)
    refs = find_frames(Path(reference)) if reference else None
    if refs is not None and list(refs) != numbers:
        raise SequenceError(
            Path(reference),
            f"reference frames {list(refs)[0]}..{list(refs)[-1]} do not match the inputs' {numbers[0]}..{numbers[-1]}",
        )
    jitters, cuts, toward = _sidecar(raw, numbers)
    first = read_passes(frames[numbers[0]])
    h, w = first["Combined"].shape[:2] if "Combined" in first else next(iter(first.values())).shape[:2]
    target = None
    if refs is not None:
        rh, rw = read_passes(refs[numbers[0]])["Combined"].shape[:2]
        target = (rw, rh)
    writer = SequenceWriter(out, (w, h), target)
    infos = []
    unmarked = 0
    for i, n in enumerate(tqdm(numbers, desc=f"import {raw.name}", unit="frame", disable=not progress)):
        passes = first if i == 0 else read_passes(frames[n])
        layers = input_layers(passes, frames[n], toward.get(n))
        unmarked += unmarked_volume_pixels(passes)
        cut = n in cuts
        if i == 0 or cut:  # Vector points at a frame that is not in the sequence (or another shot)
            layers["motion"][:] = 0.0
        writer.write_inputs(i, layers)
        if refs is not None:
            writer.write_reference(i, reference_layers(read_passes(refs[n]), refs[n]))
        infos.append(FrameInfo(i, jitters[n], cut))
    if unmarked:
        warnings.warn(
            f"{raw}: {unmarked} pixels (all frames) saw light scattered in a volume before any surface "
            f"and import as background, whose radiance the pipeline takes as exact: render with the "
            f"{VOLUME_MARK} pass (view layer > Passes > Data > Denoising Data; "
            "`jnds_deploy.blender.configure` turns it on)",
            stacklevel=2,
        )
    # the engine, where training's renderer balance reads it (training.data.SequenceArrays.renderer)
    writer.close(infos, {"renderer": {"engine": "cycles", "imported_from": str(raw)}})
    return validate(out)
