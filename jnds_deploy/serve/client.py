"""A Python client of ``jnds serve`` (standard library HTTP, one keep-alive connection
per stream).

    from jnds_deploy.serve import Client

    with Client("http://127.0.0.1:8765").open_stream() as stream:
        for frame in render_loop():              # dicts of HWC float32 layers
            color = stream.denoise(frame.layers, camera_cut=frame.cut)
            present(color)                       # (2H, 2W, 3) float32, linear

``denoise`` waits and retries while the server answers 429 (the stream's queue is
full) or 503 with Retry-After, up to ``retry_for`` seconds.
"""

from __future__ import annotations

import http.client
import json
import time
from urllib.parse import urlsplit

import numpy as np
import OpenEXR

from ..errors import ServerError
from ..io import INPUT_LAYERS, OPTIONAL_INPUT_LAYERS, OUTPUT_LAYERS, channels_to_layers, exr_bytes, read_exr_bytes


class _Connection:
    def __init__(self, url: str, timeout: float):
        u = urlsplit(url)
        self.host, self.port = u.hostname or "127.0.0.1", u.port or 80
        self.timeout = timeout
        self.conn: http.client.HTTPConnection | None = None

    def request(
        self, method: str, path: str, body: bytes | None = None, headers: dict | None = None
    ) -> tuple[int, dict, bytes]:
        for attempt in (0, 1):
            if self.conn is None:
                self.conn = http.client.HTTPConnection(self.host, self.port, timeout=self.timeout)
            try:
                self.conn.request(method, path, body=body, headers=headers or {})
                r = self.conn.getresponse()
                data = r.read()
                if r.getheader("Connection", "").lower() == "close":
                    self.close()
                return r.status, {k.lower(): v for k, v in r.getheaders()}, data
            except (http.client.RemoteDisconnected, BrokenPipeError, ConnectionResetError):
                # a keep-alive connection the server closed while idle: reconnect once.
                # The request never reached a handler, so sending it again is safe.
                self.close()
                if attempt:
                    raise
        raise AssertionError("unreachable")

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None


def _check(status: int, headers: dict, data: bytes) -> None:
    if status >= 400:
        try:
            err = json.loads(data)
            raise ServerError(status, err.get("error", ""), err.get("kind", ""))
        except ValueError:
            raise ServerError(status, data[:200].decode(errors="replace")) from None


class Client:
    def __init__(self, url: str = "http://127.0.0.1:8765", timeout: float = 120.0):
        self.url, self.timeout = url, timeout
        self._conn = _Connection(url, timeout)

    def _json(self, method: str, path: str) -> dict:
        status, headers, data = self._conn.request(method, path)
        _check(status, headers, data)
        return json.loads(data)

    def health(self) -> dict:
        return self._json("GET", "/health")

    def metrics(self) -> dict:
        return self._json("GET", "/metrics.json")

    def open_stream(self) -> "ClientStream":
        info = self._json("POST", "/streams")
        return ClientStream(self, info)

    def close(self) -> None:
        self._conn.close()


class ClientStream:
    """One stream: its own connection, its own history on the server."""

    def __init__(self, client: Client, info: dict, retry_for: float = 30.0):
        self.id, self.scale = info["stream"], info["scale"]
        self.retry_for = retry_for
        self._conn = _Connection(client.url, client.timeout)
        self.timings: dict[str, float] = {}  # of the last frame, ms per stage (server side)
        self.nonfinite: dict[str, int] = {}  # of the last frame, NaN/Inf replaced per layer
        self.frame_index = -1

    def denoise_exr(self, exr: bytes, camera_cut: bool = False) -> bytes:
        """One frame as an EXR file (input channels of jnds-sequence/1) -> the output EXR."""
        path = f"/streams/{self.id}/frames" + ("?cut=1" if camera_cut else "")
        deadline = time.monotonic() + self.retry_for
        while True:
            status, headers, data = self._conn.request("POST", path, exr, {"Content-Type": "image/x-exr"})
            if status in (429, 503) and "retry-after" in headers and time.monotonic() < deadline:
                time.sleep(float(headers["retry-after"]))
                continue
            _check(status, headers, data)
            self.timings = json.loads(headers.get("x-jnds-timings", "{}"))
            self.nonfinite = json.loads(headers.get("x-jnds-nonfinite", "{}"))
            self.frame_index = int(headers.get("x-jnds-frame", -1))
            return data

    def denoise(self, layers: dict[str, np.ndarray], camera_cut: bool = False) -> np.ndarray:
        """One frame's HWC float32 layers -> the output colour (HWC float32, linear)."""
        suffixes = {k: v for k, v in {**INPUT_LAYERS, **OPTIONAL_INPUT_LAYERS}.items() if k in layers}
        body = exr_bytes({k: layers[k] for k in suffixes}, suffixes, compression=OpenEXR.NO_COMPRESSION)
        out = read_exr_bytes(self.denoise_exr(body, camera_cut), "response")
        return channels_to_layers(out, "response", None, OUTPUT_LAYERS)["color"]

    def reset(self) -> None:
        _check(*self._conn.request("POST", f"/streams/{self.id}/reset"))

    def info(self) -> dict:
        status, headers, data = self._conn.request("GET", f"/streams/{self.id}")
        _check(status, headers, data)
        return json.loads(data)

    def close(self) -> None:
        try:
            _check(*self._conn.request("DELETE", f"/streams/{self.id}"))
        finally:
            self._conn.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
