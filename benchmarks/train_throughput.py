"""Where a training step's time goes on this CPU, and patches per second.

    python -m benchmarks.train_throughput [--data data/spp8] [--split train] [--sequences 12] [--steps 8]
        [--threads 2] [--feature-net runs/feature-spp8/feature_net.pt] [--clean-references oidn]
        [--patch N] [--unroll N] [--batch N]
        [--out benchmarks/results/train_throughput]

The step of `jnds train` (training.train) with the recipe the shipped checkpoint was trained
with (its `train_config`: model, patch, unroll, batch, losses, augmentations; the feature-loss
network and the references as given here), taken apart with the same components: the
shipped weights, --sequences training sequences decoded into memory (every n-th of the
split; the time per sequence is reported), PatchSampler batches, the loss, AdamW with
gradient clipping. Each step is timed by phase (sampling the batch, the unrolled forward,
the loss, backward, clipping and the optimizer) for two variants on the same batches, one
after the other: `grid_sample`, the history warps' input gradient by autograd through
PyTorch's bicubic `grid_sample` (jnds train before commit 6e76537); `own`, by `filters.warp`'s own
adjoint (`filters._WarpCPU`, since). Medians over --steps steps after 2 warm-up
steps (none with --smoke). A patch is one native patch of one frame, so a step trains batch x unroll patches.
Writes benchmarks/results/train_throughput.md and .json.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from benchmarks.common import RESULTS, ROOT, arguments, command_line, cpu_line, machine_info, parse, write_report
from jnds_deploy import filter_spec as filters
from jnds_deploy.checkpoint import default_checkpoint, read_checkpoint
from jnds_deploy.io import find_sequences
from jnds_deploy.model import JNDS, ModelConfig
from jnds_deploy.training.config import TrainConfig
from jnds_deploy.training.data import Augment, PatchSampler, load_sequence
from jnds_deploy.training.losses import Loss
from jnds_deploy.training.train import run_unroll

PHASES = ("batch", "forward", "loss", "backward", "optimizer")
VARIANTS = ("grid_sample", "own")
OWN_WARP = filters.warp


def _grid_sample_warp(x: torch.Tensor, motion: torch.Tensor) -> torch.Tensor:
    """``filters.warp`` as it was before commit 6e76537: autograd through ``grid_sample``."""
    n, _, h, w = x.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=x.dtype), torch.arange(w, dtype=x.dtype), indexing="ij")
    grid = torch.stack([2 * (xs + 0.5 + motion[:, 0]) / w - 1, 2 * (ys + 0.5 + motion[:, 1]) / h - 1], dim=-1)
    return F.grid_sample(x, grid, mode="bicubic", padding_mode="border", align_corners=False)


def random_feature_net(path: Path) -> str:
    """A randomly initialized feature-loss network at ``path``: a smoke run times the loss
    without the trained one."""
    from jnds_deploy.training.feature_loss import FeatureNet

    widths = (16, 32, 64)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"widths": widths, "model": FeatureNet(widths).state_dict()}, path)
    return str(path)


def main() -> None:
    ap = arguments(
        __doc__,
        RESULTS / "train_throughput",
        smoke={
            "data": str(ROOT),
            "split": "samples",
            "sequences": 1,
            "steps": 1,
            "feature_net": None,
            "patch": 16,
            "unroll": 2,
            "batch": 1,
        },
    )
    ap.add_argument("--data", default=str(ROOT / "data" / "spp8"))
    ap.add_argument("--split", default="train", help="the directory of --data whose sequences train")
    ap.add_argument("--sequences", type=int, default=12)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument(
        "--feature-net",
        default=str(ROOT / "runs" / "feature-spp8" / "feature_net.pt"),
        help="the feature-loss network (with --smoke: randomly initialized, beside --out)",
    )
    ap.add_argument("--clean-references", choices=("oidn",), default=None)
    ap.add_argument("--patch", type=int, default=None, help="native patch size (default: the recipe's)")
    ap.add_argument("--unroll", type=int, default=None, help="frames unrolled (default: the recipe's)")
    ap.add_argument("--batch", type=int, default=None, help="sequences of patches a step (default: the recipe's)")
    args = parse(ap)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    feature_net = args.feature_net or random_feature_net(Path(f"{args.out}-feature_net.pt"))

    every = find_sequences(Path(args.data) / args.split)
    paths = every[:: max(1, len(every) // args.sequences)][: args.sequences]
    t0 = time.perf_counter()
    seqs = [load_sequence(p, args.clean_references) for p in paths]
    load_s = (time.perf_counter() - t0) / len(seqs)

    ckpt = read_checkpoint(default_checkpoint())
    known = set(TrainConfig.__dataclass_fields__)
    recipe = {k: v for k, v in ckpt["train_config"].items() if k in known}
    given = {k: v for k in ("patch", "unroll", "batch") if (v := getattr(args, k)) is not None}
    cfg = TrainConfig(**{**recipe, **given, "feature_net": feature_net, "init": None, "threads": args.threads})
    model = JNDS(ModelConfig(**ckpt["model_config"]))
    model.load_state_dict(ckpt["model"])
    loss_fn = Loss(cfg, model.cfg.scale)
    if cfg.channels_last:
        model.to(memory_format=torch.channels_last)
        loss_fn.to(memory_format=torch.channels_last)
    model.train()
    start = {k: v.clone() for k, v in model.state_dict().items()}
    opt = torch.optim.AdamW(model.parameters(), lr=1e-5, weight_decay=0.0)
    sampler = PatchSampler(
        seqs,
        cfg.patch,
        cfg.unroll,
        np.random.default_rng(0),
        Augment(cfg.exposure, cfg.rotate_normals, cfg.flips, cfg.colours),
        cross_cuts=cfg.cross_cuts,
        balance_renderers=cfg.balance_renderers,
    )
    rows = {name: [] for name in VARIANTS}
    warmup = 0 if args.smoke else 2
    for step in range(args.steps + warmup):
        t_batch = time.perf_counter()
        batch = sampler.batch(cfg.batch)
        t_batch = time.perf_counter() - t_batch
        for name in VARIANTS:  # the same batch and weights, one variant after the other
            filters.warp = OWN_WARP if name == "own" else _grid_sample_warp
            model.load_state_dict(start)
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
            if step >= warmup:
                rows[name].append({"batch": t_batch, **{p: t[i + 1] - t[i] for i, p in enumerate(PHASES[1:])}})
            print(step, name, f"{t[-1] - t[0] + t_batch:.2f} s", flush=True)
    filters.warp = OWN_WARP
    med = {n: {p: float(np.median([r[p] for r in rs])) for p in PHASES} for n, rs in rows.items()}
    step_s = {n: float(np.median([sum(r.values()) for r in rs])) for n, rs in rows.items()}
    patches = cfg.batch * cfg.unroll
    info = machine_info()
    md = [
        "# Training throughput\n",
        f"`{command_line()}`\n",
        f"Machine: {cpu_line(info)}, {args.threads} torch threads. The shipped checkpoint's recipe "
        f"(`{recipe.get('run')}`: `{recipe.get('preset')}` preset, patch {cfg.patch}x{cfg.patch} native, "
        f"unroll {cfg.unroll}, batch {cfg.batch}, {patches} patches a step, loss {cfg.spatial_loss} with the "
        f"low-frequency term at {cfg.lowfreq_loss}, augmentations as trained) on {len(seqs)} sequences of "
        f"`{args.data}` (references {args.clean_references or 'as rendered'}); medians of {args.steps} steps. "
        "Two variants train on the same batches from the same weights, one after the other in each step: "
        "`grid_sample`, the warps' input gradient by autograd through PyTorch's bicubic `grid_sample` (jnds "
        "train before commit 6e76537); `own`, by `filters.warp`'s own adjoint (since).\n",
        "| phase | " + " | ".join(f"{n} s per step | share" for n in VARIANTS) + " |",
        "| --- |" + " ---: | ---: |" * len(VARIANTS),
    ]
    for p in PHASES:
        md.append(
            f"| {p} | " + " | ".join(f"{med[n][p]:.3f} | {100 * med[n][p] / step_s[n]:.1f} %" for n in VARIANTS) + " |"
        )
    md += ["| **step** | " + " | ".join(f"**{step_s[n]:.3f}** | " for n in VARIANTS) + "|", ""]
    md += [
        f"- {n}: {patches / step_s[n]:.1f} patches per second ({1 / step_s[n]:.3f} steps per second)." for n in VARIANTS
    ]
    md += [
        f"- own over grid_sample: {step_s['grid_sample'] / step_s['own']:.2f}x.",
        f"- Decoding a training sequence into memory (once per run): {load_s:.2f} s.",
    ]
    write_report(
        Path(args.out),
        {
            "machine": info,
            "command": command_line(),
            "recipe": recipe,
            "phases_s": med,
            "step_s": step_s,
            "patches_per_s": {n: patches / s for n, s in step_s.items()},
            "load_s_per_sequence": load_s,
            "steps": rows,
        },
        "\n".join(md) + "\n",
    )
    print("\n".join(md))


if __name__ == "__main__":
    main()
