"""The onnxruntime pipeline against the PyTorch model, frame after frame."""

import numpy as np
import pytest

from jnds_deploy.errors import ArtifactError, FrameError
from jnds_deploy.io import open_sequence
from jnds_deploy.runtime.pipeline import Pipeline, PipelineConfig
from jnds_deploy.training.data import load_sequence
from jnds_deploy.training.evaluate import infer_sequence

from ..conftest import SAMPLE


@pytest.fixture(scope="module")
def artifacts(tiny_artifacts):
    return tiny_artifacts


@pytest.mark.parametrize("root", [1, 4, "fixed"])
def test_pipeline_matches_torch_over_a_sequence(artifacts, tiny_artifacts_root4, tiny_artifacts_fixed, root):
    path, model = {1: artifacts, 4: tiny_artifacts_root4, "fixed": tiny_artifacts_fixed}[root]
    assert Pipeline(PipelineConfig(artifacts=str(path), precision="fp32")).upsample_root == (
        4 if root == "fixed" else root
    )
    seq = open_sequence(SAMPLE)
    ref = infer_sequence(model, load_sequence(SAMPLE))[:4]
    pipe = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))
    for i in range(4):
        frame = pipe(seq.inputs(i), seq.frames[i].camera_cut)
        out, ms = frame.output, frame.ms
        assert out.shape == (180, 320, 3) and out.dtype == np.float32
        # measured: 1e-7 (first frame) to 8e-7 (with history, when the warp was cv2.remap
        # with its 1/32-pixel map quantization); tolerance 1e-4 of the mean
        rel = np.abs(out - ref[i]).mean() / np.abs(ref[i]).mean()
        assert rel < 1e-4, (i, rel)
        assert {"network", "warp", "filter_diffuse", "filter_specular", "upsample_filter", "total"} <= set(ms)
        # one fixed kernel: no upsample graph to run
        assert ("upsample_kernel" in ms) == (root != "fixed")
    if root == "fixed":
        assert not (path / "upsample.onnx").exists()


def test_pipeline_resets_on_cut_and_resize(artifacts):
    path, _ = artifacts
    seq = open_sequence(SAMPLE)
    pipe = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))
    first = pipe(seq.inputs(0)).output
    pipe(seq.inputs(1))
    again = pipe(seq.inputs(0), camera_cut=True).output  # cut: no history, same as a first frame
    np.testing.assert_array_equal(first, again)
    crop = {k: v[:37, :51] for k, v in seq.inputs(2).items()}  # odd size: padded, cropped back
    out = pipe(crop).output
    assert out.shape == (74, 102, 3) and pipe.history.size == (51, 37)
    fresh = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))
    np.testing.assert_array_equal(out, fresh(crop).output)


def test_pipeline_fp16_filters_close_to_fp32(artifacts):
    path, _ = artifacts
    seq = open_sequence(SAMPLE)
    a = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))
    b = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32", filter_dtype="float16"))
    for i in range(3):  # the first frame, then two through the history
        oa = a(seq.inputs(i)).output
        ob = b(seq.inputs(i)).output
        assert np.abs(oa - ob).mean() / np.abs(oa).mean() < 5e-3, i


def test_pipeline_errors(tmp_path, artifacts):
    import json

    with pytest.raises(ArtifactError, match="manifest.json: missing"):
        Pipeline(PipelineConfig(artifacts=str(tmp_path)))
    with pytest.raises(ArtifactError, match="no int8 graph"):
        Pipeline(PipelineConfig(artifacts=str(artifacts[0]), precision="int8"))
    # artifacts of an older format (upsample kernel at target resolution) are refused
    manifest = json.loads((artifacts[0] / "manifest.json").read_text())
    (tmp_path / "manifest.json").write_text(json.dumps({**manifest, "format": "jnds-artifacts/1"}))
    with pytest.raises(ArtifactError, match="jnds-artifacts/1.*re-run `jnds export`"):
        Pipeline(PipelineConfig(artifacts=str(tmp_path)))
    bad = {**manifest, "model_config": {**manifest["model_config"], "upsample_root": 3}}
    (tmp_path / "manifest.json").write_text(json.dumps(bad))
    with pytest.raises(ArtifactError, match="upsample_root is 3"):
        Pipeline(PipelineConfig(artifacts=str(tmp_path)))
    # no upsample graph needs the fixed kernel, 9 taps in [-1, 1]
    for kernel in (None, [0.0] * 8, [0.0] * 8 + [2.0]):
        bad = {**manifest, "graphs": {"network": manifest["graphs"]["network"]}, "upsample_kernel": kernel}
        (tmp_path / "manifest.json").write_text(json.dumps(bad))
        with pytest.raises(ArtifactError, match="no 'upsample' graph, and upsample_kernel is"):
            Pipeline(PipelineConfig(artifacts=str(tmp_path)))


def test_jnds_run_does_not_need_torch(artifacts, tmp_path):
    """Deploying the ONNX pipeline (jnds run, the server) needs onnxruntime, numpy and
    opencv, not torch: with torch made unimportable, a run still works."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['torch'] = None\n"
        "import jnds_deploy.serve\n"
        "from jnds_deploy.cli import main\n"
        f"sys.exit(main(['run', '--artifacts', {str(artifacts[0])!r}, '--input', {str(SAMPLE)!r}, "
        f"'--output', {str(tmp_path / 'out')!r}, '--precision', 'fp32', '--quiet']))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "out" / "0007.exr").is_file()


def test_jnds_run_skips_numbas_blas_probe_and_leaves_scipy_importable(artifacts, tmp_path):
    """``tune_numba`` keeps numba's BLAS probe from importing scipy.linalg (a part of every
    cold start, docs/performance.md); a run loads its numba loops without it, and scipy
    imports as usual afterwards."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from jnds_deploy.cli import main\n"
        f"assert main(['run', '--artifacts', {str(artifacts[0])!r}, '--input', {str(SAMPLE)!r}, "
        f"'--output', {str(tmp_path / 'out')!r}, '--precision', 'fp32', '--quiet']) == 0\n"
        "assert 'scipy.linalg' not in sys.modules, 'scipy.linalg was imported'\n"
        "import numba.np.arraymath, scipy.linalg\n"
        "assert not numba.np.arraymath._HAVE_BLAS and scipy.linalg.norm([3.0, 4.0]) == 5.0\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_jnds_run_writes_frames_and_report(artifacts, tmp_path):
    import json
    import subprocess
    import sys

    out = tmp_path / "out"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "jnds_deploy",
            "run",
            "--artifacts",
            str(artifacts[0]),
            "--input",
            str(SAMPLE),
            "--output",
            str(out),
            "--precision",
            "fp32",
            "--quiet",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert "JNDS: PSNR" in proc.stdout and "changed pixels" in proc.stdout
    assert "| network |" in proc.stdout and "| **total** |" in proc.stdout
    report = json.loads((out / "run.json").read_text())
    assert report["frames"] == 8 and len(report["frame_ms"]) == 8 and report["output_size"] == [320, 180]
    # the scores are those of the frames written, against the sample's reference, frame by
    # frame; the means are theirs, and the printout says them
    from jnds_deploy.io import OUTPUT_LAYERS, read_layers
    from jnds_deploy.metrics import flip, psnr

    seq = open_sequence(SAMPLE)
    scores = report["metrics"]["per_frame"]
    assert len(scores) == 8
    for i, s in enumerate(scores):
        written = read_layers(out / f"{i:04d}.exr", (320, 180), OUTPUT_LAYERS)["color"]
        ref = seq.reference(i)["color"]
        assert s["psnr"] == pytest.approx(psnr(written, ref), abs=1e-9), i
        assert s["flip"] == pytest.approx(flip(written, ref), abs=1e-6), i
    assert report["metrics"]["psnr"] == pytest.approx(np.mean([s["psnr"] for s in scores]), abs=1e-9)
    assert report["metrics"]["flip"] == pytest.approx(np.mean([s["flip"] for s in scores]), abs=1e-9)
    assert f"JNDS: PSNR {report['metrics']['psnr']:.2f} dB, FLIP {report['metrics']['flip']:.4f}" in proc.stdout
    # the geometric test replaces the history at least wherever the frame sees background
    background = [int((np.abs(seq.inputs(i)["normal"]).sum(-1) < 0.5).sum()) for i in range(8)]
    rejected = [r["pixels"] for r in report["history_rejected"]]
    assert rejected[0] == 0 and all(r >= b > 0 for r, b in zip(rejected[1:], background[1:])), (rejected, background)
    frame = read_layers(out / "0007.exr", (320, 180), OUTPUT_LAYERS)["color"]
    assert np.isfinite(frame).all() and (frame >= 0).all()


@pytest.mark.parametrize("layer", ["diffuse", "specular", "albedo", "normal", "roughness", "motion"])
def test_nonfinite_inputs_are_replaced_and_counted(artifacts, layer):
    """NaN/Inf in any layer, on one pixel or the whole frame: replaced, counted, and the
    output and history stay finite and non-negative frame after frame."""
    path, _ = artifacts
    seq = open_sequence(SAMPLE)
    pipe = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))
    for i, bad in enumerate([np.nan, np.inf, -np.inf, "frame"]):
        layers = {k: v.copy() for k, v in seq.inputs(i).items()}
        if bad == "frame":
            layers[layer][:] = np.nan
            expected = layers[layer].size
        else:
            layers[layer][5, 7, 0] = bad
            expected = 1
        frame = pipe(layers)
        out = frame.output
        assert frame.nonfinite == {layer: expected}, (bad, frame.nonfinite)
        assert np.isfinite(out).all() and out.min() >= 0
        assert np.isfinite(pipe.history.frame).all()


def test_to_chw_stacks_sanitizes_pads_and_renormalizes():
    """reformat.to_chw against numpy: NaN as 0, every value clamped into its layer's range,
    non-finite values counted per layer, the padding replicating the last row and column,
    normals renormalized (3-channel layers take a loop of their own, the others the
    channel loop)."""
    from jnds_deploy.layout import CURRENT
    from jnds_deploy.runtime.reformat import LIMITS, to_chw

    rng = np.random.default_rng(3)
    h, w, pad = 5, 7, (8, 16)
    layers = {n: (rng.normal(size=(h, w, c)) * 3).astype(np.float32) for n, c in CURRENT + (("motion", 2),)}
    layers["diffuse"][1, 2, 0], layers["albedo"][0, 0, 2], layers["normal"][4, 6, 1] = np.nan, np.inf, -np.inf
    layers["roughness"][2, 3, 0], layers["motion"][3, 1, 1] = np.nan, np.inf
    layers["normal"][0, 1], layers["normal"][2, 2] = 0.0, (1e-30, 0.0, -1e-30)  # squared norms of 0: left as is
    for names in ([n for n, _ in CURRENT], ["motion"]):
        counts = {}
        got = to_chw(layers, names, pad, counts)
        want = []
        for n in names:
            lo, hi, unit = LIMITS[n]
            v = np.clip(np.nan_to_num(layers[n], nan=0.0, posinf=np.inf, neginf=-np.inf), lo, hi)
            v = np.pad(v, ((0, pad[0] - h), (0, pad[1] - w), (0, 0)), mode="edge")
            if unit:
                norm = np.sqrt((v * v).sum(-1, keepdims=True))
                v = np.where(norm > 0, v / np.where(norm > 0, norm, 1), v)
            want.append(v.transpose(2, 0, 1))
        np.testing.assert_allclose(got, np.concatenate(want), rtol=1e-6, atol=0)
        assert counts == {n: int((~np.isfinite(layers[n])).sum()) for n in names if not np.isfinite(layers[n]).all()}


def test_frame_errors_name_the_layer(artifacts):
    path, _ = artifacts
    layers = open_sequence(SAMPLE).inputs(0)
    pipe = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))
    with pytest.raises(FrameError, match="missing layer.*motion"):
        pipe({k: v for k, v in layers.items() if k != "motion"})
    with pytest.raises(FrameError, match="'albedo' is 80x90, diffuse is 160x90"):
        pipe({**layers, "albedo": layers["albedo"][:, :80]})
    with pytest.raises(FrameError, match="'normal' has shape"):
        pipe({**layers, "normal": layers["normal"][..., :2]})


def test_firefly_clamp_matches_torch(artifacts):
    """The runtime's clamp (the manifest's factor or PipelineConfig's) equals the model's."""
    import dataclasses

    path, model = artifacts
    model.cfg = dataclasses.replace(model.cfg, firefly_clamp=2.0)
    try:
        ref = infer_sequence(model, load_sequence(SAMPLE))[:4]
    finally:
        model.cfg = dataclasses.replace(model.cfg, firefly_clamp=0.0)
    plain = infer_sequence(model, load_sequence(SAMPLE))[:4]
    seq = open_sequence(SAMPLE)
    pipe = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32", firefly_clamp=2.0))
    assert Pipeline(PipelineConfig(artifacts=str(path), precision="fp32")).firefly_clamp == 0  # the manifest's: off
    for i in range(4):
        frame = pipe(seq.inputs(i), seq.frames[i].camera_cut)
        assert (frame.clamped > 0) == (i > 0)  # no history on the first frame: nothing to clamp against
        rel = np.abs(frame.output - ref[i]).mean() / np.abs(ref[i]).mean()
        assert rel < 1e-4, (i, rel)
        if i > 0:
            assert np.abs(ref[i] - plain[i]).mean() / np.abs(ref[i]).mean() > 1e-3  # the clamp changed it


@pytest.mark.parametrize("setting", ["diffuse_fill", "albedo_at_holes"])
def test_hole_settings_match_torch(artifacts, setting):
    """The runtime's diffuse fill and albedo at holes (PipelineConfig's or the manifest's)
    equal the model's; the bundled sample's metal pixels are holes, and a few of them (at
    corners) count as scattered."""
    import dataclasses

    path, model = artifacts
    model.cfg = dataclasses.replace(model.cfg, **{setting: True})
    try:
        ref = infer_sequence(model, load_sequence(SAMPLE))[:3]
    finally:
        model.cfg = dataclasses.replace(model.cfg, **{setting: False})
    plain = infer_sequence(model, load_sequence(SAMPLE))[:3]
    seq = open_sequence(SAMPLE)
    pipe = Pipeline(PipelineConfig(artifacts=str(path), precision="fp32", **{setting: True}))
    assert not getattr(Pipeline(PipelineConfig(artifacts=str(path), precision="fp32")), setting)  # the manifest's: off
    for i in range(3):
        frame = pipe(seq.inputs(i), seq.frames[i].camera_cut)
        assert setting in frame.ms
        rel = np.abs(frame.output - ref[i]).mean() / np.abs(ref[i]).mean()
        assert rel < 1e-4, (i, rel)
        moved = np.abs(ref[i] - plain[i]).max(-1) > 1e-3  # the pixels the setting changed
        assert moved.any()
        # there, the runtime's error is a small part of what the setting moved
        assert np.abs(frame.output[moved] - ref[i][moved]).max() < 0.1 * np.abs(ref[i] - plain[i]).max()
        if setting == "diffuse_fill":
            assert frame.filled > 0
            assert np.abs(ref[i] - plain[i]).mean() / np.abs(ref[i]).mean() > 1e-4


def test_pipeline_reads_the_guide_albedo_as_torch_does(tiny_artifacts_guided, guided_sample):
    """A network trained with the guide albedo (ModelConfig.guide_albedo): the runtime feeds
    it the frame's denoising_albedo, or its albedo where it has none, as the model does; the
    guide changes the output. A misshapen guide is refused by name."""
    path, model = tiny_artifacts_guided
    outs = {}
    for src in (guided_sample, SAMPLE):
        ref = infer_sequence(model, load_sequence(src))[:3]
        seq, pipe = open_sequence(src), Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))
        assert pipe.guide_albedo
        outs[src] = [pipe(seq.inputs(i), seq.frames[i].camera_cut).output for i in range(3)]
        for i in range(3):
            rel = np.abs(outs[src][i] - ref[i]).mean() / np.abs(ref[i]).mean()
            assert rel < 1e-4, (src, i, rel)
    assert all(np.abs(a - b).mean() > 1e-3 * np.abs(b).mean() for a, b in zip(outs[guided_sample], outs[SAMPLE]))
    layers = dict(open_sequence(guided_sample).inputs(0))
    layers["denoising_albedo"] = layers["denoising_albedo"][:, :, :2]
    with pytest.raises(FrameError, match="denoising_albedo"):
        Pipeline(PipelineConfig(artifacts=str(path), precision="fp32"))(layers)
