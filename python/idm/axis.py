"""The axes a client hands out (``client.axis(n or name)``) and the sweeps they start: the same
objects for :class:`idm.Client` and :class:`idm.aio.AsyncClient` (with the latter every method
returns an awaitable)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Optional

from . import _core, _sweep
from ._core import AxisKey, Plan, Session
from ._sweep import SweepInfo
from .status import MoveResult, Operation, parse_bool, parse_number

if TYPE_CHECKING:  # the clients import this module
    from .client import _Api

__all__ = ["Axis", "Sweep"]


class Axis:
    """One axis of a daemon, from ``client.axis(n or name)``.

    With :class:`idm.Client` every method returns its result; with
    :class:`idm.aio.AsyncClient` it returns an awaitable of it (``await axis.move(1e-6)``).
    Lengths in m, times in s. Methods that wait take ``timeout`` (default: the client's
    ``wait_timeout``); a wait that times out stops the axis and raises
    :class:`~idm.IdmTimeout`."""

    def __init__(self, client: _Api, key: AxisKey):
        if isinstance(key, bool) or not isinstance(key, (int, str)):
            raise TypeError("an axis is a number (from 1) or a name, not %r" % (key,))
        self.client = client
        self.key = key

    def __repr__(self) -> str:
        return "Axis(%r)" % (self.key,)

    def _run(self, plan: Plan) -> Any:
        return self.client._run(plan)

    def _timeout(self, timeout: Optional[float]) -> Optional[float]:
        return self.client.wait_timeout if timeout is None else timeout

    @property
    def _s(self) -> Session:
        return self.client._session

    def number(self):
        """The axis's number (a name resolved with ``AXIS<n>:NAME?``)."""
        return self._run(_core.p_axis_number(self._s, self.key))

    def name(self):
        """``AXIS<n>:NAME?``."""
        return self._run(_core.p_axis_query(self._s, self.key, "NAME?", lambda r, w: r.strip()))

    # -- motion --
    def move(self, target: float, *, wait: bool = True, timeout: Optional[float] = None,
             tolerance: Optional[float] = None):
        """``MOVE:ABSolute target``: a closed-loop move. With ``wait`` (default) it polls
        ``MOVE:DONE?`` until the axis is at rest and returns the position then; a refusal
        (-222 past a soft limit, -221 busy or unreferenced, ...) or a fault the move ended in
        (positive code) is raised as :class:`~idm.ScpiError`, a ``MOVE:RESult?`` other than OK
        as :class:`~idm.MoveError`. Where the daemon does not answer ``MOVE:RESult?``,
        ``tolerance`` (m) asks for a client-side check of the reading against ``MOVE?``.
        Without ``wait`` it returns ``None`` once the daemon has accepted the move; a fault is
        then raised by the next call on this connection."""
        return self._run(_core.p_move(self._s, self.key, target, False, wait,
                                      self._timeout(timeout), self.client.poll_interval,
                                      tolerance))

    def move_by(self, distance: float, *, wait: bool = True, timeout: Optional[float] = None,
                tolerance: Optional[float] = None):
        """``MOVE:RELative distance``; otherwise as :meth:`move`."""
        return self._run(_core.p_move(self._s, self.key, distance, True, wait,
                                      self._timeout(timeout), self.client.poll_interval,
                                      tolerance))

    def step(self, cycles: int, duty: Optional[float] = None, freq_hz: Optional[float] = None,
             stroke_m: Optional[float] = None, *, wait: bool = True,
             timeout: Optional[float] = None):
        """``STEP cycles[,duty,freq_hz[,stroke_m]]``: an open-loop burst of |cycles| cycles.
        The sign of cycles alone picks the direction (positive: the positive direction);
        ``duty`` is given as for the positive direction, and the daemon mirrors it for negative
        cycles (the protocol's STEP). ``cycles`` is sent as given, sign and all (a float that is
        a whole number as an integer). Returns the position after it when waiting."""
        return self._run(_core.p_step(self._s, self.key, cycles, duty, freq_hz, stroke_m, wait,
                                      self._timeout(timeout), self.client.poll_interval))

    def jog(self, direction: Any, *, wait: bool = False, timeout: Optional[float] = None):
        """``JOG POSitive|NEGative``: a continuous move that way at the speed limit
        (:meth:`velocity`), to the soft limit less the window; :meth:`stop` (or any STOP) ends
        it. ``direction``: ``"positive"``, ``"+"`` or ``1``; ``"negative"``, ``"-"`` or ``-1``
        (anything else is a ``ValueError``, nothing sent). Without ``wait`` (the default: a jog
        is meant to be stopped) it returns ``None`` once the daemon has accepted it; with
        ``wait`` it returns the position where the jog ended, at the limit (``OK``) or stopped
        by this connection (``STOPPED``); any other end raises as :meth:`move` does (a STOP from
        another connection: the daemon's 114 as :class:`~idm.DeviceFault`)."""
        return self._run(_core.p_jog(self._s, self.key, direction, wait, self._timeout(timeout),
                                     self.client.poll_interval))

    def stop(self):
        """Stop this axis (and a sweep running on it): ``AXIS<n>:STOP``; plain ``STOP`` on a
        daemon without the several-axes extension. Other axes go on."""
        return self._run(_core.p_axis_command(self._s, self.key, "STOP"))

    def done(self):
        """``MOVE:DONE?``: at rest."""
        return self._run(_core.p_axis_query(self._s, self.key, "MOVE:DONE?", parse_bool))

    def wait(self, timeout: Optional[float] = None, *, stop_on_timeout: bool = True):
        """Poll ``MOVE:DONE?`` until at rest; a fault the motion ended in is raised."""
        def plan():
            prefix = yield from _core.p_prefix(self._s, self.key)
            return (yield from _core.p_wait_axis(prefix, self._timeout(timeout),
                                                 self.client.poll_interval, None,
                                                 stop_on_timeout=stop_on_timeout))
        return self._run(plan())

    def reference(self, mode: Optional[str] = None, *, wait: bool = True,
                  timeout: Optional[float] = None):
        """``REFerence`` (the config's default) or ``REFerence:STARt NEGative|POSitive|MARK``;
        with ``wait``, until at rest, then ``REFerence?`` must answer 1."""
        return self._run(_core.p_reference(self._s, self.key, mode, wait, self._timeout(timeout),
                                           self.client.poll_interval))

    def referenced(self):
        """``REFerence?``."""
        return self._run(_core.p_axis_query(self._s, self.key, "REFerence?", parse_bool))

    # -- readings --
    def position(self):
        """``POSition?``, m. A position that cannot be trusted raises the daemon's error: -230
        (the daemon answers ``9.91E37``, kept in the error's ``.reply``; never returned as a
        number), or -240 from a daemon before the several-axes extension."""
        return self._run(_core.p_axis_query(self._s, self.key, "POSition?", parse_number))

    def target(self):
        """``MOVE?``: the target, m."""
        return self._run(_core.p_axis_query(self._s, self.key, "MOVE?", parse_number))

    def status(self):
        """``STATus?`` parsed (:class:`~idm.AxisStatus`), with ``operation`` the
        ``STATus:OPERation?`` bits where the daemon answers it."""
        return self._run(_core.p_status(self._s, self.key))

    def operation(self):
        """``STATus:OPERation?`` as :class:`~idm.Operation`."""
        return self._run(_core.p_axis_query(self._s, self.key, "STATus:OPERation?",
                                            lambda r, w: Operation(_core.parse_int(r, w))))

    def result(self):
        """``MOVE:RESult?`` as :class:`~idm.MoveResult` (word, final distance)."""
        return self._run(_core.p_axis_query(self._s, self.key, "MOVE:RESult?",
                                            lambda r, w: MoveResult.parse(r)))

    def resolution(self):
        """``RESolution?``: one interferometer count, m."""
        return self._run(_core.p_axis_query(self._s, self.key, "RESolution?", parse_number))

    def region(self, freq_hz: float, duty: float, stroke_m: Optional[float] = None):
        """``REGion? freq,duty[,stroke]``: ``(region, predicted step m)``."""
        return self._run(_core.p_region(self._s, self.key, freq_hz, duty, stroke_m))

    # -- the user frame --
    def set_position(self, position: float):
        """``POSition:SET``: the current position becomes ``position`` m; nothing moves, the user
        offset changes. At rest only (-221 while moving), with a trusted position (-230)."""
        return self._run(_core.p_axis_set(self._s, self.key, "POSition:SET", position))

    def offset(self):
        """``POSition:OFFSet?``: the user offset, m. Every position the daemon shows or takes
        (position, target, soft limits) is the axis's own plus it."""
        return self._run(_core.p_axis_query(self._s, self.key, "POSition:OFFSet?", parse_number))

    def set_offset(self, metres: float):
        """``POSition:OFFSet``: the user offset, m ([-10, 10], else -222)."""
        return self._run(_core.p_axis_set(self._s, self.key, "POSition:OFFSet", metres))

    # -- settings --
    def limits(self):
        """``LIMit?``: ``(lower, upper)`` soft limits, m."""
        return self._run(_core.p_limits(self._s, self.key))

    def set_limits(self, lower: float, upper: float):
        """``LIMit lower,upper``."""
        return self._run(_core.p_axis_set(self._s, self.key, "LIMit", lower, upper))

    def set_lower_limit(self, lower: float):
        """``LIMit:LOWer``."""
        return self._run(_core.p_axis_set(self._s, self.key, "LIMit:LOWer", lower))

    def set_upper_limit(self, upper: float):
        """``LIMit:UPPer``."""
        return self._run(_core.p_axis_set(self._s, self.key, "LIMit:UPPer", upper))

    def window(self):
        """``MOVE:WINDow?``: the in-position window, m."""
        return self._run(_core.p_axis_query(self._s, self.key, "MOVE:WINDow?", parse_number))

    def set_window(self, metres: float):
        """``MOVE:WINDow``."""
        return self._run(_core.p_axis_set(self._s, self.key, "MOVE:WINDow", metres))

    def velocity(self):
        """``MOVE:VELocity?``: the speed limit of the moves and jogs that follow, m/s (0: none)."""
        return self._run(_core.p_axis_query(self._s, self.key, "MOVE:VELocity?", parse_number))

    def set_velocity(self, metres_per_second: float):
        """``MOVE:VELocity``: the speed limit, m/s (0: none); out of the daemon's range
        (``control.max_speed_m_s``'s, [0, 1] m/s) -222 naming the command and the range."""
        return self._run(_core.p_axis_set(self._s, self.key, "MOVE:VELocity", metres_per_second))

    def dwell(self):
        """``MOVE:DWELl?``: how long readings must stay in the window, s."""
        return self._run(_core.p_axis_query(self._s, self.key, "MOVE:DWELl?", parse_number))

    def set_dwell(self, seconds: float):
        """``MOVE:DWELl``."""
        return self._run(_core.p_axis_set(self._s, self.key, "MOVE:DWELl", seconds))

    def hold(self):
        """``HOLD?``: hold time after moves, s (0 none, -1 until the next motion or STOP)."""
        return self._run(_core.p_axis_query(self._s, self.key, "HOLD?", parse_number))

    def set_hold(self, seconds: float):
        """``HOLD``."""
        return self._run(_core.p_axis_set(self._s, self.key, "HOLD", seconds))

    def hold_window(self):
        """``HOLD:WINDow?``, m."""
        return self._run(_core.p_axis_query(self._s, self.key, "HOLD:WINDow?", parse_number))

    def set_hold_window(self, metres: float):
        """``HOLD:WINDow``."""
        return self._run(_core.p_axis_set(self._s, self.key, "HOLD:WINDow", metres))

    def eot_cycles(self):
        """``EOT:CYCLes?``: cycles over which end of travel is judged."""
        return self._run(_core.p_axis_query(self._s, self.key, "EOT:CYCLes?",
                                            lambda r, w: _core.parse_int(r, w)))

    def set_eot_cycles(self, cycles: int):
        """``EOT:CYCLes``."""
        return self._run(_core.p_axis_set(self._s, self.key, "EOT:CYCLes", cycles))

    def eot_step(self):
        """``EOT:STEP?``: the mean step below which the axis is at an end of travel, m."""
        return self._run(_core.p_axis_query(self._s, self.key, "EOT:STEP?", parse_number))

    def set_eot_step(self, metres: float):
        """``EOT:STEP``."""
        return self._run(_core.p_axis_set(self._s, self.key, "EOT:STEP", metres))

    def push(self, metres: float):
        """``SIMulation:PUSH``: displace the simulated slider at once (simulated stage only;
        a real backend refuses it with -241)."""
        return self._run(_core.p_axis_set(self._s, self.key, "SIMulation:PUSH", metres))

    # -- sweeps --
    def sweep(self, directory: str, freqs: Any, duties: Any, trials: int,
              cycles: Optional[int] = None, *, data_dir: Optional[str] = None):
        """``SWEEP directory,freqs,duties,trials[,cycles]``: start the characterization sweep;
        returns a :class:`Sweep` to follow it. ``freqs``/``duties``: a number, a sequence
        (sent ``a;b;c``) or the protocol's ``"a:b:step"``. ``directory`` is below the daemon's
        ``recording.data_dir``; give that as ``data_dir`` when it is readable here and
        :meth:`Sweep.progress` counts the trials recorded so far."""
        client = self.client

        def plan():
            info = yield from _sweep.p_sweep_start(self._s, self.key, directory, freqs, duties,
                                                  trials, cycles, data_dir)
            return Sweep(client, info)
        return self._run(plan())

    # -- Bluesky --
    def movable(self, name: Optional[str] = None, **kwargs: Any):
        """A Bluesky-style movable of this axis (:class:`idm.bluesky.AxisMovable`); the
        synchronous client only."""
        from .bluesky import AxisMovable
        return AxisMovable(self, name=name, **kwargs)


class Sweep:
    """A sweep started by :meth:`Axis.sweep`: ``progress()``, ``done()``, ``wait(timeout)``
    (raises :class:`~idm.SweepError` if the daemon reports the sweep failed), ``stop()``."""

    def __init__(self, client: _Api, info: SweepInfo):
        self.client = client
        self.info = info

    @property
    def command(self) -> str:
        return self.info.command

    @property
    def total(self) -> Optional[int]:
        """The number of trials the sweep records (frequencies x duties x trials; the
        daemon's ``SWEEP?`` count where it answers it)."""
        return self.info.total

    @property
    def directory(self) -> Optional[str]:
        """The dataset's directory as the daemon names it (``SWEEP?``), else None."""
        return self.info.daemon_dir

    def progress(self):
        """:class:`~idm.SweepProgress`: done, trials recorded / total (and failed, state
        where the daemon answers ``SWEEP?``), elapsed."""
        return self.client._run(_sweep.p_sweep_progress(self.info))

    def state(self):
        """This sweep's :class:`~idm.SweepState` (``SWEEP?``); None when the daemon does not
        answer ``SWEEP?`` or when a later sweep has replaced it there."""
        return self.client._run(_sweep.p_sweep_state(self.info))

    def done(self):
        return self.client._run(_core.p_bool(self.info.prefix + "MOVE:DONE?"))

    def wait(self, timeout: Optional[float] = None):
        """Until the sweep has ended (``timeout`` None: no bound, a sweep may take hours; every
        poll still has the reply timeout). Returns the final progress; raises
        :class:`~idm.SweepError` when it did not end well: stopped (by :meth:`stop`, another
        client's STOP or ``*RST``), a trial failed, or fewer trials written than the sweep
        holds (``SWEEP?``; on a daemon without it: a ``STATus?`` ``daemon_error``, :meth:`stop`,
        or with ``data_dir`` the dataset's trial count)."""
        return self.client._run(_sweep.p_sweep_wait(self.info, timeout, self.client.poll_interval))

    def stop(self):
        """Stop the sweep (its axis's STOP); ``wait()`` then raises :class:`~idm.SweepError`
        unless the sweep had already ended well."""
        self.info.stopped = True
        return self.client._run(_core.p_line(self.info.prefix + "STOP"))

    def __repr__(self) -> str:
        return "Sweep(%r)" % self.info.command
