"""Which of ONNX Runtime's int8 convolution paths is faster on this CPU: MLAS's direct
symmetric convolution (AVX2 / AVX-512 VNNI kernels, chosen when the weights are prepacked)
or im2col + the int8 GEMM (which MLAS runs on AMX tiles where the CPU has them).
``session.disable_prepacking`` turns the first off for the whole session.

    python experiments/ort_conv_path.py [--artifacts out/artifacts] [--size 1280x720] [--runs 7]

Times the shipped int8 network graph on one random packed input (the graph's time does
not depend on the values), with the pipeline's session options, 2 threads; prints JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.common import cpu_line, machine_info  # noqa: E402
from jnds_deploy.runtime.network import Edges, quiet  # noqa: E402


def session(path: Path, threads: int, prepack: bool):
    o = ort.SessionOptions()
    o.intra_op_num_threads, o.inter_op_num_threads = threads, 1
    o.enable_mem_pattern = False
    o.add_session_config_entry("session.intra_op.allow_spinning", "0")
    if not prepack:
        o.add_session_config_entry("session.disable_prepacking", "1")
    return ort.InferenceSession(str(path), quiet(o), providers=["CPUExecutionProvider"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--artifacts", default="out/artifacts")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    w, h = map(int, args.size.split("x"))
    graph = Path(args.artifacts) / "network.int8.qat.onnx"
    report = {"cpu": cpu_line(machine_info()), "size": [w, h], "ort": ort.__version__, "runs": args.runs}
    outs, x = {}, None
    for prepack in (True, False, True, False):  # interleaved twice: the host drifts
        s = session(graph, args.threads, prepack)
        if x is None:  # one input for every session
            x = np.random.default_rng(0).integers(0, 256, (1, h, w, s.get_inputs()[0].shape[3]), dtype=np.uint8)
        edges = Edges(s)  # the graph's two runs where it is cut at the output block
        edges.run(s, {"inputs": x})
        ms = []
        for _ in range(args.runs):
            t = time.perf_counter()
            y = list(edges.run(s, {"inputs": x}).values())
            ms.append(1e3 * (time.perf_counter() - t))
        key = "prepacked (direct conv)" if prepack else "disable_prepacking (im2col + GEMM)"
        report.setdefault(key, []).append(float(np.median(ms)))
        outs[prepack] = y
    report["max_abs_diff"] = max(float(np.abs(a.astype(np.float64) - b).max()) for a, b in zip(outs[True], outs[False]))
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
