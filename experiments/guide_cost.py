"""What the guide albedo input (``ModelConfig.guide_albedo``) costs the int8 pipeline.

    .venv/bin/python experiments/guide_cost.py --plain out/artifacts --guided out/guided
        [--data data/val/cycles-sunroom-static-6000] [--size 1280x720] [--runs 21]
        [--out benchmarks/results/guide_cost]

The guide's three channels go into the padding of the int8 graph's u8 input (25 of 32
channels before, 28 after: ``calibration.inputs``), so the network's convolutions do the same
work; what is added is the guide's own conversion (``runtime.reformat.to_chw``) and its three
more channels in ``pack_inputs``. Timed two ways, at --size, all in one process, interleaved
(``common.interleaved``, ``common.run_frames``):

- the input packing alone, on the same frame: ``pack_inputs`` of current and history against
  ``to_chw`` of the guide plus ``pack_inputs`` with it (median of --runs);
- whole int8 frames of two pipelines, ``--plain`` (artifacts of a checkpoint without the
  input) and ``--guided`` (with it), frame after frame over the sequence's frames resized, twice.

--guided is any checkpoint trained with ``--guide-albedo``, exported and calibrated; its
weights do not change the time. Writes benchmarks/results/guide_cost.md and .json.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from benchmarks.common import (RESULTS, arguments, command_line, cpu_line, interleaved, machine_info,  # noqa: E402
                               parse_size, pipeline, resized_frames, run_frames, spread, tune_process, write_report)
from jnds_deploy.io import open_sequence  # noqa: E402
from jnds_deploy.layout import CURRENT, GUIDE, N_HISTORY, guide_of  # noqa: E402
from jnds_deploy.runtime.reformat import InputsLayout, pack_inputs, to_chw  # noqa: E402


def main() -> None:
    p = arguments(__doc__, RESULTS / "guide_cost")
    p.add_argument("--plain", default="out/artifacts")
    p.add_argument("--guided", required=True)
    p.add_argument("--data", default="data/val/cycles-sunroom-static-6000")
    p.add_argument("--size", default="1280x720")
    p.add_argument("--runs", type=int, default=21)
    args = p.parse_args()
    tune_process()
    size = parse_size(args.size, 16)
    frames = resized_frames(open_sequence(args.data), size)
    layers = frames[1][0]

    current = to_chw(layers, [n for n, _ in CURRENT])[None]
    history = np.ascontiguousarray(current[:, :N_HISTORY])
    plain, guided = InputsLayout(0.01, 0, 32, tuple(range(25))), InputsLayout(0.01, 0, 32, tuple(range(28)))

    def with_guide():
        guide = to_chw({GUIDE.name: guide_of(layers)}, [GUIDE.name])[None]
        return pack_inputs(current, history, guided, guide)

    pack = interleaved({"pack_inputs": lambda: pack_inputs(current, history, plain),
                        "to_chw(guide) + pack_inputs with it": with_guide}, args.runs, warmup=2)

    pipes = {"plain": pipeline(args.plain, precision="int8"), "guided": pipeline(args.guided, precision="int8")}
    assert pipes["guided"].guide_albedo and not pipes["plain"].guide_albedo
    runs = run_frames({k: (lambda f, c, p=p: p(f, c)) for k, p in pipes.items()}, frames + frames)
    # the first frame of each pass is a warm-up (a first frame has no history to warp)
    frame_ms = {k: [ms for i, (_, ms) in enumerate(r) if i % len(frames)] for k, r in runs.items()}

    report = {"command": command_line(), "machine": machine_info(), "size": list(size), "data": args.data,
              "pack": {k: spread(v, suffix="_ms") for k, v in pack.items()},
              "frame": {k: spread(v, suffix="_ms") for k, v in frame_ms.items()},
              "frame_ratio_median": float(np.median(np.array(frame_ms["guided"]) / np.array(frame_ms["plain"])))}
    md = [f"# The guide albedo input's cost (int8, {size[0]}x{size[1]} native)", "",
          f"Command: `{report['command']}`  ", f"Machine: {cpu_line(report['machine'])}, {report['machine']['usable_cores']} cores; "
          "the renders in the background paused (SIGSTOP) for the run", "",
          "| what | median ms | p10-p90 ms |", "| --- | ---: | ---: |"]
    for part in ("pack", "frame"):
        for k, s in report[part].items():
            md.append(f"| {part}: {k} | {s['median_ms']:.1f} | {s['p10_ms']:.1f}-{s['p90_ms']:.1f} |")
    md += ["", f"Frame by frame, guided / plain: median {report['frame_ratio_median']:.3f} "
           f"({len(frame_ms['plain'])} frames each, interleaved)."]
    write_report(args.out, report, "\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
