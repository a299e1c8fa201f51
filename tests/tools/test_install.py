"""`cmake --install` of the build tree into a staging directory (DESTDIR, never the system's own
paths): the shipped config/idmd.yaml goes to SYSCONFDIR/idmd/idmd.yaml only where there is none (a
lab's edited file survives a second install, and the install says it kept it), and every shipped
config is installed, refreshed on every install, under DOCDIR/examples.

Environment: IDM_BUILD_DIR (a built tree), IDM_SOURCE_DIR. CTest: tools.install.
"""
import filecmp
import os
import re
import shutil
import subprocess
import tempfile

import pytest

BUILD = os.environ["IDM_BUILD_DIR"]
SOURCE = os.environ["IDM_SOURCE_DIR"]
SHIPPED = ["idmd.yaml", "idmd-xyz.yaml", "idmd-modbus.yaml", "idmd-usb.yaml", "README.md"]


def cache(name):
    with open(os.path.join(BUILD, "CMakeCache.txt")) as f:
        for line in f:
            m = re.match(r"%s:[A-Z]+=(.*)$" % re.escape(name), line.strip())
            if m:
                return m.group(1)
    return None


@pytest.fixture
def stage():
    """A staging directory (DESTDIR), removed afterwards (an install holds ~150 MB)."""
    d = tempfile.mkdtemp(prefix="idm-install-")
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


def install(destdir, prefix="/usr"):
    """cmake --install BUILD --prefix PREFIX with DESTDIR; its output (it must succeed)."""
    r = subprocess.run(["cmake", "--install", BUILD, "--prefix", prefix],
                       env=dict(os.environ, DESTDIR=destdir), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout + r.stderr


def installed_config(destdir):
    """The one SYSCONFDIR/idmd/idmd.yaml below `destdir` (wherever the prefix put it)."""
    found = [os.path.join(d, "idmd.yaml") for d, _, files in os.walk(destdir)
             if os.path.basename(d) == "idmd" and "idmd.yaml" in files]
    assert len(found) == 1, found
    return found[0]


def shipped(name):
    return os.path.join(SOURCE, "config", name)


def test_a_fresh_install_puts_the_default_config_and_the_examples_in_place(stage):
    out = install(stage)
    config = os.path.join(stage, "etc", "idmd", "idmd.yaml")  # prefix /usr: /etc
    assert os.path.isfile(config), out
    assert filecmp.cmp(config, shipped("idmd.yaml"), shallow=False)
    assert "Kept" not in out
    examples = os.path.join(stage, "usr", "share", "doc", "idm", "examples")
    for name in SHIPPED:
        assert filecmp.cmp(os.path.join(examples, name), shipped(name), shallow=False), name
    assert os.path.isfile(os.path.join(stage, "usr", "sbin", "idmd"))


def test_an_edited_config_survives_a_second_install_and_the_examples_are_refreshed(stage):
    install(stage)
    config = installed_config(stage)
    with open(config, "a") as f:
        f.write("# the lab's own stage, edited after the first install\n")
    with open(config) as f:
        edited = f.read()
    # An example left from an older version (older and different): the install replaces it.
    example = os.path.join(stage, "usr", "share", "doc", "idm", "examples", "idmd-modbus.yaml")
    with open(example, "w") as f:
        f.write("# an older example\n")
    os.utime(example, (1e9, 1e9))
    out = install(stage)
    with open(config) as f:
        assert f.read() == edited, "the second install overwrote the edited configuration"
    assert "Kept: " + config in out, out
    assert "share/doc/idm/examples/idmd.yaml" in out, "the message names the shipped default: " + out
    assert filecmp.cmp(example, shipped("idmd-modbus.yaml"), shallow=False), "example refreshed"
    # A config identical to the shipped one is left as it is, and said so.
    shutil.copyfile(shipped("idmd.yaml"), config)
    out = install(stage)
    assert "Up-to-date: " + config in out, out


@pytest.mark.parametrize("prefix, sysconf", [("/opt/idm", "etc/opt/idm"),
                                             ("/srv/idm", "srv/idm/etc")])
def test_the_config_follows_the_install_prefix(stage, prefix, sysconf):
    """GNUInstallDirs' rule for the prefix given at install time: /opt/P reads /etc/opt/P, any
    other prefix but / and /usr its own etc."""
    if cache("CMAKE_INSTALL_SYSCONFDIR") != "etc":
        pytest.skip("the build names its own SYSCONFDIR")
    out = install(stage, prefix)
    config = os.path.join(stage, sysconf, "idmd", "idmd.yaml")
    assert filecmp.cmp(config, shipped("idmd.yaml"), shallow=False), out
    assert os.path.isfile(os.path.join(stage, prefix.lstrip("/"), "sbin", "idmd"))
