"""``TrainConfig``: everything that defines a training run, saved as ``<run>/config.json``,
and ``jnds train``'s options (``options.option``)."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import ConfigError
from ..layout import INPUT_BLOCKS, UPSAMPLE_ROOTS
from ..options import option

# the fields that say which model a run trains (TrainConfig.model_config); `jnds train
# --init` takes those it is not given from the checkpoint (init_settings)
MODEL_SETTINGS = (
    "preset",
    "output_width",
    "upsample_root",
    "firefly_clamp",
    "diffuse_fill",
    "albedo_at_holes",
    "guide_albedo",
    "input_block",
    "input_hidden",
    "fixed_upsample",
)
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
    data: str = option("data", "directory with train/ and val/ sequences")
    run: str = option("runs/small", "output directory (checkpoint, log, config)")
    # preset to fixed_upsample: the trained model's settings (MODEL_SETTINGS, model_config)
    preset: str = option("small", "the network's widths and depths (model.ModelConfig.preset)")
    output_width: int = option(
        0,
        "the output block's hidden channels instead of the preset's (0: the preset's; an AVX2 CPU's int8 "
        "convolution costs in steps of 16; --init narrows or widens a checkpoint to it)",
        metavar="C",
    )
    upsample_root: int = option(
        1,
        "the upsample filter interpolates the composite's root of this degree (1: linear, the paper)",
        choices=UPSAMPLE_ROOTS,
    )
    firefly_clamp: float = option(
        0.0, "train with the firefly clamp (model.ModelConfig.firefly_clamp; 0: off)", metavar="K"
    )
    diffuse_fill: bool = option(
        False,
        "train with the diffuse of samples that hit no diffuse surface filled from "
        "their neighbours' (model.ModelConfig.diffuse_fill)",
    )
    albedo_at_holes: bool = option(
        False,
        "train with the composite's albedo averaged where such samples lie "
        "scattered (model.ModelConfig.albedo_at_holes)",
    )
    guide_albedo: bool = option(
        False,
        "the network also reads the guide albedo (the optional layer denoising_albedo, the albedo where a "
        "frame has none; model.ModelConfig.guide_albedo); --init from a checkpoint without it adds the "
        "input (see --guide-init)",
    )
    guide_init: str = option(
        GUIDE_INITS[0],
        "how --guide-albedo --init from a checkpoint without the input starts its weights: zero (the "
        "same outputs), or split (the albedo's weights halved and shared with the guide: the same "
        "outputs where the two agree, the guide in use from the first step; surgery.guided)",
        choices=GUIDE_INITS,
    )
    input_block: str = option(
        INPUT_BLOCKS[0],
        "the input block's design (model.ModelConfig.input_block): native, the paper's, or "
        "space_to_depth (each 2x2 pixel block as one half-resolution pixel); --init from a "
        "checkpoint of the other design fits the new block to its features first",
        choices=INPUT_BLOCKS,
    )
    input_hidden: int = option(32, "space_to_depth: the input block's projection width", metavar="C")
    input_fit_steps: int = option(
        800,
        "--init of the other input block design: steps fitting the new block to the old one's features (the "
        "rest of the network frozen) before training (train._fit_input_block)",
        metavar="N",
    )
    fixed_upsample: bool = option(
        False,
        "one learned upsample kernel for every pixel instead of the upsample block's per-pixel prediction "
        "(ModelConfig.upsample_width 0: no upsample graph; --init from a predicting checkpoint drops its "
        "upsample block and features)",
    )
    patch: int = option(64, "native patch side, a multiple of the model's pad multiple")
    unroll: int = option(6, "consecutive frames per sample")
    burn_in: int = option(
        0,
        "up to N frames before each training window run without gradients (drawn per batch from 0..N; "
        "train.run_unroll): the history the loss sees has accumulated longer",
        metavar="N",
    )
    batch: int = option(4, "samples per step")
    fp32_steps: int = option(4000, "steps of the full-precision phase")
    qat_steps: int = option(1500, "steps of the quantization-aware phase")
    lr: float = option(1e-3, "fp32 phase learning rate")
    qat_lr: float = option(1e-4, "QAT phase learning rate")
    lr_decay: float = 0.1  # exponential decay to lr * lr_decay over each phase
    warmup_steps: int = option(
        0,
        "the fp32 learning rate rises linearly over the first N steps (a fine-tune's fresh optimizer moments "
        "otherwise move every weight by a full step at once)",
        metavar="N",
    )
    w_spatial: float = option(0.2, "each task's loss: W x spatial + (1 - W) x temporal (Sec. 3.3's 0.2)", metavar="W")
    spatial_loss: str = option("l1", "l1, feature, or l1+feature (the sum of both)", choices=SPATIAL_LOSSES)
    feature_net: str | None = option(None, "feature-loss network checkpoint (jnds train-feature-net)")
    lowfreq_loss: float = option(
        0.0,
        "add W x the L1 of 4-, 8- and 16-pixel box averages (target pixels) of output and reference to each "
        "radiance task's spatial loss (training.losses.lowfreq; 0: the paper's loss)",
        metavar="W",
    )
    init: str | None = option(
        None,
        "start a new run from this checkpoint's weights (e.g. the shipped one) to fine-tune it; the "
        "trained model's settings (--preset, --output-width, --upsample-root, --firefly-clamp, "
        "--diffuse-fill, --albedo-at-holes, --guide-albedo, --input-block, --input-hidden, "
        "--fixed-upsample) are the checkpoint's where not given",
    )
    deepen_blend: float = option(
        DEEPENED_BLEND,
        "--init one U-Net level shallower than --preset: the new level enters the old coarsest one "
        "with blend weight sigmoid(LOGIT)",
        metavar="LOGIT",
    )
    observe_batches: int = 8  # batches to observe activation ranges before QAT
    val_every: int = option(500, "steps between validations")
    checkpoint_every: int = option(100, "write <run>/checkpoint.pt every N steps (and at the end)", metavar="N")
    val_sequences: int | None = option(None, "validate on the first N sequences only", metavar="N")
    threads: int = option(2, "torch threads")
    seed: int = option(0, "seed of the weights' initialization and the sampling")
    device: str = option("cpu", "torch device of the training steps: cpu or cuda (the data stays on the host)")
    channels_last: bool = option(True, "convolutions in NHWC memory: the same values, faster steps on a CPU; off: NCHW")
    # augmentations (training.data.Augment)
    exposure: tuple[float, float] | None = option(
        None, "augmentation: radiance (inputs and reference) x 2^u, u uniform in [LO, HI] stops", metavar=("LO", "HI")
    )
    rotate_normals: bool = option(
        False, "augmentation: a uniformly random rotation of the normals' world frame per sample"
    )
    flips: bool = option(False, "augmentation: random horizontal and vertical mirroring")
    colours: bool = option(
        False,
        "augmentation: half the samples with R, G, B permuted (radiance and albedo) and "
        "the radiance tinted by up to half a stop per channel",
    )
    cross_cuts: bool = option(False, "training windows may span a camera cut (the history restarts there)")
    balance_renderers: bool = option(
        False,
        "draw each renderer's sequences (mitsuba, cycles: render.json's engine, or sequence.json's "
        "renderer.engine; sequences with neither are a group of their own) as often as another's, whatever "
        "their counts",
    )
    clean_references: str | None = option(
        None,
        "train against references whose diffuse and specular components OIDN denoised (colour recomposed "
        "from them; cached in each sequence's .cache/, training.data.clean_references): the renders' "
        "references keep noise (measured at commit df55e5a)",
        choices=("oidn",),
    )
    teacher: str | None = option(
        None,
        "distil: this checkpoint's outputs are the targets, not the references (the training sequences "
        "need none: jnds dataset --no-reference)",
        metavar="CHECKPOINT",
    )
    train_only: tuple[str, ...] = option(
        (),
        "train only the parameters whose names start with PREFIX (repeatable; e.g. network.output_block)",
        action="append",
        metavar="PREFIX",
    )

    def model_config(self):
        """The ``ModelConfig`` this run trains."""
        from ..model import ModelConfig

        fixed = dict(upsample_width=0, upsample_features=0) if self.fixed_upsample else {}
        if self.output_width:
            fixed["output_width"] = self.output_width
        return ModelConfig.preset(
            self.preset,
            upsample_root=self.upsample_root,
            firefly_clamp=self.firefly_clamp,
            diffuse_fill=self.diffuse_fill,
            albedo_at_holes=self.albedo_at_holes,
            guide_albedo=self.guide_albedo,
            input_block=self.input_block,
            input_hidden=self.input_hidden,
            **fixed,
        )

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


def init_settings(checkpoint: dict, given=()) -> dict:
    """The model settings (``MODEL_SETTINGS``) of the model in ``checkpoint`` (a checkpoint
    dict, ``checkpoint.read_checkpoint``), but those named in ``given``: ``jnds train
    --init`` trains the initial checkpoint's model unless told otherwise. The preset comes
    from the checkpoint's ``train_config``, and with it the output width, unless either is
    given; the input block's projection width comes with its design."""
    from ..model import ModelConfig

    given = set(given)
    model = ModelConfig(**checkpoint["model_config"])
    out = dict(
        upsample_root=model.upsample_root,
        firefly_clamp=model.firefly_clamp,
        diffuse_fill=model.diffuse_fill,
        albedo_at_holes=model.albedo_at_holes,
        guide_albedo=model.guide_albedo,
        input_block=model.input_block,
        fixed_upsample=model.fixed_upsample,
    )
    if "input_block" not in given:
        out["input_hidden"] = model.input_hidden
    preset = (checkpoint.get("train_config") or {}).get("preset")
    if preset and not given & {"preset", "output_width"}:
        width = ModelConfig.preset(preset).output_width
        out.update(preset=preset, output_width=0 if model.output_width == width else model.output_width)
    return {k: v for k, v in out.items() if k not in given}
