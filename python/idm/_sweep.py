"""The plans of sweeps (``SWEep``): start one, follow its progress, wait for its end; free of
I/O like the rest of the protocol logic (:mod:`idm._core`)."""

from __future__ import annotations

import numbers
import os
import time
from typing import Any, Optional

from ._core import (AxisKey, Line, Plan, Session, count_list, fmt, fmt_list, p_bool, p_optional,
                    p_prefix, p_wait_axis, quote)
from .errors import SweepError
from .status import AxisStatus, SweepState


class SweepInfo:
    """What a started sweep is: its axis prefix, the command line, the trials it will record,
    where its dataset is (the daemon's directory from ``SWEEP?``; the data directory when it is
    known here), the daemon_error before it started."""

    def __init__(self, sess: Session, mark: int, prefix: str, command: str, directory: str,
                 total: Optional[int], data_dir: Optional[str], error_before: str,
                 daemon_dir: Optional[str] = None):
        self.session = sess
        self.mark = mark
        self.prefix = prefix
        self.command = command
        self.directory = directory
        self.total = total
        self.data_dir = data_dir
        self.error_before = error_before
        # SWEEP?'s directory of this sweep (None: the daemon does not answer SWEEP?, or another
        # sweep showed there already): while SWEEP? names it, SWEEP? is this sweep's state.
        self.daemon_dir = daemon_dir
        self.started = time.monotonic()
        self.finished = False
        self.stopped = False


def p_sweep_query() -> Plan:
    """``SWEEP?`` parsed (the daemon's last or running sweep)."""
    reply = yield Line("SWEEP?")
    return SweepState.parse(reply)


def _same_dataset(daemon_dir: str, directory: str) -> bool:
    """SWEEP? names the dataset below the daemon's data directory: ``<data_dir>/<directory>``."""
    rel = directory.strip("/")
    return daemon_dir == directory or daemon_dir.endswith("/" + rel)


def p_sweep_start(sess: Session, key: AxisKey, directory: str, freqs: Any, duties: Any,
                  trials: Any, cycles: Any, data_dir: Optional[str]) -> Plan:
    args = [quote(directory), fmt_list(freqs, "freqs"), fmt_list(duties, "duties"),
            fmt(trials, "trials")]
    if cycles is not None:
        args.append(fmt(cycles, "cycles"))
    prefix = yield from p_prefix(sess, key)
    before = AxisStatus.parse((yield Line(prefix + "STATus?")))
    # Known before the sweep starts (p_multi_axis probed it; a probe answered -113 is followed
    # by *CLS, which must not clear a fault the sweep could queue).
    has_query = sess.caps.get("SWEEP?")
    if has_query is None:
        has_query = (yield from p_optional(sess, "SWEEP?", "SWEEP?")) is not None
    command = prefix + "SWEEP " + ",".join(args)
    mark = sess.fault_seq
    yield Line(command)
    nf, nd = count_list(freqs), count_list(duties)
    total = None
    if nf is not None and nd is not None and isinstance(trials, numbers.Integral):
        total = nf * nd * int(trials)
    daemon_dir = None
    if has_query:
        state = yield from p_sweep_query()
        if _same_dataset(state.directory, directory):
            daemon_dir = state.directory
            total = state.planned
    return SweepInfo(sess, mark, prefix, command, directory, total, data_dir,
                     str(before.get("daemon_error", "none")), daemon_dir)


def p_sweep_state(info: SweepInfo) -> Plan:
    """SWEEP? when it still shows this sweep, else None."""
    if info.daemon_dir is None:
        return None
    state = yield from p_sweep_query()
    if state.directory != info.daemon_dir:
        return None  # another sweep has started since
    return state


def recorded_trials(info: SweepInfo) -> Optional[int]:
    """Trials in the dataset's sweep.csv so far (the daemon rewrites it, atomically, after each
    trial); None when the data directory is not known here."""
    if info.data_dir is None:
        return None
    path = os.path.join(info.data_dir, info.directory, "sweep.csv")
    try:
        with open(path, encoding="utf-8") as f:
            rows = [line for line in f.read().splitlines() if line.strip()]
    except FileNotFoundError:
        return 0
    return max(0, len(rows) - 1)


def p_sweep_progress(info: SweepInfo) -> Plan:
    state = yield from p_sweep_state(info)
    done = yield from p_bool(info.prefix + "MOVE:DONE?")
    if state is not None:
        return SweepProgress(done, state.written, state.planned,
                             time.monotonic() - info.started, state.failed, state.state)
    return SweepProgress(done, recorded_trials(info), info.total,
                         time.monotonic() - info.started)


def p_sweep_wait(info: SweepInfo, timeout: Optional[float], poll: float) -> Plan:
    """Until the sweep has ended; then it must have ended well. Where the daemon answers
    ``SWEEP?``: state ``DONE``, no trial failed, every planned trial written. Elsewhere: no new
    ``daemon_error`` (the daemon's report of failed trials), not stopped by :meth:`Sweep.stop`,
    and, where the dataset is readable here, every trial recorded."""
    yield from p_wait_axis(info.prefix, timeout, poll, info.command, stop_on_timeout=False,
                           faults=(info.session, info.mark))
    info.finished = True
    state = yield from p_sweep_state(info)
    elapsed = time.monotonic() - info.started
    if state is not None:
        progress = SweepProgress(True, state.written, state.planned, elapsed, state.failed,
                                 state.state)
        counts = "%d of %d trials written, %d failed" % (state.written, state.planned,
                                                        state.failed)
        if state.state == "STOPPED":
            why = "by Sweep.stop()" if info.stopped else "by a STOP or *RST"
            raise SweepError("%s was stopped (%s): %s" % (info.command, why, counts), progress)
        if not state.ok:
            st = AxisStatus.parse((yield Line(info.prefix + "STATus?")))
            err = str(st.get("daemon_error", "none"))
            said = "" if err in ("none", info.error_before) else "; the daemon reports: " + \
                err.replace("_", " ")
            raise SweepError("%s ended %s: %s%s" % (info.command, state.state, counts, said),
                             progress)
        return progress
    # A daemon without SWEEP? (or another sweep has started since this one ended).
    st = AxisStatus.parse((yield Line(info.prefix + "STATus?")))
    err = str(st.get("daemon_error", "none"))
    recorded = recorded_trials(info)
    progress = SweepProgress(True, recorded, info.total, elapsed)
    if err != "none" and err != info.error_before:
        raise SweepError("%s ended with the daemon reporting: %s" % (info.command,
                                                                      err.replace("_", " ")),
                         progress)
    if info.stopped:
        raise SweepError("%s was stopped (Sweep.stop()) after %s trials" % (
            info.command, "?" if recorded is None else recorded), progress)
    if recorded is not None and info.total is not None and recorded < info.total:
        raise SweepError("%s ended with %d of %d trials recorded in %s" % (
            info.command, recorded, info.total, os.path.join(info.data_dir or "", info.directory)),
            progress)
    return progress


class SweepProgress:
    """A sweep's progress: ``done`` (the daemon's MOVE:DONE? of the axis), ``recorded`` trials
    written to the dataset (``SWEEP?``; on a daemon without it, counted in the dataset when
    the daemon's data directory is readable here, else None), ``total`` trials the sweep
    holds (None when it could not be known), ``elapsed`` seconds since it started; with
    ``SWEEP?`` also ``failed`` trials and ``state`` (``RUNNING``, ``DONE``, ``STOPPED``,
    ``FAILED``), None otherwise."""

    def __init__(self, done: bool, recorded: Optional[int], total: Optional[int], elapsed: float,
                 failed: Optional[int] = None, state: Optional[str] = None):
        self.done = done
        self.recorded = recorded
        self.total = total
        self.elapsed = elapsed
        self.failed = failed
        self.state = state

    @property
    def fraction(self) -> Optional[float]:
        if self.recorded is None or not self.total:
            return None
        return min(1.0, self.recorded / self.total)

    def __repr__(self) -> str:
        return ("SweepProgress(done=%r, recorded=%r, total=%r, elapsed=%.3f, failed=%r, "
                "state=%r)" % (self.done, self.recorded, self.total, self.elapsed, self.failed,
                               self.state))
