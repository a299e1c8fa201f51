"""pytest fixtures: a real idmd on the simulated stage (config/idmd.yaml with its paths moved to
a temporary directory, no real-time privileges), and clients of it.

The build and source trees come from the environment (IDM_BUILD_DIR, IDM_SOURCE_DIR; CTest sets
them), else this file's tree and its build/. The package under test is the tree's python/.
"""
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

import pytest

SOURCE = os.environ.get("IDM_SOURCE_DIR") or os.path.abspath(
    os.path.join(os.path.dirname(__file__), "..", ".."))
BUILD = os.environ.get("IDM_BUILD_DIR") or os.path.join(SOURCE, "build")
IDMD = os.path.join(BUILD, "daemon", "idmd")

sys.path.insert(0, os.path.join(SOURCE, "python"))

import idm  # noqa: E402  (the tree's package)

TRAVEL = (-5e-3, 5e-3)  # config/idmd.yaml stage.travel_m: the default soft limits


class Idmd:
    """idmd on a copy of config/idmd.yaml: paths under `tmp`, sched_fifo and lock_memory off,
    `edits` (old, new) applied to the text. Listens on a free TCP port and a Unix socket."""

    def __init__(self, tmp, edits=(), wait_valid=True):
        if not os.path.exists(IDMD):
            pytest.fail("idmd is not built: %s (build the idmd target)" % IDMD)
        self.tmp = tmp
        self.data_dir = os.path.join(tmp, "data")
        text = open(os.path.join(SOURCE, "config", "idmd.yaml")).read()
        for old, new in [("/var/lib/idmd/calibration.txt", os.path.join(tmp, "calibration.txt")),
                         ("/var/lib/idmd/data", self.data_dir),
                         ("sched_fifo: true", "sched_fifo: false"),
                         ("lock_memory: true", "lock_memory: false")] + list(edits):
            if old not in text:
                pytest.fail("config edit: %r is not in config/idmd.yaml" % old)
            text = text.replace(old, new)
        self.config = os.path.join(tmp, "idmd.yaml")
        with open(self.config, "w") as f:
            f.write(text)
        self.unix = os.path.join(tmp, "idmd.sock")
        self.log_path = os.path.join(tmp, "idmd.log")
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen([IDMD, "--config", self.config, "--port", "0",
                                      "--unix", self.unix],
                                     stdout=subprocess.PIPE, stderr=self._log, text=True)
        ready, _, _ = select.select([self.proc.stdout], [], [], 60)
        line = self.proc.stdout.readline() if ready else ""
        m = re.search(r"127\.0\.0\.1:(\d+)", line)
        if not m:
            self.stop()
            pytest.fail("idmd did not start: %r\n%s" % (line, self.log()))
        self.port = int(m.group(1))
        if wait_valid:
            self.wait_position_valid()

    def wait_position_valid(self, timeout=30):
        """idmd listens before the simulated interferometer's first reading has arrived (on a
        loaded machine POS? can still answer -240 then): wait for position_valid=1."""
        raw = self.raw()
        try:
            deadline = time.monotonic() + timeout
            while "position_valid=1" not in raw.ask("STAT?").split():
                if time.monotonic() > deadline:
                    self.stop()
                    pytest.fail("idmd has no valid position %g s after it started\n%s"
                                % (timeout, self.log()))
                time.sleep(0.01)
        finally:
            raw.close()

    def log(self):
        if not self._log.closed:
            self._log.flush()
        with open(self.log_path) as f:
            return f.read()

    def client(self, **kwargs):
        return idm.Client("127.0.0.1", self.port, **kwargs)

    def unix_client(self, **kwargs):
        return idm.Client(unix=self.unix, **kwargs)

    def raw(self):
        return RawLine(self.port)

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()
        return self.proc.returncode


class RawLine:
    """A plain line client (no idm code): to see what the daemon itself answers."""

    def __init__(self, port):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.f = self.s.makefile("rw", newline="\n")

    def ask(self, line):
        self.f.write(line + "\n")
        self.f.flush()
        return self.f.readline().rstrip("\n")

    def close(self):
        self.f.close()
        self.s.close()


@pytest.fixture
def tmp_dir():
    d = tempfile.mkdtemp(prefix="idm-py-")
    yield d
    shutil.rmtree(d, ignore_errors=True)


@pytest.fixture(scope="module")
def idmd():
    """One idmd for the tests of a module (the `client` fixture restores what a test changes)."""
    d = tempfile.mkdtemp(prefix="idm-py-")
    daemon = Idmd(d)
    yield daemon
    rc = daemon.stop()
    shutil.rmtree(d, ignore_errors=True)
    assert rc == 0, "idmd exited %r" % rc


@pytest.fixture
def make_idmd(tmp_dir):
    """A factory of idmd instances on edited configs, stopped after the test."""
    started = []

    def make(edits=(), wait_valid=True):
        sub = tempfile.mkdtemp(dir=tmp_dir)
        d = Idmd(sub, edits, wait_valid)
        started.append(d)
        return d
    yield make
    for d in started:
        d.stop()


@pytest.fixture
def client(idmd):
    """A TCP client of the module's idmd; afterwards the axis is stopped, the soft limits put
    back to the travel and the connection closed."""
    c = idmd.client()
    yield c
    c.close()
    with idmd.client() as restore:
        restore.stop()
        restore.axis(1).wait(30)
        restore.axis(1).set_limits(*TRAVEL)


def stalled_config():
    """The simulated slider held fast: a closed-loop move ends in a device fault."""
    return [("  sim:\n    clock: wall", "  sim:\n    faults: {slider_stalled: true}\n    clock: wall")]


def beam_lost_config():
    """The interferometer reports the measurement signal lost: no valid position."""
    return [("  sim:\n    clock: wall", "  sim:\n    faults: {beam_lost: true}\n    clock: wall")]


class SilentServer:
    """A TCP listener that accepts and never answers (for the reply timeouts)."""

    def __init__(self):
        self.s = socket.socket()
        self.s.bind(("127.0.0.1", 0))
        self.s.listen(4)
        self.port = self.s.getsockname()[1]

    def close(self):
        self.s.close()


@pytest.fixture
def silent_server():
    srv = SilentServer()
    yield srv
    srv.close()
