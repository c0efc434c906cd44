"""Energy the model keeps: mean linear output against the mean reference, per sequence.

    .venv/bin/python experiments/brightness.py --checkpoints runs/small/checkpoint.pt \\
        runs/ft-feature-long/checkpoint.pt [--data data/val] [--out benchmarks/results/brightness]

PSNR, SSIM and FLIP here compare tonemapped images, where the brightest HDR pixels weigh
little; this report looks at linear radiance. Per sequence and checkpoint (PyTorch,
int8 fake quantization for QAT checkpoints, all frames, history carried): the ratio of
mean output to mean reference luminance over all pixels, over the brightest 1 % of
reference pixels, over the other 99 %, and the ratio of medians; and, since a recurrent model
can drift as its history feeds back, the mean ratio of the first and of the last frame, with
their mean |ratio - 1| over the sequences. Writes benchmarks/results/brightness.md and .json.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import RESULTS, arguments, command_line, write_report  # noqa: E402
from jnds_deploy.checkpoint import load_model  # noqa: E402
from jnds_deploy.io import find_sequences  # noqa: E402
from jnds_deploy.training.data import load_sequence  # noqa: E402
from jnds_deploy.training.evaluate import infer_sequence, method_name  # noqa: E402


def ratios(outs: np.ndarray, refs: np.ndarray) -> dict[str, float]:
    """outs, refs: (T, H, W) luminance. The brightest 1 % are the top 1 % of reference pixels."""
    o, r = outs.ravel().astype(np.float64), refs.ravel().astype(np.float64)
    top = np.argsort(r)[-max(1, r.size // 100):]
    rest = np.ones(r.size, bool)
    rest[top] = False
    frames = outs.reshape(len(outs), -1).mean(1) / refs.reshape(len(refs), -1).mean(1)
    return {"mean": o.mean() / r.mean(), "top1": o[top].mean() / r[top].mean(),
            "rest": o[rest].mean() / r[rest].mean(), "median": float(np.median(o) / np.median(r)),
            "first": float(frames[0]), "last": float(frames[-1])}


def main() -> None:
    ap = arguments(__doc__, RESULTS / "brightness")
    ap.add_argument("--checkpoints", nargs="+", required=True)
    ap.add_argument("--data", default="data/val")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    models = {method_name(c): load_model(c) for c in args.checkpoints}
    report = {}
    with torch.no_grad():
        for path in find_sequences(args.data):
            seq = load_sequence(path)
            ref = seq.ref["color"].mean(1)  # (T, H, W) luminance (channel mean)
            report[seq.name] = {name: ratios(np.stack(infer_sequence(m, seq)).mean(-1), ref)
                                for name, m in models.items()}
    names = list(models)
    md = ["# Brightness kept (linear radiance)", "",
          f"Command: `{command_line()}`",
          "", "Mean output / mean reference (luminance = channel mean, all frames), over all pixels, over the "
          "brightest 1 % of reference pixels and over the rest; the ratio of medians; the mean ratio of "
          "the first and of the last frame. 1 = energy kept.", "",
          "| sequence | checkpoint | all | brightest 1 % | other 99 % | median | first frame | last frame |",
          "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for seq, per in report.items():
        for name in names:
            x = per[name]
            md.append(f"| {seq} | {name} | {x['mean']:.3f} | {x['top1']:.3f} | {x['rest']:.3f} | {x['median']:.3f} "
                      f"| {x['first']:.3f} | {x['last']:.3f} |")
    md += ["", "Drift: mean |ratio - 1| over the sequences, first frame against last frame.", "",
           "| checkpoint | first frame | last frame |", "| --- | ---: | ---: |"]
    for name in names:
        dev = {k: np.mean([abs(per[name][k] - 1) for per in report.values()]) for k in ("first", "last")}
        md.append(f"| {name} | {dev['first']:.3f} | {dev['last']:.3f} |")
    write_report(Path(args.out), report, "\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
