"""Which learned activation ranges clip as the exposure rises: for every quantized
convolution's input (``ActQuant``), the share of values above its range's top, with the
sequence's radiance x 2^k, in the PyTorch model as the int8 graphs quantize it; and the
PSNR of that model and of its float twin at each exposure (output / 2^k scored against the
reference, as ``benchmarks/exposure_sweep.py`` scores the deployed pipeline).

    .venv/bin/python experiments/range_saturation.py --checkpoint jnds_deploy/checkpoints/jnds.pt \\
        --sequence data/media/cycles-media-cut-16104 --stops 0 4 8
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from jnds_deploy.checkpoint import load_fp32_model, load_model
from jnds_deploy.layout import CURRENT, RADIANCE
from jnds_deploy.metrics import psnr
from jnds_deploy.model import QConv
from jnds_deploy.training.data import load_sequence
from jnds_deploy.training.evaluate import ground_truth, infer_sequence


def radiance_channels() -> list[int]:
    out, i = [], 0
    for name, c in CURRENT:
        if name in RADIANCE:
            out += list(range(i, i + c))
        i += c
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--sequence", required=True)
    ap.add_argument("--stops", type=float, nargs="+", default=[0, 4, 8])
    ap.add_argument("--top", type=int, default=8)
    a = ap.parse_args()
    torch.set_num_threads(2)
    q, f = load_model(a.checkpoint), load_fp32_model(a.checkpoint)
    refs = ground_truth(a.sequence)[0]
    rad = radiance_channels()
    for k in a.stops:
        seq = load_sequence(a.sequence)
        seq.current[:, rad] *= np.float32(2.0 ** k)
        clipped = {}

        def hook(mod, inp, name):
            x = inp[0]
            hi = float(mod.act_quant.hi)
            c = clipped.setdefault(name, [0, 0, hi, 0.0])
            c[0] += int((x > hi).sum())
            c[1] += x.numel()
            c[3] = max(c[3], float(x.max()))

        hs = [m.register_forward_pre_hook(lambda mod, inp, n=n: hook(mod, inp, n))
              for n, m in q.named_modules() if isinstance(m, QConv)]
        out_q = infer_sequence(q, seq)
        for h in hs:
            h.remove()
        out_f = infer_sequence(f, seq)
        s = np.float32(2.0 ** -k)
        pq = np.mean([psnr(o * s, r) for o, r in zip(out_q, refs)])
        pf = np.mean([psnr(o * s, r) for o, r in zip(out_f, refs)])
        print(f"exposure 2^{k:g}: int8 (fake) {pq:.2f} dB, fp32 {pf:.2f} dB, int8 - fp32 {pq - pf:+.2f}")
        worst = sorted(clipped.items(), key=lambda kv: -kv[1][0] / kv[1][1])[:a.top]
        for n, (above, total, hi, mx) in worst:
            print(f"  {n:50s} above its top {100 * above / total:7.3f} %  (top {hi:.2f}, max seen {mx:.2f})")


if __name__ == "__main__":
    main()
