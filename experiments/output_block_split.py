"""What the int8 network graph would gain if its output block's upsampling and concatenation
ran outside ONNX Runtime, between two graphs.

In the int8 graph the output block dequantizes the decoder's u8 features (48 channels at
half resolution), resizes them bilinearly in float (a float tensor of 48 channels at native
resolution), quantizes the result and concatenates it with the input block's features
(QLinearConcat) before its 3x3 convolution: about 20 ms of a 47 ms output block at
1280x720 on the Zen 5 of stop 48, where the convolution itself runs near the CPU's int8
peak (benchmarks/results/timing-zen5.json, ``network_nodes``). This prototype cuts the
graph there:

- graph A: the shipped graph up to the decoder's and the input block's u8 features, as
  extra outputs (channels last, so ONNX Runtime's NHWC int8 layout needs no transpose);
- glue (numba): the bilinear 2x upsampling (half-pixel, edge clamped, as ONNX ``Resize``)
  from the u8 codes, requantized straight to the concatenation's scale, and the input
  block's features requantized beside it: one u8 channels-last tensor;
- graph B: the output block's convolution and head from that tensor.

    python experiments/output_block_split.py [--artifacts out/artifacts] [--size 1280x720] [--runs 9]

Times the whole graph against A + glue + B on one random packed input (the time does not
depend on the values), 2 threads, two interleaved rounds; checks that the head and the
other outputs come out bit-equal; prints JSON. Not in the runtime yet: docs/design-notes.md
("The output block's glue") says what landing it takes.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from numba import njit, prange
from onnx import TensorProto, helper, numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.common import cpu_line, machine_info, tune_process  # noqa: E402

DECODED = "/network/feature_extractor/decoders.1/Relu_1_output_0_QuantizeLinear_Output"
NATIVE = "/network/input_block/Relu_1_output_0_QuantizeLinear_Output"
CONCAT = "/network/output_block/Concat_output_0_QuantizeLinear_Output"


@njit(parallel=True)
def glue(dec, nat, sd, zd, sn, zn, sc, zc, out):
    """out[y, x] = Q_c(bilinear 2x of DQ_d(dec)) then Q_c(DQ_n(nat)), u8 channels last."""
    h, w, cd = dec.shape
    H, W, cn = nat.shape
    kd, kn = np.float32(sd / sc), np.float32(sn / sc)
    zdf, znf, zcf = np.float32(zd), np.float32(zn), np.float32(zc)
    lo, hi, one = np.float32(0), np.float32(255), np.float32(1)
    xa, xb, fxs = np.empty(W, np.int64), np.empty(W, np.int64), np.empty(W, np.float32)
    for x in range(W):
        sx = (x + 0.5) * 0.5 - 0.5
        x0 = int(np.floor(sx))
        fxs[x] = np.float32(sx - x0)
        xa[x], xb[x] = min(max(x0, 0), w - 1), min(max(x0 + 1, 0), w - 1)
    for y in prange(H):
        sy = (y + 0.5) * 0.5 - 0.5
        y0 = int(np.floor(sy))
        fy = np.float32(sy - y0)
        ra, rb = dec[min(max(y0, 0), h - 1)], dec[min(max(y0 + 1, 0), h - 1)]
        for x in range(W):
            fx = fxs[x]
            w00, w01, w10, w11 = (one - fy) * (one - fx), (one - fy) * fx, fy * (one - fx), fy * fx
            a0, a1, b0, b1 = ra[xa[x]], ra[xb[x]], rb[xa[x]], rb[xb[x]]
            o = out[y, x]
            for c in range(cd):
                v = (w00 * (np.float32(a0[c]) - zdf) + w01 * (np.float32(a1[c]) - zdf)
                     + w10 * (np.float32(b0[c]) - zdf) + w11 * (np.float32(b1[c]) - zdf))
                o[c] = np.uint8(min(max(np.rint(v * kd) + zcf, lo), hi))
            n = nat[y, x]
            for c in range(cn):
                o[cd + c] = np.uint8(min(max(np.rint((np.float32(n[c]) - znf) * kn) + zcf, lo), hi))


def split(src: Path, tmp: Path) -> tuple[Path, Path, dict]:
    """Graph A and graph B files cut from ``src``, and the glue's quantization parameters."""
    model = onnx.load(str(src))
    inits = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    producers = {o: n for n in model.graph.node for o in n.output}

    def qparams(t):
        n = producers[t]
        return float(inits[n.input[1]]), int(inits[n.input[2]])

    q = dict(zip(("sd", "zd"), qparams(DECODED))) | dict(zip(("sn", "zn"), qparams(NATIVE))) \
        | dict(zip(("sc", "zc"), qparams(CONCAT)))
    g = model.graph
    keep = [o.name for o in g.output if o.name != "head"]
    g.node.extend([helper.make_node("Transpose", [DECODED], ["decoded"], perm=[0, 2, 3, 1]),
                   helper.make_node("Transpose", [NATIVE], ["native"], perm=[0, 2, 3, 1])])
    g.output.extend([helper.make_tensor_value_info(n, TensorProto.UINT8, None) for n in ("decoded", "native")])
    onnx.save(model, str(tmp / "a_full.onnx"))
    a = onnx.utils.Extractor(onnx.load(str(tmp / "a_full.onnx"))).extract_model(["inputs"], keep + ["decoded", "native"])
    onnx.save(a, str(tmp / "a.onnx"))
    model = onnx.load(str(src))
    g = model.graph
    dq = next(n for n in g.node if CONCAT in n.input)
    dq.input[0] = "block_nchw"
    g.node.insert(0, helper.make_node("Transpose", ["block"], ["block_nchw"], perm=[0, 3, 1, 2]))
    g.input.append(helper.make_tensor_value_info("block", TensorProto.UINT8, ["N", "H", "W", "C"]))
    onnx.save(model, str(tmp / "b_full.onnx"))
    b = onnx.utils.Extractor(onnx.load(str(tmp / "b_full.onnx"))).extract_model(["block"], ["head"])
    onnx.save(b, str(tmp / "b.onnx"))
    return tmp / "a.onnx", tmp / "b.onnx", q


def session(path: Path, threads: int):
    o = ort.SessionOptions()
    o.intra_op_num_threads, o.inter_op_num_threads = threads, 1
    o.enable_mem_pattern = False
    o.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(str(path), o, providers=["CPUExecutionProvider"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--artifacts", default="out/artifacts")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--runs", type=int, default=9)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    tune_process()  # numba and malloc as `jnds run` sets them (the glue allocates per frame)
    w, h = map(int, args.size.split("x"))
    src = Path(args.artifacts) / "network.int8.qat.onnx"
    with tempfile.TemporaryDirectory() as tmp:
        a_path, b_path, q = split(src, Path(tmp))
        full, a, b = (session(p, args.threads) for p in (src, a_path, b_path))
    x = np.random.default_rng(0).integers(0, 256, (1, h, w, full.get_inputs()[0].shape[3]), dtype=np.uint8)
    names = [o.name for o in full.get_outputs()]
    parts: dict[str, list[float]] = {"graph A": [], "glue": [], "graph B": []}

    def whole():
        return full.run(None, {"inputs": x})

    def cut():
        t0 = time.perf_counter()
        ra = dict(zip([o.name for o in a.get_outputs()], a.run(None, {"inputs": x})))
        t1 = time.perf_counter()
        dec, nat = ra.pop("decoded")[0], ra.pop("native")[0]
        block = np.empty((nat.shape[0], nat.shape[1], dec.shape[2] + nat.shape[2]), np.uint8)
        glue(dec, nat, q["sd"], q["zd"], q["sn"], q["zn"], q["sc"], q["zc"], block)
        t2 = time.perf_counter()
        ra["head"] = b.run(None, {"block": block[None]})[0]
        t3 = time.perf_counter()
        for k, v in zip(parts, (t1 - t0, t2 - t1, t3 - t2)):
            parts[k].append(1e3 * v)
        return [ra[n] for n in names]

    report = {"cpu": cpu_line(machine_info()), "size": [w, h], "ort": ort.__version__, "runs": args.runs,
              "whole graph": [], "A + glue + B": []}
    ref, got = whole(), cut()
    report["bit_equal"] = all(np.array_equal(u, v) for u, v in zip(ref, got))
    for _ in range(2):  # interleaved: the host drifts
        for key, fn in (("whole graph", whole), ("A + glue + B", cut)):
            ms = []
            for _ in range(args.runs):
                t = time.perf_counter()
                fn()
                ms.append(1e3 * (time.perf_counter() - t))
            report[key].append(round(float(np.median(ms)), 1))
    report["parts_median_ms"] = {k: round(float(np.median(v)), 1) for k, v in parts.items()}
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
