"""The one table of the network's input layers: their channels, their EXR channel
suffixes in ``jnds-sequence/1`` and the range the runtime clamps them into. Shared by
the sequence I/O, the model (torch) and the runtime (numpy, no torch), so that deploying
the ONNX pipeline does not need torch, and every channel index is derived from here.
"""

from __future__ import annotations

from dataclasses import dataclass

# radiance is clamped to [0, HDR_MAX] before tonemapping (paper, Sec. 3.2.1)
HDR_MAX = 65535.0
# the tonemap raises log(x + 1) below this to it: d/dx of t^(1/2.2) is infinite at 0
# (jnds_deploy.filter_spec.tonemap; the runtime's int8 input packing, runtime.reformat)
TONEMAP_FLOOR = 1e-10


@dataclass(frozen=True)
class Layer:
    name: str
    suffixes: tuple[str, ...]  # EXR channels <name>.<suffix> ("" : the bare name)
    lo: float  # valid range: NaN becomes 0, everything else is clamped into [lo, hi]
    hi: float
    unit_vector: bool = False  # renormalized after clamping (normals)

    @property
    def channels(self) -> int:
        return len(self.suffixes)


# the inputs of one frame, in the order the network stacks them (motion is not stacked:
# it drives the warp). Negative radiance becomes 0; motion beyond +-HDR_MAX pixels is
# off-screen either way.
LAYERS = (
    Layer("diffuse", ("R", "G", "B"), 0.0, HDR_MAX),
    Layer("specular", ("R", "G", "B"), 0.0, HDR_MAX),
    Layer("albedo", ("R", "G", "B"), 0.0, 1.0),
    Layer("normal", ("X", "Y", "Z"), -1.0, 1.0, unit_vector=True),
    Layer("roughness", ("",), 0.0, 1.0),
    Layer("motion", ("X", "Y"), -HDR_MAX, HDR_MAX),
)
INPUT_CHANNELS = {layer.name: layer.channels for layer in LAYERS}  # what a frame must hold
# the guide albedo (Cycles' Denoising Albedo: a mirror's or a metal's shows the albedo of
# what it reflects, where the layer ``albedo`` is 0) is an optional layer of the format; a
# network trained with it (``ModelConfig.guide_albedo``) reads it after current and history,
# and the layer ``albedo`` where a frame has none. No filter reads it
GUIDE = Layer("denoising_albedo", ("R", "G", "B"), 0.0, 1.0)

# channels of the current inputs and of the history, in order: (name, channel count)
CURRENT = tuple((layer.name, layer.channels) for layer in LAYERS if layer.name != "motion")
HISTORY = CURRENT[:4]  # diffuse, specular, albedo, normal: the filtered outputs kept
RADIANCE = ("diffuse", "specular")  # the layers that carry radiance: tonemapped, filtered, exposed
N_CURRENT = sum(c for _, c in CURRENT)
N_HISTORY = sum(c for _, c in HISTORY)
N_GUIDE = GUIDE.channels


def guide_of(layers: dict):
    """A frame's guide albedo (``GUIDE``): its ``denoising_albedo``, else its ``albedo``."""
    return layers.get(GUIDE.name, layers["albedo"])


def channels(name: str, layout=CURRENT) -> slice:
    """The channels of layer ``name`` in a stacked ``layout`` (CURRENT or HISTORY)."""
    start = 0
    for n, c in layout:
        if n == name:
            return slice(start, start + c)
        start += c
    raise KeyError(f"layer {name!r} is not in {[n for n, _ in layout]}")


# what the output block's head (model.OutputBlock) becomes after its 1x1 convolution,
# part by part: "kernel" clamped to [-1, 1], "blend" a sigmoid, "normalized" a softmax
# over the part's taps (albedo/normal kernels), "relu" (the upsample block's features).
# Here so that the runtime, which has no torch, applies the same rule to an int8 head
# (runtime.head)
HEAD_KINDS = ("kernel", "blend", "normalized", "relu")


def head_kind(name: str) -> str:
    """The kind (HEAD_KINDS) of the network output ``name`` the head predicts."""
    if name == "features":
        return "relu"
    if name.split(".")[-1] in ("blend", "up_blend"):
        return "blend"
    return "normalized" if name.startswith("aux.") else "kernel"


# geometric history rejection (jnds_deploy.filter_spec.disoccluded): a history normal further
# than acos(REJECT_COS) ~ 46 deg from every current normal in the 3x3 neighbourhood is
# another surface; a normal with |x| + |y| + |z| below BACKGROUND is background (unit: >= 1)
REJECT_COS = 0.7
BACKGROUND = 0.5
# ... and a history albedo outside the per-channel range of the current 3x3 albedos,
# widened by REJECT_ALBEDO, is another surface too: a surface facing the same way as the
# one now there (a ball's top over the floor) passes the normal test and left ghost trails
# (docs/ghosting.md). The range, not one pixel's value: the stored albedo is filtered, a
# blend of neighbours at texture edges, which the range holds
REJECT_ALBEDO = 0.1
# the ring around rejected pixels (jnds_deploy.filter_spec.history_rejected) is drawn around a
# rejected pixel that sees a surface where at least RING_MIN of its 3x3 (itself included) are
RING_MIN = 3

# diffuse holes (jnds_deploy.filter_spec.fill_diffuse_holes): a pixel whose sample hit no diffuse
# surface (albedo 0 on a surface or a volume) gets the demodulated diffuse of its 5x5
# neighbours that did, weighted by this binomial kernel (sigma 1 pixel), where their weight
# sums to at least DIFFUSE_FILL_MIN of the kernel's
DIFFUSE_FILL_TAPS = (1.0 / 16, 4.0 / 16, 6.0 / 16, 4.0 / 16, 1.0 / 16)
DIFFUSE_FILL_MIN = 0.2
# the albedo at holes (jnds_deploy.filter_spec.albedo_at_holes): where the 5x5 share of holes (the
# same taps, the border replicated) lies strictly inside SCATTERED_SHARE and the 5x5 mean of
# the hole mask's changes from pixel to pixel (horizontal plus vertical) is above
# SCATTERED_CHANGES, the composite takes the 5x5 mean of the filtered albedo
SCATTERED_SHARE = (0.05, 0.95)
SCATTERED_CHANGES = 0.5

# Rec. 709 luminance weights: the brightness the firefly clamp compares
# (jnds_deploy.filter_spec.clamp_fireflies; the runtime's twin, runtime.filters)
LUMINANCE = (0.2126, 0.7152, 0.0722)

# the roots the upsample filter may interpolate in (model.ModelConfig.upsample_root; here,
# so that the runtime, which has no torch, checks a manifest against the same list)
UPSAMPLE_ROOTS = (1, 2, 4, 8)
# the input block's designs (model.ModelConfig.input_block): the paper's, and 2x2 pixel blocks
# read at half resolution (space-to-depth)
INPUT_BLOCKS = ("native", "space_to_depth")

# the upsample filter's root interpolation (jnds_deploy.filter_spec.upsample_filter) raises the
# composite to this floor first: the derivative of x^(1/root) is infinite at 0
ROOT_FLOOR = 1e-10
