"""Reading and summarising the controller's per-tick telemetry logs (``aider-exo trace ticks``).

A log is JSON lines written by :class:`controller.telemetry.TelemetryLog`: the first line is the
schema (``{"schema": "aider-exo controller telemetry", "version": N, "fields": {...}}``), then one
record per tick. Several files are read one after the other, in the order given: a session's logs
moved aside at each restart of the controller (``NAME.<UTC>.jsonl``) and then the current one.

Time is the controller's: a record's tick times 20 ms from the first record of its file, the files
laid end to end (the time between a crash and the restart is not in the logs). What reading met is
counted, never raised: a last line cut short (the controller stopped in the middle of writing it),
a line that is not a record. A file that is not a telemetry log at all (no schema line, another
file, empty) or that was written by a newer schema is a :class:`TicksError`: one line naming the
file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller.telemetry import FIELDS, SCHEMA_VERSION
from protocol.clock import TICK_S
from tools.trace import TraceError

SCHEMA_NAME = "aider-exo controller telemetry"
EXAMPLES = 3
JOINTS = ("left hip", "left knee", "right hip", "right knee")


class TicksError(TraceError):
    """A telemetry log that cannot be read (one line, naming the file)."""


@dataclass
class LogFile:
    """One file as read: its schema version, its records' ticks, what was skipped."""

    path: str
    version: int | None = None
    records: int = 0
    first_tick: int | None = None
    last_tick: int | None = None
    missing_ticks: int = 0  # tick numbers not in the file between its first and last (dropped or skipped)
    bad_lines: int = 0  # lines that are not records (counted, skipped)
    truncated: bool = False  # the last line cut short (no newline, not JSON): skipped
    start_s: float = 0.0  # the file's first record on the session's time axis

    def as_dict(self) -> dict[str, Any]:
        return {"file": self.path, "schema_version": self.version, "records": self.records, "first_tick": self.first_tick,
                "last_tick": self.last_tick, "missing_ticks": self.missing_ticks, "bad_lines": self.bad_lines,
                "truncated_last_line": self.truncated, "start_s": round(self.start_s, 3)}


@dataclass
class Record:
    """One tick's record with its time on the session's axis."""

    time_s: float
    data: dict[str, Any]


@dataclass
class ReadTicks:
    """Everything read: the files, the skipped lines' examples, warnings."""

    files: list[LogFile] = field(default_factory=list)
    examples: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def skip(self, where: str) -> None:
        if len(self.examples) < EXAMPLES:
            self.examples.append(where)


def _schema(path: Path, line: str) -> int:
    """The schema version of the first line of ``path``, or why the file is not a telemetry log."""
    try:
        head = json.loads(line)
    except ValueError:
        head = None
    if isinstance(head, dict) and head.get("schema") == SCHEMA_NAME:
        version = head.get("version")
        if not isinstance(version, int) or isinstance(version, bool):
            raise TicksError(f"{path}: the schema line has no version number: not a telemetry log this aider-exo can read")
        if version > SCHEMA_VERSION:
            raise TicksError(f"{path}: telemetry schema version {version} is newer than this aider-exo reads "
                             f"(version {SCHEMA_VERSION}): read it with the aider-exo that wrote it, or update")
        return version
    if isinstance(head, dict) and "tick" in head and "state" in head:
        raise TicksError(f"{path}: no schema line (the first line is a tick's record): not a whole telemetry log; "
                         "its first line must be the schema the controller writes")
    raise TicksError(f"{path}: not a controller telemetry log (its first line is not the schema line "
                     f"'{{\"schema\": \"{SCHEMA_NAME}\", ...}}')")


def read_records(paths: Sequence[str | Path], read: ReadTicks, *, start_s: float | None = None,
                 end_s: float | None = None) -> Iterator[Record]:
    """The records of ``paths`` in order, on the session's time axis, those between ``start_s`` and
    ``end_s`` (seconds from the first record); what was met goes into ``read``. Each file is checked
    (exists, not a folder, its schema line) before its first record is given."""
    for p in paths:
        path = Path(p)
        if path.is_dir():
            raise TicksError(f"{path}: is a folder, not a telemetry log")
        if not path.is_file():
            raise TicksError(f"{path}: no such file")
    offset = 0.0
    for p in paths:
        path = Path(p)
        log = LogFile(str(path), start_s=offset)
        read.files.append(log)
        try:
            f = path.open("r", encoding="utf-8", errors="replace", newline="")
        except OSError as exc:
            raise TicksError(f"{path}: cannot read ({exc.strerror or exc})") from None
        with f:
            first = f.readline(1 << 20)  # the schema line is about 2 kB: not a whole binary file
            if not first:
                raise TicksError(f"{path}: the file is empty: not a telemetry log (the controller writes the schema line first)")
            log.version = _schema(path, first)
            wanted = set(FIELDS)
            line_no = 1
            for line in f:
                line_no += 1
                if not line.strip():
                    continue
                try:
                    data = json.loads(line)
                except ValueError:
                    data = None
                if not isinstance(data, dict) or not isinstance(data.get("tick"), int):
                    if not line.endswith("\n") and data is None:  # the last line, cut by a crash mid-write
                        log.truncated = True
                        read.skip(f"{path}:{line_no}: the last line is cut short")
                    else:
                        log.bad_lines += 1
                        read.skip(f"{path}:{line_no}: not a tick's record")
                    continue
                if len(data) != len(wanted) or set(data) != wanted:
                    data = {k: data.get(k) for k in FIELDS}  # an older schema: what it lacks is null
                tick = data["tick"]
                if log.first_tick is None:
                    log.first_tick = tick
                elif tick > log.last_tick + 1:
                    log.missing_ticks += tick - log.last_tick - 1
                log.records += 1
                log.last_tick = tick
                t = offset + (tick - log.first_tick) * TICK_S
                if (start_s is None or t >= start_s) and (end_s is None or t <= end_s):
                    yield Record(t, data)
        if log.first_tick is not None:
            offset += (log.last_tick - log.first_tick + 1) * TICK_S
        if log.version is not None and log.version < SCHEMA_VERSION:
            read.warnings.append(f"{path}: schema version {log.version} (this aider-exo writes {SCHEMA_VERSION}): "
                                 "fields it lacks are read as null")
        if log.truncated:
            read.warnings.append(f"{path}: the last line is cut short (the controller stopped while writing it): skipped")
        if log.bad_lines:
            read.warnings.append(f"{path}: {log.bad_lines} line(s) that are not a tick's record skipped")
        if log.records == 0:
            read.warnings.append(f"{path}: no tick's record in it (only the schema line)")


# -- the summary ---------------------------------------------------------------------------------


def percentiles(values: list[float]) -> dict[str, float] | None:
    """p50, p99 and max of ``values`` (nearest rank; None for none)."""
    if not values:
        return None
    s = sorted(values)

    def rank(q: float) -> float:
        return s[min(len(s) - 1, max(0, math.ceil(q * len(s)) - 1))]

    return {"p50": rank(0.50), "p99": rank(0.99), "max": s[-1]}


def _spread(values: list[float], digits: int) -> dict[str, Any] | None:
    if not values:
        return None
    return {"min": round(min(values), digits), "mean": round(sum(values) / len(values), digits), "max": round(max(values), digits)}


def event_kind(text: str) -> tuple[str, str]:
    """(category, kind) of one event of a record: ``fault``, ``fall``, ``hold``, ``transition``,
    ``step``, ``warning`` or ``other``; the kind is the cause's name (``NODE_LOST``) or the event."""
    if " -> " in text and ": " in text:
        states, cause = text.split(": ", 1)
        target = states.split(" -> ", 1)[1].strip()
        name = cause.split("(", 1)[0].strip()
        if target == "FAULT":
            return ("fall" if name == "FALL" else "fault"), name
        if target == "HOLD":
            return "hold", name
        return "transition", states.strip()
    if text.startswith("step "):
        return "step", "step"
    if text.endswith(": warning"):
        return "warning", text.split("(", 1)[0].strip()
    return "other", text.split("(", 1)[0].strip()


@dataclass
class Summary:
    records: int = 0
    first_s: float | None = None
    last_s: float | None = None
    states: dict[str, int] = field(default_factory=dict)  # ticks in each, in order of first appearance
    gait: dict[str, int] = field(default_factory=dict)
    step_lengths: dict[tuple[int, int], float] = field(default_factory=dict)  # (file, step index) -> length
    step_costs: list[float] = field(default_factory=list)
    events: dict[str, dict[str, int]] = field(default_factory=dict)  # category -> kind -> count
    work_us: list[float] = field(default_factory=list)
    lateness_us: list[float] = field(default_factory=list)

    def add(self, rec: Record, file_index: int) -> None:
        r = rec.data
        self.records += 1
        if self.first_s is None:
            self.first_s = rec.time_s
        self.last_s = rec.time_s
        state = r.get("state") or "(none)"
        self.states[state] = self.states.get(state, 0) + 1
        if r.get("gait"):
            self.gait[r["gait"]] = self.gait.get(r["gait"], 0) + 1
        if isinstance(r.get("step"), int) and isinstance(r.get("step_length_m"), (int, float)):
            self.step_lengths[(file_index, r["step"])] = float(r["step_length_m"])
        if isinstance(r.get("step_cost_n"), (int, float)):
            self.step_costs.append(float(r["step_cost_n"]))
        for e in r.get("events") or ():
            category, kind = event_kind(str(e))
            by_kind = self.events.setdefault(category, {})
            by_kind[kind] = by_kind.get(kind, 0) + 1
        for name, values in (("work_us", self.work_us), ("lateness_us", self.lateness_us)):
            v = r.get(name)
            if isinstance(v, (int, float)) and math.isfinite(v):
                values.append(float(v))

    def as_dict(self, read: ReadTicks) -> dict[str, Any]:
        def timed(counts: dict[str, int]) -> dict[str, dict[str, Any]]:
            return {k: {"ticks": n, "s": round(n * TICK_S, 2)} for k, n in counts.items()}

        def total(category: str) -> int:
            return sum(self.events.get(category, {}).values())

        lengths = list(self.step_lengths.values())
        files = [f.as_dict() for f in read.files]
        return {
            "files": files,
            "ticks": self.records,
            "duration_s": round(self.last_s - self.first_s + TICK_S, 2) if self.records else 0.0,
            "start_s": round(self.first_s, 2) if self.first_s is not None else None,
            "states": timed(self.states),
            "gait": timed(self.gait),
            "steps": {"count": len(lengths), "landed": len(self.step_costs),
                      "length_m": _spread(lengths, 3), "cost_n": _spread(self.step_costs, 1)},
            "falls": total("fall"), "faults": total("fault"), "holds": total("hold"),
            "events": {c: dict(sorted(k.items())) for c, k in sorted(self.events.items())},
            "work_us": percentiles(self.work_us),
            "lateness_us": percentiles(self.lateness_us),
            "missing_ticks": sum(f.missing_ticks for f in read.files),
            "bad_lines": sum(f.bad_lines for f in read.files),
            "truncated_lines": sum(f.truncated for f in read.files),
            "skipped_examples": read.examples,
            "warnings": read.warnings,
        }


def summarise(paths: Sequence[str | Path], *, start_s: float | None = None, end_s: float | None = None,
              series: Series | None = None) -> dict[str, Any]:
    """The summary of the logs ``paths`` (see :class:`Summary`; ``series``: also collect the curves)."""
    read = ReadTicks()
    summary = Summary()
    for rec in read_records(paths, read, start_s=start_s, end_s=end_s):
        summary.add(rec, len(read.files) - 1)
        if series is not None:
            series.add(rec)
    if summary.records == 0 and any(f.records for f in read.files):
        raise TicksError(f"no tick between {start_s or 0:g} s and {end_s if end_s is not None else 'the end'}"
                         f"{' s' if end_s is not None else ''} (the logs hold {read.files[-1].start_s + _span(read.files[-1]):.2f} s)")
    return summary.as_dict(read)


def _span(f: LogFile) -> float:
    return (f.last_tick - f.first_tick + 1) * TICK_S if f.first_tick is not None else 0.0


def format_text(r: dict[str, Any]) -> str:
    def pct(p: dict[str, float] | None) -> str:
        return "-" if p is None else f"p50 {p['p50']:.0f}, p99 {p['p99']:.0f}, max {p['max']:.0f} us"

    def timed(d: dict[str, dict[str, Any]]) -> str:
        return ", ".join(f"{k} {v['s']:.2f} s" for k, v in d.items()) or "-"

    files = r["files"]
    lines = [f"ticks: {r['ticks']} records, {r['duration_s']:.2f} s, from {len(files)} file(s)"
             + (f" ({', '.join(Path(f['file']).name for f in files)})" if len(files) > 1 else "")]
    lines.append(f"states: {timed(r['states'])}")
    lines.append(f"gait: {timed(r['gait'])}")
    s = r["steps"]
    text = f"steps: {s['count']} started, {s['landed']} landed"
    if s["length_m"]:
        text += f"; length {s['length_m']['min']:.3f}-{s['length_m']['max']:.3f} m (mean {s['length_m']['mean']:.3f})"
    if s["cost_n"]:
        text += f"; cost {s['cost_n']['min']:.1f}-{s['cost_n']['max']:.1f} N (mean {s['cost_n']['mean']:.1f})"
    lines.append(text)
    lines.append(f"falls {r['falls']}, faults {r['faults']}, protective stops {r['holds']}")
    for category in ("fall", "fault", "hold", "warning", "transition", "other"):
        kinds = r["events"].get(category)
        if kinds:
            lines.append(f"  {category}: " + ", ".join(f"{k} x{n}" for k, n in kinds.items()))
    lines.append(f"work: {pct(r['work_us'])}; lateness: {pct(r['lateness_us'])}")
    missing = [f"{r['missing_ticks']} tick(s) missing (records dropped by the writer, or ticks skipped by overruns)"] if r["missing_ticks"] else []
    skipped = []
    if r["truncated_lines"]:
        skipped.append(f"{r['truncated_lines']} last line(s) cut short")
    if r["bad_lines"]:
        skipped.append(f"{r['bad_lines']} line(s) not a record")
    if missing or skipped:
        lines.append("; ".join(missing + ([f"skipped: {', '.join(skipped)}"] if skipped else [])))
    return "\n".join(lines) + "\n"


# -- the figure ----------------------------------------------------------------------------------


def _floats(value: Any, n: int) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        return [math.nan] * n
    return [float(v) if isinstance(v, (int, float)) else math.nan for v in value]


def _float(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) else math.nan


@dataclass
class Series:
    """The curves of the figure, tick by tick."""

    t: list[float] = field(default_factory=list)
    q: list[list[float]] = field(default_factory=list)
    setpoint: list[list[float]] = field(default_factory=list)
    stick: list[list[float]] = field(default_factory=list)
    x_ratio: list[float] = field(default_factory=list)
    step_length: list[float] = field(default_factory=list)
    work_us: list[float] = field(default_factory=list)
    faults: list[tuple[float, str]] = field(default_factory=list)

    def add(self, rec: Record) -> None:
        r = rec.data
        self.t.append(rec.time_s)
        self.q.append(_floats(r.get("q_rad"), 4))
        self.setpoint.append(_floats(r.get("setpoint_rad"), 4))
        self.stick.append(_floats(r.get("stick_force_n"), 2))
        self.x_ratio.append(_float(r.get("x_ratio")))
        self.step_length.append(_float(r.get("step_length_m")))
        self.work_us.append(_float(r.get("work_us")))
        for e in r.get("events") or ():
            category, kind = event_kind(str(e))
            if category in ("fault", "fall", "hold"):
                self.faults.append((rec.time_s, kind))


def plot_png(series: Series, out: str | Path, *, title: str, inputs: Sequence[str | Path | None] = ()) -> dict[str, Any]:
    """Joint angles and setpoints, stick forces, X_CoM/X_SP, step lengths and the controller's work
    against time, to the PNG ``out`` (atomically, never over one of ``inputs``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from config.files import atomic_path

    if not series.t:
        raise TicksError("no tick to plot (or none in the chosen time range)")
    fig = Figure(figsize=(11, 12), layout="constrained")
    FigureCanvasAgg(fig)
    ax_q, ax_f, ax_x, ax_s, ax_w = fig.subplots(5, 1, sharex=True)
    colors = ("C0", "C1", "C2", "C3")
    for j, (name, color) in enumerate(zip(JOINTS, colors)):
        ax_q.plot(series.t, [q[j] for q in series.q], color=color, linewidth=1.0, label=name)
        ax_q.plot(series.t, [s[j] for s in series.setpoint], color=color, linewidth=0.8, linestyle="--")
    ax_q.set_ylabel("joint angle [rad]\n(dashed: setpoint)")
    for i, side in enumerate(("left", "right")):
        ax_f.plot(series.t, [f[i] for f in series.stick], linewidth=1.0, label=f"{side} stick")
    ax_f.set_ylabel("stick force [N]")
    ax_x.plot(series.t, series.x_ratio, linewidth=1.0, color="C4", label="X_CoM/X_SP")
    ax_x.set_ylabel("X_CoM / X_SP")
    ax_s.plot(series.t, series.step_length, linewidth=2.0, color="C5", label="step length (swings)")
    ax_s.set_ylabel("step length [m]")
    ax_w.plot(series.t, series.work_us, linewidth=0.6, color="C7", label="work")
    ax_w.set_ylabel("controller work [us]")
    ax_w.set_xlabel("controller time [s] (20 ms a tick, the files end to end)")
    for ax in (ax_q, ax_f, ax_x, ax_s, ax_w):
        for t, _ in series.faults:
            ax.axvline(t, color="red", linewidth=0.8, alpha=0.6)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    fig.suptitle(title + (f" ({len(series.faults)} fault/stop(s) in red)" if series.faults else ""))
    with atomic_path(out, inputs=inputs) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    return {"file": str(out), "panels": 5, "points": len(series.t), "faults_marked": len(series.faults)}
