"""``PipelineConfig``: how ``Pipeline`` runs an artifact directory. Cheap to import (no
numba, no ONNX Runtime): ``jnds run`` builds its options from it before the runtime loads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError
from ..options import option

# the network graphs' precisions, the first the default of the library and of every command
PRECISIONS = ("int8", "fp32")
DEFAULT_PRECISION = PRECISIONS[0]
PRECISION_HELP = (
    "int8: the int8 graphs `jnds calibrate` wrote (the artifacts must have them); fp32: the exported graphs"
)
FILTER_DTYPES = ("float32", "float16")
FILTER_DTYPE_HELP = "the filter stage's arithmetic (float16: the paper's)"
# the shipped checkpoint's artifacts, exported and calibrated at release (tools/package_artifacts.py)
SHIPPED_ARTIFACTS = str(Path(__file__).resolve().parents[1] / "checkpoints" / "artifacts")
ARTIFACTS_HELP = "a directory written by `jnds export` (and `jnds calibrate`); default: the shipped checkpoint's"


@dataclass(frozen=True)
class PipelineConfig:
    artifacts: str = option(SHIPPED_ARTIFACTS, ARTIFACTS_HELP)
    precision: str = option(DEFAULT_PRECISION, PRECISION_HELP, choices=PRECISIONS)
    filter_dtype: str = option(FILTER_DTYPES[0], FILTER_DTYPE_HELP, choices=FILTER_DTYPES)
    threads: int = option(2, "ONNX Runtime threads per graph run")
    int8_method: str | None = None  # which calibration's int8 graphs; None: the last calibrated
    # graphs that stay fp32 when precision is int8: the upsample block's int8 graph is
    # slower on the CPUs measured (benchmarks/results/calibration.md)
    fp32_graphs: tuple[str, ...] = ("upsample",)
    adaptive: bool = option(
        True,
        "skip the work a frame does not need where the result is the same "
        "(FrameResult.decisions); off: every stage on every frame",
    )
    native_output: bool = option(
        False,
        "denoise only: output at the input size, no upsample block (a renderer already at display "
        "resolution); metrics against the reference area-downsampled",
        flag="--native",
    )
    # with adaptive: pass empty background tiles through the filter stage (approximate; off by
    # default: finding the tiles and putting them back costs about what the smaller upsample
    # box saves, benchmarks/results/adaptive.md)
    tile_skip: bool = False
    # make the process-wide process.keep_freed_memory when the pipeline is built: off in the
    # library; `jnds run`, `serve` and `batch`, which own their process, make it and the other
    # process-wide settings with process.tune_process
    keep_freed_memory: bool = False
    firefly_clamp: float | None = option(
        None,
        "limit each pixel's current radiance to K x the brightest of its neighbours and its history "
        "(0: off; default: the model's, model_config.firefly_clamp in the manifest)",
        metavar="K",
    )
    diffuse_fill: bool | None = option(
        None,
        "fill the diffuse of samples that hit no diffuse surface from their neighbours' (default: the "
        "model's, model_config.diffuse_fill in the manifest)",
    )
    albedo_at_holes: bool | None = option(
        None,
        "composite with the local mean of the filtered albedo where samples that hit no diffuse surface "
        "lie scattered (default: the model's, model_config.albedo_at_holes in the manifest)",
    )

    def __post_init__(self):
        if self.precision not in PRECISIONS:
            raise ConfigError(f"precision must be {' or '.join(PRECISIONS)}, got {self.precision!r}")
        if self.firefly_clamp is not None and not (self.firefly_clamp == 0 or self.firefly_clamp >= 1):
            raise ConfigError(f"firefly_clamp must be 0 (off) or >= 1, got {self.firefly_clamp!r}")
        if self.filter_dtype not in FILTER_DTYPES:
            raise ConfigError(f"filter_dtype must be {' or '.join(FILTER_DTYPES)}, got {self.filter_dtype!r}")
