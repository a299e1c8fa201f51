#!/usr/bin/python3
"""The CPU a running process takes over a window, per thread and in all (utime + stime from
/proc/PID/task/*/stat), as a percentage of one core.

usage: idle_cpu.py PID SECONDS LABEL
prints one line per thread ("LABEL thread NAME cpu_pct=X") and "LABEL total cpu_pct=X".
"""
import os
import sys
import time


def threads(pid):
    """{tid: (name, clock ticks of CPU so far)} of the process's threads now."""
    out = {}
    for tid in os.listdir("/proc/%s/task" % pid):
        try:
            with open("/proc/%s/task/%s/stat" % (pid, tid)) as f:
                stat = f.read()
        except OSError:  # the thread ended meanwhile
            continue
        name = stat[stat.index("(") + 1:stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        out[tid] = (name, int(fields[11]) + int(fields[12]))  # utime, stime
    return out


def main():
    pid, seconds, label = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    hz = os.sysconf("SC_CLK_TCK")
    before, t0 = threads(pid), time.monotonic()
    time.sleep(seconds)
    after, elapsed = threads(pid), time.monotonic() - t0
    total = 0.0
    for tid, (name, ticks) in sorted(after.items(), key=lambda kv: kv[1][0]):
        pct = 100.0 * (ticks - before.get(tid, (name, 0))[1]) / hz / elapsed
        total += pct
        print("%s thread %s cpu_pct=%.2f" % (label, name, pct))
    print("%s total cpu_pct=%.2f" % (label, total))


if __name__ == "__main__":
    main()
