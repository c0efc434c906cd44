"""Peak memory and cold start of `jnds run`: fresh processes on 3-frame sequences at
several sizes, beside OIDN `balanced`'s per-frame time at the largest size.

    python -m benchmarks.memory [--sizes 320x180 640x360 1280x720]
        [--frames 3] [--runs 3] [--out benchmarks/results/memory]

For each size: the bundled sample's first frames resized to it (motion scaled) are
written as a sequence without reference; `jnds run --precision int8` runs on it --runs
times, each in a fresh process (`/usr/bin/time` reports its peak RSS; its wall time is
the cold start: interpreter, imports, ONNX Runtime sessions, numba's compilation or its
on-disk cache, reading and writing the frames). The process's own timings (run.json)
give the first frame and the steady-state frames apart. OIDN `balanced` runs in this
process on the largest size's frames (median of 5 after a warm-up). Medians of the runs.
Peak memory per input megapixel is (peak - the smallest size's peak) / (megapixels -
the smallest size's).
"""

from __future__ import annotations

import json
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
    timed,
    write_report,
)
from jnds_deploy.io import FrameInfo, SequenceWriter, open_sequence
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS

JNDS = str(Path(sys.executable).with_name("jnds"))


def write_sequence(path: Path, size: tuple[int, int], frames: int) -> list[dict]:
    seq = open_sequence(ROOT / "samples" / "orbit-160x90")
    layers = resized_frames(seq, size)[:frames]
    w = SequenceWriter(path, size, None)
    for i, (frame, _) in enumerate(layers):
        w.write_inputs(i, frame)
    w.close([FrameInfo(i, seq.frames[i].jitter, i == 0) for i in range(len(layers))])
    return [frame for frame, _ in layers]


def cold_run(artifacts: str, seq: Path, out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [
            "/usr/bin/time",
            "-f",
            "%M",
            JNDS,
            "run",
            "--artifacts",
            artifacts,
            "--input",
            str(seq),
            "--output",
            str(out),
            "--precision",
            "int8",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    wall = time.perf_counter() - t0
    report = json.loads((out / "run.json").read_text())
    frames = [f["total"] for f in report["frame_ms"]]
    return {
        "wall_s": wall,
        "peak_rss_mib": int(proc.stderr.strip().splitlines()[-1]) / 1024,
        "first_frame_ms": frames[0],
        "later_frames_ms": frames[1:],
    }


def main() -> None:
    ap = arguments(__doc__, RESULTS / "memory", smoke={"sizes": ["64x32", "128x64"], "frames": 2, "runs": 1})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--sizes", nargs="+", default=["320x180", "640x360", "1280x720"])
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--runs", type=int, default=3)
    args = parse(ap)
    from jnds_deploy import baselines

    sizes = [parse_size(s) for s in args.sizes]
    tmp = Path(tempfile.mkdtemp(prefix="memory-"))
    rows = {}
    try:
        for size in sizes:
            seq = tmp / f"seq-{size[0]}x{size[1]}"
            frames = write_sequence(seq, size, args.frames)
            runs = [cold_run(args.artifacts, seq, tmp / "out") for _ in range(args.runs)]
            rows[f"{size[0]}x{size[1]}"] = {
                "megapixels": size[0] * size[1] / 1e6,
                "runs": runs,
                "wall_s": float(np.median([r["wall_s"] for r in runs])),
                "peak_rss_mib": float(np.median([r["peak_rss_mib"] for r in runs])),
                "first_frame_ms": float(np.median([r["first_frame_ms"] for r in runs])),
                "steady_frame_ms": float(np.median([ms for r in runs for ms in r["later_frames_ms"]])),
            }
            print(
                size, rows[f"{size[0]}x{size[1]}"]["peak_rss_mib"], rows[f"{size[0]}x{size[1]}"]["wall_s"], flush=True
            )
        baselines.oidn(frames[0])  # warm-up
        oidn_ms = float(np.median([timed(baselines.oidn, frames[0])[1] for _ in range(5)]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    names = list(rows)
    small, large = rows[names[0]], rows[names[-1]]
    per_mp = (large["peak_rss_mib"] - small["peak_rss_mib"]) / (large["megapixels"] - small["megapixels"])
    info = machine_info()
    md = [
        "# Peak memory and cold start of `jnds run` (int8)\n",
        f"`{command_line()}`\n",
        f"Machine: {cpu_line(info)}, {info['usable_cores']} usable cores. A fresh `jnds run` process per run, "
        f"{args.frames} frames without reference; medians of {args.runs} runs.\n",
        "| native size | peak RSS (MiB) | process wall time (s) | first frame (ms) | later frames (ms) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name, r in rows.items():
        md.append(
            f"| {name} | {r['peak_rss_mib']:.0f} | {r['wall_s']:.2f} | {r['first_frame_ms']:.0f} | "
            f"{r['steady_frame_ms']:.0f} |"
        )
    md += [
        "",
        f"- Peak memory per input megapixel above {names[0]}: {per_mp:.0f} MiB.",
        f"- OIDN `balanced` at {names[-1]}, in this process: {oidn_ms:.0f} ms a frame; the {args.frames}-frame "
        f"`jnds run` process takes {large['wall_s']:.2f} s, {1000 * large['wall_s'] / oidn_ms:.1f}x that.",
    ]
    write_report(
        Path(args.out),
        {
            "machine": info,
            "command": command_line(),
            "frames": args.frames,
            "sizes": rows,
            "peak_mib_per_megapixel": per_mp,
            "oidn_balanced_ms": oidn_ms,
            "cold_start_over_oidn_frame": 1000 * large["wall_s"] / oidn_ms,
        },
        "\n".join(md) + "\n",
    )
    print("\n".join(md))


if __name__ == "__main__":
    main()
