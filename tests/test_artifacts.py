"""The artifact directory's manifest (docs/artifact-format.md): typed int8 fields, checked on
load, and the previous format still read."""

import json

import pytest

from jnds_deploy.artifacts import FORMAT, Block, Edge, Graph, Int8Graph, Manifest
from jnds_deploy.errors import ArtifactError


def _manifest(**int8) -> Manifest:
    entry = Int8Graph(
        file="network.int8.qat.onnx",
        sha256="0" * 16,
        activation_type="u8",
        weights="int8",
        op_types=["Conv"],
        float_nodes=[],
        ranges="calibration.qat.json",
        **int8,
    )
    graph = Graph(file="network.onnx", inputs={}, outputs={}, int8={"qat": entry})
    return Manifest(
        checkpoint={"path": "c.pt", "sha256": ""},
        model_config={"scale": 1, "filter_levels": 2},
        pad_multiple=8,
        graphs={"network": graph},
        int8_method="qat",
    )


def _written(tmp_path, data: dict):
    (tmp_path / "manifest.json").write_text(json.dumps(data))
    return tmp_path


def test_int8_edges_are_typed_and_written_as_their_values(tmp_path):
    m = _manifest(head=Edge.U8, inputs=Edge.U8, levels=Edge.U8, block=Block.CUT)
    m.save(tmp_path)
    data = json.loads((tmp_path / "manifest.json").read_text())
    entry = data["graphs"]["network"]["int8"]["qat"]
    assert data["format"] == FORMAT
    assert {k: entry[k] for k in ("head", "inputs", "levels", "block")} == {
        "head": "u8",
        "inputs": "u8",
        "levels": "u8",
        "block": "cut",
    }
    got = Manifest.load(tmp_path).graphs["network"].int8["qat"]
    assert (got.head, got.inputs, got.levels, got.block) == (Edge.U8, Edge.U8, Edge.U8, Block.CUT)
    assert isinstance(got.head, Edge) and isinstance(got.block, Block)


@pytest.mark.parametrize("key, value", [("head", "u16"), ("block", "in the graph"), ("activation_type", "f8")])
def test_a_wrong_int8_field_names_itself(tmp_path, key, value):
    data = _manifest().to_dict()
    data["graphs"]["network"]["int8"]["qat"][key] = value
    with pytest.raises(
        ArtifactError,
        match=rf"manifest.json: graphs\.network\.int8\.qat\.{key} is '{value}', "
        "expected one of",
    ):
        Manifest.load(_written(tmp_path, json.loads(json.dumps(data))))


def test_format_2_is_read_as_today(tmp_path):
    """``jnds-artifacts/2`` wrote the int8 edges as sentences; they load as the values, and
    the manifest is saved in today's format."""
    old = {
        "head": "u8, channels last, a range per channel (calibration.head_ranges)",
        "inputs": "u8, channels last, preprocessed (calibration.inputs)",
        "block": "between the graph's runs, u8 (calibration.block)",
        "levels": "u8 planes, the heads' own codes (calibration.head_ranges.code_levels)",
    }
    for edges, want in (
        (old, (Edge.U8, Edge.U8, Edge.U8, Block.CUT)),
        (
            {"head": "float", "inputs": "float", "block": "in the graph", "levels": "float"},
            (Edge.FLOAT, Edge.FLOAT, Edge.FLOAT, Block.GRAPH),
        ),
    ):
        data = json.loads(json.dumps(_manifest().to_dict()))
        data["format"] = "jnds-artifacts/2"
        data["graphs"]["network"]["int8"]["qat"].update(edges)
        m = Manifest.load(_written(tmp_path, data))
        got = m.graphs["network"].int8["qat"]
        assert (got.head, got.inputs, got.levels, got.block) == want
        m.save(tmp_path)
        assert json.loads((tmp_path / "manifest.json").read_text())["format"] == FORMAT


def test_an_unknown_int8_method_is_refused(tmp_path):
    data = json.loads(json.dumps(_manifest().to_dict()))
    data["int8_method"] = "minmax"
    with pytest.raises(ArtifactError, match="int8_method is 'minmax'"):
        Manifest.load(_written(tmp_path, data))
