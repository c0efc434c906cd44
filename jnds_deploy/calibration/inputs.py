"""The input block's preprocessing out of the int8 network graph: graph surgery.

In the float graph the input block tonemaps the radiance layers (Eq. 1), maps the normals
to [0, 1] and concatenates current and history (``model.tonemap_inputs``), all in float
at native resolution, per channel group: a Slice, Clip, Log, Exp, a QuantizeLinear for
each of 9 groups, a QLinearConcat of 25 channels and a transpose to channels last for the
first int8 convolution (what they cost: docs/performance.md). ``quantize_inputs`` cuts
them off: the int8 graph's input is ``inputs``, u8 (N, H, W, ``CHANNELS``), the
preprocessed inputs already quantized at the scale and zero point the projection
convolution reads them with, channels last, padded to a multiple of 8 (MLAS's fast int8
convolution wants input channels in multiples of 4; the padding's weights are 0).
``runtime.reformat.pack_inputs`` computes it in one pass over the frame.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ..errors import CalibrationError
from ..layout import N_CURRENT, N_HISTORY
from ..runtime.reformat import INPUTS, INPUTS_KEY, InputsLayout
from .head import save_extracted

PROJECT = "/network/input_block/project/Conv"
CHANNELS = 32  # N_CURRENT + N_HISTORY = 25, padded


def quantize_inputs(src: Path, dst: Path) -> InputsLayout:
    """Write ``src`` (an int8 network graph or variant, inputs ``current`` and ``history``
    float) with the u8 NHWC input ``inputs`` in their place, to ``dst`` (atomically); the
    input's scale and zero point go into the graph's metadata."""
    model = onnx.load(str(src))
    g = model.graph
    conv = next((n for n in g.node if n.name == PROJECT), None)
    producers = {o: n for n in g.node for o in n.output}
    inits = {i.name: i for i in g.initializer}
    x_dq = producers.get(conv.input[0]) if conv is not None else None
    w_dq = producers.get(conv.input[1]) if conv is not None else None
    if x_dq is None or x_dq.op_type != "DequantizeLinear" or w_dq is None or w_dq.op_type != "DequantizeLinear":
        raise CalibrationError(f"{src.name}: no quantized input projection {PROJECT!r}")
    scale = float(numpy_helper.to_array(inits[x_dq.input[1]]))
    zp = numpy_helper.to_array(inits[x_dq.input[2]])
    if zp.dtype != np.uint8:
        raise CalibrationError(f"{src.name}: the input projection reads {zp.dtype} activations, expected uint8")
    w = numpy_helper.to_array(inits[w_dq.input[0]])
    if w.shape[1] != N_CURRENT + N_HISTORY:
        raise CalibrationError(f"{src.name}: the input projection has {w.shape[1]} input channels, "
                               f"expected {N_CURRENT + N_HISTORY}")
    w = np.concatenate([w, np.zeros((w.shape[0], CHANNELS - w.shape[1], *w.shape[2:]), w.dtype)], 1)
    g.initializer.append(numpy_helper.from_array(w, w_dq.input[0] + "_padded"))
    w_dq.input[0] += "_padded"
    prefix = PROJECT.rsplit("/", 2)[0]  # named in the input block (runtime.profile's stages)
    at = list(g.node).index(x_dq)
    g.node.insert(at, helper.make_node("DequantizeLinear", [f"{INPUTS}_nchw", x_dq.input[1], x_dq.input[2]],
                                       [conv.input[0] + "_packed"], name=f"{prefix}/inputs_DequantizeLinear"))
    g.node.insert(at, helper.make_node("Transpose", [INPUTS], [f"{INPUTS}_nchw"], name=f"{prefix}/inputs_Transpose",
                                       perm=[0, 3, 1, 2]))
    conv.input[0] += "_packed"
    g.input.append(helper.make_tensor_value_info(INPUTS, onnx.TensorProto.UINT8, ["N", "H", "W", CHANNELS]))
    layout = InputsLayout(scale, int(zp), CHANNELS)
    save_extracted(model, dst, [INPUTS], [o.name for o in g.output], {INPUTS_KEY: layout.to_json()})
    return layout
