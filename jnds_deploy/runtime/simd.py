"""Vector primitives for numba loops, written by hand in LLVM IR (``@intrinsic``s) where
numba's loop vectorizer does not find them.

Three kinds of loop kept scalar work that the CPU could do 16 or 64 bytes at a time:

- The 8x8 byte transposes between channels-last u8 tensors and planes: the input packing
  writes each pixel's channels together (``reformat._store_pixels``), the head's decoding
  reads each channel's plane (``head._planes``). numba has no byte shuffle, and written as
  shifts and masks in 64-bit registers the transpose took 12 swaps of 6 integer
  instructions each. ``transpose8x8`` is one ``shufflevector`` of the eight words as a
  64-byte vector.
- The requantization of short runs of channels inside a pixel, as the int8 graph's cuts do
  (``reformat._upsample_concat``): a loop over a pixel's 48 or 16 channels is vectorized by
  LLVM only behind a runtime test that its output does not overlap its inputs, repeated at
  every pixel, with remainder loops. ``lerp_codes16`` and ``requantize16`` load 16 values,
  compute and store 16 codes with no test: the caller guarantees that the 16 values exist
  and that the output does not overlap them.
- The input packing's tonemap through tables (``reformat._tonemap_codes``): numba kept the
  table loads scalar. ``binned_codes16`` reads 16 values' entries by two gathers.

LLVM lowers them for the CPU numba compiles for (``vpermt2b`` with AVX-512 VBMI, byte
shuffles and unpacks with AVX2; 512-bit or two 256-bit vectors). Each computes what its
scalar form computes, bit for bit (tests/runtime/test_head.py, test_reformat.py). Why each
is hand-written: docs/architecture.md, "The filter stage"; what they bought: the record in
docs/performance.md at commit 5431ce1.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_I8, _I32, _F32 = ir.IntType(8), ir.IntType(32), ir.FloatType()
_WORDS = types.UniTuple(types.uint64, 8)
# byte p of word t out is byte t of word p in (x86 is little-endian: byte k of a word is
# bits 8k..8k+7)
_MASK = [(j % 8) * 8 + j // 8 for j in range(64)]
N = 16  # values per lerp_codes16 / requantize16
_V = ir.VectorType(_F32, N)


@intrinsic
def transpose8x8(typingctx, a0, a1, a2, a3, a4, a5, a6, a7):
    """(a0, ..., a7) uint64 -> (b0, ..., b7): byte p of b_t is byte t of a_p. Its own inverse."""
    if not all(a == types.uint64 for a in (a0, a1, a2, a3, a4, a5, a6, a7)):
        return None
    sig = _WORDS(*([types.uint64] * 8))

    def codegen(context, builder, signature, args):
        v = ir.Constant(ir.VectorType(ir.IntType(64), 8), ir.Undefined)
        for k, a in enumerate(args):
            v = builder.insert_element(v, a, ir.Constant(_I32, k))
        b = builder.bitcast(v, ir.VectorType(_I8, 64))
        t = builder.shuffle_vector(b, b, ir.Constant(ir.VectorType(_I32, 64), _MASK))
        w = builder.bitcast(t, ir.VectorType(ir.IntType(64), 8))
        out = [builder.extract_element(w, ir.Constant(_I32, k)) for k in range(8)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen


def _vector_at(context, builder, aryty, ary, index, element):
    """A pointer to the N values of 1-d ``ary`` from ``index`` on, as a vector."""
    a = context.make_array(aryty)(context, builder, ary)
    p = cgutils.get_item_pointer(context, builder, aryty, a, [index], wraparound=False)
    return builder.bitcast(p, ir.PointerType(ir.VectorType(element, N)))


def _splat(builder, x):
    v = builder.insert_element(ir.Constant(_V, ir.Undefined), x, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(_I32, N), [0] * N))


def _store_codes(builder, v, z, k, zb, ptr):
    """Store u8(min(max(rint((v - z) * k) + zb, 0), 255)) of the float vector v at ptr:
    QuantizeLinear's rounding (to nearest, ties to even) and saturation."""
    rint = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_V, [_V]), f"llvm.rint.v{N}f32")
    x = builder.fmul(builder.fsub(v, _splat(builder, z)), _splat(builder, k))
    x = builder.fadd(builder.call(rint, [x]), _splat(builder, zb))
    lo, hi = ir.Constant(_V, [0.0] * N), ir.Constant(_V, [255.0] * N)
    x = builder.select(builder.fcmp_ordered("<", x, lo), lo, x)
    x = builder.select(builder.fcmp_ordered(">", x, hi), hi, x)
    builder.store(builder.trunc(builder.fptosi(x, ir.VectorType(_I32, N)), ir.VectorType(_I8, N)), ptr, align=1)


def _is_1d(t, dtype) -> bool:
    return isinstance(t, types.Array) and t.ndim == 1 and t.layout == "C" and t.dtype == dtype


@intrinsic
def lerp_codes16(typingctx, a, ia, b, ib, wa, wb, z, k, zb, out, j):
    """out[j + n] = u8(min(max(rint((wa * a[ia + n] + wb * b[ib + n] - z) * k) + zb, 0), 255))
    for n < 16: float32 ``a``, ``b``, u8 ``out``, all 1-d and contiguous; float32 scalars (no fused
    multiply-add: the products are rounded as numba rounds them)."""
    if not (
        _is_1d(a, types.float32)
        and _is_1d(b, types.float32)
        and _is_1d(out, types.uint8)
        and all(t == types.float32 for t in (wa, wb, z, k, zb))
    ):
        return None
    sig = types.void(a, ia, b, ib, wa, wb, z, k, zb, out, j)

    def codegen(context, builder, signature, args):
        a_, ia_, b_, ib_, wa_, wb_, z_, k_, zb_, out_, j_ = args
        ta, _, tb, _, _, _, _, _, _, to, _ = signature.args
        va = builder.load(_vector_at(context, builder, ta, a_, ia_, _F32), align=4)
        vb = builder.load(_vector_at(context, builder, tb, b_, ib_, _F32), align=4)
        v = builder.fadd(builder.fmul(_splat(builder, wa_), va), builder.fmul(_splat(builder, wb_), vb))
        _store_codes(builder, v, z_, k_, zb_, _vector_at(context, builder, to, out_, j_, _I8))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def requantize16(typingctx, src, i, z, k, zb, out, j):
    """out[j + n] = u8(min(max(rint((src[i + n] - z) * k) + zb, 0), 255)) for n < 16: u8
    ``src`` and ``out``, 1-d and contiguous; float32 scalars."""
    if not (_is_1d(src, types.uint8) and _is_1d(out, types.uint8) and all(t == types.float32 for t in (z, k, zb))):
        return None
    sig = types.void(src, i, z, k, zb, out, j)

    def codegen(context, builder, signature, args):
        s_, i_, z_, k_, zb_, out_, j_ = args
        ts, _, _, _, _, to, _ = signature.args
        v = builder.uitofp(builder.load(_vector_at(context, builder, ts, s_, i_, _I8), align=1), _V)
        _store_codes(builder, v, z_, k_, zb_, _vector_at(context, builder, to, out_, j_, _I8))
        return context.get_dummy_value()

    return sig, codegen


def _splat_i64(builder, x):
    v = builder.insert_element(ir.Constant(ir.VectorType(ir.IntType(64), N), ir.Undefined), x, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(_I32, N), [0] * N))


def _gather(builder, base, index, element):
    """The N values of 4-byte ``element`` at ``base`` + ``index`` (an <N x i32> of
    non-negative indices): one ``llvm.masked.gather``, which LLVM lowers to vector gathers
    (``vpgatherdd``, ``vgatherdps``: with AVX-512, and with AVX2 for a Zen 3 too) or, on a
    CPU without them, to loads one at a time."""
    i64 = ir.VectorType(ir.IntType(64), N)
    ptrs = ir.VectorType(element.as_pointer(), N)
    offset = builder.mul(builder.zext(index, i64), ir.Constant(i64, [4] * N))
    addr = builder.inttoptr(builder.add(_splat_i64(builder, builder.ptrtoint(base, ir.IntType(64))), offset), ptrs)
    vt, mask = ir.VectorType(element, N), ir.VectorType(ir.IntType(1), N)
    kind = "i32" if element == _I32 else "f32"
    fn = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(vt, [ptrs, _I32, mask, vt]), f"llvm.masked.gather.v{N}{kind}.v{N}p0"
    )
    return builder.call(fn, [addr, ir.Constant(_I32, 4), ir.Constant(mask, [1] * N), ir.Constant(vt, ir.Undefined)])


@intrinsic
def binned_codes16(typingctx, src, i, first, step, top, out, j):
    """out[j + n] = u8(first[b] + (v >= step[b])) for n < 16, v = min(max(src[i + n], 0), top)
    and b its bin, the top 17 bits of its float32 with the sign cleared (``v.view(uint32) &
    0x7FFFFFFF) >> 15``): ``reformat._tonemap_codes``' tables, read by two gathers. float32
    ``src`` and ``step``, int32 ``first``, u8 ``out``, all 1-d and contiguous."""
    if not (
        _is_1d(src, types.float32)
        and _is_1d(first, types.int32)
        and _is_1d(step, types.float32)
        and _is_1d(out, types.uint8)
        and top == types.float32
    ):
        return None
    sig = types.void(src, i, first, step, top, out, j)

    def codegen(context, builder, signature, args):
        s_, i_, f_, t_, top_, o_, j_ = args
        ts, _, tf, tt, _, to, _ = signature.args
        v = builder.load(_vector_at(context, builder, ts, s_, i_, _F32), align=4)
        zero = ir.Constant(_V, [0.0] * N)
        v = builder.select(builder.fcmp_ordered("<", v, zero), zero, v)  # -0.0 stays: its bin is 0's
        cap = _splat(builder, top_)
        v = builder.select(builder.fcmp_ordered(">", v, cap), cap, v)
        vi = ir.VectorType(_I32, N)
        bins = builder.lshr(
            builder.and_(builder.bitcast(v, vi), ir.Constant(vi, [0x7FFFFFFF] * N)), ir.Constant(vi, [15] * N)
        )
        q = _gather(builder, context.make_array(tf)(context, builder, f_).data, bins, _I32)
        t = _gather(builder, context.make_array(tt)(context, builder, t_).data, bins, _F32)
        q = builder.add(q, builder.zext(builder.fcmp_ordered(">=", v, t), vi))
        builder.store(builder.trunc(q, ir.VectorType(_I8, N)), _vector_at(context, builder, to, o_, j_, _I8), align=1)
        return context.get_dummy_value()

    return sig, codegen
