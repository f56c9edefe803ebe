"""The controller's fault kinds (controller/faults.py): distinct, each answering a row of
docs/FAULTS.md's scenario table, printed as KIND(subject: detail)."""

from __future__ import annotations

import re

from controller.faults import Fault, FaultKind, Reaction
from tests.conftest import ROOT


def test_every_kind_is_its_own_and_answers_a_row_of_the_scenario_table():
    rows = set(re.findall(r"^\| (F\d+) \|", (ROOT / "docs" / "FAULTS.md").read_text(), re.M))
    names = [k.name for k in FaultKind]
    assert len(set(FaultKind)) == len(names) == len(set(names))  # no kind an alias of another with the same row
    assert {k.row for k in FaultKind} <= rows
    assert all(isinstance(k.reaction, Reaction) and isinstance(k.stall_can_explain, bool) for k in FaultKind)


def test_a_fault_prints_its_kind_subject_and_detail():
    assert str(Fault(FaultKind.JOINT_LIMIT, "RIGHT_KNEE", "2.105 rad")) == "JOINT_LIMIT(RIGHT_KNEE: 2.105 rad)"
    assert str(Fault(FaultKind.OVERRUN, detail="4 ticks skipped")) == "OVERRUN(4 ticks skipped)"
    assert str(Fault(FaultKind.NODE_LOST, "LEFT_HIP")) == "NODE_LOST(LEFT_HIP)"
    assert str(Fault(FaultKind.NODES_UNHEALTHY)) == "NODES_UNHEALTHY"


def test_the_kind_of_a_printed_fault_is_read_back_and_other_causes_have_none():
    for fault in (Fault(FaultKind.SENSOR_LOST, "STICK_LEFT"), Fault(FaultKind.NODES_UNHEALTHY), Fault(FaultKind.EMCY, "LEFT_HIP", "0x2310")):
        assert FaultKind.of(str(fault)) is fault.kind
    assert FaultKind.of("operator reset") is None and FaultKind.of("NODE_LOSTX(1)") is None
