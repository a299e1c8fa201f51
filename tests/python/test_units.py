"""The client's own logic without a daemon: reply parsing, number and list formatting, and the
plans (idm._core) run against scripted replies, to show how the client speaks to a daemon with
the protocol's extension (several axes, MOVE:RESult?, STATus:OPERation?). What the daemon of
this tree answers is tested against the real idmd in the other modules."""
import math

import pytest

import idm
from idm import _core
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
    """Runs a plan against scripted replies: {line: reply} or {line: error code}; records
    every line sent."""

    def __init__(self, replies):
        self.replies = replies
        self.sent = []

    def run(self, plan):
        op = next(plan)
        while True:
            try:
                if isinstance(op, Sleep):
                    result = None
                else:
                    assert isinstance(op, Line)
                    self.sent.append(op.text)
                    answer = self.replies.get(op.text, -113 if op.query else None)
                    if isinstance(answer, list):
                        answer = answer.pop(0) if len(answer) > 1 else answer[0]
                    if isinstance(answer, int):
                        raise error_from_code(answer, "scripted", op.text)
                    result = answer
            except idm.ScpiError as e:
                try:
                    op = plan.throw(e)
                except StopIteration as s:
                    return s.value
                continue
            try:
                op = plan.send(result)
            except StopIteration as s:
                return s.value


def test_single_axis_daemon_axis_one_is_unprefixed():
    sess = Session()
    daemon = Scripted({"POSition?": "1e-06", "*CLS": None})
    assert daemon.run(_core.p_axis_query(sess, 1, "POSition?", parse_number_)) == 1e-6
    assert daemon.sent == ["AXIS:COUNt?", "*CLS", "POSition?"]
    # the probe is not repeated; another axis keeps its prefix (the daemon refuses it)
    with pytest.raises(idm.CommandError):
        daemon.run(_core.p_axis_query(sess, 2, "POSition?", parse_number_))
    assert daemon.sent[3:] == ["AXIS2:POSition?"]


def parse_number_(reply, what):
    return parse_number(reply, what)


def test_several_axes_by_number_and_name():
    sess = Session()
    daemon = Scripted({"AXIS:COUNt?": "2", "AXIS1:NAME?": "x", "AXIS2:NAME?": "y",
                       "AXIS2:STOP": None, "AXIS2:POSition?": "2e-06"})
    assert daemon.run(_core.p_axis_command(sess, "y", "STOP")) is None
    assert daemon.run(_core.p_axis_query(sess, "Y", "POSition?", parse_number_)) == 2e-6
    # names are asked once; a name matched case-insensitively re-reads the count only
    assert daemon.sent == ["AXIS:COUNt?", "AXIS1:NAME?", "AXIS2:NAME?", "AXIS2:STOP",
                           "AXIS:COUNt?", "AXIS2:POSition?"]
    with pytest.raises(idm.AxisNotFound):
        daemon.run(_core.p_axis_number(sess, "z"))


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
