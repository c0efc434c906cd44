"""Upsamplings and concatenations out of the int8 network graph: graph surgery.

The U-Net's decoder blocks and the output block each upsample coarser features (bilinear,
2x) and concatenate them with a skip connection before a 3x3 convolution. In the int8
graph each is a DequantizeLinear of the u8 features, a float Resize (a float tensor of
all their channels at the finer resolution), a QuantizeLinear and a QLinearConcat: in the
output block a large share of its time, where its convolution runs near the CPU's int8
peak (measured at commit 972a32d). ``cut_blocks`` cuts the graph at those of ``CUT_AT``
(all of them), in one file with an entry per segment:

- from ``inputs``, the graph up to the first cut; from each cut's entry ``block.<k>`` (u8,
  channels last, the concatenation as its convolution reads it), the graph up to the next
  cut, the last one ending in the head;
- each cut's two u8 tensors become graph outputs, ``block.<k>.up`` and ``block.<k>.skip``,
  channels last (ONNX Runtime's NHWC int8 layout cancels the transposes).

``runtime.reformat.block_input`` makes each entry from its two outputs in one numba pass,
between the segments' runs (``runtime.network.Edges.run``); the cuts and the segments are
``artifacts.layouts.BlockLayout``. Each entry is an input with a default (an overridable
initializer), so that a run can feed one entry alone. ONNX Runtime runs every node of a
graph on each run, whatever outputs it is asked for, so each default is a frame of the
smallest size the network takes: the segments a run does not need run on them, at a cost
small against a frame's (measured at commit 77cc4c7).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ..artifacts.layouts import BLOCK_KEY, HEAD, INPUTS, BlockLayout, Cut
from ..errors import CalibrationError
from ..runtime.profile import stage_of
from .rewrite import extracted

# where the cuts are: the output block's and the feature extractor's decoder blocks'. The
# decoder blocks' cuts pay since their numba passes take 16 channels at a time (runtime.simd):
# before, the passes and the extra runs cost what the ONNX Runtime glue they took out had
# (measured at commits 972a32d and 070fb33)
CUT_AT = ("/network/output_block/", "/network/feature_extractor/")


def _single(nodes: list, what: str, label: str):
    if len(nodes) != 1:
        raise CalibrationError(f"{label}: expected one {what}, found {len(nodes)}")
    return nodes[0]


def cut_blocks(model: onnx.ModelProto, multiple: int, label: str = "the graph") -> onnx.ModelProto:
    """``model`` (an int8 network graph or variant with u8 ``inputs`` and ``head``; changed)
    cut at every upsampling + concatenation of the feature extractor and the output block;
    the cuts' quantization and the segments (``BlockLayout``) in the graph's metadata.
    ``multiple``: the native sizes the network takes are multiples of it
    (``ModelConfig.pad_multiple``), the defaults'. ``label`` names the graph in errors."""
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
            raise CalibrationError(f"{label}: {node.name} is {zp.dtype}, expected uint8")
        return float(numpy_helper.to_array(inits[node.input[1]])), int(zp)

    if HEAD not in [o.name for o in g.output]:
        raise CalibrationError(f"{label}: no u8 {HEAD!r} output to cut the output block from")
    entry_in = next((i for i in g.input if i.name == INPUTS), None)
    if entry_in is None:
        raise CalibrationError(f"{label}: no u8 {INPUTS!r} input (calibration.inputs first)")
    resizes = [n for n in g.node if n.op_type == "Resize" and n.name.startswith(CUT_AT)]
    if not resizes:
        raise CalibrationError(f"{label}: no Resize in {', '.join(CUT_AT)} to cut at")
    cuts, added, defaults = [], [], {}
    m = multiple
    for k, resize in enumerate(resizes, 1):  # graph order: the coarsest decoder first
        attrs = {a.name: helper.get_attribute_value(a) for a in resize.attribute}
        scales = resize.input[2] if len(resize.input) > 2 else ""
        factor = (
            numpy_helper.to_array(inits[scales])
            if scales in inits
            else numpy_helper.to_array(producers[scales].attribute[0].t)
            if scales in producers
            else None
        )
        if (
            attrs.get("mode") != b"linear"
            or attrs.get("coordinate_transformation_mode") != b"half_pixel"
            or factor is None
            or list(factor) != [1, 1, 2, 2]
        ):
            raise CalibrationError(f"{label}: {resize.name} is not a 2x linear half-pixel resize")
        up_dq = producers.get(resize.input[0])
        up_q = _single(consumers.get(resize.output[0], []), f"quantization of {resize.name}", label)
        up_dq2 = _single(consumers.get(up_q.output[0], []), f"dequantization of {resize.name}", label)
        concat = _single(consumers.get(up_dq2.output[0], []), f"concatenation of {resize.name}", label)
        if concat.op_type != "Concat" or len(concat.input) != 2 or concat.input[0] != up_dq2.output[0]:
            raise CalibrationError(f"{label}: {resize.name} does not feed a concatenation as its first input")
        skip_dq = producers.get(concat.input[1])
        skip_q = producers.get(skip_dq.input[0]) if skip_dq is not None else None
        d2s = producers.get(skip_q.input[0]) if skip_q is not None and skip_q.op_type == "QuantizeLinear" else None
        phases = 1
        if d2s is not None and d2s.op_type == "DepthToSpace":
            # a space-to-depth input block's native features (model.InputBlock): their u8
            # phases leave the graph as they are, and block_input's pass does the
            # depth-to-space (a float one in the graph, between a dequantization and a
            # quantization of every feature)
            attrs = {a.name: helper.get_attribute_value(a) for a in d2s.attribute}
            skip_dq, phases = producers.get(d2s.input[0]), 2
            if attrs.get("blocksize") != 2 or attrs.get("mode", b"DCR") != b"CRD" or skip_dq is None:
                raise CalibrationError(
                    f"{label}: {d2s.name} is not a quantized 2x2 depth-to-space (CRD, pixel_shuffle's order)"
                )
            _phase_first(skip_dq.input[0], d2s, inits, producers, consumers, label)
        cat_q = _single(consumers.get(concat.output[0], []), f"quantization of {concat.name}", label)
        cat_dq = _single(consumers.get(cat_q.output[0], []), f"dequantization of {concat.name}", label)
        if (
            any(n is None or n.op_type != "DequantizeLinear" for n in (up_dq, skip_dq, up_dq2, cat_dq))
            or up_q.op_type != "QuantizeLinear"
            or cat_q.op_type != "QuantizeLinear"
        ):
            raise CalibrationError(
                f"{label}: {resize.name} and {concat.name} are not quantized as expected "
                "(DequantizeLinear, Resize, QuantizeLinear, Concat, QuantizeLinear)"
            )
        conv = _single(
            [n for n in consumers.get(cat_dq.output[0], []) if n.op_type == "Conv"],
            f"convolution reading {concat.name}",
            label,
        )
        weights = producers.get(conv.input[1])
        if weights is None or weights.input[0] not in inits:
            raise CalibrationError(f"{label}: {conv.name}'s weights are not quantized initializers")
        width = int(numpy_helper.to_array(inits[weights.input[0]]).shape[1])
        entry = f"block.{k}"
        cut = Cut(
            entry,
            f"{entry}.up",
            f"{entry}.skip",
            qparams(up_dq),
            qparams(skip_dq),
            qparams(cat_q),
            stage_of(concat.name),
            phases,
        )
        prefix = concat.name.rsplit("/", 1)[0]  # named in its stage (runtime.profile's stages)
        added += [
            helper.make_node(
                "Transpose", [up_dq.input[0]], [cut.up], name=f"{prefix}/{cut.up}_Transpose", perm=[0, 2, 3, 1]
            ),
            helper.make_node(
                "Transpose", [skip_dq.input[0]], [cut.skip], name=f"{prefix}/{cut.skip}_Transpose", perm=[0, 2, 3, 1]
            ),
        ]
        cat_dq.input[0] = f"{entry}_nchw"  # the convolution reads the new entry
        g.node.insert(
            0,
            helper.make_node(
                "Transpose", [entry], [f"{entry}_nchw"], name=f"{prefix}/{entry}_Transpose", perm=[0, 3, 1, 2]
            ),
        )
        g.input.append(helper.make_tensor_value_info(entry, onnx.TensorProto.UINT8, ["N", f"H{k}", f"W{k}", width]))
        g.output.extend(
            [helper.make_tensor_value_info(n, onnx.TensorProto.UINT8, ["N", "h", "w", "C"]) for n in (cut.up, cut.skip)]
        )
        defaults[entry] = np.zeros((1, m, m, width), np.uint8)
        cuts.append(cut)
    g.node.extend(added)
    defaults[INPUTS] = np.zeros((1, m, m, entry_in.type.tensor_type.shape.dim[3].dim_value), np.uint8)
    entries = [INPUTS] + [c.entry for c in cuts]
    outputs = [o.name for o in g.output]
    layout = BlockLayout(tuple(cuts), tuple((e, tuple(_reached(g, e, outputs))) for e in entries))
    if sorted(n for _, o in layout.segments for n in o) != sorted(outputs):
        raise CalibrationError(f"{label}: the cut graph's segments do not share out its outputs {outputs}")
    return extracted(model, entries, outputs, {BLOCK_KEY: layout.to_json()}, defaults)


def _phase_first(tensor: str, d2s, inits: dict, producers: dict, consumers: dict, label: str) -> None:
    """Reorder the channels of ``tensor`` (u8 features in 2x2 phases that ``d2s`` turns into
    native ones, channel 4c + phase as pixel_shuffle orders them) phase first, (phase) C + c:
    each native pixel's C features are then contiguous for ``block_input``'s pass, where
    they were four bytes apart. The convolution that makes them has its output channels
    (weights, their scales and the bias) permuted, every other convolution that reads them
    its input channels; the depth-to-space is left out of the cut graph."""
    q = producers.get(tensor)
    conv = producers.get(q.input[0]) if q is not None and q.op_type == "QuantizeLinear" else None
    if conv is None or conv.op_type != "Conv":
        raise CalibrationError(f"{label}: the phases {d2s.name} reads are not a quantized convolution's output")
    n = int(numpy_helper.to_array(inits[producers[conv.input[1]].input[0]]).shape[0])
    perm = [4 * c + p for p in range(4) for c in range(n // 4)]  # new channel p C + c is old 4c + p

    def permute(name: str, axis: int) -> None:
        a = numpy_helper.to_array(inits[name])
        if a.ndim > axis and a.shape[axis] == n:
            inits[name].CopyFrom(numpy_helper.from_array(np.take(a, perm, axis=axis), name))

    for dq in (producers.get(i) for i in conv.input[1:]):  # weights and bias, with their scales
        for name in dq.input:
            permute(name, 0)
    for dq in consumers.get(tensor, []):
        for node in consumers.get(dq.output[0], []):
            if node is d2s:
                continue
            if node.op_type != "Conv" or node.input[0] != dq.output[0]:
                raise CalibrationError(f"{label}: {node.name} reads the phases {d2s.name} reads")
            permute(producers[node.input[1]].input[0], 1)


def _reached(g: onnx.GraphProto, entry: str, outputs: list[str]) -> list[str]:
    """The graph outputs computed from input ``entry`` (in ``outputs``' order)."""
    seen, changed = {entry}, True
    while changed:
        changed = False
        for n in g.node:
            if any(i in seen for i in n.input) and not set(n.output) <= seen:
                seen.update(n.output)
                changed = True
    return [o for o in outputs if o in seen]
