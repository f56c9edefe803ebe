"""The controller command's once-a-second status line (tools/cli/controller.py)."""

from types import SimpleNamespace

from controller.cansystem import NodeState
from controller.fsm import GaitFsm
from protocol.enums import DriveState, GaitState, NmtState
from tools.cli.controller import _status_line

NODES = ("LEFT_HIP", "LEFT_KNEE", "RIGHT_HIP", "RIGHT_KNEE")


def _loop(fault: str | None, healthy_ticks: int) -> SimpleNamespace:
    fsm = GaitFsm(reset_healthy_ticks=25)
    fsm._healthy_ticks = healthy_ticks
    nodes = {n: NodeState(NmtState.OPERATIONAL, SimpleNamespace(drive_state=DriveState.FAULT if n == fault else DriveState.HOLD))
             for n in NODES}
    return SimpleNamespace(core=SimpleNamespace(fsm=fsm), hardware=SimpleNamespace(nodes=nodes, counters=SimpleNamespace(timeouts=0)))


def test_in_fault_the_status_line_says_what_a_reset_waits_for():
    line = _status_line(_loop("RIGHT_KNEE", 3), SimpleNamespace(tick=40, state=GaitState.FAULT, estimate=None))
    assert "FAULT" in line and "healthy 3/25 ticks, drive FAULT: RIGHT_KNEE" in line, line


def test_standing_the_status_line_has_no_reset_figures():
    line = _status_line(_loop(None, 30), SimpleNamespace(tick=40, state=GaitState.STAND, estimate=None))
    assert line.startswith("controller tick 40 STAND | LH:OPER LK:OPER RH:OPER RK:OPER") and "healthy" not in line, line
