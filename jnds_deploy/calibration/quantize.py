"""``jnds calibrate``: int8 QDQ graphs next to the fp32 ones.

Weights are per output channel, symmetric int8 (threshold max|w|, as in training);
activations per tensor, affine. Methods:

- ``qat``: the activation ranges learned in quantization-aware training (``qat_ranges.json``,
  written by ``jnds export``) fix the scale of every convolution input; the remaining
  tensors (convolution outputs before their ReLU is folded, pooling, concatenation) get
  min/max ranges from the calibration data. ONNX Runtime only fuses DequantizeLinear ->
  Conv -> QuantizeLinear into an int8 convolution when the output is quantized too, so
  a purely learned model would run in float.
- ``minmax``, ``percentile``, ``entropy``: ONNX Runtime static calibration over the feeds
  of ``collect_feeds`` (the fp32 pipeline run recurrently on real sequences).

Each run writes ``<graph>.int8.<method>.onnx`` and its pruned variants
(``<graph>.int8.<method>.no-<groups>.onnx``, ``export.prune``), ``calibration.<method>.json`` (the scale and
zero point of every quantized tensor, as data) and registers them in ``manifest.json``;
the last method calibrated is the pipeline's int8 default. It ends with a validation of
the int8 graphs against PyTorch fp32 on recorded calibration inputs.

A graph is written three times: by ONNX Runtime's quantizer; after ``rewrite.fast_int8``,
before it is pruned (``export.prune`` reads the file); and, for the network graph and each
of its variants with u8 edges, after ``u8_edges``' four surgeries, done on the model in
memory.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper

from ..artifacts import ACTIVATION_TYPES, MANIFEST, Block, Edge, Int8Graph, Manifest, file_hash, write_json
from ..errors import CalibrationError
from ..export.prune import INT8_VARIANT_TOL, validate_variant, write_variants
from ..options import option
from .block import cut_blocks
from .head_ranges import HEAD_NODE, RADIANCE, STOPS, channel_ranges, code_levels, quantize_head, raw_ranges
from .inputs import quantize_inputs
from .reader import FeedReader, collect_feeds
from .rewrite import fast_int8, write_model

METHODS = ("qat", "minmax", "percentile", "entropy")
# operators quantized: the convolutions and everything between them, so int8 tensors flow
# from one convolution to the next without a float round trip (ReLU folds into the
# quantized convolution output): the fastest in benchmarks/results/calibration.md
DEFAULT_OP_TYPES = ("Conv", "Relu", "MaxPool", "AveragePool", "Resize", "Concat")
# the 1x1 kernel heads at native and target resolution stay float (with u8 edges, the
# network graph's head is quantized after all, by calibration.head_ranges): their outputs go out
# of the graph as float anyway, and int8 there costs a transpose and a dequantization of
# every per-pixel kernel; they are a few percent of the MACs
FLOAT_NODES = ("/network/output_block/head/Conv", "/head/Conv")
# int8 vs PyTorch fp32 tolerances on real calibration inputs: kernels lie in [-1, 1],
# blend weights in [0, 1]; a mean error above this means a broken range, not rounding
INT8_ATOL = 1.0
INT8_MEAN_TOL = 0.03


@dataclass(frozen=True)
class CalibrateConfig:
    artifacts: str = option(help="a directory written by `jnds export`")
    data: tuple[str, ...] = option(help="sequences, or directories of sequences", nargs="+")
    method: str = option(
        "qat",
        "qat: the activation ranges learned in quantization-aware training (the rest "
        "from the data); minmax, percentile, entropy: ONNX Runtime's static calibration",
        choices=METHODS,
    )
    activation_type: str = option("u8", "the int8 activations' type", choices=ACTIVATION_TYPES)
    op_types: tuple[str, ...] = DEFAULT_OP_TYPES
    float_nodes: tuple[str, ...] = FLOAT_NODES
    frames: int | None = option(None, "at most this many frames per sequence (default: all)")
    percentile: float = 99.999
    checkpoint: str | None = option(None, "PyTorch reference for validation (default: the manifest's)")
    threads: int = option(2, "ONNX Runtime threads")
    verbose: bool = option(False, "print every validated output's difference (default: one summary line)")
    # the int8 network graph's edges in u8 (u8 activations only): its input the packed,
    # quantized preprocessing of the input block (calibration.inputs), its output the
    # output block's head, read by the filter stage (calibration.head_ranges). False: both stay
    # float, the head as FLOAT_NODES says
    u8_edges: bool = option(
        True,
        "keep the input block's preprocessing and the output block's head float "
        "(default: the graph takes u8 inputs packed by the runtime and gives the head's u8 "
        "output to the filters)",
        flag="--float-edges",
        action="store_false",
    )

    def __post_init__(self):
        if self.method not in METHODS:
            raise CalibrationError(f"unknown method {self.method!r}, expected one of {', '.join(METHODS)}")
        if self.activation_type not in ACTIVATION_TYPES:
            raise CalibrationError(f"activation type must be u8 or s8, got {self.activation_type!r}")
        if not self.data:
            raise CalibrationError("no calibration sequences given (--data SEQ ...)")


def quantize_graph(
    fp32_path: Path,
    out_path: Path,
    feeds: list[dict[str, np.ndarray]],
    method: str,
    activation_type: str = "u8",
    op_types=DEFAULT_OP_TYPES,
    overrides: dict | None = None,
    percentile: float = 99.999,
    exclude: tuple[str, ...] = (),
    stops: tuple[float, ...] = (0,),
) -> None:
    """Static QDQ quantization of one graph; written atomically to ``out_path``. The
    calibrator sees every feed at each exposure 2^k of ``stops`` (``reader.FeedReader``)."""
    from onnxruntime.quantization import CalibrationMethod, QuantType

    calib = {
        "qat": CalibrationMethod.MinMax,
        "minmax": CalibrationMethod.MinMax,
        "percentile": CalibrationMethod.Percentile,
        "entropy": CalibrationMethod.Entropy,
    }[method]
    extra = {"CalibPercentile": percentile} if method == "percentile" else {}
    if overrides:
        extra["TensorQuantOverrides"] = overrides
    act = QuantType.QUInt8 if activation_type == "u8" else QuantType.QInt8
    # ONNX Runtime warns on the root logger to "consider pre-processing" (shape inference,
    # not needed here): that one message is dropped, the logger's level is left alone
    root_logger = logging.getLogger()
    root_logger.addFilter(_drop_preprocessing_advice)
    try:
        _quantize_static(fp32_path, out_path, FeedReader(feeds, stops, RADIANCE), calib, act, op_types, exclude, extra)
    finally:
        root_logger.removeFilter(_drop_preprocessing_advice)


def _drop_preprocessing_advice(record: logging.LogRecord) -> bool:
    return not str(record.msg).startswith("Please consider")


def _quantize_static(fp32_path, out_path, reader, calib, act, op_types, exclude, extra) -> None:
    from onnxruntime.quantization import QuantFormat, QuantType, quantize_static

    with tempfile.TemporaryDirectory(dir=out_path.parent) as tmp:
        tmp_out = Path(tmp) / out_path.name
        quantize_static(
            str(fp32_path),
            str(tmp_out),
            reader,
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            activation_type=act,
            weight_type=QuantType.QInt8,
            calibrate_method=calib,
            op_types_to_quantize=list(op_types),
            nodes_to_exclude=list(exclude),
            extra_options=extra,
        )
        os.replace(tmp_out, out_path)


def qat_overrides(ranges: dict[str, dict]) -> dict[str, list[dict]]:
    """TensorQuantOverrides from learned ranges: rmin/rmax give ONNX Runtime's scale and
    zero point the same arithmetic as training (scale = (hi - lo) / 255, zero point
    round(-lo / scale), shifted by -128 for s8)."""
    return {tensor: [{"rmin": np.float32(r["rmin"]), "rmax": np.float32(r["rmax"])}] for tensor, r in ranges.items()}


def follow_shared_ranges(fp32_path: Path, ranges: dict[str, dict], op_types) -> dict[str, dict]:
    """Move a learned range from the output of a quantized pooling node to its input.

    ONNX Runtime gives a quantized MaxPool/AveragePool output the scale of its input (the
    int8 kernels need that), so a range set on the output would be ignored; pooling does
    not widen the range, so the learned range is applied where the scale is decided."""
    producers = {o: n for n in onnx.load(str(fp32_path)).graph.node for o in n.output}
    out = {}
    for tensor, r in ranges.items():
        node = producers.get(tensor)
        while node is not None and node.op_type in ("MaxPool", "AveragePool") and node.op_type in op_types:
            tensor = node.input[0]
            node = producers.get(tensor)
        out[tensor] = r
    return out


def quantized_tensors(model: onnx.ModelProto) -> dict[str, dict]:
    """{tensor: {scale, zero_point, dtype, rmin, rmax}} of every activation QuantizeLinear."""
    inits = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    out = {}
    for node in model.graph.node:
        if node.op_type != "QuantizeLinear" or node.input[0] in inits:
            continue
        scale, zp = inits[node.input[1]], inits[node.input[2]]
        info = np.iinfo(zp.dtype)
        s, z = float(scale), int(zp)
        out[node.input[0]] = {
            "scale": s,
            "zero_point": z,
            "dtype": str(zp.dtype),
            "rmin": (info.min - z) * s,
            "rmax": (info.max - z) * s,
        }
    return out


def op_counts(path: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    for node in onnx.load(str(path)).graph.node:
        counts[node.op_type] = counts.get(node.op_type, 0) + 1
    return counts


def validate_int8(
    root: Path, manifest: Manifest, method: str, feeds: dict[str, list], checkpoint: str | None
) -> list[dict]:
    """Each int8 graph against PyTorch fp32 on up to three recorded inputs (first frame,
    middle, last), per output max/mean |diff| against INT8_ATOL / INT8_MEAN_TOL."""
    import onnxruntime as ort
    import torch

    from ..checkpoint import load_fp32_model
    from ..export.convert import validate_graph
    from ..filter_spec import to_phases
    from ..runtime.network import output_names, quiet

    ckpt = Path(checkpoint or manifest.checkpoint["path"])
    if not ckpt.is_file():
        raise CalibrationError(f"{ckpt}: checkpoint of these artifacts not found; pass --checkpoint")
    model = load_fp32_model(ckpt)
    fns = {
        "network": lambda names: lambda *x: tuple(model.network(*x)[k] for k in names),
        "upsample": lambda names: lambda c, f: to_phases(model.upsample_block(c, f), model.cfg.scale),
    }
    rows = []
    for name, g in manifest.graphs.items():
        path = root / g.int8[method].file
        names = output_names(ort.InferenceSession(str(path), quiet(), providers=["CPUExecutionProvider"]))
        recorded = feeds[name]
        for i in sorted({0, len(recorded) // 2, len(recorded) - 1}):
            f = {k: torch.from_numpy(v) for k, v in recorded[i].items()}
            rows += validate_graph(path, fns[name](names), f, names, INT8_ATOL, INT8_MEAN_TOL)
    return rows


def calibrate(cfg: CalibrateConfig, log=print) -> Manifest:
    """Write the int8 graphs of one method; returns the updated manifest."""
    from ..export.convert import report_validation

    root = Path(cfg.artifacts)
    if not (root / MANIFEST).is_file():
        raise CalibrationError(f"{root / MANIFEST}: missing; run `jnds export --out {root}` first")
    manifest = Manifest.load(root)
    overrides = {}
    if cfg.method == "qat":
        qpath = root / manifest.qat_ranges
        if not qpath.is_file():
            raise CalibrationError(f"{qpath}: missing; re-export with this version of `jnds export`")
        overrides = json.loads(qpath.read_text())

    feeds = collect_feeds(root, list(cfg.data), cfg.frames, cfg.threads)
    ranges, vrows, head_ranges = {}, [], {}
    for name, g in manifest.graphs.items():
        if not feeds[name]:
            raise CalibrationError(f"no calibration inputs recorded for graph {name!r}")
        file = f"{Path(g.file).stem}.int8.{cfg.method}.onnx"
        log(
            f"quantizing {g.file} -> {file} ({cfg.method}, {cfg.activation_type} activations, "
            f"{len(feeds[name])} calibration frames)"
        )
        learned = follow_shared_ranges(root / g.file, overrides.get(name, {}), cfg.op_types)
        # with float edges and learned ranges, the tensors left to the calibrator (the input
        # preprocessing's, the level heads' outputs) see the exposures the output block's head
        # is calibrated over (head.STOPS): ranged at exposure 1 alone, the preprocessing clipped
        # on brighter frames. With u8 edges the preprocessing is the runtime's, in the learned
        # range, and the same stops changed nothing but a little resolution (measured at
        # commit 0c8ead5; int8 against fp32 over exposures: benchmarks/results/exposure_sweep.md)
        stops = STOPS if cfg.method == "qat" and name == "network" and not cfg.u8_edges else (0,)
        quantize_graph(
            root / g.file,
            root / file,
            feeds[name],
            cfg.method,
            cfg.activation_type,
            cfg.op_types,
            qat_overrides(learned),
            cfg.percentile,
            cfg.float_nodes,
            stops,
        )
        model = onnx.load(str(root / file))
        if fast_int8(model):
            write_model(model, root / file)
        ranges[name] = quantized_tensors(model)
        if cfg.method == "qat":
            _check_overrides(file, learned, ranges[name])
        head = None
        if cfg.u8_edges and name == "network" and cfg.activation_type == "u8":
            raw = raw_ranges(model, feeds[name])
            head = channel_ranges(raw)
            head_ranges = {
                n: {"min": [float(v) for v in r[:, 0]], "max": [float(v) for v in r[:, 1]], **head[n]}
                for n, r in raw.items()
            }
        variants = write_variants(root, file, file[: -len(".onnx")])
        if head:  # after pruning: the variants slice the float head, then each is quantized
            for f in [file] + [v.file for v in variants.values()]:
                write_model(u8_edges(onnx.load(str(root / f)), head, manifest.pad_multiple, f), root / f)
        for v in variants.values():
            vrows += validate_variant(root / file, root / v.file, feeds[name][0], *INT8_VARIANT_TOL)
            v.sha256 = file_hash(root / v.file)
        g.int8[cfg.method] = Int8Graph(
            file=file,
            sha256=file_hash(root / file),
            activation_type=cfg.activation_type,
            weights="int8 per output channel, symmetric",
            op_types=list(cfg.op_types),
            float_nodes=[n for n in cfg.float_nodes if not (head and n == HEAD_NODE)],
            ranges=f"calibration.{cfg.method}.json",
            variants=variants,
            head=Edge.U8 if head else Edge.FLOAT,
            inputs=Edge.U8 if head else Edge.FLOAT,
            block=Block.CUT if head else Block.GRAPH,
            levels=Edge.U8 if head else Edge.FLOAT,
        )
    write_json(
        root / f"calibration.{cfg.method}.json",
        {
            "method": cfg.method,
            "activation_type": cfg.activation_type,
            "data": [str(d) for d in cfg.data],
            "frames_per_sequence": cfg.frames,
            "frames": {k: len(v) for k, v in feeds.items()},
            "tensors": ranges,
            "head": head_ranges,
            "head_stops": list(STOPS),
        },
    )
    manifest.int8_method = cfg.method
    rows = validate_int8(root, manifest, cfg.method, feeds, cfg.checkpoint) + vrows
    manifest.int8_validation[cfg.method] = rows
    manifest.save(root)
    report_validation(rows, log, cfg.verbose)
    return manifest


def u8_edges(
    model: onnx.ModelProto, head: dict[str, dict[str, list[float]]], multiple: int, label: str = "the graph"
) -> onnx.ModelProto:
    """The int8 network graph (or pruned variant) ``model`` with u8 edges, its layouts in its
    metadata (``artifacts.layouts``): its head quantized at the ranges ``head``
    (``calibration.head_ranges``), the input block's preprocessing cut off (``calibration.inputs``),
    the level heads ending in their codes (``head.code_levels``), and the graph cut at its
    upsamplings and concatenations (``calibration.block``; ``multiple``: the network's
    ``pad_multiple``). In this order: each surgery finds what the one before left."""
    model = quantize_head(model, head, label)
    model = quantize_inputs(model, label)
    model = code_levels(model, label)
    return cut_blocks(model, multiple, label)


def _check_overrides(file: str, learned: dict, got: dict) -> None:
    """Every learned range must have become the scale of its tensor (guards against the
    exporter renaming tensors and ONNX Runtime silently ignoring an override)."""
    bad = [
        t
        for t, r in learned.items()
        if t not in got or not np.isclose(got[t]["scale"], (r["rmax"] - r["rmin"]) / 255, rtol=1e-3)
    ]
    if bad:
        raise CalibrationError(f"{file}: learned ranges not applied to {len(bad)} tensor(s): {', '.join(bad[:5])}")
