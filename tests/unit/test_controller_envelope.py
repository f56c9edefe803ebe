"""The safety envelope on every joint command (docs/FAULTS.md I1, F16, F17, F28)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from config import default_config_path, load_config
from controller.envelope import Envelope, EnvelopeError, JointBounds
from protocol.commands import JointCommand
from protocol.enums import JointMode

CFG = load_config(default_config_path()).controller.envelope  # margin 0.02, 4 rad/s, 0.08 rad/tick, 100 N.m
KNEE = JointBounds("knee_l", 0.0, 2.0)
ENV = Envelope.from_config((KNEE,), CFG)


def track(q, qd=0.0, tau=0.0, limit=100.0):
    return JointCommand(JointMode.TRACK, q, qd, tau, limit)


def test_a_command_inside_passes_untouched():
    out = ENV.check("knee_l", track(0.5, 1.0, 20.0, 80.0), previous_position_rad=0.48)
    assert out.command == track(0.5, 1.0, 20.0, 80.0) and out.clamped == () and out.violation is None


def test_small_excursions_are_clamped_and_reported():
    out = ENV.check("knee_l", track(1.99), previous_position_rad=1.95)
    assert out.command.position_rad == pytest.approx(1.98) and out.violation is None
    assert out.clamped == ("position 1.99 -> 1.98",)
    out = ENV.check("knee_l", track(0.5, qd=4.5, tau=-110.0), previous_position_rad=0.5)
    assert out.command.velocity_rad_s == 4.0 and out.command.torque_nm == -100.0 and out.violation is None


def test_far_beyond_the_envelope_is_a_violation_not_just_a_clamp():
    assert ENV.check("knee_l", track(2.3), previous_position_rad=2.25).violation  # 0.32 rad beyond
    assert ENV.check("knee_l", track(0.5, qd=8.0), previous_position_rad=0.5).violation  # 2x the speed bound
    jump = ENV.check("knee_l", track(0.9), previous_position_rad=0.5)  # 0.4 rad in one tick
    assert jump.violation and jump.command.position_rad == pytest.approx(0.58)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_values_never_pass(bad):
    for cmd in (track(bad), track(0.5, qd=bad), track(0.5, tau=bad), track(0.5, limit=bad)):
        out = ENV.check("knee_l", cmd, previous_position_rad=0.5)
        assert out.violation and out.command.mode == JointMode.HOLD


def test_a_margin_that_leaves_no_range_is_refused():
    with pytest.raises(EnvelopeError, match="knee_l"):
        Envelope((JointBounds("knee_l", 0.0, 0.03),), margin_rad=0.02, max_velocity_rad_s=1, max_step_rad=0.1,
                 max_torque_nm=10, position_excess_rad=0.1, rate_excess_factor=1.2)


finite = st.floats(-1e6, 1e6) | st.sampled_from([math.nan, math.inf, -math.inf])


@given(st.sampled_from(list(JointMode)), finite, finite, finite, finite, st.floats(-1.0, 3.0))
def test_whatever_comes_in_what_goes_out_is_inside_the_envelope(mode, q, qd, tau, limit, previous):
    out = ENV.check("knee_l", JointCommand(mode, q, qd, tau, limit), previous_position_rad=previous).command
    values = (out.position_rad, out.velocity_rad_s, out.torque_nm, out.torque_limit_nm)
    assert all(math.isfinite(v) for v in values)
    assert 0.0 <= out.torque_limit_nm <= 100.0
    if out.mode == JointMode.TRACK:
        assert 0.02 - 1e-12 <= out.position_rad <= 1.98 + 1e-12
        # The setpoint moves at most one step, unless the last one lay outside the range.
        assert abs(out.position_rad - previous) <= 0.08 + 1e-12 or not 0.02 <= previous <= 1.98
        assert abs(out.velocity_rad_s) <= 4.0 and abs(out.torque_nm) <= 100.0
