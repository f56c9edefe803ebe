"""``aider-exo trace``: record, decode, inspect, plot, replay and re-simulate CAN traces, and read the
controller's per-tick telemetry logs (docs/TRACE.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Callable

from config.files import check_output
from tools.cli.common import StopSignals, add_config_options, add_mode_option, load_cli_config, positive_float, positive_int, print_json, sim_mode, seed_type

FORMATS_HELP = "traces: .log (candump -l/-L), .asc, .blf, .trc, .csv (python-can), .mf4 (with asammdf); - reads candump -L from stdin"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("trace", help="record, decode, inspect, plot, replay and re-simulate CAN traces",
                       description="CAN traces with the project's DBC (docs/TRACE.md). Readable " + FORMATS_HELP + ".")
    tsub = p.add_subparsers(dest="trace_command", metavar="ACTION", required=True)

    r = tsub.add_parser("record", help="record a bus (or an in-process walk) to a file, with rotation and a metadata sidecar")
    r.add_argument("output", type=Path, help="trace file; its suffix picks the format: .log .asc .blf .trc .csv .mf4")
    add_config_options(r)
    r.add_argument("--walk", type=positive_int, metavar="CYCLES",
                   help="record the lock-step pipeline (controller, nodes, simulation) walking CYCLES gait cycles in this process")
    add_mode_option(r, "--walk: the simulation's mode")
    r.add_argument("--max-time", type=positive_float, metavar="S", help="--walk: simulated seconds at most")
    r.add_argument("--seed", type=seed_type, help="seed of the run (--walk: of the simulation, default 0); kept in the sidecar")
    r.add_argument("--count", type=positive_int, help="stop after this many frames")
    r.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds")
    r.add_argument("--idle-timeout", type=positive_float, metavar="S", help="stop after S seconds without a frame")
    r.add_argument("--rotate-mb", type=positive_float, metavar="MB", help="start a new part when one reaches MB megabytes")
    r.add_argument("--rotate-s", type=positive_float, metavar="S", help="start a new part every S seconds of trace time")
    r.add_argument("--bitrate", type=positive_int, metavar="BIT_S", help="bitrate for the sidecar (default bus.bitrate_bit_s)")
    r.add_argument("--overwrite", action="store_true", help="replace an existing file")
    r.add_argument("--json", action="store_true", help="machine-readable summary")
    r.set_defaults(func=run_record)

    d = tsub.add_parser("decode", help="decode a trace with the DBC: table, CSV or JSON lines, errors marked")
    _add_input(d)
    d.add_argument("--format", choices=("table", "csv", "jsonl"), default="table", help="output (default table)")
    d.add_argument("--json", dest="format", action="store_const", const="jsonl", help="same as --format jsonl")
    d.add_argument("-o", "--output", type=Path, help="write here (atomically) instead of standard output")
    d.add_argument("--errors-only", action="store_true", help="only frames that failed a check or follow lost ones")
    d.add_argument("--numeric", action="store_true", help="enumerations as numbers, not their DBC labels")
    d.set_defaults(func=run_decode)

    s = tsub.add_parser("stats", help="per-ID counts, periods and jitter, errors, bus load and the tick seen from SYNC")
    _add_input(s)
    s.add_argument("--bitrate", type=positive_int, metavar="BIT_S", help="bitrate of the bus-load figures (default: the sidecar's, else the config's)")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(func=run_stats)

    pl = tsub.add_parser("plot", help="chosen signals against time, to a PNG")
    _add_input(pl, signals_required=True)
    pl.add_argument("-o", "--output", type=Path, required=True, help="PNG file")
    pl.add_argument("--title", help="figure title (default: the trace's name)")
    pl.add_argument("--json", action="store_true", help="machine-readable summary")
    pl.set_defaults(func=run_plot)

    rp = tsub.add_parser("replay", help="send a trace onto a bus with its original timing, by role")
    _add_input(rp, config=False)
    add_config_options(rp)
    rp.add_argument("--role", choices=("all", "nodes", "controller"), default="all",
                    help="nodes: only the node boards' frames (to drive a live controller); controller: only the controller's (to drive live nodes)")
    rp.add_argument("--speed", type=positive_float, default=1.0, help="speed factor (2 = twice as fast)")
    rp.add_argument("--loop", type=_loops, default=1, metavar="N|inf", help="play N times, or until stopped (default 1)")
    rp.add_argument("--skip-gaps", type=_non_negative, metavar="S", help="shorten every gap longer than S seconds to S (0: send at once)")
    rp.add_argument("--catch-up", action="store_true",
                    help="after a stall send the overdue frames at once (default: each keeps half its recorded gap, no burst)")
    rp.add_argument("--spin-us", type=_non_negative, default=200.0, metavar="US",
                    help="poll the clock for the last US microseconds before each frame instead of sleeping (default 200)")
    rp.add_argument("--realtime", action="store_true",
                    help="SCHED_FIFO, locked memory, no deep idle states (protocol.realtime; each refused step is a warning)")
    rp.add_argument("--json", action="store_true", help="machine-readable summary")
    rp.set_defaults(func=run_replay)

    rs = tsub.add_parser("resim", help="feed a recorded run's node frames to the controller; report the first divergence",
                         description="Re-simulates a recorded run (trace record --walk, or a real-time session recorded by "
                         "aider-exo record or candump -L, in rotated files) with a fresh controller and compares what it "
                         "sends with what the recorded controller sent (docs/TRACE.md).")
    rs.add_argument("files", nargs="+", help="the recorded run (rotated parts in recording order; .log.part too)")
    rs.add_argument("--config", metavar="FILE", help="YAML configuration of the controller (default: the packaged one)")
    rs.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a configuration value (repeatable)")
    start = rs.add_mutually_exclusive_group()
    start.add_argument("--request-walk-tick", type=_walk_tick, metavar="TICK|start",
                       help="the operator's start at this tick, or 'start': at each controller start, as controller --walk "
                       "asks it (default: the sidecar's; without one 'start' when the recorded heartbeat shows walking)")
    start.add_argument("--no-request-walk", action="store_true", help="no operator start (a standing run)")
    rs.add_argument("--json", action="store_true", help="machine-readable output")
    rs.set_defaults(func=run_resim)

    tk = tsub.add_parser("ticks", help="summarise (and plot) the controller's per-tick telemetry logs (controller --log)",
                         description="The controller's per-tick telemetry (JSON lines, aider-exo controller --log): ticks, "
                         "time in each state and gait part, steps, falls, faults and events by kind, the tick's work and "
                         "lateness; several files (the logs moved aside at each restart, then the current one) in the order given.")
    tk.add_argument("logs", nargs="+", metavar="LOG", help="telemetry log(s), .jsonl (read in the order given)")
    tk.add_argument("--from", dest="start", type=_non_negative, metavar="S", help="from S seconds of controller time after the first record")
    tk.add_argument("--to", dest="end", type=_non_negative, metavar="S", help="up to S seconds after the first record")
    tk.add_argument("--plot", type=Path, metavar="OUT.png",
                    help="also write a PNG: joint angles and setpoints, stick forces, X_CoM/X_SP, step lengths, work")
    tk.add_argument("--title", help="--plot: the figure's title (default: the logs' names)")
    tk.add_argument("--json", action="store_true", help="machine-readable output")
    tk.set_defaults(func=run_ticks)


def _walk_tick(text: str) -> int | str:
    if text.strip().lower() == "start":
        return "start"
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a tick number nor 'start'") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} is not a tick number (0 or more)")
    return value


def _loops(text: str) -> int | None:
    if text.lower() in ("inf", "i"):
        return None
    return positive_int(text)


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"{text} is not a finite number of at least 0")
    return value


def _add_input(p: argparse.ArgumentParser, *, signals_required: bool = False, config: bool = True) -> None:
    p.add_argument("files", nargs="+", help=FORMATS_HELP + " (several files: read in the order given)")
    p.add_argument("--dbc", help="DBC file (default: the project's protocol/aider.dbc)")
    if config:
        p.add_argument("--config", metavar="FILE", help="YAML configuration (max_delta_counter, bitrate; default: the packaged one)")
    p.add_argument("--node", action="append", default=[], help="a node's frames: sent by it or addressed to it alone (repeatable)")
    p.add_argument("--message", action="append", default=[], help="message name or 0xID, shell patterns: 'JOINT_STATUS_*' (repeatable)")
    p.add_argument("--signal", action="append", default=[], required=signals_required,
                   help="signal NAME or MESSAGE.NAME, shell patterns: 'JOINT_*_LH.position*' (repeatable)")
    p.add_argument("--start", type=float, metavar="S", help="from S seconds after the first frame")
    p.add_argument("--end", type=float, metavar="S", help="up to S seconds after the first frame")


# -- shared input handling -----------------------------------------------------------------------


def _input(args: argparse.Namespace, *, role: str = "all") -> Any:
    from tools.trace.decode import Selection
    from tools.trace.source import TraceInput

    selection = Selection(nodes=tuple(args.node), messages=tuple(args.message), signals=tuple(args.signal),
                          start_s=args.start, end_s=args.end)
    return TraceInput(args.files, dbc=args.dbc, selection=selection, role=role)


def _inputs(args: argparse.Namespace) -> list[Any]:
    """Every file the command reads (an output must be none of them)."""
    return [*args.files, getattr(args, "dbc", None), getattr(args, "config", None)]


def _warn(lines: list[str]) -> None:
    for line in lines:
        print(f"aider-exo: warning: {line}", file=sys.stderr)


def _protocol_settings(args: argparse.Namespace) -> tuple[int, int]:
    """(max_delta_counter, bitrate) of the configuration named by ``--config``."""
    from config import default_config_path, load_config

    cfg = load_config(args.config or default_config_path())
    return cfg.protocol.max_delta_counter, cfg.bus.bitrate_bit_s


# -- record --------------------------------------------------------------------------------------


def run_record(args: argparse.Namespace) -> int:
    from protocol.bus import open_bus
    from protocol.catalog import default_catalog
    from protocol.clock import MonotonicClock
    from tools.trace import TraceError
    from tools.trace.files import recording_metadata
    from tools.trace.record import TraceWriter, check_writable, record_bus, record_walk

    cfg = load_cli_config(args)
    check_writable(args.output, overwrite=args.overwrite)
    if args.walk is not None:
        args.mode = sim_mode(args, cfg)
    if args.walk is None and cfg.bus.interface == "virtual":
        raise TraceError("a virtual bus lives inside one process: record a socketcan bus (--bus socketcan "
                         "--channel vcan0), or the in-process pipeline with --walk CYCLES")
    if args.walk is not None and (args.count or args.duration or args.idle_timeout):
        raise TraceError("--walk records the whole walk: --count, --duration and --idle-timeout are for a live bus")
    clock = MonotonicClock()
    writer = TraceWriter(args.output, rotate_bytes=int(args.rotate_mb * 1e6) if args.rotate_mb else None,
                         rotate_s=args.rotate_s)
    try:
        if args.walk is not None:
            seed = args.seed if args.seed is not None else 0
            source = record_walk(cfg, writer, cycles=args.walk, seed=seed, mode=args.mode, max_time_s=args.max_time)
            timebase = "lockstep: simulated time, 20 ms from SYNC to SYNC"
        else:
            seed = args.seed
            with StopSignals() as stop:
                bus = open_bus(cfg.bus)
                try:
                    if not args.json:
                        print(f"recording {cfg.bus.interface}:{cfg.bus.channel} to {args.output} (Ctrl-C stops)", file=sys.stderr)
                    ended = record_bus(bus, writer, clock, count=args.count, duration_s=args.duration,
                                       idle_timeout_s=args.idle_timeout, stop=lambda: stop.requested)
                finally:
                    bus.shutdown()
            source = {"kind": "bus", "ended_by": ended if ended != "stopped" else stop.name}
            timebase = "bus receive timestamps"
    except OSError as exc:  # a full disk, a folder that went away
        writer.abort()
        raise TraceError(f"{args.output}: recording stopped, cannot write ({exc}); what was written keeps its .partial name") from None
    except BaseException:
        writer.abort()
        raise
    meta = writer.close(recording_metadata(cfg, default_catalog(), seed=seed, bitrate_bit_s=args.bitrate or cfg.bus.bitrate_bit_s,
                                           timebase=timebase, source=source))
    if args.json:
        print_json(meta)
    else:
        if meta["parts"]:
            print(f"recorded {meta['frames']} frames to {', '.join(meta['parts'])} (+ {args.output.name}.meta.json)")
        else:
            print("no frame recorded: no file written")
    return 0


# -- decode and stats ----------------------------------------------------------------------------


def run_decode(args: argparse.Namespace) -> int:
    from config.files import atomic_path
    from tools.trace import TraceError
    from tools.trace.decode import OK, Formatter, TraceDecoder, write_csv, write_jsonl, write_table

    if args.output:
        check_output(args.output, inputs=_inputs(args), option="-o")  # before reading: never over an input
    max_delta, _ = _protocol_settings(args)
    src = _input(args)
    decoder = TraceDecoder(src.codec, max_delta_counter=max_delta)
    rows: Any = decoder.rows(src.frames(), src.selection)
    if args.errors_only:
        rows = (r for r in rows if r.status != OK or r.lost_before)
    fmt = Formatter(src.catalog, src.selection, labels=not args.numeric)
    write: Callable[..., int] = {"table": write_table, "csv": write_csv,
                                 "jsonl": lambda r, f, o, **kw: write_jsonl(r, f, o, catalog=src.catalog, **kw)}[args.format]
    if args.output:
        try:
            with atomic_path(args.output, inputs=_inputs(args)) as tmp, tmp.open("w", encoding="utf-8", newline="") as out:
                write(rows, fmt, out)
        except OSError as exc:
            raise TraceError(f"{args.output}: cannot write ({exc})") from None
    else:
        write(rows, fmt, sys.stdout, flush=src.streaming)
    _warn(src.warnings(decoder.receiver))
    return 0


def run_stats(args: argparse.Namespace) -> int:
    from tools.trace.decode import TraceDecoder
    from tools.trace.stats import collect, format_text

    max_delta, config_bitrate = _protocol_settings(args)
    src = _input(args)
    recorded_bitrate = next((m.get("bitrate_bit_s") for m in src.sidecars if m.get("bitrate_bit_s")), None)
    bitrate = args.bitrate or recorded_bitrate or config_bitrate
    decoder = TraceDecoder(src.codec, max_delta_counter=max_delta)
    result = collect(decoder.rows(src.frames(), src.selection), src.catalog, bitrate)
    warnings = src.warnings(decoder.receiver)
    result = {"input": src.report.as_dict(), "warnings": warnings, **result}
    if args.json:
        print_json(result)
    else:
        print(format_text(result), end="")
        _warn(warnings)
    return 0


def run_plot(args: argparse.Namespace) -> int:
    from tools.trace.decode import Formatter, TraceDecoder
    from tools.trace.plot import plot_png

    check_output(args.output, inputs=_inputs(args), option="-o")  # before reading: never over an input
    max_delta, _ = _protocol_settings(args)
    src = _input(args)
    decoder = TraceDecoder(src.codec, max_delta_counter=max_delta)
    fmt = Formatter(src.catalog, src.selection, labels=False)
    title = args.title or ", ".join(Path(f).name for f in args.files)
    result = plot_png(decoder.rows(src.frames(), src.selection), fmt, args.output, title=title, inputs=_inputs(args))
    warnings = src.warnings(decoder.receiver)
    if args.json:
        print_json({**result, "input": src.report.as_dict(), "warnings": warnings})
    else:
        print(f"plotted {len(result['signals'])} signal(s), {result['points']} points, {result['bad_frames']} bad frame(s) "
              f"marked, to {result['file']}")
        _warn(warnings)
    return 0


# -- replay --------------------------------------------------------------------------------------


def run_replay(args: argparse.Namespace) -> int:
    from protocol.bus import open_bus
    from protocol.clock import MonotonicClock
    from tools.trace import TraceError
    from tools.trace.decode import TraceDecoder
    from tools.trace.replay import ReplayOptions, replay

    cfg = load_cli_config(args)
    if cfg.bus.interface == "virtual":
        raise TraceError("a virtual bus lives inside one process: replay onto socketcan (--bus socketcan --channel vcan0)")
    src = _input(args, role=args.role)
    decoder = TraceDecoder(src.codec, max_delta_counter=cfg.protocol.max_delta_counter)
    frames = [row.frame for row in decoder.rows(src.frames(), src.selection)]
    options = ReplayOptions(speed=args.speed, loops=args.loop, max_gap_s=args.skip_gaps, catch_up=args.catch_up,
                            spin_s=args.spin_us / 1e6)
    warnings = src.warnings(decoder.receiver)
    if args.realtime:
        from protocol.realtime import realtime_setup

        warnings += realtime_setup().warnings
    with StopSignals() as stop:
        bus = open_bus(cfg.bus)
        try:
            report = replay(frames, bus.send, MonotonicClock(), options, stop=lambda: stop.requested)
        finally:
            bus.shutdown()
    result = {"bus": {"interface": cfg.bus.interface, "channel": cfg.bus.channel}, "role": args.role,
              "options": {"speed": args.speed, "loops": args.loop, "skip_gaps_s": args.skip_gaps, "catch_up": args.catch_up,
                          "spin_us": args.spin_us, "realtime": args.realtime},
              **report.as_dict(), "input": src.report.as_dict(), "warnings": warnings}
    if args.json:
        print_json(result)
    else:
        late = result["lateness_us"] or {"p50": 0, "p99": 0, "max": 0}
        print(f"replayed {result['sent']} of {result['frames_in_trace']} frames ({args.role}) onto {cfg.bus.channel}, "
              f"{result['loops_done']} loop(s){' (stopped)' if result['stopped'] else ''}: lateness p50 {late['p50']:.0f} us, "
              f"p99 {late['p99']:.0f} us, max {late['max']:.0f} us; {result['late_frames_over_1ms']} frame(s) over 1 ms late, "
              f"{result['send_failures']} send failure(s)")
        _warn(result["warnings"])
    return 0 if result["send_failures"] == 0 else 1


# -- resim ---------------------------------------------------------------------------------------


def run_resim(args: argparse.Namespace) -> int:
    from config import config_hash, default_config_path, load_config, parse_override, with_overrides
    from tools.trace import TraceError
    from tools.trace.reader import ReadReport, read_frames
    from tools.trace.resim import format_text, resimulate, walked
    from tools.trace.session import check_order
    from tools.trace.source import TraceInput

    src = TraceInput(args.files, stdin=False)
    order_warnings = check_order(args.files)  # the recorder's rotated files: given out of order is an error
    cfg = load_config(args.config or default_config_path())
    given_hash = config_hash(cfg)
    if args.set:
        cfg = with_overrides(cfg, dict(parse_override(s) for s in args.set))
    if cfg.controller is None:
        raise TraceError("the configuration has no controller section to re-simulate")
    meta = src.metadata
    warnings = []
    if meta.get("config_sha256") and meta["config_sha256"] != given_hash:
        warnings.append(f"the configuration differs from the recording's (sha256 {meta['config_sha256'][:12]} recorded, "
                        f"{given_hash[:12]} given)")
    if args.no_request_walk:
        walk_tick = None
    elif args.request_walk_tick is not None:
        walk_tick = args.request_walk_tick
    else:
        walk_tick = ((meta.get("source") or {}).get("operator") or {}).get("request_walk_tick")
        if walk_tick is None and walked(read_frames(args.files, ReadReport()), src.codec):
            walk_tick = "start"  # a real-time session: the controller asks the start when it first stands (--walk, --cycles)
            warnings.append("no sidecar says when the operator started walking; the recorded heartbeat shows walking: "
                            "the start assumed at the controller's start, as controller --walk asks it "
                            "(--request-walk-tick TICK or --no-request-walk to change)")
        elif walk_tick is None:
            warnings.append("no sidecar says when the operator started walking: none assumed (--request-walk-tick sets it)")
    result = resimulate(src.frames(), cfg.controller, codec=src.codec, max_delta_counter=cfg.protocol.max_delta_counter,
                        request_walk_tick=walk_tick).as_dict()
    warnings = src.warnings() + order_warnings + warnings
    result = {"files": args.files, "overrides": args.set, "request_walk_tick": walk_tick, **result,
              "input": src.report.as_dict(), "warnings": warnings}
    if args.json:
        print_json(result)
    else:
        print(format_text(result), end="")
        _warn(warnings)
    return 0 if result["reproduced"] else 1


# -- ticks ---------------------------------------------------------------------------------------


def run_ticks(args: argparse.Namespace) -> int:
    from tools.trace.ticks import Series, TicksError, format_text, plot_png, summarise

    if args.start is not None and args.end is not None and args.end < args.start:
        raise TicksError(f"--to {args.end:g} is before --from {args.start:g}")
    if args.plot:
        check_output(args.plot, inputs=args.logs, option="--plot")  # before reading: never over an input
    series = Series() if args.plot else None
    result = summarise(args.logs, start_s=args.start, end_s=args.end, series=series)
    if args.plot:
        title = args.title or ", ".join(Path(f).name for f in args.logs)
        result["plot"] = plot_png(series, args.plot, title=title, inputs=args.logs)
    if args.json:
        print_json(result)
    else:
        print(format_text(result), end="")
        if args.plot:
            print(f"plotted {result['plot']['points']} ticks to {result['plot']['file']}")
        _warn(result["warnings"])
    return 0
