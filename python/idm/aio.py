"""The asyncio client: ``idm.aio.AsyncClient`` over TCP or idmd's Unix socket.

The same operations as :class:`idm.Client` (and the same :class:`idm.Axis` objects), each a
coroutine::

    async with idm.aio.AsyncClient(unix="/run/idmd/idmd.sock") as c:
        x = c.axis(1)
        await x.move(5e-6)
        print(await x.position())
"""

from __future__ import annotations

import asyncio
from typing import Any, Optional

from ._core import Line, Plan, PlanRun, Session, Sleep
from .client import _Api, _exchange, _Read, _Send

__all__ = ["AsyncClient", "connect"]


class AsyncClient(_Api):
    """An asyncio connection to idmd. Open it with ``await client.connect()`` or ``async with
    AsyncClient(...) as client``; the address (no address: the environment's), ``timeout``,
    ``wait_timeout`` and ``poll_interval`` as for :class:`idm.Client`. Tasks may share it (one
    line and its error drain at a time). A task cancelled while it waits for a reply closes the
    connection (the late reply would otherwise be taken for the next one's)."""

    def __init__(self, host: Optional[str] = None, port: Optional[int] = None, *,
                 unix: Optional[str] = None, timeout: float = 5.0,
                 wait_timeout: Optional[float] = 60.0, poll_interval: float = 0.01):
        self._settings(host, port, unix, timeout, wait_timeout, poll_interval)
        self._lock: Optional[asyncio.Lock] = None
        self._reader: Optional[asyncio.StreamReader] = None
        self._writer: Optional[asyncio.StreamWriter] = None
        self._closed_why = "not connected (await connect())"

    async def connect(self) -> "AsyncClient":
        await self._close_transport()
        try:
            if self.unix:
                opening = asyncio.open_unix_connection(self.unix, limit=1 << 20)
            else:
                opening = asyncio.open_connection(self.host, self.port, limit=1 << 20)
            self._reader, self._writer = await asyncio.wait_for(opening, self.timeout)
        except asyncio.TimeoutError:
            raise self._connect_timed_out() from None
        except OSError as e:
            raise self._connect_failed(e) from None
        self._lock = asyncio.Lock()
        self._session = Session()
        self._closed_why = "closed"
        return self

    async def _close_transport(self) -> None:
        writer, self._writer, self._reader = self._writer, None, None
        if writer is not None:
            writer.close()
            try:
                await writer.wait_closed()
            except (OSError, asyncio.CancelledError):
                pass

    def _fail(self, why: str) -> None:
        writer, self._writer, self._reader = self._writer, None, None
        if writer is not None:
            writer.close()
        self._closed_why = "closed (%s)" % why

    async def close(self) -> None:
        """Close the connection (idempotent). Motion started goes on."""
        await self._close_transport()
        self._closed_why = "closed"

    @property
    def closed(self) -> bool:
        return self._writer is None

    async def __aenter__(self) -> "AsyncClient":
        if self._writer is None:
            await self.connect()
        return self

    async def __aexit__(self, *exc: Any) -> None:
        await self.close()

    def __repr__(self) -> str:
        return "AsyncClient(%s%s)" % (self.address, ", closed" if self.closed else "")

    # -- running plans --
    def _run(self, plan: Plan):
        return self._drive(plan)

    async def _drive(self, plan: Plan) -> Any:
        run = PlanRun(plan)
        while run.running:
            try:
                if isinstance(run.op, Sleep):
                    await asyncio.sleep(run.op.seconds)
                    result = None
                else:
                    result = await self._transact(run.op)
            except Exception as exc:
                run.throw(exc)
                continue
            run.send(result)
        return run.value

    async def _transact(self, line: Line) -> Optional[str]:
        if self._lock is None or self._writer is None:
            raise self._not_open(self._closed_why)
        async with self._lock:
            if self._writer is None:
                raise self._not_open(self._closed_why)
            exchange = _exchange(line, self.timeout, self._session)
            result: Any = None
            try:
                while True:
                    result = await self._io(exchange.send(result))
            except StopIteration as done:
                return done.value
            except asyncio.CancelledError:
                self._fail("cancelled while waiting for the reply to %r" % line.text)
                raise

    async def _io(self, request: Any) -> Optional[str]:
        if isinstance(request, _Send):
            await self._send(request.data, request.what)
            return None
        if isinstance(request, _Read):
            return await self._read_line(request.seconds, request.what)
        self._fail(request.why)
        return None

    async def _send(self, data: str, what: str) -> None:
        assert self._writer is not None
        try:
            self._writer.write(data.encode("utf-8"))
            await asyncio.wait_for(self._writer.drain(), self.timeout)
        except asyncio.TimeoutError:
            raise self._send_timed_out(what) from None
        except OSError as e:
            raise self._send_failed(what, e) from None

    async def _read_line(self, timeout: float, what: str) -> str:
        assert self._reader is not None
        try:
            raw = await asyncio.wait_for(self._reader.readline(), timeout)
        except asyncio.TimeoutError:
            raise self._no_reply(what, timeout) from None
        except (OSError, ValueError) as e:
            raise self._receive_failed(what, e) from None
        if not raw.endswith(b"\n"):
            raise self._peer_closed(what)
        return raw[:-1].rstrip(b"\r").decode("utf-8", "replace")


async def connect(host: Optional[str] = None, port: Optional[int] = None,
                  **kwargs: Any) -> AsyncClient:
    """``await idm.aio.connect(...)``: an open :class:`AsyncClient`."""
    return await AsyncClient(host, port, **kwargs).connect()
