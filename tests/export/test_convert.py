import json
from collections import Counter

import onnx
import pytest
import torch

from jnds_deploy.errors import ValidationError
from jnds_deploy.export import ExportConfig, export
from jnds_deploy.export.convert import report_validation, validate_graph
from jnds_deploy.filter_spec import to_phases
from jnds_deploy.model import JNDS, ModelConfig


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    d = tmp_path_factory.mktemp("ckpt")
    model = JNDS(ModelConfig.preset("tiny"))
    path = d / "tiny.pt"
    torch.save(
        {
            "model": model.state_dict(),
            "model_config": model.cfg.__dict__,
            "train_config": {},
            "quantized": False,
            "quant_ranges": None,
            "state": {},
        },
        path,
    )
    return path


def test_export_writes_valid_graphs_and_manifest(tiny_checkpoint, tmp_path):
    lines = []
    manifest = export(ExportConfig(checkpoint=str(tiny_checkpoint), out=str(tmp_path), verbose=True), log=lines.append)
    for g in ("network.onnx", "upsample.onnx"):
        model = onnx.load(tmp_path / g)
        onnx.checker.check_model(model, full_check=True)
        assert model.opset_import[0].version >= 17
    ops = Counter(n.op_type for n in onnx.load(tmp_path / "network.onnx").graph.node)
    assert ops["Conv"] == 14  # tiny: input 2, encoder 2, bottleneck 2, decoder 2, heads 4, output 2
    on_disk = json.loads((tmp_path / "manifest.json").read_text())
    assert on_disk["pad_multiple"] == 4 and on_disk["scale"] == 2
    assert set(on_disk["graphs"]) == {"network", "upsample"}
    assert all(r["ok"] for r in manifest.validation)
    assert all(line.startswith("✓") for line in lines) and len(lines) == len(manifest.validation)


def test_validation_catches_a_corrupted_graph(tiny_checkpoint, tmp_path):
    export(ExportConfig(checkpoint=str(tiny_checkpoint), out=str(tmp_path)), log=lambda s: None)
    model = onnx.load(tmp_path / "upsample.onnx")
    for init in model.graph.initializer:  # perturb the last convolution's bias
        if init.name.endswith("head.bias"):
            arr = onnx.numpy_helper.to_array(init).copy() + 0.5
            init.CopyFrom(onnx.numpy_helper.from_array(arr, init.name))
    onnx.save(model, tmp_path / "upsample.onnx")
    net = JNDS(ModelConfig(**torch.load(tiny_checkpoint, weights_only=False)["model_config"]))
    net.load_state_dict(torch.load(tiny_checkpoint, weights_only=False)["model"])
    comp, feats = torch.rand(1, 3, 8, 8), torch.rand(1, 2, 8, 8)
    rows = validate_graph(
        tmp_path / "upsample.onnx",
        lambda c, f: to_phases(net.upsample_block(c, f), 2),
        {"composite": comp, "features": feats},
        ["kernel"],
        1e-4,
    )
    assert not rows[0]["ok"] and rows[0]["max_abs"] > 0.1
    lines = []
    with pytest.raises(ValidationError, match="1 output.* upsample.onnx:kernel max"):
        report_validation(rows, lines.append, verbose=True)
    assert lines[0].startswith("✗ upsample.onnx:kernel")


def test_shipped_checkpoint_exports_and_validates(tmp_path):
    from jnds_deploy.checkpoint import default_checkpoint

    ckpt = torch.load(default_checkpoint(), weights_only=False)
    assert ckpt["quantized"] and ckpt["quant_ranges"]  # QAT-trained, ranges exportable
    manifest = export(ExportConfig(out=str(tmp_path)), log=lambda s: None)
    assert manifest.model_config["scale"] == 2 and manifest.pad_multiple == 8
    assert all(r["ok"] for r in manifest.validation)
    # the fp32 network graph runs the weights QAT trained: per output channel, int8 codes of
    # max|w| / 127 (the upsample graph's are those with the bilinear taps folded in)
    from onnx import numpy_helper

    graph = onnx.load(tmp_path / "network.onnx").graph
    inits = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    convs = [inits[n.input[1]] for n in graph.node if n.op_type == "Conv" and n.input[1] in inits]
    assert len(convs) >= 14
    for w in convs:
        codes = w / (abs(w).reshape(len(w), -1).max(1) / 127).reshape(-1, *[1] * (w.ndim - 1))
        assert abs(codes - codes.round()).max() < 1e-3


def test_pruned_variants_drop_their_kernels(tiny_checkpoint, tmp_path):
    """One variant per set of dropped output groups; a dropped path's heads are gone and
    the output block's head convolution computes fewer channels; the kept outputs equal
    the full graph's (validated at export)."""
    from onnx import numpy_helper

    manifest = export(ExportConfig(checkpoint=str(tiny_checkpoint), out=str(tmp_path)), log=lambda s: None)
    variants = manifest.graphs["network"].variants
    assert set(variants) == {
        "no-diffuse",
        "no-specular",
        "no-features",
        "no-diffuse-specular",
        "no-diffuse-features",
        "no-specular-features",
        "no-diffuse-specular-features",
    }
    full = onnx.load(tmp_path / "network.onnx")

    def head_channels(model):
        inits = {i.name: i for i in model.graph.initializer}
        conv = next(n for n in model.graph.node if n.name == "/network/output_block/head/Conv")
        return numpy_helper.to_array(inits[conv.input[1]]).shape[0]

    n_full = len(full.graph.node)
    for key, v in variants.items():
        model = onnx.load(tmp_path / v.file)
        onnx.checker.check_model(model, full_check=True)
        outs = [o.name for o in model.graph.output]
        assert outs == v.outputs and not any(o.split(".")[0] in v.drops for o in outs)
        assert head_channels(model) < head_channels(full) and len(model.graph.node) < n_full
        if "diffuse" in v.drops:
            assert not any("/diffuse" in n.name for n in model.graph.node)
    rows = [r for r in manifest.validation if r["graph"].startswith("network.no-")]
    assert len(rows) == 7 and all(r["ok"] and r["max_abs"] == 0 for r in rows)


def test_validation_report_is_one_line_unless_verbose():
    import pytest

    from jnds_deploy.errors import ValidationError
    from jnds_deploy.export.convert import report_validation

    rows = [
        {"graph": "g.onnx", "output": f"o{i}", "ok": True, "max_abs": d, "mean_abs": d / 10, "atol": 1e-4}
        for i, d in enumerate((1e-6, 5e-5, 2e-5))
    ]
    lines = []
    report_validation(rows, lines.append)
    assert len(lines) == 1 and lines[0].startswith("✓ 3 of 3 outputs") and "g.onnx:o1" in lines[0]
    lines = []
    report_validation(rows, lines.append, verbose=True)
    assert [line.split()[1] for line in lines] == ["g.onnx:o0", "g.onnx:o1", "g.onnx:o2"]
    rows[2]["ok"] = False
    lines = []
    with pytest.raises(ValidationError):
        report_validation(rows, lines.append)
    assert lines[0].startswith("✗ 2 of 3 outputs")
