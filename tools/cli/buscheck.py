"""``aider-exo buscheck``: exchange every frame of the protocol, tick by tick, and check them all."""

from __future__ import annotations

import argparse
from pathlib import Path

from tools.buscheck import BusCheckError, ProcessPeer, ThreadPeer, run_controller, run_nodes
from tools.cli.common import add_config_options, load_cli_config, positive_float, positive_int, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "buscheck",
        help="bus bring-up check: controller and node traffic of every tick, every value verified",
        description=(
            "The controller side sends SYNC, joint commands and heartbeats; the nodes side (the four node "
            "boards' traffic) answers every SYNC. Both verify every decoded value. Run the two roles in "
            "separate processes on a SocketCAN bus, or let the controller side start the nodes side "
            "(--peer process, or --peer thread on the in-process virtual bus)."
        ),
    )
    add_config_options(p)
    p.add_argument("--role", choices=("controller", "nodes"), default="controller")
    p.add_argument(
        "--peer", choices=("none", "thread", "process"), default=None,
        help="controller role: also start the nodes side (default: thread on a virtual bus, process on socketcan)",
    )
    p.add_argument("--ticks", type=positive_int, default=250, help="ticks to run (default 250 = 5 s in real time)")
    p.add_argument("--lockstep", action="store_true", help="start each tick when the last one is complete, not every 20 ms")
    p.add_argument("--tick-timeout", type=positive_float, default=2.0, metavar="S", help="lock-step: seconds to wait for a tick's node frames")
    p.add_argument("--handshake-timeout", type=positive_float, default=60.0, metavar="S", help="seconds to wait for the nodes' boot-up")
    p.add_argument("--idle-timeout", type=positive_float, default=60.0, metavar="S", help="nodes role: give up after this long without a frame")
    p.add_argument("--candump", type=Path, metavar="FILE", help="socketcan: record the run with `candump -L` into FILE and decode it afterwards")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def _peer_argv(args: argparse.Namespace) -> list[str]:
    argv = ["buscheck", "--role", "nodes", "--json", "--idle-timeout", str(args.idle_timeout)]
    if args.config:
        argv += ["--config", args.config]
    if args.bus:
        argv += ["--bus", args.bus]
    if args.channel:
        argv += ["--channel", args.channel]
    return argv


def run(args: argparse.Namespace) -> int:
    cfg = load_cli_config(args)
    if args.role == "nodes":
        result = run_nodes(cfg, args.idle_timeout)
        if args.json:
            print_json(result)
        else:
            print(f"nodes side: {result['ticks']} ticks, {result['frames_sent']} frames sent, "
                  f"{result['receiver']['rejected']} rejected, {result['value_mismatches']} mismatches")
        return 0
    peer_kind = args.peer or ("thread" if cfg.bus.interface == "virtual" else "process")
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
