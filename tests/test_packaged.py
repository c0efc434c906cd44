"""The packaged artifacts (jnds_deploy/checkpoints/artifacts): what a fresh export and
calibration of the shipped checkpoint writes, byte for byte, and enough to run the
pipeline in an environment without torch."""

import json
import os
import subprocess
import sys

import pytest

from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS

from .conftest import ROOT, SAMPLE


def test_the_packaged_artifacts_are_a_fresh_build(shipped_artifacts):
    """tools/package_artifacts.py made them from today's checkpoint and code: rerun it
    (`python -m tools.package_artifacts`) when either changes."""
    from pathlib import Path

    packaged = Path(SHIPPED_ARTIFACTS)
    names = sorted(p.name for p in packaged.iterdir())
    assert names == sorted(p.name for p in shipped_artifacts.iterdir())
    for name in names:
        if name.endswith(".json"):  # the same but for the paths of the machine that built them
            a, b = (json.loads((d / name).read_text()) for d in (packaged, shipped_artifacts))
            if name == "manifest.json":
                assert a.pop("checkpoint")["sha256"] == b.pop("checkpoint")["sha256"]
            if name.startswith("calibration."):
                assert [Path(p).name for p in a.pop("data")] == [Path(p).name for p in b.pop("data")]
            assert a == b, name
        else:
            assert (packaged / name).read_bytes() == (shipped_artifacts / name).read_bytes(), name


@pytest.mark.slow
def test_the_base_install_runs_without_torch(tmp_path):
    """`pip install .` (no extras) into a new environment: no torch, and `jnds run` denoises
    the sample with the packaged artifacts, int8; `jnds export` says what it needs."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    built = not (ROOT / "build").exists()  # setuptools builds in the source tree: removed after
    pip = subprocess.run(
        [str(py), "-m", "pip", "install", "-q", str(ROOT)], capture_output=True, text=True, timeout=1200, env=env
    )
    if built:
        import shutil

        shutil.rmtree(ROOT / "build", ignore_errors=True)
    assert pip.returncode == 0, pip.stderr[-3000:]
    probe = subprocess.run(
        [str(py), "-c", "import importlib.util as u; print(u.find_spec('torch'), u.find_spec('onnx'))"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    assert probe.stdout.split() == ["None", "None"], probe.stdout + probe.stderr
    jnds = venv / "bin" / "jnds"
    run = subprocess.run(
        [str(jnds), "run", "--input", str(SAMPLE), "--output", str(tmp_path / "out"), "--quiet"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert "(160x90 -> 320x180, int8)" in run.stdout
    assert len(list((tmp_path / "out").glob("*.exr"))) == 8 and (tmp_path / "out" / "run.json").exists()
    export = subprocess.run(
        [str(jnds), "export", "--out", str(tmp_path / "a")], capture_output=True, text=True, env=env, cwd=tmp_path
    )
    assert export.returncode == 2 and "jnds-deploy[train]" in export.stderr
