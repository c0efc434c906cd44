"""Every benchmark imports and runs: ``python -m benchmarks.<name> --smoke`` (a tiny input,
seconds) exits 0 and writes its report, with the keys the committed reports have, into the
--out given here (never benchmarks/results)."""

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass

import pytest

from .conftest import ROOT


@dataclass(frozen=True)
class Smoke:
    keys: frozenset[str]  # keys of the JSON report
    out: str = ""  # --out below the test's directory; "" -> the benchmark's name
    json: str = ""  # the JSON report below that directory; "" -> out + ".json"
    markdown: bool = True  # a .md beside the JSON
    artifacts: bool = True  # takes --artifacts (exported and calibrated)
    needs: tuple[str, ...] = ()  # modules of the extras it imports
    slow: bool = False  # about 10 s or more on 2 cores: marked `slow`, which `make test` runs all the same


def _keys(*names: str) -> frozenset[str]:
    return frozenset(names)


SMOKES = {
    "adaptive": Smoke(
        _keys("command", "sequences", "native_720p", "size"),
        out="adaptive",
        json="adaptive/adaptive.json",
        needs=("flip_evaluator", "skimage"),
        slow=True,
    ),
    "batch_throughput": Smoke(_keys("command", "results", "runs", "size"), needs=("ray",)),
    "calibration": Smoke(
        _keys("command", "timing", "accuracy", "profiles"),
        artifacts=False,
        needs=("flip_evaluator", "skimage"),
        slow=True,
    ),
    "dataset_report": Smoke(
        _keys("command", "totals", "warped_mean"), out="dataset.md", json="dataset.json", artifacts=False
    ),
    "exposure_sweep": Smoke(_keys("command", "rows", "worst_int8_minus_fp32_db"), needs=("flip_evaluator",)),
    "exr_write": Smoke(_keys("command", "median_ms", "bytes", "exact")),
    "firefly_clamp": Smoke(_keys("command", "factors", "report"), needs=("flip_evaluator", "skimage")),
    "ghosting": Smoke(
        _keys("command", "mean", "sequences", "sheet", "video"),
        needs=("pyoidn", "flip_evaluator", "skimage", "imageio_ffmpeg"),
    ),
    "memory": Smoke(_keys("command", "sizes", "peak_mib_per_megapixel", "oidn_balanced_ms"), needs=("pyoidn",)),
    "render_timing": Smoke(
        _keys("command", "size", "spp2", "variant"),
        out="render_timing.json",
        json="render_timing.json",
        markdown=False,
        artifacts=False,
        needs=("mitsuba",),
    ),
    "serve_fuzz": Smoke(_keys("command", "statuses", "server_alive", "slow_clients")),
    "serve_load": Smoke(_keys("command", "results", "long", "server_metrics")),
    "serve_warmup": Smoke(_keys("command", "median", "runs")),
    "stability": Smoke(_keys("command", "long", "int8_range", "nan_floods", "fp16", "fuzz_frames", "fuzz_exr")),
    "timing": Smoke(_keys("command", "results", "cpu_peaks", "gemm_throughput", "copy_bandwidth_gb_s"), slow=True),
    "tradeoff": Smoke(
        _keys("command", "methods", "head_to_head"),
        needs=("pyoidn", "flip_evaluator", "skimage", "matplotlib"),
        slow=True,
    ),
    "train_throughput": Smoke(_keys("command", "phases_s", "step_s", "patches_per_s"), artifacts=False, slow=True),
}


def test_every_benchmark_has_a_smoke_run():
    names = {p.stem for p in (ROOT / "benchmarks").glob("*.py")} - {"__init__", "common"}
    assert names == set(SMOKES)


def _env() -> dict[str, str]:
    """This checkout's package and benchmarks first, whatever the environment has installed."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=[pytest.mark.slow] if s.slow else []) for n, s in SMOKES.items()]
)
def test_smoke(name, tmp_path, request):
    smoke = SMOKES[name]
    for module in smoke.needs:
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"{module} is not installed (an extra of pyproject.toml)")
    if name == "memory" and not shutil.which("time", path="/usr/bin"):
        pytest.skip("/usr/bin/time is not installed")
    out = tmp_path / (smoke.out or name)
    cmd = [sys.executable, "-m", f"benchmarks.{name}", "--smoke", "--out", str(out)]
    if smoke.artifacts:
        cmd += ["--artifacts", str(request.getfixturevalue("shipped_artifacts"))]
    if name == "timing" and importlib.util.find_spec("pyoidn") is None:
        cmd.append("--no-oidn")
    proc = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = tmp_path / (smoke.json or f"{smoke.out or name}.json")
    assert smoke.keys <= set(json.loads(report.read_text())), sorted(json.loads(report.read_text()))
    if smoke.markdown:
        assert report.with_suffix(".md").read_text().startswith("# ")


def test_smoke_refuses_to_write_into_the_results():
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks.dataset_report", "--smoke"],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "outside benchmarks/results" in proc.stderr
