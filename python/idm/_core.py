"""The protocol logic, free of I/O, shared by the synchronous and the asyncio client.

Every operation is a *plan*: a generator that yields :class:`Line` (send one line, then drain
the error queue; the value sent back is the reply, or ``None`` for a command; a queued error is
thrown into the plan as a :class:`~idm.errors.ScpiError`) and :class:`Sleep`. The clients run
plans: ``idm.Client`` with blocking sockets, ``idm.aio.AsyncClient`` with asyncio streams.
The plans of sweeps are in :mod:`idm._sweep`.
"""

from __future__ import annotations

import math
import numbers
import time
from typing import Any, Callable, Dict, Generator, List, Optional, Tuple, Union

from .errors import (IdmError, IdmTimeout, MoveError, ScpiError, error_from_code)
from .status import (AxisStatus, LoopStats, MoveResult, Operation, parse_bool, parse_int,
                     parse_number)

UNDEFINED_HEADER = -113
UNTRUSTED = -230  # data corrupt or stale: a position that cannot be trusted (9.91E37)
# After a STOP (a wait that timed out), how long the axis may take to come to rest.
STOP_SETTLE_S = 10.0

AxisKey = Union[int, str]
Plan = Generator[Any, Any, Any]


class Line:
    """Send ``text`` (one protocol line), read its reply if it is a query, drain the error queue.

    ``timeout`` overrides the client's reply timeout (``*OPC?`` waits for motion)."""

    __slots__ = ("text", "query", "timeout")

    def __init__(self, text: str, timeout: Optional[float] = None):
        check_line(text)
        self.text = text
        self.query = is_query(text)
        self.timeout = timeout

    def __repr__(self) -> str:
        return "Line(%r)" % self.text


class Sleep:
    __slots__ = ("seconds",)

    def __init__(self, seconds: float):
        self.seconds = seconds


class PlanRun:
    """One plan being run by a client that performs its ops: ``op`` is the op to perform now;
    :meth:`send` (its result) or :meth:`throw` (its exception) advance the plan. When the plan
    has returned, ``running`` is False and ``value`` is what it returned."""

    __slots__ = ("plan", "op", "running", "value")

    def __init__(self, plan: Plan):
        self.plan = plan
        self.op: Any = None
        self.running = True
        self.value: Any = None
        self._advance(lambda: next(plan))

    def send(self, result: Any) -> None:
        self._advance(lambda: self.plan.send(result))

    def throw(self, exc: BaseException) -> None:
        self._advance(lambda: self.plan.throw(exc))

    def _advance(self, step: Callable[[], Any]) -> None:
        try:
            self.op = step()
        except StopIteration as stop:
            self.running = False
            self.value = stop.value


def run_plan(plan: Plan, perform: Callable[[Any], Any]) -> Any:
    """Runs a plan synchronously: ``perform(op)`` gives each op's result; an exception it
    raises is thrown into the plan (which may handle it). Returns the plan's value."""
    run = PlanRun(plan)
    while run.running:
        try:
            result = perform(run.op)
        except Exception as exc:
            run.throw(exc)
            continue
        run.send(result)
    return run.value


def is_query(line: str) -> bool:
    """The daemon answers a line with exactly one reply when its first word ends in ``?``."""
    words = line.split(None, 1)
    return bool(words) and words[0].endswith("?")


def check_line(line: str) -> None:
    if not isinstance(line, str):
        raise TypeError("a protocol line is text, not %s" % type(line).__name__)
    if "\n" in line or "\r" in line:
        raise ValueError("one command per line: %r holds a line break" % line)


def fmt(value: Any, what: str = "value") -> str:
    """A number as the protocol wants it: plain decimal or exponent, SI units.

    Not-finite numbers are sent as they are: the daemon refuses them (-120) itself."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError("%s must be a number, not %r" % (what, value))
    if isinstance(value, numbers.Integral):
        return str(int(value))
    return repr(float(value))


def fmt_list(values: Any, what: str) -> str:
    """A SWEEP list: a number, a sequence of numbers (sent ``a;b;c``) or a string as the
    protocol writes lists (``"100:800:100"`` inclusive, ``"0.1;0.2"``)."""
    if isinstance(values, str):
        if not values.strip() or "," in values:
            raise ValueError("%s: %r is not a list (a:b:step or a;b;c)" % (what, values))
        return values.strip()
    if isinstance(values, numbers.Real) and not isinstance(values, bool):
        return fmt(values, what)
    items = [fmt(v, what) for v in values]
    if not items:
        raise ValueError("%s: an empty list" % what)
    return ";".join(items)


def count_list(values: Any) -> Optional[int]:
    """How many values a SWEEP list holds (as the daemon counts a:b:step: inclusive, rounded
    to 12 digits); None when the string cannot be read here (the daemon judges it)."""
    if isinstance(values, str):
        text = values.strip()
        try:
            if ";" in text:
                return len([x for x in text.split(";")])
            parts = text.split(":")
            if len(parts) == 3:
                a, b, step = (float(p) for p in parts)
                if step <= 0 or b < a:
                    return None
                return int(math.floor(round((b - a) / step, 12))) + 1
            float(text)
            return 1
        except ValueError:
            return None
    if isinstance(values, numbers.Real):
        return 1
    return len(list(values))


def quote(text: str) -> str:
    """A string argument: bare when it is a plain word, else in ``"..."`` with ``""`` for ``"``."""
    check_line(text)
    if text and all(c.isalnum() or c in "._-/+" for c in text):
        return text
    return '"' + text.replace('"', '""') + '"'


class Session:
    """What a client learned about its daemon: which optional commands it answers (probed
    once: -113 means not implemented), whether it has the several-axes extension, the axes'
    names; and the device faults (positive codes) drained on this connection, whichever call
    drained them, so that the wait for a motion sees its fault even when another thread's
    call on the same connection took it from the queue."""

    def __init__(self) -> None:
        self.caps: Dict[str, bool] = {}
        self.multi_axis: Optional[bool] = None
        self.axis_count: Optional[int] = None
        self.names: Dict[int, str] = {}
        self.fault_seq = 0
        self._faults: List[Tuple[int, ScpiError]] = []

    def note_errors(self, error: ScpiError) -> None:
        """Called by the clients with every error they raise (under their lock)."""
        if any(code > 0 for code, _ in error.errors):
            self.fault_seq += 1
            self._faults = self._faults[-15:] + [(self.fault_seq, error)]

    def faults_since(self, mark: int) -> List[ScpiError]:
        return [e for seq, e in self._faults if seq > mark]


# ---- generic ---------------------------------------------------------------------------------

def p_line(text: str, timeout: Optional[float] = None) -> Plan:
    reply = yield Line(text, timeout)
    return reply


def p_number(text: str) -> Plan:
    reply = yield Line(text)
    return parse_number(reply, text)


def p_int(text: str) -> Plan:
    reply = yield Line(text)
    return parse_int(reply, text)


def p_bool(text: str) -> Plan:
    reply = yield Line(text)
    return parse_bool(reply, text)


def p_optional(sess: Session, text: str, cap: str) -> Plan:
    """A query the daemon may not implement yet: its reply, or None when it answers -113 (then
    not asked again on this connection). Any other error is raised."""
    if sess.caps.get(cap) is False:
        return None
    try:
        reply = yield Line(text)
    except ScpiError as e:
        if _not_implemented(e):
            sess.caps[cap] = False
            yield from p_forget_probe()
            return None
        raise
    sess.caps[cap] = True
    return reply


def p_forget_probe() -> Plan:
    """After a probe answered -113 (already drained): ``*CLS``, so that the probe leaves no
    trace in ``STATus?``'s ``last_error`` (or in ``*ESR?``)."""
    yield Line("*CLS")


# ---- axes ------------------------------------------------------------------------------------

# Optional queries probed once per connection together with AXIS:COUNt?, at its first axis
# operation: (capability, query, with {p} axis 1's prefix).
OPTIONAL_QUERIES = (("MOVE:RESult", "{p}MOVE:RESult?"),
                    ("STATus:OPERation", "{p}STATus:OPERation?"),
                    ("SWEEP?", "SWEEP?"))


def _not_implemented(e: ScpiError) -> bool:
    return all(code == UNDEFINED_HEADER for code, _ in e.errors)


def p_multi_axis(sess: Session) -> Plan:
    """Whether the daemon has the several-axes extension (it answers AXIS:COUNt?). Asked at
    the first axis operation of a connection, before it can have started a motion; the
    optional queries are probed then too, and one ``*CLS`` follows if any was refused (-113),
    so that a later ``*CLS`` can never clear a fault queued for a motion of this connection."""
    if sess.multi_axis is None:
        refused = False
        try:
            reply = yield Line("AXIS:COUNt?")
        except ScpiError as e:
            if not _not_implemented(e):
                raise
            sess.multi_axis = False
            refused = True
        else:
            sess.axis_count = parse_int(reply, "AXIS:COUNt?")
            sess.multi_axis = True
        prefix = "AXIS1:" if sess.multi_axis else ""
        for cap, query in OPTIONAL_QUERIES:
            if cap in sess.caps:
                continue
            try:
                yield Line(query.format(p=prefix))
            except ScpiError as e:
                if not _not_implemented(e):
                    raise
                sess.caps[cap] = False
                refused = True
            else:
                sess.caps[cap] = True
        if refused:
            yield from p_forget_probe()
    return sess.multi_axis


def p_axis_count(sess: Session) -> Plan:
    n = yield from p_int("AXIS:COUNt?")
    sess.axis_count = n
    sess.multi_axis = True
    return n


def p_axis_names(sess: Session) -> Plan:
    """Every axis's name, by number (AXIS:COUNt?, AXIS<n>:NAME?)."""
    n = yield from p_axis_count(sess)
    for k in range(1, n + 1):
        if k not in sess.names:
            sess.names[k] = (yield Line("AXIS%d:NAME?" % k)).strip()
    return {k: sess.names[k] for k in range(1, n + 1)}


class AxisNotFound(IdmError, LookupError):
    """No axis of the daemon has that name."""


def p_axis_number(sess: Session, key: AxisKey) -> Plan:
    if isinstance(key, bool) or not isinstance(key, (int, str)):
        raise TypeError("an axis is a number (from 1) or a name, not %r" % (key,))
    if isinstance(key, int):
        return key
    for k, name in sess.names.items():
        if name == key:
            return k
    n = sess.axis_count
    if n is not None and all(k in sess.names for k in range(1, n + 1)):
        # every name is known (this connection): a case-insensitive match needs no round trip
        for k in range(1, n + 1):
            if sess.names[k].lower() == key.lower():
                return k
    names = yield from p_axis_names(sess)
    for k, name in names.items():
        if name == key:
            return k
    for k, name in names.items():
        if name.lower() == key.lower():
            return k
    raise AxisNotFound("no axis named %r; the daemon's axes: %s" % (
        key, ", ".join("%d %s" % kv for kv in sorted(names.items()))))


def p_prefix(sess: Session, key: AxisKey) -> Plan:
    """The header prefix of an axis: ``AXIS<n>:`` with the several-axes extension; on a daemon
    without it, axis 1 is the unprefixed commands and another axis keeps its ``AXIS<n>:`` prefix
    (so the daemon answers with its own error)."""
    n = yield from p_axis_number(sess, key)
    multi = yield from p_multi_axis(sess)
    if multi or n != 1:
        return "AXIS%d:" % n
    return ""


# ---- motion ----------------------------------------------------------------------------------

def p_wait_axis(prefix: str, timeout: Optional[float], poll: float, command: Optional[str],
                cancel: Optional[Callable[[], bool]] = None, stop_on_timeout: bool = True,
                watch: Optional[Callable[[float], None]] = None,
                watching: Optional[Callable[[], bool]] = None,
                faults: Optional[Tuple[Session, int]] = None) -> Plan:
    """Poll ``MOVE:DONE?`` until the axis is at rest. A fault the motion ended in is queued
    for this connection at its next line, so the error drain after the ``MOVE:DONE?`` that
    answers 1 raises it (attributed to ``command``). Returns False if ``cancel()`` became true.
    ``watch(position)`` is called at every poll while moving (``POSition?``), while
    ``watching()`` (if given) is true. ``faults`` (session, mark): at rest, a device fault that
    another call on this connection drained since ``mark`` (taken before the motion started)
    is raised too."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        position = None
        try:
            done = parse_bool((yield Line(prefix + "MOVE:DONE?")), "MOVE:DONE?")
            if not done and watch is not None and (watching is None or watching()):
                position = yield from p_number(prefix + "POSition?")
        except ScpiError as e:
            if command is not None:
                e.with_command(command)
            raise
        if done:
            if faults is not None:
                sess, mark = faults
                seen = sess.faults_since(mark)
                if seen:
                    first = seen[0]
                    raise error_from_code(first.code, first.text, command or first.command,
                                          first.errors)
            return True
        if cancel is not None and cancel():
            return False
        if position is not None:
            watch(position)
        if deadline is not None and time.monotonic() >= deadline:
            what = command or "the motion"
            if stop_on_timeout:
                yield Line(prefix + "STOP")
                # Back at rest before the caller gets control (and errors drained meanwhile).
                settle = time.monotonic() + STOP_SETTLE_S
                while not parse_bool((yield Line(prefix + "MOVE:DONE?")), "MOVE:DONE?"):
                    if time.monotonic() >= settle:
                        raise IdmTimeout("%s did not finish within %g s, and the axis is still "
                                         "not at rest %g s after STOP" % (what, timeout,
                                                                          STOP_SETTLE_S))
                    yield Sleep(poll)
                raise IdmTimeout("%s did not finish within %g s; the axis was stopped"
                                 % (what, timeout))
            raise IdmTimeout("%s did not finish within %g s" % (what, timeout))
        yield Sleep(poll)


def p_check_result(sess: Session, prefix: str, command: str, tolerance: Optional[float]) -> Plan:
    """After a closed-loop move came to rest without a queued error: MOVE:RESult? must be OK
    where the daemon answers it; where it does not, and only if a tolerance is given, the
    reading must lie within it of the daemon's target (``MOVE?``)."""
    reply = yield from p_optional(sess, prefix + "MOVE:RESult?", "MOVE:RESult")
    if reply is not None:
        result = MoveResult.parse(reply)
        if not result.ok:
            raise MoveError("%s ended %s, %g m from the target" % (command, result.word,
                                                                  result.distance),
                            result.word, result.distance)
        return result
    if tolerance is not None:
        target = yield from p_number(prefix + "MOVE?")
        position = yield from p_number(prefix + "POSition?")
        distance = position - target
        if not abs(distance) <= tolerance:
            raise MoveError("%s came to rest at %.12g m, %.3g m from the target %.12g m "
                            "(tolerance %g m; a client-side check: this daemon does not answer "
                            "MOVE:RESult?)" % (command, position, distance, target, tolerance),
                            None, distance)
    return None


def p_motion(sess: Session, prefix: str, command: str, wait: bool, timeout: Optional[float],
             poll: float) -> Plan:
    """Sends a command that starts motion; with ``wait``, waits until the axis is at rest (a
    fault the motion ended in raised, see :func:`p_wait_axis`). Returns whether it waited."""
    mark = sess.fault_seq
    yield Line(command)
    if not wait:
        return False
    yield from p_wait_axis(prefix, timeout, poll, command, faults=(sess, mark))
    return True


def p_move(sess: Session, key: AxisKey, value: Any, relative: bool, wait: bool,
           timeout: Optional[float], poll: float, tolerance: Optional[float]) -> Plan:
    prefix = yield from p_prefix(sess, key)
    command = prefix + ("MOVE:RELative " if relative else "MOVE:ABSolute ") + fmt(value, "target")
    if not (yield from p_motion(sess, prefix, command, wait, timeout, poll)):
        return None
    yield from p_check_result(sess, prefix, command, tolerance)
    position = yield from p_number(prefix + "POSition?")
    return position


def p_step(sess: Session, key: AxisKey, cycles: Any, duty: Any, freq_hz: Any, stroke_m: Any,
           wait: bool, timeout: Optional[float], poll: float) -> Plan:
    if isinstance(cycles, float) and cycles.is_integer():
        cycles = int(cycles)
    args = [fmt(cycles, "cycles")]
    if duty is not None or freq_hz is not None or stroke_m is not None:
        if duty is None or freq_hz is None:
            raise ValueError("STEP takes the duty and the frequency together")
        args += [fmt(duty, "duty"), fmt(freq_hz, "freq_hz")]
        if stroke_m is not None:
            args.append(fmt(stroke_m, "stroke_m"))
    prefix = yield from p_prefix(sess, key)
    command = prefix + "STEP " + ",".join(args)
    if not (yield from p_motion(sess, prefix, command, wait, timeout, poll)):
        return None
    position = yield from p_number(prefix + "POSition?")
    return position


JOG_DIRECTIONS = {"+": "POSitive", "POS": "POSitive", "POSITIVE": "POSitive",
                  "-": "NEGative", "NEG": "NEGative", "NEGATIVE": "NEGative"}


def jog_keyword(direction: Any) -> str:
    """``JOG``'s keyword for a direction: ``"positive"``/``"+"``/``+1`` or
    ``"negative"``/``"-"``/``-1`` (words in any case, ``pos``/``neg`` too)."""
    if isinstance(direction, bool):
        raise ValueError("jog direction %r: allowed positive, negative (or +, -, 1, -1)"
                         % (direction,))
    if isinstance(direction, numbers.Integral) and direction in (1, -1):
        return "POSitive" if direction > 0 else "NEGative"
    if isinstance(direction, str) and direction.strip().upper() in JOG_DIRECTIONS:
        return JOG_DIRECTIONS[direction.strip().upper()]
    raise ValueError("jog direction %r: allowed positive, negative (or +, -, 1, -1)"
                     % (direction,))


def p_jog(sess: Session, key: AxisKey, direction: Any, wait: bool, timeout: Optional[float],
          poll: float) -> Plan:
    command_word = jog_keyword(direction)
    prefix = yield from p_prefix(sess, key)
    command = prefix + "JOG " + command_word
    if not (yield from p_motion(sess, prefix, command, wait, timeout, poll)):
        return None
    # A jog ends at the soft limit (OK) or by a STOP (STOPPED): both are how a jog ends. A
    # STOP from another connection queues 114 for this one, raised above.
    reply = yield from p_optional(sess, prefix + "MOVE:RESult?", "MOVE:RESult")
    if reply is not None:
        result = MoveResult.parse(reply)
        if result.word not in ("OK", "STOPPED"):
            raise MoveError("%s ended %s, %g m from the soft limit" % (command, result.word,
                                                                       result.distance),
                            result.word, result.distance)
    position = yield from p_number(prefix + "POSition?")
    return position


def p_reference(sess: Session, key: AxisKey, mode: Optional[str], wait: bool,
                timeout: Optional[float], poll: float) -> Plan:
    prefix = yield from p_prefix(sess, key)
    if mode is None:
        command = prefix + "REFerence"
    else:
        word = str(mode).upper()
        modes = {"NEG": "NEGative", "NEGATIVE": "NEGative", "POS": "POSitive",
                 "POSITIVE": "POSitive", "MARK": "MARK"}
        if word not in modes:
            raise ValueError("reference mode %r: NEGATIVE, POSITIVE or MARK" % (mode,))
        command = prefix + "REFerence:STARt " + modes[word]
    if not (yield from p_motion(sess, prefix, command, wait, timeout, poll)):
        return None
    referenced = yield from p_bool(prefix + "REFerence?")
    if not referenced:
        raise MoveError("%s came to rest but REFerence? answers 0" % command)
    return True


def p_status(sess: Session, key: AxisKey) -> Plan:
    prefix = yield from p_prefix(sess, key)
    raw = yield Line(prefix + "STATus?")
    bits = yield from p_optional(sess, prefix + "STATus:OPERation?", "STATus:OPERation")
    return AxisStatus.parse(raw, None if bits is None else
                            Operation(parse_int(bits, "STATus:OPERation?")))


def p_axis_query(sess: Session, key: AxisKey, header: str, parse: Callable[[str, str], Any]) -> Plan:
    prefix = yield from p_prefix(sess, key)
    reply = yield Line(prefix + header)
    return parse(reply, prefix + header)


def p_axis_set(sess: Session, key: AxisKey, header: str, *values: Any) -> Plan:
    prefix = yield from p_prefix(sess, key)
    yield Line(prefix + header + " " + ",".join(fmt(v, header) for v in values))


def p_axis_command(sess: Session, key: AxisKey, header: str) -> Plan:
    prefix = yield from p_prefix(sess, key)
    yield Line(prefix + header)


def p_limits(sess: Session, key: AxisKey) -> Plan:
    prefix = yield from p_prefix(sess, key)
    reply = yield Line(prefix + "LIMit?")
    lo, sep, hi = reply.partition(",")
    if not sep:
        raise IdmError("LIMit? answered %r, not <lower>,<upper>" % reply)
    return (parse_number(lo, "LIMit? lower"), parse_number(hi, "LIMit? upper"))


def p_region(sess: Session, key: AxisKey, freq_hz: Any, duty: Any, stroke_m: Any) -> Plan:
    prefix = yield from p_prefix(sess, key)
    args = [fmt(freq_hz, "freq_hz"), fmt(duty, "duty")]
    if stroke_m is not None:
        args.append(fmt(stroke_m, "stroke_m"))
    reply = yield Line(prefix + "REGion? " + ",".join(args))
    word, sep, step = reply.partition(",")
    if not sep:
        raise IdmError("REGion? answered %r, not <region>,<step>" % reply)
    return word.strip(), parse_number(step, "REGion? step")


# ---- the whole instrument --------------------------------------------------------------------

def p_positions(sess: Session, allow_untrusted: bool = False) -> Plan:
    """``POSition:ALL?``. A position the daemon cannot trust comes as ``9.91E37`` with -230
    queued: that error is raised (the reply is in its ``.reply``), or, with
    ``allow_untrusted``, that position is NaN in the list (only when -230 is all that was
    queued)."""
    try:
        reply = yield Line("POSition:ALL?")
    except ScpiError as e:
        if not (allow_untrusted and e.reply and all(code == UNTRUSTED for code, _ in e.errors)):
            raise
        reply = e.reply
    return [parse_number(x, "POSition:ALL?") for x in reply.split(",")]


def p_reset(wait: bool, timeout: Optional[float]) -> Plan:
    yield Line("*RST")
    if wait:
        yield Line("*OPC?", timeout)


def p_opc(timeout: Optional[float]) -> Plan:
    reply = yield Line("*OPC?", timeout)
    if reply.strip() != "1":
        raise IdmError("*OPC? answered %r, not 1" % reply)
    return True


def p_register(text: str, flags: Any) -> Plan:
    value = yield from p_int(text)
    return flags(value)


def p_loop_stats() -> Plan:
    reply = yield Line("SYSTem:LOOP?")
    return LoopStats.parse(reply)

