"""Typed records of the commands the bus carries, one definition for both ends: the controller
makes them, the node boards execute them."""

from __future__ import annotations

from typing import NamedTuple

from protocol.enums import JointMode


class JointCommand(NamedTuple):
    """One joint's command (the fields of JOINT_COMMAND): what the controller sends and what a
    node's drive does until the next SYNC. Immutable records of every tick are named tuples: half
    the cost of a frozen dataclass to make."""

    mode: JointMode
    position_rad: float = 0.0
    velocity_rad_s: float = 0.0
    torque_nm: float = 0.0
    torque_limit_nm: float = 0.0
