"""A small budget of the hostile requests of benchmarks/serve_fuzz.py on every CI run:
no 500 (an unhandled case), the server alive, another stream's output unchanged."""

import numpy as np

from jnds_deploy.serve import Client
from jnds_deploy.serve.server import rss_bytes

from .test_server import _frames


def test_hostile_requests_are_answered_and_change_nothing(server):
    from benchmarks.serve_fuzz import fuzz

    url, fs = server(request_timeout=2.0)
    layers = _frames()[:3]
    with Client(url).open_stream() as s:
        first = [s.denoise(f, c) for f, c in layers]
    before = rss_bytes()

    def reference():
        with Client(url).open_stream() as s:
            for (f, c), want in zip(layers, first):
                np.testing.assert_array_equal(s.denoise(f, c), want)

    counts = fuzz(url, 300, seed=1, reference=reference, every=50)
    assert "500" not in counts, counts
    assert sum(counts.values()) == 300 and set(counts) <= {
        "200",
        "400",
        "404",
        "405",
        "408",
        "411",
        "413",
        "414",
        "431",
        "501",
        "503",
        "closed",
    }, counts
    assert Client(url).health()["status"] == "ok"
    assert rss_bytes() - before < 300 * 2**20
