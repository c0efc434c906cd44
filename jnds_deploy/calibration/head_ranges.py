"""The output block's head in int8: graph surgery on an int8 network graph.

ONNX Runtime's static quantization leaves the head float (``quantize.FLOAT_NODES``): its
85 output channels go out of the graph as float, split, clamped, through a sigmoid or a
softmax, all at native resolution (what that cost: commit 4a7fec9). ``quantize_head``
replaces the head and everything after it with one quantized 1x1 convolution whose u8
output is the graph output ``head``, channels last, padded to ``PAD`` channels (MLAS's
fast int8 convolution wants multiples of 8 and at least 16; the NHWC transpose at the end
is cancelled by ONNX Runtime's NHWC int8 layout). ``runtime.head`` does the split, clamp,
sigmoid and softmax in the filter stage's reading pass; the layout of ``head`` is
``artifacts.layouts.HeadLayout``.

One QLinearConv has one output scale and zero point, and the parts of the head span
different ranges (kernel taps are clamped to [-1, 1], blend logits and the albedo/normal
kernels' logits reach further). Each output channel c is therefore mapped onto [-1, 1]
before quantization, (raw - centre_c) / R_c: the weights are per-channel int8, so the gain
1 / R_c changes only their scales, and the centre goes into the bias. Every channel's u8
code then covers its own [centre_c - R_c, centre_c + R_c] (``channel_ranges``): the raw
head output's range on the calibration inputs, within what the part's function can tell
apart (kernels are clamped to [-1, 1], a sigmoid is flat beyond +-12, a ReLU below 0).
"""

from __future__ import annotations

import itertools

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ..artifacts.layouts import HEAD, HEAD_KEY, LEVELS_KEY, HeadLayout, levels_to_json
from ..errors import CalibrationError
from ..layout import channels, head_kind
from .reader import exposed
from .rewrite import extracted

HEAD_NODE = "/network/output_block/head/Conv"
PAD = 16
ZERO_POINT = 128  # u8 codes 0..255 are (q - 128) / 127 * R_c: [-1.008, 1] * R_c
CODE_SCALE = 1 / 127
# range caps: a blend logit beyond +-12 is a sigmoid within 6e-6 of 0 or 1; a normalized
# kernel's logits (softmax) stay exp()-able in float32 for 9 taps (runtime.head)
BOUNDS = {"kernel": (-1.0, 1.0), "blend": (-12.0, 12.0), "normalized": (-80.0, 80.0), "relu": (0.0, np.inf)}
MIN_RANGE = 1e-2  # a channel that is (nearly) constant on the calibration data
# the calibration frames' radiance x 2^k for these k: the ranges hold from 16x darker to
# 256x brighter than the frames calibrated on; ranged at exposure 1 alone, brighter
# sequences lost to fp32 where the float head did not (measured at commit d9314c4; int8
# against fp32 over these exposures: benchmarks/results/exposure_sweep.md)
STOPS = (-4, -2, 0, 2, 4, 6, 8)
RADIANCE = slice(0, channels("specular").stop)  # diffuse, specular: current and history alike


def _head(graph: onnx.GraphProto):
    """(head Conv node, its Split node, [(graph output, split index), ...] in split order)."""
    conv = next((n for n in graph.node if n.name == HEAD_NODE), None)
    if conv is None or conv.op_type != "Conv":
        raise CalibrationError(f"no float head convolution {HEAD_NODE!r} in the network graph")
    split = next((n for n in graph.node if n.op_type == "Split" and n.input[0] == conv.output[0]), None)
    if split is None:
        raise CalibrationError(f"{HEAD_NODE}: its output is not split into the network's outputs")
    producers = {o: n for n in graph.node for o in n.output}
    index = {o: i for i, o in enumerate(split.output)}
    parts = []
    for out in graph.output:
        t = out.name
        while (
            t not in index and t in producers and producers[t].input
        ):  # back along the first inputs: Clip, Sigmoid, Div <- Exp <- Sub
            t = producers[t].input[0]
        if t in index:
            parts.append((out.name, index[t]))
    parts.sort(key=lambda p: p[1])
    if [i for _, i in parts] != list(range(len(split.output))):
        raise CalibrationError(f"{HEAD_NODE}: split parts {[i for _, i in parts]} do not each reach one output")
    return conv, split, parts


def _constant(graph: onnx.GraphProto, name: str) -> np.ndarray | None:
    for i in graph.initializer:
        if i.name == name:
            return numpy_helper.to_array(i)
    for n in graph.node:
        if n.op_type == "Constant" and n.output[0] == name:
            return numpy_helper.to_array(next(a.t for a in n.attribute if a.name == "value"))
    return None


def _split_sizes(graph: onnx.GraphProto, split) -> list[int]:
    sizes = _constant(graph, split.input[1])
    if sizes is None:
        raise CalibrationError(f"{split.name}: split sizes are not a constant")
    return [int(s) for s in sizes]


def raw_ranges(model: onnx.ModelProto, feeds: list[dict[str, np.ndarray]], stops=STOPS) -> dict[str, np.ndarray]:
    """{output: (channels, 2) min and max of the head's raw output} over ``feeds``, each
    with its radiance (current and history) x 2^k for every k in ``stops``, run through
    the int8 network graph ``model`` (its head still float; left as it is)."""
    import onnxruntime as ort

    model = onnx.load_from_string(model.SerializeToString())
    conv, split, parts = _head(model.graph)
    sizes = _split_sizes(model.graph, split)
    model.graph.output.append(helper.make_tensor_value_info(conv.output[0], onnx.TensorProto.FLOAT, None))
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    lo = hi = None
    for f, k in itertools.product(feeds, stops):
        raw = sess.run([conv.output[0]], exposed(f, k, RADIANCE))[0]
        a, b = raw.min(axis=(0, 2, 3)), raw.max(axis=(0, 2, 3))
        lo, hi = (a, b) if lo is None else (np.minimum(lo, a), np.maximum(hi, b))
    starts = np.cumsum([0] + sizes)
    return {name: np.stack([lo[starts[i] : starts[i + 1]], hi[starts[i] : starts[i + 1]]], 1) for name, i in parts}


def channel_ranges(raw: dict[str, np.ndarray]) -> dict[str, dict[str, list[float]]]:
    """{output: {"centre": [...], "range": [...]}} per channel: its u8 code covers
    [centre - range, centre + range], the raw range within the part's ``BOUNDS``. A
    linear kernel's channels cover their whole clamp, [-1, 1], whatever the calibration
    data reached: the ranges the bundled sample gave lost on static window-lit rooms,
    whose taps go further (measured at commit a701940)."""
    out = {}
    for name, mm in raw.items():
        lo, hi = BOUNDS[head_kind(name)]
        if head_kind(name) == "kernel":
            mm = np.broadcast_to(np.array([lo, hi]), mm.shape)
        a, b = np.clip(mm[:, 0], lo, hi), np.clip(mm[:, 1], lo, hi)
        r = np.maximum((b - a) / 2, MIN_RANGE)
        out[name] = {"centre": [float(v) for v in (a + b) / 2], "range": [float(v) for v in r]}
    return out


def quantize_head(
    model: onnx.ModelProto, ranges: dict[str, dict[str, list[float]]], label: str = "the graph"
) -> onnx.ModelProto:
    """``model`` (an int8 network graph or pruned variant, head float; changed) with its head
    quantized and its u8 NHWC output ``head`` in place of the outputs the head fed; its
    layout (``HeadLayout``) in the graph's metadata. ``ranges``: centre and range of every
    output the head feeds (``channel_ranges``; a variant uses those of its outputs).
    ``label`` names the graph in errors."""
    g = model.graph
    conv, split, parts = _head(g)
    sizes = _split_sizes(g, split)
    names = [n for n, _ in parts]
    missing = [n for n in names if n not in ranges]
    if missing:
        raise CalibrationError(f"{label}: no head range for {', '.join(missing)}")
    r = np.concatenate([np.asarray(ranges[n]["range"], np.float64) for n in names])
    m = np.concatenate([np.asarray(ranges[n]["centre"], np.float64) for n in names])
    if [len(ranges[n]["range"]) for n in names] != sizes or len(m) != len(r):
        raise CalibrationError(
            f"{label}: head ranges of {[len(ranges[n]['range']) for n in names]} channels, the split has {sizes}"
        )
    inits = {i.name: numpy_helper.to_array(i) for i in g.initializer}
    producers = {o: n for n in g.node for o in n.output}
    x_dq = producers.get(conv.input[0])
    if x_dq is None or x_dq.op_type != "DequantizeLinear":
        raise CalibrationError(f"{HEAD_NODE}: its input is not quantized (the int8 graph is expected)")
    x_scale = float(inits[x_dq.input[1]])
    w = inits[conv.input[1]].astype(np.float64) / r[:, None, None, None]
    b = (inits[conv.input[2]].astype(np.float64) - m) / r
    pad = max(-len(w) % PAD, PAD - len(w))
    w = np.concatenate([w, np.zeros((pad, *w.shape[1:]))])
    b = np.concatenate([b, np.zeros(pad)])
    w_scale = np.maximum(np.abs(w).reshape(len(w), -1).max(1) / 127, 1e-12)
    wq = np.clip(np.round(w / w_scale[:, None, None, None]), -127, 127).astype(np.int8)
    bq = np.round(b / (x_scale * w_scale)).astype(np.int32)
    c = len(w)
    g.initializer.extend(
        [
            numpy_helper.from_array(a, n)
            for a, n in (
                (wq, "head_w_q"),
                (w_scale.astype(np.float32), "head_w_scale"),
                (np.zeros(c, np.int8), "head_w_zp"),
                (bq, "head_b_q"),
                ((x_scale * w_scale).astype(np.float32), "head_b_scale"),
                (np.zeros(c, np.int32), "head_b_zp"),
                (np.array(CODE_SCALE, np.float32), "head_y_scale"),
                (np.array(ZERO_POINT, np.uint8), "head_y_zp"),
            )
        ]
    )
    conv.input[1], conv.input[2] = "head_w", "head_b"
    at = list(g.node).index(conv)  # the nodes stay topologically sorted
    prefix = HEAD_NODE.rsplit("/", 1)[0]  # named in the output block (runtime.profile's stages)
    g.node.insert(
        at,
        helper.make_node(
            "DequantizeLinear",
            ["head_b_q", "head_b_scale", "head_b_zp"],
            ["head_b"],
            name=f"{prefix}/bias_DequantizeLinear",
            axis=0,
        ),
    )
    g.node.insert(
        at,
        helper.make_node(
            "DequantizeLinear",
            ["head_w_q", "head_w_scale", "head_w_zp"],
            ["head_w"],
            name=f"{prefix}/weight_DequantizeLinear",
            axis=0,
        ),
    )
    g.node.extend(
        [
            helper.make_node(
                "QuantizeLinear",
                [conv.output[0], "head_y_scale", "head_y_zp"],
                ["head_u8"],
                name=f"{prefix}/QuantizeLinear",
            ),
            helper.make_node("Transpose", ["head_u8"], [HEAD], name=f"{prefix}/Transpose", perm=[0, 2, 3, 1]),
        ]
    )
    for vi in [v for v in g.value_info if v.name == conv.output[0]]:
        g.value_info.remove(vi)  # its channel count changed
    keep = [o.name for o in g.output if o.name not in set(names)]
    g.output.append(helper.make_tensor_value_info(HEAD, onnx.TensorProto.UINT8, ["N", "H", "W", c]))
    layout = HeadLayout(
        tuple(zip(names, sizes)), tuple(float(v) for v in r * CODE_SCALE), tuple(float(v) for v in m), ZERO_POINT, c
    )
    return extracted(model, [i.name for i in g.input], keep + [HEAD], {HEAD_KEY: layout.to_json()})


def code_levels(model: onnx.ModelProto, label: str = "the graph") -> onnx.ModelProto:
    """``model`` (an int8 network graph or pruned variant; changed) with each of the feature
    extractor's level heads ending in its u8 output: output ``<path>.level<k>`` (N, C, h, w)
    in place of the outputs ``<path>.level<k>.<part>`` its dequantization, split, clamps and
    sigmoid fed, which ONNX Runtime ran at every level of every frame (measured at commit
    46c2dca). The codes are the ones the head's quantized convolution wrote;
    ``runtime.head`` decodes them in the filter loops as those nodes did, so nothing is
    requantized. Their layouts, {output: ``HeadLayout``}, go into the graph's metadata
    (``LEVELS_KEY``); a graph without level heads is returned as it is. ``label`` names the
    graph in errors."""
    g = model.graph
    producers = {o: n for n in g.node for o in n.output}
    groups: dict[str, list[tuple[str, int]]] = {}  # per level head: (graph output, index in its split)
    found: dict[str, tuple] = {}  # per level head: its QuantizeLinear, DequantizeLinear and Split
    for out in g.output:
        name = out.name
        head = name.rpartition(".")[0]
        if ".level" not in head:
            continue
        t, chain = name, []
        while t in producers and producers[t].op_type in ("Clip", "Sigmoid"):
            chain.append(producers[t])
            t = producers[t].input[0]
        split = producers.get(t)
        dq = producers.get(split.input[0]) if split is not None and split.op_type == "Split" else None
        q = producers.get(dq.input[0]) if dq is not None and dq.op_type == "DequantizeLinear" else None
        kind = head_kind(name)
        want = {"kernel": ["Clip"], "blend": ["Sigmoid"]}.get(kind)
        if q is None or q.op_type != "QuantizeLinear" or [n.op_type for n in chain] != want:
            raise CalibrationError(
                f"{label}: level output {name} is not a {kind} of a quantized head "
                f"(QuantizeLinear, DequantizeLinear, Split, {' '.join(want or ['?'])})"
            )
        if kind == "kernel":
            bounds = [_constant(g, i) for i in chain[0].input[1:]]
            if any(b is None for b in bounds) or [float(b) for b in bounds] != list(BOUNDS["kernel"]):
                raise CalibrationError(f"{label}: {name}'s clamp is not {BOUNDS['kernel']}")
        found[head] = (q, dq, split)
        groups.setdefault(head, []).append((name, list(split.output).index(t)))
    layouts = {}
    for head, parts in groups.items():
        q, dq, split = found[head]
        sizes = _split_sizes(g, split)
        parts.sort(key=lambda p: p[1])
        if [i for _, i in parts] != list(range(len(sizes))):
            raise CalibrationError(
                f"{label}: {split.name}'s parts {[i for _, i in parts]} do not each reach one output"
            )
        scale, zp = _constant(g, dq.input[1]), _constant(g, dq.input[2])
        if scale is None or zp is None or zp.dtype != np.uint8 or scale.size != 1:
            raise CalibrationError(f"{label}: {dq.name} is not a u8 per-tensor dequantization")
        n = sum(sizes)
        layouts[head] = HeadLayout(
            tuple((p, c) for (p, _), c in zip(parts, sizes)), (float(scale),) * n, (0.0,) * n, int(zp), n
        )
        old = q.output[0]
        q.output[0] = head  # the u8 tensor is the output (its dequantization goes with the rest)
        for node in g.node:
            node.input[:] = [head if i == old else i for i in node.input]
    if not layouts:  # a variant that filters neither path has no level heads
        return model
    gone = {p for lay in layouts.values() for p, _ in lay.parts}
    keep = [o.name for o in g.output if o.name not in gone]
    g.output.extend(
        helper.make_tensor_value_info(h, onnx.TensorProto.UINT8, ["N", lay.channels, f"h{h}", f"w{h}"])
        for h, lay in layouts.items()
    )
    return extracted(model, [i.name for i in g.input], keep + list(layouts), {LEVELS_KEY: levels_to_json(layouts)})
