"""`jnds serve` over real HTTP on loopback: round trip against `jnds run`, separate
histories, bad requests, stream control, shutdown."""

import threading
import time

import numpy as np
import OpenEXR
import pytest

from jnds_deploy.io import INPUT_LAYERS, exr_bytes, open_sequence, read_exr
from jnds_deploy.runtime.pipeline import Pipeline, PipelineConfig
from jnds_deploy.runtime.run import run_sequence
from jnds_deploy.serve import Client, ServeConfig, ServerError
from jnds_deploy.serve.server import BadRequest

from ..conftest import SAMPLE


def _frames():
    seq = open_sequence(SAMPLE)
    return [(seq.inputs(i), seq.frames[i].camera_cut) for i in range(len(seq))]


def test_stream_round_trip_equals_jnds_run(server, tiny_artifacts, tmp_path):
    url, _ = server()
    run_sequence(
        PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"),
        SAMPLE,
        tmp_path / "run",
        progress=False,
        metrics=False,
    )
    client = Client(url)
    assert client.health()["status"] == "ok"
    timings = []
    with client.open_stream() as stream:
        for i, (layers, cut) in enumerate(_frames()):
            got = stream.denoise(layers, cut)
            want = read_exr(tmp_path / "run" / f"{i:04d}.exr")
            # float32 EXR both ways: the server computes exactly what `jnds run` does
            np.testing.assert_array_equal(got, np.stack([want[f"color.{c}"] for c in "RGB"], -1))
            t = stream.timings
            assert stream.frame_index == i
            # the pipeline's total is its stages' sum; the request's time holds the queue and
            # it (the header rounds each to 0.001 ms)
            stages = {k: v for k, v in t.items() if k not in ("total", "queue", "server")}
            assert "network" in stages and t["total"] == pytest.approx(sum(stages.values()), abs=5e-4 * len(t))
            assert t["server"] >= t["queue"] + t["total"] - 2e-3
            timings.append(t)
    # the server's metrics hold exactly the frames sent: their count, and percentiles over the
    # timings each frame's response carried
    m = client.metrics()
    assert m["frames_served"] == m["latency_window"] == len(timings) == 8 and m["streams_open"] == 0
    assert set(m["latency_ms"]) == set().union(*timings)
    for k, p in m["latency_ms"].items():
        for q in (50, 90, 99):
            assert p[f"p{q}"] == pytest.approx(np.percentile([t.get(k, 0.0) for t in timings], q), abs=1e-3), (k, q)


def test_warmup_sizes_leave_no_trace_in_the_streams(server, tiny_artifacts, tmp_path, caplog):
    """--warmup runs a frame at each size before serving; a stream then computes exactly
    what `jnds run` does. Sizes that are not positive or exceed max_pixels are refused."""
    import logging

    run_sequence(
        PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"),
        SAMPLE,
        tmp_path / "run",
        progress=False,
        metrics=False,
    )
    with caplog.at_level(logging.INFO, logger="jnds.serve"):
        url, _ = server(warmup=((160, 90), (64, 36)))
    assert "warmed up at 160x90" in caplog.text and "warmed up at 64x36" in caplog.text
    with Client(url).open_stream() as stream:
        for i, (layers, cut) in enumerate(_frames()[:3]):
            want = read_exr(tmp_path / "run" / f"{i:04d}.exr")
            np.testing.assert_array_equal(
                stream.denoise(layers, cut), np.stack([want[f"color.{c}"] for c in "RGB"], -1)
            )
    for bad in ((0, 90), (2000, 2000)):
        with pytest.raises(ValueError, match=f"warm-up size {bad[0]}x{bad[1]}"):
            ServeConfig(artifacts=str(tiny_artifacts[0]), warmup=(bad,))


def test_concurrent_streams_keep_separate_histories(server, tiny_artifacts):
    url, _ = server(workers=2)
    frames = _frames()
    orders = {"forward": frames, "backward": frames[::-1]}
    want = {}
    for name, fr in orders.items():
        pipe = Pipeline(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"))
        want[name] = [pipe(layers, False).output for layers, _ in fr]
    got, errors = {}, []

    def run(name):
        try:
            with Client(url).open_stream() as s:
                got[name] = [s.denoise(layers) for layers, _ in orders[name]]
        except Exception as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(n,)) for n in orders]
    [t.start() for t in threads]
    [t.join(60) for t in threads]
    assert not errors, errors
    for name in orders:
        for g, w in zip(got[name], want[name]):
            np.testing.assert_array_equal(g, w)


def _exr(layers, drop=(), uint=None):
    suffixes = {k: v for k, v in INPUT_LAYERS.items() if k not in drop}
    body = exr_bytes({k: layers[k] for k in suffixes}, suffixes, compression=OpenEXR.NO_COMPRESSION)
    if uint:  # the same file with one channel stored as 32-bit unsigned int
        import io

        f = OpenEXR.File(io.BytesIO(body), separate_channels=True)
        ch = {k: c.pixels for k, c in f.channels().items()}
        ch[uint] = ch[uint].astype(np.uint32)
        buf = io.BytesIO()
        OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}, ch).write(buf)
        body = buf.getvalue()
    return body


def test_bad_frames_get_clear_errors_and_the_stream_goes_on(server, tiny_artifacts):
    url, _ = server()
    frames = _frames()
    pipe = Pipeline(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"))
    client = Client(url)
    stream = client.open_stream()
    other = client.open_stream()
    flood = {**frames[1][0], "specular": np.full_like(frames[1][0]["specular"], np.nan)}
    bad = [
        (b"not an exr at all", "unreadable or truncated OpenEXR"),
        (_exr(frames[1][0], drop=("motion",)), "missing channel\\(s\\) motion.X, motion.Y"),
        (_exr(frames[1][0], uint="roughness"), "channel 'roughness' is stored as uint32, expected half or float"),
        (_exr(flood), "layer 'specular' has 43200 of 43200 values NaN or Inf"),
    ]
    for i, (layers, cut) in enumerate(frames[:4]):
        want = pipe(layers, cut).output
        body, message = bad[i]
        with pytest.raises(ServerError, match=message) as exc:
            stream.denoise_exr(body)
        assert exc.value.status == 400
        # the refused frame left the history alone: this one matches the plain pipeline
        np.testing.assert_array_equal(stream.denoise(layers, cut), want)
        other.denoise(layers, cut)
    # a few NaN pixels are not a flood: replaced, counted, output finite
    spotty = {k: v.copy() for k, v in frames[4][0].items()}
    spotty["diffuse"][3, 4, :] = np.nan
    out = stream.denoise(spotty)
    assert stream.nonfinite == {"diffuse": 3} and np.isfinite(out).all()
    with pytest.raises(ServerError, match="is not open") as exc:
        Client(url)._json("GET", "/streams/nosuchstream")
    assert exc.value.status == 404
    with pytest.raises(ServerError, match="no such endpoint"):
        Client(url)._json("GET", "/nothing")
    m = client.metrics()
    assert m["errors"] == {"400": 4, "404": 2} and m["streams_open"] == 2


def test_stream_control_reset_resize(server, tiny_artifacts):
    url, fs = server()
    frames = _frames()
    pipe = Pipeline(PipelineConfig(artifacts=str(tiny_artifacts[0]), precision="fp32"))
    stream = Client(url).open_stream()
    stream.denoise(frames[0][0])
    stream.denoise(frames[1][0])
    stream.reset()  # as a camera cut: the next frame starts without history
    np.testing.assert_array_equal(stream.denoise(frames[2][0]), pipe(frames[2][0], camera_cut=True).output)
    small = {k: np.ascontiguousarray(v[:45, :70]) for k, v in frames[3][0].items()}
    out = stream.denoise(small)  # a resolution change resets history too
    assert out.shape == (90, 140, 3)
    np.testing.assert_array_equal(out, pipe(small, camera_cut=True).output)


def test_idle_streams_are_closed(server):
    url, fs = server(idle_timeout=1.0)
    client = Client(url)
    idle, busy = client.open_stream(), client.open_stream()
    frame = _frames()[0][0]
    t_end = time.monotonic() + 2.5
    while time.monotonic() < t_end:  # one stream keeps sending, the other idles past the timeout
        busy.denoise(frame)
    with pytest.raises(ServerError, match="not open") as exc:
        idle.denoise(frame)
    assert exc.value.status == 404 and list(fs.streams) == [busy.id]


def test_queue_limit_refuses_instead_of_buffering(server):
    _, fs = server(queue=0, max_streams=1)
    s = fs.open_stream()
    with pytest.raises(BadRequest, match="too many open streams") as exc:
        fs.open_stream()
    assert exc.value.status == 503
    s.running = True  # as while a frame of this stream is being processed
    with pytest.raises(BadRequest, match="already queued") as exc:
        fs.denoise(s, _frames()[0][0], False)
    assert exc.value.status == 429 and exc.value.retry_after > 0 and not s.jobs
    s.running = False


def test_shutdown_finishes_in_flight_frames(server):
    url, fs = server()
    frames = _frames()
    stream = Client(url).open_stream()
    results, errors = [], []

    def send():
        try:
            for layers, _ in frames[:4]:
                results.append(stream.denoise(layers))
        except ServerError as exc:
            errors.append(exc)

    t = threading.Thread(target=send)
    t.start()
    while not results:
        time.sleep(0.005)
    fs.close(timeout=30)  # refuses new frames, waits for the ones in flight
    t.join(30)
    assert not t.is_alive() and fs.pool._shutdown
    # every frame sent either came back whole or was refused with 503; none got lost
    assert all(r.shape == (180, 320, 3) and np.isfinite(r).all() for r in results)
    assert len(results) == 4 or (len(errors) == 1 and errors[0].status == 503), (len(results), errors)


def test_jnds_serve_command_serves_and_stops_on_sigterm(tiny_artifacts):
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "jnds_deploy",
            "serve",
            "--artifacts",
            str(tiny_artifacts[0]),
            "--port",
            "0",
            "--precision",
            "fp32",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("jnds serve: listening on http://127.0.0.1:"), (line, proc.stderr.read())
        with Client(line.split()[-1]).open_stream() as stream:
            assert stream.denoise(_frames()[0][0]).shape == (180, 320, 3)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
        assert "stopped after 1 frames" in proc.stderr.read()
    finally:
        proc.kill()


def test_a_frame_declaring_too_many_pixels_is_refused_before_decoding(server):
    """A 4000x4000 EXR of zeros in the 15 input channels compresses to a few hundred kB;
    its header is refused with 413 at once, the process's memory does not grow by the
    frame, and the stream goes on."""
    import http.client
    import io
    import json
    import resource
    import time

    import OpenEXR

    url, fs = server()
    zeros = np.zeros((4000, 4000), np.float16)
    names = [
        f"{layer}.{c}" if c else layer
        for layer, cs in (
            ("diffuse", "RGB"),
            ("specular", "RGB"),
            ("albedo", "RGB"),
            ("normal", "XYZ"),
            ("roughness", [""]),
            ("motion", "XY"),
        )
        for c in cs
    ]
    buf = io.BytesIO()
    OpenEXR.File(
        {"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION}, {n: zeros for n in names}
    ).write(buf)
    body = buf.getvalue()
    assert len(body) < 1 << 20
    with Client(url).open_stream() as stream:
        host, port = url.split("//")[1].split(":")
        conn = http.client.HTTPConnection(host, int(port), timeout=30)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        t0 = time.perf_counter()
        conn.request(
            "POST",
            f"/streams/{stream.id}/frames",
            body=body,
            headers={"Content-Type": "image/x-exr", "Content-Length": str(len(body))},
        )
        resp = conn.getresponse()
        answer = json.loads(resp.read())
        assert resp.status == 413 and time.perf_counter() - t0 < 10
        assert "4000x4000" in answer["error"] and "--max-pixels" in answer["error"]
        grown_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak
        assert grown_kib < 300 * 1024, grown_kib
        layers, cut = _frames()[0]
        assert stream.denoise(layers, cut).shape == (180, 320, 3)  # the stream goes on


def test_slow_clients_are_closed_and_do_not_starve_others(server):
    """200 connections that send half a request line and stop are closed after the request
    timeout, and a normal client is served meanwhile."""
    import socket
    import time

    url, fs = server(request_timeout=3.0)
    host, port = url.split("//")[1].split(":")
    slow = []
    for _ in range(200):
        s = socket.create_connection((host, int(port)), timeout=20)
        s.sendall(b"POST /str")
        slow.append(s)
    layers, cut = _frames()[0]
    with Client(url).open_stream() as stream:
        assert stream.denoise(layers, cut).shape == (180, 320, 3)
    t0 = time.monotonic()
    for s in slow:
        assert s.recv(1000) == b""  # closed by the server
        s.close()
    assert time.monotonic() - t0 < 30


def test_connections_beyond_the_limit_get_503(server):
    import socket
    import time

    url, fs = server(max_connections=5)
    host, port = url.split("//")[1].split(":")
    idle = [socket.create_connection((host, int(port)), timeout=10) for _ in range(5)]
    time.sleep(0.5)  # accepted: each holds a thread waiting for its request line
    extra = socket.create_connection((host, int(port)), timeout=10)
    assert extra.recv(200).startswith(b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 1")
    for s in idle + [extra]:
        s.close()


def test_a_body_that_never_completes_gets_408(server):
    import socket

    url, fs = server(body_timeout=1.0, request_timeout=5.0)
    host, port = url.split("//")[1].split(":")
    with Client(url).open_stream() as stream:
        s = socket.create_connection((host, int(port)), timeout=10)
        s.sendall(
            f"POST /streams/{stream.id}/frames HTTP/1.1\r\nHost: x\r\nContent-Length: 1000\r\n\r\n".encode() + b"x" * 10
        )
        reply = b""
        while chunk := s.recv(4096):  # trickle nothing more; the server answers, then closes
            reply += chunk
        s.close()
    assert reply.startswith(b"HTTP/1.1 408") and b"10 of 1000 bytes" in reply


def test_metrics_in_prometheus_text_format(server):
    import urllib.request

    from prometheus_client.parser import text_string_to_metric_families

    url, fs = server()
    layers, cut = _frames()[0]
    with Client(url).open_stream() as stream:
        stream.denoise(layers, cut)
        stream.denoise(layers, False)
    with urllib.request.urlopen(url + "/metrics") as r:
        assert r.headers["Content-Type"].startswith("text/plain")
        families = {f.name: f for f in text_string_to_metric_families(r.read().decode())}
    assert families["jnds_frames"].samples[0].value == 2
    assert families["jnds_streams_open"].samples[0].value == 0 and families["jnds_rss_bytes"].samples[0].value > 0
    counts = {
        s.labels["stage"]: s.value for s in families["jnds_stage_latency_seconds"].samples if s.name.endswith("_count")
    }
    assert counts["network"] == 2 and counts["server"] == 2
    assert Client(url).metrics()["frames_served"] == 2  # the JSON stays, at /metrics.json


def test_the_memory_budget_refuses_what_does_not_fit(server):
    """A frame whose estimated memory exceeds the budget gets 413 from its header; the
    budget reserved by a served frame is released."""
    from jnds_deploy.serve.server import FRAME_BYTES_PER_PIXEL

    layers, cut = _frames()[0]
    need = 160 * 90 * FRAME_BYTES_PER_PIXEL
    url, fs = server(max_memory=need - 1)
    with Client(url).open_stream() as stream:
        with pytest.raises(ServerError, match="HTTP 413: .*160x90 frame needs about .* memory budget"):
            stream.denoise(layers, cut)
    url, fs = server(max_memory=need)
    with Client(url).open_stream() as stream:
        stream.denoise(layers, cut)
    assert fs.reserved == 0 and Client(url).metrics()["memory_budget_bytes"] == need
