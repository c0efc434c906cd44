"""PyTorch -> ONNX conversion of the two graphs, their pruned variants, the manifest, and validation."""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..artifacts import Graph, Manifest, file_hash, write_json
from ..checkpoint import default_checkpoint, load_fp32_model
from ..errors import ValidationError
from ..filter_spec import to_phases
from ..layout import GUIDE
from ..model import CURRENT, HISTORY, JNDS, N_CURRENT, N_GUIDE, N_HISTORY, quant_ranges
from ..options import option
from .prune import validate_variant, write_variants

OPSET = 17
FIXED_CONVS = ("/input_block/mean/Conv",)  # Conv nodes of no QConv (model.PhaseMean)


@dataclass(frozen=True)
class ExportConfig:
    checkpoint: str | None = option(None, "the checkpoint to export (default: the shipped one)")
    out: str = option("artifacts", "the artifact directory to write", required=True)
    validate_size: tuple[int, int] = (96, 64)  # native W, H of the validation inputs
    atol: float = 1e-4  # max |ONNX Runtime - PyTorch| allowed per output (fp32)
    seed: int = 0
    verbose: bool = option(False, "print every validated output's difference (default: one summary line)")


class _NetworkGraph(torch.nn.Module):
    def __init__(self, model: JNDS, names: list[str]):
        super().__init__()
        self.network, self.names = model.network, names

    def forward(self, *inputs):
        out = self.network(*inputs)
        return tuple(out[k] for k in self.names)


def _validation_inputs(cfg: ExportConfig, model: JNDS) -> dict[str, torch.Tensor]:
    """The network graph's validation feeds: current, history and, for a model that reads
    it, the guide albedo (``guide``)."""
    g = torch.Generator().manual_seed(cfg.seed)
    w, h = cfg.validate_size
    m = model.cfg.pad_multiple
    w, h = w + (-w) % m, h + (-h) % m
    current = torch.rand(1, N_CURRENT, h, w, generator=g)
    current[:, :6] = current[:, :6] ** 4 * 50  # HDR-ish radiance with a long tail
    feeds = {"current": current, "history": torch.rand(1, N_HISTORY, h, w, generator=g)}
    if model.cfg.guide_albedo:
        feeds["guide"] = torch.rand(1, N_GUIDE, h, w, generator=g)
    return feeds


def validate_graph(
    onnx_path: Path,
    torch_fn,
    feeds: dict[str, torch.Tensor],
    names: list[str],
    atol: float,
    mean_tol: float | None = None,
) -> list[dict]:
    """Run ONNX Runtime and PyTorch on the same inputs; per output max/mean |diff| against
    ``atol`` (max) and ``mean_tol`` (mean, if given)."""
    import onnxruntime as ort

    from ..runtime.network import quiet, run_network

    sess = ort.InferenceSession(str(onnx_path), quiet(), providers=["CPUExecutionProvider"])
    out = run_network(sess, {k: v.numpy() for k, v in feeds.items()})
    got = [out[n] for n in names]
    with torch.no_grad():
        ref = torch_fn(*feeds.values())
    if isinstance(ref, torch.Tensor):
        ref = (ref,)
    rows = []
    for name, a, b in zip(names, got, ref):
        d = np.abs(a - b.numpy())
        ok = d.max() <= atol and (mean_tol is None or d.mean() <= mean_tol)
        rows.append(
            {
                "graph": onnx_path.name,
                "output": name,
                "max_abs": float(d.max()),
                "mean_abs": float(d.mean()),
                "atol": atol,
                "mean_tol": mean_tol,
                "ok": bool(ok),
            }
        )
    return rows


def export(cfg: ExportConfig, log=print) -> Manifest:
    """Write network.onnx, upsample.onnx (if scale > 1 and the upsample kernel is predicted)
    and manifest.json; validate."""
    ckpt = Path(cfg.checkpoint) if cfg.checkpoint else default_checkpoint()
    model = load_fp32_model(ckpt)  # int8 comes from `jnds calibrate`
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)

    feeds = _validation_inputs(cfg, model)
    current = feeds["current"]
    with torch.no_grad():
        net_out = model.network(*feeds.values())
    names = list(net_out)
    graphs = {}
    dyn = {2: "H", 3: "W"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            _NetworkGraph(model, names),
            tuple(feeds.values()),
            str(out / "network.onnx"),
            input_names=list(feeds),
            output_names=names,
            dynamic_axes={**{k: dyn for k in feeds}, **{n: dyn for n in names}},
            opset_version=OPSET,
            dynamo=False,
        )
    _constant_weights_as_initializers(out / "network.onnx")
    inputs = {
        "current": _layout(CURRENT, "native, linear as stored"),
        "history": _layout(HISTORY, "native, warped previous filtered outputs, linear"),
    }
    if "guide" in feeds:
        inputs["guide"] = _layout(((GUIDE.name, N_GUIDE),), "native, the frame's denoising_albedo, else its albedo")
    graphs["network"] = Graph(
        file="network.onnx",
        inputs=inputs,
        outputs={
            n: {"shape": ["N", int(net_out[n].shape[1]), _res(net_out[n], current), ""], "meaning": _meaning(n)}
            for n in names
        },
    )
    rows = validate_graph(
        out / "network.onnx", lambda *x: tuple(model.network(*x)[k] for k in names), feeds, names, cfg.atol
    )

    # one fixed kernel for every pixel: no graph, the manifest carries it (below)
    if model.upsample_block is not None and not model.cfg.fixed_upsample:
        comp = torch.rand(1, 3, *current.shape[-2:], generator=torch.Generator().manual_seed(cfg.seed + 1)) * 4
        feats = net_out["features"]
        s = model.cfg.scale
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            torch.onnx.export(
                model.upsample_block.polyphase(),
                (comp, feats),
                str(out / "upsample.onnx"),
                input_names=["composite", "features"],
                output_names=["kernel"],
                dynamic_axes={"composite": dyn, "features": dyn, "kernel": dyn},
                opset_version=OPSET,
                dynamo=False,
            )
        graphs["upsample"] = Graph(
            file="upsample.onnx",
            inputs={
                "composite": "N,3,H,W float32: albedo*diffuse+specular of the filtered signals, linear",
                "features": f"N,{feats.shape[1]},H,W float32: network output 'features'",
            },
            outputs={
                "kernel": {
                    "shape": ["N", s * s * 9, "H", "W"],
                    "layout": "phases",
                    "meaning": "3x3 kernel of every target pixel, clamped to [-1, 1], applied "
                    "to the bilinearly upsampled linear composite (with "
                    "model_config.upsample_root r > 1: its r-th root upsampled, "
                    "raised back to the power r), then ReLU; channel "
                    "(py * s + px) * 9 + tap at native (i, j) is target pixel "
                    "(s*i + py, s*j + px)",
                }
            },
        )
        # against the reference block, which convolves at target resolution
        rows += validate_graph(
            out / "upsample.onnx",
            lambda c, f: to_phases(model.upsample_block(c, f), s),
            {"composite": comp, "features": feats},
            ["kernel"],
            cfg.atol,
        )

    # pruned variants: the graphs adaptive execution runs when a frame skips a filter path
    # or the upsample block (export.prune)
    net_feeds = {k: v.numpy() for k, v in feeds.items()}
    graphs["network"].variants = write_variants(out, "network.onnx", "network")
    for v in graphs["network"].variants.values():
        rows += validate_variant(out / "network.onnx", out / v.file, net_feeds)
    for g in graphs.values():
        g.sha256 = file_hash(out / g.file)
        for v in g.variants.values():
            v.sha256 = file_hash(out / v.file)
    block_feeds = {"network": tuple(feeds.values())}
    if "upsample" in graphs:
        block_feeds["upsample"] = (comp, feats)
    fixed = None
    if model.cfg.fixed_upsample:
        with torch.no_grad():
            fixed = [float(v) for v in model.upsample_block(current, None).flatten()]
    manifest = Manifest(
        checkpoint={"path": str(ckpt), "sha256": file_hash(ckpt)},
        model_config=asdict(model.cfg),
        pad_multiple=model.cfg.pad_multiple,
        graphs=graphs,
        validation=rows,
        package_version=__version__,
        upsample_kernel=fixed,
    )
    write_json(out / manifest.qat_ranges, qat_ranges(model, graphs, out, block_feeds))
    manifest.save(out)
    report_validation(rows, log, cfg.verbose)
    return manifest


def _constant_weights_as_initializers(path: Path) -> None:
    """A convolution's weights that the exporter wrote as a Constant node (a module's buffer,
    ``model.PhaseMean``) made an initializer, as a parameter's are: ONNX Runtime's quantizer
    quantizes a Constant as an activation (u8, per tensor), which MLAS's symmetric int8
    convolution does not take (2.9 times the node's time at 720p, docs/performance.md)."""
    import onnx
    from onnx import numpy_helper

    model = onnx.load(str(path))
    g = model.graph
    consts = {n.output[0]: n for n in g.node if n.op_type == "Constant"}
    moved = [consts[n.input[1]] for n in g.node if n.op_type == "Conv" and n.input[1] in consts]
    for c in moved:
        g.initializer.append(numpy_helper.from_array(numpy_helper.to_array(c.attribute[0].t), c.output[0]))
        g.node.remove(c)
    if moved:
        onnx.save(model, str(path))


def qat_ranges(model: JNDS, graphs: dict[str, Graph], out: Path, feeds: dict[str, tuple]) -> dict:
    """The activation ranges learned in quantization-aware training, keyed by graph and by
    the ONNX tensor each one quantizes (the input of a Conv node): what `jnds calibrate
    --method qat` turns into QDQ scales. Convolutions are matched to Conv nodes by order
    of execution (the exporter traces in that order), checked against the node names."""
    import onnx

    blocks = {"network": model.network, "upsample": model.upsample_block}
    result = {}
    for name, g in graphs.items():
        block, order = blocks[name], []
        ranges = quant_ranges(block)
        hooks = [
            m.register_forward_pre_hook(lambda mod, inp, n=n: order.append(n))
            for n, m in block.named_modules()
            if n in ranges
        ]
        with torch.no_grad():
            block(*feeds[name])
        for h in hooks:
            h.remove()
        # a fixed convolution (model.PhaseMean) learned no range: its input is calibrated
        nodes = [
            n
            for n in onnx.load(str(out / g.file)).graph.node
            if n.op_type == "Conv" and not n.name.endswith(FIXED_CONVS)
        ]
        bad = [f"{n.name} <-> {m}" for n, m in zip(nodes, order) if not n.name.endswith(f"/{m.split('.')[-1]}/Conv")]
        if len(nodes) != len(order) or bad:
            raise ValidationError(
                [
                    {
                        "graph": g.file,
                        "output": "Conv nodes",
                        "ok": False,
                        "why": f"{len(nodes)} Conv nodes, {len(order)} convolutions run; "
                        f"mismatched: {', '.join(bad[:3]) or 'none'}",
                    }
                ]
            )
        result[name] = {
            node.input[0]: {
                "module": m,
                "rmin": min(ranges[m]["lo"], 0.0),
                "rmax": ranges[m]["hi"],
                "scale": ranges[m]["scale"],
                "zero_point_u8": ranges[m]["zero_point"],
            }
            for node, m in zip(nodes, order)
        }
    return result


def report_validation(rows: list[dict], log=print, verbose: bool = False) -> None:
    """One line: how many outputs passed and the largest difference, where; with
    ``verbose``, a check-mark line per output. One ValidationError lists every failure."""

    def line(r):
        tol = f"atol {r['atol']:.0e}" + (f", mean tol {r['mean_tol']:.0e}" if r.get("mean_tol") else "")
        return f"{r['graph']}:{r['output']} max |diff| {r['max_abs']:.2e} mean {r['mean_abs']:.2e} ({tol})"

    failures = [r for r in rows if not r["ok"]]
    if verbose:
        for r in rows:
            log(f"{'✓' if r['ok'] else '✗'} {line(r)}")
    elif rows:
        worst = max(rows, key=lambda r: r["max_abs"] / r["atol"])
        log(
            f"{'✓' if not failures else '✗'} {len(rows) - len(failures)} of {len(rows)} outputs within tolerance; "
            f"closest to its limit: {line(worst)}"
        )
    if failures:
        raise ValidationError(failures)


def _layout(layout, meaning: str) -> dict:
    chans, i = [], 0
    for name, c in layout:
        chans.append(f"{i}:{i + c} {name}")
        i += c
    return {"shape": ["N", i, "H", "W"], "channels": chans, "meaning": meaning}


def _res(t: torch.Tensor, current: torch.Tensor) -> str:
    f = current.shape[-1] // t.shape[-1]
    return "native" if f == 1 else f"native/{f}"


def _meaning(name: str) -> str:
    kind = name.split(".")[-1]
    return {
        "spatial": "3x3 kernel on the current signal",
        "temporal": "3x3 kernel on the warped history",
        "blend": "temporal blend weight in [0, 1]",
        "down": "3x3 kernel after 2x2 average pooling",
        "up": "3x3 kernel after bilinear upsampling",
        "up_blend": "blend of the upsampled result with the skip",
        "features": "upsample-block features (ReLU)",
    }.get(kind, kind)
