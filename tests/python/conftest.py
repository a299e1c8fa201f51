"""pytest fixtures: a real idmd on the simulated stage (config/idmd.yaml with its paths moved to
a temporary directory, no real-time privileges), and clients of it. Starting and stopping idmd,
its configs and idm-simdev are tests/pyfixtures/idmd_process.py's (shared with tests/web and
tests/tango); this file adds the Python client's view and the fixtures.

The package under test is the tree's python/.
"""
import os
import shutil
import socket
import sys
import tempfile

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "pyfixtures"))

import idmd_process  # noqa: E402
# Also for the test modules (`from conftest import ...`).
from idmd_process import (IDMD, SOURCE, TRAVEL, SimDev, axes_config,  # noqa: E402,F401
                          idmd_in_temp_dir, single_axis_config)

sys.path.insert(0, os.path.join(SOURCE, "python"))

import idm  # noqa: E402  (the tree's package)


class Idmd(idmd_process.Idmd):
    """idmd_process.Idmd with clients of the idm package."""

    def client(self, **kwargs):
        return idm.Client("127.0.0.1", self.port, **kwargs)

    def unix_client(self, **kwargs):
        return idm.Client(unix=self.unix, **kwargs)


@pytest.fixture
def tmp_dir():
    d = tempfile.mkdtemp(prefix="idm-py-")
    yield d
    shutil.rmtree(d, ignore_errors=True)


@pytest.fixture(scope="module")
def idmd():
    """One idmd for the tests of a module (the `client` fixture restores what a test changes)."""
    with idmd_in_temp_dir("idm-py-", Idmd) as daemon:
        yield daemon


@pytest.fixture(scope="module")
def idmd_xy():
    """One idmd with two simulated axes x and y on one card (axes_config)."""
    with idmd_in_temp_dir("idm-py-", Idmd, config=axes_config) as daemon:
        yield daemon


@pytest.fixture
def make_idmd(tmp_dir):
    """A factory of idmd instances on edited configs (or config texts, from a directory it
    makes: make_idmd(config=lambda d: axes_config(d, ...))), stopped after the test."""
    started = []

    def make(edits=(), config=None):
        sub = tempfile.mkdtemp(dir=tmp_dir)
        d = Idmd(sub, edits, config(sub) if callable(config) else config)
        started.append(d)
        return d
    yield make
    for d in started:
        d.stop()


def restore(daemon):
    """After a test: every axis stopped and at rest, no user offset, its soft limits back to the
    travel."""
    with daemon.client() as c:
        c.stop()
        for k in range(1, c.axis_count() + 1):
            c.axis(k).wait(30)
            c.axis(k).set_offset(0)
            c.axis(k).set_limits(*TRAVEL)


@pytest.fixture
def client(idmd):
    """A TCP client of the module's idmd; afterwards the axis is stopped, the soft limits put
    back to the travel and the connection closed."""
    c = idmd.client()
    yield c
    c.close()
    restore(idmd)


@pytest.fixture
def client_xy(idmd_xy):
    """A TCP client of the module's two-axis idmd, restored afterwards as `client`."""
    c = idmd_xy.client()
    yield c
    c.close()
    restore(idmd_xy)


def stalled_config():
    """The simulated slider held fast: a closed-loop move ends in a device fault."""
    return [("  sim:\n    clock: wall", "  sim:\n    faults: {slider_stalled: true}\n    clock: wall")]


def beam_lost_config():
    """The interferometer reports the measurement signal lost: no valid position."""
    return [("  sim:\n    clock: wall", "  sim:\n    faults: {beam_lost: true}\n    clock: wall")]


def ready_timeout_config(seconds):
    return [("  max_clients: 16", "  max_clients: 16\n  ready_timeout_s: %g" % seconds)]


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
