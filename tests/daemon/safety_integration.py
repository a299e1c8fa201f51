#!/usr/bin/python3
"""Nothing but a deliberate motion command from an authorised client moves the stage: the real
idmd on the simulated stage, attacked the way a web page, another local user, a careless config or
a hostile file would, through its sockets and its command line. Each case says what it stands for.

usage: safety_integration.py BUILD_DIR SOURCE_DIR CASE
"""
import http.client
import os
import re
import signal
import subprocess
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


cases = {
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
