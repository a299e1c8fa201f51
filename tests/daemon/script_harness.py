"""The process and client plumbing of the script tests in this folder (idmd_integration.py,
axes_integration.py, motion_integration.py, fault_matrix.py, stateful_daemon.py): their command line and temporary
directory, configs edited from config/*.yaml, idmd and tools/idm-simdev as child processes, a
plain line client of idmd's sockets, raw Modbus reads, and the case table's dispatch. No library
of the product: the scripts talk to idmd through its sockets only.

A script calls setup() first; BUILD, SOURCE, CASE, TMP and the binaries' paths are then this
module's globals.
"""
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

BUILD = SOURCE = CASE = TMP = None  # set by setup()
IDMD = IDMCTL = SIMDEV = None


def setup(tmp_prefix):
    """Reads the command line (BUILD_DIR SOURCE_DIR CASE; CASE may be --list) and makes the run's
    temporary directory, its name starting with `tmp_prefix`."""
    global BUILD, SOURCE, CASE, TMP, IDMD, IDMCTL, SIMDEV
    if len(sys.argv) != 4:
        print("usage: %s BUILD_DIR SOURCE_DIR CASE" % os.path.basename(sys.argv[0]))
        sys.exit(2)
    BUILD, SOURCE, CASE = sys.argv[1:4]
    IDMD = os.path.join(BUILD, "daemon", "idmd")
    IDMCTL = os.path.join(BUILD, "tools", "idmctl")
    SIMDEV = os.path.join(BUILD, "tools", "idm-simdev")
    TMP = tempfile.mkdtemp(prefix=tmp_prefix)


def run(cases):
    """The script's main: `--list` prints the names of `cases`, else it runs CASE (PASS at the
    end; a failed check has exited 1)."""
    if CASE == "--list":
        print(" ".join(cases))
        sys.exit(0)
    cases[CASE]()
    print("PASS", CASE)


def fail(msg):
    print("FAIL:", msg)
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)
    print("ok:", msg)


# ---- Files and configs --------------------------------------------------------------------------

def temp_file(name, text):
    """Writes `text` to TMP/`name`; returns its path."""
    path = os.path.join(TMP, name)
    with open(path, "w") as f:
        f.write(text)
    return path


def config(name="idmd.yaml", edits=(), out=None):
    """config/`name` with its paths under TMP (for /var/lib/idmd), no real-time privileges asked
    for (sched_fifo, lock_memory off) and `edits` (old, new) applied, each of which must be in the
    file; written to TMP/`out` (default: `name`). Returns its path."""
    with open(os.path.join(SOURCE, "config", name)) as f:
        text = f.read()
    text = text.replace("/var/lib/idmd", TMP)
    text = text.replace("sched_fifo: true", "sched_fifo: false")
    text = text.replace("lock_memory: true", "lock_memory: false")
    for old, new in edits:
        if old not in text:
            fail("config edit: %r not in %s" % (old, name))
        text = text.replace(old, new)
    return temp_file(out or name, text)


def modbus_config(port, edits=(), out=None):
    """config/idmd-modbus.yaml (as config() makes it) for the device at 127.0.0.1:`port`."""
    return config("idmd-modbus.yaml", [("port: 1502", "port: %d" % port)] + list(edits), out)


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# ---- Processes ----------------------------------------------------------------------------------

class Daemon:
    """idmd on `cfg`, on a free TCP port (read from its first line on stdout) and TMP/idmd.sock,
    its stderr in TMP/idmd.err, `env` added to its environment. As a context manager it is
    stopped (SIGTERM) on the way out."""

    def __init__(self, cfg, env=None):
        self.sock = os.path.join(TMP, "idmd.sock")
        self.err = open(os.path.join(TMP, "idmd.err"), "w+")
        self.proc = subprocess.Popen([IDMD, "--config", cfg, "--port", "0", "--unix", self.sock],
                                     stdout=subprocess.PIPE, stderr=self.err, text=True,
                                     env=dict(os.environ, **(env or {})))
        line = self.proc.stdout.readline()
        m = re.search(r"tcp \S+?:(\d+)", line)
        if not m:
            self.proc.wait(10)
            fail("idmd did not start: %r\n%s" % (line, self.log()))
        self.port = int(m.group(1))

    def log(self):
        self.err.flush()
        self.err.seek(0)
        return self.err.read()

    def stop(self, timeout=30):
        """SIGTERM (when it still runs) and its exit code, within `timeout` s or killed."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                return self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
                fail("idmd did not exit within %g s of SIGTERM\n%s" % (timeout, self.log()))
        return self.proc.returncode

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


class SimDev:
    """tools/idm-simdev, the simulated Modbus device, on 127.0.0.1:`port` with the config `cfg`
    (the daemon's, so that they agree on the word format), `channels` units. `ready` is its first
    line on stdout ("listening on ..."). As a context manager it is killed on the way out."""

    def __init__(self, port, cfg, channels=None):
        self.argv = [SIMDEV, "--port", str(port), "--config", cfg]
        if channels is not None:
            self.argv += ["--channels", str(channels)]
        self.start()

    def start(self):
        """Starts it (again: a restarted device) and waits for its first line."""
        self.proc = subprocess.Popen(self.argv, stdout=subprocess.PIPE, text=True)
        self.ready = self.proc.stdout.readline()

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()  # SIGKILL: a stopped (SIGSTOP) one too
        self.proc.wait(10)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.kill()


def idmctl(*args):
    """tools/idmctl with `args` (60 s at most); its CompletedProcess, the output as text."""
    return subprocess.run([IDMCTL] + [str(a) for a in args], capture_output=True, text=True,
                          timeout=60)


# ---- Clients ------------------------------------------------------------------------------------

def key_values(reply):
    """A reply of key=value words (STAT?, SYST:CLI:TABL?) as a dict."""
    return dict(kv.split("=", 1) for kv in reply.split())


def wait_done(query, timeout=30):
    """MOVE:DONE? asked through `query` (a function of the query line) until it answers 1:
    whether it did within `timeout` s."""
    end = time.time() + timeout
    while time.time() < end:
        if query("MOVE:DONE?").strip() == "1":
            return True
        time.sleep(0.01)
    return False


class Client:
    """A plain line client of the daemon `d` over TCP or its Unix socket. send() sends the text as
    it is (with its newlines, or without: half a line); ask() sends one line and reads the reply
    line."""

    def __init__(self, d, unix=False, timeout=30):
        if unix:
            self.s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.s.connect(d.sock)
        else:
            self.s = socket.create_connection(("127.0.0.1", d.port))
        self.s.settimeout(timeout)
        self.buf = b""

    def send(self, text):
        self.s.sendall(text.encode())

    def line(self):
        """The next line from the daemon; None once it closed the connection."""
        while b"\n" not in self.buf:
            chunk = self.s.recv(65536)
            if not chunk:
                return None
            self.buf += chunk
        out, self.buf = self.buf.split(b"\n", 1)
        return out.decode()

    def ask(self, query):
        self.send(query + "\n")
        reply = self.line()
        if reply is None:
            fail("the daemon closed the connection (after %s)" % query)
        return reply

    def error(self):
        return self.ask("SYST:ERR?")

    def no_error(self):
        err = self.error()
        check(err == '0,"No error"', "no error queued (%s)" % err)

    def status(self, axis=""):
        return key_values(self.ask(axis + "STAT?"))

    def wait_done(self, timeout=30):
        return wait_done(self.ask, timeout)

    def positions(self, query="POS:ALL?"):
        return [float(x) for x in self.ask(query).split(",")]

    def mean_positions(self, n=32, spacing_s=0.003, query="POS:ALL?"):
        """Where the axes are at rest: the mean of n readings spread over n * spacing_s. Each is
        quantized to one count with the sensor's noise, and a slider resting near the edge between
        two counts reads as either; readings taken back to back repeat the same few words, so a
        short burst of them can read the far count only."""
        rows = []
        for _ in range(n):
            rows.append(self.positions(query))
            time.sleep(spacing_s)
        return [sum(r[k] for r in rows) / n for k in range(len(rows[0]))]

    def mean_position(self, n=32):
        """The same for the one axis of POS?."""
        return self.mean_positions(n, query="POS?")[0]

    def close(self):
        self.s.close()


def wait_state(c, want, timeout=10, axis=""):
    """Asks STAT? until every key of `want` has its value; that status (else a FAIL)."""
    end = time.time() + timeout
    st = {}
    while time.time() < end:
        st = c.status(axis)
        if all(st.get(k) == v for k, v in want.items()):
            return st
        time.sleep(0.01)
    fail("state %s not reached in %g s: %s" % (want, timeout, st))


def bursts_stay(c, seconds=0.2):
    """The output is at rest: no chunk starts for a while."""
    before = c.status()["bursts"]
    time.sleep(seconds)
    return c.status()["bursts"] == before


def modbus_registers(port, address, count, unit=1):
    """Reads holding registers with a raw Modbus TCP request (function 3): no library of ours."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(bytes([0, 1, 0, 0, 0, 6, unit, 3, address >> 8, address & 0xFF, 0, count]))
        reply = b""
        while len(reply) < 9 + 2 * count:
            chunk = s.recv(256)
            if not chunk:
                fail("the Modbus server closed the connection")
            reply += chunk
    if reply[7] != 3:
        fail("Modbus exception reply %r" % reply)
    return [reply[9 + 2 * k] << 8 | reply[10 + 2 * k] for k in range(count)]
