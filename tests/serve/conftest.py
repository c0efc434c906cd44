"""The server fixture of the serve tests."""

import threading

import pytest

from jnds_deploy.serve import FrameServer, ServeConfig, make_http_server


@pytest.fixture
def server(tiny_artifacts):
    """Start a server on a free loopback port; yields a function making (url, FrameServer)
    for a config, shuts everything down afterwards."""
    started = []

    def start(**kw):
        cfg = ServeConfig(artifacts=str(tiny_artifacts[0]), port=0, precision="fp32", **kw)
        fs = FrameServer(cfg)
        httpd = make_http_server(fs)
        threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
        started.append((fs, httpd))
        return f"http://127.0.0.1:{httpd.server_address[1]}", fs

    yield start
    for fs, httpd in started:
        fs.close(timeout=10)
        httpd.shutdown()
        httpd.server_close()
