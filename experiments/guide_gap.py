"""Where the guide albedo differs from the albedo, is the model's excess error there?

    .venv/bin/python experiments/guide_gap.py --data data/val/cycles-* data/media/*
        [--checkpoint jnds_deploy/checkpoints/jnds.pt] [--threshold 0.1]
        [--out benchmarks/results/guide_gap]

The bet of ``ModelConfig.guide_albedo`` (docs/model-gap.md, "Where the gap is"): the model
loses to OIDN where Cycles' Denoising Albedo shows what the format's albedo does not (mirrors,
chrome, glass, sheen), because OIDN is given that guide and the model is not. Before training
anything, this splits each frame's pixels in two by the guide: "guided" where some channel of
``denoising_albedo`` differs from ``albedo`` by more than --threshold (at native resolution, each
native pixel standing for its scale x scale target pixels), "plain" elsewhere; and scores the
model (int8 fake quantization, as ``jnds evaluate``) and OIDN `balanced` + bicubic on each part
against the reference: the mean squared error of the LDR images ``metrics.psnr`` compares, over
all frames, as a PSNR. A sequence without the layer is refused.
Writes benchmarks/results/guide_gap.md and .json.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import RESULTS, arguments, command_line, cpu_line, machine_info, write_report  # noqa: E402
from jnds_deploy.checkpoint import default_checkpoint, load_model  # noqa: E402
from jnds_deploy.io import open_sequence  # noqa: E402
from jnds_deploy.layout import GUIDE  # noqa: E402
from jnds_deploy.metrics import to_ldr  # noqa: E402
from jnds_deploy.training.evaluate import baseline_outputs, model_outputs  # noqa: E402


def db(sq: float, n: int) -> float:
    return float(10 * np.log10(n / max(sq, 1e-12)))


def main() -> None:
    p = arguments(__doc__, RESULTS / "guide_gap")
    p.add_argument("--data", nargs="+", required=True)
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--threshold", type=float, default=0.1)
    args = p.parse_args()
    model = load_model(args.checkpoint or default_checkpoint())
    rows = {}
    for path in map(Path, args.data):
        seq = open_sequence(path)
        s = seq.target_size[0] // seq.native_size[0]
        ins = [seq.inputs(i) for i in range(len(seq))]
        if GUIDE.name not in ins[0]:
            raise SystemExit(f"{path}: no {GUIDE.name} layer")
        masks = [np.repeat(np.repeat(np.abs(a[GUIDE.name] - a["albedo"]).max(-1) > args.threshold, s, 0), s, 1)
                 for a in ins]
        refs = [to_ldr(seq.reference(i)["color"]) for i in range(len(seq))]
        outs = {"model": model_outputs(model, path), "oidn-balanced": baseline_outputs("oidn-balanced", path)}
        row = {"guided_share": float(np.mean([m.mean() for m in masks]))}
        for name, frames in outs.items():
            err = [(to_ldr(o) - r) ** 2 for o, r in zip(frames, refs)]
            for part, sel in (("guided", True), ("plain", False)):
                sq = sum(float(e[m == sel].sum()) for e, m in zip(err, masks))
                n = sum(int((m == sel).sum()) * 3 for m in masks)
                row[f"{name} {part}"] = db(sq, n) if n else None
        rows[path.name] = row
        print(path.name, {k: round(v, 3) if v is not None else None for k, v in row.items()}, flush=True)

    report = {"command": command_line(), "machine": machine_info(), "threshold": args.threshold, "sequences": rows}
    md = ["# The model's error where the guide albedo differs from the albedo", "",
          f"Command: `{report['command']}`  ",
          f"Machine: {cpu_line(report['machine'])}; checkpoint {args.checkpoint or 'shipped'}, int8 fake quantization", "",
          "PSNR (dB) of the LDR images over the pixels of each part; \"guided\": some channel of "
          f"`denoising_albedo` and `albedo` differ by more than {args.threshold}.", "",
          "| sequence | guided share | model guided | OIDN guided | gap guided | model plain | OIDN plain | gap plain |",
          "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name, r in rows.items():
        def gap(part):
            a, b = r[f"model {part}"], r[f"oidn-balanced {part}"]
            return f"{a - b:+.2f}" if a is not None and b is not None else "-"

        def f(v):
            return "-" if v is None else f"{v:.2f}"
        md.append(f"| {name} | {r['guided_share']:.3f} | {f(r['model guided'])} | {f(r['oidn-balanced guided'])} | "
                  f"{gap('guided')} | {f(r['model plain'])} | {f(r['oidn-balanced plain'])} | {gap('plain')} |")
    gaps = {part: [r[f"model {part}"] - r[f"oidn-balanced {part}"] for r in rows.values()
                   if r[f"model {part}"] is not None and r[f"oidn-balanced {part}"] is not None]
            for part in ("guided", "plain")}
    report["mean_gap_db"] = {k: float(np.mean(v)) for k, v in gaps.items() if v}
    md += ["", "Mean over sequences of the model's PSNR minus OIDN's: "
           + ", ".join(f"{k} {v:+.2f} dB" for k, v in report["mean_gap_db"].items()) + "."]
    write_report(args.out, report, "\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
