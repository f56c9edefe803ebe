"""Why the controller stops walking: every cause of a HOLD or a FAULT as a typed record.

A :class:`Fault` is its :class:`FaultKind`, what it is about (a node, a sensor message, a stick)
and the figure that tripped it. The kind carries what the rest of the system asks of a cause: its
row of docs/FAULTS.md, the reaction the controller takes (a protective stop, HOLD, reset when the
nodes are healthy; or a latched FAULT, reset with its preconditions) and whether a stall of the
machine running the controller (a late tick, a descheduled process) can explain it without
anything being wrong with the exoskeleton. Text is made only where a fault is printed
(``str(fault)``: ``KIND(subject: detail)``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Reaction(enum.Enum):
    """What the state machine does on a cause (docs/FAULTS.md, I4)."""

    HOLD = "HOLD"  # protective stop: every joint holds; the operator's reset when the nodes are healthy
    FAULT = "FAULT"  # latched: the reset needs healthy nodes for a while and both sticks loaded


class FaultKind(enum.Enum):
    """Every kind of cause, with its docs/FAULTS.md row, reaction and whether a stall explains it."""

    NODE_LOST = ("F1", Reaction.FAULT, True)  # no status from an operational node for lost_ticks
    SENSOR_LOST = ("F1", Reaction.FAULT, True)  # a sensor message missing as long as a lost node's status
    NODES_UNHEALTHY = ("F2", Reaction.HOLD, True)  # data older than 2 ticks or a node not operational, no fault yet
    FRAME_INTEGRITY = ("F7", Reaction.FAULT, False)  # end-to-end errors (CRC, counter) in the integrity window
    BUS_SEND_FAILED = ("F12", Reaction.FAULT, False)  # the controller's sends failed in consecutive ticks
    ENCODER_STUCK = ("F14", Reaction.FAULT, True)  # a reading frozen while its setpoint moves away
    JOINT_LIMIT = ("F16", Reaction.FAULT, False)  # a measured joint beyond its range
    ENVELOPE = ("F17", Reaction.FAULT, False)  # a command beyond the safety envelope's allowance
    FALL = ("F18", Reaction.FAULT, False)  # the trunk tilted beyond the fall limit
    STICK_UNLOADED = ("F19", Reaction.HOLD, False)  # a stick unloaded in a swing: HOLD after the landing
    NODE_REBOOTED = ("F23", Reaction.FAULT, False)  # an operational node sent a boot-up
    NODE_NOT_OPERATIONAL = ("F23", Reaction.FAULT, False)  # an operational node left OPERATIONAL
    DRIVE_FAULT = ("F24", Reaction.FAULT, False)  # a node's drive reports FAULT
    EMCY = ("F24", Reaction.FAULT, False)  # a node's emergency with an error register set
    OVERRUN = ("F25", Reaction.HOLD, True)  # ticks overran too often, or one by too much
    SUPPLY_CRITICAL = ("F29", Reaction.HOLD, False)  # the supply below critical: no new step

    def __new__(cls, row: str, reaction: Reaction, stall_can_explain: bool) -> FaultKind:
        # numbered in order: kinds that share a row, reaction and stall flag stay distinct (not aliases)
        kind = object.__new__(cls)
        kind._value_ = len(cls.__members__) + 1
        kind.row, kind.reaction, kind.stall_can_explain = row, reaction, stall_can_explain
        return kind

    @classmethod
    def of(cls, printed: str) -> FaultKind | None:
        """The kind of a printed fault (a log's or another process's ``KIND(...)``); None for a
        cause that is not a fault (``operator reset``, ``swing done``)."""
        name = printed.partition("(")[0]
        return cls.__members__.get(name)


@dataclass(frozen=True)
class Fault:
    """One cause: its kind, what it is about (a node, a message, a stick; may be empty) and the
    figure that tripped it (may be empty)."""

    kind: FaultKind
    subject: str = ""
    detail: str = ""

    def __str__(self) -> str:
        inner = ": ".join(part for part in (self.subject, self.detail) if part)
        return f"{self.kind.name}({inner})" if inner else self.kind.name
