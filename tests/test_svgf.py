"""SVGF baseline: preserves constants, removes noise, accumulates over time, no NaN."""

import numpy as np
import pytest

pytest.importorskip("numba")
from jnds_deploy.svgf import SVGF  # noqa: E402


def frame(rng, w=48, h=32, noise=0.0, level=0.5):
    diffuse = np.full((h, w, 3), level, np.float32)
    if noise:
        diffuse = diffuse * rng.exponential(1.0, (h, w, 3)).astype(np.float32)
    return {
        "diffuse": diffuse,
        "specular": np.zeros((h, w, 3), np.float32),
        "albedo": np.full((h, w, 3), 0.8, np.float32),
        "normal": np.tile(np.array([0, 0, 1], np.float32), (h, w, 1)),
        "depth": np.full((h, w, 1), 3.0, np.float32),
        "motion": np.zeros((h, w, 2), np.float32),
    }


def test_constant_input_is_preserved():
    out = SVGF()(frame(np.random.default_rng(0)))
    np.testing.assert_allclose(out, 0.8 * 0.5, rtol=1e-4)


def test_noise_is_reduced_and_history_accumulates():
    rng = np.random.default_rng(1)
    svgf = SVGF()
    errors = []
    for _ in range(6):
        f = frame(rng, noise=1.0)  # exponential noise, mean 0.5 per channel
        out = svgf(f)
        errors.append(float(np.abs(out - 0.4).mean()))
    noisy = float(np.abs(0.8 * frame(rng, noise=1.0)["diffuse"] - 0.4).mean())
    assert errors[0] < 0.5 * noisy  # spatial filtering alone
    assert errors[-1] < 0.6 * errors[0]  # temporal accumulation on a static camera


def test_non_finite_input_stays_out():
    f = frame(np.random.default_rng(2))
    f["diffuse"][3, 4] = np.nan
    f["specular"][5, 6] = np.inf
    svgf = SVGF()
    for _ in range(2):
        assert np.isfinite(svgf(f)).all()
