"""Data reformatting between the renderer's layout and the network's, with the input
sanitizing folded into the same pass.

``to_chw`` stacks the HWC layers of one frame (as ``jnds_deploy.io`` reads them) into
one CHW array for the network, replacing NaN and clamping every value into its layer's
valid range (``LIMITS``) on the way, and counts the non-finite values it met per layer;
``to_hwc`` turns the CHW output back into HWC.

numpy's ``concatenate(...).transpose(2, 0, 1)`` + copy is a strided gather on one
thread; these numba loops write each element once, rows in parallel
(docs/design-notes.md).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..layout import LAYERS

# layer -> (low, high, renormalize), from the one table of input layers (layout.LAYERS)
LIMITS: dict[str, tuple[float, float, bool]] = {layer.name: (layer.lo, layer.hi, layer.unit_vector)
                                                for layer in LAYERS}


@njit(parallel=True, cache=True)
def _hwc_into_chw(src, out, c0, h, w, lo, hi, renormalize, nonfinite):
    lo32, hi32 = np.float32(lo), np.float32(hi)
    C = src.shape[2]
    for y in prange(out.shape[1]):
        sy = min(np.int64(y), h - 1)
        bad = 0
        for i in range(out.shape[2]):
            sx = min(np.int64(i), w - 1)
            norm = np.float32(0)
            for c in range(C):
                v = src[sy, sx, c]
                if not np.isfinite(v):
                    if y < h and i < w:
                        bad += 1
                    if v != v:
                        v = np.float32(0)
                v = min(max(v, lo32), hi32)
                out[c0 + c, y, i] = v
                norm += v * v
            if renormalize and norm > 0:
                inv = np.float32(1) / np.sqrt(norm)
                for c in range(C):
                    out[c0 + c, y, i] *= inv
        nonfinite[y] = bad


@njit(parallel=True, cache=True)
def _chw_into_hwc(src, out):
    for y in prange(out.shape[0]):
        for i in range(out.shape[1]):
            for c in range(out.shape[2]):
                out[y, i, c] = src[c, y, i]


def to_chw(layers: dict[str, np.ndarray], names, padded: tuple[int, int] | None = None,
           nonfinite: dict[str, int] | None = None) -> np.ndarray:
    """Stack the HWC float32 layers ``names`` (all one size) into a (sum C, H', W')
    float32 array, sanitized by ``LIMITS``; ``padded`` = (H', W') >= (H, W) replicates the
    last row and column. Non-finite counts of the layers that have any are added to ``nonfinite``."""
    first = layers[names[0]]
    h, w = first.shape[:2]
    ph, pw = padded or (h, w)
    out = np.empty((sum(layers[n].shape[2] for n in names), ph, pw), np.float32)
    rows = np.empty(ph, np.int64)
    c0 = 0
    for n in names:
        a = layers[n]
        lo, hi, renormalize = LIMITS[n]
        _hwc_into_chw(np.ascontiguousarray(a, np.float32), out, c0, h, w, lo, hi, renormalize, rows)
        bad = int(rows.sum())
        if bad and nonfinite is not None:
            nonfinite[n] = nonfinite.get(n, 0) + bad
        c0 += a.shape[2]
    return out


def to_hwc(x: np.ndarray, h: int, w: int) -> np.ndarray:
    """The top-left (H, W) of a (C, H', W') array as a contiguous HWC float32 array."""
    out = np.empty((h, w, x.shape[0]), np.float32)
    _chw_into_hwc(np.ascontiguousarray(x, np.float32), out)
    return out
