"""The controller's lock-step loop against the emulated nodes on the in-process virtual bus: the
nodes come up, the controller supervises them, estimates the state from their frames and holds
the legs; faults on the bus latch FAULT; a reset brings it back."""

from __future__ import annotations

import pytest

from config import default_config_path, load_config, with_overrides
from controller.core import ControllerCore
from controller.hardware import CanHardware
from controller.session import Session
from controller.loop import LockstepLoop
from nodes.host import NodesHost
from protocol.bus import virtual_bus
from protocol.enums import GaitState
from tests.support.processes import stall_can_explain

BASE = load_config(default_config_path())


@pytest.fixture
def rig(request):
    def make(faults=None):
        channel = f"loop-{request.node.name}"
        cfg = with_overrides(BASE, {"bus.channel": channel, **({"nodes.faults": faults} if faults else {})})
        node_bus = virtual_bus(channel)
        ctl_bus = virtual_bus(channel)
        host = NodesHost(cfg, node_bus, lockstep=True, seed=4)
        host.boot()
        loop = LockstepLoop(ControllerCore(cfg.controller), CanHardware(cfg.controller, ctl_bus, pump=lambda: host.poll(0.0)))

        def close():
            host.close()
            node_bus.shutdown()
            ctl_bus.shutdown()

        request.addfinalizer(close)
        return loop, host

    return make


def test_nodes_come_up_and_the_controller_stands_holding_with_estimates(rig):
    loop, host = rig()
    results = [loop.step() for _ in range(60)]
    states = [r.state for r in results]
    assert states[0] == GaitState.INIT and states[-1] == GaitState.STAND
    first_stand = states.index(GaitState.STAND)
    assert first_stand <= 8  # boot-up, NMT start, a first status, the operational heartbeats
    assert all(s == GaitState.STAND for s in states[first_stand:])
    hardware = loop.hardware
    assert hardware.counters.timeouts == 0 and hardware.rx.stats.rejected_total == 0 and hardware.rx.stats.lost == 0
    status = host.status()
    assert {n["nmt"] for n in status["nodes"].values()} == {"OPERATIONAL"}
    assert {n["drive"] for n in status["nodes"].values()} == {"HOLD"} and status["fall"] is None
    est = results[-1].estimate
    assert est is not None and all(est.feet_loaded) and all(est.sticks_loaded)
    assert 0.0 < est.x_ratio < 1.0  # standing with the CoM inside the support
    assert any("INIT -> STAND" in e for e in loop.report.events)


def test_a_drive_fault_latches_fault_within_a_tick_and_a_reset_recovers(rig):
    loop, host = rig({"f": {"kind": "drive_fault", "node": "RIGHT_HIP", "start_tick": 30}})
    states = [loop.step().state for _ in range(32)]
    assert states[29] == GaitState.STAND and states[30] == GaitState.FAULT  # the EMCY of tick 30
    assert any(e.endswith(": EMCY(RIGHT_HIP: 0x2310)") for e in loop.report.events), loop.report.events
    assert [loop.step().state for _ in range(10)] == [GaitState.FAULT] * 10
    # The operator's reset: the nodes get FAULT_RESET, but the FSM leaves FAULT only after 25
    # healthy ticks (docs/FAULTS.md I4), so the first press clears the nodes and a second one, later,
    # the controller.
    loop.core.request_reset()
    states = [loop.step().state for _ in range(30)]
    assert set(states) == {GaitState.FAULT}
    assert host.status()["nodes"]["RIGHT_HIP"]["error"] == "NONE"
    loop.core.request_reset()
    assert loop.step().state == GaitState.STAND


def test_a_frozen_node_is_lost_within_three_ticks(rig):
    loop, _ = rig({"f": {"kind": "freeze", "node": "LEFT_KNEE", "start_tick": 30}})
    states = [loop.step().state for _ in range(36)]
    assert states[29] == GaitState.STAND
    fault_tick = states.index(GaitState.FAULT)
    assert 30 <= fault_tick <= 33
    assert any("NODE_LOST(LEFT_KNEE)" in e for e in loop.report.events)
    # the lost node is no longer waited for: lock-step ticks do not wait out their timeout for it
    waited = loop.hardware.counters.timeouts
    assert waited == BASE.controller.safety.lost_ticks and "LEFT_KNEE" not in loop.hardware.operational_nodes()
    states = [loop.step().state for _ in range(20)]
    assert set(states) == {GaitState.FAULT} and loop.hardware.counters.timeouts == waited


def _stopped_by_a_stall(loop, nodes: dict) -> str | None:
    """The walk's first FAULT or HOLD, when it is one a stall of the machine gives a healthy walk
    (a lost node or sensor, overruns: the kind's own data) and either side measured a stall: this
    VM's hypervisor takes a CPU away in bursts (docs/TESTING.md). Such a stop is the documented
    reaction to a machine that did not run the controller, so it passes; any other stop fails."""
    stops = [e for e in loop.report.events if "-> FAULT:" in e or "-> HOLD:" in e]
    if stops and stall_can_explain(stops[0].split(": ", 1)[1]) and (loop.report.stalls or [s for s in nodes["stalls"] if s[0] >= 0]):
        return f"{stops[0]}, stalls {loop.report.stalls} {nodes['stalls']}"
    return None


def _real_time_walk(cycles: int, channel: str):
    """The controller's real-time loop and the nodes in a thread on their own 20 ms timer, walking
    ``cycles`` gait cycles (or until a FAULT, a HOLD or a fall); returns (loop, core, states, fall, nodes' status)."""
    from controller.loop import RealtimeLoop
    from nodes.host import running_in_thread
    from protocol.clock import TICK_MS
    from tools.pipeline import default_max_time_s

    cfg = with_overrides(BASE, {"bus.channel": channel, "sim.mode": "sagittal"})
    node_bus = virtual_bus(channel)
    ctl_bus = virtual_bus(channel)
    host = NodesHost(cfg, node_bus, lockstep=False, seed=4)
    states, fall = [], None
    try:
        with running_in_thread(host):
            core = ControllerCore(cfg.controller)
            session = Session(RealtimeLoop(core, CanHardware(cfg.controller, ctl_bus, max_delta_counter=cfg.protocol.max_delta_counter)))
            loop = session.loop
            session.operator.start()  # kept until the nodes are up and it stands
            for _ in range(int(default_max_time_s(cycles) * 1000 / TICK_MS)):
                states.append(session.step().state)
                fall = host.plant.patient.fall
                if fall or states[-1] in (GaitState.FAULT, GaitState.HOLD) or sum(s.landed for s in core.steps) >= 2 * cycles:
                    break
            nodes = host.status()
    finally:
        host.close()
        node_bus.shutdown()
        ctl_bus.shutdown()
    return loop, core, states, fall, nodes


@pytest.mark.realtime
def test_real_time_controller_walks_two_gait_cycles_with_real_time_nodes():
    """The real-time smoke walk of the in-process transport, once: the controller on absolute 20 ms
    deadlines, the nodes in a thread on their own 20 ms physics timer, every value a frame on the
    in-process virtual bus. It walks two gait cycles with no FAULT and no fall, or stops with the
    documented reaction to a stall of the machine that either side measured (the timing rules
    themselves: tests/sim/test_timing_rules.py, on a manual clock). Nothing here asserts a time."""
    cycles = 2
    loop, core, states, fall, nodes = _real_time_walk(cycles, "loop-realtime-walk")
    timing = loop.stats.summary()
    why = (f"events {loop.report.events[-4:]}, controller overruns {timing['overruns']} (skipped {timing['skipped_ticks']}), "
           f"nodes overruns {nodes['overruns']}, status read-window misses {loop.hardware.counters.timeouts}, "
           f"stalls {loop.report.stalls} {nodes['stalls']}")
    assert fall is None, why
    assert loop.hardware.rx.stats.rejected_total == 0 and nodes["receiver"]["rejected"] == 0
    assert timing["ticks"] == len(states) and timing["work"]["max_us"] > 0
    stall = _stopped_by_a_stall(loop, nodes)
    if stall is not None:
        print(f"real-time walk stopped by a stall of the machine: {stall}")
        return
    assert GaitState.FAULT not in states and GaitState.HOLD not in states, why
    landed = [s.leg for s in core.steps if s.landed]
    assert len(landed) == 2 * cycles and landed[0] != landed[1], why
    assert {GaitState.SWING_LEFT, GaitState.SWING_RIGHT} <= set(states)
    assert {n["error"] for n in nodes["nodes"].values()} == {"NONE"} and nodes["fall"] is None


def test_the_controller_benchmark_runs_the_real_pipeline():
    """``aider-exo bench controller`` measures a walking run (figures are printed, never asserted);
    a short one here."""
    import argparse

    from tools.bench import controller as bench

    result = bench.run(argparse.Namespace(config=None, cycles=1, realtime_cycles=1, max_ticks=60, repeats=2))
    ls, rt = result["lockstep"], result["realtime"]
    assert ls["walk"]["ticks"] == 60 and rt["walk"]["ticks"] == 60 and result["plain_sleep_loop"]["ticks"] == 60
    assert ls["walk"]["walking_ticks"] > 0 and ls["walk"]["final_state"] in bench.WALKING_NAMES  # the figures are from walking
    assert ls["physics_ticks"] == 60 and ls["controller_work_us"]["max"] > 0 and ls["pipeline_to_bare_sim"] > 0
    assert 0 < ls["pipeline_to_bare_physics"] < ls["pipeline_to_bare_sim"]  # the physics is part of the simulation's tick
    assert rt["walk"]["fault"] is None and rt["wakeup_lateness"]["max_us"] >= rt["wakeup_lateness"]["p99_us"]
    text = bench.format_text(result)
    assert "controller work per tick, p99" in text and "plain sleep loop" in text


def test_the_profile_ranks_a_real_walk_and_keeps_the_physics_apart(tmp_path):
    """``aider-exo bench profile``: the walk's main functions timed per tick (the timers removed
    after), then the walk under cProfile, PyBullet's step as its own part, the parts adding up to
    everything profiled, and the raw profile written for other viewers."""
    import argparse
    import pstats

    from tools.bench import profile as bench

    from sim.walk import Walker

    out = tmp_path / "walk.pstats"
    tick = Walker.tick
    result = bench.run(argparse.Namespace(config=None, cycles=1, top=5, out=str(out)))
    assert Walker.tick is tick  # the timers are gone
    timed = {p["function"]: p["us_per_tick"] for p in result["timed"]["parts"]}
    assert set(timed) == {name for _, _, name in bench.TIMED} and all(us > 0 for us in timed.values())
    assert timed["Walker.tick"] > timed["World.step"] > timed["PhysicsTimer.physics_step"]
    assert result["walk"]["steps_completed"] >= 1 and result["walk"]["fall"] is None
    parts = {p["part"]: p["share"] for p in result["parts"]}
    assert parts["physics (PyBullet step)"] > 0 and parts["simulation"] > 0 and parts["controller"] > 0
    assert abs(sum(parts.values()) - 1.0) < 1e-3
    assert len(result["functions"]) == 5 and result["functions"][0]["share"] >= result["functions"][-1]["share"]
    assert any(name == "physics_step" for _, _, name in pstats.Stats(str(out)).stats)
    assert "own time by part of the system" in bench.format_text(result)


def test_the_loop_writes_one_telemetry_record_per_tick(rig, tmp_path):
    from controller.telemetry import TelemetryLog, read_log

    loop, _ = rig()
    loop.telemetry = TelemetryLog(tmp_path / "ticks.jsonl")
    for _ in range(30):
        loop.step()
    assert loop.telemetry.close()["written"] == 30
    _, records = read_log(tmp_path / "ticks.jsonl")
    assert [r["tick"] for r in records] == list(range(30))
    assert records[-1]["state"] == "STAND" and records[-1]["mode"] == ["HOLD"] * 4
    assert 0.0 < records[-1]["x_ratio"] < 1.0 and len(records[-1]["com_m"]) == 3
    assert any("INIT -> STAND" in e for r in records for e in r["events"])


class _FloodBus:
    """A bus across processes that delivers ``n`` foreign frames (an ID none of ours), one every
    ``gap_ns`` of the clock, and then nothing."""

    def __init__(self, clock, n: int, gap_ns: int) -> None:
        import can

        self.clock, self.left, self.gap_ns = clock, n, gap_ns
        self.frame = can.Message(arbitration_id=0x7EF, data=bytes(8), is_extended_id=False)

    def recv(self, timeout=None):
        if self.left:
            self.left -= 1
            self.clock.advance(self.gap_ns)
            return self.frame
        self.clock.advance(int((timeout or 0) * 1e9))
        return None

    def send(self, msg, timeout=None) -> None:
        pass


@pytest.mark.parametrize(("gap_us", "read"), [(0, 200), (100, 600)])
def test_a_lockstep_tick_reads_at_most_200_frames_per_20_ms_it_waits(gap_us, read):
    """The drain's bound scales with the time waited: a flood arriving all at once stops it at 200
    frames, one spread over 60 ms of a lock-step tick (a stalled peer) is read in full, so the
    nodes' answers behind it are not left for a timeout (the cangen flood over vcan0 did that)."""
    from protocol.clock import ManualClock

    clock = ManualClock()
    bus = _FloodBus(clock, 600, gap_us * 1000)
    hardware = CanHardware(BASE.controller, bus, clock=clock)
    hardware._drain(0, clock.now_ns() + 2_000_000_000, {"LEFT_HIP"})
    assert hardware.counters.drained_max == read
    assert hardware.rx.stats.rejected_total == read and hardware.counters.timeouts == 1


class _SharedCpuClock:
    """Manual time that passes with this thread on the CPU (``work``) or without it (``lose``:
    another process or the host had it; sleeping is off the CPU too)."""

    def __init__(self) -> None:
        self.now, self.cpu = 0, 0

    def now_ns(self) -> int:
        return self.now

    def cpu_ns(self) -> int:
        return self.cpu

    def sleep_until(self, deadline_ns: int) -> None:
        self.now = max(self.now, deadline_ns)

    def work(self, ns: int) -> None:
        self.now += ns
        self.cpu += ns

    def lose(self, ns: int) -> None:
        self.now += ns


@pytest.mark.parametrize(("ms_off", "ms_on", "stalled"), [(25, 1, True), (1, 25, False)])
def test_a_real_time_tick_that_overran_off_the_cpu_is_a_stall(ms_off, ms_on, stalled):
    """A tick that overran its 20 ms while another process had the CPU is reported as a stall (the
    real-time smoke walks accept a stop that such overruns explain); one that overran by its own
    work is not."""
    from controller.loop import RealtimeLoop

    clock = _SharedCpuClock()
    core = ControllerCore(BASE.controller)
    update = core.update

    def slow_update(snapshot):  # tick 0's update: the CPU lost, then the controller's own work
        if snapshot.tick == 0:
            clock.lose(ms_off * 1_000_000)
            clock.work(ms_on * 1_000_000)
        return update(snapshot)

    core.update = slow_update
    with virtual_bus("loop-overrun-stall") as bus:
        loop = RealtimeLoop(core, CanHardware(BASE.controller, bus, clock=clock))
        loop.step()  # tick 0, no node up: nothing to wait for
        assert loop.step().tick == 2  # tick 1 skipped
    assert loop.timer.overruns == 1 and loop.timer.skipped == 1
    if stalled:  # tick 0 was not run for its 25 ms, its sync window's wait and its 1 ms of work aside
        [(tick, ms)] = loop.report.stalls
        assert tick == 0 and ms_off <= ms < ms_off + ms_on + 2
    else:
        assert loop.report.stalls == []
