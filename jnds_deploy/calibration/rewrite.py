"""Rewrites of the int8 QDQ graph after quantization, on the model in memory: the same
arithmetic in the form ONNX Runtime's CPU kernels run fastest (``fast_int8``; why each,
in its docstring). Written here: ONNX Runtime's own graph transformers do not do these.
And the tools the graph surgeries share: ``extracted`` (a model cut down to what its
outputs need, checked), ``write_model`` (written atomically).
"""

from __future__ import annotations

import os
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


def fast_int8(model: onnx.ModelProto) -> int:
    """``pools_as_convolutions`` and ``resizes_into_concat_scale`` on ``model``, in place;
    returns the number of nodes changed."""
    return pools_as_convolutions(model) + resizes_into_concat_scale(model)


def pools_as_convolutions(model: onnx.ModelProto) -> int:
    """Rewrite each quantized 2x2, stride-2 AveragePool (DequantizeLinear -> AveragePool ->
    QuantizeLinear) of ``model`` in place as a depthwise 2x2, stride-2 convolution whose
    int8 weights are 127 at scale 0.25 / 127, exactly the mean of four. Its output keeps
    the pool's scale. Why: ONNX Runtime's QLinearAveragePool is a slow memory-bound loop at
    720p; the same pooling as a QLinearConv runs on MLAS's channels-last depthwise kernel
    (benchmarks/results/calibration.md). The rounding of exact halves can differ by one
    code. Returns the number of pools rewritten."""
    graph = model.graph
    inferred = onnx.shape_inference.infer_shapes(model).graph
    shapes = {v.name: v.type.tensor_type.shape for v in [*inferred.value_info, *inferred.input]}
    producers, users = _links(graph)
    done = 0
    for node in [n for n in graph.node if n.op_type == "AveragePool"]:
        attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
        dq, after = producers.get(node.input[0]), users.get(node.output[0], [])
        if (
            attrs.get("kernel_shape") != [2, 2]
            or attrs.get("strides") != [2, 2]
            or any(attrs.get("pads", [0]))
            or dq is None
            or dq.op_type != "DequantizeLinear"
            or [u.op_type for u in after] != ["QuantizeLinear"]
        ):
            continue
        channels = shapes[node.input[0]].dim[1].dim_value
        if not channels:
            raise CalibrationError(f"{node.name}: input channels unknown")
        w = f"{node.name}/depthwise"
        graph.initializer.extend(
            [
                numpy_helper.from_array(np.full((channels, 1, 2, 2), 127, np.int8), f"{w}_q"),
                numpy_helper.from_array(np.full(channels, 0.25 / 127, np.float32), f"{w}_scale"),
                numpy_helper.from_array(np.zeros(channels, np.int8), f"{w}_zero_point"),
            ]
        )
        at = list(graph.node).index(node)
        graph.node.remove(node)
        graph.node.insert(
            at,
            helper.make_node(
                "Conv",
                [node.input[0], w],
                [node.output[0]],
                name=node.name,
                group=channels,
                kernel_shape=[2, 2],
                strides=[2, 2],
            ),
        )
        graph.node.insert(
            at,
            helper.make_node(
                "DequantizeLinear",
                [f"{w}_q", f"{w}_scale", f"{w}_zero_point"],
                [w],
                name=f"{w}_DequantizeLinear",
                axis=0,
            ),
        )
        done += 1
    return done


def resizes_into_concat_scale(model: onnx.ModelProto) -> int:
    """Where a concatenation's input is a float Resize quantized for it (Resize ->
    QuantizeLinear -> DequantizeLinear -> Concat -> QuantizeLinear), quantize the Resize's
    output at the concatenation's own scale and zero point, in ``model``. ONNX Runtime runs
    the upsampling in float either way (it does not fuse a linear Resize into int8), but a
    QLinearConcat input already at the output's scale is copied instead of requantized
    through a lookup table, and the values are rounded once instead of twice (the clip to
    the concatenation's range happened in the requantization already). Returns the
    number of inputs changed."""
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
            if (
                q is None
                or q.op_type != "QuantizeLinear"
                or len(users[q.output[0]]) != 1
                or len(users[dq.output[0]]) != 1
                or producers.get(q.input[0]) is None
                or producers[q.input[0]].op_type != "Resize"
            ):
                continue
            q.input[1], q.input[2] = out_scale, out_zero
            dq.input[1], dq.input[2] = out_scale, out_zero
            done += 1
    return done


def extracted(
    model: onnx.ModelProto,
    inputs: list[str],
    outputs: list[str],
    props: dict,
    defaults: dict[str, np.ndarray] | None = None,
) -> onnx.ModelProto:
    """``model`` reduced to what ``outputs`` need from ``inputs`` (the nodes a surgery cut
    off go), with ``props`` added to its metadata, checked. ``defaults``: values of inputs a
    run may leave out (overridable initializers). ``model`` is left as it is."""
    props = {**{p.key: p.value for p in model.metadata_props}, **props}
    model = onnx.utils.Extractor(onnx.load_from_string(model.SerializeToString())).extract_model(inputs, outputs)
    model.graph.initializer.extend(numpy_helper.from_array(v, n) for n, v in (defaults or {}).items())
    onnx.helper.set_model_props(model, props)
    onnx.checker.check_model(model)
    return model


def write_model(model: onnx.ModelProto, path: Path) -> None:
    """``model`` written to ``path`` atomically (a reader never sees half a file)."""
    tmp = path.with_name(f".{path.name}.tmp")
    onnx.save(model, str(tmp))
    os.replace(tmp, path)
