"""Data reformatting between the renderer's layout and the network's, with the input
sanitizing folded into the same pass.

``to_chw`` stacks the HWC layers of one frame (as ``jnds_deploy.io`` reads them) into
one CHW array for the network, replacing NaN and clamping every value into its layer's
valid range (``LIMITS``) on the way, and counts the non-finite values it met per layer;
``to_hwc`` turns the CHW output back into HWC. ``pack_inputs`` gives an int8 network
graph (``calibration.inputs``) its input: the input block's preprocessing of current
and history, quantized, channels last.

numpy's ``concatenate(...).transpose(2, 0, 1)`` + copy is a strided gather on one
thread; these numba loops write each element once, rows in parallel (measured at commit
fe226b2). The layout of ``pack_inputs``' output is ``artifacts.layouts.InputsLayout``.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

from ..artifacts.layouts import Cut, InputsLayout, preprocess
from ..errors import ArtifactError
from ..layout import GUIDE, HDR_MAX, LAYERS, TONEMAP_FLOOR
from .simd import N, binned_codes16, lerp_codes16, requantize16, transpose8x8

# layer -> (low, high, renormalize), from the one table of input layers (layout.LAYERS) and
# the guide albedo (layout.GUIDE)
LIMITS: dict[str, tuple[float, float, bool]] = {
    layer.name: (layer.lo, layer.hi, layer.unit_vector) for layer in (*LAYERS, GUIDE)
}


@njit(inline="always")
def _clean(v, lo, hi):
    """NaN as 0, then clamped into [lo, hi] (selects: the loops stay branch-free)."""
    v = np.float32(0) if v != v else v
    return min(max(v, lo), hi)


@njit(parallel=True, cache=True, error_model="numpy")
def _hwc_into_chw(src, out, c0, h, w, lo, hi, renormalize, nonfinite):
    # the row cleaned and counted in its own order first (pixels interleaved: contiguous, so
    # it vectorizes), then dealt out to the channels' rows: cleaning while dealing out kept
    # the checks scalar (measured at commit b346e1b). A 3-channel layer's pixel is
    # renormalized as it is dealt out, not in a second pass over the row (commit e4e5f6e);
    # the padding columns and rows replicate the last ones
    lo32, hi32, zero = np.float32(lo), np.float32(hi), np.float32(0)
    C = src.shape[2]
    W = out.shape[2]
    for y in prange(out.shape[1]):
        sy = min(np.int64(y), h - 1)
        bad = 0
        values = src[sy].reshape(w * C)
        clean = np.empty(w * C, np.float32)
        for i in range(w * C):
            v = values[i]
            bad += np.int64(not np.isfinite(v))
            clean[i] = _clean(v, lo32, hi32)
        if C == 3:
            r0, r1, r2 = out[c0, y], out[c0 + 1, y], out[c0 + 2, y]
            for i in range(w):
                a0, a1, a2 = clean[3 * i], clean[3 * i + 1], clean[3 * i + 2]
                if renormalize:
                    # left as is where the squared norm is 0 (a select; numpy's error model
                    # lets 1 / 0 be inf rather than a branch that raises)
                    norm = a0 * a0 + a1 * a1 + a2 * a2
                    inv = np.float32(1) / np.sqrt(norm)
                    inv = inv if norm > zero else np.float32(1)
                    a0, a1, a2 = a0 * inv, a1 * inv, a2 * inv
                r0[i], r1[i], r2[i] = a0, a1, a2
        else:
            for c in range(C):
                row = out[c0 + c, y]
                for i in range(w):
                    row[i] = clean[i * C + c]
        for c in range(C):
            row = out[c0 + c, y]
            for i in range(w, W):
                row[i] = row[w - 1]
        nonfinite[y] = bad if y < h else 0
        if renormalize and C != 3:
            for i in range(W):
                norm = zero
                for c in range(C):
                    norm += out[c0 + c, y, i] * out[c0 + c, y, i]
                if norm > 0:
                    inv = np.float32(1) / np.sqrt(norm)
                    for c in range(C):
                        out[c0 + c, y, i] *= inv


@njit(parallel=True, cache=True)
def _chw_into_hwc(src, out):
    for y in prange(out.shape[0]):
        for i in range(out.shape[1]):
            for c in range(out.shape[2]):
                out[y, i, c] = src[c, y, i]


def to_chw(
    layers: dict[str, np.ndarray], names, padded: tuple[int, int] | None = None, nonfinite: dict[str, int] | None = None
) -> np.ndarray:
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


def _tonemap_codes(layout: InputsLayout) -> tuple[np.ndarray, np.ndarray]:
    """Tables giving Eq. 1's tonemap of x >= 0, quantized, without evaluating it per
    value, per bin of floats that share their top 17 bits (sign, exponent and 8 mantissa
    bits: ``x.view(uint32) >> 15``). ``first`` (int32): the code of the bin's smallest
    float32; ``step`` (float32): the x from which the next code is reached, the smallest
    float32 at or above it (+inf for code 255). Within a bin x changes by 2^-8
    of itself, the tonemap (t^(1/2.2) of log(x + 1)) by at most 0.46 of that, so a bin holds
    at most one step of any code that is not saturated: the code of x is ``first[bin] + (x >=
    step[bin])`` (``_quantize_row``; ``simd.binned_codes16``, 16 at a time by two gathers).
    The thresholds are exact in float64 and rounded up to float32, which compares float32 x
    the same way: the codes are those of rounding t / scale, up to ties."""
    s, z = layout.scale, layout.zero_point
    k = np.arange(256, dtype=np.float64)
    t = np.maximum((k - z - 0.5) * s, 0.0)  # code k from tonemap value t on
    with np.errstate(over="ignore"):  # a code out of float range is reached at +inf
        at = np.where(t > TONEMAP_FLOOR ** (1 / 2.2), np.expm1(t**2.2), -np.inf)
    at[: z + 1] = -np.inf  # the codes up to the zero point: every x >= 0
    at = np.append(at, np.inf)  # no code 256
    with np.errstate(invalid="ignore"):  # bins of NaN/Inf bits (x is clamped to HDR_MAX first)
        lows = (np.arange(1 << 16, dtype=np.uint32) << 15).view(np.float32).astype(np.float64)
    lows = np.where(np.isfinite(lows), lows, np.inf)
    first = (np.searchsorted(at, lows, side="right") - 1).clip(0, 255)
    need = at[first + 1]
    with np.errstate(over="ignore"):
        step = need.astype(np.float32)
    low = step.astype(np.float64) < need
    step[low] = np.nextafter(step[low], np.float32(np.inf))
    return first.astype(np.int32), step


@njit(inline="always")
def _input_row(current, history, guide, c, y):
    """Row y of input channel c: current's, then history's, then the guide albedo's."""
    nc, nh = current.shape[0], history.shape[0]
    return current[c, y] if c < nc else history[c - nc, y] if c < nc + nh else guide[c - nc - nh, y]


@njit(parallel=True, cache=True)
def _pack(current, history, guide, kinds, scale, zero_point, first, step, slots, pads, out):
    # each channel of a row into a contiguous byte row first, then the row's pixels
    # written out whole: storing straight into the channels-last output was one byte store
    # per value at a stride of C bytes (measured at commit ea78861)
    w, C = out.shape[2], out.shape[3]
    for y in prange(out.shape[1]):
        codes = np.empty((C, w), np.uint8)
        for c in range(kinds.shape[0]):
            src = _input_row(current, history, guide, c, y)
            # the channel's slot row taken once: indexing codes[slots[c], i] in the loops
            # reloaded slots[c] at every value and kept them scalar (measured at commit 53a7759)
            _quantize_row(src, kinds[c], scale, zero_point, first, step, codes[slots[c]])
        _store_pixels(codes, pads, zero_point, out[0, y])


@njit(inline="always")
def _quantize_row(src, k, scale, zero_point, first, step, row):
    # one row of one channel (kind k, ``preprocess``) into its u8 codes
    lo, hi = np.float32(0), np.float32(255)
    if k == 1:  # tonemap, through the tables: 16 values at a time by gathers, then the rest
        top = np.float32(HDR_MAX)
        w = row.shape[0]
        for i in range(0, w - w % N, N):
            binned_codes16(src, i, first, step, top, row, i)
        for i in range(w - w % N, w):
            v = min(max(src[i], lo), top)  # keeps -0.0: the sign bit is masked off
            b = np.int64((np.float32(v).view(np.uint32) & np.uint32(0x7FFFFFFF)) >> 15)
            # no branch: on 1-spp noise a branch here is mispredicted often
            # (measured at commit bc35550)
            row[i] = np.uint8(first[b] + np.int32(v >= step[b]))
    else:
        half, zp = np.float32(0.5), np.float32(zero_point)
        a = half if k == 2 else np.float32(1)
        b = half if k == 2 else lo
        for i in range(row.shape[0]):
            q = np.rint((src[i] * a + b) / scale) + zp
            row[i] = np.uint8(min(max(q, lo), hi))


@njit(inline="always")
def _store_pixels(codes, pads, zero_point, out_row):
    # a row's codes (C, w), the padding slots at the zero point, into its pixels (w, C)
    C, w = codes.shape
    for j in range(pads.shape[0]):
        pad = codes[pads[j]]
        for i in range(w):
            pad[i] = np.uint8(zero_point)
    if C % 8 == 0:
        # eight channels of eight pixels at a time: the channels' eight 64-bit words transposed
        # as an 8x8 byte matrix (``transpose8x8``), one word a pixel stored (x86 is
        # little-endian: channel c is byte c % 8 of its pixel's word)
        words, G = out_row.reshape(w * C).view(np.uint64), np.uint64(C // 8)
        blocks = w // 8 if w % 8 == 0 else 0  # codes' rows in whole words (8-byte aligned) only
        for g in range(C // 8):
            c = 8 * g
            if blocks:
                r0, r1, r2, r3 = (
                    codes[c].view(np.uint64),
                    codes[c + 1].view(np.uint64),
                    codes[c + 2].view(np.uint64),
                    codes[c + 3].view(np.uint64),
                )
                r4, r5, r6, r7 = (
                    codes[c + 4].view(np.uint64),
                    codes[c + 5].view(np.uint64),
                    codes[c + 6].view(np.uint64),
                    codes[c + 7].view(np.uint64),
                )
            # unsigned indices: numba wraps negative signed ones, a test and an add a store
            for b in range(np.uint64(blocks)):
                i = np.uint64(8) * b * G + np.uint64(g)
                (
                    words[i],
                    words[i + G],
                    words[i + np.uint64(2) * G],
                    words[i + np.uint64(3) * G],
                    words[i + np.uint64(4) * G],
                    words[i + np.uint64(5) * G],
                    words[i + np.uint64(6) * G],
                    words[i + np.uint64(7) * G],
                ) = transpose8x8(r0[b], r1[b], r2[b], r3[b], r4[b], r5[b], r6[b], r7[b])
            for i in range(8 * blocks, w):
                words[i * (C // 8) + g] = (
                    np.uint64(codes[c, i])
                    | (np.uint64(codes[c + 1, i]) << np.uint64(8))
                    | (np.uint64(codes[c + 2, i]) << np.uint64(16))
                    | (np.uint64(codes[c + 3, i]) << np.uint64(24))
                    | (np.uint64(codes[c + 4, i]) << np.uint64(32))
                    | (np.uint64(codes[c + 5, i]) << np.uint64(40))
                    | (np.uint64(codes[c + 6, i]) << np.uint64(48))
                    | (np.uint64(codes[c + 7, i]) << np.uint64(56))
                )
    else:
        for i in range(w):
            for c in range(C):
                out_row[i, c] = codes[c, i]


@njit(parallel=True, cache=True)
def _pack_blocks(current, history, guide, kinds, scale, zero_point, first, step, slots, pads, out):
    # ``_pack`` for a space-to-depth input block: output row y from input rows 2y and 2y + 1,
    # channel c's pixel (2y + py, 2x + px) to slot slots[4c + 2py + px] of pixel x
    w, C = out.shape[2], out.shape[3]
    for y in prange(out.shape[1]):
        codes = np.empty((C, w), np.uint8)
        line = np.empty(2 * w, np.uint8)
        for c in range(kinds.shape[0] // 4):
            for py in range(2):
                yy = 2 * y + py
                src = _input_row(current, history, guide, c, yy)
                # the input row quantized in order, as ``_pack`` does, then dealt out to the
                # two pixels' slots: read at a stride of 2, the affine loops stayed scalar
                # (measured at commit 3ab8dfe)
                _quantize_row(src, kinds[4 * c], scale, zero_point, first, step, line)
                even, odd = codes[slots[4 * c + 2 * py]], codes[slots[4 * c + 2 * py + 1]]
                for i in range(w):
                    even[i] = line[2 * i]
                    odd[i] = line[2 * i + 1]
        _store_pixels(codes, pads, zero_point, out[0, y])


def pack_inputs(
    current: np.ndarray, history: np.ndarray, layout: InputsLayout, guide: np.ndarray | None = None
) -> np.ndarray:
    """The int8 network graph's ``inputs`` (1, H, W, channels) u8 (H/2, W/2 in 2x2 blocks,
    ``InputsLayout.block``) from its float ``current``
    (1, 13, H, W) and ``history`` (1, 12, H, W), linear as the float graph takes them (and
    ``guide`` (1, 3, H, W), the guide albedo, for a graph that reads it):
    ``model.tonemap_inputs`` of both, concatenated (the guide after them, as it is),
    quantized (round half to even, saturated, as QuantizeLinear), each channel in its slot
    (``InputsLayout.slots``), the padding channels at the zero point (value 0)."""
    _, _, h, w = current.shape
    if (guide is not None) != layout.guided:
        raise ArtifactError(f"the int8 network graph {'reads' if layout.guided else 'has no'} guide albedo input")
    b = layout.block
    if h % b or w % b:
        raise ArtifactError(f"the int8 network graph reads {b}x{b} pixel blocks: a {w}x{h} frame is not made of them")
    guide = np.empty((0, h, w), np.float32) if guide is None else np.ascontiguousarray(guide[0], np.float32)
    out = np.empty((1, h // b, w // b, layout.channels), np.uint8)
    first, step = _tables(layout)
    slots, pads = _placement(layout)
    (_pack if b == 1 else _pack_blocks)(
        np.ascontiguousarray(current[0], np.float32),
        np.ascontiguousarray(history[0], np.float32),
        guide,
        preprocess(len(slots)),
        np.float32(layout.scale),
        layout.zero_point,
        first,
        step,
        slots,
        pads,
        out,
    )
    return out


@functools.lru_cache(maxsize=8)
def _placement(layout: InputsLayout) -> tuple[np.ndarray, np.ndarray]:
    """The slot of each channel and the padding slots, once per layout, not per frame."""
    slots = layout.order
    return slots, np.setdiff1d(np.arange(layout.channels), slots)


@functools.lru_cache(maxsize=8)
def _tables(layout: InputsLayout) -> tuple[np.ndarray, np.ndarray]:
    return _tonemap_codes(layout)


@njit(parallel=True, cache=True)
def _upsample_concat(dec, nat, sd, zd, sn, zn, sb, zb, phases, out):
    # ONNX Resize's linear mode with half-pixel centres at 2x, taps clamped to the edge,
    # computed from the u8 codes and rounded straight to the block's scale (ties to even,
    # saturated, as QuantizeLinear): the float graph's DequantizeLinear, Resize,
    # QuantizeLinear and concatenation in one pass (bit-equal to them on the shipped graph,
    # checked at commit dd494b5). At 2x every output's four weights are products of
    # 1/4 and 3/4, so the codes are combined first down the rows (weights 1 and 3, at half the
    # width), then along them: every intermediate is an integer below 2^12, exact in float32,
    # and the one rounding, the scaling, is done by a power of two less (kd / 16), which
    # rounds the same way. Bit-equal to taking the four taps at each output in float
    # (tests/runtime/test_reformat.py), and faster (measured at commit 53b8086). A pixel's
    # channels 16 at a time by ``simd``'s primitives, the rest one at a time (commit 9ef4435)
    h, w, cd = dec.shape
    H, W, cn = 2 * h, 2 * w, nat.shape[2] // (phases * phases)
    C = cd + cn
    kd16 = np.float32(np.float32(sd / sb) / np.float32(16))
    kn = np.float32(sn / sb)
    zd16, znf, zbf = np.float32(16 * zd), np.float32(zn), np.float32(zb)
    lo, hi, one, three, four = np.float32(0), np.float32(255), np.float32(1), np.float32(3), np.float32(4)
    vd, vn = cd - cd % N, cn - cn % N  # channels in whole vectors
    for y in prange(H):
        ya = (y - 1) // 2  # the source row above the output row's centre
        wa = one if y % 2 == 0 else three
        ra = dec[min(max(ya, 0), h - 1)].reshape(w * cd)
        rb = dec[min(max(ya + 1, 0), h - 1)].reshape(w * cd)
        col = np.empty(w * cd, np.float32)  # 4x the interpolation down the rows
        for i in range(w * cd):
            col[i] = wa * np.float32(ra[i]) + (four - wa) * np.float32(rb[i])
        o = out[0, y].reshape(W * C)
        row = nat[y // phases].reshape(nat.shape[1] * nat.shape[2])
        for x in range(W):
            xa = (x - 1) // 2
            wx = one if x % 2 == 0 else three
            ia, ib, j = min(max(xa, 0), w - 1) * cd, min(max(xa + 1, 0), w - 1) * cd, x * C
            for c in range(0, vd, N):
                lerp_codes16(col, ia + c, col, ib + c, wx, four - wx, zd16, kd16, zbf, o, j + c)
            for c in range(vd, cd):
                o[j + c] = np.uint8(
                    min(max(np.rint((wx * col[ia + c] + (four - wx) * col[ib + c] - zd16) * kd16) + zbf, lo), hi)
                )
            # pixel (y, x)'s skip features: in phases, phase 2 (y % 2) + x % 2 of (y // 2, x // 2)
            s = x * cn if phases == 1 else (4 * (x // 2) + 2 * (y % 2) + x % 2) * cn
            for c in range(0, vn, N):
                requantize16(row, s + c, znf, kn, zbf, o, j + cd + c)
            for c in range(vn, cn):
                o[j + cd + c] = np.uint8(min(max(np.rint((np.float32(row[s + c]) - znf) * kn) + zbf, lo), hi))


def block_input(up: np.ndarray, skip: np.ndarray, cut: Cut) -> np.ndarray:
    """A cut's ``entry`` (1, H, W, Cu + Cs) u8 from its outputs ``up`` (1, H/2, W/2, Cu) and
    ``skip`` (1, H, W, Cs), or (1, H/2, W/2, 4 Cs) in phases (``Cut.skip_phases``), u8
    channels last."""
    dec, nat = np.ascontiguousarray(up[0]), np.ascontiguousarray(skip[0])
    p = cut.skip_phases
    if (
        dec.dtype != np.uint8
        or nat.dtype != np.uint8
        or nat.shape[2] % (p * p)
        or (2 * dec.shape[0], 2 * dec.shape[1]) != (p * nat.shape[0], p * nat.shape[1])
    ):
        raise ArtifactError(
            f"{cut.entry}: {cut.up} {dec.dtype} {dec.shape} and {cut.skip} {nat.dtype} {nat.shape} do not fit"
        )
    out = np.empty((1, 2 * dec.shape[0], 2 * dec.shape[1], dec.shape[2] + nat.shape[2] // (p * p)), np.uint8)
    (sd, zd), (sn, zn), (sb, zb) = cut.up_q, cut.skip_q, cut.entry_q
    _upsample_concat(dec, nat, float(sd), zd, float(sn), zn, float(sb), zb, p, out)
    return out
