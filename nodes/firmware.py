"""The firmware of one node board, without I/O: CANopen NMT, the drive state, the command watchdog,
the controller-heartbeat consumer, and EMCY (docs/FAULTS.md, rows F1, F9, F20-F24).

The host feeds it decoded frames and its ticks and applies the :class:`JointCommand` it returns to
the joint; it reads the EMCY queue and the NMT state to build the node's frames. Nothing here
knows about CAN frames, PyBullet or wall-clock time, so every rule is tested tick by tick.

Rules (CiA 301 / CiA 402 practice):

* boot: BOOT_UP once, then PRE_OPERATIONAL with the drive holding its measured position (a user
  may be standing in the exoskeleton: never free-wheel on its own);
* START makes it OPERATIONAL; only then are joint commands applied and status frames sent;
* each SYNC the newest valid command received since the previous SYNC is applied (synchronous
  PDO); a command outside the joint's limits is clamped to them and reported (a warning EMCY once
  per run of clamped commands, and counted);
* command watchdog: an operational node that receives no valid command for
  ``command_timeout_ticks`` consecutive ticks, or no controller heartbeat for
  ``heartbeat_timeout_ms``, quick-stops and stays (holds the measured position with bounded
  torque), reports FAULT and sends one EMCY;
* a fault is latched until the controller's FAULT_RESET; after a reset the drive holds until the
  next command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from protocol.commands import JointCommand
from protocol.enums import DriveState, EmcyCode, JointMode, NmtCommand, NmtState, NodeError

# CiA 301 error register (object 0x1001) bits.
ERR_GENERIC = 0x01
ERR_CURRENT = 0x02
ERR_COMMUNICATION = 0x10
ERR_MANUFACTURER = 0x80


@dataclass(frozen=True)
class JointLimits:
    """What the node's drive allows: position range, speed and torque (its firmware's own limits)."""

    lower_rad: float
    upper_rad: float
    velocity_rad_s: float
    torque_nm: float


class Emcy(NamedTuple):
    code: EmcyCode
    error_register: int
    detail: int


_DRIVE_OF_MODE = {
    JointMode.HOLD: DriveState.HOLD,
    JointMode.TRACK: DriveState.TRACK,
    JointMode.QUICK_STOP: DriveState.QUICK_STOP,
    JointMode.DISABLE: DriveState.DISABLED,
}
_MODE = {int(m): m for m in JointMode}  # JointMode(value) without the enum's call (the decoder checked the value)


class NodeFirmware:
    """One node board's firmware state machine."""

    def __init__(self, name: str, limits: JointLimits, *, command_timeout_ticks: int, heartbeat_timeout_ms: int) -> None:
        self.name = name
        self.limits = limits
        self.command_timeout_ticks = command_timeout_ticks
        self.heartbeat_timeout_ms = heartbeat_timeout_ms
        self.emcy: list[Emcy] = []  # to send, drained by the host
        self.clamped = 0  # commands clamped to the limits
        self.ignored = 0  # commands received while not operational (or in a fault)
        self.boots = 0
        self.boot()

    # -- NMT -------------------------------------------------------------------------------------

    def boot(self) -> None:
        """Power-on or reset: BOOT_UP (the host sends the boot-up message), then pre-operational."""
        self.boots += 1
        self.state = NmtState.PRE_OPERATIONAL
        self.boot_up_pending = True  # the host sends BOOT_UP (with counters from 0) and clears this
        self.emcy.clear()  # a reset drops what was queued
        self.error = NodeError.NONE
        self.latched = False
        self.pending: JointCommand | None = None
        self.active: JointCommand | None = None
        self.missed_ticks = 0
        self.command_this_tick = False
        self.last_heartbeat_ms: float | None = None
        self._clamping = False

    def on_nmt(self, command: NmtCommand, now_ms: float) -> None:
        if command == NmtCommand.START:
            if self.state != NmtState.OPERATIONAL:
                self.state = NmtState.OPERATIONAL
                self.missed_ticks = 0
                self.last_heartbeat_ms = now_ms  # the consumer starts with the node
                self.active = self.pending = None
        elif command == NmtCommand.STOP:
            self.state = NmtState.STOPPED
        elif command == NmtCommand.ENTER_PRE_OPERATIONAL:
            self.state = NmtState.PRE_OPERATIONAL
        elif command in (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION):
            self.boot()
        elif command == NmtCommand.FAULT_RESET and self.latched:
            self.latched = False
            self.error = NodeError.NONE
            self.active = self.pending = None
            self.missed_ticks = 0
            self.last_heartbeat_ms = now_ms
            self.emcy.append(Emcy(EmcyCode.NO_ERROR, 0, 0))

    # -- inputs ----------------------------------------------------------------------------------

    def on_command(self, mode: int, position: float, velocity: float, torque: float, limit: float) -> None:
        """A valid (CRC, counter, range) joint command; the newest one is applied at the next SYNC."""
        if self.state != NmtState.OPERATIONAL:
            self.ignored += 1
            return
        lim = self.limits
        clamped = JointCommand(
            _MODE[mode],
            min(max(position, lim.lower_rad), lim.upper_rad),
            min(max(velocity, -lim.velocity_rad_s), lim.velocity_rad_s),
            min(max(torque, -lim.torque_nm), lim.torque_nm),
            min(max(limit, 0.0), lim.torque_nm),
        )
        changed = clamped[1:] != (position, velocity, torque, limit)
        if changed:
            self.clamped += 1
            if not self._clamping:  # one warning per run of clamped commands (no fault: error register 0)
                outside = not lim.lower_rad <= position <= lim.upper_rad
                self.emcy.append(Emcy(EmcyCode.POSITION_LIMIT if outside else EmcyCode.INVALID_COMMAND, 0, self.clamped & 0xFFFF))
        self._clamping = changed
        self.pending = clamped
        self.command_this_tick = True

    def on_controller_heartbeat(self, now_ms: float) -> None:
        self.last_heartbeat_ms = now_ms

    # -- time ------------------------------------------------------------------------------------

    def on_tick(self, now_ms: float) -> None:
        """The node's tick (a SYNC in lock-step, its own 20 ms timer in real time): watchdogs."""
        received, self.command_this_tick = self.command_this_tick, False
        if self.state != NmtState.OPERATIONAL or self.latched:
            return
        self.missed_ticks = 0 if received else self.missed_ticks + 1
        if self.missed_ticks >= self.command_timeout_ticks:
            self.raise_fault(NodeError.COMMAND_TIMEOUT, EmcyCode.COMMAND_TIMEOUT, ERR_GENERIC | ERR_COMMUNICATION, self.missed_ticks)
        elif self.last_heartbeat_ms is not None and now_ms - self.last_heartbeat_ms > self.heartbeat_timeout_ms:
            age = int(min(now_ms - self.last_heartbeat_ms, 0xFFFF))
            self.raise_fault(NodeError.HEARTBEAT_LOST, EmcyCode.HEARTBEAT_LOST, ERR_GENERIC | ERR_COMMUNICATION, age)

    def on_sync(self) -> JointCommand:
        """Apply the newest command received since the last SYNC; the drive command until the next."""
        if self.pending is not None and self.state == NmtState.OPERATIONAL and not self.latched:
            self.active, self.pending = self.pending, None
        return self.drive_command()

    def drive_command(self) -> JointCommand:
        if self.latched:
            return JointCommand(JointMode.QUICK_STOP, torque_limit_nm=self.limits.torque_nm)
        if self.state != NmtState.OPERATIONAL or self.active is None:
            return JointCommand(JointMode.HOLD, torque_limit_nm=self.limits.torque_nm)
        return self.active

    @property
    def drive_state(self) -> DriveState:
        if self.latched:
            return DriveState.FAULT
        return _DRIVE_OF_MODE[self.drive_command().mode]

    # -- faults ----------------------------------------------------------------------------------

    def raise_fault(self, error: NodeError, code: EmcyCode, register: int, detail: int = 0) -> None:
        """Latch a fault (quick stop and stay) and queue its EMCY; a second fault while latched is
        not re-announced (the first cause stays in the status)."""
        if self.latched:
            return
        self.latched = True
        self.error = error
        self.pending = None
        self.emcy.append(Emcy(code, register, int(detail) & 0xFFFF if math.isfinite(detail) else 0))
