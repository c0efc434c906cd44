"""The int8 network's input packing (``runtime.reformat.pack_inputs``) against an earlier
revision's, on the same frame.

    .venv/bin/python experiments/pack_inputs.py --against 8fab7a7 [--against 1dca1ee ...]
        [--data data/val/cycles-sunroom-static-6000] [--size 1280x720] [--runs 41]
        [--out benchmarks/results/pack_inputs]

Each revision's ``jnds_deploy/runtime/reformat.py`` (``git show REV:...``) is loaded as a module
of the package beside the working tree's, and its ``pack_inputs`` packs the same current and
history (a real frame resized to --size, the history its first 12 channels, as on a first
frame) with the identity slots where it has slots (what a graph calibrated before stop 59
has; the placement does not change the work). The outputs must be bit-equal. Timed in one
process, interleaved (``common.interleaved``), median of --runs after 3 warm-up calls each,
the process tuned as `jnds run` tunes it (numba's threading layer, malloc keeping freed
memory). Writes benchmarks/results/pack_inputs.md and .json.
"""
from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the repository root

from benchmarks.common import (RESULTS, arguments, command_line, cpu_line, interleaved, machine_info,  # noqa: E402
                               parse_size, resized_frames, spread, tune_process, write_report)
from jnds_deploy.heap import keep_freed_memory  # noqa: E402
from jnds_deploy.io import open_sequence  # noqa: E402
from jnds_deploy.layout import CURRENT, N_HISTORY  # noqa: E402
from jnds_deploy.runtime import reformat  # noqa: E402

REL = "jnds_deploy/runtime/reformat.py"


def load_revision(rev: str, tmp: Path):
    """``reformat`` as it was at ``rev``, a module inside the package (its relative imports
    resolve to the working tree's modules)."""
    src = subprocess.run(["git", "show", f"{rev}:{REL}"], cwd=ROOT, check=True, capture_output=True, text=True).stdout
    name = f"_reformat_{rev}"
    path = ROOT / "jnds_deploy" / "runtime" / f"{name}.py"
    path.write_text(src)
    try:
        spec = importlib.util.spec_from_file_location(f"jnds_deploy.runtime.{name}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
    finally:
        path.unlink()  # numba compiles on first call from the module object, not the file
    return module


def layout_of(module, channels: int = 32):
    """The identity-slot layout in ``module``'s ``InputsLayout`` (no slots before stop 59)."""
    fields = module.InputsLayout.__dataclass_fields__
    return module.InputsLayout(0.01, 0, channels, *((tuple(range(25)),) if "slots" in fields else ()))


def main() -> None:
    p = arguments(__doc__, RESULTS / "pack_inputs")
    p.add_argument("--against", action="append", required=True, help="a git revision (repeatable)")
    p.add_argument("--data", default="data/val/cycles-sunroom-static-6000")
    p.add_argument("--size", default="1280x720")
    p.add_argument("--runs", type=int, default=41)
    args = p.parse_args()
    tune_process()
    keep_freed_memory()
    size = parse_size(args.size)
    layers = resized_frames(open_sequence(args.data), size)[1][0]
    current = reformat.to_chw(layers, [n for n, _ in CURRENT])[None]
    history = np.ascontiguousarray(current[:, :N_HISTORY])
    with tempfile.TemporaryDirectory() as tmp:
        modules = {"working tree": reformat, **{rev: load_revision(rev, Path(tmp)) for rev in args.against}}
    calls = {name: (lambda m=m: m.pack_inputs(current, history, layout_of(m))) for name, m in modules.items()}
    want = calls["working tree"]()
    equal = {name: bool(np.array_equal(fn(), want)) for name, fn in calls.items()}
    ms = interleaved(calls, args.runs, warmup=3)
    report = {"command": command_line(), "machine": machine_info(), "data": args.data, "size": list(size),
              "bit_equal": equal, "ms": {k: spread(v, suffix="_ms") for k, v in ms.items()}}
    md = [f"# Input packing at {size[0]}x{size[1]} (`runtime.reformat.pack_inputs`)", "",
          f"Command: `{report['command']}`  ",
          f"Machine: {cpu_line(report['machine'])}, {report['machine']['usable_cores']} cores; the renders in the "
          "background paused (SIGSTOP) for the run", "",
          "| code | median ms | p10-p90 ms | bit-equal to the working tree's |", "| --- | ---: | ---: | --- |"]
    for name, s in report["ms"].items():
        md.append(f"| {name} | {s['median_ms']:.1f} | {s['p10_ms']:.1f}-{s['p90_ms']:.1f} | "
                  f"{'yes' if equal[name] else 'NO'} |")
    write_report(args.out, report, "\n".join(md) + "\n")
    print("\n".join(md))
    for f in (ROOT / "jnds_deploy" / "runtime" / "__pycache__").glob("_reformat_*"):
        f.unlink()  # numba's on-disk cache of the revisions' loops


if __name__ == "__main__":
    main()
