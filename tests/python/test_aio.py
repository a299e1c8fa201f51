"""idm.aio.AsyncClient against a real idmd on the simulated stage, over TCP and the Unix
socket."""
import asyncio

import pytest

import idm
import idm.aio
from conftest import TRAVEL, stalled_config

COUNT = 632.991e-9 / 64


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 120))


@pytest.mark.parametrize("transport", ["tcp", "unix"])
def test_move_over_both_transports(idmd, transport):
    async def main():
        kw = {"unix": idmd.unix} if transport == "unix" else {"port": idmd.port}
        async with idm.aio.AsyncClient(**kw) as c:
            assert (await c.idn()).split(",")[1] == "idmd"
            x = c.axis(1)
            p0 = await x.position()
            arrived = await x.move(p0 + 4e-6)
            assert arrived == pytest.approx(p0 + 4e-6, abs=2 * COUNT)
            arrived = await x.move_by(-1e-6)
            assert arrived == pytest.approx(p0 + 3e-6, abs=3 * COUNT)
            st = await x.status()
            assert st.state == "IDLE" and st.done
            assert await x.limits() == TRAVEL
        assert c.closed
        with pytest.raises(idm.IdmConnectionError):
            await c.idn()
    run(main())


def test_no_address_given_asks_the_environment(idmd, monkeypatch):
    monkeypatch.delenv("IDMD_ADDRESS", raising=False)
    monkeypatch.setenv("IDMD_SOCKET", idmd.unix)

    async def main():
        async with idm.aio.AsyncClient() as c:
            assert c.address == "unix:" + idmd.unix
            assert (await c.idn()).split(",")[1] == "idmd"
        monkeypatch.delenv("IDMD_SOCKET")
        monkeypatch.setenv("IDMD_ADDRESS", "127.0.0.1:%d" % idmd.port)
        c = await idm.aio.connect()
        try:
            assert c.address == "127.0.0.1:%d" % idmd.port
            await c.idn()
        finally:
            await c.close()
    run(main())


def test_errors_are_raised_with_code_and_text(idmd):
    async def main():
        c = await idm.aio.connect("127.0.0.1", idmd.port)
        try:
            x = c.axis(1)
            with pytest.raises(idm.ExecutionError) as e:
                await x.move(1.0)
            assert e.value.code == -222 and "soft limits" in e.value.text
            with pytest.raises(idm.CommandError) as e:
                await c.write("FROBNICATE")
            assert e.value.code == -113
            assert await c.query("SYST:ERR?") == '0,"No error"'
        finally:
            await c.close()
    run(main())


def test_fault_raises_device_fault(make_idmd):
    d = make_idmd(stalled_config())

    async def main():
        async with idm.aio.AsyncClient(unix=d.unix) as c:
            with pytest.raises(idm.DeviceFault) as e:
                await c.axis(1).move_by(5e-6)
            assert e.value.code == 102
    run(main())


def test_tasks_share_a_client_and_stop_from_another_task(idmd):
    async def main():
        async with idm.aio.AsyncClient(port=idmd.port) as c:
            x = c.axis(1)
            await x.move(0)
            mover = asyncio.ensure_future(x.move(4e-3))
            while await x.done():  # until the move shows
                await asyncio.sleep(0.005)
            readings = await asyncio.gather(*[x.position() for _ in range(10)])
            assert all(isinstance(r, float) for r in readings)
            await x.stop()
            with pytest.raises(idm.MoveError) as e:  # the move's wait ends at rest: STOPPED
                await mover
            assert e.value.result == "STOPPED" and abs(e.value.distance) > 1e-4
            assert abs(await x.position() - 4e-3) > 1e-4
            assert await x.done()
    run(main())


def test_jog_and_the_speed_limit(idmd):
    async def main():
        async with idm.aio.AsyncClient(port=idmd.port) as c:
            x = c.axis(1)
            p0 = await x.move(0)  # well inside the travel, wherever an earlier test left it
            await x.set_limits(p0 - 0.2e-3, p0 + 0.2e-3)
            await x.set_velocity(5e-4)
            try:
                assert await x.velocity() == 5e-4
                arrived = await x.jog("-", wait=True)
                window = await x.window()
                assert p0 - 0.2e-3 <= arrived <= p0 - 0.2e-3 + 2 * window + COUNT
                assert (await x.result()).word == "OK"
                assert await x.jog("POSITIVE") is None
                while await x.position() < arrived + 20e-6:
                    await asyncio.sleep(0.01)
                await x.stop()
                assert await x.wait(10)
                assert (await x.result()).word == "STOPPED"
            finally:
                await x.set_velocity(0)
                await x.set_limits(*TRAVEL)
    run(main())


def test_wait_timeout_and_opc(idmd):
    async def main():
        async with idm.aio.AsyncClient(port=idmd.port) as c:
            x = c.axis(1)
            await x.move(TRAVEL[0] + 1e-4)
            with pytest.raises(idm.IdmTimeout, match="stopped"):
                await x.move(TRAVEL[1] - 1e-4, timeout=0.05)
            assert await x.done()
            await x.move(0, wait=False)
            assert await c.wait(timeout=30) is True
            assert await x.position() == pytest.approx(0, abs=2 * COUNT)
    run(main())


def test_reply_timeout_and_cancellation_close_the_connection(silent_server):
    async def main():
        c = await idm.aio.connect("127.0.0.1", silent_server.port, timeout=0.2)
        with pytest.raises(idm.IdmTimeout):
            await c.idn()
        assert c.closed
        c = await idm.aio.connect("127.0.0.1", silent_server.port, timeout=30)
        task = asyncio.ensure_future(c.idn())
        await asyncio.sleep(0.05)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert c.closed
    run(main())


def test_two_axes_move_together_and_a_missing_axis_is_114(idmd_xy):
    """The two-axis idmd (conftest.axes_config): moves on x and y awaited together, by name,
    POSition:ALL?, AXIS2:STOP leaving x alone, -114 for axis 3."""
    async def main():
        async with idm.aio.AsyncClient(unix=idmd_xy.unix) as c:
            assert await c.axis_names() == {1: "x", 2: "y"}
            x, y = c.axis("x"), c.axis("y")
            await asyncio.gather(x.move(0), y.move(0))
            px, py = await asyncio.gather(x.move(-2e-5), y.move(3e-5))
            assert px == pytest.approx(-2e-5, abs=2 * COUNT)
            assert py == pytest.approx(3e-5, abs=2 * COUNT)
            assert await c.positions() == pytest.approx([-2e-5, 3e-5], abs=2 * COUNT)
            with pytest.raises(idm.CommandError) as e:
                await c.axis(3).move(1e-6)
            assert e.value.code == -114 and e.value.command == "AXIS3:MOVE:ABSolute 1e-06"
            # y stopped short of a far target, x goes on to its own
            far_x = asyncio.ensure_future(x.move(2e-3))
            far_y = asyncio.ensure_future(y.move(-3e-3))
            while await y.done():  # until y's move shows
                await asyncio.sleep(0.005)
            await y.stop()
            with pytest.raises(idm.MoveError) as e:
                await far_y
            assert e.value.result == "STOPPED" and abs(await y.position() + 3e-3) > 1e-4
            assert await far_x == pytest.approx(2e-3, abs=2 * COUNT)
            await asyncio.gather(x.move(0), y.move(0))
    run(main())
