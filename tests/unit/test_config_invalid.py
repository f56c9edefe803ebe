"""Invalid variants of the shipped configuration are refused before the bus opens (issue 9 item 5).

docs/FAULTS.md F27 and invariant I8: a configuration that fails validation makes the process exit non-zero
before it opens the bus (so before any node can be started or a drive enabled), with one line that
names the file and the dotted key (or, for YAML syntax errors and tags, the line); safety parameters
have no silent defaults; YAML tags are never executed.

``tests/unit/test_config.py`` covers the generic loader on a small three-section file. Here every variant
is a small edit of the real ``config/default.yaml`` (safety keys of the controller, the envelope, the
node watchdogs, the simulated hardware), checked twice: through :func:`config.load_config` and through
the real ``aider-exo controller`` / ``aider-exo nodes`` processes.

The CLI runs use ``--bus socketcan --channel vcan-nonexist``: a valid Linux interface name (at most 15
characters) that does not exist, so a configuration that passed validation would end in a bus error
(``cannot open socketcan channel 'vcan-nonexist'``, see the control tests) instead of the config error.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shlex
import subprocess
import sys
import types
import typing
from collections import Counter
from pathlib import Path
from typing import Any, Callable, NamedTuple

import pytest
import yaml

import config as config_package
from config import Config, ConfigError, default_config_path, load_config, load_yaml
from config.loader import DERIVED_KEY

DEFAULT = default_config_path().read_text(encoding="utf-8")

#: A valid interface name (13 of at most 15 characters) that no test machine has.
CHANNEL = "vcan-nonexist"

#: Printed on stderr by pybullet's C code when ``aider-exo nodes`` imports the simulation (before the
#: configuration is read); not a line of aider-exo. Every other stderr line counts.
_PYBULLET_BANNER = re.compile(r"^pybullet build time: ")


# ---------------------------------------------------------------------------
# Variants of config/default.yaml
# ---------------------------------------------------------------------------


class Bad(NamedTuple):
    """One invalid configuration and what its error must say."""

    id: str
    category: str
    text: str
    key: str | None  # the dotted key the error names (ConfigError.key), or None (syntax, tags, top level)
    part: str  # a fragment of the message
    line: int | None = None  # the line the error points at (location, or "at line N" context)


def _edit(old: str, new: str) -> tuple[str, int]:
    """``DEFAULT`` with the one occurrence of ``old`` replaced; and the 1-based line of the edit."""
    assert DEFAULT.count(old) == 1, f"{old!r} must occur exactly once in default.yaml"
    start = DEFAULT.index(old)
    return DEFAULT[:start] + new + DEFAULT[start + len(old) :], DEFAULT.count("\n", 0, start) + 1


def _text(old: str, new: str) -> str:
    return _edit(old, new)[0]


def _line_of(old: str) -> int:
    return _edit(old, old)[1]


def _structural(change: Callable[[dict[str, Any]], Any]) -> str:
    """``default.yaml`` parsed, changed by ``change(data)`` in place, dumped again (comments lost)."""
    data = load_yaml(default_config_path())
    result = change(data)
    return yaml.safe_dump(data if result is None else result, sort_keys=False)


def _section(data: dict[str, Any], dotted: str) -> tuple[dict[str, Any], str]:
    *parents, last = dotted.split(".")
    node = data
    for part in parents:
        node = node[part]
    return node, last


def _without(dotted: str) -> str:
    def change(data: dict[str, Any]) -> None:
        node, last = _section(data, dotted)
        del node[last]

    return _structural(change)


def _set(dotted: str, value: Any) -> str:
    def change(data: dict[str, Any]) -> None:
        node, last = _section(data, dotted)
        assert last in node, dotted
        node[last] = value

    return _structural(change)


def _tag(name: str, old: str, new: str, tag: str) -> Bad:
    text, line = _edit(old, new)
    return Bad(name, "python-tag", text, None, f"unsupported YAML tag {tag!r}", line)


_CTT = "  command_timeout_ticks: 3"
_HBT = "  heartbeat_timeout_ms: 300"
_TORQUE = "    max_torque_nm: 100.0"
_STEP = "    min_fraction: 0.0647      # 0.060 m\n    max_fraction: 0.2697      # 0.250 m"
_HIP_JOINT = "hip:   {lower_rad: -0.50, upper_rad: 2.00, torque_limit_nm: 100.0,"

BAD: list[Bad] = [
    # --- YAML syntax: the error points at the edited line (or names it as its context) ----------
    Bad("syntax-tab-indent", "syntax", _text(_CTT, "\tcommand_timeout_ticks: 3"), None,
        "invalid YAML: found character '\\t'", _line_of(_CTT)),
    Bad("syntax-mapping-in-scalar", "syntax", _text(_TORQUE, _TORQUE + ": 5"), None,
        "invalid YAML: mapping values are not allowed here", _line_of(_TORQUE)),
    Bad("syntax-bad-indent", "syntax", _text("    max_fraction: 0.2697", "   max_fraction: 0.2697"), None,
        "invalid YAML", _line_of("    max_fraction: 0.2697")),
    Bad("syntax-list-item-in-mapping", "syntax", _text("    min_fraction: 0.0647", "    - min_fraction: 0.0647"), None,
        "invalid YAML", _line_of("    min_fraction: 0.0647")),
    Bad("syntax-unclosed-flow-sequence", "syntax", _text("[0.0, 0.20, 0.504]", "[0.0, 0.20, 0.504"), None,
        "invalid YAML: expected ',' or ']'", _line_of("[0.0, 0.20, 0.504]")),
    Bad("syntax-unterminated-quote", "syntax", _text("channel: aider", 'channel: "aider'), None,
        "invalid YAML: found unexpected end of stream", _line_of("channel: aider")),
    # --- a required safety key is absent: no default is ever used ----------------------------
    Bad("missing-command-watchdog", "missing-key", _text(_CTT + "\n", ""), "nodes.command_timeout_ticks",
        "missing required key"),
    Bad("missing-heartbeat-timeout", "missing-key", _text(_HBT + "\n", ""), "nodes.heartbeat_timeout_ms",
        "missing required key"),
    Bad("missing-envelope-torque", "missing-key", _text(_TORQUE + "\n", ""), "controller.envelope.max_torque_nm",
        "missing required key"),
    Bad("missing-step-max", "missing-key", _text("    max_fraction: 0.2697      # 0.250 m\n", ""), "controller.step.max_fraction",
        "missing required key"),
    Bad("missing-lost-frame-budget", "missing-key", _without("protocol.max_delta_counter"),
        "protocol.max_delta_counter", "missing required key"),
    Bad("missing-lost-node-budget", "missing-key", _without("controller.safety.lost_ticks"),
        "controller.safety.lost_ticks", "missing required key"),
    Bad("missing-envelope-section", "missing-key", _without("controller.envelope"), "controller.envelope",
        "missing required key"),
    Bad("missing-joint-limit", "missing-key", _text(_HIP_JOINT, "hip:   {lower_rad: -0.50, torque_limit_nm: 100.0,"),
        "hardware.joints.hip.upper_rad", "missing required key"),
    # --- wrong types -------------------------------------------------------------------------
    Bad("type-string-for-number", "wrong-type", _text(_TORQUE, "    max_torque_nm: 100 Nm"),
        "controller.envelope.max_torque_nm", "expected a number, got '100 Nm'"),
    Bad("type-quoted-number", "wrong-type", _text(_CTT, '  command_timeout_ticks: "3"'),
        "nodes.command_timeout_ticks", "expected an integer, got '3'"),
    Bad("type-list-for-mapping", "wrong-type", _set("controller.envelope", [0.02, 4.0, 0.08, 100.0, 0.1, 1.2]),
        "controller.envelope", "expected a mapping (section), got a list"),
    Bad("type-bool-for-int", "wrong-type", _text(_CTT, "  command_timeout_ticks: true"),
        "nodes.command_timeout_ticks", "expected an integer, got true"),
    Bad("type-bool-for-float", "wrong-type", _text("    max_step_rad: 0.08", "    max_step_rad: false"),
        "controller.envelope.max_step_rad", "expected a number, got false"),
    Bad("type-float-for-int", "wrong-type", _text(_HBT, "  heartbeat_timeout_ms: 300.0"),
        "nodes.heartbeat_timeout_ms", "expected an integer, got 300.0"),
    Bad("type-null-for-int", "wrong-type", _text(_CTT, "  command_timeout_ticks:"),
        "nodes.command_timeout_ticks", "expected an integer, got null"),
    Bad("type-mapping-for-number", "wrong-type", _set("protocol.max_delta_counter", {"value": 2}),
        "protocol.max_delta_counter", "expected an integer, got a mapping"),
    # --- a lower bound above its upper bound ------------------------------------------------
    Bad("minmax-knee-limits-equal", "min-above-max", _set("hardware.joints.knee.lower_rad", 2.0),
        "hardware.joints.knee.lower_rad", "2.0 must be below upper_rad 2.0"),
    Bad("minmax-step-length", "min-above-max", _text(_STEP, "    min_fraction: 0.30\n    max_fraction: 0.2697"),
        "controller.step.min_fraction", "must not exceed max_fraction 0.2697"),
    Bad("minmax-learning-alpha", "min-above-max", _text("    alpha_max: 0.0", "    alpha_max: -30.0"),
        "controller.learning.alpha_min", "must be below alpha_max"),
    Bad("minmax-sim-joint", "min-above-max", _text(_HIP_JOINT, "hip:   {lower_rad: 2.50, upper_rad: 2.00, torque_limit_nm: 100.0,"),
        "hardware.joints.hip.lower_rad", "2.5 must be below upper_rad 2.0"),
    Bad("minmax-patient-lean", "min-above-max", _set("sim.gait.lean_x_max", 0.3),
        "sim.gait.lean_x_max", "must not be below lean_x_min 0.35"),
    # --- beyond the hard bounds of the hardware / of the safety case ------------------------
    Bad("bound-command-watchdog-6", "beyond-bound", _text(_CTT, "  command_timeout_ticks: 6"),
        "nodes.command_timeout_ticks", "6 is above the maximum 5"),
    Bad("bound-command-watchdog-0", "beyond-bound", _text(_CTT, "  command_timeout_ticks: 0"),
        "nodes.command_timeout_ticks", "0 is below the minimum 1"),
    Bad("bound-heartbeat-negative", "beyond-bound", _text(_HBT, "  heartbeat_timeout_ms: -300"),
        "nodes.heartbeat_timeout_ms", "-300 is below the minimum 120"),
    Bad("bound-lost-node-budget-6", "beyond-bound", _set("controller.safety.lost_ticks", 6),
        "controller.safety.lost_ticks", "6 is above the maximum 5"),
    Bad("bound-hold-torque-above-envelope", "beyond-bound", _set("controller.safety.hold_torque_nm", 120.0),
        "controller.safety.hold_torque_nm", "must not exceed envelope.max_torque_nm 100.0"),
    Bad("bound-envelope-torque", "beyond-bound", _text(_TORQUE, "    max_torque_nm: 250.0"),
        "controller.envelope.max_torque_nm", "250.0 is above the maximum 200.0"),
    Bad("bound-motor-torque", "beyond-bound", _text(_HIP_JOINT, "hip:   {lower_rad: -0.50, upper_rad: 2.00, torque_limit_nm: 500.0,"),
        "hardware.joints.hip.torque_limit_nm", "500.0 is above the maximum 400.0"),
    Bad("bound-zero-swing-duration", "beyond-bound", _text("    duration_scaled: 3.9037", "    duration_scaled: 0"),
        "controller.swing.duration_scaled", "0 is below the minimum 1"),
    Bad("bound-zero-physics-rate", "beyond-bound", _text("    rate_hz: 250", "    rate_hz: 0"),
        "sim.physics.rate_hz", "0 is below the minimum 200"),
    Bad("bound-joint-beyond-pi", "beyond-bound", _set("hardware.joints.hip.upper_rad", 3.5),
        "hardware.joints.hip.upper_rad", "3.5 is above the maximum"),
    # --- non-finite numbers -------------------------------------------------------------------
    Bad("nonfinite-inf-torque", "non-finite", _text(_TORQUE, "    max_torque_nm: .inf"),
        "controller.envelope.max_torque_nm", "expected a finite number, got inf"),
    Bad("nonfinite-nan-step", "non-finite", _text("    max_fraction: 0.2697", "    max_fraction: .nan"),
        "controller.step.max_fraction", "expected a finite number, got nan"),
    Bad("nonfinite-minus-inf-limit", "non-finite", _set("hardware.joints.hip.lower_rad", float("-inf")),
        "hardware.joints.hip.lower_rad", "expected a finite number, got -inf"),
    Bad("nonfinite-overflow", "non-finite", _text("    max_velocity_rad_s: 4.0", "    max_velocity_rad_s: 1e400"),
        "controller.envelope.max_velocity_rad_s", "expected a finite number, got inf"),
    Bad("nonfinite-nan-for-int", "non-finite", _text(_CTT, "  command_timeout_ticks: .nan"),
        "nodes.command_timeout_ticks", "expected an integer, got nan"),
    # --- unknown keys: most likely typos; never ignored (an ignored `node:` would drop the watchdogs)
    Bad("unknown-top-level-typo", "unknown-key", _text("\nnodes:\n", "\nnode:\n"), "node",
        "unknown key; expected one of: bus, controller, hardware, nodes, protocol, schema_version, sim (did you mean 'nodes'?)"),
    Bad("unknown-nested-typo", "unknown-key", _text(_CTT, "  command_timout_ticks: 3"),
        "nodes.command_timout_ticks", "unknown key; expected one of: command_timeout_ticks, faults, "
        "heartbeat_timeout_ms, status_interval_s, supply_voltage_v (did you mean 'command_timeout_ticks'?)"),
    Bad("unknown-envelope-typo", "unknown-key", _text(_TORQUE, "    max_torque_n: 100.0"),
        "controller.envelope.max_torque_n", "(did you mean 'max_torque_nm'?)"),
    Bad("unknown-extra-flow-key", "unknown-key", _text(_HIP_JOINT, "hip:   {lower_rad: -0.50, upper_rad: 2.00, torque_limit_nm: 100.0, gear: 3,"),
        "hardware.joints.hip.gear", "unknown key"),
    # --- duplicate keys: the second value is never silently used ------------------------------
    Bad("duplicate-top-level", "duplicate-key",
        DEFAULT + "nodes: {command_timeout_ticks: 5, heartbeat_timeout_ms: 1000}\n", "nodes",
        f"duplicate key (line {DEFAULT.count(chr(10)) + 1}; first defined on line {_line_of(chr(10) + 'nodes:') + 1})"),
    Bad("duplicate-nested", "duplicate-key", _text(_CTT, _CTT + "\n  command_timeout_ticks: 5"),
        "nodes.command_timeout_ticks", f"duplicate key (line {_line_of(_CTT) + 1}; first defined on line {_line_of(_CTT)})"),
    Bad("duplicate-in-flow-mapping", "duplicate-key", _text(_HIP_JOINT, "hip:   {lower_rad: -0.50, upper_rad: 2.00, torque_limit_nm: 100.0, torque_limit_nm: 400.0,"),
        "hardware.joints.hip.torque_limit_nm", "duplicate key"),
    # --- python tags: rejected before anything is constructed ---------------------------------
    _tag("tag-python-apply-os-system", _CTT, "  command_timeout_ticks: !!python/object/apply:os.system ['true']",
         "!!python/object/apply:os.system"),
    _tag("tag-python-name", _TORQUE, "    max_torque_nm: !!python/name:os.system", "!!python/name:os.system"),
    _tag("tag-python-object-new", "channel: aider", "channel: !!python/object/new:str [aider]",
         "!!python/object/new:str"),
    _tag("tag-python-module-key", _HBT, "  !!python/module:os : 300", "!!python/module:os"),
    # --- the top level is not a mapping of sections -------------------------------------------
    Bad("empty-file", "top-level", "", None, "document is empty; expected a mapping of sections"),
    Bad("only-comments", "top-level", "\n".join(l for l in DEFAULT.splitlines() if l.startswith("#")) + "\n",
        None, "document is empty"),
    Bad("top-level-list", "top-level", _structural(lambda data: [data]), None,
        "expected a mapping of sections at the top level, got a list"),
]

BY_ID = {bad.id: bad for bad in BAD}

#: The nodes CLI (which imports PyBullet first: about 1 s a run) is checked on a representative subset.
NODES_SUBSET = [
    "syntax-tab-indent",
    "missing-command-watchdog",
    "type-bool-for-int",
    "bound-command-watchdog-6",
    "unknown-top-level-typo",
    "duplicate-nested",
    "tag-python-apply-os-system",
]


def _params(bads: list[Bad]) -> list[Any]:
    return [pytest.param(bad, id=bad.id) for bad in bads]


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _check_message(bad: Bad, message: str, path: Path) -> None:
    """The one-line message: the file first, then the dotted key, or the line of the problem."""
    assert len(message.splitlines()) == 1, message
    assert message.startswith(f"{path}:"), message
    assert bad.part in message, message
    if bad.key is not None:
        assert message.startswith(f"{path}: {bad.key}: "), message
    if bad.line is not None:
        assert re.match(rf"{re.escape(str(path))}:{bad.line}:", message) or f"at line {bad.line}, column" in message, (
            f"expected line {bad.line}: {message}"
        )


# ---------------------------------------------------------------------------
# The table itself
# ---------------------------------------------------------------------------


def test_table_covers_every_kind_of_invalid_file():
    assert len(BAD) >= 24
    assert len(BY_ID) == len(BAD), "duplicate variant ids"
    minimum = {"syntax": 2, "missing-key": 3, "wrong-type": 3, "min-above-max": 2, "beyond-bound": 3,
               "non-finite": 1, "unknown-key": 2, "duplicate-key": 2, "python-tag": 2, "top-level": 2}
    counts = Counter(bad.category for bad in BAD)
    assert set(counts) == set(minimum)
    for category, at_least in minimum.items():
        assert counts[category] >= at_least, category
    assert set(NODES_SUBSET) <= set(BY_ID)


def test_unedited_sources_of_the_variants_are_valid(tmp_path):
    # A variant must fail because of its edit, not because the way it is made breaks the file.
    assert load_config(_write(tmp_path, _text(_CTT, _CTT))) == load_config(default_config_path())
    assert load_config(_write(tmp_path, _structural(lambda data: None))) == load_config(default_config_path())


# ---------------------------------------------------------------------------
# Library: config.load_config
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("bad", _params(BAD))
def test_load_config_rejects_naming_the_key(tmp_path, bad):
    path = _write(tmp_path, bad.text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    error = info.value
    assert type(error) is ConfigError, type(error)
    assert error.source == str(path)
    assert error.key == bad.key, str(error)
    if bad.line is not None:
        assert error.line is not None, str(error)
    _check_message(bad, str(error), path)


def _schema_fields(cls: type, path: str = "") -> typing.Iterator[tuple[str, dataclasses.Field[Any], Any]]:
    """(dotted name, field, type) of every field of the schema tree; ``*`` for a named entry."""
    hints = typing.get_type_hints(cls)
    for field in dataclasses.fields(cls):
        if field.metadata.get(DERIVED_KEY):  # not a key of its section (the root sets it)
            continue
        dotted = f"{path}.{field.name}" if path else field.name
        tp = hints[field.name]
        yield dotted, field, tp
        inner_tp = tp
        if typing.get_origin(tp) in (typing.Union, types.UnionType):  # Optional[X]
            (inner_tp,) = [arg for arg in typing.get_args(tp) if arg is not type(None)]
        if typing.get_origin(inner_tp) is dict:
            inner_tp, dotted = typing.get_args(inner_tp)[1], dotted + ".*"
        if isinstance(inner_tp, type) and dataclasses.is_dataclass(inner_tp):
            yield from _schema_fields(inner_tp, dotted)


#: Every field that may be left out of a file. None of them is a safety parameter: the three sections
#: are absent where they do not exist (on the robot: sim and nodes) and are then refused by the
#: command that needs them; hardware may be left out only with neither the controller nor the sim
#: (its own check); the rest is fault injection for tests and the status-line rate.
OPTIONAL_FIELDS = {
    "bus.receive_own_messages",
    "hardware",
    "controller",
    "sim",
    "nodes",
    "nodes.status_interval_s",
    "nodes.faults",
    "nodes.faults.*.end_tick",
    "nodes.faults.*.message",
    "nodes.faults.*.signal",
    "nodes.faults.*.value",
    "nodes.faults.*.probability",
    "nodes.faults.*.delay_ticks",
}


def test_only_the_listed_fields_have_defaults():
    """I8: safety parameters have no silent defaults. A new default must be added here, deliberately."""
    with_default = {
        dotted for dotted, field, _ in _schema_fields(Config)
        if field.default is not dataclasses.MISSING or field.default_factory is not dataclasses.MISSING
    }
    assert with_default == OPTIONAL_FIELDS


def _required_leaves(prefixes: tuple[str, ...]) -> list[str]:
    leaves = []
    for dotted, field, tp in _schema_fields(Config):
        if "*" in dotted or not dotted.startswith(prefixes):
            continue
        if field.default is not dataclasses.MISSING or field.default_factory is not dataclasses.MISSING:
            continue
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            continue  # a section: its leaves are listed
        leaves.append(dotted)
    return leaves


SAFETY_KEYS = _required_leaves(
    ("schema_version", "bus.", "protocol.", "controller.legs.", "controller.step.", "controller.envelope.",
     "controller.safety.",
     "nodes.", "hardware.joints.hip.", "hardware.joints.knee.")
)


def test_safety_keys_are_found():
    assert "nodes.command_timeout_ticks" in SAFETY_KEYS
    assert "controller.envelope.max_torque_nm" in SAFETY_KEYS
    assert "controller.safety.lost_ticks" in SAFETY_KEYS
    assert "hardware.joints.knee.torque_limit_nm" in SAFETY_KEYS
    assert len(SAFETY_KEYS) >= 25


@pytest.mark.parametrize("dotted", SAFETY_KEYS)
def test_every_safety_key_is_required(tmp_path, dotted):
    path = _write(tmp_path, _without(dotted))
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.key == dotted
    assert str(info.value) == f"{path}: {dotted}: missing required key"


# ---------------------------------------------------------------------------
# The real processes: exit 1 with the config error, before the bus is opened
# ---------------------------------------------------------------------------


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    script = Path(sys.executable).with_name("aider-exo")
    command = [str(script)] if script.exists() else [sys.executable, "-m", "tools.cli"]
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run(command + list(args), cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def _controller(path: Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return _cli("controller", "--config", str(path), "--bus", "socketcan", "--channel", CHANNEL, "--ticks", "1",
                cwd=cwd)


def _nodes(path: Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return _cli("nodes", "--config", str(path), "--bus", "socketcan", "--channel", CHANNEL, cwd=cwd)


def _error_lines(proc: subprocess.CompletedProcess[str]) -> list[str]:
    return [line for line in proc.stderr.splitlines() if line.strip() and not _PYBULLET_BANNER.match(line)]


def _assert_config_error_before_bus(proc: subprocess.CompletedProcess[str], expected: str) -> None:
    report = f"exit {proc.returncode}\nstdout: {proc.stdout!r}\nstderr: {proc.stderr!r}"
    assert proc.returncode == 1, report
    assert "Traceback" not in proc.stderr, report
    assert proc.stdout == "", report
    assert _error_lines(proc) == [f"aider-exo: error: {expected}"], report
    # Neither the --channel override nor the bus was reached: no bus or socket error in any form.
    assert CHANNEL not in proc.stderr, report
    assert "cannot open" not in proc.stderr and "AF_CAN" not in proc.stderr, report


def _library_message(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return str(info.value)


_RUNNERS = {"controller": _controller, "nodes": _nodes}
def _check_cli_run(tmp_path: Path, command: str, bad: Bad) -> None:
    """One CLI run per test (about 0.3 s; xdist spreads them over the cores: a batch of every
    run in one fixture was started by each worker whole, pytest 9 breaking xdist's loadgroup)."""
    path = _write(tmp_path, bad.text)
    proc = _RUNNERS[command](path, tmp_path)
    expected = _library_message(path)
    _check_message(bad, expected, path)
    _assert_config_error_before_bus(proc, expected)


@pytest.mark.parametrize("bad", _params(BAD))
def test_controller_cli_exits_with_the_config_error_before_the_bus(tmp_path, bad):
    _check_cli_run(tmp_path, "controller", bad)


@pytest.mark.parametrize("bad", _params([BY_ID[name] for name in NODES_SUBSET]))
def test_nodes_cli_exits_with_the_config_error_before_the_bus(tmp_path, bad):
    _check_cli_run(tmp_path, "nodes", bad)


@pytest.mark.parametrize("run", [_controller, _nodes], ids=["controller", "nodes"])
def test_control_a_valid_file_gets_as_far_as_the_bus(tmp_path, run):
    """The checks above can fail: with a valid file the same command stops at the bus, differently."""
    path = _write(tmp_path, DEFAULT)
    proc = run(path, tmp_path)
    assert proc.returncode == 1, proc.stderr
    lines = _error_lines(proc)
    assert len(lines) == 1 and lines[0].startswith(f"aider-exo: error: cannot open socketcan channel {CHANNEL!r}"), (
        proc.stderr
    )
    with pytest.raises(AssertionError):
        _assert_config_error_before_bus(proc, f"{path}: nodes.command_timeout_ticks: 6 is above the maximum 5")


def test_controller_without_its_section_exits_before_the_bus(tmp_path):
    path = _write(tmp_path, _without("controller"))
    assert load_config(path).controller is None  # the section is optional in the file ...
    proc = _controller(path, tmp_path)
    # ... but the controller refuses to run without it, naming file and key.
    _assert_config_error_before_bus(proc, f"{path}: controller: missing section (aider-exo controller needs it)")


@pytest.mark.parametrize("section", ["nodes", "sim"])
def test_nodes_without_its_section_exits_before_the_bus(tmp_path, section):
    path = _write(tmp_path, _without(section))
    proc = _nodes(path, tmp_path)
    _assert_config_error_before_bus(proc, f"{path}: {section}: missing section (aider-exo nodes needs it)")


# ---------------------------------------------------------------------------
# Tags are never executed
# ---------------------------------------------------------------------------


def _marker_tags(marker: Path) -> list[str]:
    return [
        f"!!python/object/apply:os.system [{json.dumps('touch ' + shlex.quote(str(marker)))}]",
        f"!!python/object/apply:builtins.open [{json.dumps(str(marker))}, w]",
    ]


@pytest.mark.parametrize("which", [0, 1], ids=["os.system", "builtins.open"])
def test_a_python_tag_is_never_executed(tmp_path, which):
    marker = tmp_path / "executed"
    tag = _marker_tags(marker)[which]
    path = _write(tmp_path, _text(_CTT, f"  command_timeout_ticks: {tag}"))

    with pytest.raises(ConfigError, match=r":\d+: unsupported YAML tag '!!python/object/apply:"):
        load_config(path)
    assert not marker.exists()
    proc = _controller(path, tmp_path)
    assert proc.returncode == 1 and "unsupported YAML tag" in proc.stderr, proc.stderr
    assert not marker.exists()

    # Self-check of the probe: PyYAML's unsafe loader does run the same value and creates the marker.
    made = yaml.unsafe_load(tag)
    if hasattr(made, "close"):
        made.close()
    assert marker.exists()


def test_the_config_package_never_calls_an_unsafe_yaml_loader():
    pattern = re.compile(r"yaml\.(load|full_load|unsafe_load|load_all|full_load_all|unsafe_load_all)\s*\(|"
                         r"\b(Unsafe|Full)Loader\b|yaml\.Loader\b")
    sources = sorted(Path(config_package.__file__).parent.glob("*.py"))
    assert sources
    for source in sources:
        found = pattern.search(source.read_text(encoding="utf-8"))
        assert found is None, f"{source.name}: {found.group(0) if found else ''}"
