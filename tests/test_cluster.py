"""``jnds batch`` and ``jnds dataset --address`` on a real local Ray (two CPUs): outputs equal
to ``jnds run``'s, nothing lost when a worker is SIGKILLed mid-sequence, complete sequences
skipped on a re-run, a bad sequence failing alone."""

import json
import os
import shutil
import signal

import numpy as np
import pytest

from jnds_deploy.io import open_sequence, read_exr
from jnds_deploy.runtime.pipeline import PipelineConfig
from jnds_deploy.runtime.run import run_sequence

from .conftest import SAMPLE, assert_same_sequences

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def local_ray():
    from jnds_deploy.cluster import connect

    connect(cpus=2)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    """ROOT with three sequences at different depths (copies of the sample, the last one
    cut to 4 frames) and ``jnds run``'s output of each, at one thread."""
    root = tmp_path_factory.mktemp("shots")
    for rel in ("shot1/a", "shot1/b", "c"):
        shutil.copytree(SAMPLE, root / rel)
    meta = json.loads((root / "c" / "sequence.json").read_text())
    meta["frames"], meta["frame_count"] = meta["frames"][:4], 4
    (root / "c" / "sequence.json").write_text(json.dumps(meta))
    for part in ("inputs", "reference"):
        for i in range(4, 8):
            (root / "c" / part / f"{i:04d}.exr").unlink()
    return root


def _frames(path, n):
    return [read_exr(path / f"{i:04d}.exr") for i in range(n)]


def _assert_same_as_run(artifacts, seq, out, tmp_path, precision="fp32"):
    ref = tmp_path / ("run-" + seq.name)
    run_sequence(
        PipelineConfig(artifacts=str(artifacts), precision=precision, threads=1),
        seq,
        ref,
        progress=False,
        metrics=False,
    )
    n = len(open_sequence(seq))
    for i, (a, b) in enumerate(zip(_frames(out, n), _frames(ref, n))):
        for k in b:
            np.testing.assert_allclose(a[k], b[k], atol=1e-4, rtol=0, err_msg=f"{seq} frame {i} {k}")


def test_batch_writes_what_run_writes_and_a_rerun_skips(local_ray, tiny_artifacts, shots, tmp_path):
    from jnds_deploy.cluster import SUMMARY, BatchConfig, batch

    cfg = BatchConfig(
        artifacts=str(tiny_artifacts[0]),
        precision="fp32",
        input=str(shots),
        output=str(tmp_path / "out"),
        workers=2,
        threads=1,
    )
    summary = batch(cfg, progress=False)
    assert summary["counts"] == {"done": 3, "skipped": 0, "failed": 0, "pending": 0}
    assert summary["frames_processed"] == 8 + 8 + 4
    assert json.loads((tmp_path / "out" / SUMMARY).read_text())["finished"]
    for rel in ("shot1/a", "shot1/b", "c"):
        assert summary["sequences"][rel]["attempts"] == 1
        _assert_same_as_run(tiny_artifacts[0], shots / rel, tmp_path / "out" / rel, tmp_path)

    # a re-run skips complete sequences; one with a frame missing is done again
    (tmp_path / "out" / "c" / "0002.exr").unlink()
    again = batch(cfg, progress=False)
    assert again["counts"] == {"done": 1, "skipped": 2, "failed": 0, "pending": 0}
    assert again["sequences"]["c"]["status"] == "done"
    _assert_same_as_run(tiny_artifacts[0], shots / "c", tmp_path / "out" / "c", tmp_path)


def test_a_worker_killed_mid_sequence_loses_nothing(local_ray, tiny_artifacts, shots, tmp_path):
    from jnds_deploy.cluster import BatchConfig, batch

    killed = []

    def kill_once(sequence, item):
        # SIGKILL the worker running shot1/b once it has written 3 frames
        if sequence == "shot1/b" and item["frame"] == 2 and not killed:
            killed.append(item["pid"])
            os.kill(item["pid"], signal.SIGKILL)

    cfg = BatchConfig(
        artifacts=str(tiny_artifacts[0]),
        precision="fp32",
        input=str(shots),
        output=str(tmp_path / "out"),
        workers=2,
        threads=1,
    )
    summary = batch(cfg, progress=False, on_frame=kill_once)
    assert killed
    assert summary["counts"] == {"done": 3, "skipped": 0, "failed": 0, "pending": 0}
    rec = summary["sequences"]["shot1/b"]
    assert rec["attempts"] == 2 and len(rec["worker_deaths"]) == 1
    for rel in ("shot1/a", "shot1/b", "c"):
        _assert_same_as_run(tiny_artifacts[0], shots / rel, tmp_path / "out" / rel, tmp_path)


def test_a_bad_sequence_fails_alone_with_its_error(local_ray, tiny_artifacts, shots, tmp_path):
    from jnds_deploy.cluster import BatchConfig, batch

    root = tmp_path / "in"
    shutil.copytree(shots / "c", root / "good")
    shutil.copytree(shots / "c", root / "bad")
    (root / "bad" / "inputs" / "0001.exr").write_bytes(b"not an EXR")
    shutil.copytree(shots / "c", root / "nometa")
    (root / "nometa" / "sequence.json").write_text("{")
    summary = batch(
        BatchConfig(
            artifacts=str(tiny_artifacts[0]),
            precision="fp32",
            input=str(root),
            output=str(tmp_path / "out"),
            workers=1,
            threads=1,
        ),
        progress=False,
    )
    assert summary["sequences"]["good"]["status"] == "done"
    bad = summary["sequences"]["bad"]
    assert bad["status"] == "failed" and "0001.exr" in bad["error"]
    assert not (tmp_path / "out" / "bad" / "run.json").exists()
    nometa = summary["sequences"]["nometa"]
    assert nometa["status"] == "failed" and "sequence.json" in nometa["error"]


def test_batch_errors_name_the_bad_argument(tmp_path, tiny_artifacts):
    from jnds_deploy.cluster import BatchConfig, batch
    from jnds_deploy.errors import ConfigError

    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="no sequence"):
        batch(
            BatchConfig(
                artifacts=str(tiny_artifacts[0]),
                precision="fp32",
                input=str(tmp_path / "empty"),
                output=str(tmp_path / "o"),
            ),
            progress=False,
        )
    with pytest.raises(ConfigError, match="threads"):
        BatchConfig(artifacts="a", input="b", output="c", threads=0)


def test_dataset_on_ray_renders_what_one_process_renders(local_ray, tmp_path, monkeypatch):
    pytest.importorskip("mitsuba")
    from jnds_deploy.render import RenderConfig, dataset

    specs = [
        (f"train/s{i}", RenderConfig(scene="procedural", seed=30 + i, camera="orbit", frames=2, size=(32, 18), spp=4))
        for i in range(2)
    ]
    monkeypatch.setattr(dataset, "dataset_specs", lambda split, n, engine="mitsuba", moving=0, mixed=0, lights=0: specs)
    one = dataset.render_dataset(tmp_path / "one", jobs=1, progress=False)
    on_ray = dataset.render_dataset(tmp_path / "ray", address="local", progress=False)
    assert sorted(p.name for p, _ in on_ray) == [p.name for p, _ in one] == ["s0", "s1"]
    assert_same_sequences(tmp_path / "one", tmp_path / "ray", [rel for rel, _ in specs])
    assert dataset.render_dataset(tmp_path / "ray", address="local", progress=False) == []
