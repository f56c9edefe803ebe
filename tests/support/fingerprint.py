"""A lock-step walk's fingerprint: every frame on the bus and the simulation's state, tick by tick,
hashed (tests/sim/test_fingerprint.py pins the default walk's; tests/sim/test_compiled.py sets the
compiled walk's beside the interpreted one's). ``python -m tests.support.fingerprint CYCLES SEED``
prints it, for a walk in another process (another environment)."""

from __future__ import annotations

import hashlib
import sys

from config import default_config_path, load_config
from protocol.bus import virtual_bus
from tools.pipeline import walk


def walk_fingerprint(*, cycles: int, seed: int) -> tuple[str, int]:
    """(SHA-256 over every frame (ID, DLC, data) and the simulation's joint positions, velocities
    and link positions after every tick, gait cycles walked) of a lock-step walk."""
    digest = hashlib.sha256()
    channel = f"aider-fingerprint-{seed}"
    with virtual_bus(channel) as sniffer:  # a third node on the channel: it hears both sides

        def on_tick(result, session, host) -> None:
            while (msg := sniffer.recv(0)) is not None:
                digest.update(msg.arbitration_id.to_bytes(4, "little") + bytes([msg.dlc]) + bytes(msg.data))
            world = host.plant.world
            for state in (world.q, world.qd, world.link_positions()):
                digest.update(state.tobytes())

        outcome = walk(load_config(default_config_path()), cycles=cycles, seed=seed, channel=channel, on_tick=on_tick,
                       compare_ratio=False)
    return digest.hexdigest(), outcome.cycles_completed


if __name__ == "__main__":
    fingerprint, cycles = walk_fingerprint(cycles=int(sys.argv[1]), seed=int(sys.argv[2]))
    print(fingerprint, cycles)
