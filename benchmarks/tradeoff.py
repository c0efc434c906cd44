"""Run time against error on the validation set: the pipeline's variants and the baselines.

    python -m benchmarks.tradeoff --artifacts out/artifacts --data data/val [--only NAME ...]
        [--out benchmarks/results/tradeoff]

Every method turns each validation sequence into 2x frames, frame after frame; all are
scored against the reference by the same metrics (PSNR, SSIM, FLIP per frame, temporal
error per sequence, ``jnds_deploy.metrics``) and timed per frame (inputs already in
memory; median over all frames) in one process, at the sequences' own resolution, the
methods interleaved frame by frame; the default int8 pipeline's per-frame time ratio to
OIDN fast (the closest peer in time) is reported too. The process is tuned as `jnds run`
tunes its own (``common.tune_process``).

Methods: the JNDS pipeline in PyTorch fp32 (eager), ONNX fp32 and ONNX int8 for every
calibration method in the artifacts, filter stage float32 and float16; bicubic upscaling
of the noisy composite; OIDN fast / balanced / high at native resolution + bicubic; SVGF
at native resolution + bicubic. Writes benchmarks/results/tradeoff.md, tradeoff.json and
tradeoff.png (ms/frame against FLIP, Pareto front marked).
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
    cpu_line,
    machine_info,
    parse,
    pipeline,
    run_frames,
    spread,
    tune_process,
    write_report,
)
from jnds_deploy import baselines
from jnds_deploy.artifacts import Manifest
from jnds_deploy.io import expand_sequences, open_sequence
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS
from jnds_deploy.training.evaluate import ground_truth, mean_over_sequences, score_frames


class TorchPipeline:
    """The PyTorch model frame by frame (fp32 eager), with its own history."""

    def __init__(self, checkpoint, threads: int):
        import torch

        from jnds_deploy.checkpoint import load_fp32_model
        from jnds_deploy.layout import CURRENT

        torch.set_num_threads(threads)
        self.torch, self.layout = torch, CURRENT
        self.model = load_fp32_model(checkpoint)
        self.history = None

    def __call__(self, layers, cut):
        from jnds_deploy.model import pad_to_multiple

        t = self.torch
        h, w = layers["diffuse"].shape[:2]
        cur = t.from_numpy(np.concatenate([layers[n] for n, _ in self.layout], -1).transpose(2, 0, 1)[None].copy())
        mv = t.from_numpy(layers["motion"].transpose(2, 0, 1)[None].copy())
        m = self.model.cfg.pad_multiple
        cur, _ = pad_to_multiple(cur, m)
        mv, _ = pad_to_multiple(mv, m)
        if cut:
            self.history = None
        with t.no_grad():
            out = self.model(cur, mv, self.history)
        self.history = out.history()
        s = self.model.cfg.scale
        return out.output[0, :, : h * s, : w * s].permute(1, 2, 0).numpy()


def methods(artifacts: Path, threads: int) -> dict:
    """name -> factory() -> callable(layers, camera_cut) -> HWC output at target size."""
    from jnds_deploy.svgf import SVGF

    manifest = Manifest.load(artifacts)
    scale = manifest.scale
    out = {
        "bicubic (noisy)": lambda: lambda layers, c: baselines.bicubic(baselines.noisy_composite(layers), scale),
        **{
            f"OIDN {q} + bicubic": (lambda q=q: lambda layers, c: baselines.oidn_bicubic(layers, scale, quality=q))
            for q in ("fast", "balanced", "high")
        },
    }

    def svgf():
        s = SVGF()
        return lambda layers, c: baselines.bicubic(s(layers, c), scale)

    out["SVGF + bicubic"] = svgf
    out["JNDS PyTorch fp32 (eager)"] = lambda: TorchPipeline(manifest.checkpoint["path"], threads)

    def onnx(precision, dtype, method=None):
        return lambda: pipeline(artifacts, precision=precision, filter_dtype=dtype, threads=threads, int8_method=method)

    def first(p):
        return lambda layers, c: p(layers, c).output

    for dtype in ("float32", "float16"):
        out[f"JNDS ONNX fp32, filter {dtype}"] = lambda f=onnx("fp32", dtype): first(f())
    int8 = manifest.graphs["network"].int8
    for method in int8:
        out[f"JNDS ONNX int8 {method}, filter float32"] = lambda f=onnx("int8", "float32", method): first(f())
    if int8:
        default = manifest.int8_method
        out[f"JNDS ONNX int8 {default}, filter float16"] = lambda f=onnx("int8", "float16", default): first(f())
    return out


def pareto(points: dict[str, tuple[float, float]]) -> set[str]:
    """Names not dominated in (ms, FLIP), both lower is better."""
    front = set()
    for a, (ta, fa) in points.items():
        if not any((tb <= ta and fb <= fa) and (tb < ta or fb < fa) for b, (tb, fb) in points.items() if b != a):
            front.add(a)
    return front


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = {k: (v["ms_per_frame"], v["mean"]["flip"]) for k, v in report["methods"].items()}
    front = pareto(pts)
    fig, ax = plt.subplots(figsize=(9, 6))
    # JNDS variants cluster: label them in a column beside the cluster, sorted by FLIP
    jnds = sorted((n for n in pts if n.startswith("JNDS")), key=lambda n: pts[n][1])
    for name, (t, f) in pts.items():
        on = name in front
        ax.scatter(t, f, c="C3" if name.startswith("JNDS") else "C0", marker="o" if on else "x", s=40)
        if name in jnds:
            k = jnds.index(name)
            ax.annotate(
                name.replace("JNDS ", ""),
                (t, f),
                fontsize=6.5,
                xytext=(t * 1.15, f + 0.012 + 0.0055 * k),
                textcoords="data",
                arrowprops=dict(arrowstyle="-", lw=0.3, color="0.6"),
            )
        else:
            ax.annotate(name, (t, f), fontsize=7, xytext=(4, -10 if "high" in name else 3), textcoords="offset points")
    fr = sorted(pts[n] for n in front)
    ax.plot([p[0] for p in fr], [p[1] for p in fr], "k--", lw=0.8, label="Pareto front")
    ax.set_xscale("log")
    ax.set_xlabel(f"ms per frame ({report['size']}, {report['threads']} threads, this CPU)")
    ax.set_ylabel("FLIP (lower is better)")
    ax.set_title("Run time against error, validation set (red: JNDS variants)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> int:
    ap = arguments(__doc__, RESULTS / "tradeoff", smoke={"data": [str(ROOT / "samples" / "orbit-160x90")], "frames": 3})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--data", nargs="+", default=["data/val"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--frames", type=int, default=None, help="the first frames of each sequence (default: all)")
    ap.add_argument("--only", nargs="*", default=None, help="substrings of method names to run")
    ap.add_argument("--plot-only", action="store_true", help="redraw the PNG from the JSON")
    args = parse(ap)
    if args.plot_only:
        out = Path(args.out)
        plot(json.loads(out.with_suffix(".json").read_text()), out.with_suffix(".png"))
        return 0
    tune_process()
    seqs = expand_sequences(args.data)
    first = slice(None, args.frames)
    truth = {p: tuple(t[first] for t in ground_truth(p)) for p in seqs}
    opened = {p: open_sequence(p) for p in seqs}
    inputs = {p: [(s.inputs(i), f.camera_cut) for i, f in enumerate(s.frames)][first] for p, s in opened.items()}
    report = {
        "command": command_line(),
        "threads": args.threads,
        "size": "x".join(map(str, opened[seqs[0]].native_size)) + " native",
        "sequences": [p.name for p in seqs],
        "methods": {},
    }
    factories = {
        name: f
        for name, f in methods(Path(args.artifacts), args.threads).items()
        if not args.only or any(s in name for s in args.only)
    }
    # interleaved: every method runs frame t before any runs frame t + 1 (each with its own
    # history), so that all see the same machine state (common.run_frames)
    ms = {name: [] for name in factories}
    per_seq = {name: {} for name in factories}
    for p in seqs:
        for f in factories.values():
            f()(*inputs[p][0])  # warm-up (numba compilation, session start), then from the first frame
        done = run_frames({name: f() for name, f in factories.items()}, inputs[p])
        for name, frames in done.items():
            ms[name] += [t for _, t in frames]
            per_seq[name][p.name] = score_frames([out for out, _ in frames], *truth[p][:3], masks=truth[p][3])
        print(f"{p.name}: done", flush=True)
    for name in factories:
        report["methods"][name] = {
            "mean": mean_over_sequences(per_seq[name]),
            "ms_per_frame": float(np.median(ms[name])),
            "ms_p90": float(np.percentile(ms[name], 90)),
            "sequences": per_seq[name],
        }
        m = report["methods"][name]
        print(
            f"{name}: {m['ms_per_frame']:.1f} ms, PSNR {m['mean']['psnr']:.2f}, FLIP {m['mean']['flip']:.4f}, "
            f"temporal {m['mean']['temporal']:.5f}",
            flush=True,
        )
    # the closest peer in time: the default int8 pipeline against OIDN fast, frame by frame
    default = f"JNDS ONNX int8 {Manifest.load(args.artifacts).int8_method or ''}, filter float32"
    if default in ms and "OIDN fast + bicubic" in ms:
        r = np.array(ms[default]) / np.array(ms["OIDN fast + bicubic"])
        report["head_to_head"] = {
            "method": default,
            "peer": "OIDN fast + bicubic",
            "frames": int(r.size),
            **spread(r, "ratio_"),
        }
    front = pareto({k: (v["ms_per_frame"], v["mean"]["flip"]) for k, v in report["methods"].items()})
    out = Path(args.out)
    lines = [
        "# Run time against error (validation set)",
        "",
        f"Command: `{report['command']}`  ",
        f"Machine: {cpu_line(machine_info())}.  ",
        f"{len(seqs)} sequences, {report['size']} → 2×, {args.threads} threads; ms per frame is the "
        "median over all frames (inputs in memory), all methods in one process, interleaved frame by "
        "frame (each with its own history).",
        "",
        "| method | ms/frame | PSNR dB ↑ | SSIM ↑ | FLIP ↓ | temporal error ↓ | Pareto |",
        "| --- | ---: | ---: | ---: | ---: | ---: | :---: |",
    ]
    for name, v in sorted(report["methods"].items(), key=lambda kv: kv[1]["ms_per_frame"]):
        m = v["mean"]
        lines.append(
            f"| {name} | {v['ms_per_frame']:.1f} | {m['psnr']:.2f} | {m['ssim']:.4f} | {m['flip']:.4f} | "
            f"{m['temporal']:.5f} | {'●' if name in front else ''} |"
        )
    if "head_to_head" in report:
        h = report["head_to_head"]
        lines += [
            "",
            f"Per frame, {h['method']} took {h['ratio_median']:.2f}× the time of {h['peer']} (median "
            f"of {h['frames']} frames, p10–p90 {h['ratio_p10']:.2f}–{h['ratio_p90']:.2f}).",
        ]
    lines += ["", f"![ms/frame against FLIP]({out.with_suffix('.png').name})", ""]
    write_report(out, report, "\n".join(lines))
    plot(report, out.with_suffix(".png"))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
