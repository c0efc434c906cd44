"""``TrainConfig``: everything that defines a training run, saved as ``<run>/config.json``."""
from __future__ import annotations

from dataclasses import dataclass

from ..errors import ConfigError

SPATIAL_LOSSES = ("l1", "feature", "l1+feature")
# how --init starts the guide input's weights (surgery.guided), the first the default
GUIDE_INITS = ("zero", "split")
# the default blend weight (sigmoid of this) of the new coarsest filter level where it
# enters the old one when --init deepens a checkpoint (surgery.deepened): near 0, so that
# the deepened model starts close to the old. AdamW moves a bias by about the learning
# rate a step, so a fine-tune hardly moves it from there (docs/training.md):
# TrainConfig.deepen_blend enters further in
DEEPENED_BLEND = -4.0


@dataclass
class TrainConfig:
    data: str = "data"  # holds train/ and val/ sequence directories
    run: str = "runs/small"
    preset: str = "small"
    # the preset's output block width replaced by this one (0: the preset's); --init narrows
    # or widens a checkpoint's output block to it
    output_width: int = 0
    upsample_root: int = 1  # ModelConfig.upsample_root of the trained model
    firefly_clamp: float = 0.0  # ModelConfig.firefly_clamp of the trained model (0: off)
    diffuse_fill: bool = False  # ModelConfig.diffuse_fill of the trained model
    albedo_at_holes: bool = False  # ModelConfig.albedo_at_holes of the trained model
    # ModelConfig.guide_albedo of the trained model; --init from a checkpoint without it adds the
    # input with zero weights, or with "split" half of the albedo's (surgery.guided)
    guide_albedo: bool = False
    guide_init: str = "zero"
    # ModelConfig.input_block / input_hidden of the trained model; --init from a checkpoint of
    # the other design starts the new input block fitted to the old one's features over
    # ``input_fit_steps`` steps (train._fit_input_block), the rest of the network as it was
    input_block: str = "native"
    input_hidden: int = 32
    input_fit_steps: int = 800
    # one learned upsample kernel for every pixel (ModelConfig.upsample_width 0)
    fixed_upsample: bool = False
    patch: int = 64  # native patch side, a multiple of the model's pad multiple
    unroll: int = 6  # consecutive frames per sample
    # up to this many frames before each window run first without gradients, their number
    # drawn per batch from 0..burn_in (training.train.run_unroll): the loss then also sees
    # a history accumulated over more frames than it back-propagates through
    burn_in: int = 0
    batch: int = 4
    fp32_steps: int = 4000
    qat_steps: int = 1500
    lr: float = 1e-3
    qat_lr: float = 1e-4
    lr_decay: float = 0.1  # exponential decay to lr * lr_decay over each phase
    warmup_steps: int = 0  # the fp32 phase's lr rises linearly over its first steps
    w_spatial: float = 0.2
    spatial_loss: str = "l1"  # l1 | feature | l1+feature (the sum of both)
    feature_net: str | None = None  # checkpoint of the feature-loss network
    # weight of the low-frequency term added to each radiance task's L_spatial: L1 of the
    # tonemapped output and reference box-averaged over LOWFREQ_SCALES target pixels
    # (training.losses.lowfreq; 0: off, the paper's loss)
    lowfreq_loss: float = 0.0
    init: str | None = None  # start a new run from this checkpoint's weights (fine-tuning)
    deepen_blend: float = DEEPENED_BLEND  # an init one U-Net level shallower: the new level's blend logit
    observe_batches: int = 8  # batches to observe activation ranges before QAT
    val_every: int = 500
    checkpoint_every: int = 100
    val_sequences: int | None = None  # limit validation to the first N sequences
    threads: int = 2
    seed: int = 0
    device: str = "cpu"  # torch device of the training steps (cpu, cuda); data stays on the host
    # convolutions in NHWC memory (the same values up to rounding): faster steps on a CPU
    # (benchmarks/results/train_throughput.md)
    channels_last: bool = True
    # augmentations (training.data.Augment): exposure range in stops, normal-frame rotation, flips,
    # colour permutation and tint
    exposure: tuple[float, float] | None = None
    rotate_normals: bool = False
    flips: bool = False
    colours: bool = False
    # training windows may span a camera cut, the history restarting there (PatchSampler)
    cross_cuts: bool = False
    # each renderer's sequences drawn as often as another's, whatever their counts (PatchSampler)
    balance_renderers: bool = False
    # "oidn": train against references with OIDN-denoised diffuse and specular (training.data.clean_references)
    clean_references: str | None = None
    # distillation: this checkpoint's outputs are the targets instead of the references
    # (which the training sequences then need not have: ``jnds dataset --no-reference``)
    teacher: str | None = None
    # only the parameters whose names start with one of these train (e.g.
    # "network.output_block"); empty: all
    train_only: tuple[str, ...] = ()

    def model_config(self):
        """The ``ModelConfig`` this run trains."""
        from ..model import ModelConfig

        fixed = dict(upsample_width=0, upsample_features=0) if self.fixed_upsample else {}
        if self.output_width:
            fixed["output_width"] = self.output_width
        return ModelConfig.preset(self.preset, upsample_root=self.upsample_root, firefly_clamp=self.firefly_clamp,
                                  diffuse_fill=self.diffuse_fill, albedo_at_holes=self.albedo_at_holes,
                                  guide_albedo=self.guide_albedo, input_block=self.input_block,
                                  input_hidden=self.input_hidden, **fixed)

    def __post_init__(self):
        if self.spatial_loss not in SPATIAL_LOSSES:
            raise ConfigError(f"spatial_loss must be one of {', '.join(SPATIAL_LOSSES)}, got {self.spatial_loss!r}")
        if "feature" in self.spatial_loss and not self.feature_net:
            raise ConfigError(f"spatial_loss={self.spatial_loss} needs feature_net")
        if self.exposure is not None:
            self.exposure = tuple(float(v) for v in self.exposure)  # a list when read from config.json
            if len(self.exposure) != 2 or not self.exposure[0] <= self.exposure[1]:
                raise ConfigError(f"exposure must be (lo, hi) stops with lo <= hi, got {self.exposure}")
        if not self.lowfreq_loss >= 0:
            raise ConfigError(f"lowfreq_loss must be >= 0, got {self.lowfreq_loss}")
        self.train_only = tuple(self.train_only)  # a list when read from config.json
        if self.teacher and self.clean_references:
            raise ConfigError("teacher and clean_references exclude each other: a distilled run has no reference")
        if self.guide_init not in GUIDE_INITS:
            raise ConfigError(f"guide_init must be one of {', '.join(GUIDE_INITS)}, got {self.guide_init!r}")
        if self.clean_references not in (None, "oidn"):
            raise ConfigError(f"clean_references must be None or 'oidn', got {self.clean_references!r}")
        if not 0 <= self.warmup_steps <= self.fp32_steps:
            raise ConfigError(f"warmup_steps must be in [0, fp32_steps={self.fp32_steps}], got {self.warmup_steps}")
        if self.burn_in < 0:
            raise ConfigError(f"burn_in must be >= 0 frames, got {self.burn_in}")
        if self.input_fit_steps < 0:
            raise ConfigError(f"input_fit_steps must be >= 0, got {self.input_fit_steps}")
        if not 0 <= self.w_spatial <= 1:
            raise ConfigError(f"w_spatial must be in [0, 1], got {self.w_spatial}")
