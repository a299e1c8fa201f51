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
from typing import Any, List, Optional, Tuple

from ._core import Line, Plan, Session, Sleep
from .client import DEFAULT_PORT, _MAX_DRAIN, _Api
from .errors import (IdmConnectionError, IdmTimeout, ProtocolError, error_from_code,
                     parse_error_line)

__all__ = ["AsyncClient", "connect"]


class AsyncClient(_Api):
    """An asyncio connection to idmd. Open it with ``await client.connect()`` or
    ``async with AsyncClient(...) as client``; ``timeout``, ``wait_timeout`` and
    ``poll_interval`` as for :class:`idm.Client`. Tasks may share it (one line and its error
    drain at a time). A task cancelled while it waits for a reply closes the connection (the
    late reply would otherwise be taken for the next one's)."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *,
                 unix: Optional[str] = None, timeout: float = 5.0,
                 wait_timeout: Optional[float] = 60.0, poll_interval: float = 0.01):
        if timeout is None or not timeout > 0:
            raise ValueError("timeout must be a positive number of seconds, not %r" % (timeout,))
        self.host = host
        self.port = port
        self.unix = unix
        self.timeout = float(timeout)
        self.wait_timeout = wait_timeout
        self.poll_interval = poll_interval
        self._session = Session()
        self._lock: Optional[asyncio.Lock] = None
        self._reader: Optional[asyncio.StreamReader] = None
        self._writer: Optional[asyncio.StreamWriter] = None
        self._closed_why = "not connected (await connect())"

    @property
    def address(self) -> str:
        return ("unix:" + self.unix) if self.unix else "%s:%d" % (self.host, self.port)

    async def connect(self) -> "AsyncClient":
        await self._close_transport()
        try:
            if self.unix:
                opening = asyncio.open_unix_connection(self.unix, limit=1 << 20)
            else:
                opening = asyncio.open_connection(self.host, self.port, limit=1 << 20)
            self._reader, self._writer = await asyncio.wait_for(opening, self.timeout)
        except asyncio.TimeoutError:
            raise IdmTimeout("cannot connect to idmd at %s within %g s"
                             % (self.address, self.timeout)) from None
        except OSError as e:
            raise IdmConnectionError("cannot connect to idmd at %s: %s"
                                     % (self.address, e.strerror or e)) from None
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
        try:
            op = next(plan)
        except StopIteration as stop:
            return stop.value
        while True:
            try:
                if isinstance(op, Sleep):
                    await asyncio.sleep(op.seconds)
                    result = None
                else:
                    result = await self._transact(op)
            except Exception as exc:
                try:
                    op = plan.throw(exc)
                except StopIteration as stop:
                    return stop.value
                continue
            try:
                op = plan.send(result)
            except StopIteration as stop:
                return stop.value

    async def _transact(self, line: Line) -> Optional[str]:
        if self._lock is None or self._writer is None:
            raise IdmConnectionError("the connection to idmd at %s is %s"
                                     % (self.address, self._closed_why))
        async with self._lock:
            if self._writer is None:
                raise IdmConnectionError("the connection to idmd at %s is %s"
                                         % (self.address, self._closed_why))
            try:
                timeout = self.timeout if line.timeout is None else max(line.timeout,
                                                                        self.timeout)
                await self._send(line.text + "\nSYSTem:ERRor?\n", line.text)
                reply = await self._read_line(timeout, line.text) if line.query else None
                errors: List[Tuple[int, str]] = []
                code, text = parse_error_line(await self._read_line(self.timeout, line.text))
                while code != 0:
                    errors.append((code, text))
                    if len(errors) > _MAX_DRAIN:
                        self._fail("the error queue does not empty")
                        raise ProtocolError("more than %d errors queued after %r"
                                            % (_MAX_DRAIN, line.text))
                    await self._send("SYSTem:ERRor?\n", line.text)
                    code, text = parse_error_line(await self._read_line(self.timeout, line.text))
            except asyncio.CancelledError:
                self._fail("cancelled while waiting for the reply to %r" % line.text)
                raise
            if errors:  # noted under the lock: a waiting task must see a fault
                error = error_from_code(errors[0][0], errors[0][1], line.text, errors, reply)
                self._session.note_errors(error)
                raise error
        if line.query and reply == "":
            raise ProtocolError("%r got an empty reply with no error queued" % line.text)
        return reply

    async def _send(self, data: str, what: str) -> None:
        assert self._writer is not None
        try:
            self._writer.write(data.encode("utf-8"))
            await asyncio.wait_for(self._writer.drain(), self.timeout)
        except asyncio.TimeoutError:
            self._fail("a send timed out")
            raise IdmTimeout("cannot send %r to idmd at %s within %g s"
                             % (what, self.address, self.timeout)) from None
        except OSError as e:
            self._fail("send failed: %s" % (e.strerror or e))
            raise IdmConnectionError("lost the connection to idmd at %s sending %r: %s"
                                     % (self.address, what, e.strerror or e)) from None

    async def _read_line(self, timeout: float, what: str) -> str:
        assert self._reader is not None
        try:
            raw = await asyncio.wait_for(self._reader.readline(), timeout)
        except asyncio.TimeoutError:
            self._fail("no reply to %r within %g s" % (what, timeout))
            raise IdmTimeout("no reply to %r from idmd at %s within %g s; the connection was "
                             "closed (a late reply would be taken for the next one's)"
                             % (what, self.address, timeout)) from None
        except (OSError, ValueError) as e:
            self._fail("receive failed: %s" % e)
            raise IdmConnectionError("lost the connection to idmd at %s waiting for the reply "
                                     "to %r: %s" % (self.address, what, e)) from None
        if not raw.endswith(b"\n"):
            self._fail("idmd closed it")
            raise IdmConnectionError("idmd at %s closed the connection (waiting for the reply "
                                     "to %r)" % (self.address, what))
        return raw[:-1].rstrip(b"\r").decode("utf-8", "replace")


async def connect(host: str = "127.0.0.1", port: int = DEFAULT_PORT, **kwargs: Any) -> AsyncClient:
    """``await idm.aio.connect(...)``: an open :class:`AsyncClient`."""
    return await AsyncClient(host, port, **kwargs).connect()
