"""Pruned variants of the network graph: what a configuration does not use is not computed.

ONNX Runtime runs every node of the graph it is given, so skipping a filter path at run
time saves its kernels' computation only if a graph without them exists. The network's
outputs fall into groups: ``diffuse.*`` and ``specular.*`` (the kernels and blend
weights of one filter path, at every level), ``features`` (only the upsample block reads
them) and ``aux.*`` (always needed). A variant drops one or more of the first three.

Pruning is graph surgery on the exported (fp32 or int8 QDQ) graph, no re-export:
``onnx.utils.Extractor`` keeps the nodes the remaining outputs depend on (the per-level
heads of a dropped path disappear whole), and a ``Split`` of a convolution's output
whose parts are no longer all used -- the output block's single 1x1 head conv predicts
every native kernel at once -- gets its convolution sliced to the output channels still
used (weights and bias of a float convolution; the head stays float in the int8 graphs,
``calibration.quantize.FLOAT_NODES``). The remaining outputs are the full graph's,
computed by the same nodes on the same weights (``validate_variant`` checks).
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper

from ..artifacts import GROUPS, Variant, variant_key

# (max, mean) |variant - full| allowed for int8 graphs (see validate_variant): 1.5x the
# largest difference seen, 3x the largest mean (docs/architecture.md, "The int8 graph").
# Kernels and blend weights lie in [-1, 1]; a broken variant (wrong channels kept) is off
# by far more.
INT8_VARIANT_TOL = (2e-2, 1e-4)


def group_of(output: str) -> str | None:
    """The prunable group of a network output, or None (``aux.*``: always needed)."""
    head = output.split(".")[0]
    return head if head in GROUPS else None


def variant_drops(outputs: list[str]) -> list[tuple[str, ...]]:
    """Every non-empty set of droppable groups present in ``outputs``, as sorted tuples."""
    present = [g for g in GROUPS if any(group_of(o) == g for o in outputs)]
    return [c for r in range(1, len(present) + 1) for c in itertools.combinations(present, r)]


def kept_outputs(outputs: list[str], drops) -> list[str]:
    return [o for o in outputs if group_of(o) not in set(drops)]


def prune(src: Path, dst: Path, keep: list[str]) -> dict:
    """Write the graph of ``src`` reduced to the outputs ``keep`` to ``dst`` (atomically);
    returns {sliced convolution: (channels before, after)}."""
    model = onnx.load(str(src))
    inputs = [i.name for i in model.graph.input]
    model = onnx.utils.Extractor(model).extract_model(inputs, keep)
    sliced = _slice_split_heads(model.graph)
    onnx.checker.check_model(model)
    tmp = dst.with_name(f".{dst.name}.tmp")
    onnx.save(model, str(tmp))
    os.replace(tmp, dst)
    return sliced


def _slice_split_heads(graph: onnx.GraphProto) -> dict:
    used = {i for n in graph.node for i in n.input} | {o.name for o in graph.output}
    producers = {o: n for n in graph.node for o in n.output}
    inits = {i.name: i for i in graph.initializer}
    constants = {
        n.output[0]: next(a.t for a in n.attribute if a.name == "value")
        for n in graph.node
        if n.op_type == "Constant" and any(a.name == "value" for a in n.attribute)
    }
    readers: dict[str, int] = {}
    for n in graph.node:
        for i in n.input:
            readers[i] = readers.get(i, 0) + 1
    sliced = {}
    for split in [n for n in graph.node if n.op_type == "Split"]:
        live = [o in used for o in split.output]
        if all(live):
            continue
        conv = producers.get(split.input[0])
        axis = next((a.i for a in split.attribute if a.name == "axis"), 0)
        if (
            conv is None
            or conv.op_type != "Conv"
            or axis != 1
            or len(split.input) < 2
            or not (split.input[1] in inits or split.input[1] in constants)
            or conv.input[1] not in inits
            or readers.get(conv.output[0], 0) != 1
            or (len(conv.input) > 2 and conv.input[2] not in inits)
        ):
            continue  # not a float head conv: leave the dead parts (correct, just not pruned)
        sizes = numpy_helper.to_array(inits.get(split.input[1]) or constants[split.input[1]])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        channels = np.concatenate([np.arange(s, s + n) for s, n, k in zip(starts, sizes, live) if k])
        suffix = f"_pruned_{len(channels)}"
        for slot in range(1, len(conv.input)):  # weight, bias
            w = numpy_helper.to_array(inits[conv.input[slot]])[channels]
            graph.initializer.append(numpy_helper.from_array(w, conv.input[slot] + suffix))
            conv.input[slot] += suffix
        graph.initializer.append(numpy_helper.from_array(sizes[np.array(live)], split.input[1] + suffix))
        split.input[1] += suffix
        outs = [o for o, k in zip(split.output, live) if k]
        del split.output[:]
        split.output.extend(outs)
        for vi in list(graph.value_info):  # the conv output's recorded shape is stale
            if vi.name == conv.output[0]:
                graph.value_info.remove(vi)
        sliced[conv.name] = (int(sizes.sum()), len(channels))
    still_read = {i for n in graph.node for i in n.input}
    for init in [i for i in graph.initializer if i.name not in still_read]:
        graph.initializer.remove(init)
    for node in [n for n in graph.node if n.op_type == "Constant" and n.output[0] not in still_read]:
        graph.node.remove(node)
    return sliced


def write_variants(root: Path, file: str, stem: str, log=None) -> dict[str, Variant]:
    """Every pruned variant of graph ``root/file``, written as ``<stem>.<key>.onnx``;
    returns the manifest entries by key (their sha256 is the caller's to fill in)."""
    outputs = [o.name for o in onnx.load(str(root / file)).graph.output]
    entries = {}
    for drops in variant_drops(outputs):
        key, keep = variant_key(drops), kept_outputs(outputs, drops)
        name = f"{stem}.{key}.onnx"
        sliced = prune(root / file, root / name, keep)
        if log:
            what = ", ".join(f"{c.rsplit('/', 2)[-2]} {a}->{b} channels" for c, (a, b) in sliced.items())
            log(f"pruned {file} -> {name} ({len(keep)} of {len(outputs)} outputs{'; ' + what if what else ''})")
        entries[key] = Variant(file=name, drops=list(drops), outputs=keep)
    return entries


def validate_variant(
    full: Path, variant: Path, feeds: dict[str, np.ndarray], atol: float = 1e-5, mean_tol: float | None = None
) -> list[dict]:
    """The variant's outputs against the full graph's on the same inputs (ONNX Runtime).

    fp32 variants are bit-equal in practice. In int8 QDQ graphs ONNX Runtime may group
    QDQ nodes into int8 kernels differently once a tensor loses a consumer, which can move
    a rare value by a quantization step (docs/architecture.md, "The int8 graph"):
    ``calibrate`` validates them with ``INT8_VARIANT_TOL``."""
    import onnxruntime as ort

    from ..runtime.network import quiet, run_network

    a = ort.InferenceSession(str(full), quiet(), providers=["CPUExecutionProvider"])
    b = ort.InferenceSession(str(variant), quiet(), providers=["CPUExecutionProvider"])
    ref = run_network(a, feeds)
    got = run_network(b, feeds)
    names = list(got)
    d = [np.abs(got[name].astype(np.float64) - ref[name]) for name in names]
    worst = max(float(x.max()) for x in d)
    mean = float(np.mean([x.mean() for x in d]))
    return [
        {
            "graph": variant.name,
            "output": f"{len(names)} outputs vs {full.name}",
            "max_abs": worst,
            "mean_abs": mean,
            "atol": atol,
            "mean_tol": mean_tol,
            "ok": worst <= atol and (mean_tol is None or mean <= mean_tol),
        }
    ]
