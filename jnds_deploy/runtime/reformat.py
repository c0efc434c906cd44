"""Data reformatting between the renderer's layout and the network's: HWC layers (as
``jnds_deploy.io`` reads them) into one CHW array, and CHW back to HWC.

numpy's ``concatenate(...).transpose(2, 0, 1)`` + copy is a strided gather on one
thread; these numba loops write each element once, rows in parallel. The pipeline's
``reformat`` stage at 1280x720 -> 2560x1440 went from 201.7 to about 50 ms with them
(`benchmarks/results/timing.md`).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def _hwc_into_chw(src, out, c0, h, w):
    for y in prange(out.shape[1]):
        sy = min(np.int64(y), h - 1)
        for i in range(out.shape[2]):
            sx = min(np.int64(i), w - 1)
            for c in range(src.shape[2]):
                out[c0 + c, y, i] = src[sy, sx, c]


@njit(parallel=True, cache=True)
def _chw_into_hwc(src, out):
    for y in prange(out.shape[0]):
        for i in range(out.shape[1]):
            for c in range(out.shape[2]):
                out[y, i, c] = src[c, y, i]


def to_chw(layers: list[np.ndarray], padded: tuple[int, int] | None = None) -> np.ndarray:
    """Stack HWC float32 layers of one size into a (sum C, H', W') float32 array;
    ``padded`` = (H', W') >= (H, W) replicates the last row and column."""
    h, w = layers[0].shape[:2]
    ph, pw = padded or (h, w)
    out = np.empty((sum(a.shape[2] for a in layers), ph, pw), np.float32)
    c0 = 0
    for a in layers:
        _hwc_into_chw(np.ascontiguousarray(a, np.float32), out, c0, h, w)
        c0 += a.shape[2]
    return out


def to_hwc(x: np.ndarray, h: int, w: int) -> np.ndarray:
    """The top-left (H, W) of a (C, H', W') array as a contiguous HWC float32 array."""
    out = np.empty((h, w, x.shape[0]), np.float32)
    _chw_into_hwc(np.ascontiguousarray(x, np.float32), out)
    return out
