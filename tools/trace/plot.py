"""Chosen signals against time, to a PNG (matplotlib, without its global pyplot state).

One panel per unit (signals of the same unit share an axis); frames of the plotted messages that
failed a check (CRC, counter, range) are marked on the time axis of every panel, so a glitch in a
curve can be told from a bus error at a glance.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from config.files import atomic_path
from tools.trace import TraceError
from tools.trace.decode import OK, Formatter, Row


def collect(rows: Iterable[Row], fmt: Formatter) -> tuple[dict[tuple[str, str], tuple[str, list[float], list[float]]], list[float]]:
    """(message, signal) -> (unit, times, values) of the shown signals, and the times of bad frames."""
    series: dict[tuple[str, str], tuple[str, list[float], list[float]]] = {}
    bad: list[float] = []
    for row in rows:
        if row.spec is None:
            continue
        if row.status != OK:
            bad.append(row.time_s)
            if row.values is None:
                continue
        for sig, value in fmt.signals(row):
            entry = series.get((row.spec.name, sig.name))
            if entry is None:
                entry = series[(row.spec.name, sig.name)] = (sig.unit, [], [])
            entry[1].append(row.time_s)
            entry[2].append(float(value))
    return series, bad


def plot_png(rows: Iterable[Row], fmt: Formatter, out: str | Path, *, title: str,
             inputs: Iterable[str | Path | None] = ()) -> dict[str, Any]:
    """Plot the chosen signals of ``rows`` to the PNG ``out`` (atomically; never over one of ``inputs``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    series, bad = collect(rows, fmt)
    if not series:
        raise TraceError("no values of the chosen signals in the trace (or in the chosen time range)")
    by_unit: dict[str, list[tuple[str, str]]] = defaultdict(list)
    for key, (unit, _, _) in series.items():
        by_unit[unit].append(key)
    fig = Figure(figsize=(11, 2.6 * len(by_unit) + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(by_unit), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (unit, keys) in zip(axes, sorted(by_unit.items())):
        for key in keys:
            _, times, values = series[key]
            ax.plot(times, values, linewidth=1.0, label=f"{key[0]}.{key[1]}", drawstyle="steps-post")
        if bad:
            ax.plot(bad, [0.0] * len(bad), linestyle="none", marker="|", color="red", markersize=12,
                    transform=ax.get_xaxis_transform(), label=f"bad frames ({len(bad)})")
        ax.set_ylabel(unit or "(no unit)")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("time since the first frame [s]")
    fig.suptitle(title)
    with atomic_path(out, inputs=inputs) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    return {"file": str(out), "panels": len(by_unit), "signals": [f"{m}.{s}" for m, s in series],
            "points": sum(len(v[1]) for v in series.values()), "bad_frames": len(bad)}
