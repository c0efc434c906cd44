"""The filter stage in numpy/opencv: the runtime's implementation of ``jnds_deploy.filters``.

Same specification as the torch ops, a test holds them equal. Array contract: CHW
arrays (one frame, the layout ONNX Runtime returns without the batch axis), float32 or
float16 (``dtype`` of the inputs is kept); kernels (9, H, W) in row-major 3x3 order;
borders replicate the edge pixel.

Notes on opencv: ``cv2.remap`` quantizes map coordinates to 1/32 pixel for its
interpolating modes, so warping differs from ``torch.grid_sample`` by up to a 1/64 pixel
shift; both use the bicubic kernel with a = -0.75. ``cv2.resize(INTER_LINEAR)`` has the
pixel-centre convention of ``align_corners=False``.
"""
from __future__ import annotations

import cv2
import numpy as np

HDR_MAX = 65535.0


def tonemap(x: np.ndarray) -> np.ndarray:
    """Eq. 1: (log(clamp(x, 0, 65535) + 1))^(1/2.2)."""
    return np.power(np.log1p(np.clip(x, 0.0, HDR_MAX)), 1.0 / 2.2).astype(x.dtype, copy=False)


def apply_kernel(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """out[c, y, x] = sum_k kernel[k, y, x] * x[c, y + dy_k, x + dx_k]."""
    _, h, w = x.shape
    p = np.pad(x, ((0, 0), (1, 1), (1, 1)), mode="edge")
    out = p[:, :h, :w] * kernel[0]
    tmp = np.empty_like(out)
    for i in range(1, 9):
        dy, dx = divmod(i, 3)
        np.multiply(p[:, dy:dy + h, dx:dx + w], kernel[i], out=tmp)
        out += tmp
    return out


def warp(x: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Bicubic resampling of the previous frame ``x`` (C, H, W) along motion (2, H, W):
    out(x, y) = x_prev(x + mx, y + my) with pixel centres at integers."""
    _, h, w = x.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    map_x = xs + motion[0].astype(np.float32)
    map_y = ys + motion[1].astype(np.float32)
    src = x.astype(np.float32, copy=False)
    out = np.stack([cv2.remap(c, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE) for c in src])
    return out.astype(x.dtype, copy=False)


def downsample(x: np.ndarray) -> np.ndarray:
    """2x2 average pooling (H and W even)."""
    c, h, w = x.shape
    return x.reshape(c, h // 2, 2, w // 2, 2).mean(axis=(2, 4), dtype=np.float32).astype(x.dtype, copy=False)


def upsample(x: np.ndarray, factor: int = 2) -> np.ndarray:
    """Bilinear upsampling, as cv2.resize(INTER_LINEAR) and align_corners=False."""
    _, h, w = x.shape
    src = x.astype(np.float32, copy=False)
    out = np.stack([cv2.resize(c, (w * factor, h * factor), interpolation=cv2.INTER_LINEAR) for c in src])
    return out.astype(x.dtype, copy=False)


def relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0, out=x)


def lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """a + t * (b - a), ``t`` (1, H, W) broadcast over channels."""
    return a + t * (b - a)


def spatiotemporal(x, history, k_spatial, k_temporal, blend) -> np.ndarray:
    return relu(lerp(apply_kernel(x, k_spatial), apply_kernel(history, k_temporal), blend))


def filter_path(x: np.ndarray, history: np.ndarray, native: dict, levels: list[dict]) -> np.ndarray:
    """The hierarchical filter of one signal; see ``jnds_deploy.filters.filter_path``."""
    skips = [spatiotemporal(x, history, native["spatial"], native["temporal"], native["blend"])]
    for lv in levels:
        skips.append(relu(apply_kernel(downsample(skips[-1]), lv["down"])))
    y = skips[-1]
    for k in range(len(levels) - 1, -1, -1):
        p = levels[k - 1] if k > 0 else native
        y = relu(lerp(skips[k], apply_kernel(upsample(y), p["up"]), p["up_blend"]))
    return y


def composite(albedo: np.ndarray, diffuse: np.ndarray, specular: np.ndarray) -> np.ndarray:
    """Eq. 2: albedo * diffuse + specular."""
    return albedo * diffuse + specular


def upsample_filter(color: np.ndarray, kernel: np.ndarray, factor: int) -> np.ndarray:
    """Bilinear upsampling of the linear composite, the predicted 3x3 kernel, ReLU."""
    up = upsample(color, factor) if factor > 1 else color
    return relu(apply_kernel(up, kernel))
