"""Tests of the typed configuration package ``config``."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import re
from dataclasses import dataclass
from tests.conftest import ROOT
from typing import Literal, Optional

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from config import (
    AiderError,
    BusConfig,
    Config,
    ConfigError,
    FieldError,
    ProtocolConfig,
    build,
    check_schema,
    config_to_dict,
    default_config_path,
    fail,
    field_spec,
    load_as,
    load_config,
    load_yaml,
    parse_as,
    parse_config,
    parse_override,
    with_overrides,
)


VALID = """\
schema_version: 1
bus:
  interface: virtual
  channel: aider
  bitrate_bit_s: 1000000
protocol:
  max_delta_counter: 2
"""


# A small test-only schema exercising the generic machinery: floats, tuples,
# Optional, named entries and a cross-field validate().
@dataclass(frozen=True, kw_only=True)
class Window:
    min_n: int = field_spec(doc="Lower bound.", min=0)
    max_n: int = field_spec(doc="Upper bound.", min=0)
    gain: float = field_spec(doc="A gain.", min=0.0, max=10.0)
    offsets_m: tuple[float, ...] = field_spec(doc="Offsets.", unit="m", default=())
    pair: tuple[float, float] = field_spec(doc="A pair.", default=(0.0, 1.0))
    label: Optional[str] = field_spec(doc="A label.", default=None)
    mode: Literal["a", "b"] = field_spec(doc="Mode.", default="a")

    def validate(self) -> None:
        if self.min_n > self.max_n:
            fail("min_n", f"{self.min_n} must not exceed max_n ({self.max_n})")


@dataclass(frozen=True, kw_only=True)
class Patient:
    mass_kg: float = field_spec(doc="Body mass.", unit="kg", min=20.0, max=200.0)


@dataclass(frozen=True, kw_only=True)
class Root:
    window: Window = field_spec(doc="A window.")
    patients: dict[str, Patient] = field_spec(doc="Patients by name.", default_factory=dict)
    extra: Window | None = field_spec(doc="Optional section.", default=None)


ROOT_VALID = """\
window:
  min_n: 1
  max_n: 3
  gain: 2
  offsets_m: [0.5, -1, 2.5e-3]
  pair: [1.0, 2.0]
  label: left
patients:
  alice: {mass_kg: 60.5}
  bob-2: {mass_kg: 80}
"""


def _sub(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def _drop(text: str, line: str) -> str:
    return _sub(text, line + "\n", "")


# (id, schema, yaml text, expected dotted key or None, expected message part)
INVALID = [
    ("syntax-error", Config, VALID + "bus: [unclosed\n", None, "invalid YAML"),
    ("bad-indentation", Config, _sub(VALID, "  channel: aider", "   channel: aider"), None,
     "invalid YAML"),
    ("tab-indentation", Config, _sub(VALID, "  channel: aider", "\tchannel: aider"), None,
     "invalid YAML"),
    ("control-character", Config, _sub(VALID, "aider", "ai\x07der"), None,
     "unacceptable character U+0007"),
    ("two-documents", Config, VALID + "---\n" + VALID, None, "invalid YAML"),
    ("missing-key", Config, _drop(VALID, "  channel: aider"), "bus.channel",
     "missing required key"),
    ("missing-section", Config, VALID.split("protocol:")[0], "protocol", "missing required key"),
    ("missing-schema-version", Config, _drop(VALID, "schema_version: 1"), "schema_version",
     "missing required key"),
    ("wrong-type", Config, _sub(VALID, "1000000", "fast"), "bus.bitrate_bit_s",
     "expected an integer, got 'fast'"),
    ("bool-for-int", Config, _sub(VALID, "1000000", "true"), "bus.bitrate_bit_s",
     "expected an integer, got true"),
    ("float-for-int", Config, _sub(VALID, "1000000", "1.0e6"), "bus.bitrate_bit_s",
     "expected an integer, got 1000000.0"),
    ("octal-looking-int", Config, _sub(VALID, "max_delta_counter: 2", "max_delta_counter: 010"),
     "protocol.max_delta_counter", "expected an integer, got '010'"),
    ("sexagesimal-looking-int", Config, _sub(VALID, "max_delta_counter: 2",
     "max_delta_counter: 1:30"), "protocol.max_delta_counter", "expected an integer, got '1:30'"),
    ("empty-value", Config, _sub(VALID, "max_delta_counter: 2", "max_delta_counter:"),
     "protocol.max_delta_counter", "expected an integer, got null"),
    ("above-maximum", Config, _sub(VALID, "1000000", "2000000"), "bus.bitrate_bit_s",
     "2000000 is above the maximum 1000000"),
    ("below-minimum", Config, _sub(VALID, "1000000", "5000"), "bus.bitrate_bit_s",
     "5000 is below the minimum 10000"),
    ("delta-counter-zero", Config, _sub(VALID, "max_delta_counter: 2", "max_delta_counter: 0"),
     "protocol.max_delta_counter", "0 is below the minimum 1"),
    ("delta-counter-15", Config, _sub(VALID, "max_delta_counter: 2", "max_delta_counter: 15"),
     "protocol.max_delta_counter", "15 is above the maximum 14"),
    ("unknown-key", Config, _sub(VALID, "  channel:", "  chanel:"), "bus.chanel",
     "unknown key; expected one of: bitrate_bit_s, channel, interface, receive_own_messages"),
    ("unknown-section", Config, VALID + "controler: {}\n", "controler", "unknown key"),
    ("duplicate-key", Config, _sub(VALID, "  bitrate_bit_s:", "  channel: other\n  bitrate_bit_s:"),
     "bus.channel", "duplicate key (line 5; first defined on line 4)"),
    ("duplicate-section", Config, VALID + "bus: {}\n", "bus", "duplicate key (line 8"),
    ("python-tag", Config, _sub(VALID, "aider", "!!python/object/apply:os.system ['true']"),
     None, "unsupported YAML tag '!!python/object/apply:os.system'"),
    ("python-name-tag", Config, VALID + "x: !!python/name:os.system\n", None,
     "unsupported YAML tag '!!python/name:os.system'"),
    ("local-tag", Config, _sub(VALID, "aider", "!custom aider"), None,
     "unsupported YAML tag '!custom'"),
    ("binary-tag", Config, _sub(VALID, "aider", "!!binary YWlkZXI="), None,
     "unsupported YAML tag '!!binary'"),
    ("bad-explicit-int", Config, _sub(VALID, "1000000", "!!int fast"), None, "invalid YAML"),
    ("top-level-list", Config, "- 1\n- 2\n", None, "expected a mapping of sections"),
    ("top-level-scalar", Config, "hello\n", None, "expected a mapping of sections"),
    ("top-level-null", Config, "null\n", None, "expected a mapping of sections"),
    ("empty-file", Config, "", None, "document is empty"),
    ("comments-only", Config, "# nothing here\n\n", None, "document is empty"),
    ("section-not-mapping", Config, _sub(VALID, "protocol:\n  max_delta_counter: 2",
     "protocol: 2"), "protocol", "expected a mapping (section), got 2"),
    ("section-empty", Config, _sub(VALID, "protocol:\n  max_delta_counter: 2", "protocol:"),
     "protocol", "expected a mapping (section), got null"),
    ("bad-choice", Config, _sub(VALID, "virtual", "pcan"), "bus.interface",
     "'pcan' is not one of: socketcan, virtual, udp_multicast"),
    ("bad-channel-name", Config, _sub(_sub(VALID, "virtual", "socketcan"), "aider", "can 0"),
     "bus.channel", "not a valid Linux interface name"),
    ("channel-too-long", Config, _sub(_sub(VALID, "virtual", "socketcan"), "aider",
     "a_very_long_name0"), "bus.channel", "not a valid Linux interface name"),
    ("channel-with-newline", Config, _sub(_sub(VALID, "virtual", "socketcan"), "aider",
     '"vcan\\n0"'), "bus.channel", "'vcan\\n0' is not a valid Linux interface name"),
    ("empty-channel", Config, _sub(VALID, "aider", '""'), "bus.channel", "must not be empty"),
    ("number-for-channel", Config, _sub(VALID, "aider", "0"), "bus.channel",
     "expected a string, got 0"),
    ("yes-is-not-bool", Config, VALID.replace("bus:\n", "bus:\n  receive_own_messages: yes\n"),
     "bus.receive_own_messages", "expected a boolean (true or false), got 'yes'"),
    ("schema-version-wrong", Config, _sub(VALID, "schema_version: 1", "schema_version: 2"),
     "schema_version", "expected 1, got 2"),
    ("bad-merge", Config, _sub(VALID, "  channel: aider", "  channel: aider\n  <<: 3"), None,
     "invalid YAML"),
    # Generic machinery, on the test-only schema.
    ("nan", Root, _sub(ROOT_VALID, "gain: 2", "gain: .nan"), "window.gain",
     "expected a finite number, got nan"),
    ("inf", Root, _sub(ROOT_VALID, "gain: 2", "gain: -.inf"), "window.gain",
     "expected a finite number, got -inf"),
    ("bool-for-float", Root, _sub(ROOT_VALID, "gain: 2", "gain: false"), "window.gain",
     "expected a number, got false"),
    ("float-above-maximum", Root, _sub(ROOT_VALID, "gain: 2", "gain: 1e3"), "window.gain",
     "1000.0 is above the maximum 10.0"),
    ("min-above-max", Root, _sub(ROOT_VALID, "min_n: 1", "min_n: 7"), "window.min_n",
     "7 must not exceed max_n (3)"),
    ("tuple-item-type", Root, _sub(ROOT_VALID, "[0.5, -1, 2.5e-3]", "[0.5, x]"),
     "window.offsets_m[1]", "expected a number, got 'x'"),
    ("tuple-not-list", Root, _sub(ROOT_VALID, "[0.5, -1, 2.5e-3]", "0.5"), "window.offsets_m",
     "expected a list, got 0.5"),
    ("fixed-tuple-length", Root, _sub(ROOT_VALID, "[1.0, 2.0]", "[1.0, 2.0, 3.0]"),
     "window.pair", "expected a list of 2 items, got 3"),
    ("literal-choice", Root, _sub(ROOT_VALID, "label: left", "mode: c"), "window.mode",
     "'c' is not one of: a, b"),
    ("entry-field-range", Root, _sub(ROOT_VALID, "60.5", "6.5"), "patients.alice.mass_kg",
     "6.5 is below the minimum 20.0"),
    ("entry-not-mapping", Root, _sub(ROOT_VALID, "{mass_kg: 80}", "80"), "patients.bob-2",
     "expected a mapping (section), got 80"),
    ("entry-bad-name", Root, _sub(ROOT_VALID, "alice:", "al.ice:"), "patients",
     "entry name 'al.ice' must consist of"),
    ("entries-not-mapping", Root, ROOT_VALID.split("patients:")[0] + "patients: [alice]\n",
     "patients", "expected a mapping of named entries, got a list"),
    ("optional-section-unknown-key", Root,
     ROOT_VALID + "extra: {min_n: 1, max_n: 2, gain: 1, x: 1}\n",
     "extra.x", "unknown key"),
]


@pytest.mark.parametrize(
    ("schema", "text", "key", "part"),
    [case[1:] for case in INVALID],
    ids=[case[0] for case in INVALID],
)
def test_invalid_file_gives_one_line_naming_file_and_key(tmp_path, schema, text, key, part):
    path = tmp_path / "config.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_as(schema, path)
    message = str(info.value)
    assert len(message.splitlines()) == 1, message
    assert message.startswith(f"{path}:"), message
    assert part in message, message
    if key is None:
        assert info.value.key is None, message
    else:
        assert info.value.key == key, message
        assert re.match(rf"{re.escape(str(path))}: {re.escape(key)}: ", message), message
    assert info.value.source == str(path)


def test_error_message_format_matches_style_guide():
    with pytest.raises(ConfigError) as info:
        parse_config(_sub(VALID, "1000000", "2000000"), source="config.yaml")
    assert str(info.value) == "config.yaml: bus.bitrate_bit_s: 2000000 is above the maximum 1000000"

    with pytest.raises(ConfigError) as info:
        parse_config(_sub(VALID, "  channel:", "  chanel:"), source="config.yaml")
    assert str(info.value) == (
        "config.yaml: bus.chanel: unknown key; expected one of: bitrate_bit_s, channel, "
        "interface, receive_own_messages (did you mean 'channel'?)"
    )

    text = _sub(VALID, "aider", "!!python/object/apply:os.system ['true']")
    with pytest.raises(ConfigError) as info:
        parse_config(text, source="config.yaml")
    assert str(info.value) == (
        "config.yaml:4: unsupported YAML tag '!!python/object/apply:os.system'"
    )

    with pytest.raises(ConfigError) as info:
        parse_config(VALID + "bus: [unclosed\n", source="config.yaml")
    assert re.fullmatch(r"config\.yaml:\d+:\d+: invalid YAML: .+", str(info.value))


def test_python_tags_are_never_executed(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("os.system was called")

    monkeypatch.setattr(os, "system", forbidden)
    with pytest.raises(ConfigError):
        parse_config(_sub(VALID, "aider", "!!python/object/apply:os.system ['true']"))


def test_bundled_files_load():
    default = load_config(default_config_path())
    assert default.bus == BusConfig(interface="virtual", channel="aider", bitrate_bit_s=1_000_000)
    assert default.protocol == ProtocolConfig(max_delta_counter=3)
    assert default.bus.receive_own_messages is False
    assert default.sim is not None and default.sim.model.patient.mass_kg == 70.0


@pytest.mark.parametrize("path", [default_config_path()], ids=["default"])
def test_bundled_files_list_every_key(path):
    # Every key, including those with a default, is spelled out in the file.
    assert load_yaml(path) == config_to_dict(load_config(path))


def test_default_config_path_points_into_the_package():
    path = default_config_path()
    assert path.is_absolute()
    assert path.name == "default.yaml"
    assert path.parent == ROOT / "config"


def test_load_config_accepts_str_path():
    assert load_config(str(default_config_path())) == load_config(default_config_path())


def test_unreadable_file(tmp_path):
    missing = tmp_path / "missing.yaml"
    with pytest.raises(ConfigError) as info:
        load_config(missing)
    assert str(info.value) == f"{missing}: cannot read file: No such file or directory"

    latin1 = tmp_path / "latin1.yaml"
    latin1.write_bytes(VALID.replace("aider", "ca\xefd").encode("latin-1"))
    with pytest.raises(ConfigError, match="not valid UTF-8"):
        load_config(latin1)


def test_utf8_bom_is_accepted(tmp_path):
    path = tmp_path / "bom.yaml"
    path.write_bytes(b"\xef\xbb\xbf" + VALID.encode())
    assert load_config(path).bus.channel == "aider"


def test_yaml_dialect():
    data = load_yaml(
        "a: 1_000\nb: 1e3\nc: 1.5E-3\nd: .5\ne: -.5\nf: yes\ng: on\nh: 2024-01-01\n"
        "i: 0x1F\nj: TRUE\nk: ~\nl: 010\nm: 1:30\n"
    )
    assert data == {
        "a": 1000, "b": 1000.0, "c": 0.0015, "d": 0.5, "e": -0.5, "f": "yes", "g": "on",
        "h": "2024-01-01", "i": 31, "j": True, "k": None, "l": "010", "m": "1:30",
    }
    assert type(data["b"]) is float


def test_anchors_and_merge_keys_are_allowed():
    text = VALID.replace(
        "protocol:\n  max_delta_counter: 2\n",
        "protocol: &p\n  max_delta_counter: 3\n",
    )
    assert parse_config(text).protocol.max_delta_counter == 3
    merged = load_yaml("a: &x {k: 1, j: 2}\nb:\n  <<: *x\n  k: 3\n")
    assert merged["b"] == {"k": 3, "j": 2}


def test_recursive_alias_is_an_error_not_a_crash():
    with pytest.raises(ConfigError):
        parse_config("a: &x [*x]\n")


def test_deep_nesting_is_an_error_not_a_crash():
    with pytest.raises(ConfigError) as info:
        parse_config("a: " + "[" * 5000 + "]" * 5000 + "\n")
    assert len(str(info.value).splitlines()) == 1


def test_non_string_keys_are_unknown_keys():
    with pytest.raises(ConfigError) as info:
        parse_config(VALID + "1: x\n")
    assert info.value.key == "1"
    assert "unknown key" in info.value.message


@pytest.mark.parametrize(
    ("line", "key"),
    [('"": 1', "''"), ('"a b": 1', "'a b'"), ('"a\\nb": 1', "'a\\nb'"), ("~: 1", "None")],
)
def test_odd_keys_are_quoted_in_the_path(line, key):
    with pytest.raises(ConfigError) as info:
        parse_config(VALID + line + "\n")
    assert info.value.key == key
    assert len(str(info.value).splitlines()) == 1


def test_build_top_level_not_a_mapping():
    with pytest.raises(ConfigError) as info:
        build(Config, ["bus"])
    assert str(info.value) == "expected a mapping, got a list"


def test_validate_error_carries_full_path():
    data = load_yaml(_sub(ROOT_VALID, "min_n: 1", "min_n: 7"))
    with pytest.raises(ConfigError) as info:
        build(Root, data)
    assert type(info.value) is ConfigError  # not the relative FieldError
    assert info.value.key == "window.min_n"
    with pytest.raises(ConfigError) as info:
        build(Root, data, "outer")
    assert info.value.key == "outer.window.min_n"


def test_fail_raises_field_error():
    with pytest.raises(FieldError) as info:
        fail("min_n", "too big")
    assert info.value.key == "min_n"
    assert isinstance(info.value, ConfigError)
    assert isinstance(info.value, AiderError)


def test_test_schema_builds_typed_values():
    root = parse_as(Root, ROOT_VALID)
    assert root.window.gain == 2.0 and type(root.window.gain) is float
    assert root.window.offsets_m == (0.5, -1.0, 0.0025)
    assert all(type(x) is float for x in root.window.offsets_m)
    assert root.window.pair == (1.0, 2.0)
    assert root.window.label == "left"
    assert root.window.mode == "a"
    assert root.patients == {"alice": Patient(mass_kg=60.5), "bob-2": Patient(mass_kg=80.0)}
    assert root.extra is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        root.window.gain = 3.0  # type: ignore[misc]


def test_optional_accepts_null():
    root = parse_as(Root, ROOT_VALID.replace("label: left", "label: null") + "extra: null\n")
    assert root.window.label is None
    assert root.extra is None


@pytest.mark.parametrize("text", [VALID, ROOT_VALID], ids=["config", "test-schema"])
def test_round_trip(text):
    schema = Config if text is VALID else Root
    obj = parse_as(schema, text)
    plain = config_to_dict(obj)
    assert build(schema, plain) == obj
    assert parse_as(schema, yaml.safe_dump(plain)) == obj
    assert build(schema, json.loads(json.dumps(plain))) == obj


def test_round_trip_bundled_files():
    for path in (default_config_path(),):
        config = load_config(path)
        assert build(Config, config_to_dict(config)) == config


def test_overrides():
    base = load_config(default_config_path())
    changed = with_overrides(base, {"bus.interface": "socketcan", "bus.channel": "vcan0"})
    assert changed.bus == BusConfig(interface="socketcan", channel="vcan0", bitrate_bit_s=1_000_000)
    assert changed.protocol == base.protocol
    assert base.bus.interface == "virtual"  # the original is untouched
    assert with_overrides(base, {}) == base
    whole_section = with_overrides(base, {"protocol": {"max_delta_counter": 5}})
    assert whole_section.protocol.max_delta_counter == 5


@pytest.mark.parametrize(("channel", "group"), [
    ("239.74.163.2", ("239.74.163.2", 43113)),
    ("239.74.163.2:43114", ("239.74.163.2", 43114)),
    ("ff15:7079:7468:6f6e:6465:6d6f:6d63:6173", ("ff15:7079:7468:6f6e:6465:6d6f:6d63:6173", 43113)),
    ("[FF15::1]:9", ("ff15::1", 9)),
    ("[ff15::1]", ("ff15::1", 43113)),
])
def test_a_udp_multicast_channel_names_its_group_and_port(channel, group):
    cfg = with_overrides(load_config(default_config_path()), {"bus.interface": "udp_multicast", "bus.channel": channel})
    assert cfg.bus.udp_group() == group


def test_overrides_of_entries_and_tuples():
    root = parse_as(Root, ROOT_VALID)
    changed = with_overrides(
        root,
        {"patients.alice.mass_kg": 70, "window.pair": (3, 4), "patients.carol": {"mass_kg": 50}},
    )
    assert changed.patients["alice"].mass_kg == 70.0
    assert changed.patients["carol"].mass_kg == 50.0
    assert changed.window.pair == (3.0, 4.0)


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({"bus.bitrate_bit_s": 2_000_000},
         "<overrides>: bus.bitrate_bit_s: 2000000 is above the maximum 1000000"),
        ({"bus.bitrate_bit_s": "fast"},
         "<overrides>: bus.bitrate_bit_s: expected an integer, got 'fast'"),
        ({"bus.interface": "pcan"},
         "<overrides>: bus.interface: 'pcan' is not one of: socketcan, virtual, udp_multicast"),
        ({"bus.chanel": "vcan0"}, "<overrides>: bus.chanel: unknown key; expected one of: "
         "bitrate_bit_s, channel, interface, receive_own_messages (did you mean 'channel'?)"),
        ({"bsu.channel": "vcan0"}, "<overrides>: bsu: unknown key; expected one of: "
         "bus, controller, hardware, nodes, protocol, schema_version, sim (did you mean 'bus'?)"),
        ({"bus.interface": "socketcan", "bus.channel": "my bus"}, "<overrides>: bus.channel: "
         "'my bus' is not a valid Linux interface name for socketcan "
         "(1 to 15 characters from A-Z a-z 0-9 _ . -)"),
        ({"bus.interface": "udp_multicast", "bus.channel": "vcan0"}, "<overrides>: bus.channel: 'vcan0' is not "
         "an IPv4 or IPv6 address (udp_multicast needs a multicast group)"),
        ({"bus.interface": "udp_multicast", "bus.channel": "192.168.1.2"}, "<overrides>: bus.channel: 192.168.1.2 is "
         "not a multicast address (IPv4 224.0.0.0/4, IPv6 ff00::/8)"),
        ({"bus.interface": "udp_multicast", "bus.channel": "239.1.2.3:70000"}, "<overrides>: bus.channel: "
         "'239.1.2.3:70000': the port must be a number from 1 to 65535"),
        ({"bus.interface": "udp_multicast", "bus.channel": "[ff15::1]43113"}, "<overrides>: bus.channel: "
         "'[ff15::1]43113': an IPv6 group with a port is written [group]:port"),
        ({"bus.channel.name": "x"},
         "<overrides>: bus.channel.name: cannot be set: bus.channel is a value, not a section"),
        ({"protocol": 3}, "<overrides>: protocol: expected a mapping (section), got 3"),
        ({"bus..channel": "x"}, "<overrides>: invalid override key 'bus..channel'; "
         "expected a dotted path such as 'bus.channel'"),
        ({"": "x"}, "<overrides>: invalid override key ''; "
         "expected a dotted path such as 'bus.channel'"),
    ],
)
def test_bad_overrides_fail_naming_the_key(overrides, expected):
    base = load_config(default_config_path())
    with pytest.raises(ConfigError) as info:
        with_overrides(base, overrides)
    assert str(info.value) == expected


def test_parse_override():
    assert parse_override("bus.bitrate_bit_s=500000") == ("bus.bitrate_bit_s", 500000)
    assert parse_override("bus.channel=vcan0") == ("bus.channel", "vcan0")
    assert parse_override(" bus.channel = can0") == ("bus.channel", "can0")
    assert parse_override("window.pair=[1.0, 2]") == ("window.pair", [1.0, 2])
    assert parse_override("window.label=") == ("window.label", None)
    assert parse_override("a.b=x=y") == ("a.b", "x=y")
    base = load_config(default_config_path())
    key, value = parse_override("bus.bitrate_bit_s=2e6")
    with pytest.raises(ConfigError, match=r"^<overrides>: bus.bitrate_bit_s: expected an integer"):
        with_overrides(base, {key: value})
    with pytest.raises(ConfigError) as info:
        parse_override("bus.channel")
    assert str(info.value).startswith(
        "<overrides>: invalid override 'bus.channel'; expected KEY=VALUE"
    )
    with pytest.raises(ConfigError) as info:
        parse_override("bus.channel=[vcan0")
    assert str(info.value).startswith("<overrides>: bus.channel: invalid YAML: ")
    with pytest.raises(ConfigError, match="unsupported YAML tag"):
        parse_override("bus.channel=!!python/name:os.system")


def test_config_error_pickles():
    error = ConfigError("bad", key="bus.channel", source="config.yaml", line=3)
    copy = pickle.loads(pickle.dumps(error))
    assert str(copy) == str(error) == "config.yaml:3: bus.channel: bad"
    field_error = pickle.loads(pickle.dumps(FieldError("min_n", "too big")))
    assert (field_error.key, field_error.message) == ("min_n", "too big")


def test_schemas_are_well_formed():
    check_schema(Config)
    check_schema(Root)


@dataclass(frozen=True, kw_only=True)
class _ListField:
    values: list[int] = field_spec(doc="Lists are mutable; tuples must be used.")


@dataclass(frozen=True, kw_only=True)
class _NoSpec:
    value: int = 3


@dataclass(kw_only=True)
class _NotFrozen:
    value: int = field_spec(doc="A value.")


@dataclass(frozen=True, kw_only=True)
class _BadDefault:
    value: int = field_spec(doc="A value.", min=1, default=0)


@pytest.mark.parametrize(
    ("schema", "match"),
    [
        (_ListField, "unsupported configuration field type"),
        (_NoSpec, "not declared with field_spec"),
        (_NotFrozen, "must be frozen"),
        (_BadDefault, "invalid default: value: 0 is below the minimum 1"),
    ],
)
def test_check_schema_rejects_bad_schemas(schema, match):
    with pytest.raises(TypeError, match=match):
        check_schema(schema)


def test_field_spec_checks_its_arguments():
    with pytest.raises(TypeError):
        field_spec(doc="")
    with pytest.raises(ValueError):
        field_spec(doc="x", min=2, max=1)


def _assert_config_or_one_line_error(text: str) -> None:
    try:
        result = parse_config(text, source="fuzz.yaml")
    except ConfigError as exc:
        message = str(exc)
        assert message.startswith("fuzz.yaml"), message
        assert len(message.splitlines()) == 1, message
    else:
        assert isinstance(result, Config)


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(st.text())
def test_arbitrary_text_gives_config_or_config_error(text):
    _assert_config_or_one_line_error(text)


_YAML_TOKENS = list(" \n\t:-[]{},#&*!|>'\"%@`?~.=<0123456789abexyz_") + [
    "bus", "protocol", "schema_version", "channel", "interface", "bitrate_bit_s",
    "max_delta_counter", "virtual", "socketcan", "!!int ", "!!float ", "!!str ",
    "!!python/object/apply:os.system ", "!!binary ", "<<: ", ".nan", ".inf", "1e3", "0x1F",
    "010", "1:30", "true", "yes", "null", "\n  ", "\n    ", ": ", "- ", "&a ", "*a", "---\n",
]
# Token soup: far more likely than st.text() to hit the parser's interesting paths.
YAMLISH = st.lists(st.sampled_from(_YAML_TOKENS), max_size=40).map("".join)


@settings(max_examples=500, suppress_health_check=[HealthCheck.too_slow])
@given(YAMLISH)
def test_yamlish_text_gives_config_or_config_error(text):
    _assert_config_or_one_line_error(text)


_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=20),
    st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(["schema_version", "bus", "bus.interface", "bus.channel", "bus.bitrate_bit_s",
                     "bus.receive_own_messages", "protocol", "protocol.max_delta_counter",
                     "bus.extra", "extra"]),
    _SCALARS,
)
def test_mutated_valid_config_gives_config_or_config_error(dotted, value):
    data = load_yaml(VALID)
    *parents, last = dotted.split(".")
    node = data
    for part in parents:
        node = node[part]
    node[last] = value
    _assert_config_or_one_line_error(yaml.safe_dump(data))
    base = load_config(default_config_path())
    try:
        with_overrides(base, {dotted: value})
    except ConfigError as exc:
        assert len(str(exc).splitlines()) == 1


# --- the hardware section: one definition the controller and the simulation both read ------------


def test_the_controller_and_the_simulation_read_the_one_hardware_section():
    cfg = load_config(default_config_path())
    assert cfg.controller.hardware is cfg.hardware and cfg.sim.hardware is cfg.hardware
    moved = with_overrides(cfg, {"hardware.foot.half_width_m": 0.05})
    assert moved.controller.hardware.foot.half_width_m == moved.sim.hardware.foot.half_width_m == 0.05
    assert "hardware" not in config_to_dict(cfg)["controller"] and "hardware" not in config_to_dict(cfg)["sim"]
    assert dataclasses.replace(cfg.sim, mode="sagittal").hardware is cfg.hardware  # a copy of a section keeps it


def test_a_file_with_a_controller_needs_the_hardware_section_and_never_has_it_under_the_controller():
    data = config_to_dict(load_config(default_config_path()))
    without = {k: v for k, v in data.items() if k != "hardware"}
    with pytest.raises(ConfigError, match=r"hardware: missing required key"):
        parse_config(yaml.safe_dump(without))
    data["controller"]["hardware"] = data["hardware"]
    with pytest.raises(ConfigError, match=r"controller\.hardware: unknown key"):
        parse_config(yaml.safe_dump(data))
    bare = {k: v for k, v in without.items() if k not in ("controller", "sim")}
    assert parse_config(yaml.safe_dump(bare)).hardware is None  # a bus-only file (buscheck, record) needs none


@pytest.mark.parametrize(("section", "key", "now"), [
    ("controller.legs", "hip_min_rad", "hardware.joints.hip.lower_rad"),
    ("controller.body", "foot_half_width_m", "hardware.foot.half_width_m"),
    ("sim.model", "sticks", "hardware.sticks"),
    ("sim.model.joints", "ankle", "hardware.joints.ankle"),
])
def test_a_key_of_the_earlier_format_says_where_it_is_now(section, key, now):
    data = config_to_dict(load_config(default_config_path()))
    node = data
    for part in section.split("."):
        node = node[part]
    node[key] = 0.1
    with pytest.raises(ConfigError, match=rf"{section}\.{key}: this key is now {now}$"):
        parse_config(yaml.safe_dump(data))
