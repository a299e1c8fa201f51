"""The exceptions of the idm client.

Every error the daemon queues (``SYSTem:ERRor?``) is raised as a :class:`ScpiError` (or one of
its subclasses, chosen by the code's SCPI class) carrying the daemon's code and text and the
line that caused it. Failures of the connection are :class:`IdmConnectionError`, replies that do
not come in time :class:`IdmTimeout`.
"""

from __future__ import annotations

from typing import List, Optional, Tuple

__all__ = [
    "IdmError",
    "ScpiError",
    "CommandError",
    "ExecutionError",
    "DeviceSpecificError",
    "QueryError",
    "DeviceFault",
    "IdmTimeout",
    "IdmConnectionError",
    "ProtocolError",
    "MoveError",
    "MoveStopped",
    "SweepError",
    "error_from_code",
    "parse_error_line",
]


class IdmError(Exception):
    """Base class of every exception the idm client raises."""


class ScpiError(IdmError):
    """An error the daemon put in its error queue.

    ``code`` and ``text`` are the daemon's (``-222``, ``"Data out of range; target 1000 ..."``);
    ``command`` is the line that was sent when the error was found; ``errors`` every
    ``(code, text)`` drained from the queue at that point (this one first). ``reply`` is what
    the daemon answered to that line when it was a query (``""`` for the usual empty reply of a
    failed query; ``"9.91E37"`` for an untrusted position, -230; ``POSition:ALL?``'s every
    position with the untrusted ones as ``9.91E37``), ``None`` for a command.
    """

    def __init__(self, code: int, text: str, command: Optional[str] = None,
                 errors: Optional[List[Tuple[int, str]]] = None, reply: Optional[str] = None):
        self.code = int(code)
        self.text = text
        self.command = command
        self.errors = list(errors) if errors else [(self.code, text)]
        self.reply = reply
        super().__init__(self._message())

    def _message(self) -> str:
        msg = '%d,"%s"' % (self.code, self.text)
        if self.command is not None:
            msg += " (after %r)" % self.command
        if len(self.errors) > 1:
            msg += "; also queued: " + "; ".join('%d,"%s"' % e for e in self.errors[1:])
        return msg

    def with_command(self, command: str) -> "ScpiError":
        """The same error attributed to another command line (e.g. the move a fault ended)."""
        self.command = command
        self.args = (self._message(),)
        return self

    def __reduce__(self):
        return (type(self), (self.code, self.text, self.command, self.errors, self.reply))


class CommandError(ScpiError):
    """SCPI command errors, -100..-199: the line could not be parsed (-113 undefined header,
    -114 header suffix out of range: ``AXIS<n>:`` with no axis n, -120 numeric data error,
    ...). A command the daemon does not implement is -113."""


class ExecutionError(ScpiError):
    """SCPI execution errors, -200..-299: the line parsed but could not be carried out
    (-221 settings conflict, -222 data out of range, -230 data corrupt or stale: a position
    that cannot be trusted, -240 hardware error)."""


class DeviceSpecificError(ScpiError):
    """SCPI device-specific errors, -300..-399 (-350 queue overflow, -363 input overrun)."""


class QueryError(ScpiError):
    """SCPI query errors, -400..-499."""


class DeviceFault(ScpiError):
    """A positive code: a motion this connection started ended in a device fault
    (101 invalid_sample, 102 stall, 103 retry_limit, 104 driver, 105 no_plan,
    106 capture_overrun, 107 device_lost, 108 window_unreachable, ...)."""


def error_from_code(code: int, text: str, command: Optional[str] = None,
                    errors: Optional[List[Tuple[int, str]]] = None,
                    reply: Optional[str] = None) -> ScpiError:
    """The ScpiError subclass for a code."""
    if code > 0:
        cls = DeviceFault
    elif -199 <= code <= -100:
        cls = CommandError
    elif -299 <= code <= -200:
        cls = ExecutionError
    elif -399 <= code <= -300:
        cls = DeviceSpecificError
    elif -499 <= code <= -400:
        cls = QueryError
    else:
        cls = ScpiError
    return cls(code, text, command, errors, reply)


class IdmTimeout(IdmError, TimeoutError):
    """A reply, a move or a status did not come within its timeout."""


class IdmConnectionError(IdmError, ConnectionError):
    """The daemon cannot be reached, or the connection was lost or closed."""


class ProtocolError(IdmError):
    """A reply that does not follow the protocol (e.g. not a number where one belongs)."""


class MoveError(IdmError):
    """A motion that came to rest without reaching its target although no error was queued:
    ``MOVE:RESult?`` answered something other than ``OK``, or (only where the daemon does not
    answer ``MOVE:RESult?``) the client's own tolerance check failed. ``result`` is the
    ``MOVE:RESult?`` word or ``None``; ``distance`` the final distance to the target, m."""

    def __init__(self, message: str, result: Optional[str] = None,
                 distance: Optional[float] = None):
        super().__init__(message)
        self.result = result
        self.distance = distance


class MoveStopped(IdmError):
    """A motion ended by ``stop(success=False)`` (the Bluesky-style movable's stop)."""


class SweepError(IdmError):
    """A sweep that did not end well: stopped, trials failed or missing (``SWEEP?``; on a
    daemon without it ``STATus?`` ``daemon_error`` and the dataset). ``progress`` is the
    final :class:`~idm.SweepProgress` (None when it could not be read)."""

    def __init__(self, message: str, progress: Optional[object] = None):
        super().__init__(message)
        self.progress = progress


def parse_error_line(line: str) -> Tuple[int, str]:
    """``-222,"Data out of range; ..."`` -> ``(-222, "Data out of range; ...")``.

    A doubled ``""`` inside the quotes is one ``"``."""
    head, sep, rest = line.partition(",")
    try:
        code = int(head.strip())
    except ValueError:
        raise ProtocolError("SYSTem:ERRor? answered %r, not <code>,\"<text>\"" % line) from None
    text = rest.strip()
    if len(text) >= 2 and text[0] == '"' and text[-1] == '"':
        text = text[1:-1].replace('""', '"')
    return code, text
