"""Procedural Mitsuba 3 scenes from a seed.

A scene is a ground plane and a set of objects of varied scale (spheres, boxes, thin
panels), each with one of three materials -- diffuse, rough plastic, rough metal --
over a range of roughness, textured with fine detail (checkers, value noise, stripes).
Lighting mixes an environment map, rectangular area lights and small bright sphere
lights.

``build_scene`` returns the Mitsuba scene dict and a per-shape material table
(shape id -> roughness, is_metal) that the integrator uses for the roughness AOV. In the
``moving`` kind, half the objects move on their own (``ObjectMotion``): the scene of
frame i has them where ``object_motion`` puts them, and the renderer's motion vectors
follow them.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ConfigError

SCENE_KINDS = ("procedural", "diffuse", "metal", "sky", "sunlit", "moving")
OBJECT_PREFIX = "obj"  # scene-dict keys of the objects (the ground, lights and sky are not objects)
MOVING_FRACTION = 0.5  # ``moving``: the share of objects that move on their own
EXTENT = 4.0  # objects are scattered over [-EXTENT, EXTENT]^2 on the ground


@dataclass(frozen=True)
class ObjectMotion:
    """Rigid motion of one object per frame: a translation ``velocity`` (world units a
    frame) and a turn about its vertical axis through its centre (``spin``, degrees a
    frame; spheres do not turn). Frame i is displaced by ``i - frames // 2`` steps, so a
    sequence is centred on the generated layout."""

    velocity: tuple[float, float, float]
    spin: float

    def offset(self, frame: int, frames: int) -> tuple[np.ndarray, float]:
        k = frame - frames // 2
        return np.asarray(self.velocity) * k, self.spin * k


def object_motion(seed: int, kind: str, names: list[str]) -> dict[str, ObjectMotion]:
    """The objects (``names``: all of the scene's, in order) of a ``moving`` scene that
    move, and how (none in other kinds). Drawn from a stream of its own, so the static
    layout of a seed is the same in every kind."""
    if kind != "moving":
        return {}
    rng = np.random.default_rng([seed, 7])
    out = {}
    for name in names:
        if rng.random() >= MOVING_FRACTION:
            continue
        heading, speed = rng.uniform(0, 2 * np.pi), rng.uniform(0.08, 0.35)
        lift = rng.uniform(-0.02, 0.04) if rng.random() < 0.3 else 0.0
        out[name] = ObjectMotion(
            (float(speed * np.cos(heading)), float(lift), float(speed * np.sin(heading))),
            float(rng.choice([-1, 1]) * rng.uniform(3, 15)),
        )
    return out


@dataclass(frozen=True)
class Material:
    kind: str  # "diffuse" | "plastic" | "metal"
    roughness: float  # 1 for diffuse; alpha of the microfacet lobe otherwise


# ---------------------------------------------------------------------------------------
# textures (HWC float32 in [0, 1], linear)


def _value_noise(rng: np.random.Generator, res: int, octaves: int = 5) -> np.ndarray:
    out = np.zeros((res, res), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = 4 * 2**o
        grid = rng.random((cells, cells)).astype(np.float32)
        out += amp * cv2.resize(grid, (res, res), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.55
    out /= total
    return np.clip((out - out.min()) / max(out.max() - out.min(), 1e-6), 0, 1)


def make_texture(rng: np.random.Generator, res: int = 256) -> tuple[np.ndarray, float]:
    """A random detail texture and its uv repeat count."""
    c0 = rng.uniform(0.05, 0.9, 3).astype(np.float32)
    c1 = rng.uniform(0.05, 0.9, 3).astype(np.float32)
    pattern = rng.choice(["checkers", "noise", "stripes"])
    y, x = np.mgrid[0:res, 0:res] / res
    if pattern == "checkers":
        n = int(rng.integers(2, 9))
        t = ((np.floor(x * n) + np.floor(y * n)) % 2).astype(np.float32)
    elif pattern == "noise":
        t = _value_noise(rng, res)
    else:
        n = int(rng.integers(3, 12))
        a = rng.uniform(0, np.pi)
        t = (0.5 + 0.5 * np.sin(2 * np.pi * n * (np.cos(a) * x + np.sin(a) * y)) > 0.5).astype(np.float32)
    img = c0[None, None] * (1 - t[..., None]) + c1[None, None] * t[..., None]
    return img.astype(np.float32), float(rng.uniform(1, 6))


def sky_map(rng: np.random.Generator, res: int = 64) -> np.ndarray:
    """Latitude-longitude sky: horizon-to-zenith gradient, a dimmer ground, a soft sun."""
    h, w = res, 2 * res
    theta = (np.arange(h) + 0.5) / h * np.pi  # 0 = zenith
    phi = (np.arange(w) + 0.5) / w * 2 * np.pi
    zen = rng.uniform([0.1, 0.2, 0.5], [0.4, 0.6, 1.2])
    hor = rng.uniform([0.6, 0.6, 0.6], [1.2, 1.1, 1.1])
    gnd = rng.uniform(0.05, 0.25, 3)
    up = np.cos(theta)[:, None, None]
    sky = np.where(up > 0, hor + (zen - hor) * np.maximum(up, 0) ** 0.5, gnd * np.ones_like(up))
    img = np.broadcast_to(sky, (h, w, 3)).copy()
    st, sp = rng.uniform(0.2, 1.2), rng.uniform(0, 2 * np.pi)
    d = np.arccos(
        np.clip(
            np.sin(theta)[:, None] * np.sin(st) * np.cos(phi[None] - sp) + np.cos(theta)[:, None] * np.cos(st), -1, 1
        )
    )
    img += rng.uniform(20, 80) * np.exp(-((d / 0.04) ** 2))[..., None]
    return img.astype(np.float32)


# ---------------------------------------------------------------------------------------
# scenes


def _bsdf(mi, rng: np.random.Generator, kinds: tuple[str, ...]) -> tuple[dict, Material]:
    kind = str(rng.choice(kinds))
    if kind == "metal":
        alpha = float(rng.uniform(0.03, 0.5))
        tint = rng.uniform(0.5, 1.0, 3).tolist()
        return (
            {
                "type": "roughconductor",
                "material": str(rng.choice(["Al", "Au", "Cu", "Ag", "Cr"])),
                "alpha": alpha,
                "specular_reflectance": {"type": "rgb", "value": tint},
            },
            Material("metal", alpha),
        )
    tex, rep = make_texture(rng)
    refl = (
        {"type": "bitmap", "bitmap": mi.Bitmap(tex), "raw": True, "to_uv": mi.ScalarTransform4f().scale([rep, rep, 1])}
        if rng.random() < 0.75
        else {"type": "rgb", "value": rng.uniform(0.05, 0.9, 3).tolist()}
    )
    if kind == "plastic":
        alpha = float(rng.uniform(0.03, 0.5))
        return ({"type": "roughplastic", "alpha": alpha, "diffuse_reflectance": refl}, Material("plastic", alpha))
    return {"type": "diffuse", "reflectance": refl}, Material("diffuse", 1.0)


def build_scene(
    mi, seed: int, kind: str = "procedural", frame: int = 0, frames: int = 1
) -> tuple[dict, dict[str, Material]]:
    """Mitsuba scene dict and the material of each shape id, for a seed and a scene kind
    (at ``frame`` of ``frames``, for the objects that move: ``object_motion``).

    ``diffuse``: only diffuse materials (no glossy signal); ``metal``: only metals (no
    diffuse signal); ``sky``: a few objects floating in front of the sky, no ground
    (most pixels see only the environment); ``sunlit``: diffuse materials lit by a sun (a
    directional light) with a black background, so that nothing seen directly emits and
    the specular layer is exactly zero; ``procedural``: everything; ``moving``: the
    ``procedural`` scene of the seed with half its objects moving.
    """
    if kind not in SCENE_KINDS:
        raise ConfigError(f"unknown scene {kind!r}, expected one of {', '.join(SCENE_KINDS)}")
    rng = np.random.default_rng(seed)
    T = mi.ScalarTransform4f
    kinds = {
        "procedural": ("diffuse", "plastic", "metal"),
        "diffuse": ("diffuse",),
        "metal": ("metal",),
        "sky": ("diffuse", "plastic", "metal"),
        "sunlit": ("diffuse",),
        "moving": ("diffuse", "plastic", "metal"),
    }[kind]
    layout = "procedural" if kind == "moving" else kind
    scene: dict = {"type": "scene"}
    materials: dict[str, Material] = {}

    if kind != "sky":
        bsdf, mat = _bsdf(mi, rng, ("diffuse", "plastic") if layout == "procedural" else kinds)
        scene["ground"] = {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(3 * EXTENT), "bsdf": bsdf}
        materials["ground"] = mat

    n_objects = int(rng.integers(3, 6) if kind == "sky" else rng.integers(5, 12))
    motion = object_motion(seed, kind, [f"{OBJECT_PREFIX}{i}" for i in range(n_objects)])
    for i in range(n_objects):
        shape = str(rng.choice(["sphere", "cube", "panel"]))
        scale = float(np.exp(rng.uniform(np.log(0.15), np.log(1.6))))
        x, z = rng.uniform(-EXTENT, EXTENT, 2)
        yaw = float(rng.uniform(0, 360))
        bsdf, mat = _bsdf(mi, rng, kinds)
        name = f"{OBJECT_PREFIX}{i}"
        if name in motion:
            shift, turn = motion[name].offset(frame, frames)
            x, z, yaw = x + shift[0], z + shift[2], yaw + (0.0 if shape == "sphere" else turn)
            scale_y = scale + shift[1]  # the lift: centre height above the ground
        else:
            scale_y = scale
        if shape == "sphere":
            scene[name] = {"type": "sphere", "center": [x, scale_y, z], "radius": scale, "bsdf": bsdf}
        elif shape == "cube":
            scene[name] = {
                "type": "cube",
                "bsdf": bsdf,
                "to_world": T().translate([x, scale_y, z]).rotate([0, 1, 0], yaw).scale(scale),
            }
        else:
            scene[name] = {
                "type": "rectangle",
                "bsdf": bsdf,
                "to_world": T().translate([x, scale_y + scale, z]).rotate([0, 1, 0], yaw).scale([scale, 2 * scale, 1]),
            }
        materials[name] = mat

    if kind == "sunlit":
        elevation, azimuth = rng.uniform(0.35, 1.2), rng.uniform(0, 2 * np.pi)
        direction = [-np.cos(elevation) * np.sin(azimuth), -np.sin(elevation), -np.cos(elevation) * np.cos(azimuth)]
        scene["sun"] = {
            "type": "directional",
            "direction": direction,
            "irradiance": {"type": "rgb", "value": (rng.uniform(2.0, 5.0) * rng.uniform(0.85, 1.0, 3)).tolist()},
        }
        return scene, materials
    if kind in ("metal", "sky") or rng.random() < 0.8:
        scene["sky"] = {"type": "envmap", "bitmap": mi.Bitmap(sky_map(rng)), "scale": float(rng.uniform(0.3, 1.5))}
    for i in range(0 if kind == "sky" else int(rng.integers(0 if "sky" in scene else 1, 3))):
        size = float(rng.uniform(0.5, 2.0))
        pos = [rng.uniform(-EXTENT, EXTENT), rng.uniform(4, 7), rng.uniform(-EXTENT, EXTENT)]
        power = rng.uniform(10, 40) * rng.uniform(0.8, 1.0, 3)
        scene[f"area{i}"] = {
            "type": "rectangle",
            "to_world": T().look_at(origin=pos, target=[pos[0] * 0.3, 0, pos[2] * 0.3], up=[0, 1, 0]).scale(size),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": power.tolist()}},
        }
    for i in range(int(rng.integers(0, 4))):
        r = float(rng.uniform(0.03, 0.12))
        pos = [rng.uniform(-EXTENT, EXTENT), rng.uniform(0.5, 3.0), rng.uniform(-EXTENT, EXTENT)]
        scene[f"bulb{i}"] = {
            "type": "sphere",
            "center": pos,
            "radius": r,
            "emitter": {
                "type": "area",
                "radiance": {"type": "rgb", "value": (rng.uniform(0.5, 2.0, 3) / r**2).tolist()},
            },
        }
    return scene, materials
