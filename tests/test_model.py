import json
from dataclasses import asdict, replace

import numpy as np
import pytest
import torch

from jnds_deploy import filter_spec as filters
from jnds_deploy.model import (
    JNDS,
    N_CURRENT,
    ActQuant,
    ModelConfig,
    UpsampleBlock,
    bilinear_taps,
    pad_to_multiple,
    quantize_weight,
    set_quantization,
)


def _data_dir(tmp_path, seq):
    """tmp_path/data with ``seq`` as its one training and its one validation sequence."""
    data = tmp_path / "data"
    for split in ("train", "val"):
        (data / split).mkdir(parents=True)
        (data / split / seq.name).symlink_to(seq)
    return data


def _inputs(n, h, w, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(n, N_CURRENT, h, w, generator=g) * 4
    return x, torch.randn(n, 2, h, w, generator=g) * 2


@pytest.mark.parametrize("scale", [1, 2, 3])
@pytest.mark.parametrize("size", [(16, 16), (37, 21), (8, 40)])
def test_shapes(scale, size):
    cfg = ModelConfig.preset("tiny", scale=scale)
    model = JNDS(cfg)
    h, w = size
    x, mv = _inputs(2, h, w)
    xp, (h0, w0) = pad_to_multiple(x, cfg.pad_multiple)
    mvp, _ = pad_to_multiple(mv, cfg.pad_multiple)
    assert xp.shape[-2] % cfg.pad_multiple == 0 and xp.shape[-1] % cfg.pad_multiple == 0
    out = model(xp, mvp, None)
    out = model(xp, mvp, out.history())  # second frame: warped history
    H, W = xp.shape[-2:]
    assert out.output.shape == (2, 3, H * scale, W * scale)
    assert out.diffuse.shape == out.specular.shape == out.albedo.shape == (2, 3, H, W)
    assert out.history().shape == (2, 12, H, W)
    assert out.output[..., : h0 * scale, : w0 * scale].shape[-2:] == (h * scale, w * scale)
    assert (out.output >= 0).all() and torch.isfinite(out.output).all()


@pytest.mark.parametrize("scale", [2, 3, 4])
@pytest.mark.parametrize("size", [(1, 1), (5, 7), (16, 24)])
def test_sub_pixel_upsample_block_equals_the_target_resolution_block(scale, size):
    """The native-resolution (sub-pixel) form gives the reference block's kernel at every
    target pixel, the border ring included; phase layout round-trips."""
    torch.manual_seed(scale)
    block = UpsampleBlock(ModelConfig.preset("small", scale=scale)).eval()
    with torch.no_grad():
        for p in block.parameters():
            p.normal_(0, 0.3)
    comp, feats = torch.rand(2, 3, *size) * 8, torch.rand(2, 8, *size)
    with torch.no_grad():
        ref = block(comp, feats)
        got = block.polyphase()(comp, feats)
    assert got.shape == (2, scale * scale * 9, *size)
    assert ref.abs().max() > 0.1  # not a trivially small kernel
    torch.testing.assert_close(filters.from_phases(got, scale), ref, rtol=0, atol=2e-5)
    torch.testing.assert_close(filters.to_phases(ref, scale), got, rtol=0, atol=2e-5)
    taps = bilinear_taps(scale)
    torch.testing.assert_close(taps.sum(-1), torch.ones(scale, 3, dtype=taps.dtype))  # each sample's weights sum to 1


def test_presets_and_validation():
    assert ModelConfig.preset("small").pad_multiple == 8
    assert ModelConfig.preset("paper").pad_multiple == 16
    with pytest.raises(ValueError, match="filter_levels must be in"):
        ModelConfig(encoder_widths=(8,), filter_levels=3)
    with pytest.raises(ValueError, match="scale must be an integer"):
        ModelConfig(scale=0)
    with pytest.raises(ValueError, match="unknown preset"):
        ModelConfig.preset("huge")


def test_network_kernels_respect_their_ranges():
    cfg = ModelConfig.preset("tiny")
    model = JNDS(cfg)
    for p in model.parameters():  # move away from the identity initialization
        torch.nn.init.normal_(p, std=2.0)
    x, _ = _inputs(1, 16, 16, seed=3)
    net = model.network(x, x[:, :12])
    for name, t in net.items():
        kind = name.split(".")[-1]
        if name.startswith("aux.") and kind in ("spatial", "temporal"):
            torch.testing.assert_close(t.sum(1), torch.ones_like(t[:, 0]))  # normalized
            assert (t >= 0).all()
        elif kind in ("blend", "up_blend"):
            assert (t >= 0).all() and (t <= 1).all()
        elif name != "features":
            assert (t >= -1).all() and (t <= 1).all()  # linear kernels clamped to [-1, 1]


def test_normalized_kernel_preserves_constants():
    k = torch.softmax(torch.randn(2, 9, 8, 8), dim=1)
    x = torch.full((2, 3, 8, 8), 0.37)
    torch.testing.assert_close(filters.apply_kernel(x, k), x)
    h = torch.full((2, 3, 8, 8), 0.37)
    torch.testing.assert_close(filters.spatiotemporal(x, h, k, k.flip(1), torch.rand(2, 1, 8, 8)), x)


def test_identity_filter_path_preserves_constants_through_all_levels():
    n, h, w = 1, 16, 16
    ident = lambda hh, ww: torch.nn.functional.one_hot(torch.tensor(4), 9).float().view(1, 9, 1, 1).expand(n, 9, hh, ww)  # noqa: E731
    x = torch.full((n, 3, h, w), 2.5)
    native = {
        "spatial": ident(h, w),
        "temporal": ident(h, w),
        "blend": torch.rand(n, 1, h, w),
        "up": ident(h, w),
        "up_blend": torch.rand(n, 1, h, w),
    }
    levels = [{"down": ident(8, 8), "up": ident(8, 8), "up_blend": torch.rand(n, 1, 8, 8)}, {"down": ident(4, 4)}]
    torch.testing.assert_close(filters.filter_path(x, x, native, levels), x)


def test_warp_zero_motion_is_identity_and_integer_motion_shifts():
    x = torch.rand(1, 3, 10, 12)
    torch.testing.assert_close(filters.warp(x, torch.zeros(1, 2, 10, 12)), x, atol=1e-5, rtol=0)
    mv = torch.zeros(1, 2, 10, 12)
    mv[:, 0] = 2.0  # previous position two pixels to the right
    torch.testing.assert_close(filters.warp(x, mv)[..., :-2], x[..., 2:], atol=1e-5, rtol=0)


@pytest.mark.parametrize("channels_last", [False, True])
def test_warp_gradient_equals_grid_samples(channels_last):
    # filters.warp's own input gradient (_WarpCPU) against autograd through grid_sample,
    # with motion far outside the frame, fractional, and on odd sizes
    g = torch.Generator().manual_seed(3)
    x = torch.rand(3, 5, 13, 17, generator=g)
    if channels_last:
        x = x.to(memory_format=torch.channels_last)
    x.requires_grad_()
    mv = torch.randn(3, 2, 13, 17, generator=g) * 4
    mv[0, :, :4] = 60.0
    mv[1, 0, 5:] = -35.5
    w = torch.randn(3, 5, 13, 17, generator=g)
    n, _, h, wd = x.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=x.dtype), torch.arange(wd, dtype=x.dtype), indexing="ij")
    grid = torch.stack([2 * (xs + 0.5 + mv[:, 0]) / wd - 1, 2 * (ys + 0.5 + mv[:, 1]) / h - 1], dim=-1)
    ref = torch.nn.functional.grid_sample(x, grid, mode="bicubic", padding_mode="border", align_corners=False)
    out = filters.warp(x, mv)
    torch.testing.assert_close(out, ref, rtol=0, atol=0)
    (want,) = torch.autograd.grad((ref * w).sum(), x)
    (got,) = torch.autograd.grad((out * w).sum(), x)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_tonemap_matches_eq1_and_clamps():
    x = torch.tensor([0.0, 1.0, 100.0, 1e6, -5.0])
    y = filters.tonemap(x)
    ref = np.log(np.array([0.0, 1.0, 100.0, 65535.0, 0.0]) + 1) ** (1 / 2.2)
    np.testing.assert_allclose(y.numpy(), ref, atol=1e-4)
    torch.testing.assert_close(
        filters.inverse_tonemap(filters.tonemap(torch.tensor([3.0, 40.0]))),
        torch.tensor([3.0, 40.0]),
        rtol=1e-4,
        atol=1e-4,
    )


def test_weight_fake_quant_round_trip():
    w = torch.randn(5, 4, 3, 3)
    q = quantize_weight(w)
    scale = w.abs().amax(dim=(1, 2, 3), keepdim=True) / 127
    levels = q / scale
    torch.testing.assert_close(levels, levels.round(), atol=1e-4, rtol=0)  # on the int8 grid
    assert levels.abs().max() <= 127 + 1e-4
    assert ((q - w).abs() <= scale / 2 + 1e-7).all()
    # per channel: the max |w| of each output channel is exactly representable
    torch.testing.assert_close(q.abs().amax(dim=(1, 2, 3)), w.abs().amax(dim=(1, 2, 3)))


def test_activation_fake_quant_round_trip_and_ste():
    aq = ActQuant()
    with torch.no_grad():
        aq.lo.fill_(-0.5)
        aq.hi.fill_(2.0)
    aq.enabled = True
    x = torch.linspace(-1, 3, 1001, requires_grad=True)
    y = aq(x)
    scale, zp = aq.qparams()
    # same as ONNX QuantizeLinear/DequantizeLinear with (scale, zero_point) as uint8
    q = np.clip(np.round(x.detach().numpy() / scale) + zp, 0, 255)
    np.testing.assert_allclose(y.detach().numpy(), (q - zp) * scale, atol=1e-6)
    inside = (x > -0.5 + scale) & (x < 2.0 - scale)
    assert ((y - x).abs()[inside] <= scale / 2 + 1e-6).all()
    y.sum().backward()  # straight-through: gradient 1 inside the range, 0 outside
    assert (x.grad[inside] == 1).all() and (x.grad[x < -0.6] == 0).all()
    assert aq.hi.grad is not None and aq.lo.grad is not None


def test_quantized_model_stays_close_to_float():
    cfg = ModelConfig.preset("tiny")
    model = JNDS(cfg)
    x, mv = _inputs(1, 16, 16)
    from jnds_deploy.model import set_observing

    set_observing(model, True)
    with torch.no_grad():
        ref = model(x, mv, None).output
    set_observing(model, False)
    set_quantization(model, True)
    with torch.no_grad():
        q = model(x, mv, None).output
    rel = (q - ref).abs().mean() / ref.abs().mean()
    assert 0 < rel < 0.05


def test_one_training_step_decreases_loss(tmp_path):
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.data import PatchSampler, load_sequence
    from jnds_deploy.training.losses import Loss
    from jnds_deploy.training.train import run_unroll

    from .conftest import SAMPLE

    torch.manual_seed(0)
    seq = load_sequence(SAMPLE)
    sampler = PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0))
    batch = sampler.batch(2)
    model = JNDS(ModelConfig.preset("tiny"))
    loss_fn = Loss(TrainConfig(), scale=2)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    losses = []
    for _ in range(4):
        loss, parts = loss_fn(run_unroll(model, batch), batch)
        assert set(parts) == {"diffuse", "specular", "auxiliary", "upsample"}
        losses.append(float(loss.detach()))
        opt.zero_grad()
        loss.backward()
        assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)
        opt.step()
    assert losses[-1] < losses[0], losses


def test_feature_loss_network_trains_and_scores(tmp_path):
    from jnds_deploy.training.feature_loss import FeatureNetConfig, load_feature_net, train_feature_net

    data = tmp_path / "data"
    (data / "train").mkdir(parents=True)
    from .conftest import SAMPLE

    (data / "train" / "sample").symlink_to(SAMPLE)
    path = train_feature_net(
        FeatureNetConfig(data=str(data), out=str(tmp_path / "f.pt"), steps=3, batch=2), progress=False
    )
    net = load_feature_net(path)
    a = torch.rand(1, 3, 32, 32)
    assert float(net.loss(a, a)) == 0.0
    assert float(net.loss(a, a + 0.1 * torch.randn_like(a))) > 0.0
    assert torch.isfinite(net.layer_weights).all() and (net.layer_weights > 0).all()


def test_feature_loss_network_reads_cleaned_references_when_asked(tmp_path):
    import shutil

    from jnds_deploy.training.feature_loss import _examples

    from .conftest import SAMPLE

    shutil.copytree(SAMPLE, tmp_path / "train" / "sample")  # a copy: cleaning caches beside the frames
    (x, y), (xc, yc) = _examples(str(tmp_path)), _examples(str(tmp_path), clean="oidn")
    np.testing.assert_array_equal(yc, y)  # the G-buffer targets are the inputs'
    assert xc.shape == x.shape and not np.array_equal(xc, x)  # the colour is the cleaned reference's


def test_training_resumes_from_an_init_checkpoint(tmp_path):
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.train import train

    from .conftest import SAMPLE

    data = _data_dir(tmp_path, SAMPLE)
    common = dict(
        data=str(data), preset="tiny", patch=32, unroll=3, batch=1, observe_batches=1, val_every=10**6, threads=1
    )
    first = train(TrainConfig(run=str(tmp_path / "a"), fp32_steps=2, qat_steps=1, **common), progress=False)
    a = torch.load(first, weights_only=False)
    assert a["quantized"] and a["quant_ranges"]
    assert a["train_sequences"] == [SAMPLE.name]
    from jnds_deploy.checkpoint import ship_checkpoint

    slim = torch.load(ship_checkpoint(first, tmp_path / "slim.pt"), weights_only=False)
    assert slim["train_sequences"] == [SAMPLE.name] and "optimizer" not in slim

    # no steps: the new run's checkpoint is the init's weights and ranges, in the QAT phase
    same = train(
        TrainConfig(run=str(tmp_path / "b"), fp32_steps=0, qat_steps=0, init=str(first), **common), progress=False
    )
    b = torch.load(same, weights_only=False)
    assert b["quantized"] and b["quant_ranges"] == a["quant_ranges"]
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])

    # the firefly clamp changes no weight: a checkpoint with one (as the shipped one) starts
    # a run with another, and each run records its own
    clamped = train(
        TrainConfig(run=str(tmp_path / "f"), fp32_steps=0, qat_steps=0, init=str(same), firefly_clamp=16.0, **common),
        progress=False,
    )
    assert torch.load(clamped, weights_only=False)["model_config"]["firefly_clamp"] == 16.0
    plain = train(
        TrainConfig(run=str(tmp_path / "g"), fp32_steps=0, qat_steps=0, init=str(clamped), **common), progress=False
    )
    assert torch.load(plain, weights_only=False)["model_config"]["firefly_clamp"] == 0.0

    # one QAT step (with burn-in frames) moves the weights a little, from the init's, not
    # from a fresh model
    tuned = torch.load(
        train(
            TrainConfig(
                run=str(tmp_path / "c"), fp32_steps=0, qat_steps=1, lr=1e-4, burn_in=2, init=str(first), **common
            ),
            progress=False,
        ),
        weights_only=False,
    )
    assert tuned["state"]["step"] == 1
    w = "network.output_block.head.weight"
    assert 0 < (tuned["model"][w] - a["model"][w]).abs().max() < 1e-2

    with pytest.raises(ValueError, match="is not preset"):
        train(TrainConfig(run=str(tmp_path / "d"), init=str(first), **{**common, "preset": "small"}), progress=False)

    # a fixed-kernel run from a predicting checkpoint: the same network outputs but the
    # features (dropped), the identity kernel, and a frame as the identity-kernel block gives it
    fixed = torch.load(
        train(
            TrainConfig(
                run=str(tmp_path / "e"), fp32_steps=0, qat_steps=0, init=str(first), fixed_upsample=True, **common
            ),
            progress=False,
        ),
        weights_only=False,
    )
    assert fixed["model_config"]["upsample_width"] == 0 and fixed["model_config"]["upsample_features"] == 0
    assert not any(k.startswith("upsample_block.") and k != "upsample_block.fixed" for k in fixed["model"])
    from jnds_deploy.checkpoint import load_model
    from jnds_deploy.model import ModelConfig

    pred, fix = load_model(first), load_model(tmp_path / "e" / "checkpoint.pt")
    x, h = torch.rand(1, 13, 32, 32), torch.rand(1, 12, 32, 32)
    with torch.no_grad():
        a_out, b_out = pred.network(x, h), fix.network(x, h)
        assert set(a_out) - set(b_out) == {"features"}
        assert all(torch.equal(a_out[k], b_out[k]) for k in b_out)
        comp = torch.rand(1, 3, 32, 32)
        k = fix.upsample_block(comp, None)
        assert k.shape == (1, 9, 1, 1) and torch.equal(k.flatten(), torch.eye(9)[4])
        assert torch.allclose(fix.upsample(comp, None), filters_upsampled(comp, ModelConfig(**fixed["model_config"])))


def test_init_with_the_other_input_block_fits_it_to_the_old_features(tmp_path):
    """--init from a checkpoint with the paper's input block into the space-to-depth one
    (ModelConfig.input_block): the rest of the network is the init's, the new block is fitted
    to the old block's native features (closer to them than before the fit, on a frame it
    was not fitted on), and in a QAT run its activation ranges are observed."""
    from jnds_deploy.checkpoint import load_model
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.train import train

    from .conftest import SAMPLE

    data = _data_dir(tmp_path, SAMPLE)
    common = dict(
        data=str(data), preset="tiny", patch=32, unroll=3, batch=1, observe_batches=1, val_every=10**6, threads=1
    )
    first = train(TrainConfig(run=str(tmp_path / "a"), fp32_steps=2, qat_steps=1, **common), progress=False)
    runs = {
        n: train(
            TrainConfig(
                run=str(tmp_path / n),
                fp32_steps=0,
                qat_steps=0,
                init=str(first),
                input_block="space_to_depth",
                input_hidden=8,
                input_fit_steps=steps,
                **common,
            ),
            progress=False,
        )
        for n, steps in (("fresh", 0), ("fitted", 200))
    }
    a, b = torch.load(first, weights_only=False), torch.load(runs["fitted"], weights_only=False)
    assert b["model_config"]["input_block"] == "space_to_depth" and b["quantized"]
    assert all(
        torch.equal(a["model"][k], b["model"][k]) for k in a["model"] if not k.startswith("network.input_block.")
    )
    assert all(r["hi"] > 1e-2 for k, r in b["quant_ranges"].items() if k.startswith("network.input_block."))
    from jnds_deploy.io import open_sequence
    from jnds_deploy.layout import CURRENT, HISTORY, channels

    old, fresh, fitted = load_model(first), load_model(runs["fresh"]), load_model(runs["fitted"])
    for m in (old, fresh, fitted):
        set_quantization(m, False)
    frame = open_sequence(SAMPLE).inputs(4)
    cur = torch.from_numpy(np.concatenate([frame[n] for n, _ in CURRENT], -1).transpose(2, 0, 1).copy())[None]
    hist = torch.cat([cur[:, channels(n)] for n, _ in HISTORY], 1)
    with torch.no_grad():
        want = old.network.input_block(cur, hist)[0]
        err = {
            n: (m.network.input_block(cur, hist)[0] - want).pow(2).mean().sqrt() / want.pow(2).mean().sqrt()
            for n, m in (("fresh", fresh), ("fitted", fitted))
        }
    assert err["fitted"] < 0.5 * err["fresh"]  # measured 0.57 against 1.86


@pytest.mark.parametrize(
    "fixed,narrow,wide",
    [(True, "small", "medium"), (False, "small", "medium"), (True, "medium", "large"), (True, "large", "wide")],
)
def test_init_widens_a_checkpoint_to_a_wider_preset_computing_the_same(fixed, narrow, wide):
    from jnds_deploy.training.surgery import widened, widens

    up = dict(upsample_width=0, upsample_features=0) if fixed else {}
    lo, hi = ModelConfig.preset(narrow, **up), ModelConfig.preset(wide, **up)
    assert widens(lo, hi) and not widens(hi, lo)
    assert not widens(lo, ModelConfig.preset(narrow, encoder_widths=(*lo.encoder_widths, 64), **up))  # deeper
    assert not widens(lo, ModelConfig.preset(narrow, filter_levels=2, **up))
    torch.manual_seed(0)
    old = JNDS(lo)
    for p in old.parameters():  # away from the identity initialization
        torch.nn.init.normal_(p, std=0.1)
    new = JNDS(hi)
    new.load_state_dict(widened(lo, old.state_dict(), new))
    # in float64 the zero-weight reads add exact zeros: the same outputs to rounding (in
    # float32 the wider sums round differently, by up to 1.5e-5 from large to wide)
    old, new = old.double(), new.double()
    x, mv = (t.double() for t in _inputs(1, 32, 48))
    h = torch.rand(1, 12, 32, 48, dtype=torch.float64)
    with torch.no_grad():
        a, b = old.network(x, h), new.network(x, h)
        assert a.keys() == b.keys()
        for k in a:
            assert torch.allclose(a[k], b[k], rtol=0, atol=1e-12), k
        assert torch.allclose(old(x, mv, None).output, new(x, mv, None).output, rtol=0, atol=1e-10)
        # the new channels are live: they compute features the old channels may learn to read
        assert new.network.feature_extractor.bottleneck.a.weight[lo.bottleneck_width :].abs().sum() > 0


def test_init_narrows_the_output_block_keeping_the_channels_that_matter():
    from jnds_deploy.training.surgery import narrowed, narrows

    up = dict(upsample_width=0, upsample_features=0)
    wide, narrow = ModelConfig.preset("large", **up), ModelConfig.preset("large", output_width=16, **up)
    assert narrows(wide, narrow) and not narrows(narrow, wide)
    assert not narrows(wide, ModelConfig.preset("medium", output_width=16, **up))  # other widths too
    torch.manual_seed(0)
    old = JNDS(wide)
    for p in old.parameters():
        torch.nn.init.normal_(p, std=0.1)
    conv = old.network.output_block.conv
    dead = torch.tensor([1, 4, 6, 11, 13, 17, 20, 23])  # 8 of 24 channels that ReLU silences
    with torch.no_grad():
        conv.weight[dead] = 0.0
        conv.bias[dead] = -1.0
    new = JNDS(narrow)
    new.load_state_dict(narrowed(wide, old.state_dict(), 16))
    x, mv = _inputs(1, 32, 48)
    h = torch.rand(1, 12, 32, 48)
    with torch.no_grad():
        a, b = old.network(x, h), new.network(x, h)
        for k in a:
            assert torch.allclose(a[k], b[k], atol=1e-5), k


@pytest.mark.parametrize("fixed", [True, False])
def test_init_deepens_a_checkpoint_by_one_unet_level_computing_nearly_the_same(fixed):
    from jnds_deploy.training import surgery

    up = dict(upsample_width=0, upsample_features=0) if fixed else {}
    lo = ModelConfig.preset("small", **up)
    hi = ModelConfig.preset("small", encoder_widths=(24, 32, 48), bottleneck_width=64, filter_levels=4, **up)
    assert surgery.deepens(lo, hi) and not surgery.deepens(hi, lo)
    assert not surgery.deepens(lo, replace(hi, filter_levels=3))  # the old coarsest level must go on
    assert not surgery.deepens(lo, replace(hi, encoder_widths=(24, 32, 40)))  # not the old bottleneck's width
    assert surgery.deepens(ModelConfig.preset("large"), ModelConfig.preset("deep"))
    torch.manual_seed(0)
    old = JNDS(lo)
    for p in old.parameters():  # away from the identity initialization
        torch.nn.init.normal_(p, std=0.1)
    x, mv = _inputs(1, 32, 48)
    h = torch.rand(1, 12, 32, 48)
    with torch.no_grad():
        a = old.network(x, h)
        # with the new level blended in at weight ~0 the mapping is exact: every old output as before
        exact = JNDS(hi)
        exact.load_state_dict(surgery.deepened(lo, old.state_dict(), exact, blend=-40.0))
        b = exact.network(x, h)
        assert set(b) - set(a) == {
            f"{p}.{n}" for p in ("diffuse", "specular") for n in ("level4.down", "level3.up", "level3.up_blend")
        }
        for k in a:
            assert torch.allclose(a[k], b[k], atol=1e-5), k
        assert torch.allclose(old(x, mv, None).output, exact(x, mv, None).output, atol=1e-4)
        # by default the new level enters with weight sigmoid(-4): close, and a live path to learn
        new = JNDS(hi)
        new.load_state_dict(surgery.deepened(lo, old.state_dict(), new))
        c = new.network(x, h)
        for k in a:
            assert torch.allclose(a[k], c[k], atol=1e-5), k
        blend = c["diffuse.level3.up_blend"]
        assert 0.005 < blend.min() and blend.max() < 0.05
        # --deepen-blend -2: further in (sigmoid(-2) = 0.12), the other outputs unchanged
        further = JNDS(hi)
        further.load_state_dict(surgery.deepened(lo, old.state_dict(), further, blend=-2.0))
        d = further.network(x, h)
        assert 0.08 < d["specular.level3.up_blend"].min() and d["specular.level3.up_blend"].max() < 0.16
        for k in a:
            if not k.endswith("up_blend"):
                assert torch.allclose(c[k], d[k]), k
        assert new.network.feature_extractor.bottleneck.a.weight.abs().sum() > 0


def test_evaluate_names_training_checkpoints_by_run_and_scores_them(tmp_path):
    from jnds_deploy.training.evaluate import method_name, run_evaluation

    from .conftest import SAMPLE

    assert method_name("runs/ft-l1/checkpoint.pt") == "ft-l1"
    assert method_name("jnds_deploy/checkpoints/jnds.pt") == "jnds"
    torch.manual_seed(0)
    model = JNDS(ModelConfig.preset("tiny"))
    ckpt = tmp_path / "runs" / "tiny-a" / "checkpoint.pt"
    ckpt.parent.mkdir(parents=True)
    torch.save({"model": model.state_dict(), "model_config": asdict(model.cfg), "quantized": False}, ckpt)
    report = run_evaluation([str(ckpt)], str(SAMPLE), ["bicubic"], str(tmp_path / "eval.json"), threads=1)
    assert list(report) == ["tiny-a", "bicubic"]
    for r in report.values():
        assert set(r["mean"]) == {"psnr", "ssim", "flip", "temporal", "changed_psnr", "changed_fraction"}
        assert np.isfinite(list(r["mean"].values())).all() and 0 < r["mean"]["changed_fraction"] < 0.5
        assert list(r["sequences"]) == [SAMPLE.name]
    assert json.loads((tmp_path / "eval.json").read_text()) == report


def test_channels_last_training_step_equals_the_contiguous_one(tmp_path):
    """jnds train's NHWC memory layout and its one-pass L1 change speed, not values: the
    loss and every gradient of a step (L1 + feature loss) match NCHW with autograd's
    abs().mean()."""
    import copy

    from jnds_deploy.training import feature_loss
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.data import PatchSampler, load_sequence
    from jnds_deploy.training.losses import Loss
    from jnds_deploy.training.train import run_unroll

    from .conftest import SAMPLE

    torch.manual_seed(0)
    feat = str(tmp_path / "feature_net.pt")
    torch.save({"model": feature_loss.FeatureNet().state_dict(), "widths": (16, 32, 64)}, feat)
    batch = PatchSampler([load_sequence(SAMPLE)], patch=32, unroll=3, rng=np.random.default_rng(0)).batch(2)
    model = JNDS(ModelConfig.preset("tiny"))
    cfg = TrainConfig(spatial_loss="l1+feature", feature_net=feat)
    results = []
    # one thread: with two, the layouts' reductions split differently across threads and a
    # few bias gradients differ by 2e-5 (alone it failed, after the suite's 1-thread
    # training tests it passed)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for layout, l1 in (
            (torch.contiguous_format, lambda a, b: (a - b).abs().mean()),
            (torch.channels_last, feature_loss.l1),
        ):
            m, loss_fn = copy.deepcopy(model).to(memory_format=layout), Loss(cfg, scale=2).to(memory_format=layout)
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr("jnds_deploy.training.losses.l1", l1)
                mp.setattr("jnds_deploy.training.feature_loss.l1", l1)
                loss, _ = loss_fn(run_unroll(m, batch), batch)
                loss.backward()
            results.append((loss.detach(), {n: p.grad for n, p in m.named_parameters() if p.grad is not None}))
    finally:
        torch.set_num_threads(threads)
    (loss_a, grads_a), (loss_b, grads_b) = results
    torch.testing.assert_close(loss_b, loss_a, rtol=1e-5, atol=1e-6)
    assert grads_a.keys() == grads_b.keys() and grads_a
    for n in grads_a:
        torch.testing.assert_close(grads_b[n], grads_a[n], rtol=1e-3, atol=1e-5, msg=n)


def test_l1_plus_feature_spatial_loss_is_the_sum_of_both(tmp_path):
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.feature_loss import FeatureNet
    from jnds_deploy.training.losses import Loss

    torch.manual_seed(0)  # a feature-loss network with random weights: training runs are not in git
    net = FeatureNet()
    feat = str(tmp_path / "feature_net.pt")
    torch.save({"model": net.state_dict(), "widths": (16, 32, 64)}, feat)
    o, r = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
    parts = {
        k: Loss(TrainConfig(spatial_loss=k, feature_net=None if k == "l1" else feat), scale=2).spatial(o, r)
        for k in ("l1", "feature", "l1+feature")
    }
    assert float(parts["l1"]) > 0 and float(parts["feature"]) > 0
    torch.testing.assert_close(parts["l1+feature"], parts["l1"] + parts["feature"])
    with pytest.raises(ValueError, match="needs feature_net"):
        TrainConfig(spatial_loss="l1+feature")
    with pytest.raises(ValueError, match="spatial_loss must be one of"):
        TrainConfig(spatial_loss="l2")


def test_lowfreq_loss_sees_a_level_shift_more_than_noise():
    """The low-frequency term: zero-mean pixel noise of the reference mostly averages out of
    it, a level shift of the same per-pixel L1 does not; native tasks box in native pixels."""
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.losses import LOWFREQ_SCALES, lowfreq

    torch.manual_seed(0)
    o = torch.rand(2, 3, 32, 32)
    noisy = o + 0.1 * torch.sign(torch.randn_like(o))  # per-pixel L1 0.1
    shifted = o + 0.1  # per-pixel L1 0.1
    assert float(lowfreq(o, shifted, 1)) == pytest.approx(0.1 * len(LOWFREQ_SCALES), rel=1e-4)
    assert float(lowfreq(o, noisy, 1)) < 0.25 * float(lowfreq(o, shifted, 1))
    # a native-resolution task (2 target pixels a pixel) boxes 2, 4 and 8 of its pixels
    pool = torch.nn.functional.avg_pool2d
    expected = sum(float((pool(o, k) - pool(noisy, k)).abs().mean()) for k in (2, 4, 8))
    assert float(lowfreq(o, noisy, 2)) == pytest.approx(expected, rel=1e-5)
    # a box larger than the patch is left out
    assert float(lowfreq(o[..., :8, :8], shifted[..., :8, :8], 1)) == pytest.approx(0.2, rel=1e-4)
    with pytest.raises(ValueError, match="lowfreq_loss must be >= 0"):
        TrainConfig(lowfreq_loss=-1)


def test_checkpoints_hold_host_tensors_and_load_on_the_cpu(tmp_path):
    """A run trained on a GPU must load where no GPU is: weights are saved on the host."""
    from jnds_deploy.checkpoint import load_model
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.train import train

    from .conftest import SAMPLE

    data = _data_dir(tmp_path, SAMPLE)
    ckpt = train(
        TrainConfig(
            data=str(data),
            run=str(tmp_path / "r"),
            preset="tiny",
            patch=32,
            unroll=2,
            batch=1,
            fp32_steps=1,
            qat_steps=0,
            val_every=10**6,
            threads=1,
            device="cpu",
        ),
        progress=False,
    )
    saved = torch.load(ckpt, weights_only=False)
    assert all(v.device.type == "cpu" for v in saved["model"].values())
    assert all(v.device.type == "cpu" for st in saved["optimizer"]["state"].values() for v in st.values())
    assert load_model(ckpt).cfg == ModelConfig.preset("tiny")


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error where no GPU is")
def test_train_on_a_missing_gpu_is_a_one_line_error(tmp_path):
    from jnds_deploy.cli import main

    rc = main(["train", "--data", str(tmp_path), "--run", str(tmp_path / "r"), "--device", "cuda", "--quiet"])
    assert rc == 2 and not (tmp_path / "r").exists()


def test_evaluate_reports_sets_side_by_side_with_a_contact_sheet(tmp_path, make_sequence):
    import cv2

    from jnds_deploy.training.evaluate import evaluate_sets, markdown_sets

    from .conftest import SAMPLE

    torch.manual_seed(0)
    model = JNDS(ModelConfig.preset("tiny"))
    ckpt = tmp_path / "tiny.pt"
    torch.save({"model": model.state_dict(), "model_config": asdict(model.cfg), "quantized": False}, ckpt)
    other, _, _ = make_sequence(frames=3, size=(16, 12), name="test-set/seq-a")
    reports = evaluate_sets(
        [str(ckpt)],
        [str(SAMPLE), str(other.parent)],
        ["bicubic"],
        str(tmp_path / "e.json"),
        threads=1,
        sheet=str(tmp_path / "sheet.png"),
    )
    assert list(reports) == [SAMPLE.name, "test-set"]
    assert list(reports["test-set"]["tiny"]["sequences"]) == ["seq-a"]
    assert json.loads((tmp_path / "e.json").read_text()) == reports
    text = markdown_sets(reports)
    assert "### test-set (1 sequences)" in text and "| seq-a | " in text
    sheet = cv2.imread(str(tmp_path / "sheet.png"))
    assert sheet.shape[0] == 2 * (180 + 14) and sheet.shape[1] == 4 * 320 + 3 * 2  # input, tiny, bicubic, reference
    assert (tmp_path / "sheet.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_contact_sheet_format_follows_its_name(tmp_path):
    """A sheet named .jpg is a JPEG (it was a PNG under that name), anything else a PNG."""
    from jnds_deploy import contact_sheet

    img = np.random.default_rng(0).random((12, 16, 3), dtype=np.float32)
    row = [("seq", {"input": img, "reference": img})]
    assert contact_sheet.write(tmp_path / "s.jpg", row).read_bytes()[:3] == b"\xff\xd8\xff"
    assert contact_sheet.write(tmp_path / "s.png", row).read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.jpg", "s.png"]  # no temporary left


def test_augmentations_keep_what_must_hold():
    """Exposure scales inputs and references alike; the rotation keeps unit normals unit and
    turns them all by one rotation; a mirror flips the patch and negates the motion across it."""
    from jnds_deploy.layout import channels
    from jnds_deploy.training.data import Augment, random_rotation

    rng = np.random.default_rng(0)
    T, p = 3, 8
    n = rng.normal(size=(T, 3, p, p)).astype(np.float32)
    current = rng.random((T, 13, p, p)).astype(np.float32)
    current[:, channels("normal")] = n / np.linalg.norm(n, axis=1, keepdims=True)
    sample = {
        "current": current,
        "motion": rng.normal(size=(T, 2, p, p)).astype(np.float32),
        **{c: rng.random((T, 3, 2 * p, 2 * p)).astype(np.float32) for c in ("color", "diffuse", "specular", "albedo")},
    }
    before = {k: v.copy() for k, v in sample.items()}

    gains = set()
    for s in range(12):  # half the samples keep their exposure, the others get x 2^3
        out = Augment(exposure=(3.0, 3.0))(sample, np.random.default_rng(s))
        gain = float(np.median(out["color"] / sample["color"]))
        assert gain in (1.0, 8.0)
        gains.add(gain)
        for c in ("color", "diffuse", "specular"):
            np.testing.assert_allclose(out[c], gain * sample[c], rtol=1e-6)
        for name in ("diffuse", "specular"):
            np.testing.assert_allclose(
                out["current"][:, channels(name)], gain * sample["current"][:, channels(name)], rtol=1e-6
            )
        for name in ("albedo", "normal", "roughness"):
            np.testing.assert_array_equal(out["current"][:, channels(name)], sample["current"][:, channels(name)])
        np.testing.assert_array_equal(out["albedo"], sample["albedo"])
    assert gains == {1.0, 8.0}

    out = Augment(rotate_normals=True)(sample, np.random.default_rng(5))
    r = random_rotation(np.random.default_rng(5))
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-6)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-5)
    rotated = out["current"][:, channels("normal")]
    np.testing.assert_allclose(np.linalg.norm(rotated, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(
        rotated, np.einsum("ij,tjhw->tihw", r, sample["current"][:, channels("normal")]), atol=1e-6
    )

    def mirrored(a, fx, fy, motion=False):
        a = a.copy()
        for axis, comp, flipped in ((-1, 0, fx), (-2, 1, fy)):
            if flipped:
                a = np.flip(a, axis).copy()
                if motion:
                    a[:, comp] *= -1
        return a

    seen = set()
    for s in range(16):
        out = Augment(flips=True)(sample, np.random.default_rng(s))
        match = [
            (fx, fy)
            for fx in (False, True)
            for fy in (False, True)
            if np.array_equal(out["motion"], mirrored(sample["motion"], fx, fy, motion=True))
        ]
        assert len(match) == 1
        seen.add(match[0])
        for k in ("current", "color", "diffuse", "specular", "albedo"):
            np.testing.assert_array_equal(out[k], mirrored(sample[k], *match[0]))
    assert seen == {(False, False), (True, False), (False, True), (True, True)}

    tinted = 0
    for s in range(12):  # half the samples keep their colours
        out = Augment(colours=True)(sample, np.random.default_rng(s))
        if all(np.array_equal(out[k], sample[k]) for k in sample):
            continue
        tinted += 1
        albedo = sample["current"][:, channels("albedo")]
        # the permutation: the channel of the original albedo each output channel holds
        perm = [
            next(j for j in range(3) if np.array_equal(out["current"][:, channels("albedo")][:, i], albedo[:, j]))
            for i in range(3)
        ]
        np.testing.assert_array_equal(out["albedo"], sample["albedo"][:, perm])
        tint = out["diffuse"][:, :, :1, :1] / sample["diffuse"][:, perm][:, :, :1, :1]
        assert np.all((2**-0.5 - 1e-6 <= tint) & (tint <= 2**0.5 + 1e-6))
        for c in ("color", "diffuse", "specular"):  # one tint per channel, inputs and reference alike
            np.testing.assert_allclose(out[c], sample[c][:, perm] * tint[:1], rtol=1e-5)
        for name in ("diffuse", "specular"):
            np.testing.assert_allclose(
                out["current"][:, channels(name)], sample["current"][:, channels(name)][:, perm] * tint[:1], rtol=1e-5
            )
        # colour = albedo x diffuse + specular still holds after the augmentation
        np.testing.assert_allclose(
            out["albedo"] * out["diffuse"] + out["specular"],
            (sample["albedo"] * sample["diffuse"] + sample["specular"])[:, perm] * tint[:1],
            rtol=1e-5,
        )
        for name in ("normal", "roughness"):
            np.testing.assert_array_equal(out["current"][:, channels(name)], sample["current"][:, channels(name)])
        np.testing.assert_array_equal(out["motion"], sample["motion"])
    assert 0 < tinted < 12
    for k in sample:  # the sequence's arrays are never written
        np.testing.assert_array_equal(sample[k], before[k])


def test_warmup_raises_the_learning_rate_linearly_in_the_fp32_phase_only():
    from jnds_deploy.errors import ConfigError
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.train import TrainState, _lr

    cfg = TrainConfig(data="d", run="r", fp32_steps=100, qat_steps=10, lr=1e-3, qat_lr=1e-4, warmup_steps=10)
    plain = TrainConfig(data="d", run="r", fp32_steps=100, qat_steps=10, lr=1e-3, qat_lr=1e-4)
    assert _lr(cfg, TrainState(step=0)) == pytest.approx(0.1 * _lr(plain, TrainState(step=0)))
    assert _lr(cfg, TrainState(step=4)) == pytest.approx(0.5 * _lr(plain, TrainState(step=4)))
    for step in (9, 50):
        assert _lr(cfg, TrainState(step=step)) == _lr(plain, TrainState(step=step))
    assert _lr(cfg, TrainState(step=100, phase="qat")) == _lr(plain, TrainState(step=100, phase="qat")) == 1e-4
    with pytest.raises(ConfigError, match="warmup_steps"):
        TrainConfig(data="d", run="r", fp32_steps=5, warmup_steps=6)


def test_sampler_without_augmentation_draws_what_it_drew_before(tmp_path):
    from jnds_deploy.training.data import Augment, PatchSampler, load_sequence

    from .conftest import SAMPLE

    seq = load_sequence(SAMPLE)
    a = PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0)).batch(2)
    b = PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0), augment=Augment()).batch(2)
    assert all(torch.equal(a[k], b[k]) for k in a)
    c = PatchSampler(
        [seq],
        patch=32,
        unroll=3,
        rng=np.random.default_rng(0),
        augment=Augment(exposure=(-4, 8), rotate_normals=True, flips=True, colours=True),
    ).batch(2)
    assert all(torch.isfinite(v).all() for v in c.values())
    assert not torch.equal(a["current"], c["current"])


def test_balanced_renderers_are_drawn_equally_often():
    from dataclasses import replace

    from jnds_deploy.training.data import PatchSampler, load_sequence

    from .conftest import SAMPLE

    seq = load_sequence(SAMPLE)
    assert seq.renderer == "mitsuba"  # the sample's render.json
    seqs = [replace(seq, name=f"m{i}") for i in range(3)] + [replace(seq, name="c", renderer="cycles")]
    drawn = []
    for balance in (False, True):
        s = PatchSampler(seqs, patch=16, unroll=3, rng=np.random.default_rng(0), balance_renderers=balance)
        picks = [s.window()[0] for _ in range(4000)]
        drawn.append(np.mean([seqs[i].renderer == "cycles" for i in picks]))
    assert abs(drawn[0] - 0.25) < 0.03 and abs(drawn[1] - 0.5) < 0.03
    # the batch itself draws from the same weights
    s = PatchSampler(seqs, patch=16, unroll=3, rng=np.random.default_rng(0), balance_renderers=True)
    assert s.batch(2)["current"].shape[:2] == (3, 2)


def test_clean_references_denoise_recompose_and_cache(tmp_path, monkeypatch):
    import os
    import shutil

    import pyoidn

    from jnds_deploy.training.data import CLEAN_CACHE, load_sequence

    from .conftest import SAMPLE

    path = tmp_path / "seq"
    shutil.copytree(SAMPLE, path)
    raw, clean = load_sequence(path), load_sequence(path, clean="oidn")
    np.testing.assert_array_equal(clean.ref["albedo"], raw.ref["albedo"])
    np.testing.assert_allclose(
        clean.ref["color"], raw.ref["albedo"] * clean.ref["diffuse"] + clean.ref["specular"], rtol=1e-6
    )
    for c in ("diffuse", "specular", "color"):
        assert clean.ref[c].shape == raw.ref[c].shape and clean.ref[c].dtype == np.float32
        assert np.isfinite(clean.ref[c]).all() and clean.ref[c].min() >= 0

    def grain(x):  # mean |x - its 3x3 box mean|: the noise a denoiser removes
        return float(np.abs(x - torch.nn.functional.avg_pool2d(torch.from_numpy(x), 3, 1, 1).numpy()).mean())

    assert grain(clean.ref["color"]) < 0.9 * grain(raw.ref["color"])  # 0.76 with OIDN 2.3
    assert abs(clean.ref["diffuse"].mean() / raw.ref["diffuse"].mean() - 1) < 0.05  # the level kept
    # a second load reads the cache, without OIDN; a newer reference frame invalidates it
    assert (path / CLEAN_CACHE).is_file()
    calls = []
    real = pyoidn.denoise
    monkeypatch.setattr(pyoidn, "denoise", lambda *a, **k: calls.append(1) or real(*a, **k))
    again = load_sequence(path, clean="oidn")
    assert not calls and all(np.array_equal(again.ref[k], clean.ref[k]) for k in clean.ref)
    t = (path / CLEAN_CACHE).stat().st_mtime
    os.utime(path / "reference" / "0000.exr", (t + 10, t + 10))
    load_sequence(path, clean="oidn")
    assert len(calls) == 2 * len(raw.cuts)  # diffuse and specular of every frame
    (path / CLEAN_CACHE).write_bytes(b"not a cache")  # unreadable: made again, not an error
    again = load_sequence(path, clean="oidn")
    assert len(calls) == 4 * len(raw.cuts) and np.array_equal(again.ref["color"], clean.ref["color"])
    with pytest.raises(Exception, match="unknown method"):
        load_sequence(path, clean="median")


def test_recomposed_reference_batches_equal_a_held_colour(tmp_path):
    """A cleaned reference computes its colour per window (``Recomposed``, a quarter less
    memory): the batches, augmented, are bit-equal to those of the same reference with the
    colour held as one array."""
    from dataclasses import replace

    from jnds_deploy.training.data import Augment, PatchSampler, Recomposed, load_sequence

    from .conftest import SAMPLE

    raw = load_sequence(SAMPLE)
    lazy = replace(raw, ref=Recomposed(raw.ref["albedo"], raw.ref["diffuse"], raw.ref["specular"]))
    held = replace(raw, ref={**lazy.ref})  # the colour computed once, whole
    assert set(held.ref) == set(raw.ref) and "color" in lazy.ref and "depth" not in lazy.ref
    assert lazy.scale == raw.scale == 2
    np.testing.assert_array_equal(held.ref["color"], raw.ref["albedo"] * raw.ref["diffuse"] + raw.ref["specular"])
    aug = Augment(exposure=(-4, 8), rotate_normals=True, flips=True, colours=True)
    a, b = (
        PatchSampler([s], patch=32, unroll=3, rng=np.random.default_rng(5), augment=aug).batch(4, burn_in=1)
        for s in (lazy, held)
    )
    assert a.keys() == b.keys() and "color" in a
    for k in a:
        assert torch.equal(a[k], b[k]), k


def filters_upsampled(comp, cfg):
    """The upsample filter's bilinear upsampling alone (root ``cfg.upsample_root``)."""
    from jnds_deploy import filter_spec as filters

    r = cfg.upsample_root
    return filters.upsample(comp.clamp_min(filters.ROOT_FLOOR).pow(1 / r), cfg.scale).pow(r).clamp_min(0)


def test_windows_across_a_cut_restart_the_history_there():
    from jnds_deploy.training.data import PatchSampler, load_sequence
    from jnds_deploy.training.train import run_unroll

    from .conftest import SAMPLE

    seq = load_sequence(SAMPLE)
    seq.cuts = [t == 4 for t in range(len(seq.cuts))]  # a camera cut at frame 4 of 8
    kept = PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0))
    assert [t for _, t in kept.windows] == [0, 1, 4, 5]
    assert not kept.batch(4)["cut"].any()
    crossing = PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0), cross_cuts=True)
    assert [t for _, t in crossing.windows] == [0, 1, 2, 3, 4, 5]
    crossing.windows = [(0, 2), (0, 3)]  # frames 2-4 and 3-5: the cut is their third, second frame
    batch = crossing.batch(8)
    cols = batch["cut"].T.tolist()  # samples drawn at random from the two windows
    assert {tuple(c) for c in cols} == {(False, False, True), (False, True, False)}
    a, b = cols.index([False, False, True]), cols.index([False, True, False])
    torch.manual_seed(0)
    model = JNDS(ModelConfig.preset("tiny")).eval()
    with torch.no_grad():
        outs = run_unroll(model, batch)
        # the frame at the cut is a first frame: the same as with no history at all; the
        # other sample in the batch keeps its history
        for t, n in ((2, a), (1, b)):
            fresh = model(batch["current"][t, n : n + 1], batch["motion"][t, n : n + 1], None)
            assert torch.allclose(outs[t].output[n : n + 1], fresh.output, atol=1e-6)
        carried = model(batch["current"][2, b : b + 1], batch["motion"][2, b : b + 1], outs[1].history()[b : b + 1])
        assert torch.allclose(outs[2].output[b : b + 1], carried.output, atol=1e-6)
        assert not torch.allclose(
            outs[2].output[a : a + 1],
            model(batch["current"][2, a : a + 1], batch["motion"][2, a : a + 1], outs[1].history()[a : a + 1]).output,
            atol=1e-6,
        )


def test_burn_in_frames_build_the_history_without_gradients():
    from jnds_deploy.training.data import PatchSampler, load_sequence
    from jnds_deploy.training.train import after_burn_in, run_unroll

    from .conftest import SAMPLE

    seq = load_sequence(SAMPLE)
    sampler = PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0))
    sampler.windows = [(0, 1)]  # frames 1-3, and before them frame 0, then frame 0 repeated
    batch = sampler.batch(1, burn_in=3)
    cur = batch["current"][:, 0]
    assert cur.shape[0] == 6  # frames 0, 0, 0, 1, 2, 3
    assert torch.equal(cur[0], cur[1]) and torch.equal(cur[1], cur[2]) and not torch.equal(cur[2], cur[3])
    # the history restarts at every copy of frame 0, so the last one runs as a first frame
    assert batch["cut"][:, 0].tolist() == [False, True, True, False, False, False]
    torch.manual_seed(0)
    model = JNDS(ModelConfig.preset("tiny"))
    outs = run_unroll(model, batch, burn_in=3)
    assert len(outs) == 3 and outs[0].output.requires_grad
    with torch.no_grad():  # the same as running every frame and keeping the last three
        full = run_unroll(model, batch)
        fresh = run_unroll(model, after_burn_in(batch, 2), burn_in=1)  # frame 0 once, as a first frame
    for a, b, c in zip(outs, full[3:], fresh):
        assert torch.allclose(a.output, b.output, atol=1e-6) and torch.allclose(a.output, c.output, atol=1e-6)
    loss_batch = after_burn_in(batch, 3)
    assert loss_batch["color"].shape[0] == 3 and not loss_batch["cut"].any()
    # without burn-in the batch is what it was: the window's frames, no cut
    plain = PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0))
    plain.windows = [(0, 1)]
    assert plain.batch(1)["current"].shape[0] == 3


@pytest.mark.parametrize("k", [0.5, -1.0])
def test_firefly_clamp_below_one_is_refused(k):
    from jnds_deploy.errors import ConfigError
    from jnds_deploy.runtime import PipelineConfig

    with pytest.raises(ConfigError, match="firefly_clamp"):
        ModelConfig(firefly_clamp=k)
    with pytest.raises(ConfigError, match="firefly_clamp"):
        PipelineConfig(artifacts="a", firefly_clamp=k)


def test_fill_diffuse_holes():
    """A sample that hit no diffuse surface (albedo 0, not background) gets its diffuse
    neighbours' binomial-weighted mean; background, diffuse samples and holes with too
    little diffuse around them keep their value, and so does the pixel's composite."""
    h, w = 9, 12
    diffuse = torch.full((1, 3, h, w), 2.0)
    diffuse[:, :, :, 6:] = 4.0
    albedo = torch.full((1, 3, h, w), 0.5)
    normal = torch.zeros(1, 3, h, w)
    normal[:, 2] = 1.0
    hole = torch.zeros(h, w, dtype=torch.bool)
    hole[4, 5] = True  # one hole: 2.0 on its left, 4.0 from its right neighbour on
    hole[0:9, 9:12] = True  # a wide metal strip: its inner column has no diffuse within reach
    hole[0, 0] = True  # a corner: the frame's border carries no weight
    albedo[:, :, hole] = 0.0
    diffuse[:, :, hole] = 0.0  # what the renderer writes there
    normal[:, :, 8, 0] = 0.0  # background with albedo 0: not a hole
    albedo[:, :, 8, 0] = 0.0
    out = filters.fill_diffuse_holes(diffuse, albedo, normal)
    taps = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0]) / 16
    k = taps[:, None] * taps[None, :]  # rows 2..6, columns 3..7 around (4, 5)
    values = diffuse[0, 0, 2:7, 3:8]
    valid = ~hole[2:7, 3:8]
    want = (k * values * valid).sum() / (k * valid).sum()
    assert out[0, :, 4, 5].tolist() == pytest.approx([float(want)] * 3, rel=1e-6)
    assert 2.0 < float(want) < 4.0
    assert out[0, 0, 0, 0] == pytest.approx(2.0)  # all its in-frame diffuse neighbours are 2.0
    assert torch.all(out[0, :, :, 11] == 0)  # no diffuse sample within two columns
    assert torch.all(out[0, :, :, 10] == 0)  # one two columns away: weight 1/16, below the minimum
    assert torch.all(out[0, :, :, 9] > 0)  # the strip's edge column: weight 5/16
    assert out[0, 0, 8, 0] == diffuse[0, 0, 8, 0]  # background untouched
    keep = ~hole
    assert torch.equal(out[:, :, keep], diffuse[:, :, keep])
    # the composite of a filled pixel is the same: its albedo is 0
    assert torch.equal(
        filters.composite(albedo, out, torch.zeros_like(out))[:, :, hole], torch.zeros(1, 3, int(hole.sum()))
    )


def test_distillation_trains_only_the_named_block_on_inputs_only_toward_its_teacher(tmp_path, make_sequence):
    from jnds_deploy.checkpoint import load_model
    from jnds_deploy.errors import ConfigError, TrainError
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.data import Augment, PatchSampler, load_sequence
    from jnds_deploy.training.losses import Loss
    from jnds_deploy.training.train import run_unroll, train

    from .conftest import SAMPLE

    data = tmp_path / "data"
    (data / "train").mkdir(parents=True)
    (data / "train" / "sample").symlink_to(SAMPLE)
    common = dict(
        preset="tiny",
        patch=32,
        unroll=3,
        batch=1,
        observe_batches=1,
        val_every=10**6,
        threads=1,
        fixed_upsample=True,
        cross_cuts=True,
    )
    teacher = train(
        TrainConfig(data=str(data), run=str(tmp_path / "t"), fp32_steps=2, qat_steps=1, lr=1e-2, **common),
        progress=False,
    )

    # inputs only: no reference component, which a run against references refuses
    path, _, _ = make_sequence(frames=4, size=(32, 32), reference=False, name="inputs")
    seq = load_sequence(path)
    assert seq.ref == {}
    with pytest.raises(TrainError, match="reference has no"):
        PatchSampler([seq], patch=32, unroll=3, rng=np.random.default_rng(0), cross_cuts=True)
    aug = Augment(exposure=(-4, 8), rotate_normals=True, flips=True, colours=True)
    batch = PatchSampler(
        [seq], patch=32, unroll=3, rng=np.random.default_rng(0), augment=aug, cross_cuts=True, references=False
    ).batch(2)
    assert set(batch) == {"current", "motion", "cut"}

    # a student equal to its teacher is at zero loss; one cut to fewer output-block channels is
    # not, and distilling brings it closer
    cfg = TrainConfig(**common)
    loss_fn, t_model = Loss(cfg, 2), load_model(teacher)
    with torch.no_grad():
        targets = Loss.teacher_targets(run_unroll(t_model, batch))
        assert float(loss_fn(run_unroll(t_model, batch), batch, targets)[0]) == 0.0
    dist = tmp_path / "distill"
    (dist / "train").mkdir(parents=True)
    (dist / "train" / "inputs").symlink_to(path)
    args = dict(
        data=str(dist),
        fp32_steps=0,
        init=str(teacher),
        teacher=str(teacher),
        output_width=2,
        train_only=("network.output_block",),
        **common,
    )
    cut = load_model(train(TrainConfig(run=str(tmp_path / "cut"), qat_steps=0, **args), progress=False))
    student = torch.load(
        train(TrainConfig(run=str(tmp_path / "s"), qat_steps=2, qat_lr=1e-3, **args), progress=False),
        weights_only=False,
    )
    assert student["quantized"] and student["model_config"]["output_width"] == 2
    moved = {k for k, v in cut.state_dict().items() if not torch.equal(v, student["model"][k])}
    assert moved and all(k.startswith("network.output_block.") for k in moved), moved
    opt = torch.optim.Adam(cut.network.output_block.parameters(), lr=1e-4)
    losses = []
    for _ in range(4):
        loss = loss_fn(run_unroll(cut, batch), batch, targets)[0]
        losses.append(float(loss.detach()))
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert 0 < losses[-1] < losses[0], losses

    # the student must run as its teacher does (fill, clamp, albedo at holes, upsample root)
    with pytest.raises(ConfigError, match="firefly_clamp"):
        train(TrainConfig(run=str(tmp_path / "x"), qat_steps=1, firefly_clamp=16.0, **args), progress=False)
    with pytest.raises(ConfigError, match="no parameter"):
        train(
            TrainConfig(run=str(tmp_path / "y"), qat_steps=1, **{**args, "train_only": ("network.nothing",)}),
            progress=False,
        )


def test_the_guide_albedo_input_starts_at_zero_from_a_checkpoint_without_it_and_trains(tmp_path, guided_sample):
    """``--guide-albedo --init`` a checkpoint without the input: the projection reads the
    guide with zero weights (the same outputs), the batches carry the guide (the albedo for a
    sequence without the layer) through the augmentations as an albedo, and a step trains
    the new weights."""
    from jnds_deploy.checkpoint import load_model
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.data import Augment, PatchSampler, load_sequence
    from jnds_deploy.training.evaluate import infer_sequence
    from jnds_deploy.training.surgery import GUIDED
    from jnds_deploy.training.train import train

    from .conftest import SAMPLE

    data = _data_dir(tmp_path, guided_sample)
    common = dict(
        data=str(data), preset="tiny", patch=32, unroll=3, batch=1, observe_batches=1, val_every=10**6, threads=1
    )
    first = train(TrainConfig(run=str(tmp_path / "a"), fp32_steps=1, qat_steps=1, **common), progress=False)
    guided = train(
        TrainConfig(run=str(tmp_path / "b"), fp32_steps=0, qat_steps=0, init=str(first), guide_albedo=True, **common),
        progress=False,
    )
    a, b = (torch.load(p, weights_only=False) for p in (first, guided))
    assert b["model_config"]["guide_albedo"] and b["quantized"]
    assert b["model"][GUIDED].shape[1] == a["model"][GUIDED].shape[1] + 3
    assert not b["model"][GUIDED][:, 25:].any() and torch.equal(b["model"][GUIDED][:, :25], a["model"][GUIDED])
    seq = load_sequence(guided_sample)
    assert seq.guide is not None and load_sequence(SAMPLE).guide is None
    for x, y in zip(infer_sequence(load_model(first), seq)[:2], infer_sequence(load_model(guided), seq)[:2]):
        np.testing.assert_allclose(x, y, atol=1e-5)

    # the guide is 1 - albedo in this sequence: so it stays through flips and colour permutations
    rng = np.random.default_rng(0)
    sampler = PatchSampler([seq], 32, 3, rng, Augment((-1.0, 1.0), True, True, True), guide=True)
    for _ in range(4):
        batch = sampler.batch(2)
        torch.testing.assert_close(batch["guide"], 1 - batch["current"][:, :, 6:9], atol=2e-3, rtol=0)
    plain = PatchSampler([load_sequence(SAMPLE)], 32, 3, rng, guide=True).batch(1)
    assert torch.equal(plain["guide"], plain["current"][:, :, 6:9])
    assert "guide" not in PatchSampler([seq], 32, 3, rng).batch(1)

    tuned = torch.load(
        train(
            TrainConfig(
                run=str(tmp_path / "c"),
                fp32_steps=0,
                qat_steps=1,
                lr=1e-3,
                init=str(guided),
                guide_albedo=True,
                **common,
            ),
            progress=False,
        ),
        weights_only=False,
    )
    assert tuned["model"][GUIDED][:, 25:].abs().max() > 0


def test_the_guide_albedo_input_split_from_the_albedo_reads_both_and_agrees_where_they_agree(tmp_path, guided_sample):
    """``--guide-init split``: the projection's current-albedo weights halved and shared with
    the guide, so the network reads the guide from the first step and computes the init's
    outputs (fp32) where the guide is the albedo (a sequence without the layer), not where it
    differs (this sequence's guide is 1 - albedo)."""
    from jnds_deploy.checkpoint import load_model
    from jnds_deploy.errors import ConfigError
    from jnds_deploy.model import set_quantization
    from jnds_deploy.training.config import TrainConfig
    from jnds_deploy.training.data import load_sequence
    from jnds_deploy.training.evaluate import infer_sequence
    from jnds_deploy.training.surgery import GUIDED
    from jnds_deploy.training.train import train

    from .conftest import SAMPLE

    data = _data_dir(tmp_path, guided_sample)
    common = dict(
        data=str(data), preset="tiny", patch=32, unroll=3, batch=1, observe_batches=1, val_every=10**6, threads=1
    )
    first = train(TrainConfig(run=str(tmp_path / "a"), fp32_steps=1, qat_steps=1, **common), progress=False)
    split = train(
        TrainConfig(
            run=str(tmp_path / "b"),
            fp32_steps=0,
            qat_steps=0,
            init=str(first),
            guide_albedo=True,
            guide_init="split",
            **common,
        ),
        progress=False,
    )
    a, b = (torch.load(p, weights_only=False)["model"][GUIDED] for p in (first, split))
    torch.testing.assert_close(b[:, 6:9], a[:, 6:9] / 2)  # layout.CURRENT: the albedo is 6:9
    torch.testing.assert_close(b[:, 25:], a[:, 6:9] / 2)
    assert b[:, 25:].abs().max() > 0
    torch.testing.assert_close(torch.cat([b[:, :6], b[:, 9:25]], 1), torch.cat([a[:, :6], a[:, 9:]], 1))

    models = [load_model(p) for p in (first, split)]
    for m in models:
        set_quantization(m, False)  # the halved weights may change an int8 weight scale
    same, other = (infer_sequence(m, load_sequence(SAMPLE)) for m in models)
    for x, y in zip(same[:2], other[:2]):
        np.testing.assert_allclose(x, y, atol=1e-5)
    same, other = (infer_sequence(m, load_sequence(guided_sample)) for m in models)
    assert np.abs(same[1] - other[1]).max() > 1e-4
    with pytest.raises(ConfigError, match="guide_init"):
        TrainConfig(run=str(tmp_path / "c"), guide_init="copy", **common)
