"""Pinhole cameras, camera paths and sub-pixel jitter, in plain numpy.

The renderer builds its own primary rays from these cameras, so the same math gives the
jittered G-buffer/radiance rays, the reference rays and the reprojection used for
motion vectors.

Conventions: world space is right-handed with +y up. Image coordinates are continuous
pixel units with (0, 0) at the top-left corner of the top-left pixel; pixel (x, y) has
its centre at (x + 0.5, y + 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

CAMERA_PATHS = ("static", "dolly", "orbit", "pan", "cut")


@dataclass(frozen=True)
class Camera:
    origin: tuple[float, float, float]
    target: tuple[float, float, float]
    fov_y: float = 45.0  # vertical field of view, degrees
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit (forward, right, up) vectors."""
        f = np.subtract(self.target, self.origin).astype(np.float64)
        f /= np.linalg.norm(f)
        r = np.cross(f, self.up)
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        return f, r, u

    def rays(self, px: np.ndarray, py: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Ray origins and unit directions (N, 3) through continuous image positions."""
        w, h = size
        f, r, u = self.basis()
        t = np.tan(np.radians(self.fov_y) / 2)
        sx = (2.0 * px / w - 1.0) * t * (w / h)
        sy = (1.0 - 2.0 * py / h) * t
        d = f[None] + sx[:, None] * r[None] + sy[:, None] * u[None]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        o = np.broadcast_to(np.asarray(self.origin, np.float64), d.shape)
        return o, d

    def project(
        self, points: np.ndarray, size: tuple[int, int], directions: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Continuous image positions (N, 2) of world points (N, 3), and a mask of points in
        front of the camera. Where ``directions`` is given (rows where points are NaN, e.g.
        background), the direction is projected as a point at infinity."""
        w, h = size
        f, r, u = self.basis()
        v = points - np.asarray(self.origin)[None]
        if directions is not None:
            inf = ~np.isfinite(points).all(axis=1)
            v = np.where(inf[:, None], directions, v)
        z = v @ f
        front = z > 1e-6
        zs = np.where(front, z, 1.0)
        t = np.tan(np.radians(self.fov_y) / 2)
        sx = (v @ r) / zs / (t * w / h)
        sy = (v @ u) / zs / t
        px = (sx + 1.0) * 0.5 * w
        py = (1.0 - sy) * 0.5 * h
        return np.stack([px, py], axis=1), front


def _rotate_y(v: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def camera_path(
    kind: str, frames: int, rng: np.random.Generator, extent: float = 4.0
) -> tuple[list[Camera], list[bool]]:
    """Per-frame cameras for a path kind, and per-frame camera-cut flags.

    The camera looks at the scene centre region from a random direction and height; the
    per-frame motion is drawn so that a sequence moves a few native pixels per frame.
    """
    if kind not in CAMERA_PATHS:
        raise ConfigError(f"unknown camera path {kind!r}, expected one of {', '.join(CAMERA_PATHS)}")

    def pose():
        az = rng.uniform(0, 2 * np.pi)
        dist = rng.uniform(1.3, 2.2) * extent
        height = rng.uniform(0.25, 0.9) * extent
        target = np.array(
            [rng.uniform(-0.3, 0.3) * extent, rng.uniform(0.0, 0.25) * extent, rng.uniform(-0.3, 0.3) * extent]
        )
        origin = target + np.array([np.sin(az) * dist, height, np.cos(az) * dist])
        return origin, target, float(rng.uniform(35, 55))

    def segment(kind, n):
        origin, target, fov = pose()
        cams = []
        if kind == "static":
            cams = [Camera(tuple(origin), tuple(target), fov)] * n
        elif kind == "dolly":
            step = rng.uniform(0.01, 0.025) * rng.choice([-1, 1])
            for i in range(n):
                o = target + (origin - target) * (1.0 - step * i)
                cams.append(Camera(tuple(o), tuple(target), fov))
        elif kind == "orbit":
            step = np.radians(rng.uniform(0.6, 1.5)) * rng.choice([-1, 1])
            for i in range(n):
                o = target + _rotate_y(origin - target, step * i)
                cams.append(Camera(tuple(o), tuple(target), fov))
        elif kind == "pan":
            step = np.radians(rng.uniform(0.4, 1.0)) * rng.choice([-1, 1])
            for i in range(n):
                t = origin + _rotate_y(target - origin, step * i)
                cams.append(Camera(tuple(origin), tuple(t), fov))
        return cams

    if kind == "cut":
        first = max(1, frames // 2)
        a = segment(rng.choice(["dolly", "orbit", "pan"]), first)
        b = segment(rng.choice(["dolly", "orbit", "pan", "static"]), frames - first)
        cuts = [False] * frames
        if frames > first:
            cuts[first] = True
        return a + b, cuts
    return segment(kind, frames), [False] * frames
