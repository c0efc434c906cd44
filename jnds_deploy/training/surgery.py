"""Checkpoint surgery: a checkpoint's weights for a model of another configuration, as
``jnds train --init`` starts a run from them (``training.train``). Each step is a few lines
over the state dict and keeps what the checkpoint computed (exactly, or nearly where said):

- ``guided``: the guide albedo input added (``ModelConfig.guide_albedo``);
- ``without_upsample_block``: a predicting upsample block replaced by one fixed kernel;
- ``widened``: wider network widths, the new channels read with zero weights;
- ``narrowed``: a narrower output block, the channels that matter most kept;
- ``deepened``: one U-Net level more.

``carried`` chains them for a checkpoint and the model a run trains.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from ..errors import ConfigError
from ..layout import channels
from ..model import JNDS, N_GUIDE, ModelConfig
from .config import DEEPENED_BLEND


def without_upsample_block(cfg: ModelConfig, weights: dict) -> tuple[ModelConfig, dict]:
    """A predicting checkpoint's config and weights for a fixed-kernel model: the upsample
    block's convolutions dropped, and the output block head's feature channels (its last
    ``upsample_features`` outputs, ``OutputBlock.sizes``); the fixed kernel starts as the
    identity (the predicted one was nearly that, measured at commit 4d89f8a)."""
    n = cfg.upsample_features
    weights = {k: v for k, v in weights.items() if not k.startswith("upsample_block.")}
    for k in ("network.output_block.head.weight", "network.output_block.head.bias"):
        weights[k] = weights[k][: len(weights[k]) - n] if n else weights[k]
    fixed = torch.zeros(9)
    fixed[4] = 1.0
    weights["upsample_block.fixed"] = fixed
    return replace(cfg, upsample_width=0, upsample_features=0), weights


GUIDED = "network.input_block.project.weight"  # the convolution that reads the guide albedo


def guided(cfg: ModelConfig, weights: dict, init: str = "zero") -> tuple[ModelConfig, dict]:
    """A checkpoint without the guide albedo input as one with it: the projection reads the new
    channels after current and history. ``init`` "zero": with zero weights, the same outputs;
    "split": the current albedo's weights halved and the other half given to the guide, the
    same outputs where guide and albedo agree (every frame without the layer) and the guide in
    use from the first step (from zero, a fine-tune left it unlearned: docs/training.md).
    Its learned input range stays: the guide lies in [0, 1], as the albedo does."""
    w = weights[GUIDED]
    if init == "split":
        albedo = channels("albedo")  # the projection reads the current inputs first
        w = w.clone()
        w[:, albedo] /= 2
        new = w[:, albedo].clone()
    else:
        new = w.new_zeros(w.shape[0], N_GUIDE, *w.shape[2:])
    return replace(cfg, guide_albedo=True), dict(weights, **{GUIDED: torch.cat([w, new], 1)})


WIDTHS = ("input_width", "encoder_widths", "bottleneck_width", "output_width")


def widens(old: ModelConfig, new: ModelConfig) -> bool:
    """``new`` is ``old`` with some of its network's widths larger (the same depth)."""

    def widths(c: ModelConfig) -> tuple[int, ...]:
        return (c.input_width, *c.encoder_widths, c.bottleneck_width, c.output_width)

    return (
        replace(old, **{k: getattr(new, k) for k in WIDTHS}) == new
        and old.depth == new.depth
        and all(b >= a for a, b in zip(widths(old), widths(new)))
    )


def _concat_first(cfg: ModelConfig) -> dict[str, int]:
    """The convolutions whose input is a concatenation of two tensors: the width of the
    first (``FeatureExtractor``'s decoders: upsampled deeper features, then the skip;
    ``OutputBlock``: upsampled decoder features, then the input block's)."""
    first = {f"network.feature_extractor.decoders.{i}.a": w for i, w in enumerate(cfg.decoder_inputs)}
    first["network.output_block.conv"] = cfg.encoder_widths[0]
    return first


@torch.no_grad()
def widened(cfg: ModelConfig, weights: dict, model: JNDS) -> dict:
    """A checkpoint's weights embedded in a wider ``model`` so that it computes the same
    outputs: every old channel keeps its weights and reads the new channels with zero
    weights; the new channels keep ``model``'s fresh initialization (net2net-style
    widening with zeros, written here: a few lines over the state dict)."""
    out = {}
    old_first, new_first = _concat_first(cfg), _concat_first(model.cfg)
    for key, fresh in model.state_dict().items():
        old = weights[key]
        if old.shape == fresh.shape:
            out[key] = old.clone()
            continue
        w = fresh.clone()
        o = old.shape[0]
        if w.dim() == 1:  # a bias
            w[:o] = old
        else:
            conv = key.rsplit(".", 1)[0]
            i_old = old.shape[1]
            if conv in old_first:  # two concatenated inputs: the second moves up
                a, b = old_first[conv], new_first[conv]
                cols = list(range(a)) + list(range(b, b + i_old - a))
            else:
                cols = list(range(i_old))
            w[:o] = 0.0
            w[:o, cols] = old
        out[key] = w
    return out


def narrows(old: ModelConfig, new: ModelConfig) -> bool:
    """``new`` is ``old`` with a narrower output block (fewer ``output_width`` channels), the
    only width whose cost on an AVX2 CPU falls in steps of 16 channels
    (docs/performance.md)."""
    return replace(old, output_width=new.output_width) == new and new.output_width < old.output_width


@torch.no_grad()
def narrowed(cfg: ModelConfig, weights: dict, width: int) -> dict:
    """A checkpoint's weights with its output block cut to ``width`` hidden channels: the
    channels kept are those whose path to the head weighs most (the norm of the channel's
    convolution weights times the norm of the head's weights that read it; a channel's
    ReLU output scales with the first, its effect on every head output with the second).
    The dropped channels' contribution is lost; a fine-tune recovers it (written here: a
    few lines over the state dict)."""
    conv, head = "network.output_block.conv", "network.output_block.head"
    score = weights[f"{conv}.weight"].flatten(1).norm(dim=1) * weights[f"{head}.weight"].flatten(1).norm(dim=0)
    keep = score.argsort(descending=True)[:width].sort().values
    out = dict(weights)
    out[f"{conv}.weight"] = weights[f"{conv}.weight"][keep].clone()
    out[f"{conv}.bias"] = weights[f"{conv}.bias"][keep].clone()
    out[f"{head}.weight"] = weights[f"{head}.weight"][:, keep].clone()
    return out


def deepens(old: ModelConfig, new: ModelConfig) -> bool:
    """``new`` is ``old`` with one U-Net level more: its old bottleneck an encoder block
    (``new.encoder_widths`` = ``old``'s + the old bottleneck width), a new bottleneck below
    it, and one filter level more if ``old`` filtered down to its bottleneck."""
    levels = old.filter_levels + (old.filter_levels == old.depth + 1)
    return (
        new.encoder_widths == (*old.encoder_widths, old.bottleneck_width)
        and new.filter_levels == levels
        and replace(old, encoder_widths=new.encoder_widths, bottleneck_width=new.bottleneck_width, filter_levels=levels)
        == new
    )


@torch.no_grad()
def deepened(cfg: ModelConfig, weights: dict, model: JNDS, blend: float = DEEPENED_BLEND) -> dict:
    """A checkpoint's weights in a ``model`` one U-Net level deeper (``deepens``), so that
    it computes nearly the same outputs: the old bottleneck becomes the deepest encoder
    block; the new decoder block above the new bottleneck starts as the identity of its
    skip connection (ReLU of a non-negative input: exact), which is the old bottleneck's
    output, so every shallower decoder reads what it read before; the old coarsest filter
    level's head keeps its down kernel and gains up kernels (identity) and an up blend of
    sigmoid(``blend``) towards the new level, the one inexact step. The new
    bottleneck and level keep ``model``'s fresh initialization (written here, as
    ``widened``: a few lines over the state dict)."""
    fe = "network.feature_extractor."
    d = cfg.depth
    rename = {f"{fe}bottleneck.": f"{fe}encoders.{d}."}
    rename.update({f"{fe}decoders.{i}.": f"{fe}decoders.{i + 1}." for i in range(d)})
    moved = {}
    for key, v in weights.items():
        for old, new in rename.items():
            if key.startswith(old):
                key = new + key[len(old) :]
                break
        moved[key] = v
    fresh = model.state_dict()
    # only the old coarsest filter level's heads change shape (they gain up kernels, below);
    # anything else that does not carry over means the renaming above is wrong
    grown = (
        {f"{fe}heads.{path}{cfg.filter_levels}.{p}" for path in ("diffuse", "specular") for p in ("weight", "bias")}
        if cfg.filter_levels == d + 1
        else set()
    )
    lost = sorted(k for k in moved if k not in fresh or (moved[k].shape != fresh[k].shape and k not in grown))
    if lost:
        raise ConfigError(
            f"deepening {cfg.encoder_widths} -> {model.cfg.encoder_widths}: weights that do not carry "
            f"over: {', '.join(lost[:6])}{' ...' if len(lost) > 6 else ''}"
        )
    out = {key: (moved[key] if key in moved and key not in grown else f).clone() for key, f in fresh.items()}
    width, below = model.cfg.encoder_widths[d], model.cfg.bottleneck_width
    for conv, first in ((f"{fe}decoders.0.a", below), (f"{fe}decoders.0.b", 0)):
        w = torch.zeros_like(out[f"{conv}.weight"])
        w[torch.arange(width), first + torch.arange(width), 1, 1] = 1.0
        out[f"{conv}.weight"], out[f"{conv}.bias"] = w, torch.zeros_like(out[f"{conv}.bias"])
    if cfg.filter_levels == d + 1:  # the old coarsest level: its down kernel, then up and up_blend
        for path in ("diffuse", "specular"):
            head = f"{fe}heads.{path}{cfg.filter_levels}"
            for p in ("weight", "bias"):
                old = weights[f"{head}.{p}"]
                out[f"{head}.{p}"][: len(old)] = old
            out[f"{head}.bias"][-1] = blend  # up_blend, the last of _path_sizes
    return out


def carried(
    cfg: ModelConfig, weights: dict, model: JNDS, guide_init: str = "zero", deepen_blend: float = DEEPENED_BLEND
) -> tuple[ModelConfig, dict]:
    """A checkpoint's config ``cfg`` and ``weights`` carried as far as surgery goes towards
    ``model``: the config the returned weights have, ``model.cfg`` where every difference
    was one surgery handles. The settings that change no weight (upsample root, firefly
    clamp, diffuse fill, albedo at holes) are taken from ``model``; an input block of the
    other design is replaced by ``model``'s fresh one (fitted afterwards by
    ``training.train``)."""
    cfg = replace(
        cfg,
        upsample_root=model.cfg.upsample_root,
        firefly_clamp=model.cfg.firefly_clamp,
        diffuse_fill=model.cfg.diffuse_fill,
        albedo_at_holes=model.cfg.albedo_at_holes,
    )
    if model.cfg.guide_albedo and not cfg.guide_albedo:
        cfg, weights = guided(cfg, weights, guide_init)
    if model.cfg.fixed_upsample and not cfg.fixed_upsample:
        cfg, weights = without_upsample_block(cfg, weights)
    if cfg.input_block != model.cfg.input_block:
        fresh = {k: v for k, v in model.state_dict().items() if k.startswith("network.input_block.")}
        weights = {**{k: v for k, v in weights.items() if not k.startswith("network.input_block.")}, **fresh}
        cfg = replace(cfg, input_block=model.cfg.input_block, input_hidden=model.cfg.input_hidden)
    if cfg != model.cfg and widens(cfg, model.cfg):
        cfg, weights = model.cfg, widened(cfg, weights, model)
    if cfg != model.cfg and narrows(cfg, model.cfg):
        cfg, weights = model.cfg, narrowed(cfg, weights, model.cfg.output_width)
    if cfg != model.cfg and deepens(cfg, model.cfg):
        cfg, weights = model.cfg, deepened(cfg, weights, model, deepen_blend)
    return cfg, weights
