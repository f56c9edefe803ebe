"""CRC-8 against an independent implementation, and the catalogue's rules on the DBC."""

from __future__ import annotations

from pathlib import Path

import pytest
from crccheck.crc import Crc8SaeJ1850
from hypothesis import given
from hypothesis import strategies as st

from protocol.catalog import DBC_PATH, default_catalog, load_catalog
from protocol.crc import crc8, crc8_plain, seed_for_data_id
from protocol.errors import ProtocolError

CATALOG = default_catalog()


def test_crc8_check_value():
    assert crc8_plain(b"123456789") == 0x4B


@given(data_id=st.integers(0, 0xFFFF), payload=st.binary(max_size=8))
def test_crc8_matches_crccheck_over_data_id_and_payload(data_id, payload):
    expected = Crc8SaeJ1850.calc(bytes([data_id & 0xFF, data_id >> 8]) + payload)
    assert crc8(seed_for_data_id(data_id), payload) == expected


def test_every_message_has_a_distinct_crc_seed_and_data_id():
    seeds = [m.crc_seed for m in CATALOG.messages]
    assert len(set(seeds)) == len(seeds)
    assert len({m.data_id for m in CATALOG.messages}) == len(CATALOG.messages)


def test_catalogue_covers_the_system():
    names = {m.name for m in CATALOG.messages}
    for suffix in ("LH", "LK", "RH", "RK"):
        for family in ("JOINT_COMMAND", "JOINT_STATUS", "HEARTBEAT", "EMCY"):
            assert f"{family}_{suffix}" in names
    assert {"SYNC", "NMT_COMMAND", "CONTROLLER_HEARTBEAT", "STICK_LEFT", "STICK_RIGHT", "PLANTAR_LEFT",
            "PLANTAR_RIGHT", "TRUNK_IMU_ORIENTATION", "TRUNK_IMU_RATE", "TRUNK_IMU_ACCEL"} <= names
    assert CATALOG.node_ids == {"CONTROLLER": 16, "LEFT_HIP": 1, "LEFT_KNEE": 2, "RIGHT_HIP": 3, "RIGHT_KNEE": 4}
    for m in CATALOG.messages:
        if m.family in ("JOINT_STATUS", "STICK", "PLANTAR", "TRUNK_IMU_ORIENTATION", "TRUNK_IMU_RATE", "TRUNK_IMU_ACCEL"):
            assert m.cycle_ms == 20 and m.sender != "CONTROLLER"


def test_scalings_beat_the_sensors_and_ranges_have_margin():
    checked = 0
    for m in CATALOG.messages:
        for s in m.signals:
            # the representable raw range reaches beyond the physical range at both ends (or is exactly full)
            assert s.raw_min_representable <= s.raw_min and s.raw_max <= s.raw_max_representable
            if s.sensor_resolution is not None:
                checked += 1
                assert s.scale < s.sensor_resolution, f"{m.name}.{s.name}"
                assert s.raw_min_representable < s.raw_min or s.minimum == 0
                assert s.raw_max < s.raw_max_representable, f"{m.name}.{s.name}"
    assert checked >= 30


def test_heartbeats_are_spread_over_their_period():
    phases = sorted(m.tick_phase for m in CATALOG.messages if m.family in ("HEARTBEAT", "CONTROLLER_HEARTBEAT"))
    assert phases == [0, 1, 2, 3, 4]


def _broken(tmp_path: Path, old: str, new: str) -> Path:
    text = DBC_PATH.read_text()
    assert old in text
    path = tmp_path / "broken.dbc"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    "old, new, message",
    [
        (" SG_ e2e_counter : 8|4@1+", " SG_ e2e_counter : 9|3@1+", "NMT_COMMAND: every message must carry unsigned e2e_counter at bit 8, 4 bits"),
        ("position_rad : 20|16@1- (0.0001,0) [-3.1416|3.1416]", "position_rad : 20|16@1- (0.0001,0) [-3.14165|3.1416]",
         "JOINT_STATUS_LH.position_rad: minimum -3.14165 is not a multiple of the scale 0.0001"),
        ("torque_limit_Nm : 56|8@1+ (1,0) [0|200]", "torque_limit_Nm : 56|8@1+ (1,0) [0|300]",
         "JOINT_COMMAND_LH.torque_limit_Nm: range [0, 300] needs raw [0, 300], beyond what 8 unsigned bits hold"),
        ('BA_ "AiderDataId" BO_ 128 577;', 'BA_ "AiderDataId" BO_ 128 321;', "gives the same CRC seed as NMT_COMMAND"),
        ('VAL_ 513 mode 0 "HOLD" 1 "TRACK" 2 "QUICK_STOP" 3 "DISABLE" ;', 'VAL_ 513 mode 0 "HOLD" 1 "TRACK" 2 "QUICK_STOP" 3 "OFF" ;',
         "JOINT_COMMAND_LH.mode: DBC values"),
        ('BA_ "GenMsgCycleTime" BO_ 1793 100;', 'BA_ "GenMsgCycleTime" BO_ 1793 30;', "HEARTBEAT_LH: a cyclic message needs a cycle time"),
    ],
)
def test_a_dbc_that_breaks_the_rules_fails_at_load_naming_the_signal(tmp_path, old, new, message):
    with pytest.raises(ProtocolError) as info:
        load_catalog(_broken(tmp_path, old, new))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_missing_or_garbage_dbc(tmp_path):
    with pytest.raises(ProtocolError, match="no such DBC file"):
        load_catalog(tmp_path / "nope.dbc")
    garbage = tmp_path / "garbage.dbc"
    garbage.write_text("BO_ this is not a DBC")
    with pytest.raises(ProtocolError, match="not a valid DBC file"):
        load_catalog(garbage)


def test_joint_nodes_and_their_messages_come_from_the_dbc():
    from protocol.catalog import default_catalog
    from protocol.errors import ProtocolError

    cat = default_catalog()
    assert cat.joint_nodes == ("LEFT_HIP", "LEFT_KNEE", "RIGHT_HIP", "RIGHT_KNEE")
    assert cat.message("JOINT_COMMAND", "RIGHT_KNEE").name == "JOINT_COMMAND_RK"  # addressed to it
    assert cat.message("JOINT_STATUS", "LEFT_HIP").name == "JOINT_STATUS_LH"  # sent by it
    with pytest.raises(ProtocolError, match="no PLANTAR message of node LEFT_HIP"):
        cat.message("PLANTAR", "LEFT_HIP")
