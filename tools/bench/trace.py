"""Trace tool speed: decode throughput beside cantools, and replay timing beside python-can's MessageSync.

The trace is the protocol's lock-step schedule made up from the DBC (:mod:`tools.trace.synthetic`:
every cyclic frame of every tick, frames spaced by their time on a 1 Mbit/s wire, values swept
over their ranges), written as a candump log with python-can's writer. All in one run:

1. Decode, in frames per second (median of the repeats):
   * ``ours``: the trace file read and every frame decoded and checked (ID, length, CRC-8, alive
     counter, ranges: :class:`tools.trace.decode.TraceDecoder`), and the same to JSON lines;
   * ``cantools``: the same file read by python-can's ``CanutilsLogReader`` and every frame decoded
     by cantools' ``Database.decode_message`` (no CRC or counter checks), and cantools' decode of
     the same frames already in memory;
   * the two command lines on the same file, to /dev/null: ``aider-exo trace decode --format jsonl``
     and ``cantools decode`` (both include their start-up).
2. Replay onto python-can's virtual bus, ours (:func:`tools.trace.replay.replay` on the monotonic
   clock, as ``aider-exo trace replay`` runs it: 200 us of clock polling before each frame) and
   ``can.MessageSync`` on the same frames, alternating, several rounds. The error of frame ``i`` is
   ``(sent_i - sent_0) - (t_i - t_0)``, with ``sent`` the bus's own send timestamp, the same
   measure for both: p50, p99 and max of its magnitude, the median over the rounds. First at the
   normal priority, then (unless refused or ``--no-realtime``) under the controller's real-time
   set-up (``protocol.realtime.realtime_setup``: SCHED_FIFO, no deep idle states) for both. Then
   both with one 50 ms stall in the middle of the trace (a send that blocks, as a descheduled
   process would): the most frames sent within any 1 ms afterwards, against the most in any 1 ms
   of the trace itself.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np

from protocol.catalog import DBC_PATH
from protocol.clock import Clock, MonotonicClock
from protocol.codec import Codec
from tools.trace.decode import Formatter, TraceDecoder, write_jsonl
from tools.trace.reader import Frame, ReadReport, read_frames
from tools.trace.replay import ReplayOptions, replay
from tools.trace.synthetic import lockstep_frames

GOAL_DECODE_FRAMES_PER_S = 200_000
GOAL_REPLAY_P99_US = 1000.0
STALL_S = 0.05
SPIN_S = 0.0002  # as `aider-exo trace replay` (its --spin-us default)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=100_000, help="frames in the decode trace (default 100000)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats of each decode variant (default 3)")
    parser.add_argument("--cli-frames", type=int, default=100_000,
                        help="frames for the two command lines (default 100000, at most --frames; 0 skips)")
    parser.add_argument("--replay-seconds", type=float, default=2.0, help="trace time replayed by each player per round (default 2)")
    parser.add_argument("--rounds", type=int, default=3, help="replay rounds of each player (default 3)")
    parser.add_argument("--no-realtime", action="store_true",
                        help="skip the rounds under the real-time set-up (SCHED_FIFO, ...; refused steps are reported)")


def _write_log(frames: list[Frame], path: Path) -> None:
    with can.CanutilsLogWriter(str(path)) as writer:
        for frame in frames:
            writer.on_message_received(frame.to_message())


def _rate(fn: Callable[[], int], repeats: int, clock: Clock) -> dict[str, float]:
    """Frames per second of ``fn`` (which returns how many frames it did): median and best."""
    rates = []
    for _ in range(repeats):
        start = clock.now_ns()
        n = fn()
        rates.append(n / ((clock.now_ns() - start) / 1e9))
    return {"median": round(statistics.median(rates)), "best": round(max(rates))}


class _Null:
    def write(self, text: str) -> int:
        return len(text)


def _decode(n_frames: int, repeats: int, cli_frames: int, clock: Clock) -> dict[str, Any]:
    import cantools

    codec = Codec()
    frames = lockstep_frames(codec, n_frames // len(codec.catalog.cyclic_in_tick(0)) + 1)[:n_frames]
    db = cantools.database.load_file(str(DBC_PATH), database_format="dbc")
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "bench.log"
        _write_log(frames, log)

        def ours_file() -> int:
            report = ReadReport()
            n = sum(1 for _ in TraceDecoder(codec).rows(read_frames([log], report)))
            assert report.skipped == 0 and n == len(frames)
            return n

        def ours_jsonl() -> int:
            decoder = TraceDecoder(codec)
            return write_jsonl(decoder.rows(read_frames([log], ReadReport())), Formatter(codec.catalog, None), _Null(),
                               catalog=codec.catalog)

        def ours_memory() -> int:
            return sum(1 for _ in TraceDecoder(codec).rows(frames))

        def cantools_file() -> int:
            n = 0
            for msg in can.CanutilsLogReader(str(log)):
                db.decode_message(msg.arbitration_id, msg.data)
                n += 1
            return n

        def cantools_memory() -> int:
            for f in frames:
                db.decode_message(f.arbitration_id, f.data)
            return len(frames)

        # The two decoders must agree, or the comparison means nothing.
        decoder = TraceDecoder(codec)
        for row in decoder.rows(frames[:2000]):
            theirs = db.decode_message(row.frame.arbitration_id, row.frame.data, decode_choices=False)
            assert all(abs(theirs[s.name] - v) < 1e-9 for s, v in zip(row.spec.signals, row.values)), row
        assert decoder.receiver.stats.rejected_total == 0

        variants = {"ours_file": ours_file, "ours_file_to_jsonl": ours_jsonl, "ours_in_memory": ours_memory,
                    "cantools_file": cantools_file, "cantools_in_memory": cantools_memory}
        results = {name: _rate(fn, repeats, clock) for name, fn in variants.items()}
        cli = _cli(frames[:cli_frames], log if cli_frames >= len(frames) else None, Path(tmp), clock) if cli_frames > 0 else None
    return {"frames": len(frames), "repeats": repeats, "frames_per_s": results, "command_lines": cli,
            "speedup_file": round(results["ours_file"]["median"] / results["cantools_file"]["median"], 2),
            "speedup_in_memory": round(results["ours_in_memory"]["median"] / results["cantools_in_memory"]["median"], 2)}


def _cli(frames: list[Frame], log: Path | None, folder: Path, clock: Clock) -> dict[str, Any]:
    if log is None:
        log = folder / "cli.log"
        _write_log(frames, log)
    aider = str(Path(sys.executable).with_name("aider-exo"))
    commands = {
        "aider-exo trace decode --format jsonl": ([aider, "trace", "decode", "--format", "jsonl", str(log)], None),
        "cantools decode": ([sys.executable, "-m", "cantools", "decode", str(DBC_PATH)], log),
    }
    out = {}
    for name, (argv, stdin) in commands.items():
        start = clock.now_ns()
        with open(stdin or os.devnull, "rb") as src:
            subprocess.run(argv, stdin=src, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True, timeout=600)
        seconds = (clock.now_ns() - start) / 1e9
        out[name] = {"seconds": round(seconds, 3), "frames_per_s": round(len(frames) / seconds)}
    return {"frames": len(frames), "results": out}


def _errors_us(sent: list[float], original: list[float]) -> np.ndarray:
    s = np.asarray(sent) - sent[0]
    o = np.asarray(original[: len(sent)]) - original[0]
    return np.abs(s - o) * 1e6


def _summary_us(errors: np.ndarray) -> dict[str, float]:
    return {"p50": round(float(np.percentile(errors, 50)), 1), "p99": round(float(np.percentile(errors, 99)), 1),
            "max": round(float(errors.max()), 1)}


def _max_in_1ms(times: list[float]) -> int:
    t = np.sort(np.asarray(times))
    return int(np.max(np.searchsorted(t, t + 0.001, side="left") - np.arange(t.size))) if t.size else 0


PLAYERS = ("ours", "python-can MessageSync")


def _play(frames: list[Frame], player: str, stall_at: int | None, clock: Clock) -> list[float]:
    """Replay ``frames`` with ``player`` on a fresh virtual bus; the bus's send timestamps."""
    channel = f"bench-trace-{player}-{stall_at}"
    with can.Bus(interface="virtual", channel=channel, ignore_config=True) as tx, \
            can.Bus(interface="virtual", channel=channel, ignore_config=True) as rx:
        count = 0

        def send(msg: can.Message) -> None:
            nonlocal count
            if count == stall_at:
                clock.sleep_until(clock.now_ns() + int(STALL_S * 1e9))
            count += 1
            tx.send(msg)

        if player == "ours":
            replay(frames, send, clock, ReplayOptions(spin_s=SPIN_S))
        else:
            for msg in can.MessageSync([f.to_message() for f in frames], timestamps=True):
                send(msg)
        stamps = []
        while (msg := rx.recv(timeout=0.0)) is not None:
            stamps.append(msg.timestamp)
    assert len(stamps) == len(frames), (player, len(stamps))
    return stamps


def _rounds(frames: list[Frame], rounds: int, clock: Clock) -> dict[str, Any]:
    """Both players, alternating, ``rounds`` times: the median over rounds of each figure, and every round."""
    original = [f.timestamp for f in frames]
    runs: dict[str, list[dict[str, float]]] = {p: [] for p in PLAYERS}
    for _ in range(rounds):
        for player in PLAYERS:
            runs[player].append(_summary_us(_errors_us(_play(frames, player, None, clock), original)))
    return {p: {"median_of_rounds": {k: round(statistics.median(r[k] for r in rs), 1) for k in ("p50", "p99", "max")},
                "rounds": rs} for p, rs in runs.items()}


def _replay(seconds: float, rounds: int, realtime: bool, clock: Clock) -> dict[str, Any]:
    codec = Codec()
    frames = lockstep_frames(codec, max(2, round(seconds * 50)))
    result: dict[str, Any] = {"frames": len(frames), "trace_seconds": round(frames[-1].timestamp - frames[0].timestamp, 3),
                              "rounds": rounds, "normal_priority": _rounds(frames, rounds, clock)}
    short = frames[: max(2, len(frames) // 2)]
    stall_at = len(short) // 2
    stall: dict[str, Any] = {"trace_max_frames_in_1ms": _max_in_1ms([f.timestamp for f in short]), "stall_ms": STALL_S * 1e3}
    for player in PLAYERS:
        stamps = _play(short, player, stall_at, clock)
        stall[player] = {"max_frames_in_1ms_after_stall": _max_in_1ms(stamps[stall_at:])}
    result["stall"] = stall
    if realtime:
        from protocol.realtime import realtime_setup

        setup = realtime_setup(lock_memory=False)
        try:
            result["realtime"] = {"applied": setup.applied, "refused": setup.warnings, **_rounds(frames, rounds, clock)}
        finally:
            setup.close()
            try:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            except (OSError, AttributeError):
                pass
    return result


def run(args: argparse.Namespace) -> dict[str, Any]:
    from tools.trace import TraceError

    if args.frames < 1000 or args.repeats < 1 or args.rounds < 1 or args.replay_seconds <= 0 or args.cli_frames < 0:
        raise TraceError("--frames must be at least 1000; --repeats, --rounds and --replay-seconds positive")
    clock = MonotonicClock()
    decode = _decode(args.frames, args.repeats, args.cli_frames, clock)
    replay_result = _replay(args.replay_seconds, args.rounds, not args.no_realtime, clock)
    return {
        "benchmark": "trace",
        "decode": decode,
        "replay": replay_result,
        "goals": {"decode_frames_per_s_min": GOAL_DECODE_FRAMES_PER_S, "replay_p99_us_max": GOAL_REPLAY_P99_US},
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(),
                    "processor": platform.processor() or platform.machine(),
                    "load_average_1min_at_end": round(os.getloadavg()[0], 2)},
    }


def format_text(r: dict[str, Any]) -> str:
    d, rp = r["decode"], r["replay"]
    f = d["frames_per_s"]
    lines = [
        f"decode of {d['frames']} frames (candump log), frames per second, median (best) of {d['repeats']}:",
        *[f"  {name:<22}{v['median']:>10,} ({v['best']:,})" for name, v in f.items()],
        f"  ours / cantools: {d['speedup_file']:.1f}x from the file, {d['speedup_in_memory']:.1f}x in memory "
        f"(goal: at least {r['goals']['decode_frames_per_s_min']:,} frames/s; ours from the file {f['ours_file']['median']:,})",
    ]
    if d["command_lines"]:
        c = d["command_lines"]
        lines.append(f"command lines on {c['frames']} frames (start-up included): " + "; ".join(
            f"{name} {v['seconds']:.2f} s ({v['frames_per_s']:,} frames/s)" for name, v in c["results"].items()))
    lines.append(f"replay of {rp['frames']} frames ({rp['trace_seconds']:.1f} s) on the virtual bus, |timing error|, "
                 f"median of {rp['rounds']} rounds:")
    for condition in ("normal_priority", "realtime"):
        if condition not in rp:
            continue
        c = rp[condition]
        extra = f" (applied: {', '.join(c['applied'])}{'; refused: ' + '; '.join(c['refused']) if c['refused'] else ''})" if condition == "realtime" else ""
        lines.append(f"  {condition.replace('_', ' ')}{extra}:")
        for name in PLAYERS:
            e = c[name]["median_of_rounds"]
            lines.append(f"    {name:<24} p50 {e['p50']:>7.0f} us, p99 {e['p99']:>7.0f} us, max {e['max']:>7.0f} us")
    lines.append(f"  goal: p99 at most {r['goals']['replay_p99_us_max']:.0f} us (load average at the end: "
                 f"{r['machine']['load_average_1min_at_end']})")
    s = rp["stall"]
    lines.append(f"after a {s['stall_ms']:.0f} ms stall, most frames sent within 1 ms (the trace itself: {s['trace_max_frames_in_1ms']}): "
                 + ", ".join(f"{name} {s[name]['max_frames_in_1ms_after_stall']}" for name in PLAYERS))
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    f, rp, g = r["decode"]["frames_per_s"], r["replay"], r["goals"]

    def p99(condition: str) -> str:
        return " / ".join(f"{rp[condition][name]['median_of_rounds']['p99']:.0f}" for name in PLAYERS) + " us"

    rows = [("decode from a file, ours / cantools", f"{f['ours_file']['median']:,} / {f['cantools_file']['median']:,} frames/s",
             f"at least {g['decode_frames_per_s_min']:,} frames/s")]
    for condition, title in (("normal_priority", ""), ("realtime", ", with the real-time set-up")):
        if condition in rp:
            rows.append((f"replay timing error (absolute) p99, ours / python-can MessageSync{title}", p99(condition),
                         f"at most {g['replay_p99_us_max']:.0f} us"))
    return rows
