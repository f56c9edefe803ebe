"""`aider-exo bench sim` runs both modes and reports its figures (the bus tick, the overhead over
bare physics); how fast is measured by `make perf`, never asserted here."""

from __future__ import annotations

import json

from tools.bench import sim as bench_sim
from tools.cli import main


def test_bench_sim_reports_both_modes_at_the_bus_tick(capsys):
    assert main(["bench", "sim", "--seconds", "0.4", "--repeats", "1", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["tick_hz"] == 50.0
    assert [m["mode"] for m in r["modes"]] == ["full3d", "sagittal"]
    for m in r["modes"]:
        assert m["simulated_s"] > 0.3 and m["physics_steps"] > 0 and m["overhead_percent_runs"] == [m["overhead_percent"]]
    assert bench_sim.table_rows(r) and "simulation benchmark" in bench_sim.format_text(r)
