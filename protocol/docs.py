"""Human-readable views of the catalogue: a JSON-ready dict, a terminal table, and docs/PROTOCOL.md.

All three are generated from the DBC (through :class:`protocol.catalog.Catalog`) and the bus-load
formulas; nothing here is written by hand, so the documentation cannot drift from the protocol.
"""

from __future__ import annotations

from typing import Any

from protocol.busload import frame_bits, load_report
from protocol.catalog import COUNTER_SIGNAL, CRC_SIGNAL, Catalog, MessageSpec, SignalSpec


def _period(m: MessageSpec) -> str:
    if m.cycle_ms is None:
        return "event"
    if m.period_ticks == 1:
        return f"{m.cycle_ms} ms"
    return f"{m.cycle_ms} ms (tick % {m.period_ticks} == {m.tick_phase})"


def _range(sig: SignalSpec) -> str:
    if sig.is_integer:
        return f"{int(sig.minimum)} .. {int(sig.maximum)}"
    return f"{sig.minimum:g} .. {sig.maximum:g}"


def signal_dict(sig: SignalSpec) -> dict[str, Any]:
    out: dict[str, Any] = {
        "name": sig.name,
        "start_bit": sig.start,
        "bits": sig.length,
        "signed": sig.signed,
        "scale": sig.scale,
        "offset": sig.offset,
        "min": sig.minimum,
        "max": sig.maximum,
        "unit": sig.unit,
    }
    if sig.choices is not None:
        out["choices"] = {str(k): v for k, v in sig.choices.items()}
    if sig.comment:
        out["comment"] = sig.comment
    return out


def catalog_dict(catalog: Catalog, bitrates: tuple[int, ...] = (500_000, 1_000_000)) -> dict[str, Any]:
    """The whole catalogue and its bus load as plain data (``aider-exo protocol --json``)."""
    return {
        "protocol_version": catalog.version,
        "dbc": catalog.source,
        "nodes": catalog.node_ids,
        "e2e": {
            "crc": "CRC-8 SAE J1850 (poly 0x1D, init 0xFF, xor-out 0xFF) over Data ID low, high byte, then bytes 1..DLC-1",
            "crc_signal": {"name": CRC_SIGNAL, "start_bit": 0, "bits": 8},
            "counter_signal": {"name": COUNTER_SIGNAL, "start_bit": 8, "bits": 4},
        },
        "messages": [
            {
                "id": m.frame_id,
                "id_hex": f"0x{m.frame_id:03X}",
                "name": m.name,
                "family": m.family,
                "sender": m.sender,
                "receivers": list(m.receivers),
                "dlc": m.dlc,
                "period_ms": m.cycle_ms,
                "tick_phase": m.tick_phase if m.cycle_ms else None,
                "data_id": m.data_id,
                "bits_worst_case": frame_bits(m.dlc),
                "signals": [signal_dict(s) for s in m.signals],
                "comment": m.comment,
            }
            for m in catalog.messages
        ],
        "bus_load": load_report(catalog, bitrates),
    }


def catalog_text(catalog: Catalog, bitrates: tuple[int, ...] = (500_000, 1_000_000)) -> str:
    """Terminal listing: one block per message, then the bus load."""
    lines = [f"AIDER CAN protocol v{catalog.version} ({catalog.source})", ""]
    for m in catalog.messages:
        receivers = ",".join(m.receivers)
        lines.append(f"0x{m.frame_id:03X} {m.name:<22} {m.sender} -> {receivers}  DLC {m.dlc}  {_period(m)}")
        for s in m.signals:
            unit = f" {s.unit}" if s.unit else ""
            kind = "enum" if s.choices is not None else f"x{s.scale:g}"
            lines.append(f"      {s.name:<24} bit {s.start:>2}+{s.length:<2} {kind:<8} [{_range(s)}]{unit}")
    report = load_report(catalog, bitrates)
    busiest = report["busiest_tick"]
    lines += ["", f"Busiest {report['tick_ms']} ms tick: {busiest['frames']} frames, {busiest['bits_worst']} bits worst case "
              f"({busiest['bits_nominal']} without stuffing)"]
    for rate, figures in report["bitrates"].items():
        lines.append(
            f"  at {int(rate) // 1000} kbit/s: {figures['busiest_tick_percent_worst']:.2f} % worst case, "
            f"{figures['busiest_tick_percent_nominal']:.2f} % nominal; with every event frame once: "
            f"{figures['busiest_tick_with_event_burst_percent_worst']:.2f} %"
        )
    return "\n".join(lines) + "\n"


# -- docs/PROTOCOL.md ----------------------------------------------------------------------------

def _md_table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def markdown(catalog: Catalog) -> str:
    """docs/PROTOCOL.md, generated (``aider-exo protocol --markdown``)."""
    report = load_report(catalog)
    lines = [
        "# AIDER CAN protocol",
        "",
        "<!-- Generated from protocol/aider.dbc by `aider-exo protocol --markdown > docs/PROTOCOL.md`."
        " Do not edit; a test fails when this file is stale. -->",
        "",
        f"Protocol version {catalog.version}: classic CAN, 11-bit identifiers, little-endian (Intel) signals,"
        " one controller and four node boards. The DBC file `protocol/aider.dbc` is the only definition;"
        " cantools, SavvyCAN and Vector tools read it directly.",
        "",
        "## Frame conventions",
        "",
        f"- Byte 0 of every frame is `{CRC_SIGNAL}`: CRC-8 SAE J1850 (polynomial 0x1D, initial value 0xFF,"
        " final XOR 0xFF) over the message's 16-bit Data ID (low byte, then high byte) followed by bytes"
        " 1..DLC-1 (AUTOSAR E2E profile 1 style). Each message has its own Data ID (DBC attribute"
        " `AiderDataId`), chosen so that no two messages share a CRC start value: a frame sent under"
        " another message's ID fails its CRC.",
        f"- Bits 8..11 are `{COUNTER_SIGNAL}`, the alive counter: +1 modulo 16 per frame of that message."
        " A receiver rejects a repeated counter (duplicate or frozen sender) and a jump beyond"
        " `protocol.max_delta_counter` (lost or reordered frames); smaller gaps are accepted and counted as"
        " lost frames. A sender's restart starts its counters again: a node's boot-up heartbeat and the"
        " controller's SYNC of tick 0, each with counter 0, make the next frame of each of its messages a first one.",
        "- Payload signals start at bit 12. Every signal has a physical range (DBC `[min|max]`); a received"
        " value outside it, or an enumerated value that is not listed, rejects the frame.",
        "- Cyclic messages follow the controller tick (20 ms): the controller sends SYNC with the tick number"
        " and its joint commands; each node answers every SYNC with its status and sensor frames. 100 ms"
        " heartbeats are spread over the five ticks of their period (DBC attribute `AiderTickPhase`:"
        " sent when `tick % 5 == phase`), so no tick carries more than one heartbeat.",
        "",
        "## Nodes and the sensors they carry",
        "",
        "Each node board collects the sensors near it (cables stay short):",
        "",
    ]
    rows = []
    for node, node_id in catalog.node_ids.items():
        sent = [m.name for m in catalog.sent_by(node)]
        rows.append([node, str(node_id), ", ".join(sent)])
    lines += _md_table(["node", "node ID", "sends"], rows)
    lines += [
        "",
        "- Left hip board: its joint, the left stick (load cell and IMU; the stick cable runs to the waist)"
        " and the trunk IMU (on the pelvis frame beside it).",
        "- Right hip board: its joint and the right stick.",
        "- Knee boards: their joint and the insole (plantar) sensors of the shoe on the same side.",
        "",
        "## Messages",
        "",
    ]
    rows = []
    for m in catalog.messages:
        rows.append([
            f"0x{m.frame_id:03X}", f"`{m.name}`", m.sender, ", ".join(m.receivers), str(m.dlc), _period(m),
            str(frame_bits(m.dlc)), f"0x{m.data_id:04X}",
        ])
    lines += _md_table(["ID", "name", "sender", "receivers", "DLC", "period", "bits (worst)", "Data ID"], rows)
    lines += ["", "## Signals", ""]
    seen_families: dict[str, str] = {}
    for m in catalog.messages:
        layout = tuple((s.name, s.start, s.length, s.scale, s.minimum, s.maximum) for s in m.signals)
        key = f"{m.family}:{layout}"
        if key in seen_families:
            continue
        same = [x.name for x in catalog.messages if x.family == m.family]
        seen_families[key] = m.name
        lines += [f"### {' / '.join(f'`{n}`' for n in same)}", "", m.comment, ""]
        rows = [[f"`{CRC_SIGNAL}`", "0", "8", "1", "0 .. 255", "", "E2E CRC-8"],
                [f"`{COUNTER_SIGNAL}`", "8", "4", "1", "0 .. 15", "", "alive counter"]]
        for s in m.signals:
            note = s.comment
            if s.choices is not None:
                note = (note + " " if note else "") + ", ".join(f"{k} {v}" for k, v in s.choices.items())
            raw = f"{'signed' if s.signed else 'unsigned'} {s.length}"
            rows.append([f"`{s.name}`", str(s.start), raw, f"{s.scale:g}", _range(s), s.unit, note])
        lines += _md_table(["signal", "start bit", "bits", "scale", "range", "unit", "notes"], rows)
        lines.append("")
    lines += [
        "## Resolution against the sensors",
        "",
        "Every sensor signal's scale is finer than the resolution of the device that measures it (DBC signal"
        " attributes `AiderSensor`, `AiderSensorResolution`; a test enforces it), and its raw range reaches"
        " beyond the physical range, which covers the device's full scale.",
        "",
    ]
    rows = []
    done: set[tuple[str, str]] = set()
    for m in catalog.messages:
        for s in m.signals:
            if s.sensor_resolution is None or (m.family, s.name) in done:
                continue
            done.add((m.family, s.name))
            lo = s.raw_min_representable * s.scale + s.offset
            hi = s.raw_max_representable * s.scale + s.offset
            rows.append([f"{m.family}.{s.name}", s.sensor, f"{s.sensor_resolution:g}", f"{s.scale:g}", _range(s), f"{lo:g} .. {hi:g}", s.unit])
    lines += _md_table(["signal", "sensor", "sensor resolution", "scale", "physical range", "representable", "unit"], rows)
    lines.append("")
    busiest = report["busiest_tick"]
    lines += [
        "## Bus load",
        "",
        f"Frame lengths from can-utils' `canframelen` formulas ({report['formula']}). The busiest tick of the"
        f" {busiest['hyperperiod_ticks']}-tick schedule carries {busiest['frames']} frames:"
        f" {busiest['bits_worst']} bits with worst-case bit stuffing, {busiest['bits_nominal']} without.",
        "",
    ]
    rows = []
    for rate, f in report["bitrates"].items():
        rows.append([
            f"{int(rate) // 1000} kbit/s", f"{f['busiest_tick_percent_worst']:.2f} %", f"{f['busiest_tick_percent_nominal']:.2f} %",
            f"{f['busiest_tick_with_event_burst_percent_worst']:.2f} %", f"{f['mean_percent_worst']:.2f} %",
        ])
    lines += _md_table(
        ["bitrate", "busiest tick (worst)", "busiest tick (nominal)", "busiest tick + every event frame once", "mean (worst)"],
        rows,
    )
    lines += ["", "Event frames (NMT commands, EMCY) are rare; the column with every event frame once is a bound, not a"
              " normal tick.", ""]
    return "\n".join(lines)
