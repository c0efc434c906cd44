"""What the network graph's float post-processing costs: an upper bound for moving it out.

    .venv/bin/python benchmarks/head_postprocess.py --artifacts out/calibration-bench

The output block's 1x1 head convolution predicts all native-resolution kernels at once
(85 channels at 1280x720 for `small`). In the exported graph its output is split, and
the kernels are clamped, the blend weights pass a sigmoid and the albedo/normal kernels
a softmax (`model.OutputBlock`); all of it runs in float, in the fp32 and int8 graphs
alike. This report cuts those nodes off by graph surgery: the head's raw output becomes
the graph output (the coarser levels' outputs are kept). The runtime does not run these
graphs. They show what a runtime would gain by reading the raw head and doing the
clamp/sigmoid/softmax inside its filter loops, which it does not do yet.

Times fp32 and int8 (``network.int8.<method>.onnx``), full and cut, at --size, median of
--runs, all in one process, interleaved. Writes benchmarks/results/head_postprocess.md
and .json.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import tempfile
from pathlib import Path

import numpy as np
import onnx

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("calibration_bench", ROOT / "benchmarks" / "calibration.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

HEAD = "/network/output_block/head/Conv"


def cut_after_head(src: Path, dst: Path) -> int:
    """Writes ``src`` with every node downstream of the output block's head removed and
    the head's output as a graph output; returns how many nodes were removed."""
    model = onnx.load(str(src))
    g = model.graph
    head = next(n for n in g.node if n.name == HEAD).output[0]
    downstream, grew = {head}, True
    while grew:
        grew = False
        for n in g.node:
            if set(n.input) & downstream and not set(n.output) <= downstream:
                downstream |= set(n.output)
                grew = True
    keep = [o.name for o in g.output if o.name not in downstream]
    with tempfile.TemporaryDirectory() as tmp:
        onnx.save(model, f"{tmp}/m.onnx")
        onnx.utils.extract_model(f"{tmp}/m.onnx", str(dst), [i.name for i in g.input], keep + [head])
    return len(g.node) - len(onnx.load(str(dst)).graph.node)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--artifacts", default="out/calibration-bench")
    ap.add_argument("--method", default="qat")
    ap.add_argument("--data", default="data/val/procedural-orbit-2002", help="a sequence for the timing frame")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--runs", type=int, default=9)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "head_postprocess"))
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    art = Path(args.artifacts)
    graphs = {"fp32": art / "network.onnx", "int8": art / f"network.int8.{args.method}.onnx"}
    with tempfile.TemporaryDirectory() as tmp:
        paths, removed = {}, {}
        for name, src in graphs.items():
            paths[name] = src
            paths[f"{name}, head output raw"] = Path(tmp) / f"{name}.cut.onnx"
            removed[name] = cut_after_head(src, paths[f"{name}, head output raw"])
        feeds = bench.timing_inputs(Path(args.data), size)
        t = bench.time_sessions(paths, feeds, args.runs, args.threads, {n: "all" for n in paths})
    med = {n: v["median_ms"] for n, v in t.items()}
    result = {"machine": f"{platform.machine()}, {bench.cpu_peaks()['cores']} cores",
              "cpu": bench.cpu_peaks(), "size": size, "runs": args.runs, "method": args.method,
              "nodes_removed": removed, "timing": t}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    cpu = result["cpu"]
    lines = ["# The network graph's float post-processing",
             "",
             f"Command: `python benchmarks/head_postprocess.py --artifacts {args.artifacts} --method {args.method}`  ",
             f"Machine: {result['machine']}, {cpu['ghz']:.1f} GHz nominal, int8 ISA {cpu['int8_isa']}; "
             f"ONNX Runtime CPU, {args.threads} intra-op threads; {size[0]}x{size[1]} native, "
             f"median of {args.runs} runs, interleaved in one process.",
             "",
             "\"head output raw\": the graph cut after the output block's 1x1 head (split, clamp, "
             "sigmoid and softmax removed: "
             f"{removed['fp32']} nodes in fp32, {removed['int8']} in int8). Not used by the runtime: an upper "
             "bound for doing that post-processing inside the filter loops.",
             "",
             "| graph | median ms | min-max ms | vs fp32 full |",
             "| --- | ---: | ---: | ---: |"]
    for n, v in t.items():
        lines.append(f"| {n} | {v['median_ms']:.0f} | {v['min_ms']:.0f}-{v['max_ms']:.0f} | "
                     f"{med['fp32'] / v['median_ms']:.2f}x |")
    lines += ["",
              f"- int8 over fp32, full graphs: {med['fp32'] / med['int8']:.2f}x; "
              f"cut graphs: {med['fp32, head output raw'] / med['int8, head output raw']:.2f}x.",
              f"- The post-processing costs {med['fp32'] - med['fp32, head output raw']:.0f} ms in fp32 and "
              f"{med['int8'] - med['int8, head output raw']:.0f} ms in int8, where the whole graph takes "
              f"{med['fp32']:.0f} and {med['int8']:.0f} ms.",
              ""]
    out.with_suffix(".md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
