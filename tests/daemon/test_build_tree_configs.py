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
    assert "/var/lib/idmd" not in text and "/run/idmd" not in text, path
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
