"""idmd from a clone's build tree (what ./idm run does), without the installed service's
/var/lib/idmd and /run/idmd: the build writes build/config/NAME.yaml for every shipped config with
the state under build/state; each checks clean (no error, no warning), and idmd runs on the
default one as ./idm run starts it: `idmctl show` has no error to show before or after a move, and
SIGTERM ends it with 0. The shipped files keep the service's paths.

Environment: IDM_BUILD_DIR, IDM_SOURCE_DIR. CTest: daemon.build_tree_configs.
"""
import os
import re
import shutil
import signal
import subprocess
import tempfile

import pytest

BUILD = os.environ["IDM_BUILD_DIR"]
SOURCE = os.environ["IDM_SOURCE_DIR"]
IDMD = os.path.join(BUILD, "daemon", "idmd")
IDMCTL = os.path.join(BUILD, "tools", "idmctl")
STATE = os.path.join(BUILD, "state")
NAMES = ["idmd", "idmd-xyz", "idmd-modbus", "idmd-usb"]
PATH_KEYS = re.compile(r"^\s*(calibration_file|data_dir|unix_socket|reference_file):\s*(\S+)",
                       re.M)


def build_config(name):
    return os.path.join(BUILD, "config", name + ".yaml")


@pytest.mark.parametrize("name", NAMES)
def test_the_build_tree_config_keeps_its_state_in_the_build_tree_and_checks_clean(name):
    path = build_config(name)
    assert os.path.isfile(path), "the build did not write " + path
    with open(path) as f:
        text = f.read()
    paths = PATH_KEYS.findall(text)
    assert paths, "no paths in " + path
    for key, value in paths:
        assert value.startswith(STATE + "/"), (key, value)
    r = subprocess.run([IDMD, "--check-config", path], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", "warnings: " + r.stderr
    # The shipped file is the installed service's: its state stays in /var/lib/idmd.
    with open(os.path.join(SOURCE, "config", name + ".yaml")) as f:
        assert "/var/lib/idmd/data" in f.read()


def test_idmd_runs_on_the_build_tree_config_as_idm_run_starts_it():
    run_dir = tempfile.mkdtemp(prefix="idm-run-")
    sock = os.path.join(run_dir, "idmd.sock")
    err = open(os.path.join(run_dir, "idmd.err"), "w+")
    proc = subprocess.Popen([IDMD, "--config", build_config("idmd"), "--port", "0", "--unix", sock],
                            stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        line = proc.stdout.readline()
        assert "listening" in line, line

        def ctl(*args):
            r = subprocess.run([IDMCTL, "--unix", sock] + list(args), capture_output=True,
                               text=True, timeout=120)
            return r.returncode, r.stdout + r.stderr

        rc, out = ctl("show")
        assert rc == 0 and "last error" not in out, out
        rc, out = ctl("move", "5e-6")
        assert rc == 0, out
        rc, out = ctl("show")
        assert rc == 0 and "last error" not in out and "OK" in out, out
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        err.seek(0)
        log = err.read()
        err.close()
        shutil.rmtree(run_dir, ignore_errors=True)
    for line in log.splitlines():
        if " warning: " in line or " error: " in line:
            assert "data_dir" not in line and "calibration" not in line, log


def shipped_calibration_files():
    """(config, calibration_file) of every axis of every shipped config, as the file gives it."""
    out = []
    for name in NAMES:
        with open(os.path.join(SOURCE, "config", name + ".yaml")) as f:
            out += [(name, v) for k, v in PATH_KEYS.findall(f.read()) if k == "calibration_file"]
    return out


def test_every_shipped_stage_learns_into_a_file_of_its_own():
    """A calibration belongs to one stage: two shipped configs (or two axes) sharing one file
    would stop idmd on the second ('a calibration of another stage') once the first had run."""
    files = shipped_calibration_files()
    assert len(files) >= len(NAMES)
    paths = [p for _, p in files]
    assert len(set(paths)) == len(paths), files


def test_after_the_default_config_ran_every_shipped_config_still_checks_and_starts():
    """The lab's path: ./idm run (the default config) first, then another shipped config in the
    same state directory: --check-config is clean and idmd starts on the simulated ones."""
    test_idmd_runs_on_the_build_tree_config_as_idm_run_starts_it()
    for name in NAMES:
        r = subprocess.run([IDMD, "--check-config", build_config(name)], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 0 and "calibration" not in r.stderr, (name, r.stderr)


def test_check_config_refuses_a_calibration_of_another_stage():
    """--check-config reads the calibration file as the start does: one written for another stage
    (here Table 1's, step_correction 1, under the Modbus stage's 0.35) is an error naming the key
    and both values, exit 2, as idmd's start would be."""
    tmp = tempfile.mkdtemp(prefix="idm-cal-")
    try:
        cal = os.path.join(tmp, "calibration.txt")
        with open(os.path.join(SOURCE, "config", "idmd.yaml")) as f:
            default = f.read().replace("/var/lib/idmd", tmp)
        with open(os.path.join(SOURCE, "config", "idmd-modbus.yaml")) as f:
            modbus = re.sub(r"calibration_file: \S+", "calibration_file: " + cal,
                            f.read().replace("/var/lib/idmd", tmp))
        for n, text in (("a.yaml", default), ("b.yaml", modbus)):
            with open(os.path.join(tmp, n), "w") as f:
                f.write(text.replace("sched_fifo: true", "sched_fifo: false")
                        .replace("lock_memory: true", "lock_memory: false"))
        sock = os.path.join(tmp, "s.sock")
        proc = subprocess.Popen([IDMD, "--config", os.path.join(tmp, "a.yaml"), "--port", "0",
                                 "--unix", sock], stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True)
        try:
            assert "listening" in proc.stdout.readline()
            r = subprocess.run([IDMCTL, "--unix", sock, "move", "50um"], capture_output=True,
                               text=True, timeout=120)
            assert r.returncode == 0, r.stdout + r.stderr
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)
        assert os.path.exists(cal)
        r = subprocess.run([IDMD, "--check-config", os.path.join(tmp, "b.yaml")],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 2, r.stdout + r.stderr
        assert "step_correction 1 differs from the configured 0.35" in r.stderr, r.stderr
        assert "control.calibration_file" in r.stderr and cal in r.stderr, r.stderr
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
