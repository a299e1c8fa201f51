"""A real idmd (and its helpers) as child processes of a pytest run: finding the built binaries,
writing a temporary config, starting a process and waiting for its ready line, tearing it down.
Shared by tests/python, tests/web and tests/tango (README.md here).

The build and source trees come from the environment (IDM_BUILD_DIR, IDM_SOURCE_DIR; CTest sets
them), else this file's tree and its build/.
"""
import contextlib
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import tempfile

import pytest

SOURCE = os.environ.get("IDM_SOURCE_DIR") or os.path.abspath(
    os.path.join(os.path.dirname(__file__), "..", ".."))
BUILD = os.environ.get("IDM_BUILD_DIR") or os.path.join(SOURCE, "build")
IDMD = os.path.join(BUILD, "daemon", "idmd")
SIMDEV = os.path.join(BUILD, "tools", "idm-simdev")

TRAVEL = (-5e-3, 5e-3)  # config/idmd.yaml stage.travel_m: the default soft limits


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# ---- Configs ------------------------------------------------------------------------------------

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
            # Every shipped file's own calibration (calibration.txt, calibration-modbus.txt, ...),
            # in the build tree or installed: this axis's own here.
            text = re.sub(r"(%s|/var/lib/idmd)/calibration[-\w]*\.txt" % re.escape(tmp),
                          os.path.join(tmp, "calibration-%s.txt" % name), text)
            if key == "sim":  # each simulated stage its own noise
                text = edit(text, [("seed: 1", "seed: %d" % (index + 1))], "sim:")
            out.append("    %s:" % key)
            out += ["    " + line for line in text.splitlines()]
    for key in ("server", "realtime", "logging", "recording"):
        out.append(key + ":")
        out += top[key]
    return "\n".join(out) + "\n"


# ---- Processes ----------------------------------------------------------------------------------

class ChildProcess:
    """A program whose first line on stdout says it is ready; its stderr goes to `log_path`.
    start() returns that line ("" when none came within `ready_s`); stop() sends SIGTERM, waits
    30 s (then kills) and returns the exit code."""

    def __init__(self, log_path, log_mode="w"):
        self.log_path = log_path
        self._log_mode = log_mode
        self._log = None
        self.proc = None

    def start(self, argv, ready_s, env=None):
        self._log = open(self.log_path, self._log_mode)
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     env=env)
        ready, _, _ = select.select([self.proc.stdout], [], [], ready_s)
        return self.proc.stdout.readline() if ready else ""

    def log(self):
        if self._log is not None and not self._log.closed:
            self._log.flush()
        with open(self.log_path) as f:
            return f.read()

    def alive(self):
        return self.proc.poll() is None

    def stop(self):
        if self.proc is None:
            return None
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


def require_built(path, what):
    if not os.path.exists(path):
        pytest.fail("%s is not built: %s (build the %s target)" % (what, path, what))


class Idmd(ChildProcess):
    """idmd on a config: by default a copy of config/idmd.yaml with paths under `tmp`,
    sched_fifo and lock_memory off, `edits` (old, new) applied to the text; or the config text
    `config` (e.g. axes_config). Listens on a free TCP port and a Unix socket.

    idmd prints its "listening" line only once every axis reads a valid position; that is
    checked here (position_valid=1 on every axis at once)."""

    def __init__(self, tmp, edits=(), config=None):
        require_built(IDMD, "idmd")
        super().__init__(os.path.join(tmp, "idmd.log"))
        self.tmp = tmp
        self.data_dir = os.path.join(tmp, "data")
        text = config if config is not None else single_axis_config(tmp, edits)
        self.config = os.path.join(tmp, "idmd.yaml")
        with open(self.config, "w") as f:
            f.write(text)
        self.unix = os.path.join(tmp, "idmd.sock")
        line = self.start([IDMD, "--config", self.config, "--port", "0", "--unix", self.unix], 60)
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

    def raw(self):
        return RawLine(self.port)


def ask(daemon, line):
    """One query on a fresh plain connection: (reply, SYST:ERR?'s reply)."""
    raw = daemon.raw()
    try:
        return raw.ask(line), raw.ask("SYST:ERR?")
    finally:
        raw.close()


def send(daemon, line):
    """One command on a fresh plain connection; asserts that it queued no error."""
    raw = daemon.raw()
    try:
        raw.f.write(line + "\n")
        raw.f.flush()
        err = raw.ask("SYST:ERR?")
        assert err == '0,"No error"', "%s: %s" % (line, err)
    finally:
        raw.close()


@contextlib.contextmanager
def idmd_in_temp_dir(prefix, idmd_class=Idmd, **kwargs):
    """An idmd (idmd_class(tmp, **kwargs); `config` may be a function of tmp) in a fresh
    temporary directory; on the way out it is stopped and the directory removed, and, when the
    body raised nothing, its exit code must be 0."""
    d = tempfile.mkdtemp(prefix=prefix)
    daemon = None
    try:
        if callable(kwargs.get("config")):
            kwargs["config"] = kwargs["config"](d)
        daemon = idmd_class(d, **kwargs)
        yield daemon
    finally:
        rc = daemon.stop() if daemon is not None else None
        shutil.rmtree(d, ignore_errors=True)
    assert rc == 0, "idmd exited %r" % rc


class SimDev(ChildProcess):
    """tools/idm-simdev: a simulated Modbus TCP device (config/idmd-modbus.yaml's stage and
    word format, the ideal plant) on a free port. stop() ends it (a device that vanishes: idmd
    loses it), start() brings it back on the same port (a new device: its count starts over)."""

    def __init__(self, tmp):
        require_built(SIMDEV, "idm-simdev")
        super().__init__(os.path.join(tmp, "simdev.log"), log_mode="a")
        self.port = free_port()
        self.config = os.path.join(tmp, "simdev.yaml")
        text = edit(read_config("idmd-modbus.yaml"),
                    [("port: 1502", "port: %d" % self.port),
                     ("step_correction: 0.35", "step_correction: 1.0")],
                    "config/idmd-modbus.yaml")
        with open(self.config, "w") as f:
            f.write(text)
        self.start()

    def start(self):
        line = super().start([SIMDEV, "--port", str(self.port), "--config", self.config], 30)
        if "listening" not in line:
            self.stop()
            pytest.fail("idm-simdev did not start: %r\n%s" % (line, self.log()))


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
