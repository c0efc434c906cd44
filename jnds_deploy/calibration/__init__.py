"""``jnds calibrate``: int8 QDQ graphs from the fp32 artifacts, the calibration ranges as
data, and the calibration report (per-tensor int8 error, end-to-end PSNR/FLIP)."""

from ..errors import CalibrationError
from .quantize import METHODS, CalibrateConfig, calibrate

__all__ = ["METHODS", "CalibrateConfig", "CalibrationError", "calibrate"]
