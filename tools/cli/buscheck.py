"""``aider-exo buscheck``: check a CAN bus and the node boards on it, safely by default.

Three modes: ``listen`` sends nothing; ``hold`` (the default) commands every joint to HOLD; ``sweep``
exchanges every frame of the protocol with every signal over its whole range, and is refused on a
real bus (anything but the virtual bus and vcan*) without ``--i-understand-motors-will-move``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from protocol.clock import MonotonicClock
from tools.buscheck import (SWEEP_FLAG, BusCheckError, ProcessPeer, ThreadPeer, is_vcan, run_controller, run_nodes,
                            sweep_refusal)
from tools.busmonitor import run_hold, run_listen
from tools.cli.common import add_config_options, load_cli_config, positive_float, positive_int, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "buscheck",
        help="bus bring-up check: listen only, HOLD only (default), or the full-range protocol sweep",
        description=(
            "--mode listen reads the bus and sends nothing: the nodes' heartbeats and NMT states, supply "
            "voltages, drive states, error codes and EMCYs, every message's rate against its DBC cycle time, "
            "every signal's range, CRC and alive-counter health. Run it with the nodes powered, or beside a "
            "running controller. --mode hold (the default) is the controller's part with every joint commanded "
            "to HOLD (the drives hold where they are, within controller.safety.hold_torque_nm): NMT START, per "
            "tick SYNC, four HOLD commands and the controller heartbeat, at the end ENTER_PRE_OPERATIONAL; it "
            "also checks that every node answers every SYNC and every drive reports HOLD. --mode sweep sends "
            "joint commands in TRACK over every signal's full range (it moves motors) against a nodes side that "
            "answers with swept values (--role nodes, started by --peer), and verifies every value: it runs on "
            "the virtual bus and vcan* only, or with " + SWEEP_FLAG + " on a bench where nothing is attached to "
            "the motors. Bring-up order on a real bus: docs/DEPLOY.md."
        ),
    )
    add_config_options(p)
    p.add_argument("--mode", choices=("listen", "hold", "sweep"), default="hold",
                   help="listen: send nothing; hold: every joint commanded to HOLD (default); sweep: the full-range "
                        "protocol conformance check (moves motors)")
    p.add_argument(SWEEP_FLAG, dest="motors_may_move", action="store_true",
                   help="sweep: allow it on a bus other than virtual or vcan* (no one in the exoskeleton, joints free)")
    p.add_argument("--role", choices=("controller", "nodes"), default="controller",
                   help="sweep: which side to play (nodes: answer a sweep's SYNCs as the four boards would)")
    p.add_argument(
        "--peer", choices=("none", "thread", "process"), default=None,
        help="sweep: also start the nodes side (default: thread on a virtual bus, process on vcan*, none elsewhere)",
    )
    p.add_argument("--duration", type=positive_float, default=5.0, metavar="S", help="listen: seconds to listen (default 5)")
    p.add_argument("--ticks", type=positive_int, default=250, help="hold, sweep: ticks to run (default 250 = 5 s in real time)")
    p.add_argument("--lockstep", action="store_true", help="hold, sweep: start each tick when the last one is complete, not every 20 ms")
    p.add_argument("--fault-reset", action="store_true", help="hold: send FAULT_RESET before START (nodes latched in a fault)")
    p.add_argument("--tick-timeout", type=positive_float, default=2.0, metavar="S", help="lock-step: seconds to wait for a tick's node frames")
    p.add_argument("--handshake-timeout", type=positive_float, default=60.0, metavar="S",
                   help="hold, sweep: seconds to wait for every node's heartbeat (sweep: boot-up)")
    p.add_argument("--idle-timeout", type=positive_float, default=60.0, metavar="S", help="nodes role: give up after this long without a frame")
    p.add_argument("--candump", type=Path, metavar="FILE", help="sweep on socketcan: record the run with `candump -L` into FILE and decode it afterwards")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def _peer_argv(args: argparse.Namespace) -> list[str]:
    argv = ["buscheck", "--mode", "sweep", "--role", "nodes", "--json", "--idle-timeout", str(args.idle_timeout)]
    if args.config:
        argv += ["--config", args.config]
    if args.bus:
        argv += ["--bus", args.bus]
    if args.channel:
        argv += ["--channel", args.channel]
    return argv


def _only_with_sweep(args: argparse.Namespace) -> None:
    for given, option in ((args.peer, "--peer"), (args.candump, "--candump"), (args.role == "nodes", "--role nodes")):
        if given:
            raise BusCheckError(f"{option} belongs to --mode sweep (--mode {args.mode} checks real nodes)")


def run(args: argparse.Namespace) -> int:
    if args.mode == "listen":
        _only_with_sweep(args)
        result = run_listen(load_cli_config(args), MonotonicClock(), args.duration)
    elif args.mode == "hold":
        _only_with_sweep(args)
        result = run_hold(
            load_cli_config(args, needs=("controller",)), MonotonicClock(), ticks=args.ticks, lockstep=args.lockstep,
            tick_timeout_s=args.tick_timeout, handshake_timeout_s=args.handshake_timeout, fault_reset=args.fault_reset,
        )
    else:
        return _sweep(args)
    if args.json:
        print_json(result)
    else:
        print(format_safe(result), end="")
    return 0 if result["ok"] else 1


def _sweep(args: argparse.Namespace) -> int:
    cfg = load_cli_config(args)
    if args.role == "nodes":
        result = run_nodes(cfg, args.idle_timeout)
        if args.json:
            print_json(result)
        else:
            print(f"nodes side: {result['ticks']} ticks, {result['frames_sent']} frames sent, "
                  f"{result['receiver']['rejected']} rejected, {result['value_mismatches']} mismatches")
        return 0
    refusal = sweep_refusal(cfg.bus.interface, cfg.bus.channel, args.motors_may_move)
    if refusal:
        raise BusCheckError(refusal)
    peer_kind = args.peer or ("thread" if cfg.bus.interface == "virtual" else "process" if is_vcan(cfg.bus.interface, cfg.bus.channel) else "none")
    if peer_kind == "process" and cfg.bus.interface == "virtual":
        raise BusCheckError("a virtual bus lives inside one process: use --peer thread, or a socketcan bus")
    if args.candump and cfg.bus.interface != "socketcan":
        raise BusCheckError("--candump records a SocketCAN interface: use --bus socketcan --channel vcan0")
    peer = {"none": None, "thread": ThreadPeer(cfg, args.idle_timeout), "process": ProcessPeer(_peer_argv(args), args.idle_timeout + 30)}[peer_kind]
    result = run_controller(
        cfg, ticks=args.ticks, lockstep=args.lockstep, tick_timeout_s=args.tick_timeout,
        handshake_timeout_s=args.handshake_timeout, peer=peer, candump_path=args.candump,
    )
    if args.json:
        print_json(result)
    else:
        print(format_text(result), end="")
    return 0 if result["ok"] else 1


def format_safe(r: dict) -> str:
    """The listen and hold checks' report as text."""
    what = f"listened {r['duration_s']:g} s" if r["mode"] == "listen" else f"HOLD for {r['ticks']} ticks ({r['timing']})"
    rx = r["receiver"]
    lines = [
        f"bus check on {r['bus']['interface']}:{r['bus']['channel']}, {what}: sent {r['frames_sent']} frames, "
        f"accepted {rx['accepted']}, rejected {rx['rejected']}, lost {rx['lost']}"
    ]
    for name, n in r["nodes"].items():
        supply = n["supply_voltage_V"]
        joint = next((m["signals"]["position_rad"] for key, m in r["messages"].items()
                      if key.startswith("JOINT_STATUS_") and m["sender"] == name), None)
        lines.append(
            f"  {name:<10} heartbeats {n['heartbeats']:>4} last {n['last_nmt_state'] or '-'}"
            + (f", supply {supply[0]:.1f}-{supply[1]:.1f} V" if supply else "")
            + (f", joint {joint[0]:+.3f} to {joint[1]:+.3f} rad" if joint else "")
            + (f", drive {n['drive_states']}" if n["drive_states"] else "")
            + (f", EMCY {n['emcy_total']}" if n["emcy_total"] else "")
        )
    for name, m in r["messages"].items():
        timing = f", longest interval {m['max_interval_ms']:.0f} ms (cycle {m['cycle_ms']})" if "max_interval_ms" in m else ""
        lines.append(f"  {name:<22} {m['frames']:>6} frames{timing}")
    for problem in r["problems"]:
        lines.append(f"  problem: {problem}")
    lines.append("  result: " + ("OK" if r["ok"] else "FAILED"))
    return "\n".join(lines) + "\n"


def format_text(r: dict) -> str:
    c = r["controller"]
    lines = [f"bus check on {r['bus']['interface']}:{r['bus']['channel']} ({r['mode']}): {c['ticks']} ticks"]
    for key in ("controller", "nodes"):
        if key not in r:
            continue
        s = r[key]
        rx = s["receiver"]
        where = f" (pid {s['pid']})" if "pid" in s else ""
        reasons = f" {rx['rejected_by_reason']}" if rx["rejected_by_reason"] else ""
        lines.append(
            f"  {key} side{where}: sent {s['frames_sent']}, received {s['frames_received']}, "
            f"rejected {rx['rejected']}{reasons}, lost {rx['lost']}, "
            f"value mismatches {s['value_mismatches']}, missing {s['missing_frames']}, late {s['late_frames']}"
        )
    if "round_trip_us" in c:
        t = c["round_trip_us"]
        lines.append(f"  SYNC -> last node frame: p50 {t['p50']:.0f} us, p99 {t['p99']:.0f} us, max {t['max']:.0f} us")
    if "candump" in r:
        d = r["candump"]
        lines.append(
            f"  candump -L recorded {d['frames']} frames in {d['file']}: decoded with "
            f"{d['receiver']['rejected']} rejections, {d['receiver']['lost']} lost"
        )
    lines.append("  result: " + ("OK, every frame and value as expected" if r["ok"] else "FAILED"))
    return "\n".join(lines) + "\n"
