"""Sub-pixel jitter: the Halton (2, 3) sequence, in plain Python (the Mitsuba renderer and
the Blender side, which has no numpy 2 and none of this package's dependencies, share it)."""

from __future__ import annotations


def halton(index: int, base: int) -> float:
    """Radical inverse of ``index`` in ``base`` (index >= 1 avoids the 0 sample)."""
    f, r = 1.0, 0.0
    while index > 0:
        f /= base
        r += f * (index % base)
        index //= base
    return r


def jitter(frame: int, period: int = 16) -> tuple[float, float]:
    """Halton (2, 3) sub-pixel offset in [-0.5, 0.5) for a frame, repeating every ``period``."""
    k = frame % period + 1
    return (halton(k, 2) - 0.5, halton(k, 3) - 0.5)
