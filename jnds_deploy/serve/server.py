"""``jnds serve``: a long-running ONNX Runtime loop serving frame streams over HTTP.

The artifacts are loaded once; every stream gets its own recurrent history
(``Pipeline.fork``: same sessions, own state). Frames of one stream run in arrival
order, one at a time; frames of different streams run concurrently on a bounded pool of
``workers``. Each stream queues at most ``queue`` frames and the server holds at most
``max_streams`` streams: beyond that a request is refused at once (429 / 503 with
``Retry-After``) instead of piling up in memory. The protocol is in ``PROTOCOL``
(``jnds_deploy/serve/__init__.py`` re-exports it; the README shows a render loop).
"""

from __future__ import annotations

import io
import json
import logging
import os
import threading
import time
import uuid
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlsplit

import numpy as np
import OpenEXR

from ..errors import BadRequest, ConfigError, JndsError
from ..io import INPUT_LAYERS, OPTIONAL_INPUT_LAYERS, OUTPUT_LAYERS, channels_to_layers, exr_bytes, read_exr_bytes
from ..layout import INPUT_CHANNELS
from ..options import gib, option, parse_size
from ..runtime.config import ARTIFACTS_HELP, DEFAULT_PRECISION, PRECISION_HELP, PRECISIONS, SHIPPED_ARTIFACTS
from ..runtime.pipeline import Pipeline, PipelineConfig

log = logging.getLogger("jnds.serve")

PROTOCOL = """\
HTTP/1.1, JSON for control, OpenEXR for frames (any language with an EXR writer can talk):

  POST   /streams                        -> 201 {"stream": ID, "scale": 2, ...}
  POST   /streams/ID/frames[?cut=1]      body: one frame as an EXR file with the input
                                         channels of jnds-sequence/1 (diffuse.R/G/B,
                                         specular.R/G/B, albedo.R/G/B, normal.X/Y/Z,
                                         roughness, motion.X/Y; half or float);
                                         cut=1 marks a camera cut (history reset)
                                         -> 200 EXR with color.R/G/B (float32, uncompressed)
                                            at scale x the input size; headers
                                            X-JNDS-Frame (index in the stream),
                                            X-JNDS-Timings (JSON, ms per stage),
                                            X-JNDS-Nonfinite (JSON, NaN/Inf replaced per layer)
  POST   /streams/ID/reset               -> 200 (history dropped, as on a cut)
  DELETE /streams/ID                     -> 200
  GET    /streams/ID                     -> 200 {"frames": n, "queued": q, ...}
  GET    /health                         -> 200 {"status": "ok" | "closing", ...}
  GET    /metrics                        -> 200 Prometheus text format: jnds_frames_total,
                                            jnds_errors_total{status}, jnds_queue_depth,
                                            jnds_streams_open, jnds_rss_bytes,
                                            jnds_stage_latency_seconds{stage} (histogram), ...
  GET    /metrics.json                   -> 200 JSON: frames, errors, queue depth,
                                            latency percentiles per stage, memory
Errors: JSON {"error": message, "kind": type}. 400 bad frame (message names the
channel, layer or value), 404 unknown stream (closed, or idle longer than the timeout),
411/413 missing or too large body (413 also for a frame whose EXR header declares more
pixels than --max-pixels, checked before decoding), 429 the stream's queue is full, 503 too many streams
(429 and this 503 carry Retry-After in seconds) or shutting down (no Retry-After).
Connections: a read that waits longer than --request-timeout (request line, headers,
keep-alive idle) closes the connection; a body not complete within body_timeout gets 408
and the connection closes; beyond --max-connections a connection gets 503 at once.
"""


@dataclass(frozen=True)
class ServeConfig:
    artifacts: str = option(SHIPPED_ARTIFACTS, ARTIFACTS_HELP)
    host: str = option("127.0.0.1", "the address to listen on")
    port: int = option(8765, "0 picks a free port")
    precision: str = option(DEFAULT_PRECISION, PRECISION_HELP, choices=PRECISIONS)
    threads: int = option(2, "ONNX Runtime threads per graph run")
    workers: int = option(1, "frames processed at once, over all streams")
    queue: int = option(2, "frames waiting per stream (beyond the one running) before 429")
    max_streams: int = option(64, "streams open at once")
    idle_timeout: float = option(300.0, "seconds without a request before a stream is closed")
    max_frame_bytes: int = 512 << 20
    # checked on the EXR header before anything is decoded: the pipeline's memory grows with
    # the frame (a compressed EXR of zeros declaring 4000x4000 is a few hundred kB), so the
    # size a body declares is refused, not discovered
    max_pixels: int = option(
        1920 * 1080, "native pixels a frame may have (checked on its EXR header before decoding; 413 beyond)"
    )
    # estimated at FRAME_BYTES_PER_PIXEL per native pixel. A frame that alone exceeds it gets
    # 413, one that does not fit beside the frames in flight 503 + Retry-After
    max_memory: int | None = option(
        None,
        "GiB the frames in flight may take (estimated per pixel); default: half the machine's memory",
        type=gib,
        metavar="GIB",
    )
    max_channels: int = 64  # EXR channels per frame (the format uses 15 or 16)
    # slow or careless clients: a connection is closed when a read waits longer than
    # request_timeout (the request line and headers, or idle between keep-alive requests),
    # or its body takes longer than body_timeout in all (408); at most max_connections at
    # once, each a thread, the next one refused with 503
    request_timeout: float = option(
        30.0, "seconds a read may wait (request line, headers, keep-alive idle) before the connection closes"
    )
    body_timeout: float = 60.0
    max_connections: int = option(256, "connections at once; the next gets a 503")
    max_nonfinite: float = 0.5  # a layer with more NaN/Inf than this fraction: 400 (a NaN flood)
    # PipelineConfig.keep_freed_memory (process-wide; `jnds serve` makes it with the other
    # process-wide settings, process.tune_process)
    keep_freed_memory: bool = False
    # the first frame at a new size otherwise pays ONNX Runtime's allocations at that size
    # (docs/performance.md)
    warmup: tuple[tuple[int, int], ...] = option(
        (),
        "run one frame at each of these native sizes before serving, so that a stream's first frame at that "
        "size is not the slow one",
        type=parse_size,
        nargs="+",
        metavar="WxH",
    )

    def __post_init__(self):
        object.__setattr__(self, "warmup", tuple(tuple(int(v) for v in size) for size in self.warmup))
        for w, h in self.warmup:
            if w < 1 or h < 1 or w * h > self.max_pixels:
                raise ConfigError(
                    f"warm-up size {w}x{h}: must be positive and at most max_pixels ({self.max_pixels}) native pixels"
                )


class Stream:
    def __init__(self, pipe: Pipeline):
        self.id = uuid.uuid4().hex[:16]
        self.pipe = pipe
        self.jobs: deque = deque()
        self.running = False
        self.frames = 0
        self.errors = 0
        self.last_used = time.monotonic()
        self.users = 0  # requests holding the stream right now: never reaped while > 0
        self.closed = False


# peak memory of a frame in the pipeline per native pixel (int8, 2x output, buffers kept), an
# estimate on the safe side: the peak RSS per input pixel of `jnds run` between sizes
# (benchmarks/results/memory.md and the per-CPU memory-*.md), rounded up
FRAME_BYTES_PER_PIXEL = 1700


def machine_memory() -> int:
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


# Prometheus latency buckets, seconds: from a small frame's filter step to a 1080p frame
LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)


class Metrics:
    """Counters and a window of the last ``window`` frames' stage timings (the JSON's
    percentiles), and the same as Prometheus metrics in a registry of this server's own
    (``prometheus_client``; names prefixed ``jnds_``), so that two servers in one process
    do not share them."""

    def __init__(self, window: int = 2000):
        from prometheus_client import CollectorRegistry, Counter, Histogram

        self.lock = threading.Lock()
        self.frames = 0
        self.errors: dict[str, int] = {}
        self.timings: deque = deque(maxlen=window)
        self.started = time.time()
        self.registry = CollectorRegistry()
        self.frames_total = Counter("jnds_frames", "Frames served", registry=self.registry)
        self.errors_total = Counter(
            "jnds_errors", "Requests refused or failed, by HTTP status", ["status"], registry=self.registry
        )
        self.latency = Histogram(
            "jnds_stage_latency_seconds",
            "Time per pipeline stage and frame (queue, server: the whole request)",
            ["stage"],
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )

    def frame(self, ms: dict) -> None:
        with self.lock:
            self.frames += 1
            self.timings.append(ms)
        self.frames_total.inc()
        for stage, v in ms.items():
            self.latency.labels(stage).observe(v / 1000)

    def error(self, kind: str) -> None:
        with self.lock:
            self.errors[kind] = self.errors.get(kind, 0) + 1
        self.errors_total.labels(kind).inc()

    def snapshot(self) -> dict:
        with self.lock:
            timings = list(self.timings)
            out = {
                "frames_served": self.frames,
                "errors": dict(self.errors),
                "uptime_s": round(time.time() - self.started, 3),
            }
        stages = sorted({k for t in timings for k in t})
        out["latency_ms"] = {
            k: {f"p{q}": float(np.percentile([t.get(k, 0.0) for t in timings], q)) for q in (50, 90, 99)}
            for k in stages
        }
        out["latency_window"] = len(timings)
        return out


def rss_bytes(pid: int | str = "self") -> int | None:
    """Resident memory of a process (Linux /proc), None elsewhere."""
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return None


class _Gauges:
    """A Prometheus collector of a server's ``snapshot`` values, read when scraped."""

    GAUGES = (
        ("streams_open", "Open streams"),
        ("queue_depth", "Frames queued, all streams"),
        ("streams_running", "Streams with a frame running"),
        ("requests_in_flight", "HTTP requests being handled"),
        ("rss_bytes", "Resident memory of the process"),
        ("workers", "Worker threads"),
        ("memory_reserved_bytes", "Memory budget held by frames in flight"),
        ("memory_budget_bytes", "The memory budget (jnds serve --max-memory)"),
        ("uptime_s", "Seconds since the server started"),
    )

    def __init__(self, server: "FrameServer"):
        self.server = server

    def collect(self):
        from prometheus_client.core import GaugeMetricFamily

        snap = self.server.snapshot()
        for key, doc in self.GAUGES:
            yield GaugeMetricFamily(f"jnds_{key}", doc, value=float(snap[key] or 0))


class FrameServer:
    """The server's state and work: streams, the worker pool, metrics. The HTTP layer
    (``_Handler``) only parses requests and calls these methods."""

    def __init__(self, cfg: ServeConfig):
        self.cfg = cfg
        self.base = Pipeline(
            PipelineConfig(
                artifacts=cfg.artifacts,
                precision=cfg.precision,
                threads=cfg.threads,
                keep_freed_memory=cfg.keep_freed_memory,
            )
        )
        self.pool = ThreadPoolExecutor(max_workers=cfg.workers, thread_name_prefix="jnds-worker")
        self._warm_up(cfg.workers, [(self.base.multiple,) * 2, *cfg.warmup])
        self.streams: dict[str, Stream] = {}
        self.lock = threading.Lock()
        self.metrics = Metrics()
        self.closing = False
        self.inflight = 0  # requests being handled (graceful shutdown waits for 0)
        self.budget = cfg.max_memory if cfg.max_memory is not None else machine_memory() // 2
        self.reserved = 0  # bytes of the budget held by frames in flight
        self.metrics.registry.register(_Gauges(self))
        self.idle = threading.Event()
        self.idle.set()
        self._reaper = threading.Thread(target=self._reap, name="jnds-reaper", daemon=True)
        self._reaper.start()

    def _warm_up(self, workers: int, sizes) -> None:
        """One frame at each native (W, H) size in every worker thread, before serving:
        compiles the numba loops, lets ONNX Runtime allocate, and starts each thread's
        parallel-loop team, so the first client frame at a warmed size is not the slow one
        (docs/performance.md; ``benchmarks/serve_warmup.py``). A tiny frame of zeros first,
        then constant non-zero signals (zeros would run the pruned graphs)."""
        barrier = threading.Barrier(workers)

        def job():
            barrier.wait()  # every worker thread takes one job
            for i, (w, h) in enumerate(sizes):
                t0 = time.perf_counter()
                self.base.fork()(
                    {
                        n: np.full((h, w, c), 0.0 if n == "motion" or i == 0 else 0.5, np.float32)
                        for n, c in INPUT_CHANNELS.items()
                    }
                )
                if i:
                    log.info(
                        "warmed up at %dx%d in %.0f ms (%s)",
                        w,
                        h,
                        1000 * (time.perf_counter() - t0),
                        threading.current_thread().name,
                    )

        for fut in [self.pool.submit(job) for _ in range(workers)]:
            fut.result()

    # streams ------------------------------------------------------------------------

    def open_stream(self) -> Stream:
        with self.lock:
            if self.closing:
                raise BadRequest(503, "server is shutting down")
            if len(self.streams) >= self.cfg.max_streams:
                raise BadRequest(
                    503, f"too many open streams ({self.cfg.max_streams}); close one first", retry_after=1.0
                )
            s = Stream(self.base.fork())
            self.streams[s.id] = s
        log.info("stream %s opened (%d open)", s.id, len(self.streams))
        return s

    def stream(self, sid: str) -> Stream:
        with self.lock:
            s = self.streams.get(sid)
        if s is None:
            raise BadRequest(
                404, f"stream {sid!r} is not open (closed, or idle longer than {self.cfg.idle_timeout:g} s)"
            )
        s.last_used = time.monotonic()
        return s

    @contextmanager
    def using(self, sid: str):
        """The stream, held for one request: the idle reaper leaves it alone meanwhile."""
        s = self.stream(sid)
        with self.lock:
            s.users += 1
        try:
            yield s
        finally:
            with self.lock:
                s.users -= 1
                s.last_used = time.monotonic()

    def close_stream(self, sid: str) -> None:
        with self.lock:
            s = self.streams.pop(sid, None)
        if s is None:
            raise BadRequest(404, f"stream {sid!r} is not open")
        s.closed = True
        log.info("stream %s closed after %d frames", sid, s.frames)

    def reset_stream(self, sid: str) -> None:
        s = self.stream(sid)
        # through the stream's queue, so it lands between the frames sent before and after
        self._submit(s, None).result()

    def _reap(self) -> None:
        while True:
            time.sleep(max(0.05, min(self.cfg.idle_timeout / 4, 5.0)))
            now = time.monotonic()
            with self.lock:
                stale = [
                    s
                    for s in self.streams.values()
                    if now - s.last_used > self.cfg.idle_timeout and not (s.users or s.jobs or s.running)
                ]
                for s in stale:
                    del self.streams[s.id]
                    s.closed = True
            for s in stale:
                log.info("stream %s closed: idle for more than %g s", s.id, self.cfg.idle_timeout)

    # frames -------------------------------------------------------------------------

    def admit(self, body: bytes) -> None:
        """Refuse a frame by its EXR header alone (413), before decoding: more native pixels
        than ``max_pixels`` or more channels than ``max_channels`` in any part."""
        try:
            parts = OpenEXR.File(io.BytesIO(body), header_only=True).parts
            windows = [(p.header["dataWindow"], p.header.get("channels", [])) for p in parts]
        except Exception:  # not an EXR header: decoding reports it (io.read_exr_bytes' message)
            return
        for (lo, hi), channels in windows:
            w, h = int(hi[0]) - int(lo[0]) + 1, int(hi[1]) - int(lo[1]) + 1
            if w < 1 or h < 1:
                raise BadRequest(400, f"request body: EXR data window {w}x{h} is empty")
            if w * h > self.cfg.max_pixels:
                raise BadRequest(
                    413,
                    f"request body: a {w}x{h} frame ({w * h} pixels) exceeds the server's "
                    f"limit of {self.cfg.max_pixels} pixels (jnds serve --max-pixels)",
                )
            if w * h * FRAME_BYTES_PER_PIXEL > self.budget:
                raise BadRequest(
                    413,
                    f"request body: a {w}x{h} frame needs about "
                    f"{w * h * FRAME_BYTES_PER_PIXEL / 2**20:.0f} MiB, more than the server's memory "
                    f"budget of {self.budget / 2**20:.0f} MiB (jnds serve --max-memory)",
                )
            if len(channels) > self.cfg.max_channels:
                raise BadRequest(
                    413,
                    f"request body: {len(channels)} EXR channels exceed the server's limit of {self.cfg.max_channels}",
                )

    def decode(self, body: bytes) -> dict:
        """An EXR request body into the pipeline's layers, or BadRequest naming the problem."""
        self.admit(body)
        try:
            raw = read_exr_bytes(body, "request body")
            layers = channels_to_layers(raw, "request body", None, INPUT_LAYERS, OPTIONAL_INPUT_LAYERS)
        except JndsError as exc:
            raise BadRequest(400, str(exc)) from exc
        for name, a in layers.items():
            bad = a.size - int(np.count_nonzero(np.isfinite(a)))
            if bad > self.cfg.max_nonfinite * a.size:
                raise BadRequest(
                    400,
                    f"request body: layer {name!r} has {bad} of {a.size} values NaN or Inf "
                    f"(more than {self.cfg.max_nonfinite:.0%}); frame refused, stream unchanged",
                )
        return layers

    def denoise(self, s: Stream, layers: dict, cut: bool) -> tuple[np.ndarray, dict, dict, int]:
        """Queue one frame on its stream and wait for it: (colour HWC, ms per stage,
        non-finite counts, index of the frame in the stream). The frame's memory is
        reserved from the budget until it is done; 503 + Retry-After if it does not fit."""
        h, w = np.shape(layers["diffuse"])[:2]
        need = w * h * FRAME_BYTES_PER_PIXEL
        with self.lock:
            if self.reserved + need > self.budget:
                raise BadRequest(
                    503,
                    f"memory budget: {self.reserved / 2**20:.0f} of {self.budget / 2**20:.0f} MiB "
                    f"reserved by frames in flight, this one needs {need / 2**20:.0f}",
                    retry_after=1.0,
                )
            self.reserved += need
        try:
            return self._submit(s, (layers, cut, time.perf_counter())).result()
        finally:
            with self.lock:
                self.reserved -= need

    def _submit(self, s: Stream, job) -> Future:
        fut: Future = Future()
        with self.lock:
            if self.closing and job is not None:
                raise BadRequest(503, "server is shutting down")
            if s.closed:
                raise BadRequest(404, f"stream {s.id!r} is not open")
            if len(s.jobs) + (1 if s.running else 0) > self.cfg.queue:
                raise BadRequest(
                    429,
                    f"stream {s.id}: {len(s.jobs)} frame(s) already queued "
                    f"(limit {self.cfg.queue}); send the next frame after a response",
                    retry_after=0.05,
                )
            s.jobs.append((job, fut))
            start = not s.running
            s.running = True
        if start:
            self.pool.submit(self._drain, s)
        return fut

    def _drain(self, s: Stream) -> None:
        """Run a stream's queued jobs in order (one worker per stream at a time)."""
        while True:
            with self.lock:
                if not s.jobs:
                    s.running = False
                    return
                job, fut = s.jobs.popleft()
            if job is None:  # reset
                s.pipe.reset()
                fut.set_result(None)
                continue
            layers, cut, t0 = job
            try:
                queued = 1000 * (time.perf_counter() - t0)
                frame = s.pipe(layers, cut)
                ms = {**frame.ms, "queue": queued, "server": 1000 * (time.perf_counter() - t0)}
                s.frames += 1
                s.last_used = time.monotonic()
                self.metrics.frame(ms)
                fut.set_result((frame.output, ms, frame.nonfinite, s.frames - 1))
            except JndsError as exc:  # a frame the pipeline refuses: the stream goes on
                s.errors += 1
                fut.set_exception(BadRequest(400, str(exc)))
            except Exception as exc:  # a bug: drop this stream's history, keep serving
                log.exception("stream %s: frame failed", s.id)
                s.errors += 1
                s.pipe.reset()
                fut.set_exception(exc)

    # status -------------------------------------------------------------------------

    def health(self) -> dict:
        return {
            "status": "closing" if self.closing else "ok",
            "streams": len(self.streams),
            "artifacts": self.cfg.artifacts,
            "precision": self.cfg.precision,
            "graphs": dict(self.base.graph_precision),
            "scale": self.base.out_scale,
        }

    def snapshot(self) -> dict:
        with self.lock:
            queued = sum(len(s.jobs) for s in self.streams.values())
            running = sum(1 for s in self.streams.values() if s.running)
            streams = len(self.streams)
        return {
            **self.metrics.snapshot(),
            "streams_open": streams,
            "queue_depth": queued,
            "streams_running": running,
            "requests_in_flight": self.inflight,
            "rss_bytes": rss_bytes(),
            "workers": self.cfg.workers,
            "memory_reserved_bytes": self.reserved,
            "memory_budget_bytes": self.budget,
        }

    def prometheus(self) -> bytes:
        """The metrics in Prometheus' text format: the counters and histogram kept per
        frame, and the gauges of ``snapshot`` (``_Gauges``, read at the scrape)."""
        from prometheus_client import generate_latest

        return generate_latest(self.metrics.registry)

    def begin_request(self) -> None:
        with self.lock:
            self.inflight += 1
            self.idle.clear()

    def end_request(self) -> None:
        with self.lock:
            self.inflight -= 1
            if self.inflight == 0:
                self.idle.set()

    def close(self, timeout: float = 60.0) -> None:
        """Refuse new work, let queued and running frames finish and their responses be
        written, then stop the workers."""
        with self.lock:
            self.closing = True
        self.idle.wait(timeout)
        self.pool.shutdown(wait=True)


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server_version = "jnds-serve"
    frames: FrameServer  # set on the subclass made by make_http_server

    def log_message(self, fmt, *args):  # access log at debug level, not on stderr
        log.debug("%s %s", self.address_string(), fmt % args)

    def _send(self, status: int, body: bytes, ctype: str, headers: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(body)

    def _json(self, status: int, obj, headers: dict | None = None) -> None:
        self._send(status, json.dumps(obj).encode(), "application/json", headers)

    def _error(self, exc: BadRequest) -> None:
        kind = type(exc.__cause__).__name__ if exc.__cause__ else HTTPStatus(exc.status).phrase
        self.frames.metrics.error(str(exc.status))
        headers = {"Retry-After": f"{exc.retry_after:g}"} if exc.retry_after is not None else {}
        if exc.status in (408, 411, 413) or self.close_connection:  # an unread body: the connection is unusable
            headers["Connection"] = "close"
            self.close_connection = True
        self._json(exc.status, {"error": str(exc), "kind": kind}, headers)

    def _body(self) -> bytes:
        n = self.headers.get("Content-Length")
        if n is None:
            raise BadRequest(411, "Content-Length required")
        try:
            n = int(n)
        except ValueError:
            raise BadRequest(400, f"Content-Length {n!r} is not a number") from None
        cfg = self.frames.cfg
        if n < 0 or n > cfg.max_frame_bytes:
            raise BadRequest(413, f"body of {n} bytes exceeds the limit of {cfg.max_frame_bytes}")
        # in chunks against one deadline: a client trickling bytes must not hold a thread
        deadline, chunks, left = time.monotonic() + cfg.body_timeout, [], n
        try:
            while left:
                wait = deadline - time.monotonic()
                if wait <= 0:
                    raise TimeoutError
                self.connection.settimeout(min(cfg.request_timeout, wait))
                chunk = self.rfile.read1(min(left, 1 << 20))
                if not chunk:
                    self.close_connection = True
                    raise BadRequest(400, f"body truncated: {n - left} of {n} bytes")
                chunks.append(chunk)
                left -= len(chunk)
        except TimeoutError:
            raise BadRequest(
                408, f"body not received within {cfg.body_timeout:g} s ({n - left} of {n} bytes)"
            ) from None
        finally:
            self.connection.settimeout(cfg.request_timeout)
        return b"".join(chunks)

    def _route(self, method: str) -> None:
        fs = self.frames
        fs.begin_request()
        try:
            url = urlsplit(self.path)
            parts = [p for p in url.path.split("/") if p]
            if method == "GET" and parts == ["health"]:
                return self._json(200, fs.health())
            if method == "GET" and parts == ["metrics"]:  # Prometheus' text format
                return self._send(200, fs.prometheus(), "text/plain; version=0.0.4; charset=utf-8")
            if method == "GET" and parts == ["metrics.json"]:
                return self._json(200, fs.snapshot())
            if method == "POST" and parts == ["streams"]:
                if self.headers.get("Content-Length"):
                    self._body()
                s = fs.open_stream()
                return self._json(
                    201,
                    {
                        "stream": s.id,
                        "scale": fs.base.scale,
                        "precision": fs.cfg.precision,
                        "idle_timeout_s": fs.cfg.idle_timeout,
                    },
                )
            if len(parts) >= 2 and parts[0] == "streams":
                sid = parts[1]
                if method == "POST" and parts[2:] == ["frames"]:
                    body = self._body()
                    cut = parse_qs(url.query).get("cut", ["0"])[0] not in ("0", "false", "")
                    with fs.using(sid) as stream:  # 404 before decoding a body for nothing
                        color, ms, nonfinite, index = fs.denoise(stream, fs.decode(body), cut)
                    out = exr_bytes({"color": color}, OUTPUT_LAYERS, compression=OpenEXR.NO_COMPRESSION)
                    return self._send(
                        200,
                        out,
                        "image/x-exr",
                        {
                            "X-JNDS-Frame": str(index),
                            "X-JNDS-Timings": json.dumps({k: round(v, 3) for k, v in ms.items()}),
                            "X-JNDS-Nonfinite": json.dumps(nonfinite),
                        },
                    )
                if method == "POST" and parts[2:] == ["reset"]:
                    fs.reset_stream(sid)
                    return self._json(200, {"stream": sid, "reset": True})
                if method == "DELETE" and parts[2:] == []:
                    fs.close_stream(sid)
                    return self._json(200, {"stream": sid, "closed": True})
                if method == "GET" and parts[2:] == []:
                    s = fs.stream(sid)
                    return self._json(
                        200,
                        {
                            "stream": sid,
                            "frames": s.frames,
                            "errors": s.errors,
                            "queued": len(s.jobs),
                            "running": s.running,
                        },
                    )
            raise BadRequest(404, f"no such endpoint: {method} {url.path}")
        except BadRequest as exc:
            self._error(exc)
        except (BrokenPipeError, ConnectionResetError):
            self.close_connection = True
        except Exception as exc:  # never let a request kill the server
            log.exception("%s %s failed", method, self.path)
            self._error(BadRequest(500, f"internal error: {type(exc).__name__}: {exc}"))
        finally:
            fs.end_request()

    def do_GET(self):
        self._route("GET")

    def do_POST(self):
        self._route("POST")

    def do_DELETE(self):
        self._route("DELETE")


class _BoundedServer(ThreadingHTTPServer):
    """A thread per connection, at most ``max_connections`` at once: the next connection
    gets a 503 and is closed, so slow clients cannot exhaust the process's threads."""

    daemon_threads = True  # idle keep-alive connections do not hold up shutdown
    # the listen backlog (socketserver's default is 5): a burst of connections must queue
    # in the kernel, not be dropped and retried by the clients seconds later
    request_queue_size = 128

    def __init__(self, address, handler, max_connections: int):
        super().__init__(address, handler)
        self.max_connections = max_connections
        self.connections = 0
        self._count_lock = threading.Lock()

    def process_request(self, request, client_address):
        with self._count_lock:
            full = self.connections >= self.max_connections
            if not full:
                self.connections += 1
        if full:
            try:
                request.sendall(
                    b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 1\r\nContent-Length: 0\r\n"
                    b"Connection: close\r\n\r\n"
                )
            except OSError:
                pass
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request, client_address):
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._count_lock:
                self.connections -= 1


def make_http_server(frames: FrameServer) -> ThreadingHTTPServer:
    # timeout: StreamRequestHandler sets it on the socket; a read that waits longer ends
    # the connection (BaseHTTPRequestHandler closes it on the timeout)
    handler = type("Handler", (_Handler,), {"frames": frames, "timeout": frames.cfg.request_timeout})
    return _BoundedServer((frames.cfg.host, frames.cfg.port), handler, frames.cfg.max_connections)


def serve(cfg: ServeConfig, ready=None) -> None:
    """Run until SIGINT/SIGTERM, then shut down gracefully. ``ready(host, port)`` is
    called once the socket listens."""
    import signal

    frames = FrameServer(cfg)
    httpd = make_http_server(frames)
    host, port = httpd.server_address[:2]
    stop = threading.Event()

    def on_signal(signum, _frame):
        log.info("signal %d: finishing in-flight frames", signum)
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    thread.start()
    log.info("serving %s (%s) on http://%s:%d", cfg.artifacts, cfg.precision, host, port)
    if ready:
        ready(host, port)
    stop.wait()
    frames.close()  # refuse new frames, wait for requests in flight
    httpd.shutdown()
    httpd.server_close()
    log.info("stopped after %d frames", frames.metrics.frames)
