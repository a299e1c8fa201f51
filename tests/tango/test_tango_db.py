"""idm-tango with a Tango database: its devices configured by the device properties Axis,
IdmdSocket and IdmdAddress alone. The database is PyTango's own database server with its sqlite3
backend (pytango_database.py here, python3-tango), in a temporary directory on a free port;
idm-tango runs without -nodb, with TANGO_HOST pointing there and IDMD_ADDRESS pointing to a
closed port, so that only the properties can lead a device to idmd (config/idmd-xyz.yaml: three
simulated axes x, y, z)."""
import os
import sys
import time

import pytest
import tango

from conftest import IDM_TANGO, fixtures, wait_for

DATABASE_DS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "pytango_database.py")
SERVER = "idm-tango/dbtest"

ask = fixtures.ask
send = fixtures.send


def xyz_config(tmp):
    return fixtures.edit(fixtures.read_config("idmd-xyz.yaml"),
                         [("/var/lib/idmd", tmp), ("sched_fifo: true", "sched_fifo: false"),
                          ("lock_memory: true", "lock_memory: false")], "config/idmd-xyz.yaml")


class TangoDatabase(fixtures.ChildProcess):
    """PyTango's database server (sys/database/2) on a free port, its sqlite file in
    `tmp`; TANGO_HOST only in its own environment."""

    def __init__(self, tmp):
        super().__init__(os.path.join(tmp, "databaseds.log"))
        self.port = fixtures.free_port()
        self.host = "127.0.0.1:%d" % self.port
        env = dict(os.environ, TANGO_HOST=self.host)
        line = self.start([sys.executable, "-u", DATABASE_DS, tmp, "--port", str(self.port),
                           "2"], 60, env=env)
        if "Ready" not in line:
            self.stop()
            pytest.fail("the Tango database did not start: %r\n%s" % (line, self.log()))
        self.db = self._connect(30)

    def _connect(self, timeout):
        end = time.monotonic() + timeout
        while True:
            try:
                return tango.Database("127.0.0.1", self.port)
            except tango.DevFailed:
                if time.monotonic() > end or not self.alive():
                    self.stop()
                    pytest.fail("the Tango database does not answer\n" + self.log())
                time.sleep(0.2)

    def add_device(self, name, properties, server=SERVER, klass="IdmAxis"):
        info = tango.DbDevInfo()
        info.name, info._class, info.server = name, klass, server
        self.db.add_device(info)
        self.db.put_device_property(name, properties)


class DbTangoServer(fixtures.ChildProcess):
    """idm-tango INSTANCE with the database (no -nodb): TANGO_HOST and `env` its environment."""

    def __init__(self, tmp, database, env, instance="dbtest"):
        fixtures.require_built(IDM_TANGO, "idm-tango")
        super().__init__(os.path.join(tmp, "idm-tango-%s.log" % instance))
        self.database = database
        full_env = {k: v for k, v in os.environ.items()
                    if k not in ("IDMD_SOCKET", "IDMD_ADDRESS", "TANGO_HOST")}
        full_env.update(env)
        full_env["TANGO_HOST"] = database.host
        line = self.start([IDM_TANGO, instance], 60, env=full_env)
        if "ready" not in line:
            self.stop()
            pytest.fail("idm-tango did not start: %r\n%s\ndatabase:\n%s"
                        % (line, self.log(), database.log()))

    def proxy(self, device):
        d = tango.DeviceProxy("tango://%s/%s" % (self.database.host, device))
        d.set_timeout_millis(10000)
        return d


def bad_properties(daemon):
    """Devices whose properties are wrong: {name: (properties, words its Status must hold)}."""
    unix = [daemon.unix]
    tcp = ["127.0.0.1:%d" % daemon.port]
    return {
        "lab/bad/axis": ({"Axis": ["two"], "IdmdSocket": unix},
                         ["property Axis", "'two'", "not an axis number (1..1000)"]),
        "lab/bad/zero": ({"Axis": ["0"], "IdmdSocket": unix},
                         ["property Axis", "'0'", "not an axis number (1..1000)"]),
        "lab/bad/address": ({"Axis": ["1"], "IdmdAddress": ["127.0.0.1:http"]},
                            ["property IdmdAddress", "'127.0.0.1:http'", "port is not a number"]),
        "lab/bad/both": ({"Axis": ["1"], "IdmdSocket": unix, "IdmdAddress": tcp},
                         ["IdmdSocket and IdmdAddress are both set"]),
    }


BAD = ("lab/bad/axis", "lab/bad/zero", "lab/bad/address", "lab/bad/both")


@pytest.fixture(scope="module")
def lab():
    """idmd on three axes, the database with this module's devices, idm-tango serving them with
    IDMD_ADDRESS a closed port: (daemon, database, server, that address)."""
    with fixtures.idmd_in_temp_dir("idm-tango-db-", config=xyz_config) as daemon:
        database = TangoDatabase(daemon.tmp)
        server = None
        try:
            unix = {"IdmdSocket": [daemon.unix]}
            tcp = {"IdmdAddress": ["127.0.0.1:%d" % daemon.port]}
            database.add_device("lab/stage/x", dict(unix, Axis=["1"]))
            database.add_device("lab/stage/y", dict(tcp, Axis=["2"]))
            database.add_device("idm/axis/3", unix)
            database.add_device("lab/env/x", {"Axis": ["1"]})
            for name, (properties, _) in bad_properties(daemon).items():
                database.add_device(name, properties)
            nowhere = "127.0.0.1:%d" % fixtures.free_port()
            server = DbTangoServer(daemon.tmp, database, {"IDMD_ADDRESS": nowhere})
            yield daemon, database, server, nowhere
            alive = server.alive()
        finally:
            if server is not None:
                server.stop()
            database.stop()
    assert alive, "idm-tango died during the tests"


def resolution(daemon, axis):
    return float(ask(daemon, "AXIS%d:RES?" % axis)[0])


def mean_position(daemon, axis, n=8):
    return sum(float(ask(daemon, "AXIS%d:POS?" % axis)[0]) for _ in range(n)) / n


def wait_on(dev, timeout=60):
    wait_for("State ON", lambda: dev.state() == tango.DevState.ON, timeout)


def wait_done(daemon, axis, timeout=60):
    wait_for("axis %d at rest" % axis,
             lambda: ask(daemon, "AXIS%d:MOVE:DONE?" % axis)[0] == "1", timeout)


def test_properties_lead_a_device_to_idmd_over_its_unix_socket(lab):
    daemon, database, server, _ = lab
    x = server.proxy("lab/stage/x")
    assert x.state() == tango.DevState.ON, x.status()
    assert "axis x" in x.status() and daemon.unix in x.status(), x.status()
    position = x.read_attribute("Position")
    assert position.quality == tango.AttrQuality.ATTR_VALID
    assert abs(position.value - mean_position(daemon, 1)) < 5 * resolution(daemon, 1)
    # Position's min/max, the soft limits, as attribute properties in the database.
    config = x.get_attribute_config("Position")
    lower, upper = (float(v) for v in ask(daemon, "AXIS1:LIM?")[0].split(","))
    assert float(config.min_value) == pytest.approx(lower)
    assert float(config.max_value) == pytest.approx(upper)
    stored = database.db.get_device_attribute_property("lab/stage/x", ["Position"])["Position"]
    assert float(stored["min_value"][0]) == pytest.approx(lower)
    assert float(stored["max_value"][0]) == pytest.approx(upper)


def test_a_written_position_moves_the_stage(lab):
    daemon, _, server, _ = lab
    x = server.proxy("lab/stage/x")
    target = mean_position(daemon, 1) + 20e-6
    x.write_attribute("Position", target)
    wait_for("State MOVING or the target", lambda: x.state() == tango.DevState.MOVING or
             float(ask(daemon, "AXIS1:MOVE?")[0]) == pytest.approx(target, abs=1e-12), 10)
    wait_on(x)
    wait_done(daemon, 1)
    assert float(ask(daemon, "AXIS1:MOVE?")[0]) == pytest.approx(target, abs=1e-12)
    assert abs(mean_position(daemon, 1) - target) <= 2 * resolution(daemon, 1)
    assert abs(x.read_attribute("Position").value - target) <= 2 * resolution(daemon, 1)


def test_the_axis_property_selects_the_axis_over_tcp(lab):
    """lab/stage/y: Axis=2, IdmdAddress the daemon's TCP port. Axis 2 moved by the daemon's
    protocol first, so that the axes' positions differ."""
    daemon, _, server, _ = lab
    y = server.proxy("lab/stage/y")
    res = resolution(daemon, 2)
    moved = mean_position(daemon, 1) - 60e-6
    send(daemon, "AXIS2:MOVE:ABS %.12g" % moved)
    wait_done(daemon, 2)
    assert abs(mean_position(daemon, 2) - mean_position(daemon, 1)) > 40e-6
    wait_on(y)
    assert "axis y" in y.status() and "127.0.0.1:%d" % daemon.port in y.status(), y.status()
    assert abs(y.read_attribute("Position").value - mean_position(daemon, 2)) < 5 * res
    # A write moves axis 2, and only axis 2.
    target_1 = float(ask(daemon, "AXIS1:MOVE?")[0])
    target = moved + 15e-6
    y.write_attribute("Position", target)
    wait_for("the move of axis 2",
             lambda: float(ask(daemon, "AXIS2:MOVE?")[0]) == pytest.approx(target, abs=1e-12), 10)
    wait_on(y)
    wait_done(daemon, 2)
    assert abs(mean_position(daemon, 2) - target) <= 2 * res
    assert float(ask(daemon, "AXIS1:MOVE?")[0]) == target_1


def test_without_an_axis_property_the_name_gives_the_axis(lab):
    daemon, _, server, _ = lab
    z = server.proxy("idm/axis/3")
    wait_on(z, 10)
    assert "axis z" in z.status(), z.status()
    assert abs(z.read_attribute("Position").value - mean_position(daemon, 3)) < \
        5 * resolution(daemon, 3)


def test_without_an_address_property_the_environment_is_used(lab):
    """lab/env/x has Axis=1 alone: it goes to IDMD_ADDRESS, the closed port (so the devices
    above reached idmd by their properties)."""
    _, _, server, nowhere = lab
    dev = server.proxy("lab/env/x")
    assert dev.state() == tango.DevState.FAULT
    assert "idmd not reached" in dev.status() and nowhere in dev.status(), dev.status()


def test_the_properties_override_a_malformed_environment(lab):
    """A second server whose IDMD_ADDRESS does not parse: its device with an IdmdSocket property
    works all the same."""
    daemon, database, _, _ = lab
    database.add_device("lab/other/x", {"Axis": ["1"], "IdmdSocket": [daemon.unix]},
                        server="idm-tango/dbenv")
    other = DbTangoServer(daemon.tmp, database, {"IDMD_ADDRESS": "127.0.0.1:http"},
                          instance="dbenv")
    try:
        x = other.proxy("lab/other/x")
        assert x.state() == tango.DevState.ON, x.status()
        assert "axis x" in x.status(), x.status()
    finally:
        other.stop()


@pytest.mark.parametrize("name", BAD)
def test_a_bad_property_puts_the_device_in_fault_saying_which(lab, name):
    daemon, _, server, _ = lab
    dev = server.proxy(name)
    assert dev.state() == tango.DevState.FAULT
    status = dev.status()
    for words in bad_properties(daemon)[name][1]:
        assert words in status, status
    with pytest.raises(tango.DevFailed) as failed:
        dev.read_attribute("Position")
    assert failed.value.args[0].reason == "IdmConfig"
    assert server.alive()
