"""Typed exceptions of jnds_deploy. Only the CLI turns them into exit codes."""
from __future__ import annotations

from pathlib import Path


class JndsError(Exception):
    """Base class of every error this package raises on purpose."""


class SequenceError(JndsError):
    """A frame sequence does not follow ``jnds-sequence/1``.

    ``path`` names the file (or directory) at fault, ``problem`` says what is wrong.
    """

    def __init__(self, path: str | Path, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class SequenceFormatError(SequenceError):
    """``sequence.json`` is missing, unparsable, has the wrong ``format`` key or bad values."""


class FrameCountError(SequenceError):
    """Frames are missing, numbered with gaps, or there are more than ``frame_count``."""


class ChannelError(SequenceError):
    """A required channel is missing from an EXR file."""


class ImageSizeError(SequenceError):
    """An EXR file does not have the size that ``sequence.json`` states."""


class ExrReadError(SequenceError):
    """An EXR file is unreadable: not OpenEXR, truncated or corrupted."""


class RenderError(JndsError):
    """The renderer cannot run with the given configuration."""


class TrainError(JndsError):
    """Training cannot start with the given configuration (e.g. a device that is not here)."""


class ValidationError(JndsError):
    """ONNX Runtime and PyTorch disagree beyond tolerance; lists every failing output."""

    def __init__(self, failures: list[dict]):
        self.failures = failures
        lines = [f"{f['graph']}:{f['output']} " + (f["why"] if "why" in f else
                 f"max |diff| {f['max_abs']:.3g} (atol {f['atol']:.3g}), mean {f['mean_abs']:.3g}"
                 + (f" (mean tol {f['mean_tol']:.3g})" if f.get("mean_tol") is not None else ""))
                 for f in failures]
        super().__init__(f"{len(failures)} output(s) failed validation: " + "; ".join(lines))
