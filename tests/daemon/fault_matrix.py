#!/usr/bin/python3
"""The fault and bad-input matrix: the real idmd on the simulated stage, driven through its
sockets by plain clients (no library of ours), one case per way a client, a file or a device can
misbehave. Each case asserts what the daemon reports, that nothing moved that should not have,
the error queued, and the recovery.

usage: fault_matrix.py BUILD_DIR SOURCE_DIR CASE
"""
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

BUILD, SOURCE, CASE = sys.argv[1], sys.argv[2], sys.argv[3]
IDMD = os.path.join(BUILD, "daemon", "idmd")
TMP = tempfile.mkdtemp(prefix="idmd-fm-")


def fail(msg):
    print("FAIL:", msg)
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)
    print("ok:", msg)


def config(replace=(), name="idmd.yaml"):
    """config/idmd.yaml with paths under TMP, no real-time privileges, and the given edits."""
    text = open(os.path.join(SOURCE, "config", "idmd.yaml")).read()
    text = text.replace("/var/lib/idmd/calibration.txt", os.path.join(TMP, "calibration.txt"))
    text = text.replace("/var/lib/idmd/data", os.path.join(TMP, "data"))
    text = text.replace("sched_fifo: true", "sched_fifo: false")
    text = text.replace("lock_memory: true", "lock_memory: false")
    for old, new in replace:
        if old not in text:
            fail("config edit: %r not in the config" % old)
        text = text.replace(old, new)
    path = os.path.join(TMP, name)
    open(path, "w").write(text)
    return path


class Daemon:
    def __init__(self, cfg, env=None):
        self.sock = os.path.join(TMP, "idmd.sock")
        self.err = open(os.path.join(TMP, "idmd.err"), "w+")
        self.proc = subprocess.Popen([IDMD, "--config", cfg, "--port", "0", "--unix", self.sock],
                                     stdout=subprocess.PIPE, stderr=self.err, text=True,
                                     env=dict(os.environ, **(env or {})))
        line = self.proc.stdout.readline()
        m = re.search(r"127\.0\.0\.1:(\d+)", line)
        if not m:
            self.proc.wait(10)
            fail("idmd did not start: %r\n%s" % (line, self.log()))
        self.port = int(m.group(1))

    def log(self):
        self.err.flush()
        self.err.seek(0)
        return self.err.read()

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            return self.proc.wait(30)
        return self.proc.returncode

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


class Client:
    """A plain line client over TCP or the Unix socket."""

    def __init__(self, d, unix=False):
        if unix:
            self.s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.s.connect(d.sock)
        else:
            self.s = socket.create_connection(("127.0.0.1", d.port))
        self.s.settimeout(20)
        self.buf = b""

    def send(self, text):
        self.s.sendall(text.encode())

    def line(self):
        while b"\n" not in self.buf:
            chunk = self.s.recv(65536)
            if not chunk:
                return None
            self.buf += chunk
        out, self.buf = self.buf.split(b"\n", 1)
        return out.decode()

    def ask(self, query):
        self.send(query + "\n")
        return self.line()

    def error(self):
        return self.ask("SYST:ERR?")

    def status(self):
        return dict(kv.split("=", 1) for kv in self.ask("STAT?").split())

    def wait_done(self, timeout=30):
        end = time.time() + timeout
        while time.time() < end:
            if self.ask("MOVE:DONE?") == "1":
                return True
            time.sleep(0.01)
        return False

    def close(self):
        self.s.close()


def expect_refused(c, line, code, words):
    """A command line refused with `code`, its text holding every word; nothing moved."""
    before = c.status()
    c.send(line + "\n")
    err = c.error()
    check(err.startswith("%d," % code) and all(w in err for w in words),
          "%s -> %s" % (line, err))
    after = c.status()
    check(after["bursts"] == before["bursts"] and after["cycles"] == before["cycles"],
          "%s played nothing" % line)


def case_bad_input():
    """Typos and hostile lines: every one refused with its code, naming the argument and the
    range, and nothing played."""
    with Daemon(config()) as d:
        c = Client(d)
        check(c.ask("POS?") not in ("", None), "a position at once")
        # Units typed wrong: 1 km, -1 km.
        expect_refused(c, "MOVE:REL 1e3", -222, ["target 1000", "soft limits"])
        expect_refused(c, "MOVE:ABS -1e3", -222, ["target -1000", "soft limits"])
        expect_refused(c, "LIM:UPP 1e3", -222, ["upper limit 1000", "travel"])
        expect_refused(c, "LIM 1e-6,1e-6", -222, ["must be below the upper limit"])
        # Every STEP argument used or refused.
        expect_refused(c, "STEP 10,1.5,200", -222, ["STEP duty: 1.5"])
        expect_refused(c, "STEP 10,0.1,-200", -222, ["STEP freq_hz: -200"])
        expect_refused(c, "STEP 10,-0.1,200,2e-5", -222, ["STEP duty: -0.1"])
        expect_refused(c, "STEP 10,0.1,200,-1e-6", -222, ["STEP stroke_m"])
        expect_refused(c, "STEP 10,0.1,200,0", -222, ["STEP stroke_m: 0"])
        expect_refused(c, "STEP 1000000000", -222, ["soft limits"])
        expect_refused(c, "STEP 0", -222, ["STEP cycles"])
        # Quoted numbers are strings, not numbers.
        expect_refused(c, 'MOVE:REL "1e-6"', -104, ["quoted"])
        expect_refused(c, 'STEP "10"', -104, ["quoted"])
        expect_refused(c, 'LIM:LOW "-1e-3"', -104, ["quoted"])
        check(c.ask("SYST:ERR?") == '0,"No error"', "nothing else queued")
        # STEP n,duty,freq plays that duty and frequency: the way REG? says.
        reg = c.ask("REG? 200,0.1")
        step = float(reg.split(",")[1])
        p0 = float(c.ask("POS?"))
        c.send("STEP 10,0.1,200\n")
        check(c.wait_done(), "STEP 10,0.1,200 finishes")
        moved = float(c.ask("POS?")) - p0
        check(moved * step > 0 and abs(moved - 10 * step) < 0.3 * abs(10 * step),
              "STEP 10,0.1,200 moved %.4g m, REG? predicts %.4g m" % (moved, 10 * step))
        check(c.ask("SYST:ERR?") == '0,"No error"', "no error after the step")


def case_unterminated_line():
    """A last line without its newline never runs, over TCP or the Unix socket."""
    with Daemon(config()) as d:
        watcher = Client(d)
        start = watcher.status()
        for unix in (False, True):
            c = Client(d, unix=unix)
            c.send("MOVE:REL 1e-3")  # no newline
            c.s.shutdown(socket.SHUT_WR)
            check(c.line() is None, "closed without a reply (%s)" % ("unix" if unix else "tcp"))
            c.close()
        time.sleep(0.3)
        now = watcher.status()
        check(now["moves"] == start["moves"] and now["bursts"] == start["bursts"],
              "nothing moved: moves %s, bursts %s" % (now["moves"], now["bursts"]))


def case_reset_keeps_limits():
    """*RST by one client keeps the limits another set, and the target."""
    with Daemon(config()) as d:
        a, b = Client(d), Client(d, unix=True)
        a.send("LIM -1e-3,2e-3\n")
        a.send("MOVE:REL 2e-6\n")
        check(a.wait_done(), "the move finishes")
        target = a.status()["target"]
        b.send("*RST\n")
        check(b.ask("*OPC?") == "1", "*RST completes")
        check(a.ask("LIM?") == "-0.001,0.002", "the limits survive *RST: " + a.ask("LIM?"))
        check(a.status()["target"] == target, "the target survives *RST")
        check(a.ask("SYST:ERR?") == '0,"No error"', "no error")


def case_sweep_confined():
    """SWEEP writes only below recording.data_dir, into a new directory."""
    data = os.path.join(TMP, "data")
    outside = os.path.join(TMP, "outside")
    os.makedirs(data, exist_ok=True)
    os.makedirs(outside, exist_ok=True)
    open(os.path.join(outside, "keep.txt"), "w").write("keep\n")
    os.symlink(outside, os.path.join(data, "link"))
    with Daemon(config()) as d:
        c = Client(d)
        for target in ("../outside/x", outside + "/x", "link/x", "link"):
            c.send("SWEEP %s,500,0.1,1,2\n" % target)
            err = c.error()
            check(err.startswith("-222,"), "SWEEP %s refused: %s" % (target, err))
        c.send("SWEEP run1,500,0.1,1,2\n")
        check(c.wait_done(), "a sweep into a new name runs")
        check(os.path.exists(os.path.join(data, "run1", "sweep.csv")), "written inside data_dir")
        c.send("SWEEP run1,500,0.1,1,2\n")
        check(c.error().startswith("-222,"), "the same name again is refused")
        check(sorted(os.listdir(outside)) == ["keep.txt"], "nothing written outside")


def case_client_table_full():
    """Clients that sent *OPC? and vanished free their slots; with the table full a STOP still
    gets through."""
    cfg = config([("  max_clients: 16", "  max_clients: 2")])
    with Daemon(cfg) as d:
        mover = Client(d)
        mover.send("MOVE:REL 4e-3\n")
        time.sleep(0.1)
        check(mover.ask("MOVE:DONE?") == "0", "a long move is on")
        ghosts = [Client(d, unix=True) for _ in range(2)]
        for g in ghosts:
            g.send("*OPC?\n")
            g.close()
        time.sleep(0.2)
        other = Client(d, unix=True)
        check(other.ask("*IDN?").startswith("idm,idmd"), "the ghosts' slots are free")
        hog = Client(d)  # the table is full now (mover, other)
        hog.send("MOVE:ABS 0\n")
        check(hog.error().startswith("-221,"), "a client past the table is stop-only")
        hog.send("STOP\n")
        check(mover.wait_done(5), "its STOP got through")
        check(mover.status()["state"] in ("IDLE",), "at rest after STOP")


CASES = {
    "bad_input": case_bad_input,
    "unterminated_line": case_unterminated_line,
    "reset_keeps_limits": case_reset_keeps_limits,
    "sweep_confined": case_sweep_confined,
    "client_table_full": case_client_table_full,
}

if __name__ == "__main__":
    if CASE == "--list":
        print(" ".join(CASES))
        sys.exit(0)
    CASES[CASE]()
    print("PASS", CASE)
