"""The compiled codec: agreement with cantools, total decoding, typed rejections, encode errors."""

from __future__ import annotations

import math

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.catalog import DBC_PATH, default_catalog
from protocol.codec import Codec, Decoded, RejectReason, Rejection
from protocol.errors import EncodeError
from tests.support.strategies import record

CATALOG = default_catalog()
CODEC = Codec(CATALOG)
DB = cantools.database.load_file(str(DBC_PATH), database_format="dbc")
MESSAGES = CATALOG.messages


@pytest.mark.parametrize("spec", MESSAGES, ids=lambda m: m.name)
@given(data=st.data(), counter=st.integers(0, 15))
@settings(max_examples=60)
def test_agrees_with_cantools_on_every_message(spec, data, counter):
    values = data.draw(record(spec))
    payload = CODEC.encode(spec, values, counter)
    assert len(payload) == spec.dlc

    # cantools, given the same signals plus our CRC and counter, builds the very same bytes ...
    theirs = DB.get_message_by_frame_id(spec.frame_id)
    signals = dict(values._asdict(), e2e_crc=payload[0], e2e_counter=counter)
    assert theirs.encode(signals, strict=True) == payload

    # ... and reads back every signal value we read.
    decoded = CODEC.decode(spec.frame_id, payload)
    assert isinstance(decoded, Decoded), decoded
    assert decoded.counter == counter
    assert decoded.values == values
    theirs_decoded = theirs.decode(payload, decode_choices=False)
    assert theirs_decoded.pop("e2e_crc") == payload[0]
    assert theirs_decoded.pop("e2e_counter") == counter
    assert theirs_decoded == values._asdict()


@given(frame_id=st.integers(0, 0x7FF), data=st.binary(min_size=0, max_size=8))
@settings(max_examples=10_000)
def test_any_frame_decodes_or_is_rejected(frame_id, data):
    result = CODEC.decode(frame_id, data)
    assert isinstance(result, (Decoded, Rejection))
    if isinstance(result, Rejection):
        assert result.reason is not RejectReason.DECODER_FAULT, result
        assert result.frame_id == frame_id and result.detail


@pytest.mark.parametrize("spec", MESSAGES, ids=lambda m: m.name)
@given(body=st.binary(min_size=8, max_size=8))
@settings(max_examples=150)
def test_frames_with_a_valid_crc_decode_to_values_in_range_or_out_of_range(spec, body):
    # Random payloads rarely pass the CRC; fix it up so the range checks are exercised too.
    data = bytearray(body[: spec.dlc])
    data[0] = _crc(spec, data)
    result = CODEC.decode(spec.frame_id, bytes(data))
    if isinstance(result, Rejection):
        assert result.reason is RejectReason.OUT_OF_RANGE
        assert result.detail.startswith(spec.name + ".")
        return
    for sig, value in zip(spec.signals, result.values):
        assert sig.minimum <= value <= sig.maximum
        if sig.choices is not None:
            assert value in sig.choices
    # Re-encoding gives the same frame, except for bits no signal uses.
    again = CODEC.encode(spec, result.values, result.counter)
    used = _used_bits_mask(spec)
    assert int.from_bytes(again, "little") == int.from_bytes(data, "little") & used | (again[0])


def _crc(spec, data) -> int:
    from protocol.crc import crc8

    return crc8(spec.crc_seed, bytes(data[1:]))


def _used_bits_mask(spec) -> int:
    mask = (1 << 12) - 1
    for sig in spec.signals:
        mask |= ((1 << sig.length) - 1) << sig.start
    return mask & ~0xFF  # byte 0 (the CRC) is compared separately


def _frame(name, **values):
    spec = CATALOG.by_name(name)
    return spec, CODEC.encode(spec, values, 5)


def test_rejections_are_typed_and_name_the_problem():
    spec, good = _frame("JOINT_STATUS_LK", drive_state=3, error_code=0, position_rad=0.5, velocity_rad_s=-1.25, torque_Nm=12.5)
    assert isinstance(CODEC.decode(spec.frame_id, good), Decoded)

    unknown = CODEC.decode(0x7FF, good)
    assert unknown.reason is RejectReason.UNKNOWN_ID

    short = CODEC.decode(spec.frame_id, good[:-1])
    assert short.reason is RejectReason.WRONG_DLC and "DLC 7, expected 8" in short.detail

    flipped = bytearray(good)
    flipped[4] ^= 0x10
    assert CODEC.decode(spec.frame_id, bytes(flipped)).reason is RejectReason.BAD_CRC

    # The same payload under another node's ID (masquerade) fails its CRC: Data IDs differ.
    other = CATALOG.by_name("JOINT_STATUS_RK")
    assert CODEC.decode(other.frame_id, good).reason is RejectReason.BAD_CRC

    # drive_state 7 is not an enumerated value: out of range, even with a good CRC.
    raw = int.from_bytes(good, "little") | (0b111 << 12)
    bad_enum = bytearray(raw.to_bytes(8, "little"))
    bad_enum[0] = _crc(spec, bad_enum)
    rejection = CODEC.decode(spec.frame_id, bytes(bad_enum))
    assert rejection.reason is RejectReason.OUT_OF_RANGE
    assert rejection.detail == "JOINT_STATUS_LK.drive_state out of range"


def test_decode_is_total_for_odd_inputs():
    for frame_id, data in [(-1, b""), (0x800, b"\x00"), (0x181, bytearray(8)), (0x181, memoryview(bytes(8))), (0x080, None)]:
        result = CODEC.decode(frame_id, data)
        assert isinstance(result, (Decoded, Rejection))


@pytest.mark.parametrize(
    "values, message",
    [
        ({"mode": 1, "position_setpoint_rad": math.nan, "velocity_ff_rad_s": 0.0, "torque_ff_Nm": 0.0, "torque_limit_Nm": 50},
         "JOINT_COMMAND_LH.position_setpoint_rad: nan is outside [-3.1416, 3.1416] rad"),
        ({"mode": 1, "position_setpoint_rad": 0.0, "velocity_ff_rad_s": math.inf, "torque_ff_Nm": 0.0, "torque_limit_Nm": 50},
         "JOINT_COMMAND_LH.velocity_ff_rad_s: inf is outside [-15, 15] rad/s"),
        ({"mode": 1, "position_setpoint_rad": 0.0, "velocity_ff_rad_s": 0.0, "torque_ff_Nm": -250.0, "torque_limit_Nm": 50},
         "JOINT_COMMAND_LH.torque_ff_Nm: -250.0 is outside [-200, 200] N.m"),
        ({"mode": 7, "position_setpoint_rad": 0.0, "velocity_ff_rad_s": 0.0, "torque_ff_Nm": 0.0, "torque_limit_Nm": 50},
         "JOINT_COMMAND_LH.mode: 7 is not one of 0 (HOLD), 1 (TRACK), 2 (QUICK_STOP), 3 (DISABLE)"),
        ({"mode": 1, "position_setpoint_rad": 0.0},
         "JOINT_COMMAND_LH: missing signals ['velocity_ff_rad_s', 'torque_ff_Nm', 'torque_limit_Nm'], unknown signals []"),
        ({"mode": 1, "position_setpoint_rad": None, "velocity_ff_rad_s": 0.0, "torque_ff_Nm": 0.0, "torque_limit_Nm": 50},
         "JOINT_COMMAND_LH: cannot encode"),
    ],
)
def test_encode_rejects_bad_values_with_one_line(values, message):
    with pytest.raises(EncodeError) as info:
        CODEC.encode("JOINT_COMMAND_LH", values, 0)
    text = str(info.value)
    assert text.startswith(message) and "\n" not in text


def test_encode_accepts_enum_members_and_sequences():
    from protocol.enums import JointMode

    spec = CATALOG.by_name("JOINT_COMMAND_RH")
    a = CODEC.encode(spec, (JointMode.TRACK, 0.25, 0.5, -3.0, 80), 9)
    b = CODEC.encode(spec.name, {"mode": 1, "position_setpoint_rad": 0.25, "velocity_ff_rad_s": 0.5,
                                 "torque_ff_Nm": -3.0, "torque_limit_Nm": 80}, 9)
    assert a == b
    with pytest.raises(EncodeError, match="expected 5 values, got 2"):
        CODEC.encode(spec, (1, 0.0), 0)



def test_the_kernel_refuses_what_it_would_read_out_of_bounds():
    """protocol/codec_kernel.py's loops read unchecked (compiled): a value sequence of another
    length, a table of another size or a DLC below 2 is refused before they run."""
    from array import array

    from protocol import codec_kernel as kernel

    spec = CODEC.spec("SYNC")
    layout = kernel.layout_of(spec)
    with pytest.raises(ValueError, match="expected 1 values, got 2"):
        kernel.encode(layout, (1, 2), 0)
    with pytest.raises(ValueError, match="needs 11 numbers"):
        kernel.Layout(spec.dlc, spec.crc_seed, spec.record, (None,), array("d", [0.0] * 5))
    with pytest.raises(ValueError, match="DLC of 2"):
        kernel.Layout(1, spec.crc_seed, spec.record, (None,), array("d", [0.0] * 11))  # a row has 11 numbers
    assert kernel.decode(layout, b"\x00") == kernel.WRONG_LENGTH  # too short to hold a CRC and a counter
