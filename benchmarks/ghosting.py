"""Ghost trails: the pipeline against a single-frame denoiser where the previous frame showed
another surface.

    python -m benchmarks.ghosting --data data/ghost-test [--before out/before]

For every sequence of --data (directories of sequences with references; the ghosting sets
of docs/ghosting.md), per method: PSNR, FLIP, the temporal error and the changed-pixel PSNR
(``metrics.changed_mask``: where the previous frame showed another surface, pooled over the
frames after the first). Methods: the int8 and fp32 pipelines, OIDN ``balanced`` + bicubic
(``baselines``) and, with ``--before DIR``, the frames another version of `jnds run` wrote
to DIR/<sequence>/ (e.g. the commit before a change, run from a worktree of it).
Writes OUT.json/.md, OUT.jpg (per sequence the frame with the most changed pixels: input,
OIDN, before, int8 output, reference, the changed pixels marked) and OUT.mp4 (every frame of
every sequence side by side: OIDN, before, int8 output, reference).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from benchmarks.common import RESULTS, ROOT, arguments, command_line, cpu_line, machine_info, parse, write_report
from jnds_deploy import baselines, contact_sheet, video
from jnds_deploy.io import OUTPUT_LAYERS, expand_sequences, open_sequence, read_layers
from jnds_deploy.runtime import Pipeline, PipelineConfig
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS
from jnds_deploy.training.evaluate import ground_truth, mean_over_sequences, score_frames

KEYS = ("psnr", "flip", "temporal", "changed_psnr")


def outputs(seq_path: Path, args) -> dict[str, list[np.ndarray]]:
    """Every method's frames of one sequence (HWC, target resolution)."""
    seq = open_sequence(seq_path)
    inputs = [seq.inputs(i) for i in range(len(seq))]
    scale = seq.target_size[0] // seq.native_size[0]
    methods = {"OIDN balanced + bicubic": [baselines.oidn_bicubic(a, scale) for a in inputs]}
    if args.before:
        d = Path(args.before) / seq_path.name
        methods["before"] = [
            read_layers(d / f"{i:04d}.exr", seq.target_size, OUTPUT_LAYERS)["color"] for i in range(len(seq))
        ]
    for precision in args.precision:
        pipe = Pipeline(PipelineConfig(artifacts=args.artifacts, precision=precision))
        methods[f"JNDS {precision}"] = [pipe(a, f.camera_cut).output for a, f in zip(inputs, seq.frames)]
    return methods


def markdown(report: dict) -> str:
    methods = list(report["mean"])
    int8 = next(m for m in methods if m.startswith("JNDS"))
    lines = [
        "# Ghost trails: changed-pixel PSNR against a single-frame denoiser",
        "",
        f"`{report['command']}`",
        "",
        f"{cpu_line(report['machine'])}, {report['machine']['usable_cores']} cores",
        "",
        "Changed pixels: where the previous frame showed another surface (`metrics.changed_mask`, "
        "docs/ghosting.md); their PSNR is pooled over every frame after the first. "
        "Display values (Reinhard, gamma 1/2.2) as every metric of the project.",
        "",
        "## Per sequence: changed-pixel PSNR (dB)",
        "",
        "| sequence | changed | " + " | ".join(methods) + f" | {int8} - OIDN |",
        "| --- | ---: |" + " ---: |" * (len(methods) + 1),
    ]
    for name, per in report["sequences"].items():
        oidn = per["OIDN balanced + bicubic"]["changed_psnr"]
        cells = [f"{per[m]['changed_psnr']:.2f}" for m in methods]
        lines.append(
            f"| {name} | {100 * per[int8]['changed_fraction']:.1f} % | "
            + " | ".join(cells)
            + f" | {per[int8]['changed_psnr'] - oidn:+.2f} |"
        )
    lines += [
        "",
        "## Mean over the sequences",
        "",
        "| method | PSNR (dB) ↑ | FLIP ↓ | temporal error ↓ | changed-pixel PSNR (dB) ↑ |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for m in methods:
        v = report["mean"][m]
        lines.append(f"| {m} | {v['psnr']:.2f} | {v['flip']:.4f} | {v['temporal']:.5f} | {v['changed_psnr']:.2f} |")
    lines += [
        "",
        "## Per sequence: PSNR (dB) / FLIP",
        "",
        "| sequence | " + " | ".join(methods) + " |",
        "| --- |" + " ---: |" * len(methods),
    ]
    for name, per in report["sequences"].items():
        lines.append(
            f"| {name} | " + " | ".join(f"{per[m]['psnr']:.2f} / {per[m]['flip']:.4f}" for m in methods) + " |"
        )
    lines += [
        "",
        f"Contact sheet: [{report['sheet']}]({report['sheet']}); video: [{report['video']}]({report['video']}).",
        "",
    ]
    return "\n".join(lines)


def main() -> int:
    ap = arguments(__doc__, RESULTS / "ghosting", smoke={"data": [str(ROOT / "samples")]})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--data", nargs="+", default=["data/ghost-test"])
    ap.add_argument("--before", default=None, help="DIR/<sequence>/NNNN.exr: another version's `jnds run` frames")
    ap.add_argument("--precision", nargs="+", default=["int8", "fp32"])
    args = parse(ap)
    out = Path(args.out)
    per_seq, rows, clips = {}, [], []
    for p in expand_sequences(args.data):
        methods = outputs(p, args)
        refs, motions, cuts, masks = ground_truth(p)
        per_seq[p.name] = {m: score_frames(o, refs, motions, cuts, masks=masks) for m, o in methods.items()}
        print(p.name, {m: round(v["changed_psnr"], 2) for m, v in per_seq[p.name].items()}, flush=True)
        seq = open_sequence(p)
        shown = {m: o for m, o in methods.items() if m != "JNDS fp32"}
        t = int(np.argmax([0 if m is None else m.mean() for m in masks]))
        rows.append(
            (
                f"{p.name} {t}",
                {
                    "input": baselines.noisy_composite(seq.inputs(t)),
                    **{m: o[t] for m, o in shown.items()},
                    "reference": refs[t],
                    "changed pixels": contact_sheet.mark(refs[t], masks[t]),
                },
            )
        )
        for i in range(len(refs)):
            frame = video.side_by_side(f"{p.name} {i}", {**{m: o[i] for m, o in shown.items()}, "reference": refs[i]})
            if clips and frame.shape != clips[0].shape:  # one video: every frame at the first one's size
                frame = cv2.resize(frame, clips[0].shape[1::-1], interpolation=cv2.INTER_AREA)
            clips.append(frame)
    first = next(iter(per_seq.values()))
    report = {
        "command": command_line(),
        "machine": machine_info(),
        "mean": {m: mean_over_sequences({s: per[m] for s, per in per_seq.items()}) for m in first},
        "sequences": per_seq,
        "sheet": out.with_suffix(".jpg").name,
        "video": out.with_suffix(".mp4").name,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    contact_sheet.write(out.with_suffix(".jpg"), rows)
    video.write_mp4(out.with_suffix(".mp4"), clips, fps=4)
    write_report(out, report, markdown(report))
    print(f"wrote {out}.md/.json/.jpg/.mp4")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
