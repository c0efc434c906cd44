"""The README's snippets run as written: its Python blocks against the shipped checkpoint's
artifacts (a temporary out/artifacts) and the bundled sample, the server block against a
server started here, and the Blender block in Blender's environment."""

import re
import subprocess
import sys
import threading

import pytest

from .conftest import ROOT

README = (ROOT / "README.md").read_text()


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, re.S)


def _run(code: str, artifacts) -> str:
    """``code`` in a new interpreter at the repository root, out/artifacts meaning ``artifacts``."""
    code = code.replace('"out/artifacts"', repr(str(artifacts)))
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_the_readme_has_the_blocks_it_shows():
    assert README.startswith("# jnds-deploy\n\n```sh\nmake demo")
    assert len(_blocks("python")) == 3 and len(_blocks("sh")) == 2


def test_python_block(shipped_artifacts):
    code = next(b for b in _blocks("python") if "Pipeline(" in b)
    lines = _run(code, shipped_artifacts).splitlines()
    assert [line.split()[0] for line in lines] == [str(i) for i in range(8)]  # every frame of the sample
    assert all("(180, 320, 3)" in line for line in lines)


def test_server_block(shipped_artifacts):
    from jnds_deploy.serve import ServeConfig
    from jnds_deploy.serve.server import FrameServer, make_http_server

    fs = FrameServer(ServeConfig(artifacts=str(shipped_artifacts), port=0))
    httpd = make_http_server(fs)
    threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    try:
        code = next(b for b in _blocks("python") if "Client(" in b)
        code = code.replace("http://127.0.0.1:8765", f"http://127.0.0.1:{httpd.server_address[1]}")
        lines = _run(code, shipped_artifacts).splitlines()
        assert lines == [f"{i} (180, 320, 3)" for i in range(8)]
        from jnds_deploy.serve import Client

        assert Client(f"http://127.0.0.1:{httpd.server_address[1]}").metrics()["frames_served"] == 8
    finally:
        fs.close(timeout=10)
        httpd.shutdown()
        httpd.server_close()


def test_jnds_run_line(shipped_artifacts, tmp_path):
    """The usage block's `jnds run` line, as written but for its paths."""
    line = next(x for x in _blocks("sh")[1].splitlines() if x.startswith("jnds run "))
    cmd = line.split("#")[0].replace("out/artifacts", str(shipped_artifacts)).replace("out/run", str(tmp_path / "run"))
    proc = subprocess.run(
        [sys.executable, "-m", "jnds_deploy", *cmd.split()[1:], "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "(160x90 -> 320x180, int8)" in proc.stdout  # int8 by default
    assert len(list((tmp_path / "run").glob("*.exr"))) == 8


BLENDER = ROOT / ".venv-blender" / "bin" / "python"


@pytest.mark.slow
@pytest.mark.skipif(not BLENDER.exists(), reason="no .venv-blender (make setup)")
def test_blender_block(tmp_path):
    """The Blender block, copied literally after a scene is built (a tiny scene of the
    tests), renders inputs and references that `jnds import cycles` turns into a sequence."""
    block = next(b for b in _blocks("python") if "import bpy" in b)
    build = (ROOT / "tests" / "blender" / "tiny_scene.py").read_text().split("\nif __name__")[0]
    # the block as written, but for where "//" points (no .blend file here) and a cheap reference
    block = block.replace('"//jnds/', f'"{tmp_path}/jnds/').replace("spp=128", "spp=4")
    script = build + "\nbuild()\n" + block
    proc = subprocess.run([str(BLENDER), "-c", script], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = tmp_path / "seq"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "jnds_deploy",
            "import",
            "cycles",
            str(tmp_path / "jnds" / "raw"),
            "--out",
            str(out),
            "--reference",
            str(tmp_path / "jnds" / "ref"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    from jnds_deploy.io import open_sequence

    seq = open_sequence(out)
    assert len(seq) >= 2 and seq.has_reference
