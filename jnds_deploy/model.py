"""The JNDS network (Thomas et al. 2022, Sec. 3.2) in PyTorch, with int8 fake quantization.

Stages, named as in the paper:
- ``InputBlock`` (native resolution): clamp + tonemap (Eq. 1), concatenate the current
  inputs with the warped history of the previous filtered outputs, 1x1 projection, 3x3
  convolution, 2x2 average pooling; the native features are skipped to the output block.
- ``FeatureExtractor`` (sub-native): a U-Net; two 1x1 heads per decoder block and the
  bottleneck predict the hierarchical kernels of the diffuse and specular filter paths.
- ``OutputBlock`` (native): 3x3 spatial and temporal kernels and blend weights for
  diffuse, specular and (shared) albedo/normal, the last upsampling kernels of the
  filter paths, and features for the upsample block.
- filter paths, composite (``jnds_deploy.filter_spec``, no parameters);
- ``UpsampleBlock`` (target resolution): a 3x3 kernel predicted from the bilinearly
  upsampled tonemapped composite and output-block features -- or, with
  ``upsample_width`` 0 (not in the paper), one learned 3x3 kernel for every pixel.

``JNDSNetwork`` (input block + feature extractor + output block) and ``UpsampleBlock``
are the two graphs the export issue writes to ONNX; ``JNDS`` runs the whole frame
recurrently for training and reference.

Quantization-aware training (Sec. 3.2.6): every convolution of the non-filter blocks
quantizes its weights per output channel, symmetric, threshold max|w|, and its input
activation per tensor, affine (uint8), with a trained range [lo, hi] (straight-through
estimator). A concatenation of skip tensors is quantized once, as one tensor, so both
parts share one range. Filter paths stay float.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import torch
import torch.nn as nn
import torch.nn.functional as F

from . import filter_spec as filters
from .errors import ConfigError
from .layout import CURRENT, HISTORY, INPUT_BLOCKS, N_CURRENT, N_GUIDE, N_HISTORY, RADIANCE, UPSAMPLE_ROOTS, head_kind  # noqa: F401 (re-exported)


@dataclass(frozen=True)
class ModelConfig:
    """Widths and depths of the network. Presets: ``ModelConfig.preset("small")``."""

    input_width: int = 16  # input block features at native resolution
    encoder_widths: tuple[int, ...] = (24, 32)  # U-Net encoder blocks; depth = len()
    bottleneck_width: int = 48
    output_width: int = 16  # output block hidden features at native resolution
    upsample_features: int = 8  # output-block features handed to the upsample block
    # upsample block hidden features at target resolution; 0: no per-pixel prediction, one
    # learned kernel for every pixel (then upsample_features is 0): the kernel a trained model
    # predicts is nearly constant, and predicting it per pixel is a large share of the frame
    # (the study at commit 4d89f8a: benchmarks/results/constant_upsample_kernel.md)
    upsample_width: int = 8
    filter_levels: int = 3  # levels below native in the diffuse/specular filter paths
    scale: int = 2  # target = scale x native; 1 = denoise only (no upsample block)
    # the upsample block's filter interpolates the composite's root of this degree and raises
    # the result back (filters.upsample_filter): 1 = linear, as in the paper
    upsample_root: int = 1
    # each pixel's current diffuse and specular luminance at most this many times the
    # brightest of its neighbours and of its warped history (filters.clamp_fireflies); 0: off.
    # Not in the paper, not a weight: a checkpoint trained without it can run with it
    firefly_clamp: float = 0.0
    # the demodulated diffuse of samples that hit no diffuse surface filled from their
    # neighbours' (filters.fill_diffuse_holes). Not in the paper, not a weight: a checkpoint
    # trained without it can run with it
    diffuse_fill: bool = False
    # the composite takes the 5x5 mean of the filtered albedo where diffuse holes lie
    # scattered (filters.albedo_at_holes). Not in the paper, not a weight
    albedo_at_holes: bool = False
    # the input block also reads the guide albedo (layout.GUIDE: Cycles' Denoising Albedo, the
    # albedo where a frame has none), after current and history: what a mirror or chrome
    # reflects, where the albedo is 0 and the reflection lives only in the noisy specular
    # layer (docs/model-gap.md, "Mirrors, glossy reflections and hair"). A weight: three more
    # projection inputs
    guide_albedo: bool = False
    # the input block's design (``INPUT_BLOCKS``): "native", the paper's (a 1x1 projection and a
    # 3x3 convolution at native resolution, then the 2x2 average pool); "space_to_depth", each
    # 2x2 block of input pixels as one pixel of 4x the channels at half resolution, a 1x1
    # projection to ``input_hidden`` and a 3x3 convolution to the four pixels' ``input_width``
    # features: the same native features and pooled ones, from fewer, wider convolutions that
    # int8 kernels run nearer their peak (docs/performance.md, "Where the time goes"; the
    # study at commit 9bb4de9: benchmarks/results/input_block_designs.md)
    input_block: str = "native"
    input_hidden: int = 32  # "space_to_depth" only: the projection's width

    def __post_init__(self):
        object.__setattr__(self, "encoder_widths", tuple(self.encoder_widths))
        depth = len(self.encoder_widths)
        if depth < 1:
            raise ConfigError("encoder_widths needs at least one U-Net level")
        if not 0 <= self.filter_levels <= depth + 1:
            raise ConfigError(
                f"filter_levels must be in [0, {depth + 1}] for U-Net depth {depth}, got {self.filter_levels}"
            )
        if self.input_block not in INPUT_BLOCKS:
            raise ConfigError(f"input_block must be one of {', '.join(INPUT_BLOCKS)}, got {self.input_block!r}")
        if self.upsample_root not in UPSAMPLE_ROOTS:
            raise ConfigError(f"upsample_root must be one of {UPSAMPLE_ROOTS}, got {self.upsample_root!r}")
        if not (self.firefly_clamp == 0 or self.firefly_clamp >= 1):
            raise ConfigError(f"firefly_clamp must be 0 (off) or >= 1, got {self.firefly_clamp!r}")
        if not isinstance(self.scale, int) or self.scale < 1:
            raise ConfigError(f"scale must be an integer >= 1, got {self.scale!r}")
        for name, v in asdict(self).items():
            if name != "encoder_widths" and isinstance(v, int) and v < 0:
                raise ConfigError(f"{name} must be >= 0, got {v}")
        if self.upsample_width == 0 and self.upsample_features:
            raise ConfigError(
                f"upsample_width 0 (one fixed kernel) reads no features: upsample_features "
                f"must be 0, got {self.upsample_features}"
            )

    @property
    def fixed_upsample(self) -> bool:
        """The upsample block is one learned 3x3 kernel (no per-pixel prediction, no graph)."""
        return self.scale > 1 and self.upsample_width == 0

    @property
    def depth(self) -> int:
        return len(self.encoder_widths)

    @property
    def decoder_inputs(self) -> list[int]:
        """Per U-Net decoder block, deepest first, the width of the upsampled deeper
        features it reads ahead of its skip connection (``FeatureExtractor``)."""
        return [self.bottleneck_width, *reversed(self.encoder_widths[1:])]

    @property
    def pad_multiple(self) -> int:
        """Native sizes must be multiples of this (input pooling + U-Net max-pools)."""
        return 2 ** (self.depth + 1)

    @staticmethod
    def preset(name: str, **overrides) -> "ModelConfig":
        presets = {
            # about 21 GMAC per 1280x720 frame: sized for a 2-core CPU
            "small": {},
            # the U-Net and output block wider (about 32 GMAC at 720p): what the time
            # allowed beside OIDN leaves room for; trained from "small" (``jnds train --init``
            # widens a checkpoint)
            "medium": dict(encoder_widths=(32, 48), bottleneck_width=64, output_width=24),
            # the U-Net wider again (about 53 GMAC at 720p; the output block as in "medium"):
            # what the time allowed beside OIDN left room for on a 2-core CPU (docs/training.md,
            # "The lineage"); widened from "medium" the same way
            "large": dict(encoder_widths=(48, 64), bottleneck_width=96, output_width=24),
            # "large" one U-Net level deeper, filtering down to native / 16 (4 levels, as the
            # paper): the reach "large" lacked on unseen scenes (docs/model-gap.md); deepened
            # from "large" (``jnds train --init`` keeps what the old levels computed)
            "deep": dict(encoder_widths=(48, 64, 96), bottleneck_width=128, output_width=24, filter_levels=4),
            # "large" with its coarser half wider (the second encoder block 96, the bottleneck
            # 192; about 77 GMAC at 720p): the capacity where the model's excess error over OIDN
            # lies, at 2-32 pixels (docs/model-gap.md). Widened from "large" it gained nothing in a
            # fine-tune, and on an AVX2 CPU it is over the time allowed beside OIDN: a probe, not
            # shipped (docs/training.md, "What did not work")
            "wide": dict(encoder_widths=(48, 96), bottleneck_width=192, output_width=24),
            # deeper and wider, closer to the paper's network (whose exact widths are in its
            # Fig. 3, not in the text we have): for GPUs and quality comparisons
            "paper": dict(
                input_width=32,
                encoder_widths=(48, 64, 80),
                bottleneck_width=96,
                output_width=32,
                upsample_features=8,
                upsample_width=16,
                filter_levels=4,
            ),
            # for tests: tiny and fast
            "tiny": dict(
                input_width=4,
                encoder_widths=(6,),
                bottleneck_width=8,
                output_width=4,
                upsample_features=2,
                upsample_width=4,
                filter_levels=2,
            ),
        }
        if name not in presets:
            raise ConfigError(f"unknown preset {name!r}, expected one of {', '.join(presets)}")
        return ModelConfig(**{**presets[name], **overrides})


# ---------------------------------------------------------------------------------------
# fake quantization


def _ste_round(x: torch.Tensor) -> torch.Tensor:
    return x + (torch.round(x) - x).detach()


class ActQuant(nn.Module):
    """Per-tensor affine uint8 fake quantization with a trained range [lo, hi].

    Disabled (identity) until ``enabled`` is set; ``calibrate`` runs the range to the
    observed min/max first so QAT starts from a sensible range.
    """

    def __init__(self):
        super().__init__()
        self.lo = nn.Parameter(torch.tensor(0.0))
        self.hi = nn.Parameter(torch.tensor(1.0))
        self.enabled = False
        self.observing = False

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.observing:
            with torch.no_grad():
                self.lo.copy_(torch.minimum(self.lo, x.min().clamp(max=0.0)))
                self.hi.copy_(torch.maximum(self.hi, x.max()))
        if not self.enabled:
            return x
        lo = torch.minimum(self.lo, torch.zeros_like(self.lo))  # zero must be representable
        hi = torch.maximum(self.hi, lo + 1e-4)
        scale = (hi - lo) / 255.0
        zero_point = _ste_round(-lo / scale)
        q = torch.clamp(_ste_round(x / scale) + zero_point, 0.0, 255.0)
        return (q - zero_point) * scale

    def qparams(self) -> tuple[float, int]:
        """(scale, uint8 zero point) as ONNX QuantizeLinear wants them."""
        lo = min(self.lo.item(), 0.0)
        hi = max(self.hi.item(), lo + 1e-4)
        scale = (hi - lo) / 255.0
        return scale, int(round(-lo / scale))


def quantize_weight(w: torch.Tensor) -> torch.Tensor:
    """Per-output-channel symmetric int8 fake quantization, threshold max|w|."""
    scale = w.detach().abs().amax(dim=(1, 2, 3), keepdim=True).clamp_min(1e-8) / 127.0
    return w + (torch.clamp(torch.round(w / scale), -127, 127) * scale - w).detach()


class QConv(nn.Conv2d):
    """A convolution whose input activation and weights are fake-quantized when enabled."""

    def __init__(self, cin: int, cout: int, k: int, padding_mode: str = "zeros"):
        if padding_mode not in ("zeros", "replicate"):
            raise ValueError(f"padding_mode must be 'zeros' or 'replicate', got {padding_mode!r}")
        super().__init__(cin, cout, k, padding=k // 2, padding_mode=padding_mode)
        self.act_quant = ActQuant()
        self.quantize = False

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.act_quant(x)
        w = quantize_weight(self.weight) if self.quantize else self.weight
        if self.padding_mode == "replicate":
            p = self.kernel_size[0] // 2
            return F.conv2d(F.pad(x, (p, p, p, p), mode="replicate"), w, self.bias)
        return F.conv2d(x, w, self.bias, padding=self.padding)


def round_weights(module: nn.Module) -> int:
    """Replace every convolution's weights by their int8 fake-quantized values, the weights
    quantization-aware training ran; returns how many. Idempotent: rounding rounded weights
    changes nothing (the per-channel maximum is a code of 127)."""
    n = 0
    with torch.no_grad():
        for m in module.modules():
            if isinstance(m, QConv):
                m.weight.copy_(quantize_weight(m.weight))
                n += 1
    return n


def set_quantization(module: nn.Module, enabled: bool) -> None:
    for m in module.modules():
        if isinstance(m, QConv):
            m.quantize = enabled
            m.act_quant.enabled = enabled


def set_observing(module: nn.Module, observing: bool) -> None:
    for m in module.modules():
        if isinstance(m, ActQuant):
            m.observing = observing


def quant_ranges(module: nn.Module) -> dict[str, dict]:
    """The learned activation ranges, as data: conv name -> {lo, hi, scale, zero_point}."""
    out = {}
    for name, m in module.named_modules():
        if isinstance(m, QConv):
            s, z = m.act_quant.qparams()
            out[name] = {"lo": m.act_quant.lo.item(), "hi": m.act_quant.hi.item(), "scale": s, "zero_point": z}
    return out


# ---------------------------------------------------------------------------------------
# blocks


def _kernel(raw: torch.Tensor) -> torch.Tensor:
    """Diffuse/specular/upsample kernels: linear weights clamped to [-1, 1]."""
    return raw.clamp(-1.0, 1.0)


def _normalized_kernel(raw: torch.Tensor) -> torch.Tensor:
    """Albedo/normal kernels: normalized (softmax over the 9 taps). Written out rather
    than ``torch.softmax``: ONNX Runtime's Softmax over the channel axis of an NCHW tensor
    transposes internally and dominated the frame (docs/architecture.md, "The network graph"); the
    ReduceMax/Exp/ReduceSum/Div form it exports to computes the same values."""
    e = torch.exp(raw - raw.amax(dim=1, keepdim=True))
    return e / e.sum(dim=1, keepdim=True)


def _blend(raw: torch.Tensor) -> torch.Tensor:
    return torch.sigmoid(raw)


def init_identity(head: nn.Conv2d, sizes: list[tuple[str, int]]) -> None:
    """Start a kernel head near pass-through: small weights, and a bias that makes every
    3x3 kernel an identity (centre tap) and every blend weight 0.5; feature channels keep
    the default initialization."""
    default = head.weight.detach().clone()
    nn.init.normal_(head.weight, std=1e-3)
    with torch.no_grad():
        head.bias.zero_()
        i = 0
        for name, n in sizes:
            if n == 9:
                head.bias[i + 4] = 4.0 if name.startswith("aux.") else 1.0
            elif name == "features":
                # features pass a ReLU: near-zero weights and bias left them dead in the
                # first trained checkpoint (all zero on every input); keep PyTorch's init
                head.weight[i : i + n] = default[i : i + n]
                head.bias[i : i + n] = 0.01
            i += n


def _split(t: torch.Tensor, sizes: list[tuple[str, int]]) -> dict[str, torch.Tensor]:
    parts = torch.split(t, [s for _, s in sizes], dim=1)
    return {n: p for (n, _), p in zip(sizes, parts)}


class PhaseMean(nn.Module):
    """The 2x2 average of native features held as four phases (pixel_shuffle's order,
    channel c * 4 + phase) at half resolution: a 1x1 convolution with fixed weights, which the
    int8 graph runs as one convolution where a depth-to-space and a pool would be two passes.
    Not trained (a buffer, not saved)."""

    def __init__(self, width: int):
        super().__init__()
        mean = torch.zeros(width, 4 * width, 1, 1)
        for c in range(width):
            mean[c, 4 * c : 4 * c + 4] = 0.25
        self.register_buffer("weight", mean, persistent=False)

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        return F.conv2d(f, self.weight)


class InputBlock(nn.Module):
    """``cfg.input_block`` "native" (the paper's) or "space_to_depth" (``ModelConfig``): the
    same two outputs either way, the native features and their 2x2 average."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        channels = N_CURRENT + N_HISTORY + (N_GUIDE if cfg.guide_albedo else 0)
        self.space_to_depth = cfg.input_block == "space_to_depth"
        if self.space_to_depth:
            # pixel_unshuffle's channel c * 4 + phase: each input channel's 2x2 block together
            self.project = QConv(4 * channels, cfg.input_hidden, 1)
            self.conv = QConv(cfg.input_hidden, 4 * cfg.input_width, 3)
            self.mean = PhaseMean(cfg.input_width)
        else:
            self.project = QConv(channels, cfg.input_width, 1)
            self.conv = QConv(cfg.input_width, cfg.input_width, 3)

    def forward(
        self, current: torch.Tensor, history: torch.Tensor, guide: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """current (N, 13, H, W), history (N, 12, H, W): linear, as stored; guide (N, 3, H, W)
        the guide albedo, with ``guide_albedo`` (else None). Returns (native features for
        the output block, pooled features for the U-Net)."""
        parts = [tonemap_inputs(current, CURRENT), tonemap_inputs(history, HISTORY)]
        x = torch.cat(parts + ([guide] if guide is not None else []), 1)
        if self.space_to_depth:
            # features c * 4 + phase of each half-resolution pixel: pixel_shuffle's order
            f = F.relu(self.conv(F.relu(self.project(F.pixel_unshuffle(x, 2)))))
            return F.pixel_shuffle(f, 2), self.mean(f)
        f = F.relu(self.conv(F.relu(self.project(x))))
        return f, filters.downsample(f)


def tonemap_inputs(x: torch.Tensor, layout) -> torch.Tensor:
    """Radiance layers through Eq. 1; albedo, roughness as is; normals to [0, 1]."""
    parts, i = [], 0
    for name, c in layout:
        p = x[:, i : i + c]
        if name in RADIANCE:
            p = filters.tonemap(p)
        elif name == "normal":
            p = p * 0.5 + 0.5
        parts.append(p)
        i += c
    return torch.cat(parts, 1)


class DoubleConv(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.a = QConv(cin, cout, 3)
        self.b = QConv(cout, cout, 3)

    def forward(self, x):
        return F.relu(self.b(F.relu(self.a(x))))


def _path_sizes(coarsest: bool) -> list[tuple[str, int]]:
    return [("down", 9)] if coarsest else [("down", 9), ("up", 9), ("up_blend", 1)]


class FeatureExtractor(nn.Module):
    """U-Net at sub-native resolution with per-level filter-path heads."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        widths = [cfg.input_width, *cfg.encoder_widths]
        self.encoders = nn.ModuleList(DoubleConv(widths[i], widths[i + 1]) for i in range(cfg.depth))
        self.bottleneck = DoubleConv(widths[-1], cfg.bottleneck_width)
        dec_out = list(reversed(cfg.encoder_widths))
        self.decoders = nn.ModuleList(
            DoubleConv(cfg.decoder_inputs[i] + dec_out[i], dec_out[i]) for i in range(cfg.depth)
        )
        # level k (1-based, resolution native / 2^k) is predicted by the decoder block at
        # that resolution, the coarsest possible level (depth + 1) by the bottleneck
        self.heads = nn.ModuleDict()
        for level in range(1, cfg.filter_levels + 1):
            width = cfg.bottleneck_width if level == cfg.depth + 1 else cfg.encoder_widths[level - 1]
            n = sum(s for _, s in _path_sizes(level == cfg.filter_levels))
            for path in ("diffuse", "specular"):
                self.heads[f"{path}{level}"] = QConv(width, n, 1)
                init_identity(self.heads[f"{path}{level}"], _path_sizes(level == cfg.filter_levels))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, list[dict]]]:
        skips = []
        for enc in self.encoders:
            x = enc(x)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = self.bottleneck(x)
        by_level = {self.cfg.depth + 1: x}
        for i, dec in enumerate(self.decoders):
            skip = skips[-1 - i]
            x = dec(torch.cat([filters.upsample(x), skip], 1))
            by_level[self.cfg.depth - i] = x
        kernels: dict[str, list[dict]] = {"diffuse": [], "specular": []}
        for level in range(1, self.cfg.filter_levels + 1):
            sizes = _path_sizes(level == self.cfg.filter_levels)
            for path in kernels:
                raw = _split(self.heads[f"{path}{level}"](by_level[level]), sizes)
                kernels[path].append({k: _blend(v) if k == "up_blend" else _kernel(v) for k, v in raw.items()})
        return x, kernels


class OutputBlock(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        self.conv = QConv(cfg.encoder_widths[0] + cfg.input_width, cfg.output_width, 3)
        self.path_sizes = [("spatial", 9), ("temporal", 9), ("blend", 1)]
        if cfg.filter_levels > 0:
            self.path_sizes += [("up", 9), ("up_blend", 1)]
        self.sizes = (
            [(f"diffuse.{n}", s) for n, s in self.path_sizes]
            + [(f"specular.{n}", s) for n, s in self.path_sizes]
            + [("aux.spatial", 9), ("aux.temporal", 9), ("aux.blend", 1)]
        )
        if cfg.scale > 1 and cfg.upsample_features:
            self.sizes.append(("features", cfg.upsample_features))
        self.head = QConv(cfg.output_width, sum(s for _, s in self.sizes), 1)
        init_identity(self.head, self.sizes)

    def forward(self, decoded: torch.Tensor, native: torch.Tensor) -> dict[str, torch.Tensor]:
        x = F.relu(self.conv(torch.cat([filters.upsample(decoded), native], 1)))
        post = {"relu": F.relu, "blend": _blend, "normalized": _normalized_kernel, "kernel": _kernel}
        return {name: post[head_kind(name)](t) for name, t in _split(self.head(x), self.sizes).items()}


class JNDSNetwork(nn.Module):
    """Input block + feature extractor + output block: every per-pixel kernel and blend
    weight of the filter paths, and the features of the upsample block.

    Inputs: current (N, 13, H, W) and warped history (N, 12, H, W), linear as stored, and
    with ``cfg.guide_albedo`` the guide albedo (N, 3, H, W); H and W multiples of
    ``cfg.pad_multiple``. Output: a flat dict of tensors named
    ``diffuse.spatial``, ..., ``diffuse.level1.down``, ..., ``features``.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        self.input_block = InputBlock(cfg)
        self.feature_extractor = FeatureExtractor(cfg)
        self.output_block = OutputBlock(cfg)

    def forward(
        self, current: torch.Tensor, history: torch.Tensor, guide: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        if (guide is not None) != self.cfg.guide_albedo:
            raise ConfigError(f"the network {'reads' if self.cfg.guide_albedo else 'has no'} guide albedo input")
        native, pooled = self.input_block(current, history, guide)
        decoded, levels = self.feature_extractor(pooled)
        out = self.output_block(decoded, native)
        for path, lv in levels.items():
            for k, d in enumerate(lv, start=1):
                for name, t in d.items():
                    out[f"{path}.level{k}.{name}"] = t
        return out


class UpsampleBlock(nn.Module):
    """Kernel prediction at target resolution from the composite and output-block features.

    Inputs at native resolution: composite (N, 3, H, W) linear, features (N, F, H, W).
    Output: the clamped linear 3x3 kernel (N, 9, sH, sW).

    The 3x3 convolution pads by replicating the border (the paper does not say; zeros
    would make the sub-pixel form below differ on the outermost target pixels).
    ``polyphase`` computes the same values at native resolution (``SubPixelUpsampleBlock``).

    With ``cfg.fixed_upsample`` the block is one learned kernel (``fixed``, 9 taps, identity
    at first), the same at every pixel: output (N, 9, 1, 1), which broadcasts.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.scale = cfg.scale
        if cfg.fixed_upsample:
            self.fixed = nn.Parameter(torch.zeros(9))
            with torch.no_grad():
                self.fixed[4] = 1.0
            return
        self.fixed = None
        self.conv = QConv(3 + cfg.upsample_features, cfg.upsample_width, 3, padding_mode="replicate")
        self.head = QConv(cfg.upsample_width, 9, 1)
        init_identity(self.head, [("kernel", 9)])

    def forward(self, composite: torch.Tensor, features: torch.Tensor | None) -> torch.Tensor:
        if self.fixed is not None:
            return _kernel(self.fixed).view(1, 9, 1, 1).expand(composite.shape[0], 9, 1, 1)
        parts = [filters.upsample(filters.tonemap(composite), self.scale)]
        if features is not None:
            parts.append(filters.upsample(features, self.scale))
        return _kernel(self.head(F.relu(self.conv(torch.cat(parts, 1)))))

    def polyphase(self) -> "SubPixelUpsampleBlock":
        return SubPixelUpsampleBlock(self)


def bilinear_taps(scale: int) -> torch.Tensor:
    """(scale, 3, 3) weights: for target phase p (target index s*i + p) and target tap
    d in {-1, 0, 1}, the bilinear (align_corners=False) weights of native pixels
    i-1, i, i+1. Every 3-tap target neighbourhood reads only those three native pixels."""
    a = torch.zeros(scale, 3, 3, dtype=torch.float64)
    for p in range(scale):
        for d in (-1, 0, 1):
            u = (p + d + 0.5) / scale - 0.5  # native coordinate relative to i
            u0 = math.floor(u)
            f = u - u0
            a[p, d + 1, u0 + 1] += 1 - f
            a[p, d + 1, u0 + 2] += f
    return a


class SubPixelUpsampleBlock(nn.Module):
    """The upsample block evaluated at native resolution (sub-pixel convolution, Shi et
    al. 2016): bilinear upsampling is linear, so the 3x3 convolution of the upsampled
    input is, for each of the s^2 target phases, a 3x3 convolution of the native input
    with the bilinear weights folded into it; the 1x1 head runs per phase (grouped).
    Output: the kernel in phase layout (N, s*s*9, H, W), ``filters.to_phases`` of
    ``UpsampleBlock.forward``'s, equal everywhere, borders included (with replicate
    padding at both resolutions, the clamped bilinear sample outside the image is the edge
    pixel). It never builds the upsampled (3 + F)-channel input at target resolution, and
    leaves interleaving the phases to whoever applies the kernel (ONNX Runtime's
    DepthToSpace is slow at it, docs/architecture.md, "The network graph"; the fused filter loop reads the
    phases directly). Fake quantization is not applied (used for export, fp32)."""

    def __init__(self, block: UpsampleBlock):
        super().__init__()
        s = self.scale = block.scale
        a = bilinear_taps(s)
        w = block.conv.weight.detach().double()  # (O, C, 3, 3)
        folded = torch.einsum("ocab,yan,xbm->yxocnm", w, a, a)  # phase (y, x), native taps (n, m)
        o, c = w.shape[:2]
        # named as in UpsampleBlock, so the ONNX nodes (/conv/Conv, /head/Conv) match its modules
        self.conv = nn.Conv2d(c, s * s * o, 3)
        self.head = nn.Conv2d(s * s * o, s * s * 9, 1, groups=s * s)
        with torch.no_grad():
            self.conv.weight.copy_(folded.reshape(s * s * o, c, 3, 3))
            self.conv.bias.copy_(block.conv.bias.repeat(s * s))
            self.head.weight.copy_(block.head.weight.repeat(s * s, 1, 1, 1))
            self.head.bias.copy_(block.head.bias.repeat(s * s))
        self.requires_grad_(False)

    def forward(self, composite: torch.Tensor, features: torch.Tensor | None) -> torch.Tensor:
        parts = [filters.tonemap(composite)] + ([features] if features is not None else [])
        x = F.pad(torch.cat(parts, 1), (1, 1, 1, 1), mode="replicate")
        return _kernel(self.head(F.relu(self.conv(x))))


# ---------------------------------------------------------------------------------------
# the whole frame


@dataclass
class FrameOutput:
    """Outputs of one frame (NCHW, linear): the filtered native signals (also the next
    frame's history), the native composite and the target-resolution output."""

    diffuse: torch.Tensor
    specular: torch.Tensor
    albedo: torch.Tensor
    normal: torch.Tensor
    composite: torch.Tensor
    output: torch.Tensor
    extras: dict = field(default_factory=dict)

    def history(self) -> torch.Tensor:
        """(N, 12, H, W) in HISTORY order; normals stored in [-1, 1]."""
        return torch.cat([self.diffuse, self.specular, self.albedo, self.normal], 1)


def split_history(h: torch.Tensor) -> dict[str, torch.Tensor]:
    return _split(h, list(HISTORY))


class JNDS(nn.Module):
    """The whole recurrent frame step in PyTorch (training, reference for the runtime)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        self.network = JNDSNetwork(cfg)
        self.upsample_block = UpsampleBlock(cfg) if cfg.scale > 1 else None

    def forward(
        self,
        current: torch.Tensor,
        motion: torch.Tensor,
        history: torch.Tensor | None,
        reset: torch.Tensor | None = None,
        guide: torch.Tensor | None = None,
    ) -> FrameOutput:
        """One frame. ``current`` (N, 13, H, W) linear inputs; ``motion`` (N, 2, H, W);
        ``history`` the previous frame's ``FrameOutput.history()`` or None (first frame,
        camera cut): then the current inputs stand in for the history. ``reset`` (N,) bool:
        the samples whose history is dropped, as if None (a cut inside a training window).
        ``guide`` (N, 3, H, W): the guide albedo, read only with ``cfg.guide_albedo``
        (None: the albedo, as for a frame without one)."""
        cur = _split(current, list(CURRENT))
        if self.cfg.guide_albedo:
            guide = (cur["albedo"] if guide is None else guide).clamp(0, 1)
        else:
            guide = None
        holes = filters.diffuse_holes(cur["albedo"], cur["normal"]) if self.cfg.albedo_at_holes else None
        if self.cfg.diffuse_fill:
            cur["diffuse"] = filters.fill_diffuse_holes(cur["diffuse"], cur["albedo"], cur["normal"])
            current = torch.cat([cur[n] for n, _ in CURRENT], 1)
        cur_hist = torch.cat([cur[n] for n, _ in HISTORY], 1)
        if history is None:
            warped = cur_hist
        else:
            warped = filters.warp(history, motion)
            # bicubic overshoot: radiance and albedo stay >= 0, normals in [-1, 1]
            w = split_history(warped)
            warped = torch.cat(
                [
                    w["diffuse"].clamp_min(0),
                    w["specular"].clamp_min(0),
                    w["albedo"].clamp(0, 1),
                    w["normal"].clamp(-1, 1),
                ],
                1,
            )
            # where the history shows another surface, or the pixel sees background, the
            # current inputs stand in for it, as in the first frame
            rejected = filters.history_rejected(
                cur["normal"], w["normal"].clamp(-1, 1), cur["albedo"], w["albedo"].clamp(0, 1), motion
            )
            warped = torch.where(rejected, cur_hist, warped)
            if reset is not None:
                warped = torch.where(reset.view(-1, 1, 1, 1), cur_hist, warped)
            if self.cfg.firefly_clamp:
                w = split_history(warped)
                for p in RADIANCE:
                    cur[p] = filters.clamp_fireflies(cur[p], w[p], self.cfg.firefly_clamp)
                current = torch.cat([cur[n] for n, _ in CURRENT], 1)
        net = self.network(current, warped, guide)
        hist = split_history(warped)
        paths = {}
        for p in ("diffuse", "specular"):
            native = {
                k: net[f"{p}.{k}"] for k in ("spatial", "temporal", "blend", "up", "up_blend") if f"{p}.{k}" in net
            }
            levels = []
            for k in range(1, self.cfg.filter_levels + 1):
                levels.append(
                    {n: net[f"{p}.level{k}.{n}"] for n in ("down", "up", "up_blend") if f"{p}.level{k}.{n}" in net}
                )
            paths[p] = filters.filter_path(cur[p], hist[p], native, levels)
        aux = [
            filters.spatiotemporal(x, h, net["aux.spatial"], net["aux.temporal"], net["aux.blend"])
            for x, h in ((cur["albedo"], hist["albedo"]), (cur["normal"] * 0.5 + 0.5, hist["normal"] * 0.5 + 0.5))
        ]
        albedo, normal = aux[0], aux[1] * 2.0 - 1.0
        lit = filters.albedo_at_holes(albedo, filters.scattered_holes(holes)) if holes is not None else albedo
        comp = filters.composite(lit, paths["diffuse"], paths["specular"])
        return FrameOutput(
            paths["diffuse"], paths["specular"], albedo, normal, comp, self.upsample(comp, net.get("features"))
        )

    def upsample(self, composite: torch.Tensor, features: torch.Tensor | None) -> torch.Tensor:
        """The upsample block and its filter: the target-resolution output of a native
        composite and the output block's features (the composite itself at scale 1)."""
        if self.upsample_block is None:
            return composite
        kernel = self.upsample_block(composite, features)
        return filters.upsample_filter(composite, kernel, self.cfg.scale, self.cfg.upsample_root)


def pad_to_multiple(x: torch.Tensor, multiple: int) -> tuple[torch.Tensor, tuple[int, int]]:
    """Replicate-pad H and W up to a multiple; returns the padded tensor and (H, W) to crop back."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    return x, (h, w)


def count_macs(cfg: ModelConfig, width: int = 1280, height: int = 720) -> dict[str, float]:
    """Multiply-accumulates of the convolutions per frame, by stage, in GMAC, at a native
    size (padded to the model's multiple): counted by running the model on zeros."""
    model = JNDS(cfg)
    counts: dict[str, float] = {}

    def hook(name):
        def f(mod, inp, out):
            k = mod.kernel_size[0] * mod.kernel_size[1] * mod.in_channels // mod.groups
            counts[name] = counts.get(name, 0.0) + out.numel() * k / 1e9

        return f

    stages = {
        "input_block": model.network.input_block,
        "feature_extractor": model.network.feature_extractor,
        "output_block": model.network.output_block,
    }
    if model.upsample_block is not None:
        stages["upsample_block"] = model.upsample_block
    handles = [
        m.register_forward_hook(hook(stage))
        for stage, block in stages.items()
        for m in block.modules()
        if isinstance(m, nn.Conv2d)
    ]
    x, _ = pad_to_multiple(torch.zeros(1, N_CURRENT, height, width), cfg.pad_multiple)
    with torch.no_grad():
        model(x, torch.zeros(1, 2, *x.shape[-2:]), None)
    for h in handles:
        h.remove()
    counts["total"] = sum(counts.values())
    return counts
