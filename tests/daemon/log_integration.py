#!/usr/bin/python3
"""What idmd's log says after an incident (journalctl is all an operator has afterwards): the real
idmd on the simulated stage, driven through its socket, its stderr read back. Each case provokes
one kind of event and counts the lines it left.

usage: log_integration.py BUILD_DIR SOURCE_DIR CASE
"""
import os
import re
import signal
import time

import script_harness as harness
from script_harness import Client, Daemon, check, config, wait_state

harness.setup("idmd-log-")


# The travel's low end 50 um beyond the simulated stage's low end stop: a stop near the end.
NEAR_END = [("travel_m: [-5e-3, 5e-3]", "travel_m: [-0.35e-3, 5e-3]"),
            ("  noise_m: 1e-9\n", "  noise_m: 1e-9\n  end_stops_m: [-0.3e-3, 5e-3]\n")]


def motion_lines(d, axis="x"):
    """idmd's log lines about the axis's faults and failed motions."""
    return [l for l in d.log().splitlines() if "axis %s: " % axis in l]


def field(line, name):
    """The number after `name` in a log line ("target 5e-05 m")."""
    return float(re.search(name + r" (\S+) m", line).group(1))


def new_line(d, before, timeout=10):
    """Waits for a line past the first `before` of motion_lines (housekeeping logs every 50 ms,
    the main thread every 100 ms); then waits a little more and returns every line past them."""
    end = time.time() + timeout
    while time.time() < end and len(motion_lines(d)) <= before:
        time.sleep(0.05)
    time.sleep(0.5)  # a second line for the same event would be there by now
    return motion_lines(d)[before:]


def case_faults():
    """A move that arrives leaves no line; the beam lost mid-move (SIM:FAULt beam_lost) and a
    stalled slider (SIM:FAULt stalled) each leave exactly one warning naming the axis, the
    fault, the motion it ended, the position and the target (nothing was logged but a device
    lost)."""
    with Daemon(config()) as d:
        c = Client(d)
        c.send("MOVE:REL 20e-6\n")
        check(c.ask("*OPC?") == "1" and c.ask("MOVE:RES?").startswith("OK"), "a move arrives")
        time.sleep(0.5)
        check(motion_lines(d) == [], "no line for it: %r" % motion_lines(d))
        c.send("MOVE:REL 3e-3\n")
        time.sleep(0.1)
        check(c.ask("MOVE:DONE?") == "0", "a long move is on")
        c.send("SIM:FAULT beam_lost,1\n")
        wait_state(c, {"state": "FAULT", "fault": "invalid_sample"})
        lines = new_line(d, 0)
        check(len(lines) == 1 and "warn" in lines[0] and
              "axis x: FAULT invalid_sample, ending its MOVE: position unknown, target" in lines[0],
              "one line for the beam lost: %r" % lines)
        c.send("SIM:FAULT beam_lost,0\n*RST\n")
        check(c.ask("*OPC?") == "1", "*RST")
        wait_state(c, {"state": "IDLE", "position_valid": "1"})
        c.send("SIM:FAULT stalled,1\nMOVE:REL 50e-6\n")
        wait_state(c, {"state": "FAULT", "fault": "stall"}, timeout=20)
        target = float(c.ask("MOVE?"))
        lines = new_line(d, 1)
        check(len(lines) == 1 and "axis x: FAULT stall, ending its MOVE: position " in lines[0] and
              abs(field(lines[0], "target") - target) < 1e-12,
              "one line for the stall (target %g): %r" % (target, lines))


def case_limit():
    """A STEP that left the soft limits (the map predicts half the step the simulated stage makes:
    stage.step_correction 0.5) leaves exactly one warning with the result, position, target and
    distance (nothing was logged)."""
    with Daemon(config(edits=[("step_correction: 1.0 ", "step_correction: 0.5 ")])) as d:
        c = Client(d)
        c.send("LIM -1e-3,0.2e-3\nSTEP 10\n")
        check(c.ask("*OPC?") == "1" and c.ask("MOVE:RES?").startswith("OK"), "STEP 10")
        p, predicted_end = c.mean_position(), float(c.ask("MOVE?"))
        step = predicted_end / 10  # the predicted step from 0 (the start)
        n = int(0.6 * (0.2e-3 - p) / step)  # predicted to stop short; it steps twice as far
        c.send("STEP %d\n" % n)
        check(c.wait_done(30) and c.ask("MOVE:RES?").startswith("LIMIT"), "STEP %d: LIMIT" % n)
        lines = new_line(d, 0)
        check(len(lines) == 1 and "axis x: STEP ended LIMIT: position " in lines[0] and
              field(lines[0], "position") > 0.2e-3 and field(lines[0], "distance") < 0,
              "one line for LIMIT: %r" % lines)


def case_end_of_travel():
    """A move that met the end stop near the travel's end (END_OF_TRAVEL) leaves exactly one
    warning with the result, position, target and distance; a move the client stopped leaves
    none."""
    with Daemon(config(edits=NEAR_END)) as d:
        c = Client(d)
        c.send("MOVE:ABS -0.34e-3\n")
        check(c.wait_done(30) and c.ask("MOVE:RES?").startswith("END_OF_TRAVEL"),
              "END_OF_TRAVEL at the stop 50 um before the travel's end")
        lines = new_line(d, 0)
        check(len(lines) == 1 and "axis x: MOVE ended END_OF_TRAVEL (low end): " in lines[0] and
              abs(field(lines[0], "position") + 0.3e-3) < 1e-6 and
              field(lines[0], "target") == -0.34e-3, "one line for the end of travel: %r" % lines)
        c.send("MOVE:ABS 3e-3\n")
        time.sleep(0.1)
        check(c.ask("MOVE:DONE?") == "0", "a long move is on")
        c.send("STOP\n")
        check(c.wait_done(30) and c.ask("MOVE:RES?").startswith("STOPPED"), "a move stopped")
        time.sleep(0.5)
        check(len(motion_lines(d)) == 1, "no line for it: %r" % motion_lines(d)[1:])


def case_deadline_misses():
    """A loop that misses most of its deadlines (a 10 us period without SCHED_FIFO, at that rate
    at rest too: rest_period_s 0) gets one warning saying the rate and what to do after its first
    10 s (as measured: a little more when housekeeping looks late), not one per miss."""
    with Daemon(config(edits=[("period_s: 1e-4", "period_s: 1e-5\n  rest_period_s: 0")])) as d:
        c = Client(d)
        misses = lambda: [l for l in d.log().splitlines() if "the real-time loop missed" in l]
        end = time.time() + 60
        while time.time() < end and not misses():
            time.sleep(0.2)
        time.sleep(1)
        lines = misses()
        check(len(lines) == 1 and "warn" in lines[0] and
              re.search(r"%\) in the last 10(\.\d+)? s", lines[0]) and
              "realtime.period_s" in lines[0], "one warning: %r" % lines)
        check(c.ask("*OPC?") == "1", "idmd serves on")


def plan_status(path):
    text = open(os.path.join(path, "plan.yaml")).read()
    return re.search(r"^status: (\w+)", text, re.M).group(1), text


def case_sigterm_mid_sweep():
    """SIGTERM while a sweep runs: exit 0; plan.yaml says the daemon stopped (SIGTERM) (it said a
    client had stopped it), and the log has one line for the sweep saying so."""
    data = os.path.join(harness.TMP, "data", "term")
    with Daemon(config()) as d:
        c = Client(d)
        c.send("SWEEP term,200:800:100,0.1;0.9,3,12\n")
        csv = os.path.join(data, "sweep.csv")
        end = time.time() + 60
        while time.time() < end and not (os.path.exists(csv) and
                                          len(open(csv).read().splitlines()) > 2):
            time.sleep(0.02)
        check(c.ask("SWEEP?").startswith("RUNNING"), "the sweep runs")
        d.proc.send_signal(signal.SIGTERM)
        check(d.proc.wait(30) == 0, "exit code 0")
        status, text = plan_status(data)
        check(status == "stopped" and "the daemon stopped (SIGTERM)" in text,
              "plan.yaml: the daemon stopped (SIGTERM):\n%s" % text[-300:])
        lines = [l for l in d.log().splitlines() if "data/term (axis x)" in l]
        check(len(lines) == 1 and "stopped: the daemon stopped (SIGTERM)" in lines[0],
              "one log line for the sweep: %r" % lines)


CASES = {
    "faults": case_faults,
    "limit": case_limit,
    "end_of_travel": case_end_of_travel,
    "sigterm_mid_sweep": case_sigterm_mid_sweep,
    "deadline_misses": case_deadline_misses,
}

if __name__ == "__main__":
    harness.run(CASES)
