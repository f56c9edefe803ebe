"""Every benchmark in one run, and their figures as one table (the one in docs/PERFORMANCE.md).

``aider-exo bench all --out DIR`` runs each benchmark as its own ``aider-exo bench NAME --json``
process, one after the other (so none measures beside another), and keeps each result as
``DIR/NAME.json`` with ``DIR/machine.json`` (the machine and the commit). ``aider-exo bench table
DIR`` renders the files as a Markdown table, or with ``--update FILE`` rewrites the block between
the table markers of FILE; a test fails when docs/PERFORMANCE.md's block and docs/perf disagree.
"""

from __future__ import annotations

import importlib
import json
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable

from config.errors import AiderError
from protocol.clock import MonotonicClock

ROOT = Path(__file__).resolve().parents[2]
BEGIN = "<!-- bench-table: made by `make perf` from docs/perf/*.json; do not edit by hand -->"
END = "<!-- /bench-table -->"
CODE = ("*.py", "*.dbc", "*.c", "config", "pyproject.toml")  # what the figures depend on (not docs, not docs/perf)


class BenchError(AiderError):
    """A benchmark failed, or a results directory or document is not what the table needs."""


def machine() -> dict[str, Any]:
    """What the figures were measured on: CPU, cores, kernel, Python, and the commit."""
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.exists() else []
    model = next((line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")), platform.processor())
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.strip()
        changed = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE], cwd=ROOT,
                                 capture_output=True, text=True, check=True).stdout.strip()
        if changed:
            commit += " with uncommitted changes to the code"
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    return {"cpu": model, "cores": os.cpu_count(), "kernel": platform.release(), "python": platform.python_version(),
            "commit": commit}


def run_all(out: Path, names: list[str], progress: Callable[[str], None]) -> dict[str, float]:
    """Run each benchmark of ``names`` into ``out/NAME.json``; the seconds each took."""
    out.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}
    clock = MonotonicClock()
    for i, name in enumerate(names, 1):
        progress(f"bench all: {i} of {len(names)}: {name}")
        start = clock.now_ns()
        proc = subprocess.run([sys.executable, "-m", "tools.cli", "bench", name, "--json"], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        seconds[name] = round((clock.now_ns() - start) / 1e9, 1)
        if proc.returncode != 0:
            last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            raise BenchError(f"bench {name} failed ({proc.returncode}): {last}")
        (out / f"{name}.json").write_text(proc.stdout)
    (out / "machine.json").write_text(json.dumps({**machine(), "seconds": seconds}, indent=2) + "\n")
    return seconds


def rows(results: Path, benchmarks: dict[str, str]) -> list[dict[str, str]]:
    """Every benchmark's summary rows from the files in ``results``, in the benchmarks' order."""
    out = []
    for name, module_name in benchmarks.items():
        path = results / f"{name}.json"
        if not path.exists():
            raise BenchError(f"{path}: missing (aider-exo bench all --out {results})")
        try:
            result = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise BenchError(f"{path}: not a benchmark's JSON ({exc})") from None
        try:
            table = importlib.import_module(module_name).table_rows(result)
        except (KeyError, TypeError, StopIteration) as exc:
            raise BenchError(f"{path}: not what bench {name} writes ({exc!r})") from None
        out += [{"command": f"bench {name}", "figure": f, "measured": m, "against": a} for f, m, a in table]
    return out


def markdown(table: list[dict[str, str]], where: dict[str, Any], profile: dict[str, Any]) -> str:
    """The block of docs/PERFORMANCE.md: every benchmark's rows, then where a walking tick's time goes."""
    lines = [
        BEGIN,
        f"Measured at commit {where['commit']} on {where['cores']} cores ({where['cpu']}), Linux {where['kernel']}, "
        f"Python {where['python']}; one `aider-exo bench all` run, each benchmark its own process.",
        "",
        "| command | figure | measured | goal or baseline (same run) |",
        "|---|---|---|---|",
    ]
    lines += [f"| `{r['command']}` | {r['figure']} | {r['measured']} | {r['against']} |" for r in table]
    timed, walk = profile["timed"], profile["walk"]
    lines += [
        "",
        f"Where a walking tick's time goes (`bench profile`: {profile['mode']}, seed {profile['seed']}, "
        f"{walk['cycles_completed']} gait cycles, {walk['ticks']} ticks): wall time per tick, unprofiled, inclusive "
        "(a deeper row is part of the row above it).",
        "",
        "| function | us per tick |",
        "|---|---|",
    ]
    lines += [f"| {'&nbsp;&nbsp;' * part['depth']}`{part['function']}` | {part['us_per_tick']:.0f} |" for part in timed["parts"]]
    lines += [
        "",
        "Own time by part of the system, under cProfile (which inflates the Python parts):",
        "",
        "| part | share |",
        "|---|---|",
    ]
    lines += [f"| {part['part']} | {part['share'] * 100:.1f} % |" for part in profile["parts"]]
    lines.append(END)
    return "\n".join(lines) + "\n"


def render(results: Path, benchmarks: dict[str, str]) -> str:
    where = results / "machine.json"
    if not where.exists():
        raise BenchError(f"{where}: missing (aider-exo bench all --out {results})")
    table = rows(results, benchmarks)  # checks every file first
    return markdown(table, json.loads(where.read_text()), json.loads((results / "profile.json").read_text()))


def block(document: str, path: Path) -> tuple[int, int]:
    """Where the generated table sits in ``document`` (start of BEGIN, end of END)."""
    start, end = document.find(BEGIN), document.find(END)
    if start < 0 or end < start:
        raise BenchError(f"{path}: no table markers ({BEGIN} ... {END})")
    return start, end + len(END) + 1


def update(path: Path, table: str) -> bool:
    """Put ``table`` between the markers of ``path``; whether the file changed."""
    text = path.read_text()
    start, end = block(text, path)
    new = text[:start] + table + text[end:]
    if new != text:
        path.write_text(new)
    return new != text
