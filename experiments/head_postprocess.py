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

Two more cuts of the int8 graph also quantize the head itself: int8 weights (per output
channel, symmetric, as everywhere else), and its output quantized to u8 with one scale
over the raw output's range on the timing frame, so ONNX Runtime fuses it into a
QLinearConv whose u8 output is the graph output. "head int8, u8 output": as is (85
channels, NCHW). "... 96 channels, NHWC": output channels padded with zero weights to a
multiple of 16 (MLAS's fast int8 convolution wants multiples of 8 and at least 16), and
the graph ends in a transpose to NHWC, which ONNX Runtime's NHWC int8 layout cancels, so
each pixel's kernels come out contiguous with no transpose. Their values are not checked
(one range for blend logits and kernel taps alike is too coarse to use as it is): they
bound what a runtime reading 8-bit kernels would save, a quarter of the bytes.

It needs the int8 graphs of `jnds calibrate --float-edges` (float head and inputs, what
the runtime ran until stop 33; since then the head's u8 output is what `jnds calibrate`
writes by default, `calibration.head`).

Times fp32 and int8 (the manifest's int8 network graph of --method), full and cut, at
--size, median of --runs, all in one process, interleaved (``common.time_sessions``), the
int8 graphs without NCHWc as the pipeline runs them (``Pipeline.disabled_optimizers``).
Writes benchmarks/results/head_postprocess.md and .json.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import (RESULTS, arguments, command_line, cpu_peaks, machine_info, machine_line,  # noqa: E402
                               network_feeds, parse_size, time_sessions, write_report)
from jnds_deploy.artifacts import Manifest  # noqa: E402

HEAD = "/network/output_block/head/Conv"
U8_NHWC = "int8, head int8, u8 output, 96 channels, NHWC"


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


def quantize_head(cut: Path, dst: Path, feeds: dict, pad_to: int = 1, nhwc: bool = False) -> None:
    """``cut`` (an int8 graph cut after its float head) with the head quantized: int8
    weights per output channel, int32 bias, the output quantized to u8 (the range of the
    raw output on ``feeds``) and that u8 tensor the graph output; output channels padded
    with zero weights to a multiple of ``pad_to``; with ``nhwc``, the output transposed
    to (N, H, W, C)."""
    import onnxruntime as ort

    model = onnx.load(str(cut))
    g = model.graph
    head = next(n for n in g.node if n.name == HEAD)
    raw = ort.InferenceSession(str(cut), providers=["CPUExecutionProvider"]).run([head.output[0]], feeds)[0]
    inits = {i.name: numpy_helper.to_array(i) for i in g.initializer}
    x_dq = next(n for n in g.node if head.input[0] in n.output)  # DequantizeLinear of the head's input
    x_scale = float(inits[x_dq.input[1]])
    w, b = inits[head.input[1]], inits[head.input[2]]
    pad = -len(w) % pad_to
    w = np.concatenate([w, np.zeros((pad, *w.shape[1:]), w.dtype)])
    b = np.concatenate([b, np.zeros(pad, b.dtype)])
    w_scale = np.maximum(np.abs(w).reshape(len(w), -1).max(1) / 127, 1e-8).astype(np.float32)
    wq = np.clip(np.round(w / w_scale[:, None, None, None]), -127, 127).astype(np.int8)
    bq = np.round(b / (x_scale * w_scale)).astype(np.int32)
    lo, hi = min(float(raw.min()), 0.0), float(raw.max())
    y_scale = np.float32((hi - lo) / 255)
    y_zp = np.uint8(round(-lo / float(y_scale)))
    g.initializer.extend([numpy_helper.from_array(a, n) for a, n in (
        (wq, "head_wq"), (w_scale, "head_w_scale"), (np.zeros(len(w), np.int8), "head_w_zp"),
        (bq, "head_bq"), ((x_scale * w_scale).astype(np.float32), "head_b_scale"),
        (np.zeros(len(w), np.int32), "head_b_zp"), (np.array(y_scale), "head_y_scale"),
        (np.array(y_zp), "head_y_zp"))])
    dq = [helper.make_node("DequantizeLinear", ["head_wq", "head_w_scale", "head_w_zp"], ["head_w"], axis=0),
          helper.make_node("DequantizeLinear", ["head_bq", "head_b_scale", "head_b_zp"], ["head_b"], axis=0)]
    head.input[1], head.input[2] = "head_w", "head_b"
    q = helper.make_node("QuantizeLinear", [head.output[0], "head_y_scale", "head_y_zp"], ["head_u8"])
    g.node.extend(dq + [q])
    out = next(o for o in g.output if o.name == head.output[0])
    g.output.remove(out)
    if nhwc:
        g.node.append(helper.make_node("Transpose", ["head_u8"], ["head_u8_nhwc"], perm=[0, 2, 3, 1]))
    g.output.append(helper.make_tensor_value_info("head_u8_nhwc" if nhwc else "head_u8", onnx.TensorProto.UINT8,
                                                  None))
    onnx.save(model, str(dst))


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
        paths["int8, head int8, u8 output"] = Path(tmp) / "int8.u8head.onnx"
        quantize_head(paths["int8, head output raw"], paths["int8, head int8, u8 output"], feeds)
        paths[U8_NHWC] = Path(tmp) / "int8.u8head.nhwc.onnx"
        quantize_head(paths["int8, head output raw"], paths[U8_NHWC], feeds, pad_to=16, nhwc=True)
        t = time_sessions(paths, feeds, args.runs, args.threads, {n: "all" for n in paths},
                          {n: ["NchwcTransformer"] for n in paths if n.startswith("int8")})
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
              f"- With the head in int8 and a u8 output too, the int8 graph takes "
              f"{med['int8, head int8, u8 output']:.0f} ms as is and {med[U8_NHWC]:.0f} ms with 96 output "
              f"channels in NHWC: {med['int8'] - med[U8_NHWC]:.0f} ms "
              f"({100 * (1 - med[U8_NHWC] / med['int8']):.0f} %) less than the full int8 graph.",
              ""]
    write_report(Path(args.out), result, "\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
