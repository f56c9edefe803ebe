"""Enumerated signal values, named for code that acts on them.

The DBC's VAL_ tables are the source; :func:`check_enums` (run when the catalogue is loaded)
fails at start-up if these classes and the DBC ever disagree.
"""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING

from protocol.errors import ProtocolError

if TYPE_CHECKING:
    from protocol.catalog import Catalog


class NmtCommand(enum.IntEnum):
    """NMT_COMMAND.command: CANopen command specifiers plus the operator's fault reset."""

    START = 1
    STOP = 2
    ENTER_PRE_OPERATIONAL = 128
    RESET_NODE = 129
    RESET_COMMUNICATION = 130
    FAULT_RESET = 240


class NmtState(enum.IntEnum):
    """HEARTBEAT_*.nmt_state (CANopen heartbeat states)."""

    BOOT_UP = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


class JointMode(enum.IntEnum):
    """JOINT_COMMAND_*.mode."""

    HOLD = 0
    TRACK = 1
    QUICK_STOP = 2
    DISABLE = 3


class DriveState(enum.IntEnum):
    """JOINT_STATUS_*.drive_state."""

    NOT_READY = 0
    DISABLED = 1
    HOLD = 2
    TRACK = 3
    QUICK_STOP = 4
    FAULT = 5


class NodeError(enum.IntEnum):
    """JOINT_STATUS_*.error_code: the node's current fault cause."""

    NONE = 0
    OVER_CURRENT = 1
    OVER_TEMPERATURE = 2
    UNDER_VOLTAGE = 3
    OVER_VOLTAGE = 4
    ENCODER_FAULT = 5
    FOLLOWING_ERROR = 6
    POSITION_LIMIT = 7
    VELOCITY_LIMIT = 8
    COMMAND_TIMEOUT = 9
    HEARTBEAT_LOST = 10
    INVALID_COMMAND = 11
    SENSOR_FAULT = 12
    INTERNAL_ERROR = 13


class EmcyCode(enum.IntEnum):
    """EMCY_*.emcy_code (CiA 301 classes; 0xFFxx manufacturer specific)."""

    NO_ERROR = 0x0000
    OVER_CURRENT = 0x2310
    OVER_VOLTAGE = 0x3210
    UNDER_VOLTAGE = 0x3220
    OVER_TEMPERATURE = 0x4310
    HARDWARE = 0x5000
    SOFTWARE_INTERNAL = 0x6100
    ENCODER = 0x7305
    HEARTBEAT_LOST = 0x8130
    BUS_OFF_RECOVERED = 0x8140
    FRAME_INVALID = 0x8210
    COMMAND_TIMEOUT = 0x8250
    FOLLOWING_ERROR = 0x8611
    POSITION_LIMIT = 0xFF01
    VELOCITY_LIMIT = 0xFF02
    SENSOR_OUT_OF_RANGE = 0xFF03
    INVALID_COMMAND = 0xFF04


class GaitState(enum.IntEnum):
    """CONTROLLER_HEARTBEAT.gait_state: the controller's gait-phase state machine."""

    INIT = 0
    STAND = 1
    DOUBLE_SUPPORT = 2
    SWING_LEFT = 3
    SWING_RIGHT = 4
    STOP = 5
    HOLD = 6
    FAULT = 7


#: the states with a leg in the air
SWINGS = (GaitState.SWING_LEFT, GaitState.SWING_RIGHT)
#: the states in which the gait moves the legs (double support and the swings; not a stop, HOLD or FAULT)
WALKING = (GaitState.DOUBLE_SUPPORT, *SWINGS)


class PolicyMode(enum.IntEnum):
    """CONTROLLER_STEP.policy: where the controller's step lengths come from."""

    FIXED = 0
    COMPENSATED = 1
    LEARNING = 2


#: signal name -> the enumeration that names its values (same for every message carrying it)
BY_SIGNAL: dict[str, type[enum.IntEnum]] = {
    "command": NmtCommand,
    "nmt_state": NmtState,
    "mode": JointMode,
    "drive_state": DriveState,
    "error_code": NodeError,
    "emcy_code": EmcyCode,
    "gait_state": GaitState,
    "policy": PolicyMode,
}


def check_enums(catalog: Catalog) -> None:
    """Raise :class:`ProtocolError` unless every enumerated signal matches its class exactly."""
    seen = set()
    for msg in catalog.messages:
        for sig in msg.signals:
            if sig.choices is None:
                continue
            cls = BY_SIGNAL.get(sig.name)
            if cls is None:
                raise ProtocolError(f"{msg.name}.{sig.name}: enumerated in the DBC but has no enum class")
            expected = {m.value: m.name for m in cls}
            if sig.choices != expected:
                raise ProtocolError(f"{msg.name}.{sig.name}: DBC values {sig.choices} differ from {cls.__name__}")
            seen.add(sig.name)
    missing = set(BY_SIGNAL) - seen
    if missing:
        raise ProtocolError(f"enum classes without a DBC signal: {sorted(missing)}")
