"""Fuzzing the controller's receive path (docs/FAULTS.md F10, issue 9): 100,000 random frames go onto the
bus while the controller walks the HHEA with its nodes, through the real loop (python-can bus,
E2E receiver, node supervision, estimator, FSM, envelope), and the invariants I1-I7 hold on every
tick (tools/safety/oracle.py); no exception escapes.

The frames are a seeded mix, so that they reach past the CRC too:

* any 11-bit ID with any length and bytes (almost all unknown IDs or wrong lengths);
* our nodes' IDs with the right length and random bytes (the CRC rejects them);
* our nodes' IDs with random bytes under a good CRC for the ID's Data-ID: random values, in
  range or not, random counters (the receiver's sequence check and the controller's plausibility
  checks meet them: joint limits, drive states, tilt);
* extended, remote and error frames.

The operator resets every 100 ticks, so the controller leaves FAULT whenever the reset's
preconditions hold and is attacked in every state it reaches.
"""

from __future__ import annotations

import can
import numpy as np

from config import default_config_path, load_config
from protocol.codec import Codec
from protocol.crc import crc8
from protocol.enums import GaitState
from tools.safety.rig import FaultRig

CFG = load_config(default_config_path())
FRAMES = 100_000
PER_TICK = 50


def random_frames(rng: np.random.Generator, n: int, catalog) -> list[can.Message]:
    nodes = [m for m in catalog.messages if m.sender != "CONTROLLER"]
    kinds = rng.choice(4, size=n, p=[0.4, 0.25, 0.25, 0.1])
    out = []
    for kind in kinds.tolist():
        if kind == 0:
            dlc = int(rng.integers(0, 9))
            out.append(can.Message(arbitration_id=int(rng.integers(0, 0x800)), data=rng.bytes(dlc), is_extended_id=False))
        elif kind in (1, 2):
            spec = nodes[int(rng.integers(len(nodes)))]
            data = bytearray(rng.bytes(spec.dlc))
            if kind == 2:
                data[0] = crc8(spec.crc_seed, bytes(data[1:]))
            out.append(can.Message(arbitration_id=spec.frame_id, data=data, is_extended_id=False))
        else:
            choice = int(rng.integers(3))
            if choice == 0:
                out.append(can.Message(arbitration_id=int(rng.integers(0, 2**29)), data=rng.bytes(8), is_extended_id=True))
            elif choice == 1:
                out.append(can.Message(arbitration_id=int(rng.integers(0, 0x800)), is_remote_frame=True, dlc=8,
                                       is_extended_id=False))
            else:
                out.append(can.Message(arbitration_id=0x20000004, is_error_frame=True, is_extended_id=True, data=bytes(8)))
    return out


def test_a_hundred_thousand_random_frames_break_no_invariant():
    rng = np.random.default_rng(2026)
    frames = random_frames(rng, FRAMES, Codec().catalog)
    # A tick whose node frames the attack has made unacceptable waits this long for them (the
    # attack makes most ticks such ticks): short, so that the run takes seconds.
    with FaultRig(CFG, seed=11, tick_timeout_s=0.002) as rig:
        rig.operator.start()
        rig.run(60)  # standing, then walking
        states = set()
        with rig.foreign() as intruder:
            for start in range(0, FRAMES, PER_TICK):
                for msg in frames[start:start + PER_TICK]:
                    intruder.send(msg)
                if rig.tick % 100 == 0:
                    rig.operator.reset()
                    rig.operator.start()
                rig.step()
                states.add(rig.state)
        stats = rig.hardware.rx.stats
        assert rig.oracle.violations == [], rig.oracle.violations[:10]
        assert rig.oracle.ticks == 60 + FRAMES // PER_TICK
        # Every frame went through the receive path: the intruder's all rejected or (a good CRC
        # with a counter in sequence by chance) accepted, and counted.
        assert stats.rejected_total + stats.accepted >= FRAMES
        assert stats.rejected_total >= 0.9 * FRAMES
        reasons = {r.value for r in stats.rejected}
        assert {"unknown_id", "wrong_dlc", "bad_crc", "error_frame", "remote_frame", "not_classic_frame"} <= reasons, reasons
        assert "decoder_fault" not in reasons
        assert GaitState.FAULT in states  # the attack is seen as one
