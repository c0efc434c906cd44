"""Load test of `jnds serve` on loopback: N concurrent streams, throughput, latency,
server memory over time, and a long run for memory growth.

    python -m benchmarks.serve_load [--frames 48] [--counts 1 2 4 8]
        [--long-s 120] [--out benchmarks/results/serve_load]

Starts `jnds serve` as a subprocess on a free loopback port, then for each stream count
(1, 2, 4, 8) every stream sends the bundled sample's frames in a loop (each stream
waits for its response before sending the next frame, as a render loop does) until it
has sent --frames frames. Latency is measured at the client (request sent to response
read, EXR encoding and decoding included); the server's RSS is sampled from /proc every
0.2 s. The long run keeps 2 streams busy for --long-s seconds and compares the RSS of
its first and last minute. Bounded: every phase has a frame count or a deadline.
Writes benchmarks/results/serve_load.md and .json.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, arguments, command_line, cpu_line, machine_info, parse, timed, write_report
from jnds_deploy.io import open_sequence
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS
from jnds_deploy.serve import Client
from jnds_deploy.serve.server import rss_bytes


class Sampler(threading.Thread):
    def __init__(self, pid: int, period: float = 0.2):
        super().__init__(daemon=True)
        self.pid, self.period = pid, period
        self.samples: list[tuple[float, float]] = []
        self.stop = threading.Event()
        self.t0 = time.monotonic()

    def run(self):
        while not self.stop.is_set():
            self.samples.append((time.monotonic() - self.t0, rss_bytes(self.pid) / 2**20))
            time.sleep(self.period)


def drive(url: str, frames: list, streams: int, per_stream: int | None, deadline_s: float | None) -> dict:
    """``streams`` client threads; each sends frames until ``per_stream`` or the deadline."""
    lat: list[list[float]] = [[] for _ in range(streams)]
    server_ms: list[float] = []
    errors: list[str] = []
    t_end = time.monotonic() + deadline_s if deadline_s else None

    def one(k: int):
        try:
            with Client(url).open_stream() as s:
                i = 0
                while (per_stream is None or i < per_stream) and (t_end is None or time.monotonic() < t_end):
                    layers, cut = frames[(i + k) % len(frames)]
                    lat[k].append(timed(s.denoise, layers, cut)[1])
                    server_ms.append(s.timings["server"])
                    i += 1
        except Exception as exc:
            errors.append(f"stream {k}: {type(exc).__name__}: {exc}")

    t0 = time.perf_counter()
    threads = [threading.Thread(target=one, args=(k,)) for k in range(streams)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    wall = time.perf_counter() - t0
    flat = [x for s in lat for x in s]
    return {
        "streams": streams,
        "frames": len(flat),
        "wall_s": wall,
        "fps": len(flat) / wall,
        "p50_ms": float(np.percentile(flat, 50)),
        "p99_ms": float(np.percentile(flat, 99)),
        "server_p50_ms": float(np.percentile(server_ms, 50)),
        "errors": errors,
    }


def main() -> int:
    ap = arguments(__doc__, RESULTS / "serve_load", smoke={"counts": [1, 2], "frames": 4, "long_s": 1.0})
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--input", default=str(ROOT / "samples" / "orbit-160x90"))
    ap.add_argument("--precision", default="int8")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--frames", type=int, default=48, help="frames per stream count (split over the streams)")
    ap.add_argument("--counts", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument("--long-s", type=float, default=120.0)
    args = parse(ap)

    seq = open_sequence(args.input)
    frames = [(seq.inputs(i), seq.frames[i].camera_cut) for i in range(len(seq))]
    cmd = [
        sys.executable,
        "-m",
        "jnds_deploy",
        "serve",
        "--artifacts",
        args.artifacts,
        "--port",
        "0",
        "--precision",
        args.precision,
        "--workers",
        str(args.workers),
        "--queue",
        "2",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        url = proc.stdout.readline().split()[-1]
        sampler = Sampler(proc.pid)
        sampler.start()
        results = []
        for n in args.counts:
            r = drive(url, frames, n, max(1, args.frames // n), None)
            results.append(r)
            print(
                f"{n} streams: {r['fps']:.1f} frames/s, p50 {r['p50_ms']:.1f} ms, p99 {r['p99_ms']:.1f} ms, "
                f"errors {len(r['errors'])}",
                flush=True,
            )
        t_long = sampler.samples[-1][0]
        long = drive(url, frames, 2, None, args.long_s)
        rss_long = [(t - t_long, m) for t, m in sampler.samples if t >= t_long]
        k = max(1, len(rss_long) // 4)
        long["rss_first_quarter_mib"] = float(np.median([m for _, m in rss_long[:k]]))
        long["rss_last_quarter_mib"] = float(np.median([m for _, m in rss_long[-k:]]))
        # median RSS per 30 s window: growth shows as a rising sequence, a plateau as a flat one
        long["rss_windows_mib"] = [
            float(np.median([m for t, m in rss_long if a <= t < a + 30])) for a in range(0, int(args.long_s), 30)
        ]
        print(
            f"long run: {long['frames']} frames in {long['wall_s']:.0f} s, RSS {long['rss_first_quarter_mib']:.1f} -> "
            f"{long['rss_last_quarter_mib']:.1f} MiB",
            flush=True,
        )
        metrics = Client(url).metrics()
        sampler.stop.set()
        proc.terminate()
        rc = proc.wait(60)
    finally:
        proc.kill()

    report = {
        "command": command_line(),
        "machine": machine_info(),
        "input": seq.path.name,
        "native": list(seq.native_size),
        "precision": args.precision,
        "workers": args.workers,
        "results": results,
        "long": long,
        "server_exit_code": rc,
        "server_metrics": metrics,
        "rss_mib": sampler.samples,
    }
    out = Path(args.out)
    w, h = seq.native_size
    md = [
        "# `jnds serve` under load (loopback)",
        "",
        f"Command: `{report['command']}`  ",
        f"Machine: {cpu_line(report['machine'])}, {report['machine']['platform']}, "
        f"{report['machine']['cpu_count']} cores; server: "
        f"{args.precision}, {args.workers} worker(s), 2 ORT threads, queue 2 per stream; frames of "
        f"{seq.path.name} ({w}x{h} → {2 * w}x{2 * h}), EXR float32 uncompressed both ways. Latency at the "
        "client: request sent to response decoded; each stream waits for a response before sending again.",
        "",
        "| streams | frames | frames/s | p50 ms | p99 ms | server p50 ms | errors |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in results:
        md.append(
            f"| {r['streams']} | {r['frames']} | {r['fps']:.1f} | {r['p50_ms']:.1f} | {r['p99_ms']:.1f} | "
            f"{r['server_p50_ms']:.1f} | {len(r['errors'])} |"
        )
    md += [
        "",
        f"Long run: 2 streams for {long['wall_s']:.0f} s, {long['frames']} frames ({long['fps']:.1f} frames/s, "
        f"p50 {long['p50_ms']:.1f} ms, p99 {long['p99_ms']:.1f} ms, {len(long['errors'])} errors). Server RSS, "
        f"median of the first and last quarter of the run: {long['rss_first_quarter_mib']:.1f} → "
        f"{long['rss_last_quarter_mib']:.1f} MiB "
        f"({long['rss_last_quarter_mib'] - long['rss_first_quarter_mib']:+.1f} MiB); median per 30 s: "
        + " → ".join(f"{m:.1f}" for m in long["rss_windows_mib"])
        + " MiB.",
        f"Peak RSS over the whole test: {max(m for _, m in sampler.samples):.1f} MiB. Server exit code after "
        f"SIGTERM: {rc}.",
        "",
        "The server's own per-stage percentiles over its last frames (`GET /metrics.json`, ms):",
        "",
        "| stage | p50 | p90 | p99 |",
        "| --- | ---: | ---: | ---: |",
    ]
    for k, v in metrics["latency_ms"].items():
        md.append(f"| {k} | {v['p50']:.1f} | {v['p90']:.1f} | {v['p99']:.1f} |")
    write_report(out, report, "\n".join(md) + "\n")
    print("\n".join(md))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        t, m = zip(*sampler.samples)
        plt.figure(figsize=(7, 3))
        plt.plot(t, m)
        plt.xlabel("time since start (s)")
        plt.ylabel("server RSS (MiB)")
        plt.title("jnds serve memory during the load test")
        plt.tight_layout()
        plt.savefig(out.with_suffix(".png"), dpi=100)
    except ImportError:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
