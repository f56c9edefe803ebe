"""Live view speed: frame-to-browser latency, page updates per second and the listener's CPU share
during a walk, and the controller's work per tick with and without the view attached, in one run.

Two settings, each ``--repeats`` walks of ``--cycles`` gait cycles (sagittal mode, seed 0, the
compensated step length) with the view, each between two without it: the spread of the
controller's p99 over the walks without the view is the run's noise, against which the median
p99 of the walks with it is compared.

1. **Beside the walk** (a deployment): ``aider-exo nodes`` and ``aider-exo controller --cycles N``
   in real time (the controller's real-time set-up: SCHED_FIFO where allowed), two processes on a
   UDP multicast group of the loopback, and ``aider-exo view`` on the same group as a third
   process, started at niceness 10 with its browser (docs/VIEW.md advises it on a shared
   machine). The listener's CPU share is that whole process's CPU time (``/proc/PID/stat``)
   over the walk's wall time. The goals apply to this setting.
2. **In the walk's process** (``aider-exo walk --view``): the lock-step walk paced at ``--pace``
   times real time on python-can's in-process virtual bus, the view's bus reader and server as
   threads of the same process (their CPU time from ``/proc/self/task``). Here the view costs the
   controller: the virtual bus copies every frame once more, in the sender's thread, for the
   view's socket, and the view's threads share the interpreter lock with the controller.

In both, Debian's chromium (headless, driven by playwright) has the page open: the page measures
each update's latency, from the newest frame's bus timestamp to the update's arrival in the page
(the same machine's wall clock), once per new frame, and counts its updates. The browser's own
CPU (it draws the page, 25 times a second) is reported beside the listener's. The controller's
work per tick is its own (reading and checking frames, estimation, FSM, gait, encoding), as
``aider-exo controller`` and ``aider-exo walk`` report it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from config import ConfigError, default_config_path, load_config, with_overrides
from config.errors import AiderError
from protocol.bus import free_udp_channel
from protocol.clock import MonotonicClock
from tools.view.browser import cpu_s

GOAL_LATENCY_P99_MS = 100.0
GOAL_UPDATES_PER_S = 20.0
GOAL_LISTENER_CPU_PERCENT = 10.0
MODE = "sagittal"
SEED = 0
AIDER = str(Path(sys.executable).with_name("aider-exo"))
NICE = 10  # beside the walk, the view and the browser yield the CPU to it, as docs/VIEW.md advises


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--cycles", type=int, default=1, help="gait cycles of each walk (default 1, about 11 s at real time)")
    parser.add_argument("--pace", type=float, default=1.0, help="times real time of the lock-step walks in the walk's process (default 1)")
    parser.add_argument("--repeats", type=int, default=2,
                        help="walks with the view in each setting, each between two without it (default 2: five walks a setting)")
    parser.add_argument("--max-ticks", type=int, help="end each walk after at most this many ticks (a short run)")
    parser.add_argument("--screenshot", metavar="PNG", type=Path,
                        help="save the page as the last walk beside the view ends")


def browser_cpu_s() -> float:
    """CPU time (s) so far of every chromium process on this machine (the page's browser: its
    renderer draws the canvases)."""
    total = 0.0
    for comm in Path("/proc").glob("[0-9]*/comm"):
        try:
            if comm.read_text().strip() in ("chromium", "chrome"):
                total += cpu_s(str(comm.with_name("stat")))
        except OSError:
            continue
    return total


def _percentiles_ms(latencies_s: list[float]) -> dict[str, Any]:
    ms = np.array(latencies_s, dtype=float) * 1e3
    if ms.size == 0:
        return {"samples": 0, "p50": None, "p99": None, "max": None}
    return {"samples": int(ms.size), "p50": round(float(np.percentile(ms, 50)), 1),
            "p99": round(float(np.percentile(ms, 99)), 1), "max": round(float(ms.max()), 1)}


def _work(timing: dict[str, Any]) -> dict[str, Any]:
    """The controller's own work per tick over a walk (``aider-exo walk``'s timing)."""
    w = timing["work"]
    return {k: w[k] for k in ("avg_us", "p50_us", "p99_us", "p99_ci_us", "max_us")} | {"ticks": timing["ticks"]}


def _walked(summary: dict[str, Any]) -> dict[str, Any]:
    return {"cycles_completed": summary["cycles_completed"], "fall": summary["fall_reason"], "fault": summary["fault"],
            "ticks": summary["ticks"], "overruns": summary["timing"]["overruns"]}


def _watch(url: str, run_walk: Callable[[], None], cpu: Callable[[], float], screenshot: Path | None, *, nice: int = 0) -> dict[str, Any]:
    """A headless chromium on the page at ``url`` while ``run_walk()`` runs (in a thread: the
    browser is driven from this one): latency, updates per second and ``cpu()``'s share of the walk."""
    from tools.view.browser import Browser

    clock = MonotonicClock()
    error: list[BaseException] = []

    def walk() -> None:
        try:
            run_walk()
        except BaseException as exc:  # handed to this thread
            error.append(exc)

    walker = threading.Thread(target=walk, name="bench-view-walk", daemon=True)
    with Browser(url, nice=nice) as page:
        page.wait_for("document.getElementById('link').textContent === 'connected'", 30)
        cpu0, browser0, updates0, start = cpu(), browser_cpu_s(), page.stats()["updates"], clock.now_ns()
        walker.start()
        while walker.is_alive():
            walker.join(0.5)
        wall_s = (clock.now_ns() - start) / 1e9
        used_s, browser_s = cpu() - cpu0, browser_cpu_s() - browser0
        stats = page.stats()
        shot = page.screenshot(screenshot) if screenshot else None
    if error:
        raise error[0]
    return {"latency_ms": _percentiles_ms(stats["latencies"]), "updates_per_s": round((stats["updates"] - updates0) / wall_s, 1),
            "listener_cpu_percent": round(100 * used_s / wall_s, 1), "browser_cpu_percent": round(100 * browser_s / wall_s, 1),
            "wall_s": round(wall_s, 2),
            "screenshot": str(shot) if shot else None}


# -- beside the walk: the view as its own process ----------------------------------------------------


def _realtime_walk(cfg: Any, args: argparse.Namespace, channel: str) -> dict[str, Any]:
    """A deployment's walk: ``aider-exo nodes`` and ``aider-exo controller --cycles N`` (its real-time
    set-up: SCHED_FIFO where allowed), both in real time on ``channel``; the controller's summary."""
    from protocol.clock import TICK_MS
    from tools.pipeline import default_max_time_s, wait_for_boot_ups

    bus = ["--bus", "udp_multicast", "--channel", channel] + (["--config", args.config] if args.config else [])
    ticks = args.max_ticks or int(default_max_time_s(args.cycles) * 1000 / TICK_MS)
    nodes = subprocess.Popen([AIDER, "nodes", *bus, "--mode", MODE, "--seed", str(SEED), "--json", "--quiet"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_boot_ups(with_overrides(cfg, {"bus.interface": "udp_multicast", "bus.channel": channel}).bus, nodes)
        done = subprocess.run([AIDER, "controller", *bus, "--cycles", str(args.cycles), "--ticks", str(ticks), "--json", "--quiet"],
                              capture_output=True, text=True, check=False)
    finally:
        nodes.send_signal(signal.SIGTERM)
        nodes_out, _ = nodes.communicate(timeout=60)
    if done.returncode != 0:
        raise AiderError(f"the controller failed: {done.stderr.strip().splitlines()[-1:] or done.returncode}")
    summary = json.loads(done.stdout)
    faults = summary["fault_causes"]
    fall = json.loads(nodes_out).get("fall") if nodes_out.strip() else "the nodes process reported nothing"
    return summary | {"cycles_completed": summary["steps_completed"] // 2, "fall_reason": fall,
                      "fault": faults[0] if faults else None}


@contextmanager
def _view_process(args: argparse.Namespace, channel: str) -> Iterator[tuple[subprocess.Popen, str]]:
    cmd = ["nice", "-n", str(NICE), AIDER, "view", "--bus", "udp_multicast", "--channel", channel, "--port", "0", "--json"]
    view = subprocess.Popen(cmd + (["--config", args.config] if args.config else []),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        started = view.stderr.readline()  # "aider-exo view: SOURCE at URL (Ctrl-C stops)"
        if " at http" not in started:
            raise AiderError(f"the view did not start: {(started + view.stderr.read()).strip()}")
        yield view, started.split(" at ", 1)[1].split()[0]
    finally:
        view.send_signal(signal.SIGINT)
        view.communicate(timeout=30)


def _beside(cfg: Any, args: argparse.Namespace, say: Callable[[str], None]) -> dict[str, Any]:
    channel = free_udp_channel()

    def with_view(last: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        walked: dict[str, Any] = {}
        with _view_process(args, channel) as (view, url):
            seen = _watch(url, lambda: walked.update(_realtime_walk(cfg, args, channel)),
                          lambda: cpu_s(f"/proc/{view.pid}/stat"), args.screenshot if last else None, nice=NICE)
        return seen, walked

    return _alternate(args, say, "beside the walk", lambda: _realtime_walk(cfg, args, channel), with_view,
                      listener="the view process", what="aider-exo view as a third process")


# -- in the walk's process (walk --view) -----------------------------------------------------------


def _in_process_walk(cfg: Any, args: argparse.Namespace, channel: str) -> dict[str, Any]:
    from protocol.clock import TICK_S
    from tools.pipeline import Pace, walk

    pace = Pace(args.pace)
    outcome = walk(cfg, cycles=args.cycles, seed=SEED, mode=MODE, channel=channel, compare_ratio=False,
                   max_time_s=args.max_ticks * TICK_S if args.max_ticks else None,
                   on_tick=lambda result, session, host: pace(result.tick))
    return outcome.summary()


def _in_process(cfg: Any, args: argparse.Namespace, say: Callable[[str], None]) -> dict[str, Any]:
    from tools.pipeline import walk_config
    from tools.view.live import LiveView

    channel = "bench-view"

    def with_view(last: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        view = LiveView(cfg, walk_config(cfg, MODE, channel).bus, port=0)
        walked: dict[str, Any] = {}
        try:
            url = view.start()
            threads = [f"/proc/self/task/{t.native_id}/stat" for t in (view.reader, view.server)]
            seen = _watch(url, lambda: walked.update(_in_process_walk(cfg, args, channel)), lambda: sum(map(cpu_s, threads)), None)
        finally:
            view.close()
        return seen, walked

    return _alternate(args, say, "in the walk's process", lambda: _in_process_walk(cfg, args, channel), with_view,
                      listener="the view's two threads", what="the view's threads (walk --view)")


def _alternate(args: argparse.Namespace, say: Callable[[str], None], setting: str, without: Callable[[], dict[str, Any]],
               with_view: Callable[[bool], tuple[dict[str, Any], dict[str, Any]]], *, listener: str, what: str) -> dict[str, Any]:
    """Walks without the view and with it, alternating (``--repeats`` with it, each between two
    without): the figures of the walks with the view (the worst of them; the controller's p99 their
    median) against the spread of the walks without it, the run's noise."""
    total = 2 * args.repeats + 1
    bare: list[dict[str, Any]] = []
    viewed: list[tuple[dict[str, Any], dict[str, Any]]] = []
    for k in range(total):
        if k % 2 == 0:
            say(f"{setting}, walk {k + 1} of {total}: without the view")
            bare.append(without())
        else:
            say(f"{setting}, walk {k + 1} of {total}: with {what} and a headless chromium on its page")
            viewed.append(with_view(k == total - 2))
    work = {"without_view": [_work(s["timing"]) for s in bare], "with_view": [_work(w["timing"]) for _, w in viewed]}
    spread = [min(w["p99_us"] for w in work["without_view"]), max(w["p99_us"] for w in work["without_view"])]
    median_p99 = float(np.median([w["p99_us"] for w in work["with_view"]]))
    seen = [s for s, _ in viewed]
    lat = [s["latency_ms"] for s in seen]
    return {
        "listener": listener,
        "walks": {"without_view": [_walked(s) for s in bare], "with_view": [_walked(w) for _, w in viewed]},
        "latency_ms": {"samples": sum(x["samples"] for x in lat), "p50": float(np.median([x["p50"] for x in lat])),
                       "p99": max(x["p99"] for x in lat), "max": max(x["max"] for x in lat)},
        "updates_per_s": min(s["updates_per_s"] for s in seen),
        "listener_cpu_percent": max(s["listener_cpu_percent"] for s in seen),
        "browser_cpu_percent": max(s["browser_cpu_percent"] for s in seen),
        "wall_s": [s["wall_s"] for s in seen],
        "screenshot": next((s["screenshot"] for s in seen if s["screenshot"]), None),
        "controller_work_us": {
            **work,
            "p99_without_view_spread_us": spread,
            "p99_with_view_median_us": round(median_p99, 1),
            "p99_within_noise": spread[0] <= median_p99 <= spread[1],
        },
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if min(args.cycles, args.repeats) <= 0 or args.pace <= 0 or (args.max_ticks is not None and args.max_ticks <= 0):
        raise ConfigError("--cycles, --repeats, --pace and --max-ticks must be positive")
    from tools.view.browser import missing

    if (why := missing()) is not None:
        raise ConfigError(f"bench view drives a browser: {why}")
    cfg = load_config(args.config or default_config_path())
    if cfg.sim is None or cfg.nodes is None or cfg.controller is None:
        raise ConfigError("controller, sim and nodes sections required by the view benchmark", key="controller")
    cfg = with_overrides(cfg, {"sim.mode": MODE})

    def say(text: str) -> None:
        print(f"bench view: {text}", file=sys.stderr, flush=True)

    return {
        "benchmark": "view",
        "mode": MODE, "seed": SEED, "cycles": args.cycles, "pace": args.pace, "repeats": args.repeats,
        "beside_the_walk": _beside(cfg, args, say),
        "in_the_walks_process": _in_process(cfg, args, say),
        "goals": {"latency_p99_ms_max": GOAL_LATENCY_P99_MS, "updates_per_s_min": GOAL_UPDATES_PER_S,
                  "listener_cpu_percent_max": GOAL_LISTENER_CPU_PERCENT,
                  "controller_work_p99": "unchanged within the run's noise (beside the walk)"},
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(),
                    "processor": platform.processor() or platform.machine(), "load_avg_1min": round(os.getloadavg()[0], 2)},
    }


def _rows(s: dict[str, Any], g: dict[str, Any]) -> list[tuple[str, str, str]]:
    lat, c = s["latency_ms"], s["controller_work_us"]

    def us(runs: list[dict[str, Any]], key: str) -> str:
        return " ".join(f"{w[key]:.0f}" for w in runs) + " us"

    spread = c["p99_without_view_spread_us"]
    return [
        ("frame-to-page latency, p50 / p99 / max", f"{lat['p50']:.1f} / {lat['p99']:.1f} / {lat['max']:.1f} ms",
         f"p99 at most {g['latency_p99_ms_max']:.0f} ms ({lat['samples']} updates)"),
        ("page updates per second", f"{s['updates_per_s']}", f"at least {g['updates_per_s_min']:.0f}"),
        ("listener CPU, % of one core", f"{s['listener_cpu_percent']}",
         f"at most {g['listener_cpu_percent_max']:.0f} ({s['listener']}; the browser {s['browser_cpu_percent']})"),
        ("controller work p99, walks without the view", us(c["without_view"], "p99_us"), "the run's noise"),
        ("controller work p99, walks with the view", us(c["with_view"], "p99_us"),
         f"median {c['p99_with_view_median_us']:.0f} us: {'within' if c['p99_within_noise'] else 'beyond'} "
         f"the noise ({spread[0]:.0f}-{spread[1]:.0f} us)"),
        ("controller work mean, without the view", us(c["without_view"], "avg_us"), ""),
        ("controller work mean, with the view", us(c["with_view"], "avg_us"), ""),
    ]


def format_text(r: dict[str, Any]) -> str:
    lines = [f"view benchmark: walks of {r['cycles']} gait cycle(s) ({r['mode']}, seed {r['seed']}); "
             f"each setting {r['repeats']} walks with the view, each between two without it"]
    for key, title in (("beside_the_walk", "beside the walk (nodes and controller in real time, the view a third process; UDP multicast)"),
                       ("in_the_walks_process", f"in the walk's process (walk --view: lock-step at {r['pace']:g} x real time, "
                                                "the view's threads; in-process virtual bus)")):
        s = r[key]
        w = s["walks"]["with_view"][-1]
        lines += [f"{title}: the last walk with the view {w['cycles_completed']} cycles, {w['ticks']} ticks in {s['wall_s'][-1]} s",
                  f"  {'figure':<44}{'measured':>28}  goal / baseline (same run)"]
        lines += [f"  {name:<44}{value:>28}  {note}".rstrip() for name, value, note in _rows(s, r["goals"])]
    shot = r["beside_the_walk"]["screenshot"]
    if shot:
        lines.append(f"screenshot: {shot}")
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    rows = []
    for key, where in (("beside_the_walk", "beside a real-time walk"), ("in_the_walks_process", "in the walk's process")):
        latency, updates, listener, _without, with_view, *_ = _rows(r[key], r["goals"])
        rows += [(f"{where}: {latency[0]}", latency[1], latency[2]), (f"{where}: {updates[0]}", updates[1], updates[2]),
                 (f"{where}: {listener[0]}", listener[1], listener[2]),
                 (f"{where}: controller work p99 with the view", with_view[1], with_view[2])]
    return rows
