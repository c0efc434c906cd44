"""A path tracer on Mitsuba 3 that splits radiance at the first bounce.

Radiance reaching the camera is split by the lobe of the first vertex: light that
leaves the first surface through its diffuse lobe is *diffuse*, light through its
glossy or delta lobes is *specular*; emission and background seen directly are
specular. Next-event estimation at the first vertex evaluates each lobe alone
(``BSDFContext.type_mask``) with MIS weights from the full BSDF, so diffuse + specular
is an unbiased estimate of the total. Later vertices are an ordinary path tracer with
NEE and MIS.

The same code runs on Mitsuba's ``llvm_ad_rgb`` variant (all samples at once, vectorized)
and on ``scalar_rgb`` (one sample at a time, slow) when no usable LLVM is installed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RenderError

LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/llvm-19/lib/libLLVM-19.so",
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
)


def load_mitsuba(variant: str | None = None):
    """Import Mitsuba with ``llvm_ad_rgb`` when LLVM 19 is installed, else ``scalar_rgb``.

    Mitsuba imports its LLVM variant even when the system LLVM (14/15) would crash it at
    the first render, so the variant is chosen by whether LLVM 19 is on disk.
    """
    if variant is None:
        llvm = os.environ.get("DRJIT_LIBLLVM_PATH") or next((p for p in LLVM_CANDIDATES if Path(p).exists()), None)
        if llvm:
            os.environ["DRJIT_LIBLLVM_PATH"] = llvm
        variant = "llvm_ad_rgb" if llvm else "scalar_rgb"
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:
        raise RenderError("mitsuba is not installed: pip install 'jnds-deploy[render]'") from exc
    mi.set_variant(variant)
    return mi, dr


@dataclass
class Samples:
    """Per-sample results, numpy (N, C) float32: radiance split at the first bounce
    (not demodulated) and the first vertex's G-buffer."""

    diffuse: np.ndarray
    specular: np.ndarray
    albedo: np.ndarray
    normal: np.ndarray
    roughness: np.ndarray
    depth: np.ndarray


def emitter_id(emitter) -> str:
    """An emitter's name in the scene dict: its shape's id for an area light, else its own."""
    shape = emitter.get_shape()
    return shape.id() if shape is not None else emitter.id()


def _mis(a, b, dr):
    a2 = a * a
    return dr.select(a > 0, a2 / dr.maximum(a2 + b * b, 1e-30), 0.0)


class SplitPathTracer:
    """Traces primary rays given as numpy origins/directions through a loaded scene."""

    def __init__(self, mi, dr, scene_dict: dict, materials: dict, max_depth: int = 5):
        self.mi, self.dr = mi, dr
        self.scene = mi.load_dict(scene_dict)
        self.max_depth = max_depth
        self.vectorized = not mi.variant().startswith("scalar")
        rough = {s.id(): m.roughness for s, m in ((s, materials.get(s.id())) for s in self.scene.shapes()) if m}
        self._rough_by_id = rough
        self.shape_names = [s.id() for s in self.scene.shapes()]  # the scene dict's keys
        if self.vectorized:
            ids = np.asarray(dr.reinterpret_array(mi.UInt32, self.scene.shapes_dr()))
            table = np.ones(int(ids.max()) + 1, np.float32)
            self._index_by_reg = np.full(int(ids.max()) + 1, -1, np.int64)
            for k, (reg_id, shape) in enumerate(zip(ids, self.scene.shapes())):
                table[reg_id] = rough.get(shape.id(), 1.0)
                self._index_by_reg[reg_id] = k
            self._rough_table = mi.Float(table)
        # the emitters in a fixed order: Mitsuba orders a loaded scene's emitters differently
        # from one load to the next, and its emitter sampling picks by that order, so the same
        # random numbers lit a pixel from another light in another process (docs/dataset.md)
        emitters = list(self.scene.emitters())
        keys = [emitter_id(e) for e in emitters]
        if len(set(keys)) != len(keys):
            raise RenderError(
                f"emitters without unique ids ({sorted(keys)}): their order, and so the render, "
                "would change from one load of the scene to the next"
            )
        order = sorted(range(len(emitters)), key=keys.__getitem__)
        self._emitter_list = [emitters[k] for k in order]
        if self.vectorized and emitters:
            self._emitters = dr.gather(mi.EmitterPtr, self.scene.emitters_dr(), mi.UInt32(order))

    # -- public ---------------------------------------------------------------------
    def trace(self, origins: np.ndarray, directions: np.ndarray, seed: int) -> Samples:
        """One path per row of ``origins``/``directions`` (N, 3), seeded deterministically."""
        mi, dr = self.mi, self.dr
        n = len(origins)
        if self.vectorized:
            o = mi.Point3f(*[origins[:, i].astype(np.float32) for i in range(3)])
            d = mi.Vector3f(*[directions[:, i].astype(np.float32) for i in range(3)])
            rng = mi.PCG32(size=n, initstate=mi.UInt64(seed & 0xFFFFFFFFFFFF), initseq=dr.arange(mi.UInt64, n))
            out = self._trace(o, d, rng)
            dr.eval(*out)
            cols = [np.asarray(v, np.float32) for v in out]
            cols = [c.T if c.ndim == 2 else c[:, None] for c in cols]
            return Samples(*cols)
        rows = []
        for k in range(n):
            rng = mi.PCG32(initstate=seed & 0xFFFFFFFFFFFF, initseq=k)
            out = self._trace(mi.Point3f(origins[k]), mi.Vector3f(directions[k]), rng)
            rows.append([np.atleast_1d(np.asarray(v, np.float32)) for v in out])
        return Samples(*[np.stack([r[j] for r in rows]) for j in range(6)])

    def intersect(self, origins: np.ndarray, directions: np.ndarray, shapes: bool = False):
        """Distance to the first hit along each ray, ``inf`` where it misses; with
        ``shapes``, also the index in ``shape_names`` of the shape hit (-1: none)."""
        mi, dr = self.mi, self.dr
        if self.vectorized:
            o = mi.Point3f(*[origins[:, i].astype(np.float32) for i in range(3)])
            d = mi.Vector3f(*[directions[:, i].astype(np.float32) for i in range(3)])
            si = self.scene.ray_intersect(mi.Ray3f(o, d))
            t = np.asarray(dr.select(si.is_valid(), si.t, dr.inf), np.float64)
            if not shapes:
                return t
            reg = np.asarray(dr.reinterpret_array(mi.UInt32, si.shape))
            return t, np.where(np.isfinite(t), self._index_by_reg[np.minimum(reg, len(self._index_by_reg) - 1)], -1)
        hits = [self.scene.ray_intersect(mi.Ray3f(mi.Point3f(o), mi.Vector3f(d))) for o, d in zip(origins, directions)]
        t = np.array([float(si.t) if si.is_valid() else np.inf for si in hits])
        if not shapes:
            return t
        return t, np.array([self.shape_names.index(si.shape.id()) if si.is_valid() else -1 for si in hits])

    # -- internals ------------------------------------------------------------------
    def _roughness(self, si, valid):
        if self.vectorized:
            idx = self.dr.reinterpret_array(self.mi.UInt32, si.shape)
            return self.dr.gather(self.mi.Float, self._rough_table, idx, valid)
        return self._rough_by_id.get(si.shape.id(), 1.0) if valid else 0.0

    def _emitted(self, si, active):
        """Radiance emitted towards the ray by the shape hit, or the environment on a miss."""
        mi = self.mi
        em = si.emitter(self.scene, active)
        if not self.vectorized:
            return em.eval(si, active) if (em is not None and active) else mi.Color3f(0.0)
        return em.eval(si, active)

    def _sample_emitter_direction(self, si, sample, active):
        """``Scene.sample_emitter_direction`` with the visibility test: an emitter picked
        uniformly by ``sample.x`` from ``_emitter_list`` (a fixed order, not the scene's), the
        rest of ``sample.x`` reused for the point on it; (DirectionSample3f, emitted radiance
        over the pdf, 0 where occluded)."""
        mi, dr = self.mi, self.dr
        n = len(self._emitter_list)
        if n == 0:
            return dr.zeros(mi.DirectionSample3f), mi.Color3f(0.0)
        scaled = sample.x * n
        if self.vectorized:
            index = dr.minimum(mi.UInt32(scaled), n - 1)
            emitter = dr.gather(mi.EmitterPtr, self._emitters, index, active)
        else:
            index = min(int(scaled), n - 1)
            emitter = self._emitter_list[index]
        ds, spec = emitter.sample_direction(si, mi.Point2f(scaled - index, sample.y), active)
        ds.pdf *= 1.0 / n
        active = active & (ds.pdf != 0.0)
        occluded = self.scene.ray_test(si.spawn_ray_to(ds.p), active)
        ds.pdf = dr.select(occluded, 0.0, ds.pdf)
        return ds, dr.select(active & ~occluded, spec * n, 0.0)

    def _nee(self, si, bsdf, rng, active, masks):
        """Next-event estimate per BSDF lobe mask, MIS-weighted against BSDF sampling."""
        mi, dr = self.mi, self.dr
        active = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds, em_w = self._sample_emitter_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        active = active & (ds.pdf != 0.0)
        wo = si.to_local(ds.d)
        pdf_b = bsdf.pdf(mi.BSDFContext(), si, wo, active)
        w = dr.select(ds.delta, 1.0, _mis(ds.pdf, pdf_b, dr))
        out = []
        for m in masks:
            ctx = mi.BSDFContext()
            if m is not None:
                ctx.type_mask = m
            out.append(dr.select(active, em_w * bsdf.eval(ctx, si, wo, active) * w, 0.0))
        return out

    def _trace(self, o, d, rng):
        mi, dr = self.mi, self.dr
        F = mi.BSDFFlags
        ray = mi.Ray3f(o, d)
        si = self.scene.ray_intersect(ray)
        valid = si.is_valid()
        specular = mi.Color3f(self._emitted(si, True))
        diffuse = mi.Color3f(0.0)
        if not self.vectorized and not valid:  # scalar miss: background only
            zero = mi.Color3f(0.0)
            return diffuse, specular, zero, zero, 0.0, 0.0

        bsdf = si.bsdf(ray)
        flags = bsdf.flags()
        has_diffuse = valid & mi.has_flag(flags, F.Diffuse)
        albedo = dr.select(has_diffuse, dr.clip(bsdf.eval_diffuse_reflectance(si, valid), 0.0, 1.0), 0.0)
        normal = dr.select(valid, si.sh_frame.n, 0.0)
        depth = dr.select(valid, si.t, 0.0)
        roughness = self._roughness(si, valid)

        nee_d, nee_s = self._nee(si, bsdf, rng, valid, (F.Diffuse, F.Glossy | F.Delta))
        diffuse += nee_d
        specular += nee_s

        active = mi.Bool(valid)
        bs, weight = bsdf.sample(
            mi.BSDFContext(), si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), active
        )
        first_diffuse = mi.has_flag(bs.sampled_type, F.Diffuse)
        beta = mi.Color3f(weight)
        tail = mi.Color3f(0.0)
        for bounce in range(1, self.max_depth):
            active &= (beta.x > 0) | (beta.y > 0) | (beta.z > 0)
            if not self.vectorized and not active:
                break  # scalar: no masked lanes, so stop instead of calling through null pointers
            prev_si, prev_pdf = si, bs.pdf
            prev_delta = mi.has_flag(bs.sampled_type, F.Delta)
            ray = prev_si.spawn_ray(prev_si.to_world(bs.wo))
            si = self.scene.ray_intersect(ray, active)
            ds = mi.DirectionSample3f(self.scene, si, prev_si)
            if self.vectorized:
                em_pdf = self.scene.pdf_emitter_direction(prev_si, ds, active & ~prev_delta)
            else:
                hit_emitter = si.emitter(self.scene) is not None
                em_pdf = self.scene.pdf_emitter_direction(prev_si, ds) if hit_emitter and not prev_delta else 0.0
            w = dr.select(prev_delta, 1.0, _mis(prev_pdf, em_pdf, dr))
            tail += dr.select(active, beta * w * self._emitted(si, active), 0.0)
            active &= si.is_valid()
            if bounce == self.max_depth - 1 or (not self.vectorized and not active):
                break
            bsdf = si.bsdf(ray)
            (nee,) = self._nee(si, bsdf, rng, active, (None,))
            tail += beta * nee
            bs, weight = bsdf.sample(
                mi.BSDFContext(), si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), active
            )
            beta = dr.select(active, beta * weight, 0.0)
        diffuse += dr.select(first_diffuse, tail, 0.0)
        specular += dr.select(first_diffuse, 0.0, tail)
        return diffuse, specular, albedo, normal, roughness, depth
