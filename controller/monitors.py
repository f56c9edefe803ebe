"""The controller's own safety monitors over typed data (docs/FAULTS.md): what the core judges
from the measurements and its commands, where :mod:`controller.cansystem` judges the nodes and the
bus. Each check returns or collects :class:`~controller.faults.Fault` records; none acts: the core
hands them to the state machine by their kind's reaction.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from config.controller_schema import SafetyConfig
from controller.estimator import Measurements
from controller.faults import Fault, FaultKind
from protocol.enums import SWINGS, GaitState


class Monitors:
    """Fall (F18), a stuck encoder (F14), an unloaded stick (F19), the supply (F29) and the loop's
    overruns (F25), each with the state it counts in."""

    def __init__(self, safety: SafetyConfig, joints: tuple[str, ...]) -> None:
        self.safety = safety
        self.joints = joints  # the controller's joint names, in command order
        self._tilted_ticks = 0
        self._follow = _Following()
        self._unloaded = [0, 0]  # per stick: ticks in a row of this swing below stick_unloaded_n
        self._slipped: Fault | None = None  # F19: a stick unloaded in this swing, a HOLD once it has landed
        self._supply_low = [0, 0]  # F29: ticks in a row with the lowest supply below warn, below critical
        self._overruns: deque[int] = deque()  # ticks that followed an overrun
        self.overrun_stop: Fault | None = None  # a protective stop asked by the loop's timing

    def overran(self, state: GaitState, tick: int, skipped: int) -> None:
        """The loop overran into ``tick``, skipping ``skipped`` ticks (F25). In INIT, before the
        nodes are operational, the controller commands nothing, and a process's first ticks are
        its slowest: there an overrun is only counted (the loop's statistics), not budgeted. In the
        vcan sandbox the controller started beside a starting nodes process overran 3 times in its
        first 12-15 ticks and was in HOLD before any node was up."""
        if state == GaitState.INIT:
            return
        s = self.safety
        self._overruns.append(tick)
        while self._overruns[0] <= tick - s.overrun_window_ticks:
            self._overruns.popleft()
        if skipped > s.overrun_max_ticks:
            self.overrun_stop = Fault(FaultKind.OVERRUN, detail=f"{skipped} ticks skipped")
        elif len(self._overruns) >= s.overrun_limit:
            self.overrun_stop = Fault(FaultKind.OVERRUN, detail=f"{len(self._overruns)} in {s.overrun_window_ticks} ticks")


    def fall(self, m: Measurements | None, faults: list[Fault]) -> None:
        """F18: the trunk tilted beyond ``fall_tilt_rad`` for ``fall_ticks`` ticks in a row."""
        tilt = max(abs(float(m.trunk_rpy_rad[0])), abs(float(m.trunk_rpy_rad[1]))) if m is not None else 0.0
        self._tilted_ticks = self._tilted_ticks + 1 if tilt > self.safety.fall_tilt_rad else 0
        if self._tilted_ticks >= self.safety.fall_ticks:
            faults.append(Fault(FaultKind.FALL, detail=f"trunk tilt {tilt:.2f} rad"))

    def following(self, targets: np.ndarray | None, m: Measurements | None, fresh: bool, faults: list[Fault]) -> None:
        """F14: while the joints track, an encoder stuck while its joint moves: its reading stays
        exactly the same while the setpoint moves away from it. A tick counts when the reading
        is the one of the tick before and the setpoint stands ``stuck_motion_rad`` further from it
        than when the reading last changed; ``stuck_ticks`` such ticks are ENCODER_STUCK.

        Not a setpoint that merely moves while the reading stands: a loaded knee at a swing's
        start keeps its reading while the setpoint first closes the gap it held the knee at (in
        the real-time walks of 2026-12-05 up to 4 such ticks while the setpoint moved 0.03-0.04
        rad; an extra tick of the nodes' latency made ENCODER_STUCK of a sound knee, once in CI).
        Measured away from the frozen reading, the same walks count at most 2. A following-error
        rule (the measured angle far from the setpoint) is not used either: a step too long for
        the patient drives the joints off their setpoints as the body falls, and would name the
        fall a fault of the legs. O(1) a joint and tick."""
        f = self._follow
        if targets is None or m is None or not fresh:
            f.reset()
            return
        s = self.safety
        q, c = m.joint_position_rad.tolist(), targets.tolist()
        for j in range(4):
            gap = abs(c[j] - q[j])
            if q[j] != f.reading[j]:
                f.reading[j], f.away[j], f.gap[j] = q[j], 0, gap
            elif gap - f.gap[j] >= s.stuck_motion_rad:
                f.away[j] += 1
                if f.away[j] >= s.stuck_ticks:
                    faults.append(Fault(FaultKind.ENCODER_STUCK, self.joints[j]))


    def sticks(self, before: GaitState, m: Measurements | None, fresh: bool) -> Fault | None:
        """F19: a stick that carries less than ``stick_unloaded_n`` for ``stick_unloaded_ticks``
        ticks in a row of a swing has slipped or been lifted while the patient needs it. The swing
        goes on to its landing (stopping the legs mid-swing would drop the patient on one leg);
        the tick after the landing is a HOLD, whose cause this returns. The next step is inhibited
        anyway: no step starts without both sticks loaded (I2)."""
        if before in SWINGS:
            if m is not None and fresh:
                s = self.safety
                for i, force in enumerate(m.stick_force_n.tolist()):
                    self._unloaded[i] = self._unloaded[i] + 1 if force < s.stick_unloaded_n else 0
                    if self._unloaded[i] == s.stick_unloaded_ticks and self._slipped is None:
                        self._slipped = Fault(FaultKind.STICK_UNLOADED, f"{('left', 'right')[i]} stick",
                                              f"below {s.stick_unloaded_n:g} N for {s.stick_unloaded_ticks} ticks in the swing")
            return None
        self._unloaded = [0, 0]
        slipped, self._slipped = self._slipped, None
        return slipped if before in (GaitState.DOUBLE_SUPPORT, GaitState.STOP) else None  # landed (a HOLD or FAULT has stopped it anyway)


    def supply(self, state: GaitState, low: float, events: list[str]) -> Fault | None:
        """F29: the lowest supply voltage ``low`` of the nodes' heartbeats below ``supply_warn_v`` for
        ``supply_warn_ticks`` ticks is a warning (an event; nothing else changes); below
        ``supply_critical_v`` for ``supply_critical_ticks`` no step starts any more: in double
        support (a swing lands first, its next tick is in double support) the cause of a HOLD this
        returns, as often as the operator resets and starts again."""
        s = self.safety
        warn, critical = self._supply_low
        self._supply_low = [warn + 1 if low < s.supply_warn_v else 0, critical + 1 if low < s.supply_critical_v else 0]
        if self._supply_low[0] == s.supply_warn_ticks:
            events.append(f"SUPPLY_LOW({low:.2f} V below {s.supply_warn_v:g} V for {s.supply_warn_ticks} ticks): warning")
        if self._supply_low[1] >= s.supply_critical_ticks and state == GaitState.DOUBLE_SUPPORT:
            return Fault(FaultKind.SUPPLY_CRITICAL, detail=f"{low:.2f} V below {s.supply_critical_v:g} V for {self._supply_low[1]} ticks")
        return None


@dataclass
class _Following:
    """Per joint: the reading, the setpoint's distance from it when it last changed, and the ticks
    since that the setpoint stood ``stuck_motion_rad`` further away (Monitors.following)."""

    away: list[int] = field(default_factory=lambda: [0] * 4)
    reading: list[float] = field(default_factory=lambda: [math.nan] * 4)
    gap: list[float] = field(default_factory=lambda: [0.0] * 4)

    def reset(self) -> None:
        self.away[:], self.reading[:] = [0] * 4, [math.nan] * 4


