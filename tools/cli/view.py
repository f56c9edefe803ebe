"""aider-exo view: the live view of a walk in the browser, from the bus or a recorded trace.

A passive listener on the bus (--bus socketcan --channel can0|vcan0, or udp_multicast) or on a
recorded trace (--trace FILE, any format the trace tool reads) that decodes every frame with the DBC
and the receiver's checks, runs the controller's own estimator on them, and serves one page over
HTTP and a WebSocket. It never sends a frame. For a walk in this process: aider-exo walk --view. See
docs/VIEW.md.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

from tools.cli.common import StopSignals, add_config_options, load_cli_config, port, positive_float, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="serve a live view of the walk (gait phase, forces, CoM in the support polygon, node health) from the bus alone",
        description=__doc__,
    )
    add_config_options(p)
    p.add_argument("--trace", nargs="+", metavar="FILE", help="play recorded traces instead of listening to the bus")
    p.add_argument("--speed", type=float, default=1.0, metavar="X",
                   help="--trace: times the recorded pace (default 1; 0: as fast as it reads)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1; any other needs --token)")
    p.add_argument("--port", type=port, default=8050, help="port (default 8050; 0: any free one)")
    p.add_argument("--token", help="secret the page must present (/?token=SECRET); required off loopback")
    p.add_argument("--rate", type=positive_float, default=25.0, metavar="HZ", help="page updates per second (default 25)")
    p.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--screenshot", metavar="PNG", type=Path,
                   help="open the page in a headless chromium and save it when the trace ends (or after --duration), then stop")
    p.add_argument("--json", action="store_true", help="at the end, print what the view saw and served as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from config.errors import AiderError
    from tools.view import make_feed
    from tools.view.server import ViewServer, check_bind

    if args.speed < 0:
        raise AiderError(f"--speed {args.speed}: give 0 (as fast as it reads) or a positive factor")
    check_bind(args.host, args.token)  # before anything is opened
    if args.screenshot and not (args.trace or args.duration):
        raise AiderError("--screenshot is taken when the trace ends or after --duration: give --trace or --duration")
    if args.screenshot:
        from config.files import check_output

        check_output(args.screenshot, inputs=[*(args.trace or ()), args.config], option="--screenshot")
    if args.trace:
        from tools.trace.reader import check_has_frames, check_readable

        check_readable(args.trace)
        check_has_frames(args.trace)  # an empty or unreadable trace is an error, not a view of nothing
    if args.screenshot:
        from tools.view.browser import missing

        if (why := missing()) is not None:
            raise AiderError(f"--screenshot drives a browser: {why}")
    cfg = load_cli_config(args)
    feed = make_feed(cfg)
    bus = None
    if args.trace:
        from tools.trace.reader import check_readable, read_frames, ReadReport
        from tools.view.source import TraceReader

        check_readable(args.trace)
        report = ReadReport()
        reader: Any = TraceReader(read_frames(args.trace, report), feed, speed=args.speed)
        source = f"trace {', '.join(Path(f).name for f in args.trace)}"
    else:
        if cfg.bus.interface == "virtual":
            raise AiderError("--bus virtual is the in-process bus of a walk in the same process: use aider-exo walk --view, "
                             "or listen on socketcan or udp_multicast")
        from protocol.bus import open_bus
        from tools.view.source import BusReader, ListenOnly

        bus = ListenOnly(open_bus(cfg.bus))
        reader = BusReader(bus, feed)
        source = f"{cfg.bus.interface}:{cfg.bus.channel}"
    server = ViewServer(feed, host=args.host, port=args.port, token=args.token, rate_hz=args.rate, title=source)
    shot = None
    try:
        if args.screenshot:
            shot = _screenshot(server, reader, args.duration, args.screenshot)
        else:
            asyncio.run(_serve(server, reader, args.duration, source))
    finally:
        reader.stop()
        if reader.is_alive():
            reader.join(timeout=getattr(reader, "DRAIN_S", 0.0) + 2.0)  # a bus reader drains what came before the stop
        if bus is not None:
            bus.shutdown()
    snap = feed.snapshot()
    summary = {
        "source": source, "url": server.url, "frames": snap["frames"], "receiver": snap["receiver"],
        "gait": {k: snap["gait"][k] for k in ("state", "steps", "cycles")}, "server": server.stats.as_dict(),
        "sends_refused": getattr(bus, "sends_refused", 0), "reader_error": reader.error,
        "screenshot": str(shot) if shot else None,
    }
    if args.json:
        print_json(summary)
    else:
        print(f"view of {source}: {summary['frames']} frames, {snap['gait']['steps']} steps seen; "
              f"served {server.stats.connects} browser connections, {server.stats.snapshots} updates"
              + (f"; the page saved as {shot}" if shot else ""))
    if reader.error:
        print(f"aider-exo view: warning: {reader.error}", file=sys.stderr)
    return 0


async def _serve(server: Any, reader: Any, duration_s: float | None, source: str) -> None:
    url = await server.start()
    reader.start()
    print(f"aider-exo view: {source} at {url} (Ctrl-C stops)", file=sys.stderr, flush=True)
    from protocol.clock import MonotonicClock

    clock = MonotonicClock()
    end_ns = None if duration_s is None else clock.now_ns() + int(duration_s * 1e9)
    try:
        with StopSignals() as stop:
            while not stop.requested and (end_ns is None or clock.now_ns() < end_ns):
                await asyncio.sleep(0.1)
    finally:
        await server.stop()


def _screenshot(server: Any, reader: Any, duration_s: float | None, path: Path) -> Path:
    """Serve in a thread, open the page in a headless chromium, and save it when the trace has
    been played (the page has drawn its last frame) or after ``duration_s``; the file written."""
    from protocol.clock import MonotonicClock
    from tools.view.browser import Browser
    from tools.view.server import ServerThread

    thread = ServerThread(server)
    url = thread.start_serving()
    try:
        with Browser(url) as page:
            page.wait_for("document.getElementById('link').textContent === 'connected'", 30)
            clock = MonotonicClock()
            end_ns = None if duration_s is None else clock.now_ns() + int(duration_s * 1e9)
            reader.start()
            while reader.is_alive() and (end_ns is None or clock.now_ns() < end_ns):
                reader.join(0.1)
            frames = server.feed.snapshot()["frames"]
            page.wait_for(f"window.viewStats.frames >= {frames}", 10)  # its last update drawn
            return page.screenshot(path)
    finally:
        thread.close()
