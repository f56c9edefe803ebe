"""The lock-step walk's fingerprint: every frame on the bus and the simulation's state, tick by tick,
hashed. A change that must not alter behaviour (a refactor, a speed-up) keeps it; a change meant to
alter the walk updates ``FINGERPRINT`` to the value the failure prints, and says so in its commit."""

from __future__ import annotations

from tests.support.fingerprint import walk_fingerprint

#: the default configuration's 10-cycle walk, seed 0 (full3d)
FINGERPRINT = "e6ae2ba6b21f238e6fda044ef58c82329cb785b381d69240dcaef1da0d217128"


def test_the_lockstep_walk_is_the_recorded_one_frame_for_frame_and_state_for_state():
    fingerprint, cycles = walk_fingerprint(cycles=10, seed=0)
    assert cycles == 10
    assert fingerprint == FINGERPRINT, f"the walk changed: if that is meant, set FINGERPRINT = {fingerprint!r}"
