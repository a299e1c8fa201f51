"""Fixtures of the Tango device server tests: a real idmd on the simulated stage (the Idmd helper
of tests/python/conftest.py) and idm-tango started without a database (-nodb -port -dlist),
driven by PyTango (Debian's python3-tango).

The simulated stage is slowed (a 1.5 um stroke: about 0.8 mm/s) so that a long move
lasts seconds and a Stop lands in the middle of it."""
import importlib.util
import os
import select
import shutil
import signal
import subprocess
import tempfile
import time

import pytest
import tango

_spec = importlib.util.spec_from_file_location(
    "idm_daemon_fixtures", os.path.join(os.path.dirname(__file__), "..", "python", "conftest.py"))
fixtures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fixtures)

BUILD = fixtures.BUILD
IDM_TANGO = os.path.join(BUILD, "tango", "idm-tango")
SLOW = [("stroke_m: 20.35e-6", "stroke_m: 1.5e-6")]


class TangoServer:
    """idm-tango INSTANCE -nodb -port P -dlist DEVICES, finding idmd from `env`."""

    def __init__(self, tmp, env, devices=("idm/axis/1",), instance="test"):
        if not os.path.exists(IDM_TANGO):
            pytest.fail("idm-tango is not built: %s" % IDM_TANGO)
        self.port = fixtures.free_port()
        self.log_path = os.path.join(tmp, "idm-tango-%s.log" % instance)
        self._log = open(self.log_path, "w")
        full_env = {k: v for k, v in os.environ.items() if k not in ("IDMD_SOCKET", "IDMD_ADDRESS")}
        full_env.update(env)
        self.proc = subprocess.Popen(
            [IDM_TANGO, instance, "-nodb", "-port", str(self.port), "-dlist", ",".join(devices)],
            stdout=subprocess.PIPE, stderr=self._log, text=True, env=full_env)
        ready, _, _ = select.select([self.proc.stdout], [], [], 60)
        line = self.proc.stdout.readline() if ready else ""
        if "ready" not in line:
            self.stop()
            pytest.fail("idm-tango did not start: %r\n%s" % (line, self.log()))

    def proxy(self, device="idm/axis/1"):
        d = tango.DeviceProxy("tango://127.0.0.1:%d/%s#dbase=no" % (self.port, device))
        d.set_timeout_millis(10000)
        return d

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


@pytest.fixture(scope="module")
def lab():
    """One slowed idmd (one axis x) and one idm-tango serving idm/axis/1 over its Unix socket."""
    d = tempfile.mkdtemp(prefix="idm-tango-")
    daemon = fixtures.Idmd(d, edits=SLOW)
    server = TangoServer(d, {"IDMD_SOCKET": daemon.unix})
    yield daemon, server
    alive = server.alive()
    server.stop()
    rc = daemon.stop()
    shutil.rmtree(d, ignore_errors=True)
    assert alive, "idm-tango died during the tests"
    assert rc == 0, "idmd exited %r" % rc


def wait_for(what, predicate, timeout=60, period=0.02):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(period)
    pytest.fail("timed out waiting for " + what)
