"""``aider-exo bench trace`` measures real runs (its figures are printed, never asserted here)."""

from __future__ import annotations

import argparse

from tools.bench import trace as bench


def test_the_trace_benchmark_runs_both_decoders_and_both_players():
    args = argparse.Namespace(frames=2000, repeats=1, cli_frames=0, replay_seconds=0.2, rounds=1, no_realtime=True)
    r = bench.run(args)
    assert r["decode"]["frames"] == 2000 and set(r["decode"]["frames_per_s"]) == {
        "ours_file", "ours_file_to_jsonl", "ours_in_memory", "cantools_file", "cantools_in_memory"}
    assert all(v["median"] > 0 for v in r["decode"]["frames_per_s"].values())
    assert set(r["replay"]["normal_priority"]) == set(bench.PLAYERS) and "realtime" not in r["replay"]
    assert r["replay"]["stall"]["trace_max_frames_in_1ms"] > 0
    text = bench.format_text(r)
    assert "ours / cantools" in text and "python-can MessageSync" in text
