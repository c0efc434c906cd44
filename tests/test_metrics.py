"""The changed-pixel measure (metrics.changed_mask / changed_psnr): where the previous frame
showed another surface."""

import numpy as np
import pytest

from jnds_deploy.metrics import changed_mask, changed_psnr, masked_squared_error, psnr, psnr_of


def _frame(h=12, w=16, ball_x=None):
    """A floor (albedo 0.5, normal up) with a green 3x3 'ball' facing up too at ball_x."""
    f = {
        "albedo": np.full((h, w, 3), 0.5, np.float32),
        "normal": np.zeros((h, w, 3), np.float32),
        "motion": np.zeros((h, w, 2), np.float32),
        "depth": np.full((h, w, 1), 4.0, np.float32),
    }
    f["normal"][..., 1] = 1.0
    if ball_x is not None:
        f["albedo"][4:7, ball_x : ball_x + 3] = (0.1, 0.8, 0.1)
        f["depth"][4:7, ball_x : ball_x + 3] = 3.0
    return f


def test_a_moving_object_leaves_changed_pixels_where_it_was():
    prev, cur = _frame(ball_x=3), _frame(ball_x=9)
    cur["motion"][4:7, 9:12, 0] = -6.0  # the ball's pixels came from 6 to the left
    m = changed_mask(cur, prev)
    core = np.zeros_like(m)
    core[4:7, 3:6] = True  # floor now, the ball before: changed
    # the 3x3 tolerance leaves the old centre alone changed, dilated by one pixel: the 3x3
    assert m[core].all() and m.sum() == 9
    assert not m[4:7, 9:12][1, 1]  # the ball's centre: the same surface, moved
    assert not m[0, 14] and not m[11, 0]  # the floor far from both
    # dilated by one pixel, then repeated to the target resolution
    m2 = changed_mask(cur, prev, scale=2)
    assert m2.shape == (24, 32) and (m2[::2, ::2] == m).all() and (m2[1::2, 1::2] == m).all()


@pytest.mark.parametrize("key,value", [("albedo", 0.5 + 0.07), ("normal", None)])
def test_tolerances(key, value):
    prev, cur = _frame(), _frame()
    if key == "albedo":
        cur["albedo"][:] = value  # within CHANGED_ALBEDO: the same surface
        assert not changed_mask(cur, prev).any()
        cur["albedo"][:] = 0.5 + 0.1
        assert changed_mask(cur, prev).all()
    else:
        cur["normal"][:] = (0.0, 0.8, 0.6)  # 37 degrees: dot 0.8, the same surface
        assert not changed_mask(cur, prev).any()
        cur["normal"][:] = (0.0, 0.6, 0.8)
        assert changed_mask(cur, prev).all()


def test_off_screen_and_depth():
    prev, cur = _frame(), _frame()
    cur["motion"][:, :, 0] = 1.0  # a pan: the last column came from outside the frame
    m = changed_mask(cur, prev)
    assert m[:, -2:].all() and not m[:, :-2].any()  # the column and its 1-pixel dilation
    cur = _frame()
    cur["depth"][:] = 4.0 * 1.2  # 20 % further: another surface
    assert changed_mask(cur, prev).all()
    del cur["depth"]  # without depth in both frames, depth is not tested
    assert not changed_mask(cur, prev).any()


def test_changed_psnr_pools_the_masked_pixels_of_every_frame():
    rng = np.random.default_rng(0)
    refs = [rng.random((8, 8, 3), dtype=np.float32) for _ in range(3)]
    outs = [r + rng.normal(0, 0.05, r.shape).astype(np.float32) for r in refs]
    full = np.ones((8, 8), bool)
    r = changed_psnr(outs, refs, [None, full, full])
    sums = [masked_squared_error(o, f, full) for o, f in zip(outs[1:], refs[1:])]
    assert r["changed_psnr"] == pytest.approx(psnr_of(sum(s for s, _ in sums), sum(c for _, c in sums)))
    assert r["changed_fraction"] == 1.0
    # one frame, every pixel: the frame's PSNR
    assert changed_psnr(outs[1:2], refs[1:2], [full])["changed_psnr"] == pytest.approx(psnr(outs[1], refs[1]), abs=1e-4)
    assert np.isnan(changed_psnr(outs, refs, [None] * 3)["changed_psnr"])
