"""The input block's preprocessing out of the int8 network graph: graph surgery.

In the float graph the input block tonemaps the radiance layers (Eq. 1), maps the normals
to [0, 1] and concatenates current and history (``model.tonemap_inputs``), all in float
at native resolution, per channel group: a Slice, Clip, Log, Exp, a QuantizeLinear for
each of 9 groups, a QLinearConcat of 25 channels and a transpose to channels last for the
first int8 convolution (what they cost: commit 14d0c4c). ``quantize_inputs`` cuts
them off: the int8 graph's input is ``inputs``, u8 (N, H, W, ``CHANNELS``), the
preprocessed inputs already quantized at the scale and zero point the projection
convolution reads them with, channels last, padded to a multiple of 8 (MLAS's fast int8
convolution wants input channels in multiples of 4; the padding's weights are 0).
``runtime.reformat.pack_inputs`` computes it in one pass over the frame; its layout is
``artifacts.layouts.InputsLayout``. A space-to-depth input block (``model.InputBlock``)
projects each 2x2 block of pixels: its ``inputs`` is (N, H/2, W/2, 104), the four pixels
of each channel side by side (``InputsLayout.block``).

The channels are placed so that no two neighbours can overflow a 16-bit sum
(``safe_slots``): on AVX2 without VNNI, MLAS multiplies u8 activations by s8 weights with
``vpmaddubsw``, which adds the products of channels 2j and 2j+1 into a saturating 16-bit
integer. The radiance channels reach code 255 on bright frames, and in their first order two
of them with large weights of one sign overflowed: the int8 graph lost to fp32 on bright
frames (measured at commit 84b3903). Where no such placement exists the channels keep their
order.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ..artifacts.layouts import INPUTS, INPUTS_KEY, InputsLayout, preprocess
from ..errors import ArtifactError, CalibrationError
from ..layout import HDR_MAX, N_CURRENT, N_HISTORY
from .rewrite import extracted

PROJECT = "/network/input_block/project/Conv"
CHANNELS = 32  # N_CURRENT + N_HISTORY = 25 (+ N_GUIDE = 28 with the guide albedo), padded


def quantize_inputs(model: onnx.ModelProto, label: str = "the graph") -> onnx.ModelProto:
    """``model`` (an int8 network graph or variant, inputs ``current`` and ``history``
    float; changed) with the u8 NHWC input ``inputs`` in their place; its layout
    (``InputsLayout``) in the graph's metadata. ``label`` names the graph in errors."""
    g = model.graph
    conv = next((n for n in g.node if n.name == PROJECT), None)
    producers = {o: n for n in g.node for o in n.output}
    inits = {i.name: i for i in g.initializer}
    x_dq = producers.get(conv.input[0]) if conv is not None else None
    w_dq = producers.get(conv.input[1]) if conv is not None else None
    if x_dq is None or x_dq.op_type != "DequantizeLinear" or w_dq is None or w_dq.op_type != "DequantizeLinear":
        raise CalibrationError(f"{label}: no quantized input projection {PROJECT!r}")
    scale = float(numpy_helper.to_array(inits[x_dq.input[1]]))
    zp = numpy_helper.to_array(inits[x_dq.input[2]])
    if zp.dtype != np.uint8:
        raise CalibrationError(f"{label}: the input projection reads {zp.dtype} activations, expected uint8")
    w = numpy_helper.to_array(inits[w_dq.input[0]])
    # a space-to-depth input block (model.InputBlock) projects 2x2 blocks: 4x the channels
    block = 2 if w.shape[1] > CHANNELS else 1
    channels = -(-w.shape[1] // 8) * 8 if block == 2 else CHANNELS
    try:  # safe_slots refuses a projection of neither 25 nor 28 inputs, or 4x (layouts.preprocess)
        slots = safe_slots(w[:, :, 0, 0], scale, int(zp), channels)
    except ArtifactError as e:
        raise CalibrationError(f"{label}: {e}") from e
    padded = np.zeros((w.shape[0], channels, *w.shape[2:]), w.dtype)
    padded[:, slots] = w
    w = padded
    g.initializer.append(numpy_helper.from_array(w, w_dq.input[0] + "_padded"))
    w_dq.input[0] += "_padded"
    prefix = PROJECT.rsplit("/", 2)[0]  # named in the input block (runtime.profile's stages)
    at = list(g.node).index(x_dq)
    g.node.insert(
        at,
        helper.make_node(
            "DequantizeLinear",
            [f"{INPUTS}_nchw", x_dq.input[1], x_dq.input[2]],
            [conv.input[0] + "_packed"],
            name=f"{prefix}/inputs_DequantizeLinear",
        ),
    )
    g.node.insert(
        at,
        helper.make_node(
            "Transpose", [INPUTS], [f"{INPUTS}_nchw"], name=f"{prefix}/inputs_Transpose", perm=[0, 3, 1, 2]
        ),
    )
    conv.input[0] += "_packed"
    g.input.append(helper.make_tensor_value_info(INPUTS, onnx.TensorProto.UINT8, ["N", "H", "W", channels]))
    layout = InputsLayout(scale, int(zp), channels, tuple(slots), block)
    return extracted(model, [INPUTS], [o.name for o in g.output], {INPUTS_KEY: layout.to_json()})


I16 = (-32768, 32767)


def code_bounds(scale: float, zero_point: int, kinds: np.ndarray | None = None) -> np.ndarray:
    """The largest u8 code each of current and history's channels (``kinds``, from
    ``artifacts.layouts.preprocess``; current and history's by default) can take in
    ``inputs``: radiance through Eq. 1's tonemap up to HDR_MAX, the other layers (albedo,
    roughness, normals mapped to [0, 1], the guide albedo) up to 1; the inputs are clamped to
    these ranges on reading."""
    kinds = preprocess(N_CURRENT + N_HISTORY) if kinds is None else kinds
    top = np.where(kinds == 1, np.log1p(HDR_MAX) ** (1 / 2.2), 1.0)
    return np.minimum(np.ceil(top / scale) + zero_point, 255).astype(np.int64)


def safe_slots(w: np.ndarray, scale: float, zero_point: int, channels: int = CHANNELS) -> list[int]:
    """A slot in ``channels`` for each input channel of the projection's int8 weights ``w``
    (out, in), such that for every output the products of the two channels of each slot pair
    (2j, 2j+1) sum within a 16-bit integer at any codes up to ``code_bounds``; a padding slot
    (weights 0) is safe beside any channel. A perfect matching found by backtracking from the
    channel with the fewest safe partners (written here: 25 channels, found at once for the
    shipped weights). The identity order if there is none."""
    w = w.astype(np.int64)
    a = code_bounds(scale, zero_point, preprocess(w.shape[1]))
    hi, lo = np.maximum(w, 0) * a, np.minimum(w, 0) * a  # (out, in): the extremes of each product
    n, pads = w.shape[1], channels - w.shape[1]
    safe = ((hi[:, :, None] + hi[:, None, :]).max(0) <= I16[1]) & ((lo[:, :, None] + lo[:, None, :]).min(0) >= I16[0])
    np.fill_diagonal(safe, False)

    def match(left: list[int], pads: int) -> list[tuple[int, int]] | None:
        """Pairs (channel, partner or -1 for a padding slot) covering ``left``, or None."""
        if not left:
            return []  # the padding left over fills whole pairs: n + pads is even
        c = min(left, key=lambda c: int(safe[c, left].sum()))
        partners = [d for d in left if safe[c, d]]
        # a padding slot first while there is padding to spare, a partner channel first after
        tries = ([-1] + partners) if pads > len(left) // 2 else (partners + [-1])
        for d in tries:
            if d < 0 and not pads:
                continue
            rest = match([e for e in left if e not in (c, d)], pads - (d < 0))
            if rest is not None:
                return [(c, d)] + rest
        return None

    pairs = match(list(range(n)), pads)
    if pairs is None:
        return list(range(n))
    slots = [0] * n
    for j, (c, d) in enumerate(pairs):
        slots[c] = 2 * j
        if d >= 0:
            slots[d] = 2 * j + 1
    return slots
