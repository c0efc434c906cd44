"""The onnxruntime pipeline against the PyTorch model, frame after frame."""
import numpy as np
import pytest
import torch

from jnds_deploy.export import ExportConfig, export
from jnds_deploy.io import open_sequence
from jnds_deploy.model import JNDS, ModelConfig
from jnds_deploy.runtime.pipeline import ArtifactError, Pipeline, PipelineConfig
from jnds_deploy.train import infer_sequence, load_sequence

from ..conftest import SAMPLE


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory):
    d = tmp_path_factory.mktemp("artifacts")
    torch.manual_seed(1)
    model = JNDS(ModelConfig.preset("tiny"))
    for name, p in model.named_parameters():  # away from the identity init, so every path matters
        if "head" in name:
            p.data += 0.3 * torch.randn_like(p)
    ckpt = d / "tiny.pt"
    torch.save({"model": model.state_dict(), "model_config": model.cfg.__dict__, "train_config": {},
                "quantized": False, "quant_ranges": None, "state": {}}, ckpt)
    export(ExportConfig(checkpoint=str(ckpt), out=str(d / "a")), log=lambda s: None)
    return d / "a", model


def test_pipeline_matches_torch_over_a_sequence(artifacts):
    path, model = artifacts
    seq = open_sequence(SAMPLE)
    ref = infer_sequence(model, load_sequence(SAMPLE))[:4]
    pipe = Pipeline(PipelineConfig(artifacts=str(path)))
    for i in range(4):
        out, ms = pipe(seq.inputs(i), seq.frames[i].camera_cut)
        assert out.shape == (180, 320, 3) and out.dtype == np.float32
        # measured: 1e-7 (first frame) to 8e-7 (with history: cv2.remap's 1/32-pixel map
        # quantization in the warp); tolerance 1e-4 of the mean
        rel = np.abs(out - ref[i]).mean() / np.abs(ref[i]).mean()
        assert rel < 1e-4, (i, rel)
        assert {"network", "warp", "filter_diffuse", "filter_specular", "upsample_kernel", "total"} <= set(ms)


def test_pipeline_resets_on_cut_and_resize(artifacts):
    path, _ = artifacts
    seq = open_sequence(SAMPLE)
    pipe = Pipeline(PipelineConfig(artifacts=str(path)))
    first, _ = pipe(seq.inputs(0))
    pipe(seq.inputs(1))
    again, _ = pipe(seq.inputs(0), camera_cut=True)  # cut: no history, same as a first frame
    np.testing.assert_array_equal(first, again)
    crop = {k: v[:37, :51] for k, v in seq.inputs(2).items()}  # odd size: padded, cropped back
    out, _ = pipe(crop)
    assert out.shape == (74, 102, 3) and pipe.size == (51, 37)
    fresh = Pipeline(PipelineConfig(artifacts=str(path)))
    np.testing.assert_array_equal(out, fresh(crop)[0])


def test_pipeline_fp16_filters_close_to_fp32(artifacts):
    path, _ = artifacts
    seq = open_sequence(SAMPLE)
    a = Pipeline(PipelineConfig(artifacts=str(path)))
    b = Pipeline(PipelineConfig(artifacts=str(path), filter_dtype="float16"))
    for i in range(3):
        oa, _ = a(seq.inputs(i))
        ob, _ = b(seq.inputs(i))
    assert np.abs(oa - ob).mean() / np.abs(oa).mean() < 5e-3


def test_pipeline_errors(tmp_path, artifacts):
    with pytest.raises(ArtifactError, match="manifest.json: missing"):
        Pipeline(PipelineConfig(artifacts=str(tmp_path)))
    with pytest.raises(ArtifactError, match="no int8 graph"):
        Pipeline(PipelineConfig(artifacts=str(artifacts[0]), precision="int8"))


def test_jnds_run_writes_frames_and_report(artifacts, tmp_path):
    import json
    import subprocess
    import sys
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "jnds_deploy", "run", "--artifacts", str(artifacts[0]),
                           "--input", str(SAMPLE), "--output", str(out), "--quiet"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "against the reference: PSNR" in proc.stdout
    assert "| network |" in proc.stdout and "| **total** |" in proc.stdout
    report = json.loads((out / "run.json").read_text())
    assert report["frames"] == 8 and len(report["frame_ms"]) == 8 and report["output_size"] == [320, 180]
    assert report["metrics"]["psnr"] > 0 and 0 <= report["metrics"]["flip"] <= 1
    from jnds_deploy.io import OUTPUT_LAYERS, read_layers
    frame = read_layers(out / "0007.exr", (320, 180), OUTPUT_LAYERS)["color"]
    assert np.isfinite(frame).all() and (frame >= 0).all()
