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

SIMDEV = os.path.join(BUILD, "tools", "idm-simdev")

TRAVEL = (-5e-3, 5e-3)  # config/idmd.yaml stage.travel_m: the default soft limits


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def top_sections(text):
    """The top-level sections of a config file, as {name: [the lines of its body]} (the body
    keeps its own indentation; comments and blank lines between sections are dropped)."""
    sections, name = {}, None
    for line in text.splitlines():
        if line and not line[0].isspace() and not line.startswith("#"):
            key = line.split(":", 1)[0].strip()
            name = key
            sections[name] = []
        elif name is not None and line.strip() and not line.lstrip().startswith("#"):
            sections[name].append(line)
    return sections


def indented(lines, spaces):
    return "\n".join(" " * spaces + line for line in lines) + "\n"


def edit(text, edits, what):
    for old, new in edits:
        if old not in text:
            pytest.fail("config edit: %r is not in %s" % (old, what))
        text = text.replace(old, new)
    return text


def base_edits(tmp):
    """config/idmd.yaml's paths under `tmp`, no real-time privileges asked for."""
    return [("/var/lib/idmd/calibration.txt", os.path.join(tmp, "calibration.txt")),
            ("/var/lib/idmd/data", os.path.join(tmp, "data")),
            ("sched_fifo: true", "sched_fifo: false"),
            ("lock_memory: true", "lock_memory: false")]


def read_config(name):
    with open(os.path.join(SOURCE, "config", name)) as f:
        return f.read()


def single_axis_config(tmp, edits=()):
    """config/idmd.yaml (one axis `x`), paths under `tmp`, `edits` (old, new) applied."""
    return edit(read_config("idmd.yaml"), base_edits(tmp) + list(edits), "config/idmd.yaml")


def axes_config(tmp, names=("x", "y"), stalled=(), modbus=None):
    """A config with several axes (the `devices:` / `axes:` form): every axis the stage,
    interferometer, sim and control of config/idmd.yaml (each with its own calibration file),
    on one simulated card `card` (config/idmd.yaml's daq.sim). Axes in `stalled` are on a
    second simulated card `stuck` whose slider is held (a closed-loop move there ends in fault
    102). `modbus` = (name, port): that axis is instead config/idmd-modbus.yaml's stage on the
    Modbus device `remote` at 127.0.0.1:port (idm-simdev, see SimDev)."""
    top = top_sections(single_axis_config(tmp))
    daq = top["daq"]  # "  driver: sim", "  sim:", "    clock: wall", ...
    out = ["devices:", "  card:"] + ["  " + line for line in daq]
    if stalled:
        out += ["  stuck:"] + ["  " + line for line in daq]
        out.append("      faults: {slider_stalled: true}")
    if modbus is not None:
        mtop = top_sections(read_config("idmd-modbus.yaml"))
        mdaq = edit("\n".join(mtop["daq"]), [("port: 1502", "port: %d" % modbus[1])],
                    "config/idmd-modbus.yaml")
        out += ["  remote:"] + ["  " + line for line in mdaq.splitlines()]
    out.append("axes:")
    for index, name in enumerate(names):
        out.append("  %s:" % name)
        if modbus is not None and name == modbus[0]:
            out.append("    device: remote")
            stage = edit("\n".join(mtop["stage"]), [("step_correction: 0.35",
                                                     "step_correction: 1.0")],
                         "config/idmd-modbus.yaml")
            sections = [("stage", stage.splitlines()), ("interferometer", mtop["interferometer"]),
                        ("control", mtop["control"])]
        else:
            out.append("    device: %s" % ("stuck" if name in stalled else "card"))
            sections = [(key, top[key]) for key in ("stage", "interferometer", "sim", "control")]
        for key, body in sections:
            text = "\n".join(body)
            for cal in (os.path.join(tmp, "calibration.txt"), "/var/lib/idmd/calibration.txt"):
                text = text.replace(cal, os.path.join(tmp, "calibration-%s.txt" % name))
            if key == "sim":  # each simulated stage its own noise
                text = edit(text, [("seed: 1", "seed: %d" % (index + 1))], "sim:")
            out.append("    %s:" % key)
            out += ["    " + line for line in text.splitlines()]
    for key in ("server", "realtime", "logging", "recording"):
        out.append(key + ":")
        out += top[key]
    return "\n".join(out) + "\n"


class Idmd:
    """idmd on a config: by default a copy of config/idmd.yaml with paths under `tmp`,
    sched_fifo and lock_memory off, `edits` (old, new) applied to the text; or the config text
    `config` (e.g. axes_config). Listens on a free TCP port and a Unix socket.

    idmd prints its "listening" line only once every axis reads a valid position; that is
    checked here (position_valid=1 on every axis at once)."""

    def __init__(self, tmp, edits=(), config=None):
        if not os.path.exists(IDMD):
            pytest.fail("idmd is not built: %s (build the idmd target)" % IDMD)
        self.tmp = tmp
        self.data_dir = os.path.join(tmp, "data")
        text = config if config is not None else single_axis_config(tmp, edits)
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
            pytest.fail("idmd did not start: %r (exit %r)\n%s" % (line, self.proc.returncode,
                                                                 self.log()))
        self.port = int(m.group(1))
        self.check_ready()

    def check_ready(self):
        raw = self.raw()
        try:
            n = int(raw.ask("AXIS:COUNt?"))
            for k in range(1, n + 1):
                st = raw.ask("AXIS%d:STATus?" % k).split()
                if "position_valid=1" not in st:
                    self.stop()
                    pytest.fail("idmd listens but axis %d has no valid position: %s\n%s"
                                % (k, " ".join(st), self.log()))
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
        self.proc.stdout.close()
        self._log.close()
        return self.proc.returncode


class SimDev:
    """tools/idm-simdev: a simulated Modbus TCP device (config/idmd-modbus.yaml's stage and
    word format, the ideal plant) on a free port. stop() ends it (a device that vanishes: idmd
    loses it), start() brings it back on the same port (a new device: its count starts over)."""

    def __init__(self, tmp):
        if not os.path.exists(SIMDEV):
            pytest.fail("idm-simdev is not built: %s (build the idm-simdev target)" % SIMDEV)
        self.port = free_port()
        self.config = os.path.join(tmp, "simdev.yaml")
        text = edit(read_config("idmd-modbus.yaml"),
                    [("port: 1502", "port: %d" % self.port),
                     ("step_correction: 0.35", "step_correction: 1.0")],
                    "config/idmd-modbus.yaml")
        with open(self.config, "w") as f:
            f.write(text)
        self.log_path = os.path.join(tmp, "simdev.log")
        self.proc = None
        self.start()

    def start(self):
        with open(self.log_path, "a") as log:
            self.proc = subprocess.Popen([SIMDEV, "--port", str(self.port), "--config",
                                          self.config], stdout=subprocess.PIPE, stderr=log,
                                         text=True)
        ready, _, _ = select.select([self.proc.stdout], [], [], 30)
        line = self.proc.stdout.readline() if ready else ""
        if "listening" not in line:
            self.stop()
            with open(self.log_path) as f:
                pytest.fail("idm-simdev did not start: %r\n%s" % (line, f.read()))

    def stop(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        if self.proc is not None:
            self.proc.stdout.close()
        return None if self.proc is None else self.proc.returncode


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


@pytest.fixture(scope="module")
def idmd_xy():
    """One idmd with two simulated axes x and y on one card (axes_config)."""
    d = tempfile.mkdtemp(prefix="idm-py-")
    daemon = Idmd(d, config=axes_config(d))
    yield daemon
    rc = daemon.stop()
    shutil.rmtree(d, ignore_errors=True)
    assert rc == 0, "idmd exited %r" % rc


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
    """After a test: every axis stopped and at rest, its soft limits back to the travel."""
    with daemon.client() as c:
        c.stop()
        for k in range(1, c.axis_count() + 1):
            c.axis(k).wait(30)
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
