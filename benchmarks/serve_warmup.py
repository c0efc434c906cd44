"""A stream's first frames in `jnds serve`, with and without `--warmup` at their size.

    python -m benchmarks.serve_warmup [--size 1280x720] [--frames 4]
        [--runs 3] [--out benchmarks/results/serve_warmup]

Each run is a fresh process that builds the server (``FrameServer``: its pipeline and the
warm-up it always does, one tiny frame), opens a stream and sends it the bundled
sample's first --frames frames resized to --size, timing each frame's ``denoise``
(queueing and the pipeline; no HTTP). Without --warmup the server has seen no frame of
that size; with ``warmup=(size,)`` it ran one before serving. The two kinds of process
alternate, --runs each; medians per frame index. Writes benchmarks/results/serve_warmup.md
and .json.
"""

from __future__ import annotations

import json
import subprocess
import sys
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
    write_report,
)
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS


def one_process(artifacts: str, size: tuple[int, int], frames: int, warmup: bool) -> dict:
    """In this (fresh) process: build time of the server and ms of each frame."""
    import time

    from benchmarks.common import resized_frames, tune_process
    from jnds_deploy.io import open_sequence
    from jnds_deploy.serve import FrameServer, ServeConfig

    tune_process()
    t0 = time.perf_counter()
    fs = FrameServer(
        ServeConfig(artifacts=artifacts, threads=2, warmup=(size,) if warmup else (), keep_freed_memory=True)
    )
    build_ms = 1000 * (time.perf_counter() - t0)
    stream = fs.open_stream()
    ms = []
    for layers, cut in resized_frames(open_sequence(ROOT / "samples" / "orbit-160x90"), size)[:frames]:
        t = time.perf_counter()
        fs.denoise(stream, layers, cut)
        ms.append(1000 * (time.perf_counter() - t))
    fs.close(timeout=10)
    return {"build_ms": build_ms, "frame_ms": ms}


def main() -> None:
    ap = arguments(__doc__, RESULTS / "serve_warmup", smoke={"size": "160x96", "frames": 2, "runs": 1})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--child", choices=("warmup", "none"), help=argparse_hidden())
    args = parse(ap)
    size = parse_size(args.size)
    if args.child:
        print(json.dumps(one_process(args.artifacts, size, args.frames, args.child == "warmup")))
        return
    runs = {"none": [], "warmup": []}
    for _ in range(args.runs):
        for kind in runs:
            out = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "benchmarks.serve_warmup",
                    "--artifacts",
                    args.artifacts,
                    "--size",
                    args.size,
                    "--frames",
                    str(args.frames),
                    "--child",
                    kind,
                ],
                capture_output=True,
                text=True,
                check=True,
                cwd=ROOT,
            )
            runs[kind].append(json.loads(out.stdout.strip().splitlines()[-1]))
    med = {
        k: {
            "build_ms": float(np.median([r["build_ms"] for r in v])),
            "frame_ms": np.median([r["frame_ms"] for r in v], axis=0).tolist(),
        }
        for k, v in runs.items()
    }
    w, h = size
    md = [
        "# A stream's first frames in `jnds serve`, with and without `--warmup`\n",
        f"`{command_line()}`\n",
        f"Machine: {cpu_line(machine_info())}, 2 threads. The sample's first {args.frames} frames at {w}x{h} "
        f"native through a new stream of a new server (`FrameServer`, int8, no HTTP); a fresh process per run, "
        f"{args.runs} runs each, alternating; medians.\n",
        "| server | build (s) | " + " | ".join(f"frame {i} (ms)" for i in range(args.frames)) + " |",
        "| --- | ---: |" + " ---: |" * args.frames,
    ]
    for k, label in (("none", "default warm-up (one tiny frame)"), ("warmup", f"`--warmup {w}x{h}`")):
        md.append(
            f"| {label} | {med[k]['build_ms'] / 1000:.2f} | "
            + " | ".join(f"{v:.0f}" for v in med[k]["frame_ms"])
            + " |"
        )
    md += [
        "",
        f"- First frame: {med['none']['frame_ms'][0]:.0f} ms without, {med['warmup']['frame_ms'][0]:.0f} ms "
        f"with the warm-up at its size, which costs {(med['warmup']['build_ms'] - med['none']['build_ms']):.0f}"
        " ms more at start-up.",
    ]
    write_report(
        Path(args.out),
        {"machine": machine_info(), "command": command_line(), "size": [w, h], "median": med, "runs": runs},
        "\n".join(md) + "\n",
    )
    print("\n".join(md))


def argparse_hidden() -> str:
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
