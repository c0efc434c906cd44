"""Beyond one machine: ``jnds batch`` (every sequence under a directory through the
pipeline) and ``jnds dataset --address`` (the training data's sequences rendered), both
on Ray, a sequence being one unit of work (its history needs its frames in order).

Where the work runs: an embedded local Ray by default; a cluster with ``address`` (or
``RAY_ADDRESS``), whose nodes must see the input and output directories at the same paths
(a shared filesystem). Nothing is lost when a worker dies: frames are written atomically
and ``run.json`` last, so an output directory with ``run.json`` is complete; a sequence
whose worker died (killed, out of memory, node lost) is retried from its first frame on a
new worker, its partial output removed first; a re-run skips complete sequences.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

from .errors import ConfigError, JndsError
from .io import OUTPUT_FORMATS
from .options import option
from .runtime.config import (
    ARTIFACTS_HELP,
    DEFAULT_PRECISION,
    FILTER_DTYPE_HELP,
    FILTER_DTYPES,
    PRECISION_HELP,
    PRECISIONS,
    SHIPPED_ARTIFACTS,
)

SUMMARY = "batch.json"
OUTPUT_FORMAT_HELP = "output frames: float (32-bit, uncompressed) or half (16-bit, PIZ: a quarter of the size)"


def connect(address: str | None = None, cpus: int | None = None) -> dict:
    """Ray, connected: to ``address`` (or ``RAY_ADDRESS``) if given, else an embedded local
    instance with ``cpus`` CPUs (default: this process's usable cores). Returns the
    cluster's resources."""
    import ray

    if not ray.is_initialized():
        address = address or os.environ.get("RAY_ADDRESS") or None
        options = dict(include_dashboard=False, logging_level=logging.WARNING, configure_logging=True)
        try:
            if address:
                ray.init(address=address, **options)
            else:
                ray.init(num_cpus=cpus or len(os.sched_getaffinity(0)), **options)
        except ConnectionError as e:
            raise ConfigError(f"--address {address}: no Ray cluster there ({e})") from None
    return ray.cluster_resources()


# --- jnds batch ------------------------------------------------------------------------


@dataclass
class BatchConfig:
    input: str = option(help="ROOT: every directory under it with a sequence.json")
    output: str = option(help="OUT: ROOT/<path> goes to OUT/<path>; OUT/batch.json sums up")
    artifacts: str = option(SHIPPED_ARTIFACTS, ARTIFACTS_HELP)
    precision: str = option(DEFAULT_PRECISION, PRECISION_HELP, choices=PRECISIONS)
    filter_dtype: str = option(FILTER_DTYPES[0], FILTER_DTYPE_HELP, choices=FILTER_DTYPES)
    adaptive: bool = option(True, "skip the work a frame does not need where the result is the same")
    threads: int = option(1, "ONNX Runtime and numba threads per worker (and the Ray CPUs it reserves)")
    workers: int | None = option(None, "default: the cluster's CPUs / --threads")
    address: str | None = option(
        None, "a Ray cluster (ray start --head prints it; default RAY_ADDRESS, else a local Ray)"
    )
    retries: int = option(2, "further attempts of a sequence whose worker died")
    output_format: str = option("float", OUTPUT_FORMAT_HELP, choices=tuple(OUTPUT_FORMATS))

    def __post_init__(self):
        if self.threads < 1:
            raise ConfigError(f"threads must be >= 1, got {self.threads}")
        if self.workers is not None and self.workers < 1:
            raise ConfigError(f"workers must be >= 1, got {self.workers}")
        if self.retries < 0:
            raise ConfigError(f"retries must be >= 0, got {self.retries}")
        if self.output_format not in OUTPUT_FORMATS:
            raise ConfigError(f"output format {self.output_format!r}: expected one of {', '.join(OUTPUT_FORMATS)}")


def find_work(root: str | Path, output: str | Path) -> list[tuple[Path, Path]]:
    """(sequence directory, its output directory) of every sequence under ``root``, sorted;
    nothing inside ``output`` (when the output lies under the input) or in a hidden
    directory."""
    root, output = Path(root), Path(output)
    if not root.is_dir():
        raise ConfigError(f"--input {root}: no such directory")
    out = []
    for meta in sorted(root.rglob("sequence.json")):
        seq = meta.parent
        rel = seq.relative_to(root)
        if any(part.startswith(".") for part in rel.parts) or seq.resolve().is_relative_to(output.resolve()):
            continue
        out.append((seq, output / rel))
    if not out:
        raise ConfigError(f"--input {root}: no sequence (a directory with sequence.json) under it")
    return out


def frame_count(seq: Path) -> int:
    """The sequence's frame count, or ConfigError naming its unreadable sequence.json."""
    try:
        return int(json.loads((seq / "sequence.json").read_text())["frame_count"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"{seq / 'sequence.json'}: no frame count ({type(e).__name__}: {e})") from None


def is_complete(out: Path, frames: int, checkpoint_sha256: str, precision: str) -> bool:
    """``out`` holds a finished run of these artifacts at this precision: ``run.json``
    (written last) and every frame."""
    try:
        report = json.loads((out / "run.json").read_text())
    except (OSError, ValueError):
        return False
    return (
        report.get("frames") == frames
        and report.get("checkpoint_sha256") == checkpoint_sha256
        and report.get("precision") == precision
        and all((out / f"{i:04d}.exr").is_file() for i in range(frames))
    )


class SequenceWorker:
    """A Ray actor: one pipeline (its ONNX Runtime sessions created once), sequences run
    through it one after another."""

    def __init__(self, cfg: BatchConfig):
        from .process import tune_process

        tune_process()  # the worker owns its process (jnds_deploy.process)
        import numba

        from .io import exr_threads
        from .runtime import Pipeline, PipelineConfig

        exr_threads(cfg.threads)
        # the filter stage's parallel loops on the worker's own CPUs, not on every core
        numba.set_num_threads(min(cfg.threads, numba.config.NUMBA_NUM_THREADS))
        self.pipe = Pipeline(
            PipelineConfig(
                artifacts=cfg.artifacts,
                precision=cfg.precision,
                filter_dtype=cfg.filter_dtype,
                threads=cfg.threads,
                adaptive=cfg.adaptive,
            )
        )
        import ray

        self.output_format = cfg.output_format
        self.where = {
            "node": socket.gethostname(),
            "node_id": ray.get_runtime_context().get_node_id(),
            "pid": os.getpid(),
        }

    def run(self, seq: str, out: str):
        """Yields {"frame": i, "node", "pid"} per frame written, then {"report": run.json's}
        or, if the sequence cannot be run, {"error": its one-line message} (as text: the
        driver may not be able to import or unpickle every exception)."""
        from .runtime.run import iter_run

        shutil.rmtree(out, ignore_errors=True)  # a partial output of an earlier attempt
        try:
            for item in iter_run(self.pipe, seq, out, output_format=self.output_format):
                yield {"report": item, **self.where} if isinstance(item, dict) else {"frame": item, **self.where}
        except Exception as e:  # noqa: BLE001 -- reported per sequence; the batch goes on
            msg = str(e) if isinstance(e, JndsError) else f"{type(e).__name__}: {e}"
            yield {"error": msg, **self.where}


@dataclass
class _Attempt:
    """A sequence on a worker: ``reported`` frames written so far."""

    worker: object
    seq: Path
    out: Path
    frames: int
    reported: int = 0


def batch(cfg: BatchConfig, progress: bool = True, on_frame: Callable[[str, dict], None] | None = None) -> dict:
    """Every sequence under ``cfg.input`` through the pipeline on Ray; returns the summary
    (also written to ``OUT/batch.json``). ``on_frame(sequence, item)`` is called for each
    frame a worker reports (``item``: frame index, node, pid)."""
    import ray
    from tqdm import tqdm

    from .artifacts import Manifest

    manifest = Manifest.load(cfg.artifacts)  # a bad artifact directory fails here, not in every worker
    sha = manifest.checkpoint["sha256"]
    work = find_work(cfg.input, cfg.output)
    out_root = Path(cfg.output)
    out_root.mkdir(parents=True, exist_ok=True)
    resources = connect(cfg.address)
    workers = cfg.workers or max(1, int(resources.get("CPU", 1)) // cfg.threads)
    t0 = time.perf_counter()

    records: dict[str, dict] = {}
    todo: list[tuple[Path, Path, int]] = []
    for seq, out in work:
        key = str(seq.relative_to(cfg.input))
        try:
            n = frame_count(seq)
        except ConfigError as e:  # fails alone, like a bad frame
            records[key] = {"status": "failed", "frames": 0, "output": str(out), "error": str(e)}
            continue
        if is_complete(out, n, sha, cfg.precision):
            records[key] = {"status": "skipped", "frames": n, "output": str(out)}
        else:
            records[key] = {"status": "pending", "frames": n, "output": str(out), "attempts": 0}
            todo.append((seq, out, n))

    def write_summary(final: bool) -> dict:
        done = [r for r in records.values() if r["status"] == "done"]
        frames = sum(r["frames"] for r in done)
        wall = time.perf_counter() - t0
        summary = {
            "input": str(cfg.input),
            "output": str(cfg.output),
            "config": asdict(cfg),
            "workers": workers,
            "cluster_cpus": resources.get("CPU"),
            "finished": final,
            "wall_s": wall,
            "frames_processed": frames,
            "frames_per_s": frames / wall if wall > 0 else None,
            "counts": {
                s: sum(r["status"] == s for r in records.values()) for s in ("done", "skipped", "failed", "pending")
            },
            "sequences": records,
        }
        tmp = out_root / f".{SUMMARY}.tmp"
        tmp.write_text(json.dumps(summary, indent=1))
        os.replace(tmp, out_root / SUMMARY)
        return summary

    Worker = ray.remote(num_cpus=cfg.threads, max_restarts=0)(SequenceWorker)
    idle = [Worker.remote(cfg) for _ in range(min(workers, len(todo)))]
    queue = list(todo)
    running: dict[object, _Attempt] = {}  # a worker's generator -> what it is running
    bar = tqdm(total=sum(n for _, _, n in todo), unit="frame", desc="batch", disable=not progress)
    try:
        while queue or running:
            while queue and idle:
                seq, out, n = queue.pop(0)
                worker = idle.pop()
                records[str(seq.relative_to(cfg.input))]["attempts"] += 1
                running[worker.run.remote(str(seq), str(out))] = _Attempt(worker, seq, out, n)
            ready, _ = ray.wait(list(running), num_returns=1)
            gen = ready[0]
            attempt = running[gen]
            worker, seq, out, n, reported = attempt.worker, attempt.seq, attempt.out, attempt.frames, attempt.reported
            key = str(seq.relative_to(cfg.input))
            try:
                item = ray.get(next(gen))
            except StopIteration:
                del running[gen]
                idle.append(worker)
                continue
            except ray.exceptions.RayError as e:  # the worker died: a new one, the sequence again
                del running[gen]
                ray.kill(worker, no_restart=True)
                idle.append(Worker.remote(cfg))
                if records[key]["status"] in ("done", "failed"):  # it died after its last word
                    continue
                bar.update(-reported)
                records[key].setdefault("worker_deaths", []).append(type(e).__name__)
                if records[key]["attempts"] > cfg.retries:
                    records[key].update(status="failed", error=f"worker died {records[key]['attempts']} times")
                    write_summary(False)
                else:
                    queue.insert(0, (seq, out, n))
                continue
            if "error" in item:  # the sequence itself cannot be run (bad input)
                bar.update(n - reported)
                records[key].update(status="failed", error=item["error"])
                write_summary(False)
            elif "report" in item:
                report = item["report"]
                records[key].update(
                    status="done",
                    node=item["node"],
                    node_id=item["node_id"],
                    median_ms=report["median_ms"]["total"],
                    **({"psnr": report["metrics"]["psnr"]} if "metrics" in report else {}),
                )
                write_summary(False)
            else:
                attempt.reported += 1
                bar.update(1)
                if on_frame:
                    on_frame(key, item)
    finally:
        bar.close()
        for worker in idle + [a.worker for a in running.values()]:
            ray.kill(worker, no_restart=True)
    return write_summary(True)


def _task_error(e) -> str:
    """The one-line message of the exception a worker raised."""
    cause = getattr(e, "cause", None)
    return f"{type(cause).__name__}: {cause}" if cause is not None else str(e).strip().splitlines()[-1]


# --- jnds dataset --address ----------------------------------------------------------------


def render_on_ray(render_one: Callable, todo: list, address: str | None, progress: bool = True) -> list:
    """``render_one(job)`` for every job of ``todo`` ((RenderConfig, path) pairs, from
    ``render.dataset``) as Ray tasks, one CPU each; a task whose worker dies is retried by
    Ray and resumes from the sequence's finished frames (``render.sequence`` writes frames
    atomically, sequence.json last). Returns the results in completion order."""
    import ray
    from tqdm import tqdm

    connect(address)
    task = ray.remote(num_cpus=1, max_retries=3, retry_exceptions=False)(render_one)
    pending = {task.remote(job): job for job in todo}
    done = []
    with tqdm(total=len(todo), unit="sequence", desc="dataset", disable=not progress) as bar:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            job = pending.pop(ready[0])
            try:
                done.append(ray.get(ready[0]))
            except ray.exceptions.RayError as e:
                raise JndsError(f"{job[1]}: rendering failed: {_task_error(e)}") from None
            bar.update(1)
    return done
