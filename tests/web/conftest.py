"""Fixtures of the status page tests: a real idmd on the simulated stage (the Idmd helper of
tests/python/conftest.py) and idm-web as a separate process, on a free port.

The simulated stage is slowed (a 1.5 um stroke: about 0.8 mm/s) so that a long move lasts
seconds and a STOP lands in the middle of it."""
import importlib.util
import json
import os
import re
import select
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.error
import urllib.request

import pytest

_spec = importlib.util.spec_from_file_location(
    "idm_daemon_fixtures", os.path.join(os.path.dirname(__file__), "..", "python", "conftest.py"))
fixtures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fixtures)

BUILD = fixtures.BUILD
IDM_WEB = os.path.join(BUILD, "web", "idm-web")
SLOW = [("stroke_m: 20.35e-6", "stroke_m: 1.5e-6")]


class Web:
    """idm-web ARGS --listen 127.0.0.1:0; `url` is where it listens."""

    def __init__(self, tmp, args, name="web"):
        if not os.path.exists(IDM_WEB):
            pytest.fail("idm-web is not built: %s" % IDM_WEB)
        self.log_path = os.path.join(tmp, "idm-web-%s.log" % name)
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen([IDM_WEB] + list(args) + ["--listen", "127.0.0.1:0"],
                                     stdout=subprocess.PIPE, stderr=self._log, text=True)
        ready, _, _ = select.select([self.proc.stdout], [], [], 30)
        line = self.proc.stdout.readline() if ready else ""
        m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
        if not m:
            self.stop()
            pytest.fail("idm-web did not start: %r\n%s" % (line, self.log()))
        self.port = int(m.group(1))
        self.url = "http://127.0.0.1:%d" % self.port

    def request(self, path, method="GET", data=None, headers=None):
        """(status, headers, body bytes); HTTP errors are returned, not raised."""
        req = urllib.request.Request(self.url + path, method=method, data=data,
                                     headers=headers or {})
        try:
            with urllib.request.urlopen(req, timeout=30) as r:
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

    def log(self):
        if not self._log.closed:
            self._log.flush()
        with open(self.log_path) as f:
            return f.read()

    def alive(self):
        return self.proc.poll() is None

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self.proc.stdout.close()
        self._log.close()
        return self.proc.returncode


def wait_for(what, predicate, timeout=30, period=0.05):
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        last = predicate()
        if last:
            return last
        time.sleep(period)
    pytest.fail("timed out waiting for %s (last: %r)" % (what, last))


def ask(daemon, line):
    """One query on a fresh plain connection: (reply, SYST:ERR?'s reply)."""
    raw = daemon.raw()
    try:
        return raw.ask(line), raw.ask("SYST:ERR?")
    finally:
        raw.close()


def send(daemon, line):
    raw = daemon.raw()
    try:
        raw.f.write(line + "\n")
        raw.f.flush()
        err = raw.ask("SYST:ERR?")
        assert err == '0,"No error"', "%s: %s" % (line, err)
    finally:
        raw.close()


def wait_done(daemon, timeout=60):
    wait_for("the motion done", lambda: ask(daemon, "MOVE:DONE?")[0] == "1", timeout)


def mean_position(daemon, n=8):
    return sum(float(ask(daemon, "POS?")[0]) for _ in range(n)) / n


@pytest.fixture(scope="module")
def lab():
    """A slowed idmd (one axis x), idm-web read-only on its TCP port and idm-web with --control on
    its Unix socket."""
    d = tempfile.mkdtemp(prefix="idm-web-")
    daemon = fixtures.Idmd(d, edits=SLOW)
    readonly = Web(d, ["--idmd", "127.0.0.1:%d" % daemon.port], "readonly")
    control = Web(d, ["--unix", daemon.unix, "--control"], "control")
    yield daemon, readonly, control
    alive = readonly.alive() and control.alive()
    rc = [readonly.stop(), control.stop()]
    drc = daemon.stop()
    shutil.rmtree(d, ignore_errors=True)
    assert alive, "idm-web died during the tests"
    assert rc == [0, 0], "idm-web exited %r" % rc
    assert drc == 0, "idmd exited %r" % drc


@pytest.fixture
def restore(lab):
    """After a test: every axis stopped and at rest, the soft limits the travel."""
    yield
    daemon = lab[0]
    send(daemon, "STOP")
    wait_done(daemon)
    send(daemon, "LIM %g,%g" % fixtures.TRAVEL)
