"""The session's operator (its reset procedure) and its one status line (controller/session.py)."""

from types import SimpleNamespace

from controller.session import Operator, Status
from protocol.enums import GaitState

NODES = ("LEFT_HIP", "LEFT_KNEE", "RIGHT_HIP", "RIGHT_KNEE")


def _status(state: GaitState, drive_faults=(), healthy_ticks=3, x_ratio=float("nan")) -> Status:
    return Status(tick=40, state=state, nodes=tuple((n, "OPERATIONAL") for n in NODES), drive_faults=tuple(drive_faults),
                  healthy_ticks=healthy_ticks, reset_healthy_ticks=25, timeouts=0, steps=0, step="", stick_force_n=None,
                  x_ratio=x_ratio, sticks_loaded=None, feet_loaded=None)


def test_in_fault_the_status_line_says_what_a_reset_waits_for():
    line = _status(GaitState.FAULT, drive_faults=("RIGHT_KNEE",)).line()
    assert "FAULT" in line and "healthy 3/25 ticks, drive FAULT: RIGHT_KNEE" in line, line


def test_standing_the_status_line_has_no_reset_figures():
    line = _status(GaitState.STAND, healthy_ticks=30).line()
    assert line.startswith("tick 40 STAND") and "| LH:OPER LK:OPER RH:OPER RK:OPER" in line and "healthy" not in line, line


def test_a_walking_status_line_shows_the_step_the_sticks_and_x():
    s = Status(tick=900, state=GaitState.SWING_LEFT, nodes=(), drive_faults=(), healthy_ticks=0, reset_healthy_ticks=25,
               timeouts=1, steps=3, step="3 (l) 0.120 m", stick_force_n=(151.0, 149.4), x_ratio=0.55, sticks_loaded=2, feet_loaded=1)
    line = s.line(18.0)
    assert line.startswith("tick 900   18.0 s SWING_LEFT")
    assert "step 3 (l) 0.120 m | sticks  151  149 N | X_CoM/X_SP 0.55 | loaded: sticks 2 feet 1 | timeouts 1" in line, line


class _Core:
    """What the operator presses on: the requests, counted, and the FSM's reset figures."""

    def __init__(self) -> None:
        self.fsm = SimpleNamespace(healthy_ticks=0, reset_healthy_ticks=25)
        self.resets = 0

    def request_reset(self) -> None:
        self.resets += 1


def _heard(operator: Operator, tick: int, state: GaitState, sticks_loaded=(True, True)) -> None:
    operator.heard(SimpleNamespace(tick=tick, state=state, estimate=SimpleNamespace(sticks_loaded=sticks_loaded)))


def test_the_reset_procedure_presses_again_once_the_nodes_are_healthy_with_both_sticks_loaded():
    """FAULT_RESET at once (the nodes unlatch), the FSM's reset once it can take it (I4), then done."""
    core = _Core()
    operator = Operator(core)
    _heard(operator, 9, GaitState.FAULT)
    operator.recover()
    assert core.resets == 1 and operator.presses == [(10, "reset")] and operator.recovering
    for k in range(10, 39):
        core.fsm.healthy_ticks = k - 10
        _heard(operator, k, GaitState.FAULT, sticks_loaded=(True, not 30 <= k < 38))  # a stick lifted in ticks 30-37
    assert core.resets == 2 and operator.presses[-1] == (39, "reset")  # healthy from 35, both sticks loaded at 38
    _heard(operator, 39, GaitState.STAND)
    assert not operator.recovering
    _heard(operator, 40, GaitState.STAND)
    assert core.resets == 2
