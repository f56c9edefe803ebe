"""Alive counters and the receive path: AUTOSAR-E2E-style counter checks, counted rejections."""

from __future__ import annotations

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.codec import Codec, Decoded, RejectReason, Rejection
from protocol.e2e import Receiver, Transmitter
from protocol.enums import NmtState

CODEC = Codec()
SPEC = CODEC.spec("PLANTAR_LEFT")


def frame(counter: int, heel: float = 100.0) -> bytes:
    return CODEC.encode(SPEC, (heel, 50.0), counter)


def test_counter_rules():
    rx = Receiver(CODEC, max_delta_counter=2)
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(14)), Decoded)  # first frame: any counter
    assert rx.receive_data(SPEC.frame_id, frame(14)).reason is RejectReason.REPEATED
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(15)), Decoded)
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(1)), Decoded)  # 15 -> 1: one frame lost, wraps
    assert rx.stats.lost == 1
    wrong = rx.receive_data(SPEC.frame_id, frame(5))  # jump of 4 > 2
    assert wrong.reason is RejectReason.WRONG_SEQUENCE and "counter 1 -> 5" in wrong.detail
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(6)), Decoded)  # re-synchronised
    assert rx.stats.accepted == 4
    assert rx.stats.rejected == {RejectReason.REPEATED: 1, RejectReason.WRONG_SEQUENCE: 1}
    assert rx.stats.as_dict()["rejected_by_id"] == {"0x282": 2}


def test_max_delta_one_rejects_any_gap_and_reordering():
    rx = Receiver(CODEC, max_delta_counter=1)
    rx.receive_data(SPEC.frame_id, frame(3))
    assert rx.receive_data(SPEC.frame_id, frame(5)).reason is RejectReason.WRONG_SEQUENCE
    assert rx.receive_data(SPEC.frame_id, frame(4)).reason is RejectReason.WRONG_SEQUENCE  # older frame after newer


def test_bad_crc_does_not_move_the_counter_but_out_of_range_does():
    rx = Receiver(CODEC, max_delta_counter=1)
    rx.receive_data(SPEC.frame_id, frame(0))
    corrupt = bytearray(frame(1))
    corrupt[2] ^= 0x01
    assert rx.receive_data(SPEC.frame_id, bytes(corrupt)).reason is RejectReason.BAD_CRC
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(1)), Decoded)

    from protocol.crc import crc8

    raw = int.from_bytes(frame(2), "little") | (0xFFF << 12)  # heel force 2047.5 N > 2000 N
    out_of_range = bytearray(raw.to_bytes(5, "little"))
    out_of_range[0] = crc8(SPEC.crc_seed, bytes(out_of_range[1:]))
    assert rx.receive_data(SPEC.frame_id, bytes(out_of_range)).reason is RejectReason.OUT_OF_RANGE
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(3)), Decoded)  # no gap counted
    assert rx.stats.lost == 0


def test_counters_are_per_message_and_reset_forgets_them():
    rx = Receiver(CODEC)
    other = CODEC.spec("PLANTAR_RIGHT")
    rx.receive_data(SPEC.frame_id, frame(7))
    assert isinstance(rx.receive_data(other.frame_id, CODEC.encode(other, (1.0, 2.0), 7)), Decoded)
    rx.reset(SPEC.frame_id)
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(7)), Decoded)  # a rebooted sender starts afresh


def test_a_boot_up_heartbeat_restarts_its_senders_sequence_and_nothing_else_does():
    # F23: a rebooted node's counters start again at 0; its boot-up must be seen at once, whatever
    # counter its last heartbeat had (rejected, the reboot showed only as a lost node, ticks later)
    hb = CODEC.spec("HEARTBEAT_LK")
    rx = Receiver(CODEC, max_delta_counter=3)
    assert isinstance(rx.receive_data(hb.frame_id, CODEC.encode(hb, (NmtState.OPERATIONAL, 24.0), 7)), Decoded)
    pre = rx.receive_data(hb.frame_id, CODEC.encode(hb, (NmtState.PRE_OPERATIONAL, 24.0), 0))
    assert pre.reason is RejectReason.WRONG_SEQUENCE  # counter 0 alone is no restart
    rx.reset(hb.frame_id)
    rx.receive_data(hb.frame_id, CODEC.encode(hb, (NmtState.OPERATIONAL, 24.0), 7))
    boot = rx.receive_data(hb.frame_id, CODEC.encode(hb, (NmtState.BOOT_UP, 24.0), 0))
    assert isinstance(boot, Decoded) and boot.values.nmt_state == NmtState.BOOT_UP
    assert isinstance(rx.receive_data(hb.frame_id, CODEC.encode(hb, (NmtState.PRE_OPERATIONAL, 24.0), 1)), Decoded)
    # the boot-up restarts every counter of its sender (PLANTAR_LEFT is the left knee's), no other's
    rx.receive_data(SPEC.frame_id, frame(7))
    other = CODEC.spec("PLANTAR_RIGHT")
    rx.receive_data(other.frame_id, CODEC.encode(other, (1.0, 2.0), 7))
    rx.receive_data(hb.frame_id, CODEC.encode(hb, (NmtState.BOOT_UP, 24.0), 0))
    assert isinstance(rx.receive_data(SPEC.frame_id, frame(0)), Decoded)
    assert rx.receive_data(other.frame_id, CODEC.encode(other, (1.0, 2.0), 0)).reason is RejectReason.WRONG_SEQUENCE
    # a boot-up whose counter is not 0 is not a restart
    assert rx.receive_data(hb.frame_id, CODEC.encode(hb, (NmtState.BOOT_UP, 24.0), 9)).reason is RejectReason.WRONG_SEQUENCE


def test_the_controllers_first_sync_restarts_its_sequence():
    # F22: a restarted controller's counters start again at 0; its first NMT command (the operator's
    # FAULT_RESET) has counter 0 like the last controller's only one had, and was lost as a repeat
    sync, nmt = CODEC.spec("SYNC"), CODEC.spec("NMT_COMMAND")
    rx = Receiver(CODEC, max_delta_counter=3)
    for tick in range(20):
        assert isinstance(rx.receive_data(sync.frame_id, CODEC.encode(sync, (tick,), tick % 16)), Decoded)
    assert isinstance(rx.receive_data(nmt.frame_id, CODEC.encode(nmt, (1, 0), 0)), Decoded)  # START
    assert rx.receive_data(nmt.frame_id, CODEC.encode(nmt, (130, 0), 0)).reason is RejectReason.REPEATED
    assert isinstance(rx.receive_data(sync.frame_id, CODEC.encode(sync, (0,), 0)), Decoded)  # a new controller
    assert isinstance(rx.receive_data(nmt.frame_id, CODEC.encode(nmt, (130, 0), 0)), Decoded)  # FAULT_RESET
    # only tick 0 with counter 0: a SYNC of another tick, or tick 0 out of sequence, is no start
    assert isinstance(rx.receive_data(sync.frame_id, CODEC.encode(sync, (1,), 1)), Decoded)
    assert rx.receive_data(sync.frame_id, CODEC.encode(sync, (5,), 0)).reason is RejectReason.WRONG_SEQUENCE
    assert rx.receive_data(sync.frame_id, CODEC.encode(sync, (0,), 9)).reason is RejectReason.WRONG_SEQUENCE


@pytest.mark.parametrize(
    "msg, reason",
    [
        (can.Message(arbitration_id=0x181, is_error_frame=True), RejectReason.ERROR_FRAME),
        (can.Message(arbitration_id=0x181, is_remote_frame=True, dlc=8, is_extended_id=False), RejectReason.REMOTE_FRAME),
        (can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=True), RejectReason.NOT_CLASSIC),
        (can.Message(arbitration_id=0x181, data=bytes(12), is_fd=True, is_extended_id=False), RejectReason.NOT_CLASSIC),
        (can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False), RejectReason.UNKNOWN_ID),
    ],
)
def test_non_protocol_frames_are_counted(msg, reason):
    rx = Receiver(CODEC)
    result = rx.receive(msg)
    assert isinstance(result, Rejection) and result.reason is reason
    assert rx.stats.rejected[reason] == 1


def test_transmitter_counts_per_message_and_wraps():
    tx = Transmitter(CODEC)
    rx = Receiver(CODEC, max_delta_counter=1)
    for i in range(40):
        msg = tx.message(SPEC, (float(i), 0.0))
        assert msg.arbitration_id == SPEC.frame_id and not msg.is_extended_id
        assert msg.data[1] & 0xF == i % 16
        assert isinstance(rx.receive(msg), Decoded)
    assert rx.stats.accepted == 40 and rx.stats.rejected_total == 0


def test_a_failed_encode_does_not_advance_the_counter():
    from protocol.errors import EncodeError

    tx = Transmitter(CODEC)
    tx.payload(SPEC, (1.0, 1.0))
    with pytest.raises(EncodeError):
        tx.payload(SPEC, (-1.0, 1.0))
    assert tx.payload(SPEC, (1.0, 1.0))[1] & 0xF == 1


@given(frames=st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=50))
@settings(max_examples=300)
def test_receiver_never_raises_and_counts_everything(frames):
    rx = Receiver(CODEC)
    for frame_id, data in frames:
        result = rx.receive(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
        assert isinstance(result, (Decoded, Rejection))
    assert rx.stats.accepted + rx.stats.rejected_total == len(frames)
    assert RejectReason.DECODER_FAULT not in rx.stats.rejected
