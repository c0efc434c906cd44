"""`jnds calibrate`: int8 QDQ graphs, learned ranges applied, validation that can fail."""

import json
from collections import Counter

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

from jnds_deploy.artifacts import (
    BLOCK_KEY,
    HEAD,
    HEAD_KEY,
    INPUTS,
    INPUTS_KEY,
    Block,
    BlockLayout,
    Edge,
    HeadLayout,
    InputsLayout,
)
from jnds_deploy.calibration import CalibrateConfig, calibrate
from jnds_deploy.calibration.head_ranges import BOUNDS, HEAD_NODE, MIN_RANGE, STOPS
from jnds_deploy.calibration.inputs import PROJECT
from jnds_deploy.calibration.quantize import FLOAT_NODES, validate_int8
from jnds_deploy.calibration.reader import collect_feeds
from jnds_deploy.errors import CalibrationError, ValidationError
from jnds_deploy.export import ExportConfig, export
from jnds_deploy.export.convert import report_validation
from jnds_deploy.io import open_sequence
from jnds_deploy.layout import head_kind
from jnds_deploy.metrics import psnr
from jnds_deploy.runtime.pipeline import Pipeline, PipelineConfig

from ..conftest import SAMPLE


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """The shipped checkpoint exported and calibrated (qat) on three frames of the sample."""
    d = tmp_path_factory.mktemp("artifacts")
    export(ExportConfig(out=str(d)), log=lambda s: None)
    lines = []
    manifest = calibrate(
        CalibrateConfig(artifacts=str(d), data=(str(SAMPLE),), method="qat", frames=3, verbose=True), log=lines.append
    )
    return d, manifest, lines


def _producers(model):
    return {o: n for n in model.graph.node for o in n.output}


def _check_concats(model):
    """Each concatenation's resized input is quantized at the scale of what reads the
    concatenation (calibration.quantize's resizes_into_concat_scale)."""
    prod = _producers(model)
    for concat in [n for n in model.graph.node if n.op_type == "Concat"]:
        out = next(u for u in model.graph.node if concat.output[0] in u.input)
        resized = [
            prod[i]
            for i in concat.input
            if prod[prod[i].input[0]].op_type == "QuantizeLinear"
            and prod[prod[prod[i].input[0]].input[0]].op_type == "Resize"
        ]
        assert len(resized) == 1 and resized[0].input[1:] == out.input[1:], concat.name


def test_every_convolution_is_quantized(calibrated):
    d, manifest, _ = calibrated
    for name, g in manifest.graphs.items():
        model = onnx.load(d / g.int8["qat"].file)
        onnx.checker.check_model(model, full_check=True)
        ops = Counter(n.op_type for n in model.graph.node)
        prod = _producers(model)
        for n in model.graph.node:  # int8 from one conv to the next: pooling, resize, concat in QDQ
            inside = "/feature_extractor/" in n.name or "/output_block/" in n.name or "AveragePool" in n.name
            if n.op_type in ("MaxPool", "AveragePool", "Resize", "Concat") and inside:
                users = [u.op_type for u in model.graph.node if n.output[0] in u.input]
                assert prod[n.input[0]].op_type == "DequantizeLinear" and users == ["QuantizeLinear"], n.name
        float_nodes = [n for n in FLOAT_NODES if n in g.int8["qat"].float_nodes]
        convs = [n for n in model.graph.node if n.op_type == "Conv" and n.name not in float_nodes]
        heads = [n for n in model.graph.node if n.op_type == "Conv" and n.name in float_nodes]
        # the upsample block's head stays float; the output block's is quantized, its u8
        # output the graph's (runtime.head)
        assert len(heads) == (name == "upsample")
        assert all(h.input[1] not in prod for h in heads)  # float weights
        if name == "network":
            assert HEAD_NODE not in float_nodes and g.int8["qat"].head == Edge.U8
            out = {o.name: o for o in model.graph.output}
            assert out[HEAD].type.tensor_type.elem_type == onnx.TensorProto.UINT8
            assert "diffuse.spatial" not in out and prod[HEAD].op_type == "Transpose"
            props = {p.key: p.value for p in model.metadata_props}
            assert HeadLayout.from_json(props[HEAD_KEY]).channels % 16 == 0
            # its input: the u8 packed preprocessing, channels last, a multiple of 8
            # and an entry per cut at an upsampling + concatenation (calibration.block), with
            # u8 defaults: each decoder block's, then the output block's
            layout = BlockLayout.from_json(props[BLOCK_KEY])
            entries = [e for e, _ in layout.segments]
            depth = len(manifest.model_config["encoder_widths"])
            assert [i.name for i in model.graph.input] == entries and entries[0] == INPUTS
            assert [c.stage for c in layout.cuts] == ["feature_extractor"] * depth + ["output_block"]
            defaults = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer if i.name in entries}
            assert {k: v.dtype for k, v in defaults.items()} == {e: np.uint8 for e in entries}
            assert layout.internal <= set(out) and HEAD in dict(layout.segments)[entries[-1]]
            assert g.int8["qat"].block == Block.CUT
            assert not ops["Resize"] and not ops["Concat"]
            assert InputsLayout.from_json(props[INPUTS_KEY]).channels % 8 == 0
            project = next(n for n in model.graph.node if n.name == PROJECT)
            assert not ops["Log"] and not ops["Exp"]  # no float tonemap left
            assert prod[prod[project.input[0]].input[0]].op_type == "Transpose"
        assert convs and ops["QuantizeLinear"] >= len(convs) and ops["Relu"] <= 1  # ReLUs folded
        assert not ops["AveragePool"]  # a depthwise convolution (pools_as_convolutions)
        _check_concats(model)
        for conv in convs:  # DQ -> Conv <- DQ(int8 weight), and Conv -> Q (what ORT fuses)
            assert prod[conv.input[0]].op_type == "DequantizeLinear", conv.name
            assert prod[conv.input[1]].op_type == "DequantizeLinear", conv.name
            users = [n.op_type for n in model.graph.node if conv.output[0] in n.input]
            assert "QuantizeLinear" in users, conv.name
        weights = [i for i in model.graph.initializer if i.data_type == onnx.TensorProto.INT8 and len(i.dims) == 4]
        assert len(weights) == len(convs)  # per-channel int8 weights, one per convolution


def test_a_quantized_pool_rewritten_as_a_depthwise_convolution_pools_the_same(tmp_path):
    """DQ -> AveragePool(2x2, stride 2) -> Q becomes a QLinearConv in ONNX Runtime with
    the same output but for exact halves rounded the other way (one code)."""
    import onnxruntime as ort
    from onnx import TensorProto, helper

    from jnds_deploy.calibration.rewrite import pools_as_convolutions

    scale, zp = numpy_helper.from_array(np.float32(0.02), "s"), numpy_helper.from_array(np.uint8(3), "z")
    nodes = [
        helper.make_node("DequantizeLinear", ["x", "s", "z"], ["xf"]),
        helper.make_node("AveragePool", ["xf"], ["pf"], name="pool", kernel_shape=[2, 2], strides=[2, 2]),
        helper.make_node("QuantizeLinear", ["pf", "s", "z"], ["y"]),
    ]
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("x", TensorProto.UINT8, [1, 16, None, None])],
        [helper.make_tensor_value_info("y", TensorProto.UINT8, None)],
        [scale, zp],
    )
    path = tmp_path / "pool.onnx"
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    onnx.save(model, path)
    x = np.random.default_rng(0).integers(0, 256, (1, 16, 36, 64), dtype=np.uint8)
    before = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"x": x})[0]
    assert pools_as_convolutions(model) == 1
    onnx.save(model, path)
    opts = ort.SessionOptions()
    opts.optimized_model_filepath = str(tmp_path / "optimized.onnx")
    after = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"]).run(None, {"x": x})[0]
    ops = [n.op_type for n in onnx.load(tmp_path / "optimized.onnx").graph.node]
    assert "QLinearConv" in ops and not {"AveragePool", "QLinearAveragePool"} & set(ops), ops
    mean = x.reshape(1, 16, 18, 2, 32, 2).astype(np.float64).mean((3, 5))  # codes share the zero point
    np.testing.assert_allclose(after, mean, atol=0.5)  # rounded to nearest
    diff = np.abs(after.astype(int) - before.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 0.3  # ties only (a quarter of the means end in .5)


def test_int8_graph_has_pruned_variants(calibrated):
    d, manifest, lines = calibrated
    variants = manifest.graphs["network"].int8["qat"].variants
    # every non-empty set of the droppable groups the network has: diffuse, specular and, for
    # a model that predicts its upsample kernel, the upsample features
    n = 2 ** (2 + bool(manifest.model_config["upsample_features"])) - 1
    assert len(variants) == n
    for v in variants.values():
        assert (d / v.file).is_file() and v.file.startswith("network.int8.qat.no-")
    assert sum(1 for line in lines if ".int8.qat.no-" in line and line.startswith("✓")) == n


def test_learned_ranges_become_the_scales(calibrated):
    d, manifest, _ = calibrated
    learned = json.loads((d / "qat_ranges.json").read_text())
    saved = json.loads((d / "calibration.qat.json").read_text())
    assert saved["method"] == "qat" and saved["frames"] == {name: 3 for name in manifest.graphs}
    for graph, tensors in learned.items():
        for tensor, r in tensors.items():
            got = saved["tensors"][graph][tensor]
            assert got["scale"] == pytest.approx(r["scale"], rel=1e-4)
            assert got["zero_point"] == r["zero_point_u8"] and got["dtype"] == "uint8"


def test_int8_pipeline_stays_close_to_fp32(calibrated):
    d, manifest, lines = calibrated
    assert manifest.int8_method == "qat" and any(line.startswith("✓") for line in lines)
    assert not any(line.startswith("✗") for line in lines)
    seq = open_sequence(SAMPLE)
    pipes = [
        Pipeline(PipelineConfig(artifacts=str(d), precision=p, filter_dtype=f))
        for p, f in (("fp32", "float32"), ("int8", "float32"), ("int8", "float16"))
    ]
    for i in range(4):
        a, b, c = (p(seq.inputs(i), seq.frames[i].camera_cut).output for p in pipes)
        assert np.isfinite(b).all() and np.isfinite(c).all()
        # measured with calibration on all 8 frames: 35.7 dB on frame 1 falling to 34.1 dB
        # on frame 4 (int8 error accumulates in the history)
        assert psnr(b, a) > 30.0
        assert psnr(c, b) > 40.0  # the u8 head decoded for the float16 filter stage


def test_validation_catches_a_corrupted_int8_graph(calibrated, tmp_path):
    d, manifest, _ = calibrated
    path = d / manifest.graphs["network"].int8["qat"].file
    good = path.read_bytes()
    try:
        model = onnx.load(path)
        # the u8 head's weight scales x4: its raw outputs x4, every kernel and blend weight off
        head = next(n for n in model.graph.node if n.op_type == "DequantizeLinear" and n.output[0] == "head_w")
        for init in model.graph.initializer:
            if init.name == head.input[1]:
                init.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(init) * np.float32(4), init.name))
        onnx.save(model, path)
        feeds = collect_feeds(d, [SAMPLE], frames=2, progress=False)
        rows = [r for r in validate_int8(d, manifest, "qat", feeds, None) if r["graph"] == path.name]
        assert rows and not all(r["ok"] for r in rows)
        with pytest.raises(ValidationError, match="network.int8.qat.onnx:"):
            report_validation(rows, lambda s: None)
    finally:
        path.write_bytes(good)


@pytest.mark.parametrize("method", ["minmax", "percentile", "entropy"])
def test_post_training_methods(calibrated, method):
    d, _, _ = calibrated
    manifest = calibrate(
        CalibrateConfig(artifacts=str(d), data=(str(SAMPLE),), method=method, frames=2, activation_type="s8"),
        log=lambda s: None,
    )
    entry = manifest.graphs["network"].int8[method]
    assert (d / entry.file).is_file() and entry.activation_type == "s8"
    saved = json.loads((d / f"calibration.{method}.json").read_text())
    assert all(t["dtype"] == "int8" and t["rmin"] <= 0 <= t["rmax"] for t in saved["tensors"]["network"].values())
    assert all(r["ok"] for r in manifest.int8_validation[method])
    # every method stays registered; the pipeline runs the one it is asked for: this method's
    # graph, whose frames stay within 40 dB PSNR of fp32's (50-60 dB measured) and within
    # 0.1 dB of fp32's PSNR against the reference, frame after frame through the history
    assert "qat" in manifest.graphs["network"].int8
    pipe = Pipeline(PipelineConfig(artifacts=str(d), precision="int8", int8_method=method))
    assert pipe.graphs["network"].path.name == entry.file
    fp32 = Pipeline(PipelineConfig(artifacts=str(d), precision="fp32"))
    seq = open_sequence(SAMPLE)
    for i in range(4):
        a, b = pipe(seq.inputs(i)).output, fp32(seq.inputs(i)).output
        ref = seq.reference(i)["color"]
        assert psnr(a, b) > 40 and abs(psnr(a, ref) - psnr(b, ref)) < 0.1, (method, i, psnr(a, b))
    Pipeline(PipelineConfig(artifacts=str(d), precision="int8", int8_method="qat"))  # the others stay usable


def test_bad_calibration_requests(tmp_path):
    with pytest.raises(CalibrationError, match="unknown method"):
        CalibrateConfig(artifacts=str(tmp_path), data=(str(SAMPLE),), method="magic")
    with pytest.raises(CalibrationError, match="no calibration sequences"):
        CalibrateConfig(artifacts=str(tmp_path), data=())
    with pytest.raises(CalibrationError, match="manifest.json: missing"):
        calibrate(CalibrateConfig(artifacts=str(tmp_path), data=(str(SAMPLE),)))


def test_end_to_end_report_scores_int8_against_fp32_and_the_reference(calibrated):
    from jnds_deploy.calibration.report import end_to_end

    d, _, _ = calibrated
    from jnds_deploy.metrics import flip

    report = end_to_end(d, "qat", [SAMPLE], progress=False)
    m = report["mean"]
    assert set(report["per_sequence"]) == {SAMPLE.name}
    # the fp32 scores are the fp32 pipeline's over every frame of the sample
    seq = open_sequence(SAMPLE)
    fp32 = Pipeline(PipelineConfig(artifacts=str(d), precision="fp32"))
    outs = [fp32(seq.inputs(i), seq.frames[i].camera_cut).output for i in range(len(seq))]
    refs = [seq.reference(i)["color"] for i in range(len(seq))]
    assert m["fp32_psnr"] == pytest.approx(np.mean([psnr(o, r) for o, r in zip(outs, refs)]), abs=1e-3)
    assert m["fp32_flip"] == pytest.approx(np.mean([flip(o, r) for o, r in zip(outs, refs)]), abs=1e-4)
    # int8 (qat) next to it: 50-56 dB from fp32's frames, 0.01 dB and 0.0005 FLIP off its scores
    # (measured); the bounds allow ten times that
    assert m["int8_vs_fp32_psnr"] > 40 and abs(m["psnr_loss_db"]) < 0.1
    assert abs(m["int8_flip"] - m["fp32_flip"]) < 0.005


def test_head_ranges_and_the_float_head_option(calibrated):
    d, _, _ = calibrated
    saved = json.loads((d / "calibration.qat.json").read_text())
    head = saved["head"]
    assert saved["head_stops"] == list(STOPS) and min(STOPS) < 0 < max(STOPS)  # ranges for every brightness
    for name in ("diffuse.spatial", "diffuse.blend", "aux.spatial", "features"):
        if name == "features" and name not in head:  # a model with one fixed upsample kernel
            continue
        r = head[name]
        lo, hi = BOUNDS[head_kind(name)]
        assert len(r["range"]) == len(r["centre"]) == len(r["min"]) == len(r["max"])
        for c, rng, a, b in zip(r["centre"], r["range"], r["min"], r["max"]):
            # the code covers the calibration range, within what the part's function tells apart
            # (a channel constant on these frames gets MIN_RANGE either side)
            assert rng > 0 and lo - MIN_RANGE <= c - rng <= max(a, lo) + 1e-6
            assert min(b, hi) - 1e-6 <= c + rng <= hi + MIN_RANGE
            if head_kind(name) == "kernel":  # the whole clamp, not what these frames reached
                assert (c, rng) == (0.0, 1.0)
    manifest = calibrate(
        CalibrateConfig(artifacts=str(d), data=(str(SAMPLE),), method="minmax", frames=2, u8_edges=False),
        log=lambda s: None,
    )
    entry = manifest.graphs["network"].int8["minmax"]
    outputs = [o.name for o in onnx.load(d / entry.file).graph.output]
    assert entry.head == entry.inputs == "float" and HEAD_NODE in entry.float_nodes
    assert "diffuse.spatial" in outputs and HEAD not in outputs
    assert all(r["ok"] for r in manifest.int8_validation["minmax"])


def test_int8_pipeline_skips_with_the_u8_head(calibrated):
    """Adaptive execution runs the pruned int8 variant (its own u8 head layout) and tile
    skipping reads the coded head: both stay with the full int8 pipeline."""
    d, _, _ = calibrated
    seq = open_sequence(SAMPLE)
    cfg = dict(artifacts=str(d), precision="int8", int8_method="qat")
    full = Pipeline(PipelineConfig(**cfg, adaptive=False))
    adaptive = Pipeline(PipelineConfig(**cfg))
    tiles = Pipeline(PipelineConfig(**cfg, tile_skip=True))
    for i in range(3):
        layers = {**seq.inputs(i)}
        layers["specular"] = np.zeros_like(layers["specular"])
        cut = seq.frames[i].camera_cut
        a = full(layers, cut).output
        r = adaptive(layers, cut)
        assert r.decisions["network_graph"] == "no-specular" and r.decisions["skip_specular"]
        assert psnr(r.output, a) > 40.0
        c = tiles(layers, cut).output
        assert np.isfinite(c).all() and psnr(c, a) > 30.0


def test_the_cut_graph_computes_what_the_whole_graph_did(calibrated, tmp_path, monkeypatch):
    """calibration.block cuts the int8 network graph at every upsampling + concatenation;
    the numba passes between its runs (reformat.block_input) give the head the whole graph
    gave, and every other output the same. A graph already cut has nothing left to cut."""
    import shutil

    import onnxruntime as ort

    import jnds_deploy.calibration.quantize as quantize
    from jnds_deploy.calibration.block import cut_blocks
    from jnds_deploy.runtime.network import Edges, quiet

    d, manifest, _ = calibrated
    whole = tmp_path / "whole"
    shutil.copytree(d, whole)
    monkeypatch.setattr(quantize, "cut_blocks", lambda model, multiple, label: model)
    calibrate(CalibrateConfig(artifacts=str(whole), data=(str(SAMPLE),), method="qat", frames=3), log=lambda s: None)
    file = manifest.graphs["network"].int8["qat"].file
    _check_concats(onnx.load(whole / file))  # the cut graph has none left
    cut, ref = (ort.InferenceSession(str(p / file), quiet(), providers=["CPUExecutionProvider"]) for p in (d, whole))
    e_cut, e_ref = Edges(cut), Edges(ref)
    assert e_cut.block is not None and e_ref.block is None and sorted(e_cut.outputs) == sorted(e_ref.outputs)
    for feeds in collect_feeds(d, [SAMPLE], frames=2)["network"]:
        packed = e_ref.feeds(feeds)
        got, want = e_cut.run(cut, packed), e_ref.run(ref, packed)
        assert sorted(got) == sorted(want)
        for name in want:
            if name == HEAD:  # rounding the same value two ways may move a rare code by one
                diff = np.abs(got[name].astype(int) - want[name])
                assert diff.max() <= 1 and diff.mean() < 1e-3, name
            else:
                np.testing.assert_array_equal(got[name], want[name], err_msg=name)
    with pytest.raises(CalibrationError, match="Resize"):
        cut_blocks(onnx.load(d / file), manifest.pad_multiple)


def test_coded_level_heads_give_the_outputs_their_nodes_gave(calibrated, tmp_path, monkeypatch):
    """calibration.head_ranges.code_levels ends each level head in its u8 codes (planes, one output
    per head, metadata per head); decoded, they are the float outputs the graph's
    dequantization, clamps and sigmoids gave, in every variant that has them."""
    import shutil

    import onnxruntime as ort

    import jnds_deploy.calibration.quantize as quantize
    from jnds_deploy.artifacts import LEVELS_KEY
    from jnds_deploy.runtime.network import Edges, quiet, run_network

    d, manifest, _ = calibrated
    entry = manifest.graphs["network"].int8["qat"]
    assert entry.levels == Edge.U8
    plain = tmp_path / "plain"
    shutil.copytree(d, plain)
    monkeypatch.setattr(quantize, "code_levels", lambda model, label: model)
    calibrate(CalibrateConfig(artifacts=str(plain), data=(str(SAMPLE),), method="qat", frames=3), log=lambda s: None)
    feeds = collect_feeds(d, [SAMPLE], frames=2)["network"]
    for file in [entry.file] + [v.file for v in entry.variants.values()]:
        coded, ref = (
            ort.InferenceSession(str(p / file), quiet(), providers=["CPUExecutionProvider"]) for p in (d, plain)
        )
        levels = Edges(coded).levels
        outputs = [o.name for o in coded.get_outputs()]
        assert Edges(ref).levels == {} and LEVELS_KEY not in ref.get_modelmeta().custom_metadata_map
        assert sorted(levels) == sorted(n for n in outputs if ".level" in n), file
        assert all(n.count(".") == 1 for n in levels), file  # "<path>.level<k>": no float part left
        if file == entry.file:  # both paths' every level
            assert len(levels) == 2 * manifest.filter_levels
        for f in feeds:
            got, want = run_network(coded, f), run_network(ref, f)
            assert sorted(got) == sorted(want), file
            for name in want:
                if ".level" in name:  # q * scale + offset against (q - zero point) * scale; ORT's sigmoid
                    np.testing.assert_allclose(got[name], want[name], rtol=1e-5, atol=2e-7, err_msg=name)
                else:
                    np.testing.assert_array_equal(got[name], want[name], err_msg=name)


def test_feed_reader_gives_every_feed_at_every_exposure():
    from jnds_deploy.calibration.head_ranges import RADIANCE
    from jnds_deploy.calibration.reader import FeedReader

    rng = np.random.default_rng(0)
    feeds = [
        {"current": rng.random((1, 13, 4, 4), np.float32), "history": rng.random((1, 12, 4, 4), np.float32)}
        for _ in range(2)
    ]
    kept = [{k: v.copy() for k, v in f.items()} for f in feeds]
    reader = FeedReader(feeds, (-2, 0, 3), RADIANCE)
    for _ in range(2):  # and again after a rewind
        got = list(iter(reader.get_next, None))
        assert len(got) == 6
        for i, g in enumerate(got):
            f, k = feeds[i // 3], (-2, 0, 3)[i % 3]
            for name in f:
                assert np.allclose(g[name][:, RADIANCE], f[name][:, RADIANCE] * 2.0**k)
                assert np.array_equal(g[name][:, RADIANCE.stop :], f[name][:, RADIANCE.stop :])
        reader.rewind()
    assert all(np.array_equal(f[n], k[n]) for f, k in zip(feeds, kept) for n in f)  # the feeds untouched
    with pytest.raises(ValueError):
        FeedReader(feeds, (0, 2))


def test_float_edges_ranges_left_to_the_calibrator_cover_every_exposure(tmp_path):
    """With float edges, a tensor without a learned range (the input preprocessing's, a level
    head's output) is ranged over the calibration frames at every exposure of head.STOPS, as
    the output block's head is."""
    import onnxruntime as ort
    from onnx import helper

    from jnds_deploy.calibration.head_ranges import RADIANCE
    from jnds_deploy.calibration.reader import exposed

    d = tmp_path
    export(ExportConfig(out=str(d)), log=lambda s: None)
    calibrate(
        CalibrateConfig(artifacts=str(d), data=(str(SAMPLE),), method="qat", frames=2, u8_edges=False),
        log=lambda s: None,
    )
    saved = json.loads((d / "calibration.qat.json").read_text())["tensors"]["network"]
    model = onnx.load(d / "network.onnx")
    tensors = [t for t in saved if t.endswith("Exp_output_0") or t.endswith("specular1/Conv_output_0")]
    assert len(tensors) == 2
    for t in tensors:
        model.graph.output.append(helper.make_tensor_value_info(t, onnx.TensorProto.FLOAT, None))
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    feeds = collect_feeds(d, [SAMPLE], frames=2, progress=False)["network"]
    for i, t in enumerate(tensors):
        at = {k: [sess.run([t], exposed(f, k, RADIANCE))[0] for f in feeds] for k in STOPS}
        lo = min(min(v.min() for v in vs) for vs in at.values())
        hi = max(max(v.max() for v in vs) for vs in at.values())
        step = (saved[t]["rmax"] - saved[t]["rmin"]) / 255
        assert saved[t]["rmin"] <= lo + step and saved[t]["rmax"] >= hi - step, t
        # wider than the frames as they are would have given
        assert hi > max(v.max() for v in at[0]) + step or lo < min(v.min() for v in at[0]) - step, t


def _pair_extremes(w, bounds):
    """The smallest and largest 16-bit pair sums (channels 2j, 2j+1) of int8 weights w (out, in)
    at codes 0..bounds."""
    hi, lo = np.maximum(w, 0) * bounds, np.minimum(w, 0) * bounds
    return (lo[:, 0::2] + lo[:, 1::2]).min(), (hi[:, 0::2] + hi[:, 1::2]).max()


def test_safe_slots_keep_every_pair_within_16_bits():
    from jnds_deploy.calibration.inputs import I16, code_bounds, safe_slots

    scale = 2.9 / 255  # below the tonemap's top: the brightest radiance saturates at 255
    bounds = code_bounds(scale, 0)
    assert bounds.max() == 255 and bounds.min() < 128  # radiance to the top, the other layers to 1.0
    rng = np.random.default_rng(3)
    w = rng.integers(-60, 61, (16, 25)).astype(np.int64)
    w[:, :6] = 127  # six radiance channels that overflow beside each other or a large weight
    slots = safe_slots(w, scale, 0)
    assert sorted(slots) == sorted(set(slots)) and max(slots) < 32
    placed, b = np.zeros((16, 32), np.int64), np.zeros(32, np.int64)
    placed[:, slots], b[slots] = w, bounds
    lo, hi = _pair_extremes(placed, b)
    assert I16[0] <= lo and hi <= I16[1]
    lo, hi = _pair_extremes(np.concatenate([w, np.zeros((16, 7), np.int64)], 1), np.append(bounds, [0] * 7))
    assert hi > I16[1]  # in order they would overflow
    # no placement: every channel a radiance channel at the top, no padding
    assert safe_slots(np.full((4, 25), 127), scale, 0, channels=25) == list(range(25))


def test_the_calibrated_projection_cannot_overflow_16_bits(calibrated):
    """In the int8 graph every pair of the projection's input channels stays within a 16-bit
    sum at any code the packed inputs can hold (AVX2's vpmaddubsw)."""
    from jnds_deploy.calibration.inputs import I16, code_bounds

    d, manifest, _ = calibrated
    model = onnx.load(d / manifest.graphs["network"].int8["qat"].file)
    layout = InputsLayout.from_json({p.key: p.value for p in model.metadata_props}[INPUTS_KEY])
    w = next(
        numpy_helper.to_array(i) for i in model.graph.initializer if i.name.endswith("project.weight_quantized_padded")
    )
    b = np.zeros(layout.channels, np.int64)
    b[list(layout.slots)] = code_bounds(layout.scale, layout.zero_point)
    lo, hi = _pair_extremes(w[:, :, 0, 0].astype(np.int64), b)
    assert len(layout.slots) == 25 and I16[0] <= lo and hi <= I16[1]


def _calibrated_copy(src, sequence, tmp_path):
    """A copy of fp32 artifacts ``src`` calibrated (minmax) on 3 frames of ``sequence``, every
    graph passing validation: the copy and its int8 network graph's metadata."""
    import shutil

    d = tmp_path / "a"
    shutil.copytree(src, d)
    lines = []
    manifest = calibrate(
        CalibrateConfig(artifacts=str(d), data=(str(sequence),), method="minmax", frames=3), log=lines.append
    )
    assert not any(line.startswith("✗") for line in lines)
    model = onnx.load(d / manifest.graphs["network"].int8["minmax"].file)
    return d, {p.key: p.value for p in model.metadata_props}


def test_a_network_with_the_guide_albedo_calibrates_and_packs_it(tiny_artifacts_guided, guided_sample, tmp_path):
    """int8 graphs of a network that reads the guide albedo: its u8 input holds the guide's
    channels too (artifacts.InputsLayout.guided), they pass validation against PyTorch,
    and the int8 pipeline stays close to fp32 on a sequence with the layer, where the guide
    moves the output."""
    d, props = _calibrated_copy(tiny_artifacts_guided[0], guided_sample, tmp_path)
    layout = InputsLayout.from_json(props[INPUTS_KEY])
    assert layout.guided and len(layout.slots) == 28
    seq = open_sequence(guided_sample)
    fp32, int8 = (Pipeline(PipelineConfig(artifacts=str(d), precision=p)) for p in ("fp32", "int8"))
    plain = Pipeline(PipelineConfig(artifacts=str(d), precision="int8"))
    for i in range(3):
        layers = seq.inputs(i)
        a, b = fp32(layers, seq.frames[i].camera_cut).output, int8(layers, seq.frames[i].camera_cut).output
        without = plain({k: v for k, v in layers.items() if k != "denoising_albedo"}, seq.frames[i].camera_cut).output
        assert psnr(b, a) > 40.0  # measured 53-56 dB
        assert psnr(without, b) < psnr(b, a) - 3.0


def test_a_space_to_depth_input_block_calibrates_packs_and_cuts_in_phases(tiny_artifacts_s2d, tmp_path):
    """int8 graphs of a network with the space-to-depth input block (model.InputBlock): its
    u8 input is each 2x2 block of pixels as one (InputsLayout.block 2, 4 x 25 channels padded
    to 104), its native features leave the graph as u8 phases with no depth-to-space in it
    (the output block's cut does it, Cut.skip_phases), the graphs pass validation against
    PyTorch, and the int8 pipeline stays close to fp32."""
    d, props = _calibrated_copy(tiny_artifacts_s2d[0], SAMPLE, tmp_path)
    model = onnx.load(d / "network.int8.minmax.onnx")
    layout = InputsLayout.from_json(props[INPUTS_KEY])
    assert layout.block == 2 and layout.channels == 104 and len(layout.slots) == 100
    cuts = BlockLayout.from_json(props[BLOCK_KEY]).cuts  # the decoder blocks' skips are not in phases
    assert [c.skip_phases for c in cuts] == [1] * (len(cuts) - 1) + [2] and cuts[-1].stage == "output_block"
    assert not [n for n in model.graph.node if n.op_type in ("DepthToSpace", "AveragePool")]
    seq = open_sequence(SAMPLE)
    fp32, int8 = (Pipeline(PipelineConfig(artifacts=str(d), precision=p)) for p in ("fp32", "int8"))
    for i in range(3):
        layers = seq.inputs(i)
        a, b = fp32(layers, seq.frames[i].camera_cut).output, int8(layers, seq.frames[i].camera_cut).output
        assert psnr(b, a) > 40.0  # measured 60-61 dB
