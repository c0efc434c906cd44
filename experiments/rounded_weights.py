"""The shipped checkpoint with every convolution weight rounded as QAT rounds it: is the
fp32 graph, not int8, the one off the trained model?

    .venv/bin/python experiments/rounded_weights.py --out /tmp/rounded.pt
    .venv/bin/jnds export --checkpoint /tmp/rounded.pt --out out/art-rw
    .venv/bin/jnds calibrate --artifacts out/art-rw --data samples/orbit-160x90
    .venv/bin/python benchmarks/exposure_sweep.py --artifacts out/art-rw --input data/val data/test \\
        --stops 0 --out benchmarks/results/int8_rounded_fp32

Quantization-aware training (``model.QConv``) trains every convolution with its weights
fake-quantized per output channel (``model.quantize_weight``), but ``jnds export`` writes
the fp32 graphs with the float weights. Since the int8 graph's head is int8 too
(``calibration.head``), its int8 pipeline runs the weights training saw everywhere. This
writes a checkpoint whose weights are already rounded (rounding them again is the
identity, so its int8 graphs are the shipped ones), so that its fp32 graphs run the
trained weights: the exposure_sweep report then sets int8 against that fp32.

Since this measurement ``jnds export`` does it itself (``checkpoint.load_fp32_model``):
exporting this script's output and the checkpoint it read gives the same graphs.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from jnds_deploy.checkpoint import default_checkpoint, read_checkpoint  # noqa: E402
from jnds_deploy.model import quantize_weight  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", default=None, help="default: the shipped one")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    ckpt = read_checkpoint(args.checkpoint or default_checkpoint())
    rounded = 0
    for name, w in ckpt["model"].items():
        if name.endswith(".weight") and w.ndim == 4:  # every convolution is a QConv
            ckpt["model"][name] = quantize_weight(w.float()).detach()
            rounded += 1
    torch.save(ckpt, args.out)
    print(f"{rounded} convolution weights rounded -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
