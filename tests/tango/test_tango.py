"""idm-tango against a real idmd on the simulated stage, driven by PyTango: the device's state,
a move written to Position (State MOVING then ON, change events, the arrived position), Stop in
the middle of a move, a write outside the soft limits refused, the attributes that mirror the
daemon's queries, Step, and what a device says when idmd is gone or its name names no axis."""
import math
import tempfile
import shutil
import threading
import time

import pytest
import tango

from conftest import TangoServer, fixtures, wait_for


ask = fixtures.ask
send = fixtures.send


def resolution(daemon):
    return float(ask(daemon, "RES?")[0])


def mean_position(daemon, n=8):
    return sum(float(ask(daemon, "POS?")[0]) for _ in range(n)) / n


class Events:
    """Change events of one attribute, collected by PyTango's callback thread."""

    def __init__(self, dev, attr):
        self.values = []
        self.errors = []
        self.cond = threading.Condition()
        self.dev = dev
        self.id = dev.subscribe_event(attr, tango.EventType.CHANGE_EVENT, self)

    def push_event(self, ev):
        with self.cond:
            if ev.err:
                self.errors.append(ev.errors)
            else:
                self.values.append((ev.attr_value.value, ev.attr_value.quality))
            self.cond.notify_all()

    def wait_for(self, what, predicate, timeout=60):
        with self.cond:
            if not self.cond.wait_for(lambda: predicate(list(self.values)), timeout):
                pytest.fail("no %s within %g s; events: %r" % (what, timeout, self.values))

    def close(self):
        self.dev.unsubscribe_event(self.id)


def wait_at_rest(dev, timeout=60):
    wait_for("the axis at rest", lambda: dev.state() != tango.DevState.MOVING, timeout)


@pytest.fixture
def axis(lab):
    """The device of axis 1; afterwards stopped, at rest, without a user offset, with its soft
    limits the travel."""
    daemon, server = lab
    dev = server.proxy()
    yield dev
    send(daemon, "STOP")
    wait_at_rest(dev)
    send(daemon, "POS:OFFS 0")
    send(daemon, "LIM %g,%g" % fixtures.TRAVEL)


def test_at_rest_the_device_is_on_and_reads_the_daemon(lab, axis):
    daemon, _ = lab
    assert axis.state() == tango.DevState.ON
    assert "axis x" in axis.status()
    position = axis.read_attribute("Position")
    assert position.quality == tango.AttrQuality.ATTR_VALID
    # The sensor's noise: a few counts around the daemon's own mean reading.
    assert abs(position.value - mean_position(daemon)) < 5 * resolution(daemon)
    config = axis.get_attribute_config("Position")
    assert config.unit == "m"
    lower, upper = (float(v) for v in ask(daemon, "LIM?")[0].split(","))
    assert float(config.min_value) == pytest.approx(lower)
    assert float(config.max_value) == pytest.approx(upper)


def test_a_written_position_is_reached_with_moving_then_on_and_events(lab, axis):
    daemon, _ = lab
    start = mean_position(daemon)
    target = start + 25e-6
    states = Events(axis, "State")
    positions = Events(axis, "Position")
    try:
        states.wait_for("the first State event", lambda v: len(v) >= 1, 10)
        axis.write_attribute("Position", target)
        states.wait_for("State MOVING then ON",
                        lambda v: any(s == tango.DevState.MOVING for s, _ in v) and
                        v[-1][0] == tango.DevState.ON and
                        [s for s, _ in v].index(tango.DevState.MOVING) < len(v) - 1)
        positions.wait_for("a Position event at the target",
                           lambda v: v and abs(v[-1][0] - target) < 1e-6)
    finally:
        states.close()
        positions.close()
    seen = [s for s, _ in states.values]
    assert seen[seen.index(tango.DevState.MOVING):][-1] == tango.DevState.ON
    moving = [(p, q) for p, q in positions.values if q == tango.AttrQuality.ATTR_CHANGING]
    assert moving, "no Position event while moving: %r" % positions.values
    assert all(start - 1e-6 < p < target + 1e-6 for p, _ in moving)
    assert axis.state() == tango.DevState.ON
    # Arrived: within 1.5 counts of the target, as the daemon itself reads it.
    arrived = axis.read_attribute("Position").value
    assert abs(arrived - target) <= 1.5 * resolution(daemon), (arrived, target)
    assert axis.read_attribute("Target").value == pytest.approx(target, abs=1e-12)
    assert float(ask(daemon, "MOVE?")[0]) == pytest.approx(target, abs=1e-12)


def test_stop_ends_a_move_midway(lab, axis):
    daemon, _ = lab
    lower, upper = fixtures.TRAVEL
    axis.write_attribute("Position", lower + 0.2e-3)
    wait_at_rest(axis)
    start = axis.read_attribute("Position").value
    target = upper - 0.2e-3  # 9.6 mm: seconds on the slowed stage
    axis.write_attribute("Position", target)
    wait_for("State MOVING", lambda: axis.state() == tango.DevState.MOVING, 10)
    wait_for("progress", lambda: axis.read_attribute("Position").value > start + 20e-6, 30)
    axis.Stop()
    wait_at_rest(axis, 10)
    assert axis.state() == tango.DevState.ON
    stopped = axis.read_attribute("Position").value
    assert start + 20e-6 < stopped < target - 1e-3, (start, stopped, target)
    reply, _ = ask(daemon, "MOVE:DONE?")
    assert reply == "1"
    # At rest it stays where it stopped.
    assert abs(mean_position(daemon) - stopped) < 5 * resolution(daemon)


def test_a_write_outside_the_soft_limits_is_refused(lab, axis):
    daemon, _ = lab
    axis.write_attribute("Position", 0.0)
    wait_at_rest(axis)
    send(daemon, "LIM -1e-3,1e-3")
    wait_for("Position's max_value to follow the soft limit",
             lambda: float(axis.get_attribute_config("Position").max_value) == pytest.approx(1e-3),
             10)
    assert float(axis.get_attribute_config("Position").min_value) == pytest.approx(-1e-3)
    before = ask(daemon, "MOVE?")[0]
    with pytest.raises(tango.DevFailed) as refused:
        axis.write_attribute("Position", 1.5e-3)
    assert "maximum" in refused.value.args[0].desc
    with pytest.raises(tango.DevFailed):
        axis.write_attribute("Position", -1.5e-3)
    # Nothing moved, nothing was asked of the daemon.
    assert ask(daemon, "MOVE?")[0] == before
    assert axis.state() == tango.DevState.ON
    # Outside the limits (moved there before they shrank) the axis is in ALARM, as a motor at a
    # limit switch.
    send(daemon, "LIM -1e-3,1e-3")
    send(daemon, "LIM 0.5e-3,1e-3")
    wait_for("State ALARM", lambda: axis.state() == tango.DevState.ALARM, 10)


def test_attributes_report_what_the_daemon_answers(lab, axis):
    """Window, Hold and StatusBits read the protocol's MOVE:WIND?, HOLD? and STAT:OPER?: equal to
    the daemon's reply where it answers, and the daemon's error (its code) as a Tango exception
    where it does not; Referenced is STAT?'s referenced."""
    daemon, _ = lab
    for attr, query in (("Window", "MOVE:WIND?"), ("Hold", "HOLD?"), ("StatusBits", "STAT:OPER?")):
        reply, error = ask(daemon, query)
        if reply:
            assert error == '0,"No error"'
            assert axis.read_attribute(attr).value == pytest.approx(float(reply)), attr
        else:
            code = error.split(",", 1)[0]
            assert code != "0", (query, error)
            with pytest.raises(tango.DevFailed) as failed:
                axis.read_attribute(attr)
            assert failed.value.args[0].reason == "IdmdError"
            assert code + "," in failed.value.args[0].desc, (attr, failed.value.args[0].desc)
    status, _ = ask(daemon, "STAT?")
    referenced = dict(w.split("=", 1) for w in status.split())["referenced"] == "1"
    assert axis.read_attribute("Referenced").value == referenced


def test_step_bursts_both_ways(lab, axis):
    daemon, _ = lab
    counts = resolution(daemon)
    p0 = mean_position(daemon)
    axis.Step(20)
    wait_at_rest(axis)
    p1 = mean_position(daemon)
    axis.Step(-20)
    wait_at_rest(axis)
    p2 = mean_position(daemon)
    assert abs(p1 - p0) > 10 * counts and abs(p2 - p1) > 10 * counts, (p0, p1, p2)
    assert (p1 - p0) * (p2 - p1) < 0, "the two bursts went the same way: %r" % ((p0, p1, p2),)


def test_step_says_what_the_sign_of_n_means(lab, axis):
    """What a Tango client (Jive, a script's command_query) reads about Step: the protocol's
    STEP, the sign of n alone picking the direction, the duty as for the positive direction."""
    info = axis.command_query("Step")
    assert info.in_type == tango.CmdArgType.DevLong
    desc = " ".join(info.in_type_desc.split())
    assert "the sign of n alone picks the direction (positive: the positive direction)" in desc
    assert "the duty is given as for the positive direction and mirrored for negative n" in desc


def test_step_outside_the_daemon_s_range_is_a_tango_exception(lab, axis):
    with pytest.raises(tango.DevFailed) as failed:
        axis.Step(0)
    assert failed.value.args[0].reason == "IdmdError"
    assert "-222," in failed.value.args[0].desc


def failure_text(failed):
    """Every reason and description of a DevFailed, joined."""
    return " | ".join("%s: %s" % (e.reason, e.desc) for e in failed.value.args)


def test_velocity_is_the_daemons_speed_limit(lab, axis):
    """Velocity reads and writes MOVE:VELocity (m/s); a value out of the daemon's range is a
    Tango exception carrying idmd's -222, which names the command and the range, and changes
    nothing."""
    daemon, _ = lab
    assert float(ask(daemon, "MOVE:VEL?")[0]) == 0
    assert axis.read_attribute("Velocity").value == 0
    assert axis.get_attribute_config("Velocity").unit == "m/s"
    try:
        axis.write_attribute("Velocity", 5e-4)
        assert float(ask(daemon, "MOVE:VEL?")[0]) == 5e-4
        assert axis.read_attribute("Velocity").value == pytest.approx(5e-4, rel=1e-12)
        for bad in (2.0, -1e-6):
            with pytest.raises(tango.DevFailed) as refused:
                axis.write_attribute("Velocity", bad)
            text = failure_text(refused)
            assert "IdmdError" in text and "-222," in text, text
            assert "MOVE:VELocity" in text and "allowed [0, 1] m/s" in text, text
        assert float(ask(daemon, "MOVE:VEL?")[0]) == 5e-4
    finally:
        send(daemon, "MOVE:VEL 0")


def test_set_position_and_offset_are_the_daemons_user_frame(lab, axis):
    """SetPosition (POSition:SET) makes the current position the one given, nothing moving;
    Offset reads and writes POSition:OFFSet; Position and its min/max (the soft limits) follow
    the offset; an offset out of range is idmd's -222 and changes nothing."""
    daemon, _ = lab
    axis.write_attribute("Position", 0.0)
    wait_at_rest(axis)
    count = resolution(daemon)
    info = axis.command_query("SetPosition")
    assert info.in_type == tango.CmdArgType.DevDouble
    axis.SetPosition(2e-3)
    assert abs(mean_position(daemon) - 2e-3) <= 3 * count
    offset = axis.read_attribute("Offset").value
    assert offset == pytest.approx(float(ask(daemon, "POS:OFFS?")[0]), abs=1e-15)
    assert abs(axis.read_attribute("Position").value - 2e-3) <= 3 * count
    wait_for("Position's max_value to follow the offset",
             lambda: float(axis.get_attribute_config("Position").max_value) ==
             pytest.approx(fixtures.TRAVEL[1] + offset, abs=1e-9), 10)
    axis.write_attribute("Offset", 0.0)
    assert abs(mean_position(daemon) - (2e-3 - offset)) <= 3 * count
    assert axis.get_attribute_config("Offset").unit == "m"
    with pytest.raises(tango.DevFailed) as refused:
        axis.write_attribute("Offset", 11.0)
    text = failure_text(refused)
    assert "-222," in text and "allowed [-10, 10] m" in text, text
    assert float(ask(daemon, "POS:OFFS?")[0]) == 0


def test_jog_moves_to_the_soft_limit_and_stop_ends_it(lab, axis):
    """JogPositive: MOVING, then at rest at the upper soft limit less the window (MOVE:RESult?
    OK), no faster than Velocity; JogNegative runs until Stop (STOPPED) and the device is ON
    where it stopped."""
    daemon, _ = lab
    axis.write_attribute("Position", 0.0)
    wait_at_rest(axis)
    send(daemon, "LIM -0.2e-3,0.2e-3")
    limit = 4e-4
    axis.write_attribute("Velocity", limit)
    try:
        start_position = mean_position(daemon)
        states = Events(axis, "State")
        try:
            states.wait_for("the first State event", lambda v: len(v) >= 1, 10)
            # The first event is read at the subscription; pushed ones reach this client only
            # once its event channel is connected, a moment later (an event pushed before is
            # lost, as seen here: the jog's MOVING).
            time.sleep(1)
            start = time.monotonic()
            axis.JogPositive()
            states.wait_for("State MOVING, then at rest",
                            lambda v: any(s == tango.DevState.MOVING for s, _ in v) and
                            v[-1][0] != tango.DevState.MOVING, 30)
            elapsed = time.monotonic() - start
        finally:
            states.close()
        assert axis.state() in (tango.DevState.ON, tango.DevState.ALARM)
        window = float(ask(daemon, "MOVE:WIND?")[0])
        count = resolution(daemon)
        arrived = mean_position(daemon)
        assert 0.2e-3 - 2 * window - count <= arrived <= 0.2e-3 + count, (arrived, window)
        assert ask(daemon, "MOVE:RES?")[0].startswith("OK,")
        assert axis.read_attribute("Target").value == pytest.approx(0.2e-3 - window, abs=1e-12)
        assert elapsed >= (0.2e-3 - start_position) / (1.3 * limit), elapsed

        axis.JogNegative()
        wait_for("State MOVING", lambda: axis.state() == tango.DevState.MOVING, 10)
        wait_for("progress", lambda: axis.read_attribute("Position").value < arrived - 20e-6, 30)
        axis.Stop()
        wait_at_rest(axis, 10)
        assert axis.state() == tango.DevState.ON
        stopped = axis.read_attribute("Position").value
        assert -0.2e-3 + 20e-6 < stopped < arrived - 20e-6, (stopped, arrived)
        assert ask(daemon, "MOVE:RES?")[0].startswith("STOPPED,")
    finally:
        send(daemon, "MOVE:VEL 0")
    for name in ("JogPositive", "JogNegative"):
        info = axis.command_query(name)
        assert info.in_type == tango.CmdArgType.DevVoid
        assert info.out_type == tango.CmdArgType.DevVoid


def test_reference_does_what_the_daemon_does(lab, axis):
    daemon, _ = lab
    reply, error = ask(daemon, "REF?")
    if not reply:
        code = error.split(",", 1)[0]
        with pytest.raises(tango.DevFailed) as failed:
            axis.Reference()
        assert code + "," in failed.value.args[0].desc
    else:
        axis.Reference()
        wait_at_rest(axis)
        assert axis.read_attribute("Referenced").value


def test_two_axes_and_a_device_that_names_none():
    d = tempfile.mkdtemp(prefix="idm-tango-")
    daemon = fixtures.Idmd(d, config=fixtures.axes_config(d))
    server = TangoServer(d, {"IDMD_ADDRESS": "127.0.0.1:%d" % daemon.port},
                         devices=("idm/axis/1", "idm/axis/2", "idm/axis/x"), instance="two")
    try:
        x, y, bad = server.proxy("idm/axis/1"), server.proxy("idm/axis/2"), server.proxy("idm/axis/x")
        assert "axis x" in x.status() and "axis y" in y.status()
        assert y.state() == tango.DevState.ON
        target = y.read_attribute("Position").value - 15e-6
        y.write_attribute("Position", target)
        wait_at_rest(y)
        assert abs(y.read_attribute("Position").value - target) <= 1.5 * resolution(daemon)
        assert float(ask(daemon, "AXIS2:MOVE?")[0]) == pytest.approx(target, abs=1e-12)
        assert float(ask(daemon, "AXIS1:MOVE?")[0]) == 0  # axis 1 was not moved
        assert bad.state() == tango.DevState.FAULT
        assert "axis number" in bad.status()
        with pytest.raises(tango.DevFailed):
            bad.read_attribute("Position")
        assert server.alive()
    finally:
        server.stop()
        daemon.stop()
        shutil.rmtree(d, ignore_errors=True)


def test_without_idmd_the_device_is_in_fault_and_recovers():
    d = tempfile.mkdtemp(prefix="idm-tango-")
    daemon = fixtures.Idmd(d)
    server = TangoServer(d, {"IDMD_SOCKET": daemon.unix}, instance="gone")
    try:
        dev = server.proxy()
        assert dev.state() == tango.DevState.ON
        daemon.stop()
        wait_for("State FAULT", lambda: dev.state() == tango.DevState.FAULT, 10)
        assert "idmd not reached" in dev.status()
        with pytest.raises(tango.DevFailed) as failed:
            dev.read_attribute("Position")
        assert failed.value.args[0].reason == "IdmdUnreachable"
        with pytest.raises(tango.DevFailed):
            dev.write_attribute("Position", 1e-6)
        # idmd back on the same socket: the device reconnects by itself.
        daemon = fixtures.Idmd(d)
        wait_for("State ON again", lambda: dev.state() == tango.DevState.ON, 10)
        assert math.isfinite(dev.read_attribute("Position").value)
        assert server.alive()
    finally:
        server.stop()
        daemon.stop()
        shutil.rmtree(d, ignore_errors=True)
