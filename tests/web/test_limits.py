"""idm-web's limits against a real idmd on the simulated stage: clients that send slowly or never
finish a request do not keep /metrics or STOP waiting, connections past --max-connections are
refused at once (503), a request's header block is bounded in fields and bytes (431), its line
(414) and body (413) too, and megabytes of headers do not grow the process.

Sizes near the limits come from a seeded generator: each run the same cases, many of them."""
import json
import random
import socket
import threading
import time

import pytest

from conftest import (SLOW, Web, ask, fixtures, mean_position, read_reply, send, wait_done,
                      wait_for)

FIELDS, HEADER_BYTES, LINE_BYTES = 100, 16384, 8192  # web/http_server.h's HttpLimits
CONTROL = {"X-Idm-Control": "1"}


@pytest.fixture(scope="module")
def daemon():
    with fixtures.idmd_in_temp_dir("idm-web-limits-", edits=SLOW) as d:
        yield d


@pytest.fixture(scope="module")
def web(daemon):
    w = Web(daemon.tmp, ["--unix", daemon.unix, "--control"], "limits")
    wait_for("the first poll", lambda: w.json("/api/state")["connected"], 30)
    yield w
    alive = w.alive()
    assert w.stop() == 0 and alive


def connect(port, timeout=30):
    return socket.create_connection(("127.0.0.1", port), timeout=timeout)


class SlowClients:
    """n connections that each start a request and then send one more byte of a header every
    `period` s, never ending it (slow loris)."""

    def __init__(self, port, n, period=0.5):
        self.socks = [connect(port) for _ in range(n)]
        for s in self.socks:
            s.sendall(b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.trickle, args=(period,))
        self.thread.start()

    def trickle(self, period):
        while not self.stop.wait(period):
            for s in self.socks:
                try:
                    s.send(b"a")
                except OSError:
                    pass

    def close(self):
        self.stop.set()
        self.thread.join()
        for s in self.socks:
            s.close()


def test_slow_clients_do_not_starve_it(daemon, web):
    """100 connections that never finish a request: /metrics and STOP are answered meanwhile,
    and each slow one is answered 408 and closed once its request timeout has passed."""
    start = mean_position(daemon)
    target = 4e-3 if start < 0 else -4e-3
    slow = SlowClients(web.port, 100)
    try:
        send(daemon, "MOVE:ABS %.12g" % target)
        for _ in range(3):
            status, _, body = web.request("/metrics", timeout=8)
            assert status == 200 and b"idm_up 1" in body
        status, _, body = web.request("/api/stop", "POST", b"", CONTROL, timeout=8)
        assert status == 200 and json.loads(body) == {"ok": True}
        wait_done(daemon, 10)
        assert abs(mean_position(daemon) - target) > 1e-3
        # Each slow client, still trickling, gets its 408 and the end of its connection.
        for s in slow.socks:
            s.settimeout(30)
        replies = [read_reply(s) for s in slow.socks]
        assert all(r.startswith(b"HTTP/1.1 408 ") for r in replies), set(r[:40] for r in replies)
    finally:
        slow.close()
    assert web.request("/metrics", timeout=8)[0] == 200


def test_connections_past_the_limit_are_refused_at_once(daemon, tmp_path):
    web = Web(str(tmp_path), ["--unix", daemon.unix, "--max-connections", "8"], "eight")
    try:
        # Eight idle connections (nothing sent yet): the oldest makes room for a request.
        idle = [connect(web.port) for _ in range(8)]
        time.sleep(0.2)
        assert web.request("/metrics", timeout=8)[0] == 200
        for s in idle:
            s.close()
        # Eight that started a request hold their slots: a ninth is refused at once.
        busy = SlowClients(web.port, 8)
        try:
            time.sleep(0.2)
            status, headers, body = web.request("/metrics", timeout=8)
            assert status == 503 and headers["Retry-After"] == "1", (status, body)
            assert b"at most 8 at once" in body
        finally:
            busy.close()
        wait_for("a slot again", lambda: web.request("/metrics", timeout=8)[0] == 200, 10)
    finally:
        assert web.stop() == 0


def status_of(port, head):
    """The status code idm-web answers to the request head `head` (bytes), on a raw socket."""
    s = connect(port)
    try:
        s.sendall(head)
        reply = read_reply(s)
    except (BrokenPipeError, ConnectionResetError):
        reply = b""
    finally:
        s.close()
    assert reply.startswith(b"HTTP/1.1 "), (head[:80], reply[:80])
    return int(reply[9:12])


def head_with(fields, target=b"/metrics"):
    """GET target with Host first, then `fields` (a list of bytes lines without CR LF)."""
    block = b"".join(f + b"\r\n" for f in [b"Host: 127.0.0.1", b"Connection: close"] + fields)
    return b"GET " + target + b" HTTP/1.1\r\n" + block + b"\r\n", len(block) + 2


def test_header_fields_are_bounded(web):
    """Up to 100 fields and 16384 bytes of header block answered; past either, 431."""
    rng = random.Random(431)
    cases = [(98, 10), (99, 10), (FIELDS - 2, 150), (5000, 2), (3, 6000), (1, 20000)]
    for _ in range(40):
        cases.append((rng.randrange(0, 2 * FIELDS), rng.randrange(1, 2 * HEADER_BYTES // FIELDS)))
    for _ in range(20):  # one field's size near the byte limit
        cases.append((1, HEADER_BYTES - rng.randrange(-80, 80)))
    for n, size in cases:
        fields = [b"X-F%d: " % k + b"v" * size for k in range(n)]
        head, block_bytes = head_with(fields)
        over = n + 2 > FIELDS or block_bytes > HEADER_BYTES
        status = status_of(web.port, head)
        assert status == (431 if over else 200), (n, size, block_bytes, status)
    # The request line and the body have their own limits.
    for length in (LINE_BYTES - 100, LINE_BYTES + 100, 100000):
        target = b"/metrics?" + b"a" * (length - len(b"GET /metrics? HTTP/1.1"))
        status = status_of(web.port, head_with([], target)[0])
        assert status == (414 if length > LINE_BYTES else 200), (length, status)
    big = (b"POST /api/move HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Idm-Control: 1\r\n"
           b"Content-Length: 70000\r\n\r\naxis=1")
    assert status_of(web.port, big) == 413


def vm_kb(pid, key):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise AssertionError(key)


def test_megabytes_of_headers_do_not_grow_it(web):
    """64 MiB of header lines on one connection: refused (431) after the first 16 KiB, the rest
    never read into memory (the old server took 210 MB of them to 711 MB)."""
    pid = web.proc.pid
    before = vm_kb(pid, "VmHWM")
    s = connect(web.port, 30)
    sent = 0
    chunk = b"".join(b"X-Fill-%06d: %s\r\n" % (k, b"v" * 100) for k in range(500))
    s.sendall(b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    try:
        while sent < 64 * 1024 * 1024:
            s.sendall(chunk)
            sent += len(chunk)
    except (BrokenPipeError, ConnectionResetError, socket.timeout):
        pass
    reply = read_reply(s)
    s.close()
    assert sent < 64 * 1024 * 1024, "all 64 MiB were taken"
    assert reply == b"" or reply.startswith(b"HTTP/1.1 431 "), reply[:100]
    grown = vm_kb(pid, "VmHWM") - before
    assert grown < 16 * 1024, "the peak resident size grew by %d kB" % grown
    assert web.request("/metrics", timeout=8)[0] == 200
