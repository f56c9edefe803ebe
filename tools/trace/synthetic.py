"""A lock-step trace made up from the DBC's schedule, for benchmarks and tests that need traffic
without running the simulation (never used to judge the controller).

Tick ``k``: SYNC at ``k`` x 20 ms, then the nodes' cyclic frames of the tick after ``node_delay_s``
and the controller's after ``command_delay_s``, each frame following the previous one by its
time on the wire at ``bitrate_bit_s`` (can-utils' worst-case frame length). Values are the bus
check's (every signal swept over its range), alive counters consecutive, CRCs good.
"""

from __future__ import annotations

from protocol.busload import frame_bits
from protocol.clock import TICK_MS
from protocol.codec import Codec
from protocol.e2e import Transmitter
from tools.buscheck import expected_record
from tools.trace.reader import Frame


def lockstep_frames(codec: Codec, ticks: int, *, start_s: float = 1_700_000_000.0, bitrate_bit_s: int = 1_000_000,
                    node_delay_s: float = 0.0015, command_delay_s: float = 0.0045, channel: str = "vcan0") -> list[Frame]:
    catalog = codec.catalog
    sync = catalog.by_name("SYNC")
    tx = Transmitter(codec)
    frames: list[Frame] = []
    for k in range(ticks):
        t_sync = start_s + k * TICK_MS / 1000.0
        cyclic = [m for m in catalog.cyclic_in_tick(k) if m is not sync]
        groups = ((node_delay_s, [m for m in cyclic if m.sender != sync.sender]),
                  (command_delay_s, [m for m in cyclic if m.sender == sync.sender]))
        frames.append(Frame(round(t_sync, 6), sync.frame_id, tx.payload(sync, (k,)), channel))
        for delay, specs in groups:
            t = t_sync + delay
            for spec in specs:
                frames.append(Frame(round(t, 6), spec.frame_id, tx.payload(spec, expected_record(spec, k)), channel))
                t += frame_bits(spec.dlc) / bitrate_bit_s
    return frames
