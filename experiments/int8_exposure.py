"""Where the int8 network graph departs from fp32 at high exposure: its outputs on one
frame of a sequence at radiance x 2^k, run by ONNX Runtime at each graph optimization
level and with its QDQ fusion (``QDQSelectorActionTransformer``, which turns
DequantizeLinear -> op -> QuantizeLinear groups into the int8 kernels) disabled, against
the fp32 graph. Needs a float-edged int8 graph, whose outputs are the fp32 graph's:

    .venv/bin/jnds calibrate --artifacts out/cal-fe --data samples/orbit-160x90 --float-edges
    .venv/bin/python experiments/int8_exposure.py --artifacts out/cal-fe \\
        --sequence data/media/cycles-media-cut-16104 --stops 0 8

Prints the mean over the graph's outputs of mean |int8 - fp32| / mean |fp32|
(benchmarks/results/int8_exposure.md).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import onnxruntime as ort

from jnds_deploy.calibration.head import RADIANCE
from jnds_deploy.calibration.reader import collect_feeds, exposed

RUNS = [("ORT_DISABLE_ALL", []), ("ORT_ENABLE_BASIC", []), ("ORT_ENABLE_EXTENDED", []), ("ORT_ENABLE_ALL", []),
        ("ORT_ENABLE_ALL", ["QDQSelectorActionTransformer"])]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--artifacts", required=True)
    ap.add_argument("--sequence", required=True)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--stops", type=float, nargs="+", default=[0, 8])
    a = ap.parse_args()
    art = Path(a.artifacts)
    feed = collect_feeds(art, [a.sequence], frames=a.frame + 1, progress=False)["network"][a.frame]
    fp32 = ort.InferenceSession(str(art / "network.onnx"), providers=["CPUExecutionProvider"])
    int8 = art / "network.int8.qat.onnx"
    names = [o.name for o in fp32.get_outputs()]
    if [o.name for o in ort.InferenceSession(str(int8), providers=["CPUExecutionProvider"]).get_outputs()] != names:
        raise SystemExit(f"{int8}: its outputs are not the fp32 graph's (calibrate with --float-edges)")
    for level, disabled in RUNS:
        so = ort.SessionOptions()
        so.graph_optimization_level = getattr(ort.GraphOptimizationLevel, level)
        sess = ort.InferenceSession(str(int8), so, providers=["CPUExecutionProvider"], disabled_optimizers=disabled)
        errs = []
        for k in a.stops:
            f = exposed(feed, k, RADIANCE)
            ref = dict(zip(names, fp32.run(names, f)))
            got = dict(zip(names, sess.run(names, f)))
            errs.append(np.mean([np.abs(got[n] - ref[n]).mean() / (np.abs(ref[n]).mean() + 1e-9) for n in names]))
        what = level + (f" without {', '.join(disabled)}" if disabled else "")
        print(f"{what:62s} " + "  ".join(f"2^{k:g}: {e:.3f}" for k, e in zip(a.stops, errs)), flush=True)


if __name__ == "__main__":
    main()
