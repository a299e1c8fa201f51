"""idm-web over HTTP against a real idmd on the simulated stage: the JSON endpoints and /metrics
follow the daemon, a read-only server refuses everything but GET, control (STOP, moves, jogs, the
speed limit) works only with --control and its header, foreign Host names are refused, hostile
requests do not bring it down, and pipelined requests are all answered in order.

Inputs that vary (pipelined requests, how they are cut into pieces) come from hypothesis."""
import json
import math
import random
import re
import socket
import threading
import time

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from conftest import Web, ask, fixtures, mean_position, read_reply, send, wait_done, wait_for

SAMPLE = re.compile(r'^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{(.*)\})? (\S+)$')
LABEL = re.compile(r'([a-zA-Z_][a-zA-Z0-9_]*)="((?:[^"\\]|\\.)*)"')


def parse_metrics(text):
    """The Prometheus text format: ({(name, ((label, value), ...)): float}, {family: type})."""
    samples, types, helps = {}, {}, set()
    for line in text.splitlines():
        if line.startswith("# HELP "):
            helps.add(line.split()[2])
        elif line.startswith("# TYPE "):
            _, _, name, kind = line.split(" ", 3)
            assert kind in ("gauge", "counter", "histogram"), line
            assert name not in types, "TYPE twice: " + name
            types[name] = kind
        else:
            m = SAMPLE.match(line)
            assert m, "not a sample line: %r" % line
            labels = tuple(sorted(LABEL.findall(m.group(3) or "")))
            key = (m.group(1), labels)
            assert key not in samples, "a sample twice: %r" % (key,)
            samples[key] = float(m.group(4))
    assert set(types) == helps, "a family without HELP or TYPE"
    for name, _ in samples:
        family = re.sub(r"_(bucket|sum|count)$", "", name) if name not in types else name
        assert family in types, "a sample without its TYPE: " + name
    return samples, types


def test_state_json_follows_the_daemon(lab, restore):
    daemon, web, _ = lab
    s = web.json("/api/state")
    assert s["connected"] is True and s["control"] is False
    assert s["idn"] == ask(daemon, "*IDN?")[0]
    (a,) = s["axes"]
    status = dict(w.split("=", 1) for w in ask(daemon, "STAT?")[0].split())
    assert a["axis"] == 1 and a["name"] == status["axis"] == "x"
    assert a["state"] == "IDLE" and a["done"] is True and a["position_valid"] is True
    lower, upper = (float(v) for v in ask(daemon, "LIM?")[0].split(","))
    assert (a["lower_m"], a["upper_m"]) == (pytest.approx(lower), pytest.approx(upper))
    assert abs(a["position_m"] - mean_position(daemon)) < 5 * float(ask(daemon, "RES?")[0])
    reply, error = ask(daemon, "STAT:OPER?")
    if reply:
        assert a["status_bits"] == int(reply)
    else:
        assert a["status_bits"] is None
        assert a["status_bits_error"].startswith(error.split(",", 1)[0] + ",")
    sweep = ask(daemon, "SWEEP?")[0]
    assert s["sweep"]["state"] == sweep.split(",", 1)[0]
    assert s["loop"]["period_s"] > 0


def test_a_move_shows_in_state_history_and_metrics(lab, restore):
    daemon, web, _ = lab
    samples, _ = parse_metrics(web.metrics())
    moves = samples[("idm_moves_total", (("axis", "x"),))]
    target = mean_position(daemon) + 30e-6
    send(daemon, "MOVE:ABS %.12g" % target)
    wait_done(daemon)
    arrived = mean_position(daemon)
    count = float(ask(daemon, "RES?")[0])

    def metrics_follow():
        s, _ = parse_metrics(web.metrics())
        return (s[("idm_moves_total", (("axis", "x"),))] == moves + 1 and
                abs(s[("idm_position_meters", (("axis", "x"),))] - arrived) < 5 * count and
                s[("idm_target_meters", (("axis", "x"),))] == pytest.approx(target))
    wait_for("the move in /metrics", metrics_follow, 10)
    # A sample every poll (0.1 s): a move that lands within one poll leaves the start and the
    # end; the next poll adds a third.
    wait_for("three samples in /api/history",
             lambda: len(web.json("/api/history")["axes"][0]["t"]) > 2, 10)
    h = web.json("/api/history")
    (axis,) = h["axes"]
    assert axis["name"] == "x" and len(axis["t"]) == len(axis["position_m"]) > 2
    assert all(-61 <= t <= 0 for t in axis["t"]) and axis["t"] == sorted(axis["t"])
    assert abs(axis["position_m"][-1] - arrived) < 5 * count
    # The history saw the axis on its way, not only at the two ends.
    assert min(axis["position_m"]) < target - 20e-6


def test_metrics_are_well_formed(lab):
    daemon, web, _ = lab
    idle = ("idm_axis_state", (("axis", "x"), ("state", "IDLE")))
    wait_for("the axis IDLE in /metrics", lambda: parse_metrics(web.metrics())[0][idle] == 1, 10)
    # SYST:LOOP? is polled once a second: the first, at idmd's start, may have no wake-up yet.
    wait_for("a loop wake-up in /metrics",
             lambda: parse_metrics(web.metrics())[0].get(("idm_loop_latency_seconds_count", ()), 0) > 0,
             10)
    samples, types = parse_metrics(web.metrics())
    assert samples[("idm_up", ())] == 1
    for family, kind in (("idm_position_meters", "gauge"), ("idm_moves_total", "counter"),
                         ("idm_faults_total", "counter"), ("idm_axis_state", "gauge"),
                         ("idm_loop_latency_seconds", "histogram"),
                         ("idm_web_clients_connected", "gauge"),
                         ("idm_clients_connected", "gauge"), ("idm_clients_max", "gauge")):
        assert types[family] == kind, family
    assert samples[("idm_axis_state", (("axis", "x"), ("state", "IDLE")))] == 1
    assert samples[("idm_axis_state", (("axis", "x"), ("state", "FAULT")))] == 0
    assert samples[("idm_faults_total", (("axis", "x"),))] == 0
    # The loop's latency histogram: cumulative buckets, +Inf the count, from SYST:LOOP?.
    buckets = sorted((float(dict(l)["le"].replace("+Inf", "inf")), v)
                     for (n, l), v in samples.items() if n == "idm_loop_latency_seconds_bucket")
    assert len(buckets) == 32 and buckets[-1][0] == math.inf
    assert all(a[1] <= b[1] for a, b in zip(buckets, buckets[1:]))
    assert buckets[-1][1] == samples[("idm_loop_latency_seconds_count", ())] > 0, buckets
    loop = dict(w.split("=", 1) for w in ask(daemon, "SYST:LOOP?")[0].split())
    assert buckets[0][0] == pytest.approx(float(loop["bin_width"]))
    assert samples[("idm_loop_period_seconds", ())] == pytest.approx(float(loop["period"]))
    # This request's own connection is open while it is answered.
    assert samples[("idm_web_clients_connected", ())] >= 1


def test_idmd_s_clients_are_counted_in_metrics(lab):
    """idm_clients_connected is idmd's own count (SYST:CLI:TABL?), not idm-web's: it follows
    plain clients of idmd that idm-web knows nothing of."""
    daemon, web, _ = lab

    def gauges():
        s = parse_metrics(web.metrics())[0]
        return (s.get(("idm_clients_connected", ())), s.get(("idm_clients_stop_only", ())),
                s.get(("idm_clients_max", ())))

    def settled():
        """The gauges once two reads 0.3 s apart agree (earlier tests' connections gone)."""
        first = gauges()
        time.sleep(0.3)
        return first if first == gauges() and first[0] is not None else None
    base, stop_only, table = wait_for("idm_clients_connected settled", settled, 10)
    assert base >= 2 and stop_only == 0 and table == 16  # two idm-webs poll; config's max_clients
    extra = [daemon.raw() for _ in range(5)]
    try:
        assert all(r.ask("*IDN?").startswith("idm,idmd") for r in extra)  # accepted by now
        wait_for("5 more clients in /metrics", lambda: gauges()[0] == base + 5, 10)
        assert int(extra[0].ask("SYST:CLI?")) == base + 5
        table = web.json("/api/state")["clients"]
        assert table["connected"] == base + 5 and table["max_clients"] == 16, table
    finally:
        for r in extra:
            r.close()
    wait_for("the count back down in /metrics", lambda: gauges()[0] == base, 10)


def test_the_region_map_is_the_daemon_s(lab):
    daemon, web, _ = lab
    m = web.json("/api/regions?axis=1")
    assert m["error"] == "" and len(m["cells"]) == len(m["freqs_hz"])
    assert 0.5 not in m["duties"]
    kinds = set()
    for i, f in enumerate(m["freqs_hz"]):
        assert len(m["cells"][i]) == len(m["duties"])
        for j, d in enumerate(m["duties"]):
            reply, error = ask(daemon, "REG? %g,%g" % (f, d))
            cell = m["cells"][i][j]
            if reply:
                region, step = reply.split(",")
                assert cell["region"] == region and cell["step_m"] == pytest.approx(float(step))
                kinds.add(region)
            else:
                assert cell is None, (f, d, error)
                kinds.add(None)
    assert {"ONESTEP", "CUTOFF"} <= kinds
    status, _, body = web.request("/api/regions?axis=7")
    assert status == 502 and json.loads(body)["error"].startswith("-114,")
    for bad in ("", "?axis=0", "?axis=x", "?axis=1e3", "?axis=100"):
        assert web.request("/api/regions" + bad)[0] == 400, bad


def test_read_only_refuses_everything_but_get(lab, restore):
    daemon, web, _ = lab
    target = mean_position(daemon) + 0.5e-3
    send(daemon, "MOVE:ABS %.12g" % target)
    for method in ("POST", "PUT", "DELETE", "PATCH", "OPTIONS"):
        status, headers, _ = web.request("/api/stop", method=method, data=b"",
                                         headers={"X-Idm-Control": "1"})
        assert status == 405, method
        assert headers["Allow"] == "GET, HEAD"
    assert web.request("/api/move", "POST", b"axis=1&target=0", {"X-Idm-Control": "1"})[0] == 405
    # The move was not stopped: it ends at its target.
    wait_done(daemon)
    assert abs(mean_position(daemon) - target) < 5 * float(ask(daemon, "RES?")[0])
    assert web.request("/api/state", "HEAD")[0] == 200
    assert web.request("/nothing")[0] == 404


def test_control_moves_and_stops(lab, restore):
    daemon, _, web = lab
    assert web.json("/api/state")["control"] is True
    start = mean_position(daemon)
    # Without the header (a form on another site): refused, nothing moves.
    assert web.request("/api/move", "POST", b"axis=1&target=1e-4")[0] == 403
    assert float(ask(daemon, "MOVE?")[0]) != pytest.approx(1e-4)
    hdr = {"X-Idm-Control": "1"}
    target = 4e-3 if start < 0 else -4e-3
    status, _, body = web.request("/api/move", "POST", ("axis=1&target=%r" % target).encode(), hdr)
    assert status == 200 and json.loads(body) == {"ok": True}
    assert float(ask(daemon, "MOVE?")[0]) == pytest.approx(target)
    wait_for("progress", lambda: abs(mean_position(daemon, 2) - start) > 50e-6, 30)
    status, _, body = web.request("/api/stop", "POST", b"", hdr)
    assert status == 200 and json.loads(body) == {"ok": True}
    wait_done(daemon, 10)
    stopped = mean_position(daemon)
    assert abs(stopped - target) > 1e-3, (start, stopped, target)
    # The daemon's refusals come back with its error.
    status, _, body = web.request("/api/move", "POST", b"axis=1&target=0.02", hdr)
    assert status == 422 and json.loads(body)["error"].startswith("-222,")
    status, _, body = web.request("/api/move", "POST", b"axis=9&target=0", hdr)
    assert status == 422 and json.loads(body)["error"].startswith("-114,")
    for bad in (b"axis=1&target=nan", b"axis=1&target=1e999", b"axis=1&target=abc",
                b"axis=1", b"target=0", b"axis=-1&target=0", b"axis=1&target=1e-6%0A*RST"):
        assert web.request("/api/move", "POST", bad, hdr)[0] == 400, bad
    assert web.request("/api/stop", "POST", b"axis=1", hdr)[0] == 200
    assert web.request("/api/stop", "POST", b"axis=0", hdr)[0] == 400


def test_control_jogs_and_sets_the_speed_limit(lab, restore):
    """POST /api/velocity sets MOVE:VELocity (shown in /api/state as speed_limit_m_s), refused
    out of the daemon's range with its error (the command and the range); POST /api/jog starts
    JOG toward that soft limit, which /api/stop ends; both need --control and the header, and
    bad parameters are 400 before anything reaches idmd."""
    daemon, readonly, web = lab
    hdr = {"X-Idm-Control": "1"}
    for path, body in (("/api/jog", b"axis=1&direction=positive"),
                       ("/api/velocity", b"axis=1&speed=1e-4")):
        assert readonly.request(path, "POST", body, hdr)[0] == 405, path
        assert web.request(path, "POST", body)[0] == 403, path
    assert float(ask(daemon, "MOVE:VEL?")[0]) == 0
    assert web.json("/api/state")["axes"][0]["offset_m"] == 0
    send(daemon, "POS:OFFS 1.5e-3")
    try:
        wait_for("the user offset in the state",
                 lambda: web.json("/api/state")["axes"][0]["offset_m"] == 1.5e-3, 10)
    finally:
        send(daemon, "POS:OFFS 0")
    assert web.json("/api/state")["axes"][0]["speed_limit_m_s"] == 0
    assert readonly.json("/api/state")["axes"][0]["speed_limit_m_s"] == 0
    try:
        status, _, body = web.request("/api/velocity", "POST", b"axis=1&speed=0.0004", hdr)
        assert status == 200 and json.loads(body) == {"ok": True}
        assert float(ask(daemon, "MOVE:VEL?")[0]) == 4e-4
        wait_for("the speed limit in the state",
                 lambda: web.json("/api/state")["axes"][0]["speed_limit_m_s"] == 4e-4, 10)
        for bad in (b"2", b"-1e-6"):
            status, _, body = web.request("/api/velocity", "POST", b"axis=1&speed=" + bad, hdr)
            error = json.loads(body)["error"]
            assert status == 422 and error.startswith("-222,"), (bad, status, body)
            assert "MOVE:VELocity" in error and "allowed [0, 1] m/s" in error, error
        assert float(ask(daemon, "MOVE:VEL?")[0]) == 4e-4
        for bad in (b"axis=1&speed=nan", b"axis=1&speed=abc", b"axis=1", b"speed=1e-4",
                    b"axis=0&speed=1e-4", b"axis=1&speed=1e-4%0A*RST", b"axis=1&speed=1e999"):
            assert web.request("/api/velocity", "POST", bad, hdr)[0] == 400, bad
        status, _, body = web.request("/api/velocity", "POST", b"axis=9&speed=0", hdr)
        assert status == 422 and json.loads(body)["error"].startswith("-114,")

        send(daemon, "MOVE:ABS 0")  # well inside the travel, wherever an earlier test left it
        wait_done(daemon)
        start = mean_position(daemon)
        send(daemon, "LIM %.12g,%.12g" % (start - 0.5e-3, start + 0.5e-3))
        status, _, body = web.request("/api/jog", "POST", b"axis=1&direction=negative", hdr)
        assert status == 200 and json.loads(body) == {"ok": True}
        window = float(ask(daemon, "MOVE:WIND?")[0])
        assert float(ask(daemon, "MOVE?")[0]) == pytest.approx(start - 0.5e-3 + window, abs=1e-12)
        wait_for("progress", lambda: mean_position(daemon, 2) < start - 30e-6, 30)
        assert ask(daemon, "MOVE:DONE?")[0] == "0"
        status, _, body = web.request("/api/stop", "POST", b"axis=1", hdr)
        assert status == 200
        wait_done(daemon, 10)
        stopped = mean_position(daemon)
        assert ask(daemon, "MOVE:RES?")[0].startswith("STOPPED,")
        assert start - 0.5e-3 + 20e-6 < stopped < start - 30e-6, (start, stopped)
        for bad in (b"axis=1&direction=up", b"axis=1&direction=POSITIVE", b"axis=1",
                    b"direction=positive", b"axis=x&direction=negative"):
            assert web.request("/api/jog", "POST", bad, hdr)[0] == 400, bad
        status, _, body = web.request("/api/jog", "POST", b"axis=9&direction=positive", hdr)
        assert status == 422 and json.loads(body)["error"].startswith("-114,")
        assert ask(daemon, "MOVE:DONE?")[0] == "1"
    finally:
        send(daemon, "MOVE:VEL 0")


def test_a_foreign_host_name_is_refused(lab):
    _, web, _ = lab
    for host in ("evil.example", "evil.example:%d" % web.port, "127.0.0.1.evil.example"):
        assert web.request("/api/state", headers={"Host": host})[0] == 403, host
    for host in ("localhost:%d" % web.port, "127.0.0.1:%d" % web.port, "127.0.0.1"):
        assert web.request("/api/state", headers={"Host": host})[0] == 200, host


def raw_http(port, data, read=True):
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    try:
        s.sendall(data)
        if not read:
            return b""
        s.shutdown(socket.SHUT_WR)
        return read_reply(s)
    except (BrokenPipeError, ConnectionResetError):
        return b""
    finally:
        s.close()


def test_hostile_requests_do_not_bring_it_down(lab):
    daemon, readonly, control = lab
    for web in (readonly, control):
        port = web.port
        attacks = [
            b"\x00\xff\xfe garbage\r\n\r\n",
            b"GET /" + b"a" * 100000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
            b"GET / HTTP/1.1\r\n" + b"X-A: b\r\n" * 5000 + b"\r\n",
            b"GET / HTTP/1.1\r\nX-Long: " + b"v" * 100000 + b"\r\n\r\n",
            b"POST /api/move HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Idm-Control: 1\r\n"
            b"Content-Length: 99999999999\r\n\r\naxis=1",
            b"POST /api/move HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Idm-Control: 1\r\n"
            b"Transfer-Encoding: chunked\r\n\r\nffffffffffffffff\r\nx\r\n",
            b"BREW /coffee HTTP/1.1\r\n\r\n",
            b"GET /api/regions?axis=%00%ff%%% HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
            b"GET /api/regions?axis=99999999999999999999999 HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
            b"GET /../../etc/passwd HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
            b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nRange: bytes=0-1,2-3,-5,99999999-\r\n\r\n",
            b"GET / HTTP/1.1\r\n",  # cut short
        ]
        for a in attacks:
            reply = raw_http(port, a)
            assert not reply.startswith(b"HTTP/1.1 500"), (a[:60], reply[:200])
            assert b"root:" not in reply
        # Many connections at once, some left half-open.
        socks = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(40)]
        for s in socks[::2]:
            s.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        threads = [threading.Thread(target=web.request, args=("/metrics",)) for _ in range(20)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        for s in socks:
            s.close()
        assert web.alive()
        assert web.json("/api/state")["connected"] is True
    # No move came of any of it.
    assert ask(daemon, "MOVE:DONE?")[0] == "1"


# What each path answers on a read-only server: (status, the start of its Content-Type).
PIPELINED = {b"/api/state": (200, "application/json"), b"/metrics": (200, "text/plain; version"),
             b"/": (200, "text/html"), b"/app.js": (200, "text/javascript"),
             b"/nothing": (404, "text/plain"), b"/api/regions": (400, "application/json")}


def parse_replies(data):
    """The HTTP/1.1 replies in `data`, in order: [(status, headers dict (lower case), body)]."""
    replies = []
    while data:
        head, sep, rest = data.partition(b"\r\n\r\n")
        assert sep, "a reply cut short: %r" % data[:200]
        lines = head.decode("latin-1").split("\r\n")
        assert lines[0].startswith("HTTP/1.1 "), lines[0]
        headers = dict((k.strip().lower(), v.strip())
                       for k, v in (line.split(":", 1) for line in lines[1:]))
        n = int(headers["content-length"])
        assert len(rest) >= n, "a body cut short"
        replies.append((int(lines[0][9:12]), headers, rest[:n]))
        data = rest[n:]
    return replies


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(paths=st.lists(st.sampled_from(sorted(PIPELINED)), min_size=1, max_size=12),
       cuts=st.lists(st.integers(1, 400), max_size=8),
       end=st.sampled_from(["half-close", "connection-close", "both"]), cork=st.booleans())
def test_pipelined_requests_are_all_answered_in_order(lab, paths, cuts, end, cork):
    """Requests sent back to back, in pieces of any size or corked (TCP_CORK: the bytes and the
    end of the client's side arrive together), then the client's end (a half-close of its side,
    Connection: close on the last request, or both): every one answered, in order, then the
    connection closed. (Corked, a half-close after two requests got one answer.)"""
    _, web, _ = lab
    data = b""
    for k, path in enumerate(paths):
        last = k == len(paths) - 1
        close = b"Connection: close\r\n" if last and end != "half-close" else b""
        data += b"GET " + path + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n" + close + b"\r\n"
    s = socket.create_connection(("127.0.0.1", web.port), timeout=20)
    try:
        if cork:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_CORK, 1)
        pos = 0
        for cut in cuts:
            s.sendall(data[pos:pos + cut])
            pos += cut
        s.sendall(data[pos:])
        if end != "connection-close":
            s.shutdown(socket.SHUT_WR)
        elif cork:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_CORK, 0)
        out = b""
        while True:
            chunk = s.recv(65536)
            if not chunk:
                break
            out += chunk
    finally:
        s.close()
    replies = parse_replies(out)
    assert [r[0] for r in replies] == [PIPELINED[p][0] for p in paths], (paths, end)
    for (status, headers, _), path in zip(replies, paths):
        assert headers["content-type"].startswith(PIPELINED[path][1]), (path, headers)
    if end != "half-close":
        assert replies[-1][1]["connection"] == "close"


def test_the_gap_report_is_served_when_there_is_one(tmp_path, lab):
    daemon = lab[0]
    path = tmp_path / "gap.json"
    web = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % daemon.port, "--gap-report", str(path)],
              "gap")
    try:
        status, _, body = web.request("/api/gap")
        assert status == 404 and "no gap report" in json.loads(body)["error"]
        report = {"dataset": "sweep-1", "diagnosis": {"effects": ["amplifier"], "gap_before": 74,
                                                      "gap_after": 1.3, "shrink": 0.98}}
        path.write_text(json.dumps(report))
        assert web.json("/api/gap") == report
    finally:
        assert web.stop() == 0


def test_without_idmd_it_says_so_and_reconnects(tmp_path):
    """With idmd gone nothing of it is shown as current: every axis is stale (no state, the
    position not valid, the last one only as last_position_m), no sweep, loop or client table,
    and /metrics has idm_up 0 and none of idmd's families."""
    daemon = fixtures.Idmd(str(tmp_path))
    web = Web(str(tmp_path), ["--unix", daemon.unix, "--poll", "0.05"], "gone")
    try:
        wait_for("connected", lambda: web.json("/api/state")["connected"], 10)
        wait_for("a loop sample", lambda: web.json("/api/state")["loop"] is not None, 10)
        last = web.json("/api/state")["axes"][0]
        assert last["stale"] is False and last["position_valid"] is True
        daemon.stop()
        wait_for("disconnected", lambda: not web.json("/api/state")["connected"], 10)
        s = web.json("/api/state")
        assert s["error"] and s["last_seen"] is not None and s["last_seen"] <= s["time"]
        (a,) = s["axes"]
        assert a["name"] == "x" and a["stale"] is True and a["state"] is None
        assert a["position_valid"] is False and a["position_m"] is None
        assert a["last_position_m"] == pytest.approx(last["position_m"], abs=50e-9)
        assert "target_m" not in a and a["status_error"] == "idmd not reached"
        assert s["sweep"] is None and s["loop"] is None and s["clients"] is None
        assert web.json("/api/history")["connected"] is False
        samples, _ = parse_metrics(web.metrics())
        assert samples[("idm_up", ())] == 0 and samples[("idm_web_poll_errors_total", ())] >= 1
        idmd_s = [n for n, _ in samples if not n.startswith(("idm_up", "idm_web_"))]
        assert idmd_s == [], idmd_s
        daemon = fixtures.Idmd(str(tmp_path))
        wait_for("connected again", lambda: web.json("/api/state")["connected"], 10)
        samples, _ = parse_metrics(web.metrics())
        assert samples[("idm_up", ())] == 1
    finally:
        assert web.stop() == 0
        daemon.stop()


def test_bad_command_lines_are_refused(tmp_path):
    import subprocess
    from conftest import IDM_WEB
    for args in (["--idmd", "host:99999"], ["--idmd", "::1:5025"], ["--listen", "[::1"],
                 ["--poll", "0"], ["--unix", "/x", "--idmd", "127.0.0.1:1"], ["--bogus"],
                 ["--region-freq", "abc"]):
        r = subprocess.run([IDM_WEB] + args, capture_output=True, text=True, timeout=30)
        assert r.returncode == 2, (args, r.returncode, r.stderr)
        assert r.stderr.startswith("idm-web: ") and len(r.stderr.splitlines()) == 1, r.stderr


def test_sweep_progress_is_the_daemon_s(lab, restore):
    daemon, web, _ = lab
    send(daemon, 'SWEEP "web-sweep",400;500,0.1;0.2,2,4')
    wait_for("the sweep done", lambda: ask(daemon, "SWEEP?")[0].startswith("DONE,"), 120)
    state, axis, written, failed, planned, directory = ask(daemon, "SWEEP?")[0].split(",", 5)
    assert int(planned) == 8 and int(written) + int(failed) == 8

    def shown():
        s = web.json("/api/state")["sweep"]
        return s if s["state"] == "DONE" else None
    s = wait_for("the sweep in /api/state", shown, 10)
    # SWEEP?'s axis is 1-based already (daemon/README.md).
    assert (s["axis"], s["written"], s["failed"], s["planned"]) == \
        (int(axis), int(written), int(failed), int(planned)) and s["axis"] == 1
    assert s["directory"] == json.loads(directory)
    samples, _ = parse_metrics(web.metrics())
    assert samples[("idm_sweep_running", ())] == 0
    assert samples[("idm_sweep_trials", (("kind", "written"),))] == int(written)
    assert samples[("idm_sweep_trials", (("kind", "planned"),))] == 8


def test_a_sweep_on_the_second_axis_is_shown_on_axis_2(tmp_path):
    with fixtures.idmd_in_temp_dir("idm-web-xy-", config=lambda d: fixtures.axes_config(d)) as d:
        web = Web(str(tmp_path), ["--idmd", "127.0.0.1:%d" % d.port], "xy")
        try:
            send(d, 'AXIS2:SWEEP "web-sweep-y",400,0.1,1,2')
            wait_for("the sweep done", lambda: ask(d, "SWEEP?")[0].startswith("DONE,"), 60)
            assert ask(d, "SWEEP?")[0].split(",")[1] == "2"

            def shown():
                s = web.json("/api/state")["sweep"]
                return s if s and s["state"] == "DONE" else None
            s = wait_for("the sweep in /api/state", shown, 10)
            assert s["axis"] == 2, s
            names = [a["name"] for a in web.json("/api/state")["axes"]]
            assert names == ["x", "y"]
        finally:
            assert web.stop() == 0


def check_rows(m, lo, hi):
    """The map's rows span [lo, hi]: lo, the multiples of a 1-2-5 step inside, hi."""
    f = m["freqs_hz"]
    assert m["freq_source"] == "idmd" and m["freq_range_hz"] == [pytest.approx(lo), pytest.approx(hi)]
    assert f[0] == pytest.approx(lo) and f[-1] == pytest.approx(hi) and f == sorted(set(f))
    assert 10 <= len(f) <= 23, f
    inner = f[1:-1]
    step = inner[1] - inner[0]
    mantissa = step / 10 ** math.floor(math.log10(step) + 1e-9)
    assert any(abs(mantissa - k) < 1e-6 for k in (1, 2, 5, 10)), step
    for v in inner:
        assert abs(v / step - round(v / step)) < 1e-6, (v, step)
    assert inner[0] - lo <= step * (1 + 1e-9) and hi - inner[-1] <= step * (1 + 1e-9)


def test_the_region_map_s_rows_are_the_axis_s_frequency_range(tmp_path):
    """The default grid comes from the axis's frequency range as idmd gives it (REG:RANG?:
    control's min_freq_hz and max_freq_hz, narrowed by the device). Reading it moves nothing."""
    rng = random.Random(2000)
    ranges = [(10, 2000)]
    for _ in range(3):
        lo = round(rng.uniform(5, 300), 1)
        ranges.append((lo, round(rng.uniform(lo + 60, 20000), 1)))
    for lo, hi in ranges:
        edits = [("min_freq_hz: 10", "min_freq_hz: %g" % lo),
                 ("max_freq_hz: 2000", "max_freq_hz: %g" % hi)]
        with fixtures.idmd_in_temp_dir("idm-web-range-", edits=edits) as d:
            web = Web(str(tmp_path), ["--unix", d.unix], "range")
            try:
                before = mean_position(d)
                m = web.json("/api/regions?axis=1")
                assert m["error"] == "", m["error"]
                check_rows(m, lo, hi)
                for i in rng.sample(range(len(m["freqs_hz"])), 3):
                    f, j = m["freqs_hz"][i], rng.randrange(len(m["duties"]))
                    region, step = ask(d, "REG? %r,%r" % (f, m["duties"][j]))[0].split(",")
                    assert m["cells"][i][j]["region"] == region, (f, m["duties"][j])
                status = dict(w.split("=", 1) for w in ask(d, "STAT?")[0].split())
                assert status["bursts"] == "0" and status["result"] == "NONE", status
                assert status["daemon_error"] == "none" and status["state"] == "IDLE", status
                assert abs(mean_position(d) - before) < 5 * float(ask(d, "RES?")[0])
                # --region-freq still rules when given.
                given = Web(str(tmp_path), ["--unix", d.unix, "--region-freq", "200:400:100"],
                            "given")
                try:
                    g = given.json("/api/regions?axis=1")
                    assert g["freqs_hz"] == [200, 300, 400] and g["freq_source"] == "--region-freq"
                finally:
                    assert given.stop() == 0
            finally:
                assert web.stop() == 0
