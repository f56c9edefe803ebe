"""The fault-injecting bus wrapper (protocol/faultbus.py) on the in-process virtual bus: each kind
does what it says to exactly the frames its rule names, ticks follow the wrapped side's SYNCs, and
a seed makes a run repeatable."""

from __future__ import annotations

import can
import numpy as np
import pytest

from protocol.bus import virtual_bus
from protocol.codec import Codec, Decoded, RejectReason, Rejection
from protocol.e2e import Receiver, Transmitter
from protocol.faultbus import BusFault, FaultBus, ids_of

CODEC = Codec()
SYNC = CODEC.spec("SYNC").frame_id
STATUS = CODEC.spec("JOINT_STATUS_LH").frame_id
OTHER = CODEC.spec("JOINT_STATUS_RK").frame_id


@pytest.fixture
def rig(request):
    """(peer, wrap): ``peer`` is the far end; ``wrap(*faults, seed=0)`` our end with the rules."""
    channel = f"faultbus-{request.node.name}"
    peer = virtual_bus(channel)
    opened = [peer]

    def wrap(*faults: BusFault, seed: int = 0) -> FaultBus:
        bus = FaultBus(virtual_bus(channel), faults, rng=np.random.default_rng(seed))
        opened.append(bus)
        return bus

    yield peer, wrap
    for b in opened:
        b.shutdown()


def frame(frame_id: int, n: int) -> can.Message:
    return can.Message(arbitration_id=frame_id, data=bytes([n, 0, 0, 0, 0, 0, 0, 0]), is_extended_id=False)


def received(bus: can.BusABC) -> list[tuple[int, int]]:
    out = []
    while (m := bus.recv(timeout=0)) is not None:
        out.append((m.arbitration_id, m.data[0]) if not m.is_error_frame else ("error", 0))
    return out


def sync(bus: FaultBus) -> None:
    """The SYNC of the wrapped side's next tick (its bytes differ from the last one's)."""
    bus.send(can.Message(arbitration_id=SYNC, data=(bus.tick + 1).to_bytes(5, "little"), is_extended_id=False))


def test_a_resent_sync_is_the_same_tick(rig):
    _, wrap = rig
    bus = wrap()
    sync(bus)
    bus.send(can.Message(arbitration_id=SYNC, data=(0).to_bytes(5, "little"), is_extended_id=False))  # a retry
    assert bus.tick == 0
    sync(bus)
    assert bus.tick == 1


def statuses(got: list, frame_id: int = STATUS) -> list[int]:
    return [n for i, n in got if i == frame_id]


def test_a_drop_burst_loses_exactly_that_many_frames_of_the_named_id(rig):
    peer, wrap = rig
    bus = wrap(BusFault("drop", frame_ids={STATUS}, start_tick=1, end_tick=2, burst=3, times=1, name="burst"))
    got = []
    for n in range(8):
        sync(bus)  # tick n
        peer.send(frame(STATUS, n))
        peer.send(frame(OTHER, n))
        got += received(bus)  # rx rules apply at the tick a frame is read in
    assert statuses(got) == [0, 4, 5, 6, 7]  # fires at tick 1; the burst runs on past the window
    assert statuses(got, OTHER) == list(range(8))
    assert bus.injected == {"burst:drop": 3}


def test_a_dropped_frame_does_not_make_a_poll_return_nothing(rig):
    peer, wrap = rig
    bus = wrap(BusFault("drop", frame_ids={STATUS}))
    peer.send(frame(STATUS, 1))
    peer.send(frame(OTHER, 2))
    assert bus.recv(timeout=0).arbitration_id == OTHER  # not None while a frame is waiting


def test_delay_releases_a_frame_when_its_tick_begins(rig):
    peer, wrap = rig
    bus = wrap(BusFault("delay", frame_ids={STATUS}, start_tick=0, end_tick=1, delay_ticks=2))
    sync(bus)  # tick 0
    peer.send(frame(STATUS, 0))
    peer.send(frame(OTHER, 0))
    assert received(bus) == [(OTHER, 0)]
    sync(bus)  # tick 1
    peer.send(frame(STATUS, 1))
    assert received(bus) == [(STATUS, 1)]
    sync(bus)  # tick 2: the frame of tick 0 comes before the frames of tick 2
    peer.send(frame(STATUS, 2))
    assert received(bus) == [(STATUS, 0), (STATUS, 2)]


def test_duplicate_and_reorder(rig):
    peer, wrap = rig
    bus = wrap(BusFault("duplicate", frame_ids={OTHER}), BusFault("reorder", frame_ids={STATUS}, times=1))
    for n in range(3):
        peer.send(frame(STATUS, n))
        peer.send(frame(OTHER, n))
    got = received(bus)
    assert statuses(got) == [1, 0, 2]  # the first swapped with the next of its ID
    assert statuses(got, OTHER) == [0, 0, 1, 1, 2, 2]


def test_corrupt_flips_the_given_number_of_bits_and_the_crc_catches_it(rig):
    peer, wrap = rig
    bus = wrap(BusFault("corrupt", frame_ids={STATUS}, bits=3), seed=7)
    tx, rx = Transmitter(CODEC), Receiver(CODEC)
    values = {"position_rad": 0.25, "velocity_rad_s": 0.0, "torque_Nm": 1.0, "drive_state": 1, "error_code": 0}
    sent = tx.message("JOINT_STATUS_LH", values)
    peer.send(sent)
    got = bus.recv(timeout=0)
    flipped = sum(bin(a ^ b).count("1") for a, b in zip(sent.data, got.data))
    assert flipped == 3 and len(got.data) == len(sent.data)
    result = rx.receive(got)
    assert isinstance(result, Rejection) and result.reason == RejectReason.BAD_CRC
    assert isinstance(rx.receive(tx.message("JOINT_STATUS_LH", values)), Decoded)  # the next good frame passes


def test_truncate_and_masquerade_are_caught_by_length_and_data_id(rig):
    peer, wrap = rig
    knee = CODEC.spec("JOINT_STATUS_LK").frame_id
    bus = wrap(BusFault("truncate", frame_ids={STATUS}, times=1), BusFault("masquerade", frame_ids={OTHER}, to_id=knee, times=1))
    tx, rx = Transmitter(CODEC), Receiver(CODEC)
    values = {"position_rad": 0.25, "velocity_rad_s": 0.0, "torque_Nm": 1.0, "drive_state": 1, "error_code": 0}
    peer.send(tx.message("JOINT_STATUS_LH", values))
    peer.send(tx.message("JOINT_STATUS_RK", values))
    short, masked = bus.recv(timeout=0), bus.recv(timeout=0)
    assert len(short.data) == 7 and rx.receive(short).reason == RejectReason.WRONG_DLC
    assert masked.arbitration_id == knee and rx.receive(masked).reason == RejectReason.BAD_CRC  # RK's Data-ID in its CRC
    with pytest.raises(ValueError, match="to_id"):
        BusFault("masquerade")


def test_error_frames_come_before_the_frame(rig):
    peer, wrap = rig
    bus = wrap(BusFault("error_frame", frame_ids={STATUS}, burst=2, times=1))
    peer.send(frame(STATUS, 5))
    peer.send(frame(STATUS, 6))
    assert received(bus) == [("error", 0), ("error", 0), (STATUS, 5), (STATUS, 6)]
    assert Receiver(CODEC).receive(can.Message(is_error_frame=True, arbitration_id=0x20000004, is_extended_id=True)).reason \
        == RejectReason.ERROR_FRAME


def test_send_failure_raises_and_sends_nothing_and_tx_rules_follow_the_ticks(rig):
    peer, wrap = rig
    bus = wrap(BusFault("send_failure", "tx", frame_ids={OTHER}, start_tick=1, end_tick=2),
               BusFault("delay", "tx", frame_ids={STATUS}, start_tick=0, end_tick=1))
    sync(bus)  # tick 0
    bus.send(frame(STATUS, 0))
    bus.send(frame(OTHER, 0))
    sync(bus)  # tick 1: the delayed frame goes out after this SYNC
    with pytest.raises(can.CanOperationError, match="injected send failure"):
        bus.send(frame(OTHER, 1))
    got = [(i, n) for i, n in received(peer) if i != SYNC]
    assert got == [(OTHER, 0), (STATUS, 0)]
    assert bus.tick == 1


def test_a_seed_repeats_a_run_and_another_seed_does_not(rig):
    peer, wrap = rig

    def run(seed: int) -> list:
        bus = wrap(BusFault("drop", probability=0.3), BusFault("duplicate", probability=0.2), seed=seed)
        for n in range(200):
            peer.send(frame(STATUS, n % 256))
        out = received(bus)
        bus.shutdown()
        return out

    a, b, c = run(1), run(1), run(2)
    assert a == b and a != c
    assert 100 < len(a) < 200  # about 0.7 kept, some of them twice


@pytest.mark.parametrize("kwargs, message", [
    ({"kind": "explode"}, "kind must be one of"),
    ({"kind": "drop", "direction": "up"}, "direction must be rx or tx"),
    ({"kind": "send_failure"}, "applies to sent frames"),
    ({"kind": "drop", "probability": 0.0}, "probability must be in"),
    ({"kind": "drop", "burst": 0}, "at least 1"),
    ({"kind": "drop", "start_tick": 5, "end_tick": 5}, "must be after start_tick"),
])
def test_an_invalid_rule_is_one_line_naming_it(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        BusFault(name="r1", **kwargs)
    assert "r1" in str(err.value) and "\n" not in str(err.value)


def test_ids_of_names_messages_by_the_dbc():
    assert ids_of(CODEC.catalog, ["SYNC", "JOINT_STATUS_LH"]) == {SYNC, STATUS}
