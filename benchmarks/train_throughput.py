"""Where a training step's time goes on this CPU, and patches per second.

    .venv/bin/python benchmarks/train_throughput.py [--data data] [--sequences 4] [--patch 96] [--unroll 6]
        [--batch 4] [--threads 2] [--steps 8] [--feature-net runs/feature/feature_net.pt]
        [--out benchmarks/results/train_throughput]

The step of `jnds train` (training.train), taken apart with the same components: the
shipped checkpoint's weights, --sequences training sequences decoded into memory (the
time per sequence is reported), PatchSampler batches with the augmentations of issue 24
(exposure, normal rotation, flips), the L1 + feature loss, AdamW. Each step is timed by
phase (sampling the batch, the unrolled forward, the loss, backward, the optimizer),
before and after stop 30's changes (NCHW convolutions and autograd's L1; NHWC and a
one-pass L1) on the same batches; medians over --steps steps after 2 warm-up steps. A patch is one native patch of one
frame, so a step trains batch x unroll patches. Writes
benchmarks/results/train_throughput.md and .json.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import (RESULTS, ROOT, arguments, command_line, cpu_line, machine_info,  # noqa: E402
                               write_report)
from jnds_deploy.checkpoint import default_checkpoint, read_checkpoint  # noqa: E402
from jnds_deploy.io import find_sequences  # noqa: E402
from jnds_deploy.model import JNDS, ModelConfig  # noqa: E402
from jnds_deploy.training.config import TrainConfig  # noqa: E402
from jnds_deploy.training.data import Augment, PatchSampler, load_sequence  # noqa: E402
from jnds_deploy.training import feature_loss, losses  # noqa: E402
from jnds_deploy.training.losses import Loss  # noqa: E402
from jnds_deploy.training.train import run_unroll  # noqa: E402

PHASES = ("batch", "forward", "loss", "backward", "optimizer")
VARIANTS = ("before", "after")  # NCHW + autograd's abs().mean(); NHWC + the one-pass L1 (jnds train)


ONE_PASS_L1 = feature_loss.l1


def _autograd_l1(a, b):
    return (a - b).abs().mean()


def main() -> None:
    ap = arguments(__doc__, RESULTS / "train_throughput")
    ap.add_argument("--data", default=str(ROOT / "data"))
    ap.add_argument("--sequences", type=int, default=4)
    ap.add_argument("--patch", type=int, default=96)
    ap.add_argument("--unroll", type=int, default=6)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--feature-net", default=str(ROOT / "runs" / "feature" / "feature_net.pt"))
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    paths = find_sequences(Path(args.data) / "train")[:: max(1, len(find_sequences(Path(args.data) / "train"))
                                                           // args.sequences)][:args.sequences]
    t0 = time.perf_counter()
    seqs = [load_sequence(p) for p in paths]
    load_s = (time.perf_counter() - t0) / len(seqs)

    ckpt = read_checkpoint(default_checkpoint())
    cfg = TrainConfig(patch=args.patch, unroll=args.unroll, batch=args.batch, spatial_loss="l1+feature",
                      feature_net=args.feature_net)
    layouts = {}
    for name in VARIANTS:
        model = JNDS(ModelConfig(**ckpt["model_config"]))
        model.load_state_dict(ckpt["model"])
        loss_fn = Loss(cfg, model.cfg.scale)
        if name == "after":
            model.to(memory_format=torch.channels_last)
            loss_fn.to(memory_format=torch.channels_last)
        model.train()
        layouts[name] = (model, loss_fn, torch.optim.AdamW(model.parameters(), lr=1e-5, weight_decay=0.0))
    sampler = PatchSampler(seqs, args.patch, args.unroll, np.random.default_rng(0),
                           Augment(exposure=(-4, 8), rotate_normals=True, flips=True))
    rows = {name: [] for name in VARIANTS}
    for step in range(args.steps + 2):
        t_batch = time.perf_counter()
        batch = sampler.batch(args.batch)
        t_batch = time.perf_counter() - t_batch
        for name, (model, loss_fn, opt) in layouts.items():  # the same batch, one variant after the other
            for module in (losses, feature_loss):
                module.l1 = ONE_PASS_L1 if name == "after" else _autograd_l1
            t = [time.perf_counter()]
            outs = run_unroll(model, batch)
            t.append(time.perf_counter())
            loss, _ = loss_fn(outs, batch)
            t.append(time.perf_counter())
            opt.zero_grad(set_to_none=True)
            loss.backward()
            t.append(time.perf_counter())
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            t.append(time.perf_counter())
            if step >= 2:
                rows[name].append({"batch": t_batch, **{p: t[i + 1] - t[i] for i, p in enumerate(PHASES[1:])}})
            print(step, name, f"{t[-1] - t[0] + t_batch:.2f} s", flush=True)
    med = {n: {p: float(np.median([r[p] for r in rs])) for p in PHASES} for n, rs in rows.items()}
    step_s = {n: float(np.median([sum(r.values()) for r in rs])) for n, rs in rows.items()}
    patches = args.batch * args.unroll
    info = machine_info()
    md = ["# Training throughput\n", f"`{command_line()}`\n",
          f"Machine: {cpu_line(info)}, {args.threads} torch threads. Patch {args.patch}x{args.patch} native, "
          f"unroll {args.unroll}, batch {args.batch} ({patches} patches a step), L1 + feature loss, augmentations "
          f"on; medians of {args.steps} steps. Two variants train on the same batches, one after the other in "
          "each step: `before`, convolutions in NCHW memory and autograd's `abs().mean()` as the L1 (jnds train "
          "until stop 29); `after`, NHWC (channels_last) and the one-pass L1 of `training.feature_loss.l1` "
          "(jnds train since stop 30).\n",
          "| phase | " + " | ".join(f"{n} s per step | share" for n in VARIANTS) + " |",
          "| --- |" + " ---: | ---: |" * len(VARIANTS)]
    for p in PHASES:
        md.append(f"| {p} | " + " | ".join(f"{med[n][p]:.3f} | {100 * med[n][p] / step_s[n]:.1f} %"
                                         for n in VARIANTS) + " |")
    md += ["| **step** | " + " | ".join(f"**{step_s[n]:.3f}** | " for n in VARIANTS) + "|", ""]
    md += [f"- {n}: {patches / step_s[n]:.1f} patches per second ({1 / step_s[n]:.3f} steps per second)."
           for n in VARIANTS]
    md += [f"- after over before: {step_s['before'] / step_s['after']:.2f}x.",
           f"- Decoding a training sequence into memory (once per run): {load_s:.2f} s."]
    write_report(Path(args.out), {"machine": info, "command": command_line(), "phases_s": med, "step_s": step_s,
                                  "patches_per_s": {n: patches / s for n, s in step_s.items()},
                                  "load_s_per_sequence": load_s, "steps": rows}, "\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
