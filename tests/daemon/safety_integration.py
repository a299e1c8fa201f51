#!/usr/bin/python3
"""Nothing but a deliberate motion command from an authorised client moves the stage: the real
idmd on the simulated stage, attacked the way a web page, another local user, a careless config or
a hostile file would, through its sockets and its command line. Each case says what it stands for.

usage: safety_integration.py BUILD_DIR SOURCE_DIR CASE
"""
import http.client
import os
import pwd
import re
import shutil
import signal
import subprocess
import tempfile
import time

import script_harness as harness
from script_harness import Client, Daemon, check, config, fail, free_port, temp_file

harness.setup("idmd-safety-")


def check_config(path, timeout=60):
    """idmd --check-config PATH: (exit code, stdout, stderr, seconds)."""
    t0 = time.time()
    r = subprocess.run([harness.IDMD, "--check-config", path], capture_output=True, text=True,
                       timeout=timeout)
    return r.returncode, r.stdout, r.stderr, time.time() - t0


def case_http_post():
    """A web page's cross-origin fetch (POST, mode no-cors) to the command port: the request line
    and headers close the connection before any line runs; the body's MOVE never moves; one log
    line however many requests."""
    with Daemon(config()) as d:
        c = Client(d)
        p0 = c.mean_position()
        bursts0 = c.status()["bursts"]
        for _ in range(5):
            conn = http.client.HTTPConnection("127.0.0.1", d.port, timeout=10)
            body = "MOVE:REL 2e-4\nSTEP 1000\n"
            conn.putrequest("POST", "/")
            conn.putheader("Origin", "http://evil.example")
            conn.putheader("Content-Type", "text/plain;charset=UTF-8")
            conn.putheader("Content-Length", str(len(body)))
            conn.endheaders(body.encode())
            try:
                resp = conn.getresponse()
                got = resp.read()
                fail("idmd answered HTTP: %r" % got[:80])
            except (http.client.RemoteDisconnected, ConnectionResetError, http.client.BadStatusLine):
                pass
            conn.close()
        time.sleep(0.5)
        check(c.status()["bursts"] == bursts0, "no burst played")
        check(abs(c.mean_position() - p0) < 20e-9, "the stage did not move")
        log = d.log()
        lines = [l for l in log.splitlines() if "HTTP" in l]
        check(len(lines) == 1, "one log line for five requests: %r" % lines)
        check(c.ask("*IDN?").startswith("idm,"), "the port still serves its own clients")


def token_file(mode=0o600, text="0123456789abcdefABCDEF-token\n", name="token"):
    path = temp_file(name, text)
    os.chmod(path, mode)
    return path


def case_token():
    """server.auth_token_file: over TCP nothing that moves or changes a setting runs before
    *AUTH <token>; queries and STOP do; the Unix socket (its file mode is its permission) needs
    none; a wrong token closes the connection."""
    cfg = config(edits=[("  max_clients: 16", "  max_clients: 16\n  auth_token_file: %s" %
                         token_file())])
    with Daemon(cfg) as d:
        c = Client(d)
        before = c.status()
        c.send("MOVE:REL 1e-5\n")
        err = c.error()
        check(err.startswith("-203,") and "*AUTH" in err, "MOVE before *AUTH: %s" % err)
        for line in ("LIM -1e-5,1e-5", "STEP 10", "*RST", "HOLD 1", "SIM:PUSH 1e-5"):
            c.send(line + "\n")
            check(c.error().startswith("-203,"), "%s before *AUTH is -203" % line)
        check(c.status()["bursts"] == before["bursts"], "nothing played")
        c.send("STOP\n")
        c.no_error()
        check(c.ask("*AUTH?") == "0", "*AUTH? 0 before")
        c.send("*AUTH 0123456789abcdefABCDEF-token\nMOVE:REL 1e-6\n")
        check(c.wait_done(), "the move after *AUTH finishes")
        c.no_error()
        check(c.ask("MOVE:RES?").startswith("OK"), "and arrives")
        u = Client(d, unix=True)
        u.send("MOVE:REL -1e-6\n")
        check(u.wait_done(), "the Unix socket moves without a token")
        u.no_error()
        w = Client(d)
        w.send("*AUTH 0123456789abcdefABCDEF-tokeX\nMOVE:REL 1e-6\n")
        check(w.line() is None, "a wrong token closes the connection")
        check("wrong *AUTH token" in d.log(), "and is logged")


def case_token_file_checked():
    """A token file others can read, a symlink, a short token: exit 2 naming the key and why, at
    --check-config and at start (nothing opened)."""
    good = token_file()
    for path, words in ((token_file(0o644, name="token-0644"), "other users"),
                        (token_file(0o600, "short\n", name="token-short"), "characters"),
                        (token_file(0o600, "a token with blanks in it\n", name="token-blanks"),
                         "letters, digits")):
        cfg = config(edits=[("  max_clients: 16", "  max_clients: 16\n  auth_token_file: %s" % path)],
                     out="bad-token.yaml")
        code, out, err, _ = check_config(cfg)
        check(code == 2 and "server.auth_token_file" in err and words in err,
              "--check-config: %s" % err.strip())
        r = subprocess.run([harness.IDMD, "--config", cfg, "--port", "0", "--unix", ""],
                           capture_output=True, text=True, timeout=60)
        check(r.returncode == 2 and words in r.stderr, "idmd exits 2: %s" % r.stderr.strip())
    link = os.path.join(harness.TMP, "token-link")
    os.symlink(good, link)
    cfg = config(edits=[("  max_clients: 16", "  max_clients: 16\n  auth_token_file: %s" % link)],
                 out="link-token.yaml")
    code, _, err, _ = check_config(cfg)
    check(code == 2 and "symbolic link" in err, "a symlinked token file: %s" % err.strip())


def case_remote_address():
    """tcp_address 0.0.0.0 is refused unless allow_remote: true, which then warns at
    --check-config and in the start log."""
    cfg = config(edits=[("tcp_address: 127.0.0.1", "tcp_address: 0.0.0.0")], out="any.yaml")
    code, _, err, _ = check_config(cfg)
    check(code == 2 and "server.tcp_address" in err and "allow_remote" in err,
          "0.0.0.0 refused: %s" % err.strip())
    cfg = config(edits=[("tcp_address: 127.0.0.1", "tcp_address: 0.0.0.0\n  allow_remote: true")],
                 out="remote.yaml")
    code, out, err, _ = check_config(cfg)
    check(code == 0 and "warning" in err and "auth_token_file" in err,
          "allow_remote passes with a warning: %s" % err.strip())
    with Daemon(cfg) as d:
        time.sleep(0.2)
        check(re.search(r"warn.*can move the stage", d.log()) is not None,
              "the start log warns: %s" % d.log()[:400])


def case_second_instance():
    """A second idmd on the sockets of a running one exits 4 before it opens a device: with its
    device absent (a Modbus port nobody serves) it would exit 3 if it opened the device first."""
    with Daemon(config()) as d:
        cfg = config("idmd-modbus.yaml", [("port: 1502", "port: %d" % free_port())],
                     out="second.yaml")
        r = subprocess.run([harness.IDMD, "--config", cfg, "--port", str(d.port), "--unix",
                            d.sock], capture_output=True, text=True, timeout=60)
        check(r.returncode == 4, "the second idmd exits 4 (cannot listen), not 3: %d %s" %
              (r.returncode, r.stderr[-300:]))
        c = Client(d)
        check(c.ask("*IDN?").startswith("idm,"), "the first one still serves")


def case_alias_bomb():
    """A 600-byte YAML alias bomb: refused at once, naming the file, never expanded."""
    levels = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for k in range(1, 10):
        prev = "*a%d" % (k - 1)
        levels.append("a%d: &a%d [%s]" % (k, k, ", ".join([prev] * 9)))
    bomb = temp_file("bomb.yaml", "\n".join(levels) + "\n")
    code, _, err, seconds = check_config(bomb, timeout=120)
    check(code == 2 and "bomb.yaml" in err and "alias" in err,
          "refused naming the file in %.2f s: %s" % (seconds, err.strip()))


def syscall_names(trace_dir):
    names = set()
    for f in os.listdir(trace_dir):
        with open(os.path.join(trace_dir, f)) as t:
            for line in t:
                m = re.match(r"^\s*(?:\d+\s+)?([a-z_0-9]+)\(", line)
                if m:
                    names.add(m.group(1))
    return names


def filter_set(group, seen=None):
    """The system calls of a systemd syscall group, its sub-groups expanded."""
    seen = seen if seen is not None else set()
    out = set()
    text = subprocess.run(["systemd-analyze", "syscall-filter", group], capture_output=True,
                          text=True, check=True).stdout
    for line in text.splitlines()[1:]:
        word = line.strip()
        if not word or word.startswith("#"):
            continue
        if word.startswith("@"):
            if word not in seen:
                seen.add(word)
                out |= filter_set(word, seen)
        else:
            out.add(word)
    return out


def case_syscalls():
    """Every system call idmd makes (start, moves, a sweep, SIGHUP, *RST, SIGTERM) is in the
    installed unit's SystemCallFilter=@system-service, so the filter never refuses one."""
    unit = open(os.path.join(harness.BUILD, "systemd", "idmd.service")).read()
    m = re.search(r"^SystemCallFilter=(.+)$", unit, re.M)
    check(m is not None, "the unit has a SystemCallFilter")
    allowed = set()
    for g in m.group(1).split():
        allowed |= filter_set(g) if g.startswith("@") else {g}
    trace = os.path.join(harness.TMP, "trace")
    os.mkdir(trace)
    cfg = config()
    sock = os.path.join(harness.TMP, "idmd.sock")
    proc = subprocess.Popen(["strace", "-f", "-qq", "-ff", "-o", os.path.join(trace, "t"),
                             harness.IDMD, "--config", cfg, "--port", "0", "--unix", sock],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = proc.stdout.readline()
    port = int(re.search(r"127\.0\.0\.1:(\d+)", line).group(1))
    pid = int(subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True,
                             check=True).stdout.split()[0])  # idmd, strace's child

    class D:
        pass
    d = D()
    d.port, d.sock = port, sock
    c = Client(d)
    c.send("MOVE:REL 2e-6\n")
    check(c.wait_done(60), "a move under strace")
    c.send("SWEEP trace-sweep,200,0.1;0.2,1,4\n")
    end = time.time() + 120
    while time.time() < end and not c.ask("SWEEP?").startswith(("DONE", "FAILED", "STOPPED")):
        time.sleep(0.1)
    os.kill(pid, signal.SIGHUP)
    time.sleep(0.5)
    c.send("*RST\n")
    time.sleep(0.5)
    c.close()
    os.kill(pid, signal.SIGTERM)
    proc.wait(60)
    used = syscall_names(trace)
    check(len(used) > 20, "traced %d distinct system calls" % len(used))
    outside = sorted(used - allowed)
    check(not outside, "every one is in the filter (outside: %s)" % outside)


def rest_position(c):
    return c.mean_position()


def sweep_until_done(c, timeout=180):
    """SWEEP? until it is no longer RUNNING; its reply split."""
    end = time.time() + timeout
    while time.time() < end:
        r = c.ask("SWEEP?")
        if not r.startswith("RUNNING"):
            return r.split(",")
        time.sleep(0.05)
    fail("the sweep did not end within %g s" % timeout)


def plan_status(path):
    text = open(os.path.join(path, "plan.yaml")).read()
    return re.search(r"^status: (\w+)", text, re.M).group(1), text


def case_in_position_after_push():
    """A move arrives (in position); a 100 um push takes the slider away: in position is cleared
    at once and MOVE:REL 1e-6 goes from the reading, not back to the old target (it moved the
    stage back by all of the push, result OK)."""
    with Daemon(config()) as d:
        c = Client(d)
        c.send("MOVE:REL 20e-6\n")
        check(c.wait_done(), "the move ends")
        check(int(c.ask("STAT:OPER?")) & 2, "in position after it")
        target = float(c.ask("MOVE?"))
        c.send("SIM:PUSH 1e-4\n")
        time.sleep(0.2)
        pushed = rest_position(c)
        check(abs(pushed - target - 1e-4) < 1e-6, "pushed to %.9g" % pushed)
        check(not int(c.ask("STAT:OPER?")) & 2, "no longer in position")
        check(c.status()["in_position"] == "0", "STAT? in_position=0")
        c.send("MOVE:REL 1e-6\n")
        check(c.wait_done(), "the relative move ends")
        after = rest_position(c)
        check(abs(after - (pushed + 1e-6)) < 50e-9,
              "MOVE:REL counted from the reading: %.9g, expected %.9g" % (after, pushed + 1e-6))
        c.no_error()


def case_sweep_limits():
    """SWEEP within soft limits of +-10 um: trials whose worst-case excursion could leave them are
    refused before they play; the sweep ends FAILED, its dataset says failed and why, the client
    that started it gets an error, and no reading left the limits (a sweep drove 575 um past them)."""
    with Daemon(config()) as d:
        c = Client(d)
        c.send("LIM -10e-6,10e-6\n")
        c.no_error()
        lo = hi = rest_position(c)
        c.send("SWEEP lim,100:800:100,0.05;0.1;0.9;0.95,5,40\n")
        end = time.time() + 120
        while time.time() < end and c.ask("SWEEP?").startswith("RUNNING"):
            p = float(c.ask("POS?"))
            lo, hi = min(lo, p), max(hi, p)
        state = sweep_until_done(c)
        check(state[0] == "FAILED", "the sweep failed: %s" % state)
        err = c.error()
        check(err.startswith("-200,") and "soft limits" in err, "the error says why: %s" % err)
        check(lo > -10e-6 - 3e-6 and hi < 10e-6 + 3e-6,
              "no reading far past the limits: [%.3g, %.3g]" % (lo, hi))
        status, text = plan_status(os.path.join(harness.TMP, "data", "lim"))
        check(status == "failed" and "soft limits" in text, "plan.yaml: failed, and why")


def case_sweep_near_the_end():
    """A sweep started 20 um from the end of the travel driving toward it: the trials that could
    reach it are refused (the travel bounds the soft limits); none hammers the end stop."""
    cfg = config(edits=[("travel_m: [-5e-3, 5e-3]", "travel_m: [-5e-3, 0.5e-3]")], out="end.yaml")
    with Daemon(cfg) as d:
        c = Client(d)
        c.send("MOVE:ABS 0.48e-3\n")
        check(c.wait_done(60), "near the end")
        c.no_error()
        hi = rest_position(c)
        reg = c.ask("REG? 300,0.9")
        check(float(reg.split(",")[1]) > 0, "duty 0.9 drives toward the end: %s" % reg)
        c.send("SWEEP end,200:400:100,0.9;0.95,10,40\n")
        end = time.time() + 120
        while time.time() < end and c.ask("SWEEP?").startswith("RUNNING"):
            hi = max(hi, float(c.ask("POS?")))
        state = sweep_until_done(c)
        check(state[0] == "FAILED", "the sweep failed: %s" % state)
        check(hi < 0.5e-3, "never at the end stop: highest %.6g" % hi)
        check(c.error().startswith("-200,"), "an error for the client")


def case_sweep_end_stop_unknown():
    """The end stop nearer than stage.travel_m says (a config that is wrong): a cell whose first
    trial moved clearly moves almost nothing on a later trial: the sweep stops there, FAILED,
    saying the end of travel, and that trial is not written (14 of 20 trials hammered the stop,
    each recorded as valid, SWEEP? DONE); the log has one warning for that trial."""
    cfg = config(edits=[("  noise_m: 1e-9", "  noise_m: 1e-9\n  end_stops_m: [-5e-3, 0.3e-3]")],
                 out="stop.yaml")
    with Daemon(cfg) as d:
        c = Client(d)
        c.send("MOVE:ABS 0.2e-3\n")
        check(c.wait_done(60), "100 um before the stop")
        c.no_error()
        c.send("SWEEP stop,300,0.9,10,12\n")
        state = sweep_until_done(c)
        check(state[0] == "FAILED", "the sweep failed: %s" % state)
        written = int(state[2])
        check(2 <= written < 10, "it stopped after the trials that moved: %s" % state)
        err = c.error()
        check(err.startswith("-200,") and "end of travel" in err, "the client is told: %s" % err)
        status, text = plan_status(os.path.join(harness.TMP, "data", "stop"))
        check(status == "failed" and "end of travel" in text, "plan.yaml says so")
        rows = open(os.path.join(harness.TMP, "data", "stop", "sweep.csv")).read().splitlines()
        check(len(rows) == written + 1, "only the trials that moved are in sweep.csv")
        time.sleep(0.5)
        lines = [l for l in d.log().splitlines() if "axis x: sweep" in l]
        check(len(lines) == 1 and "data/stop trial %d (300" % written in lines[0] and
              "ended FAILED: the end of travel" in lines[0] and "warn" in lines[0],
              "one log line for the trial: %r" % lines)


def case_sweep_full_disk():
    """recording.data_dir on an 8 MiB file system: a sweep too large for it is refused before it
    starts (-250, naming the room it needs); one that fills it as it runs stops at the first
    failed write, FAILED, with an error for its client (the daemon played every trial into a full
    disk and marked the dataset complete)."""
    if os.geteuid() != 0:
        fail("needs root to mount a small tmpfs for recording.data_dir")
    data = os.path.join(harness.TMP, "small")
    os.makedirs(data)
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", data], check=True)
    try:
        cfg = config(edits=[("data_dir: %s/data" % harness.TMP, "data_dir: %s" % data)],
                     out="small.yaml")
        with Daemon(cfg) as d:
            c = Client(d)
            c.send("SWEEP big,100:800:100,0.05:0.45:0.05,20,12\n")
            err = c.error()
            check(err.startswith("-250,") and "MB" in err, "too large: refused: %s" % err)
            check(not os.path.exists(os.path.join(data, "big")), "and nothing created")
            c.send("SWEEP fills,800,0.1;0.9,20,12\n")
            c.no_error()
            time.sleep(0.5)
            filler = os.path.join(data, "filler")
            with open(filler, "wb") as f:  # the disk fills while it runs
                try:
                    while True:
                        f.write(b"\0" * 65536)
                except OSError:
                    pass
            state = sweep_until_done(c)
            check(state[0] == "FAILED", "the sweep failed: %s" % state)
            written, failed, planned = int(state[2]), int(state[3]), int(state[4])
            check(failed == 1 and written < planned, "stopped at the first failed write: %s" % state)
            err = c.error()
            check(err.startswith("-200,") and "write" in err, "its client is told: %s" % err)
            os.unlink(filler)
    finally:
        subprocess.run(["umount", data])


def slow_config(out="slow.yaml"):
    """config/idmd.yaml with the frequencies capped at 200 Hz: a 2 mm move takes seconds. The
    window is 40 nm: these tests are about what stops a move, not how it lands on one count (at
    200 Hz the finest rungs are few and a one-count landing now and then ends retry_limit: the
    positioning benchmark's business)."""
    return config(edits=[("max_freq_hz: 2000", "max_freq_hz: 200"),
                         ("tolerance_m: 0 ", "tolerance_m: 4e-8 ")], out=out)


def case_sighup_waits_for_a_move():
    """SIGHUP while another client's move runs: the move is not cut short (it ends OK at its
    target); new motions are refused meanwhile (-221 naming the reload); once it ends the
    settings are reloaded (the log says so) and motion is accepted again."""
    with Daemon(slow_config()) as d:
        a, b = Client(d), Client(d)
        start = rest_position(a)
        a.send("MOVE:REL 2e-3\n")
        time.sleep(0.3)
        check(a.ask("MOVE:DONE?") == "0", "the move runs")
        d.proc.send_signal(signal.SIGHUP)
        time.sleep(0.3)
        b.send("AXIS1:MOVE:REL 1e-6\n")
        err = b.error()
        check(err.startswith("-221,") and "reload" in err, "a new move waits for the reload: %s" % err)
        check(a.wait_done(120), "the first move ends")
        check(a.ask("MOVE:RES?").startswith("OK"), "OK: %s" % a.ask("MOVE:RES?"))
        check(abs(rest_position(a) - start - 2e-3) < 50e-9, "at its target")
        a.no_error()
        end = time.time() + 10
        while time.time() < end and "control settings reloaded" not in d.log():
            time.sleep(0.1)
        check("SIGHUP: control settings reloaded" in d.log(), "the reload happened after it")
        b.send("MOVE:REL 1e-6\n")
        check(b.wait_done(30), "motion accepted again")
        b.no_error()


def case_rst_during_a_sweep():
    """*RST during a sweep stops the sweep now; a move another client starts just after is not
    stopped by the reload that follows (it stopped such a move ~90 um short with no error)."""
    with Daemon(slow_config()) as d:
        a, b, c = Client(d), Client(d), Client(d, unix=True)
        a.send("SWEEP rst,100:200:50,0.1;0.9,3,20\n")
        time.sleep(0.5)
        check(a.ask("SWEEP?").startswith("RUNNING"), "the sweep runs")
        b.send("*RST\n")
        state = sweep_until_done(c)
        check(state[0] == "STOPPED", "the sweep stopped: %s" % state)
        # The axis at rest again: a move right away (the reload may still be pending).
        end = time.time() + 10
        while time.time() < end:
            start = rest_position(c)
            c.send("MOVE:REL 1e-3\n")
            err = c.error()
            if err.startswith("0,"):
                break
            check(err.startswith("-221,"), "refused only while the reload waits: %s" % err)
            time.sleep(0.05)
        check(c.wait_done(120), "the move ends")
        res = c.ask("MOVE:RES?")
        check(res.startswith("OK"), "OK: %s (STAT? %s, error %s)" % (res, c.ask("STAT?"), c.error()))
        check(abs(rest_position(c) - start - 1e-3) < 50e-9, "at its target")
        c.no_error()


def case_stopped_by_another_client():
    """A move stopped by another client's STOP tells the client that started it (114); one it
    stopped itself does not."""
    with Daemon(slow_config()) as d:
        a, b = Client(d), Client(d)
        a.send("MOVE:REL 2e-3\n")
        time.sleep(0.3)
        b.send("STOP\n")
        check(a.wait_done(30), "stopped")
        err = a.error()
        check(err.startswith("114,") and "another client" in err, "the mover is told: %s" % err)
        b.no_error()
        a.send("MOVE:REL -1e-3\n")
        time.sleep(0.3)
        a.send("STOP\n")
        check(a.wait_done(30), "stopped by itself")
        a.no_error()


def start_exit(cfg):
    """idmd --config cfg run to its exit (it must not start): (code, stderr)."""
    r = subprocess.run([harness.IDMD, "--config", cfg, "--port", "0", "--unix", ""],
                       capture_output=True, text=True, timeout=60)
    return r.returncode, r.stderr


def case_shared_calibration_file():
    """Two axes naming one calibration_file (or one's reference_file another's calibration): both
    refused by --check-config naming the keys (all but one axis lost its calibration)."""
    cfg = config("idmd-xyz.yaml", [("calibration-z.txt", "calibration-y.txt")], out="shared.yaml")
    code, _, err, _ = check_config(cfg)
    check(code == 2 and "axes.z.control.calibration_file" in err and
          "axes.y.control.calibration_file" in err, "shared calibration refused: %s" % err.strip())
    cfg = config(edits=[("  calibration_file: %s/calibration.txt" % harness.TMP,
                         "  calibration_file: %s/calibration.txt\nreference_file: %s/calibration.txt"
                         % (harness.TMP, harness.TMP))], out="same.yaml")
    code, _, err, _ = check_config(cfg)
    check(code == 2 and "reference_file" in err, "calibration = reference refused: %s" % err.strip())


def case_unreadable_files_kept():
    """A calibration_file or reference_file that does not parse (a file idmd did not write, or a
    damaged one) is never overwritten: --check-config and the start refuse it naming the file;
    the file is as it was (it was logged as bad and then overwritten)."""
    cal = os.path.join(harness.TMP, "calibration.txt")
    for name, text, key in (("calibration.txt", "not: [a calibration\n", "calibration_file"),
                            ("reference.yaml", "referenced: maybe\n", "reference_file")):
        path = temp_file(name, text)
        edits = [("  calibration_file: %s" % cal, "  calibration_file: %s" % cal)]
        if key == "reference_file":
            edits = [("  calibration_file: %s" % cal,
                      "  calibration_file: %s\nreference_file: %s" % (cal, path))]
            if os.path.exists(cal):
                os.unlink(cal)
        cfg = config(edits=edits, out="bad-%s.yaml" % key)
        code, _, err, _ = check_config(cfg)
        check(code == 2 and path in err and "does not overwrite" in err,
              "--check-config refuses the %s: %s" % (key, err.strip()))
        code, err = start_exit(cfg)
        check(code == 2 and path in err, "idmd refuses to start on it: %s" % err.strip()[-300:])
        check(open(path).read() == text, "and the file is as it was")
        os.unlink(path)


def case_writable_by_others():
    """recording.data_dir writable by every user (no sticky bit) is refused; a sticky shared one
    and a group-writable one are warned about; a calibration directory that does not exist is
    refused (the axis would lose what it learns)."""
    data = os.path.join(harness.TMP, "data")
    os.makedirs(data, exist_ok=True)
    cfg = config()
    for mode, expect in ((0o777, "error"), (0o1777, "warning"), (0o775, "warning"),
                         (0o755, None)):
        os.chmod(data, mode)
        # Group-writable matters when the group is another's (gid 1, not this process's).
        os.chown(data, -1, 1 if mode == 0o775 else os.getegid())
        code, out, err, _ = check_config(cfg)
        if expect == "error":
            check(code == 2 and "writable by every user" in err, "0%o refused: %s" % (mode, err))
        elif expect == "warning":
            check(code == 0 and "warning" in err and data in err, "0%o warned: %s" % (mode, err))
        else:
            check(code == 0 and data not in err, "0%o quiet: %s" % (mode, err))
    cfg = config(edits=[("calibration_file: %s/calibration.txt" % harness.TMP,
                         "calibration_file: %s/nowhere/calibration.txt" % harness.TMP)],
                 out="nowhere.yaml")
    code, _, err, _ = check_config(cfg)
    check(code == 2 and "does not exist" in err, "a missing calibration directory: %s" % err)


def case_check_as_the_service_user():
    """--check-config says when recording.data_dir or a calibration directory does not exist or
    is not writable by the user idmd runs as: the caller's (at start, idmd's own), or with
    --user NAME (as root) NAME's, the service's `idmd` on a lab PC (`nobody` here). Root, who can
    write anywhere, saw no problem with directories the service's user cannot write in."""
    if os.geteuid() != 0:
        fail("this case takes another user's permissions: run it as root")
    base = tempfile.mkdtemp(prefix="idmd-service-user-")
    try:
        os.chmod(base, 0o755)
        cal, data = os.path.join(base, "cal"), os.path.join(base, "data")
        os.mkdir(cal, 0o755)
        made = config(edits=[("calibration_file: %s/calibration.txt" % harness.TMP,
                              "calibration_file: %s/calibration.txt" % cal),
                             ("data_dir: %s/data" % harness.TMP, "data_dir: %s" % data)],
                      out="service.yaml")
        cfg = os.path.join(base, "idmd.yaml")
        shutil.copyfile(made, cfg)
        os.chmod(cfg, 0o644)
        code, _, err, _ = check_config(cfg)
        check(code == 0 and "note: recording.data_dir %s: does not exist yet" % data in err,
              "a data_dir that is not there yet is said: %s" % err)

        def as_nobody():
            r = subprocess.run([harness.IDMD, "--check-config", cfg, "--user", "nobody"],
                               capture_output=True, text=True, timeout=60)
            return r.returncode, r.stderr

        code, err = as_nobody()
        check(code == 2 and "control.calibration_file: the directory %s is not writable by user "
              "nobody" % cal in err, "a calibration directory nobody cannot write: %s" % err)
        check("warning: recording.data_dir %s: does not exist, and %s is not writable by user "
              "nobody" % (data, base) in err, "nor make data_dir in: %s" % err)
        os.mkdir(data, 0o755)
        code, err = as_nobody()
        check(code == 2 and "recording.data_dir %s: %s is not writable by user nobody" % (data, data)
              in err, "a data_dir nobody cannot write in: %s" % err)
        nobody = pwd.getpwnam("nobody")
        for d in (cal, data):
            os.chown(d, nobody.pw_uid, nobody.pw_gid)
        code, err = as_nobody()
        check(code == 0 and err == "", "both nobody's: clean: %s" % err)
        shutil.rmtree(cal)
        code, err = as_nobody()
        check(code == 2 and "the directory %s does not exist" % cal in err,
              "a calibration directory that is not there: %s" % err)
        r = subprocess.run([harness.IDMD, "--check-config", cfg, "--user", "no-such-user-idm"],
                           capture_output=True, text=True, timeout=60)
        check(r.returncode == 2 and "no-such-user-idm" in r.stderr, "an unknown user: " + r.stderr)
        r = subprocess.run([harness.IDMD, "--config", cfg, "--user", "nobody"],
                           capture_output=True, text=True, timeout=60)
        check(r.returncode == 2 and "--user is for --check-config" in r.stderr,
              "--user only with --check-config: " + r.stderr)
    finally:
        shutil.rmtree(base, ignore_errors=True)


def case_dataset_swapped_for_a_link():
    """Another user who can write in data_dir swaps a running sweep's dataset directory for a
    symlink to a directory of theirs (or any file's): the recorder writes on into the directory it
    made (held open), never through the link."""
    victim = os.path.join(harness.TMP, "victim")
    os.makedirs(victim)
    with Daemon(slow_config()) as d:
        c = Client(d)
        c.send("SWEEP swap,100:200:50,0.1;0.9,4,12\n")
        time.sleep(0.4)
        check(c.ask("SWEEP?").startswith("RUNNING"), "the sweep runs")
        ds = os.path.join(harness.TMP, "data", "swap")
        moved = os.path.join(harness.TMP, "data", "moved")
        os.rename(ds, moved)
        os.symlink(victim, ds)
        state = sweep_until_done(c)
        check(os.listdir(victim) == [], "nothing written through the link: %s" % os.listdir(victim))
        written = int(state[2])
        rows = open(os.path.join(moved, "sweep.csv")).read().splitlines()
        check(written > 0 and len(rows) == written + 1,
              "every trial in the directory it made: %s" % state)


cases = {
    "shared_calibration_file": case_shared_calibration_file,
    "unreadable_files_kept": case_unreadable_files_kept,
    "writable_by_others": case_writable_by_others,
    "check_as_the_service_user": case_check_as_the_service_user,
    "dataset_swapped_for_a_link": case_dataset_swapped_for_a_link,
    "sighup_waits_for_a_move": case_sighup_waits_for_a_move,
    "rst_during_a_sweep": case_rst_during_a_sweep,
    "stopped_by_another_client": case_stopped_by_another_client,
    "in_position_after_push": case_in_position_after_push,
    "sweep_limits": case_sweep_limits,
    "sweep_near_the_end": case_sweep_near_the_end,
    "sweep_full_disk": case_sweep_full_disk,
    "sweep_end_stop_unknown": case_sweep_end_stop_unknown,
    "http_post": case_http_post,
    "token": case_token,
    "token_file_checked": case_token_file_checked,
    "remote_address": case_remote_address,
    "second_instance": case_second_instance,
    "alias_bomb": case_alias_bomb,
    "syscalls": case_syscalls,
}

if __name__ == "__main__":
    harness.run(cases)
