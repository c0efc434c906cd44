"""A feature (perceptual) loss from a small network trained on the project's own renders.

The paper's spatial loss uses the first three layers of a U-Net trained to segment
Hypersim renderings (Sec. 3.3, Eq. 6). We cannot download such weights, and our data
has no semantic labels, so the loss network here learns a task of the same kind from
what the renderer does provide: from a converged image (the reference, box-filtered to
native resolution, tonemapped with Eq. 1) predict the G-buffer of the scene -- albedo,
normal, roughness and coverage. Telling texture from shading from geometry needs
features that respond to edges and texture rather than to noise.

The loss is Eq. 6: sum over the first three feature maps of w_j * L1(f_j(o), f_j(r)),
with w_j = 1 / mean|f_j(r)| measured on the training data so each layer contributes
about equally. Inputs are tonemapped NCHW images with 3 channels.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from .. import filter_spec as filters
from ..errors import TrainError
from ..layout import channels
from ..options import option


class _MeanAbs(torch.autograd.Function):
    """mean(|d|), whose backward is sign(d) / n in one pass: autograd's backward of
    ``abs().mean()`` takes ``sgn`` and two multiplications, slower than this on a CPU (the
    record: commit 7b331ac). The same subgradient (0 at d = 0)."""

    @staticmethod
    def forward(ctx, d: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(d)
        return d.abs().mean()

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (d,) = ctx.saved_tensors
        return torch.sign(d).mul_(grad / d.numel())


def l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference of two tensors of the same shape."""
    return _MeanAbs.apply(a - b)


def _block(cin, cout):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.ReLU(), nn.Conv2d(cout, cout, 3, padding=1), nn.ReLU())


class FeatureNet(nn.Module):
    """U-Net with skip connections (as the paper's Fig. 5), three levels."""

    OUTPUTS = 8  # albedo 3, normal 3 (in [0, 1]), roughness 1, coverage 1

    def __init__(self, widths=(16, 32, 64)):
        super().__init__()
        a, b, c = widths
        self.enc1, self.enc2, self.enc3 = _block(3, a), _block(a, b), _block(b, c)
        self.dec2, self.dec1 = _block(c + b, b), _block(b + a, a)
        self.head = nn.Conv2d(a, self.OUTPUTS, 1)
        self.register_buffer("layer_weights", torch.ones(3))

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        f1 = self.enc1(x)
        f2 = self.enc2(F.max_pool2d(f1, 2))
        f3 = self.enc3(F.max_pool2d(f2, 2))
        return [f1, f2, f3]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f1, f2, f3 = self.features(x)
        d2 = self.dec2(torch.cat([filters.upsample(f3), f2], 1))
        d1 = self.dec1(torch.cat([filters.upsample(d2), f1], 1))
        return torch.sigmoid(self.head(d1))

    def loss(self, out: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        """Eq. 6 on tonemapped images (N, 3, H, W), H and W multiples of 4."""
        fo = self.features(out)
        with torch.no_grad():
            fr = self.features(ref)
        return sum(w * l1(a, b) for w, a, b in zip(self.layer_weights, fo, fr))


def load_feature_net(path: str | Path) -> FeatureNet:
    if not Path(path).is_file():
        raise TrainError(f"{path}: no such feature-loss network; `jnds train-feature-net` writes one")
    data = torch.load(path, weights_only=False, map_location="cpu")
    net = FeatureNet(tuple(data["widths"]))
    net.load_state_dict(data["model"])
    net.eval()
    for p in net.parameters():
        p.requires_grad_(False)
    return net


@dataclass
class FeatureNetConfig:
    data: str = option("data", "directory with train/ sequences")
    out: str = option("runs/feature/feature_net.pt", "the checkpoint to write")
    steps: int = option(1500, "training steps")
    batch: int = 16
    patch: int = 64
    lr: float = 2e-3
    seed: int = 0
    threads: int = option(2, "torch threads")
    # cheap references keep too much noise to read a G-buffer from (docs/dataset.md)
    clean_references: str | None = option(
        None, "learn from the references cleaned as jnds train --clean-references cleans them", choices=("oidn",)
    )


def _examples(data_root: str, clean: str | None = None):
    """(tonemapped native-resolution reference colour, G-buffer target) per frame."""
    from .data import load_split

    xs, ys = [], []
    for s in load_split(Path(data_root) / "train", clean=clean):
        k = s.scale
        color = torch.from_numpy(s.ref["color"])
        xs.append(filters.tonemap(F.avg_pool2d(color, k)).numpy())
        cur = s.current
        normal = cur[:, channels("normal")]
        coverage = (np.abs(normal).sum(1, keepdims=True) > 0).astype(np.float32)
        ys.append(
            np.concatenate([cur[:, channels("albedo")], normal * 0.5 + 0.5, cur[:, channels("roughness")], coverage], 1)
        )
    return np.concatenate(xs), np.concatenate(ys)


def train_feature_net(cfg: FeatureNetConfig, progress: bool = True) -> Path:
    from tqdm import tqdm

    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    x, y = _examples(cfg.data, cfg.clean_references)
    net = FeatureNet()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    n, _, h, w = x.shape
    p = cfg.patch
    for step in tqdm(range(cfg.steps), desc="feature net", disable=not progress):
        idx = rng.integers(0, n, cfg.batch)
        ys_, xs_ = rng.integers(0, h - p + 1, cfg.batch), rng.integers(0, w - p + 1, cfg.batch)
        xb = torch.from_numpy(np.stack([x[i, :, a : a + p, b : b + p] for i, a, b in zip(idx, ys_, xs_)]))
        yb = torch.from_numpy(np.stack([y[i, :, a : a + p, b : b + p] for i, a, b in zip(idx, ys_, xs_)]))
        for g in opt.param_groups:
            g["lr"] = cfg.lr * 0.1 ** (step / cfg.steps)
        loss = (net(xb) - yb).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():  # Eq. 6 weights: each layer contributes about equally
        net.eval()
        feats = net.features(torch.from_numpy(x[: min(n, 32)]))
        net.layer_weights.copy_(torch.tensor([1.0 / (3 * f.abs().mean().item() + 1e-8) for f in feats]))
    out = Path(cfg.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    torch.save(
        {"model": net.state_dict(), "widths": (16, 32, 64), "final_l1": float(loss.detach()), "config": cfg.__dict__},
        tmp,
    )
    os.replace(tmp, out)
    return out
