"""Image and sequence error metrics, one definition for training logs, model card and
benchmarks.

Array contract: HWC float32 linear HDR radiance >= 0. Every metric first maps linear
values to a display-referred LDR image: Reinhard x / (1 + x), then gamma 1/2.2, in
[0, 1]. PSNR, SSIM and FLIP (NVIDIA's ``flip-evaluator``, LDR mode) compare LDR images.
The temporal error is Eq. 5 of the paper against the reference: the mean absolute
difference between the output's and the reference's temporal gradients after warping
the previous frame along the motion vectors, in LDR.
"""
from __future__ import annotations

import cv2
import numpy as np


def to_ldr(x: np.ndarray) -> np.ndarray:
    x = np.nan_to_num(np.maximum(x, 0.0), nan=0.0, posinf=1e6).astype(np.float32)
    return np.power(x / (1.0 + x), 1.0 / 2.2)


def psnr(out: np.ndarray, ref: np.ndarray) -> float:
    mse = float(np.mean((to_ldr(out) - to_ldr(ref)) ** 2))
    return float(10 * np.log10(1.0 / max(mse, 1e-12)))


def ssim(out: np.ndarray, ref: np.ndarray) -> float:
    from skimage.metrics import structural_similarity

    return float(structural_similarity(to_ldr(out), to_ldr(ref), channel_axis=2, data_range=1.0))


def flip(out: np.ndarray, ref: np.ndarray) -> float:
    import flip_evaluator

    _, mean, _ = flip_evaluator.evaluate(to_ldr(ref), to_ldr(out), "LDR")
    return float(mean)


def warp_previous(prev: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Bicubic warp of the previous frame (HWC) along native motion vectors (h, w, 2),
    which are upsampled (nearest) and scaled when ``prev`` is larger than ``motion``."""
    h, w = prev.shape[:2]
    s = w / motion.shape[1]
    if s != 1:
        motion = cv2.resize(motion, (w, h), interpolation=cv2.INTER_NEAREST) * s
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    return cv2.remap(prev, x + motion[..., 0], y + motion[..., 1], cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_REPLICATE)


def temporal_error(outs: list[np.ndarray], refs: list[np.ndarray], motions: list[np.ndarray],
                   cuts: list[bool] | None = None) -> float:
    """Eq. 5 of the paper, averaged over frames 1..N-1 (frames after a cut skipped)."""
    errs = []
    for t in range(1, len(outs)):
        if cuts and cuts[t]:
            continue
        o = to_ldr(outs[t]) - warp_previous(to_ldr(outs[t - 1]), motions[t])
        r = to_ldr(refs[t]) - warp_previous(to_ldr(refs[t - 1]), motions[t])
        errs.append(float(np.mean(np.abs(o - r))))
    return float(np.mean(errs)) if errs else float("nan")


def frame_metrics(out: np.ndarray, ref: np.ndarray, with_flip: bool = True) -> dict[str, float]:
    m = {"psnr": psnr(out, ref), "ssim": ssim(out, ref)}
    if with_flip:
        m["flip"] = flip(out, ref)
    return m
