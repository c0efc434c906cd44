"""The firefly clamp's factor against error: the deployed int8 pipeline at each factor
(``PipelineConfig.firefly_clamp``; 0: off), beside OIDN `balanced` + bicubic.

    python -m benchmarks.firefly_clamp --input data/val
        [--factors 0 2 4 8 16] [--baselines oidn-balanced] [--sheet PNG] [--out benchmarks/results/firefly_clamp]

Every sequence given (or found in a directory given), every frame, history carried;
scored as `jnds evaluate` scores (``training.evaluate.evaluate_methods``: mean per-frame
PSNR, SSIM, FLIP and the sequence's temporal error). Choose a factor on validation only:
a test or holdout set given here is for the report, not the choice. ``--sheet``: a
contact sheet of each sequence's middle frame (input, each factor, baselines,
reference).
"""

from __future__ import annotations

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
from jnds_deploy.io import expand_sequences, open_sequence
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS
from jnds_deploy.training.evaluate import baseline_outputs, evaluate_methods


def runner(artifacts: str, factor: float):
    pipe = pipeline(artifacts, precision="int8", firefly_clamp=factor)

    def run(path: Path) -> list[np.ndarray]:
        seq = open_sequence(path)
        pipe.reset()
        return [pipe(seq.inputs(i), camera_cut=seq.frames[i].camera_cut).output for i in range(len(seq))]

    return run


def main() -> None:
    ap = arguments(
        __doc__,
        RESULTS / "firefly_clamp",
        smoke={"input": [str(ROOT / "samples" / "orbit-160x90")], "factors": [0, 16], "baselines": ["bicubic"]},
    )
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--input", nargs="+", help="sequences with references, or directories of them (required)")
    ap.add_argument("--factors", type=float, nargs="+", default=[0, 2, 4, 8, 16])
    ap.add_argument("--baselines", nargs="*", default=["oidn-balanced"])
    ap.add_argument("--sheet", help="contact sheet PNG (middle frames)")
    args = parse(ap)
    if not args.input:
        ap.error("--input is required")
    tune_process()
    paths = expand_sequences(args.input)
    methods = {f"int8 k={f:g}": runner(args.artifacts, f) for f in args.factors}
    methods.update({b: (lambda p, b=b: baseline_outputs(b, p)) for b in args.baselines})
    shown = {} if args.sheet else None
    report = evaluate_methods(paths, methods, shown=shown)
    if args.sheet:
        from jnds_deploy import contact_sheet

        contact_sheet.write(args.sheet, [(p.name, shown[p.name]) for p in paths])
    names = list(report)
    md = [
        "# The firefly clamp's factor against error (int8 pipeline)",
        "",
        f"`{command_line()}`",
        "",
        f"Machine: {cpu_line(machine_info())}. Sequences: {', '.join(str(p) for p in paths)}. "
        "k=0: no clamp. Means over sequences of the mean per-frame PSNR / SSIM / FLIP and the temporal "
        "error (`jnds evaluate`'s metrics).",
        "",
        "| method | PSNR (dB) | SSIM | FLIP | temporal error |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for n in names:
        m = report[n]["mean"]
        md.append(f"| {n} | {m['psnr']:.2f} | {m['ssim']:.4f} | {m['flip']:.4f} | {m['temporal']:.5f} |")
    md += [
        "",
        "Per sequence, PSNR / FLIP / temporal error:",
        "",
        "| sequence | " + " | ".join(names) + " |",
        "| --- |" + " --- |" * len(names),
    ]
    for seq in report[names[0]]["sequences"]:
        cells = [report[n]["sequences"][seq] for n in names]
        md.append(
            f"| {seq} | " + " | ".join(f"{c['psnr']:.2f} / {c['flip']:.4f} / {c['temporal']:.4f}" for c in cells) + " |"
        )
    write_report(
        Path(args.out),
        {
            "command": command_line(),
            "machine": machine_info(),
            "sequences": [str(p) for p in paths],
            "factors": args.factors,
            "report": report,
        },
        "\n".join(md) + "\n",
    )
    print("\n".join(md))


if __name__ == "__main__":
    main()
