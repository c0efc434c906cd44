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


class Mp4Writer:
    """An H.264 MP4 written frame by frame (``write``: HWC uint8 RGB, one size), renamed into
    place on ``close`` (a run killed mid-way leaves no half file under the name). Odd sizes
    are padded by one edge row or column (yuv420p needs even ones). Raises ConfigError when
    imageio-ffmpeg is not installed."""

    def __init__(self, path: str | Path, fps: int = FPS):
        try:
            import imageio_ffmpeg
        except ImportError as e:
            raise ConfigError("writing a video needs imageio-ffmpeg: pip install 'jnds-deploy[video]'") from e
        self._ffmpeg = imageio_ffmpeg
        self.path, self.fps = Path(path), fps
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.name}.tmp.mp4")
        self._gen, self.size, self.frames = None, None, 0

    def write(self, frame: np.ndarray) -> None:
        h, w = frame.shape[:2]
        frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        if self._gen is None:
            self.size = frame.shape[1], frame.shape[0]
            self._gen = self._ffmpeg.write_frames(
                str(self._tmp),
                self.size,
                fps=self.fps,
                codec="libx264",
                quality=QUALITY,
                pix_fmt_out="yuv420p",
                macro_block_size=1,
                output_params=["-movflags", "+faststart"],
            )
            self._gen.send(None)
        elif (frame.shape[1], frame.shape[0]) != self.size:
            raise ValueError(
                f"{self.path}: frame of {frame.shape[1]}x{frame.shape[0]} in a video of {self.size[0]}x{self.size[1]}"
            )
        self._gen.send(np.ascontiguousarray(frame))
        self.frames += 1

    def close(self) -> Path:
        if self._gen is None:
            raise ValueError(f"{self.path}: no frames")
        self._gen.close()
        os.replace(self._tmp, self.path)
        return self.path

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is None:
            self.close()
        elif self._gen is not None:
            self._gen.close()
            self._tmp.unlink(missing_ok=True)


def write_mp4(path: str | Path, frames, fps: int = FPS) -> Path:
    """Encode ``frames`` (an iterable of HWC uint8 RGB images of one size) to an H.264 MP4
    at ``path`` (``Mp4Writer``)."""
    with Mp4Writer(path, fps) as w:
        for f in frames:
            w.write(f)
    return w.path


def read_mp4(path: str | Path) -> list[np.ndarray]:
    """The frames of an MP4 as HWC uint8 RGB (decoded by imageio-ffmpeg's ffmpeg)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    return [np.frombuffer(b, np.uint8).reshape(h, w, 3).copy() for b in reader]
