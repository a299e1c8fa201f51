"""Fixtures of the Tango device server tests: a real idmd on the simulated stage
(tests/pyfixtures' idmd_process) and idm-tango started without a database (-nodb -port -dlist),
driven by PyTango (Debian's python3-tango).

The simulated stage is slowed (a 1.5 um stroke: about 0.8 mm/s) so that a long move
lasts seconds and a Stop lands in the middle of it."""
import os
import sys
import time

import pytest
import tango

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "pyfixtures"))

import idmd_process as fixtures  # noqa: E402

BUILD = fixtures.BUILD
IDM_TANGO = os.path.join(BUILD, "tango", "idm-tango")
SLOW = [("stroke_m: 20.35e-6", "stroke_m: 1.5e-6")]


class TangoServer(fixtures.ChildProcess):
    """idm-tango INSTANCE -nodb -port P -dlist DEVICES, finding idmd from `env`."""

    def __init__(self, tmp, env, devices=("idm/axis/1",), instance="test"):
        fixtures.require_built(IDM_TANGO, "idm-tango")
        super().__init__(os.path.join(tmp, "idm-tango-%s.log" % instance))
        self.port = fixtures.free_port()
        full_env = {k: v for k, v in os.environ.items() if k not in ("IDMD_SOCKET", "IDMD_ADDRESS")}
        full_env.update(env)
        line = self.start(
            [IDM_TANGO, instance, "-nodb", "-port", str(self.port), "-dlist", ",".join(devices)],
            60, env=full_env)
        if "ready" not in line:
            self.stop()
            pytest.fail("idm-tango did not start: %r\n%s" % (line, self.log()))

    def proxy(self, device="idm/axis/1"):
        d = tango.DeviceProxy("tango://127.0.0.1:%d/%s#dbase=no" % (self.port, device))
        d.set_timeout_millis(10000)
        return d


@pytest.fixture(scope="module")
def lab():
    """One slowed idmd (one axis x) and one idm-tango serving idm/axis/1 over its Unix socket."""
    with fixtures.idmd_in_temp_dir("idm-tango-", edits=SLOW) as daemon:
        server = TangoServer(daemon.tmp, {"IDMD_SOCKET": daemon.unix})
        yield daemon, server
        alive = server.alive()
        server.stop()
    assert alive, "idm-tango died during the tests"


def wait_for(what, predicate, timeout=60, period=0.02):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(period)
    pytest.fail("timed out waiting for " + what)
