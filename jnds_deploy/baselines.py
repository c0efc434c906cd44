"""What users have today, as functions of one frame: bicubic upscaling of the noisy
composite, and Intel Open Image Denoise at native resolution followed by bicubic
upscaling.

Array contract: HWC float32 linear HDR, inputs at native resolution as read by
``jnds_deploy.io``; outputs at ``scale`` x native.
"""

from __future__ import annotations

import cv2
import numpy as np


def noisy_composite(inputs: dict) -> np.ndarray:
    """Eq. 2 on the noisy inputs: albedo * diffuse + specular."""
    return inputs["albedo"] * inputs["diffuse"] + inputs["specular"]


def bicubic(image: np.ndarray, scale: int) -> np.ndarray:
    h, w = image.shape[:2]
    return np.maximum(cv2.resize(image, (w * scale, h * scale), interpolation=cv2.INTER_CUBIC), 0.0)


def oidn(inputs: dict, quality: str = "balanced") -> np.ndarray:
    """OIDN's HDR denoiser at native resolution with albedo and normal guides.

    OIDN wants the albedo of the first hit including specular surfaces' tint: the inputs'
    optional ``denoising_albedo`` where the sequence has it (Cycles' Denoising Albedo, what
    a Cycles user gives OIDN), else the format's albedo, 0 on metals, hair and volumes,
    which OIDN accepts as a (dark) guide but denoises worse with (docs/dataset.md).
    """
    import pyoidn

    color = np.ascontiguousarray(noisy_composite(inputs), np.float32)
    albedo = np.ascontiguousarray(inputs.get("denoising_albedo", inputs["albedo"]), np.float32)
    normal = np.ascontiguousarray(inputs["normal"], np.float32)
    return np.maximum(pyoidn.denoise(color, albedo, normal, hdr=True, quality=quality), 0.0)


def oidn_bicubic(inputs: dict, scale: int, quality: str = "balanced") -> np.ndarray:
    return bicubic(oidn(inputs, quality), scale)
