"""Numerical stability of the pipeline: long runs, int8 outside the calibration range,
NaN floods, fp16 limits, and fuzzing with a larger budget than the tests.

    python -m benchmarks.stability [--data data/val]
        [--long-frames 1008] [--fuzz 2000] [--out benchmarks/results/stability]

Cases (each states what it checks; the figures go to benchmarks/results/stability.md,
.json and stability_drift.png):
1. long run: each validation sequence looped to --long-frames frames, the loop seam NOT
   flagged as a cut (the history runs through all of it), int8 pipeline: the output's
   mean brightness against the reference's, per frame; drift = slope of that ratio per
   1000 frames (least squares) and the ratio of the last loop against the first; the
   largest history value seen.
2. int8 outside the calibration range: the radiance of the validation frames times
   1 ... 4096 (the calibration saw x1); int8 against fp32 output, relative mean error
   and PSNR (tonemapped), 6 frames per sequence with history.
3. NaN floods: a fraction of diffuse pixels set to NaN (0.1 % ... 100 %); output finite,
   PSNR of the output against the clean run's.
4. fp16 filter stage near and beyond 65504: peak radiance 1e3 ... 1e6; fp16 against
   fp32 filter stage, relative mean error.
5. fuzzing: --fuzz random frames (sizes 1-64, values log-uniform over 1e-30 ... 1e30 with
   random sign, NaN/Inf sprinkled in) through the pipeline; failures = exception, or
   output not finite or negative. --fuzz byte-damaged EXR files through the reader;
   failures = anything but ExrReadError.
"""

from __future__ import annotations

import platform
import sys
import time
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
    tune_process,
    write_report,
)
from jnds_deploy.errors import ExrReadError
from jnds_deploy.io import INPUT_LAYERS, exr_bytes, find_sequences, open_sequence, read_exr_bytes
from jnds_deploy.layout import INPUT_CHANNELS
from jnds_deploy.runtime import Pipeline
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS

STEADY_LOOPS = 10
SCALES = (1, 4, 16, 64, 256, 1024, 4096)  # radiance x k beyond the calibration range, int8 against fp32
FRACTIONS = (0.001, 0.01, 0.1, 1.0)  # of the diffuse radiance's pixels made NaN
PEAKS = (1e3, 3e4, 6e4, 65535.0, 1e6)  # the specular radiance's peak, float16 filter stage against float32


def tonemapped_psnr(a: np.ndarray, b: np.ndarray) -> float:
    ta, tb = np.log1p(np.maximum(a, 0)), np.log1p(np.maximum(b, 0))
    mse = float(np.mean((ta - tb) ** 2))
    peak = max(float(tb.max()), 1e-6)
    return float("inf") if mse == 0 else 10 * np.log10(peak**2 / mse)


def long_run(pipe: Pipeline, seq, frames: int) -> dict:
    inputs = [seq.inputs(i) for i in range(len(seq))]
    refs = [seq.reference(i)["color"].mean() for i in range(len(seq))]
    pipe.reset()
    ratio, hist_max, rejected = [], 0.0, 0
    for t in range(frames):
        i = t % len(seq)
        # the sequence's own cuts are flagged in every loop; the loop seam is not
        result = pipe(inputs[i], camera_cut=t == 0 or seq.frames[i].camera_cut)
        ratio.append(float(np.mean(result.output, dtype=np.float64) / refs[i]))
        hist_max = max(hist_max, float(pipe.history.frame[..., :6].max()))
        rejected += result.rejected
        assert np.isfinite(result.output).all()
    r = np.array(ratio)
    n = len(seq)
    steady = STEADY_LOOPS * n  # the recurrence settles within a few loops; drift is measured after
    slope = float(np.polyfit(np.arange(steady, frames), r[steady:], 1)[0]) * 1000
    return {
        "sequence": seq.path.name,
        "frames": frames,
        "ratio": ratio,
        "drift_per_1000": slope,
        "first_loop_ratio": float(r[:n].mean()),
        "steady_ratio": float(r[steady : steady + n].mean()),
        "last_loop_ratio": float(r[-n:].mean()),
        "rejected_tiles": rejected,
        "history_max": hist_max,
        "output_ratio_min": float(r.min()),
        "output_ratio_max": float(r.max()),
    }


def run_frames(pipe: Pipeline, frames: list[dict]) -> list[np.ndarray]:
    pipe.reset()
    return [pipe(f, camera_cut=i == 0).output for i, f in enumerate(frames)]


def scaled(frames: list[dict], k: float) -> list[dict]:
    return [{**f, "diffuse": f["diffuse"] * np.float32(k), "specular": f["specular"] * np.float32(k)} for f in frames]


def fuzz_frames(pipe: Pipeline, n: int, rng: np.random.Generator) -> dict:
    failures, examples = 0, []
    for _ in range(n):
        h, w = int(rng.integers(1, 65)), int(rng.integers(1, 65))
        layers = {}
        for name, c in INPUT_CHANNELS.items():
            a = (10.0 ** rng.uniform(-30, 30, (h, w, c))) * rng.choice([-1.0, 1.0], (h, w, c))
            special = rng.random((h, w, c))
            a[special < 0.01] = np.nan
            a[(special >= 0.01) & (special < 0.02)] = np.inf
            a[(special >= 0.02) & (special < 0.03)] = -np.inf
            layers[name] = a.astype(np.float32)
        try:
            out = pipe(layers, camera_cut=bool(rng.random() < 0.3)).output
            ok = np.isfinite(out).all() and out.min() >= 0 and out.shape == (2 * h, 2 * w, 3)
        except Exception as exc:  # counted and reported
            ok, out = False, repr(exc)
        if not ok:
            failures += 1
            examples.append(f"{w}x{h}: {out if isinstance(out, str) else 'non-finite or negative output'}")
    return {"frames": n, "failures": failures, "examples": examples[:5]}


def fuzz_exr(n: int, rng: np.random.Generator) -> dict:
    base = rng.random((7, 9, 3)).astype(np.float32)
    layers = {k: np.repeat(base[..., :1], len(v), -1) if k != "diffuse" else base for k, v in INPUT_LAYERS.items()}
    data0 = exr_bytes(layers, INPUT_LAYERS)
    failures, read_ok, examples = 0, 0, []
    for _ in range(n):
        data = bytearray(data0[: int(rng.integers(0, len(data0) + 1))])
        for _ in range(int(rng.integers(0, 9))):
            if data:
                data[int(rng.integers(0, len(data)))] = int(rng.integers(0, 256))
        try:
            read_exr_bytes(bytes(data), "fuzz")
            read_ok += 1
        except ExrReadError:
            pass
        except Exception as exc:
            failures += 1
            examples.append(repr(exc))
    return {"files": n, "failures": failures, "read": read_ok, "examples": examples[:5]}


def main() -> int:
    ap = arguments(__doc__, RESULTS / "stability", smoke={"data": str(ROOT / "samples"), "long_frames": 96, "fuzz": 20})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--data", default="data/val")
    ap.add_argument("--long-frames", type=int, default=1008)
    ap.add_argument("--fuzz", type=int, default=2000)
    args = parse(ap)
    tune_process()
    t_start = time.time()
    seqs = [open_sequence(p) for p in find_sequences(args.data)]
    int8 = pipeline(args.artifacts, precision="int8")
    fp32 = pipeline(args.artifacts, precision="fp32")
    f16 = pipeline(args.artifacts, precision="fp32", filter_dtype="float16")
    report = {
        "command": command_line(),
        "machine": platform.platform(),
        "machine_info": machine_info(),
        "artifacts": args.artifacts,
        "data": args.data,
    }

    report["long"] = [long_run(int8, s, args.long_frames) for s in seqs]
    for r in report["long"]:
        print(
            f"long {r['sequence']}: drift {r['drift_per_1000']:+.4f}/1000 frames, "
            f"loop ratio {r['first_loop_ratio']:.4f} -> {r['last_loop_ratio']:.4f}",
            flush=True,
        )

    clips = [[s.inputs(i) for i in range(min(3 if args.smoke else 6, len(s)))] for s in seqs]
    # a smoke run takes the ends of each range
    scales, fractions, peaks = ((1, 4096), (0.01, 1.0), (6e4, 1e6)) if args.smoke else (SCALES, FRACTIONS, PEAKS)
    growth = []
    for k in scales:
        rel, ps = [], []
        for clip in clips:
            a, b = run_frames(int8, scaled(clip, k)), run_frames(fp32, scaled(clip, k))
            rel += [float(np.abs(x - y).mean() / max(np.abs(y).mean(), 1e-12)) for x, y in zip(a, b)]
            ps += [tonemapped_psnr(x, y) for x, y in zip(a, b)]
        growth.append({"scale": k, "rel_mean_error": float(np.mean(rel)), "psnr_db": float(np.median(ps))})
        print(f"int8 x{k}: rel err {growth[-1]['rel_mean_error']:.4f}, PSNR {growth[-1]['psnr_db']:.1f}", flush=True)
    report["int8_range"] = growth

    rng = np.random.default_rng(0)
    floods = []
    for frac in fractions:
        ps, finite = [], True
        for clip in clips:
            clean = run_frames(int8, clip)
            dirty = []
            for f in clip:
                d = f["diffuse"].copy()
                d[rng.random(d.shape[:2]) < frac] = np.nan
                dirty.append({**f, "diffuse": d})
            outs = run_frames(int8, dirty)
            finite &= all(np.isfinite(o).all() and o.min() >= 0 for o in outs)
            ps += [tonemapped_psnr(o, c) for o, c in zip(outs, clean)]
        floods.append(
            {"nan_fraction": frac, "finite_nonnegative": bool(finite), "psnr_vs_clean_db": float(np.median(ps))}
        )
        print(f"NaN {frac:.1%}: finite {finite}, PSNR vs clean {floods[-1]['psnr_vs_clean_db']:.1f}", flush=True)
    report["nan_floods"] = floods

    fp16 = []
    for peak in peaks:
        rel, finite = [], True
        for clip in clips[:3]:
            bright = [
                {**f, "specular": f["specular"] * np.float32(peak / max(float(f["specular"].max()), 1e-6))}
                for f in clip
            ]
            a, b = run_frames(f16, bright), run_frames(fp32, bright)
            finite &= all(np.isfinite(x).all() for x in a)
            rel += [float(np.abs(x - y).mean() / max(np.abs(y).mean(), 1e-12)) for x, y in zip(a, b)]
        fp16.append({"peak": peak, "finite": bool(finite), "rel_mean_error": float(np.mean(rel))})
        print(f"fp16 peak {peak:g}: finite {finite}, rel err {fp16[-1]['rel_mean_error']:.2e}", flush=True)
    report["fp16"] = fp16

    report["fuzz_frames"] = fuzz_frames(fp32, args.fuzz, np.random.default_rng(1))
    report["fuzz_exr"] = fuzz_exr(args.fuzz, np.random.default_rng(2))
    print(f"fuzz: {report['fuzz_frames']}, {report['fuzz_exr']}", flush=True)
    report["wall_s"] = time.time() - t_start

    out = Path(args.out)
    write_report(out, report, markdown(report, args))
    plot(report, out)
    print(out.with_suffix(".md").read_text())
    return 0


def markdown(r: dict, args) -> str:
    md = [
        "# Numerical stability",
        "",
        f"Command: `{r['command']}`  ",
        f"Machine: {cpu_line(r['machine_info'])}, {r['machine']}; artifacts {r['artifacts']} (the shipped checkpoint); data {r['data']}; "
        f"{r['wall_s'] / 60:.1f} min. Correctness cases with pass/fail are in `tests/runtime/test_stability.py` "
        "(extreme radiance, zero/constant frames, black albedo, broken motion, sizes 1x1 to 1921x1081, fp16 "
        "overflow, the finite-output property, fuzzed EXR and sequence.json, broken frames in `jnds run`) and "
        "`tests/runtime/test_pipeline.py` (NaN/Inf per layer, cuts, resolution changes).",
        "",
        f"## 1. Long runs ({args.long_frames} frames per validation sequence, looped, seams not flagged as cuts, int8)",
        "",
        "Checks: output finite every frame; brightness (mean output / mean reference) does not drift; history "
        f"bounded. Drift: least-squares slope of the brightness ratio per 1000 frames, after the first "
        f"{STEADY_LOOPS} loops (the recurrence settles to its steady state within them); the ratio in the first "
        f"loop, in loop {STEADY_LOOPS + 1} and in the last loop; history tiles restarted by the rejection test.",
        "",
        "| sequence | drift per 1000 frames | first loop | loop 11 | last loop | min–max | max history radiance "
        "| rejected tiles |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for x in r["long"]:
        md.append(
            f"| {x['sequence']} | {x['drift_per_1000']:+.4f} | {x['first_loop_ratio']:.4f} | "
            f"{x['steady_ratio']:.4f} | {x['last_loop_ratio']:.4f} | {x['output_ratio_min']:.3f}–"
            f"{x['output_ratio_max']:.3f} | {x['history_max']:.1f} | {x['rejected_tiles']} |"
        )
    md += [
        "",
        "Before the history rejection test (`REJECT_RATIO` in `jnds_deploy/runtime/history.py`), the same "
        "run grew without bound on procedural-dolly-2001 (brightness ratio 7.4e4 at frame 100, 6.4e17 at 300, "
        "history radiance 7.9e37) and procedural-static-2000 (static camera: 23 at frame 300, Inf by 1000, "
        "history 6.9e37): the checkpoint shipped then (runs/small, L1 loss) had temporal kernels summing to "
        "about 2.3 with blend weights about 0.7, and the 6-frame training unrolls never saw the loop gain exceed 1. The test rejects nothing on "
        "the 12-frame validation sequences (outputs unchanged).",
    ]
    md += [
        "",
        "Plot: `stability_drift.png` (output/reference mean brightness per frame).",
        "",
        "## 2. int8 outside the calibration range",
        "",
        "Checks: int8 against fp32 as the input radiance is scaled beyond what calibration saw (x1).",
        "",
        "| radiance scale | int8 vs fp32 relative mean error | PSNR (log-tonemapped) dB |",
        "| ---: | ---: | ---: |",
    ]
    for x in r["int8_range"]:
        md.append(f"| x{x['scale']} | {x['rel_mean_error']:.4f} | {x['psnr_db']:.1f} |")
    md += [
        "",
        "## 3. NaN floods in the diffuse input (int8)",
        "",
        "Checks: NaN replaced before the network; output finite and non-negative; how far it moves from the clean run.",
        "",
        "| NaN pixels | output finite, >= 0 | PSNR vs clean run dB |",
        "| ---: | :---: | ---: |",
    ]
    for x in r["nan_floods"]:
        md.append(
            f"| {x['nan_fraction']:.1%} | {'yes' if x['finite_nonnegative'] else 'NO'} | {x['psnr_vs_clean_db']:.1f} |"
        )
    md += [
        "",
        "## 4. float16 filter stage near and beyond the half range (65504)",
        "",
        "Checks: frames brighter than 2048 are filtered scaled down by a power of two; output finite and close to "
        "the float32 filter stage.",
        "",
        "| peak specular radiance | finite | fp16 vs fp32 relative mean error |",
        "| ---: | :---: | ---: |",
    ]
    for x in r["fp16"]:
        md.append(f"| {x['peak']:g} | {'yes' if x['finite'] else 'NO'} | {x['rel_mean_error']:.2e} |")
    fz, fe = r["fuzz_frames"], r["fuzz_exr"]
    md += [
        "",
        "## 5. Fuzzing",
        "",
        f"- {fz['frames']} random frames (sizes 1–64, |values| log-uniform 1e-30…1e30, either sign, 1 % NaN, "
        f"1 % +Inf, 1 % -Inf per layer): {fz['failures']} failures (exception, non-finite or negative output)."
        + (f" Examples: {fz['examples']}" if fz["examples"] else ""),
        f"- {fe['files']} byte-damaged EXR files (truncated, up to 8 bytes overwritten): {fe['failures']} failures "
        f"(anything but `ExrReadError`); {fe['read']} were still readable."
        + (f" Examples: {fe['examples']}" if fe["examples"] else ""),
        "",
    ]
    return "\n".join(md)


def plot(r: dict, out: Path) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    plt.figure(figsize=(8, 3.5))
    for x in r["long"]:
        plt.plot(x["ratio"], lw=0.6, label=x["sequence"])
    plt.xlabel("frame")
    plt.ylabel("mean output / mean reference")
    plt.title("Brightness over long looped runs (int8)")
    plt.legend(fontsize=6, ncol=3)
    plt.tight_layout()
    plt.savefig(out.parent / f"{out.name}_drift.png", dpi=100)


if __name__ == "__main__":
    sys.exit(main())
