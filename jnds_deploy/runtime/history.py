"""The history between frames: the previous frame's filtered signals, warped along the
motion vectors into the current frame, cleaned, and stored again after filtering.

Warping is bicubic (``filters.warp_channels_last``); each channel is then clamped to its
input layer's valid range (bicubic overshoots). Two rejections replace the warped history
by the current inputs, as on a first frame:
- geometric, per pixel (``jnds_deploy.filter_spec.history_rejected``, the model's training
  does the same): the current sample sees background, the history shows another surface
  (normal or albedo), the pixel's previous position is off screen, or it lies in the ring
  around such a trail (docs/ghosting.md);
- brightness, per tile (``reject_history``): a tile whose warped diffuse (or specular)
  history is far brighter than the current frame there restarts that signal. The
  recurrence of some checkpoints has a loop gain above 1 in places; without this test
  some sequences looped over many frames grew without bound
  (benchmarks/results/stability.md).
The stored history is flushed to 0 below ``HISTORY_FLUSH``: the recurrence shrinks a
signal that left a pixel until it reaches float32 denormals, which the CPU computes with
microcode assists (docs/architecture.md, "The filter stage").

Array contract: current inputs (13, H, W) float32 in ``layout.CURRENT`` order, motion
(2, H, W) in pixels, warped history (12, H, W) in ``layout.HISTORY`` order; the stored
history is channels last, (H, W, 12), the warp's input layout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..layout import HISTORY, N_HISTORY, RADIANCE, channels
from . import filters as F
from .reformat import LIMITS

# each history channel is clamped after warping to its input layer's valid range
HISTORY_LO = np.array([LIMITS[n][0] for n, c in HISTORY for _ in range(c)], np.float32)
HISTORY_HI = np.array([LIMITS[n][1] for n, c in HISTORY for _ in range(c)], np.float32)
# history values smaller than this are set to 0 (above float32's denormals, with headroom
# for the kernels' weights; radiance this small is black in any format)
HISTORY_FLUSH = 1e-30
# a tile of REJECT_TILE^2 pixels whose warped diffuse (or specular) history is brighter
# than REJECT_RATIO x (the current frame's tile mean + REJECT_FLOOR x the current frame's
# mean) restarts that signal from the current frame (a signal that vanished from the whole
# frame, a light switched off, drops its history)
REJECT_TILE = 32
REJECT_RATIO = 8.0
REJECT_FLOOR = 0.1


def reject_history(current: np.ndarray, warped: np.ndarray) -> int:
    """Restart (in place) the tiles of the warped diffuse or specular history that are far
    brighter than the current frame there (see REJECT_RATIO); returns how many tiles."""
    h, w = current.shape[1:]
    t = REJECT_TILE
    rows, cols = np.minimum(t, h - t * np.arange(-(-h // t))), np.minimum(t, w - t * np.arange(-(-w // t)))
    pixels = np.outer(rows, cols)  # per tile (the last row and column partial)
    rejected = 0
    for signal in RADIANCE:
        c = channels(signal).start
        cur, his = F.tile_sums(current, c, t), F.tile_sums(warped, c, t)
        bad = his / pixels > REJECT_RATIO * (cur / pixels + REJECT_FLOOR * cur.sum() / (h * w))
        for ty, tx in np.argwhere(bad):
            tile = (slice(c, c + 3), slice(ty * t, (ty + 1) * t), slice(tx * t, (tx + 1) * t))
            warped[tile] = current[tile]
        rejected += int(bad.sum())
    return rejected


@dataclass
class Warped:
    """The history as the current frame's network and filters see it."""

    signals: np.ndarray  # (12, H, W) float32
    valid: bool  # False: no history (first frame, cut, resize): the current inputs stand in
    static: bool = False  # zero motion everywhere: used as stored, no resampling
    disoccluded: int = 0  # pixels replaced by the current inputs (geometric test)
    rejected: int = 0  # tiles restarted from the current frame (brightness test)


class History:
    """One stream's history: ``warp`` it into the current frame, ``store`` the frame's
    filtered signals. ``reset`` drops it (a camera cut)."""

    def __init__(self):
        self.frame: np.ndarray | None = None  # (H, W, 12) filtered outputs of the last frame
        self.size: tuple[int, int] | None = None  # (W, H) of the frame it belongs to

    def reset(self) -> None:
        self.frame = None
        self.size = None

    def warp(self, current: np.ndarray, motion: np.ndarray, size: tuple[int, int], adaptive: bool) -> Warped:
        """The history warped to the current frame of ``size`` (W, H), clamped and
        rejected where it no longer fits; with ``adaptive``, not resampled when nothing
        moves (bicubic resampling at zero motion is the identity)."""
        if self.frame is None or self.size != size:
            return Warped(current[:N_HISTORY].copy(), valid=False)
        static = adaptive and not motion.any()
        if static:
            warped = np.empty(current[:N_HISTORY].shape, np.float32)
            np.clip(self.frame.transpose(2, 0, 1), HISTORY_LO[:, None, None], HISTORY_HI[:, None, None], out=warped)
            disoccluded = F.reject_disoccluded(current, warped)
        else:  # with the geometric rejection fused into the warp's pass
            warped, disoccluded = F.warp_channels_last(self.frame, motion, HISTORY_LO, HISTORY_HI, current)
        rejected = reject_history(current, warped)
        return Warped(warped, valid=True, static=static, disoccluded=disoccluded, rejected=rejected)

    def store(self, filtered: dict[str, np.ndarray], size: tuple[int, int], radiance_scale: float = 1.0) -> int:
        """Keep the frame's filtered signals (CHW, padded size) as the next frame's history,
        radiance divided by ``radiance_scale`` (the float16 filter stage's); returns how
        many non-finite values were replaced (0 unless something upstream broke)."""
        # non-finite values replaced and counted in the same pass (replace_nonfinite's values)
        self.frame, bad = F.channels_last(*[filtered[n] for n, _ in HISTORY], flush=HISTORY_FLUSH, counted=True)
        if radiance_scale != 1:
            self.frame[..., : channels("specular").stop] /= radiance_scale
        self.size = size
        return bad


def replace_nonfinite(a: np.ndarray) -> int:
    """NaN -> 0, +Inf -> HDR_MAX, -Inf -> 0 in place; returns how many were replaced."""
    finite = np.isfinite(a)
    if finite.all():
        return 0
    np.nan_to_num(a, copy=False, nan=0.0, posinf=F.HDR_MAX, neginf=0.0)
    return int(a.size - finite.sum())
