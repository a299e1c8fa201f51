"""A Bluesky-style movable per axis, following the bluesky protocols by duck typing.

``AxisMovable`` is Movable, Readable, Configurable, Locatable and Stoppable as
``bluesky.protocols`` defines them, so a RunEngine plan (``bps.mv``, ``bp.scan``) or code
written for ophyd positioners drives it without an EPICS IOC; bluesky itself is not needed::

    import idm
    client = idm.Client(unix="/run/idmd/idmd.sock")
    x = client.axis(1).movable("x")
    status = x.set(5e-6)          # returns at once
    status.wait(10)               # raises if the move failed
    print(x.read())               # {'x': {'value': 5.0e-06, 'timestamp': ...}, ...}

A move that fails (refused: past a soft limit, busy; ended in a fault; not in position) ends
its status with ``success`` False and the exception, never as a silent success.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable, Dict, List, Optional

from . import _core
from ._core import Line
from .errors import IdmTimeout, MoveError, MoveStopped, ScpiError

__all__ = ["Status", "MoveStatus", "AxisMovable", "StatusTimeout"]

log = logging.getLogger(__name__)

# The movable's in-position check where the daemon does not answer MOVE:RESult?, m.
DEFAULT_TOLERANCE = 1e-7


class StatusTimeout(IdmTimeout):
    """``Status.wait(timeout)`` / ``exception(timeout)``: not done within the timeout (the
    operation goes on)."""


class Status:
    """The status of an operation (``bluesky.protocols.Status``): ``done``, ``success``,
    ``add_callback(cb)`` (``cb(status)`` once done, from any thread; at once if already done),
    ``exception(timeout)``, ``wait(timeout)``. Awaitable in asyncio code (``await status``)."""

    def __init__(self, timeout: Optional[float] = None, settle_time: float = 0.0):
        self.timeout = timeout
        self.settle_time = settle_time
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._exception: Optional[BaseException] = None
        self._callbacks: List[Callable[["Status"], None]] = []

    @property
    def done(self) -> bool:
        return self._event.is_set()

    @property
    def success(self) -> bool:
        """True once done without an exception (False while not done)."""
        return self._event.is_set() and self._exception is None

    def add_callback(self, callback: Callable[["Status"], None]) -> None:
        with self._lock:
            if not self._event.is_set():
                self._callbacks.append(callback)
                return
        self._call(callback)

    @property
    def callbacks(self) -> List[Callable[["Status"], None]]:
        return list(self._callbacks)

    def exception(self, timeout: Optional[float] = 0.0) -> Optional[BaseException]:
        """The exception the operation ended with, None on success; waits up to ``timeout``
        (None: forever) and raises :class:`StatusTimeout` if it is still not done."""
        if not self._event.wait(timeout):
            raise StatusTimeout("%r not done within %s s" % (self, timeout))
        return self._exception

    def wait(self, timeout: Optional[float] = None) -> None:
        """Until done (at most ``timeout`` s, None: forever); raises the operation's exception
        if it failed, :class:`StatusTimeout` if it is not done in time."""
        if not self._event.wait(timeout):
            raise StatusTimeout("%r not done within %s s" % (self, timeout))
        if self._exception is not None:
            raise self._exception

    def __await__(self):
        import asyncio
        loop = asyncio.get_running_loop()
        future = loop.create_future()

        def wake(_status: "Status") -> None:
            loop.call_soon_threadsafe(lambda: future.done() or future.set_result(None))
        self.add_callback(wake)
        yield from future.__await__()
        if self._exception is not None:
            raise self._exception

    # -- finishing (first call wins) --
    def set_finished(self) -> bool:
        return self._finish(None)

    def set_exception(self, exc: BaseException) -> bool:
        return self._finish(exc)

    def _finish(self, exc: Optional[BaseException]) -> bool:
        with self._lock:
            if self._event.is_set():
                return False
            self._exception = exc
            self._event.set()
            callbacks, self._callbacks = self._callbacks, []
        for cb in callbacks:
            self._call(cb)
        return True

    def _call(self, callback: Callable[["Status"], None]) -> None:
        try:
            callback(self)
        except Exception:  # a callback's failure must not break the status (as in ophyd)
            log.exception("status callback %r failed", callback)

    def __repr__(self) -> str:
        state = ("done, success" if self.success else "done, failed: %r" % self._exception) \
            if self.done else "pending"
        return "%s(%s)" % (type(self).__name__, state)


class MoveStatus(Status):
    """The status of ``AxisMovable.set(target)``. Also ``target``, ``start`` (position before),
    ``watch(func)`` (bluesky's WatchableStatus: ``func(current=, initial=, target=, name=,
    unit=, time_elapsed=, fraction=)`` at every poll while moving), ``errors`` (what a
    ``stop(success=True)`` absorbed)."""

    def __init__(self, movable: "AxisMovable", target: float, start: Optional[float],
                 timeout: Optional[float]):
        super().__init__(timeout=timeout)
        self.movable = movable
        self.target = target
        self.start = start
        self.started = time.monotonic()
        self.errors: List[BaseException] = []
        self._stop_success: Optional[bool] = None
        self._watchers: List[Callable[..., None]] = []

    def watch(self, func: Callable[..., None]) -> None:
        self._watchers.append(func)

    def _notify(self, current: float) -> None:
        if not self._watchers:
            return
        initial = self.start if self.start is not None else current
        span = self.target - initial
        fraction = 1.0 if span == 0 else max(0.0, min(1.0, 1 - (self.target - current) / span))
        for func in list(self._watchers):
            try:
                func(current=current, initial=initial, target=self.target,
                     name=self.movable.name, unit="m",
                     time_elapsed=time.monotonic() - self.started, fraction=fraction)
            except Exception:
                log.exception("watch callback %r failed", func)

    def _conclude(self, exc: Optional[BaseException]) -> None:
        """End the move as the daemon reported it, or as ``stop(success=...)`` asked."""
        if self._stop_success is None:
            self._finish(exc)
        elif self._stop_success:
            if exc is not None:
                self.errors.append(exc)
            self._finish(None)
        else:
            stopped = MoveStopped("the move to %.12g m was stopped (stop(success=False))"
                                  % self.target)
            stopped.__cause__ = exc
            self._finish(stopped)


class AxisMovable:
    """A Bluesky-style movable of one axis of a synchronous :class:`idm.Client`.

    ``name`` defaults to the axis's name (``AXIS<n>:NAME?`` where the daemon answers it, else
    ``axis<n>``). ``timeout``: the default bound of a ``set()`` (None: the client's
    ``wait_timeout``); a move that exceeds it is stopped and its status fails with
    :class:`~idm.IdmTimeout`. ``tolerance`` (m): where the daemon does not answer
    ``MOVE:RESult?``, a move must end with the reading within this of the daemon's target
    (``MOVE?``) to succeed: default 100 nm (ten counts of the default stage's interferometer),
    so that a move stopped by another client is not taken for a success; None: no such check.
    """

    def __init__(self, axis: Any, name: Optional[str] = None, *, timeout: Optional[float] = None,
                 tolerance: Optional[float] = DEFAULT_TOLERANCE, parent: Any = None):
        from .client import Client
        if not isinstance(axis.client, Client):
            raise TypeError("AxisMovable needs an axis of a synchronous idm.Client")
        self.axis = axis
        self.client = axis.client
        self.parent = parent
        self.timeout = timeout
        self.tolerance = tolerance
        self.egu = "m"
        self._status: Optional[MoveStatus] = None
        self._set_lock = threading.Lock()
        if name is None:
            name = self._default_name()
        self.name = name

    def _default_name(self) -> str:
        if isinstance(self.axis.key, str):
            return self.axis.key
        try:
            return self.axis.name()
        except ScpiError as e:
            if e.code != _core.UNDEFINED_HEADER:
                raise
            return "axis%d" % self.axis.key

    def __repr__(self) -> str:
        return "AxisMovable(%r, axis=%r, %s)" % (self.name, self.axis.key, self.client.address)

    @property
    def hints(self) -> Dict[str, List[str]]:
        return {"fields": [self.name]}

    @property
    def source(self) -> str:
        return "idmd:%s/%s" % (self.client.address, self.axis.key)

    # -- Movable --
    def set(self, value: float, *, timeout: Optional[float] = None) -> MoveStatus:
        """Start a closed-loop move to ``value`` (m); returns a :class:`MoveStatus` at once.
        A refusal finishes it at once with the daemon's error."""
        timeout = self.timeout if timeout is None else timeout
        timeout = self.client.wait_timeout if timeout is None else timeout
        sess = self.client._session
        key = self.axis.key
        with self._set_lock:
            def begin():
                prefix = yield from _core.p_prefix(sess, key)
                command = prefix + "MOVE:ABSolute " + _core.fmt(value, "target")
                try:
                    start = _core.parse_number((yield Line(prefix + "POSition?")), "POSition?")
                except ScpiError as e:
                    if e.code not in (-230, -240):  # no valid position: the move judges
                        raise
                    start = None
                status.start = start
                mark = sess.fault_seq
                yield Line(command)
                return prefix, command, mark
            _core.fmt(value, "target")  # a number (TypeError here otherwise)
            status = MoveStatus(self, float(value), None, timeout)
            try:
                prefix, command, mark = self.client._run(begin())
            except Exception as e:
                status._finish(e)
                return status
            previous, self._status = self._status, status
            if previous is not None and not previous.done:
                previous._finish(MoveError("superseded by set(%.12g)" % float(value), "SUPERSEDED"))
            thread = threading.Thread(target=self._follow,
                                      args=(status, prefix, command, timeout, mark),
                                      name="idm-%s-set" % self.name, daemon=True)
            thread.start()
        return status

    def _follow(self, status: MoveStatus, prefix: str, command: str,
                timeout: Optional[float], mark: int) -> None:
        sess = self.client._session
        try:
            ended = self.client._run(_core.p_wait_axis(
                prefix, timeout, self.client.poll_interval, command, cancel=lambda: status.done,
                stop_on_timeout=True, watch=status._notify,
                watching=lambda: bool(status._watchers), faults=(sess, mark)))
            if not ended:
                return  # finished meanwhile (stop(), a newer set())
            if status._stop_success is None:
                self.client._run(_core.p_check_result(sess, prefix, command, self.tolerance))
        except BaseException as e:  # every failure ends the status
            status._conclude(e)
        else:
            status._conclude(None)

    # -- Stoppable --
    def stop(self, success: bool = True) -> None:
        """Stop the axis (``bluesky.protocols.Stoppable``). A pending ``set()`` status ends
        once the axis is at rest: marked successful with ``success=True`` (the protocol's
        default: the plan asked for the stop; errors it caused are kept in
        ``status.errors``), failed with :class:`~idm.MoveStopped` with ``success=False``."""
        status = self._status
        if status is not None and not status.done:
            status._stop_success = success
        self.axis.stop()
        if status is None or status.done:
            return
        try:
            prefix = self.client._run(_core.p_prefix(self.client._session, self.axis.key))
            self.client._run(_core.p_wait_axis(prefix, _core.STOP_SETTLE_S,
                                               self.client.poll_interval, "STOP",
                                               stop_on_timeout=False))
        except BaseException as e:
            status._conclude(e)
            if not isinstance(e, ScpiError):
                raise
        else:
            status._conclude(None)

    # -- Readable --
    def read(self) -> Dict[str, Dict[str, Any]]:
        """``{name: {"value": position, "timestamp": t}, name_setpoint: {...}}``."""
        position = self.axis.position()
        t = time.time()
        target = self.axis.target()
        return {self.name: {"value": position, "timestamp": t},
                self.name + "_setpoint": {"value": target, "timestamp": time.time()}}

    def describe(self) -> Dict[str, Dict[str, Any]]:
        return {self.name: {"source": self.source + "/POSition?", "dtype": "number",
                            "shape": [], "units": "m", "precision": 12},
                self.name + "_setpoint": {"source": self.source + "/MOVE?", "dtype": "number",
                                          "shape": [], "units": "m", "precision": 12}}

    # -- Configurable --
    def read_configuration(self) -> Dict[str, Dict[str, Any]]:
        """The soft limits (``LIMit?``)."""
        lower, upper = self.axis.limits()
        t = time.time()
        return {self.name + "_lower_limit": {"value": lower, "timestamp": t},
                self.name + "_upper_limit": {"value": upper, "timestamp": t}}

    def describe_configuration(self) -> Dict[str, Dict[str, Any]]:
        return {self.name + "_lower_limit": {"source": self.source + "/LIMit:LOWer?",
                                             "dtype": "number", "shape": [], "units": "m"},
                self.name + "_upper_limit": {"source": self.source + "/LIMit:UPPer?",
                                             "dtype": "number", "shape": [], "units": "m"}}

    # -- Locatable --
    def locate(self) -> Dict[str, float]:
        """``{"setpoint": MOVE?, "readback": POSition?}``."""
        readback = self.axis.position()
        return {"setpoint": self.axis.target(), "readback": readback}

    # -- ophyd positioner conveniences --
    @property
    def position(self) -> float:
        return self.axis.position()

    @property
    def limits(self):
        return self.axis.limits()

    def move(self, value: float, *, wait: bool = True, timeout: Optional[float] = None) -> MoveStatus:
        """``set()`` that, with ``wait``, waits and raises a failure (as ophyd's ``move``)."""
        status = self.set(value, timeout=timeout)
        if wait:
            status.wait()
        return status
