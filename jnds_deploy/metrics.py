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
    return cv2.remap(prev, x + motion[..., 0], y + motion[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)


def temporal_error(
    outs: list[np.ndarray], refs: list[np.ndarray], motions: list[np.ndarray], cuts: list[bool] | None = None
) -> float:
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


# a native pixel's previous frame showed the same surface when one of the 3x3 pixels around
# its reprojected position has an albedo within CHANGED_ALBEDO per channel, a normal within
# acos(CHANGED_COS) and, where the sequence has depth, a depth within CHANGED_DEPTH of the
# pixel's own, relative (the changed-pixel measure of docs/ghosting.md)
CHANGED_ALBEDO = 0.08
CHANGED_COS = 0.8
CHANGED_DEPTH = 0.15


def changed_mask(cur: dict, prev: dict, scale: int = 1) -> np.ndarray:
    """(H * scale, W * scale) bool: the pixels whose previous frame showed another surface,
    where a history-reusing method ghosts and a single-frame one does not.

    ``cur``/``prev``: two consecutive frames' input layers as ``io`` reads them (HWC
    float32: ``albedo``, ``normal``, ``motion`` of ``cur``, and ``depth`` where both have
    it). A native pixel is changed when its position in the previous frame (its motion
    vector) leaves the frame, or when no pixel in the 3x3 around that position shows the
    same surface (``CHANGED_*``; the background, normal 0, matches only background). The
    mask is dilated by one native pixel, then repeated to the target resolution."""
    h, w = cur["albedo"].shape[:2]
    y, x = np.mgrid[0:h, 0:w]
    px = np.rint(x + cur["motion"][..., 0]).astype(np.int64)
    py = np.rint(y + cur["motion"][..., 1]).astype(np.int64)
    inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    depth = "depth" in cur and "depth" in prev
    bg = np.abs(cur["normal"]).sum(-1) < 1e-3
    same = np.zeros((h, w), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            qx, qy = px + dx, py + dy
            ok = inside & (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h)
            qx, qy = np.clip(qx, 0, w - 1), np.clip(qy, 0, h - 1)
            a, n = prev["albedo"][qy, qx], prev["normal"][qy, qx]
            match = (np.abs(a - cur["albedo"]).max(-1) <= CHANGED_ALBEDO) & ((n * cur["normal"]).sum(-1) >= CHANGED_COS)
            if depth:
                d, d0 = prev["depth"][qy, qx, 0], cur["depth"][..., 0]
                match &= np.abs(d - d0) <= CHANGED_DEPTH * np.maximum(d0, 1e-6)
            match = np.where(bg, np.abs(n).sum(-1) < 1e-3, match)
            same |= ok & match
    changed = cv2.dilate((~same).astype(np.uint8), np.ones((3, 3), np.uint8))
    return np.repeat(np.repeat(changed, scale, 0), scale, 1).astype(bool)


def masked_squared_error(out: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """The sum of squared display-value differences (``to_ldr``, per channel) over the
    pixels of ``mask`` (H, W), and the number of values summed: pooled over frames, then
    ``psnr_of`` turns them into a PSNR."""
    d = (to_ldr(out) - to_ldr(ref))[mask]
    return float(np.sum(d.astype(np.float64) ** 2)), int(d.size)


def psnr_of(sum_sq: float, count: int) -> float:
    """PSNR (display values in [0, 1]) of a pooled squared error; NaN over no values."""
    if count == 0:
        return float("nan")
    return float(10 * np.log10(1.0 / max(sum_sq / count, 1e-12)))


def changed_psnr(outs: list[np.ndarray], refs: list[np.ndarray], masks: list[np.ndarray | None]) -> dict:
    """PSNR over the changed pixels (``changed_mask``) of every frame that has a mask
    (frame 0 and frames after a cut have none), pooled: {"changed_psnr", "changed_fraction"}."""
    total, count, pixels, seen = 0.0, 0, 0, 0
    for o, r, m in zip(outs, refs, masks):
        if m is None:
            continue
        s, c = masked_squared_error(o, r, m)
        total, count, pixels, seen = total + s, count + c, pixels + int(m.sum()), seen + m.size
    return {"changed_psnr": psnr_of(total, count), "changed_fraction": pixels / seen if seen else float("nan")}


def changed_masks(inputs: list[dict], cuts: list[bool], scale: int) -> list[np.ndarray | None]:
    """``changed_mask`` of every frame of a sequence (its frames' input layers, camera-cut
    flags and upscaling factor); None for frame 0 and after a camera cut."""
    return [None if i == 0 or cuts[i] else changed_mask(cur, inputs[i - 1], scale) for i, cur in enumerate(inputs)]


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
    warped = cv2.remap(
        prev, x + mv[..., 0], y + mv[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan
    )
    edges = cv2.resize(
        disocclusion_mask(inputs["depth"]).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST
    ).astype(bool)
    valid = np.isfinite(warped).all(-1) & ~edges
    return {
        "warped": float(np.abs(warped - cur)[valid].mean()),
        "unwarped": float(np.abs(prev - cur)[valid].mean()),
        "valid": float(valid.mean()),
    }
