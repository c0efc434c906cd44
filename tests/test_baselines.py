"""The baselines of ``jnds evaluate``: OIDN takes the guide albedo a renderer's user gives it."""

import numpy as np
import pytest

from jnds_deploy import baselines

from .conftest import random_inputs


def test_oidn_takes_the_denoising_albedo_where_the_inputs_have_one():
    pyoidn = pytest.importorskip("pyoidn")
    rng = np.random.default_rng(0)
    inputs = random_inputs(rng, 48, 32)
    inputs["albedo"][:, :24] = 0  # metal: no diffuse albedo
    guide = inputs["albedo"].copy()
    guide[:, :24] = 0.8  # its tint, as Cycles' Denoising Albedo has it
    with_guide = baselines.oidn({**inputs, "denoising_albedo": guide})
    color = baselines.noisy_composite(inputs)
    expected = pyoidn.denoise(color, guide, inputs["normal"], hdr=True, quality="balanced")
    np.testing.assert_array_equal(with_guide, np.maximum(expected, 0))
    assert not np.allclose(baselines.oidn(inputs), with_guide)  # without it: the format's albedo
