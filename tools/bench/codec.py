"""Encode plus decode of one full tick's frames: our compiled codec against cantools, in one run.

The tick is the protocol's busiest 20 ms tick (every cyclic frame of that tick). Values are
random but valid (seeded), a fresh set per tick from a pool. Measured, per tick:

* ``ours``: :meth:`Codec.encode` and :meth:`Codec.decode` (ID, DLC, CRC-8, range checks);
* ``ours_e2e``: the process's real paths, :class:`Transmitter` (alive counters) and
  :class:`Receiver` (adds counter checks and rejection counting);
* ``cantools``: ``Database.encode_message`` / ``decode_message`` (the generic DBC codec);
* ``cantools_crc``: cantools plus the same CRC-8 computed and checked in Python: the work a
  cantools user needs for the same protection.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
from typing import Any, Callable

import numpy as np

from protocol.busload import busiest_tick, load_report
from protocol.catalog import DBC_PATH
from protocol.clock import MonotonicClock
from protocol.codec import Codec
from protocol.crc import crc8
from protocol.e2e import Receiver, Transmitter
from protocol.synthetic import random_record

GOAL_US_PER_TICK = 100.0
GOAL_SPEEDUP = 10.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ticks", type=int, default=2000, help="ticks per timed repeat (default 2000)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats per variant (default 5)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the random signal values")


def _time_per_tick_us(fn: Callable[[int], None], ticks: int, repeats: int) -> dict[str, float]:
    clock = MonotonicClock()
    fn(min(ticks, 200))  # warm-up
    samples = []
    for _ in range(repeats):
        start = clock.now_ns()
        fn(ticks)
        samples.append((clock.now_ns() - start) / 1000 / ticks)
    return {"median": round(statistics.median(samples), 3), "best": round(min(samples), 3)}


def run(args: argparse.Namespace) -> dict[str, Any]:
    import cantools

    if args.ticks < 1 or args.repeats < 1:
        raise SystemExit("aider-exo: error: --ticks and --repeats must be positive")
    codec = Codec()
    frames = busiest_tick(codec.catalog).frames
    rng = np.random.default_rng(args.seed)
    pool = 64
    records = [[random_record(m, rng) for m in frames] for _ in range(pool)]
    # Every tick's frames, encoded once with consecutive counters (decode benches read these).
    tx = Transmitter(codec)
    sequence = [[tx.payload(m, rec) for m, rec in zip(frames, records[t % pool])] for t in range(args.ticks)]

    db = cantools.database.load_file(str(DBC_PATH), database_format="dbc")
    ids = [m.frame_id for m in frames]
    cantools_dicts = [
        [dict(rec._asdict(), e2e_crc=data[0], e2e_counter=data[1] & 0xF) for rec, data in zip(records[t], sequence[t])]
        for t in range(pool)
    ]
    # The baseline must produce the very same bytes and values, or the comparison is meaningless.
    for t in range(pool):
        for fid, d, data, rec in zip(ids, cantools_dicts[t], sequence[t], records[t]):
            assert db.encode_message(fid, d) == data, f"cantools encodes {fid:#x} differently"
            decoded = db.decode_message(fid, data, decode_choices=False)
            assert all(abs(decoded[k] - v) < 1e-9 for k, v in rec._asdict().items())

    specs = list(frames)

    def ours_encode(n: int) -> None:
        for t in range(n):
            recs = records[t % pool]
            for m, rec in zip(specs, recs):
                codec.encode(m, rec, t)

    def ours_decode(n: int) -> None:
        for t in range(n):
            for fid, data in zip(ids, sequence[t]):
                codec.decode(fid, data)

    def e2e_encode(n: int) -> None:
        sender = Transmitter(codec)
        for t in range(n):
            for m, rec in zip(specs, records[t % pool]):
                sender.payload(m, rec)

    receiver = Receiver(codec, max_delta_counter=2)

    def e2e_decode(n: int) -> None:
        receiver.reset()
        for t in range(n):
            for fid, data in zip(ids, sequence[t]):
                receiver.receive_data(fid, data)

    def cantools_encode(n: int) -> None:
        for t in range(n):
            for fid, d in zip(ids, cantools_dicts[t % pool]):
                db.encode_message(fid, d)

    def cantools_decode(n: int) -> None:
        for t in range(n):
            for fid, data in zip(ids, sequence[t]):
                db.decode_message(fid, data)

    seeds = [m.crc_seed for m in specs]

    def cantools_crc_encode(n: int) -> None:
        for t in range(n):
            for fid, seed, d in zip(ids, seeds, cantools_dicts[t % pool]):
                data = bytearray(db.encode_message(fid, d))
                data[0] = crc8(seed, memoryview(data)[1:])

    def cantools_crc_decode(n: int) -> None:
        for t in range(n):
            for fid, seed, data in zip(ids, seeds, sequence[t]):
                if crc8(seed, memoryview(data)[1:]) == data[0]:
                    db.decode_message(fid, data)

    variants = {
        "ours": (ours_encode, ours_decode),
        "ours_e2e": (e2e_encode, e2e_decode),
        "cantools": (cantools_encode, cantools_decode),
        "cantools_crc": (cantools_crc_encode, cantools_crc_decode),
    }
    results: dict[str, Any] = {}
    for name, (enc, dec) in variants.items():
        e = _time_per_tick_us(enc, args.ticks, args.repeats)
        d = _time_per_tick_us(dec, args.ticks, args.repeats)
        results[name] = {
            "encode_us_per_tick": e,
            "decode_us_per_tick": d,
            "total_us_per_tick": {k: round(e[k] + d[k], 3) for k in e},
        }
    if receiver.stats.rejected_total or receiver.stats.lost:
        raise AssertionError(f"the receiver rejected benchmark frames: {receiver.stats.as_dict()}")
    ours_total = results["ours"]["total_us_per_tick"]["median"]
    e2e_total = results["ours_e2e"]["total_us_per_tick"]["median"]
    report = load_report(codec.catalog)
    return {
        "benchmark": "codec",
        "frames_per_tick": len(frames),
        "messages": [m.name for m in frames],
        "ticks_per_repeat": args.ticks,
        "repeats": args.repeats,
        "results": results,
        "speedup": {
            "ours_vs_cantools": round(results["cantools"]["total_us_per_tick"]["median"] / ours_total, 2),
            "ours_vs_cantools_crc": round(results["cantools_crc"]["total_us_per_tick"]["median"] / ours_total, 2),
            "ours_e2e_vs_cantools_crc": round(results["cantools_crc"]["total_us_per_tick"]["median"] / e2e_total, 2),
        },
        "goals": {
            "us_per_tick_max": GOAL_US_PER_TICK,
            "speedup_vs_cantools_min": GOAL_SPEEDUP,
            "bus_load_500k_percent_max": 25.0,
        },
        "bus_load_busiest_tick_percent_worst": {
            rate: f["busiest_tick_percent_worst"] for rate, f in report["bitrates"].items()
        },
        "machine": {
            "python": platform.python_version(),
            "implementation": platform.python_implementation(),
            "cpu_count": os.cpu_count(),
            "processor": platform.processor() or platform.machine(),
        },
    }


def format_text(r: dict[str, Any]) -> str:
    lines = [
        f"codec benchmark: encode + decode of one full tick ({r['frames_per_tick']} frames), "
        f"{r['repeats']} x {r['ticks_per_repeat']} ticks, median (best) us per tick",
        f"{'variant':<14}{'encode':>18}{'decode':>18}{'total':>18}",
    ]
    for name, res in r["results"].items():
        cells = [f"{res[k]['median']:.1f} ({res[k]['best']:.1f})" for k in ("encode_us_per_tick", "decode_us_per_tick", "total_us_per_tick")]
        lines.append(f"{name:<14}" + "".join(f"{c:>18}" for c in cells))
    s = r["speedup"]
    lines += [
        f"speed-up: ours {s['ours_vs_cantools']:.1f}x cantools, {s['ours_vs_cantools_crc']:.1f}x cantools+CRC; "
        f"ours with counters {s['ours_e2e_vs_cantools_crc']:.1f}x cantools+CRC "
        f"(goal {r['goals']['speedup_vs_cantools_min']:.0f}x)",
        f"goal: at most {r['goals']['us_per_tick_max']:.0f} us per tick; ours "
        f"{r['results']['ours']['total_us_per_tick']['median']:.1f} us, with counters "
        f"{r['results']['ours_e2e']['total_us_per_tick']['median']:.1f} us",
        "bus load of the busiest tick (worst-case stuffing): "
        + ", ".join(f"{int(rate) // 1000} kbit/s {pct:.2f} %" for rate, pct in r["bus_load_busiest_tick_percent_worst"].items()),
    ]
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    res, s, g = r["results"], r["speedup"], r["goals"]
    load = r["bus_load_busiest_tick_percent_worst"]
    return [
        (f"encode + decode of the busiest tick ({r['frames_per_tick']} frames): ours, ours with counters, cantools, cantools with CRC",
         ", ".join(f"{res[k]['total_us_per_tick']['median']:.1f}" for k in ("ours", "ours_e2e", "cantools", "cantools_crc")) + " us",
         f"at most {g['us_per_tick_max']:.0f} us"),
        ("ours against cantools; against cantools with CRC", f"{s['ours_vs_cantools']:.1f}x; {s['ours_vs_cantools_crc']:.1f}x",
         f"at least {g['speedup_vs_cantools_min']:.0f}x"),
        ("bus load of the busiest tick (worst-case stuffing), 500 kbit/s / 1 Mbit/s",
         f"{load['500000']:.1f} % / {load['1000000']:.1f} %", f"at most {g['bus_load_500k_percent_max']:.0f} % at 500 kbit/s"),
    ]
