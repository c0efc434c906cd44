"""What the history gives: the model with no history, with history as the paper uses it,
and with the geometric history rejection (``filters.disoccluded``, the default).

    .venv/bin/python experiments/history_gain.py --data data/val data/adaptive [--checkpoint CKPT]
        [--baseline oidn-balanced] [--out benchmarks/results/history_gain]

PyTorch, the shipped checkpoint (or --checkpoint; int8 fake quantization where QAT-trained), every
frame of every sequence. "no history": every frame is run as a first frame (the current
inputs stand in for the history). "history, no rejection": the warped history is used
everywhere. Per sequence: mean PSNR, FLIP and temporal error (``jnds_deploy.metrics``),
and per-frame PSNR; ``--baseline`` adds a baseline's per-frame PSNR (``jnds evaluate``'s
baselines), to see whether the history makes up for the single frame's error (frame 0
has none). Writes benchmarks/results/history_gain.md and .json.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import RESULTS, arguments, command_line, write_report  # noqa: E402
from jnds_deploy import filters  # noqa: E402
from jnds_deploy.checkpoint import default_checkpoint, load_model  # noqa: E402
from jnds_deploy.io import expand_sequences  # noqa: E402
from jnds_deploy.metrics import psnr  # noqa: E402
from jnds_deploy.training.data import load_sequence  # noqa: E402
from jnds_deploy.training.evaluate import baseline_outputs, infer_sequence, score_frames  # noqa: E402

MODES = ("no history", "history, no rejection", "history + rejection (default)")


def run(model, seq, mode: str) -> list[np.ndarray]:
    """``training.evaluate.infer_sequence`` in one of MODES: no history is every frame a cut."""
    if mode == MODES[0]:
        return infer_sequence(model, replace(seq, cuts=[True] * len(seq.cuts)))
    keep = filters.disoccluded
    if mode == MODES[1]:
        filters.disoccluded = lambda n, w: torch.zeros_like(n[:, :1], dtype=torch.bool)
    try:
        return infer_sequence(model, seq)
    finally:
        filters.disoccluded = keep


def main() -> int:
    ap = arguments(__doc__, RESULTS / "history_gain")
    ap.add_argument("--data", nargs="+", default=["data/val"])
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--baseline", default=None, help="e.g. oidn-balanced: its per-frame PSNR beside the model's")
    args = ap.parse_args()
    model = load_model(args.checkpoint or default_checkpoint())
    model.eval()
    quantized = any(getattr(m, "quantize", False) for m in model.modules())  # load_model: QAT-trained
    result = {"checkpoint": str(args.checkpoint or "shipped"), "int8_fake_quantization": quantized,
              "sequences": {}}
    for path in expand_sequences(args.data):
        seq = load_sequence(path)
        refs = [r.transpose(1, 2, 0) for r in seq.ref["color"]]
        motions = [m.transpose(1, 2, 0) for m in seq.motion]
        name = f"{Path(path).parent.name}/{Path(path).name}"
        per = {}
        for mode in MODES:
            outs = run(model, seq, mode)
            m = score_frames(outs, refs, motions, seq.cuts)
            m["psnr_per_frame"] = [psnr(o, r) for o, r in zip(outs, refs)]
            per[mode] = m
        if args.baseline:
            per[args.baseline] = {"psnr_per_frame": [psnr(o, r) for o, r in zip(baseline_outputs(args.baseline, path),
                                                                               refs)]}
        result["sequences"][name] = per
        print(name, "  ".join(f"{mode}: {per[mode]['psnr']:.2f}" for mode in MODES), flush=True)
    lines = ["# What the history gives",
             "",
             f"Command: `{command_line()}`  ",
             f"PyTorch, {'the shipped checkpoint' if args.checkpoint is None else f'`{args.checkpoint}`'} "
             f"{'at int8 fake quantization' if quantized else 'in fp32 (not QAT-trained yet)'}. PSNR (dB) / FLIP per "
             "sequence, mean over its frames; temporal error (Eq. 5) in brackets.",
             "",
             "| sequence | " + " | ".join(MODES) + " |",
             "| --- |" + " ---: |" * len(MODES)]
    seqs = result["sequences"]
    for name, per in seqs.items():
        lines.append(f"| {name} | " + " | ".join(
            f"{per[m]['psnr']:.2f} / {per[m]['flip']:.4f} ({per[m]['temporal']:.4f})" for m in MODES) + " |")
    for split in sorted({n.split("/")[0] for n in seqs}):
        group = [per for n, per in seqs.items() if n.startswith(split + "/")]
        lines.append(f"| **mean of {split}** | " + " | ".join(
            f"{np.mean([p[m]['psnr'] for p in group]):.2f} / {np.mean([p[m]['flip'] for p in group]):.4f} "
            f"({np.mean([p[m]['temporal'] for p in group]):.4f})" for m in MODES) + " |")
    lines += ["", "## PSNR per frame", ""]
    for name, per in seqs.items():
        lines.append(f"- {name}:")
        for m in per:
            lines.append(f"  - {m}: " + " ".join(f"{v:.1f}" for v in per[m]["psnr_per_frame"]))
    lines.append("")
    write_report(Path(args.out), result, "\n".join(lines))
    print("\n".join(lines[:8 + len(seqs) + 2]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
