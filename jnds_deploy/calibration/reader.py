"""Calibration inputs: the fp32 pipeline run recurrently over real sequences.

The network's ``history`` input is its own filtered output of the previous frame, warped;
calibrating on anything else (zeros, the noisy inputs) would give the int8 graph ranges
it never sees in use. ``collect_feeds`` runs the fp32 artifacts frame after frame, exactly
as ``jnds run`` does, and records every graph's inputs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from onnxruntime.quantization import CalibrationDataReader

from ..io import open_sequence
from ..runtime.pipeline import Pipeline, PipelineConfig


def collect_feeds(
    artifacts: str | Path,
    sequences: list[str | Path],
    frames: int | None = None,
    threads: int = 2,
    progress: bool = True,
) -> dict[str, list[dict[str, np.ndarray]]]:
    """{graph name: [feeds of one frame, ...]} from the fp32 pipeline over ``sequences``
    (at most ``frames`` per sequence, from the first, so history builds up as in use)."""
    from tqdm import tqdm

    pipe = Pipeline(PipelineConfig(artifacts=str(artifacts), precision="fp32", threads=threads))
    feeds: dict[str, list[dict[str, np.ndarray]]] = {name: [] for name in pipe.sessions}
    pipe.on_feeds = lambda name, f: feeds[name].append({k: v.copy() for k, v in f.items()})
    for path in sequences:
        seq = open_sequence(path)
        pipe.reset()
        n = len(seq) if frames is None else min(frames, len(seq))
        for i in tqdm(range(n), desc=f"calibration inputs {seq.path.name}", unit="frame", disable=not progress):
            pipe(seq.inputs(i), seq.frames[i].camera_cut)
    return feeds


class FeedReader(CalibrationDataReader):
    """ONNX Runtime's reader interface over recorded feeds (rewindable); with ``stops``,
    every feed once per exposure 2^k, its radiance channels (``radiance``: current and
    history alike) scaled, one copy at a time."""

    def __init__(
        self, feeds: list[dict[str, np.ndarray]], stops: tuple[float, ...] = (0,), radiance: slice | None = None
    ):
        self.feeds, self.stops, self.radiance = feeds, tuple(stops), radiance
        if self.stops != (0,) and radiance is None:
            raise ValueError("FeedReader: stops other than (0,) need the radiance channels")
        self.i = 0

    def get_next(self) -> dict[str, np.ndarray] | None:
        if self.i >= len(self.feeds) * len(self.stops):
            return None
        f, k = divmod(self.i, len(self.stops))
        self.i += 1
        return exposed(self.feeds[f], self.stops[k], self.radiance)

    def rewind(self) -> None:
        self.i = 0


def exposed(feed: dict[str, np.ndarray], stop: float, radiance: slice | None) -> dict[str, np.ndarray]:
    """``feed`` with its radiance channels x 2^stop (a copy; the feed itself if stop is 0).
    The guide albedo (``guide``) is an albedo: no exposure changes it."""
    if stop == 0:
        return feed
    out = {n: v.copy() for n, v in feed.items()}
    for n, v in out.items():
        if n != "guide":
            v[:, radiance] *= np.float32(2.0**stop)
    return out
