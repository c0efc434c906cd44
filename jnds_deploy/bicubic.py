"""The bicubic convolution weights (Keys' cubic, a = -0.75: OpenCV's ``INTER_CUBIC`` and
PyTorch's bicubic ``grid_sample``), one numba function for the two sides that must weigh
the history warp's taps alike: the runtime's warp (``runtime.filters``) and the torch
specification's adjoint of ``grid_sample`` (``filters.warp``'s backward). Below both, so
that neither imports the other.
"""

from __future__ import annotations

import numpy as np
from numba import njit

CUBIC_A = np.float32(-0.75)


@njit(inline="always", fastmath={"contract"})
def cubic_weights(t):
    """The 4 weights of taps -1, 0, 1, 2 at fraction t in [0, 1)."""
    u, v = t + np.float32(1), np.float32(1) - t
    w0 = ((CUBIC_A * u - np.float32(5) * CUBIC_A) * u + np.float32(8) * CUBIC_A) * u - np.float32(4) * CUBIC_A
    w1 = ((CUBIC_A + np.float32(2)) * t - (CUBIC_A + np.float32(3))) * t * t + np.float32(1)
    w2 = ((CUBIC_A + np.float32(2)) * v - (CUBIC_A + np.float32(3))) * v * v + np.float32(1)
    return w0, w1, w2, np.float32(1) - w0 - w1 - w2
