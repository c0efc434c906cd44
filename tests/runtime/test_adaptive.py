"""Adaptive execution: the exact skips give the full pipeline's output (and run the pruned
network graph); empty-tile skipping passes background through; denoise-only output."""

import json

import cv2
import numpy as np
import pytest

from jnds_deploy.io import open_sequence
from jnds_deploy.runtime import filters as F
from jnds_deploy.runtime.pipeline import TILE, Pipeline, PipelineConfig
from jnds_deploy.runtime.run import run_sequence

from ..conftest import SAMPLE


def _run(artifacts, frames, adaptive):
    # the default: the exact skips only (tile skipping is approximate and opt-in, tested below)
    pipe = Pipeline(PipelineConfig(artifacts=str(artifacts), precision="fp32", adaptive=adaptive))
    outs, decisions = [], []
    for i, layers in enumerate(frames):
        frame = pipe(layers, camera_cut=i == 0)
        outs.append(frame.output)
        decisions.append(dict(frame.decisions))
    return outs, decisions


@pytest.mark.parametrize("scene", ["diffuse_only", "specular_only", "static_camera"])
def test_exact_skips_equal_the_full_pipeline(tiny_artifacts, scene):
    seq = open_sequence(SAMPLE)
    frames = [{k: v.copy() for k, v in seq.inputs(i).items()} for i in range(4)]
    for f in frames:
        if scene == "diffuse_only":
            f["specular"][:] = 0
        elif scene == "specular_only":
            f["diffuse"][:] = 0
        else:
            f["motion"][:] = 0
    full, off = _run(tiny_artifacts[0], frames, adaptive=False)
    fast, on = _run(tiny_artifacts[0], frames, adaptive=True)
    assert not any(v for d in off for v in d.values())
    key = {"diffuse_only": "skip_specular", "specular_only": "skip_diffuse", "static_camera": "static"}[scene]
    # static needs a history to reuse: every frame after the first
    assert [d[key] for d in on] == ([False, True, True, True] if scene == "static_camera" else [True] * 4)
    graph = {"diffuse_only": "no-specular", "specular_only": "no-diffuse"}.get(scene)
    assert all(d.get("network_graph") == graph for d in on)  # the pruned graph ran
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)


def test_skip_decision_looks_at_the_history(tiny_artifacts):
    """Specular vanishes from the whole frame: its history is dropped (rejection: nothing
    current supports it) and the path is skipped, exactly; while the current frame still
    has specular somewhere, the path runs."""
    seq = open_sequence(SAMPLE)
    frames = [seq.inputs(0), seq.inputs(1)]
    spec = np.zeros_like(frames[1]["specular"])
    spec[:4, :4] = 1.0  # a little specular left in one corner
    frames.append({**seq.inputs(2), "specular": spec})
    frames.append({**seq.inputs(3), "specular": np.zeros_like(spec)})
    full, _ = _run(tiny_artifacts[0], frames, adaptive=False)
    fast, on = _run(tiny_artifacts[0], frames, adaptive=True)
    assert [d["skip_specular"] for d in on] == [False, False, False, True]
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)


def _sky_frame(h=40, w=64, split=32):
    """Geometry on the left (x < split), a flat sky (specular only, no geometry) on the right."""
    rng = np.random.default_rng(0)
    f = {
        "diffuse": rng.random((h, w, 3), np.float32),
        "specular": rng.random((h, w, 3), np.float32) * 0.2,
        "albedo": rng.random((h, w, 3), np.float32),
        "normal": np.tile(np.float32([0, 0, 1]), (h, w, 1)),
        "roughness": rng.random((h, w, 1), np.float32),
        "motion": np.zeros((h, w, 2), np.float32),
    }
    for k in ("diffuse", "albedo", "normal", "roughness"):
        f[k][:, split:] = 0
    f["specular"][:, split:] = np.float32([0.4, 0.6, 0.9])
    return f


def test_empty_tiles_need_no_geometry_and_a_flat_background():
    from jnds_deploy.model import CURRENT
    from jnds_deploy.runtime.reformat import to_chw

    f = _sky_frame()
    cur = to_chw(f, [n for n, _ in CURRENT], (48, 64), {})
    tiles = F.empty_tiles(cur, cur[:12].copy(), 16, 0.1)
    # tiles 0-1 hold geometry; tile 2 touches it through its 1-pixel border; tile 3 is sky
    assert tiles.tolist() == [[0, 0, 0, 1]] * 3
    cur[3:6, :, 48:] *= np.linspace(1, 2, 16, dtype=np.float32)  # a gradient steeper than 10 %
    assert F.empty_tiles(cur, cur[:12].copy(), 16, 0.1).sum() == 0


def test_tile_skip_passes_the_background_through(tiny_artifacts):
    f = _sky_frame()
    pipe = Pipeline(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32", tile_skip=True))
    comps = []
    pipe.on_feeds = lambda name, feeds: comps.append(feeds["composite"][0]) if name == "upsample" else None
    frame = pipe(f)
    out = frame.output
    assert frame.decisions["empty_tiles"] == 3
    # in the sky tile (native x >= 48, output x >= 96): the bilinear upsampling of the input
    up = cv2.resize(np.ascontiguousarray(comps[0].transpose(1, 2, 0)), (128, 80), interpolation=cv2.INTER_LINEAR)
    np.testing.assert_allclose(out[:, 96:], up[:, 96:], rtol=1e-6)
    # away from the bilinear footprint of the last filtered column: the sky as rendered
    np.testing.assert_allclose(out[:, 98:], np.broadcast_to(np.float32([0.4, 0.6, 0.9]), out[:, 98:].shape), rtol=1e-5)
    assert np.isfinite(out).all()


def test_upsample_block_on_the_box_equals_the_whole_frame(tiny_artifacts):
    """The upsample block run on the bounding box of the non-empty tiles (with its halo)
    gives the whole frame's kernel inside the tiles that use it."""
    pipe = Pipeline(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"))
    rng = np.random.default_rng(1)
    nf = pipe.sessions["upsample"].get_inputs()[1].shape[1]
    feeds = {"composite": rng.random((1, 3, 64, 96), np.float32), "features": rng.random((1, nf, 64, 96), np.float32)}
    tiles = np.ones((64 // TILE, 96 // TILE), np.uint8)
    tiles[1:3, 2:4] = 0  # native rows 16-47, columns 32-63 used
    whole = pipe.sessions["upsample"].run(None, feeds)[0][0]
    box = pipe._upsample_kernel(feeds, tiles)  # phase layout, native resolution
    assert box.shape == whole.shape == (4 * 9, 64, 96)
    np.testing.assert_allclose(box[:, 16:48, 32:64], whole[:, 16:48, 32:64], atol=1e-5)
    assert not box[:, :, :30].any()  # outside the box and its halo: not computed


def test_native_output_is_the_composite_without_the_upsample_block(tiny_artifacts, tmp_path):
    seq = open_sequence(SAMPLE)
    full = Pipeline(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"))
    native = Pipeline(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32", native_output=True))
    assert "upsample" not in native.sessions
    comps = []
    full.on_feeds = lambda name, feeds: comps.append(feeds["composite"][0]) if name == "upsample" else None
    h, w = seq.native_size[1], seq.native_size[0]
    for i in range(3):
        full(seq.inputs(i))
        frame = native(seq.inputs(i))
        out, ms = frame.output, frame.ms
        assert out.shape == (h, w, 3) and "upsample_kernel" not in ms
        assert frame.decisions["network_graph"].endswith("features")  # variant without the features
        np.testing.assert_array_equal(out, comps[-1][:, :h, :w].transpose(1, 2, 0))
    report = run_sequence(
        PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32", native_output=True),
        SAMPLE,
        tmp_path / "run",
        progress=False,
    )
    assert report["output_size"] == list(seq.native_size) and "psnr" in report["metrics"]
    assert json.loads((tmp_path / "run" / "run.json").read_text())["native_output"] is True
