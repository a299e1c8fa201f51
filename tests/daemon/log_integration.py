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
from script_harness import Client, Daemon, check, config

harness.setup("idmd-log-")


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
    "sigterm_mid_sweep": case_sigterm_mid_sweep,
}

if __name__ == "__main__":
    harness.run(CASES)
