"""docs/PERFORMANCE.md's table is made from the benchmarks' JSON in docs/perf (`make perf`), and
the table command fails clearly on what it cannot read. No benchmark runs here."""

from __future__ import annotations

import importlib
import json
import shutil

import pytest

from tests.conftest import ROOT
from tools.bench.summary import BEGIN, END, BenchError, block, render, run_all, update
from tools.cli import main
from tools.cli.bench import BENCHMARKS

PERF = ROOT / "docs" / "perf"
DOC = ROOT / "docs" / "PERFORMANCE.md"


def test_performance_md_shows_the_table_of_docs_perf():
    text = DOC.read_text()
    start, end = block(text, DOC)
    assert text[start:end] == render(PERF, BENCHMARKS), "stale: run `make perf` (or `aider-exo bench table docs/perf --update docs/PERFORMANCE.md`)"


@pytest.mark.parametrize("name", list(BENCHMARKS))
def test_every_benchmark_has_a_committed_result_and_its_rows(name):
    rows = importlib.import_module(BENCHMARKS[name]).table_rows(json.loads((PERF / f"{name}.json").read_text()))
    assert rows and all(len(r) == 3 and all(isinstance(cell, str) for cell in r) and r[1] for r in rows)
    assert all("|" not in cell for r in rows for cell in r)  # a cell must not break the Markdown table


def test_the_table_command_prints_rows_as_json(capsys):
    assert main(["bench", "table", str(PERF), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {r["command"] for r in rows} == {f"bench {name}" for name in BENCHMARKS}


def test_a_missing_or_damaged_result_is_one_line(tmp_path, capsys):
    shutil.copytree(PERF, tmp_path / "perf")
    (tmp_path / "perf" / "codec.json").write_text("{not json")
    assert main(["bench", "table", str(tmp_path / "perf")]) == 1
    err = capsys.readouterr().err
    assert "codec.json: not a benchmark's JSON" in err and err.count("\n") == 1
    (tmp_path / "perf" / "codec.json").write_text('{"results": {}}')
    assert main(["bench", "table", str(tmp_path / "perf")]) == 1
    assert "codec.json: not what bench codec writes" in capsys.readouterr().err
    (tmp_path / "perf" / "codec.json").unlink()
    assert main(["bench", "table", str(tmp_path / "perf")]) == 1
    assert "codec.json: missing (aider-exo bench all --out" in capsys.readouterr().err


def test_update_rewrites_only_the_block(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text(f"# before\n\n{BEGIN}\nold\n{END}\n\nafter\n")
    assert update(doc, f"{BEGIN}\nnew\n{END}\n")
    assert doc.read_text() == f"# before\n\n{BEGIN}\nnew\n{END}\n\nafter\n"
    assert not update(doc, f"{BEGIN}\nnew\n{END}\n")
    (tmp_path / "none.md").write_text("no markers\n")
    with pytest.raises(BenchError, match="no table markers"):
        update(tmp_path / "none.md", "x")


def test_a_failing_benchmark_stops_bench_all_with_its_error(tmp_path):
    with pytest.raises(BenchError, match=r"bench no-such-benchmark failed \(2\): .*invalid choice"):
        run_all(tmp_path, ["no-such-benchmark"], lambda _line: None)
