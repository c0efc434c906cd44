"""Per-stage time inside one ONNX graph, from ONNX Runtime's own profiler.

The network graph holds three of the paper's stages (input block, feature extractor,
output block). ONNX Runtime's profiler times every node it runs; the exporter names nodes
after the module that made them (``/network/feature_extractor/encoders.0/a/Conv``), and
ONNX Runtime keeps that name as the prefix of fused nodes, so node time adds up per
stage. Layout changes ONNX Runtime inserts (``ReorderInput``, ``Transpose`` of the NHWC
int8 kernels) are attributed to the stage of the node they feed, or to ``reformat``.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from .network import Edges, quiet

STAGES = ("input_block", "feature_extractor", "output_block")


def stage_of(node_name: str) -> str:
    for s in STAGES:
        if f"/{s}/" in node_name:
            return s
    return "reformat"


def profile_stages(
    onnx_path: str | Path,
    feeds: dict[str, np.ndarray],
    runs: int = 5,
    threads: int = 2,
    optimization: str = "all",
    disabled_optimizers: list[str] | None = None,
) -> dict:
    """Median over ``runs`` of the summed node time per stage (ms), mean per operator type,
    and median per node ({node: {"op", "stage", "ms"}}, largest first). ``disabled_optimizers``:
    as the session to be profiled has them (``Pipeline.disabled_optimizers``)."""
    import onnxruntime as ort

    with tempfile.TemporaryDirectory() as tmp:
        o = ort.SessionOptions()
        o.intra_op_num_threads, o.inter_op_num_threads = threads, 1
        o.graph_optimization_level = {
            "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
            "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
        }[optimization]
        o.enable_profiling = True
        o.profile_file_prefix = os.path.join(tmp, "profile")
        sess = ort.InferenceSession(
            str(onnx_path),
            quiet(o),
            providers=["CPUExecutionProvider"],
            disabled_optimizers=disabled_optimizers or None,
        )
        edges = Edges(sess)
        feeds = edges.feeds(feeds)  # an int8 graph's u8 inputs, packed once (not profiled)
        for _ in range(runs + 1):  # the first a warm-up, dropped below
            edges.run(sess, feeds)
        events = json.loads(Path(sess.end_profiling()).read_text())
    # a cut graph runs once per segment a frame (runtime.network): one run's events span
    # them all; the cuts' passes between them (numba) are not ONNX Runtime's to time
    calls = [ev for ev in events if ev.get("cat") == "Session" and ev.get("name") == "model_run"]
    per = len(edges.block.segments) if edges.block else 1
    events = [ev for ev in events if not (ev.get("cat") == "Session" and ev.get("name") == "model_run")] + [
        {
            "cat": "Session",
            "name": "model_run",
            "ts": calls[i]["ts"],
            "dur": calls[i + per - 1]["ts"] + calls[i + per - 1]["dur"] - calls[i]["ts"],
            "graph_ms": sum(c["dur"] for c in calls[i : i + per]) / 1000,
        }
        for i in range(0, len(calls) - per + 1, per)
    ]
    runs_ms: list[dict[str, float]] = []
    ops: dict[str, list[float]] = {}
    nodes: dict[str, list[float]] = {}
    node_op: dict[str, str] = {}
    for ev in events:
        if ev.get("cat") == "Session" and ev.get("name") == "model_run":
            runs_ms.append({"_start": ev["ts"], "_end": ev["ts"] + ev["dur"], "total": ev["graph_ms"]})
    runs_ms = runs_ms[1:]  # drop the warm-up
    for r in runs_ms:
        r["_nodes"] = {}
    for ev in events:
        if ev.get("cat") != "Node" or not ev.get("name", "").endswith("_kernel_time"):
            continue
        for r in runs_ms:
            if r["_start"] <= ev["ts"] <= r["_end"]:
                stage = stage_of(ev["name"])
                r[stage] = r.get(stage, 0.0) + ev["dur"] / 1000
                op = ev.get("args", {}).get("op_name", "?")
                ops.setdefault(op, []).append(ev["dur"] / 1000)
                node = ev["name"][: -len("_kernel_time")]
                # summed per run: a cut graph runs every node once per segment a frame,
                # on the small defaults of the entries a run is not fed
                r["_nodes"][node] = r["_nodes"].get(node, 0.0) + ev["dur"] / 1000
                node_op[node] = op
    for r in runs_ms:
        for node, ms in r.pop("_nodes").items():
            nodes.setdefault(node, []).append(ms)
    keys = ["total", *STAGES, "reformat"]
    med = {k: float(np.median([r.get(k, 0.0) for r in runs_ms])) for k in keys}
    med["other"] = med["total"] - sum(med[k] for k in (*STAGES, "reformat"))  # scheduling between nodes
    by_op = {k: float(np.sum(v)) / len(runs_ms) for k, v in sorted(ops.items(), key=lambda kv: -sum(kv[1]))}
    # median over the runs (a node runs once a run): one slow run (page faults while an
    # arena grows) would dominate a mean
    by_node = {
        k: {"op": node_op[k], "stage": stage_of(k), "ms": float(np.median(v))}
        for k, v in sorted(nodes.items(), key=lambda kv: -float(np.median(kv[1])))
    }
    return {"median_ms": med, "by_op_ms": by_op, "by_node_ms": by_node, "runs": len(runs_ms)}
