"""The numpy/opencv filter stage against the torch specification (jnds_deploy.filter_spec)."""

import numpy as np
import pytest
import torch

from jnds_deploy import filter_spec as T
from jnds_deploy.io import open_sequence
from jnds_deploy.layout import HDR_MAX, REJECT_ALBEDO
from jnds_deploy.runtime import filters as N

from ..conftest import SAMPLE

RNG = np.random.default_rng(0)


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a, np.float32))[None]


def _kernel(h, w, normalized=False):
    k = RNG.normal(size=(9, h, w)).astype(np.float32)
    if normalized:
        e = np.exp(k)
        return e / e.sum(0)
    return np.clip(k * 0.4, -1, 1)


def test_apply_kernel_matches_torch():
    x = RNG.random((3, 17, 23), dtype=np.float32) * 10
    k = _kernel(17, 23)
    np.testing.assert_allclose(N.apply_kernel(x, k), T.apply_kernel(_t(x), _t(k))[0].numpy(), rtol=1e-5, atol=1e-5)


def test_pool_upsample_tonemap_match_torch():
    x = RNG.random((3, 16, 24), dtype=np.float32) * 5
    np.testing.assert_allclose(N.downsample(x), T.downsample(_t(x))[0].numpy(), rtol=1e-6)
    for f in (2, 3):
        np.testing.assert_allclose(N.upsample(x, f), T.upsample(_t(x), f)[0].numpy(), rtol=1e-5, atol=1e-5)
    hdr = np.array([[[0.0, 0.5, 3.0, 7e4, -1.0]]], np.float32)
    np.testing.assert_allclose(N.tonemap(hdr), T.tonemap(_t(hdr))[0].numpy(), rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("source", ["random", "sample"])
def test_warp_matches_torch(source):
    if source == "random":
        x = RNG.random((3, 20, 30), dtype=np.float32)
        mv = RNG.normal(scale=3, size=(2, 20, 30)).astype(np.float32)
    else:
        seq = open_sequence(SAMPLE)
        x = seq.inputs(3)["albedo"].transpose(2, 0, 1)
        mv = seq.inputs(4)["motion"].transpose(2, 0, 1)
    got = N.warp(x, mv)
    ref = T.warp(_t(x), _t(mv))[0].numpy()
    # exact coordinates (measured max 1.4e-6 random, 7.2e-6 sample: torch's round trip
    # through normalized grid coordinates); cv2.remap's 1/32-pixel quantization gave 0.03
    err = np.abs(got - ref)
    assert err.max() < 1e-4, err.max()


def test_warp_clamps_and_handles_far_motion():
    x = RNG.random((12, 9, 11), dtype=np.float32) * 4 - 2
    mv = np.zeros((2, 9, 11), np.float32)
    mv[:, 0, 0] = 1e30  # far outside: every tap is the bottom-right pixel
    mv[:, 1, 1] = -1e30
    hwc = N.channels_last(x[:5], x[5:])
    np.testing.assert_array_equal(hwc, x.transpose(1, 2, 0))
    lo, hi = np.full(12, -1, np.float32), np.full(12, 1, np.float32)
    got = N.warp_channels_last(hwc, mv, lo, hi)
    np.testing.assert_allclose(got[:, 2:, 2:], np.clip(x, -1, 1)[:, 2:, 2:], atol=1e-6)  # zero motion: identity
    np.testing.assert_allclose(got[:, 0, 0], np.clip(x[:, -1, -1], -1, 1), atol=1e-6)
    np.testing.assert_allclose(got[:, 1, 1], np.clip(x[:, 0, 0], -1, 1), atol=1e-6)
    assert got.min() >= -1 and got.max() <= 1
    tiny = np.array([[[1e-35, -1e-31, 2e-30, -1.0]]], np.float32).transpose(2, 0, 1)  # (4, 1, 1)
    np.testing.assert_array_equal(N.channels_last(tiny, flush=1e-30).ravel(), np.float32([0, 0, 2e-30, -1]))
    # non-finite values: replaced as history.replace_nonfinite replaces them, and counted
    bad = np.array([[[np.nan, np.inf, -np.inf, 3.0]]], np.float32).transpose(2, 0, 1)
    got, n = N.channels_last(bad, x[:2, :1, :1], flush=1e-30, counted=True)
    np.testing.assert_array_equal(got.ravel()[:4], np.float32([0, HDR_MAX, 0, 3]))
    assert n == 3


def test_channels_last_of_four_3_channel_layers_is_the_general_loops():
    """The history's four 3-channel layers take their own unrolled loop: the same values
    and counts as the general loop, which a 4 + 2 + 3 + 3 split takes."""
    x = RNG.random((12, 7, 9), dtype=np.float32) * 4 - 2
    x[0, 1, 2], x[4, 3, 3], x[7, 0, 0], x[11, 6, 8] = np.nan, np.inf, -np.inf, 1e-35
    fast, n_fast = N.channels_last(x[:3], x[3:6], x[6:9], x[9:], flush=1e-30, counted=True)
    general, n_general = N.channels_last(x[:4], x[4:6], x[6:9], x[9:], flush=1e-30, counted=True)
    np.testing.assert_array_equal(fast, general)
    assert n_fast == n_general == 3
    assert fast[1, 2, 0] == 0 and fast[3, 3, 4] == HDR_MAX and fast[0, 0, 7] == 0 and fast[6, 8, 11] == 0


def _levels(h, w, n):
    levels = []
    for k in range(1, n + 1):
        hh, ww = h >> k, w >> k
        lv = {"down": _kernel(hh, ww)}
        if k < n:
            lv.update(up=_kernel(hh, ww), up_blend=RNG.random((1, hh, ww), dtype=np.float32))
        levels.append(lv)
    return levels


@pytest.mark.parametrize("source", ["random", "sample"])
def test_filter_path_matches_torch(source):
    if source == "random":
        h, w = 32, 48
        x = RNG.exponential(size=(3, h, w)).astype(np.float32)
        hist = RNG.exponential(size=(3, h, w)).astype(np.float32)
    else:
        seq = open_sequence(SAMPLE)
        x = seq.inputs(5)["diffuse"].transpose(2, 0, 1)[:, :88, :160]
        hist = seq.inputs(4)["diffuse"].transpose(2, 0, 1)[:, :88, :160]
        h, w = 88, 160
    native = {
        "spatial": _kernel(h, w),
        "temporal": _kernel(h, w),
        "blend": RNG.random((1, h, w), dtype=np.float32),
        "up": _kernel(h, w),
        "up_blend": RNG.random((1, h, w), dtype=np.float32),
    }
    levels = _levels(h, w, 3)
    got = N.filter_path(x, hist, native, levels)
    tt = lambda d: {k: _t(v) for k, v in d.items()}  # noqa: E731
    ref = T.filter_path(_t(x), _t(hist), tt(native), [tt(lv) for lv in levels])[0].numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-4 * max(1.0, float(np.abs(ref).max())))


def test_upsample_filter_and_composite_match_torch():
    h, w = 12, 20
    a, d, s = (RNG.random((3, h, w), dtype=np.float32) for _ in range(3))
    c = N.composite(a, d, s)
    np.testing.assert_allclose(c, T.composite(_t(a), _t(d), _t(s))[0].numpy(), rtol=1e-6)
    np.testing.assert_array_equal(c, a * d + s)  # the fused loop rounds as numpy does (no FMA)
    for s in (2, 3):
        k = _kernel(s * h, s * w)
        phases = T.to_phases(_t(k), s)[0].numpy()  # the upsample graph's layout
        ref = T.upsample_filter(_t(c), _t(k), s)[0].numpy()
        np.testing.assert_allclose(N.upsample_filter(c, phases, s), ref, rtol=1e-5, atol=1e-5)
        np.testing.assert_array_equal(N.from_phases(phases, s), k)
        half = N.upsample_filter(c.astype(np.float16), phases.astype(np.float16), s)  # the numpy path
        np.testing.assert_allclose(half, ref, rtol=2e-2, atol=2e-2)
        hdr = c * RNG.exponential(20.0, size=c.shape).astype(np.float32)
        for root in (2, 4, 8):  # interpolating roots
            ref = T.upsample_filter(_t(hdr), _t(k), s, root)[0].numpy()
            np.testing.assert_allclose(N.upsample_filter(hdr.copy(), phases, s, root=root), ref, rtol=1e-4, atol=1e-4)
            assert not np.allclose(ref, T.upsample_filter(_t(hdr), _t(k), s)[0].numpy(), rtol=1e-2)


@pytest.mark.parametrize("root", [1, 4])
def test_fixed_upsample_kernel_matches_torch(root):
    """One kernel for every pixel (ModelConfig.upsample_width 0): the cv2 path at any
    scale and the fused 2x pass into the output (cropped, channels last) against the torch
    upsample filter with that kernel broadcast; the fused pass counts and replaces NaN/Inf."""
    from jnds_deploy.runtime.reformat import to_hwc

    h, w = 12, 20
    c = RNG.random((3, h, w), dtype=np.float32) * RNG.exponential(5.0, size=(3, h, w)).astype(np.float32)
    k = np.clip(RNG.normal(size=9).astype(np.float32) * 0.3 + np.eye(9, dtype=np.float32)[4], -1, 1)
    for s in (2, 3):
        ref = T.upsample_filter(_t(c), torch.from_numpy(k).view(1, 9, 1, 1), s, root)[0].numpy()
        np.testing.assert_allclose(N.upsample_fixed(c, k, s, root), ref, rtol=1e-4, atol=1e-5)
    ref = T.upsample_filter(_t(c), torch.from_numpy(k).view(1, 9, 1, 1), 2, root)[0].numpy()
    out, bad = N.upsample_fixed_hwc(c, k, root, h - 3, w - 5)  # the padded frame's top-left
    np.testing.assert_allclose(out, to_hwc(ref, 2 * (h - 3), 2 * (w - 5)), rtol=1e-4, atol=1e-5)
    assert bad == 0 and out.flags.c_contiguous and out.min() >= 0
    c[1, 4, 7] = np.nan
    c[2, 0, 0] = np.inf
    out, bad = N.upsample_fixed_hwc(c, k, root, h, w)
    assert bad > 0 and np.isfinite(out).all()
    # three channels are stored by a loop of their own (vectorized), other counts one at a time:
    # five here, channels 1 and 2 then all three
    out4, bad4 = N.upsample_fixed_hwc(np.concatenate([c[1:], c]), k, root, h, w)
    np.testing.assert_array_equal(out4[..., 2:], out)
    assert bad4 == 2 * bad  # the NaN and Inf are in channels 1 and 2, which come twice


def test_fp16_filter_stays_close_to_fp32():
    h, w = 32, 48
    x = RNG.exponential(size=(3, h, w)).astype(np.float32)
    native = {
        "spatial": _kernel(h, w, True),
        "temporal": _kernel(h, w, True),
        "blend": RNG.random((1, h, w), dtype=np.float32),
        "up": _kernel(h, w, True),
        "up_blend": RNG.random((1, h, w), dtype=np.float32),
    }
    levels = _levels(h, w, 3)
    f32 = N.filter_path(x, x, native, levels)
    h16 = lambda d: {k: v.astype(np.float16) for k, v in d.items()}  # noqa: E731
    f16 = N.filter_path(x.astype(np.float16), x.astype(np.float16), h16(native), [h16(lv) for lv in levels])
    assert f16.dtype == np.float16
    np.testing.assert_allclose(f16.astype(np.float32), f32, rtol=1e-2, atol=1e-2)


def _taps(a, k):
    """The numpy formula: shifted views of the edge-padded image, taps summed in order."""
    h, w = a.shape[1:]
    p = np.pad(a, ((0, 0), (1, 1), (1, 1)), mode="edge")
    out = p[:, :h, :w] * k[0]
    for i in range(1, 9):
        out = out + p[:, i // 3 : i // 3 + h, i % 3 : i % 3 + w] * k[i]
    return out


@pytest.mark.parametrize("h,w", [(1, 1), (7, 5), (33, 17), (8, 6)])
def test_fused_float32_loops_equal_numpy_formulas(h, w):
    """The numba loops of the float32 path compute the numpy formulas in the same
    order: bit-equal results, borders included."""
    x, hist = (RNG.exponential(size=(3, h, w)).astype(np.float32) for _ in range(2))
    ks, kt = _kernel(h, w), _kernel(h, w)
    blend = RNG.random((1, h, w), dtype=np.float32)
    np.testing.assert_array_equal(N.apply_kernel(x, ks), _taps(x, ks))
    s, t = _taps(x, ks), _taps(hist, kt)
    np.testing.assert_array_equal(N.spatiotemporal(x, hist, ks, kt, blend), np.maximum(s + blend * (t - s), 0))
    skip = RNG.random((3, 2 * h, 2 * w), dtype=np.float32)
    k2, b2 = _kernel(2 * h, 2 * w), RNG.random((1, 2 * h, 2 * w), dtype=np.float32)
    u = _taps(N.upsample(x), k2)
    np.testing.assert_array_equal(N.up_level(skip, x, k2, b2), np.maximum(skip + b2 * (u - skip), 0))
    if h % 2 == 0 and w % 2 == 0:
        # numpy's mean pools in another order: rounding of the O(1) terms, which the
        # kernel's cancellation can make large relative to a small sum (3e-6 seen)
        np.testing.assert_allclose(
            N.down_level(x, ks[:, ::2, ::2].copy()),
            np.maximum(_taps(N.downsample(x), ks[:, ::2, ::2]), 0),
            rtol=1e-6,
            atol=1e-6,
        )


def test_one_pass_auxiliary_filter_equals_the_models_normal_mapping():
    """The pipeline filters albedo and normals in one pass without ReLU and without mapping
    normals to [0, 1] and back: with normalized kernels and a convex blend that is the
    model's formula (albedo bit for bit, normals to rounding)."""
    h, w = 24, 40
    albedo = RNG.random((3, h, w), dtype=np.float32)
    normal = RNG.random((3, h, w), dtype=np.float32) * 2 - 1
    h_albedo = RNG.random((3, h, w), dtype=np.float32)
    h_normal = RNG.random((3, h, w), dtype=np.float32) * 2 - 1
    ks, kt = _kernel(h, w, normalized=True), _kernel(h, w, normalized=True)
    blend = RNG.random((1, h, w), dtype=np.float32)
    both = N.spatiotemporal(
        np.concatenate([albedo, normal]), np.concatenate([h_albedo, h_normal]), ks, kt, blend, relu=False
    )
    ref_albedo = T.spatiotemporal(_t(albedo), _t(h_albedo), _t(ks), _t(kt), _t(blend))[0].numpy()
    ref_normal = (
        T.spatiotemporal(_t(normal * 0.5 + 0.5), _t(h_normal * 0.5 + 0.5), _t(ks), _t(kt), _t(blend))[0].numpy() * 2 - 1
    )
    np.testing.assert_allclose(both[:3], ref_albedo, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(both[3:], ref_normal, rtol=0, atol=2e-6)
    assert (both[3:] < 0).any()  # negative normals survive: no ReLU
    assert np.array_equal(both[:3], N.spatiotemporal(albedo, h_albedo, ks, kt, blend))


def _normals(h, w):
    n = RNG.normal(size=(3, h, w)).astype(np.float32)
    n /= np.linalg.norm(n, axis=0)
    return n


def test_disoccluded_background_and_other_surfaces():
    n = np.zeros((3, 5, 7), np.float32)
    n[2] = 1.0  # a plane facing +z
    n[:, :, 0] = 0.0  # background in column 0
    hist = n.copy()
    hist[:, 2, 3] = (1.0, 0.0, 0.0)  # another surface, 90 degrees off
    hist[:, 4, 6] = (0.0, 0.6, 0.8)  # 37 degrees off: the same surface
    hist[:, 1, 5] = 0.0  # background in the history, a surface now
    albedo = np.full((3, 5, 7), 0.5, np.float32)
    got = T.disoccluded(_t(n), _t(hist), _t(albedo), _t(albedo))[0, 0].numpy()
    want = np.zeros((5, 7), bool)
    want[:, 0] = True  # background now: the current inputs are exact there
    want[2, 3] = True
    assert (got == want).all(), np.argwhere(got != want)


def test_disoccluded_tolerates_a_one_pixel_silhouette_shift():
    n = np.zeros((3, 6, 8), np.float32)
    n[2, :, :4] = 1.0
    n[0, :, 4:] = 1.0  # two planes meeting at column 4
    hist = np.roll(n, 1, axis=2)  # the silhouette one pixel to the right in the history
    hist[:, :, 0] = n[:, :, 0]
    a = np.zeros((3, 6, 8), np.float32)
    a[:, :, :4], a[:, :, 4:] = 0.2, 0.7  # each plane its albedo
    ha = np.roll(a, 1, axis=2)
    ha[:, :, 0] = a[:, :, 0]
    assert not T.disoccluded(_t(n), _t(hist), _t(a), _t(ha)).any()
    assert T.disoccluded(_t(n), _t(np.roll(n, 2, axis=2)), _t(a), _t(a)).any()  # two pixels: rejected
    assert T.disoccluded(_t(n), _t(hist), _t(a), _t(np.roll(a, 2, axis=2))).any()


def test_disoccluded_rejects_another_albedo_facing_the_same_way():
    """A ball's top over a floor: the same normal, another albedo (the ghost trails of
    docs/ghosting.md); a filtered albedo between two neighbours' passes."""
    n = np.zeros((3, 5, 7), np.float32)
    n[2] = 1.0
    a = np.full((3, 5, 7), 0.5, np.float32)
    a[:, :, 4:] = 0.9  # a texture edge at column 4
    ha = a.copy()
    ha[:, 1, 1] = (0.1, 0.8, 0.1)  # a green ball was there
    ha[:, 2, 4] = 0.7  # the edge blurred by filtering: inside the neighbours' range
    ha[:, 3, 2] = 0.5 + REJECT_ALBEDO * 0.9  # within the tolerance
    ha[:, 0, 0] = 0.0  # background in the history (normal 0 there too)
    hn = n.copy()
    hn[:, 0, 0] = 0.0
    got = T.disoccluded(_t(n), _t(hn), _t(a), _t(ha))[0, 0].numpy()
    want = np.zeros((5, 7), bool)
    want[1, 1] = want[0, 0] = True
    assert (got == want).all(), np.argwhere(got != want)


@pytest.mark.parametrize("h,w", [(1, 1), (3, 2), (17, 23)])
def test_reject_disoccluded_matches_torch(h, w):
    from jnds_deploy.layout import BACKGROUND, REJECT_COS

    current = RNG.random((13, h, w), dtype=np.float32)
    current[9:12] = _normals(h, w)
    warped = RNG.random((12, h, w), dtype=np.float32) * 3
    warped[9:12] = _normals(h, w) * RNG.random((h, w), dtype=np.float32)  # filtered: shorter
    warped[9:12, ::3] = current[9:12, ::3]  # some agree
    current[9:12, :, ::4] = 0.0  # background columns
    warped[9:12, 1::5] = 0.0
    current[6:9] = RNG.random((3, h, w), dtype=np.float32)
    warped[6:9] = np.clip(current[6:9] + RNG.normal(scale=0.15, size=(3, h, w)).astype(np.float32), 0, 1)
    mask = T.history_rejected(
        _t(current[9:12]), _t(warped[9:12]), _t(current[6:9]), _t(warped[6:9]), torch.zeros(1, 2, h, w)
    )[0, 0].numpy()
    want = np.where(mask, current[:12], warped)
    got = warped.copy()
    n = N.reject_disoccluded(current, got, REJECT_COS, BACKGROUND)
    assert n == mask.sum() and 0 < n
    np.testing.assert_array_equal(got, want)


def test_warp_with_rejection_fused_equals_warp_then_reject():
    h, w = 19, 26
    current = RNG.random((13, h, w), dtype=np.float32)
    current[9:12] = _normals(h, w)
    current[9:12, :, :5] = 0.0  # background
    hist = RNG.random((h, w, 12), dtype=np.float32)
    hist[..., 9:12] = np.where(
        RNG.random((h, w, 1)) < 0.5, current[9:12].transpose(1, 2, 0), _normals(h, w).transpose(1, 2, 0)
    )
    mv = RNG.normal(scale=1.5, size=(2, h, w)).astype(np.float32)
    lo, hi = np.full(12, -1, np.float32), np.full(12, 1, np.float32)
    current[6:9] = RNG.random((3, h, w), dtype=np.float32)
    hist[..., 6:9] = np.clip(current[6:9].transpose(1, 2, 0) + RNG.normal(scale=0.1, size=(h, w, 3)), 0, 1)
    want = N.warp_channels_last(hist, mv, lo, hi)
    off = T.offscreen(_t(mv))[0, 0].numpy()
    assert 0 < off.sum() < h * w
    n_want = N.reject_disoccluded(current, want, offscreen=off)
    got, n = N.warp_channels_last(hist, mv, lo, hi, current)
    assert n == n_want > 0
    np.testing.assert_array_equal(got, want)


def test_history_rejected_rings_trails_only():
    """The 3x3 around a trail's pixels (at least RING_MIN rejected surface pixels in its 3x3)
    is rejected; not around a lone rejected pixel, nor around background."""
    from jnds_deploy.layout import RING_MIN

    assert RING_MIN == 3
    n = np.zeros((3, 5, 7), np.float32)
    n[2] = 1.0
    n[:, :, 6] = 0.0  # background in the last column: rejected, not dilated
    a = np.full((3, 5, 7), 0.5, np.float32)
    ha = a.copy()
    ha[:, 2, 1:4] = 0.0  # another surface was there: a trail of three
    ha[:, 4, 4] = 0.0  # one pixel of a texture whose filtered albedo left the range
    got = T.history_rejected(_t(n), _t(n), _t(a), _t(ha), torch.zeros(1, 2, 5, 7))[0, 0].numpy()
    want = np.zeros((5, 7), bool)
    want[1:4, 1:4] = True  # the ring around the trail's middle pixel (its 3x3 holds 3)
    want[2, 1:4] = True
    want[4, 4] = True
    want[:, 6] = True
    assert (got == want).all(), np.argwhere(got != want)
    cur = np.zeros((13, 5, 7), np.float32)
    cur[6:9], cur[9:12] = a, n
    warped = np.zeros((12, 5, 7), np.float32)
    warped[6:9], warped[9:12] = ha, n
    warped[:6] = 7.0
    assert N.reject_disoccluded(cur, warped) == want.sum()
    np.testing.assert_array_equal(warped[0] == 0, want)


def test_offscreen():
    mv = np.zeros((2, 4, 6), np.float32)
    mv[0, 1, 0] = -0.49  # still nearest pixel 0
    mv[0, 2, 0] = -0.51  # nearer a pixel left of the frame
    mv[1, 3, 5] = 0.6  # below the frame
    want = np.zeros((4, 6), bool)
    want[2, 0] = want[3, 5] = True
    np.testing.assert_array_equal(T.offscreen(_t(mv))[0, 0].numpy(), want)


@pytest.mark.parametrize("k", [1.0, 4.0, 16.0])
def test_clamp_fireflies_matches_torch(k):
    rng = np.random.default_rng(int(k))
    cur = (rng.exponential(1, (13, 19, 27)) ** 3).astype(np.float32)  # heavy-tailed, as 1 spp is
    hist = rng.exponential(1, (12, 19, 27)).astype(np.float32)
    got = cur.copy()
    n = N.clamp_fireflies(got, hist, k)
    t, h = torch.from_numpy(cur)[None], torch.from_numpy(hist)[None]
    want = torch.cat(
        [T.clamp_fireflies(t[:, 0:3], h[:, 0:3], k), T.clamp_fireflies(t[:, 3:6], h[:, 3:6], k), t[:, 6:]], 1
    )[0].numpy()
    np.testing.assert_array_equal(got, want)
    changed = (got[:6] != cur[:6]).reshape(2, 3, -1).any(1).sum()
    assert n == changed > 0
    np.testing.assert_array_equal(got[6:], cur[6:])  # only radiance changes


def test_clamp_fireflies_keeps_what_the_history_or_the_neighbours_show():
    cur = np.zeros((13, 9, 9), np.float32)
    cur[:6] = 0.1
    cur[0:3, 4, 4] = [500.0, 400.0, 300.0]  # a firefly in the diffuse signal
    cur[3:6, 2, 2] = 80.0  # a small emitter in the specular, bright in the history too
    hist = np.full((12, 9, 9), 0.1, np.float32)
    hist[3:6, 2, 2] = 60.0
    got = cur.copy()
    assert N.clamp_fireflies(got, hist, 4.0) == 1
    lum = np.dot(np.array([0.2126, 0.7152, 0.0722], np.float32), got[0:3, 4, 4])
    assert lum == pytest.approx(0.4, rel=1e-6)  # 4 x the brightest neighbour / history (0.1)
    np.testing.assert_allclose(got[0:3, 4, 4] / cur[0:3, 4, 4], got[0, 4, 4] / cur[0, 4, 4], rtol=1e-6)  # hue kept
    np.testing.assert_array_equal(got[3:6], cur[3:6])
    bright = cur.copy()
    bright[0:3, 4, 5] = 200.0  # a bright neighbour: no longer isolated, kept
    assert N.clamp_fireflies(bright, hist, 4.0) == 0


def test_fill_diffuse_holes_matches_torch():
    rng = np.random.default_rng(5)
    cur = rng.exponential(1, (13, 23, 31)).astype(np.float32)
    cur[9:12] = rng.normal(size=(3, 23, 31))
    holes = rng.random((23, 31)) < 0.45
    holes[5:16, 10:20] = True  # a region wider than the kernel: its middle stays as it is
    cur[6:9, holes] = 0.0
    cur[0:3, holes] = 0.0
    cur[9:12, 0:3, 0:4] = 0.0  # background: not filled
    got = cur.copy()
    n = N.fill_diffuse_holes(got)
    want = T.fill_diffuse_holes(*(torch.from_numpy(cur[None, a : a + 3]) for a in (0, 6, 9)))[0].numpy()
    np.testing.assert_allclose(got[0:3], want, rtol=1e-6, atol=1e-7)  # sums in another order
    changed = (got[0:3] != cur[0:3]).any(0)
    assert n == changed.sum() > 0 and not changed[0:3, 0:4].any() and not changed[~holes].any()
    assert not changed[10, 15]  # the wide region's middle
    np.testing.assert_array_equal(got[3:], cur[3:])
    clean = cur.copy()
    clean[6:9] = 0.5  # no holes: nothing to do
    assert N.fill_diffuse_holes(clean) == 0


def test_albedo_at_holes_matches_torch():
    """The runtime's albedo at holes (a patch of the composite) equals the torch ops
    (``filters.scattered_holes``, ``albedo_at_holes``, then the composite): the albedo's mean
    where holes lie scattered, the filtered albedo itself beside a solid hole region's straight
    edge, in the region and where there are none."""
    rng = np.random.default_rng(6)
    cur = rng.exponential(1, (13, 40, 52)).astype(np.float32)
    normals = rng.normal(size=(3, 40, 52))
    cur[9:12] = normals / np.linalg.norm(normals, axis=0)
    holes = np.zeros((40, 52), bool)
    holes[:, :24] = rng.random((40, 24)) < 0.4  # scattered, up to the frame's borders
    holes[10:30, 32:48] = True  # a solid object: its edge changes once
    holes[36:, :] = False  # rows without holes below them
    cur[6:9, holes] = 0.0
    cur[9:12, 0:2, 0:3] = 0.0  # background: not a hole
    albedo, diffuse, specular = (rng.random((3, 40, 52)).astype(np.float32) for _ in range(3))
    found = N.diffuse_holes(cur)
    plain = N.composite(albedo, diffuse, specular)
    got = plain.copy()
    n = N.albedo_at_holes(got, albedo, diffuse, specular, found)
    hole = T.diffuse_holes(torch.from_numpy(cur[None, 6:9]), torch.from_numpy(cur[None, 9:12]))
    np.testing.assert_array_equal(found[0] == 2, hole[0, 0].numpy())
    scattered = T.scattered_holes(hole)
    lit = T.albedo_at_holes(torch.from_numpy(albedo[None]), scattered)
    want = T.composite(lit, torch.from_numpy(diffuse[None]), torch.from_numpy(specular[None]))[0].numpy()
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)  # sums in another order
    changed = (got != plain).any(0)
    np.testing.assert_array_equal(changed, scattered[0, 0].numpy())
    assert n == changed.sum()
    assert changed[:, :20].mean() > 0.4 and changed[20, 0] and changed[34, 0]  # borders replicated
    assert not changed[12:28, 28:].any()  # the solid region, its edges but for the corners, and beyond
    assert not changed[38:].any()
    half = plain.astype(np.float16)
    N.albedo_at_holes(half, albedo, diffuse, specular, found)
    assert np.allclose(half, want, atol=4e-3, rtol=2e-3)
    clean = cur.copy()
    clean[6:9] = 0.5  # no holes: nothing to do
    assert N.albedo_at_holes(plain, albedo, diffuse, specular, N.diffuse_holes(clean)) == 0


@pytest.mark.parametrize("h, w", [(64, 96), (37, 67)])
def test_tile_sums_match_numpy(h, w):
    """Per-tile sums of three channels, the last row and column of tiles partial, as numpy
    sums them in float64 (the loop's order differs: equal to rounding)."""
    rng = np.random.default_rng(6)
    x = rng.exponential(size=(8, h, w)).astype(np.float32) * 100
    tile = 32
    got = N.tile_sums(x, 3, tile)
    s = x[3:6].astype(np.float64).sum(0)
    want = np.array([[s[ty : ty + tile, tx : tx + tile].sum() for tx in range(0, w, tile)] for ty in range(0, h, tile)])
    assert got.shape == want.shape == (-(-h // tile), -(-w // tile))
    np.testing.assert_allclose(got, want, rtol=1e-12)
