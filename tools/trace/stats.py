"""Statistics of a trace: per CAN ID and for the whole bus, and the controller's tick as the bus saw it.

Per ID: frames, the DBC's message and sender, the period (mean, jitter as its standard
deviation, min, max) beside the DBC's cycle time, frames lost according to alive-counter gaps,
CRC errors and every other rejection by reason, first and last timestamps. For the bus: its
load at a bitrate (can-utils' frame lengths with worst-case bit stuffing, as ``canbusload``, and
without stuffing), averaged over the trace and in the busiest 20 ms window. From the SYNC frames:
the tick period and its jitter, ticks missed or repeated, the delay from each SYNC to the last
node frame of its tick and to the controller's first command of the tick.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable
from typing import Any

import numpy as np

from protocol.busload import frame_bits
from protocol.catalog import Catalog
from protocol.clock import TICK_MS
from tools.trace.decode import OK, Row


def _ms_summary(values_s: list[float] | np.ndarray) -> dict[str, float] | None:
    arr = np.asarray(values_s, dtype=float) * 1e3
    if arr.size == 0:
        return None
    return {"mean": round(float(arr.mean()), 4), "jitter_std": round(float(arr.std()), 4),
            "min": round(float(arr.min()), 4), "p50": round(float(np.percentile(arr, 50)), 4),
            "p99": round(float(np.percentile(arr, 99)), 4), "max": round(float(arr.max()), 4)}


class TraceStats:
    """Feed it every :class:`Row` of a trace (:meth:`add`), then read :meth:`result`."""

    def __init__(self, catalog: Catalog) -> None:
        self.catalog = catalog
        self.times: dict[int, list[float]] = defaultdict(list)
        self.status: dict[int, Counter[str]] = defaultdict(Counter)
        self.lost: Counter[int] = Counter()
        self.extended: set[int] = set()
        self.bits_worst = 0
        self.bits_nominal = 0
        self.window_bits: Counter[int] = Counter()
        self.kinds: Counter[str] = Counter()  # error, remote, FD and 29-bit frames
        self.first: float | None = None
        self.last: float | None = None
        self.frames = 0
        # the tick seen from SYNC
        sync = catalog.by_name("SYNC")
        self.sync_id, self.controller = sync.frame_id, sync.sender
        self.sync_times: list[float] = []
        self.sync_ticks: list[int] = []
        self.node_delay: list[float] = []
        self.command_delay: list[float] = []
        self._sync_at: float | None = None
        self._last_node: float | None = None
        self._commanded = False

    def add(self, row: Row) -> None:
        frame = row.frame
        ts, ident = frame.timestamp, frame.arbitration_id
        self.frames += 1
        if self.first is None:
            self.first = ts
        self.last = ts
        key = ident | (1 << 31) if frame.is_extended_id else ident
        self.times[key].append(ts)
        self.status[key][row.status] += 1
        self.lost[key] += row.lost_before
        for kind, flag in (("error_frames", frame.is_error_frame), ("remote_frames", frame.is_remote_frame),
                           ("fd_frames", frame.is_fd), ("extended_id_frames", frame.is_extended_id)):
            if flag:
                self.kinds[kind] += 1
        if not frame.is_fd and len(frame.data) <= 8:
            worst = frame_bits(len(frame.data), extended=frame.is_extended_id)
            self.bits_worst += worst
            self.bits_nominal += frame_bits(len(frame.data), extended=frame.is_extended_id, worst_case=False)
            self.window_bits[int(row.time_s * 1000 // TICK_MS)] += worst
        if row.spec is None or row.status != OK:
            return
        if ident == self.sync_id:
            self._close_tick()
            self._sync_at = ts
            self.sync_times.append(ts)
            self.sync_ticks.append(int(row.values.tick))
        elif self._sync_at is not None:
            if row.spec.sender == self.controller:
                if not self._commanded:
                    self.command_delay.append(ts - self._sync_at)
                    self._commanded = True
            elif not self._commanded:
                self._last_node = ts

    def _close_tick(self) -> None:
        if self._sync_at is not None and self._last_node is not None:
            self.node_delay.append(self._last_node - self._sync_at)
        self._last_node, self._commanded = None, False

    def _sync(self) -> dict[str, Any] | None:
        self._close_tick()
        self._sync_at = None
        if not self.sync_times:
            return None
        ticks = np.asarray(self.sync_ticks)
        steps = np.diff(ticks)
        periods = np.diff(np.asarray(self.sync_times))
        periods = periods[periods >= 0]
        return {
            "syncs": len(self.sync_times),
            "first_tick": int(ticks[0]),
            "last_tick": int(ticks[-1]),
            "ticks_missed": int(np.sum(steps[steps > 1] - 1)),
            "ticks_repeated_or_back": int(np.sum(steps <= 0)),
            "nominal_period_ms": TICK_MS,
            "period_ms": _ms_summary(periods),
            "period_error_ms": _ms_summary(np.abs(periods - TICK_MS / 1000.0)),
            "sync_to_last_node_frame_ms": _ms_summary(self.node_delay),
            "sync_to_first_command_ms": _ms_summary(self.command_delay),
        }

    def result(self, bitrate_bit_s: int) -> dict[str, Any]:
        duration = (self.last - self.first) if self.first is not None and self.last is not None else 0.0
        per_id = []
        for key in sorted(self.times):
            ident, extended = key & 0x1FFFFFFF, bool(key >> 31)
            times = np.asarray(self.times[key])
            deltas = np.diff(times)
            deltas = deltas[deltas >= 0]
            spec = None if extended else self.catalog.by_id(ident)
            statuses = self.status[key]
            per_id.append({
                "id": f"0x{ident:08X}" if extended else f"0x{ident:03X}",
                "message": spec.name if spec else None,
                "sender": spec.sender if spec else None,
                "count": int(times.size),
                "first_timestamp": float(times[0]),
                "last_timestamp": float(times[-1]),
                "dbc_period_ms": spec.cycle_ms if spec else None,
                "period_ms": _ms_summary(deltas),
                "lost_by_counter": int(self.lost[key]),
                "crc_errors": int(statuses.get("bad_crc", 0)),
                "counter_errors": int(statuses.get("repeated_counter", 0) + statuses.get("wrong_sequence", 0)),
                "rejected_by_reason": {k: v for k, v in sorted(statuses.items()) if k != OK},
            })
        load = {}
        if duration > 0:
            peak = max(self.window_bits.values(), default=0)
            load = {
                "mean_percent_worst": round(100.0 * self.bits_worst / duration / bitrate_bit_s, 3),
                "mean_percent_nominal": round(100.0 * self.bits_nominal / duration / bitrate_bit_s, 3),
                "peak_20ms_window_percent_worst": round(100.0 * peak / (bitrate_bit_s * TICK_MS / 1000.0), 3),
            }
        totals = Counter()
        for statuses in self.status.values():
            totals.update(statuses)
        return {
            "frames": self.frames,
            "first_timestamp": self.first,
            "last_timestamp": self.last,
            "duration_s": round(duration, 6),
            "ids": len(per_id),
            "unknown_id_frames": int(totals.get("unknown_id", 0)),
            "crc_errors": int(totals.get("bad_crc", 0)),
            "counter_errors": int(totals.get("repeated_counter", 0) + totals.get("wrong_sequence", 0)),
            "lost_by_counter": int(sum(self.lost.values())),
            "rejected_by_reason": {k: int(v) for k, v in sorted(totals.items()) if k != OK},
            "frame_kinds": dict(self.kinds),
            "bus_load": {"bitrate_bit_s": bitrate_bit_s, **load},
            "tick": self._sync(),
            "per_id": per_id,
        }


def collect(rows: Iterable[Row], catalog: Catalog, bitrate_bit_s: int) -> dict[str, Any]:
    stats = TraceStats(catalog)
    for row in rows:
        stats.add(row)
    return stats.result(bitrate_bit_s)


def _fmt(summary: dict[str, float] | None, key: str = "mean") -> str:
    return "-" if summary is None else f"{summary[key]:.3f}"


def format_text(r: dict[str, Any]) -> str:
    lines = [
        f"{r['frames']} frames, {r['ids']} IDs, {r['duration_s']:.3f} s"
        + (f" (timestamps {r['first_timestamp']:.6f} .. {r['last_timestamp']:.6f})" if r["frames"] else ""),
        f"errors: {r['crc_errors']} CRC, {r['counter_errors']} counter, {r['lost_by_counter']} frames lost by counter gaps, "
        f"{r['unknown_id_frames']} unknown ID" + (f"; all rejections: {r['rejected_by_reason']}" if r["rejected_by_reason"] else ""),
    ]
    load = r["bus_load"]
    if "mean_percent_worst" in load:
        lines.append(f"bus load at {load['bitrate_bit_s'] // 1000} kbit/s: mean {load['mean_percent_worst']:.2f} % "
                     f"(no stuffing {load['mean_percent_nominal']:.2f} %), busiest 20 ms {load['peak_20ms_window_percent_worst']:.2f} %")
    tick = r["tick"]
    if tick:
        lines.append(f"tick (SYNC): {tick['syncs']} SYNCs, ticks {tick['first_tick']}..{tick['last_tick']}, "
                     f"{tick['ticks_missed']} missed, {tick['ticks_repeated_or_back']} repeated or back; period mean "
                     f"{_fmt(tick['period_ms'])} ms, jitter {_fmt(tick['period_ms'], 'jitter_std')} ms, error p99 "
                     f"{_fmt(tick['period_error_ms'], 'p99')} ms, max {_fmt(tick['period_error_ms'], 'max')} ms")
        lines.append(f"  SYNC -> last node frame p50 {_fmt(tick['sync_to_last_node_frame_ms'], 'p50')} ms, p99 "
                     f"{_fmt(tick['sync_to_last_node_frame_ms'], 'p99')} ms; SYNC -> first command p50 "
                     f"{_fmt(tick['sync_to_first_command_ms'], 'p50')} ms, p99 {_fmt(tick['sync_to_first_command_ms'], 'p99')} ms")
    lines.append(f"{'id':>5}  {'message':<22} {'sender':<11}{'count':>7} {'dbc ms':>7} {'mean ms':>9} {'jitter':>8} "
                 f"{'min':>8} {'max':>8} {'lost':>5} {'crc':>4} {'ctr':>4}")
    for e in r["per_id"]:
        p = e["period_ms"]
        lines.append(
            f"{e['id']:>5}  {e['message'] or '?':<22} {e['sender'] or '':<11}{e['count']:>7} "
            f"{e['dbc_period_ms'] if e['dbc_period_ms'] else '-':>7} {_fmt(p):>9} {_fmt(p, 'jitter_std'):>8} "
            f"{_fmt(p, 'min'):>8} {_fmt(p, 'max'):>8} {e['lost_by_counter']:>5} {e['crc_errors']:>4} {e['counter_errors']:>4}"
        )
    return "\n".join(lines) + "\n"
