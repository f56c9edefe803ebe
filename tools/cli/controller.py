"""aider-exo controller: the main controller's 20 ms loop on a CAN bus.

The main controller: SYNC every tick, the nodes' frames read and checked, node supervision, state
estimation and the gait FSM, the DMP swing with the CoM-compensated step length, joint commands
through the safety envelope, its heartbeat. It brings the nodes up and stands; it walks only when
the operator asks for it (--walk, or --cycles N), so a controller restarted after a crash never
walks on its own (docs/FAULTS.md F22). Lock-step: each tick waits for the nodes' frames of its SYNC;
real time (default): absolute 20 ms deadlines with the real-time set-up where the OS permits it. A
one-line status per second on stderr; SIGINT or SIGTERM asks for a stop (the swing in progress ends
first), then the run ends with cyclictest-style tick statistics.
"""

from __future__ import annotations

import argparse
import sys

from protocol.enums import WALKING, GaitState
from tools.cli.common import StopSignals, add_config_options, config_path, load_cli_config, learned_folder, positive_float, positive_int, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "controller",
        help="run the main controller's tick loop on a CAN bus (nodes up, supervision, estimation, walking)",
        description=__doc__,
    )
    add_config_options(p)
    p.add_argument("--lockstep", action="store_true", help="a tick advances when the nodes have reported (default: real time)")
    p.add_argument("--ticks", type=positive_int, help="stop after this many ticks (default: run until SIGINT/SIGTERM)")
    p.add_argument("--cpu", type=int, help="real time: pin the loop to this CPU")
    p.add_argument("--walk", action="store_true", help="the operator's start: walk once standing, until SIGINT/SIGTERM")
    p.add_argument("--cycles", type=positive_int, metavar="N", help="walk N gait cycles once standing, then stop and exit")
    p.add_argument("--reset", action="store_true",
                   help="the operator's reset, once: the first time the controller is in FAULT it sends FAULT_RESET to "
                   "the nodes, then asks the FSM's reset as soon as its preconditions hold (nodes healthy for "
                   "controller.safety.reset_healthy_ticks, both sticks loaded); a later FAULT stays latched, and it never "
                   "walks on its own (add --walk or --cycles)")
    p.add_argument("--fixed-step", type=positive_float, metavar="M", help="every step this long: no compensation (the baseline)")
    p.add_argument("--learn", action="store_true", help="learn the compensation online with PI² (saved to --patient's learned file)")
    p.add_argument("--patient", metavar="NAME", help="walk with (and, learning, update) this patient's learned parameters "
                   "(no such file: an error, unless --learn creates it)")
    p.add_argument("--learned-dir", metavar="DIR", help="folder of the learned files (default: controller.learned_dir, relative: to the configuration file's folder)")
    p.add_argument("--log", metavar="FILE", help="per-tick telemetry as JSON lines (the first line is the schema); an existing log "
                   "is first moved aside to FILE's name dated with its last change (NAME.20261207T054200Z.jsonl), never truncated")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout at exit")
    p.add_argument("--quiet", action="store_true", help="no status lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.core import ControllerCore
    from controller.hardware import CanHardware
    from controller.loop import LockstepLoop, RealtimeLoop
    from controller.session import Session
    from controller.sdnotify import Notifier
    from controller.telemetry import TelemetryLog
    from protocol.realtime import realtime_setup
    from protocol.bus import open_bus
    from protocol.clock import MonotonicClock

    cfg = load_cli_config(args, needs=("controller",))
    from config.files import check_output
    from controller.factory import step_policy
    from controller.learned import learned_path

    # Everything that can be wrong with the configuration, the log or a learned file fails here, before the bus opens.
    if args.log:
        check_output(args.log, inputs=[config_path(args)], option="the telemetry log --log")
    patients = learned_folder(args, cfg)
    policy, saver = step_policy(cfg.controller, fixed_m=args.fixed_step, learn=args.learn, patient=args.patient,
                                learned_dir=str(patients))
    if args.learn and not args.patient:
        print("aider-exo controller: warning: learning without --patient: what is learnt is not kept", file=sys.stderr)
    if args.patient and not (args.quiet or args.json):
        print(f"aider-exo controller: patient {args.patient}: {learned_path(patients, args.patient)}", file=sys.stderr)
    core = ControllerCore(cfg.controller, policy=policy)
    notifier = Notifier()
    rt = None
    telemetry = None
    with StopSignals() as stop:
        bus = open_bus(cfg.bus)
        try:
            clock = MonotonicClock()
            telemetry = TelemetryLog(args.log) if args.log else None
            if telemetry is not None and telemetry.previous is not None:  # a restart: the crashed run's log is kept
                print(f"aider-exo controller: the previous log {args.log} was moved to {telemetry.previous}", file=sys.stderr)
            hardware = CanHardware(cfg.controller, bus, max_delta_counter=cfg.protocol.max_delta_counter, clock=clock)
            if args.lockstep:
                loop: LockstepLoop = LockstepLoop(core, hardware, telemetry=telemetry)
            else:
                rt = realtime_setup(cpu=args.cpu)
                for warning in rt.warnings:
                    print(f"aider-exo controller: warning: {warning}", file=sys.stderr)
                loop = RealtimeLoop(core, hardware, bitrate_bit_s=cfg.bus.bitrate_bit_s, telemetry=telemetry)
            session = Session(loop)
            operator = session.operator
            notifier.ready("controller loop running")
            next_status = clock.now_ns()
            result = None
            stopping_since = None  # the tick at which a stop was asked
            reset = "armed" if args.reset else "off"  # --reset: the operator's one reset procedure, at the first FAULT
            start = args.walk or args.cycles is not None  # the operator's one start, at the first STAND
            while args.ticks is None or loop.report.ticks < args.ticks:
                state = session.state
                if stopping_since is None:
                    if start and state == GaitState.STAND:
                        operator.start()  # it holds until the FSM leaves STAND
                        start = False
                    landed = sum(1 for step in core.steps if step.landed)
                    if stop.requested or (args.cycles is not None and landed >= 2 * args.cycles):
                        operator.stop()  # the swing in progress ends first
                        stopping_since = loop.report.ticks
                elif state not in WALKING or loop.report.ticks - stopping_since > 500:
                    break
                if reset == "armed" and state == GaitState.FAULT:
                    operator.recover()
                    reset = "spent"
                if args.cycles is not None and state in (GaitState.FAULT, GaitState.HOLD) and reset != "armed" and not operator.recovering:
                    break  # a walk of N cycles ends at a fault (on the robot the loop holds and waits for a reset)
                result = session.step()
                notifier.ping(clock.now_ns())  # from the loop itself: a hung loop stops the pings
                if not args.quiet and clock.now_ns() >= next_status:
                    print(f"controller {session.status().line()}", file=sys.stderr, flush=True)
                    next_status = clock.now_ns() + 1_000_000_000
        finally:
            notifier.stopping()
            notifier.close()
            log_report = telemetry.close() if telemetry is not None else None
            if saver is not None:
                saver.close()
            bus.shutdown()
            if rt is not None:
                rt.close()
    summary = {
        "mode": "lockstep" if args.lockstep else "realtime",
        "ticks": loop.report.ticks,
        "final_state": result.state.name if result else None,
        "fault_causes": [str(f) for f in core.fsm.fault_causes],  # every cause seen while FAULT is latched (the first announced)
        "fault_kinds": [f.kind.name for f in core.fsm.fault_causes],
        "timeouts": hardware.counters.timeouts,
        "frames_sent": hardware.counters.frames_sent,
        "send_failures": hardware.counters.send_failures,
        "receiver": hardware.rx.stats.as_dict(),
        "timing": loop.stats.summary(),
        "stalls": [list(x) for x in loop.report.stalls],
        "realtime_setup": {"applied": rt.applied, "warnings": rt.warnings} if rt else None,
        "events": loop.report.events,
        "telemetry": log_report,
        "x_ratio": round(result.estimate.x_ratio, 4) if result and result.estimate else None,
        "policy": core.policy.mode,
        "steps_completed": sum(1 for step in core.steps if step.landed),
        "steps": [step.as_dict() for step in core.steps],
        "learned_file": {"path": str(saver.path), "writes": saver.writes, "errors": saver.errors} if saver else None,
        "stopped_by": stop.name,
        "resets": [tick for tick, button in operator.presses if button == "reset"],
    }
    if args.json:
        print_json(summary)
    if not args.quiet:
        print(loop.stats.format(), file=sys.stderr)
    return 0
