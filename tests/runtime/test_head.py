"""The int8 network graph's u8 edges: runtime.head decodes the head's output as the float
graph's nodes would, the filter loops read it as its decoded values; runtime.reformat
packs the inputs as the input block's preprocessing and quantization would."""

import numpy as np
import pytest
import torch
import torch.nn.functional as TF

from jnds_deploy import model as M
from jnds_deploy.artifacts import HeadLayout, InputsLayout
from jnds_deploy.errors import ArtifactError
from jnds_deploy.runtime import filters as F
from jnds_deploy.runtime.head import Coded, Head
from jnds_deploy.runtime.reformat import pack_inputs

PARTS = (
    ("diffuse.spatial", 9),
    ("diffuse.temporal", 9),
    ("diffuse.blend", 1),
    ("diffuse.up", 9),
    ("diffuse.up_blend", 1),
    ("aux.spatial", 9),
    ("aux.temporal", 9),
    ("aux.blend", 1),
    ("features", 3),
)
H = 7


# widths and head channels: rows of whole 64-bit words or not (runtime.head._planes), and a
# channel count that is no multiple of 8 (numpy's copy)
@pytest.fixture(params=[(11, 64), (16, 64), (16, 62), (16, 52)], ids=["w11", "w16", "w16-c62", "w16-c52"])
def head(request):
    w, channels = request.param
    rng = np.random.default_rng(0)
    n = sum(c for _, c in PARTS)
    # kernels: 1/127 (range 1); others up to a range of 20 (aux logits: exp() of +-20)
    scale = np.where(np.arange(n) < 29, 1 / 127, rng.uniform(0.01, 20, n) / 127)
    centre = np.where(np.arange(n) < 29, rng.uniform(-0.3, 0.3, n), rng.uniform(-5, 5, n))
    layout = HeadLayout(PARTS, tuple(float(s) for s in scale), tuple(float(c) for c in centre), 128, channels)
    q = rng.integers(0, 256, (1, H, w, channels), dtype=np.uint8)
    return Head(layout), q


def _raw(head, q, name):
    c0, c = head.slices[name]
    raw = (q[0, :, :, c0 : c0 + c].astype(np.float64) - 128) * np.array(head.layout.scale[c0 : c0 + c]) + np.array(
        head.layout.centre[c0 : c0 + c]
    )
    return torch.from_numpy(raw.transpose(2, 0, 1).copy())[None]


def test_decode_is_the_output_blocks_post_processing(head):
    """Each part decoded equals model.OutputBlock's function of the dequantized head."""
    h, q = head
    post = {"relu": TF.relu, "blend": M._blend, "normalized": M._normalized_kernel, "kernel": M._kernel}
    for name, _ in PARTS:
        want = post[M.head_kind(name)](_raw(h, q, name))[0].numpy()
        got = h.coded(q)[name].decode()
        assert got.dtype == np.float32 and got.shape == want.shape
        # float32 against float64, raw = q * scale + offset in one rounding
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7, err_msg=name)
    aux = h.coded(q)["aux.spatial"].decode()
    np.testing.assert_allclose(aux.sum(0), 1, rtol=1e-6)


def test_filters_read_coded_parts_as_their_decoded_values(head):
    """The filter loops that decode the head row by row give bit-equal results to the
    float loops on the decoded kernels."""
    h, q = head
    W = q.shape[2]
    rng = np.random.default_rng(1)
    x, hist, coarse = (rng.uniform(0, 4, s).astype(np.float32) for s in ((3, H, W), (3, H, W), (3, 4, 6)))
    coded = h.coded(q)
    dec = {k: v.decode() for k, v in coded.items()}
    for relu in (True, False):
        got = F.spatiotemporal(
            x, hist, coded["diffuse.spatial"], coded["diffuse.temporal"], coded["diffuse.blend"], relu=relu
        )
        want = F.spatiotemporal(
            x, hist, dec["diffuse.spatial"], dec["diffuse.temporal"], dec["diffuse.blend"], relu=relu
        )
        np.testing.assert_array_equal(got, want)
    got = F.spatiotemporal(x, hist, coded["aux.spatial"], coded["aux.temporal"], coded["aux.blend"], relu=False)
    want = F.spatiotemporal(x, hist, dec["aux.spatial"], dec["aux.temporal"], dec["aux.blend"], relu=False)
    np.testing.assert_array_equal(got, want)
    skip, low = x[:, :6, :10], coarse[:, :3, :5]
    sub = h.coded(np.ascontiguousarray(q[:, :6, :10]))
    np.testing.assert_array_equal(
        F.up_level(skip, low, sub["diffuse.up"], sub["diffuse.up_blend"]),
        F.up_level(skip, low, sub["diffuse.up"].decode(), sub["diffuse.up_blend"].decode()),
    )


def test_level_heads_read_as_planes_decode_as_their_nodes_and_filter_alike():
    """A u8 level head (calibration.head_ranges.code_levels: the QLinearConv's own codes, one scale,
    planes) decodes as its DequantizeLinear, Clip and Sigmoid did (within a rounding), without
    a copy, and the
    levels' filter loops read it bit-equal to its decoded values."""
    rng = np.random.default_rng(2)
    parts = (("diffuse.level1.down", 9), ("diffuse.level1.up", 9), ("diffuse.level1.up_blend", 1))
    scale, zp = 0.0155, 50
    h = Head(HeadLayout(parts, (scale,) * 19, (0.0,) * 19, zp, 19))
    for w in (11, 16):
        q = rng.integers(0, 256, (1, 19, 6, w), dtype=np.uint8)
        coded = h.planar(q)
        assert all(np.shares_memory(c.q, q) for c in coded.values())
        raw = (q[0].astype(np.float32) - np.float32(zp)) * np.float32(scale)  # DequantizeLinear
        # q * scale + offset in one rounding: within an ulp of (q - zero point) * scale
        np.testing.assert_allclose(coded["diffuse.level1.down"].decode(), np.clip(raw[:9], -1, 1), rtol=0, atol=1.2e-7)
        np.testing.assert_allclose(coded["diffuse.level1.up"].decode(), np.clip(raw[9:18], -1, 1), rtol=0, atol=1.2e-7)
        np.testing.assert_allclose(
            coded["diffuse.level1.up_blend"].decode(), 1 / (1 + np.exp(-raw[18:].astype(np.float64))), rtol=1e-6
        )
        x, low = (
            rng.uniform(0, 4, (3, 12, 2 * w)).astype(np.float32),
            rng.uniform(0, 4, (3, 3, w // 2)).astype(np.float32),
        )
        np.testing.assert_array_equal(
            F.down_level(x, coded["diffuse.level1.down"]), F.down_level(x, coded["diffuse.level1.down"].decode())
        )
        skip = x[:, :6, :w].copy()
        np.testing.assert_array_equal(
            F.up_level(skip, low, coded["diffuse.level1.up"], coded["diffuse.level1.up_blend"]),
            F.up_level(skip, low, coded["diffuse.level1.up"].decode(), coded["diffuse.level1.up_blend"].decode()),
        )
    with pytest.raises(ArtifactError, match="level head"):
        h.planar(np.zeros((1, 18, 6, 8), np.uint8))


def test_bad_layouts_and_heads_are_named():
    with pytest.raises(ArtifactError, match="malformed"):
        HeadLayout.from_json('{"parts": 3}')
    with pytest.raises(ArtifactError, match="aux.spatial"):
        HeadLayout((("aux.spatial", 8),), (0.1,) * 8, (0.0,) * 8, 128, 16)
    with pytest.raises(ArtifactError, match="channels"):
        HeadLayout((("diffuse.spatial", 9),), (0.1,) * 8, (0.0,) * 8, 128, 16)
    h = Head(HeadLayout((("diffuse.spatial", 9),), (1 / 127,) * 9, (0.0,) * 9, 128, 16))
    with pytest.raises(ArtifactError, match=r"u8 \(H, W, 16\)"):
        h.coded(np.zeros((4, 4, 9), np.uint8))
    assert isinstance(h.coded(np.zeros((1, 4, 4, 16), np.uint8))["diffuse.spatial"], Coded)


@pytest.mark.parametrize("scale, zero_point", [(0.011, 3), (0.004, 0), (0.02, 40)])
def test_pack_inputs_is_the_input_blocks_preprocessing_quantized(scale, zero_point):
    """pack_inputs equals model.tonemap_inputs of current and history quantized as
    QuantizeLinear does, but for a rare tie between neighbouring codes; the padding holds
    the zero point."""
    rng = np.random.default_rng(2)
    h, w = 24, 40
    cur = (rng.random((1, 13, h, w)) ** 6 * 400).astype(np.float32)
    hist = (rng.random((1, 12, h, w)) ** 6 * 400).astype(np.float32)
    for x in (cur, hist):
        x[:, 6:9] = rng.random((1, 3, h, w))  # albedo
        n = rng.normal(size=(1, 3, h, w))
        x[:, 9:12] = n / np.linalg.norm(n, axis=1, keepdims=True)
    cur[:, 12] = rng.random((1, h, w))
    cur[0, 0, 0, :7] = [0, 1e-30, 1e-9, 65535, 1e9, 7.5, -0.0]  # floor, huge (clamped), zeros of both signs
    hist[0, 1, 0, :2] = [-0.0, -3.0]
    layout = InputsLayout(scale, zero_point, 32)
    got = pack_inputs(cur, hist, layout)
    x = torch.cat(
        [M.tonemap_inputs(torch.from_numpy(cur), M.CURRENT), M.tonemap_inputs(torch.from_numpy(hist), M.HISTORY)], 1
    )[0].numpy()
    want = np.clip(np.rint(x / np.float32(scale)) + zero_point, 0, 255).transpose(1, 2, 0)
    d = np.abs(got[0, :, :, :25].astype(np.int64) - want)
    assert got.shape == (1, h, w, 32) and got.dtype == np.uint8
    assert d.max() <= 1 and (d > 0).mean() < 1e-3
    assert (got[0, :, :, 25:] == zero_point).all()
    # channel counts that are not a multiple of 8 take the byte loop, 8 and more the word stores
    np.testing.assert_array_equal(pack_inputs(cur, hist, InputsLayout(scale, zero_point, 28)), got[..., :28])
    # a width that is no multiple of 8 takes the words one pixel at a time (the others 8x8 at once)
    np.testing.assert_array_equal(pack_inputs(cur[..., :37], hist[..., :37], layout), got[:, :, :37])
    # channels in other slots (calibration.inputs.safe_slots): the same codes, moved; the rest padding
    slots = tuple(np.random.default_rng(1).permutation(32)[:25].tolist())
    moved = pack_inputs(cur, hist, InputsLayout(scale, zero_point, 32, slots))
    np.testing.assert_array_equal(moved[..., list(slots)], got[..., :25])
    assert (np.delete(moved, list(slots), axis=3) == zero_point).all()
    assert InputsLayout.from_json(InputsLayout(scale, zero_point, 32, slots).to_json()).slots == slots


@pytest.mark.parametrize("guided", [False, True])
def test_pack_inputs_in_2x2_blocks_is_the_space_to_depth_input(guided):
    """A space-to-depth input block's input (InputsLayout.block 2): each 2x2 block of pixels
    as one pixel, channel c's four pixels at 4c..4c+3 as torch's pixel_unshuffle orders them
    (model.InputBlock), placed by slots, bit-equal to packing the frame pixel by pixel."""
    rng = np.random.default_rng(3)
    h, w = 12, 20
    cur = (rng.random((1, 13, h, w)) ** 6 * 400).astype(np.float32)
    hist = (rng.random((1, 12, h, w)) ** 6 * 400).astype(np.float32)
    guide = rng.random((1, 3, h, w)).astype(np.float32) if guided else None
    n = 28 if guided else 25
    flat = pack_inputs(cur, hist, InputsLayout(0.011, 3, n, tuple(range(n))), guide)[0]  # (h, w, n), in order
    want = torch.nn.functional.pixel_unshuffle(torch.from_numpy(flat.transpose(2, 0, 1).copy())[None], 2)[0]
    slots = tuple(np.random.default_rng(4).permutation(4 * n + 4)[: 4 * n].tolist())
    layout = InputsLayout(0.011, 3, 4 * n + 4, slots, block=2)
    assert layout.guided == guided and InputsLayout.from_json(layout.to_json()) == layout
    got = pack_inputs(cur, hist, layout, guide)
    assert got.shape == (1, h // 2, w // 2, 4 * n + 4)
    np.testing.assert_array_equal(got[0][..., list(slots)], want.numpy().transpose(1, 2, 0))
    assert (np.delete(got, list(slots), axis=3) == 3).all()
    with pytest.raises(ArtifactError, match="2x2 pixel blocks"):
        pack_inputs(cur[..., 1:], hist[..., 1:], layout, None if guide is None else guide[..., 1:])


def test_pack_inputs_places_the_guide_albedo_after_current_and_history():
    """A graph that reads the guide albedo (ModelConfig.guide_albedo) packs its channels
    after current and history's, as they are (an albedo: no tonemap); one that does not
    refuses a guide, and the other way round."""
    rng = np.random.default_rng(3)
    h, w = 8, 16
    cur = (rng.random((1, 13, h, w)) * 3).astype(np.float32)
    hist = (rng.random((1, 12, h, w)) * 3).astype(np.float32)
    guide = rng.random((1, 3, h, w)).astype(np.float32)
    scale, zp = 0.01, 4
    slots = tuple(np.random.default_rng(4).permutation(32)[:28].tolist())
    layout = InputsLayout(scale, zp, 32, slots)
    assert layout.guided and InputsLayout.from_json(layout.to_json()) == layout
    got = pack_inputs(cur, hist, layout, guide)
    plain = pack_inputs(cur, hist, InputsLayout(scale, zp, 32, slots[:25]))
    np.testing.assert_array_equal(got[..., list(slots[:25])], plain[..., list(slots[:25])])
    want = np.clip(np.rint(guide[0] / np.float32(scale)) + zp, 0, 255).transpose(1, 2, 0)
    np.testing.assert_array_equal(got[0][..., list(slots[25:])], want)
    assert (np.delete(got, list(slots), axis=3) == zp).all()
    with pytest.raises(ArtifactError, match="reads guide albedo"):
        pack_inputs(cur, hist, layout)
    with pytest.raises(ArtifactError, match="has no guide albedo"):
        pack_inputs(cur, hist, InputsLayout(scale, zp, 32), guide)


def test_transpose8x8_is_the_byte_transpose_and_its_own_inverse():
    """runtime.simd: byte p of word t out is byte t of word p in."""
    from numba import njit

    from jnds_deploy.runtime.simd import transpose8x8

    @njit
    def t(a):
        return transpose8x8(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7])

    a = np.random.default_rng(3).integers(0, 256, 64, dtype=np.uint8).view(np.uint64)
    b = np.array(t(a), np.uint64)
    np.testing.assert_array_equal(b.view(np.uint8).reshape(8, 8), a.view(np.uint8).reshape(8, 8).T)
    np.testing.assert_array_equal(np.array(t(b), np.uint64), a)


@pytest.mark.parametrize("scale, zero_point", [(0.011, 0), (0.004, 3), (0.05, 128)])
def test_tonemap_codes_16_at_a_time_are_the_codes_one_at_a_time(scale, zero_point):
    """The packing's tonemap codes by gathers (simd.binned_codes16, whole vectors of a row)
    are those of the scalar loop (the row's remainder), on floats of every exponent, the
    clamps and signed zeros, and those of rounding the float64 tonemap but for rare ties."""
    from numba import njit

    from jnds_deploy.runtime.reformat import _quantize_row, _tonemap_codes

    @njit
    def both(src, scale, zero_point, first, step, whole, single):
        _quantize_row(src, 1, scale, zero_point, first, step, whole)
        one, code = np.empty(1, np.float32), np.empty(1, np.uint8)
        for i in range(src.shape[0]):  # a row of one value: the remainder loop
            one[0] = src[i]
            _quantize_row(one, 1, scale, zero_point, first, step, code)
            single[i] = code[0]

    rng = np.random.default_rng(4)
    bits = rng.integers(0, 0x47800000, 4096, dtype=np.uint32)  # every exponent up to 65536
    x = np.concatenate(
        [
            bits.view(np.float32),
            np.float32([0, -0.0, -3, 65535, 1e9, np.inf, 1e-30, 7.5]),
            np.float32(rng.random(4088) ** 6 * 400),
        ]
    )
    layout = InputsLayout(scale, zero_point, 32)
    first, step = _tonemap_codes(layout)
    whole, single = np.empty(len(x), np.uint8), np.empty(len(x), np.uint8)
    both(x, np.float32(scale), zero_point, first, step, whole, single)
    np.testing.assert_array_equal(whole, single)
    t = np.log1p(np.clip(x.astype(np.float64), 0, 65535)) ** (1 / 2.2)
    want = np.clip(np.rint(t / scale) + zero_point, 0, 255)
    assert np.abs(whole - want).max() <= 1 and (whole != want).mean() < 1e-3
