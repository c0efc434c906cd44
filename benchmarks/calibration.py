"""Int8 calibration benchmark: speed of the QDQ options on this CPU, accuracy of each method.

    python -m benchmarks.calibration --data data/val [--size 1280x720] [--runs 7]
        [--methods qat minmax percentile entropy] [--frames N] [--work out/calibration-bench]
        [--out benchmarks/results/calibration]

1. Exports the shipped checkpoint (fp32) and records calibration inputs by running the
   fp32 pipeline recurrently over the validation sequences.
2. Speed: the network graph at 1280x720 native, fp32 against int8 QDQ variants
   (activations u8 / s8; quantized operators: Conv only, or Conv plus the pooling, resize
   and concatenation between them; ONNX Runtime graph optimization all / extended),
   median of --runs runs each, all in one process, interleaved. GMAC/s against the int8
   and fp32 FMA peaks of this CPU (by its instruction set, ``common.cpu_peaks``).
3. Accuracy: every calibration method with the default options: per-tensor SQNR and the
   end-to-end PSNR/FLIP of the int8 pipeline against fp32 and the reference.

The process is tuned as `jnds run` tunes its own (``common.tune_process``). Writes
benchmarks/results/calibration.md and calibration.json.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from benchmarks.common import (
    RESULTS,
    ROOT,
    arguments,
    command_line,
    cpu_peaks,
    machine_info,
    network_feeds,
    parse,
    parse_size,
    time_sessions,
    tune_process,
    write_report,
)
from jnds_deploy.calibration import CalibrateConfig, calibrate
from jnds_deploy.calibration.quantize import (
    DEFAULT_OP_TYPES,
    FLOAT_NODES,
    METHODS,
    follow_shared_ranges,
    op_counts,
    qat_overrides,
    quantize_graph,
)
from jnds_deploy.calibration.reader import collect_feeds
from jnds_deploy.calibration.report import end_to_end, markdown, tensor_errors
from jnds_deploy.export import ExportConfig, export
from jnds_deploy.io import expand_sequences
from jnds_deploy.model import ModelConfig, count_macs
from jnds_deploy.runtime.profile import profile_stages

# (activation type, quantized operators, nodes kept float); the last is the default
VARIANTS = {
    "u8, Conv only": ("u8", ("Conv",), ()),
    "u8, Conv+ReLU": ("u8", ("Conv", "Relu"), ()),
    "u8, all between convs": ("u8", DEFAULT_OP_TYPES, ()),
    "s8, all between convs, float heads": ("s8", DEFAULT_OP_TYPES, FLOAT_NODES),
    "u8, all between convs, float heads (default)": ("u8", DEFAULT_OP_TYPES, FLOAT_NODES),
}


def main() -> int:
    ap = arguments(
        __doc__,
        RESULTS / "calibration",
        smoke={
            "data": [str(ROOT / "samples" / "orbit-160x90")],
            "work": None,
            "size": "64x32",
            "runs": 1,
            "methods": ["qat"],
            "frames": 2,
        },
    )
    ap.add_argument("--data", nargs="+", default=["data/val"])
    ap.add_argument(
        "--work", default="out/calibration-bench", help="where the graphs go (default with --smoke: beside --out)"
    )
    ap.add_argument("--frames", type=int, default=None, help="calibration frames per sequence (default: all)")
    ap.add_argument("--size", default="1280x720", help="native size of the timing frame (a multiple of pad_multiple)")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--methods", nargs="+", default=list(METHODS))
    args = parse(ap)
    tune_process()
    seqs = expand_sequences(args.data)
    work = Path(args.work or f"{args.out}-work")
    manifest = export(ExportConfig(out=str(work)), log=lambda *a: None)
    size = parse_size(args.size, manifest.pad_multiple)
    network = work / manifest.graphs["network"].file
    # a model with one fixed upsample kernel has no upsample graph
    upsample = work / manifest.graphs["upsample"].file if "upsample" in manifest.graphs else None
    feeds = collect_feeds(work, seqs, args.frames, threads=args.threads)
    overrides = json.loads((work / manifest.qat_ranges).read_text())

    # --- speed of the options, on the qat ranges
    variants, levels = {"fp32": network}, {"fp32": "all"}
    timed_variants = list(VARIANTS.items())[-1:] if args.smoke else VARIANTS.items()  # smoke: the default alone
    for i, (name, (act, ops, float_nodes)) in enumerate(timed_variants):
        path = work / "variants" / f"network.{i}.onnx"
        path.parent.mkdir(parents=True, exist_ok=True)
        learned = follow_shared_ranges(network, overrides["network"], ops)
        quantize_graph(network, path, feeds["network"], "qat", act, ops, qat_overrides(learned), exclude=float_nodes)
        variants[f"int8 {name}"], levels[f"int8 {name}"] = path, "all"
    default = f"int8 {list(VARIANTS)[-1]}"
    variants["fp32, optimization extended"], levels["fp32, optimization extended"] = network, "extended"
    variants["int8 default, optimization extended"] = variants[default]
    levels["int8 default, optimization extended"] = "extended"
    net_feeds = network_feeds(seqs[0], size, manifest.guide_albedo)
    timing = time_sessions(variants, net_feeds, args.runs, args.threads, levels)
    profiles = {k: profile_stages(variants[k], net_feeds, runs=3, threads=args.threads) for k in ("fp32", default)}

    upsample_timing = (
        None if upsample is None else time_upsample(work, upsample, feeds, overrides, default, network, net_feeds, args)
    )
    cfg = ModelConfig(**manifest.model_config)
    macs = count_macs(cfg, *size)
    net_gmac = macs["input_block"] + macs["feature_extractor"] + macs["output_block"]
    peaks = cpu_peaks()
    fp32_ms = timing["fp32"]["median_ms"]
    for name, t in timing.items():
        t["speedup_vs_fp32"] = fp32_ms / t["median_ms"]
        t["gmac_per_s"] = net_gmac / (t["median_ms"] / 1000)
        t["op_counts"] = op_counts(variants[name])

    # --- accuracy of each method, default options
    accuracy = {}
    for method in args.methods:
        calibrated = calibrate(
            CalibrateConfig(
                artifacts=str(work), data=tuple(map(str, seqs)), method=method, frames=args.frames, threads=args.threads
            ),
            log=lambda *a: None,
        )
        # per tensor on a plain QDQ graph with this method's ranges and the default options:
        # the deployed int8 graph takes packed inputs and may run in pieces (runtime.network.Edges)
        act, ops, float_nodes = VARIANTS[default[len("int8 ") :]]
        tensors = {}
        for name, g in calibrated.graphs.items():
            plain = work / "variants" / f"{name}.{method}.onnx"
            learned = (
                qat_overrides(follow_shared_ranges(work / g.file, overrides[name], ops)) if method == "qat" else None
            )
            quantize_graph(work / g.file, plain, feeds[name], method, act, ops, learned, exclude=float_nodes)
            tensors[name] = tensor_errors(work / g.file, plain, feeds[name][::6])
        accuracy[method] = {"end_to_end": end_to_end(work, method, seqs, args.threads), "tensors": tensors}

    report = {
        "command": command_line(),
        "machine": {**machine_info(), **peaks},
        "size": list(size),
        "threads": args.threads,
        "network_gmac": net_gmac,
        "timing": timing,
        "upsample_timing": upsample_timing,
        "upsample_gmac": macs.get("upsample_block", 0.0),
        "profiles": profiles,
        "default_variant": default,
        "accuracy": accuracy,
        "calibration_frames": {k: len(v) for k, v in feeds.items()},
        "sequences": [str(s) for s in seqs],
        "default_op_types": list(DEFAULT_OP_TYPES),
    }
    write_report(Path(args.out), report, render_markdown(report))
    print(render_markdown(report))
    return 0


def time_upsample(work, upsample, feeds, overrides, default, network, net_feeds, args) -> dict:
    """The upsample block's graph, fp32 and int8 with the default options."""
    up8 = work / "variants" / "upsample.default.onnx"
    act, ops, float_nodes = VARIANTS[default[len("int8 ") :]]
    quantize_graph(
        upsample,
        up8,
        feeds["upsample"],
        "qat",
        act,
        ops,
        qat_overrides(follow_shared_ranges(upsample, overrides["upsample"], ops)),
        exclude=float_nodes,
    )
    import onnxruntime as ort

    net = ort.InferenceSession(str(network), providers=["CPUExecutionProvider"])
    features = net.run(["features"], net_feeds)[0]
    c = net_feeds["current"]
    up_feeds = {"composite": np.ascontiguousarray(c[:, 6:9] * c[:, 0:3] + c[:, 3:6]), "features": features}
    del net
    upsample_timing = time_sessions(
        {"fp32": upsample, "int8 default": up8},
        up_feeds,
        args.runs,
        args.threads,
        {"fp32": "all", "int8 default": "all"},
    )
    return upsample_timing


STAGE_COLS = ("input_block", "feature_extractor", "output_block", "reformat", "total")


def render_markdown(r: dict) -> str:
    m = r["machine"]
    w, h = r["size"]
    lines = [
        "# Int8 calibration: speed and accuracy",
        "",
        f"Command: `{r['command']}`  ",
        f"Machine: {m['processor']}, {m['cores']} cores, "
        f"{m['ghz']:.1f} GHz nominal, AVX-512 VNNI {m['avx512_vnni']}, AMX-INT8 {m['amx_int8']}; "
        f"ONNX Runtime CPU execution provider, {r['threads']} intra-op threads.",
        "",
        f"## Network graph at {w}x{h} native ({r['network_gmac']:.1f} GMAC per frame)",
        "",
        f"| variant | median ms | min–max ms | speed-up vs fp32 | GMAC/s | % of int8 peak ({m['int8_isa']}) |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, t in r["timing"].items():
        lines.append(
            f"| {name} | {t['median_ms']:.0f} | {t['min_ms']:.0f}–{t['max_ms']:.0f} | "
            f"{t['speedup_vs_fp32']:.2f}× | {t['gmac_per_s']:.1f} | "
            f"{100 * t['gmac_per_s'] / m['int8_gmacs']:.1f} |"
        )
    ut = r["upsample_timing"]
    lines += (
        ["", "No upsample block graph: the model has one fixed upsample kernel."]
        if ut is None
        else [
            "",
            f"Upsample block graph ({r['upsample_gmac']:.1f} GMAC, the kernel for {2 * w}x{2 * h} from "
            f"convolutions at {w}x{h}, sub-pixel form): fp32 "
            f"{ut['fp32']['median_ms']:.0f} ms, int8 {ut['int8 default']['median_ms']:.0f} ms "
            f"({ut['fp32']['median_ms'] / ut['int8 default']['median_ms']:.2f}×).",
        ]
    )
    lines += [
        "",
        f"Peaks ({m['derivation']}): int8 {m['int8_gmacs']:.0f} GMAC/s, fp32 FMA {m['fp32_fma_gmacs']:.0f} GMAC/s.",
        "",
        "### Where the time goes (ONNX Runtime profiler, median of 3 runs, ms)",
        "",
        "| graph | " + " | ".join(STAGE_COLS) + " |",
        "| --- |" + " ---: |" * len(STAGE_COLS),
    ]
    for name, p in r["profiles"].items():
        lines.append(f"| {name} | " + " | ".join(f"{p['median_ms'][c]:.0f}" for c in STAGE_COLS) + " |")
    lines += ["", "Heaviest operator types (ms per run):", ""]
    for name, p in r["profiles"].items():
        lines.append(f"- {name}: " + ", ".join(f"{k} {v:.0f}" for k, v in list(p["by_op_ms"].items())[:10]))
    lines += [
        "",
        "## Accuracy per calibration method",
        "",
        "| method | fp32 PSNR dB | int8 PSNR dB | loss dB | fp32 FLIP | int8 FLIP | int8 vs fp32 PSNR dB |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for method, a in r["accuracy"].items():
        e = a["end_to_end"]["mean"]
        lines.append(
            f"| {method} | {e['fp32_psnr']:.2f} | {e['int8_psnr']:.2f} | {e['psnr_loss_db']:.3f} | "
            f"{e['fp32_flip']:.4f} | {e['int8_flip']:.4f} | {e['int8_vs_fp32_psnr']:.2f} |"
        )
    for method, a in r["accuracy"].items():
        lines += [
            "",
            f"## {method}: per-tensor error",
            "",
            "On the QDQ graph of the default options with this method's ranges, before the rewrite into "
            "the graphs the runtime runs (`calibration.rewrite`).",
            "",
            markdown(a["tensors"], None),
        ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
