"""Tick statistics (cyclictest style) and the real-time set-up's reporting (protocol/realtime.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from controller.timing import TickStats, quantile_interval
from protocol import realtime as timing
from protocol.realtime import realtime_setup
from tests.conftest import ROOT

PERIOD = 20_000_000


def test_statistics_of_known_ticks():
    stats = TickStats(PERIOD, capacity=1000)
    for k in range(100):
        stats.record(lateness_ns=1_000 * k, work_ns=500_000)
    stats.record(lateness_ns=3_000_000, work_ns=19_000_000)  # 22 ms: past the next boundary
    s = stats.summary()
    assert s["ticks"] == 101 and s["overruns"] == 1
    assert s["work"]["min_us"] == 500.0 and s["work"]["max_us"] == 19000.0
    assert s["wakeup_lateness"]["min_us"] == 0.0 and s["wakeup_lateness"]["max_us"] == 3000.0
    assert 98.0 <= s["wakeup_lateness"]["p99_us"] <= 3000.0
    assert "overruns 1" in stats.format()


def test_the_ring_keeps_the_newest_ticks():
    stats = TickStats(PERIOD, capacity=10)
    for k in range(25):
        stats.record(lateness_ns=0, work_ns=k * 1000)
    s = stats.summary()
    assert s["ticks"] == 25 and s["samples"] == 10 and s["work"]["min_us"] == 15.0


def test_realtime_setup_warns_for_every_step_the_os_refuses(monkeypatch):
    def refuse(*_args, **_kwargs):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(timing.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(timing.os, "sched_setaffinity", refuse)

    class NoLock:
        def mlockall(self, _flags):
            return -1

    monkeypatch.setattr(timing.ctypes, "CDLL", lambda *_a, **_k: NoLock())
    report = realtime_setup(cpu=0, dma_latency_path="/nonexistent/cpu_dma_latency")
    try:
        assert report.applied == ["linear-algebra buffers allocated", "gc.freeze"]
        joined = " | ".join(report.warnings)
        for what in ("mlockall", "CPU 0", "SCHED_FIFO", "cpu_dma_latency"):
            assert what in joined
        assert len(report.warnings) == 4
    finally:
        report.close()
        import gc

        gc.unfreeze()


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root")
def test_realtime_setup_as_root_applies_what_the_kernel_offers():
    report = realtime_setup(lock_memory=False)
    try:
        assert {"linear-algebra buffers allocated", "gc.freeze"} <= set(report.applied)
        assert len(report.applied) + len(report.warnings) == 4
    finally:
        report.close()
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        import gc

        gc.unfreeze()


def test_realtime_setup_allocates_the_linear_algebra_buffers_before_the_loop():
    """After the set-up, the DMP fit's first solve allocates nothing (in a fresh interpreter: this
    one's numpy has solved before)."""
    code = """
import numpy as np
from protocol.realtime import warm_up_linear_algebra
def vm_kib():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmSize"))
warm_up_linear_algebra()
before = vm_kib()
np.linalg.solve(np.eye(12) * 2.0 + 0.1, np.ones((12, 3)))
np.eye(9) @ np.ones((9, 9))
print(vm_kib() - before)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=ROOT)
    assert int(out.stdout) < 1024, f"the first solve after the warm-up mapped {out.stdout.strip()} KiB"


def test_the_p99s_interval_covers_the_true_p99_about_95_times_in_100():

    rng = np.random.default_rng(7)
    true_p99 = -np.log(0.01)  # of the exponential distribution of mean 1
    covered = [lo <= true_p99 <= hi for lo, hi in (quantile_interval(rng.exponential(size=600), 0.99) for _ in range(400))]
    assert 0.92 <= np.mean(covered) <= 0.99
    lo, hi = quantile_interval(np.arange(1000.0), 0.99)
    assert lo < 989.5 < hi and hi - lo < 15  # about the 990th value, a few ranks either side
