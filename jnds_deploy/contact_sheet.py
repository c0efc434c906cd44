"""Contact sheets: a PNG a person looks at, because a mean hides smears and blur.

One row per frame, one column per image (e.g. input, OIDN, model, reference), each shown
through the metrics' display mapping (``metrics.to_ldr``: Reinhard, then gamma 1/2.2),
labelled, at the target resolution (smaller images are enlarged by pixel replication, so
the input's aliasing stays visible).

Array contract: HWC float32 linear HDR; the PNG is 8-bit sRGB-ish, written atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from .metrics import to_ldr

LABEL_H = 14  # pixels of the label strip above each row
GAP = 2


def _tile(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` (H, W, 3) in display values [0, 1] at ``size`` (W, H), nearest-neighbour."""
    w, h = size
    if image.shape[:2] != (h, w):
        image = cv2.resize(image, (w, h), interpolation=cv2.INTER_NEAREST)
    return image


def mark(image: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """``image`` (HWC linear) with the pixels of ``mask`` (H, W bool; None: none) tinted
    red, e.g. the pixels whose previous frame showed another surface
    (``metrics.changed_mask``)."""
    out = image[..., :3].astype(np.float32, copy=True)
    if mask is not None:
        out[mask] = 0.4 * out[mask] + np.float32([0.6, 0.0, 0.0])
    return out


def render(rows: list[tuple[str, dict[str, np.ndarray]]]) -> np.ndarray:
    """(H, W, 3) uint8 BGR: per row a title and {column label: HWC linear image}; every
    row has the same columns, shown at the size of the largest image."""
    columns = list(rows[0][1])
    h = max(img.shape[0] for _, imgs in rows for img in imgs.values())
    w = max(img.shape[1] for _, imgs in rows for img in imgs.values())
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.35
    out_rows = []
    for title, images in rows:
        strip = np.full((LABEL_H, len(columns) * (w + GAP) - GAP, 3), 255, np.uint8)
        tiles = []
        for c, name in enumerate(columns):
            tiles.append((_tile(to_ldr(images[name])[..., :3], (w, h)) * 255 + 0.5).astype(np.uint8)[..., ::-1])
            if c < len(columns) - 1:
                tiles.append(np.full((h, GAP, 3), 255, np.uint8))
            label = f"{title}: {name}" if c == 0 else name
            cv2.putText(strip, label, (c * (w + GAP) + 2, LABEL_H - 4), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
        out_rows += [strip, np.concatenate(tiles, 1)]
    return np.concatenate(out_rows, 0)


def write(path: str | Path, rows: list[tuple[str, dict[str, np.ndarray]]]) -> Path:
    """Write the contact sheet of ``rows`` (see ``render``) atomically: JPEG (quality 90)
    if ``path`` ends in .jpg or .jpeg, else PNG."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    jpeg = path.suffix.lower() in (".jpg", ".jpeg")
    tmp = path.with_name(f".{path.name}.tmp{'.jpg' if jpeg else '.png'}")
    if not cv2.imwrite(str(tmp), render(rows), [cv2.IMWRITE_JPEG_QUALITY, 90] if jpeg else []):
        raise OSError(f"{path}: could not write the contact sheet")
    os.replace(tmp, path)
    return path


def sheet_frames(n: int, count: int = 3) -> list[int]:
    """Which frames of an ``n``-frame sequence a sheet shows: first, middle, last."""
    return sorted({0, n // 2, n - 1})[:count] if n else []
