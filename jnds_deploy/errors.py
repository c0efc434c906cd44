"""Every typed exception of jnds_deploy, in one place. The library raises them with a
message naming the bad file, layer, channel or value; only the CLI turns them into a
one-line message and exit code 2."""

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


class ConfigError(JndsError, ValueError):
    """A configuration value is out of range or unknown (a preset, a split, a precision)."""


class CheckpointError(JndsError):
    """A checkpoint is missing or is not one this package wrote."""

    def __init__(self, path: str | Path, problem: str):
        self.path = Path(path)
        super().__init__(f"{self.path}: {problem}")


class ArtifactError(JndsError):
    """The artifact directory is missing files or has an unsupported manifest."""


class FrameError(JndsError):
    """A frame handed to the pipeline lacks a layer or has the wrong shape."""


class CalibrationError(JndsError):
    """Calibration cannot run: missing artifacts, no data, unknown method."""


class RenderError(JndsError):
    """The renderer cannot run with the given configuration."""


class TrainError(JndsError):
    """Training cannot start with the given configuration (e.g. a device that is not here)."""


class ValidationError(JndsError):
    """ONNX Runtime and PyTorch disagree beyond tolerance; lists every failing output."""

    def __init__(self, failures: list[dict]):
        self.failures = failures
        lines = [
            f"{f['graph']}:{f['output']} "
            + (
                f["why"]
                if "why" in f
                else f"max |diff| {f['max_abs']:.3g} (atol {f['atol']:.3g}), mean {f['mean_abs']:.3g}"
                + (f" (mean tol {f['mean_tol']:.3g})" if f.get("mean_tol") is not None else "")
            )
            for f in failures
        ]
        super().__init__(f"{len(failures)} output(s) failed validation: " + "; ".join(lines))


class BadRequest(JndsError):
    """The server refuses a request: ``status`` is the HTTP status to answer with."""

    def __init__(self, status: int, message: str, retry_after: float | None = None):
        self.status, self.retry_after = status, retry_after
        super().__init__(message)


class ServerError(JndsError):
    """The server refused a request (client side); ``status`` is the HTTP status, ``kind``
    its error type."""

    def __init__(self, status: int, message: str, kind: str = ""):
        self.status, self.kind = status, kind
        super().__init__(f"HTTP {status}: {message}")
