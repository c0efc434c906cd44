"""What the benchmark scripts share: the machine a report was made on, the process tuned as
`jnds run` tunes its own, timed repeats and their summaries, frames at a benchmark's size,
their command line (``--out``, ``--smoke``) and writing a report.

The benchmarks are a package: run one from the repository root as a module, e.g.
``python -m benchmarks.timing``; each takes ``--smoke`` (a run of seconds on a tiny input,
its report into the ``--out`` given; ``tests/test_benchmarks.py`` runs them all).

Heavy modules (onnxruntime, numba, cv2, the runtime) are imported by the functions that
need them, so a script that renders or reads checkpoints pays nothing for them.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

import numpy as np

from jnds_deploy.process import brief_openmp_spin

# at import, not in tune_process: a script that imports torch (MAC counts, checkpoints) loads
# libgomp before its main() runs, and libgomp reads its spin count once, when loaded
brief_openmp_spin()

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

# --- the machine -------------------------------------------------------------------------

# instruction-set flags of /proc/cpuinfo that the pipeline's speed depends on
FLAGS = ("avx2", "fma", "f16c", "avx512f", "avx512_vnni", "avx_vnni", "amx_int8")
VERSIONS = ("onnxruntime", "numpy", "numba")
# int8 multiply-accumulates per cycle and core, by the widest int8 dot product the CPU
# has, assuming two vector multiply ports (server cores of the last years): AVX-512 VNNI
# vpdpbusd does 64 int8 MACs per instruction (16 lanes x 4) and AVX-VNNI 32; plain AVX2
# needs vpmaddubsw + vpmaddwd for 32 MACs (two multiply uops), so 32 per cycle. fp32 FMA
# does 16 MACs per 512-bit instruction, 8 per 256-bit one. AMD's Zen 4 (family 19h with
# AVX-512) has the instructions but a 256-bit datapath: each 512-bit instruction runs as two
# halves, so half these (``avx512_halves``; its 2048^3 GEMM here reached 403 int8 and 96 fp32
# GMAC/s on 2 cores at 2.6 GHz nominal: above the full-width 665 / 166 it could not be).
INT8_MACS_PER_CYCLE = {"avx512_vnni": 2 * 64, "avx_vnni": 2 * 32, "avx2": 32}


@functools.cache
def _cpuinfo() -> dict[str, str]:
    """The first processor's entries of /proc/cpuinfo (empty where there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return {}
    info: dict[str, str] = {}
    for line in text.split("\n\n")[0].splitlines():
        key, sep, value = line.partition(":")
        if sep:
            info.setdefault(key.strip(), value.strip())
    return info


def cpu_model() -> str:
    """The processor's model name (/proc/cpuinfo), else what ``platform`` knows."""
    return _cpuinfo().get("model name") or platform.processor() or platform.machine()


def cpu_flags() -> set[str]:
    return set(_cpuinfo().get("flags", "").split())


def usable_cores() -> int:
    """The cores this process may run on (its affinity; a container may get fewer than
    ``os.cpu_count``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def versions() -> dict[str, str | None]:
    """Python's version and the installed versions of the packages the timings depend on."""
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in VERSIONS:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def machine_info() -> dict:
    """The machine a report was made on: ``platform`` and ``cpu_count`` (the keys the
    reports always had), the CPU model, its usable cores, the instruction-set flags of
    ``FLAGS`` it has and the versions of ``VERSIONS``."""
    flags = cpu_flags()
    cpu = _cpuinfo()
    return {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "processor": cpu_model(),
        "cpu_family": cpu.get("cpu family"),
        "cpu_model": cpu.get("model"),
        "usable_cores": usable_cores(),
        "flags": [f for f in FLAGS if f in flags],
        "versions": versions(),
    }


def cpu_line(info: dict) -> str:
    """``machine_info``'s CPU for a report's text: model, family and the instruction sets
    that matter (the family tells the AMD EPYCs of these sessions apart: 25 Zen 4, 26 Zen 5)."""
    family = f"family {info['cpu_family']} model {info.get('cpu_model')}, " if info.get("cpu_family") else ""
    return f"{info['processor']} ({family}{', '.join(info['flags']) or 'no AVX2'})"


def machine_line() -> str:
    """The short machine description some reports keep in their ``machine`` key."""
    return f"{platform.machine()}, {usable_cores()} cores"


def cpu_peaks() -> dict:
    """Peak multiply-accumulates per second of this CPU, from its core count, clock and
    instruction set (``INT8_MACS_PER_CYCLE``). The clock is the nominal one /proc/cpuinfo
    reports (no turbo information under KVM), so the peak is an estimate. The cores are
    those this process may use: a 16-core machine pinned to 2 (``taskset``) peaks at 2's.
    AMX tiles (``amx_int8``) are named but not counted: the int8 peak is the vector
    units'; ``gemm_throughput`` shows what ONNX Runtime's GEMM gets from AMX."""
    cores = usable_cores()
    mhz = _cpuinfo().get("cpu MHz")
    flags = cpu_flags()
    ghz = (float(mhz) if mhz else 2000.0) / 1000
    isa = next((i for i in INT8_MACS_PER_CYCLE if i in flags), "avx2")
    halves = avx512_halves()
    width = 256 if halves or "avx512f" not in flags else 512
    int8 = INT8_MACS_PER_CYCLE[isa] // (2 if halves and isa == "avx512_vnni" else 1)
    fp32 = 2 * width // 32
    return {
        "cores": cores,
        "ghz": ghz,
        "avx512_vnni": "avx512_vnni" in flags,
        "amx_int8": "amx_int8" in flags,
        "int8_isa": isa,
        "avx512_halves": halves,
        "int8_gmacs": cores * ghz * int8,
        "fp32_fma_gmacs": cores * ghz * fp32,
        "derivation": f"cores x GHz x {int8} int8 MACs per cycle ({isa}"
        f"{', 512-bit instructions run as two 256-bit halves (Zen 4)' if halves else ''}) or "
        f"{fp32} fp32 MACs per cycle (two {width}-bit FMAs a cycle)"
        f"{'; AMX int8 tiles present, not counted' if 'amx_int8' in flags else ''}",
    }


def avx512_halves() -> bool:
    """Whether this CPU runs AVX-512 on a 256-bit datapath, two halves per instruction:
    AMD's Zen 4, /proc/cpuinfo family 25 (19h; its Zen 3 models have no AVX-512)."""
    info = _cpuinfo()
    return info.get("vendor_id") == "AuthenticAMD" and info.get("cpu family") == "25" and "avx512f" in cpu_flags()


def gemm_throughput(threads: int, n: int = 2048, runs: int = 10) -> dict:
    """What ONNX Runtime's own kernels (MLAS) reach here on one large matrix product, in
    GMAC/s, median of ``runs``: int8 ``MatMulInteger`` (u8 x s8, the pair the int8 graphs'
    convolutions use) and fp32 ``MatMul``, n x n x n. An attainable peak beside the nominal
    one of ``cpu_peaks``, whose clock /proc/cpuinfo states without turbo."""
    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper

    rng = np.random.default_rng(0)
    out = {"n": n, "runs": runs}
    for name, op, a, b, result in (
        (
            "int8",
            "MatMulInteger",
            rng.integers(0, 256, (n, n), dtype=np.uint8),
            rng.integers(-127, 128, (n, n), dtype=np.int8),
            TensorProto.INT32,
        ),
        (
            "fp32",
            "MatMul",
            rng.standard_normal((n, n), dtype=np.float32),
            rng.standard_normal((n, n), dtype=np.float32),
            TensorProto.FLOAT,
        ),
    ):
        graph = helper.make_graph(
            [helper.make_node(op, ["a", "b"], ["y"])],
            name,
            [helper.make_tensor_value_info("a", helper.np_dtype_to_tensor_dtype(a.dtype), [n, n])],
            [helper.make_tensor_value_info("y", result, [n, n])],
            [onnx.numpy_helper.from_array(b, "b")],
        )
        # the exported graphs' IR version: make_model writes the onnx package's newest, which
        # an older ONNX Runtime refuses (1.30 takes at most 13; onnx 1.23 writes 14)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
        sess.run(None, {"a": a})
        ms = []
        for _ in range(runs):
            t0 = time.perf_counter()
            sess.run(None, {"a": a})
            ms.append(time.perf_counter() - t0)
        out[f"{name}_gmacs"] = n**3 / float(np.median(ms)) / 1e9
    return out


def cpu_times() -> list[int]:
    """The aggregate CPU line of /proc/stat (user, nice, system, idle, iowait, irq, softirq, steal)."""
    with open("/proc/stat") as f:
        return [int(x) for x in f.readline().split()[1:9]]


class CpuSteal:
    """Virtual machines lose CPU to their host ("steal"): timings taken under steal are
    slower and noisier. ``share()``: the share of CPU time stolen since construction."""

    def __init__(self):
        self.start = cpu_times()

    def share(self) -> float:
        d = [b - a for a, b in zip(self.start, cpu_times())]
        return d[7] / max(1, sum(d))


# --- the process, tuned as `jnds run` tunes its own ----------------------------------------


def tune_process() -> None:
    """Tune this process as `jnds run` and `jnds serve` tune theirs
    (``jnds_deploy.process.tune_process``), so that timings compare with the committed
    reports. Call it first in ``main``, before anything compiles or runs a numba loop or
    builds a pipeline."""
    from jnds_deploy.process import tune_process as tune

    tune()


def pipeline(artifacts: str | Path, **config):
    """A ``Pipeline`` over ``artifacts`` configured as `jnds run` configures one
    (``keep_freed_memory``); ``config``: the other ``PipelineConfig`` fields."""
    from jnds_deploy.runtime import Pipeline, PipelineConfig

    return Pipeline(PipelineConfig(artifacts=str(artifacts), keep_freed_memory=True, **config))


# --- timed repeats -------------------------------------------------------------------------


def timed(fn: Callable, *args, **kwargs) -> tuple[Any, float]:
    """``fn(*args, **kwargs)`` and the milliseconds it took (wall clock)."""
    t0 = time.perf_counter()
    result = fn(*args, **kwargs)
    return result, 1000 * (time.perf_counter() - t0)


def interleaved(calls: dict[str, Callable[[], Any]], runs: int, warmup: int = 1) -> dict[str, list[float]]:
    """ms of each call over ``runs`` rounds, each round calling every one in turn, after
    ``warmup`` untimed calls each. Interleaving lets every call see the same machine
    state: these VMs drift within minutes (see benchmarks/results/timing.md)."""
    for fn in calls.values():
        for _ in range(warmup):
            fn()
    ms: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(runs):
        for name, fn in calls.items():
            ms[name].append(timed(fn)[1])
    return ms


def run_frames(
    runners: dict[str, Callable[[dict, bool], Any]], frames: list[tuple[dict, bool]]
) -> dict[str, list[tuple[Any, float]]]:
    """Every runner on every (layers, camera_cut) frame, interleaved: all run frame t
    before any runs frame t + 1 (each keeps its own history). Per runner: (result, wall
    ms) per frame."""
    out: dict[str, list[tuple[Any, float]]] = {name: [] for name in runners}
    for layers, cut in frames:
        for name, run in runners.items():
            out[name].append(timed(run, layers, cut))
    return out


def spread(values, prefix: str = "", suffix: str = "") -> dict[str, float]:
    """Median, 10th and 90th percentile: {prefix}median{suffix}, {prefix}p10{suffix},
    {prefix}p90{suffix} (``spread(ms, suffix="_ms")`` gives median_ms, p10_ms, p90_ms)."""
    v = np.asarray(values, np.float64)
    return {
        f"{prefix}median{suffix}": float(np.median(v)),
        f"{prefix}p10{suffix}": float(np.percentile(v, 10)),
        f"{prefix}p90{suffix}": float(np.percentile(v, 90)),
    }


def time_sessions(
    paths: dict[str, Path],
    feeds: dict,
    runs: int,
    threads: int,
    levels: dict[str, str],
    disabled: dict[str, list[str]] | None = None,
) -> dict:
    """Median and range (ms) of each ONNX graph run on ``feeds`` with ONNX Runtime's
    optimization ``levels[name]`` ("all" or "extended") and without the graph optimizers
    ``disabled[name]`` (as ``Pipeline.disabled_optimizers`` gives them), interleaved run by
    run in one process after a warm-up run each."""
    import onnxruntime as ort

    opt = {"all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL, "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED}
    sessions = {}
    for name, path in paths.items():
        o = ort.SessionOptions()
        o.intra_op_num_threads, o.inter_op_num_threads = threads, 1
        o.graph_optimization_level = opt[levels[name]]
        sessions[name] = ort.InferenceSession(
            str(path), o, providers=["CPUExecutionProvider"], disabled_optimizers=(disabled or {}).get(name) or None
        )
    ms = interleaved({name: functools.partial(s.run, None, feeds) for name, s in sessions.items()}, runs)
    return {
        name: {"median_ms": float(np.median(v)), "min_ms": float(np.min(v)), "max_ms": float(np.max(v)), "runs": v}
        for name, v in ms.items()
    }


# --- frames at a benchmark's size ----------------------------------------------------------


def parse_size(text: str, multiple: int = 1) -> tuple[int, int]:
    """ "1280x720" -> (1280, 720); exits with a message unless both are multiples of
    ``multiple`` (the network graphs take multiples of the artifacts' ``pad_multiple``)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise SystemExit(f"size {text!r}: expected WxH, e.g. 1280x720") from None
    if w < 1 or h < 1 or w % multiple or h % multiple:
        raise SystemExit(f"size {text!r}: width and height must be positive multiples of {multiple}")
    return w, h


def resized_frames(seq, size: tuple[int, int] | None) -> list[tuple[dict, bool]]:
    """The sequence's (layers, camera_cut) frames, optionally resized to ``size`` (W, H)
    (motion scaled with the image)."""
    import cv2

    frames = []
    for i in range(len(seq)):
        layers = seq.inputs(i)
        if size:
            sx = size[0] / seq.native_size[0]
            sy = size[1] / seq.native_size[1]
            out = {}
            for k, v in layers.items():
                r = cv2.resize(v, size, interpolation=cv2.INTER_LINEAR).reshape(size[1], size[0], -1)
                if k == "motion":
                    r = r * np.array([sx, sy], np.float32)
                out[k] = np.ascontiguousarray(r, np.float32)
            layers = out
        frames.append((layers, seq.frames[i].camera_cut))
    return frames


def network_feeds(seq_path: Path, size: tuple[int, int], guide: bool = False) -> dict[str, np.ndarray]:
    """The network graph's inputs from a real frame resized to ``size`` (history: the
    current inputs, as on a first frame; with ``guide``, the guide albedo, for a network
    that reads it: ``Manifest.guide_albedo``)."""
    import cv2

    from jnds_deploy.io import open_sequence
    from jnds_deploy.layout import CURRENT, GUIDE, N_HISTORY, guide_of

    layers = dict(open_sequence(seq_path).inputs(0))
    layers[GUIDE.name] = guide_of(layers)
    names = [n for n, _ in CURRENT] + ([GUIDE.name] if guide else [])
    x = np.concatenate(
        [cv2.resize(layers[n], size, interpolation=cv2.INTER_LINEAR).reshape(size[1], size[0], -1) for n in names], -1
    ).transpose(2, 0, 1)
    x = np.ascontiguousarray(x[None], np.float32)
    cur = np.ascontiguousarray(x[:, : -GUIDE.channels]) if guide else x
    feeds = {"current": cur, "history": np.ascontiguousarray(cur[:, :N_HISTORY])}
    if guide:
        feeds["guide"] = np.ascontiguousarray(x[:, -GUIDE.channels :])
    return feeds


# --- reports -------------------------------------------------------------------------------

SMOKE_HELP = (
    "a run of seconds on a tiny input, to check that the benchmark runs (CI: "
    "tests/test_benchmarks.py), with these settings in place of the defaults (flags given still "
    "win): {settings}; its report goes to --out, which must be given, outside benchmarks/results"
)


def arguments(
    doc: str,
    out: Path | None = None,
    out_help: str = "the report's path without suffix: .json and .md are written",
    smoke: dict[str, Any] | None = None,
) -> argparse.ArgumentParser:
    """A script's argument parser: its docstring as the help, ``--out`` (default ``out``,
    e.g. ``RESULTS / "timing"``) and, for a benchmark, ``--smoke``, whose settings ``smoke``
    holds ({dest: value}: what ``parse`` puts in place of the defaults)."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    if out is not None:
        ap.add_argument("--out", default=str(out), help=out_help)
    if smoke is not None:
        settings = ", ".join(f"{k}={v}" for k, v in smoke.items()) or "the defaults"
        ap.add_argument("--smoke", action="store_true", help=SMOKE_HELP.format(settings=settings))
        ap.set_defaults(_smoke=dict(smoke))
    return ap


def parse(ap: argparse.ArgumentParser) -> argparse.Namespace:
    """``ap``'s arguments. With ``--smoke``, the smoke settings ``arguments`` was given
    replace the defaults (flags given on the command line still win), and ``--out`` must
    lie outside benchmarks/results: a smoke run never overwrites a committed report."""
    args = ap.parse_args()
    if getattr(args, "smoke", False):
        ap.set_defaults(**args._smoke)
        args = ap.parse_args()
        out = Path(args.out).resolve()
        if out == RESULTS or out.is_relative_to(RESULTS):
            ap.error("--smoke writes a throwaway report: give --out outside benchmarks/results")
    vars(args).pop("_smoke", None)
    return args


def command_line() -> str:
    """This run's command as the reports quote it: ``python -m benchmarks.<name> <arguments>``
    for a benchmark (else ``python <script, relative to the repository> <arguments>``)."""
    script = Path(sys.argv[0]).resolve()
    if script.parent == ROOT / "benchmarks":
        return " ".join(["python", "-m", f"benchmarks.{script.stem}", *sys.argv[1:]])
    if script.is_relative_to(ROOT):
        script = script.relative_to(ROOT)
    return " ".join(["python", str(script), *sys.argv[1:]])


def write_text(path: Path, text: str) -> None:
    """``text`` at ``path``, atomically: a reader, or a run killed while writing, never
    leaves half a file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_report(out: Path, report: dict, markdown: str | None = None) -> None:
    """``out``.json (``report``, indent 1) and, if given, ``out``.md, each atomically;
    creates ``out``'s directory."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text(out.with_suffix(".json"), json.dumps(report, indent=1))
    if markdown is not None:
        write_text(out.with_suffix(".md"), markdown)
