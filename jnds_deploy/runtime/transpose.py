"""An 8x8 byte transpose for numba loops, as one vector shuffle.

Channels-last u8 tensors and planes meet twice a frame: the input packing writes each
pixel's channels together (``reformat._store_pixels``), the head's decoding reads each
channel's plane (``head._planes``). Both move eight channels of eight pixels at a time:
eight 64-bit words in, the 8x8 byte matrix they make transposed, eight words out.

numba has no byte shuffle, and written as shifts and masks in 64-bit registers the transpose
took 12 swaps of 6 integer instructions each. ``transpose8x8`` is written here by hand in
LLVM IR (an ``@intrinsic``): the eight words as one 64-byte vector, one ``shufflevector``,
the eight words back, which LLVM lowers for the CPU numba compiles for (one ``vpermt2b``
with AVX-512 VBMI; byte shuffles and unpacks with AVX2). The transpose is its own inverse.
Timings: docs/performance.md, stop 75.
"""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

_WORDS = types.UniTuple(types.uint64, 8)
# byte p of word t out is byte t of word p in (x86 is little-endian: byte k of a word is
# bits 8k..8k+7)
_MASK = [(j % 8) * 8 + j // 8 for j in range(64)]


@intrinsic
def transpose8x8(typingctx, a0, a1, a2, a3, a4, a5, a6, a7):
    """(a0, ..., a7) uint64 -> (b0, ..., b7): byte p of b_t is byte t of a_p."""
    if not all(a == types.uint64 for a in (a0, a1, a2, a3, a4, a5, a6, a7)):
        return None
    sig = _WORDS(*([types.uint64] * 8))

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        v = ir.Constant(ir.VectorType(ir.IntType(64), 8), ir.Undefined)
        for k, a in enumerate(args):
            v = builder.insert_element(v, a, ir.Constant(i32, k))
        b = builder.bitcast(v, ir.VectorType(ir.IntType(8), 64))
        t = builder.shuffle_vector(b, b, ir.Constant(ir.VectorType(i32, 64), _MASK))
        w = builder.bitcast(t, ir.VectorType(ir.IntType(64), 8))
        out = [builder.extract_element(w, ir.Constant(i32, k)) for k in range(8)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen
