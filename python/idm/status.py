"""Parsed replies: STATus?, the IEEE 488.2 / SCPI status registers, MOVE:RESult?, SWEEP?,
SYSTem:LOOP?.

The bit names are the protocol's (docs/command-protocol.md, "Status").
"""

from __future__ import annotations

import enum
import math
from typing import Any, Dict, Iterator, List, NamedTuple, Optional

from .errors import ProtocolError

__all__ = [
    "Operation",
    "StatusByte",
    "EventStatus",
    "AxisStatus",
    "MoveResult",
    "SweepState",
    "LoopStats",
    "parse_number",
    "parse_bool",
    "parse_int",
]

# SCPI's not-a-number and infinities as the daemon writes them in replies.
SCPI_NAN = 9.91e37
SCPI_INF = 9.9e37


class Operation(enum.IntFlag):
    """``STATus:OPERation?`` of one axis."""

    MOVING = 1 << 0
    IN_POSITION = 1 << 1
    HOLDING = 1 << 2
    REFERENCED = 1 << 3
    AT_LOWER_LIMIT = 1 << 4
    AT_UPPER_LIMIT = 1 << 5
    END_OF_TRAVEL = 1 << 6
    FAULT = 1 << 7
    POSITION_VALID = 1 << 8
    REFERENCING = 1 << 9


class StatusByte(enum.IntFlag):
    """``*STB?`` (IEEE 488.2). The protocol names bits 2, 5 and 7; 4 and 6 are the standard's."""

    ERROR_QUEUE = 1 << 2         # the error queue is not empty
    MESSAGE_AVAILABLE = 1 << 4   # MAV (IEEE 488.2)
    EVENT_SUMMARY = 1 << 5       # ESB: a bit of *ESR? is set
    MASTER_SUMMARY = 1 << 6      # MSS/RQS (IEEE 488.2)
    OPERATION_SUMMARY = 1 << 7   # a bit of STATus:OPERation is set


class EventStatus(enum.IntFlag):
    """``*ESR?``, the standard event status register (IEEE 488.2)."""

    OPERATION_COMPLETE = 1 << 0
    REQUEST_CONTROL = 1 << 1
    QUERY_ERROR = 1 << 2
    DEVICE_ERROR = 1 << 3
    EXECUTION_ERROR = 1 << 4
    COMMAND_ERROR = 1 << 5
    USER_REQUEST = 1 << 6
    POWER_ON = 1 << 7


def parse_number(reply: str, what: str = "reply") -> float:
    """A number from a reply; SCPI's 9.91e37 is NaN, +-9.9e37 +-infinity."""
    try:
        v = float(reply)
    except ValueError:
        raise ProtocolError("%s: %r is not a number" % (what, reply)) from None
    if math.isfinite(v) and abs(v) >= SCPI_INF * (1 - 1e-9):
        if abs(v - SCPI_NAN) <= SCPI_NAN * 1e-9:
            return math.nan
        return math.copysign(math.inf, v)
    return v


def parse_int(reply: str, what: str = "reply") -> int:
    try:
        return int(reply.strip())
    except ValueError:
        raise ProtocolError("%s: %r is not an integer" % (what, reply)) from None


def parse_bool(reply: str, what: str = "reply") -> bool:
    r = reply.strip()
    if r not in ("0", "1"):
        raise ProtocolError("%s: %r is not 0 or 1" % (what, reply))
    return r == "1"


# STATus? keys and their types (daemon/session.cpp's STATus?); other keys stay text (state,
# fault, daemon_error, axis (the axis's name), device (up, lost), and keys a later daemon adds).
_STATUS_TYPES = {
    "done": parse_bool,
    "position_valid": parse_bool,
    "referenced": parse_bool,
    "position": parse_number,
    "target": parse_number,
    "lower": parse_number,
    "upper": parse_number,
    "offset": parse_number,
    "moves": parse_int,
    "bursts": parse_int,
    "cycles": parse_int,
    "errors": parse_int,
    "last_error": parse_int,
}


class AxisStatus:
    """``STATus?`` of one axis, parsed.

    Every ``key=value`` of the line is an attribute and an item (``st.state``, ``st["state"]``),
    typed where the key is known (numbers in m, counters as int, flags as bool), text otherwise
    (keys a later daemon adds, e.g. ``eot``, stay available as text). ``raw`` is the line.
    A position that cannot be trusted (``position=9.91E37``, ``position_valid=0``) is NaN.
    ``operation`` is the axis's ``STATus:OPERation?`` as :class:`Operation` when the daemon
    answers it, else ``None`` (then :meth:`idm.Axis.operation` raises the daemon's error).
    """

    def __init__(self, raw: str, operation: Optional[Operation] = None):
        self.raw = raw
        self.operation = operation
        self._fields: Dict[str, Any] = {}
        for word in raw.split():
            key, sep, value = word.partition("=")
            if not sep:
                raise ProtocolError("STATus?: %r is not key=value (in %r)" % (word, raw))
            conv = _STATUS_TYPES.get(key)
            self._fields[key] = conv(value, "STATus? " + key) if conv else value
        if "state" not in self._fields:
            raise ProtocolError("STATus? has no state: %r" % raw)

    @classmethod
    def parse(cls, raw: str, operation: Optional[Operation] = None) -> "AxisStatus":
        return cls(raw, operation)

    def __getattr__(self, key: str) -> Any:
        fields = self.__dict__.get("_fields", {})
        if key in fields:
            return fields[key]
        raise AttributeError("STATus? has no %r (keys: %s)" % (key, " ".join(fields)))

    def __getitem__(self, key: str) -> Any:
        return self._fields[key]

    def __contains__(self, key: object) -> bool:
        return key in self._fields

    def __iter__(self) -> Iterator[str]:
        return iter(self._fields)

    def get(self, key: str, default: Any = None) -> Any:
        return self._fields.get(key, default)

    def as_dict(self) -> Dict[str, Any]:
        return dict(self._fields)

    @property
    def moving(self) -> bool:
        """In motion: ``done=0`` (the motor record's DMOV inverted)."""
        return not self._fields.get("done", True)

    @property
    def faulted(self) -> bool:
        """The daemon reports a fault (``state=FAULT`` or a ``fault`` other than ``none``)."""
        return self._fields.get("state") == "FAULT" or self._fields.get("fault", "none") != "none"

    def __repr__(self) -> str:
        op = "" if self.operation is None else ", operation=%r" % (self.operation,)
        return "AxisStatus(%r%s)" % (self.raw, op)


class MoveResult(NamedTuple):
    """``MOVE:RESult?``: why the axis came to rest (``OK``, ``STOPPED``, ``LIMIT``,
    ``END_OF_TRAVEL``, ``FAULT``, ``TIMEOUT``, ``NONE``) and the final distance to the target."""

    word: str
    distance: float

    @property
    def ok(self) -> bool:
        return self.word == "OK"

    @classmethod
    def parse(cls, reply: str) -> "MoveResult":
        word, sep, dist = reply.partition(",")
        if not sep:
            raise ProtocolError("MOVE:RESult?: %r is not <word>,<m>" % reply)
        return cls(word.strip().upper(), parse_number(dist, "MOVE:RESult? distance"))


class SweepState(NamedTuple):
    """``SWEEP?``: the last (or running) sweep of the daemon. ``state`` one of ``NONE``,
    ``RUNNING``, ``DONE``, ``STOPPED``, ``FAILED``; ``axis`` its axis (from 1); ``written``
    trials recorded in the dataset, ``failed`` trials that failed (a trial a STOP interrupts
    counts), ``planned`` trials the sweep holds; ``directory`` the dataset's directory as the
    daemon names it (below its ``recording.data_dir``)."""

    state: str
    axis: int
    written: int
    failed: int
    planned: int
    directory: str

    @property
    def running(self) -> bool:
        return self.state == "RUNNING"

    @property
    def ok(self) -> bool:
        """Ended with every planned trial written and none failed."""
        return (self.state == "DONE" and self.failed == 0 and self.written == self.planned)

    @classmethod
    def parse(cls, reply: str) -> "SweepState":
        parts = reply.split(",", 5)
        if len(parts) != 6:
            raise ProtocolError("SWEEP?: %r is not <state>,<axis>,<written>,<failed>,<planned>,"
                                "\"<dir>\"" % reply)
        state = parts[0].strip().upper()
        axis, written, failed, planned = (parse_int(x, "SWEEP?") for x in parts[1:5])
        directory = parts[5].strip()
        if len(directory) < 2 or directory[0] != '"' or directory[-1] != '"':
            raise ProtocolError("SWEEP?: the directory %r is not quoted (in %r)" % (directory,
                                                                                    reply))
        return cls(state, axis, written, failed, planned, directory[1:-1].replace('""', '"'))


class LoopStats(NamedTuple):
    """``SYSTem:LOOP?``: the real-time loop's period, wake-ups, misses and latency."""

    period: float
    wakeups: int
    misses: int
    latency_min: float
    latency_avg: float
    latency_max: float
    bin_width: float
    histogram: List[int]

    @classmethod
    def parse(cls, reply: str) -> "LoopStats":
        f = {}
        for word in reply.split():
            k, sep, v = word.partition("=")
            if not sep:
                raise ProtocolError("SYSTem:LOOP?: %r is not key=value" % word)
            f[k] = v
        try:
            return cls(parse_number(f["period"]), parse_int(f["wakeups"]), parse_int(f["misses"]),
                       parse_number(f["min"]), parse_number(f["avg"]), parse_number(f["max"]),
                       parse_number(f["bin_width"]),
                       [parse_int(x) for x in f["hist"].split(";") if x])
        except KeyError as e:
            raise ProtocolError("SYSTem:LOOP? lacks %s: %r" % (e, reply)) from None
