"""Per-stage timing of the pipeline, in the form of the paper's Table 4.

    python -m benchmarks.timing [--input samples/orbit-160x90]
        [--size 1280x720] [--repeats 3] [--no-oidn] [--out benchmarks/results/timing]

Runs the frame-recurrent pipeline (fp32 and int8 network graphs, float32 filter stage)
on the input sequence at its own size and on the same frames resized to --size native
(1280x720 -> 2560x1440 by default), all in one process, tuned as `jnds run` tunes its
own (``common.tune_process``). The network stage is split into the paper's input
block, feature extractor and output block by ONNX Runtime's profiler on the same inputs
(its per-stage shares of the profiled time, applied to the pipeline's measured network
time). Writes benchmarks/results/timing.md and timing.json.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from benchmarks.common import (
    RESULTS,
    ROOT,
    CpuSteal,
    arguments,
    command_line,
    cpu_line,
    cpu_peaks,
    gemm_throughput,
    machine_info,
    parse,
    parse_size,
    pipeline,
    resized_frames,
    run_frames,
    spread,
    timed,
    tune_process,
    write_report,
)
from jnds_deploy.artifacts import Manifest
from jnds_deploy.io import open_sequence
from jnds_deploy.model import ModelConfig, count_macs
from jnds_deploy.runtime import Pipeline
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS
from jnds_deploy.runtime.network import Edges
from jnds_deploy.runtime.profile import STAGES, profile_stages
from jnds_deploy.runtime.reformat import block_input

ROWS = (
    "reformat",
    "diffuse_fill",
    "warp",
    "firefly_clamp",
    "input_block",
    "feature_extractor",
    "output_block",
    "filter_diffuse",
    "filter_specular",
    "filter_auxiliary",
    "composite",
    "albedo_at_holes",
    "upsample_kernel",
    "upsample_filter",
)


def time_pipeline(pipe: Pipeline, frames, repeats: int, between=None) -> list[dict]:
    pipe.reset()
    pipe(*frames[0])  # warm-up (first frame: no history)
    recorded = []
    for _ in range(repeats):
        for layers, cut in frames[1:]:
            recorded.append(pipe(layers, cut).ms)
            if between:
                between()
    return recorded


def network_split(pipe: Pipeline, frames, threads: int) -> tuple[dict[str, float], dict, float, dict[str, float]]:
    """Shares of input block / feature extractor / output block in the network graph,
    ONNX Runtime's per-node times (``profile_stages``' ``by_node_ms``), and the ms of the
    network stage spent outside the graph, medians of 7 on the same frame: an int8 graph's
    input packing (``runtime.reformat.pack_inputs``: the input block's tonemap and
    quantization, in numba), and per stage the passes of the upsamplings and concatenations
    where the graph is cut at them (``runtime.reformat.block_input``); 0 and {} where the graph
    has no such step."""
    feeds = {}
    pipe.on_feeds = lambda name, f: feeds.setdefault(name, f)
    pipe.reset()
    pipe(*frames[0])
    pipe.on_feeds = None
    profile = profile_stages(
        pipe.graphs["network"].path,
        feeds["network"],
        runs=3,
        threads=threads,
        disabled_optimizers=pipe.disabled_optimizers("network"),
    )
    prof = profile["median_ms"]
    # layout changes and scheduling are spread over the three stages by their share
    inside = sum(prof[s] for s in STAGES)
    edges = Edges(pipe.sessions["network"])
    pack = float(np.median([timed(edges.feeds, feeds["network"])[1] for _ in range(7)])) if edges.inputs else 0.0
    glue: dict[str, float] = {}
    if edges.block:  # every cut's pass, on the tensors the graph gives it
        made = edges.run(pipe.sessions["network"], edges.feeds(feeds["network"]), internal=True)
        glue = {}
        for c in edges.block.cuts:
            ms = float(np.median([timed(block_input, made[c.up], made[c.skip], c)[1] for _ in range(7)]))
            glue[c.stage] = glue.get(c.stage, 0.0) + ms
    return {s: prof[s] / inside for s in STAGES}, profile["by_node_ms"], pack, glue


def summarize(
    recorded: list[dict],
    split: dict,
    macs: dict,
    peaks: dict,
    gemm: dict,
    pack_ms: float = 0.0,
    glue_ms: dict[str, float] | None = None,
) -> dict:
    """Per stage: spread of its time, share of the frame, and for the network stages and
    the upsample block GMAC, GMAC/s and the share of ``peaks`` ({stage: GMAC/s of this CPU
    at the precision the stage runs at}) and of ``gemm`` (the same, by ONNX Runtime on one
    large matrix product here, ``common.gemm_throughput``) reached. The network time less
    ``pack_ms`` and ``glue_ms`` (``network_split``) is split by ``split``; ``pack_ms`` goes to
    the input block, whose preprocessing it is (an fp32 graph runs it inside the input
    block), ``glue_ms`` to the stages whose upsampling and concatenation it is."""
    rows = {}
    glue_ms = glue_ms or {}
    net = np.array([r["network"] for r in recorded]) - pack_ms - sum(glue_ms.values())
    total = np.array([r["total"] for r in recorded])
    for k in ROWS:
        if k in STAGES:
            v = net * split[k] + (pack_ms if k == "input_block" else 0.0) + glue_ms.get(k, 0.0)
        elif k in recorded[0]:
            v = np.array([r[k] for r in recorded])
        else:
            continue
        row = {**spread(v, suffix="_ms"), "share": float(np.median(v / total))}
        gm = macs.get(k if k in STAGES else ("upsample_block" if k == "upsample_kernel" else ""), None)
        if gm is not None:
            row["gmac"] = gm
            row["gmac_per_s"] = gm / (row["median_ms"] / 1000)
            row["peak_share"] = row["gmac_per_s"] / peaks[k]
            row["gemm_share"] = row["gmac_per_s"] / gemm[k]
        rows[k] = row
    rows["total"] = {**spread(total, suffix="_ms"), "share": 1.0}
    return rows


def table(rows: dict) -> str:
    lines = [
        "| stage | median ms | p10–p90 ms | % of total | GMAC | GMAC/s | % of peak | % of GEMM |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for k, r in rows.items():
        g = (
            f"{r['gmac']:.2f} | {r['gmac_per_s']:.1f} | {100 * r['peak_share']:.0f} | {100 * r['gemm_share']:.0f}"
            if "gmac" in r
            else " |  |  | "
        )
        name = f"**{k}**" if k == "total" else k
        lines.append(
            f"| {name} | {r['median_ms']:.1f} | {r['p10_ms']:.1f}–{r['p90_ms']:.1f} | {100 * r['share']:.1f} | {g} |"
        )
    return "\n".join(lines)


FILTER_ROWS = ("warp", "filter_diffuse", "filter_specular", "filter_auxiliary", "composite", "upsample_filter")


def traffic_bytes(cfg: ModelConfig, w: int, h: int, u8_head: bool = False) -> dict[str, float]:
    """Bytes each filter-stage step must move at the least: its inputs read once and its
    output written once (float32; the native kernels and blend weights 1 byte each where
    the output block's head is u8, ``runtime.head``), as a fully fused loop would;
    intermediates (the pooled levels, the upsampled composite) not counted. N native
    pixels, T = s^2 N target pixels.
    - warp: history 12N + motion 2N + the current normals 3N (geometric rejection) read,
      12N written (a rejected pixel also reads the current inputs' 12 channels: not counted);
    - filter path (diffuse or specular): current 3N + history 3N + native kernels (spatial 9,
      temporal 9, blend 1, with levels also up 9, up_blend 1) read; level k (N / 4^k pixels)
      kernels down 9, up 9, up_blend 1 (the coarsest: down only); output 3N written;
    - auxiliary: albedo and normal, current and history 12N, shared kernels 19N read, 6N written;
    - composite: 9N read, 3N written;
    - upsample filter: composite 3N and kernel 9T read, 3T written (one fixed kernel for
      every pixel, ``ModelConfig.fixed_upsample``: nothing per pixel to read for it)."""
    n, t = w * h, w * h * cfg.scale**2
    k = 1.0 if u8_head else 4.0  # bytes per native kernel tap
    native = 19 + (10 if cfg.filter_levels > 0 else 0)
    levels = sum((9 if lv == cfg.filter_levels else 19) * n / 4**lv for lv in range(1, cfg.filter_levels + 1))
    path = 4 * (6 + 3) * n + k * native * n + 4 * levels
    return {
        "warp": 4.0 * 29 * n,
        "filter_diffuse": path,
        "filter_specular": path,
        "filter_auxiliary": 4 * 18 * n + k * 19 * n,
        "composite": 4.0 * 12 * n,
        "upsample_filter": 4.0 * (3 * n + (3 if cfg.fixed_upsample else 12) * t) if cfg.scale > 1 else 0.0,
    }


class CopyProbe:
    """Copy bandwidth (bytes read + bytes written per second) of a numba loop over rows on
    ``threads`` threads copying ``mbytes`` MB, the way the filter stage moves memory. Call
    it between frames: this VM's bandwidth drifts between runs minutes apart (the spread in
    benchmarks/results/timing.md), so the bound uses samples taken in the same minutes as
    the frames it is compared with."""

    def __init__(self, threads: int, mbytes: int = 256):
        import numba
        from numba import njit, prange

        @njit(parallel=True, cache=False)
        def copy(src, dst):
            for y in prange(src.shape[0]):
                for x in range(src.shape[1]):
                    dst[y, x] = src[y, x]

        numba.set_num_threads(threads)
        self.copy = copy
        self.src = np.ones((mbytes * 256, 1024), np.float32)  # mbytes MB
        self.dst = np.empty_like(self.src)
        self.copy(self.src, self.dst)
        self.samples: list[float] = []

    def __call__(self) -> None:
        ms = timed(self.copy, self.src, self.dst)[1]
        self.samples.append(2 * self.src.nbytes / (ms / 1000))


def traffic_table(rows: dict, need: dict, bandwidth: float) -> tuple[str, dict]:
    lines = [
        "| step | must move (MB) | bound (ms) | measured median (ms) | measured / bound |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    result = {}
    for k in (*FILTER_ROWS, "total"):
        if k == "total":
            b = sum(need[r] for r in FILTER_ROWS if r in rows)
            m = sum(rows[r]["median_ms"] for r in FILTER_ROWS if r in rows)
        elif k in rows:
            b, m = need[k], rows[k]["median_ms"]
        else:
            continue
        bound = 1000 * b / bandwidth
        result[k] = {"bytes": b, "bound_ms": bound, "measured_ms": m, "ratio": m / bound}
        name = "**filter stage**" if k == "total" else k
        lines.append(f"| {name} | {b / 1e6:.0f} | {bound:.1f} | {m:.1f} | {m / bound:.2f} |")
    return "\n".join(lines), result


def head_to_head(pipe: Pipeline, frames, passes: int) -> dict:
    """The peer users have: OIDN balanced (and fast) denoising alone at native size, same
    frames, interleaved frame by frame with the int8 pipeline so that both see the same
    machine state (these machines drift within minutes: the spread in
    benchmarks/results/timing.md). Each pass starts from a first frame, not timed."""
    from jnds_deploy.baselines import oidn

    runners = {
        "pipeline": pipe,
        "balanced": lambda layers, cut: oidn(layers, "balanced"),
        "fast": lambda layers, cut: oidn(layers, "fast"),
    }
    ms_pipe, ms_oidn, ms_fast = [], [], []
    for _ in range(passes):
        pipe.reset()
        pipe(*frames[0])
        done = run_frames(runners, frames[1:])
        ms_pipe += [result.ms["total"] for result, _ in done["pipeline"]]
        ms_oidn += [ms for _, ms in done["balanced"]]
        ms_fast += [ms for _, ms in done["fast"]]
    ratio = np.array(ms_pipe) / np.array(ms_oidn)
    ratio_fast = np.array(ms_pipe) / np.array(ms_fast)
    oidn_spread = spread(ms_oidn, "oidn_", "_ms")
    return {
        "frames": len(ms_pipe),
        "int8_pipeline_median_ms": float(np.median(ms_pipe)),
        "oidn_balanced_median_ms": oidn_spread["oidn_median_ms"],
        "oidn_p10_ms": oidn_spread["oidn_p10_ms"],
        "oidn_p90_ms": oidn_spread["oidn_p90_ms"],
        **spread(ratio, "ratio_"),
        "oidn_fast_median_ms": float(np.median(ms_fast)),
        **spread(ratio_fast, "ratio_fast_"),
    }


def main() -> int:
    ap = arguments(__doc__, RESULTS / "timing", smoke={"size": "160x96", "repeats": 1})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS, help="exported and calibrated (`make demo` does both)")
    ap.add_argument("--input", default=str(ROOT / "samples" / "orbit-160x90"))
    ap.add_argument("--size", default="1280x720", help="native size the frames are also resized to")
    ap.add_argument("--repeats", type=int, default=3, help="passes over the sequence's frames 1..N")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--precisions", nargs="+", default=["int8", "fp32"])
    ap.add_argument(
        "--no-oidn", action="store_true", help="leave out the head to head with OIDN (where pyoidn cannot be installed)"
    )
    args = parse(ap)
    tune_process()
    seq = open_sequence(args.input)
    manifest = Manifest.load(args.artifacts)
    cfg = ModelConfig(**manifest.model_config)
    big = parse_size(args.size)
    big_label = f"{big[0]}x{big[1]}"
    report = {
        "command": command_line(),
        "machine": machine_info(),
        "input": str(seq.path),
        "threads": args.threads,
        "int8_method": manifest.int8_method,
        "results": {},
    }
    steal = CpuSteal()
    probe = CopyProbe(args.threads, 8 if args.smoke else 256)
    cpu = report["cpu_peaks"] = cpu_peaks()
    gemm = report["gemm_throughput"] = gemm_throughput(args.threads, *((256, 2) if args.smoke else ()))
    int8 = manifest.graphs["network"].int8.get(manifest.int8_method or "")
    u8_head = bool(int8 and int8.head.startswith("u8"))  # the int8 pipeline's kernels come as bytes
    for label, size in ((big_label, big), (f"{seq.native_size[0]}x{seq.native_size[1]}", None)):
        frames = resized_frames(seq, size)
        w, h = size or seq.native_size
        macs = count_macs(cfg, w, h)
        for precision in args.precisions:
            pipe = pipeline(args.artifacts, precision=precision, threads=args.threads)
            split, nodes, pack_ms, glue_ms = network_split(pipe, frames, args.threads)
            # copy-bandwidth samples between the frames of the large int8 run: the
            # filter stage's memory-traffic bound (below)
            probed = size == big and precision == "int8"
            peak = {"int8": cpu["int8_gmacs"], "fp32": cpu["fp32_fma_gmacs"]}
            peaks = {
                **{s: peak[pipe.graph_precision["network"]] for s in STAGES},
                "upsample_kernel": peak[pipe.graph_precision.get("upsample", "fp32")],
            }
            at = {"int8": gemm["int8_gmacs"], "fp32": gemm["fp32_gmacs"]}
            gemms = {
                **{s: at[pipe.graph_precision["network"]] for s in STAGES},
                "upsample_kernel": at[pipe.graph_precision.get("upsample", "fp32")],
            }
            rows = summarize(
                time_pipeline(pipe, frames, args.repeats, probe if probed else None),
                split,
                macs,
                peaks,
                gemms,
                pack_ms,
                glue_ms,
            )
            report["results"][f"{label} {precision}"] = {
                "native": [w, h],
                "target": [w * pipe.scale, h * pipe.scale],
                "precision": precision,
                "graphs": dict(pipe.graph_precision),
                "split": split,
                "input_packing_ms": pack_ms,
                "block_glue_ms": glue_ms,
                "stages": rows,
                "network_nodes": nodes,
            }
            if probed:
                bw = np.array(probe.samples)
                report["copy_bandwidth_gb_s"] = {**spread(bw / 1e9), "samples": len(bw)}
                report["results"][f"{label} {precision}"]["traffic"] = traffic_table(
                    rows, traffic_bytes(cfg, w, h, u8_head), float(np.median(bw))
                )[1]
            print(f"{label} {precision}: {rows['total']['median_ms']:.1f} ms/frame", flush=True)
        if size == big and not args.no_oidn:
            report[f"head_to_head_{label}"] = head_to_head(
                pipeline(args.artifacts, precision="int8", threads=args.threads),
                frames,
                1 if args.smoke else args.repeats + 2,
            )
    # the share of CPU time the VM host stole during this run goes into the report
    report["cpu_steal_share"] = steal.share()
    out = Path(args.out)
    md = [
        "# Per-stage timing (the paper's Table 4, on this CPU)",
        "",
        f"Command: `{report['command']}`  ",
        f"Machine: {cpu_line(report['machine'])}, {report['machine']['platform']}, "
        f"{report['machine']['cpu_count']} cores, "
        f"{args.threads} threads; input {seq.path.name}, frames 2–{len(seq)} × {args.repeats} passes "
        f"(the first frame is a warm-up); filter stage float32; int8 graphs: {report['int8_method']}; "
        f"CPU time stolen by the VM host during the run: {100 * report['cpu_steal_share']:.0f} %.",
        "",
        f"Peaks of this CPU (`common.cpu_peaks`, {cpu['derivation']}; {cpu['cores']} cores at the nominal "
        f"{cpu['ghz']:.2f} GHz): int8 {cpu['int8_gmacs']:.0f} GMAC/s, fp32 {cpu['fp32_fma_gmacs']:.0f} GMAC/s. "
        '"% of peak" sets a stage\'s GMAC/s against the peak of the precision its graph runs at. '
        f"The same ONNX Runtime on one {gemm['n']}^3 matrix product here (`common.gemm_throughput`, median of "
        f"{gemm['runs']}): int8 (MatMulInteger, u8 x s8) {gemm['int8_gmacs']:.0f} GMAC/s, fp32 (MatMul) "
        f'{gemm["fp32_gmacs"]:.0f} GMAC/s; "% of GEMM" sets a stage against that. A stage above 100 % of '
        "peak means the cores ran above the nominal clock (turbo, which a VM's /proc/cpuinfo does not show).",
        "",
    ]
    for name, r in report["results"].items():
        graphs = ", ".join(f"{g} {p}" for g, p in r["graphs"].items())
        md += [
            f"## {r['native'][0]}x{r['native'][1]} → {r['target'][0]}x{r['target'][1]}, {r['precision']} "
            f"pipeline ({graphs})",
            "",
            table(r["stages"]),
            "",
        ]
    if f"head_to_head_{big_label}" in report:
        o = report[f"head_to_head_{big_label}"]
        s = manifest.scale
        md += [
            f"Head to head at {big_label}, interleaved frame by frame ({o['frames']} frames): the int8 pipeline "
            f"(denoising and {s}x upsampling to {big[0] * s}x{big[1] * s}) median "
            f"{o['int8_pipeline_median_ms']:.1f} ms, OIDN `balanced` denoising alone at native resolution median "
            f"{o['oidn_balanced_median_ms']:.1f} ms (p10–p90 {o['oidn_p10_ms']:.1f}–{o['oidn_p90_ms']:.1f}); "
            f"per-frame time ratio pipeline/OIDN median {o['ratio_median']:.2f} "
            f"(p10–p90 {o['ratio_p10']:.2f}–{o['ratio_p90']:.2f}). OIDN `fast`, timed in the same loop: median "
            f"{o['oidn_fast_median_ms']:.1f} ms, ratio pipeline/OIDN fast "
            f"{o['ratio_fast_median']:.2f} (p10–p90 {o['ratio_fast_p10']:.2f}–{o['ratio_fast_p90']:.2f}).",
            "",
        ]
    if "copy_bandwidth_gb_s" in report:
        r, bw = report["results"][f"{big_label} int8"], report["copy_bandwidth_gb_s"]
        md += [
            "## The filter stage against its memory-traffic bound "
            f"({big_label} → {r['target'][0]}x{r['target'][1]}, int8 pipeline)",
            "",
            f"Bound = bytes a step must move (its inputs read once, its output written once, float32, the "
            f"native kernels as {'bytes' if u8_head else 'float32'}; "
            f"`traffic_bytes` says what is counted) ÷ the copy bandwidth measured between the frames of this "
            f"run: median {bw['median']:.1f} GB/s (p10–p90 {bw['p10']:.1f}–{bw['p90']:.1f}, "
            f"{bw['samples']} samples; read + written, a numba row loop on {args.threads} threads copying "
            f"{probe.src.nbytes >> 20} MB; `CopyProbe`).",
            "",
            traffic_table(r["stages"], traffic_bytes(cfg, *r["native"], u8_head), bw["median"] * 1e9)[0],
            "",
            "The bound is a model, not a floor: the probe writes as many bytes as it reads, and a write costs "
            "more than a read (the cache line is read for ownership first), so a step that mostly reads can "
            "beat it (the composite reads 3 bytes per byte it writes).",
            "",
        ]
    if f"{big_label} int8" in report["results"]:
        nodes = report["results"][f"{big_label} int8"]["network_nodes"]
        total = sum(n["ms"] for n in nodes.values())
        md += [
            f"## The network graph's largest nodes ({big_label}, int8)",
            "",
            f"ONNX Runtime's profiler, median of 3 runs per node, in a session with the pipeline's graph "
            f"optimizers; the medians add up to {total:.1f} ms (the table's input block to output block rows "
            "also hold the time between nodes).",
            "",
            "| node | operator | stage | ms | % of nodes |",
            "| --- | --- | --- | ---: | ---: |",
        ]
        for name, n in list(nodes.items())[:15]:
            md.append(f"| `{name}` | {n['op']} | {n['stage']} | {n['ms']:.1f} | {100 * n['ms'] / total:.1f} |")
        md.append("")
    md += [
        (
            "The model has no upsample graph: one learned 3x3 kernel for every target pixel "
            "(`ModelConfig.upsample_width` 0), applied in the upsample filter."
            if cfg.fixed_upsample
            else "The int8 pipeline keeps the upsample graph in fp32 (`PipelineConfig.fp32_graphs`): its int8 graph "
            "is slower on this CPU (see `benchmarks/results/calibration.md`)."
        ),
        "The filter stage (filter paths, composite, upsample filter) and the reformatting are numba-fused "
        "float32 loops; before them (commit cc5865c) the table had filter_diffuse 303.0, filter_specular "
        "291.3, filter_auxiliary 305.5, upsample_filter 344.6, reformat 201.7 ms (int8, 1280x720; total "
        "2554.7 ms against OIDN balanced 1416.3 ms in that run).",
        "",
    ]
    packing = {name: r["input_packing_ms"] for name, r in report["results"].items() if r["input_packing_ms"]}
    glue = {name: sum(r["block_glue_ms"].values()) for name, r in report["results"].items() if r["block_glue_ms"]}
    md += [
        "The input block / feature extractor / output block rows split the measured network time by the "
        "shares ONNX Runtime's profiler gives those stages on the same inputs. An int8 graph takes its "
        "input packed (`runtime.reformat.pack_inputs`: the input block's tonemap, quantization and channels-"
        "last layout, a numba loop, which the fp32 graph runs inside the input block): that time, measured "
        "apart on the same frame (median of 7), is taken out before the split and counted in the input block "
        "row (" + "; ".join(f"{name}: {ms:.1f} ms" for name, ms in packing.items()) + "). Where the int8 "
        "graph is cut at its upsamplings and concatenations (`calibration.block`), their numba passes between "
        "the graph's runs (`runtime.reformat.block_input`) are measured apart likewise and counted in the rows "
        "of their stages, the feature extractor's and the output block's ("
        + "; ".join(f"{name}: {ms:.1f} ms in all" for name, ms in glue.items())
        + ").",
        "",
    ]
    write_report(out, report, "\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
