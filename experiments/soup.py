"""A weight average of checkpoints fine-tuned from one init ("model soup", Wortsman et al.
2022; with the init among them and weights (1 - a, a): WiSE-FT, Wortsman et al. 2022, "Robust
fine-tuning of zero-shot models"). Both papers found the average of fine-tunes of one
network more robust on data unlike the fine-tuning data than any one of them: the question
here is whether that holds for unseen Cycles kinds (docs/training.md, "Soups").

    .venv/bin/python experiments/soup.py --checkpoint A.pt B.pt [C.pt ...] [--weights 0.5 0.5] --out soup.pt

Every checkpoint must have the same model config. Every float tensor of the state dict is
averaged: the weights, biases and the learned activation ranges (``act_quant.lo``/``hi``,
from which the quantization parameters are recomputed). The other fields are the first
checkpoint's, with ``soup`` recording the parts and weights; no optimizer state.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from jnds_deploy.checkpoint import read_checkpoint  # noqa: E402
from jnds_deploy.model import JNDS, ModelConfig, quant_ranges, set_quantization  # noqa: E402


def soup(paths: list[str], weights: list[float]) -> dict:
    parts = [read_checkpoint(p) for p in paths]
    config = parts[0]["model_config"]
    for p, d in zip(paths, parts):
        if d["model_config"] != config:
            raise SystemExit(f"{p}: model config differs from {paths[0]}'s")
        if d["model"].keys() != parts[0]["model"].keys():
            raise SystemExit(f"{p}: state dict keys differ from {paths[0]}'s")
    state = {}
    for k, v in parts[0]["model"].items():
        if v.is_floating_point():
            state[k] = sum(w * d["model"][k].double() for w, d in zip(weights, parts)).to(v.dtype)
        else:
            state[k] = v.clone()
    model = JNDS(ModelConfig(**config))
    model.load_state_dict(state)
    quantized = all(d.get("quantized") for d in parts)
    if quantized:
        set_quantization(model, True)
    out = {k: parts[0][k] for k in ("model_config", "train_config", "state", "train_sequences") if k in parts[0]}
    out.update(model=model.state_dict(), quantized=quantized, quant_ranges=quant_ranges(model) if quantized else None,
               soup=[{"checkpoint": str(p), "sha256": hashlib.sha256(Path(p).read_bytes()).hexdigest(), "weight": w}
                     for p, w in zip(paths, weights)])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", nargs="+", required=True)
    ap.add_argument("--weights", nargs="+", type=float, default=None, help="one per checkpoint (default: equal)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    weights = args.weights or [1 / len(args.checkpoint)] * len(args.checkpoint)
    if len(weights) != len(args.checkpoint) or abs(sum(weights) - 1) > 1e-6:
        raise SystemExit("--weights: one per checkpoint, summing to 1")
    torch.save(soup(args.checkpoint, weights), args.out)
    print(f"wrote {args.out}: {', '.join(f'{w:g} x {p}' for p, w in zip(args.checkpoint, weights))}")


if __name__ == "__main__":
    main()
