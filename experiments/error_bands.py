"""Where in scale the model's error lies, against OIDN's: a diagnostic for the network's
reach (docs/model-gap.md). Each method's LDR error image (``metrics.to_ldr`` of output
minus reference, the error PSNR counts) is split by a Laplacian pyramid (``cv2.pyrDown``)
into octaves: band k holds the error between 2^k and 2^(k+1) target pixels, the last
band what is coarser. The report gives each band's share of the mean squared error
(mean square per target pixel; the pyramid's bands of an error image nearly partition its
energy, the report shows their sum beside the total), per set mean and per sequence.

If the model's excess over OIDN sits in the coarse bands, its filters reach too short
(the ``large`` preset filters at most 3 levels below native); if it sits in the fine
bands, reach is not the problem.

    .venv/bin/python experiments/error_bands.py --checkpoint jnds_deploy/checkpoints/jnds.pt \
        --data data/val [--out benchmarks/results/error_bands]
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.common import RESULTS, arguments, command_line, cpu_line, machine_info, write_report  # noqa: E402
from jnds_deploy.checkpoint import load_fp32_model  # noqa: E402
from jnds_deploy.io import expand_sequences  # noqa: E402
from jnds_deploy.metrics import to_ldr  # noqa: E402
from jnds_deploy.training.evaluate import baseline_outputs, ground_truth, method_name, model_outputs  # noqa: E402

LEVELS = 6  # bands of 1, 2, 4, ..., 32 target pixels, then the rest (>= 64)


def band_energy(err: np.ndarray, levels: int = LEVELS) -> np.ndarray:
    """Mean squared value per target pixel of each Laplacian band of ``err`` (HWC), finest
    first, the last entry the low-pass residual."""
    out, g = [], err.astype(np.float32)
    for _ in range(levels):
        down = cv2.pyrDown(g)
        band = g - cv2.pyrUp(down, dstsize=(g.shape[1], g.shape[0]))
        out.append(float(np.mean(band.astype(np.float64) ** 2)))  # a band pixel covers 4^k target pixels
        g = down
    out.append(float(np.mean(g.astype(np.float64) ** 2)))
    return np.array(out)


def sequence_bands(outs, refs) -> dict:
    errs = [to_ldr(o) - to_ldr(r) for o, r in zip(outs, refs)]
    bands = np.mean([band_energy(e) for e in errs], axis=0)
    mse = float(np.mean([np.mean(e ** 2) for e in errs]))
    # the frame's mean error per channel, squared: a brightness or colour bias, inside the coarsest band
    dc = float(np.mean([np.mean(e.mean(axis=(0, 1)) ** 2) for e in errs]))
    signed = np.mean([e.mean(axis=(0, 1)) for e in errs], axis=0)  # > 0: brighter than the reference
    return {"mse": mse, "bands": bands.tolist(), "dc": dc, "mean_error": signed.tolist()}


def band_labels(levels: int = LEVELS) -> list[str]:
    return [f"{2 ** k}px" for k in range(levels)] + [f">={2 ** levels}px"]


def markdown(report: dict) -> str:
    labels = band_labels()
    lines = []
    for data, methods in report["results"].items():
        lines += [f"## {data}", "", "Mean over sequences of the squared LDR error per target pixel, x 1e-4, "
                  "by band (the band's scale in target pixels); the bias is the frame's mean error per channel, squared:", "",
                  "| method | total MSE | bands' sum | " + " | ".join(labels) + " | of which bias |",
                  "| --- | ---: | ---: | " + " | ".join("---:" for _ in labels) + " | ---: |"]
        means, mses = {}, {}
        for name, seqs in methods.items():
            mse = mses[name] = np.mean([s["mse"] for s in seqs.values()])
            b = means[name] = np.mean([s["bands"] for s in seqs.values()], axis=0)
            lines.append(f"| {name} | {1e4 * mse:.2f} | {1e4 * b.sum():.2f} | " + " | ".join(f"{1e4 * v:.2f}" for v in b)
                         + f" | {1e4 * np.mean([s['dc'] for s in seqs.values()]):.2f} |")
        names = list(means)
        if len(names) >= 2:
            d = means[names[0]] - means[names[-1]]
            dm = mses[names[0]] - mses[names[-1]]
            lines.append(f"| {names[0]} - {names[-1]} | {1e4 * dm:+.2f} | {1e4 * d.sum():+.2f} | "
                         + " | ".join(f"{1e4 * v:+.2f}" for v in d) + " |")
        lines += ["", f"Per sequence, {names[0]}'s excess over {names[-1]} by band (x 1e-4), and the mean "
                  "LDR error of each (x 1e-3, over pixels and channels; < 0: darker than the reference):", "",
                  "| sequence | " + " | ".join(labels) + f" | mean error {names[0]} | {names[-1]} |",
                  "| --- | " + " | ".join("---:" for _ in labels) + " | ---: | ---: |"]
        first, last = methods[names[0]], methods[names[-1]]
        for seq in first:
            d = np.array(first[seq]["bands"]) - np.array(last[seq]["bands"])
            lines.append(f"| {seq} | " + " | ".join(f"{1e4 * v:+.2f}" for v in d)
                         + f" | {1e3 * np.mean(first[seq]['mean_error']):+.1f} | {1e3 * np.mean(last[seq]['mean_error']):+.1f} |")
        lines.append("")
    return "\n".join(lines)


def main() -> int:
    ap = arguments(__doc__, RESULTS / "error_bands")
    ap.add_argument("--checkpoint", nargs="+", required=True)
    ap.add_argument("--data", nargs="+", default=["data/val"])
    ap.add_argument("--baseline", default="oidn-balanced")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    report = {"command": command_line(), "machine": machine_info(), "results": {}}
    for data in args.data:
        paths = expand_sequences([data])
        refs = {p: ground_truth(p)[0] for p in paths}
        methods = {}
        for ck in args.checkpoint:
            model = load_fp32_model(ck)
            methods[method_name(ck)] = {p.name: sequence_bands(model_outputs(model, p), refs[p]) for p in paths}
        methods[args.baseline] = {p.name: sequence_bands(baseline_outputs(args.baseline, p), refs[p]) for p in paths}
        report["results"][data] = methods
    header = (f"# The error by scale (`experiments/error_bands.py`)\n\nCommand: `{report['command']}`  \n"
              f"Machine: {cpu_line(report['machine'])}; the checkpoints in fp32 (PyTorch, their int8-rounded "
              f"weights); {args.baseline} at native resolution + bicubic.\n\n")
    write_report(args.out, report, header + markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
