"""Rewrites of the int8 QDQ graph after quantization: the same arithmetic in the form
ONNX Runtime's CPU kernels run fastest (measured in docs/performance.md, "Where the network
graph's time goes"). Written here: ONNX Runtime's own graph transformers do not do these.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ..errors import CalibrationError


def _links(graph: onnx.GraphProto) -> tuple[dict, dict]:
    """({tensor: the node writing it}, {tensor: [nodes reading it]})."""
    producers = {o: n for n in graph.node for o in n.output}
    users: dict[str, list] = {}
    for n in graph.node:
        for i in n.input:
            users.setdefault(i, []).append(n)
    return producers, users


def pools_as_convolutions(path: Path) -> int:
    """Rewrite each quantized 2x2, stride-2 AveragePool (DequantizeLinear -> AveragePool ->
    QuantizeLinear) of the graph at ``path`` in place as a depthwise 2x2, stride-2
    convolution whose int8 weights are 127 at scale 0.25 / 127, exactly the mean of
    four. Its output keeps the pool's scale. Why: ONNX Runtime's QLinearAveragePool is
    a slow memory-bound loop at 720p; the same pooling as a QLinearConv runs on MLAS's
    channels-last depthwise kernel (docs/performance.md). The rounding of exact halves
    can differ by one code. Returns the number of pools rewritten."""
    model = onnx.load(str(path))
    graph = model.graph
    inferred = onnx.shape_inference.infer_shapes(model).graph
    shapes = {v.name: v.type.tensor_type.shape for v in [*inferred.value_info, *inferred.input]}
    producers, users = _links(graph)
    done = 0
    for node in [n for n in graph.node if n.op_type == "AveragePool"]:
        attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
        dq, after = producers.get(node.input[0]), users.get(node.output[0], [])
        if (attrs.get("kernel_shape") != [2, 2] or attrs.get("strides") != [2, 2]
                or any(attrs.get("pads", [0])) or dq is None or dq.op_type != "DequantizeLinear"
                or [u.op_type for u in after] != ["QuantizeLinear"]):
            continue
        channels = shapes[node.input[0]].dim[1].dim_value
        if not channels:
            raise CalibrationError(f"{path}: {node.name}: input channels unknown")
        w = f"{node.name}/depthwise"
        graph.initializer.extend([numpy_helper.from_array(np.full((channels, 1, 2, 2), 127, np.int8), f"{w}_q"),
                                  numpy_helper.from_array(np.full(channels, 0.25 / 127, np.float32), f"{w}_scale"),
                                  numpy_helper.from_array(np.zeros(channels, np.int8), f"{w}_zero_point")])
        at = list(graph.node).index(node)
        graph.node.remove(node)
        graph.node.insert(at, helper.make_node("Conv", [node.input[0], w], [node.output[0]], name=node.name,
                                               group=channels, kernel_shape=[2, 2], strides=[2, 2]))
        graph.node.insert(at, helper.make_node("DequantizeLinear", [f"{w}_q", f"{w}_scale", f"{w}_zero_point"], [w],
                                               name=f"{w}_DequantizeLinear", axis=0))
        done += 1
    if done:
        onnx.save(model, str(path))
    return done


def resizes_into_concat_scale(path: Path) -> int:
    """Where a concatenation's input is a float Resize quantized for it (Resize ->
    QuantizeLinear -> DequantizeLinear -> Concat -> QuantizeLinear), quantize the Resize's
    output at the concatenation's own scale and zero point, in place. ONNX Runtime runs
    the upsampling in float either way (it does not fuse a linear Resize into int8), but a
    QLinearConcat input already at the output's scale is copied instead of requantized
    through a lookup table, and the values are rounded once instead of twice (the clip to
    the concatenation's range happened in the requantization already). Returns the
    number of inputs changed."""
    model = onnx.load(str(path))
    producers, users = _links(model.graph)
    done = 0
    for concat in [n for n in model.graph.node if n.op_type == "Concat"]:
        after = users.get(concat.output[0], [])
        if [u.op_type for u in after] != ["QuantizeLinear"]:
            continue
        out_scale, out_zero = after[0].input[1], after[0].input[2]
        for tensor in concat.input:
            dq = producers.get(tensor)
            q = producers.get(dq.input[0]) if dq is not None and dq.op_type == "DequantizeLinear" else None
            if (q is None or q.op_type != "QuantizeLinear" or len(users[q.output[0]]) != 1
                    or len(users[dq.output[0]]) != 1 or producers.get(q.input[0]) is None
                    or producers[q.input[0]].op_type != "Resize"):
                continue
            q.input[1], q.input[2] = out_scale, out_zero
            dq.input[1], dq.input[2] = out_scale, out_zero
            done += 1
    if done:
        onnx.save(model, str(path))
    return done
