"""The pipeline's per-stage times with the working tree's code against an earlier revision's,
in the pipeline itself (not a loop alone on data the cache still holds).

    .venv/bin/python experiments/stage_ab.py --against 728a9d5 [--artifacts out/artifacts]
        [--input samples/orbit-160x90] [--size 1280x720] [--runs 4] [--repeats 3]
        [--out benchmarks/results/stage_ab]

The revision is checked out into a temporary git worktree. Each run is a fresh process per
code, alternated (A B A B ...): it imports ``jnds_deploy`` from its tree, runs the int8
pipeline over the input's frames resized to --size, --repeats passes (each from a reset
history; the first two frames of the first pass are a warm-up), tuned as `jnds run` tunes
itself, and prints the medians of the pipeline's own stage timings (``FrameResult.ms``). The
report gives each stage's median over the runs for both codes and the difference. Both use
the same artifacts (made by the working tree's `jnds export` and `jnds calibrate`): a
revision whose runtime reads them differently is not comparable here. Writes
benchmarks/results/stage_ab.md and .json.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(tree: str, artifacts: str, input_: str, size: str, repeats: int) -> None:
    """One run in this process, with ``jnds_deploy`` (and benchmarks.common) from ``tree``."""
    sys.path.insert(0, tree)
    import numpy as np

    from benchmarks.common import parse_size, pipeline, resized_frames, tune_process
    import jnds_deploy
    from jnds_deploy.io import open_sequence

    if not Path(jnds_deploy.__file__).resolve().is_relative_to(Path(tree).resolve()):
        raise SystemExit(f"jnds_deploy imported from {jnds_deploy.__file__}, not from {tree}")
    tune_process()
    frames = resized_frames(open_sequence(input_), parse_size(size))
    pipe = pipeline(artifacts, precision="int8", threads=2)
    ms: dict[str, list[float]] = {}
    for rep in range(repeats):
        pipe.reset()
        for i, frame in enumerate(frames):
            result = pipe(*frame)
            if rep or i >= 2:
                for k, v in result.ms.items():
                    ms.setdefault(k, []).append(v)
    print(json.dumps({k: float(np.median(v)) for k, v in ms.items()}))


def main() -> None:
    sys.path.insert(0, str(ROOT))
    import numpy as np

    from benchmarks.common import RESULTS, arguments, command_line, cpu_line, machine_info, write_report

    p = arguments(__doc__, RESULTS / "stage_ab")
    p.add_argument("--against", required=True, help="a git revision")
    p.add_argument("--artifacts", default="out/artifacts")
    p.add_argument("--input", default=str(ROOT / "samples" / "orbit-160x90"))
    p.add_argument("--size", default="1280x720")
    p.add_argument("--runs", type=int, default=4, help="processes per code, alternated")
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    rev = subprocess.run(["git", "rev-parse", "--short", args.against], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp) / "tree"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(old), rev], cwd=ROOT, check=True)
        try:
            trees = {"working tree": str(ROOT), rev: str(old)}
            runs: dict[str, list[dict]] = {name: [] for name in trees}
            for _ in range(args.runs):
                for name, tree in trees.items():
                    out = subprocess.run([sys.executable, __file__, "--child", tree, str(Path(args.artifacts).resolve()),
                                          args.input, args.size, str(args.repeats)],
                                         check=True, capture_output=True, text=True, cwd=tree).stdout
                    runs[name].append(json.loads(out.strip().splitlines()[-1]))
                    print(name, f"{runs[name][-1]['total']:.1f} ms", flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT, check=True)
    stages = list(runs["working tree"][0])
    med = {name: {s: float(np.median([r[s] for r in rs if s in r])) for s in stages} for name, rs in runs.items()}
    report = {"command": command_line(), "machine": machine_info(), "against": rev, "size": args.size,
              "runs": runs, "median_ms": med}
    md = [f"# Per-stage times in the pipeline: working tree against {rev}", "",
          f"Command: `{report['command']}`  ",
          f"Machine: {cpu_line(report['machine'])}, {report['machine']['usable_cores']} cores. Int8 pipeline, "
          f"{args.size} native, {args.runs} processes per code alternated, each the median over frames of "
          f"{args.repeats} passes; the table gives the median of the processes' medians.", "",
          f"| stage | {rev} ms | working tree ms | difference ms |", "| --- | ---: | ---: | ---: |"]
    for s in stages:
        a, b = med[rev][s], med["working tree"][s]
        md.append(f"| {s} | {a:.1f} | {b:.1f} | {b - a:+.1f} |")
    write_report(args.out, report, "\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(*sys.argv[2:6], int(sys.argv[6]))
    else:
        main()
