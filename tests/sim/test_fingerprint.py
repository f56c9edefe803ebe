"""The lock-step walk's fingerprint: every frame on the bus and the simulation's state, tick by tick,
hashed. A change that must not alter behaviour (a refactor, a speed-up) keeps it; a change meant to
alter the walk updates ``FINGERPRINT`` to the value the failure prints, and says so in its commit."""

from __future__ import annotations

import hashlib

from config import default_config_path, load_config
from protocol.bus import virtual_bus
from tools.pipeline import walk

#: the default configuration's 10-cycle walk, seed 0 (full3d)
FINGERPRINT = "e6ae2ba6b21f238e6fda044ef58c82329cb785b381d69240dcaef1da0d217128"


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


def test_the_lockstep_walk_is_the_recorded_one_frame_for_frame_and_state_for_state():
    fingerprint, cycles = walk_fingerprint(cycles=10, seed=0)
    assert cycles == 10
    assert fingerprint == FINGERPRINT, f"the walk changed: if that is meant, set FINGERPRINT = {fingerprint!r}"
