"""Fuzzing the HTTP surface of `jnds serve`: hostile and careless requests, the server
alive and bounded, another stream's output unchanged.

    python -m benchmarks.serve_fuzz [--cases 10000] [--seed 0]
        [--out benchmarks/results/serve_fuzz]

Starts `jnds serve` as a subprocess on a free loopback port and opens a reference stream
that sends the bundled sample's frames between the fuzz cases. Each case is one new
connection carrying one hostile request (``hostile_request``): malformed request lines,
methods and paths, broken headers and Content-Length, truncated and garbage bodies, and
EXRs with hostile headers (huge, negative or empty data windows, hundreds of channels,
integer channels, wrong channels, NaN floods). The report counts the answers by status,
the server crashes (0 is the only good number), its RSS over the run, and whether every
reference frame equals the first run's. ``tests/serve/test_fuzz.py`` runs a small budget
of the same cases in-process on every CI run.
"""

from __future__ import annotations

import io
import random
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, arguments, command_line, cpu_line, machine_info, parse, write_report
from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS

INPUT_CHANNELS = [
    "diffuse.R",
    "diffuse.G",
    "diffuse.B",
    "specular.R",
    "specular.G",
    "specular.B",
    "albedo.R",
    "albedo.G",
    "albedo.B",
    "normal.X",
    "normal.Y",
    "normal.Z",
    "roughness",
    "motion.X",
    "motion.Y",
]


def _exr(channels: dict, compression=None) -> bytes:
    import OpenEXR

    buf = io.BytesIO()
    OpenEXR.File(
        {"type": OpenEXR.scanlineimage, "compression": compression or OpenEXR.ZIP_COMPRESSION}, channels
    ).write(buf)
    return buf.getvalue()


def _with_data_window(exr: bytes, x0: int, y0: int, x1: int, y1: int) -> bytes:
    """``exr`` with its header's dataWindow (and displayWindow) rewritten: what a hostile
    client can declare without sending the pixels."""
    out = bytearray(exr)
    box = np.array([x0, y0, x1, y1], "<i4").tobytes()
    for name in (b"dataWindow", b"displayWindow"):
        key = name + b"\x00box2i\x00\x10\x00\x00\x00"
        i = out.find(key)
        if i >= 0:
            out[i + len(key) : i + len(key) + 16] = box
    return bytes(out)


def hostile_body(rng: random.Random) -> bytes:
    w, h = rng.choice([(1, 1), (8, 8), (16, 9), (33, 17)])
    kind = rng.randrange(9)
    ok = {c: np.full((h, w), rng.random(), np.float16) for c in INPUT_CHANNELS}
    if kind == 0:  # huge declared size, tiny file
        return _with_data_window(_exr(ok), 0, 0, rng.choice([4000, 20000, 2**30]), rng.choice([4000, 2**30]))
    if kind == 1:  # negative or inverted windows
        return _with_data_window(_exr(ok), rng.randint(-(2**31), 0), 0, rng.randint(-(2**31), -1), 5)
    if kind == 2:  # hundreds of channels
        return _exr({f"c{i}": np.zeros((h, w), np.float16) for i in range(rng.choice([65, 300]))})
    if kind == 3:  # integer channels
        return _exr({c: np.zeros((h, w), np.uint32) for c in INPUT_CHANNELS})
    if kind == 4:  # a missing channel
        return _exr({c: v for c, v in ok.items() if c != rng.choice(INPUT_CHANNELS)})
    if kind == 5:  # NaN flood
        return _exr({c: np.full((h, w), np.nan, np.float16) for c in INPUT_CHANNELS})
    good = _exr(ok)
    if kind == 6:  # truncated
        return good[: rng.randrange(1, len(good))]
    if kind == 7:  # bytes flipped
        b = bytearray(good)
        for _ in range(rng.randint(1, 20)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    return bytes(rng.randrange(256) for _ in range(rng.randint(0, 4096)))  # garbage


def hostile_request(rng: random.Random, stream: str) -> bytes:
    """One hostile request, as raw bytes to write on a fresh connection."""
    kind = rng.randrange(8)
    path = f"/streams/{stream}/frames"
    if kind == 0:  # a request line that is not one
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 300))) + b"\r\n\r\n"
    if kind == 1:  # a very long line or header
        return b"GET /" + b"a" * rng.choice([70000, 200000]) + b" HTTP/1.1\r\n\r\n"
    if kind == 2:  # methods and paths
        method = rng.choice([b"GET", b"PUT", b"PATCH", b"DELETE", b"OPTIONS", b"BREW", b"POST"])
        p = rng.choice(
            [
                b"/",
                b"/streams/nope/frames",
                b"/../../etc/passwd",
                b"/streams/%00",
                b"/metrics?x=\xff",
                path.encode() + b"?cut=maybe",
                b"/streams/" + b"x" * 5000,
            ]
        )
        return method + b" " + p + b" HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n"
    if kind == 3:  # broken Content-Length
        cl = rng.choice([b"-1", b"abc", b"99999999999999999999", b"10, 20", b""])
        return f"POST {path} HTTP/1.1\r\nHost: x\r\n".encode() + b"Content-Length: " + cl + b"\r\n\r\nxyz"
    if kind == 4:  # many headers
        return (
            f"POST {path} HTTP/1.1\r\n".encode()
            + b"".join(b"X-%d: y\r\n" % i for i in range(rng.choice([50, 150])))
            + b"Content-Length: 0\r\n\r\n"
        )
    if kind == 5:  # a body shorter than announced, then the connection closes
        body = hostile_body(rng)
        return f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Length: {len(body) + 100}\r\n\r\n".encode() + body
    if kind == 6:  # chunked, which the server does not take
        return f"POST {path} HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n".encode()
    body = hostile_body(rng)  # a hostile EXR, well framed
    return f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Length: {len(body)}\r\n\r\n".encode() + body


def send(host: str, port: int, raw: bytes, timeout: float = 30.0) -> str:
    """Write ``raw`` on a new connection, half-close it, and return the response's status
    code, or 'closed' if the server closed without one."""
    with socket.create_connection((host, port), timeout=timeout) as s:
        try:
            s.sendall(raw)
            s.shutdown(socket.SHUT_WR)
        except OSError:
            pass  # the server may close early (413 before the whole body): read what it said
        data = b""
        try:
            while len(data) < 16 and (chunk := s.recv(4096)):
                data += chunk
        except (ConnectionResetError, socket.timeout):
            pass
    return data.split(b" ")[1].decode() if data.startswith(b"HTTP/1.") and data.count(b" ") else "closed"


def fuzz(url: str, cases: int, seed: int, reference=None, every: int = 100) -> dict:
    """Send ``cases`` hostile requests; ``reference()`` (frames of a well-behaved stream,
    compared by the caller) runs every ``every`` cases. Returns counts by status."""
    from jnds_deploy.serve import Client

    rng = random.Random(seed)
    host, port = url.split("//")[1].split(":")
    counts: dict[str, int] = {}
    with Client(url).open_stream() as victim:
        for i in range(cases):
            status = send(host, int(port), hostile_request(rng, victim.id))
            counts[status] = counts.get(status, 0) + 1
            if reference is not None and i % every == 0:
                reference()
    return dict(sorted(counts.items()))


def slow_clients(url: str, frames, count: int = 200, rounds: int = 15) -> dict:
    """Frame latency of a normal stream without and with ``count`` connections that sent
    half a request line and stopped (interleaved by round), and how long the server takes
    to close them all."""
    from jnds_deploy.serve import Client

    host, port = url.split("//")[1].split(":")

    def frame_ms(stream):
        t0 = time.perf_counter()
        stream.denoise(*frames[0])
        return 1000 * (time.perf_counter() - t0)

    alone, beside = [], []
    with Client(url).open_stream() as stream:
        frame_ms(stream)  # warm-up
        for _ in range(rounds):
            alone.append(frame_ms(stream))
        slow = []
        for _ in range(count):
            sock = socket.create_connection((host, int(port)), timeout=120)
            sock.sendall(b"POST /str")
            slow.append(sock)
        t_open = time.monotonic()
        for _ in range(rounds):
            beside.append(frame_ms(stream))
    closed_after = []
    for sock in slow:
        try:
            sock.recv(100)
        except OSError:
            pass
        closed_after.append(time.monotonic() - t_open)
        sock.close()
    return {
        "slow_connections": count,
        "frame_ms_alone": alone,
        "frame_ms_beside_slow": beside,
        "median_ms_alone": float(np.median(alone)),
        "median_ms_beside_slow": float(np.median(beside)),
        "all_closed_after_s": float(max(closed_after)),
    }


def main() -> None:
    ap = arguments(
        __doc__,
        RESULTS / "serve_fuzz",
        smoke={"cases": 40, "every": 20, "slow": 4, "rounds": 2, "request_timeout": 1.0},
    )
    ap.add_argument("--artifacts", default=SHIPPED_ARTIFACTS)
    ap.add_argument("--cases", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=int, default=100, help="cases between two runs of the reference stream")
    ap.add_argument("--slow", type=int, default=200, help="slow clients (half a request line each)")
    ap.add_argument("--rounds", type=int, default=15, help="frames of the normal stream, alone and beside them")
    ap.add_argument("--request-timeout", type=float, default=5.0, help="the server's --request-timeout (s)")
    args = parse(ap)

    from jnds_deploy.io import open_sequence
    from jnds_deploy.serve import Client
    from jnds_deploy.serve.server import rss_bytes

    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "jnds_deploy",
            "serve",
            "--artifacts",
            args.artifacts,
            "--port",
            "0",
            "--request-timeout",
            str(args.request_timeout),
        ],
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        url = proc.stdout.readline().strip().rsplit(" ", 1)[-1]
        seq = open_sequence(ROOT / "samples" / "orbit-160x90")
        frames = [(seq.inputs(i), seq.frames[i].camera_cut) for i in range(len(seq))]
        with Client(url).open_stream() as s:
            first = [s.denoise(layers, cut) for layers, cut in frames]
        rss = [(0, rss_bytes(proc.pid))]
        mismatches = []

        def reference():
            with Client(url).open_stream() as s:
                got = [s.denoise(layers, cut) for layers, cut in frames[:3]]
            mismatches.append(sum(not np.array_equal(a, b) for a, b in zip(got, first)))
            rss.append((len(rss), rss_bytes(proc.pid)))

        t0 = time.perf_counter()
        counts = fuzz(url, args.cases, args.seed, reference, args.every)
        wall = time.perf_counter() - t0
        slow = slow_clients(url, frames, args.slow, args.rounds)
        alive = Client(url).health()["status"] == "ok" and proc.poll() is None
    finally:
        proc.terminate()
        proc.wait(30)
    mib = [r / 2**20 for _, r in rss]
    report = {
        "command": command_line(),
        "machine": machine_info(),
        "cases": args.cases,
        "seed": args.seed,
        "wall_s": wall,
        "statuses": counts,
        "server_alive": alive,
        "server_exit_code": proc.returncode,
        "reference_checks": len(mismatches),
        "reference_frames_changed": int(sum(mismatches)),
        "rss_mib": mib,
        "slow_clients": slow,
    }
    md = (
        [
            "# `jnds serve` under fuzzing",
            "",
            f"Command: `{report['command']}`  ",
            f"Machine: {cpu_line(report['machine'])}, {report['machine']['cpu_count']} cores.",
            "",
            f"{args.cases} hostile requests (seed {args.seed}), one connection each, in {wall:.0f} s; a reference "
            f"stream ran the sample's first 3 frames every {args.every} cases ({len(mismatches)} times).",
            "",
            "| answer | requests |",
            "| --- | ---: |",
        ]
        + [f"| {k} | {v} |" for k, v in counts.items()]
        + [
            "",
            f"- server alive at the end: {alive} (crashes: {0 if alive else 1})",
            f"- reference frames different from the first run's: {int(sum(mismatches))}",
            f"- server RSS: {mib[0]:.0f} MiB at the start, max {max(mib):.0f}, last {mib[-1]:.0f} MiB",
            "",
            f"Slow clients: {slow['slow_connections']} connections send half a request line and stop (the "
            f"server's --request-timeout {args.request_timeout:g} s). A normal stream's 160x90 frame, "
            f"{len(slow['frame_ms_alone'])} each: "
            f"median {slow['median_ms_alone']:.1f} ms alone, {slow['median_ms_beside_slow']:.1f} ms beside them; "
            f"all {slow['slow_connections']} closed by the server {slow['all_closed_after_s']:.1f} s after they "
            "were opened.",
            "",
        ]
    )
    write_report(Path(args.out), report, "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
