"""The filter stage in numpy/opencv: the runtime's implementation of ``jnds_deploy.filter_spec``.

Same specification as the torch ops, a test holds them equal. Array contract: CHW
arrays (one frame, the layout ONNX Runtime returns without the batch axis), float32 or
float16 (``dtype`` of the inputs is kept); kernels (9, H, W) in row-major 3x3 order;
borders replicate the edge pixel.

Notes: the warp is a numba loop with exact coordinates (cv2.remap quantizes them to 1/32
pixel, and was slower: commit e833640); both it and torch.grid_sample use the bicubic
kernel with a = -0.75 (``jnds_deploy.bicubic``). ``cv2.resize(INTER_LINEAR)`` has the pixel-centre convention of
``align_corners=False``.

float32 takes the fast path: the per-pixel kernel application and everything fused
around it (the lerp of the spatiotemporal filter and of the up levels, the ReLU, the 2x2
pooling) are single-pass loops compiled by numba and run over rows on all threads; the
same sums in the same order as the numpy code (bit-equal, a test holds it). numpy
makes ~36 passes over memory for one spatiotemporal filter where the fused loop makes
one (docs/architecture.md, "The filter stage"). numba has no float16 arithmetic on the
CPU, so float16 runs the numpy code, which rounds every operation to float16 as a GPU's half
arithmetic would (and is slow: numpy emulates half precision).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit, prange

from ..bicubic import cubic_weights
from ..layout import (
    BACKGROUND,
    DIFFUSE_FILL_MIN,
    DIFFUSE_FILL_TAPS,
    HDR_MAX,
    LUMINANCE,
    REJECT_ALBEDO,
    REJECT_COS,
    RING_MIN,
    ROOT_FLOOR,
    SCATTERED_CHANGES,
    SCATTERED_SHARE,
    channels,
)
from .head import Coded, decode_row

# channel indices of the stacked inputs (layout.CURRENT; the history shares its first 12):
# numba compiles them as constants
_DIFFUSE, _SPECULAR = channels("diffuse").start, channels("specular").start
_GEOMETRY = (channels("albedo").start, channels("normal").stop)  # albedo and normal
_ALBEDO = channels("albedo").start
_NX = channels("normal").start
_NY, _NZ = _NX + 1, _NX + 2


def tonemap(x: np.ndarray) -> np.ndarray:
    """Eq. 1: (log(clamp(x, 0, 65535) + 1))^(1/2.2)."""
    return np.power(np.log1p(np.clip(x, 0.0, HDR_MAX)), 1.0 / 2.2).astype(x.dtype, copy=False)


@njit(inline="always")
def _taps(src, k, c, ya, yb, yc, y, xa, xb, xc, x):
    """sum_k k[k, y, x] * src[c, row_k, col_k], rows (ya, yb, yc), cols (xa, xb, xc)."""
    a = src[c, ya, xa] * k[0, y, x]
    a = a + src[c, ya, xb] * k[1, y, x]
    a = a + src[c, ya, xc] * k[2, y, x]
    a = a + src[c, yb, xa] * k[3, y, x]
    a = a + src[c, yb, xb] * k[4, y, x]
    a = a + src[c, yb, xc] * k[5, y, x]
    a = a + src[c, yc, xa] * k[6, y, x]
    a = a + src[c, yc, xb] * k[7, y, x]
    a = a + src[c, yc, xc] * k[8, y, x]
    return a


# The row loops below filter a row's first and last pixels (whose clamped neighbours are
# the border) apart from its interior, where the neighbours are i - 1 and i + 1: with
# clamped indices in the loop LLVM kept it scalar on AVX2 (same sums, bit-equal;
# docs/architecture.md, "The filter stage").


@njit(inline="always")
def _apply_px(x, k, ky, kx, out, relu, c, ya, y, yc, ia, i, ic):
    v = _taps(x, k, c, ya, y, yc, ky, ia, i, ic, kx)
    out[c, y, i] = max(v, np.float32(0)) if relu else v


@njit(inline="always")
def _apply_row(x, k, ky, out, relu, c, ya, y, yc):
    """out[c, y, :] = kernel row k[:, ky, :] on rows (ya, y, yc) of x, columns clamped."""
    W = x.shape[2]
    _apply_px(x, k, ky, 0, out, relu, c, ya, y, yc, 0, 0, min(1, W - 1))
    if W > 1:
        _apply_px(x, k, ky, W - 1, out, relu, c, ya, y, yc, W - 2, W - 1, W - 1)
    for i in range(1, W - 1):
        _apply_px(x, k, ky, i, out, relu, c, ya, y, yc, i - 1, i, i + 1)


@njit(parallel=True, cache=True)
def _apply(x, k, out, relu):
    """out = kernel k on x (ReLU if asked)."""
    C, H, W = x.shape
    for y in prange(H):
        ya, yc = max(y - 1, 0), min(y + 1, H - 1)
        for c in range(C):
            _apply_row(x, k, y, out, relu, c, ya, y, yc)


@njit(inline="always")
def _lerp_px(a, ka, b, kb, t, ky, out, relu, plain, c, ya, y, yc, ia, i, ic):
    va = a[c, y, i] if plain else _taps(a, ka, c, ya, y, yc, ky, ia, i, ic, i)
    vb = _taps(b, kb, c, ya, y, yc, ky, ia, i, ic, i)
    v = va + t[0, ky, i] * (vb - va)
    out[c, y, i] = max(v, np.float32(0)) if relu else v


@njit(inline="always")
def _lerp_row(a, ka, b, kb, t, ky, out, relu, plain, y, ya, yc):
    """Row y of _lerp_taps, its kernels and blend weights at row ky of ka, kb, t."""
    C, _, W = b.shape
    for c in range(C):
        _lerp_px(a, ka, b, kb, t, ky, out, relu, plain, c, ya, y, yc, 0, 0, min(1, W - 1))
        if W > 1:
            _lerp_px(a, ka, b, kb, t, ky, out, relu, plain, c, ya, y, yc, W - 2, W - 1, W - 1)
        # one interior loop per case, so that neither carries the branch
        if plain:
            for i in range(1, W - 1):
                _lerp_px(a, ka, b, kb, t, ky, out, relu, True, c, ya, y, yc, i - 1, i, i + 1)
        else:
            for i in range(1, W - 1):
                _lerp_px(a, ka, b, kb, t, ky, out, relu, False, c, ya, y, yc, i - 1, i, i + 1)


@njit(parallel=True, cache=True)
def _lerp_taps(a, ka, b, kb, t, out, relu=True):
    """out = relu(A + t * (B - A)) (no ReLU if not ``relu``), A = a itself if ka is empty
    else the kernel ka on a, B = the kernel kb on b."""
    H = b.shape[1]
    plain = ka.shape[0] == 0
    for y in prange(H):
        _lerp_row(a, ka, b, kb, t, y, out, relu, plain, y, max(y - 1, 0), min(y + 1, H - 1))


@njit(parallel=True, cache=True)
def _lerp_coded(a, b, q, ca, cb, ct, kinds, scale, offset, table, out, relu):
    """_lerp_taps with its kernels (ka: head channels ca..ca+9, none if ca < 0; kb: cb..cb+9)
    and blend weights (channel ct) read from the u8 head's planes q (runtime.head): each row's are
    decoded into row buffers first (cache-resident; the same values as decoding them whole)."""
    H, W = b.shape[1], b.shape[2]
    plain = ca < 0
    for y in prange(H):
        ka = np.empty((0 if plain else 9, 1, W), np.float32)
        kb = np.empty((9, 1, W), np.float32)
        t = np.empty((1, 1, W), np.float32)
        if not plain:
            decode_row(q, y, ca, 9, kinds, scale, offset, table, ka, 0)
        decode_row(q, y, cb, 9, kinds, scale, offset, table, kb, 0)
        decode_row(q, y, ct, 1, kinds, scale, offset, table, t, 0)
        _lerp_row(a, ka, b, kb, t, 0, out, relu, plain, y, max(y - 1, 0), min(y + 1, H - 1))


def _lerp_head(a, ka, b, kb, t, relu=True) -> np.ndarray | None:
    """``_lerp_taps`` from the u8 head where kb and t (and ka, unless None) are ``Coded``
    parts of one head and the signals float32; None where they are not."""
    parts = [p for p in (ka, kb, t) if p is not None]
    if not (all(isinstance(p, Coded) for p in parts) and len({id(p.q) for p in parts}) == 1 and _fast(a, b)):
        return None
    h = kb.head
    out = np.empty_like(a)
    _lerp_coded(a, b, kb.q, -1 if ka is None else ka.c0, kb.c0, t.c0, h.kinds, h.scale, h.offset, h.table, out, relu)
    return out


def _decoded(*kernels):
    """Kernels as float arrays (``Coded`` head parts decoded)."""
    return [k.decode() if isinstance(k, Coded) else k for k in kernels]


@njit(parallel=True, cache=True)
def _restore_tiles(src, out, skip, tile):
    """out = src in the tiles set in ``skip`` (``empty_tiles``): they pass through."""
    C, H, W = out.shape
    for y in prange(H):
        row = skip[y // tile]
        if not row.any():
            continue
        for c in range(C):
            for tx in range(row.shape[0]):
                if row[tx]:
                    for i in range(tx * tile, min((tx + 1) * tile, W)):
                        out[c, y, i] = src[c, y, i]


def _pass_tiles(src: np.ndarray, out: np.ndarray, skip, tile: int) -> np.ndarray:
    """Empty tiles (``skip``, float32 only) take the source's values. The filter loops
    run over every pixel and the tiles are put back afterwards: loops that skipped the
    tiles themselves lost their vectorization and ran slower per pixel
    (docs/architecture.md, "The filter stage")."""
    if skip is not None:
        _restore_tiles(src, out, skip, tile)
    return out


@njit(parallel=True, cache=True)
def empty_tiles(current, history, tile, flat):
    """Tiles with nothing to filter: (ceil(H / tile), ceil(W / tile)) uint8, 1 where the
    tile and a 1-pixel border around it see no geometry (|albedo|, |normal| <= 1e-3: the
    filtered history of an empty pixel is zero up to rounding) in the current frame
    (13, H, W) and the warped history (12, H, W), the specular signal (what the background
    emits) varies by at most ``flat`` x its maximum and the diffuse signal stays below
    that: sky and empty background, which the filter stage passes through."""
    _, H, W = current.shape
    th, tw = (H + tile - 1) // tile, (W + tile - 1) // tile
    out = np.zeros((th, tw), np.uint8)
    for t in prange(th * tw):
        ty, tx = t // tw, t % tw
        y0, y1 = max(ty * tile - 1, 0), min((ty + 1) * tile + 1, H)
        x0, x1 = max(tx * tile - 1, 0), min((tx + 1) * tile + 1, W)
        empty = True
        lo, hi, dmax = np.inf, -np.inf, 0.0
        for y in range(y0, y1):
            for i in range(x0, x1):
                for c in range(_GEOMETRY[0], _GEOMETRY[1]):
                    if abs(current[c, y, i]) > 1e-3 or abs(history[c, y, i]) > 1e-3:
                        empty = False
                for s in (
                    current[_SPECULAR, y, i] + current[_SPECULAR + 1, y, i] + current[_SPECULAR + 2, y, i],
                    history[_SPECULAR, y, i] + history[_SPECULAR + 1, y, i] + history[_SPECULAR + 2, y, i],
                ):
                    lo, hi = min(lo, s), max(hi, s)
                for d in (
                    current[_DIFFUSE, y, i] + current[_DIFFUSE + 1, y, i] + current[_DIFFUSE + 2, y, i],
                    history[_DIFFUSE, y, i] + history[_DIFFUSE + 1, y, i] + history[_DIFFUSE + 2, y, i],
                ):
                    dmax = max(dmax, d)
                if not empty:
                    break
            if not empty:
                break
        if empty and hi - lo <= flat * hi and dmax <= flat * hi:
            out[ty, tx] = 1
    return out


@njit(inline="always")
def _pool(x, pooled):
    C, H, W = pooled.shape
    for y in prange(H):
        for c in range(C):
            for i in range(W):
                pooled[c, y, i] = (
                    x[c, 2 * y, 2 * i] + x[c, 2 * y, 2 * i + 1] + x[c, 2 * y + 1, 2 * i] + x[c, 2 * y + 1, 2 * i + 1]
                ) * np.float32(0.25)


@njit(parallel=True, cache=True)
def _pool_taps(x, k, out):
    """out = relu(kernel k on the 2x2 average pool of x)."""
    pooled = np.empty(out.shape, np.float32)
    _pool(x, pooled)
    _apply(pooled, k, out, True)


@njit(parallel=True, cache=True)
def _pool_coded(x, q, c0, kinds, scale, offset, table, out):
    """_pool_taps with its kernel read from planes c0..c0+9 of a u8 head's planes q
    (runtime.head), decoded row by row as _lerp_coded does."""
    C, H, W = out.shape
    pooled = np.empty(out.shape, np.float32)
    _pool(x, pooled)
    for y in prange(H):
        k = np.empty((9, 1, W), np.float32)
        decode_row(q, y, c0, 9, kinds, scale, offset, table, k, 0)
        ya, yc = max(y - 1, 0), min(y + 1, H - 1)
        for c in range(C):
            _apply_row(pooled, k, 0, out, True, c, ya, y, yc)


_NONE = np.empty((0, 1, 1), np.float32)


def _fast(*arrays) -> bool:
    return all(a.dtype == np.float32 for a in arrays)


def apply_kernel(x: np.ndarray, kernel: np.ndarray, relu: bool = False, skip=None, tile: int = 1) -> np.ndarray:
    """out[c, y, x] = sum_k kernel[k, y, x] * x[c, y + dy_k, x + dx_k] (then ReLU if asked);
    ``skip`` (float32 only): a tile mask (``empty_tiles``) where out = x."""
    if _fast(x, kernel):
        out = np.empty_like(x)
        _apply(x, kernel, out, relu)
        return _pass_tiles(x, out, skip, tile)
    _no_skip(skip)
    _, h, w = x.shape
    p = np.pad(x, ((0, 0), (1, 1), (1, 1)), mode="edge")
    out = p[:, :h, :w] * kernel[0]
    tmp = np.empty_like(out)
    for i in range(1, 9):
        dy, dx = divmod(i, 3)
        np.multiply(p[:, dy : dy + h, dx : dx + w], kernel[i], out=tmp)
        out += tmp
    return np.maximum(out, 0, out=out) if relu else out


@njit(inline="always", fastmath={"contract"})
def _bicubic(r0, r1, r2, r3, xs, wx, wy, c):
    """Channel c of the 4x4 taps: rows r0..r3 (W, C), columns xs, weights wx, wy."""
    a = wx[0] * r0[xs[0], c] + wx[1] * r0[xs[1], c] + wx[2] * r0[xs[2], c] + wx[3] * r0[xs[3], c]
    b = wx[0] * r1[xs[0], c] + wx[1] * r1[xs[1], c] + wx[2] * r1[xs[2], c] + wx[3] * r1[xs[3], c]
    d = wx[0] * r2[xs[0], c] + wx[1] * r2[xs[1], c] + wx[2] * r2[xs[2], c] + wx[3] * r2[xs[3], c]
    e = wx[0] * r3[xs[0], c] + wx[1] * r3[xs[1], c] + wx[2] * r3[xs[2], c] + wx[3] * r3[xs[3], c]
    return wy[0] * a + wy[1] * b + wy[2] * d + wy[3] * e


WARP_CHANNELS = 12  # channels per pass of the warp loop (the history's 12)


@njit(parallel=True, cache=True, fastmath={"contract"})
def _warp_rows(src, motion, lo, hi, out, current, cos, background, tol, rej):
    """out[c, y, x] = clamp(bicubic sample of src (H, W, 12, channels last) at (x + mx,
    y + my), lo[c], hi[c]), taps clamped to the frame (border replicate). The 12 channels of
    a pixel are 12 explicit sums over the same taps: LLVM's SLP vectorizer (which
    ``runtime.tune_numba`` turns on) makes them vector loads and FMAs over adjacent
    channels. Each row is written channels-last into a row buffer first and transposed
    from there (cache-resident). With ``current`` (13, H, W) rather than
    an empty array, each row's rejection marks (``_mark_row``) go to rej (H, W) in the same
    pass, for ``_replace_rejected``."""
    H, W, _ = src.shape
    reject = current.shape[1] == H
    for y in prange(H):
        row = np.empty((W, WARP_CHANNELS), np.float32)
        taps = np.empty((2, W), np.int64)
        weights = np.empty((8, W), np.float32)
        off = np.empty(W, np.bool_)
        # the row's tap positions and weights first, in a loop of their own: independent per
        # pixel, it vectorizes. Computed inside the sampling loop, they left the channel sums
        # scalar too, and the warp slower (docs/architecture.md, "The filter stage")
        for x in range(W):
            px, py = np.float32(x) + motion[0, y, x], np.float32(y) + motion[1, y, x]
            # jnds_deploy.filter_spec.offscreen
            off[x] = (
                (px < np.float32(-0.5))
                | (px > np.float32(W - 0.5))
                | (py < np.float32(-0.5))
                | (py > np.float32(H - 0.5))
            )
            # clamped before the integer conversion: beyond 2 px outside, every tap is the edge
            sx = min(max(px, np.float32(-3)), np.float32(W + 2))
            sy = min(max(py, np.float32(-3)), np.float32(H + 2))
            fx, fy = np.floor(sx), np.floor(sy)
            taps[0, x], taps[1, x] = np.int64(fx), np.int64(fy)
            w0, w1, w2, w3 = cubic_weights(sx - fx)
            weights[0, x], weights[1, x], weights[2, x], weights[3, x] = w0, w1, w2, w3
            w0, w1, w2, w3 = cubic_weights(sy - fy)
            weights[4, x], weights[5, x], weights[6, x], weights[7, x] = w0, w1, w2, w3
        for x in range(W):
            ix, iy = taps[0, x], taps[1, x]
            wx = (weights[0, x], weights[1, x], weights[2, x], weights[3, x])
            wy = (weights[4, x], weights[5, x], weights[6, x], weights[7, x])
            xs = (
                min(max(ix - 1, 0), W - 1),
                min(max(ix, 0), W - 1),
                min(max(ix + 1, 0), W - 1),
                min(max(ix + 2, 0), W - 1),
            )
            r0, r1 = src[min(max(iy - 1, 0), H - 1)], src[min(max(iy, 0), H - 1)]
            r2, r3 = src[min(max(iy + 1, 0), H - 1)], src[min(max(iy + 2, 0), H - 1)]
            v = (
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 0),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 1),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 2),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 3),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 4),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 5),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 6),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 7),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 8),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 9),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 10),
                _bicubic(r0, r1, r2, r3, xs, wx, wy, 11),
            )
            for c in range(WARP_CHANNELS):
                row[x, c] = v[c]
        for c in range(out.shape[0]):
            for x in range(W):
                out[c, y, x] = min(max(row[x, c], lo[c]), hi[c])
        if reject:
            # on the clamped row just written (cache-resident); a select in the loop above
            # kept LLVM from vectorizing it (docs/architecture.md, "The filter stage")
            _mark_row(current, out, y, cos, background, tol, off, rej)


@njit(inline="always")
def _sanitized(v, flush):
    """v with NaN and -Inf as 0, +Inf as HDR_MAX (``history.replace_nonfinite``'s values),
    and magnitudes below ``flush`` as 0: selects, no branch (the loop vectorizes)."""
    zero = np.float32(0)
    v = zero if v != v or v == -np.inf else v
    v = np.float32(HDR_MAX) if v == np.inf else v
    return v if abs(v) >= flush else zero


@njit(parallel=True, cache=True)
def _interleave(a, b, d, e, out, flush, nonfinite):
    """out[y, x, :] = a[:, y, x], b[:, y, x], d[:, y, x], e[:, y, x] (one pass over out),
    sanitized (``_sanitized``); nonfinite[y]: how many of row y's values were not finite."""
    ca, cb, cd, ce = a.shape[0], b.shape[0], d.shape[0], e.shape[0]
    H, W, _ = out.shape
    for y in prange(H):
        n = 0
        if ca == 3 and cb == 3 and cd == 3 and ce == 3:
            # the history's four layers: with the channel count a constant, the 12 values of
            # a pixel are one unrolled run of loads and stores, faster than the loop below
            # (measured at commit 22e394c)
            o = out[y]
            for x in range(W):
                for c in range(3):
                    v = a[c, y, x]
                    n += np.int64(not np.isfinite(v))
                    o[x, c] = _sanitized(v, flush)
                    v = b[c, y, x]
                    n += np.int64(not np.isfinite(v))
                    o[x, 3 + c] = _sanitized(v, flush)
                    v = d[c, y, x]
                    n += np.int64(not np.isfinite(v))
                    o[x, 6 + c] = _sanitized(v, flush)
                    v = e[c, y, x]
                    n += np.int64(not np.isfinite(v))
                    o[x, 9 + c] = _sanitized(v, flush)
            nonfinite[y] = n
            continue
        for x in range(W):
            for c in range(ca):
                n += np.int64(not np.isfinite(a[c, y, x]))
                out[y, x, c] = _sanitized(a[c, y, x], flush)
            for c in range(cb):
                n += np.int64(not np.isfinite(b[c, y, x]))
                out[y, x, ca + c] = _sanitized(b[c, y, x], flush)
            for c in range(cd):
                n += np.int64(not np.isfinite(d[c, y, x]))
                out[y, x, ca + cb + c] = _sanitized(d[c, y, x], flush)
            for c in range(ce):
                n += np.int64(not np.isfinite(e[c, y, x]))
                out[y, x, ca + cb + cd + c] = _sanitized(e[c, y, x], flush)
        nonfinite[y] = n


def channels_last(*arrays: np.ndarray, flush: float = 0.0, counted: bool = False):
    """(H, W, sum C_i) float32 from up to 4 CHW arrays of one size, in one pass: the warp's
    input layout (the pipeline keeps its history so). Values of magnitude below ``flush``
    become 0 (the history flushes what would decay into denormals, see HISTORY_FLUSH);
    NaN and -Inf 0, +Inf HDR_MAX. With ``counted``: (that array, how many values were not
    finite)."""
    if not 1 <= len(arrays) <= 4:
        raise ValueError(f"channels_last takes 1 to 4 arrays, got {len(arrays)}")
    arrays = [np.ascontiguousarray(a, np.float32) for a in arrays]
    _, h, w = arrays[0].shape
    out = np.empty((h, w, sum(a.shape[0] for a in arrays)), np.float32)
    nonfinite = np.empty(h, np.int64)
    _interleave(*arrays, *[arrays[0][:0]] * (4 - len(arrays)), out, np.float32(flush), nonfinite)
    return (out, int(nonfinite.sum())) if counted else out


@njit(parallel=True, cache=True)
def tile_sums(x, c0, tile):
    """Sums of x[c0] + x[c0 + 1] + x[c0 + 2] (float64) over tiles of tile x tile pixels:
    (ceil(H / tile), ceil(W / tile)), the last row and column of tiles partial."""
    _, H, W = x.shape
    th, tw = (H + tile - 1) // tile, (W + tile - 1) // tile
    out = np.zeros((th, tw))
    for ty in prange(th):
        # each column summed down the tile row first: sums independent along the row, which
        # vectorize. One running sum per tile was a chain of dependent float64 adds, and
        # slower (measured at commit c419e9e)
        col = np.zeros(W)
        for y in range(ty * tile, min((ty + 1) * tile, H)):
            a, b, d = x[c0, y], x[c0 + 1, y], x[c0 + 2, y]
            for i in range(W):
                col[i] += np.float64(a[i]) + np.float64(b[i]) + np.float64(d[i])
        for tx in range(tw):
            s = 0.0
            for i in range(tx * tile, min((tx + 1) * tile, W)):
                s += col[i]
            out[ty, tx] = s
    return out


def warp_channels_last(x: np.ndarray, motion: np.ndarray, lo=None, hi=None, current=None):
    """Bicubic resampling of the previous frame ``x`` (H, W, 12, channels last) along motion
    (2, H, W): out(x, y) = x_prev(x + mx, y + my), pixel centres at integers, taps beyond
    the border replicate it (``jnds_deploy.filter_spec.warp``, exact coordinates: no 1/32-pixel
    quantization as in cv2.remap). Returns (12, H, W) float32, channel c clamped to
    [lo[c], hi[c]] if given. Faster than one cv2.remap per channel (docs/architecture.md, "The filter stage").

    With ``current`` (the frame's (13, H, W) inputs), the history rejection
    (``reject_disoccluded`` with this motion's ``offscreen``) runs in the same pass and the
    result is (warped, pixels rejected)."""
    h, w, c = x.shape
    if c != WARP_CHANNELS:
        raise ValueError(f"warp_channels_last takes {WARP_CHANNELS} channels, got {c}")
    lo = np.full(c, -np.inf, np.float32) if lo is None else np.asarray(lo, np.float32)
    hi = np.full(c, np.inf, np.float32) if hi is None else np.asarray(hi, np.float32)
    out = np.empty((c, h, w), np.float32)
    cur = np.zeros((13, 0, 0), np.float32) if current is None else np.ascontiguousarray(current, np.float32)
    rej = np.empty((h, w) if current is not None else (0, 0), np.uint8)
    _warp_rows(
        np.ascontiguousarray(x, np.float32),
        np.ascontiguousarray(motion, np.float32),
        lo,
        hi,
        out,
        cur,
        np.float32(REJECT_COS),
        np.float32(BACKGROUND),
        np.float32(REJECT_ALBEDO),
        rej,
    )
    if current is None:
        return out
    counts = np.zeros(h, np.int64)
    _replace_rejected(cur, out, rej, RING_MIN, counts)
    return out, int(counts.sum())


@njit(inline="always")
def _mark_row(current, warped, y, cos, background, tol, off, rej):
    """Row y of ``jnds_deploy.filter_spec.disoccluded`` or off[x] (``offscreen``) into rej[y],
    from current (13, H, W) and the warped (clamped) history (12, H, W): 0 kept, 1 rejected
    where the pixel sees background, 2 rejected where it sees a surface (``_replace_rejected``
    rings those). The first loop, branch-free, settles every pixel whose own normal and
    albedo pass the tests; only the others look at their neighbours."""
    _, h, w = current.shape
    cx, cy, cz = current[_NX, y], current[_NY, y], current[_NZ, y]
    hx, hy, hz = warped[_NX, y], warped[_NY, y], warped[_NZ, y]
    ca, ha = current[_ALBEDO : _ALBEDO + 3, y], warped[_ALBEDO : _ALBEDO + 3, y]
    for x in range(w):
        limit = cos * np.sqrt(hx[x] * hx[x] + hy[x] * hy[x] + hz[x] * hz[x])
        background_now = abs(cx[x]) + abs(cy[x]) + abs(cz[x]) < background
        surface_before = abs(hx[x]) + abs(hy[x]) + abs(hz[x]) >= background
        far = cx[x] * hx[x] + cy[x] * hy[x] + cz[x] * hz[x] < limit
        # inside [own - tol, own + tol] is inside [min - tol, max + tol] of the neighbourhood
        # (the same float32 operations as the full test: no pixel settled differently)
        near = (
            (ha[0, x] >= ca[0, x] - tol)
            & (ha[0, x] <= ca[0, x] + tol)
            & (ha[1, x] >= ca[1, x] - tol)
            & (ha[1, x] <= ca[1, x] + tol)
            & (ha[2, x] >= ca[2, x] - tol)
            & (ha[2, x] <= ca[2, x] + tol)
        )
        bad = background_now | (surface_before & far) | (not near) | off[x]
        rej[y, x] = np.uint8(bad) * (np.uint8(2) - np.uint8(background_now))
    for x in range(w):
        if rej[y, x] == 2 and not off[x]:
            # over the 3x3 neighbourhood (clamped: the replicated border adds no new value):
            # a close enough normal, and the albedo range
            limit = cos * np.sqrt(hx[x] * hx[x] + hy[x] * hy[x] + hz[x] * hz[x])
            normal_ok = not (abs(hx[x]) + abs(hy[x]) + abs(hz[x]) >= background)
            lo0 = hi0 = ca[0, x]
            lo1 = hi1 = ca[1, x]
            lo2 = hi2 = ca[2, x]
            for yy in range(max(y - 1, 0), min(y + 2, h)):
                for xx in range(max(x - 1, 0), min(x + 2, w)):
                    if (
                        current[_NX, yy, xx] * hx[x] + current[_NY, yy, xx] * hy[x] + current[_NZ, yy, xx] * hz[x]
                        >= limit
                    ):
                        normal_ok = True
                    a0, a1, a2 = current[_ALBEDO, yy, xx], current[_ALBEDO + 1, yy, xx], current[_ALBEDO + 2, yy, xx]
                    lo0, hi0 = min(lo0, a0), max(hi0, a0)
                    lo1, hi1 = min(lo1, a1), max(hi1, a1)
                    lo2, hi2 = min(lo2, a2), max(hi2, a2)
            inside = (
                ha[0, x] >= lo0 - tol
                and ha[0, x] <= hi0 + tol
                and ha[1, x] >= lo1 - tol
                and ha[1, x] <= hi1 + tol
                and ha[2, x] >= lo2 - tol
                and ha[2, x] <= hi2 + tol
            )
            if normal_ok and inside:
                rej[y, x] = 0


@njit(parallel=True, cache=True)
def _replace_rejected(current, warped, rej, ring_min, counts):
    """``jnds_deploy.filter_spec.history_rejected`` from the marks of ``_mark_row``: a pixel
    marked, or next to a trail's pixel (marked 2, with at least ``ring_min`` marked 2 in its
    3x3), takes the current inputs' 12 channels; counts[y] says how many per row."""
    h, w = rej.shape
    trail = np.zeros((h, w), np.uint8)
    for y in prange(h):
        for x in range(w):
            if rej[y, x] == 2:
                n = 0
                for yy in range(max(y - 1, 0), min(y + 2, h)):
                    for xx in range(max(x - 1, 0), min(x + 2, w)):
                        n += rej[yy, xx] == 2
                trail[y, x] = n >= ring_min
    across = np.empty((h, w), np.uint8)  # the dilation, separable: rows' maxima first
    for y in prange(h):
        for x in range(w):
            m = trail[y, x]
            if x > 0:
                m |= trail[y, x - 1]
            if x < w - 1:
                m |= trail[y, x + 1]
            across[y, x] = m
    for y in prange(h):
        bad = np.empty(w, np.bool_)
        n = 0
        for x in range(w):
            b = (rej[y, x] != 0) | (across[y, x] != 0)
            if y > 0:
                b |= across[y - 1, x] != 0
            if y < h - 1:
                b |= across[y + 1, x] != 0
            bad[x] = b
            n += b
        counts[y] = n
        if n:
            # one channel at a time: the planes of a frame are far apart, and touching all 25
            # per pixel thrashed the cache (docs/architecture.md, "The filter stage")
            for c in range(WARP_CHANNELS):
                for x in range(w):
                    if bad[x]:
                        warped[c, y, x] = current[c, y, x]


@njit(parallel=True, cache=True)
def _mark_rows(current, warped, cos, background, tol, rej):
    off = np.zeros(warped.shape[2], np.bool_)  # no motion: nothing enters the view
    for y in prange(warped.shape[1]):
        _mark_row(current, warped, y, cos, background, tol, off, rej)


def reject_disoccluded(
    current: np.ndarray,
    warped: np.ndarray,
    cos: float = REJECT_COS,
    background: float = BACKGROUND,
    albedo: float = REJECT_ALBEDO,
    offscreen: np.ndarray | None = None,
) -> int:
    """``jnds_deploy.filter_spec.history_rejected`` applied in place: where the current sample
    sees background or the warped history shows another surface (or where ``offscreen``,
    (H, W) bool: ``jnds_deploy.filter_spec.offscreen``; None: no motion), and next to such a
    pixel that sees a surface, the history's 12 channels become the current inputs'
    (current (13, H, W), warped (12, H, W) float32, albedo at channels 6-8 and normals at
    9-11 of both). Returns how many pixels."""
    rej = np.empty(warped.shape[1:], np.uint8)
    _mark_rows(current, warped, np.float32(cos), np.float32(background), np.float32(albedo), rej)
    if offscreen is not None:
        surface = np.abs(current[_NX : _NZ + 1]).sum(0) >= np.float32(background)
        rej = np.where(offscreen & (rej == 0), 1 + surface, rej).astype(np.uint8)
    counts = np.zeros(warped.shape[1], np.int64)
    _replace_rejected(current, warped, rej, RING_MIN, counts)
    return int(counts.sum())


_LUM = tuple(np.float32(v) for v in LUMINANCE)


@njit(parallel=True, cache=True)
def _luminance_planes(current, history, out):
    """out[2 s] = luminance of current's signal s, out[2 s + 1] = the history's (s:
    diffuse, specular), with the sums in ``jnds_deploy.filter_spec.luminance``'s order."""
    r, g, b = _LUM
    for y in prange(current.shape[1]):
        for s in range(2):
            c = _DIFFUSE if s == 0 else _SPECULAR
            for x in range(current.shape[2]):
                out[2 * s, y, x] = current[c, y, x] * r + current[c + 1, y, x] * g + current[c + 2, y, x] * b
                out[2 * s + 1, y, x] = history[c, y, x] * r + history[c + 1, y, x] * g + history[c + 2, y, x] * b


@njit(inline="always")
def _max3(row, out, skip_centre):
    """out[x] = max of row[x - 1], row[x] and row[x + 1] (without row[x] if ``skip_centre``),
    indices clamped to the row (a clamped index may bring row[x] back, as in
    ``jnds_deploy.filter_spec.clamp_fireflies``'s padding)."""
    w = row.shape[0]
    out[0] = max(row[0], row[min(1, w - 1)])
    if w > 1:
        out[w - 1] = max(row[w - 2], row[w - 1])
    if skip_centre:
        for x in range(1, w - 1):
            out[x] = max(row[x - 1], row[x + 1])
    else:
        for x in range(1, w - 1):
            out[x] = max(max(row[x - 1], row[x]), row[x + 1])


@njit(parallel=True, cache=True)
def _clamp_rows(current, lum, k, counts):
    # the 3x3 maximum as maxima of three along each row (border columns apart: clamped
    # indices in the loop kept it scalar) taken over the three rows; maxima are exact, so
    # the bounds are the 3x3 loop's bit for bit (docs/architecture.md, "The filter stage")
    h, w = current.shape[1], current.shape[2]
    for y in prange(h):
        ya, yc = max(y - 1, 0), min(y + 1, h - 1)
        m = np.empty((6, w), np.float32)
        n = 0
        for s in range(2):
            c = _DIFFUSE if s == 0 else _SPECULAR
            cur, his = lum[2 * s], lum[2 * s + 1]
            _max3(cur[ya], m[0], False)
            _max3(cur[y], m[1], True)  # the pixel itself is not its own bound
            _max3(cur[yc], m[2], False)
            _max3(his[ya], m[3], False)
            _max3(his[y], m[4], False)
            _max3(his[yc], m[5], False)
            for x in range(w):
                bound = max(max(max(m[0, x], m[1, x]), max(m[2, x], m[3, x])), max(m[4, x], m[5, x]))
                bound = max(bound, np.float32(0)) * k
                v = cur[y, x]
                if v > bound:
                    f = bound / v
                    current[c, y, x] *= f
                    current[c + 1, y, x] *= f
                    current[c + 2, y, x] *= f
                    n += 1
        counts[y] = n


def clamp_fireflies(current: np.ndarray, history: np.ndarray, k: float) -> int:
    """``jnds_deploy.filter_spec.clamp_fireflies`` of the current diffuse and specular in place
    (current (13, H, W), the warped history (12, H, W), float32). Returns how many pixel
    values (per signal) were clamped."""
    _, h, w = current.shape
    lum = np.empty((4, h, w), np.float32)
    _luminance_planes(current, history, lum)
    counts = np.zeros(h, np.int64)
    _clamp_rows(current, lum, np.float32(k), counts)
    return int(counts.sum())


_FILL_TAPS = tuple(np.float32(t) for t in DIFFUSE_FILL_TAPS)
_FILL_R = len(DIFFUSE_FILL_TAPS) // 2


@njit(parallel=True, cache=True)
def _diffuse_holes(current, flags, counts):
    """flags[y, x] = 1 where the sample hit a diffuse surface (albedo > 0), 2 where it is a
    hole (albedo 0, normal not background), else 0; counts[y] = the row's holes."""
    b = np.float32(BACKGROUND)
    for y in prange(current.shape[1]):
        n = 0
        for x in range(current.shape[2]):
            a = max(max(current[_ALBEDO, y, x], current[_ALBEDO + 1, y, x]), current[_ALBEDO + 2, y, x])
            if a > 0:
                flags[y, x] = 1
            elif abs(current[_NX, y, x]) + abs(current[_NY, y, x]) + abs(current[_NZ, y, x]) >= b:
                flags[y, x] = 2
                n += 1
            else:
                flags[y, x] = 0
        counts[y] = n


@njit(parallel=True, cache=True)
def _fill_row_sums(current, flags, sums):
    """sums[0:3] = the horizontal taps of diffuse x valid, sums[3] of valid (zero beyond the
    row's ends)."""
    w = current.shape[2]
    for y in prange(current.shape[1]):
        for x in range(w):
            s0 = s1 = s2 = s3 = np.float32(0)
            for i in range(2 * _FILL_R + 1):
                xx = x + i - _FILL_R
                if 0 <= xx < w and flags[y, xx] == 1:
                    t = _FILL_TAPS[i]
                    s0 += t * current[_DIFFUSE, y, xx]
                    s1 += t * current[_DIFFUSE + 1, y, xx]
                    s2 += t * current[_DIFFUSE + 2, y, xx]
                    s3 += t
            sums[0, y, x], sums[1, y, x], sums[2, y, x], sums[3, y, x] = s0, s1, s2, s3


@njit(parallel=True, cache=True)
def _fill_holes(current, flags, sums, counts):
    """The holes' diffuse from the vertical taps of the row sums (in place: a hole's diffuse
    is never read, its weight is 0). ``counts[y]``: the row's holes in, its filled pixels out."""
    h = current.shape[1]
    lo = np.float32(DIFFUSE_FILL_MIN)
    for y in prange(h):
        if counts[y] == 0:
            continue
        n = 0
        for x in range(current.shape[2]):
            if flags[y, x] != 2:
                continue
            s0 = s1 = s2 = s3 = np.float32(0)
            for i in range(2 * _FILL_R + 1):
                yy = y + i - _FILL_R
                if 0 <= yy < h:
                    t = _FILL_TAPS[i]
                    s0 += t * sums[0, yy, x]
                    s1 += t * sums[1, yy, x]
                    s2 += t * sums[2, yy, x]
                    s3 += t * sums[3, yy, x]
            if s3 >= lo:
                current[_DIFFUSE, y, x] = s0 / s3
                current[_DIFFUSE + 1, y, x] = s1 / s3
                current[_DIFFUSE + 2, y, x] = s2 / s3
                n += 1
        counts[y] = n


def diffuse_holes(current: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The current inputs' (13, H, W) float32 samples as flags (H, W) u8: 1 a diffuse surface,
    2 a hole (``jnds_deploy.filter_spec.diffuse_holes``), 0 background; and each row's number of
    holes (H,). One pass over the albedo and normals."""
    _, h, w = current.shape
    flags = np.empty((h, w), np.uint8)
    counts = np.zeros(h, np.int64)
    _diffuse_holes(current, flags, counts)
    return flags, counts


def fill_diffuse_holes(current: np.ndarray, holes: tuple[np.ndarray, np.ndarray] | None = None) -> int:
    """``jnds_deploy.filter_spec.fill_diffuse_holes`` on the current inputs (13, H, W) float32,
    in place (``holes``: their ``diffuse_holes``, else found here). Returns how many pixels
    were filled. Separable, as the torch op: a frame without holes costs one pass over its
    albedo and normals."""
    flags, counts = holes if holes is not None else diffuse_holes(current)
    if not counts.any():
        return 0
    _, h, w = current.shape
    counts = counts.copy()  # _fill_holes counts the filled pixels into it
    sums = np.empty((4, h, w), np.float32)
    _fill_row_sums(current, flags, sums)
    _fill_holes(current, flags, sums, counts)
    return int(counts.sum())


_SHARE_LO, _SHARE_HI = (np.float32(v) for v in SCATTERED_SHARE)
_CHANGES_MIN = np.float32(SCATTERED_CHANGES)


@njit(parallel=True, cache=True)
def _hole_row_sums(flags, counts, sums, live):
    """sums[0] = the horizontal taps of the hole mask, sums[1] of its changes (to the right
    plus downward, none beyond the last column and row), the border replicated; rows with
    no hole in them or below are 0 (``live`` False) without being read."""
    h, w = flags.shape
    t0, t1, t2, t3, t4 = _FILL_TAPS
    for y in prange(h):
        if counts[y] == 0 and (y + 1 == h or counts[y + 1] == 0):
            live[y] = False
            sums[0, y, :] = 0
            sums[1, y, :] = 0
            continue
        live[y] = True
        hr = np.empty(w + 4, np.float32)  # the row's hole mask and changes, 2 replicated each side
        cr = np.empty(w + 4, np.float32)
        for x in range(w):
            hr[x + 2] = np.float32(1) if flags[y, x] == 2 else np.float32(0)
        below = min(y + 1, h - 1)
        for x in range(w):
            m = np.float32(0)
            if x + 1 < w:
                m += abs(hr[x + 3] - hr[x + 2])
            if y + 1 < h:
                m += abs((np.float32(1) if flags[below, x] == 2 else np.float32(0)) - hr[x + 2])
            cr[x + 2] = m
        hr[0] = hr[1] = hr[2]
        hr[w + 2] = hr[w + 3] = hr[w + 1]
        cr[0] = cr[1] = cr[2]
        cr[w + 2] = cr[w + 3] = cr[w + 1]
        for x in range(w):
            sums[0, y, x] = t0 * hr[x] + t1 * hr[x + 1] + t2 * hr[x + 2] + t3 * hr[x + 3] + t4 * hr[x + 4]
            sums[1, y, x] = t0 * cr[x] + t1 * cr[x + 1] + t2 * cr[x + 2] + t3 * cr[x + 3] + t4 * cr[x + 4]


@njit(parallel=True, cache=True)
def _composite_at_holes(comp, albedo, diffuse, specular, sums, live, counts):
    """comp = the 5x5 binomial mean of albedo (border replicated) x diffuse + specular where
    the vertical taps of ``sums`` say the holes lie scattered; ``counts[y]`` those pixels."""
    c, h, w = albedo.shape
    t0, t1, t2, t3, t4 = _FILL_TAPS
    for y in prange(h):
        r0, r1, r2, r3, r4 = max(y - 2, 0), max(y - 1, 0), y, min(y + 1, h - 1), min(y + 2, h - 1)
        if not (live[r0] or live[r1] or live[r2] or live[r3] or live[r4]):
            continue
        n = 0
        for x in range(w):
            share = (
                t0 * sums[0, r0, x]
                + t1 * sums[0, r1, x]
                + t2 * sums[0, r2, x]
                + t3 * sums[0, r3, x]
                + t4 * sums[0, r4, x]
            )
            moves = (
                t0 * sums[1, r0, x]
                + t1 * sums[1, r1, x]
                + t2 * sums[1, r2, x]
                + t3 * sums[1, r3, x]
                + t4 * sums[1, r4, x]
            )
            if not (_SHARE_LO < share < _SHARE_HI and moves > _CHANGES_MIN):
                continue
            n += 1
            for k in range(c):
                m = np.float32(0)
                for j in range(2 * _FILL_R + 1):
                    yy = min(max(y + j - _FILL_R, 0), h - 1)
                    r = np.float32(0)
                    for i in range(2 * _FILL_R + 1):
                        r += _FILL_TAPS[i] * albedo[k, yy, min(max(x + i - _FILL_R, 0), w - 1)]
                    m += _FILL_TAPS[j] * r
                comp[k, y, x] = m * diffuse[k, y, x] + specular[k, y, x]
        counts[y] = n


def albedo_at_holes(
    comp: np.ndarray,
    albedo: np.ndarray,
    diffuse: np.ndarray,
    specular: np.ndarray,
    holes: tuple[np.ndarray, np.ndarray],
) -> int:
    """``jnds_deploy.filter_spec.albedo_at_holes`` then the composite, as a patch: the composite
    ``comp`` (3, H, W) of the filtered ``albedo``, ``diffuse`` and ``specular`` is computed
    again, in place, with the albedo's 5x5 binomial mean where ``holes`` (``diffuse_holes`` of
    the frame's inputs) lie scattered. The albedo itself, which the history keeps, is not
    changed. Returns how many pixels were. Rows with no hole within two rows cost nothing;
    float32 inside, ``comp``'s dtype out."""
    flags, counts = holes
    if not counts.any():
        return 0
    _, h, w = albedo.shape
    sums = np.empty((2, h, w), np.float32)
    live = np.empty(h, np.bool_)
    _hole_row_sums(flags, counts, sums, live)
    f32 = [np.ascontiguousarray(a, dtype=np.float32) for a in (comp, albedo, diffuse, specular)]
    patched = np.zeros(h, np.int64)
    _composite_at_holes(*f32, sums, live, patched)
    if f32[0] is not comp:
        comp[...] = f32[0]
    return int(patched.sum())


def warp(x: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Bicubic resampling of the previous frame ``x`` (C, H, W) along motion (2, H, W), any
    C (``warp_channels_last`` in passes of 12 channels, zero-padded)."""
    c, h, w = x.shape
    out = np.empty((c, h, w), np.float32)
    for c0 in range(0, c, WARP_CHANNELS):
        part = x[c0 : c0 + WARP_CHANNELS]
        pad = np.zeros((WARP_CHANNELS - part.shape[0], h, w), np.float32)
        out[c0 : c0 + part.shape[0]] = warp_channels_last(channels_last(part, pad), motion)[: part.shape[0]]
    return out.astype(x.dtype, copy=False)


def downsample(x: np.ndarray) -> np.ndarray:
    """2x2 average pooling (H and W even)."""
    c, h, w = x.shape
    return x.reshape(c, h // 2, 2, w // 2, 2).mean(axis=(2, 4), dtype=np.float32).astype(x.dtype, copy=False)


def upsample(x: np.ndarray, factor: int = 2) -> np.ndarray:
    """Bilinear upsampling, as cv2.resize(INTER_LINEAR) and align_corners=False."""
    c, h, w = x.shape
    src = x.astype(np.float32, copy=False)
    out = np.empty((c, h * factor, w * factor), np.float32)
    for i in range(c):  # straight into the output (dst=): no copy of the result
        cv2.resize(src[i], (w * factor, h * factor), dst=out[i], interpolation=cv2.INTER_LINEAR)
    return out.astype(x.dtype, copy=False)


def relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0, out=x)


def lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """a + t * (b - a), ``t`` (1, H, W) broadcast over channels."""
    return a + t * (b - a)


def spatiotemporal(x, history, k_spatial, k_temporal, blend, skip=None, tile: int = 1, relu: bool = True) -> np.ndarray:
    """relu(lerp(kernel k_spatial on x, kernel k_temporal on history, blend)) (no ReLU if
    not ``relu``); in the tiles set in ``skip``: x."""
    if (out := _lerp_head(x, k_spatial, history, k_temporal, blend, relu)) is not None:
        return _pass_tiles(x, out, skip, tile)
    k_spatial, k_temporal, blend = _decoded(k_spatial, k_temporal, blend)
    if _fast(x, history, k_spatial, k_temporal, blend):
        out = np.empty_like(x)
        _lerp_taps(x, k_spatial, history, k_temporal, blend, out, relu)
        return _pass_tiles(x, out, skip, tile)
    _no_skip(skip)
    out = lerp(apply_kernel(x, k_spatial), apply_kernel(history, k_temporal), blend)
    return np.maximum(out, 0, out=out) if relu else out


def down_level(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """One level down: relu(kernel on the 2x2 average pool of x)."""
    if isinstance(kernel, Coded) and _fast(x):
        c, h, w = x.shape
        out = np.empty((c, h // 2, w // 2), np.float32)
        k = kernel.head
        _pool_coded(x, kernel.q, kernel.c0, k.kinds, k.scale, k.offset, k.table, out)
        return out
    (kernel,) = _decoded(kernel)
    if _fast(x, kernel):
        c, h, w = x.shape
        out = np.empty((c, h // 2, w // 2), np.float32)
        _pool_taps(x, kernel, out)
        return out
    return apply_kernel(downsample(x), kernel, relu=True)


def up_level(
    skip: np.ndarray, coarse: np.ndarray, kernel: np.ndarray, blend: np.ndarray, tiles=None, tile: int = 1
) -> np.ndarray:
    """One level up: relu(lerp(skip, kernel on the bilinear upsampling of coarse, blend));
    in the tiles set in ``tiles``: skip."""
    up = upsample(coarse)
    if (out := _lerp_head(skip, None, up, kernel, blend)) is not None:
        return _pass_tiles(skip, out, tiles, tile)
    kernel, blend = _decoded(kernel, blend)
    if _fast(skip, up, kernel, blend):
        out = np.empty_like(skip)
        _lerp_taps(skip, _NONE, up, kernel, blend, out)
        return _pass_tiles(skip, out, tiles, tile)
    _no_skip(tiles)
    return relu(lerp(skip, apply_kernel(up, kernel), blend))


def filter_path(
    x: np.ndarray, history: np.ndarray, native: dict, levels: list[dict], skip=None, tile: int = 1
) -> np.ndarray:
    """The hierarchical filter of one signal; see ``jnds_deploy.filter_spec.filter_path``.
    ``skip``: empty tiles passed through at native resolution (the levels below native are
    small and filtered whole)."""
    skips = [spatiotemporal(x, history, native["spatial"], native["temporal"], native["blend"], skip, tile)]
    for lv in levels:
        skips.append(down_level(skips[-1], lv["down"]))
    y = skips[-1]
    for k in range(len(levels) - 1, -1, -1):
        p = levels[k - 1] if k > 0 else native
        y = up_level(skips[k], y, p["up"], p["up_blend"], *((skip, tile) if k == 0 else ()))
    return y


@njit(parallel=True, cache=True)
def _composite(a, d, s, out):
    C, H, W = out.shape
    for y in prange(H):
        for c in range(C):
            for x in range(W):
                out[c, y, x] = a[c, y, x] * d[c, y, x] + s[c, y, x]


def composite(albedo: np.ndarray, diffuse: np.ndarray, specular: np.ndarray) -> np.ndarray:
    """Eq. 2: albedo * diffuse + specular (float32: one fused pass, the same rounding as
    numpy's two, without numpy's temporary)."""
    if _fast(albedo, diffuse, specular) and albedo.shape == diffuse.shape == specular.shape:
        out = np.empty(albedo.shape, np.float32)
        _composite(np.ascontiguousarray(albedo), np.ascontiguousarray(diffuse), np.ascontiguousarray(specular), out)
        return out
    return albedo * diffuse + specular


@njit(parallel=True, cache=True)
def _apply_phases(x, k, out, s):
    """out = relu(kernel on x), x at target resolution, the kernel in phase layout
    (s*s*9, H, W): k[(py * s + px) * 9 + t, i, j] is tap t of target pixel (s*i + py, s*j + px).
    Each target row's taps are first interleaved into a row buffer (cache-resident), so the
    tap loop stays contiguous and vectorizes; reading the phases in place was slower, and
    making a target-layout kernel with ONNX Runtime's DepthToSpace slower still
    (docs/architecture.md, "The network graph")."""
    C, H, W = x.shape
    w = W // s
    for y in prange(H):
        row = np.empty((9, 1, W), np.float32)
        i, py = y // s, y % s
        for px in range(s):
            base = (py * s + px) * 9
            for t in range(9):
                for j in range(w):
                    row[t, 0, j * s + px] = k[base + t, i, j]
        ya, yc = max(y - 1, 0), min(y + 1, H - 1)
        for c in range(C):
            _apply_row(x, row, 0, out, True, c, ya, y, yc)


def from_phases(kernel: np.ndarray, factor: int) -> np.ndarray:
    """(s*s*C, H, W) phase layout -> (C, sH, sW) (``jnds_deploy.filter_spec.from_phases``)."""
    _, h, w = kernel.shape
    s = factor
    return np.ascontiguousarray(kernel.reshape(s, s, -1, h, w).transpose(2, 3, 0, 4, 1).reshape(-1, h * s, w * s))


def upsample_filter(
    color: np.ndarray, kernel: np.ndarray, factor: int, skip=None, tile: int = 1, root: int = 1
) -> np.ndarray:
    """Bilinear upsampling of the linear composite (of its ``root``-th root, raised back to
    the power ``root``: ``jnds_deploy.filter_spec.upsample_filter``), the predicted 3x3 kernel,
    ReLU; in the native tiles set in ``skip``, the upsampling alone. ``kernel`` comes in
    the upsample graph's phase layout (s*s*9, H, W) at native resolution (factor > 1)."""
    if factor == 1:
        return apply_kernel(color, kernel, relu=True, skip=skip, tile=tile)
    up = _upsampled(color, factor, root)
    if _fast(up, kernel):
        out = np.empty_like(up)
        _apply_phases(up, kernel, out, factor)
        return _pass_tiles(up, out, skip, tile * factor)
    return apply_kernel(up, from_phases(kernel, factor), relu=True, skip=skip, tile=tile * factor)


def upsample_fixed(color: np.ndarray, kernel, factor: int, root: int = 1) -> np.ndarray:
    """``upsample_filter`` with one 3x3 kernel (9 taps) for every target pixel
    (``model.ModelConfig.upsample_width`` 0): cv2.filter2D, a correlation with the border
    replicated, as ``apply_kernel`` reads it. Float32 (OpenCV filters no float16)."""
    up = _upsampled(color.astype(np.float32, copy=False), factor, root)
    k = np.asarray(kernel, np.float32).reshape(3, 3)
    for i in range(up.shape[0]):  # in place: filter2D buffers the rows it still reads
        cv2.filter2D(up[i], -1, k, dst=up[i], borderType=cv2.BORDER_REPLICATE)
    if k.min() < 0:  # non-negative taps on a non-negative image need no ReLU
        relu(up)
    return up.astype(color.dtype, copy=False)


@njit(inline="always")
def _stored(v, zero, inf, top):
    """(ReLU(v), 0) for finite v, else (``top`` for +Inf, 0 for NaN and -Inf; 1): selects, no
    branch, so that the loops storing it vectorize."""
    finite = abs(v) < inf
    return (max(v, zero) if finite else (top if v > zero else zero)), np.int64(not finite)


@njit(parallel=True, cache=True)
def _upsample2_fixed_hwc(r, k, squarings, out):
    """out (Ho, Wo, C) = ReLU(3x3 kernel ``k`` on the 2x bilinear upsampling of ``r`` (C, H, W),
    each sample raised to the power 2^squarings), the top-left Ho x Wo of it; non-finite
    results replaced by 0 (NaN, -Inf) or HDR_MAX (+Inf); returns how many. Blocks of
    target rows per thread: each upsamples the rows it reads (its own and one on each
    side) once into a buffer, padded by one replicated column on each side; the kernel runs
    along a buffered row (contiguous, vectorized) and is stored interleaved."""
    C, H, W = r.shape
    Ho, Wo = out.shape[0], out.shape[1]
    TH, TW = 2 * H, 2 * W
    zero, inf, top = np.float32(0.0), np.float32(np.inf), np.float32(HDR_MAX)
    B = 16
    nb = (Ho + B - 1) // B
    bad = np.zeros(nb, np.int64)
    for b in prange(nb):
        y0 = b * B
        y1 = min(y0 + B, Ho)
        n = y1 - y0 + 2
        up = np.empty((n, C, TW + 2), np.float32)
        vrow = np.empty(W, np.float32)
        acc = np.empty((C, Wo), np.float32)
        for t in range(n):
            yy = min(max(y0 - 1 + t, 0), TH - 1)
            i = yy >> 1
            i2 = min(i + 1, H - 1) if yy & 1 else max(i - 1, 0)
            for c in range(C):
                for j in range(W):
                    vrow[j] = np.float32(0.75) * r[c, i, j] + np.float32(0.25) * r[c, i2, j]
                row = up[t, c]
                for j in range(W):
                    row[2 * j + 1] = np.float32(0.75) * vrow[j] + np.float32(0.25) * vrow[max(j - 1, 0)]
                    row[2 * j + 2] = np.float32(0.75) * vrow[j] + np.float32(0.25) * vrow[min(j + 1, W - 1)]
                for _ in range(squarings):
                    for x in range(1, TW + 1):
                        row[x] = row[x] * row[x]
                row[0] = row[1]
                row[TW + 1] = row[TW]
        for y in range(y0, y1):
            t = y - y0
            for c in range(C):
                a, m, z, dst = up[t, c], up[t + 1, c], up[t + 2, c], acc[c]
                for x in range(Wo):
                    dst[x] = (
                        k[0] * a[x]
                        + k[1] * a[x + 1]
                        + k[2] * a[x + 2]
                        + k[3] * m[x]
                        + k[4] * m[x + 1]
                        + k[5] * m[x + 2]
                        + k[6] * z[x]
                        + k[7] * z[x + 1]
                        + k[8] * z[x + 2]
                    )
            # stored interleaved with selects, not a branch, and counted as a sum: the
            # branch kept this loop scalar (measured at commit 67e04b5)
            if C == 3:
                a0, a1, a2, o = acc[0], acc[1], acc[2], out[y].reshape(3 * Wo)  # flat: a stride LLVM knows
                n = 0
                for x in range(Wo):
                    o[3 * x], n0 = _stored(a0[x], zero, inf, top)
                    o[3 * x + 1], n1 = _stored(a1[x], zero, inf, top)
                    o[3 * x + 2], n2 = _stored(a2[x], zero, inf, top)
                    n += n0 + n1 + n2
                bad[b] += n
            else:
                for c in range(C):
                    for x in range(Wo):
                        out[y, x, c], nc = _stored(acc[c, x], zero, inf, top)
                        bad[b] += nc
    return bad.sum()


@njit(parallel=True, cache=True)
def _floored_roots(x, floor, halvings, out):
    """out = max(x, floor) (NaN kept, as np.maximum keeps it) through ``halvings`` square
    roots: ``_roots`` of ``np.maximum(x, floor)``, bit for bit, in one pass on all threads."""
    C, H, W = x.shape
    for y in prange(H):
        for c in range(C):
            src, dst = x[c, y], out[c, y]
            for i in range(W):
                v = src[i]
                dst[i] = floor if v < floor else v
            for _ in range(halvings):  # a pass along the row each: a loop inside kept it scalar
                for i in range(W):
                    dst[i] = np.sqrt(dst[i])


def upsample_fixed_hwc(color: np.ndarray, kernel, root: int, h: int, w: int) -> tuple[np.ndarray, int]:
    """``upsample_fixed`` at factor 2 and ``reformat.to_hwc`` of its top-left (2h, 2w) in one
    pass (written here: the upsampled image is never stored whole, nor the channels-first
    result), non-finite values replaced as ``history.replace_nonfinite`` does: (output
    (2h, 2w, 3) float32, how many were replaced). The roots before it are one pass of their
    own on all threads (numpy's maximum and square roots made three on one)."""
    if root > 1:
        src = np.empty(color.shape, np.float32)
        _floored_roots(np.ascontiguousarray(color, np.float32), np.float32(ROOT_FLOOR), root.bit_length() - 1, src)
    else:
        src = np.ascontiguousarray(color, np.float32)
    out = np.empty((2 * h, 2 * w, color.shape[0]), np.float32)
    bad = _upsample2_fixed_hwc(src, np.asarray(kernel, np.float32).reshape(9), root.bit_length() - 1, out)
    return out, int(bad)


def _upsampled(color: np.ndarray, factor: int, root: int) -> np.ndarray:
    """The bilinear upsampling of ``color`` (of its ``root``-th root, raised back)."""
    if root == 1:
        return upsample(color, factor)
    # roots and powers of two by square roots and squares: no pow() (model.UPSAMPLE_ROOTS)
    up = upsample(_roots(np.maximum(color, ROOT_FLOOR, dtype=np.float32), root), factor)
    for _ in range(root.bit_length() - 1):
        np.multiply(up, up, out=up)
    return up.astype(color.dtype, copy=False)


def _roots(x: np.ndarray, root: int) -> np.ndarray:
    """x^(1/root) for root a power of two (the pipeline checks the manifest's), in place."""
    for _ in range(root.bit_length() - 1):
        np.sqrt(x, out=x)
    return x


def _no_skip(skip) -> None:
    if skip is not None:
        raise ValueError("tile skipping needs the float32 filter stage")
