"""Videos a person watches, because only moving pictures show flicker and ghost trails.

``write_mp4`` encodes frames with the ffmpeg binary that ``imageio-ffmpeg`` ships in its
wheel (H.264, yuv420p: what browsers and players take); ``display`` maps a frame to the
8-bit image every picture of this project shows (``metrics.to_ldr``: Reinhard, then gamma
1/2.2), ``side_by_side`` puts labelled columns into one frame (``contact_sheet.render``).

Array contract: frames HWC float32 linear HDR in, uint8 RGB to the encoder.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import ConfigError
from .metrics import to_ldr

FPS = 8  # the bundled and rendered sequences are short: 8 frames a second shows each one


def display(frame: np.ndarray) -> np.ndarray:
    """HWC linear HDR -> HWC uint8 RGB through the metrics' display mapping."""
    return (to_ldr(frame[..., :3]) * 255 + 0.5).astype(np.uint8)


def side_by_side(title: str, columns: dict[str, np.ndarray]) -> np.ndarray:
    """One video frame: the labelled columns of a contact-sheet row (HWC linear each), RGB."""
    from .contact_sheet import render

    return np.ascontiguousarray(render([(title, columns)])[..., ::-1])


# imageio-ffmpeg's quality (0-10, 10 best): 5 keeps noise and trails visible at a few hundred
# kB for a contact sheet's worth of frames
QUALITY = 5


def write_mp4(path: str | Path, frames, fps: int = FPS) -> Path:
    """Encode ``frames`` (an iterable of HWC uint8 RGB images of one size) to an H.264 MP4
    at ``path``, atomically. Odd sizes are padded by one edge row or column (yuv420p needs
    even ones). Raises ConfigError when imageio-ffmpeg is not installed."""
    try:
        import imageio_ffmpeg
    except ImportError as e:
        raise ConfigError("writing a video needs imageio-ffmpeg: pip install 'jnds-deploy[video]'") from e
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.mp4")
    writer = None
    try:
        for f in frames:
            h, w = f.shape[:2]
            f = np.pad(f, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
            if writer is None:
                size = f.shape[1], f.shape[0]
                writer = imageio_ffmpeg.write_frames(str(tmp), size, fps=fps, codec="libx264", quality=QUALITY,
                                                     pix_fmt_out="yuv420p", macro_block_size=1,
                                                     output_params=["-movflags", "+faststart"])
                writer.send(None)
            elif (f.shape[1], f.shape[0]) != size:
                raise ValueError(f"{path}: frame of {f.shape[1]}x{f.shape[0]} in a video of {size[0]}x{size[1]}")
            writer.send(np.ascontiguousarray(f))
    finally:
        if writer is not None:
            writer.close()
    if writer is None:
        raise ValueError(f"{path}: no frames")
    os.replace(tmp, path)
    return path


def read_mp4(path: str | Path) -> list[np.ndarray]:
    """The frames of an MP4 as HWC uint8 RGB (decoded by imageio-ffmpeg's ffmpeg)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    return [np.frombuffer(b, np.uint8).reshape(h, w, 3).copy() for b in reader]
