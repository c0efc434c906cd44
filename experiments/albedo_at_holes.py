"""The albedo at scattered diffuse holes (docs/model-gap.md, "The albedo at holes"): the
shipped model as it is, and with the composite taking the local mean of the filtered albedo
(the holes' zeros included) where diffuse holes lie scattered among diffuse samples.

A hole is a sample with albedo 0 on a surface (``filters.diffuse_holes``): hair, metal,
glass, a medium. The model's auxiliary filter keeps each hole's 0 in the albedo it
composites with, so hair over a rug or a medium over a floor leaves the 1-spp coverage
pattern as grain; the reference has the mean. ``ModelConfig.albedo_at_holes`` (stop 58; until
then this script patched the model, with the thresholds as arguments) composites with the
5x5 binomial mean of the filtered albedo where the holes lie scattered
(``filters.scattered_holes``, thresholds ``layout.SCATTERED_SHARE`` and ``SCATTERED_CHANGES``,
chosen in stop 57 on the ``media`` training sequences and then on validation). This script
scores the checkpoint with it off and on, in PyTorch (int8 fake quantization), as ``jnds
evaluate`` scores.

    .venv/bin/python experiments/albedo_at_holes.py --data data/holdout data/val [--checkpoint CKPT]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from jnds_deploy.checkpoint import default_checkpoint, load_model  # noqa: E402
from jnds_deploy.io import expand_sequences  # noqa: E402
from jnds_deploy.training.data import load_sequence  # noqa: E402
from jnds_deploy.training.evaluate import infer_sequence, score_frames  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", nargs="+", required=True, help="sets: sequences or directories of them")
    ap.add_argument("--checkpoint", default=str(default_checkpoint()))
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    model = load_model(args.checkpoint)
    metrics = ("psnr", "flip", "ssim", "temporal")
    print("| set / sequence | as shipped: PSNR / FLIP / SSIM / temporal | albedo mean at scattered holes |")
    print("| --- | --- | --- |")
    for d in args.data:
        rows = {}
        for p in expand_sequences([d]):
            seq = load_sequence(p)
            refs = [r.transpose(1, 2, 0) for r in seq.ref["color"]]
            mots = [m.transpose(1, 2, 0) for m in seq.motion]
            rows[p.name] = []
            for on in (False, True):
                model.cfg = dataclasses.replace(model.cfg, albedo_at_holes=on)
                rows[p.name].append(score_frames(infer_sequence(model, seq), refs, mots, seq.cuts))
            print(f"| {p.name} | " + " | ".join(" / ".join(f"{r[k]:.4f}" for k in metrics) for r in rows[p.name]) + " |",
                  flush=True)
        means = [{k: float(np.mean([v[i][k] for v in rows.values()])) for k in metrics} for i in (0, 1)]
        print(f"| **{Path(d).name}** ({len(rows)}) | " + " | ".join(" / ".join(f"{m[k]:.4f}" for k in metrics)
                                                                  for m in means) + " |", flush=True)


if __name__ == "__main__":
    main()
