"""The generated blocks of the hand-written documents: every figure in them comes from the code.

A document marks a block with ``<!-- generated: NAME ... -->`` and ``<!-- /generated: NAME -->``;
``python -m tools.docgen --update FILE...`` (``make docs``) rewrites what lies between the two
from :data:`BLOCKS`, and ``--check`` (``tests/unit/test_docs_generated.py``) fails on a stale block.
The prose around a block is written by hand and quotes no figure of its own.

* docs/FIRMWARE.md: CRC-8 test vectors, every message's Data ID, CRC seed and an example frame,
  a worked example of every frame kind, the node IDs, the timing a node board must keep; encoded
  and decoded by the project's own codec (:mod:`protocol.codec`), never typed by hand.
* docs/FAULTS.md: the controller's fault kinds (:class:`controller.faults.FaultKind`).
* docs/TRACE.md: the ``trace record --walk`` / ``trace resim`` transcript, run here through the
  real command line, and the figures of the last ``make perf`` (docs/perf/trace.json).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import shlex
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from protocol.catalog import COUNTER_SIGNAL, CRC_SIGNAL, Catalog, MessageSpec, default_catalog
from protocol.codec import Codec, Decoded
from protocol.crc import INIT, POLY, XOR_OUT, crc8_plain
from protocol.enums import (
    DriveState, EmcyCode, GaitState, JointMode, NmtCommand, NmtState, NodeError, PolicyMode,
)

ROOT = Path(__file__).resolve().parents[1]
CAN_UNIT = ROOT / "tools" / "deploy" / "aider-can0.service"
BEGIN = re.compile(r"^<!-- generated: ([\w-]+)[^\n]*-->\n", re.M)


class DocgenError(Exception):
    """A document's generated blocks cannot be found or made."""


def _md_table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return out + ["| " + " | ".join(r) + " |" for r in rows]


def _hex(data: bytes) -> str:
    return " ".join(f"{b:02X}" for b in data)


# -- the bus set-up the unit applies (docs/DEPLOY.md quotes the same) ----------------------------

def can_link_settings(unit: Path = CAN_UNIT) -> dict[str, str]:
    """The ``ip link set can0 type can ...`` settings of the can0 unit: bitrate, sample-point, restart-ms."""
    for line in unit.read_text().splitlines():  # every ExecStart= line (configparser keeps only the last)
        if not line.startswith("ExecStart="):
            continue
        words = shlex.split(line.removeprefix("ExecStart="))
        if "type" in words and words[words.index("type") + 1:words.index("type") + 2] == ["can"]:
            rest = words[words.index("type") + 2:]
            return dict(zip(rest[::2], rest[1::2]))
    raise DocgenError(f"{unit}: no 'ip link set ... type can' line")


# -- CRC-8 ---------------------------------------------------------------------------------------

#: Inputs whose CRC the page lists: the standard check input, the empty input, and AUTOSAR's
#: published CRC-8 SAE J1850 vectors (SWS CRC Library; tests/unit/test_docs_generated.py holds their values).
CRC_INPUTS: tuple[tuple[str, bytes], ...] = (
    ('ASCII "123456789" (the standard check value)', b"123456789"),
    ("empty (the final XOR of the initial value)", b""),
    ("AUTOSAR vector", bytes.fromhex("00000000")),
    ("AUTOSAR vector", bytes.fromhex("F20183")),
    ("AUTOSAR vector", bytes.fromhex("0FAA0055")),
    ("AUTOSAR vector", bytes.fromhex("00FF5511")),
    ("AUTOSAR vector", bytes.fromhex("332255AABBCCDDEEFF")),
    ("AUTOSAR vector", bytes.fromhex("926B55")),
    ("AUTOSAR vector", bytes.fromhex("FFFFFFFF")),
)

#: Example values of every frame kind (one message per family; the node variants differ only by
#: ID, Data ID and so CRC). Each is encoded by the codec and decoded again for the page.
EXAMPLES: dict[str, dict[str, Any]] = {
    "NMT_COMMAND": {"command": NmtCommand.START, "node_id": 0},
    "SYNC": {"tick": 1234},
    "EMCY_LH": {"emcy_code": EmcyCode.COMMAND_TIMEOUT, "error_register": 0x11, "detail": 3},
    "JOINT_STATUS_LH": {"drive_state": DriveState.TRACK, "error_code": NodeError.NONE, "position_rad": 0.3512,
                        "velocity_rad_s": -1.204, "torque_Nm": 12.35},
    "JOINT_COMMAND_LH": {"mode": JointMode.TRACK, "position_setpoint_rad": 0.35, "velocity_ff_rad_s": -1.2,
                         "torque_ff_Nm": 5.0, "torque_limit_Nm": 60},
    "STICK_LEFT": {"force_N": 250.5, "roll_rad": 0.0128, "pitch_rad": -0.1504, "yaw_rad": 0.0},
    "PLANTAR_LEFT": {"heel_force_N": 310.5, "toe_force_N": 120.0},
    "TRUNK_IMU_ORIENTATION": {"roll_rad": 0.0125, "pitch_rad": 0.1, "yaw_rad": -0.05},
    "TRUNK_IMU_RATE": {"rate_x_rad_s": 0.012, "rate_y_rad_s": -0.25, "rate_z_rad_s": 0.003},
    "TRUNK_IMU_ACCEL": {"specific_force_x_m_s2": 0.5, "specific_force_y_m_s2": -0.12, "specific_force_z_m_s2": 9.81},
    "HEARTBEAT_LH": {"nmt_state": NmtState.OPERATIONAL, "supply_voltage_V": 48.02},
    "CONTROLLER_HEARTBEAT": {"gait_state": GaitState.DOUBLE_SUPPORT},
    "CONTROLLER_STEP": {"step_index": 12, "step_length_m": 0.35, "placed_step_m": 0.342, "step_cost_N": 85.5,
                        "policy": PolicyMode.LEARNING},
    "CONTROLLER_LEARNING": {"alpha": 1.25, "xhat_com": -0.05, "update_index": 3, "rollout_index": 2,
                            "cycle_index": 1, "cycle_cost_N": 42.5},
}
EXAMPLE_COUNTER = 7  # the alive counter of every example frame
HEX_SIGNALS = frozenset({"emcy_code", "error_register"})  # codes and bit fields, shown in hex


def example_frame(codec: Codec, spec: MessageSpec) -> tuple[bytes, Decoded]:
    """The example payload of ``spec`` (its family's example values) and its decoding."""
    example = next(name for name in EXAMPLES if codec.spec(name).family == spec.family)
    values = {k: (int(v) if hasattr(v, "name") else v) for k, v in EXAMPLES[example].items()}
    data = codec.encode(spec, values, EXAMPLE_COUNTER)
    decoded = codec.decode(spec.frame_id, data)
    if not isinstance(decoded, Decoded):
        raise DocgenError(f"{spec.name}: the example frame does not decode: {decoded}")
    return data, decoded


def _raw(spec_data: bytes, start: int, length: int, signed: bool) -> int:
    raw = (int.from_bytes(spec_data, "little") >> start) & ((1 << length) - 1)
    return raw - (1 << length) if signed and raw >> (length - 1) else raw


def _value(decoded: Decoded, name: str) -> str:
    sig = decoded.message.signal(name)
    value = getattr(decoded.values, name)
    if sig.choices is not None:
        return f"{sig.choices[value]} ({value:#06x})" if name in HEX_SIGNALS else f"{sig.choices[value]} ({value})"
    if sig.is_integer:
        return f"{int(value):#04x}" if name in HEX_SIGNALS else str(int(value))
    digits = max(0, -int(f"{sig.scale:e}".split("e")[1]))  # the digits of the scale
    return f"{value:.{digits}f}"


def block_crc_vectors(catalog: Catalog, codec: Codec) -> list[str]:
    rows = [[what, f"`{_hex(data)}`" if data else "(none)", f"0x{crc8_plain(data):02X}"] for what, data in CRC_INPUTS]
    sync = catalog.by_name("SYNC")
    data, decoded = example_frame(codec, sync)
    crc_input = sync.data_id.to_bytes(2, "little") + data[1:]
    rows.append([f"the SYNC frame of the worked example below (tick {decoded.values.tick}, counter {decoded.counter}):"
                 f" Data ID 0x{sync.data_id:04X} low, high byte, then bytes 1..{sync.dlc - 1}",
                 f"`{_hex(crc_input)}`", f"0x{crc8_plain(crc_input):02X} (byte 0 of `{_hex(data)}`)"])
    if crc8_plain(crc_input) != data[0]:
        raise DocgenError("the SYNC example's CRC differs from crc8 over its Data ID and bytes")
    lines = [f"Parameters: width 8, polynomial 0x{POLY:02X}, initial value 0x{INIT:02X}, input and output not"
             f" reflected, final XOR 0x{XOR_OUT:02X} (CRC-8/SAE-J1850).", ""]
    return lines + _md_table(["input", "bytes (hex)", "CRC-8"], rows)


def block_messages(catalog: Catalog, codec: Codec) -> list[str]:
    rows = []
    for m in catalog.messages:
        data, _ = example_frame(codec, m)
        rows.append([f"0x{m.frame_id:03X}", f"`{m.name}`", m.sender, str(m.dlc), f"0x{m.data_id:04X}",
                     f"`{_hex(m.data_id.to_bytes(2, 'little'))}`", f"0x{m.crc_seed:02X}", f"`{_hex(data)}`"])
    return _md_table(["ID", "message", "sender", "DLC", "Data ID", "CRC input prefix", "register after it",
                      f"example frame (counter {EXAMPLE_COUNTER})"], rows)


def block_frame_examples(catalog: Catalog, codec: Codec) -> list[str]:
    lines: list[str] = []
    for name in EXAMPLES:
        spec = catalog.by_name(name)
        data, decoded = example_frame(codec, spec)
        family = [m.name for m in catalog.messages if m.family == spec.family]
        also = f" (the same layout as {', '.join(f'`{n}`' for n in family if n != name)})" if len(family) > 1 else ""
        title = f"`{name}`" if spec.family == name else f"{spec.family}: `{name}`"
        lines += [f"#### {title}{also}", "",
                  f"ID 0x{spec.frame_id:03X}, DLC {spec.dlc}, data `{_hex(data)}`; CRC over"
                  f" `{_hex(spec.data_id.to_bytes(2, 'little') + data[1:])}` (Data ID 0x{spec.data_id:04X}, then bytes 1..{spec.dlc - 1}).", ""]
        rows = [[f"`{CRC_SIGNAL}`", "0", "u8", f"0x{data[0]:02X}", f"0x{data[0]:02X}", ""],
                [f"`{COUNTER_SIGNAL}`", "8", "u4", str(data[1] & 0xF), str(decoded.counter), ""]]
        for sig in spec.signals:
            raw = _raw(data, sig.start, sig.length, sig.signed)
            rows.append([f"`{sig.name}`", str(sig.start), f"{'s' if sig.signed else 'u'}{sig.length}", str(raw),
                         _value(decoded, sig.name), sig.unit])
        lines += _md_table(["signal", "start bit", "bits", "raw", "value", "unit"], rows) + [""]
    return lines[:-1]


def block_node_ids(catalog: Catalog, codec: Codec) -> list[str]:
    bases: dict[str, set[int]] = {}
    rows = []
    for node, node_id in catalog.node_ids.items():
        sent = [m for m in catalog.sent_by(node)]
        addressed = [m for m in catalog.messages if m.receivers == (node,)]
        if node != "CONTROLLER":
            for m in sent + addressed:
                bases.setdefault(m.family, set()).add(m.frame_id - node_id)
        alone = ", ".join(f"0x{m.frame_id:03X} `{m.name}`" for m in addressed) or "-"
        if node == "CONTROLLER":
            alone = "every node board's frames"
        rows.append([node, str(node_id), ", ".join(f"0x{m.frame_id:03X} `{m.name}`" for m in sent), alone])
    uneven = sorted(f for f, b in bases.items() if len(b) > 1)
    if uneven:
        raise DocgenError(f"identifiers that are not a base plus the node ID: {uneven}")
    lines = _md_table(["node", "node ID (DBC `AiderNodeId`)", "sends", "receives alone"], rows)
    rule = ", ".join(f"{family} 0x{next(iter(b)):03X}" for family, b in sorted(bases.items(), key=lambda i: min(i[1])))
    return lines + ["", f"Every identifier a node board sends, or receives alone, is its family's base plus the node ID: {rule}."
                    " `NMT_COMMAND.node_id` addresses one board by its node ID, or every board with 0."]


def block_node_timing(catalog: Catalog, codec: Codec) -> list[str]:
    from config import default_config_path, load_config

    cfg = load_config(default_config_path())
    link = can_link_settings()
    bitrate = int(link["bitrate"])
    heartbeat = next(m for m in catalog.messages if m.family == "HEARTBEAT")
    recovery_bits = 128 * 11  # ISO 11898-1: 128 occurrences of 11 consecutive recessive bits
    assert cfg.nodes is not None
    rows = [
        ["controller tick (SYNC period)", f"{catalog.by_name('SYNC').cycle_ms} ms", "`protocol/aider.dbc` (`GenMsgCycleTime` of `SYNC`)"],
        ["node heartbeat period", f"{heartbeat.cycle_ms} ms", f"`{heartbeat.name}` and its siblings (`GenMsgCycleTime`)"],
        ["node command watchdog", f"{cfg.nodes.command_timeout_ticks} ticks", "`nodes.command_timeout_ticks`"],
        ["node controller-heartbeat watchdog", f"{cfg.nodes.heartbeat_timeout_ms} ms", "`nodes.heartbeat_timeout_ms`"],
        ["controller: a node is lost after", f"{cfg.controller.safety.lost_ticks} ticks without its status",
         "`controller.safety.lost_ticks`"],
        ["largest alive-counter step a receiver accepts", str(cfg.protocol.max_delta_counter), "`protocol.max_delta_counter`"],
        ["bitrate", f"{bitrate} bit/s", f"`{CAN_UNIT.relative_to(ROOT)}`"],
        ["sample point", f"{float(link['sample-point']) * 100:g} %", f"`{CAN_UNIT.relative_to(ROOT)}`"],
        ["controller adapter's `restart-ms`", f"{link['restart-ms']} ms", f"`{CAN_UNIT.relative_to(ROOT)}`"],
        ["bus-off recovery, at the least (128 x 11 recessive bits)",
         f"{recovery_bits} bit times, {recovery_bits / bitrate * 1000:g} ms at {bitrate // 1000} kbit/s", "ISO 11898-1"],
    ]
    return _md_table(["what", "value", "where it is set"], rows)


# -- docs/TRACE.md -------------------------------------------------------------------------------

RESIM_COMMANDS = (
    "trace record walk.log --walk 1 --seed 1",
    "trace resim walk.log",
    "trace resim walk.log --set controller.gait.lean_speed_m_s=0.08",
)
RESIM_LINES_SHOWN = 2  # of the divergences listed after the result line


def block_resim_example(catalog: Catalog, codec: Codec) -> list[str]:
    from tools.cli import main

    lines = ["```"]
    with tempfile.TemporaryDirectory() as folder:
        here = os.getcwd()
        os.chdir(folder)
        try:
            for command in RESIM_COMMANDS:
                out = io.StringIO()
                with contextlib.redirect_stdout(out):
                    code = main(shlex.split(command))
                if code not in (0, 1):
                    raise DocgenError(f"aider-exo {command}: exit status {code}")
                printed = out.getvalue().splitlines()
                result = next((i for i, line in enumerate(printed) if line.startswith("result: ")), len(printed) - 1)
                shown = printed[:result + 1 + RESIM_LINES_SHOWN]
                lines += [f"$ aider-exo {command}", *shown] + (["  ..."] if len(printed) > len(shown) else [])
        finally:
            os.chdir(here)
    return lines + ["```"]


def block_trace_bench(catalog: Catalog, codec: Codec) -> list[str]:
    r = json.loads((ROOT / "docs" / "perf" / "trace.json").read_text())
    decode, replay = r["decode"], r["replay"]
    normal = replay["normal_priority"]
    ours, sync = normal["ours"]["median_of_rounds"], normal["python-can MessageSync"]["median_of_rounds"]
    stall = replay["stall"]
    rt = replay["realtime"]["ours"]["median_of_rounds"]
    return [
        f"What the last run shows (docs/perf/trace.json): decoding {decode['frames']:,} frames, ours decodes"
        f" {decode['speedup_file']:g} times as many frames per second as cantools from the file and"
        f" {decode['speedup_in_memory']:g} times in memory, with the"
        " checks cantools lacks (cantools decodes through a C extension, bitstruct; ours is pure Python compiled"
        f" from the DBC, `protocol/codec.py`). Replaying {replay['frames']:,} frames ({replay['trace_seconds']:g} s) at"
        " normal priority, the"
        f" median round's p99 error was {ours['p99']:g} us for ours against {sync['p99']:g} us for `MessageSync`"
        f" ({rt['p99']:g} us for ours with the real-time set-up); after a {stall['stall_ms']:g} ms stall ours sent"
        f" at most {stall['ours']['max_frames_in_1ms_after_stall']} frames in 1 ms against"
        f" {stall['python-can MessageSync']['max_frames_in_1ms_after_stall']} (the trace itself has"
        f" {stall['trace_max_frames_in_1ms']}). The spread between runs on a VM is large: CHANGELOG.md keeps"
        " runs made under load.",
    ]


def block_fault_kinds(catalog: Catalog, codec: Codec) -> list[str]:
    from controller.faults import FaultKind

    rows = [[f"`{k.name}`", k.row, k.reaction.value, "yes" if k.stall_can_explain else "no"] for k in FaultKind]
    return _md_table(["kind", "row", "reaction", "a stall can explain it"], rows)


BLOCKS: dict[str, Callable[[Catalog, Codec], list[str]]] = {
    "crc-vectors": block_crc_vectors,
    "messages": block_messages,
    "frame-examples": block_frame_examples,
    "node-ids": block_node_ids,
    "node-timing": block_node_timing,
    "resim-example": block_resim_example,
    "trace-bench": block_trace_bench,
    "fault-kinds": block_fault_kinds,
}
DOCUMENTS = (ROOT / "docs" / "FIRMWARE.md", ROOT / "docs" / "TRACE.md", ROOT / "docs" / "FAULTS.md")


def blocks_of(text: str, path: Path) -> list[tuple[str, int, int]]:
    """(name, start, end) of the body of every generated block of ``text``."""
    found = []
    for begin in BEGIN.finditer(text):
        name = begin.group(1)
        if name not in BLOCKS:
            raise DocgenError(f"{path}: unknown generated block {name!r} (known: {', '.join(BLOCKS)})")
        end = text.find(f"<!-- /generated: {name} -->", begin.end())
        if end < 0:
            raise DocgenError(f"{path}: block {name!r} has no end marker <!-- /generated: {name} -->")
        found.append((name, begin.end(), end))
    return found


def render(name: str, catalog: Catalog | None = None, codec: Codec | None = None) -> str:
    catalog = catalog or default_catalog()
    return "\n".join(BLOCKS[name](catalog, codec or Codec(catalog))) + "\n"


def regenerate(path: Path, only: set[str] | None = None) -> tuple[str, list[str]]:
    """The text of ``path`` with its blocks (or those in ``only``) made again, and the names of those that changed."""
    text = path.read_text()
    catalog = default_catalog()
    codec = Codec(catalog)
    changed, out, at = [], [], 0
    for name, start, end in blocks_of(text, path):
        if only is not None and name not in only:
            continue
        body = render(name, catalog, codec)
        if text[start:end] != body:
            changed.append(name)
        out += [text[at:start], body]
        at = end
    return "".join(out) + text[at:], changed


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.docgen", description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="*", type=Path, help=f"documents (default: {', '.join(str(d.relative_to(ROOT)) for d in DOCUMENTS)})")
    p.add_argument("--check", action="store_true", help="exit 1 naming every stale block; write nothing")
    p.add_argument("--block", action="append", help="only this block (repeatable)")
    args = p.parse_args(argv)
    stale = []
    for path in args.files or DOCUMENTS:
        try:
            text, changed = regenerate(path, set(args.block) if args.block else None)
        except (DocgenError, OSError) as exc:
            print(f"docgen: error: {exc}", file=sys.stderr)
            return 1
        stale += [f"{path}: {name}" for name in changed]
        if changed and not args.check:
            tmp = path.with_name(f".{path.name}.docgen")
            tmp.write_text(text)
            tmp.replace(path)
    for line in stale:
        print(("stale " if args.check else "updated ") + line)
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
