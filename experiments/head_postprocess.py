"""What the network graph's float post-processing costs: an upper bound for moving it out.

    .venv/bin/python experiments/head_postprocess.py --artifacts out/calibration-bench [--method qat]
        [--data data/val/procedural-orbit-2002] [--size 1280x720] [--runs 9]
        [--out benchmarks/results/head_postprocess]

The output block's 1x1 head convolution predicts all native-resolution kernels at once
(85 channels at 1280x720 for `small`). In the exported graph its output is split, and
the kernels are clamped, the blend weights pass a sigmoid and the albedo/normal kernels
a softmax (`model.OutputBlock`); all of it runs in float, in the fp32 and int8 graphs
alike. This report cuts those nodes off by graph surgery: the head's raw output becomes
the graph output (the coarser levels' outputs are kept). The runtime does not run these
graphs. They show what a runtime would gain by reading the raw head and doing the
clamp/sigmoid/softmax inside its filter loops, which it does not do yet.

Times fp32 and int8 (the manifest's int8 network graph of --method), full and cut, at
--size, median of --runs, all in one process, interleaved (``common.time_sessions``).
Writes benchmarks/results/head_postprocess.md and .json.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import onnx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import (RESULTS, arguments, command_line, cpu_peaks, machine_info, machine_line,  # noqa: E402
                               network_feeds, parse_size, time_sessions, write_report)
from jnds_deploy.artifacts import Manifest  # noqa: E402

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
    ap = arguments(__doc__, RESULTS / "head_postprocess")
    ap.add_argument("--artifacts", default="out/calibration-bench")
    ap.add_argument("--method", default="qat")
    ap.add_argument("--data", default="data/val/procedural-orbit-2002", help="a sequence for the timing frame")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--runs", type=int, default=9)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    art = Path(args.artifacts)
    manifest = Manifest.load(art)
    size = parse_size(args.size, manifest.pad_multiple)
    network = manifest.graphs["network"]
    if args.method not in network.int8:
        raise SystemExit(f"{art}: no int8 network graph for {args.method!r}; "
                         f"run `jnds calibrate --method {args.method}` first")
    graphs = {"fp32": art / network.file, "int8": art / network.int8[args.method].file}
    with tempfile.TemporaryDirectory() as tmp:
        paths, removed = {}, {}
        for name, src in graphs.items():
            paths[name] = src
            paths[f"{name}, head output raw"] = Path(tmp) / f"{name}.cut.onnx"
            removed[name] = cut_after_head(src, paths[f"{name}, head output raw"])
        feeds = network_feeds(Path(args.data), size)
        t = time_sessions(paths, feeds, args.runs, args.threads, {n: "all" for n in paths})
    med = {n: v["median_ms"] for n, v in t.items()}
    result = {"machine": machine_line(), "machine_info": machine_info(),
              "cpu": cpu_peaks(), "size": size, "runs": args.runs, "method": args.method,
              "nodes_removed": removed, "timing": t}
    cpu = result["cpu"]
    lines = ["# The network graph's float post-processing",
             "",
             f"Command: `{command_line()}`  ",
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
    write_report(Path(args.out), result, "\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
