"""The client's own logic without a daemon: reply parsing, number and list formatting, and the
plans (idm._core) run against scripted replies, to show how the client speaks to a daemon with
the parts of the protocol's extension this tree's idmd does not answer yet (MOVE:RESult?,
STATus:OPERation?), to a daemon before the extension (no AXIS:COUNt?, no SWEEP?), and how it
handles replies that are hard to get from the real daemon on demand. What the daemon of this
tree answers is tested against the real idmd in the other modules."""
import math
import random
import re

import pytest

import idm
from idm import _core, _sweep
from idm._core import Line, Session, Sleep
from idm.errors import error_from_code, parse_error_line
from idm.status import AxisStatus, MoveResult, Operation, parse_number


def test_scpi_special_numbers():
    assert math.isnan(parse_number("9.91e+37"))
    assert parse_number("9.9e+37") == math.inf
    assert parse_number("-9.9e+37") == -math.inf
    assert parse_number("1.5e-06") == 1.5e-6
    with pytest.raises(idm.ProtocolError):
        parse_number("")


def test_error_lines_and_classes():
    assert parse_error_line('-222,"Data out of range; target 1000 m"') == (
        -222, "Data out of range; target 1000 m")
    assert parse_error_line('-102,"Syntax error; a ""quoted"" word"') == (
        -102, 'Syntax error; a "quoted" word')
    assert parse_error_line('0,"No error"') == (0, "No error")
    kinds = {-113: idm.CommandError, -222: idm.ExecutionError, -350: idm.DeviceSpecificError,
             -410: idm.QueryError, 102: idm.DeviceFault}
    for code, cls in kinds.items():
        e = error_from_code(code, "t", "X")
        assert type(e) is cls and isinstance(e, idm.ScpiError) and e.code == code


def test_number_and_list_formatting():
    assert _core.fmt(5e-6) == "5e-06" and _core.fmt(3) == "3"
    with pytest.raises(TypeError):
        _core.fmt(True)
    with pytest.raises(TypeError):
        _core.fmt("1")
    assert _core.fmt_list([100, 200.5], "f") == "100;200.5"
    assert _core.fmt_list("100:800:100", "f") == "100:800:100"
    assert _core.count_list("100:800:100") == 8
    assert _core.count_list("200:800:20") == 31
    assert _core.count_list("0.1;0.2") == 2 and _core.count_list(0.1) == 1
    with pytest.raises(ValueError):
        _core.fmt_list("1,2", "f")
    assert _core.quote("run-1/a") == "run-1/a"
    assert _core.quote('my "run", 2') == '"my ""run"", 2"'
    with pytest.raises(ValueError):
        _core.quote("a\nSTOP")


def test_status_and_result_parsing():
    st = AxisStatus.parse("state=MOVING done=0 position=1e-06 position_valid=1 target=2e-06 "
                          "fault=none moves=3 eot=low", Operation(0b100000001))
    assert st.moving and st.position == 1e-6 and st.moves == 3 and st.eot == "low"
    assert Operation.MOVING in st.operation and Operation.POSITION_VALID in st.operation
    assert MoveResult.parse("END_OF_TRAVEL,3.2e-06") == ("END_OF_TRAVEL", 3.2e-6)
    assert MoveResult.parse("OK,1e-09").ok


class Scripted:
    """Runs a plan against scripted replies: {line: reply}, {line: error code} (a query's
    reply then empty) or {line: (reply, error code)} (the daemon's 9.91E37 with -230); a list
    is answered item by item, its last item for ever after. Records every line sent."""

    def __init__(self, replies):
        self.replies = replies
        self.sent = []

    def run(self, plan):
        return _core.run_plan(plan, self.answer)

    def answer(self, op):
        if isinstance(op, Sleep):
            return None
        assert isinstance(op, Line)
        self.sent.append(op.text)
        answer = self.replies.get(op.text, -113 if op.query else None)
        if isinstance(answer, list):
            answer = answer.pop(0) if len(answer) > 1 else answer[0]
        if isinstance(answer, int):
            raise error_from_code(answer, "scripted", op.text, None, "" if op.query else None)
        if isinstance(answer, tuple):
            reply, code = answer
            raise error_from_code(code, "scripted", op.text, None, reply)
        return answer


def test_single_axis_daemon_axis_one_is_unprefixed():
    sess = Session()
    daemon = Scripted({"POSition?": "1e-06", "*CLS": None})
    assert daemon.run(_core.p_axis_query(sess, 1, "POSition?", parse_number_)) == 1e-6
    # the extension and the optional queries probed at once, one *CLS for the refusals
    assert daemon.sent == ["AXIS:COUNt?", "MOVE:RESult?", "STATus:OPERation?", "SWEEP?", "*CLS",
                           "POSition?"]
    # the probes are not repeated; another axis keeps its prefix (the daemon refuses it)
    with pytest.raises(idm.CommandError):
        daemon.run(_core.p_axis_query(sess, 2, "POSition?", parse_number_))
    assert daemon.sent[6:] == ["AXIS2:POSition?"]


def test_several_axes_daemon_probes_with_axis_one_and_clears_only_after_refusals():
    sess = Session()
    daemon = Scripted({"AXIS:COUNt?": "2", "AXIS1:MOVE:RESult?": "NONE,0",
                       "AXIS1:STATus:OPERation?": "256", "SWEEP?": 'NONE,1,0,0,0,""',
                       "AXIS2:STOP": None})
    daemon.run(_core.p_axis_command(sess, 2, "STOP"))
    assert daemon.sent == ["AXIS:COUNt?", "AXIS1:MOVE:RESult?", "AXIS1:STATus:OPERation?",
                           "SWEEP?", "AXIS2:STOP"]
    # a probe that fails with something other than -113 is raised (e.g. a device fault)
    daemon = Scripted({"AXIS:COUNt?": "2", "AXIS1:MOVE:RESult?": 102})
    with pytest.raises(idm.DeviceFault):
        daemon.run(_core.p_axis_command(Session(), 2, "STOP"))


def parse_number_(reply, what):
    return parse_number(reply, what)


def test_several_axes_by_number_and_name():
    sess = Session()
    daemon = Scripted({"AXIS:COUNt?": "2", "AXIS1:NAME?": "x", "AXIS2:NAME?": "y",
                       "AXIS2:STOP": None, "AXIS2:POSition?": "2e-06"})
    assert daemon.run(_core.p_axis_command(sess, "y", "STOP")) is None
    assert daemon.run(_core.p_axis_query(sess, "Y", "POSition?", parse_number_)) == 2e-6
    # names are asked once; with every name known, a case-insensitive match needs no query
    assert daemon.sent == ["AXIS:COUNt?", "AXIS1:NAME?", "AXIS2:NAME?", "AXIS2:STOP",
                           "AXIS2:POSition?"]
    # an unknown name asks the count again (the names stay cached), then is refused
    with pytest.raises(idm.AxisNotFound, match="1 x, 2 y"):
        daemon.run(_core.p_axis_number(sess, "z"))
    assert daemon.sent[5:] == ["AXIS:COUNt?"]


def test_move_result_not_ok_raises_move_error():
    sess = Session()
    daemon = Scripted({"AXIS:COUNt?": "1", "AXIS1:MOVE:ABSolute 1e-06": None,
                       "AXIS1:MOVE:DONE?": ["0", "1"], "AXIS1:MOVE:RESult?": "STOPPED,4e-07"})
    with pytest.raises(idm.MoveError) as e:
        daemon.run(_core.p_move(sess, 1, 1e-6, False, True, 10, 0, None))
    assert e.value.result == "STOPPED" and e.value.distance == 4e-7
    assert "AXIS1:MOVE:DONE?" in daemon.sent


def test_status_with_operation_bits():
    sess = Session()
    daemon = Scripted({"AXIS:COUNt?": "1", "AXIS1:STATus?": "state=IDLE done=1 position=0",
                       "AXIS1:STATus:OPERation?": "266"})
    st = daemon.run(_core.p_status(sess, 1))
    assert st.operation == Operation.IN_POSITION | Operation.REFERENCED | Operation.POSITION_VALID


def test_fault_noted_by_another_call_fails_the_wait():
    sess = Session()
    mark = sess.fault_seq
    sess.note_errors(error_from_code(102, "Stall", "POSition?"))
    daemon = Scripted({"MOVE:DONE?": "1"})
    with pytest.raises(idm.DeviceFault) as e:
        daemon.run(_core.p_wait_axis("", 10, 0, "MOVE:ABSolute 1e-06", faults=(sess, mark)))
    assert e.value.command == "MOVE:ABSolute 1e-06"
    # a fault from before the motion started does not count
    daemon.run(_core.p_wait_axis("", 10, 0, "MOVE:ABSolute 1e-06", faults=(sess, sess.fault_seq)))


def test_untrusted_position_is_raised_with_the_daemons_reply():
    """POS? without a trustworthy position: the daemon answers 9.91E37 and queues -230; the
    client raises -230 (never returns a number, never NaN) and keeps the reply."""
    sess = Session()
    daemon = Scripted({"AXIS:COUNt?": "2", "AXIS2:POSition?": ("9.91E37", -230)})
    with pytest.raises(idm.ExecutionError) as e:
        daemon.run(_core.p_axis_query(sess, 2, "POSition?", parse_number_))
    assert e.value.code == -230 and e.value.reply == "9.91E37"
    assert e.value.command == "AXIS2:POSition?"


def test_positions_with_an_untrusted_axis():
    daemon = Scripted({"POSition:ALL?": ("1.5e-06,9.91E37,-2e-06", -230)})
    with pytest.raises(idm.ExecutionError) as e:
        daemon.run(_core.p_positions(Session()))
    assert e.value.code == -230 and e.value.reply == "1.5e-06,9.91E37,-2e-06"
    got = daemon.run(_core.p_positions(Session(), allow_untrusted=True))
    assert got[0] == 1.5e-6 and math.isnan(got[1]) and got[2] == -2e-6
    # any other error is raised even with allow_untrusted (the reply is not taken then)
    daemon = Scripted({"POSition:ALL?": ("1.5e-06,9.91E37", -350)})
    with pytest.raises(idm.DeviceSpecificError):
        daemon.run(_core.p_positions(Session(), allow_untrusted=True))
    # an error without a reply neither
    daemon = Scripted({"POSition:ALL?": -113})
    with pytest.raises(idm.CommandError):
        daemon.run(_core.p_positions(Session(), allow_untrusted=True))
    daemon = Scripted({"POSition:ALL?": "0,1e-06"})
    assert daemon.run(_core.p_positions(Session())) == [0.0, 1e-6]


def test_status_of_the_several_axes_daemon():
    st = AxisStatus.parse("state=FAULT done=1 position=9.91E37 position_valid=0 target=5e-06 "
                          "fault=device_lost lower=-0.005 upper=0.005 moves=1 bursts=12 "
                          "cycles=32 errors=0 last_error=-230 daemon_error=device_remote_lost "
                          "axis=y referenced=0 device=lost")
    assert math.isnan(st.position) and st.position_valid is False
    assert st.axis == "y" and st.referenced is False and st.device == "lost"
    assert st.last_error == -230 and st.faulted
    assert AxisStatus.parse("state=IDLE referenced=1").referenced is True
    with pytest.raises(idm.ProtocolError):
        AxisStatus.parse("state=IDLE referenced=yes")


def test_sweep_state_parsing():
    st = idm.SweepState.parse('STOPPED,2,3,1,24,"/data/run ""a"", b"')
    assert st == ("STOPPED", 2, 3, 1, 24, '/data/run "a", b')
    assert not st.ok and not st.running
    assert idm.SweepState.parse('DONE,1,9,0,9,"/d/s"').ok
    assert not idm.SweepState.parse('DONE,1,8,1,9,"/d/s"').ok
    assert idm.SweepState.parse('NONE,1,0,0,0,""').directory == ""
    for bad in ("DONE,1,9,0,9", 'DONE,1,x,0,9,"/d"', "DONE,1,9,0,9,/d"):
        with pytest.raises(idm.ProtocolError):
            idm.SweepState.parse(bad)


def sweep_daemon(states, done=("0", "1"), extra=None):
    """A several-axes daemon that starts AXIS1:SWEEP run,500,0.1,3 and shows it in SWEEP?."""
    replies = {"AXIS:COUNt?": "1", "AXIS1:STATus?": "state=IDLE daemon_error=none",
               "SWEEP?": ['NONE,1,0,0,0,""'] + list(states),
               "AXIS1:SWEEP run,500,0.1,3": None, "AXIS1:MOVE:DONE?": list(done)}
    replies.update(extra or {})
    return Scripted(replies)


def test_sweep_follows_sweep_query():
    sess = Session()
    daemon = sweep_daemon(['RUNNING,1,0,0,3,"/data/run"', 'RUNNING,1,1,0,3,"/data/run"',
                           'DONE,1,3,0,3,"/data/run"'])
    info = daemon.run(_sweep.p_sweep_start(sess, 1, "run", 500, 0.1, 3, None, None))
    assert info.daemon_dir == "/data/run" and info.total == 3
    progress = daemon.run(_sweep.p_sweep_progress(info))
    assert (progress.done, progress.recorded, progress.total, progress.failed,
            progress.state) == (False, 1, 3, 0, "RUNNING")
    final = daemon.run(_sweep.p_sweep_wait(info, 10, 0))
    assert final.done and final.recorded == 3 and final.state == "DONE"
    # the probe came before the sweep started
    assert daemon.sent.index("SWEEP?") < daemon.sent.index("AXIS1:SWEEP run,500,0.1,3")


@pytest.mark.parametrize("end,match", [
    ('STOPPED,1,1,1,3,"/data/run"', "stopped \\(by a STOP or \\*RST\\): 1 of 3 trials written, 1 failed"),
    ('DONE,1,2,1,3,"/data/run"', "ended DONE: 2 of 3 trials written, 1 failed"),
    ('FAILED,1,0,3,3,"/data/run"', "ended FAILED: 0 of 3"),
    ('DONE,1,2,0,3,"/data/run"', "ended DONE: 2 of 3 trials written, 0 failed"),
])
def test_sweep_that_did_not_end_well_raises(end, match):
    daemon = sweep_daemon(['RUNNING,1,0,0,3,"/data/run"', end])
    info = daemon.run(_sweep.p_sweep_start(Session(), 1, "run", 500, 0.1, 3, None, None))
    with pytest.raises(idm.SweepError, match=match) as e:
        daemon.run(_sweep.p_sweep_wait(info, 10, 0))
    assert e.value.progress.state == end.split(",")[0]


def test_sweep_replaced_in_sweep_query_falls_back_to_the_status():
    """Another client's sweep started after this one ended: SWEEP? no longer tells about this
    one; the daemon_error (and, with data_dir, the dataset) decide."""
    daemon = sweep_daemon(['RUNNING,1,0,0,3,"/data/run"', 'RUNNING,1,0,0,5,"/data/other"'],
                          extra={"AXIS1:STATus?": ["state=IDLE daemon_error=none",
                                                   "state=IDLE daemon_error=sweep_failed"]})
    info = daemon.run(_sweep.p_sweep_start(Session(), 1, "run", 500, 0.1, 3, None, None))
    with pytest.raises(idm.SweepError, match="the daemon reporting: sweep failed"):
        daemon.run(_sweep.p_sweep_wait(info, 10, 0))


def test_sweep_on_a_daemon_without_sweep_query():
    sess = Session()
    daemon = Scripted({"AXIS:COUNt?": -113, "*CLS": None,
                       "STATus?": "state=IDLE daemon_error=none",
                       "SWEEP run,500,0.1,3": None, "MOVE:DONE?": "1"})
    info = daemon.run(_sweep.p_sweep_start(sess, 1, "run", 500, 0.1, 3, None, None))
    assert info.daemon_dir is None and info.total == 3
    assert daemon.sent == ["AXIS:COUNt?", "MOVE:RESult?", "STATus:OPERation?", "SWEEP?", "*CLS",
                           "STATus?", "SWEEP run,500,0.1,3"]
    progress = daemon.run(_sweep.p_sweep_wait(info, 10, 0))
    assert progress.recorded is None and progress.state is None
    info.stopped = True
    with pytest.raises(idm.SweepError, match="stopped"):
        daemon.run(_sweep.p_sweep_wait(info, 10, 0))
    assert "SWEEP?" not in daemon.sent[7:]  # not asked again on this connection


# ---- the address from the environment (idm.address; the C++ clients' rules) --------------------

def test_address_from_the_environment_in_order():
    env = idm.address_from_environment
    assert env({}) == ("127.0.0.1", 5025, None)
    assert env({"IDMD_SOCKET": "/run/idmd/idmd.sock"}).unix == "/run/idmd/idmd.sock"
    assert env({"IDMD_ADDRESS": "192.168.1.5:6000"}) == ("192.168.1.5", 6000, None)
    assert env({"IDMD_ADDRESS": "lab-pc"}) == ("lab-pc", 5025, None)
    assert env({"IDMD_ADDRESS": "[::1]:7000"}) == ("::1", 7000, None)
    assert env({"IDMD_SOCKET": "", "IDMD_ADDRESS": "h:1"}) == ("h", 1, None)  # empty is unset
    with pytest.raises(ValueError, match="^IDMD_SOCKET and IDMD_ADDRESS are both set: set one$"):
        env({"IDMD_SOCKET": "/s", "IDMD_ADDRESS": "h:1"})
    for bad, why in [("127.0.0.1:http", "the port is not a number in 1..65535"),
                     ("h:0", "the port is out of range, allowed 1..65535"),
                     ("h:70000", "the port is out of range"), ("h:", "an empty port"),
                     (":5025", "an empty host"), ("::1:5025", "an IPv6 address goes in brackets"),
                     ("[::1", "a '\\[' without its '\\]'"),
                     ("h/x:1", "the host holds a character a host name cannot")]:
        with pytest.raises(ValueError, match="^IDMD_ADDRESS: '%s': %s" % (re.escape(bad), why)):
            env({"IDMD_ADDRESS": bad})


def test_host_and_port_read_back_for_generated_addresses():
    rnd = random.Random(5)
    letters = "abcdefghijklmnopqrstuvwxyz0123456789-."
    for _ in range(500):
        port = rnd.randint(1, 65535)
        if rnd.random() < 0.3:
            host = ":".join("%x" % rnd.randint(0, 0xffff) for _ in range(rnd.randint(2, 8)))
            text = "[%s]:%d" % (host, port)
        else:
            host = "".join(rnd.choice(letters) for _ in range(rnd.randint(1, 30)))
            text = "%s:%d" % (host, port)
        assert idm.address.parse_host_port(text) == (host, port, None), text


# ---- lengths with units (idm.units; idmctl's rules) ---------------------------------------------

def test_every_number_with_every_unit_reads_back_as_its_metres():
    rnd = random.Random(11)
    for k in range(2000):
        number = rnd.uniform(-10, 10) * 10.0 ** rnd.randint(-12, 6)
        text = ("%.17g" if k % 2 else "%.6e") % number
        written = float(text)
        for name, per_metre in idm.units.UNITS.items():
            metres = idm.units.length(text + name)
            assert metres == written / per_metre, text + name
            assert float(idm.units.format_length(metres, name)) == pytest.approx(written,
                                                                                   rel=1e-11)
        assert idm.units.length(text) == written  # a bare number: metres
        assert idm.units.length(text, bare="um") == written / 1e6


def test_lengths_formatted_as_idmctl_prints_them():
    assert idm.units.format_length(1e-6, "nm") == "1000"
    assert idm.units.format_length(-2.5e-7, "um") == "-0.25"
    assert idm.units.format_length(9.93993679687e-07, "nm") == "993.993679687"
    assert idm.units.format_length(1e-6, "m") == "1e-6"
    assert idm.units.in_unit(0.0015, "mm") == pytest.approx(1.5)
    with pytest.raises(ValueError, match="'km' is not one of nm, um, mm, m"):
        idm.units.in_unit(1, "km")


def test_what_is_not_a_length_is_refused_naming_it_and_the_units():
    for bad in ["5km", "5MM", "5Mm", "5Um", "5nM", "1e", "um", "", "-", "5 um", "0x10m",
                "1..2mm", "infm", "nanum", "1e400m", "5m5", "5mm,", "5\u00b5m"]:
        with pytest.raises(ValueError) as e:
            idm.units.length(bad, "move X")
        assert str(e.value).startswith("move X: '%s'" % bad), str(e.value)
        assert "nm, um, mm, m" in str(e.value)
    with pytest.raises(ValueError, match="'5km': unknown unit 'km', accepted nm, um, mm, m"):
        idm.units.length("5km")
    with pytest.raises(ValueError, match="write um for micrometres"):
        idm.units.length("5\u00b5m")
    with pytest.raises(ValueError, match="'5' has no unit"):
        idm.units.length("5", bare=None)
    with pytest.raises(TypeError):
        idm.units.length(5e-6)


# ---- STEP: the sign of n alone picks the direction -----------------------------------------------

def test_step_sends_the_sign_of_cycles_as_given_and_says_what_it_means():
    rnd = random.Random(3)
    for _ in range(200):
        n = rnd.choice([-1, 1]) * rnd.randint(1, 10 ** 6)
        cycles = float(n) if rnd.random() < 0.3 else n
        daemon = Scripted({"AXIS:COUNt?": "1", "AXIS1:MOVE:RESult?": "NONE,0",
                           "AXIS1:STATus:OPERation?": "256", "SWEEP?": 'NONE,1,0,0,0,""'})
        daemon.replies["AXIS1:STEP %d,0.3,250" % n] = None
        assert daemon.run(_core.p_step(Session(), 1, cycles, 0.3, 250, None, False, 10, 0)) is None
        assert daemon.sent[-1] == "AXIS1:STEP %d,0.3,250" % n
    doc = " ".join(idm.Axis.step.__doc__.split())
    assert "The sign of cycles alone picks the direction (positive: the positive direction)" in doc
    assert "``duty`` is given as for the positive direction" in doc
