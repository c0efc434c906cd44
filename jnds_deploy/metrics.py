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


def disocclusion_mask(depth: np.ndarray) -> np.ndarray:
    """Pixels next to depth discontinuities or silhouettes against background (where
    reprojection cannot be trusted), from a native (H, W, 1) depth; dilated by 1 pixel."""
    d = depth[..., 0]
    jumps = np.abs(cv2.Laplacian(d, cv2.CV_32F)) / np.maximum(d, 1e-3) > 0.05
    silhouette = (d == 0) & (cv2.dilate((d > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    return cv2.dilate((jumps | silhouette).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def motion_warp_error(seq, t: int, layer: str = "albedo") -> dict[str, float]:
    """Check a sequence's motion vectors: warp the reference ``layer`` of frame t-1 into
    frame t (bilinear) and compare with frame t's, outside disocclusions and off-screen
    pixels. Returns the mean |error| warped and unwarped and the fraction of pixels used."""
    inputs = seq.inputs(t)
    prev, cur = seq.reference(t - 1)[layer], seq.reference(t)[layer]
    h, w = cur.shape[:2]
    s = w / seq.native_size[0]
    mv = cv2.resize(inputs["motion"], (w, h), interpolation=cv2.INTER_NEAREST) * s
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    warped = cv2.remap(prev, x + mv[..., 0], y + mv[..., 1], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    edges = cv2.resize(disocclusion_mask(inputs["depth"]).astype(np.uint8), (w, h),
                       interpolation=cv2.INTER_NEAREST).astype(bool)
    valid = np.isfinite(warped).all(-1) & ~edges
    return {"warped": float(np.abs(warped - cur)[valid].mean()),
            "unwarped": float(np.abs(prev - cur)[valid].mean()), "valid": float(valid.mean())}
