"""idm-web's access rules against a real idmd on the simulated stage: the Host names it answers on
every listen address (the loopback names on any port, so that an ssh tunnel works), control
reachable from other machines only with --allow-remote-control and a token (from a file only its
owner reads, or the environment; never the command line), the gap report never read through a
symbolic link, a taken port refused, --version.

Inputs that vary (Host names, ports, wrong tokens) come from a seeded generator: each run the
same cases, many of them."""
import json
import os
import random
import re
import socket
import string
import subprocess

import pytest

from conftest import IDM_WEB, SLOW, Web, ask, fixtures, mean_position, send, wait_done, wait_for

CONTROL = {"X-Idm-Control": "1"}


@pytest.fixture(scope="module")
def daemon():
    with fixtures.idmd_in_temp_dir("idm-web-access-", edits=SLOW) as d:
        yield d


@pytest.fixture
def at_rest(daemon):
    yield
    send(daemon, "STOP")
    wait_done(daemon)


def run_web(args, env=None, timeout=15):
    """idm-web ARGS to its end: (exit code, stdout, stderr); one that serves instead is a
    failure (killed after `timeout`)."""
    try:
        r = subprocess.run([IDM_WEB] + args, capture_output=True, text=True, timeout=timeout,
                           env=env)
    except subprocess.TimeoutExpired:
        pytest.fail("idm-web %s started instead of refusing" % " ".join(args))
    return r.returncode, r.stdout, r.stderr


def clean_env(**extra):
    env = {k: v for k, v in os.environ.items() if k != "IDM_WEB_TOKEN"}
    env.update(extra)
    return env


def write_token(path, token, mode=0o600):
    with open(path, "w") as f:
        f.write(token + "\n")
    os.chmod(path, mode)
    return str(path)


def new_token(rng, n=32):
    return "".join(rng.choice(string.ascii_letters + string.digits + "-_.~") for _ in range(n))


# ---- Host names ---------------------------------------------------------------------------------

def loopback_hosts(rng, n):
    """Loopback names as a browser through a tunnel or on this machine sends them."""
    out = []
    for _ in range(n):
        name = rng.choice(["localhost", "LocalHost", "localhost.", "127.0.0.1", "[::1]",
                           "127.%d.%d.%d" % (rng.randrange(256), rng.randrange(256),
                                             rng.randrange(256))])
        port = rng.choice([None, 80, 8080, 9000, rng.randrange(1, 65536)])
        out.append(name if port is None else "%s:%d" % (name, port))
    return out


def foreign_hosts(rng, n):
    """Names a DNS-rebinding page would send, and near misses of the loopback names."""
    fixed = ["evil.example", "127.0.0.1.evil.example", "localhost.evil.example",
             "evil-localhost", "127.0.0.256", "127.1", "127.0.0.1.2", "[::2]", "[::1].evil",
             "localhost:abc", "0x7f.0.0.1", "lab-pc.evil.example", "xn--lab-pc"]
    out = list(fixed)
    for _ in range(n):
        label = "".join(rng.choice(string.ascii_lowercase + string.digits + "-")
                        for _ in range(rng.randrange(1, 12))).strip("-") or "x"
        name = label + rng.choice([".example", ".test", ".com", ".localdomain", ""])
        if name in ("localhost", "lab-pc"):
            continue
        out.append(name if rng.random() < 0.5 else "%s:%d" % (name, rng.randrange(1, 65536)))
    return out


def test_loopback_names_on_any_port_are_answered(daemon, tmp_path):
    """Bound to loopback, Host localhost:9000 (ssh -L 9000:localhost:8080) is this server."""
    web = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % daemon.port], "loopback")
    try:
        rng = random.Random(32)
        for host in ["localhost:9000", "127.0.0.1:1", "[::1]:9000"] + loopback_hosts(rng, 40):
            status, _, body = web.request("/api/state", headers={"Host": host})
            assert status == 200, (host, status, body)
        for host in foreign_hosts(rng, 40):
            status, _, body = web.request("/api/state", headers={"Host": host})
            assert status == 403, (host, status, body)
            assert b"is not a name of this server" in body
    finally:
        assert web.stop() == 0


def test_a_wildcard_listener_checks_the_host_too(daemon, tmp_path):
    """On 0.0.0.0 the Host check still applies: the loopback names and the literal listen
    address are answered, and the names listed with --allow-host; nothing else."""
    rng = random.Random(30)
    web = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % daemon.port], "wildcard",
              listen="0.0.0.0:0")
    try:
        for host in ["0.0.0.0:%d" % web.port, "0.0.0.0"] + loopback_hosts(rng, 20):
            assert web.request("/metrics", headers={"Host": host})[0] == 200, host
        for host in foreign_hosts(rng, 40):
            assert web.request("/metrics", headers={"Host": host})[0] == 403, host
        assert "Host names accepted" in web.log()
    finally:
        assert web.stop() == 0
    web = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % daemon.port, "--allow-host", "lab-pc",
                              "--allow-host", "192.0.2.7", "--allow-host", "fe80::1"],
              "listed", listen="0.0.0.0:0")
    try:
        for host in ["lab-pc", "LAB-PC:8080", "lab-pc.:80", "192.0.2.7:%d" % web.port,
                     "[fe80::1]:8080", "localhost:9000"]:
            assert web.request("/metrics", headers={"Host": host})[0] == 200, host
        for host in foreign_hosts(rng, 40) + ["192.0.2.8", "lab-pc2", "[fe80::2]"]:
            assert web.request("/metrics", headers={"Host": host})[0] == 403, host
    finally:
        assert web.stop() == 0
    for bad in ("evil host", "a/b", "", "lab-pc:http"):
        rc, _, err = run_web(["--idmd", "127.0.0.1:1", "--allow-host", bad])
        assert rc == 2 and "--allow-host" in err, (bad, err)


# ---- Control from other machines ----------------------------------------------------------------

def test_control_off_the_machine_needs_allow_remote_control_and_a_token(tmp_path):
    rng = random.Random(7)
    good = write_token(tmp_path / "token", new_token(rng))
    unix = ["--unix", str(tmp_path / "no-idmd.sock")]
    cases = [
        # (arguments, environment additions, words the one-line error must hold)
        (["--listen", "0.0.0.0:0", "--control"], {}, ["--allow-remote-control", "token"]),
        (["--listen", "0.0.0.0:0", "--control", "--allow-remote-control"], {}, ["token"]),
        (["--listen", "0.0.0.0:0", "--allow-remote-control"], {}, ["only with --control"]),
        (["--control", "--token", "s3cret-s3cret-s3cret"], {}, ["never taken from the command"]),
        (["--control", "--token-file", good], {"IDM_WEB_TOKEN": new_token(rng)}, ["one way"]),
        (["--control", "--token-file", str(tmp_path / "missing")], {}, ["--token-file"]),
    ]
    loose = write_token(tmp_path / "loose", new_token(rng), 0o644)
    cases.append((["--control", "--token-file", loose], {}, ["mode 0644", "chmod 600"]))
    grouped = write_token(tmp_path / "grouped", new_token(rng), 0o640)
    cases.append((["--control", "--token-file", grouped], {}, ["mode 0640"]))
    link = tmp_path / "link"
    os.symlink(good, link)
    cases.append((["--control", "--token-file", str(link)], {}, ["symbolic link"]))
    short = write_token(tmp_path / "short", "abc")
    cases.append((["--control", "--token-file", short], {}, ["16 to 1024"]))
    cases.append((["--control"], {"IDM_WEB_TOKEN": "has a blank in it 1234"}, ["IDM_WEB_TOKEN"]))
    if os.geteuid() == 0:
        foreign = write_token(tmp_path / "foreign", new_token(rng))
        os.chown(foreign, 65534, 65534)
        cases.append((["--control", "--token-file", foreign], {}, ["belongs to uid 65534"]))
    for args, env, words in cases:
        rc, _, err = run_web(unix + args, clean_env(**env))
        assert rc == 2, (args, rc, err)
        assert err.startswith("idm-web: ") and len(err.splitlines()) == 1, err
        for w in words:
            assert w in err, (args, w, err)


def wrong_tokens(rng, token):
    """Near misses of the token: cut, grown, one character changed, another case. (Blanks
    after it are not: HTTP drops them from a header's value.)"""
    out = ["", token[:-1], token + "x", token[1:], token.upper(), " " + token, "Bearer " + token]
    for _ in range(20):
        i = rng.randrange(len(token))
        c = rng.choice([ch for ch in string.ascii_letters if ch != token[i]])
        out.append(token[:i] + c + token[i + 1:])
    return out


def test_remote_control_with_a_token(daemon, tmp_path, at_rest):
    """--allow-remote-control and a token on 0.0.0.0: it warns at start, refuses control without
    the token (401) or with a foreign Host (403), and STOP with the token stops the move."""
    rng = random.Random(11)
    token = new_token(rng, 40)
    path = write_token(tmp_path / "token", token)
    web = Web(str(tmp_path), ["--unix", daemon.unix, "--control", "--allow-remote-control",
                              "--token-file", path], "remote", listen="0.0.0.0:0", env=clean_env())
    try:
        assert "WARNING: CONTROL IS REACHABLE FROM OTHER MACHINES" in web.log()
        wait_for("the first poll", lambda: web.json("/api/state")["connected"], 30)
        s = web.json("/api/state")
        assert s["control"] is True and s["token_required"] is True
        start = mean_position(daemon)
        target = 4e-3 if start < 0 else -4e-3
        send(daemon, "MOVE:ABS %.12g" % target)
        wait_for("progress", lambda: abs(mean_position(daemon, 2) - start) > 20e-6, 30)
        for wrong in [None] + wrong_tokens(rng, token):
            headers = dict(CONTROL)
            if wrong is not None:
                headers["Authorization"] = "Bearer " + wrong
            status, h, body = web.request("/api/stop", "POST", b"", headers)
            assert status == 401, (wrong, status, body)
            assert h["WWW-Authenticate"].startswith("Bearer")
        bearer = dict(CONTROL, Authorization="Bearer " + token)
        assert web.request("/api/stop", "POST", b"", dict(bearer, Host="evil.example"))[0] == 403
        assert web.request("/api/stop", "POST", b"", {"Authorization": "Bearer " + token})[0] == 403
        assert ask(daemon, "MOVE:DONE?")[0] == "0", "a refused STOP stopped the move"
        status, _, body = web.request("/api/stop", "POST", b"", bearer)
        assert status == 200 and json.loads(body) == {"ok": True}
        wait_done(daemon, 10)
        assert abs(mean_position(daemon) - target) > 1e-3
    finally:
        assert web.stop() == 0


def test_a_token_from_the_environment_guards_control_on_loopback(daemon, tmp_path, at_rest):
    token = new_token(random.Random(5), 24)
    web = Web(str(tmp_path), ["--unix", daemon.unix, "--control"], "env-token",
              env=clean_env(IDM_WEB_TOKEN=token))
    try:
        wait_for("the first poll", lambda: web.json("/api/state")["connected"], 30)
        assert web.json("/api/state")["token_required"] is True
        assert token not in " ".join(web.proc.args)
        hdr = dict(CONTROL)
        assert web.request("/api/move", "POST", b"axis=1&target=1e-4", hdr)[0] == 401
        assert float(ask(daemon, "MOVE?")[0]) != pytest.approx(1e-4)
        hdr["Authorization"] = "Bearer " + token
        assert web.request("/api/move", "POST", b"axis=1&target=1e-4", hdr)[0] == 200
        assert float(ask(daemon, "MOVE?")[0]) == pytest.approx(1e-4)
        assert web.request("/api/stop", "POST", b"", hdr)[0] == 200
    finally:
        assert web.stop() == 0


# ---- The gap report -----------------------------------------------------------------------------

def test_the_gap_report_is_never_read_through_a_symbolic_link(daemon, tmp_path):
    secret = tmp_path / "secret"
    secret.write_text('{"root": "secret-content"}')
    os.chmod(secret, 0o600)
    report = tmp_path / "gap.json"
    os.symlink(secret, report)
    # A link there at start: refused at once.
    rc, _, err = run_web(["--idmd", "127.0.0.1:%d" % daemon.port, "--gap-report", str(report)])
    assert rc == 2 and "symbolic link" in err, (rc, err)
    os.unlink(report)
    web = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % daemon.port, "--gap-report",
                              str(report)], "gap-link")
    try:
        assert web.request("/api/gap")[0] == 404
        os.symlink(secret, report)  # put there while it runs
        status, _, body = web.request("/api/gap")
        assert status == 403 and b"secret-content" not in body, (status, body)
        assert "symbolic link" in json.loads(body)["error"]
        os.unlink(report)
        os.mkfifo(report)  # a FIFO would block a plain open: refused, at once
        status, _, body = web.request("/api/gap", timeout=10)
        assert status == 403 and "not a regular file" in json.loads(body)["error"], body
        os.unlink(report)
        with open(report, "wb") as f:
            f.truncate(16 * 1024 * 1024 + 1)
        status, _, body = web.request("/api/gap")
        assert status == 413 and "at most 16777216" in json.loads(body)["error"], body
        os.unlink(report)
        report.write_text('{"dataset": "sweep-1"}')
        assert web.json("/api/gap") == {"dataset": "sweep-1"}
    finally:
        assert web.stop() == 0


def vm_hwm_kb(pid):
    with open("/proc/%d/status" % pid) as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))


def test_a_gap_report_costs_its_own_size(daemon, tmp_path):
    """Reading the gap report takes about its size of memory, not the 16 MiB it may reach (every
    request took a 16 MiB buffer): generated sizes up to 1 MiB, the peak resident size checked."""
    report = tmp_path / "gap.json"
    report.write_text("{}")
    web = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % daemon.port, "--gap-report",
                              str(report)], "gap-size")
    try:
        assert web.json("/api/gap") == {}
        rng = random.Random(16)
        before = vm_hwm_kb(web.proc.pid)
        for n in [0, 1, 4095, 4096, 4097, 1 << 20] + [rng.randrange(1, 1 << 20) for _ in range(8)]:
            text = json.dumps({"pad": "x" * n})
            report.write_text(text)
            status, _, body = web.request("/api/gap")
            assert status == 200 and body == text.encode(), (n, status, len(body))
        grown = vm_hwm_kb(web.proc.pid) - before
        assert grown < 8 * 1024, "the peak resident size grew by %d kB" % grown
    finally:
        assert web.stop() == 0


# ---- The port, the version ----------------------------------------------------------------------

def test_a_taken_port_is_refused(daemon, tmp_path):
    """No SO_REUSEPORT: a second idm-web on the first one's port exits 4 and says why, and the
    first one keeps every request."""
    first = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % daemon.port], "first")
    try:
        for listen, control in (("127.0.0.1:%d" % first.port, ["--control"]),
                                ("0.0.0.0:%d" % first.port, [])):
            rc, out, err = run_web(["--unix", daemon.unix, "--listen", listen] + control)
            assert rc == 4, (listen, rc, out, err)
            assert "Address already in use" in err and len(err.splitlines()) == 1, err
        for _ in range(20):
            assert first.json("/api/state")["control"] is False
        # Something else on a port: the same.
        other = socket.socket()
        other.bind(("127.0.0.1", 0))
        other.listen()
        try:
            rc, _, err = run_web(["--unix", daemon.unix,
                                  "--listen", "127.0.0.1:%d" % other.getsockname()[1]])
            assert rc == 4 and "Address already in use" in err, err
        finally:
            other.close()
    finally:
        assert first.stop() == 0


def test_version():
    with open(os.path.join(fixtures.SOURCE, "CMakeLists.txt")) as f:
        version = re.search(r"project\(\s*idm\b[^)]*\bVERSION\s+([0-9.]+)", f.read()).group(1)
    rc, out, err = run_web(["--version"])
    assert (rc, out, err) == (0, "idm-web %s\n" % version, "")
    idmd = subprocess.run([fixtures.IDMD, "--version"], capture_output=True, text=True,
                          timeout=30)
    assert idmd.stdout.split() == ["idmd", version]
