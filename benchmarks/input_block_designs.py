"""How fast an input block can run in int8 on this CPU: today's design against
space-to-depth ones, random weights, ONNX Runtime's profiler (issue 25's "network stages at
>= 50 % of the int8 peak").

    python benchmarks/input_block_designs.py [--size 1280x720] [--runs 10] [--out benchmarks/results/input_block_designs]

Designs (the packed u8 input, 25 channels padded to 32 as `runtime.reformat.pack_inputs`
writes it, is what each reads; the packing itself is not timed here):
- ``current``: `model.InputBlock`, a 1x1 projection 32 -> 16 and a 3x3 16 -> 16 at native
  resolution, then the 2x2 average pool for the U-Net;
- ``space-to-depth``: the packing writes each 2x2 block's 4 x 25 channels as 100 (no extra
  pass); a 1x1 projection 100 -> 32 and a 3x3 32 -> 32 at half resolution, about the same
  MACs a frame (the U-Net reads its 32 channels as they are, no pool; a depth-to-space would
  give the output block 8 native channels);
- ``space-to-depth, 1x1 to 16 (32), 3x3 to 64, phase mean``: `model.InputBlock`'s
  ``space_to_depth`` design: today's 16 native channels (a 2x2 block's four in 64) and the
  U-Net's 16 pooled ones (the four phases' mean, a 1x1 convolution here) from a projection of
  the 100 channels and one 3x3 convolution at half resolution;
- ``space-to-depth, one 3x3 to 32`` and ``to 64``: the same 100 channels, one 3x3 convolution
  at half resolution (a 6x6 window of native pixels), more MACs in the kernel MLAS runs
  fastest; 64 gives the output block today's 16 native channels by a depth-to-space.

Each is exported from PyTorch, quantized by ONNX Runtime (QDQ, u8 activations, symmetric s8
weights, as `jnds calibrate` writes them, the pool rewritten as its depthwise convolution) on
random inputs, and run at ORT_ENABLE_ALL on the session's threads; the profiler's medians of
the quantized convolution and pooling nodes (`runtime.profile.profile_stages`) are summed
(the input's QuantizeLinear, which the real graph does not have, is left out). Random weights: the speed of a design, not its accuracy, which needs training."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

from jnds_deploy.calibration import rewrite  # noqa: E402
from jnds_deploy.runtime.profile import profile_stages  # noqa: E402

COMPUTE = ("Conv", "Pool")  # op types counted: QLinearConv, NhwcQLinearConv, QLinearAveragePool, ...


class Current(nn.Module):
    def __init__(self):
        super().__init__()
        self.project, self.conv = nn.Conv2d(32, 16, 1), nn.Conv2d(16, 16, 3, padding=1)

    def forward(self, x):
        # only the pooled features out: a graph output cannot be the rewritten pool's input,
        # and the native ones are computed for it either way
        return nn.functional.avg_pool2d(torch.relu(self.conv(torch.relu(self.project(x)))), 2)


class SpaceToDepth(nn.Module):
    def __init__(self):
        super().__init__()
        self.project, self.conv = nn.Conv2d(100, 32, 1), nn.Conv2d(32, 32, 3, padding=1)

    def forward(self, x):
        return torch.relu(self.conv(torch.relu(self.project(x))))


class SpaceToDepthProjected(nn.Module):
    """`model.InputBlock` with ``input_block="space_to_depth"``: a 1x1 projection 100 -> hidden,
    a 3x3 hidden -> 64 (today's 16 native channels in 2x2 phases) and the U-Net's input as the
    mean of the four phases (the pool's values, a 1x1 convolution with fixed weights)."""

    def __init__(self, hidden: int):
        super().__init__()
        self.project, self.conv = nn.Conv2d(100, hidden, 1), nn.Conv2d(hidden, 64, 3, padding=1)
        self.mean = nn.Conv2d(64, 16, 1, bias=False)
        with torch.no_grad():
            self.mean.weight.copy_(torch.eye(16).repeat_interleave(4, 1)[:, :, None, None] / 4)

    def forward(self, x):
        # the phase mean alone out, as `Current` gives the pool alone: the real graph hands the
        # native features on in u8, channels last (`calibration.block`), not as a float output
        return self.mean(torch.relu(self.conv(torch.relu(self.project(x)))))


class SpaceToDepth3x3(nn.Module):
    def __init__(self, width: int):
        super().__init__()
        self.conv = nn.Conv2d(100, width, 3, padding=1)

    def forward(self, x):
        return torch.relu(self.conv(x))


def designs(w: int, h: int) -> dict[str, tuple[nn.Module, tuple[int, ...], float]]:
    """name: (module, input shape, GMAC a frame)."""
    native, half = w * h, (w // 2) * (h // 2)
    return {"current": (Current(), (1, 32, h, w), native * (32 * 16 + 16 * 16 * 9) / 1e9),
            "space-to-depth": (SpaceToDepth(), (1, 100, h // 2, w // 2), half * (100 * 32 + 32 * 32 * 9) / 1e9),
            "space-to-depth, one 3x3 to 32": (SpaceToDepth3x3(32), (1, 100, h // 2, w // 2), half * 100 * 32 * 9 / 1e9),
            "space-to-depth, one 3x3 to 64": (SpaceToDepth3x3(64), (1, 100, h // 2, w // 2), half * 100 * 64 * 9 / 1e9),
            **{f"space-to-depth, 1x1 to {k}, 3x3 to 64, phase mean": (
                SpaceToDepthProjected(k), (1, 100, h // 2, w // 2), half * (100 * k + k * 64 * 9 + 64 * 16) / 1e9)
               for k in (16, 32)}}


def quantized(module: nn.Module, shape: tuple[int, ...], folder: Path) -> Path:
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    float_path, int8_path = folder / "float.onnx", folder / "int8.onnx"
    x = torch.rand(*shape)
    # not "inputs": runtime.profile would take a graph input of that name for the packed one
    torch.onnx.export(module.eval(), (x,), str(float_path), input_names=["x"], opset_version=17, dynamo=False)
    onnx.save(onnx.shape_inference.infer_shapes(onnx.load(str(float_path))), str(float_path))  # the rewrite needs them

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.left = [{"x": np.random.default_rng(i).random(shape, np.float32)} for i in range(2)]

        def get_next(self):
            return self.left.pop() if self.left else None

    quantize_static(str(float_path), str(int8_path), Reader(), quant_format=QuantFormat.QDQ,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                    extra_options={"WeightSymmetric": True, "ActivationSymmetric": False})
    model = onnx.load(str(int8_path))
    rewrite.pools_as_convolutions(model)  # as `jnds calibrate` does: the pool on MLAS's depthwise kernel
    rewrite.write_model(model, int8_path)
    return int8_path


def profile(path: Path, shape: tuple[int, ...], runs: int, threads: int) -> dict:
    """The quantized convolution and pooling nodes' medians (``runtime.profile``), summed."""
    by_node = profile_stages(path, {"x": np.random.default_rng(0).random(shape, np.float32)}, runs,
                             threads)["by_node_ms"]
    ops = {f"{k} ({v['op']})": v["ms"] for k, v in by_node.items() if any(c in v["op"] for c in COMPUTE)}
    return {"compute_ms": sum(ops.values()), "ops": ops}


def main() -> None:
    ap = common.arguments(__doc__, common.RESULTS / "input_block_designs")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    w, h = common.parse_size(args.size, 2)
    threads = common.usable_cores()
    peaks = common.cpu_peaks()
    torch.manual_seed(0)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (module, shape, gmac) in designs(w, h).items():
            folder = Path(tmp) / name
            folder.mkdir()
            r = profile(quantized(module, shape, folder), shape, args.runs, threads)
            r.update(gmac=gmac, gmacs=gmac / r["compute_ms"] * 1000)
            r["percent_of_peak"] = 100 * r["gmacs"] / peaks["int8_gmacs"]
            rows[name] = r
    lines = ["# Input block designs in int8 (random weights)", "",
             f"Command: `{common.command_line()}`  ", f"Machine: {common.cpu_line(common.machine_info())}; int8 peak "
             f"{peaks['int8_gmacs']:.0f} GMAC/s ({peaks['derivation']}).", "",
             f"{w}x{h}, {threads} threads, ORT_ENABLE_ALL; the profiler's quantized convolution and "
             f"pooling nodes, each the median of {args.runs} runs, summed; the input packing is not "
             "included (the timing report counts it in the input block row).", "",
             "| design | GMAC | compute ms | GMAC/s | % of int8 peak | nodes: median ms |",
             "| --- | ---: | ---: | ---: | ---: | --- |"]
    for name, r in rows.items():
        nodes = "; ".join(f"`{k}` {v:.2f}" for k, v in r["ops"].items())
        lines.append(f"| {name} | {r['gmac']:.2f} | {r['compute_ms']:.2f} | {r['gmacs']:.0f} | "
                     f"{r['percent_of_peak']:.0f} | {nodes} |")
    common.write_report(Path(args.out), {"command": common.command_line(), "machine": common.machine_info(),
                                         "peaks": peaks, "size": [w, h], "designs": rows},
                        "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
