"""idm.Client against a real idmd with several axes (conftest.axes_config: x and y, config/idmd.yaml's
simulated stage each, on one simulated card): axes by number and by name, -114 for a missing
axis, moves on two axes at once, POSition:ALL?, AXIS<n>:STOP against STOP, a sweep on axis 2,
a fault on one axis; and an untrusted position (9.91E37, -230) from a Modbus device that
vanishes (tools/idm-simdev)."""
import math
import threading
import time

import pytest

import idm
from conftest import TRAVEL, SimDev, axes_config

COUNT = 632.991e-9 / 64  # config/idmd.yaml's interferometer: one count, m
FAR = 4e-3  # a move this long takes about a second on the simulated stage (wall clock)


def wait_for(what, predicate, timeout=30):
    """Polls predicate() until true (a bound, not a timing assertion)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail("%s: not within %g s" % (what, timeout))
        time.sleep(0.01)


def test_axes_by_number_and_by_name(client_xy):
    assert client_xy.axis_count() == 2
    assert client_xy.axis_names() == {1: "x", 2: "y"}
    x, y = client_xy.axis("x"), client_xy.axis("y")
    assert (x.number(), y.number(), client_xy.axis("Y").number()) == (1, 2, 2)
    assert client_xy.axis(2).name() == "y"
    assert x.status().axis == "x" and y.status().axis == "y"
    assert y.resolution() == pytest.approx(COUNT, rel=1e-9)
    with pytest.raises(idm.AxisNotFound, match="1 x, 2 y"):
        client_xy.axis("z").position()


@pytest.mark.parametrize("n", [3, 0, 99])
def test_a_missing_axis_is_the_daemons_114(client_xy, n):
    before = client_xy.positions()
    with pytest.raises(idm.CommandError) as e:
        client_xy.axis(n).position()
    assert e.value.code == -114 and e.value.command == "AXIS%d:POSition?" % n
    with pytest.raises(idm.CommandError) as e:
        client_xy.axis(n).move(1e-6)
    assert e.value.code == -114 and e.value.command == "AXIS%d:MOVE:ABSolute 1e-06" % n
    with pytest.raises(idm.CommandError) as e:
        client_xy.axis(n).stop()
    assert e.value.code == -114
    # nothing moved, and the queue is clean afterwards
    assert client_xy.positions() == pytest.approx(before, abs=3 * COUNT)
    assert client_xy.query("SYST:ERR?") == '0,"No error"'


def test_moves_on_two_axes_at_once(client_xy):
    x, y = client_xy.axis("x"), client_xy.axis("y")
    x.move(0)
    y.move(0)
    # Both started, the first still moving when the second is accepted (a move on another
    # axis is not "busy"), both arrive.
    x.move(-FAR, wait=False)
    y.move(FAR, wait=False)
    assert x.done() is False and y.done() is False
    assert client_xy.wait(timeout=60) is True
    px, py = client_xy.positions()
    assert px == pytest.approx(-FAR, abs=2 * COUNT)
    assert py == pytest.approx(FAR, abs=2 * COUNT)
    # Two threads, each waiting for its own axis's move on the one connection.
    arrived, failures = {}, []

    def mover(axis, target):
        try:
            arrived[axis.key] = axis.move(target, timeout=60)
        except Exception as e:  # collected, asserted below
            failures.append(e)
    threads = [threading.Thread(target=mover, args=(x, 1e-5)),
               threading.Thread(target=mover, args=(y, -2e-5))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert failures == []
    assert arrived["x"] == pytest.approx(1e-5, abs=2 * COUNT)
    assert arrived["y"] == pytest.approx(-2e-5, abs=2 * COUNT)
    assert (x.target(), y.target()) == (pytest.approx(1e-5), pytest.approx(-2e-5))


def test_positions_all_in_axis_order(client_xy):
    x, y = client_xy.axis(1), client_xy.axis(2)
    x.move(2e-5)
    y.move(-4e-5)
    both = client_xy.positions()
    assert len(both) == 2
    assert both[0] == pytest.approx(2e-5, abs=2 * COUNT)
    assert both[1] == pytest.approx(-4e-5, abs=2 * COUNT)
    assert both == pytest.approx([x.position(), y.position()], abs=3 * COUNT)
    assert client_xy.positions(allow_untrusted=True) == pytest.approx(both, abs=3 * COUNT)


def test_axis_stop_stops_that_axis_only(client_xy):
    x, y = client_xy.axis("x"), client_xy.axis("y")
    x.move(0)
    y.move(0)
    x.move(FAR, wait=False)
    y.move(FAR, wait=False)
    y.stop()  # AXIS2:STOP
    assert y.wait(10) is True
    stopped_at = y.position()
    assert abs(stopped_at - FAR) > 1e-4
    # x went on to its target
    assert x.wait(60) is True
    assert x.position() == pytest.approx(FAR, abs=2 * COUNT)
    assert y.position() == pytest.approx(stopped_at, abs=3 * COUNT)


def test_client_stop_stops_every_axis(client_xy):
    x, y = client_xy.axis("x"), client_xy.axis("y")
    x.move(0)
    y.move(0)
    x.move(-FAR, wait=False)
    y.move(FAR, wait=False)
    client_xy.stop()  # STOP: every axis
    assert x.wait(10) is True and y.wait(10) is True
    px, py = client_xy.positions()
    assert abs(px + FAR) > 1e-4 and abs(py - FAR) > 1e-4


def test_settings_and_steps_are_per_axis(client_xy):
    x, y = client_xy.axis("x"), client_xy.axis("y")
    y.set_limits(-1e-3, 1e-3)
    assert y.limits() == (-1e-3, 1e-3) and x.limits() == TRAVEL
    with pytest.raises(idm.ExecutionError) as e:
        y.move(2e-3)
    assert e.value.code == -222 and e.value.command == "AXIS2:MOVE:ABSolute 0.002"
    assert x.move(2e-3) == pytest.approx(2e-3, abs=2 * COUNT)
    # An open-loop burst on y moves y as its region map predicts, and x not at all.
    region, step = y.region(200, 0.1)
    px, py = client_xy.positions()
    after = y.step(10, 0.1, 200)
    assert abs((after - py) - 10 * step) < 0.3 * abs(10 * step)
    assert x.position() == pytest.approx(px, abs=3 * COUNT)


def test_sweep_on_axis_two_while_axis_one_moves(client_xy, idmd_xy):
    """A sweep on axis 2: axis 1's STOP leaves it alone, axis 1 moves meanwhile. One trial
    of 1.1 s (20 Hz, 20 cycles): idmd of this tree sometimes fails a trial that follows
    another ("motion in progress", a race between the trial's end in the capture and in the
    loop), which is not what this test is about."""
    x, y = client_xy.axis("x"), client_xy.axis("y")
    x.move(0)
    sweep = y.sweep("axis2-sweep", 20, 0.1, 1, 20, data_dir=idmd_xy.data_dir)
    x.stop()  # AXIS1:STOP
    state = client_xy.sweep_state()
    assert state == ("RUNNING", 2, 0, 0, 1, sweep.directory)
    assert x.move(5e-6) == pytest.approx(5e-6, abs=2 * COUNT)
    final = sweep.wait(timeout=120)
    assert final.state == "DONE" and final.recorded == final.total == 1 and final.failed == 0
    assert client_xy.sweep_state() == ("DONE", 2, 1, 0, 1, sweep.directory)
    assert x.position() == pytest.approx(5e-6, abs=2 * COUNT)


def test_a_fault_on_one_axis(make_idmd):
    d = make_idmd(config=lambda tmp: axes_config(tmp, stalled=("y",)))
    with d.client() as c:
        x, y = c.axis("x"), c.axis("y")
        with pytest.raises(idm.DeviceFault) as e:
            y.move_by(5e-6)
        assert e.value.code == 102 and e.value.command == "AXIS2:MOVE:RELative 5e-06"
        assert y.status().state == "FAULT" and x.status().state == "IDLE"
        assert x.move_by(5e-6) == pytest.approx(5e-6, abs=2 * COUNT)
        with pytest.raises(idm.DeviceFault, match="RST"):
            y.move_by(5e-6)
        c.reset()
        assert y.status().state == "IDLE"


def test_untrusted_position_of_a_lost_device(make_idmd, tmp_dir):
    """A position that cannot be trusted after start: axis y on a Modbus device
    (tools/idm-simdev) that goes away. POS? answers 9.91E37 with -230 (raised, never a number),
    POSition:ALL? every position with 9.91E37 for y (raised, or NaN with allow_untrusted);
    back once the device is."""
    simdev = SimDev(tmp_dir)
    try:
        d = make_idmd(config=lambda tmp: axes_config(tmp, modbus=("y", simdev.port)))
        with d.client() as c:
            x, y = c.axis("x"), c.axis("y")
            assert y.move_by(5e-6) == pytest.approx(5e-6, abs=20e-9)
            assert y.status().device == "up"
            simdev.stop()
            wait_for("device lost", lambda: y.status().device == "lost")
            with pytest.raises(idm.ExecutionError) as e:
                y.position()
            assert e.value.code == -230 and e.value.reply == "9.91E37"
            assert e.value.command == "AXIS2:POSition?"
            px = x.position()
            with pytest.raises(idm.ExecutionError) as e:
                c.positions()
            assert e.value.code == -230
            reply = e.value.reply.split(",")
            assert len(reply) == 2 and reply[1] == "9.91E37"
            assert float(reply[0]) == pytest.approx(px, abs=3 * COUNT)
            both = c.positions(allow_untrusted=True)
            assert both[0] == pytest.approx(px, abs=3 * COUNT) and math.isnan(both[1])
            st = y.status()
            assert st.position_valid is False and math.isnan(st.position)
            assert st.device == "lost" and "lost" in st.daemon_error
            # the movable cannot read y either: the -230 is raised, not a stale value
            with pytest.raises(idm.ExecutionError):
                y.movable().read()
            simdev.start()
            wait_for("device back", lambda: y.status().device == "up" and
                     y.status().position_valid, 60)
            assert math.isfinite(y.position())
            assert all(math.isfinite(p) for p in c.positions())
            c.reset()  # the loss left the axis in FAULT (device_lost)
            p = y.position()
            assert y.move_by(1e-6) == pytest.approx(p + 1e-6, abs=20e-9)
    finally:
        simdev.stop()
