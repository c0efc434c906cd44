"""Adaptive execution: run time with and without it in one run, and the error it changes.

    python -m benchmarks.adaptive [--frames 5] [--out benchmarks/results]

Renders (once, resumable) a scene for each skip into data/adaptive/: a sunlit diffuse-only
scene (no specular signal), a metal-only scene (no diffuse signal), a static camera, a
sky-heavy scene and diffuse materials under a sky; the general validation set is
data/val/*. Three int8 pipelines run every frame, interleaved frame by frame, each with
its own history: ``full`` (adaptive off), ``exact`` (the default: the skips that leave
the output unchanged: pruned network variants + skipped filter paths, history used
without resampling on a static camera) and ``adaptive`` (exact + empty-tile skipping,
which passes background tiles through; ``PipelineConfig.tile_skip``, off by default). At each sequence's own size: FLIP and
PSNR against the reference, max |output - full output|. At --size (1280x720 -> 2560x1440; the
same frames resized): ms per frame. Also at --size: denoise only (``--native``, no
upsample block) against the full 2x pipeline. The process is tuned as `jnds run` tunes
its own (``common.tune_process``). Writes benchmarks/results/adaptive.md/json.
"""

from __future__ import annotations

import subprocess
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
    machine_info,
    machine_line,
    parse,
    parse_size,
    pipeline,
    resized_frames,
    run_frames,
    tune_process,
    write_report,
)
from jnds_deploy.artifacts import Manifest
from jnds_deploy.errors import ArtifactError
from jnds_deploy.io import open_sequence
from jnds_deploy.metrics import flip, psnr
from jnds_deploy.runtime import Pipeline
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS

SCENES = (  # scene, camera, seed, what it allows
    ("sunlit", "orbit", 3004, "diffuse only (no specular signal)"),
    ("metal", "orbit", 3001, "metal only (no diffuse signal)"),
    ("procedural", "static", 3003, "static camera"),
    ("sky", "orbit", 3002, "sky-heavy"),
    ("diffuse", "orbit", 3000, "diffuse materials under a sky (the sky is specular signal)"),
)
VARIANTS = {"full": {"adaptive": False}, "exact": {}, "adaptive": {"tile_skip": True}}


def ensure_scenes(data: Path) -> list[tuple[Path, str]]:
    from jnds_deploy.render.sequence import RenderConfig, render_sequence

    out = []
    for scene, camera, seed, what in SCENES:
        path = data / f"{scene}-{camera}-{seed}"
        cfg = RenderConfig(scene=scene, seed=seed, camera=camera, frames=10, size=(192, 108), spp=64)
        render_sequence(cfg, path, progress=False)  # resumes; nothing to do when complete
        out.append((path, what))
    return out


def pipelines(artifacts: str, **kw) -> dict[str, Pipeline]:
    return {k: pipeline(artifacts, precision="int8", **v, **kw) for k, v in VARIANTS.items()}


def error_run(artifacts: str, path: Path) -> dict:
    """Every frame at the sequence's own size through the three pipelines."""
    seq = open_sequence(path)
    pipes = pipelines(artifacts)
    rec = {k: {"flip": [], "psnr": [], "ms": []} for k in pipes}
    max_diff = {k: 0.0 for k in pipes}
    decisions = []
    for i in range(len(seq)):
        layers, cut = seq.inputs(i), seq.frames[i].camera_cut
        ref = seq.reference(i)["color"]
        results = {k: p(layers, cut) for k, p in pipes.items()}
        for k, r in results.items():
            rec[k]["flip"].append(flip(r.output, ref))
            rec[k]["psnr"].append(psnr(r.output, ref))
            rec[k]["ms"].append(r.ms["total"])
            max_diff[k] = max(max_diff[k], float(np.abs(r.output - results["full"].output).max()))
        decisions.append({k: v for k, v in results["adaptive"].decisions.items() if v})
    return {
        "frames": len(seq),
        "size": list(seq.native_size),
        "flip": {k: float(np.mean(v["flip"])) for k, v in rec.items()},
        "psnr": {k: float(np.mean(v["psnr"])) for k, v in rec.items()},
        "median_ms": {k: float(np.median(v["ms"])) for k, v in rec.items()},
        "max_abs_diff_vs_full": max_diff,
        "decisions": decisions,
    }


def interleaved_ms(pipes: dict[str, Pipeline], data: list[tuple[dict, bool]]) -> dict[str, list[dict]]:
    """Each pipeline's stage times on every frame, the pipelines interleaved frame by
    frame, after a warm-up frame each (sessions, numba, allocator)."""
    for p in pipes.values():
        p(*data[0])
        p.reset()
    return {k: [result.ms for result, _ in done] for k, done in run_frames(pipes, data).items()}


def timing_run(artifacts: str, path: Path, frames: int, size: tuple[int, int]) -> dict:
    """ms per frame at ``size`` for the three pipelines, interleaved frame by frame."""
    data = resized_frames(open_sequence(path), size)[:frames]
    stages = interleaved_ms(pipelines(artifacts), data)
    ms = {k: [t["total"] for t in v] for k, v in stages.items()}
    ratios = {k: [f / a for f, a in zip(ms["full"], ms[k])] for k in ms}
    return {
        "frames": len(data),
        "median_ms": {k: float(np.median(v)) for k, v in ms.items()},
        "speedup_median": {k: float(np.median(v)) for k, v in ratios.items()},
        "speedup_p10_p90": {k: [float(np.percentile(v, 10)), float(np.percentile(v, 90))] for k, v in ratios.items()},
        "stage_median_ms": {
            k: {s: float(np.median([t.get(s, 0.0) for t in v])) for s in sorted({s for t in v for s in t})}
            for k, v in stages.items()
        },
    }


def native_run(artifacts: str, path: Path, frames: int, size: tuple[int, int]) -> dict:
    data = resized_frames(open_sequence(path), size)[:frames]
    pipes = {
        "2x": pipeline(artifacts, precision="int8"),
        "native": pipeline(artifacts, precision="int8", native_output=True),
    }
    ms = {k: [t["total"] for t in v] for k, v in interleaved_ms(pipes, data).items()}
    return {
        "frames": len(data),
        "median_ms": {k: float(np.median(v)) for k, v in ms.items()},
        "speedup_median": float(np.median([a / b for a, b in zip(ms["2x"], ms["native"])])),
    }


def ensure_artifacts(artifacts: Path) -> None:
    """Exports and calibrates (qat) ``artifacts`` unless it holds qat int8 graphs with
    pruned variants."""
    try:
        if any("qat" in g.int8 and g.int8["qat"].variants for g in Manifest.load(artifacts).graphs.values()):
            return
    except ArtifactError:
        pass
    jnds = [sys.executable, "-m", "jnds_deploy"]
    subprocess.run([*jnds, "export", "--out", str(artifacts)], check=True, stdout=subprocess.DEVNULL)
    subprocess.run(
        [
            *jnds,
            "calibrate",
            "--artifacts",
            str(artifacts),
            "--data",
            str(ROOT / "samples" / "orbit-160x90"),
            "--method",
            "qat",
        ],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def main() -> int:
    ap = arguments(
        __doc__, RESULTS, "directory of adaptive.md and adaptive.json", smoke={"frames": 2, "size": "160x96"}
    )
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--data", default=str(ROOT / "data"), help="renders the scenes into DATA/adaptive; DATA/val")
    ap.add_argument("--frames", type=int, default=5, help="frames per sequence timed at --size")
    ap.add_argument("--size", default="1280x720", help="native size the timed frames are resized to")
    args = parse(ap)
    size = parse_size(args.size)
    tune_process()
    ensure_artifacts(Path(args.artifacts))
    if args.smoke:  # the bundled sample alone, nothing rendered
        scenes, val = [(ROOT / "samples" / "orbit-160x90", "the bundled sample")], []
    else:
        scenes = ensure_scenes(Path(args.data) / "adaptive")
        val = sorted(p for p in (Path(args.data) / "val").iterdir() if (p / "sequence.json").is_file())
    seqs = scenes + [(p, "validation") for p in val]

    steal = CpuSteal()
    manifest = Manifest.load(args.artifacts)
    upsample = (
        "one fixed upsample kernel, no upsample graph" if "upsample" not in manifest.graphs else "fp32 upsample graph"
    )
    report = {
        "command": command_line(),
        "machine": machine_line(),
        "machine_info": machine_info(),
        "upsample": upsample,
        "artifacts": args.artifacts,
        "precision": "int8",
        "size": list(size),
        "sequences": {},
    }
    for path, what in seqs:
        print(f"{path.name}: error at own size", flush=True)
        entry = {"what": what, "error": error_run(args.artifacts, path)}
        print(f"{path.name}: timing at {args.size}", flush=True)
        entry["timing_720p"] = timing_run(args.artifacts, path, args.frames, size)
        report["sequences"][path.name] = entry
    print(f"native output at {args.size}", flush=True)
    report["native_720p"] = native_run(args.artifacts, scenes[0][0], args.frames, size)
    report["cpu_steal_share"] = steal.share()

    write_report(Path(args.out) / "adaptive", report, markdown(report))
    print(markdown(report))
    return 0


def markdown(r: dict) -> str:
    w, h = r["size"]
    lines = [
        "# Adaptive execution: time and error, with and without",
        "",
        "Made by `python -m benchmarks.adaptive` on this machine "
        f"({cpu_line(r['machine_info'])}, {r['machine']}; int8 network graph, "
        f"{r.get('upsample', 'fp32 upsample graph')}, float32 filter stage). "
        "Three pipelines run the same frames interleaved frame by frame, each with its own history: "
        "**full** (`jnds run --no-adaptive`), **exact** (the default, `jnds run`: the skips that leave the "
        "output unchanged: pruned network variant and no filter path for a signal that is zero in the frame "
        "and its history; history used without resampling when nothing moves) and **adaptive** (exact + "
        "empty background tiles passed through the filter stage and, with an upsample graph, left out of it: "
        "`PipelineConfig(tile_skip=True)`, off by default). "
        f"CPU time stolen by the VM host during the run: {100 * r['cpu_steal_share']:.0f} %.",
        "",
        f"## Run time at {w}x{h} -> {2 * w}x{2 * h} (the sequences' frames resized)",
        "",
        "| sequence | allows | full ms | exact ms | adaptive ms | speed-up exact | speed-up adaptive (p10-p90) | what was skipped |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for name, e in r["sequences"].items():
        t = e["timing_720p"]
        m, s, pr = t["median_ms"], t["speedup_median"], t["speedup_p10_p90"]
        skipped = _skipped(e["error"]["decisions"])
        lines.append(
            f"| {name} | {e['what']} | {m['full']:.0f} | {m['exact']:.0f} | {m['adaptive']:.0f} | "
            f"{s['exact']:.3f} | {s['adaptive']:.3f} ({pr['adaptive'][0]:.2f}-{pr['adaptive'][1]:.2f}) | {skipped} |"
        )
    lines += [
        "",
        "Speed-up: per frame full ms / variant ms, median over the frames "
        f"({next(iter(r['sequences'].values()))['timing_720p']['frames']} per sequence after a warm-up frame).",
        "",
        "## Error at the sequences' own size (every frame)",
        "",
        "| sequence | FLIP full | FLIP exact | FLIP adaptive | ΔFLIP adaptive | PSNR full | PSNR adaptive | max abs diff exact vs full | max abs diff adaptive vs full |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    val = []
    for name, e in r["sequences"].items():
        x = e["error"]
        f, p, dm = x["flip"], x["psnr"], x["max_abs_diff_vs_full"]
        if e["what"] == "validation":
            val.append(x)
        lines.append(
            f"| {name} | {f['full']:.5f} | {f['exact']:.5f} | {f['adaptive']:.5f} | "
            f"{f['adaptive'] - f['full']:+.5f} | {p['full']:.2f} | {p['adaptive']:.2f} | {dm['exact']:.2e} | {dm['adaptive']:.2e} |"
        )
    if val:
        mf = {k: float(np.mean([x["flip"][k] for x in val])) for k in VARIANTS}
        lines += [
            "",
            f"Validation set mean FLIP: full {mf['full']:.5f}, exact {mf['exact']:.5f}, adaptive "
            f"{mf['adaptive']:.5f} (change {mf['adaptive'] - mf['full']:+.5f}).",
        ]
    n = r["native_720p"]
    lines += [
        "",
        "## Denoise only (`jnds run --native`): no upsample block",
        "",
        f"At {w}x{h}, {n['frames']} frames: 2x output {n['median_ms']['2x']:.0f} ms/frame, native output "
        f"{n['median_ms']['native']:.0f} ms/frame (network variant without the upsample features, no upsample "
        f"graph, no upsample filter): speed-up {n['speedup_median']:.2f}x.",
        "",
    ]
    return "\n".join(lines)


def _skipped(decisions: list[dict]) -> str:
    n = len(decisions)
    parts = []
    for key, label in (("skip_diffuse", "diffuse path"), ("skip_specular", "specular path"), ("static", "warp")):
        k = sum(1 for d in decisions if d.get(key))
        if k:
            parts.append(f"{label} {k}/{n} frames")
    tiles = [d.get("empty_tiles", 0) for d in decisions]
    if any(tiles):
        parts.append(f"empty tiles {np.mean(tiles):.0f}/frame")
    return ", ".join(parts) or "nothing"


if __name__ == "__main__":
    sys.exit(main())
