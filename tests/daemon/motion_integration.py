#!/usr/bin/python3
"""Motion a client can rely on, through idmd's sockets on the simulated stage: status bytes and
operation bits, the in-position window and dwell, why a move ended (and the error when it did not
arrive), end of travel open and closed loop against the simulated end stop, referencing and the
referenced flag, hold against pushes, and what POS? reads after a move on a realistic plant.

usage: motion_integration.py BUILD_DIR SOURCE_DIR CASE
"""
import math
import os
import random
import re
import time

import script_harness as harness
from script_harness import Client, Daemon, bursts_stay, check, config, wait_state

harness.setup("idmd-motion-")
COUNT_M = 632.991e-9 / 64
# A stage whose zero lies off-centre: the low end stop comes before the soft limit (-5 mm).
STOPS = ("  noise_m: 1e-9\n", "  noise_m: 1e-9\n  end_stops_m: [-0.3e-3, 5e-3]\n")
# The same stop with the travel's low end 50 um beyond it (the soft limit there): a stop near the
# travel's end is its end of travel (one 4.7 mm inside, as with STOPS alone, is an obstruction).
NEAR_END = [STOPS, ("travel_m: [-5e-3, 5e-3]", "travel_m: [-0.35e-3, 5e-3]")]


def oper(c, axis=""):
    return int(c.ask(axis + "STAT:OPER?"))


def result(c):
    word, dist = c.ask("MOVE:RES?").split(",")
    return word, float(dist)


def errors(c):
    out = []
    while True:
        e = c.error()
        if e.startswith("0,"):
            return out
        out.append(e)


def case_status_bits():
    with Daemon(config()) as d:
        c = Client(d)
        check(c.ask("*STB?") == "0" and c.ask("*ESR?") == "0", "*STB? and *ESR? 0 at start")
        bits = oper(c)
        check(bits & (1 << 8) and not bits & 1, "STAT:OPER? bit 8 (position valid), not moving: %d" % bits)
        c.send("FOO:BAR 1\n")  # a command error
        stb = int(c.ask("*STB?"))
        check(stb & (1 << 2) and stb & (1 << 5), "*STB? bit 2 (error queued) and bit 5 (event): %d" % stb)
        esr = int(c.ask("*ESR?"))
        check(esr & (1 << 5), "*ESR? bit 5 (command error): %d" % esr)
        check(c.ask("*ESR?") == "0", "*ESR? is cleared by reading it")
        check(c.error().startswith("-113,"), "the -113 is in the queue")
        check(c.ask("*STB?") == "0", "*STB? 0 once the queue is read")
        c.send("MOVE:ABS 1\n")  # an execution error (-222)
        check(int(c.ask("*ESR?")) & (1 << 4), "*ESR? bit 4 after -222")
        c.send("*CLS\n")
        c.send("MOVE:REL 2e-3\n")
        time.sleep(0.05)
        bits, stb = oper(c), int(c.ask("*STB?"))
        check(bits & 1 and not bits & 2, "moving: bit 0 set, bit 1 clear (%d)" % bits)
        check(stb & (1 << 7), "*STB? bit 7 (operation) while moving: %d" % stb)
        check(c.ask("*OPC?") == "1", "the move ends")
        bits = oper(c)
        check(bits & 2 and not bits & 1, "in position: bit 1 set, bit 0 clear (%d)" % bits)
        check(not int(c.ask("*STB?")) & (1 << 7), "*STB? bit 7 clear at rest")
        check(not bits & (1 << 3), "not referenced: bit 3 clear")
        c.send("LIM %s,5e-3\n" % c.ask("POS?"))
        check(oper(c) & (1 << 4), "at the lower soft limit: bit 4")
    with Daemon(config()) as d:  # a slider stuck from the start: a stall, not an end of travel
        c = Client(d)
        c.send("SIM:FAULT stalled,1\nMOVE:REL 50e-6\n")
        st = wait_state(c, {"state": "FAULT"}, timeout=20)
        check(st["fault"] == "stall" and "not_move" in st["fault_reason"],
              "STAT? names the fault in words: %s" % st["fault_reason"])
        check(oper(c) & (1 << 7), "bit 7: fault")
        check(c.ask("MOVE:RES?").startswith("FAULT,"), "MOVE:RES? FAULT")
        check(any(e.startswith("102,") for e in errors(c)), "the stall (102) is queued for the mover")


def case_bad_settings():
    with Daemon(config()) as d:
        c = Client(d)
        for line, words in (("MOVE:WIND -1e-9", "MOVE:WINDow"), ("MOVE:WIND 1", "MOVE:WINDow"),
                            ("MOVE:DWEL 100", "MOVE:DWELl"), ("EOT:STEP -1", "EOT:STEP"),
                            ("EOT:CYCL 2.5", "EOT:CYCLes"), ("EOT:CYCL 0", "EOT:CYCLes"),
                            ("HOLD -2", "HOLD"), ("HOLD:WIND 1", "HOLD:WINDow"),
                            ("REF SIDEWAYS", "REFerence")):
            c.send(line + "\n")
            e = c.error()
            check(e.startswith("-222,") and words in e and "allowed" in e, "%s: %s" % (line, e))
        c.send("MOVE:WIND nan\n")
        check(c.error().startswith("-120,"), "MOVE:WIND nan is -120")
        c.send("MOVE:WIND 50e-9\nMOVE:DWEL 0.02\nEOT:STEP 5e-9\nEOT:CYCL 30\nHOLD 2\nHOLD:WIND 80e-9\n")
        got = [float(c.ask(q)) for q in ("MOVE:WIND?", "MOVE:DWEL?", "EOT:STEP?", "EOT:CYCL?",
                                          "HOLD?", "HOLD:WIND?")]
        check(got == [50e-9, 0.02, 5e-9, 30, 2, 80e-9], "settings read back: %s" % got)
        c.send("*RST\n")
        check(c.ask("*OPC?") == "1" and float(c.ask("MOVE:DWEL?")) == 0, "*RST restores the config's")


def case_window_and_dwell():
    with Daemon(config()) as d:
        c = Client(d)
        check(c.ask("MOVE:RES?") == "NONE,0", "MOVE:RES? NONE before any move")
        window = 3 * COUNT_M
        c.send("MOVE:WIND %g\nMOVE:DWEL 0.2\n" % window)
        for target in (1.234567e-4, -2.5e-5, 3.1e-6):
            t0 = time.time()
            c.send("MOVE:ABS %r\n" % target)
            check(c.ask("*OPC?") == "1", "move to %g done" % target)
            took = time.time() - t0
            word, dist = result(c)
            check(word == "OK" and abs(dist) <= window, "MOVE:RES? OK within the window (%g m)" % dist)
            check(took >= 0.2, "done only after the 0.2 s dwell (%.3f s)" % took)
            p = float(c.ask("POS?"))
            check(abs(p - target) <= window + COUNT_M, "a fresh reading is in the window (%g m)" % (p - target))
            check(oper(c) & 2, "in position (bit 1)")
        check(errors(c) == [], "no error for moves that arrived")
        # MOVE:REL from the target when in position
        c.send("MOVE:DWEL 0\nMOVE:REL 1e-6\n")
        check(c.ask("*OPC?") == "1" and float(c.ask("MOVE?")) == 3.1e-6 + 1e-6,
              "MOVE:REL is relative to the target when in position")


def case_speed_and_jog():
    """MOVE:VELocity caps the approach's speed (positions sampled while a move runs: a loaded
    machine can only make it slower); JOG POSitive/NEGative moves to that soft limit at that
    speed, ends OK there or STOPPED by the client's STOP with no error; out-of-range speeds are
    refused naming the range, and *RST restores the config's (no limit)."""
    with Daemon(config()) as d:
        c = Client(d)
        check(float(c.ask("MOVE:VEL?")) == 0, "no speed limit by default")
        c.send("MOVE:VEL 2\n")
        e = c.error()
        check(e.startswith("-222,") and "allowed [0, 1] m/s" in e, "2 m/s refused: %s" % e)
        limit = 4e-4
        c.send("MOVE:VEL %g\n" % limit)
        check(float(c.ask("MOVE:VEL?")) == limit, "MOVE:VEL? reads back")

        def sampled_move(command):
            start = float(c.ask("POS?"))
            c.send(command + "\n")
            samples = [(time.time(), start)]
            while c.ask("MOVE:DONE?") == "0":
                samples.append((time.time(), float(c.ask("POS?"))))
                time.sleep(0.02)
            return samples

        samples = sampled_move("MOVE:REL 1e-3")
        check(result(c)[0] == "OK", "the limited move arrives: %s" % (result(c),))
        fastest = 0
        for i, (t, p) in enumerate(samples):
            for t2, p2 in samples[i + 1:]:
                if t2 - t >= 0.25:
                    fastest = max(fastest, abs(p2 - p) / (t2 - t))
                    break
        check(fastest <= 1.3 * limit, "at most the speed limit over any 0.25 s: %g m/s" % fastest)
        check(samples[-1][0] - samples[0][0] >= 1e-3 / (1.3 * limit), "the move took its time")
        c.send("MOVE:VEL 0\nLIM -1e-3,1.6e-3\n")
        check(errors(c) == [], "no errors so far")
        c.send("JOG POS\n")
        check(c.ask("*OPC?") == "1", "the jog ends")
        word, dist = result(c)
        window = float(c.ask("MOVE:WIND?"))
        p = float(c.ask("POS?"))
        check(word == "OK" and 1.6e-3 - 2 * window - COUNT_M <= p <= 1.6e-3,
              "JOG POS ends at the upper soft limit, inside: %s %r" % (word, p))
        for _ in range(4):  # a move to the limit itself lands there too (not LIMIT)
            c.send("MOVE:ABS 1.2e-3\n")
            check(c.ask("*OPC?") == "1" and result(c)[0] == "OK", "back from the limit")
            c.send("MOVE:ABS 1.6e-3\n")
            check(c.ask("*OPC?") == "1", "the move to the limit ends")
            check(result(c)[0] == "OK", "MOVE:ABS to the limit ends OK: %s at %s" % (result(c), c.ask("POS?")))
        c.send("MOVE:VEL %g\nJOG NEG\n" % limit)
        time.sleep(0.5)
        c.send("STOP\n")
        check(c.ask("*OPC?") == "1", "the jog stops")
        p = float(c.ask("POS?"))
        check(result(c)[0] == "STOPPED" and -1e-3 < p < 1.6e-3 - 1e-5,
              "JOG NEG stopped on the way: %s at %g" % (result(c), p))
        check(errors(c) == [], "a STOP the client asked for queues nothing")
        c.send("JOG UP\n")
        e = c.error()
        check(e.startswith("-222,") and "POSitive, NEGative" in e, "JOG UP refused: %s" % e)
        c.send("*RST\n")
        check(c.ask("*OPC?") == "1" and float(c.ask("MOVE:VEL?")) == 0, "*RST: the config's (0)")


def case_not_arrived():
    move_timeout = ("  max_chunk_s: 0.05\n", "  max_chunk_s: 0.05\n  move_timeout_s: 0.15\n")
    with Daemon(config(edits=[move_timeout])) as d:
        c = Client(d)
        c.send("MOVE:REL 4e-3\n")
        check(c.ask("*OPC?") == "1", "the long move ends")
        word, dist = result(c)
        check(word == "TIMEOUT" and abs(dist) > 1e-4, "MOVE:RES? TIMEOUT, far off (%g m)" % dist)
        e = errors(c)
        check(len(e) == 1 and e[0].startswith("113,"), "113 queued for the mover: %s" % e)
        c.send("MOVE:REL -2e-3\n")
        time.sleep(0.05)
        c.send("STOP\n")
        check(c.ask("*OPC?") == "1", "stopped")
        word, dist = result(c)
        check(word == "STOPPED" and abs(dist) > 1e-5, "MOVE:RES? STOPPED (%g m)" % dist)
        check(errors(c) == [], "a STOP the client asked for queues nothing")
        check(not oper(c) & 2, "not in position")


def case_eot_open_loop():
    with Daemon(config(edits=NEAR_END)) as d:
        c = Client(d)
        # 21 um a STEP (0.53 um a cycle), short enough for the soft limit 50 um past the stop.
        e = []
        for _ in range(40):
            c.send("STEP 40,0.1,1000,2e-6\n")
            check(c.ask("*OPC?") == "1", "STEP 40,0.1,1000,2e-6 done")
            e = errors(c)
            if result(c)[0] != "OK":
                break
            check(e == [], "not refused: %s" % e)
        check(result(c)[0] == "END_OF_TRAVEL", "MOVE:RES? END_OF_TRAVEL")
        st = c.status()
        check(st["eot"] == "low" and st["state"] == "IDLE", "STAT? eot=low, IDLE: %s" % st["eot"])
        check(float(st["position"]) > -0.3e-3 - 2 * COUNT_M, "the slider is at the stop, not past it")
        check(oper(c) & (1 << 6), "bit 6: end of travel")
        check(bursts_stay(c), "the output is at rest")
        check(any(x.startswith("112,") for x in e), "112 queued: %s" % e)
        c.send("STEP 5,0.1,1000,2e-6\n")
        check(c.error().startswith("-221,"), "a STEP further into the stop is refused")
        c.send("STEP 100\n")
        check(c.ask("*OPC?") == "1" and result(c)[0] == "OK", "a STEP away is allowed")
        check(c.status()["eot"] == "none", "eot cleared by moving away")


def case_eot_closed_loop():
    with Daemon(config(edits=NEAR_END)) as d:
        c = Client(d)
        c.send("MOVE:ABS -0.35e-3\n")
        check(c.ask("*OPC?") == "1", "the move into the stop ends")
        word, dist = result(c)
        check(word == "END_OF_TRAVEL" and dist < -4e-5, "MOVE:RES? END_OF_TRAVEL (%g m)" % dist)
        check(c.status()["eot"] == "low", "eot=low")
        check(bursts_stay(c), "the output is at rest")
        check(any(x.startswith("112,") for x in errors(c)), "112 queued for the mover")
        c.send("MOVE:ABS -0.32e-3\n")
        e = c.error()
        check(e.startswith("-221,") and "end of travel" in e, "a move beyond the stop is refused: %s" % e)
        c.send("*RST\n")
        check(c.ask("*OPC?") == "1" and c.status()["eot"] == "low", "*RST keeps the end of travel")
        c.send("MOVE:ABS 1e-4\n")
        check(c.ask("*OPC?") == "1", "a move away is allowed")
        word, dist = result(c)
        check(word == "OK" and abs(dist) <= COUNT_M, "and arrives (%g m)" % dist)
        check(abs(c.mean_position() - 1e-4) <= COUNT_M, "at the target by a fresh reading")


def case_obstruction():
    """The slider held 4.7 mm before the end of its travel (the simulated stop at -0.3 mm, the
    travel from -5 mm): a stall fault, not END_OF_TRAVEL (which only a move away cleared, and
    *RST did not); *RST clears it; moves either way are allowed again."""
    with Daemon(config(edits=[STOPS])) as d:
        c = Client(d)
        c.send("MOVE:ABS -1e-3\n")
        check(c.ask("*OPC?") == "1", "the move into the stop ends")
        st = c.status()
        check(st["state"] == "FAULT" and st["fault"] == "stall" and st["eot"] == "none",
              "FAULT stall, eot=none: %s %s %s" % (st["state"], st["fault"], st["eot"]))
        check(result(c)[0] == "FAULT" and abs(float(st["position"]) + 0.3e-3) < 1e-6,
              "MOVE:RES? FAULT, at the stop (%s)" % st["position"])
        check(any(x.startswith("102,") for x in errors(c)), "102 (stall) queued for the mover")
        c.send("*RST\n")
        check(c.ask("*OPC?") == "1", "*RST")
        st = wait_state(c, {"state": "IDLE"})
        check(st["fault"] == "none" and st["eot"] == "none", "*RST cleared it")
        c.send("MOVE:ABS -0.2e-3\n")
        check(c.ask("*OPC?") == "1" and result(c)[0] == "OK", "a move away arrives")
        c.send("MOVE:ABS -0.25e-3\n")
        check(c.ask("*OPC?") == "1" and result(c)[0] == "OK" and errors(c) == [],
              "a move toward the stop is not refused as an end of travel")


def case_reference():
    cfg = config(edits=[STOPS, ("  max_retries: 10\n", "  max_retries: 10\n"),
                  ("stage:                          # Table 1",
                   "require_reference: true\nstage:                          # Table 1")])
    with Daemon(cfg) as d:
        c = Client(d)
        check(c.ask("REF?") == "0" and not oper(c) & (1 << 3), "not referenced at start")
        c.send("MOVE:ABS 1e-4\n")
        e = c.error()
        check(e.startswith("-221,") and "referenced" in e, "MOVE:ABS refused unreferenced: %s" % e)
        c.send("MOVE:REL 1e-4\n")
        check(c.ask("*OPC?") == "1" and result(c)[0] == "OK", "MOVE:REL is allowed")
        c.send("REF MARK\n")
        check(c.error().startswith("-221,"), "REF MARK without a mark signal is refused")
        c.send("REF NEG\n")
        time.sleep(0.05)
        check(oper(c) & (1 << 9), "bit 9 while referencing")
        check(c.ask("*OPC?") == "1", "REF NEG ends")
        check(c.ask("REF?") == "1" and oper(c) & (1 << 3), "referenced")
        check(result(c)[0] == "OK", "MOVE:RES? OK after the reference")
        # the stop is at -0.3 mm on the stage; the reference puts it at the travel's end (-5 mm)
        p = c.mean_position()
        check(abs(p - (-5e-3)) < 1e-6, "the position at the stop is the travel's lower end (%g)" % p)
        c.send("MOVE:ABS -4.9e-3\n")
        check(c.ask("*OPC?") == "1" and result(c)[0] == "OK" and errors(c) == [],
              "absolute moves allowed once referenced")
        p = c.mean_position()
        check(abs(p + 4.9e-3) <= COUNT_M, "at -4.9 mm (%g)" % p)
        c.send("SIM:FAULT beam_lost,1\n")
        wait_state(c, {"position_valid": "0"})
        check(c.ask("REF?") == "0", "beam loss clears the referenced flag")
        c.send("SIM:FAULT beam_lost,0\n*RST\n")
        check(c.ask("*OPC?") == "1", "*RST")
        wait_state(c, {"position_valid": "1"})
        check(c.ask("REF?") == "0", "still not referenced after the beam is back")
        c.send("REF\n")
        check(c.ask("*OPC?") == "1" and c.ask("REF?") == "1", "REF (the config's default, negative)")
        c.send("SIM:FAULT power_cycle,1\n")
        wait_state(c, {"device": "lost"})
        c.send("SIM:FAULT power_cycle,0\n")
        wait_state(c, {"device": "up"}, timeout=20)
        check(c.ask("REF?") == "0", "a power cycle (count started over) clears it")
        c.send("*RST\n")
        check(c.ask("*OPC?") == "1", "*RST")
        c.send("MOVE:ABS 1e-4\n")
        check(c.error().startswith("-221,"), "MOVE:ABS refused again")
    with Daemon(cfg) as d:
        c = Client(d)
        check(c.ask("REF?") == "0", "a restarted daemon is not referenced")


def case_reference_positive():
    high_stop = ("  noise_m: 1e-9\n", "  noise_m: 1e-9\n  end_stops_m: [-5e-3, 0.4e-3]\n")
    with Daemon(config(edits=[high_stop])) as d:
        c = Client(d)
        c.send("REF POS\n")
        check(c.ask("*OPC?") == "1" and c.ask("REF?") == "1", "REF POS found the high stop")
        p = c.mean_position()
        check(abs(p - 5e-3) < 1e-6, "the position there is the travel's upper end (%g)" % p)
        check(c.status()["eot"] == "high", "and it is at the end of travel (high)")


def case_reference_mark():
    # An index mark at -0.1 mm on the stage, the zero off-centre as in STOPS; the mark is where the
    # user's coordinates put 1 mm.
    mark = ("  noise_m: 1e-9\n",
            "  noise_m: 1e-9\n  end_stops_m: [-0.3e-3, 5e-3]\n  reference_mark_m: -0.1e-3\n")
    at = ("stage:                          # Table 1",
          "require_reference: true\nreference_position_m: 1e-3\nstage:                          # Table 1")
    with Daemon(config(edits=[mark, at])) as d:
        c = Client(d)
        check(c.ask("REF?") == "0", "not referenced at start")
        c.send("REF MARK\n")
        time.sleep(0.05)
        check(oper(c) & (1 << 9), "bit 9 while referencing")
        check(c.ask("*OPC?") == "1", "REF MARK ends")
        check(errors(c) == [], "no error queued")
        check(c.ask("REF?") == "1" and oper(c) & (1 << 3), "referenced")
        word, dist = result(c)
        check(word == "OK" and abs(dist) <= COUNT_M, "MOVE:RES? OK (%s, %g m)" % (word, dist))
        p = c.mean_position()
        check(abs(p - 1e-3) <= 2 * COUNT_M, "POS? at the reference position on the mark (%g)" % p)
        st = c.status()
        check(st["eot"] == "none" and st["state"] == "IDLE", "IDLE, not at an end stop: %s" % st)
        c.send("MOVE:ABS 1.05e-3\n")
        check(c.ask("*OPC?") == "1" and result(c)[0] == "OK" and errors(c) == [],
              "absolute moves allowed once referenced")
        c.send("REF NEG\n")
        check(c.ask("*OPC?") == "1" and c.ask("REF?") == "1", "REF NEG still finds the stop")
    # A mark outside the travel: the search meets both end stops and fails, truthfully. It drives
    # negative first unless reference_mark_search says positive: it ends at the other stop.
    beyond = ("  noise_m: 1e-9\n",
              "  noise_m: 1e-9\n  end_stops_m: [-0.3e-3, 0.3e-3]\n  reference_mark_m: 1e-3\n")
    first = ("stage:                          # Table 1",
             "reference_mark_search: positive\nstage:                          # Table 1")
    for edits, last in (([beyond], "high"), ([beyond, first], "low")):
        with Daemon(config(edits=edits)) as d:
            c = Client(d)
            c.send("REF MARK\n")
            check(c.ask("*OPC?") == "1", "REF MARK ends")
            check(c.ask("REF?") == "0", "not referenced")
            check(result(c)[0] == "END_OF_TRAVEL", "MOVE:RES? END_OF_TRAVEL: %s" % (result(c),))
            e = errors(c)
            check(any(x.startswith("112,") and "reference" in x for x in e), "112 queued: %s" % e)
            check(c.status()["eot"] == last, "at the %s stop (the second one it met)" % last)
    # The default configuration's simulated stage has no mark: refused, nothing moves.
    with Daemon(config()) as d:
        c = Client(d)
        bursts = c.status()["bursts"]
        c.send("REF MARK\n")
        e = c.error()
        check(e.startswith("-221,") and "reports no reference mark" in e, "REF MARK refused: %s" % e)
        check(c.ask("*OPC?") == "1" and c.status()["bursts"] == bursts and bursts_stay(c),
              "nothing moved")
        check(c.ask("REF?") == "0" and result(c)[0] == "NONE", "not referenced, no motion")


def case_hold():
    with Daemon(config()) as d:
        c = Client(d)
        window = 4 * COUNT_M
        c.send("HOLD -1\nHOLD:WIND %g\n" % window)
        c.send("MOVE:ABS 2e-4\n")
        check(c.ask("*OPC?") == "1", "the move is done (the hold does not keep *OPC? waiting)")
        check(oper(c) & (1 << 2) and oper(c) & 2, "holding (bit 2) and in position (bit 1)")
        check(c.ask("MOVE:DONE?") == "1", "MOVE:DONE? 1 while holding")
        check(bursts_stay(c, 0.3), "output at rest inside the window")
        for push in (3e-6, -0.5e-6, 60e-9):
            before = int(c.status()["bursts"])
            c.send("SIM:PUSH %g\n" % push)
            end = time.time() + 10
            while time.time() < end:
                time.sleep(0.05)
                if int(c.status()["bursts"]) > before and c.status()["state"] == "IDLE" and \
                        abs(c.mean_position(4) - 2e-4) <= window:
                    break
            p = c.mean_position()
            check(abs(p - 2e-4) <= window, "pushed by %g m: back within the hold window (%g m)" % (push, p - 2e-4))
            check(int(c.status()["bursts"]) > before, "it corrected")
            check(bursts_stay(c, 0.2), "and rests again")
        check(errors(c) == [], "no error while holding")
        c.send("STOP\n")
        time.sleep(0.05)
        check(not oper(c) & (1 << 2), "STOP ends the hold")
        before = c.status()["bursts"]
        c.send("SIM:PUSH 2e-6\n")
        time.sleep(0.3)
        check(c.status()["bursts"] == before and abs(c.mean_position() - 2e-4 - 2e-6) < 3 * COUNT_M,
              "no correction after the hold ended")
        c.send("HOLD 0.3\nMOVE:ABS 1e-4\n")
        check(c.ask("*OPC?") == "1", "a move with a 0.3 s hold")
        check(oper(c) & (1 << 2), "holding")
        time.sleep(0.5)
        check(not oper(c) & (1 << 2), "the hold ended after 0.3 s")


# The realistic plant of bench/positioning_bench.cpp: compliant actuator, 3 kHz amplifier,
# Stribeck friction, friction varying along the guide, 2 nm rms noise; the map's alpha is what one
# 200-cycle burst measures there.
REALISTIC = (("  step_correction: 1.0 ", "  step_correction: 0.7628 "),
             ("  plant: rigid\n  seed: 1\n  noise_m: 1e-9\n",
              "  plant: mck\n  seed: 7\n  noise_m: 2e-9\n  effects:\n"
              "    amplifier: {cutoff_hz: 3000}\n    stribeck: {static_over_kinetic: 1.15}\n"
              "    friction_spread: {relative_sd: 0.05}\n"))


def case_fresh_reading():
    """Moves of 10 nm .. 1 mm both ways on the realistic plant: after *OPC?, a POS? read later
    (from readings at rest, all taken after done) is within one count of the target (the true
    position is the positioning bench's to check: bench/README.md)."""
    with Daemon(config(edits=REALISTIC)) as d:
        c = Client(d)
        rng = random.Random(5)
        misses, worst = [], 0.0
        n = 24
        for k in range(n):
            distance = math.exp(rng.uniform(math.log(10e-9), math.log(1e-3)))
            here = float(c.ask("MOVE?"))
            target = here + (distance if k % 2 == 0 else -distance)
            c.send("MOVE:ABS %.12g\n" % target)
            check(c.ask("*OPC?") == "1", "move %d (%+.3g m) done" % (k, target - here))
            time.sleep(0.02)  # fresh readings at rest, all taken after done
            error = float(c.ask("POS?")) - target
            worst = max(worst, abs(error))
            if abs(error) > COUNT_M:
                misses.append((k, round(error / COUNT_M, 2), c.ask("MOVE:RES?")))
        check(c.error() == '0,"No error"', "no error queued")
        check(len(misses) <= 1, "POS? within one count of the target after done in %d of %d "
              "moves (worst %.1f nm; misses in counts: %s)"
              % (n - len(misses), n, worst * 1e9, misses))


def case_window_unreachable():
    """A window the stage cannot meet is said before the hunting: a lambda/16384 interferometer (a
    count of 0.04 nm, the window one count) on the realistic plant, whose finest chunks scatter
    by nanometres. The move ends FAULT window_unreachable with 108 queued naming the narrowest
    window not ruled out (STAT? least_window, above the window), in far less time than the
    hunting takes; motion is refused until *RST; with MOVE:WINDow at ten times that window, a
    move is not called unreachable."""
    fine = ("  optics: single_beam_linear\n", "  optics: custom\n  divisor: 16384\n")
    with Daemon(config(edits=REALISTIC + (fine,))) as d:
        c = Client(d)
        count = float(c.ask("RES?"))
        check(abs(count - 632.991e-9 / 16384) < 1e-15, "RES? is the custom optics' count: %g" % count)
        here = float(c.ask("MOVE?"))
        unreachable, least = 0, 0.0
        for k in range(4):
            target = here + (k + 1) * 3.7e-6
            t0 = time.monotonic()
            c.send("MOVE:ABS %.12g\n" % target)
            check(c.ask("*OPC?") == "1", "move %d done" % k)
            took = time.monotonic() - t0
            st = c.status()
            if st["fault"] != "window_unreachable":
                c.send("*RST\n")
                check(c.ask("*OPC?") == "1", "*RST")
                errors(c)
                continue
            unreachable += 1
            check(result(c)[0] == "FAULT", "MOVE:RES? says FAULT")
            check(st["fault_reason"].startswith("the_window_is_narrower"),
                  "STAT? says why in words: %s" % st["fault_reason"])
            window = float(c.ask("MOVE:WIND?"))
            least = float(st["least_window"])
            check(least > window, "least_window %g above the window %g" % (least, window))
            errs = errors(c)
            check(len(errs) == 1 and errs[0].startswith("108,") and "%.3g" % least
                  in "%.3g" % float(re.search(r"narrower than ([0-9.eE+-]+) m", errs[0]).group(1)),
                  "108 queued, naming the least window: %s" % errs)
            check(took < 5.0, "said at once (%.2f s)" % took)
            c.send("MOVE:ABS %.12g\n" % here)
            refusal = errors(c)
            check(refusal[0].startswith("108,") and "*RST" in refusal[0],
                  "motion refused in FAULT: %s" % refusal)
            c.send("*RST\n")
            check(c.ask("*OPC?") == "1", "*RST")
        check(unreachable >= 3, "%d of 4 moves said window_unreachable" % unreachable)
        c.send("MOVE:WIND %.6g\n" % (10 * least))
        check(errors(c) == [], "the wider window accepted")
        c.send("MOVE:ABS %.12g\n" % (here - 2.1e-6))
        check(c.ask("*OPC?") == "1", "the move with the wider window done")
        st = c.status()
        check(st["fault"] != "window_unreachable" and float(st["least_window"]) == 0,
              "a window ten times the least is not called unreachable: %s %s"
              % (st["fault"], st["least_window"]))


def case_reference_kept():
    """reference_file: the reference outlives idmd while the device keeps its count (a Modbus
    device, a process of its own, its boot_id unchanged); not once the device restarted, nor on
    the simulated device (it lives in idmd and counts afresh)."""
    port = harness.free_port()
    ref = os.path.join(harness.TMP, "reference-kept.yaml")
    if os.path.exists(ref):
        os.remove(ref)
    # The device's stop 0.3 mm below its zero (idm-simdev reads the sim: section too); its plant
    # is the ideal model (alpha 1).
    cfg = harness.modbus_config(port, [("stage:\n", "reference_file: %s\nstage:\n" % ref),
                                       ("step_correction: 0.35", "step_correction: 1.0"),
                                       ("daq:\n", "sim:\n  end_stops_m: [-0.3e-3, 5e-3]\ndaq:\n")],
                                out="reference-kept.yaml.cfg")
    with harness.SimDev(port, cfg) as dev:
        with Daemon(cfg) as d:
            c = Client(d)
            check(c.ask("REF?") == "0", "not referenced at the first start")
            c.send("REF NEG\n")
            check(c.ask("*OPC?") == "1" and c.ask("REF?") == "1", "REF NEG over Modbus")
            c.send("MOVE:ABS -4.9e-3\n")
            check(c.ask("*OPC?") == "1" and result(c)[0] == "OK",
                  "MOVE:ABS -4.9 mm: %s %s" % (result(c), errors(c)))
            c.send("POS:SET 1.5e-3\n")  # a user offset: kept with the reference
            c.no_error()
            before = c.mean_position()
            time.sleep(0.2)  # housekeeping writes the file within 50 ms
        with open(ref) as f:
            text = f.read()
        check("referenced: true" in text and "user_offset_m:" in text,
              "the file says referenced, with the user offset:\n" + text)
        with Daemon(cfg) as d:
            c = Client(d)
            check(c.ask("REF?") == "1", "referenced after the restart\n" + d.log())
            check("referenced as before the restart" in d.log() and "user offset" in d.log(),
                  "the log says so, with the user offset:\n" + d.log())
            p = c.mean_position()
            check(abs(p - before) <= 2 * COUNT_M and abs(p - 1.5e-3) <= 3 * COUNT_M,
                  "the same position (user frame): %.4g before, %.4g after the restart" % (
                      before, p))
            c.send("MOVE:ABS %.17g\n" % (-4.8e-3 + float(c.ask("POS:OFFS?"))))
            check(c.ask("*OPC?") == "1" and result(c)[0] == "OK" and errors(c) == [],
                  "absolute moves go on")
        dev.kill()
        dev.start()  # the device restarted: a new boot_id, its count from zero
        with Daemon(cfg) as d:
            c = Client(d)
            check(c.ask("REF?") == "0", "not referenced once the device restarted")
            check("count started over" in d.log(), "the log says why:\n" + d.log())
            check(c.ask("POS:OFFS?") == "0", "nor is the user offset restored")
    with open(ref) as f:
        check("referenced: false" in f.read(), "the file follows")
    sim_ref = os.path.join(harness.TMP, "reference-sim.yaml")
    cfg = config(edits=[STOPS, ("stage:                          # Table 1",
                                "reference_file: %s\nstage:                          # Table 1"
                                % sim_ref)], out="reference-sim.yaml.cfg")
    with Daemon(cfg) as d:
        c = Client(d)
        c.send("REF NEG\n")
        check(c.ask("*OPC?") == "1" and c.ask("REF?") == "1", "REF NEG on the simulated stage")
    with Daemon(cfg) as d:
        c = Client(d)
        check(c.ask("REF?") == "0" and "count started over" in d.log(),
              "the simulated stage is not referenced after a restart:\n" + d.log())


def case_user_offset():
    """POSition:SET / POSition:OFFSet (a user offset, as the EPICS motor record's SET and OFF):
    every position the protocol shows or takes moves with the offset (POS?, POS:ALL?, MOVE:ABS and
    its query, LIM, STAT?), the stage's own frame (the soft limits and travel on the stage, where
    a move lands on it) does not. A mixed sequence of offsets, positions, limits and moves drawn
    at random (seed printed), checked against a model of the two frames kept here."""
    seed = int(os.environ.get("IDM_TEST_SEED", random.randrange(1 << 30)))
    print("seed %d (IDM_TEST_SEED)" % seed)
    rng = random.Random(seed)
    travel = (-5e-3, 5e-3)
    with Daemon(config()) as d:
        c = Client(d)
        check(c.ask("POS:OFFS?") == "0" and c.status()["offset"] == "0", "no offset at start")
        offset = 0.0
        dial_limits = list(travel)  # the soft limits on the stage: the travel at start

        def user_limits():
            return [float(x) for x in c.ask("LIM?").split(",")]

        largest = [0.0]  # the largest offset so far, m

        def agrees(why):
            largest[0] = max(largest[0], abs(offset))
            u = user_limits()
            check(abs(float(c.ask("POS:OFFS?")) - offset) <= 1e-11 * abs(offset),
                  "%s: POS:OFFS? %s, expected %.17g" % (why, c.ask("POS:OFFS?"), offset))
            for k in (0, 1):
                # Replies carry 12 significant digits: LIM? and POS:OFFS? are each rounded, and
                # the model's stage limits carry the rounding of every offset they met.
                check(abs(u[k] - (dial_limits[k] + offset)) <= 1e-11 * (largest[0] + 1e-2),
                      "%s: LIM? %s is the stage's limits %s + the offset %.12g" % (
                          why, u, dial_limits, offset))
            st = c.status()
            check(float(st["offset"]) == float(c.ask("POS:OFFS?")) and
                  float(st["lower"]) == u[0] and float(st["upper"]) == u[1],
                  "%s: STAT? says the same: %s" % (why, st))
            check(c.positions("POS:ALL?")[0] != 9.91e37, "%s: POS:ALL? valid" % why)

        for k in range(14):
            action = rng.choice(["set", "set", "offset", "offset_bad", "limits", "limits_bad",
                                 "move", "move", "move_outside", "rst"])
            why = "step %d (%s)" % (k, action)
            if action == "set":
                x = rng.choice([rng.uniform(-8, 8), rng.uniform(-1e-2, 1e-2), 0.0])
                before = c.mean_position()
                c.send("POS:SET %.17g\n" % x)
                c.no_error()
                reply = float(c.ask("POS:OFFS?"))  # the daemon's reading at rest, not ours
                check(abs(reply - (offset + x - before)) <= 3 * COUNT_M + 1e-11 * abs(reply),
                      "%s: POS:SET %.12g at %.12g: offset %.12g -> %.12g" % (why, x, before,
                                                                            offset, reply))
                offset = reply
                p = c.mean_position()
                check(abs(p - x) <= 3 * COUNT_M + 1e-12 * abs(x),
                      "%s: POS:SET %.12g, then POS? %.12g" % (why, x, p))
            elif action == "offset":
                new = rng.choice([rng.uniform(-10, 10), rng.uniform(-1e-3, 1e-3), 0.0, -10.0, 10.0])
                before = c.mean_position()
                c.send("POS:OFFS %.17g\n" % new)
                c.no_error()
                p = c.mean_position()
                check(abs((p - before) - (new - offset)) <= 3 * COUNT_M + 1e-12 * abs(new),
                      "%s: the position moved with the offset: %.12g -> %.12g, offset %.12g -> "
                      "%.12g" % (why, before, p, offset, new))
                offset = new
            elif action == "offset_bad":
                bad = rng.choice([1, -1]) * rng.uniform(10.0000001, 1e6)
                c.send("POS:OFFS %.17g\n" % bad)
                e = c.error()
                check(e.startswith("-222,") and "[-10, 10] m" in e, "%s: %s" % (why, e))
            elif action in ("limits", "limits_bad"):
                lo = rng.uniform(travel[0], travel[0] / 2)
                hi = rng.uniform(travel[1] / 2, travel[1])
                if rng.random() < 0.3:
                    lo = travel[0]  # the travel's end, given in the user frame
                if action == "limits_bad":
                    (lo, hi) = (travel[0] - rng.uniform(1e-7, 1e-3), hi) if rng.random() < 0.5 \
                        else (lo, travel[1] + rng.uniform(1e-7, 1e-3))
                c.send("LIM %.17g,%.17g\n" % (lo + offset, hi + offset))
                e = c.error()
                if action == "limits":
                    check(e.startswith("0,"), "%s: LIM within the travel: %s" % (why, e))
                    u = user_limits()
                    check(all(abs(u[i] - (lo, hi)[i] - offset) <= 1e-11 * (largest[0] + 1e-2)
                              for i in (0, 1)),
                          "%s: LIM? %s after LIM %.12g,%.12g" % (why, u, lo + offset, hi + offset))
                    dial_limits = [u[0] - offset, u[1] - offset]
                else:
                    check(e.startswith("-222,") and "travel" in e, "%s: refused: %s" % (why, e))
                    if offset != 0:
                        check("user offset" in e, "%s: the message names the offset: %s" % (why, e))
            elif action == "move":
                t = rng.uniform(dial_limits[0] + 1e-4, dial_limits[1] - 1e-4) + offset
                c.send("MOVE:ABS %.17g\n" % t)
                check(c.ask("*OPC?") == "1", why)
                word, dist = result(c)
                p = c.mean_position()
                check(word == "OK" and abs(p - t) <= 2 * COUNT_M,
                      "%s: MOVE:ABS %.12g: %s %g, POS? %.12g %s" % (why, t, word, dist, p,
                                                                 errors(c)))
                check(abs(float(c.ask("MOVE:ABS?")) - t) <= 1e-11 * max(1e-3, abs(t)),
                      "%s: MOVE:ABS? %s" % (why, c.ask("MOVE:ABS?")))
            elif action == "move_outside":
                t = dial_limits[1] + rng.uniform(1e-6, 1e-3) + offset
                bursts = c.status()["bursts"]
                c.send("MOVE:ABS %.17g\n" % t)
                e = c.error()
                lim = user_limits()
                m = re.search(r"soft limits \[(\S+), (\S+)\] m", e)
                check(e.startswith("-222,") and m and all(
                    abs(float(m.group(i + 1)) - lim[i]) <= 1e-8 * max(1e-3, abs(lim[i]))
                    for i in (0, 1)),
                      "%s: refused naming the user-frame limits %s: %s" % (why, lim, e))
                check(c.status()["bursts"] == bursts, "%s: nothing moved" % why)
            elif action == "rst":
                c.send("*RST\n")
                check(c.ask("*OPC?") == "1", why)
            agrees(why)
        # At rest only, with a trusted position.
        u = user_limits()
        far = u[0] + 0.1 * (u[1] - u[0])
        if abs(c.mean_position() - far) < 1e-3:
            far = u[1] - 0.1 * (u[1] - u[0])
        c.send("MOVE:ABS %.17g\nPOS:SET 0\n" % far)
        e = c.error()
        check(e.startswith("-221,") and "POSition:SET" in e, "POS:SET while moving: %s" % e)
        check(c.ask("*OPC?") == "1", "the move ends")
        c.send("SIM:FAULT beam_lost,1\n")
        wait_state(c, {"position_valid": "0"})
        c.send("POS:SET 0\n")
        e = c.error()
        check(e.startswith("-230,"), "POS:SET without a valid position: %s" % e)
        c.send("SIM:FAULT beam_lost,0\n")
        wait_state(c, {"position_valid": "1"})
        # A change of 1 mm toward zero stays inside [-10, 10] m whatever offset the draw left.
        c.send("POS:OFFS %.17g\n" % (offset - math.copysign(1e-3, offset)))
        c.no_error()
        end = time.time() + 5
        while "user offset" not in d.log() and time.time() < end:
            time.sleep(0.05)
        check("user offset" in d.log(), "the log says when the offset changed:\n" + d.log())


def case_shipped_configs():
    """Every axis of every shipped config that runs here lands, as the file is (its stage, its
    fresh calibration): idmd.yaml and idmd-xyz.yaml on the simulated card (the xyz z axis carries
    0.25 kg), idmd-modbus.yaml against idm-simdev. Seeded moves of 10 nm to 3 mm within each
    axis's soft limits, all axes of a card moving at once: every one ends OK with POS? within the
    axis's window (one count) of its target."""
    rng = random.Random(31)

    def moves(c, name, n=6):
        axes = int(c.ask("AXIS:COUN?"))
        x = [0.0] * axes
        limits = []
        for a in range(1, axes + 1):
            lo, hi = (float(v) for v in c.ask("AXIS%d:LIM?" % a).split(","))
            limits.append((lo, hi))
            x[a - 1] = float(c.ask("AXIS%d:POS?" % a))
        for k in range(n):
            targets = []
            for a in range(1, axes + 1):
                lo, hi = limits[a - 1]
                d = math.exp(rng.uniform(math.log(10e-9), math.log(3e-3))) * rng.choice((-1, 1))
                t = x[a - 1] + d
                if not lo * 0.95 < t < hi * 0.95:
                    t = x[a - 1] - d
                targets.append(t)
                c.send("AXIS%d:MOVE:ABS %.12g\n" % (a, t))
            check(c.ask("*OPC?") == "1", "%s: moves %d done" % (name, k))
            for a in range(1, axes + 1):
                word, dist = c.ask("AXIS%d:MOVE:RES?" % a).split(",")
                pos = float(c.ask("AXIS%d:POS?" % a))
                window = float(c.ask("AXIS%d:MOVE:WIND?" % a))
                check(word == "OK" and abs(pos - targets[a - 1]) <= window + 1e-15,
                      "%s axis %d: %.4g m -> %s, POS? %.3f counts off (window %.3g m)%s"
                      % (name, a, targets[a - 1], word, (pos - targets[a - 1]) / COUNT_M, window,
                         "" if word == "OK" else "; errors: %s" % errors(c)))
                x[a - 1] = targets[a - 1]
            c.no_error()

    def fresh_state():  # each file as a lab of its own starts it: no calibration of another
        for f in os.listdir(harness.TMP):
            if f.startswith("calibration"):
                os.remove(os.path.join(harness.TMP, f))

    for name in ("idmd.yaml", "idmd-xyz.yaml"):
        fresh_state()
        with Daemon(config(name)) as d:
            moves(Client(d), name)
    fresh_state()
    port = harness.free_port()
    cfg = harness.modbus_config(port)
    with harness.SimDev(port, cfg):
        with Daemon(cfg) as d:
            moves(Client(d), "idmd-modbus.yaml")


CASES = {
    "user_offset": case_user_offset,
    "fresh_reading": case_fresh_reading,
    "window_unreachable": case_window_unreachable,
    "status_bits": case_status_bits,
    "bad_settings": case_bad_settings,
    "window_and_dwell": case_window_and_dwell,
    "not_arrived": case_not_arrived,
    "speed_and_jog": case_speed_and_jog,
    "eot_open_loop": case_eot_open_loop,
    "eot_closed_loop": case_eot_closed_loop,
    "obstruction": case_obstruction,
    "reference": case_reference,
    "reference_positive": case_reference_positive,
    "reference_mark": case_reference_mark,
    "reference_kept": case_reference_kept,
    "hold": case_hold,
    "shipped_configs": case_shipped_configs,
}

if __name__ == "__main__":
    harness.run(CASES)
