"""The synchronous client: ``idm.Client`` over TCP or idmd's Unix socket, and its axes."""

from __future__ import annotations

import socket
import threading
import time
from typing import Any, Generator, List, NamedTuple, Optional, Tuple

from . import _core, _sweep
from ._core import AxisKey, Line, Plan, Session, Sleep
from .address import DEFAULT_HOST, DEFAULT_PORT, address_from_environment
from .axis import Axis, Sweep
from .errors import (IdmConnectionError, IdmTimeout, ProtocolError, error_from_code,
                     parse_error_line)
from .status import EventStatus, StatusByte

__all__ = ["Client", "Axis", "Sweep", "DEFAULT_PORT"]

# A daemon's queue holds 32 errors (then -350): more than this many in one drain is a broken peer.
_MAX_DRAIN = 64


class _Send(NamedTuple):
    data: str
    what: str  # the line it is for, in error messages


class _Read(NamedTuple):
    seconds: float
    what: str


class _Fail(NamedTuple):
    why: str


def _exchange(line: Line, timeout: float, session: Session) -> Generator[Any, Any, Optional[str]]:
    """One line's exchange with idmd, the same for both clients: the line and ``SYSTem:ERRor?``
    in one write, the reply (a query), the error queue drained; the first queued error raised
    (and noted in the session: a waiter elsewhere must see a fault). A generator of the I/O it
    needs (:class:`_Send`, :class:`_Read` answered with the line read, :class:`_Fail` to
    close the connection); returns the reply."""
    reply_timeout = timeout if line.timeout is None else max(line.timeout, timeout)
    yield _Send(line.text + "\nSYSTem:ERRor?\n", line.text)
    reply = (yield _Read(reply_timeout, line.text)) if line.query else None
    errors: List[Tuple[int, str]] = []
    code, text = parse_error_line((yield _Read(timeout, line.text)))
    while code != 0:
        errors.append((code, text))
        if len(errors) > _MAX_DRAIN:
            yield _Fail("the error queue does not empty")
            raise ProtocolError("more than %d errors queued after %r" % (_MAX_DRAIN, line.text))
        yield _Send("SYSTem:ERRor?\n", line.text)
        code, text = parse_error_line((yield _Read(timeout, line.text)))
    if errors:
        error = error_from_code(errors[0][0], errors[0][1], line.text, errors, reply)
        session.note_errors(error)
        raise error
    if line.query and reply == "":
        raise ProtocolError("%r got an empty reply with no error queued" % line.text)
    return reply


class _Api:
    """The operations of a client, shared by :class:`Client` (they return the result) and
    :class:`idm.aio.AsyncClient` (they return an awaitable of it), and what both clients do
    alike around their I/O: the settings, the address, the errors of a failed connection."""

    _session: Session
    host: str
    port: int
    unix: Optional[str]
    timeout: float
    wait_timeout: Optional[float]
    poll_interval: float

    def _run(self, plan: Plan) -> Any:  # pragma: no cover - defined by the clients
        raise NotImplementedError

    def _fail(self, why: str) -> None:  # pragma: no cover - defined by the clients
        raise NotImplementedError

    def _settings(self, host: Optional[str], port: Optional[int], unix: Optional[str],
                  timeout: float, wait_timeout: Optional[float], poll_interval: float) -> None:
        if timeout is None or not timeout > 0:
            raise ValueError("timeout must be a positive number of seconds, not %r" % (timeout,))
        if host is None and port is None and unix is None:
            # No address given: IDMD_SOCKET, else IDMD_ADDRESS, else 127.0.0.1:5025.
            host, port, unix = address_from_environment()
        host = DEFAULT_HOST if host is None else host
        port = DEFAULT_PORT if port is None else port
        self.host = host
        self.port = port
        self.unix = unix
        self.timeout = float(timeout)
        self.wait_timeout = wait_timeout
        self.poll_interval = poll_interval
        self._session = Session()

    @property
    def address(self) -> str:
        return ("unix:" + self.unix) if self.unix else "%s:%d" % (self.host, self.port)

    # The errors of the I/O (each closes the connection first where it is broken).
    def _connect_timed_out(self) -> IdmTimeout:
        return IdmTimeout("cannot connect to idmd at %s within %g s" % (self.address, self.timeout))

    def _connect_failed(self, e: OSError) -> IdmConnectionError:
        return IdmConnectionError("cannot connect to idmd at %s: %s"
                                  % (self.address, e.strerror or e))

    def _not_open(self, why: str) -> IdmConnectionError:
        return IdmConnectionError("the connection to idmd at %s is %s" % (self.address, why))

    def _send_timed_out(self, what: str) -> IdmTimeout:
        self._fail("a send timed out")
        return IdmTimeout("cannot send %r to idmd at %s within %g s"
                          % (what, self.address, self.timeout))

    def _send_failed(self, what: str, e: Any) -> IdmConnectionError:
        reason = getattr(e, "strerror", None) or e
        self._fail("send failed: %s" % reason)
        return IdmConnectionError("lost the connection to idmd at %s sending %r: %s"
                                  % (self.address, what, reason))

    def _no_reply(self, what: str, timeout: float) -> IdmTimeout:
        self._fail("no reply to %r within %g s" % (what, timeout))
        return IdmTimeout("no reply to %r from idmd at %s within %g s; the connection was "
                          "closed (a late reply would be taken for the next one's)"
                          % (what, self.address, timeout))

    def _receive_failed(self, what: str, e: Any) -> IdmConnectionError:
        reason = getattr(e, "strerror", None) or e
        self._fail("receive failed: %s" % reason)
        return IdmConnectionError("lost the connection to idmd at %s waiting for the reply to "
                                  "%r: %s" % (self.address, what, reason))

    def _peer_closed(self, what: str) -> IdmConnectionError:
        self._fail("idmd closed it")
        return IdmConnectionError("idmd at %s closed the connection (waiting for the reply to "
                                  "%r)" % (self.address, what))

    # -- axes --
    def axis(self, key: AxisKey = 1) -> "Axis":
        """Axis ``key``: a number from 1, or a name (resolved with ``AXIS:COUNt?`` and
        ``AXIS<n>:NAME?`` at its first use; a daemon without them raises its -113)."""
        return Axis(self, key)

    def axis_count(self):
        """``AXIS:COUNt?``: the number of axes."""
        return self._run(_core.p_axis_count(self._session))

    def axis_names(self):
        """``{number: name}`` of every axis (``AXIS:COUNt?``, ``AXIS<n>:NAME?``)."""
        return self._run(_core.p_axis_names(self._session))

    def positions(self, *, allow_untrusted: bool = False):
        """``POSition:ALL?``: every axis's position (m), read at one instant, in axis order.
        A position the daemon cannot trust (no valid reading, beam or device lost) comes as
        ``9.91E37`` with -230 queued: that is raised as :class:`~idm.ExecutionError` (code
        -230, the whole reply in ``.reply``); with ``allow_untrusted`` the list is returned
        with NaN for each untrusted position instead."""
        return self._run(_core.p_positions(self._session, allow_untrusted))

    def sweep_state(self):
        """``SWEEP?``: the daemon's last or running sweep (:class:`~idm.SweepState`: state,
        axis, trials written / failed / planned, directory)."""
        return self._run(_sweep.p_sweep_query())

    # -- the instrument --
    def idn(self):
        """``*IDN?``: ``<maker>,idmd,<serial>,<version>``."""
        return self._run(_core.p_line("*IDN?"))

    def reset(self, *, wait: bool = True, timeout: Optional[float] = None):
        """``*RST`` (stop motion, clear errors, reload control settings), then, with ``wait``,
        ``*OPC?`` until it has completed."""
        return self._run(_core.p_reset(wait, self.wait_timeout if timeout is None else timeout))

    def clear(self):
        """``*CLS``: clear the error queue."""
        return self._run(_core.p_line("*CLS"))

    def stop(self):
        """``STOP``: every axis brought to rest, output to zero (and a running sweep
        stopped)."""
        return self._run(_core.p_line("STOP"))

    def wait(self, timeout: Optional[float] = None):
        """``*OPC?``: until every motion started before has finished (at most ``timeout``,
        default ``wait_timeout``). On a timeout the connection is closed (its late reply
        would otherwise be taken for the next one's)."""
        return self._run(_core.p_opc(self.wait_timeout if timeout is None else timeout))

    def self_test(self):
        """``*TST?``: 0 with a valid position and no fault."""
        return self._run(_core.p_int("*TST?"))

    def status_byte(self):
        """``*STB?`` as :class:`~idm.StatusByte`."""
        return self._run(_core.p_register("*STB?", StatusByte))

    def event_status(self):
        """``*ESR?`` as :class:`~idm.EventStatus` (reading clears it)."""
        return self._run(_core.p_register("*ESR?", EventStatus))

    def version(self):
        """``SYSTem:VERSion?`` (the SCPI version)."""
        return self._run(_core.p_line("SYSTem:VERSion?"))

    def loop_stats(self):
        """``SYSTem:LOOP?``: the real-time loop's period and latency, parsed."""
        return self._run(_core.p_loop_stats())

    def clients(self):
        """``SYSTem:CLIents?``: connections open to the daemon now, this one included."""
        return self._run(_core.p_int("SYSTem:CLIents?"))

    def query(self, line: str, timeout: Optional[float] = None):
        """Send one query line, return its reply; a queued error is raised."""
        if not _core.is_query(line):
            raise ValueError("%r is not a query (its first word does not end in '?')" % line)
        return self._run(_core.p_line(line, timeout))

    def write(self, line: str):
        """Send one command line; a queued error is raised."""
        if _core.is_query(line):
            raise ValueError("%r is a query: use query()" % line)
        return self._run(_core.p_line(line))


class Client(_Api):
    """A synchronous connection to idmd.

    ``Client(unix="/run/idmd/idmd.sock")`` connects to the Unix socket, ``Client("host", 5025)``
    (or either of host and port alone, the other one's default 127.0.0.1 / 5025) over TCP;
    ``Client()`` with no address asks the environment, as idmctl, idm-web and idm-tango do:
    ``IDMD_SOCKET=path``, else ``IDMD_ADDRESS=host:port``, else TCP 127.0.0.1:5025 (both set, or
    an address that does not parse, is a ValueError naming the variable). ``timeout`` bounds
    every reply (s); ``wait_timeout`` is the default bound of the waits for motion (moves,
    steps, reference, ``wait()``); ``poll_interval`` the ``MOVE:DONE?`` polling period. After
    each line the error queue is drained (``SYSTem:ERRor?`` until ``0``) and a queued error is
    raised as :class:`~idm.ScpiError`. Safe to share between threads (one line and its drain at
    a time). A context manager: ``with idm.Client() as c: ...`` closes the connection at the
    end."""

    def __init__(self, host: Optional[str] = None, port: Optional[int] = None, *,
                 unix: Optional[str] = None, timeout: float = 5.0,
                 wait_timeout: Optional[float] = 60.0, poll_interval: float = 0.01):
        self._settings(host, port, unix, timeout, wait_timeout, poll_interval)
        self._lock = threading.RLock()
        self._sock: Optional[socket.socket] = None
        self._buf = b""
        self._closed_why: Optional[str] = None
        self.connect()

    def connect(self) -> None:
        """(Re)connect; a client closed after a timeout can be reconnected this way."""
        with self._lock:
            self._drop()
            try:
                if self.unix:
                    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                    s.settimeout(self.timeout)
                    try:
                        s.connect(self.unix)
                    except BaseException:
                        s.close()
                        raise
                else:
                    s = socket.create_connection((self.host, self.port), timeout=self.timeout)
                    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except socket.timeout:
                raise self._connect_timed_out() from None
            except OSError as e:
                raise self._connect_failed(e) from None
            self._sock = s
            self._buf = b""
            self._closed_why = None
            self._session = Session()

    def _drop(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    def close(self) -> None:
        """Close the connection (idempotent). Motion started goes on: the daemon owns it."""
        sock = self._sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)  # wakes a thread blocked in a read
            except OSError:
                pass
        with self._lock:
            self._drop()
            self._closed_why = "closed"

    @property
    def closed(self) -> bool:
        return self._sock is None

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            if self._sock is not None:
                self._sock.close()
        except Exception:
            pass

    def __repr__(self) -> str:
        return "Client(%s%s)" % (self.address, ", closed" if self.closed else "")

    # -- running plans --
    def _run(self, plan: Plan) -> Any:
        return _core.run_plan(plan, self._perform)

    def _perform(self, op: Any) -> Any:
        if isinstance(op, Sleep):
            time.sleep(op.seconds)
            return None
        return self._transact(op)

    def _transact(self, line: Line) -> Optional[str]:
        with self._lock:
            if self._sock is None:
                raise self._not_open(self._closed_why or "closed")
            exchange = _exchange(line, self.timeout, self._session)
            result: Any = None
            try:
                while True:
                    result = self._io(exchange.send(result))
            except StopIteration as done:
                return done.value

    def _io(self, request: Any) -> Optional[str]:
        if isinstance(request, _Send):
            self._send(request.data, request.what)
            return None
        if isinstance(request, _Read):
            return self._read_line(request.seconds, request.what)
        self._fail(request.why)
        return None

    def _fail(self, why: str) -> None:
        self._drop()
        self._closed_why = "closed (%s)" % why

    def _send(self, data: str, what: str) -> None:
        assert self._sock is not None
        try:
            self._sock.settimeout(self.timeout)
            self._sock.sendall(data.encode("utf-8"))
        except socket.timeout:
            raise self._send_timed_out(what) from None
        except OSError as e:
            raise self._send_failed(what, e) from None

    def _read_line(self, timeout: float, what: str) -> str:
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or self._sock is None:
                raise self._no_reply(what, timeout)
            try:
                self._sock.settimeout(left)
                chunk = self._sock.recv(65536)
            except socket.timeout:
                continue
            except OSError as e:
                raise self._receive_failed(what, e) from None
            if not chunk:
                raise self._peer_closed(what)
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\n", 1)
        return raw.rstrip(b"\r").decode("utf-8", "replace")
