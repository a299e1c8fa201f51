#!/usr/bin/python3
"""The fault and bad-input matrix: the real idmd on the simulated stage, driven through its
sockets by plain clients (no library of ours), one case per way a client, a file or a device can
misbehave. Each case asserts what the daemon reports, that nothing moved that should not have,
the error queued, and the recovery.

usage: fault_matrix.py BUILD_DIR SOURCE_DIR CASE
"""
import os
import re
import signal
import socket
import time

import script_harness as harness
from script_harness import (Client, Daemon, SimDev, bursts_stay, check, config, free_port,
                            key_values, modbus_config, modbus_registers, wait_state)

harness.setup("idmd-fm-")


def expect_refused(c, line, code, words):
    """A command line refused with `code`, its text holding every word; nothing moved."""
    before = c.status()
    c.send(line + "\n")
    err = c.error()
    check(err.startswith("%d," % code) and all(w in err for w in words),
          "%s -> %s" % (line, err))
    after = c.status()
    check(after["bursts"] == before["bursts"] and after["cycles"] == before["cycles"],
          "%s played nothing" % line)


def case_bad_input():
    """Typos and hostile lines: every one refused with its code, naming the argument and the
    range, and nothing played."""
    with Daemon(config()) as d:
        c = Client(d)
        check(c.ask("POS?") not in ("", None), "a position at once")
        # Units typed wrong: 1 km, -1 km.
        expect_refused(c, "MOVE:REL 1e3", -222, ["target 1000", "soft limits"])
        expect_refused(c, "MOVE:ABS -1e3", -222, ["target -1000", "soft limits"])
        expect_refused(c, "LIM:UPP 1e3", -222, ["upper limit 1000", "travel"])
        expect_refused(c, "LIM 1e-6,1e-6", -222, ["must be below the upper limit"])
        # Every STEP argument used or refused.
        expect_refused(c, "STEP 10,1.5,200", -222, ["STEP duty: 1.5"])
        expect_refused(c, "STEP 10,0.1,-200", -222, ["STEP freq_hz: -200"])
        expect_refused(c, "STEP 10,-0.1,200,2e-5", -222, ["STEP duty: -0.1"])
        expect_refused(c, "STEP 10,0.1,200,-1e-6", -222, ["STEP stroke_m"])
        expect_refused(c, "STEP 10,0.1,200,0", -222, ["STEP stroke_m: 0"])
        expect_refused(c, "STEP 1000000000", -222, ["soft limits"])
        expect_refused(c, "STEP 0", -222, ["STEP cycles"])
        # Quoted numbers are strings, not numbers.
        expect_refused(c, 'MOVE:REL "1e-6"', -104, ["quoted"])
        expect_refused(c, 'STEP "10"', -104, ["quoted"])
        expect_refused(c, 'LIM:LOW "-1e-3"', -104, ["quoted"])
        check(c.ask("SYST:ERR?") == '0,"No error"', "nothing else queued")
        # STEP n,duty,freq plays that duty and frequency: the way REG? says.
        reg = c.ask("REG? 200,0.1")
        step = float(reg.split(",")[1])
        p0 = float(c.ask("POS?"))
        c.send("STEP 10,0.1,200\n")
        check(c.wait_done(), "STEP 10,0.1,200 finishes")
        moved = float(c.ask("POS?")) - p0
        check(moved * step > 0 and abs(moved - 10 * step) < 0.3 * abs(10 * step),
              "STEP 10,0.1,200 moved %.4g m, REG? predicts %.4g m" % (moved, 10 * step))
        check(c.ask("SYST:ERR?") == '0,"No error"', "no error after the step")


def case_unterminated_line():
    """A last line without its newline never runs, over TCP or the Unix socket."""
    with Daemon(config()) as d:
        watcher = Client(d)
        start = watcher.status()
        for unix in (False, True):
            c = Client(d, unix=unix)
            c.send("MOVE:REL 1e-3")  # no newline
            c.s.shutdown(socket.SHUT_WR)
            check(c.line() is None, "closed without a reply (%s)" % ("unix" if unix else "tcp"))
            c.close()
        time.sleep(0.3)
        now = watcher.status()
        check(now["moves"] == start["moves"] and now["bursts"] == start["bursts"],
              "nothing moved: moves %s, bursts %s" % (now["moves"], now["bursts"]))


def case_reset_keeps_limits():
    """*RST by one client keeps the limits another set, and the target."""
    with Daemon(config()) as d:
        a, b = Client(d), Client(d, unix=True)
        a.send("LIM -1e-3,2e-3\n")
        a.send("MOVE:REL 2e-6\n")
        check(a.wait_done(), "the move finishes")
        target = a.status()["target"]
        b.send("*RST\n")
        check(b.ask("*OPC?") == "1", "*RST completes")
        check(a.ask("LIM?") == "-0.001,0.002", "the limits survive *RST: " + a.ask("LIM?"))
        check(a.status()["target"] == target, "the target survives *RST")
        check(a.ask("SYST:ERR?") == '0,"No error"', "no error")


def case_sweep_confined():
    """SWEEP writes only below recording.data_dir, into a new directory."""
    data = os.path.join(harness.TMP, "data")
    outside = os.path.join(harness.TMP, "outside")
    os.makedirs(data, exist_ok=True)
    os.makedirs(outside, exist_ok=True)
    open(os.path.join(outside, "keep.txt"), "w").write("keep\n")
    os.symlink(outside, os.path.join(data, "link"))
    with Daemon(config()) as d:
        c = Client(d)
        for target in ("../outside/x", outside + "/x", "link/x", "link"):
            c.send("SWEEP %s,500,0.1,1,2\n" % target)
            err = c.error()
            check(err.startswith("-222,"), "SWEEP %s refused: %s" % (target, err))
        c.send("SWEEP run1,500,0.1,1,2\n")
        check(c.wait_done(), "a sweep into a new name runs")
        check(os.path.exists(os.path.join(data, "run1", "sweep.csv")), "written inside data_dir")
        c.send("SWEEP run1,500,0.1,1,2\n")
        check(c.error().startswith("-222,"), "the same name again is refused")
        check(sorted(os.listdir(outside)) == ["keep.txt"], "nothing written outside")


def case_client_table_full():
    """Clients that sent *OPC? and vanished free their slots; with the table full a STOP still
    gets through."""
    cfg = config(edits=[("  max_clients: 16", "  max_clients: 2")])
    with Daemon(cfg) as d:
        mover = Client(d)
        mover.send("MOVE:REL 4e-3\n")
        time.sleep(0.1)
        check(mover.ask("MOVE:DONE?") == "0", "a long move is on")
        ghosts = [Client(d, unix=True) for _ in range(2)]
        for g in ghosts:
            g.send("*OPC?\n")
            g.close()
        time.sleep(0.2)
        other = Client(d, unix=True)
        check(other.ask("*IDN?").startswith("idm,idmd"), "the ghosts' slots are free")
        hog = Client(d)  # the table is full now (mover, other)
        hog.send("MOVE:ABS 0\n")
        check(hog.error().startswith("-221,"), "a client past the table is stop-only")
        hog.send("STOP\n")
        check(mover.wait_done(5), "its STOP got through")
        check(mover.status()["state"] in ("IDLE",), "at rest after STOP")


def case_client_count():
    """SYST:CLI? counts the connections open now (the asking one included), over TCP and the
    Unix socket, a stop-only one too; it goes back down as they close."""
    n = 8  # besides the asker: the table (max_clients 9) is then full
    cfg = config(edits=[("  max_clients: 16", "  max_clients: %d" % (n + 1))])
    with Daemon(cfg) as d:
        asker = Client(d)
        check(asker.ask("SYST:CLI?") == "1", "alone: SYST:CLI? 1")
        others = []
        for k in range(n):
            others.append(Client(d, unix=k % 2 == 1))
            check(others[-1].ask("*IDN?").startswith("idm,idmd"), "client %d answered" % (k + 1))
            check(asker.ask("SYST:CLI?") == str(k + 2), "%d open: SYST:CLI? %d" % (k + 2, k + 2))
        extra = Client(d)  # past the table: a stop-only slot (for 2 s), counted too
        check(extra.ask("*IDN?").startswith("idm,idmd"), "the stop-only client answered")
        table = key_values(asker.ask("SYST:CLI:TABL?"))
        check(table == {"connected": str(n + 2), "slots": str(n + 1), "max_clients": str(n + 1),
                        "stop_only": "1", "overflow_slots": "4", "draining": "0"},
              "SYST:CLI:TABL? %r" % table)
        extra.close()
        for o in [None] + others:
            if o is not None:
                o.close()
            want = str(1 + sum(1 for x in others if x.s.fileno() >= 0))
            end = time.time() + 5
            while asker.ask("SYST:CLI?") != want and time.time() < end:
                time.sleep(0.01)
            check(asker.ask("SYST:CLI?") == want, "one closed: SYST:CLI? back to %s" % want)
        check(asker.error() == '0,"No error"', "no error queued")


def case_beam_loss():
    """The beam lost mid-move: FAULT at once, output at zero, position untrusted, 101 queued for the
    mover; back with the beam and *RST."""
    with Daemon(config()) as d:
        mover, other = Client(d), Client(d, unix=True)
        mover.send("MOVE:REL 3e-3\n")
        time.sleep(0.1)
        check(mover.ask("MOVE:DONE?") == "0", "a long move is on")
        other.send("SIM:FAULT beam_lost,1\n")
        st = wait_state(other, {"state": "FAULT", "fault": "invalid_sample"})
        check(st["position_valid"] == "0" and st["position"] == "9.91E37", "the position is untrusted")
        check(other.ask("POS?") == "9.91E37" and other.error().startswith("-230,"), "POS? is 9.91E37 with -230")
        check(bursts_stay(other), "nothing plays after the beam is lost")
        check(mover.ask("MOVE:DONE?") == "1", "the move is over")
        check(mover.error().startswith("101,"), "the mover gets 101 (invalid interferometer sample)")
        check(st["referenced"] == "0", "not referenced after counts may have been lost")
        mover.send("MOVE:REL 1e-6\n")
        check(mover.error().startswith("101,"), "moves are refused in FAULT")
        other.send("SIM:FAULT beam_lost,0\n")
        other.send("*RST\n")
        check(other.ask("*OPC?") == "1", "*RST completes")
        wait_state(other, {"state": "IDLE", "position_valid": "1"})
        mover.send("MOVE:REL 2e-6\n")
        check(mover.ask("*OPC?") == "1" and mover.ask("SYST:ERR?") == '0,"No error"', "it moves again")


def case_device_disconnect_and_return():
    """A cable pulled at rest: FAULT device_lost with the position untrusted and a log line; back
    with its count: the axis carries on by itself, at the same position."""
    with Daemon(config()) as d:
        c = Client(d)
        p0 = float(c.ask("POS?"))
        c.send("SIM:FAULT disconnect,1\n")
        st = wait_state(c, {"state": "FAULT", "fault": "device_lost", "device": "lost"})
        check(st["position"] == "9.91E37", "the position is untrusted while the device is away")
        c.send("MOVE:REL 1e-6\n")
        check(c.error()[:4] in ("107,", "-230"), "no move while the device is away")
        c.send("SIM:FAULT disconnect,0\n")
        st = wait_state(c, {"state": "IDLE", "device": "up", "position_valid": "1"}, timeout=10)
        check(abs(float(st["position"]) - p0) < 2e-8, "the position went on from the device's own count")
        time.sleep(0.2)
        log = d.log()
        check("device daq lost" in log and "device daq back" in log, "the log names the device, lost and back")


def case_device_power_cycle_mid_move():
    """The device restarts mid-move (its count starts over): FAULT device_lost; once back the
    position goes on from the last reading (not the device's new zero), the axis is not
    referenced, and the fault stays until *RST."""
    with Daemon(config()) as d:
        c = Client(d)
        c.send("MOVE:REL 1e-3\n")
        time.sleep(0.1)
        c.send("SIM:FAULT power_cycle,1\n")
        wait_state(c, {"state": "FAULT", "fault": "device_lost"})
        last = None
        c.send("SIM:FAULT power_cycle,0\n")
        st = wait_state(c, {"device": "up", "position_valid": "1"}, timeout=10)
        check(st["state"] == "FAULT" and st["fault"] == "device_lost", "the fault stays (a move was cut short)")
        check(st["referenced"] == "0", "not referenced")
        p = float(st["position"])
        check(p > 1e-5, "the position did not re-base to the device's new zero (%.3g m)" % p)
        c.send("*RST\n")
        check(c.ask("*OPC?") == "1", "*RST")
        wait_state(c, {"state": "IDLE"})
        c.send("MOVE:REL 2e-6\n")
        check(c.ask("*OPC?") == "1" and c.ask("SYST:ERR?") == '0,"No error"', "it moves again")


def case_stall():
    with Daemon(config()) as d:
        c = Client(d)
        c.send("SIM:FAULT stalled,1\n")
        c.send("MOVE:REL 50e-6\n")
        wait_state(c, {"state": "FAULT", "fault": "stall"}, timeout=20)
        check(bursts_stay(c), "the output is at rest after the stall")
        check(c.error().startswith("102,"), "102 (stall) queued for the mover")
        c.send("SIM:FAULT stalled,0\n*RST\n")
        check(c.ask("*OPC?") == "1", "*RST")
        c.send("MOVE:REL 5e-6\n")
        check(c.ask("*OPC?") == "1" and c.ask("SYST:ERR?") == '0,"No error"', "it moves again")


def case_sim_commands_on_a_real_backend():
    """SIMulation: commands are refused (-241) on a real backend: Modbus against idm-simdev."""
    port = free_port()
    cfg = modbus_config(port)
    with SimDev(port, cfg), Daemon(cfg) as d:
        c = Client(d)
        c.send("SIM:PUSH 1e-6\n")
        check(c.error().startswith("-241,"), "SIM:PUSH on Modbus is -241")


def case_modbus_server_killed():
    """The Modbus device lost (server killed) and back (a new server: a restarted device)."""
    port = free_port()
    cfg = modbus_config(port)
    with SimDev(port, cfg) as sim, Daemon(cfg) as d:
        c = Client(d)
        c.send("MOVE:REL 30e-6\n")
        check(c.ask("*OPC?") == "1", "a move over Modbus")
        p = float(c.ask("POS?"))
        sim.kill()
        t0 = time.time()
        st = wait_state(c, {"state": "FAULT", "fault": "device_lost", "device": "lost"}, timeout=5)
        check(time.time() - t0 < 2, "lost within 2 s (%.2f s)" % (time.time() - t0))
        check(c.ask("POS?") == "9.91E37" and c.error().startswith("-230,"), "POS? untrusted")
        sim.start()
        st = wait_state(c, {"device": "up", "position_valid": "1"}, timeout=10)
        check(abs(float(st["position"]) - p) < 2e-8, "a restarted device: the position goes on from the last reading")
        check(st["referenced"] == "0" and st["state"] == "FAULT", "not referenced, FAULT until *RST")
        c.send("*RST\n")
        check(c.ask("*OPC?") == "1", "*RST")
        # It moves again (how precisely it lands is the positioner's business, not this test's).
        before = float(c.ask("POS?"))
        c.send("MOVE:REL 50e-6\n")
        opc, err = c.ask("*OPC?"), c.ask("SYST:ERR?")
        moved = float(c.ask("POS?")) - before
        check(opc == "1" and not err.startswith(("104,", "107,", "-230")) and abs(moved - 50e-6) < 1e-7,
              "it moves again over Modbus: %.4g um (%s)" % (moved * 1e6, err))
        check("device daq lost" in d.log(), "the log names the device")


def case_modbus_server_stalled():
    """A Modbus server that stops answering (SIGSTOP): the device's I/O thread waits on it, the
    real-time loop does not: it keeps ticking, the command link keeps answering, the device is
    reported lost after its timeout, and all is well again once the server answers."""
    port = free_port()
    cfg = modbus_config(port)
    with SimDev(port, cfg) as sim, Daemon(cfg) as d:
        c = Client(d)
        loop = lambda: int(re.search(r"wakeups=(\d+)", c.ask("SYST:LOOP?")).group(1))
        sim.proc.send_signal(signal.SIGSTOP)
        w0, t0 = loop(), time.time()
        wait_state(c, {"state": "FAULT", "fault": "device_lost"}, timeout=5)
        time.sleep(1.0)
        w1, t1 = loop(), time.time()
        expected = (t1 - t0) / 1e-3  # the Modbus config's loop runs at 1 kHz
        check(w1 - w0 > 0.5 * expected, "the loop kept ticking while the server was stalled: "
              "%d wake-ups in %.2f s (%d expected)" % (w1 - w0, t1 - t0, expected))
        check(c.ask("*IDN?").startswith("idm,idmd"), "the command link answers")
        sim.proc.send_signal(signal.SIGCONT)
        # The same device (its boot_id unchanged): it kept its count, the axis was at rest.
        st = wait_state(c, {"device": "up", "position_valid": "1", "state": "IDLE"}, timeout=10)
        check(st["fault"] == "none", "back by itself, at rest with its count")
        c.send("MOVE:REL 20e-6\n")
        check(c.ask("*OPC?") == "1" and c.status()["state"] == "IDLE", "it moves again")


def case_sigkill_mid_sweep():
    """SIGKILL mid-sweep: every trial written is whole (sweep.csv lists only finished trials and
    each of their files reads back)."""
    data = os.path.join(harness.TMP, "data", "killed")
    with Daemon(config()) as d:
        c = Client(d)
        c.send("SWEEP killed,200:800:100,0.1;0.9,3,12\n")
        end = time.time() + 20
        while time.time() < end:
            rows = open(os.path.join(data, "sweep.csv")).read().splitlines() if os.path.exists(os.path.join(data, "sweep.csv")) else []
            if len(rows) > 3:
                break
            time.sleep(0.01)
        d.proc.kill()
        d.proc.wait(10)
    rows = open(os.path.join(data, "sweep.csv")).read().splitlines()
    check(len(rows) > 3, "some trials were written before the kill (%d rows)" % (len(rows) - 1))
    header = rows[0].split(",")
    fi = header.index("file")
    for row in rows[1:]:
        f = os.path.join(data, row.split(",")[fi])
        lines = open(f).read().splitlines()
        check(lines[0] == "t_s,xi_cmd_m,x_m" and len(lines) > 100, "trial %s reads back whole" % row.split(",")[0])
    listed = {row.split(",")[fi] for row in rows[1:]}
    on_disk = {os.path.join("trials", n) for n in os.listdir(os.path.join(data, "trials"))}
    stray = sorted(n for n in on_disk - listed if not os.path.basename(n).startswith("."))
    check(not stray, "every trial file on disk is a listed, whole trial (stray: %s)" % stray)


def case_sigterm_mid_move():
    """SIGTERM mid-move (systemd stopping the service) on a Modbus device: idmd stops the output,
    exits 0 within its stop timeout and says so; the device is left at rest (not running, no new
    burst); a new idmd on the same device goes on from the device's count and moves."""
    port = free_port()
    cfg = modbus_config(port)
    with SimDev(port, cfg):
        with Daemon(cfg) as d:
            c = Client(d)
            c.send("MOVE:REL 2e-3\n")
            time.sleep(0.3)
            check(c.ask("MOVE:DONE?") == "0", "a long move is on")
            d.proc.send_signal(signal.SIGTERM)
            t0 = time.time()
            code = d.proc.wait(10)
            check(code == 0, "exit code 0 (%s) in %.2f s" % (code, time.time() - t0))
            check("SIGTERM: stopping motion" in d.log(), "the log says why it stopped")
        status, burst = modbus_registers(port, 1, 2)
        check(status & 1 == 0, "the device is not playing (status 0x%04x)" % status)
        time.sleep(0.3)
        check(modbus_registers(port, 2, 1)[0] == burst, "no burst started after the exit")
        with Daemon(cfg) as again:
            c2 = Client(again)
            wait_state(c2, {"position_valid": "1", "state": "IDLE"})
            p = float(c2.ask("POS?"))
            check(p > 1e-5, "the position goes on from the device's count (%.4g um)" % (p * 1e6))
            c2.send("MOVE:REL -20e-6\n")
            opc, err = c2.ask("*OPC?"), c2.error()
            check(opc == "1" and err == '0,"No error"',
                  "it moves again (*OPC? %s, %s, status %s)\n%s"
                  % (opc, err, c2.status(), again.log()[-3000:]))


def case_client_vanishes_mid_query():
    """Clients that vanish mid-query (a query sent and the socket closed unread, a reset with
    unread replies, half a line) cost nothing: the move in progress goes on to its target, the
    daemon answers everyone else, and their slots are free again."""
    cfg = config(edits=[("  max_clients: 16", "  max_clients: 3")])
    with Daemon(cfg) as d:
        mover = Client(d)
        mover.send("MOVE:REL 1e-3\n")
        for _ in range(20):
            # The daemon may not have seen the previous ghost go yet: then a ghost gets a
            # stop-only slot, which may close on it; the ghosts do not care.
            try:
                g = Client(d)
                g.send("POS?\nSTAT?\nSYST:ERR:ALL?\n" * 50)
                g.close()
                r = Client(d, unix=True)
                r.s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
                r.send("*IDN?\nPOS:ALL?\n")
                r.close()  # linger 0: a reset, replies unread
                h = Client(d)
                h.send("MOVE:RE")  # half a line, never finished
                h.close()
            except OSError:
                pass
        time.sleep(0.3)
        others = [Client(d), Client(d, unix=True)]
        check(all(o.ask("*IDN?").startswith("idm,idmd") for o in others), "the vanished clients' slots are free")
        check(mover.ask("*OPC?") == "1", "the move went on to its end")
        err = mover.error()
        check(err == '0,"No error"', "no error from the vanished clients' lines (%s)" % err)
        check(abs(float(mover.ask("POS?")) - 1e-3) < 2e-8, "it arrived")
        check(d.proc.poll() is None, "idmd still runs")


CASES = {
    "bad_input": case_bad_input,
    "unterminated_line": case_unterminated_line,
    "reset_keeps_limits": case_reset_keeps_limits,
    "sweep_confined": case_sweep_confined,
    "client_table_full": case_client_table_full,
    "client_count": case_client_count,
    "beam_loss": case_beam_loss,
    "device_disconnect_and_return": case_device_disconnect_and_return,
    "device_power_cycle_mid_move": case_device_power_cycle_mid_move,
    "stall": case_stall,
    "sim_commands_on_a_real_backend": case_sim_commands_on_a_real_backend,
    "modbus_server_killed": case_modbus_server_killed,
    "sigkill_mid_sweep": case_sigkill_mid_sweep,
    "modbus_server_stalled": case_modbus_server_stalled,
    "sigterm_mid_move": case_sigterm_mid_move,
    "client_vanishes_mid_query": case_client_vanishes_mid_query,
}

if __name__ == "__main__":
    harness.run(CASES)
