"""aider-exo nodes: the simulated HHEA and its four node boards, speaking only CAN.

Hosts the PyBullet HHEA (with the patient) and four CANopen-style node boards (left/right hip and
knee). They boot, wait for the controller's NMT start, apply its joint commands per SYNC, report
status and sensors per SYNC with alive counters and CRCs, and quick-stop on a lost controller.
Lock-step: each SYNC advances the physics by one 20 ms tick; with ``--silence S`` a controller that
sends no SYNC for S seconds is taken as gone and the boards run on their own clock until it is back. A one-line status per second goes to
stderr; SIGINT or SIGTERM ends the run cleanly.
"""

from __future__ import annotations

import argparse
import json
import sys
from tools.cli.common import StopSignals, add_config_options, add_mode_option, config_path, load_cli_config, print_json, seed_type



def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "nodes",
        help="emulate the four node boards driving the simulated HHEA over CAN",
        description=__doc__,
    )
    add_config_options(p)
    p.add_argument("--lockstep", action="store_true", help="advance the physics one tick per SYNC (default: real time)")
    p.add_argument("--silence", type=float, metavar="S",
                   help="lock-step: after S seconds (wall time) without a SYNC the boards run on their own 20 ms clock, "
                        "watchdogs included, as after a crashed controller, until a SYNC comes again (default: wait for it)")
    p.add_argument("--gui", action="store_true", help="open the PyBullet window")
    p.add_argument("--seed", type=seed_type, default=0, help="seed of sensor noise, the patient and fault injection (default 0)")
    add_mode_option(p)
    p.add_argument("--truth", metavar="FILE", help="write the simulation's ground truth after every SYNC as JSON lines "
                   "(tick, X_CoM/X_SP, fall): for tests and experiments, never sent on the bus")
    p.add_argument("--json", action="store_true", help="print the final state as JSON on stdout at exit")
    p.add_argument("--quiet", action="store_true", help="no status lines")
    p.add_argument("--priority", type=int, metavar="P",
                   help="real time: run the boards' loop SCHED_FIFO at P (below the controller's 50; default: the normal "
                        "scheduler, which on a one-CPU machine leaves room for candump and the controller)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from config import with_overrides
    from nodes.host import NodesHost
    from protocol.bus import open_bus
    from protocol.clock import MonotonicClock
    from protocol.realtime import realtime_setup

    cfg = load_cli_config(args, needs=("sim", "nodes"))
    if args.truth:
        from config.files import check_output

        check_output(args.truth, inputs=[config_path(args)], option="--truth")  # before the simulation loads
    if args.mode:
        cfg = with_overrides(cfg, {"sim.mode": args.mode})
    with StopSignals() as stop:
        bus = open_bus(cfg.bus)
        try:
            host = NodesHost(cfg, bus, lockstep=args.lockstep, seed=args.seed, gui=args.gui, clock=MonotonicClock(),
                             silence_s=args.silence)
            truth = open(args.truth, "w", encoding="utf-8") if args.truth else None
            if truth is not None:
                host.on_sync_hook = lambda _tick: truth.write(json.dumps(host.truth(), allow_nan=True) + "\n")
            rt = None
            try:
                if not args.lockstep:
                    # The boards are microcontrollers: no pause of the emulator's own (a full garbage
                    # collection of the simulation's heap took 31 ms here and several times that in
                    # the vcan sandbox, past the controller's 3-tick budget for a lost node).
                    rt = realtime_setup(priority=args.priority)
                    for warning in rt.warnings:
                        print(f"aider-exo nodes: warning: {warning}", file=sys.stderr)
                host.boot()
                interval = cfg.nodes.status_interval_s if cfg.nodes else 1.0
                while not stop.requested:
                    host.poll(interval)
                    if not args.quiet:
                        print(host.status_line(), file=sys.stderr, flush=True)
                result = host.status()
                result["realtime_setup"] = {"applied": rt.applied, "warnings": rt.warnings} if rt else None
            finally:
                if rt is not None:
                    rt.close()
                host.close()
                if truth is not None:
                    truth.close()
        finally:
            bus.shutdown()
    result["stopped_by"] = stop.name
    if args.json:
        print_json(result)
    elif not args.quiet:
        print(f"nodes: stopped by {result['stopped_by']} after {result['syncs']} SYNCs", file=sys.stderr)
    return 0
