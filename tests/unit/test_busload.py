"""Frame lengths and bus load (can-utils canframelen formulas)."""

from __future__ import annotations

import pytest

from protocol.busload import busiest_tick, frame_bits, load_report
from protocol.catalog import default_catalog


@pytest.mark.parametrize(
    "dlc, extended, worst, bits",
    [(0, False, True, 55), (1, False, True, 65), (8, False, True, 135), (0, False, False, 47), (8, False, False, 111),
     (0, True, True, 80), (8, True, True, 160), (8, True, False, 131), (3, False, True, 85), (5, False, True, 105)],
)
def test_frame_bits_match_can_utils(dlc, extended, worst, bits):
    assert frame_bits(dlc, extended=extended, worst_case=worst) == bits


def test_frame_bits_rejects_fd_lengths():
    with pytest.raises(ValueError):
        frame_bits(9)


def test_can_utils_issue_example():
    # can-utils #257: 3122 one-byte frames per second = 202,930 bit/s worst case.
    assert 3122 * frame_bits(1) == 202_930


def test_a_full_tick_fits_the_budget():
    catalog = default_catalog()
    busiest = busiest_tick(catalog)
    assert len(busiest.frames) == 18  # the controller's heartbeat or one of its telemetry frames in every tick
    assert busiest.bits_worst == sum(frame_bits(m.dlc) for m in busiest.frames)
    assert busiest.percent(500_000) <= 25.0
    assert busiest.percent(1_000_000) <= 12.5
    report = load_report(catalog)
    assert report["bitrates"]["500000"]["busiest_tick_percent_worst"] == pytest.approx(100 * busiest.bits_worst / 10_000)
    # one heartbeat per tick at most
    assert sum(m.family in ("HEARTBEAT", "CONTROLLER_HEARTBEAT") for m in busiest.frames) == 1
