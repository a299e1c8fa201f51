"""The README's install, for real and offline: a new venv (Debian's python3-venv, with the
system's setuptools and wheel), `pip install --no-build-isolation ./python` with every package
index switched off, then an axis moved and a Bluesky-style set()/wait() from that venv's python
(outside the source tree) against a real idmd."""
import json
import os
import shutil
import subprocess
import textwrap

import pytest

from conftest import SOURCE

SYSTEM_PYTHON = "/usr/bin/python3"


def offline_env():
    """The environment without any pip configuration or index: nothing may be downloaded."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("PIP_") and k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PIP_CONFIG_FILE"] = os.devnull
    env["PIP_NO_INDEX"] = "1"
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


def sh(args, cwd, env, timeout=300):
    r = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, "%s failed (%d):\n%s\n%s" % (" ".join(args), r.returncode,
                                                          r.stdout[-3000:], r.stderr[-3000:])
    return r.stdout


def test_pip_install_into_a_venv_and_move(tmp_dir, make_idmd):
    if not os.path.exists(SYSTEM_PYTHON):
        pytest.fail("no %s (Debian's python3)" % SYSTEM_PYTHON)
    # The package tree copied, so that the build's files (build/, *.egg-info) stay out of the
    # source tree; the commands are README.md's.
    src = os.path.join(tmp_dir, "idm-src", "python")
    shutil.copytree(os.path.join(SOURCE, "python"), src,
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    venv = os.path.join(tmp_dir, "venv")
    env = offline_env()
    sh([SYSTEM_PYTHON, "-m", "venv", "--system-site-packages", venv], tmp_dir, env)
    pip = os.path.join(venv, "bin", "pip")
    sh([pip, "install", "--no-build-isolation", "./idm-src/python"], tmp_dir, env)
    show = sh([pip, "show", "idm-client"], tmp_dir, env)
    assert "Name: idm-client" in show

    d = make_idmd()
    script = textwrap.dedent("""
        import json, sys
        import idm
        with idm.Client(unix=sys.argv[1]) as client:
            x = client.axis(1)
            p0 = x.position()
            arrived = x.move(p0 + 5e-6)
            motor = x.movable("x")
            status = motor.set(p0 + 2e-6)
            status.wait(60)
            print(json.dumps({"file": idm.__file__, "p0": p0, "arrived": arrived,
                              "success": status.success, "read": motor.read()["x"]["value"]}))
    """)
    out = sh([os.path.join(venv, "bin", "python"), "-c", script, d.unix], tmp_dir, env)
    got = json.loads(out.strip().splitlines()[-1])
    assert got["file"].startswith(os.path.realpath(venv)) or got["file"].startswith(venv), got
    assert abs(got["arrived"] - (got["p0"] + 5e-6)) < 20e-9
    assert got["success"] is True
    assert abs(got["read"] - (got["p0"] + 2e-6)) < 20e-9
