"""Fixtures of the status page tests: a real idmd on the simulated stage (tests/pyfixtures'
idmd_process) and idm-web as a separate process, on a free port.

The simulated stage is slowed (a 1.5 um stroke: about 0.8 mm/s) so that a long move lasts
seconds and a STOP lands in the middle of it."""
import json
import os
import re
import socket
import sys
import time
import urllib.error
import urllib.request

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "pyfixtures"))

import idmd_process as fixtures  # noqa: E402

BUILD = fixtures.BUILD
IDM_WEB = os.path.join(BUILD, "web", "idm-web")
SLOW = [("stroke_m: 20.35e-6", "stroke_m: 1.5e-6")]


class Web(fixtures.ChildProcess):
    """idm-web ARGS --listen LISTEN (default 127.0.0.1:0), the environment `env` (None: this
    one's); `url` is where it listens (a wildcard listener through 127.0.0.1)."""

    def __init__(self, tmp, args, name="web", listen="127.0.0.1:0", env=None):
        fixtures.require_built(IDM_WEB, "idm-web")
        super().__init__(os.path.join(tmp, "idm-web-%s.log" % name))
        line = self.start([IDM_WEB] + list(args) + ["--listen", listen], 30, env=env)
        m = re.search(r"http://(\S+):(\d+)/", line)
        if not m:
            self.stop()
            pytest.fail("idm-web did not start: %r\n%s" % (line, self.log()))
        self.port = int(m.group(2))
        host = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}.get(m.group(1), m.group(1))
        self.url = "http://%s:%d" % (host, self.port)

    def request(self, path, method="GET", data=None, headers=None, timeout=30):
        """(status, headers, body bytes); HTTP errors are returned, not raised."""
        req = urllib.request.Request(self.url + path, method=method, data=data,
                                     headers=headers or {})
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                return r.status, r.headers, r.read()
        except urllib.error.HTTPError as e:
            return e.code, e.headers, e.read()

    def json(self, path):
        status, _, body = self.request(path)
        assert status == 200, (path, status, body)
        return json.loads(body)

    def metrics(self):
        status, headers, body = self.request("/metrics")
        assert status == 200
        assert headers["Content-Type"].startswith("text/plain; version=0.0.4")
        return body.decode()


def read_reply(s):
    """Everything a socket receives until the server closes (or resets) the connection."""
    out = b""
    while True:
        try:
            chunk = s.recv(65536)
        except (ConnectionResetError, socket.timeout):
            break
        if not chunk:
            break
        out += chunk
    return out


def wait_for(what, predicate, timeout=30, period=0.05):
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        last = predicate()
        if last:
            return last
        time.sleep(period)
    pytest.fail("timed out waiting for %s (last: %r)" % (what, last))


ask = fixtures.ask
send = fixtures.send


def wait_done(daemon, timeout=60):
    wait_for("the motion done", lambda: ask(daemon, "MOVE:DONE?")[0] == "1", timeout)


def mean_position(daemon, n=8):
    return sum(float(ask(daemon, "POS?")[0]) for _ in range(n)) / n


@pytest.fixture(scope="module")
def lab():
    """A slowed idmd (one axis x), idm-web read-only on its TCP port and idm-web with --control on
    its Unix socket."""
    with fixtures.idmd_in_temp_dir("idm-web-", edits=SLOW) as daemon:
        readonly = Web(daemon.tmp, ["--idmd", "127.0.0.1:%d" % daemon.port], "readonly")
        control = Web(daemon.tmp, ["--unix", daemon.unix, "--control"], "control")
        # idm-web answers before its first poll of idmd has come back (connected: false until
        # then); on a loaded machine that poll can take a while, so the tests start after it.
        for web in (readonly, control):
            wait_for("idm-web's first poll of idmd",
                     lambda web=web: web.json("/api/state")["connected"], 30)
        yield daemon, readonly, control
        alive = readonly.alive() and control.alive()
        rc = [readonly.stop(), control.stop()]
    assert alive, "idm-web died during the tests"
    assert rc == [0, 0], "idm-web exited %r" % rc


@pytest.fixture
def restore(lab):
    """After a test: every axis stopped and at rest, the soft limits the travel."""
    yield
    daemon = lab[0]
    send(daemon, "STOP")
    wait_done(daemon)
    send(daemon, "LIM %g,%g" % fixtures.TRAVEL)
