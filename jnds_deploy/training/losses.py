"""The losses of Sec. 3.3: for each task -- diffuse, specular, auxiliary (albedo),
upsample -- ``w_spatial * L_spatial + (1 - w_spatial) * L_temporal`` with w_spatial = 0.2,
all task weights 1. Native-resolution tasks compare with the 2x2-box-downsampled
reference component; all radiance is compared after the tonemap of Eq. 1. L_temporal is
Eq. 5. L_spatial is L1, the feature loss of ``training.feature_loss``, or their sum; with
``TrainConfig.lowfreq_loss`` > 0 the radiance tasks' L_spatial also holds ``lowfreq``, the
L1 of box averages over 4 to 16 target pixels (not in the paper: on scene kinds it was not
trained on, the shipped model's excess error over OIDN lies in blotches of 2 to 64+ target
pixels, docs/model-gap.md, "Unseen content")."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .. import filter_spec as filters
from .config import TrainConfig
from .feature_loss import l1, load_feature_net


def loss_tonemap(x: torch.Tensor) -> torch.Tensor:
    """Eq. 1 shifted by a small offset so its gradient stays bounded near 0 (the offset
    cancels in every difference the losses take)."""
    return (torch.log1p(x.clamp(0.0, filters.HDR_MAX)) + 1e-3).pow(1.0 / 2.2)


# box sizes of ``lowfreq``, in target pixels (a native-resolution task uses them / scale)
LOWFREQ_SCALES = (4, 8, 16)
RADIANCE_TASKS = ("diffuse", "specular", "upsample")  # the tasks ``lowfreq`` joins


def lowfreq(o: torch.Tensor, r: torch.Tensor, pixel: int) -> torch.Tensor:
    """Sum over LOWFREQ_SCALES of the L1 between o and r (N, C, H, W) box-averaged over
    that many target pixels (``pixel``: target pixels per pixel of o); sizes the patch
    cannot hold are left out. Per-pixel L1 weighs fine grain (the reference's own noise
    among it) as much as blotches; averaged over a box, grain falls away and what stays is
    the blotches and level shifts of the box's size, which on a trained model's outputs
    still hold much of the per-pixel L1 at every scale (the record: commit d056829)."""
    total = o.new_zeros(())
    for s in LOWFREQ_SCALES:
        k = s // pixel
        if k >= 1 and min(o.shape[-2:]) >= k:
            total = total + l1(F.avg_pool2d(o, k), F.avg_pool2d(r, k))
    return total


def _upsampled_motion(motion: torch.Tensor, scale: int) -> torch.Tensor:
    return F.interpolate(motion, scale_factor=scale, mode="nearest") * scale if scale > 1 else motion


class Loss:
    """Eq. 3-5: per task w_spatial * L_spatial + (1 - w_spatial) * L_temporal."""

    def __init__(self, cfg: TrainConfig, scale: int):
        self.w = cfg.w_spatial
        self.w_lowfreq = cfg.lowfreq_loss
        self.scale = scale
        self.feature_net = None
        self.with_l1 = cfg.spatial_loss != "feature"
        if "feature" in cfg.spatial_loss:
            self.feature_net = load_feature_net(cfg.feature_net).to(cfg.device)

    def to(self, **kwargs) -> "Loss":
        """Moves the feature network (``torch.nn.Module.to`` arguments)."""
        if self.feature_net is not None:
            self.feature_net.to(**kwargs)
        return self

    def spatial(self, o: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        """L1, the feature loss (of 3-channel images), or their sum: the feature loss alone
        compares tonemapped features and lets bright HDR regions darken
        (the study at commit 8f1dc31: benchmarks/results/brightness.md); the L1 term holds
        their level."""
        if self.feature_net is not None and o.shape[1] == 3:
            feat = self.feature_net.loss(o, r)
            return feat + l1(o, r) if self.with_l1 else feat
        return l1(o, r)

    def targets(self, batch: dict) -> dict[str, torch.Tensor]:
        """The reference of each task, (T * N, C, H, W) linear: native tasks box-downsampled."""
        s = self.scale
        return {
            "diffuse": F.avg_pool2d(batch["diffuse"].flatten(0, 1), s),
            "specular": F.avg_pool2d(batch["specular"].flatten(0, 1), s),
            "auxiliary": F.avg_pool2d(batch["albedo"].flatten(0, 1), s),
            "upsample": batch["color"].flatten(0, 1),
        }

    @staticmethod
    def teacher_targets(outs: list) -> dict[str, torch.Tensor]:
        """A teacher's outputs as each task's target (``targets``' layout): distillation."""

        def stack(name):
            return torch.cat([getattr(o, name) for o in outs]).detach()

        return {
            "diffuse": stack("diffuse"),
            "specular": stack("specular"),
            "auxiliary": stack("albedo"),
            "upsample": stack("output"),
        }

    def __call__(self, outs: list, batch: dict, targets: dict | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        """``targets``: each task's target (``teacher_targets``); the batch's reference by default."""
        s, tm = self.scale, loss_tonemap
        ref = self.targets(batch) if targets is None else targets
        tasks = {
            "diffuse": ([tm(o.diffuse) for o in outs], tm(ref["diffuse"]), False),
            "specular": ([tm(o.specular) for o in outs], tm(ref["specular"]), False),
            "auxiliary": ([o.albedo for o in outs], ref["auxiliary"], False),
            "upsample": ([tm(o.output) for o in outs], tm(ref["upsample"]), True),
        }
        T, N = batch["current"].shape[:2]
        total, parts = 0.0, {}
        for name, (o_list, r_flat, target_res) in tasks.items():
            r = r_flat.view(T, N, *r_flat.shape[1:])
            o = torch.stack(o_list)
            l_sp = self.spatial(o.flatten(0, 1), r.flatten(0, 1))
            if self.w_lowfreq and name in RADIANCE_TASKS:
                l_sp = l_sp + self.w_lowfreq * lowfreq(o.flatten(0, 1), r.flatten(0, 1), 1 if target_res else s)
            l_t = o.new_zeros(())
            if T > 1:
                mv = batch["motion"][1:].flatten(0, 1)
                if target_res:
                    mv = _upsampled_motion(mv, s)
                o_prev = filters.warp(o[:-1].flatten(0, 1), mv)
                r_prev = filters.warp(r[:-1].flatten(0, 1), mv)
                d_o, d_r = o[1:].flatten(0, 1) - o_prev, r[1:].flatten(0, 1) - r_prev
                if "cut" in batch and bool(batch["cut"][1:].any()):
                    # no temporal term across a camera cut: the frames show different scenes
                    keep = (~batch["cut"][1:]).flatten().view(-1, 1, 1, 1).to(d_o.dtype)
                    d_o, d_r = d_o * keep, d_r * keep
                l_t = l1(d_o, d_r)
            task = self.w * l_sp + (1 - self.w) * l_t
            total = total + task
            parts[name] = float(task.detach())
        return total, parts
