"""The output block's head in int8: one u8 tensor of every native kernel, decoded where
the filter stage reads it.

The int8 network graph (``calibration.head_ranges``) ends in the head's quantized 1x1
convolution: graph output ``head``, u8, (1, H, W, C) channels last, C padded to a
multiple of 16 for ONNX Runtime's fast int8 convolution. The float graph's split, clamp,
sigmoid and softmax nodes are not in it: ``Head.coded`` turns the channels in use to u8
planes (C', H, W) in one pass and hands each output on as a ``Coded`` part, which the
filter loops decode row by row (``runtime.filters``), reading a quarter of the bytes the
float outputs took; ``Coded.decode`` gives the float planes where a caller wants them.
Planes because each filter path reads a few channels of every pixel: channels last, each
path pulled the whole head through memory again and read its bytes one at a time; planes
are read once, contiguously, and their decoding vectorizes (measured at commit 5edddad).
The graph's metadata says which channels are which output and how each dequantizes
(``artifacts.layouts.HeadLayout``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..artifacts.layouts import HeadLayout
from ..errors import ArtifactError
from ..layout import HEAD_KINDS, head_kind
from .simd import transpose8x8

# a channel's kind as decode_row reads it: kernel 0 and relu 3 are computed in the loop (an
# affine map and a clamp vectorize), blend 1 (sigmoid) and normalized 2 (exp) looked up
_KIND_CODE = {k: i for i, k in enumerate(HEAD_KINDS)}


def tables(layout: HeadLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per channel of ``layout``: kind code, scale and offset (raw = q * scale + offset,
    float32), and a (channels, 256) table of the kind's function of every code (sigmoid;
    exp for the normalized kernels)."""
    kinds = np.array([_KIND_CODE[head_kind(n)] for n, c in layout.parts for _ in range(c)], np.int64)
    scale = np.array(layout.scale, np.float32)
    offset = (np.array(layout.centre, np.float64) - layout.zero_point * scale.astype(np.float64)).astype(np.float32)
    raw = np.arange(256, dtype=np.float32)[None] * scale[:, None] + offset[:, None]
    table = np.where(
        (kinds == _KIND_CODE["blend"])[:, None],
        1 / (1 + np.exp(-raw.astype(np.float64))),
        np.exp(raw.astype(np.float64)),
    )
    return kinds, scale, offset, table.astype(np.float32)


@njit(inline="always")
def decode_row(q, y, c0, n, kinds, scale, offset, table, out, r):
    """out[t, r, :] = plane c0 + t of the planar head q (C', H, W), row y, decoded (t < n):
    kernel taps clamped, features ReLU'd, blend weights through the sigmoid table,
    normalized kernels through the exp table and divided by their taps' sum."""
    w = q.shape[2]
    one = np.float32(1)
    for t in range(n):
        c = c0 + t
        k, s, o = kinds[c], scale[c], offset[c]
        src, dst = q[c, y], out[t, r]
        if k == 0:  # kernel
            for x in range(w):
                dst[x] = min(max(np.float32(src[x]) * s + o, -one), one)
        elif k == 3:  # relu
            for x in range(w):
                dst[x] = max(np.float32(src[x]) * s + o, np.float32(0))
        else:
            tab = table[c]
            for x in range(w):
                dst[x] = tab[src[x]]
    if kinds[c0] == 2:  # normalized
        for x in range(w):
            total = out[0, r, x]
            for t in range(1, n):
                total += out[t, r, x]
            inv = one / total
            for t in range(n):
                out[t, r, x] *= inv


@njit(parallel=True, cache=True)
def _decode(q, c0, kinds, scale, offset, table, out):
    for y in prange(q.shape[1]):
        decode_row(q, y, c0, out.shape[0], kinds, scale, offset, table, out, y)


@njit(parallel=True, cache=True)
def _planes(q, out):
    """out[c, y, x] = q[y, x, c] for the first out.shape[0] channels (a multiple of 8; q's
    channels too). Eight channels of eight pixels at a time: the eight 64-bit words (one a
    pixel) transposed as an 8x8 byte matrix (``transpose8x8``), stored as one word a channel;
    stored a byte at a time, the planes took longer (measured at commit 5edddad)."""
    H, W, C = q.shape
    n = out.shape[0] // 8
    G = np.uint64(C // 8)
    blocks = W // 8 if W % 8 == 0 else 0  # rows of whole words (8-byte aligned) only
    for y in prange(H):
        words = q[y].reshape(W * C).view(np.uint64)
        for g in range(n):
            c = 8 * g
            if blocks:
                d0, d1, d2, d3 = (
                    out[c, y].view(np.uint64),
                    out[c + 1, y].view(np.uint64),
                    out[c + 2, y].view(np.uint64),
                    out[c + 3, y].view(np.uint64),
                )
                d4, d5, d6, d7 = (
                    out[c + 4, y].view(np.uint64),
                    out[c + 5, y].view(np.uint64),
                    out[c + 6, y].view(np.uint64),
                    out[c + 7, y].view(np.uint64),
                )
            # unsigned indices: numba wraps negative signed ones, a test and an add a load
            for b in range(np.uint64(blocks)):
                i = np.uint64(8) * b * G + np.uint64(g)
                (d0[b], d1[b], d2[b], d3[b], d4[b], d5[b], d6[b], d7[b]) = transpose8x8(
                    words[i],
                    words[i + G],
                    words[i + np.uint64(2) * G],
                    words[i + np.uint64(3) * G],
                    words[i + np.uint64(4) * G],
                    words[i + np.uint64(5) * G],
                    words[i + np.uint64(6) * G],
                    words[i + np.uint64(7) * G],
                )
            for x in range(8 * blocks, W):
                for t in range(8):
                    out[c + t, y, x] = q[y, x, c + t]


class Head:
    """A layout's tables, built once per graph: decodes one frame's u8 head."""

    def __init__(self, layout: HeadLayout):
        self.layout = layout
        self.kinds, self.scale, self.offset, self.table = tables(layout)
        self.slices, c0 = {}, 0
        for name, c in layout.parts:
            self.slices[name] = (c0, c)
            c0 += c

    def _check(self, q: np.ndarray) -> np.ndarray:
        q = q[0] if q.ndim == 4 else q
        if q.dtype != np.uint8 or q.ndim != 3 or q.shape[2] != self.layout.channels:
            raise ArtifactError(f"head: expected u8 (H, W, {self.layout.channels}), got {q.dtype} {q.shape}")
        return np.ascontiguousarray(q)

    def coded(self, q: np.ndarray) -> dict[str, "Coded"]:
        """Every output of the u8 head, still coded, from planes of the channels in use:
        the filter stage decodes each row where it reads it (``runtime.filters``)."""
        q = self._check(q)
        used = sum(c for _, c in self.layout.parts)
        if q.shape[2] % 8:  # no layout here has one; planes by numpy's strided copy
            planes = np.ascontiguousarray(q[:, :, :used].transpose(2, 0, 1))
        else:  # whole groups of 8 (the tensor's channels are)
            planes = np.empty((-(-used // 8) * 8, q.shape[0], q.shape[1]), np.uint8)
            _planes(q, planes)
        return {name: Coded(planes, c0, c, self) for name, (c0, c) in self.slices.items()}

    def planar(self, q: np.ndarray) -> dict[str, "Coded"]:
        """Every output of a u8 level head given as planes, (1, C, h, w) or (C, h, w): no copy."""
        q = q[0] if q.ndim == 4 else q
        if q.dtype != np.uint8 or q.ndim != 3 or q.shape[0] != self.layout.channels:
            raise ArtifactError(f"level head: expected u8 ({self.layout.channels}, h, w), got {q.dtype} {q.shape}")
        q = np.ascontiguousarray(q)
        return {name: Coded(q, c0, c, self) for name, (c0, c) in self.slices.items()}


@dataclass(frozen=True)
class Coded:
    """Planes ``c0 .. c0 + n`` of a u8 head's planes (C', H, W): one network output, not decoded."""

    q: np.ndarray
    c0: int
    n: int
    head: Head

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.n, self.q.shape[1], self.q.shape[2])

    def decode(self) -> np.ndarray:
        """(n, H, W) float32: the values the float graph's nodes compute (within the head's
        quantization)."""
        out = np.empty(self.shape, np.float32)
        h = self.head
        _decode(self.q, self.c0, h.kinds, h.scale, h.offset, h.table, out)
        return out
