"""Bits on the wire and bus load of the protocol, with can-utils' frame-length formulas.

can-utils ``canframelen.c`` (used by ``canbusload``) counts a classic frame including the 3-bit
inter-frame space. Without stuffing: 47 + 8n bits (11-bit ID), 67 + 8n (29-bit ID). Worst-case
stuffing of the stuffed region: ``(34 + 8n - 1) // 4 + 34 + 8n + 13`` (11-bit ID) and
``(54 + 8n - 1) // 4 + 54 + 8n + 13`` (29-bit ID), i.e. 55 + 10n and 80 + 10n for n <= 8.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import lcm

from protocol.catalog import Catalog, MessageSpec
from protocol.clock import TICK_MS


def frame_bits(dlc: int, *, extended: bool = False, worst_case: bool = True) -> int:
    """Bits one classic CAN data frame occupies on the bus, inter-frame space included."""
    if not 0 <= dlc <= 8:
        raise ValueError(f"classic CAN DLC must be 0..8, got {dlc}")
    data = 8 * dlc
    if extended:
        return (54 + data - 1) // 4 + 54 + data + 13 if worst_case else 67 + data
    return (34 + data - 1) // 4 + 34 + data + 13 if worst_case else 47 + data


def wire_time_ns(frames: tuple[MessageSpec, ...], bitrate_bit_s: int) -> int:
    """How long ``frames`` take on the bus one after another, worst-case stuffing."""
    return sum(frame_bits(m.dlc) for m in frames) * 1_000_000_000 // bitrate_bit_s


@dataclass(frozen=True)
class TickLoad:
    """Frames and bits of one controller tick."""

    tick: int
    frames: tuple[MessageSpec, ...]
    bits_worst: int
    bits_nominal: int

    def percent(self, bitrate_bit_s: int, *, worst_case: bool = True) -> float:
        capacity = bitrate_bit_s * TICK_MS / 1000
        return 100.0 * (self.bits_worst if worst_case else self.bits_nominal) / capacity


def tick_load(catalog: Catalog, tick: int, extra: tuple[MessageSpec, ...] = ()) -> TickLoad:
    frames = catalog.cyclic_in_tick(tick) + extra
    return TickLoad(
        tick=tick,
        frames=frames,
        bits_worst=sum(frame_bits(m.dlc) for m in frames),
        bits_nominal=sum(frame_bits(m.dlc, worst_case=False) for m in frames),
    )


def hyperperiod_ticks(catalog: Catalog) -> int:
    """Ticks after which the cyclic schedule repeats."""
    periods = [m.period_ticks for m in catalog.messages if m.period_ticks]
    return lcm(*periods) if periods else 1


def busiest_tick(catalog: Catalog) -> TickLoad:
    """The tick of the schedule with the most bits on the wire (worst-case stuffing)."""
    loads = [tick_load(catalog, t) for t in range(hyperperiod_ticks(catalog))]
    return max(loads, key=lambda load: (load.bits_worst, -load.tick))


def event_burst(catalog: Catalog) -> tuple[MessageSpec, ...]:
    """Every event (non-cyclic) message once: NMT command and one EMCY per node."""
    return tuple(m for m in catalog.messages if not m.is_cyclic)


def mean_load_bits_per_s(catalog: Catalog, *, worst_case: bool = True) -> float:
    """Average bits per second of the cyclic schedule."""
    total = 0.0
    for m in catalog.messages:
        if m.cycle_ms:
            total += frame_bits(m.dlc, worst_case=worst_case) * 1000.0 / m.cycle_ms
    return total


def load_report(catalog: Catalog, bitrates: tuple[int, ...] = (500_000, 1_000_000)) -> dict:
    """Bus-load figures of the protocol at the given bitrates (a plain dict, ready for JSON)."""
    busiest = busiest_tick(catalog)
    burst = tick_load(catalog, busiest.tick, event_burst(catalog))
    mean_worst = mean_load_bits_per_s(catalog)
    mean_nominal = mean_load_bits_per_s(catalog, worst_case=False)
    return {
        "tick_ms": TICK_MS,
        "formula": "can-utils canframelen: worst = (34+8n-1)//4 + 34+8n + 13, nominal = 47+8n (11-bit ID, incl. 3-bit IFS)",
        "busiest_tick": {
            "tick_in_schedule": busiest.tick,
            "hyperperiod_ticks": hyperperiod_ticks(catalog),
            "frames": len(busiest.frames),
            "messages": [m.name for m in busiest.frames],
            "bits_worst": busiest.bits_worst,
            "bits_nominal": busiest.bits_nominal,
        },
        "busiest_tick_with_event_burst": {
            "frames": len(burst.frames),
            "events": [m.name for m in event_burst(catalog)],
            "bits_worst": burst.bits_worst,
        },
        "bitrates": {
            str(rate): {
                "busiest_tick_percent_worst": round(busiest.percent(rate), 2),
                "busiest_tick_percent_nominal": round(busiest.percent(rate, worst_case=False), 2),
                "busiest_tick_with_event_burst_percent_worst": round(burst.percent(rate), 2),
                "mean_percent_worst": round(100.0 * mean_worst / rate, 2),
                "mean_percent_nominal": round(100.0 * mean_nominal / rate, 2),
            }
            for rate in bitrates
        },
    }
