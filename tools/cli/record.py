"""``aider-exo record``: the session recorder, every frame of a CAN channel into rotating candump
log files, beside the controller for the whole session (docs/TRACE.md, "Session recorder")."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import Any

from tools.cli.common import StopSignals, print_json

#: for tests only: simulate a disk with this many bytes free at the start, less what this run wrote
FAKE_FREE_ENV = "AIDER_RECORD_TEST_FREE_BYTES"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record", help="the session recorder: every frame of a CAN channel into rotating candump log files",
        description="Record every frame of a CAN channel into candump log files (.log, as `candump -L` writes) named "
                    "CHANNEL_UTCTIME_SEQ.log, each written as .log.part and renamed when finished; rotation by size "
                    "or age, the oldest removed beyond --keep, a stop above a free-disk floor. SIGTERM/SIGINT finish "
                    "the current file and exit 0; the disk floor exits 3, a failing interface 4 (docs/TRACE.md).")
    p.add_argument("--channel", required=True, help="SocketCAN interface (can0, vcan0), or a --bus virtual/udp_multicast channel")
    p.add_argument("--bus", choices=("socketcan", "virtual", "udp_multicast"), default="socketcan",
                   help="bus interface (default socketcan; virtual is one process's bus, for tests)")
    p.add_argument("--dir", dest="folder", type=Path, required=True, help="existing, writable folder of the files")
    p.add_argument("--max-bytes", metavar="N", help="finish a file before it exceeds N bytes (suffixes k, M, G: 10^3, 10^6, 10^9)")
    p.add_argument("--max-seconds", metavar="S", help="finish a file once it is S seconds old")
    p.add_argument("--keep", metavar="K", help="keep only the newest K finished files of the channel in the folder")
    p.add_argument("--min-free-mb", metavar="M", default="100",
                   help="stop (exit 3) when the folder's file system has less than M megabytes free (default 100; 0: never)")
    p.add_argument("--status-every", metavar="S", default="5", help="seconds between status lines on stderr (default 5)")
    p.add_argument("--quiet", action="store_true", help="no status lines (the stop message is still printed)")
    p.add_argument("--json", action="store_true", help="a summary as JSON on stdout at the end")
    p.set_defaults(func=run_record)


def _number(text: str | None, option: str, *, integer: bool, allow_zero: bool = False) -> Any:
    from tools.trace import TraceError

    if text is None:
        return None
    scale, body = 1, text.strip()
    if integer and body[-1:] in ("k", "K", "M", "G"):
        scale, body = {"k": 10**3, "K": 10**3, "M": 10**6, "G": 10**9}[body[-1]], body[:-1]
    try:
        value = (int(body) if integer else float(body)) * scale
    except ValueError:
        kind = "a whole number" if integer else "a number"
        raise TraceError(f"{option}: {text!r} is not {kind}") from None
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        kind = "whole number" if integer else "finite number"
        raise TraceError(f"{option}: {text} is not a {'non-negative' if allow_zero else 'positive'} {kind}")
    return value


def _mb(n: int | None) -> str:
    return "?" if n is None else f"{n / 1e6:.1f} MB"


def run_record(args: argparse.Namespace) -> int:
    from config import BusConfig
    from config.errors import AiderError
    from protocol.bus import open_bus
    from protocol.clock import MonotonicClock
    from controller.sdnotify import Notifier
    from tools.trace import TraceError
    from tools.trace.session import EXIT_DISK_FLOOR, SessionRecorder, check_folder, disk_free, record_session

    max_bytes = _number(args.max_bytes, "--max-bytes", integer=True)
    max_seconds = _number(args.max_seconds, "--max-seconds", integer=False)
    keep = _number(args.keep, "--keep", integer=True)
    min_free_bytes = int(_number(args.min_free_mb, "--min-free-mb", integer=False, allow_zero=True) * 1e6)
    status_every = _number(args.status_every, "--status-every", integer=False)
    check_folder(args.folder)
    bus_cfg = BusConfig(interface=args.bus, channel=args.channel, bitrate_bit_s=1_000_000)
    try:
        bus_cfg.validate()
    except AiderError as exc:
        raise TraceError(f"--channel: {exc}".replace("--channel: channel: ", "--channel: ")) from None

    def say(line: str) -> None:
        if not args.quiet:
            print(f"record: {line}", file=sys.stderr, flush=True)

    fake = os.environ.get(FAKE_FREE_ENV)
    clock = MonotonicClock()
    recorder = SessionRecorder(
        args.folder, args.channel, max_bytes=max_bytes, max_seconds=max_seconds, keep=keep, min_free_bytes=min_free_bytes,
        clock=clock, on_finished=lambda path, frames, size: say(f"finished {path.name}: {frames} frames, {size} bytes"))
    if fake is not None:
        start_free = _number(fake, FAKE_FREE_ENV, integer=True, allow_zero=True)
        recorder.free_bytes = lambda _folder: start_free - recorder.bytes
    else:
        recorder.free_bytes = disk_free

    def stopped_on_floor(detail: str) -> int:
        where = f"; last file {recorder.files[-1].name} finished" if recorder.files else ""
        print(f"aider-exo: record: stopped: {args.folder} has {_mb(recorder.last_free)} free, below the floor of "
              f"{_mb(min_free_bytes)} (--min-free-mb){where}{'; ' + detail if detail else ''}", file=sys.stderr)
        return EXIT_DISK_FLOOR

    notifier = Notifier()
    reason, status, detail = "", 0, ""
    try:
        with StopSignals() as stop:
            if not recorder.space_ok(force=True):
                reason, status = "disk_floor", stopped_on_floor("nothing recorded")
            else:
                bus = open_bus(bus_cfg)
                try:
                    say(f"recording {args.bus}:{args.channel} into {args.folder} (SIGTERM or Ctrl-C stops)")
                    notifier.ready(f"recording {args.channel}")
                    next_status = clock.now_ns() + int(status_every * 1e9)

                    def on_idle() -> None:
                        nonlocal next_status
                        now = clock.now_ns()
                        notifier.ping(now)
                        if now >= next_status:
                            next_status = now + int(status_every * 1e9)
                            current = recorder.current.name if recorder.current else "none (no frame yet)"
                            say(f"{args.channel}: {recorder.frames} frames, {len(recorder.files)} files finished, "
                                f"{_mb(recorder.bytes)}; writing {current}; free {_mb(recorder.last_free)}")

                    reason, status, detail = record_session(bus, recorder, stop=lambda: stop.requested, on_idle=on_idle)
                finally:
                    notifier.stopping()
                    bus.shutdown()
                if reason == "signal":
                    reason = stop.name or "signal"
                elif reason == "disk_floor":
                    stopped_on_floor(detail)
                else:
                    last = f"; last file {recorder.files[-1].name} finished" if recorder.files else ""
                    print(f"aider-exo: record: stopped: the bus failed ({detail}){last}", file=sys.stderr)
    except OSError as exc:  # a write failed (the disk, the folder went away): the .part file stays
        recorder.abandon()
        raise TraceError(f"{args.folder}: recording stopped, cannot write ({exc.strerror or exc}); "
                         f"the file being written keeps its .part name") from None
    except BaseException:
        recorder.abandon()
        raise
    finally:
        notifier.close()
    summary = {"channel": args.channel, "bus": args.bus, "dir": str(args.folder), **recorder.status(),
               "frames_not_written": recorder.unwritten, "stopped_by": reason, "exit_status": status}
    if args.json:
        print_json(summary)
    else:
        say(f"{recorder.frames} frames in {len(recorder.files)} files ({_mb(recorder.bytes)}); stopped by {reason}")
    return status
