"""The albedo at scattered diffuse holes (docs/model-gap.md, "The albedo at holes"): the
shipped model as it is, and with the composite taking the local mean of the filtered albedo
(the holes' zeros included) where diffuse holes lie scattered among diffuse samples.

A hole is a sample with albedo 0 on a surface (``filters.fill_diffuse_holes``'s test): hair,
metal, glass, a medium. The model's auxiliary filter keeps each hole's 0 in the albedo it
composites with, so hair over a rug or a medium over a floor leaves the 1-spp coverage
pattern as grain; the reference has the mean. Where the binomial 5x5 share of holes is
between ``--lo`` and ``--hi`` and the hole mask changes from pixel to pixel often enough
(the binomial 5x5 mean of its horizontal plus vertical changes above ``--transitions``: a
solid metal object's edge changes once, scattered holes at every other pixel), the
composite's albedo is its 5x5 binomial mean. Inference only; the PyTorch model (int8 fake
quantization), scored as ``jnds evaluate`` scores. Not in the runtime.

    .venv/bin/python experiments/albedo_at_holes.py --data data/holdout data/val [--checkpoint CKPT]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from jnds_deploy import filters, model as M  # noqa: E402
from jnds_deploy.checkpoint import default_checkpoint, load_model  # noqa: E402
from jnds_deploy.io import expand_sequences  # noqa: E402
from jnds_deploy.layout import BACKGROUND, DIFFUSE_FILL_TAPS, channels  # noqa: E402
from jnds_deploy.training.data import load_sequence  # noqa: E402
from jnds_deploy.training.evaluate import infer_sequence, score_frames  # noqa: E402

_TAPS = torch.tensor(DIFFUSE_FILL_TAPS)  # the diffuse fill's 5-tap binomial
_KERNEL = (_TAPS[:, None] * _TAPS[None, :])[None, None]


def binomial(x: torch.Tensor) -> torch.Tensor:
    c = x.shape[1]
    return F.conv2d(F.pad(x, (2, 2, 2, 2), mode="replicate"), _KERNEL.repeat(c, 1, 1, 1), groups=c)


class AlbedoAtHoles:
    """Wraps ``JNDS.forward`` (to see the frame's holes) and ``filters.composite`` (to
    average the albedo where they are scattered) while ``on``."""

    def __init__(self, lo: float, hi: float, transitions: float):
        self.lo, self.hi, self.transitions = lo, hi, transitions
        self.on, self.hole = False, None
        self._forward, self._composite = M.JNDS.forward, filters.composite
        patch = self
        M.JNDS.forward = lambda net, *a, **k: patch.forward(net, *a, **k)  # a method of the model
        filters.composite = self.composite

    def forward(self, net, current, motion, history, reset=None):
        a, n = current[:, channels("albedo")], current[:, channels("normal")]
        self.hole = ((a.amax(1, keepdim=True) <= 0) & (n.abs().sum(1, keepdim=True) >= BACKGROUND)).float()
        return self._forward(net, current, motion, history, reset)

    def composite(self, albedo, diffuse, specular):
        if self.on:
            h = self.hole
            changes = (F.pad((h[..., :, 1:] - h[..., :, :-1]).abs(), (0, 1))
                       + F.pad((h[..., 1:, :] - h[..., :-1, :]).abs(), (0, 0, 0, 1)))
            share = binomial(h)
            use = (share > self.lo) & (share < self.hi) & (binomial(changes) > self.transitions)
            albedo = torch.where(use, binomial(albedo), albedo)
        return self._composite(albedo, diffuse, specular)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", nargs="+", required=True, help="sets: sequences or directories of them")
    ap.add_argument("--checkpoint", default=str(default_checkpoint()))
    ap.add_argument("--lo", type=float, default=0.05)
    ap.add_argument("--hi", type=float, default=0.95)
    ap.add_argument("--transitions", type=float, default=0.5)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    patch = AlbedoAtHoles(args.lo, args.hi, args.transitions)
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
                patch.on = on
                rows[p.name].append(score_frames(infer_sequence(model, seq), refs, mots, seq.cuts))
            print(f"| {p.name} | " + " | ".join(" / ".join(f"{r[k]:.4f}" for k in metrics) for r in rows[p.name]) + " |",
                  flush=True)
        means = [{k: float(np.mean([v[i][k] for v in rows.values()])) for k in metrics} for i in (0, 1)]
        print(f"| **{Path(d).name}** ({len(rows)}) | " + " | ".join(" / ".join(f"{m[k]:.4f}" for k in metrics)
                                                                  for m in means) + " |", flush=True)


if __name__ == "__main__":
    main()
