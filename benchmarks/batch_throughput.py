"""Throughput of `jnds batch` on Ray: one worker, two workers, and two Ray nodes started on
this machine (`ray start --head`, `ray start --address`), with what limits scaling.

    python -m benchmarks.batch_throughput [--sequences 6]
        [--frames 8] [--size 640x360] [--runs 3] [--configs NAME ...] [--out benchmarks/results/batch_throughput]

The input: --sequences copies of the bundled sample resized to --size (motion scaled),
--frames frames each, no reference (so no metrics or contact sheet: the pipeline's work
only), int8. Each configuration runs the whole batch --runs times into a fresh output
directory; frames/s counts from the first sequence submitted to the last one finished
(the batch summary's wall_s), "with start" adds connecting to Ray and starting the
workers (their ONNX Runtime sessions). Medians of the runs. The two-node cluster is made
with Ray's own command line, each node given one CPU, and the batch connects with
--address; it is stopped afterwards.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import (
    RESULTS,
    ROOT,
    arguments,
    command_line,
    cpu_line,
    machine_info,
    parse,
    parse_size,
    resized_frames,
    tune_process,
    write_report,
)
from jnds_deploy.io import FrameInfo, SequenceWriter, open_sequence
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS

RAY = str(Path(sys.executable).with_name("ray"))
# (workers, threads)
CONFIGS = {"1 worker x 1 thread": (1, 1), "1 worker x 2 threads": (1, 2), "2 workers x 1 thread": (2, 1)}
TWO_NODES = "2 nodes x 1 worker x 1 thread"


def make_input(root: Path, n: int, frames: int, size: tuple[int, int]) -> None:
    seq = open_sequence(ROOT / "samples" / "orbit-160x90")
    layers = resized_frames(seq, size)
    for k in range(n):
        w = SequenceWriter(root / f"shot{k // 2}" / f"seq{k}", size, None)
        infos = []
        for i in range(frames):
            w.write_inputs(i, layers[i % len(layers)][0])
            infos.append(FrameInfo(i, seq.frames[i % len(seq)].jitter, i == 0))
        w.close(infos)


def run_batch(artifacts: str, root: Path, workers: int, threads: int, address: str | None) -> dict:
    import ray

    from jnds_deploy.cluster import BatchConfig, batch

    out = Path(tempfile.mkdtemp(prefix="batch-out-"))
    t0 = time.perf_counter()
    try:
        summary = batch(
            BatchConfig(
                artifacts=artifacts,
                input=str(root),
                output=str(out),
                precision="int8",
                workers=workers,
                threads=threads,
                address=address,
            ),
            progress=False,
        )
    finally:
        ray.shutdown()
        shutil.rmtree(out, ignore_errors=True)
    summary["with_start_s"] = time.perf_counter() - t0
    assert summary["counts"]["done"] == len(summary["sequences"]), summary["counts"]
    return summary


def two_nodes() -> str:
    """A head node and a worker node on this machine, one CPU each; returns the address."""
    port = "6399"
    subprocess.run(
        [
            RAY,
            "start",
            "--head",
            f"--port={port}",
            "--num-cpus=1",
            "--include-dashboard=false",
            "--disable-usage-stats",
        ],
        check=True,
        capture_output=True,
    )
    subprocess.run([RAY, "start", f"--address=127.0.0.1:{port}", "--num-cpus=1"], check=True, capture_output=True)
    import ray

    ray.init(address=f"127.0.0.1:{port}")
    for _ in range(100):  # the second node registers within seconds
        if len([n for n in ray.nodes() if n["Alive"]]) == 2:
            break
        time.sleep(0.2)
    nodes = len([n for n in ray.nodes() if n["Alive"]])
    ray.shutdown()
    if nodes != 2:
        raise SystemExit(f"the two-node cluster has {nodes} node(s)")
    return f"127.0.0.1:{port}"


def main() -> None:
    ap = arguments(
        __doc__,
        RESULTS / "batch_throughput",
        smoke={"sequences": 2, "frames": 2, "size": "64x32", "runs": 1, "configs": ["1 worker x 1 thread"]},
    )
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--sequences", type=int, default=6)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--configs", nargs="+", choices=(*CONFIGS, TWO_NODES), default=[*CONFIGS, TWO_NODES])
    args = parse(ap)
    tune_process()
    size = parse_size(args.size, 8)
    root = Path(tempfile.mkdtemp(prefix="batch-in-"))
    make_input(root, args.sequences, args.frames, size)
    results = {}
    try:
        for name in args.configs:
            if name == TWO_NODES:
                continue
            workers, threads = CONFIGS[name]
            runs = [run_batch(args.artifacts, root, workers, threads, None) for _ in range(args.runs)]
            results[name] = runs
            print(name, [f"{r['frames_per_s']:.2f}" for r in runs], flush=True)
        if TWO_NODES in args.configs:
            address = two_nodes()
            try:
                runs = [run_batch(args.artifacts, root, 2, 1, address) for _ in range(args.runs)]
                results[TWO_NODES] = runs
                print("2 nodes", [f"{r['frames_per_s']:.2f}" for r in runs], flush=True)
            finally:
                subprocess.run([RAY, "stop", "--force"], capture_output=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)

    info = machine_info()
    total = args.sequences * args.frames
    rows = {}
    for name, runs in results.items():
        rows[name] = {
            "frames_per_s": float(np.median([r["frames_per_s"] for r in runs])),
            "frames_per_s_runs": [r["frames_per_s"] for r in runs],
            "with_start_frames_per_s": float(np.median([total / r["with_start_s"] for r in runs])),
            "median_frame_ms": float(np.median([s["median_ms"] for r in runs for s in r["sequences"].values()])),
            "workers": runs[0]["workers"],
            "cluster_cpus": runs[0]["cluster_cpus"],
            # the Ray nodes that ran sequences, per run
            "nodes_used": [len({s["node_id"] for s in r["sequences"].values()}) for r in runs],
        }
    base = next(iter(rows.values()))["frames_per_s"]
    md = [
        "# `jnds batch` throughput on Ray\n",
        f"`{command_line()}`\n",
        f"Machine: {cpu_line(info)}, {info['usable_cores']} usable cores. {args.sequences} sequences of "
        f"{args.frames} frames at {size[0]}x{size[1]} -> {2 * size[0]}x{2 * size[1]}, int8, no reference; "
        f"medians of {args.runs} runs.\n",
        f"| configuration | frames/s | x {next(iter(rows))} | frames/s with Ray and worker start "
        "| median ms per frame in a worker "
        "| Ray nodes used |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, r in rows.items():
        md.append(
            f"| {name} | {r['frames_per_s']:.2f} | {r['frames_per_s'] / base:.2f} | "
            f"{r['with_start_frames_per_s']:.2f} | {r['median_frame_ms']:.0f} | "
            f"{', '.join(map(str, r['nodes_used']))} |"
        )
    write_report(
        Path(args.out),
        {
            "machine": info,
            "command": command_line(),
            "size": list(size),
            "sequences": args.sequences,
            "frames": args.frames,
            "results": rows,
            "runs": {
                k: [{kk: v for kk, v in r.items() if kk != "config"} for r in runs] for k, runs in results.items()
            },
        },
        "\n".join(md) + "\n",
    )
    print("\n".join(md))


if __name__ == "__main__":
    main()
