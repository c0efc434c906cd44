"""The output block's upsampling and concatenation out of the int8 network graph: graph
surgery.

The output block upsamples the U-Net's finest decoder features (bilinear, 2x) and
concatenates them with the input block's features before its 3x3 convolution. In the
int8 graph that is a DequantizeLinear of the u8 decoder features, a float Resize (a float
tensor of all their channels at native resolution), a QuantizeLinear and a
QLinearConcat: about 20 ms of a 47 ms output block at 1280x720 where the convolution runs
near the CPU's int8 peak (docs/design-notes.md, "The output block's glue"). ``cut_block``
cuts the graph there, in one file with two entries:

- from ``inputs``, the graph as before, with two more outputs: ``block.decoded`` and
  ``block.native``, the u8 tensors the block is made from, channels last (ONNX Runtime's
  NHWC int8 layout cancels the transposes);
- from ``block`` (u8, channels last, the concatenation as the convolution reads it), the
  output block: its convolution and the head.

``runtime.reformat.block_input`` makes ``block`` from the two outputs in one numba pass.
Each entry is an input with a default (an overridable initializer), so that a run can feed
one entry alone. ONNX Runtime runs every node of a graph on each run, whatever outputs it
is asked for, so each default is a frame of the smallest size the network takes: the half
a run does not need runs on it (both halves on their 8x8 defaults: 0.12 ms on the Zen 5 of
stop 48).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ..errors import CalibrationError
from ..runtime.head import HEAD
from ..runtime.reformat import BLOCK, BLOCK_KEY, DECODED, INPUTS, NATIVE, BlockLayout
from .head import save_extracted

RESIZE = "/network/output_block/Resize"
CONCAT = "/network/output_block/Concat"


def _single(nodes: list, what: str, src: Path):
    if len(nodes) != 1:
        raise CalibrationError(f"{src.name}: expected one {what}, found {len(nodes)}")
    return nodes[0]


def cut_block(src: Path, dst: Path, multiple: int) -> BlockLayout:
    """Write ``src`` (an int8 network graph or variant with u8 ``inputs`` and ``head``) cut at
    the output block's upsampling and concatenation, to ``dst`` (atomically); the three
    tensors' quantization goes into the graph's metadata. ``multiple``: the native sizes
    the network takes are multiples of it (``ModelConfig.pad_multiple``), the defaults'."""
    model = onnx.load(str(src))
    g = model.graph
    inits = {i.name: i for i in g.initializer}
    producers = {o: n for n in g.node for o in n.output}
    consumers: dict[str, list] = {}
    for n in g.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n)

    def qparams(node) -> tuple[float, int]:
        zp = numpy_helper.to_array(inits[node.input[2]])
        if zp.dtype != np.uint8:
            raise CalibrationError(f"{src.name}: {node.name} is {zp.dtype}, expected uint8")
        return float(numpy_helper.to_array(inits[node.input[1]])), int(zp)

    resize = _single([n for n in g.node if n.name == RESIZE], f"resize {RESIZE!r}", src)
    attrs = {a.name: helper.get_attribute_value(a) for a in resize.attribute}
    scales = resize.input[2] if len(resize.input) > 2 else ""
    factor = (numpy_helper.to_array(inits[scales]) if scales in inits
              else numpy_helper.to_array(producers[scales].attribute[0].t) if scales in producers else None)
    if (attrs.get("mode") != b"linear" or attrs.get("coordinate_transformation_mode") != b"half_pixel"
            or factor is None or list(factor) != [1, 1, 2, 2]):
        raise CalibrationError(f"{src.name}: {RESIZE} is not a 2x linear half-pixel resize ({attrs}, {factor})")
    dec_dq = producers.get(resize.input[0])
    concat = _single([n for n in g.node if n.name == CONCAT], f"concatenation {CONCAT!r}", src)
    nat_dq = producers.get(concat.input[1])
    up_q = _single(consumers.get(resize.output[0], []), "quantization of the resize", src)
    cat_q = _single(consumers.get(concat.output[0], []), "quantization of the concatenation", src)
    if (any(n is None or n.op_type != "DequantizeLinear" for n in (dec_dq, nat_dq))
            or up_q.op_type != "QuantizeLinear" or cat_q.op_type != "QuantizeLinear"
            or producers.get(concat.input[0]) is None
            or producers[concat.input[0]].input[0] != up_q.output[0]):
        raise CalibrationError(f"{src.name}: the output block's resize and concatenation are not quantized "
                               "as expected (DequantizeLinear, Resize, QuantizeLinear, Concat, QuantizeLinear)")
    layout = BlockLayout(qparams(dec_dq), qparams(nat_dq), qparams(cat_q))
    cat_dq = _single(consumers.get(cat_q.output[0], []), "dequantization of the concatenation", src)
    conv = _single([n for n in consumers.get(cat_dq.output[0], []) if n.op_type == "Conv"],
                   "convolution reading the concatenation", src)
    weights = producers.get(conv.input[1])
    if weights is None or weights.input[0] not in inits:
        raise CalibrationError(f"{src.name}: {conv.name}'s weights are not quantized initializers")
    width = int(numpy_helper.to_array(inits[weights.input[0]]).shape[1])
    prefix = CONCAT.rsplit("/", 1)[0]  # named in the output block (runtime.profile's stages)
    g.node.extend([
        helper.make_node("Transpose", [dec_dq.input[0]], [DECODED], name=f"{prefix}/decoded_Transpose", perm=[0, 2, 3, 1]),
        helper.make_node("Transpose", [nat_dq.input[0]], [NATIVE], name=f"{prefix}/native_Transpose", perm=[0, 2, 3, 1])])
    cat_dq.input[0] = f"{BLOCK}_nchw"  # the convolution reads the new entry
    g.node.insert(0, helper.make_node("Transpose", [BLOCK], [f"{BLOCK}_nchw"], name=f"{prefix}/block_Transpose",
                                      perm=[0, 3, 1, 2]))
    g.input.append(helper.make_tensor_value_info(BLOCK, onnx.TensorProto.UINT8, ["N", "H", "W", width]))
    g.output.extend([helper.make_tensor_value_info(n, onnx.TensorProto.UINT8, ["N", h, w, "C"])
                     for n, h, w in ((DECODED, "h", "w"), (NATIVE, "H", "W"))])
    outputs = [o.name for o in g.output]
    if HEAD not in outputs:
        raise CalibrationError(f"{src.name}: no u8 {HEAD!r} output to cut the output block from")
    entry = next((i for i in g.input if i.name == INPUTS), None)
    if entry is None:
        raise CalibrationError(f"{src.name}: no u8 {INPUTS!r} input (calibration.inputs first)")
    m = multiple
    defaults = {INPUTS: np.zeros((1, m, m, entry.type.tensor_type.shape.dim[3].dim_value), np.uint8),
                BLOCK: np.zeros((1, m, m, width), np.uint8)}
    save_extracted(model, dst, [INPUTS, BLOCK], outputs, {BLOCK_KEY: layout.to_json()}, defaults)
    return layout
