"""How ONNX Runtime's int8 convolution's time grows with its channel counts on this CPU: one
QDQ 3x3 (or kxk) convolution, u8 activations, s8 symmetric per-channel weights, ReLU, at
1280x720, 2 threads, timed by ONNX Runtime's profiler (its QLinearConv node, median of 7
after 3 warm-up runs). Each argument is CIN,COUT,K (docs/performance.md, stop 58).

    .venv/bin/python experiments/conv_channel_blocks.py 64,16,3 64,24,3 64,32,3
"""
import json, os, sys, tempfile, time
import numpy as np, onnx, onnxruntime as ort
from onnx import helper, TensorProto, numpy_helper
def model(cin, cout, k, H, W):
    rng = np.random.default_rng(0)
    w = rng.integers(-127, 128, (cout, cin, k, k)).astype(np.int8)
    inits = [numpy_helper.from_array(w, "w"), numpy_helper.from_array(np.full(cout, 0.01, np.float32), "ws"),
             numpy_helper.from_array(np.zeros(cout, np.int8), "wz"),
             numpy_helper.from_array(np.array(0.02, np.float32), "xs"), numpy_helper.from_array(np.array(128, np.uint8), "xz"),
             numpy_helper.from_array(np.array(0.5, np.float32), "ys"), numpy_helper.from_array(np.array(0, np.uint8), "yz"),
             numpy_helper.from_array(np.zeros(cout, np.float32), "b")]
    nodes = [helper.make_node("DequantizeLinear", ["x", "xs", "xz"], ["xf"]),
             helper.make_node("DequantizeLinear", ["w", "ws", "wz"], ["wf"], axis=0),
             helper.make_node("Conv", ["xf", "wf", "b"], ["yf"], pads=[k // 2] * 4),
             helper.make_node("Relu", ["yf"], ["yr"]),
             helper.make_node("QuantizeLinear", ["yr", "ys", "yz"], ["y"])]
    g = helper.make_graph(nodes, "c", [helper.make_tensor_value_info("x", TensorProto.UINT8, [1, cin, H, W])],
                          [helper.make_tensor_value_info("y", TensorProto.UINT8, [1, cout, H, W])], inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)]); m.ir_version = 8
    return m.SerializeToString()
H, W = 720, 1280
res = {}
for spec in sys.argv[1:]:
    cin, cout, k = map(int, spec.split(","))
    so = ort.SessionOptions(); so.intra_op_num_threads = 2; so.enable_profiling = True
    # the profile goes to a temporary folder, not the working directory
    so.profile_file_prefix = os.path.join(tempfile.mkdtemp(), "conv")
    s = ort.InferenceSession(model(cin, cout, k, H, W), so, providers=["CPUExecutionProvider"])
    x = np.random.default_rng(1).integers(0, 256, (1, cin, H, W)).astype(np.uint8)
    for _ in range(3): s.run(None, {"x": x})
    ts = []
    for _ in range(7):
        t = time.perf_counter(); s.run(None, {"x": x}); ts.append(time.perf_counter() - t)
    prof = json.load(open(s.end_profiling()))
    conv = [e["dur"] for e in prof if e.get("cat") == "Node" and e["name"].endswith("_kernel_time") and e["args"].get("op_name") in ("QLinearConv",)]
    ops = sorted({e["args"].get("op_name") for e in prof if e.get("cat") == "Node"})
    macs = cin * cout * k * k * H * W
    cm = np.median(conv[-7:]) / 1e3
    print(f"{cin:4d}->{cout:4d} k{k}: conv {cm:7.1f} ms  {macs/cm/1e6:6.1f} GMAC/s  total {1e3*np.median(ts):7.1f} ms  ops {ops}", flush=True)
