"""The numba pass between the cut int8 graph's runs (runtime.reformat.block_input)."""

import numpy as np
import pytest

from jnds_deploy.artifacts import Cut
from jnds_deploy.runtime import reformat


def _taps_in_float(dec, nat, sd, zd, sn, zn, sb, zb):
    """The bilinear 2x upsampling (half-pixel centres, edge taps clamped) with each output's
    four taps weighted in float32, then requantized, and the skip requantized: the pass as it
    was before commit 53b8086."""
    f = np.float32
    h, w, cd = dec.shape
    H, W = 2 * h, 2 * w

    def taps(n, size):
        s = (np.arange(size) + 0.5) * 0.5 - 0.5
        i0 = np.floor(s).astype(int)
        return np.clip(i0, 0, n - 1), np.clip(i0 + 1, 0, n - 1), (s - i0).astype(f)

    ya, yb, fy = taps(h, H)
    xa, xb, fx = taps(w, W)
    d = dec.astype(f) - f(zd)
    one = f(1)
    w00, w01 = ((one - fy)[:, None] * (one - fx)[None])[..., None], ((one - fy)[:, None] * fx[None])[..., None]
    w10, w11 = (fy[:, None] * (one - fx)[None])[..., None], (fy[:, None] * fx[None])[..., None]
    v = (w00 * d[ya][:, xa] + w01 * d[ya][:, xb]) + w10 * d[yb][:, xa] + w11 * d[yb][:, xb]
    up = np.clip(np.rint(v * f(sd / sb)) + f(zb), 0, 255).astype(np.uint8)
    skip = np.clip(np.rint((nat.astype(f) - f(zn)) * f(sn / sb)) + f(zb), 0, 255).astype(np.uint8)
    return np.concatenate([up, skip], -1)[None]


@pytest.mark.parametrize(
    "q",
    [
        (0.0371, 3, 0.0213, 0, 0.0297, 7),
        (0.05, 0, 0.01, 0, 0.013, 128),
        (1.3e-3, 255, 0.7, 11, 2.1e-3, 40),
        (0.02, 17, 0.02, 17, 0.02, 17),
    ],
)
# channels: whole vectors of 16 (simd) and one at a time, both, or either alone
@pytest.mark.parametrize("cd,cn", [(24, 8), (48, 16), (5, 3)])
def test_upsample_concat_is_bit_equal_to_the_four_taps_in_float(q, cd, cn):
    rng = np.random.default_rng(7)
    dec = rng.integers(0, 256, (9, 13, cd)).astype(np.uint8)
    nat = rng.integers(0, 256, (18, 26, cn)).astype(np.uint8)
    out = np.empty((1, 18, 26, cd + cn), np.uint8)
    reformat._upsample_concat(dec, nat, *q, 1, out)
    want = _taps_in_float(dec, nat, *q)
    np.testing.assert_array_equal(out, want)
    assert len(np.unique(out)) > 20  # not all saturated


def test_block_input_does_the_depth_to_space_of_a_skip_in_phases():
    """A space-to-depth input block's native features leave the graph as 2x2 phases at half
    resolution, phase first (Cut.skip_phases 2); block_input gives the entry the same bytes as
    from those features in native layout."""
    rng = np.random.default_rng(8)
    dec = rng.integers(0, 256, (1, 9, 13, 24)).astype(np.uint8)
    nat = rng.integers(0, 256, (1, 18, 26, 16)).astype(np.uint8)
    # (1, 9, 13, 64): pixel (2y + py, 2x + px)'s channel c at (2py + px) 16 + c
    phased = np.ascontiguousarray(nat.reshape(1, 9, 2, 13, 2, 16).transpose(0, 1, 3, 2, 4, 5).reshape(1, 9, 13, 64))
    q = dict(up_q=(0.0371, 3), skip_q=(0.0213, 5), entry_q=(0.0297, 7))
    plain = Cut("block.1", "u", "s", stage="output_block", **q)
    cut = Cut("block.1", "u", "s", stage="output_block", skip_phases=2, **q)
    np.testing.assert_array_equal(reformat.block_input(dec, phased, cut), reformat.block_input(dec, nat, plain))
    with pytest.raises(reformat.ArtifactError, match="do not fit"):
        reformat.block_input(dec, nat, cut)
