#!/usr/bin/python3
"""idmd end to end: the real binary on the simulated stage (and on the Modbus backend against
tools/idm-simdev), driven through PyVISA (Debian's python3-pyvisa + python3-pyvisa-py) and idmctl,
with a NOTIFY_SOCKET listener standing in for systemd.

usage: idmd_integration.py BUILD_DIR SOURCE_DIR CASE
CASE: pyvisa | idmctl | idmctl_jog | notify_sigterm | modbus | bad_config | missing_device
"""
import os
import socket
import subprocess
import threading
import time

import script_harness as harness
from script_harness import (Daemon, SimDev, check, config, fail, free_port, idmctl, key_values,
                            modbus_config, temp_file, wait_done)

harness.setup("idmd-it-")


def visa(port):
    import pyvisa
    rm = pyvisa.ResourceManager("@py")
    inst = rm.open_resource("TCPIP::127.0.0.1::%d::SOCKET" % port, read_termination="\n",
                            write_termination="\n", timeout=10000)
    return inst


def status(inst):
    return key_values(inst.query("STAT?"))


def case_pyvisa():
    with Daemon(config()) as d:
        inst = visa(d.port)
        idn = inst.query("*IDN?").strip()
        check(idn.split(",")[1] == "idmd", "*IDN? names idmd: " + idn)
        p0 = float(inst.query("POS?"))
        inst.write("MOVE:REL 5e-6")
        check(wait_done(inst.query), "MOVE:REL 5e-6 finishes")
        p1 = float(inst.query("POS?"))
        check(abs(p1 - p0 - 5e-6) < 20e-9, "moved 5 um: %g -> %g" % (p0, p1))
        check(inst.query("SYST:ERR?").strip().startswith("0,"), "no error after the move")
        inst.write("MOVE:ABS %r" % (p1 - 2e-6))
        check(wait_done(inst.query), "MOVE:ABS back 2 um finishes")
        check(abs(float(inst.query("POS?")) - (p1 - 2e-6)) < 20e-9, "at the absolute target")
        # Errors: an unknown header, a target past the soft limits, a non-number.
        inst.write("FROBNICATE 3")
        check(inst.query("SYST:ERR?").startswith("-113"), "unknown header -> -113")
        inst.write("LIM:UPP 1e-4")
        inst.write("MOVE:ABS 2e-4")
        err = inst.query("SYST:ERR?")
        check(err.startswith("-222"), "past the soft limit -> -222: " + err.strip())
        inst.write("LIM:UPP 5e-3")  # back to the travel
        inst.write("MOVE:REL nan")
        check(inst.query("SYST:ERR?").startswith("-1"), "NaN argument -> command error")
        # STOP mid-move: a long move, stopped; at rest quickly, far from the target.
        inst.write("MOVE:REL -4e-3")
        time.sleep(0.3)
        check(inst.query("MOVE:DONE?").strip() == "0", "a long move is in progress")
        t = time.time()
        inst.write("STOP")
        check(wait_done(inst.query, 5), "STOP brings it to rest")
        st = status(inst)
        check(st["state"] == "IDLE", "IDLE after STOP (%.3f s)" % (time.time() - t))
        check(abs(float(st["position"]) - float(st["target"])) > 10e-6, "stopped short of the target")
        check(inst.query("*OPC?").strip() == "1", "*OPC? 1 at rest")
        inst.close()
        check(d.stop(20) == 0, "SIGTERM -> exit 0")


def case_idmctl():
    if not os.path.exists(harness.IDMCTL):
        fail("idmctl not built")
    with Daemon(config()) as d:
        def ctl(*args):
            r = idmctl("--port", d.port, *args)
            return r.returncode, r.stdout.strip(), r.stderr.strip()
        rc, out, _ = ctl("pos")
        check(rc == 0, "idmctl pos: " + out)
        p0 = float(out.split()[-1])
        rc, out, err = ctl("move", repr(p0 + 4e-6))
        check(rc == 0, "idmctl move waits and succeeds " + err)
        rc, out, _ = ctl("pos")
        check(abs(float(out.split()[-1]) - p0 - 4e-6) < 20e-9, "at the target: " + out)
        r = idmctl("--unix", d.sock, "status")
        rc, out = r.returncode, r.stdout.strip()
        check(rc == 0 and "state=IDLE" in out, "idmctl over the Unix socket: " + out)
        check(d.stop(20) == 0, "SIGTERM -> exit 0")


def case_idmctl_jog():
    """idmctl velocity and jog against the real idmd: the speed limit set and read in units per
    second, refused out of range with idmd's message (the command and the range); jog + ends at
    the upper soft limit (OK), jog - stopped by another idmctl's stop, and by Ctrl-C on the jog's
    own idmctl (it sends STOP, exit 130)."""
    if not os.path.exists(harness.IDMCTL):
        fail("idmctl not built")
    with Daemon(config()) as d:
        def ctl(*args):
            r = idmctl("--unix", d.sock, *args)
            return r.returncode, r.stdout.strip(), r.stderr.strip()

        def result():
            word, dist = ctl("raw", "MOVE:RES?")[1].split(",")
            return word, float(dist)

        rc, out, err = ctl("velocity")
        check(rc == 0 and float(out) == 0, "no speed limit by default: %r %r" % (out, err))
        rc, out, err = ctl("velocity", "2m/s")
        check(rc == 1 and out == "" and "-222," in err and "MOVE:VELocity" in err and
              "allowed [0, 1] m/s" in err, "2 m/s refused, naming the command and range: " + err)
        rc, out, err = ctl("velocity", "-1um/s")
        check(rc == 1 and "-222," in err and "allowed [0, 1] m/s" in err, "-1 um/s refused: " + err)
        rc, out, err = ctl("velocity", "2mm/s")
        check(rc == 0 and out == "" and err == "", "velocity 2mm/s: %r" % err)
        rc, out, _ = ctl("--unit", "um", "velocity")
        check(rc == 0 and out == "2000", "read back in um/s: %r" % out)
        check(float(ctl("raw", "MOVE:VEL?")[1]) == 2e-3, "idmd has 0.002 m/s")
        check(ctl("limits", "-50um", "150um")[0] == 0, "soft limits -50 um, 150 um")
        rc, out, err = ctl("--unit", "um", "jog", "+")
        window_um = float(ctl("--unit", "um", "raw", "MOVE:WIND?")[1]) * 1e6
        count_um = float(ctl("raw", "RES?")[1]) * 1e6
        check(rc == 0 and 150 - 2 * window_um - count_um <= float(out) <= 150,
              "jog + waits and ends at the upper soft limit, inside: %r %r" % (out, err))
        check(result()[0] == "OK", "MOVE:RES? OK at the limit: %r" % (result(),))
        # Slower, so that the stops land on the way.
        check(ctl("velocity", "200um/s")[0] == 0, "velocity 200um/s")
        rc, out, err = ctl("--no-wait", "jog", "negative")
        check(rc == 0 and out == "", "jog negative --no-wait returns at once: %r" % err)
        time.sleep(0.3)
        check(ctl("raw", "MOVE:DONE?")[1] == "0", "the jog goes on")
        check(ctl("stop")[0] == 0, "idmctl stop")
        rc, out, _ = ctl("wait")
        word, _ = result()
        p = float(ctl("pos")[1])
        check(word == "STOPPED" and -50e-6 < p < 150e-6 - 10e-6,
              "jog - stopped on the way: %s at %g" % (word, p))
        # Ctrl-C while jog waits: idmctl sends STOP and exits 130.
        jog = subprocess.Popen([harness.IDMCTL, "--unix", d.sock, "jog", "-"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(0.4)
        check(jog.poll() is None, "jog - waits while the axis moves")
        jog.send_signal(2)
        out, err = jog.communicate(timeout=20)
        check(jog.returncode == 130 and "sent STOP" in err, "Ctrl-C: STOP, exit 130: %r" % err)
        ctl("wait")
        word, _ = result()
        q = float(ctl("pos")[1])
        check(word == "STOPPED" and -50e-6 < q < p - 10e-6,
              "jog - stopped by Ctrl-C on the way: %s at %g (from %g)" % (word, q, p))
        check(d.stop(20) == 0, "SIGTERM -> exit 0")


def case_notify_sigterm():
    """READY=1, WATCHDOG=1 while the loop runs, STOPPING=1; SIGTERM mid-move -> exit 0, output 0."""
    path = os.path.join(harness.TMP, "notify.sock")
    rx = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    rx.bind(path)
    rx.settimeout(0.2)
    got = []
    stop = threading.Event()

    def listen():
        while not stop.is_set():
            try:
                got.append((time.time(), rx.recv(4096).decode()))
            except socket.timeout:
                pass
    th = threading.Thread(target=listen)
    th.start()
    try:
        with Daemon(config(), env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "200000"}) as d:
            end = time.time() + 10
            while time.time() < end and not any("READY=1" in m for _, m in got):
                time.sleep(0.01)
            check(any("READY=1" in m for _, m in got), "READY=1 once the device is configured")
            check(any("STATUS=" in m for _, m in got), "STATUS= in words: " +
                  "; ".join(m.replace("\n", " ") for _, m in got[:3]))
            # Three pings (every WATCHDOG_USEC / 2 = 0.1 s); waited for up to 10 s, not counted
            # in a fixed window: a loaded machine (CI's sanitizer stage) delays them.
            t_ready = time.time()
            end = t_ready + 10
            while time.time() < end and sum("WATCHDOG=1" in m for _, m in got) < 3:
                time.sleep(0.01)
            pings = [t for t, m in got if "WATCHDOG=1" in m]
            check(len(pings) >= 3, "WATCHDOG=1 while the loop advances (%d in %.2f s)"
                  % (len(pings), time.time() - t_ready))
            inst = visa(d.port)
            inst.write("MOVE:REL 4e-3")
            time.sleep(0.3)
            check(inst.query("MOVE:DONE?").strip() == "0", "moving when SIGTERM comes")
            inst.close()
            rc = d.stop(20)
            check(rc == 0, "SIGTERM mid-move -> exit 0")
            time.sleep(0.3)
            check(any("STOPPING=1" in m for _, m in got), "STOPPING=1 on the way out")
            log = d.log()
            check("every output at zero (commanded elongation x 0 m)" in log, "output at zero after SIGTERM")
    finally:
        stop.set()
        th.join()


def case_modbus():
    port = free_port()
    # The simulated device's plant is the ideal model: alpha 1.
    cfg = modbus_config(port, [("step_correction: 0.35", "step_correction: 1.0")],
                        out="modbus.yaml")
    # The device and the daemon read the same file, so that they agree on the word format.
    with SimDev(port, cfg), Daemon(cfg) as d:
        inst = visa(d.port)
        p0 = float(inst.query("POS?"))
        inst.write("STEP 20")
        check(wait_done(inst.query, 30), "open-loop STEP 20 over Modbus finishes")
        p1 = float(inst.query("POS?"))
        check(p1 - p0 > 1e-6, "20 cycles moved the slider: %g -> %g" % (p0, p1))
        err = inst.query("SYST:ERR?").strip()
        check(err.startswith("0,"), "no error: " + err)
        inst.write("MOVE:REL -5e-6")
        check(wait_done(inst.query, 30), "closed-loop MOVE:REL over Modbus finishes")
        p2 = float(inst.query("POS?"))
        st = status(inst)
        check(st["state"] == "IDLE" and abs(p2 - p1 + 5e-6) < 50e-9,
              "moved -5 um closed loop: %g -> %g (%s)" % (p1, p2, st["fault"]))
        inst.write("STEP 20000")
        time.sleep(0.2)
        inst.close()
        check(d.stop(20) == 0, "SIGTERM mid-burst over Modbus -> exit 0")
        check("output at zero" in d.log(), "output at zero")


def idmd(*args):
    """idmd run with `args` to its end (30 s at most), the output as text."""
    return subprocess.run([harness.IDMD] + list(args), capture_output=True, text=True, timeout=30)


def case_bad_config():
    cfg = temp_file("bad.yaml", "daq:\n  driver: sim\ncontrol:\n  max_retries: many\n")
    r = idmd("--check-config", cfg)
    check(r.returncode == 2, "--check-config of a bad file exits 2")
    check("bad.yaml:4" in r.stderr and "control.max_retries" in r.stderr,
          "the error names the line and the key: " + r.stderr.strip())
    r = idmd("--config", cfg, "--port", "0", "--unix", "")
    check(r.returncode == 2, "idmd with a bad file exits 2 before touching hardware")
    # The default config as the build writes it (its state under build/state): config/idmd.yaml
    # itself names the installed service's /var/lib/idmd, which a dev machine does not have.
    r = idmd("--check-config", os.path.join(harness.BUILD, "config", "idmd.yaml"))
    check(r.returncode == 0, "the default config checks: " + r.stdout.strip() + r.stderr.strip())
    r = idmd("--port", "x")
    check(r.returncode == 2, "bad usage exits 2")


def case_missing_device():
    port = free_port()  # nothing listens there
    cfg = modbus_config(port, out="nodev.yaml")
    r = idmd("--config", cfg, "--port", "0", "--unix", "")
    check(r.returncode == 3, "a missing device exits 3 (got %d)" % r.returncode)
    check("cannot open the modbus device" in r.stderr and str(port) in r.stderr,
          "the error says which device: " + r.stderr.strip().splitlines()[-1])


CASES = {"pyvisa": case_pyvisa, "idmctl": case_idmctl, "idmctl_jog": case_idmctl_jog,
         "notify_sigterm": case_notify_sigterm,
         "modbus": case_modbus, "bad_config": case_bad_config,
         "missing_device": case_missing_device}

if __name__ == "__main__":
    harness.run(CASES)
