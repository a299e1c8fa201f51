"""A stateful, randomized test of the real idmd on the simulated stage (CTest daemon.stateful.short
and daemon.stateful.long).

A seeded generator drives idmd (config/idmd.yaml: one axis; config/idmd-xyz.yaml: three) through
its sockets, with several plain clients at once (TCP and the Unix socket), in random sequences of
MOVE:ABS / MOVE:REL (targets near and past the soft limits and the travel), STEP (both signs, with
and without duty, frequency and stroke, some out of range), small SWEEPs, STOP / ABORt /
AXIS<n>:STOP, *RST, SIGHUP, SIM:PUSH, SIM:FAULt (beam_lost, stalled, glitches), soft-limit
changes, MOVE:WINDow / MOVE:DWELl / HOLD / HOLD:WINDow, connections opened and closed, half a
command then close, and *OPC? (answered at once or left waiting while others go on). After every
step it checks:

  (a) no reading outside the soft limits by more than one step's worth (the largest step of the
      axis's map, from REG?, plus the window), the limits widened to where the slider rested when
      they were set (or pushed);
  (b) no motion without a motion command: an axis that no client moved since it was last at rest
      rests where it was (a few counts), or where SIM:PUSH put it;
  (c) in position (STAT? in_position=1) means the mean reading at rest is within the window of
      the target (MOVE:WINDow, 0: one count; the hold window while holding), and MOVE:REL goes
      from the reading unless the axis truly is in position;
  (d) every motion ends honestly: MOVE:RESult? OK only when the fresh mean reading is within the
      window of the target; any other end leaves an error in the queue of the client that started
      it (a positive code, or -200), except a STOP (or *RST) that client asked for, which ends
      STOPPED; a SWEEP stopped other than by its own client leaves it an error too;
  (e) idmd never crashes or hangs: every query answered within REPLY_BOUND_S, *OPC? and rest
      within the move timeout, the process alive after every step, exit 0 on SIGTERM.

What it knows of the daemon comes from daemon/README.md and the README's tables, and from queries
(LIM?, RES?, REG?, REG:RANG?, STAT?), never from the daemon's code.

Why a generator of its own and not hypothesis's RuleBasedStateMachine: one example here is a real
daemon on the wall clock (0.5-1 s to start, up to 3 s a move), and Debian's hypothesis (6.67)
shrinks without a time bound (up to 500 successful shrinks, each a full replay on a fresh idmd):
a 3-minute CTest budget cannot hold once anything fails. Outcomes depend on timing (a STOP landing
mid-move or after it, a *RST between two sweep trials), which hypothesis reports as Flaky instead
of shrinking. And hypothesis stops an example at its first failure, where this test goes on and
reports every class of violation once, so that one run shows which defects are left. So: a seeded
random generator (episode k of master seed S draws from random.Random(S * 1000003 + k)) whose
steps are concrete protocol lines, recorded; on failure the seed, the numbered steps and the
violations are printed and saved (trace.json, with idmd's log, in the kept temporary directory),
and `replay=TRACE` / `minimize=TRACE[:CLASS]` re-run them (minimize: delta debugging within a time
budget, each candidate on a fresh idmd, kept only if the same class of violation comes back).

    stateful_daemon.py BUILD_DIR SOURCE_DIR short            ~150 s (CTest daemon.stateful.short)
    stateful_daemon.py BUILD_DIR SOURCE_DIR long             IDM_STATEFUL_LONG_S seconds (unset:
                                                             skipped, exit 77; ./idm check sets it)
    stateful_daemon.py BUILD_DIR SOURCE_DIR replay=TRACE     the steps of a saved trace again
    stateful_daemon.py BUILD_DIR SOURCE_DIR minimize=TRACE[:CLASS]
Environment: IDM_STATEFUL_SEED (master seed), IDM_STATEFUL_BUDGET_S (the run's generation time),
IDM_STATEFUL_MINIMIZE_S (minimization budget after a failed run; the long run's default 600),
IDM_STATEFUL_WITHOUT (actions left out, e.g. `sweep,push,sighup,rst`, to check one fix at a time).
"""
import json
import math
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import time

import script_harness as harness

REPLY_BOUND_S = 10.0      # (e): every query answered within this
MOVE_TIMEOUT_S = 120.0    # control.move_timeout_s's default: *OPC? and rest within it (and a margin)
REST_BOUND_S = MOVE_TIMEOUT_S + 10.0
SIGTERM_BOUND_S = 30.0
INVALID = 9e37            # 9.91E37: a position that cannot be trusted
NOISE_COUNTS = 3          # (b): a position at rest repeats within this many counts
REST_SAMPLES = 24         # readings averaged for a position at rest
MOTION_END_CODES = "a positive code or -200"
ROOT = None               # the run's directory (harness.TMP points at the episode's while it runs)
# Actions the generator leaves out (IDM_STATEFUL_WITHOUT=sweep,push,...: the names of Generator's
# gen_* methods), to check one fix at a time.
WITHOUT = [w for w in os.environ.get("IDM_STATEFUL_WITHOUT", "").split(",") if w]


def motion_end_error(code):
    """An error a motion's end leaves (README's error table: 101-108 faults, 111-113 LIMIT,
    END_OF_TRAVEL, TIMEOUT, -200 a fault without a code of its own); the negative others are
    refusals of commands."""
    return code > 0 or code == -200


def fmt(x):
    return "%.9g" % x


class Unresponsive(Exception):
    """(e): idmd did not answer, closed a connection, or exited; `conn` the connection that
    waited."""

    def __init__(self, msg, conn=None):
        super().__init__(msg)
        self.conn = conn


class EndEpisode(Exception):
    pass


# ---- Connections ------------------------------------------------------------------------------

class Conn(harness.Client):
    """A plain line client whose failures raise Unresponsive instead of ending the script."""

    def __init__(self, d, unix):
        try:
            super().__init__(d, unix=unix, timeout=REPLY_BOUND_S)
        except OSError as e:
            raise Unresponsive("cannot connect (%s): %s" % ("unix" if unix else "tcp", e))
        self.unix = unix

    def send(self, text):
        try:
            super().send(text)
        except OSError as e:
            raise Unresponsive("send %r: %s" % (text, e))

    def reply(self, what, timeout=REPLY_BOUND_S):
        self.s.settimeout(timeout)
        try:
            r = self.line()
        except socket.timeout:
            raise Unresponsive("no reply to %r within %g s" % (what, timeout), self)
        except OSError as e:
            raise Unresponsive("reading the reply to %r: %s" % (what, e))
        if r is None:
            raise Unresponsive("idmd closed the connection (after %r)" % what)
        return r

    def ask(self, query, timeout=REPLY_BOUND_S):
        self.send(query + "\n")
        return self.reply(query, timeout)


def parse_error(reply):
    code, _, text = reply.partition(",")
    try:
        return int(code), text
    except ValueError:
        raise Unresponsive("SYST:ERR? answered %r" % reply)


# ---- The generator: concrete steps from a seed and what the README says ------------------------

class Generator:
    """Draws the next steps from its seed and its own idea of the state (what it asked for, never
    what the daemon answered), so that a seed gives the same steps on every run. `info` is what
    the config fixes, read once at the episode's start: per axis its travel, frequency and stroke
    range."""

    def __init__(self, seed, info):
        self.r = random.Random(seed)
        self.info = info
        self.n = len(info)
        self.lim = [list(a["travel"]) for a in info]
        self.pos = [0.0] * self.n
        self.slots = {0: False, 1: True}  # client slot -> over the Unix socket
        self.next_slot = 2
        self.opc_waiting = set()
        self.injected = set()
        self.sweeps = 0
        self.running = False  # the last action started a motion and did not wait for its end

    # helpers
    def log_uniform(self, lo, hi):
        return math.exp(self.r.uniform(math.log(lo), math.log(hi)))

    def axis(self):
        return self.r.randint(1, self.n)

    def prefix(self, axis):
        if axis == 1 and self.r.random() < 0.5:
            return ""
        return "AXIS%d:" % axis

    def client(self):
        free = [c for c in self.slots if c not in self.opc_waiting]
        return self.r.choice(free) if free else None

    def wait(self):
        w = self.r.random() < 0.5
        self.running = not w
        return w

    def target(self, a):
        lo, hi = self.lim[a - 1]
        tlo, thi = self.info[a - 1]["travel"]
        kind = self.r.choices(["inside", "near", "past", "travel", "here"], [3, 2, 2, 1, 2])[0]
        side = self.r.choice([-1, 1])
        edge = hi if side > 0 else lo
        if kind == "inside":
            return self.r.uniform(lo, hi)
        if kind == "near":
            return edge - side * self.r.uniform(0, 2e-5)
        if kind == "past":
            return edge + side * self.r.uniform(0, 2e-5)
        if kind == "travel":
            return (thi if side > 0 else tlo) + side * self.log_uniform(1e-9, 1e-3)
        return self.pos[a - 1] + side * self.log_uniform(1e-8, 5e-5)

    # one action: a list of steps
    def next(self):
        r = self.r
        acts = {"move_abs": 14, "move_rel": 10, "step": 10, "sweep": 5, "stop": 5, "rst": 3,
                "sighup": 2, "push": 6, "fault": 3 + 12 * bool(self.injected), "lim": 6,
                "set": 6, "clients": 3, "half": 3, "opc": 3, "watch": 3, "settle": 8}
        if self.running:  # a motion is on: what may come in the middle of it, more often
            for name, more in (("stop", 8), ("rst", 6), ("sighup", 4), ("push", 4), ("lim", 3), ("opc", 3)):
                acts[name] += more
        self.running = False
        for name in WITHOUT:
            acts[name] = 0
        act = r.choices(list(acts), list(acts.values()))[0]
        c = self.client()
        if c is None:
            act = "settle"
        return getattr(self, "gen_" + act)(c)

    def gen_move_abs(self, c):
        a = self.axis()
        x = self.target(a)
        lo, hi = self.lim[a - 1]
        if lo <= x <= hi:
            self.pos[a - 1] = x
        return [dict(op="move", c=c, axis=a, rel=False, value=x, wait=self.wait(),
                     line="%sMOVE%s %s" % (self.prefix(a), self.r.choice(["", ":ABS", ":ABSOLUTE"]), fmt(x)))]

    def gen_move_rel(self, c):
        a = self.axis()
        d = self.r.choice([-1, 1]) * self.log_uniform(1e-9, 1.2e-2)
        return [dict(op="move", c=c, axis=a, rel=True, value=d, wait=self.wait(),
                     line="%sMOVE:REL %s" % (self.prefix(a), fmt(d)))]

    def gen_step(self, c):
        r = self.r
        a = self.axis()
        n = r.choice([-1, 1]) * (r.randint(1, 40) if r.random() < 0.95 else r.randint(100, 2000))
        args = [str(n)]
        info = self.info[a - 1]
        if r.random() < 0.5:
            duty = round(r.uniform(0.02, 0.98), 3) if r.random() < 0.95 else r.choice([0.5, 0, 1.2])
            fmin, fmax = info["freq"]
            freq = round(self.log_uniform(fmin, fmax), 1) if r.random() < 0.95 else fmax * 3
            args += [fmt(duty), fmt(freq)]
            if r.random() < 0.5:
                smin, smax = info["stroke"]
                stroke = self.log_uniform(smin, smax) if r.random() < 0.95 else smax * 2
                args.append(fmt(stroke))
        return [dict(op="step", c=c, axis=a, wait=self.wait(),
                     line="%sSTEP %s" % (self.prefix(a), ",".join(args)))]

    def gen_sweep(self, c):
        r = self.r
        a = self.axis()
        fmin, fmax = self.info[a - 1]["freq"]
        freqs = sorted({round(r.uniform(max(fmin, 50), fmax) / 10) * 10 for _ in range(r.randint(1, 3))})
        duties = sorted({r.choice([0.05, 0.1, 0.2, 0.3, 0.7, 0.8, 0.9, 0.95]) for _ in range(r.randint(1, 2))})
        self.sweeps += 1
        name = "s%03d" % self.sweeps
        line = "%sSWEEP %s,%s,%s,%d,%d" % (self.prefix(a), name, ";".join(fmt(f) for f in freqs),
                                          ";".join(fmt(d) for d in duties), r.randint(1, 2),
                                          r.randint(2, 12))
        return [dict(op="sweep", c=c, axis=a, wait=self.wait(), line=line)]

    def gen_stop(self, c):
        if self.r.random() < 0.6:
            return [dict(op="stop", c=c, axis=None, line=self.r.choice(["STOP", "ABOR", "ABORT"]))]
        a = self.axis()
        return [dict(op="stop", c=c, axis=a, line="AXIS%d:STOP" % a)]

    def gen_rst(self, c):
        return [dict(op="rst", c=c, line="*RST")]

    def gen_sighup(self, c):
        self.lim = [list(a["travel"]) for a in self.info]
        return [dict(op="sighup")]

    def gen_push(self, c):
        a = self.axis()
        d = self.r.choice([-1, 1]) * self.log_uniform(1e-8, 1e-4)
        return [dict(op="push", c=c, axis=a, value=d, line="%sSIM:PUSH %s" % (self.prefix(a), fmt(d)))]

    def gen_fault(self, c):
        r = self.r
        if self.injected and r.random() < 0.8:
            a, name = sorted(self.injected)[r.randrange(len(self.injected))]
            self.injected.discard((a, name))
            steps = [dict(op="fault", c=c, axis=a, line="%sSIM:FAUL %s,0" % (self.prefix(a), name))]
            if not self.injected:
                steps.append(dict(op="rst", c=c, line="*RST"))
            return steps
        a = self.axis()
        name = r.choices(["beam_lost", "stalled", "glitches"], [4, 3, 3])[0]
        value = "1" if name != "glitches" else fmt(r.choice([1e-4, 1e-3, 0.02]))
        self.injected.add((a, name))
        return [dict(op="fault", c=c, axis=a, line="%sSIM:FAUL %s,%s" % (self.prefix(a), name, value))]

    def gen_lim(self, c):
        r = self.r
        a = self.axis()
        tlo, thi = self.info[a - 1]["travel"]
        p = self.prefix(a)
        kind = r.choices(["travel", "narrow", "low", "upp", "bad"], [2, 3, 1, 1, 1])[0]
        if kind == "travel":
            self.lim[a - 1] = [tlo, thi]
            return [dict(op="lim", c=c, axis=a, line="%sLIM %s,%s" % (p, fmt(tlo), fmt(thi)))]
        if kind == "narrow":
            # a window around where the slider is sent first: sweeps and steps then meet its edges
            x = min(max(self.pos[a - 1] + r.uniform(-1e-4, 1e-4), 0.8 * tlo), 0.8 * thi)
            lo, hi = x - self.log_uniform(2e-6, 2e-4), x + self.log_uniform(2e-6, 2e-4)
            self.pos[a - 1] = x
            self.lim[a - 1] = [lo, hi]
            return [dict(op="move", c=c, axis=a, rel=False, value=x, wait=True,
                         line="%sMOVE:ABS %s" % (p, fmt(x))),
                    dict(op="lim", c=c, axis=a, line="%sLIM %s,%s" % (p, fmt(lo), fmt(hi)))]
        lo, hi = self.lim[a - 1]
        if kind == "low":
            v = r.uniform(tlo, hi)
            self.lim[a - 1][0] = v
            return [dict(op="lim", c=c, axis=a, line="%sLIM:LOW %s" % (p, fmt(v)))]
        if kind == "upp":
            v = r.uniform(lo, thi)
            self.lim[a - 1][1] = v
            return [dict(op="lim", c=c, axis=a, line="%sLIM:UPP %s" % (p, fmt(v)))]
        lo, hi = r.choice([(hi, lo), (tlo - 1e-4, thi), (tlo, thi + 1e-3), (lo, lo)])
        return [dict(op="lim", c=c, axis=a, line="%sLIM %s,%s" % (p, fmt(lo), fmt(hi)))]

    def gen_set(self, c):
        r = self.r
        a = self.axis()
        header, values = r.choice([("MOVE:WIND", [0, 5e-9, 1e-8, 3e-8, 1e-7, 1e-6, 2e-3]),
                                   ("MOVE:DWEL", [0, 0.005, 0.02, 0.1, 61]),
                                   ("HOLD", [0, -1, 0.1, 0.5, 2]),
                                   ("HOLD:WIND", [0, 1e-8, 5e-8, 2e-7]),
                                   ("MOVE:VEL", [0, 0, 5e-4, 2e-3, 2])])
        return [dict(op="set", c=c, axis=a, line="%s%s %s" % (self.prefix(a), header, fmt(r.choice(values))))]

    def gen_clients(self, c):
        r = self.r
        if len(self.slots) < 4 and (len(self.slots) < 2 or r.random() < 0.5):
            s = self.next_slot
            self.next_slot += 1
            self.slots[s] = r.random() < 0.5
            return [dict(op="open", c=s, unix=self.slots[s])]
        s = r.choice(sorted(self.slots))
        del self.slots[s]
        self.opc_waiting.discard(s)
        return [dict(op="close", c=s)]

    def gen_half(self, c):
        r = self.r
        a = self.axis()
        text = r.choice(["%sMOVE:ABS %s" % (self.prefix(a), fmt(self.target(a))),
                         "%sMOVE:REL %s" % (self.prefix(a), fmt(r.choice([-1, 1]) * self.log_uniform(1e-7, 1e-3))),
                         "%sSTEP %d" % (self.prefix(a), r.choice([-1, 1]) * r.randint(1, 40)),
                         "*RST", "%sSIM:PUSH 1e-5" % self.prefix(a)])
        if r.random() < 0.3:
            text = "POS?\n" + text
        cut = r.randint(1, len(text))  # half a line: never its newline
        return [dict(op="half", unix=r.random() < 0.5, text=text[:cut])]

    def gen_opc(self, c):
        now = self.r.random() < 0.6
        if not now:
            self.opc_waiting.add(c)
        return [dict(op="opc", c=c, wait=now)]

    def gen_watch(self, c):
        return [dict(op="watch", seconds=round(self.r.uniform(0.05, 0.4), 3))]

    def gen_settle(self, c):
        self.opc_waiting.clear()
        return [dict(op="settle")]


def describe(st):
    """A step as the protocol lines it sends (what a person replays with nc or idmctl)."""
    op = st["op"]
    if "line" in st:
        text = "c%d> %s" % (st["c"], st["line"])
        if st.get("wait"):
            text += "    (then wait until at rest)"
        return text
    if op == "sighup":
        return "kill -HUP idmd"
    if op == "open":
        return "c%d: connect (%s)" % (st["c"], "unix" if st["unix"] else "tcp")
    if op == "close":
        return "c%d: close" % st["c"]
    if op == "half":
        return "new %s connection: send %r (no newline), close" % ("unix" if st["unix"] else "tcp", st["text"])
    if op == "opc":
        return "c%d> *OPC?%s" % (st["c"], "" if st["wait"] else "    (its reply read later)")
    if op == "watch":
        return "watch positions for %g s" % st["seconds"]
    if op == "settle":
        return "wait until every axis is at rest"
    return repr(st)


# ---- The checker: the real daemon and the invariants ------------------------------------------

class Axis:
    def __init__(self, n):
        self.n = n
        self.lim = (-math.inf, math.inf)
        self.env = [-math.inf, math.inf]  # the soft limits widened to where the slider was put
        self.count = 1e-8                 # RES?
        self.step = 0.0                   # the largest step of the map (REG?)
        self.window = self.hold_window = self.move_window = 0.0
        self.rest = None                  # the mean reading at rest the last time (trusted)
        self.moved_by = []                # motion commands (and pushes of unknown effect) since
        self.push = 0.0                   # pushes at rest, not held, since the last rest
        self.kinds = set()                # what moved it since the last rest (labels (a))
        self.pending = None               # the last motion started on it, not yet judged
        self.since_move = set()           # what happened to it since its last MOVE (labels (c))
        self.reported_a = False           # (a) said for this stretch of motion
        self.reported_c = None            # the target (c) was said for
        self.since = 0                    # the step of the last rest


class Client:
    def __init__(self, slot, conn):
        self.slot = slot
        self.conn = conn
        self.errors = []      # (step, code, text), every error read from its queue
        self.opc_since = None  # *OPC? sent, its reply not read yet: when
        self.cleared_at = -1  # its own *RST / *CLS (its queue emptied)


class Violation:
    def __init__(self, cls, step, detail):
        self.cls, self.step, self.detail = cls, step, detail

    def as_dict(self):
        return dict(cls=self.cls, step=self.step, detail=self.detail)


class Episode:
    """One idmd on `cfg_name` in `workdir`, the steps run against it and their violations."""

    def __init__(self, cfg_name, workdir, seed=None, quiet=False):
        self.cfg_name, self.workdir, self.seed, self.silent = cfg_name, workdir, seed, quiet
        self.steps = []
        self.violations = []
        self.seen = set()
        self.clients = {}
        self.i = -1
        harness.TMP = workdir
        cfg = harness.config(cfg_name)
        self.d = harness.Daemon(cfg)
        self.obs = Conn(self.d, unix=False)  # the checker's own connection: never a motion
        self.n = int(self.obs.ask("AXIS:COUNT?"))
        self.axes = [Axis(k + 1) for k in range(self.n)]
        self.info = []
        for a in self.axes:
            p = "AXIS%d:" % a.n
            a.count = float(self.obs.ask(p + "RES?"))
            lo, hi = (float(x) for x in self.obs.ask(p + "LIM?").split(","))
            fmin, fmax, smin, smax = (float(x) for x in self.obs.ask(p + "REG:RANG?").split(","))
            a.step = self.largest_step(p, fmin, fmax, smax)
            self.info.append(dict(travel=(lo, hi), freq=(fmin, fmax), stroke=(smin, smax)))
        for slot, unix in ((0, False), (1, True)):
            self.open(slot, unix)
        self.read_settings()
        self.rest_check(self.axes)

    # -- plumbing
    def largest_step(self, p, fmin, fmax, smax):
        """The largest step of the axis's map at its largest stroke (REG? over a grid of the
        frequencies and duties it covers), grown by a half for the friction's uncertainty."""
        big = 0.0
        for k in range(21):
            f = fmin + (fmax - fmin) * k / 20
            for j in range(1, 25):
                reply = self.obs.ask("%sREG? %s,%s,%s" % (p, fmt(f), fmt(j / 25), fmt(smax)))
                try:
                    big = max(big, abs(float(reply.split(",")[1])))
                except (IndexError, ValueError):
                    pass
        return 1.5 * big

    def violate(self, cls, detail):
        v = Violation(cls, self.i, detail)
        self.violations.append(v)
        if cls not in self.seen and not self.silent:
            self.seen.add(cls)
            print("VIOLATION %s at step %d: %s" % (cls, self.i, detail), flush=True)

    def open(self, slot, unix):
        if slot in self.clients:
            self.close(slot)
        self.clients[slot] = Client(slot, Conn(self.d, unix))

    def close(self, slot):
        cl = self.clients.pop(slot, None)
        if cl is None:
            return
        cl.conn.close()
        for a in self.axes:
            if a.pending and a.pending["client"] is cl:
                a.pending["closed"] = True

    def client(self, slot):
        """The client in `slot` (opened over TCP when a replayed trace lost its `open`), its
        *OPC? answered first."""
        if slot not in self.clients:
            self.open(slot, False)
        cl = self.clients[slot]
        self.collect_opc(cl)
        return cl

    def collect_opc(self, cl):
        if cl.opc_since is None:
            return
        left = max(0.1, cl.opc_since + REST_BOUND_S - time.time())
        r = cl.conn.reply("*OPC?", timeout=left)
        cl.opc_since = None
        if r != "1":
            self.violate("e:opc_reply", "c%d's *OPC? answered %r" % (cl.slot, r))

    def alive(self):
        if self.d.proc.poll() is not None:
            raise Unresponsive("idmd exited with %s" % self.d.proc.returncode)

    def drain(self, cl):
        """Reads `cl`'s error queue empty (its *OPC? answered first); the errors read (code,
        text)."""
        self.collect_opc(cl)
        got = []
        for _ in range(40):
            code, text = parse_error(cl.conn.ask("SYST:ERR?"))
            if code == 0:
                break
            got.append((code, text))
            cl.errors.append((self.i, code, text))
        return got

    def status(self, a):
        return harness.key_values(self.obs.ask("AXIS%d:STAT?" % a.n))

    def read_settings(self):
        for a in self.axes:
            p = "AXIS%d:" % a.n
            lo, hi = (float(x) for x in self.obs.ask(p + "LIM?").split(","))
            if (lo, hi) != a.lim:
                a.lim = (lo, hi)
                a.env = [min(a.env[0], lo), max(a.env[1], hi)]
            w = float(self.obs.ask(p + "MOVE:WIND?"))
            a.window = w if w > 0 else a.count
            hw = float(self.obs.ask(p + "HOLD:WIND?"))
            a.hold_window = hw if hw > 0 else a.window

    # -- (a): every reading
    def check_reading(self, a, x, where):
        if x >= INVALID:
            return
        margin = a.step + max(a.window, a.hold_window, a.move_window) + NOISE_COUNTS * a.count
        lo, hi = a.env[0] - margin, a.env[1] + margin
        if not lo <= x <= hi and not a.reported_a:
            a.reported_a = True  # once per axis until it rests again
            kinds = "+".join(sorted(a.kinds)) or "no motion"
            self.violate("a:outside_soft_limits(%s)" % kinds,
                         "axis %d read %.9g m (%s), the soft limits %s (where it rested or was "
                         "pushed: [%.9g, %.9g]) by %.3g m, more than one step's worth %.3g m"
                         % (a.n, x, where, [fmt(v) for v in a.lim], a.env[0], a.env[1],
                            max(lo - x, x - hi) + margin, margin))

    def readings(self, where):
        xs = [float(v) for v in self.obs.ask("POS:ALL?").split(",")]
        for a, x in zip(self.axes, xs):
            self.check_reading(a, x, where)
        return xs

    def mean_positions(self):
        """Where the axes rest: the mean of REST_SAMPLES readings, taken again until two such
        means agree within a count (a push shows in the readings a few milliseconds late); None
        for an axis with an untrusted reading."""
        prev = None
        for _ in range(20):
            rows = []
            for _ in range(REST_SAMPLES):
                rows.append(self.readings("at rest"))
                time.sleep(0.003)
            self.obs.send("*CLS\n")  # its -230s of untrusted readings
            means = []
            for k in range(self.n):
                col = [r[k] for r in rows]
                means.append(None if any(x >= INVALID for x in col) else sum(col) / len(col))
            if prev is not None and all(
                    (m is None) == (p is None) and (m is None or abs(m - p) <= a.count)
                    for m, p, a in zip(means, prev, self.axes)):
                return means
            prev = means
        return means

    # -- rest: (b), (c), (d)
    def wait_rest(self, axes, bound, fatal=True):
        """Until every axis of `axes` is done, IDLE or FAULT, no sweep runs on it and its burst
        count stays (a hold's corrections are done too); the last status of each. Past `bound`:
        (e) when `fatal`, else None."""
        end = time.time() + bound
        last = None
        while True:
            self.alive()
            sts = [self.status(a) for a in axes]
            for a, st in zip(axes, sts):
                self.check_reading(a, float(st["position"]), "STAT?")
            sweep = self.obs.ask("SWEEP?").split(",")
            sweeping = sweep[0] == "RUNNING" and int(sweep[1]) in [a.n for a in axes]
            still = all(st["done"] == "1" and st["state"] in ("IDLE", "FAULT") for st in sts)
            key = [st["bursts"] for st in sts]
            if still and not sweeping and key == last:
                return sts
            last = key if still and not sweeping else None
            if time.time() > end:
                if not fatal:
                    return None
                self.violate("e:never_at_rest", "not at rest within %g s: %s; SWEEP? %s"
                             % (bound, [(st["state"], st["done"]) for st in sts], ",".join(sweep)))
                raise EndEpisode()
            self.readings("coming to rest")
            time.sleep(0.03)

    def rest_check(self, axes, bound=REST_BOUND_S, fatal=True):
        """Waits until `axes` are at rest, then checks (a), (b), (c) and judges their motions
        (d); the baseline of (b) and the envelope of (a) start over from there."""
        if self.wait_rest(axes, bound, fatal) is None:
            return
        self.read_settings()
        means = self.mean_positions()
        for a in axes:
            st = self.status(a)
            m = means[a.n - 1]
            self.check_still(a, m)
            self.check_in_position(a, st, m)
            if a.pending:
                self.judge(a, m)
            if m is None:
                continue  # untrusted: what moved it since stays on the books
            a.rest = m
            a.env = [min(a.lim[0], m), max(a.lim[1], m)]
            a.moved_by, a.push, a.kinds, a.since = [], 0.0, set(), self.i
            a.reported_a = False

    def check_still(self, a, m):
        """(b): no motion without a motion command (pushes accounted)."""
        if m is None or a.rest is None or a.moved_by:
            return
        want = a.rest + a.push
        tol = NOISE_COUNTS * a.count
        if abs(m - want) > tol:
            self.violate("b:moved_without_motion_command" if a.push == 0 else "b:push_not_where_expected",
                         "axis %d rested at %.9g m after step %d, now at %.9g m (%+.3g m, %s), "
                         "with no motion command since" % (a.n, a.rest, a.since, m, m - a.rest,
                                                           "pushed %+.3g m" % a.push if a.push else "no push"))

    def check_in_position(self, a, st, m):
        """(c): in position means at rest within the window of the target."""
        if m is None or st.get("in_position") != "1":
            return
        target = float(st["target"])
        w = max(a.window, a.move_window)
        if st.get("holding") == "1":
            w = max(w, a.hold_window)
        if abs(m - target) > w + 0.5 * a.count and a.reported_c != target:
            a.reported_c = target
            self.violate("c:in_position_outside_window(after %s)" % ("+".join(sorted(a.since_move)) or "its MOVE"),
                         "axis %d STAT? in_position=1 at rest, the mean reading %.9g m is %.3g m from "
                         "the target %.9g m, the window %.3g m (since its last MOVE: %s)"
                         % (a.n, m, m - target, target, w, ", ".join(sorted(a.since_move)) or "nothing"))

    def judge(self, a, m):
        """(d): the motion last started on `a` ended honestly."""
        pend, a.pending = a.pending, None
        cl = pend["client"]
        if not pend.get("closed") and cl.slot in self.clients:
            self.drain(cl)
        owed = not pend.get("closed") and cl.cleared_at < pend["step"]
        got = [e for e in cl.errors if e[0] >= pend["step"] and motion_end_error(e[1])]
        asked, others = pend["asked"], pend["others"]
        what = "c%d's %s at step %d" % (cl.slot, pend["line"], pend["step"])
        if pend["kind"] == "SWEEP":
            sw = self.obs.ask("SWEEP?").split(",")
            state = sw[0]
            name = pend["line"].split(" ", 1)[1].split(",")[0]
            if not sw[-1].rstrip('"').endswith("/" + name):
                return  # a later sweep (on another axis) answers SWEEP? now
            if state in ("DONE", "RUNNING") or (state == "STOPPED" and asked):
                return
            if owed and not got:
                why = ", ".join(sorted(others)) if others else "no STOP, *RST or SIGHUP"
                self.violate("d:sweep_%s_without_error(%s)" % (state.lower(), why.split(" ")[0]),
                             "%s ended %s (stopped by %s) and left its client no error" % (what, state, why))
            return
        word, _, dist = self.obs.ask("AXIS%d:MOVE:RES?" % a.n).partition(",")
        if word == "OK":
            if pend["kind"] == "MOVE" and m is not None and not pend["disturbed"]:
                target = float(self.obs.ask("AXIS%d:MOVE?" % a.n))
                w = max(a.window, pend["window"]) + 0.5 * a.count
                if abs(m - target) > w:
                    self.violate("d:ok_outside_window", "%s ended OK, but the mean reading %.9g m is "
                                 "%.3g m from the target %.9g m (window %.3g m)" % (what, m, m - target, target, w))
            return
        if word == "STOPPED":
            if asked:
                return
            if not others:
                if not pend.get("closed"):
                    self.violate("d:stopped_unasked", "%s ended STOPPED with no STOP, *RST or SIGHUP" % what)
                return
            if pend["kind"] == "MOVE" and owed and not got:
                why = sorted(others)[0]
                self.violate("d:move_stopped_without_error(%s)" % why.split(" ")[0],
                             "%s ended STOPPED by %s and left its client no error (%s owed)"
                             % (what, ", ".join(sorted(others)), MOTION_END_CODES))
            return
        if word == "NONE":
            if not pend["disturbed"]:
                self.violate("d:result_none", "%s: MOVE:RES? answers NONE after it" % what)
            return
        if pend["kind"] == "STEP" and word == "TIMEOUT":
            return  # README: a STEP queues errors for 111/112 (and faults) only
        if owed and not got:
            after = "(after %s)" % sorted(others)[0].split(" ")[0] if others else ""
            self.violate("d:%s_without_error%s" % (word.lower(), after),
                         "%s ended %s,%s and left its client no error (%s owed)%s" % (
                             what, word, dist, MOTION_END_CODES,
                             "; meanwhile " + ", ".join(sorted(others)) if others else ""))

    # -- the steps
    def run_step(self, st):
        self.i += 1
        self.steps.append(st)
        try:
            getattr(self, "do_" + st["op"])(st)
            self.alive()
            self.readings("after the step")
        except Unresponsive as e:
            self.violate("e:unresponsive", "%s; %s" % (e, self.diagnose(e.conn)))
            raise EndEpisode()

    def accepted(self, a, kind, st, before, got):
        """Whether a motion command started a motion: the axis's counters (STAT? moves for a
        MOVE, bursts and cycles for a STEP; SWEEP?'s directory for a SWEEP) moved on and no
        refusal was queued. (A refusal is not always negative: in FAULT a MOVE is refused with
        the fault's code.)"""
        if any(not motion_end_error(code) for code, _ in got):
            return False
        if kind == "SWEEP":
            name = st["line"].split(" ", 1)[1].split(",")[0]
            return self.obs.ask("SWEEP?").rstrip('"').endswith("/" + name)
        after = self.status(a)
        if kind == "MOVE":
            return after["moves"] != before["moves"]
        return ((after["bursts"], after["cycles"]) != (before["bursts"], before["cycles"])
                or (after["done"], before["done"]) == ("0", "1"))

    def motion_start(self, st, kind):
        """Sends a motion command; the axis when it started a motion, else None."""
        a = self.axes[st["axis"] - 1]
        cl = self.client(st["c"])
        if a.pending and self.quiet(a):
            self.rest_check([a], bound=2.0, fatal=False)
        pre = None
        if kind == "MOVE" and st["rel"] and self.quiet(a):
            pre = self.mean_positions()[a.n - 1]
            pre_st = self.status(a)
        self.drain(cl)  # what earlier motions left: read before this command's own
        before = self.status(a)
        cl.conn.send(st["line"] + "\n")
        got = self.drain(cl)
        if not self.accepted(a, kind, st, before, got):
            return None
        if pre is not None:
            self.check_rel_target(a, st, pre, pre_st)
        a.moved_by.append(self.i)
        a.kinds.add(kind)
        if kind == "MOVE":
            a.move_window = a.window
            a.since_move = set()
        else:
            a.since_move.add(kind)
        a.pending = dict(kind=kind, client=cl, step=self.i, line=st["line"], asked=False,
                         others=set(), disturbed=False, window=a.window)
        return a

    def quiet(self, a):
        st = self.status(a)
        return st["done"] == "1" and st["state"] == "IDLE" and st.get("holding") != "1"

    def check_rel_target(self, a, st, pre, pre_st):
        """(c): MOVE:REL goes from the target only when the axis is in position, else from the
        reading; either way from within the window of where the slider is."""
        target = float(self.obs.ask("AXIS%d:MOVE?" % a.n))
        want = pre + st["value"]
        w = max(a.window, a.move_window) + a.count
        if abs(target - want) > w:
            self.violate("c:rel_from_stale_target",
                         "axis %d at rest at %.9g m (STAT? in_position=%s, target %s; since its last "
                         "MOVE: %s): %s aims at %.9g m, %.3g m from the reading plus the distance" % (
                             a.n, pre, pre_st.get("in_position"), pre_st.get("target"),
                             ", ".join(sorted(a.since_move)) or "nothing", st["line"], target, target - want))

    def finish_motion(self, st):
        if st.get("wait"):
            self.settle()
        else:
            for _ in range(3):
                self.readings("while moving")
                time.sleep(0.01)

    def do_move(self, st):
        self.motion_start(st, "MOVE")
        self.finish_motion(st)

    def do_step(self, st):
        self.motion_start(st, "STEP")
        self.finish_motion(st)

    def do_sweep(self, st):
        self.motion_start(st, "SWEEP")
        self.finish_motion(st)

    def stop_causes(self, cl, axis, cause):
        for a in self.axes:
            if a.pending and (axis is None or a.n == axis):
                if a.pending["client"] is cl:
                    a.pending["asked"] = True
                else:
                    a.pending["others"].add(cause)

    def do_stop(self, st):
        cl = self.client(st["c"])
        self.stop_causes(cl, st["axis"], "STOP from c%d" % cl.slot)
        cl.conn.send(st["line"] + "\n")
        self.drain(cl)

    def do_rst(self, st):
        cl = self.client(st["c"])
        for a in self.axes:
            a.since_move.add("*RST")
        self.stop_causes(cl, None, "*RST from c%d" % cl.slot)
        cl.conn.send("*RST\n")
        cl.cleared_at = self.i
        self.drain(cl)
        self.read_settings()

    def do_sighup(self, st):
        for a in self.axes:
            a.since_move.add("SIGHUP")
            if a.pending:
                a.pending["others"].add("SIGHUP")
        before = self.d.log().count("reloaded")
        self.d.proc.send_signal(signal.SIGHUP)
        end = time.time() + REPLY_BOUND_S
        while self.d.log().count("reloaded") == before and time.time() < end:
            self.alive()
            time.sleep(0.02)
        self.read_settings()

    def do_push(self, st):
        a = self.axes[st["axis"] - 1]
        cl = self.client(st["c"])
        if a.pending and self.quiet(a):
            self.rest_check([a], bound=2.0, fatal=False)
        s = self.status(a)
        at_rest = s["done"] == "1" and s["state"] in ("IDLE", "FAULT") and s.get("holding") != "1"
        cl.conn.send(st["line"] + "\n")
        if any(not motion_end_error(code) for code, _ in self.drain(cl)):
            return
        if a.pending:
            a.pending["disturbed"] = True
        a.kinds.add("PUSH")
        a.since_move.add("PUSH")
        tlo, thi = self.info[a.n - 1]["travel"]
        inside = a.rest is not None and tlo + a.step < a.rest + a.push + st["value"] < thi - a.step
        if at_rest and inside and self.status(a)["bursts"] == s["bursts"]:
            a.push += st["value"]
        else:
            a.moved_by.append(self.i)  # pushed while moving or held, or into an end stop
        lo, hi = a.env
        a.env = [lo + min(st["value"], 0), hi + max(st["value"], 0)]

    def do_fault(self, st):
        a = self.axes[st["axis"] - 1]
        cl = self.client(st["c"])
        cl.conn.send(st["line"] + "\n")
        self.drain(cl)
        a.since_move.add("SIM:FAUL")
        if a.pending:
            a.pending["disturbed"] = True

    def do_lim(self, st):
        cl = self.client(st["c"])
        cl.conn.send(st["line"] + "\n")
        self.drain(cl)
        self.read_settings()
        a = self.axes[st["axis"] - 1]
        s = self.status(a)
        if s["done"] == "1" and s["state"] in ("IDLE", "FAULT") and not a.moved_by and a.rest is not None:
            # at rest since the last rest check: the new limits, widened only to where it rests
            a.env = [min(a.lim[0], a.rest + a.push), max(a.lim[1], a.rest + a.push)]

    def do_set(self, st):
        cl = self.client(st["c"])
        cl.conn.send(st["line"] + "\n")
        self.drain(cl)
        self.read_settings()

    def do_open(self, st):
        self.open(st["c"], st["unix"])

    def do_close(self, st):
        self.close(st["c"])

    def do_half(self, st):
        c = Conn(self.d, st["unix"])
        c.send(st["text"])
        time.sleep(0.02)
        c.close()

    def do_opc(self, st):
        cl = self.client(st["c"])
        cl.conn.send("*OPC?\n")
        cl.opc_since = time.time()
        if st["wait"]:
            self.collect_opc(cl)

    def do_watch(self, st):
        end = time.time() + st["seconds"]
        while time.time() < end:
            self.readings("watching")
            time.sleep(0.01)

    def do_settle(self, st=None):
        self.settle()

    def settle(self):
        for cl in list(self.clients.values()):
            self.collect_opc(cl)
        self.rest_check(self.axes)

    def finish(self):
        """The last rest check, then SIGTERM: exit 0 within SIGTERM_BOUND_S."""
        try:
            self.i += 1
            self.settle()
        except (Unresponsive, EndEpisode) as e:
            if isinstance(e, Unresponsive):
                self.violate("e:unresponsive", str(e))
        if self.d.proc.poll() is None:
            self.d.proc.send_signal(signal.SIGTERM)
            try:
                rc = self.d.proc.wait(SIGTERM_BOUND_S)
            except Exception:
                self.d.proc.kill()
                self.d.proc.wait(10)
                self.violate("e:sigterm", "idmd did not exit within %g s of SIGTERM" % SIGTERM_BOUND_S)
                return
            if rc != 0:
                self.violate("e:sigterm", "idmd exited %s on SIGTERM" % rc)
        else:
            self.violate("e:exited", "idmd had exited with %s" % self.d.proc.returncode)

    def diagnose(self, stuck=None):
        """What a hang looks like from outside: whether idmd runs, whether a new connection and
        the checker's own are answered (and what the axes say), whether the waiting connection
        answers within a minute more; every thread's stack (gdb) in idmd-stacks.txt."""
        if self.d.proc.poll() is not None:
            return "idmd exited with %s" % self.d.proc.returncode
        notes = []
        for name, probe in (("a new connection", lambda: Conn(self.d, unix=False)), ("the checker's", lambda: self.obs)):
            try:
                c = probe()
                c.ask("*IDN?", timeout=5)
                notes.append("%s is answered" % name)
            except Unresponsive as e:
                notes.append("%s is not (%s)" % (name, e))
        try:
            notes.append("MOVE:DONE? %s, SWEEP? %s, SYST:CLI:TABL? %s" % (
                ",".join(self.obs.ask("AXIS%d:MOVE:DONE?" % a.n, timeout=5) for a in self.axes),
                self.obs.ask("SWEEP?", timeout=5), self.obs.ask("SYST:CLI:TABL?", timeout=5)))
            for a in self.axes:
                notes.append("axis %d: %s" % (a.n, self.obs.ask("AXIS%d:STAT?" % a.n, timeout=5)))
        except Unresponsive as e:
            notes.append("the checker's queries failed (%s)" % e)
        path = os.path.join(self.workdir, "idmd-stacks.txt")
        try:
            with open(path, "w") as f:
                subprocess.run(["gdb", "-p", str(self.d.proc.pid), "-batch", "-ex", "thread apply all bt"],
                               stdout=f, stderr=subprocess.STDOUT, timeout=120)
            notes.append("threads' stacks in %s" % path)
        except (OSError, subprocess.SubprocessError) as e:
            notes.append("no stacks (%s)" % e)
        if stuck is not None:
            t0 = time.time()
            try:
                r = stuck.reply("the same line", timeout=60)
                notes.append("the waiting connection answered %r %.1f s later" % (r, time.time() - t0))
            except Unresponsive as e:
                notes.append("the waiting connection: still %s" % e)
        return "; ".join(notes)

    def kill(self):
        if self.d.proc.poll() is None:
            self.d.proc.kill()
            self.d.proc.wait(10)


# ---- Runs ---------------------------------------------------------------------------------------

CONFIGS = ["idmd.yaml", "idmd-xyz.yaml"]


def episode_seed(master, k):
    return master * 1000003 + k


def run_episode(workdir, cfg_name, seed, steps=None, max_steps=40, deadline=None, quiet=False):
    """One idmd: the generator's steps from `seed` (or the given `steps`) until `max_steps` or
    `deadline`. The Episode (its steps and violations)."""
    os.makedirs(workdir, exist_ok=True)
    ep = Episode(cfg_name, workdir, seed, quiet)
    gen = Generator(seed, ep.info) if steps is None else None
    queue = list(steps or [])
    try:
        while True:
            if steps is None:
                if len(ep.steps) >= max_steps or (deadline and time.time() > deadline):
                    break
                queue = queue or gen.next()
            if not queue:
                break
            st = queue.pop(0)
            if not quiet:
                print("  %3d %s" % (ep.i + 1, describe(st)), flush=True)
            ep.run_step(st)
        ep.finish()
    except EndEpisode:
        ep.kill()
    except BaseException:
        ep.kill()
        save_trace(ep)  # a fault of this script: its steps kept for a replay
        raise
    save_trace(ep)
    return ep


def save_trace(ep):
    with open(os.path.join(ep.workdir, "trace.json"), "w") as f:
        json.dump(dict(config=ep.cfg_name, seed=ep.seed, steps=ep.steps,
                       violations=[v.as_dict() for v in ep.violations]), f, indent=1)
    shutil.copy(os.path.join(ep.workdir, "idmd.err"), os.path.join(ep.workdir, "idmd.log"))


def report(episodes):
    """Prints every class of violation with its first occurrence, the episode's seed and its steps
    up to there; whether there were any."""
    first = {}
    for ep in episodes:
        for v in ep.violations:
            first.setdefault(v.cls, (ep, v, sum(1 for e in episodes for w in e.violations if w.cls == v.cls)))
    if not first:
        return False
    print("\n==== %d class(es) of invariant violation" % len(first))
    here = os.path.abspath(sys.argv[0])
    for cls, (ep, v, count) in sorted(first.items()):
        print("\n-- %s (%d time(s)); first: config/%s, episode seed %s, step %d"
              % (cls, count, ep.cfg_name, ep.seed, v.step))
        print("   %s" % v.detail)
        print("   steps up to it:")
        for k, st in enumerate(ep.steps[:v.step + 1]):
            print("   %3d %s" % (k, describe(st)))
        trace = os.path.join(ep.workdir, "trace.json")
        print("   idmd's log: %s; trace: %s" % (os.path.join(ep.workdir, "idmd.log"), trace))
        print("   replay:   /usr/bin/python3 %s %s %s replay=%s" % (here, harness.BUILD, harness.SOURCE, trace))
        print("   minimize: /usr/bin/python3 %s %s %s 'minimize=%s:%s'" % (here, harness.BUILD, harness.SOURCE, trace, cls))
    return True


def run_generated(master, budget_s, max_steps, minimize_s):
    root = ROOT
    print("stateful: master seed %d (IDM_STATEFUL_SEED), %g s, work in %s%s" % (
        master, budget_s, root, "; without " + ",".join(WITHOUT) if WITHOUT else ""))
    deadline = time.time() + budget_s
    episodes = []
    k = 0
    while time.time() < deadline - 15 or not episodes:
        cfg = CONFIGS[k % len(CONFIGS)]
        seed = episode_seed(master, k)
        print("== episode %d: config/%s, seed %d" % (k, cfg, seed), flush=True)
        ep = run_episode(os.path.join(root, "episode-%d" % k), cfg, seed, max_steps=max_steps,
                         deadline=deadline)
        print("   %d steps, %d violation(s)" % (len(ep.steps), len(ep.violations)), flush=True)
        episodes.append(ep)
        k += 1
    failed = report(episodes)
    if failed and minimize_s > 0:
        end = time.time() + minimize_s
        done = set()
        for ep in episodes:
            for v in ep.violations:
                if v.cls in done or time.time() > end - 20:
                    continue
                done.add(v.cls)
                minimize(ep.cfg_name, ep.steps[:v.step + 1], v.cls, end, ep.seed)
    if failed:
        harness.fail("invariant violations above; the runs' directories are kept in %s" % root)
    shutil.rmtree(root, ignore_errors=True)


# ---- Replay and minimization -------------------------------------------------------------------

def replay_classes(cfg_name, steps, seed=None):
    """Runs `steps` on a fresh idmd; the classes of violation seen (the directory is removed
    unless one was)."""
    work = os.path.join(ROOT, "replay-%d" % int(time.time() * 1000))
    ep = run_episode(work, cfg_name, seed, steps=steps, quiet=True)
    cls = {v.cls for v in ep.violations}
    if not cls:
        shutil.rmtree(work, ignore_errors=True)
    return cls, ep


def minimize(cfg_name, steps, cls, end, seed=None):
    """Delta debugging (Zeller's ddmin) of `steps` for `cls` until `end`; prints the smallest
    sequence that still showed it."""
    print("\n==== minimizing %s from %d steps (until %s)" % (cls, len(steps), time.strftime("%H:%M:%S", time.localtime(end))), flush=True)
    runs = [0]

    def fails(sub):
        if time.time() > end:
            return False
        runs[0] += 1
        got, _ = replay_classes(cfg_name, sub, seed)
        return cls in got

    if not fails(steps):
        print("   the full sequence did not show %s again (timing): not minimized" % cls)
        return steps
    n = 2
    while len(steps) >= 2 and time.time() < end:
        size = math.ceil(len(steps) / n)
        chunks = [steps[k:k + size] for k in range(0, len(steps), size)]
        reduced = False
        for k in range(len(chunks)):
            rest = [s for j, c in enumerate(chunks) if j != k for s in c]
            if rest and fails(rest):
                steps, n, reduced = rest, max(n - 1, 2), True
                break
        if not reduced:
            if n >= len(steps):
                break
            n = min(len(steps), 2 * n)
    _, ep = replay_classes(cfg_name, steps, seed)
    print("   %s in %d steps (%d replays), config/%s:" % (cls, len(steps), runs[0], cfg_name))
    for k, st in enumerate(steps):
        print("   %3d %s" % (k, describe(st)))
    for v in ep.violations:
        if v.cls == cls:
            print("   -> step %d: %s" % (v.step, v.detail))
            break
    path = os.path.join(ROOT, "minimal-%s.json" % "".join(ch if ch.isalnum() else "_" for ch in cls))
    with open(path, "w") as f:
        json.dump(dict(config=cfg_name, seed=seed, steps=steps, cls=cls), f, indent=1)
    print("   saved: %s" % path, flush=True)
    return steps


def load_trace(arg):
    path, _, cls = arg.partition(":")
    with open(path) as f:
        trace = json.load(f)
    return trace, cls


def main():
    case = sys.argv[3] if len(sys.argv) == 4 else ""
    global ROOT
    harness.setup("idm-stateful-")
    ROOT = harness.TMP
    seed_env = os.environ.get("IDM_STATEFUL_SEED")
    if case == "--list":
        print("short long")
        return
    if case == "short":
        run_generated(int(seed_env or 1), float(os.environ.get("IDM_STATEFUL_BUDGET_S", 150)), 40,
                      float(os.environ.get("IDM_STATEFUL_MINIMIZE_S", 0)))
    elif case == "long":
        budget = os.environ.get("IDM_STATEFUL_LONG_S")
        if not budget:
            print("SKIP: the long run needs IDM_STATEFUL_LONG_S (seconds; ./idm check sets it)")
            shutil.rmtree(harness.TMP, ignore_errors=True)
            sys.exit(77)
        run_generated(int(seed_env or 1000), float(budget), 80,
                      float(os.environ.get("IDM_STATEFUL_MINIMIZE_S", 600)))
    elif case.startswith("replay="):
        trace, _ = load_trace(case[len("replay="):])
        ep = run_episode(os.path.join(ROOT, "replay"), trace["config"], trace.get("seed"), steps=trace["steps"])
        if report([ep]):
            harness.fail("invariant violations above; kept in %s" % ROOT)
        shutil.rmtree(ROOT, ignore_errors=True)
    elif case.startswith("minimize="):
        trace, cls = load_trace(case[len("minimize="):])
        classes = [cls] if cls else sorted({v["cls"] for v in trace["violations"]})
        end = time.time() + float(os.environ.get("IDM_STATEFUL_MINIMIZE_S", 600))
        for c in classes:
            first = min(v["step"] for v in trace["violations"] if v["cls"] == c) if any(
                v["cls"] == c for v in trace["violations"]) else len(trace["steps"]) - 1
            minimize(trace["config"], trace["steps"][:first + 1], c, end, trace.get("seed"))
        print("kept in %s" % ROOT)
    else:
        print("usage: %s BUILD_DIR SOURCE_DIR short|long|replay=TRACE|minimize=TRACE[:CLASS]" % sys.argv[0])
        sys.exit(2)
    print("PASS", case)


if __name__ == "__main__":
    main()
