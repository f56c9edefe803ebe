"""The controller's tick loop (ros2_control's controller manager): read the hardware, update the
core, write the hardware, on one clock.

Lock-step: tick ``k`` reads (:meth:`CanHardware.read`: SYNC(k), then every operational node's
frames of the tick, its JOINT_STATUS and the sensors it sends per SYNC, for at most
``tick_timeout_s``; a node whose JOINT_STATUS does not come is counted, and the lost-node
supervision makes it a fault after ``lost_ticks``), runs the core and writes its commands and, on
the DBC's schedule, the controller's heartbeat and telemetry. Before the nodes are operational a
tick waits ``boot_wait_s`` for frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from controller.core import ControllerCore, TickResult
from controller.hardware import CanHardware, Hardware
from controller.telemetry import TelemetryLog
from controller.timing import TickStats
from protocol.clock import MAX_STALLS, STALL_NS, TICK_NS, TickTimer
from protocol.enums import SWINGS, JointMode


@dataclass
class LoopReport:
    ticks: int = 0
    events: list[str] = field(default_factory=list)
    # ticks woken STALL_NS or more late, or whose work took that much longer than its CPU time
    # (protocol.clock), and real-time ticks that overran while mostly off the CPU: (tick, ms not run)
    stalls: list[tuple[int, float]] = field(default_factory=list)


class LockstepLoop:
    """Lock-step: each tick waits for the nodes' frames of its SYNC (see the module doc)."""

    def __init__(
        self, core: ControllerCore, hardware: Hardware, *, tick_timeout_s: float = 2.0, boot_wait_s: float = 0.05,
        telemetry: TelemetryLog | None = None, first_tick: int = 0,
    ) -> None:
        """``first_tick``: the number of the first tick (a recording's, where it does not start at 0)."""
        self.core, self.hardware = core, hardware
        self.tick_timeout_s, self.boot_wait_s = tick_timeout_s, boot_wait_s
        self.tick_ns = TICK_NS
        self.telemetry = telemetry
        self.clock = hardware.clock
        self.stats = TickStats(self.tick_ns)
        self.report = LoopReport()
        self.tick = first_tick - 1
        self._ran_ns = 0  # the thread's CPU time in the last tick

    def _tick(self, k: int, start_ns: int, read_until_ns: int, lateness_ns: int, first_read_ns: int = 0) -> TickResult:
        """Read (from ``first_read_ns`` on, until the operational nodes reported or ``read_until_ns``),
        update, write: one tick ``k`` that started at ``start_ns``."""
        self.tick = k
        cpu0 = self.clock.cpu_ns()
        hardware = self.hardware
        result = self.core.update(hardware.read(k, read_until_ns, first_read_ns))
        hardware.write(k, result.commands)
        self.report.events += [f"tick {k}: {e}" for e in result.events]
        self.report.ticks += 1
        elapsed = self.clock.now_ns() - start_ns
        work = elapsed - hardware.idle_ns
        self.stats.record(lateness_ns, work, elapsed)
        self._ran_ns = self.clock.cpu_ns() - cpu0
        self._stall(k, work - self._ran_ns)  # not run while working (a lower bound: reads count as waiting)
        if self.telemetry is not None:
            self.telemetry.put(self._record(result, work, lateness_ns))
        return result

    def _stall(self, tick: int, ns: int, least_ns: int = STALL_NS) -> None:
        if ns >= least_ns and len(self.report.stalls) < MAX_STALLS:
            self.report.stalls.append((tick, round(ns / 1e6, 1)))

    def _record(self, result: TickResult, work_ns: int, lateness_ns: int) -> dict:
        m, est = result.measurements, result.estimate
        step = self.core.steps[-1] if self.core.steps and result.state in SWINGS else None
        return {
            "tick": result.tick,
            "state": result.state.name,
            "q_rad": None if m is None else m.joint_position_rad,
            "setpoint_rad": [c.position_rad if c.mode == JointMode.TRACK else None for c in result.commands.joints],
            "mode": [c.mode.name for c in result.commands.joints],
            "stick_force_n": None if m is None else m.stick_force_n,
            "plantar_n": None if m is None else m.heel_force_n + m.toe_force_n,
            "trunk_rpy_rad": None if m is None else m.trunk_rpy_rad,
            "com_m": None if est is None else est.com,
            "x_ratio": None if est is None else est.x_ratio,
            "gait": (self.core.gait_part or None) if self.core.fsm.moving else None,  # "" before the first gait tick
            "step": None if step is None else step.index,
            "step_length_m": None if step is None else step.length_m,
            "step_cost_n": None if result.landed is None else result.landed.mean_stick_force_n,  # paper eq. (10), at landing
            "theta": None if step is None else step.theta,
            "work_us": round(work_ns / 1e3, 1),
            "lateness_us": round(lateness_ns / 1e3, 1),
            "events": result.events,
        }

    def resume_at(self, tick: int) -> None:
        """The next step is tick ``tick`` (a recording's numbering, where ticks were skipped)."""
        self.tick = tick - 1

    def step(self) -> TickResult:
        start = self.clock.now_ns()
        wait = self.tick_timeout_s if self.hardware.operational_nodes() else self.boot_wait_s
        return self._tick(self.tick + 1, start, start + int(wait * 1e9), 0)


READ_WINDOW_S = 0.012  # real time: the nodes' frames count for the tick if read this soon after its start


class RealtimeLoop(LockstepLoop):
    """Real time: tick ``k`` starts at its absolute monotonic deadline (``TickTimer``: an overrun is
    counted and the loop re-aligns to the next boundary, never a catch-up burst); the nodes' frames
    are read for at most ``read_window_s`` into the tick (12 ms: the nodes answer in 1-2 ms, in the
    vcan sandbox in 1-5 ms and now and then 8-15 ms; the core's work, 0.2-0.4 ms here and 1-2 ms
    in the sandbox, fits in what is left), then the core runs and the commands go out for the
    nodes to apply at the next SYNC.

    Reading starts once the nodes' answers can all be on the wire (CANopen's synchronous window):
    SYNC and every node's per-SYNC frames back to back at ``bitrate_bit_s`` with worst-case
    stuffing (1.5 ms at 1 Mbit/s). Woken for each frame as it came, the controller (the higher
    priority) took the CPU from the nodes between their frames where both share one (the vcan
    sandbox: the last frames came after the read window, and three such ticks were a lost node)."""

    def __init__(self, core: ControllerCore, hardware: CanHardware, *, read_window_s: float = READ_WINDOW_S,
                 bitrate_bit_s: int = 1_000_000, **kwargs) -> None:
        super().__init__(core, hardware, **kwargs)
        self.read_window_ns = int(read_window_s * 1e9)
        self.sync_window_ns = hardware.sync_window_ns(bitrate_bit_s)
        self.timer = TickTimer(self.clock, self.tick_ns)

    def step(self) -> TickResult:
        skipped_before = self.timer.skipped
        ended_ns = self.clock.now_ns()  # of the last tick and what its caller did after it
        k = self.timer.wait()
        start = self.clock.now_ns()
        self.stats.skipped = self.timer.skipped
        if self.timer.skipped > skipped_before:
            self.core.overran(k, self.timer.skipped - skipped_before)
            # The last tick, on the CPU for under half a period (its thread's CPU time; what the
            # caller does between ticks is microseconds), overran because the machine did not run
            # it: a stall, shorter than STALL_NS but an overrun all the same (this VM's hypervisor
            # takes the CPU for 20-40 ms, and three such in 50 ticks are the overrun budget's HOLD).
            # An overrun of the controller's own work is none.
            if self._ran_ns < self.tick_ns // 2:
                self._stall(self.tick, ended_ns - self.timer.deadline_ns(self.tick) - self._ran_ns, least_ns=0)
        lateness = self.timer.last_lateness_ns
        self._stall(k, lateness)
        # With no node operational (booting, or all lost) no answer is due: read what came, do not wait.
        read_until = start + (self.read_window_ns if self.hardware.operational_nodes() else self.sync_window_ns)
        return self._tick(k, start, read_until, lateness, start + self.sync_window_ns)
