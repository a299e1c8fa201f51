"""The Bluesky-style movable (idm.bluesky.AxisMovable) against a real idmd: the bluesky
protocols' contract (Movable, Readable, Configurable, Locatable, Stoppable, Status) checked the
way a RunEngine uses it, by duck typing (bluesky is not packaged here)."""
import asyncio
import threading
import time

import pytest

import idm
import idm.aio
from idm.bluesky import AxisMovable, MoveStatus, StatusTimeout
from conftest import TRAVEL, axes_config, stalled_config

COUNT = 632.991e-9 / 64


def run_plan_step(status, timeout=60):
    """Wait for a status the way the RunEngine does: a callback from any thread, then
    success/exception() (bluesky's RunEngine._wait_for / _status_object_completed)."""
    fired = threading.Event()
    seen = []

    def done(st):
        seen.append(st)
        fired.set()
    status.add_callback(done)
    assert fired.wait(timeout), "the status never called back"
    assert seen == [status]
    return status.success, status.exception()


def check_data_keys(reading, description):
    """The event model's shape: the same keys; value + timestamp; source, dtype, shape."""
    assert set(reading) == set(description)
    for key, r in reading.items():
        assert set(r) >= {"value", "timestamp"}
        assert isinstance(r["timestamp"], float) and abs(r["timestamp"] - time.time()) < 60
        d = description[key]
        assert {"source", "dtype", "shape"} <= set(d)
        assert d["dtype"] == "number" and d["shape"] == [] and d["units"] == "m"
        assert isinstance(r["value"], float)


def test_set_wait_read_describe_locate(client):
    m = client.axis(1).movable("x")
    assert m.name == "x" and m.parent is None and m.hints == {"fields": ["x"]}
    p0 = m.read()["x"]["value"]
    status = m.set(p0 + 5e-6)
    assert isinstance(status, MoveStatus)
    success, exc = run_plan_step(status)
    assert success is True and exc is None
    assert status.done and status.success
    status.wait(1)  # already done: returns, raises nothing
    reading = m.read()
    check_data_keys(reading, m.describe())
    assert reading["x"]["value"] == pytest.approx(p0 + 5e-6, abs=2 * COUNT)
    assert reading["x_setpoint"]["value"] == pytest.approx(p0 + 5e-6, rel=1e-11)
    conf = m.read_configuration()
    assert set(conf) == set(m.describe_configuration())
    assert (conf["x_lower_limit"]["value"], conf["x_upper_limit"]["value"]) == TRAVEL
    loc = m.locate()
    assert set(loc) == {"setpoint", "readback"}
    assert loc["readback"] == pytest.approx(p0 + 5e-6, abs=2 * COUNT)
    assert loc["setpoint"] == pytest.approx(p0 + 5e-6, rel=1e-11)
    # A callback added after the end is called at once.
    late = []
    status.add_callback(late.append)
    assert late == [status]


def test_default_name_is_the_axis(client):
    assert client.axis(1).movable().name == "x"  # AXIS1:NAME? (config/idmd.yaml's axis x)
    assert client.axis("x").movable().name == "x"


def test_movable_on_axis_two(client_xy):
    """The movable of axis 2 of the two-axis idmd: set()/wait(), read, locate and stop act on
    y (AXIS2:...), and x is left alone."""
    x = client_xy.axis(1)
    m = client_xy.axis(2).movable()
    assert m.name == "y" and m.hints == {"fields": ["y"]}
    px = x.move(1e-5)
    success, exc = run_plan_step(m.set(-7e-6))
    assert success is True and exc is None
    reading = m.read()
    check_data_keys(reading, m.describe())
    assert reading["y"]["value"] == pytest.approx(-7e-6, abs=2 * COUNT)
    assert reading["y_setpoint"]["value"] == pytest.approx(-7e-6, rel=1e-11)
    assert m.locate()["readback"] == pytest.approx(-7e-6, abs=2 * COUNT)
    assert x.position() == pytest.approx(px, abs=3 * COUNT)
    # stop() stops y (AXIS2:STOP) while x's own move goes on to its target.
    x.move(-3e-3, wait=False)
    status = m.set(-4e-3)
    m.stop(success=False)
    success, exc = run_plan_step(status)
    assert success is False and isinstance(exc, idm.MoveStopped)
    assert abs(m.position + 4e-3) > 1e-4
    assert x.wait(60) and x.position() == pytest.approx(-3e-3, abs=2 * COUNT)
    # A refusal by y's own soft limits, not x's.
    client_xy.axis(2).set_limits(-1e-3, 1e-3)
    conf = m.read_configuration()
    assert (conf["y_lower_limit"]["value"], conf["y_upper_limit"]["value"]) == (-1e-3, 1e-3)
    refused = m.set(2e-3)
    assert refused.done and not refused.success and refused.exception().code == -222
    assert refused.exception().command == "AXIS2:MOVE:ABSolute 0.002"
    assert x.movable().set(2e-3).wait(60) is None  # x's limits are the travel still


def test_movable_on_a_faulty_second_axis(make_idmd):
    d = make_idmd(config=lambda tmp: axes_config(tmp, stalled=("y",)))
    with d.client() as c:
        m = c.axis("y").movable()
        success, exc = run_plan_step(m.set(5e-6))
        assert success is False
        assert isinstance(exc, idm.DeviceFault) and exc.code == 102
        assert exc.command == "AXIS2:MOVE:ABSolute 5e-06"
        # x is unaffected: its movable moves
        success, exc = run_plan_step(c.axis("x").movable().set(5e-6))
        assert success is True, exc


def test_refused_move_fails_the_status_with_the_daemons_error(client):
    x = client.axis(1)
    x.set_limits(-1e-3, 1e-3)
    m = x.movable("x")
    status = m.set(2e-3)
    assert status.done  # refused at once
    success, exc = run_plan_step(status)
    assert success is False
    assert isinstance(exc, idm.ExecutionError) and exc.code == -222
    with pytest.raises(idm.ExecutionError, match="-222"):
        status.wait(1)
    with pytest.raises(idm.ExecutionError):
        m.move(2e-3)  # ophyd-style move(): raises


def test_fault_fails_the_status(make_idmd):
    d = make_idmd(stalled_config())
    with d.client() as c:
        m = c.axis(1).movable("x")
        status = m.set(5e-6)
        success, exc = run_plan_step(status)
        assert success is False
        assert isinstance(exc, idm.DeviceFault) and exc.code == 102
        with pytest.raises(idm.DeviceFault):
            status.wait(1)
        assert c.axis(1).status().state == "FAULT"
        # In FAULT the next set is refused with the fault's code, at once.
        again = m.set(1e-6)
        assert again.done and not again.success and again.exception().code == 102


def test_stop_success_false_fails_the_pending_status(client):
    x = client.axis(1)
    x.move(0)
    m = x.movable("x")
    status = m.set(4e-3)
    m.stop(success=False)
    success, exc = run_plan_step(status)
    assert success is False and isinstance(exc, idm.MoveStopped)
    assert x.done() and abs(x.position() - 4e-3) > 1e-4


def test_stop_success_true_marks_it_done(client):
    x = client.axis(1)
    x.move(0)
    m = x.movable("x")
    status = m.set(4e-3)
    m.stop()  # the protocol's default: success=True
    success, exc = run_plan_step(status)
    assert success is True and exc is None
    assert x.done()


def test_move_stopped_by_another_client_is_not_a_success(client, idmd):
    x = client.axis(1)
    x.move(0)
    m = x.movable("x")
    status = m.set(4e-3)
    with idmd.client() as other:
        other.stop()
    success, exc = run_plan_step(status)
    assert success is False
    # MOVE:RESult? where the daemon answers it (or its queued error); else the movable's
    # tolerance check against MOVE?.
    assert isinstance(exc, (idm.MoveError, idm.ScpiError))


def test_set_timeout_stops_the_axis_and_fails(client):
    x = client.axis(1)
    x.move(TRAVEL[0] + 1e-4)
    m = x.movable("x")
    # 9 mm on the simulated stage (wall clock) takes seconds: a 0.05 s bound must expire.
    status = m.set(TRAVEL[1] - 1e-4, timeout=0.05)
    success, exc = run_plan_step(status)
    assert success is False and isinstance(exc, idm.IdmTimeout)
    assert x.done() and x.position() < TRAVEL[1] - 1e-3


def test_set_while_moving_is_refused_and_the_first_move_still_completes(client):
    x = client.axis(1)
    x.move(0)
    m = x.movable("x")
    first = m.set(1e-3)
    second = m.set(-1e-3)
    # idmd refuses a move while one is in progress (-221): the second fails, loudly.
    assert second.done and not second.success
    assert isinstance(second.exception(), idm.ExecutionError)
    assert second.exception().code == -221
    success, exc = run_plan_step(first)
    assert success is True, exc
    assert x.position() == pytest.approx(1e-3, abs=2 * COUNT)


def test_watch_reports_progress(client):
    x = client.axis(1)
    x.move(0)
    m = x.movable("x")
    calls = []
    # Hold the client's lock so that the watcher is registered before the first poll (the
    # daemon shows the motion to the first MOVE:DONE? after the move).
    with client._lock:
        status = m.set(2e-3)
        status.watch(lambda **kw: calls.append(kw))
    status.wait(60)
    assert calls, "no progress reported"
    for kw in calls:
        assert {"current", "initial", "target", "name", "unit", "fraction",
                "time_elapsed"} <= set(kw)
        assert kw["name"] == "x" and kw["target"] == 2e-3 and 0 <= kw["fraction"] <= 1


def test_a_scan_driven_like_a_runengine(client):
    """bp.scan's loop: set, wait for the status, read, check the event against describe."""
    m = client.axis(1).movable("x")
    description = m.describe()
    events = []
    for target in [0.0, 1e-6, 2e-6, 3e-6]:
        success, exc = run_plan_step(m.set(target))
        assert success, exc
        reading = m.read()
        check_data_keys(reading, description)
        events.append({"data": {k: v["value"] for k, v in reading.items()},
                       "timestamps": {k: v["timestamp"] for k, v in reading.items()}})
    for ev, target in zip(events, [0.0, 1e-6, 2e-6, 3e-6]):
        assert ev["data"]["x"] == pytest.approx(target, abs=2 * COUNT)
        assert ev["data"]["x_setpoint"] == pytest.approx(target, rel=1e-11, abs=1e-18)


def test_status_is_awaitable(client):
    x = client.axis(1)
    x.set_limits(-1e-3, 1e-3)
    m = x.movable("x")

    async def plan():
        await m.set(4e-6)
        with pytest.raises(idm.ExecutionError):
            await m.set(2e-3)
        return m.locate()
    loc = asyncio.run(plan())
    assert loc["readback"] == pytest.approx(4e-6, abs=2 * COUNT)


def test_status_wait_timeout_leaves_the_move_going(client):
    x = client.axis(1)
    x.move(0)
    m = x.movable("x")
    status = m.set(3e-3)
    with pytest.raises(StatusTimeout):
        status.wait(0.001)  # the status's wait, not the move's: the move goes on
    with pytest.raises(TimeoutError):
        status.exception(timeout=0.001)
    status.wait(60)
    assert status.success
    assert x.position() == pytest.approx(3e-3, abs=2 * COUNT)


def test_async_client_is_refused(idmd):
    async def make():
        async with idm.aio.AsyncClient("127.0.0.1", idmd.port) as c:
            with pytest.raises(TypeError):
                AxisMovable(c.axis(1))
    asyncio.run(make())


def test_fault_drained_by_another_thread_still_fails_the_status(make_idmd):
    """A RunEngine monitor or a GUI reading the same client while the move runs may take the
    fault from the daemon's queue first: the status must still fail with it."""
    d = make_idmd(stalled_config())
    with d.client() as c:
        m = c.axis(1).movable("x")
        stop = threading.Event()
        raised = []

        def reader():
            while not stop.is_set():
                try:
                    m.read()
                except idm.DeviceFault as e:
                    raised.append(e)
                time.sleep(0.001)
        t = threading.Thread(target=reader)
        t.start()
        try:
            status = m.set(5e-6)
            success, exc = run_plan_step(status)
        finally:
            stop.set()
            t.join(30)
        assert success is False
        assert isinstance(exc, idm.DeviceFault) and exc.code == 102
