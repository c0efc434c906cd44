"""Cut a checkpoint's output block to fewer hidden channels without training: choose the
channels by backward elimination and refit the 1x1 head on the kept ones by least squares,
both on the head's own inputs and outputs recorded on real sequences (channel pruning with
linear reconstruction, He, Zhang and Sun, ICCV 2017; written here: a Gram matrix and a
solve). An AVX2 CPU's int8 convolution costs in blocks of 16 output channels, so the
shipped 24 cost as 32 (docs/performance.md, "Speed").

    .venv/bin/python experiments/narrow_refit.py --checkpoint jnds_deploy/checkpoints/jnds.pt \\
        --data data/val --width 16 --out runs/narrow/refit16.pt

The fitting sequences must not be the ones it is scored on afterwards.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from jnds_deploy.checkpoint import read_checkpoint
from jnds_deploy.io import expand_sequences
from jnds_deploy.model import JNDS, ModelConfig, quantize_weight, set_quantization
from jnds_deploy.training.data import load_sequence
from jnds_deploy.training.evaluate import infer_sequence


def record(model: JNDS, paths, per_frame: int, rng) -> tuple[torch.Tensor, torch.Tensor]:
    """The head's (quantized) inputs X (n, C) and outputs Y (n, K) at per_frame random
    pixels of every frame, the model running each sequence recurrently as deployed."""
    head = model.network.output_block.head
    xs, ys = [], []

    def hook(mod, inp, out):
        x = mod.act_quant(inp[0])  # what the convolution reads
        x = x.permute(0, 2, 3, 1).reshape(-1, x.shape[1])
        y = out.permute(0, 2, 3, 1).reshape(-1, out.shape[1])
        idx = torch.from_numpy(rng.choice(len(x), min(per_frame, len(x)), replace=False))
        xs.append(x[idx].double())
        ys.append(y[idx].double())

    h = head.register_forward_hook(hook)
    for p in paths:
        infer_sequence(model, load_sequence(p))
    h.remove()
    return torch.cat(xs), torch.cat(ys)


def lstsq_error(X: torch.Tensor, Y: torch.Tensor, keep: list[int]) -> tuple[float, torch.Tensor]:
    """Least-squares fit of Y on X[:, keep] and a constant: (mean squared error, (len(keep)+1, K))."""
    A = torch.cat([X[:, keep], torch.ones(len(X), 1, dtype=X.dtype)], 1)
    sol = torch.linalg.lstsq(A, Y).solution
    return float(((A @ sol - Y) ** 2).mean()), sol


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--width", type=int, default=16)
    ap.add_argument("--keep", default=None, help="comma-separated channels to keep (default: chosen by elimination)")
    ap.add_argument("--per-frame", type=int, default=4000)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    torch.set_num_threads(2)
    data = read_checkpoint(a.checkpoint)
    cfg = ModelConfig(**data["model_config"])
    model = JNDS(cfg)
    model.load_state_dict(data["model"])
    set_quantization(model, bool(data.get("quantized")))
    model.eval()
    X, Y = record(model, expand_sequences(a.data), a.per_frame, np.random.default_rng(0))
    head = model.network.output_block.head
    w = (quantize_weight(head.weight) if head.quantize else head.weight).detach().double()[:, :, 0, 0]
    full = X @ w.T + head.bias.detach().double()
    print(f"{len(X)} samples; recorded outputs reproduced by the weights: max |diff| {float((full - Y).abs().max()):.2e}")
    keep = list(map(int, a.keep.split(","))) if a.keep else list(range(X.shape[1]))
    while len(keep) > a.width:
        errs = [(lstsq_error(X, Y, [c for c in keep if c != d])[0], d) for d in keep]
        err, d = min(errs)
        keep.remove(d)
        print(f"drop channel {d:2d}: {len(keep)} kept, head output MSE {err:.3e} (output variance {float(Y.var()):.3e})")
    err, sol = lstsq_error(X, Y, keep)
    conv, hd = "network.output_block.conv", "network.output_block.head"
    weights = dict(data["model"])
    k = torch.tensor(keep)
    weights[f"{conv}.weight"] = weights[f"{conv}.weight"][k].clone()
    weights[f"{conv}.bias"] = weights[f"{conv}.bias"][k].clone()
    weights[f"{hd}.weight"] = sol[:-1].T.float().reshape(-1, len(keep), 1, 1).contiguous()
    weights[f"{hd}.bias"] = sol[-1].float().contiguous()
    out = dict(data, model=weights, model_config={**data["model_config"], "output_width": a.width},
               narrowed={"from": str(a.checkpoint), "kept_channels": keep, "fit_data": list(map(str, a.data)),
                         "head_mse": err})
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    torch.save(out, a.out)
    print(f"kept {keep}; wrote {a.out}")


if __name__ == "__main__":
    main()
