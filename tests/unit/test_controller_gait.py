"""Pure unit tests of controller/gait.py on synthetic estimates: the stick-move detection
(StickTracker), the stance legs in double support, the lean, the step's readiness, the swing's
split of work (GaitPlanner) and the foot placement loop. Only the design's promises (the module and
docs/CONTROLLER.md) are asserted, with every threshold taken from the configuration, so that the
tests survive gait tuning."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from config import default_config_path, load_config
from controller import factory
from controller import kinematics as kin
from controller.dmp import Dmp
from controller.estimator import Estimate, Measurements
from controller.gait import LEFT, RIGHT, GaitPlanner, minimum_jerk
from controller.sticks import StickTracker
from controller.swing import load_swing

CFG = load_config(default_config_path()).controller
P = CFG.gait
DT = 0.02
LEG = factory.leg(CFG)
LOADED_N = max(P.stick_placed_n, P.swing_stick_n, P.stick_lifted_n) + 40.0  # a stick clearly carrying load
FOOT_N = P.foot_contact_n + 300.0
AT_COMFORT_N = P.comfort_stick_n + 10.0


def estimate(ankles_x=(-0.06, 0.06), ankles_z=(-0.84, -0.84), com_x=0.0, tips_x=(0.35, 0.35)) -> Estimate:
    """A standing estimate in the heading frame (hips at the origin)."""
    ankles = np.array([[ankles_x[0], 0.10, ankles_z[0]], [ankles_x[1], -0.10, ankles_z[1]]])
    tips = np.array([[tips_x[0], 0.25, -0.90], [tips_x[1], -0.25, -0.90]])
    return Estimate(com=np.array([com_x, 0.0, 0.10]), ankles=ankles, tips=tips, feet_loaded=(True, True),
                    sticks_loaded=(True, True), floor_z=-0.90, support=np.zeros((0, 2)), x_ratio=math.nan,
                    elbow_rad=(1.0, 1.0), tips_on_floor=(True, True))


def joints_for(est: Estimate, pitch: float = 0.0) -> np.ndarray:
    q = []
    for i in (LEFT, RIGHT):
        hip, knee = kin.inverse(LEG, float(est.ankles[i][0]), float(est.ankles[i][2]))
        q += [hip + pitch, knee]
    return np.array(q)


def measurements(est: Estimate, sticks=(LOADED_N, LOADED_N), feet=(FOOT_N, FOOT_N), q=None, pitch: float = 0.0) -> Measurements:
    return Measurements(
        joint_position_rad=joints_for(est, pitch) if q is None else np.asarray(q, dtype=float),
        trunk_rpy_rad=np.array([0.0, pitch, 0.0]),
        stick_rpy_rad=np.zeros((2, 3)),
        stick_force_n=np.asarray(sticks, dtype=float),
        heel_force_n=np.asarray(feet, dtype=float) / 2,
        toe_force_n=np.asarray(feet, dtype=float) / 2,
    )


def ticks_for(seconds: float) -> int:
    return math.ceil(seconds / DT - 1e-9)


# Generous bounds on how long the force filter takes to settle (never a tight timing assertion).
SETTLE = ticks_for(10 * P.stick_filter_s) + 2
LIFT = ticks_for(P.stick_lift_s) + SETTLE + 2


def feed(tracker: StickTracker, est: Estimate, sticks, n: int) -> None:
    m = measurements(est, sticks=sticks)
    for _ in range(n):
        tracker.update(m)


# -- StickTracker --------------------------------------------------------------------------------


def test_a_stick_has_moved_once_lifted_long_enough_and_planted_again():
    t = StickTracker(P, DT)
    est = estimate()
    feed(t, est, (LOADED_N, LOADED_N), 50)
    assert t.moved == [False, False] and t.lifted == [False, False]
    lifted_after = None
    for k in range(1, LIFT + 1):
        feed(t, est, (0.0, LOADED_N), 1)
        if t.lifted[LEFT]:
            lifted_after = k
            break
    assert lifted_after is not None and lifted_after * DT >= P.stick_lift_s - 1e-9  # not before stick_lift_s
    assert t.lifted == [True, False] and t.moved == [False, False]  # lifted is not moved
    feed(t, est, (LOADED_N, LOADED_N), SETTLE)
    assert t.moved == [True, False]


def test_a_stick_put_back_where_it_stood_has_moved():
    # wherever it went: a stick re-planted where it stood is the patient's move too (the tip
    # estimate of a stick in the air is no measure of where it lands)
    t = StickTracker(P, DT)
    feed(t, estimate(), (0.0, 0.0), LIFT)
    assert t.lifted == [True, True]
    feed(t, estimate(tips_x=(0.35, 0.30)), (LOADED_N, LOADED_N), 3 * SETTLE)
    assert t.moved == [True, True]


def test_a_lift_shorter_than_stick_lift_s_does_not_count():
    t = StickTracker(P, DT)
    est = estimate()
    feed(t, est, (LOADED_N, LOADED_N), 20)
    feed(t, est, (0.0, 0.0), max(1, ticks_for(P.stick_lift_s / 2)))  # e.g. sensor noise on a light stick
    feed(t, est, (LOADED_N, LOADED_N), 3 * SETTLE)
    assert t.lifted == [False, False] and t.moved == [False, False]


def test_a_lifted_sticks_noisy_reading_does_not_restart_the_count():
    # hysteresis: a reading between stick_lifted_n and stick_placed_n now and then (sensor noise
    # about 0 N) keeps the count; only a planted stick's load ends it
    noisy = (P.stick_lifted_n + P.stick_placed_n) / 2
    t = StickTracker(P, DT)
    est = estimate()
    feed(t, est, (0.0, LOADED_N), SETTLE)
    for k in range(ticks_for(4 * P.stick_lift_s)):
        feed(t, est, (noisy if k % 3 == 0 else 0.0, LOADED_N), 1)
    assert t.lifted == [True, False]


def test_reset_starts_a_new_cycle():
    t = StickTracker(P, DT)
    est = estimate()
    feed(t, est, (0.0, 0.0), LIFT)
    feed(t, est, (LOADED_N, LOADED_N), SETTLE)
    assert t.moved == [True, True]
    t.reset()  # a swing started: the sticks must move again
    assert t.moved == [False, False] and t.lifted == [False, False]
    feed(t, est, (LOADED_N, LOADED_N), SETTLE)
    assert t.moved == [False, False] and not t.any_lifted_now


# -- GaitPlanner: the stance legs in double support ----------------------------------------------


def planner(est: Estimate, m: Measurements, params=P) -> GaitPlanner:
    """A planner standing at ``est``, with the configured gait or ``params``."""
    g = GaitPlanner(LEG, Dmp(load_swing(CFG)), params, factory.leg_loads(CFG), factory.balance_gains(CFG),
                    ankle_height_m=CFG.legs.ankle_height_m, swing_s=factory.swing_duration_s(CFG), dt_s=DT, substeps=CFG.swing.substeps)
    g.stand_here(est, m)
    return g


def mid_lead(g: GaitPlanner, est: Estimate) -> float:
    """How far the commanded ankles' midpoint lies behind the measured one (the hips' lead)."""
    return float(np.mean(est.ankles[:, 0]) - np.mean(g.ankle_cmd[:, 0]))


def move_sticks(g: GaitPlanner, sticks=(LEFT, RIGHT), com_x: float = 0.0, tips_x=(0.42, 0.46)) -> Estimate:
    """Lift ``sticks`` and plant them again (tips at ``tips_x``); returns that estimate."""
    est = estimate(com_x=com_x)
    lifted = tuple(0.0 if i in sticks else LOADED_N for i in (LEFT, RIGHT))
    for _ in range(LIFT):
        g.track_sticks(est, measurements(est, sticks=lifted))
    ahead = estimate(com_x=com_x, tips_x=tips_x)
    for _ in range(SETTLE):
        g.track_sticks(ahead, measurements(ahead))
    assert all(g.sticks.moved[i] for i in sticks)
    return ahead


def test_before_the_sticks_moved_double_support_is_the_weight_shift_and_not_ready():
    est = estimate()
    g = planner(est, measurements(est))
    for _ in range(20):
        ds = g.double_support(est, measurements(est), RIGHT)
        assert not ds.ready and ds.part == "shift" and math.isnan(ds.lean_goal_x)


@pytest.mark.parametrize("mode, moved, lean", [
    ("stance_side", (LEFT,), True),  # the right foot swings next: the left (stance) side's stick
    ("stance_side", (RIGHT,), False),
    ("both", (LEFT,), False),
    ("both", (LEFT, RIGHT), True),
])
def test_the_lean_starts_once_the_sticks_of_the_gait_pattern_have_moved(mode, moved, lean):
    est = estimate()
    g = planner(est, measurements(est), replace(P, stick_moves=mode))
    ahead = move_sticks(g, moved)
    assert g.double_support(ahead, measurements(ahead), RIGHT).part == ("lean" if lean else "shift")


def test_the_stance_ankles_are_commanded_level_at_the_measured_spacing():
    est = estimate(ankles_x=(-0.08, 0.05), ankles_z=(-0.842, -0.836), com_x=-0.01)
    m = measurements(est)
    g = planner(est, m)
    for _ in range(5):
        g.double_support(est, m, RIGHT)
        assert g.ankle_cmd[LEFT][1] == g.ankle_cmd[RIGHT][1]  # the floor is flat: no height between the two
        assert g.ankle_cmd[RIGHT][0] - g.ankle_cmd[LEFT][0] == pytest.approx(0.13)  # the feet where they are
        assert -g.ankle_cmd[LEFT][1] <= g.stand_height_m + 1e-12


def test_a_foot_that_carries_nothing_keeps_the_last_loaded_spacing():
    est = estimate(ankles_x=(-0.06, 0.06))
    g = planner(est, measurements(est))
    g.double_support(est, measurements(est), RIGHT)
    drifted = estimate(ankles_x=(-0.06 - 0.03, 0.06))  # the unloaded left foot's measurement drifts
    g.double_support(drifted, measurements(drifted, feet=(0.0, FOOT_N)), RIGHT)
    assert g.ankle_cmd[RIGHT][0] - g.ankle_cmd[LEFT][0] == pytest.approx(0.12)
    g.double_support(drifted, measurements(drifted), RIGHT)  # loaded again: the measured spacing
    assert g.ankle_cmd[RIGHT][0] - g.ankle_cmd[LEFT][0] == pytest.approx(0.15)


def test_the_shift_aims_into_the_middle_half_of_the_lift_window():
    est = estimate()
    g = planner(est, measurements(est))
    g.double_support(est, measurements(est), RIGHT)  # sets the reference foot (the stance, left)
    ref = float(est.ankles[LEFT][0])
    lo, hi = g.lift_window(est, LEFT)
    assert lo < hi
    quarter = (hi - lo) / 4
    # a CoM in the window but outside its middle half: the goal moves toward it; inside: it stays
    for com_over_ref, direction in ((lo + quarter / 2, 1.0), (hi - quarter / 2, -1.0), ((lo + hi) / 2, 0.0)):
        body = estimate(com_x=ref + com_over_ref)
        g = planner(body, measurements(body))
        g.double_support(body, measurements(body), RIGHT)
        lead = mid_lead(g, body)
        if direction == 0.0:
            assert lead == pytest.approx(0.0, abs=1e-12)
        else:
            assert np.sign(lead) == direction  # hips forward (ankles commanded back) for a CoM behind it


def test_a_body_that_does_not_follow_cannot_wind_the_command_up():
    est = estimate(ankles_x=(-0.06, 0.06), com_x=-0.30)  # the shift wants the hips far forward ...
    m = measurements(est)
    g = planner(est, m)
    leads = []
    for _ in range(200):  # ... and the body never moves
        g.double_support(est, m, RIGHT)
        leads.append(mid_lead(g, est))
    assert max(leads) <= P.max_lead_m + 1e-12
    assert leads[-1] == pytest.approx(P.max_lead_m)  # it leads, by at most max_lead


def test_the_shift_holds_while_a_stick_is_in_the_air():
    est = estimate(ankles_x=(-0.06, 0.06), com_x=-0.20)
    g = planner(est, measurements(est))
    lifted = measurements(est, sticks=(0.0, LOADED_N))
    for _ in range(SETTLE):
        g.track_sticks(est, lifted)
    assert g.sticks.any_lifted_now
    for _ in range(10):
        g.double_support(est, lifted, RIGHT)
        assert mid_lead(g, est) == pytest.approx(0.0, abs=1e-12)


def test_joint_targets_move_at_most_max_target_step_per_tick_toward_the_commanded_ankles():
    est = estimate(ankles_x=(-0.06, 0.06))
    off = joints_for(est) + np.array([0.3, -0.25, -0.3, 0.35])  # measured far from the commanded posture
    m = measurements(est, q=np.clip(off, 0.0, None))
    g = planner(est, m)
    previous = g.targets.copy()
    errors = []
    for _ in range(40):
        g.double_support(est, m, RIGHT)
        assert np.all(np.abs(g.targets - previous) <= P.max_target_step_rad + 1e-12)
        previous = g.targets.copy()
        want = np.array([v for i in (LEFT, RIGHT) for v in kin.inverse(LEG, *map(float, g.ankle_cmd[i]))])
        want[[0, 2]] += g.pitch_goal_rad
        errors.append(float(np.max(np.abs(g.targets - want))))
    assert errors[-1] < 1e-6 < errors[0]  # rate-limited, yet it gets there


def test_the_stance_hips_targets_add_the_trunks_pitch_goal():
    pitch = 0.08
    est = estimate(ankles_x=(-0.06, 0.06))
    m = measurements(est, pitch=pitch)
    g = planner(est, m)
    assert g.pitch_goal_rad == pytest.approx(pitch)
    for _ in range(5):
        g.double_support(est, m, RIGHT)
    for i in (LEFT, RIGHT):
        hip, knee = kin.inverse(LEG, *map(float, g.ankle_cmd[i]))
        assert g.targets[2 * i] == pytest.approx(hip + pitch) and g.targets[2 * i + 1] == pytest.approx(knee)


# -- GaitPlanner: the lean and the step's readiness -----------------------------------------------


def test_the_legs_lead_the_lean_by_at_most_lean_lead_and_not_at_comfort():
    est = estimate()
    g = planner(est, measurements(est))
    ahead = move_sticks(g)
    for _ in range(ticks_for(2.0)):
        ds = g.double_support(ahead, measurements(ahead), RIGHT)
    assert ds.part == "lean"
    assert ds.lean_goal_x == pytest.approx(float(ahead.com[0]) + P.lean_lead_m)  # led, the body not following
    assert mid_lead(g, ahead) > 0.0  # the hips go forward
    g = planner(est, measurements(est))
    ahead = move_sticks(g)
    for _ in range(ticks_for(2.0)):
        ds = g.double_support(ahead, measurements(ahead, sticks=(AT_COMFORT_N, LOADED_N)), RIGHT)
    assert ds.lean_goal_x <= float(ahead.com[0]) + 1e-12  # a stick at comfort: the arms, not the legs, hold the body


def ticks_to_ready(g: GaitPlanner, est: Estimate, limit: int = 500, swing_leg: int = RIGHT, **m_kw) -> int:
    """Lean ticks with the CoM held at ``est`` until the step is ready."""
    for n in range(1, limit + 1):
        if g.double_support(est, measurements(est, **m_kw), swing_leg).ready:
            return n
    raise AssertionError(f"the step was not ready after {limit} ticks")


STALL = replace(P, lean_stall_s=0.3, lean_start_s=1.0)  # the rule, whatever the configured times


def stalling_planner() -> tuple[GaitPlanner, Estimate]:
    est = estimate()
    g = planner(est, measurements(est), STALL)
    return g, move_sticks(g)


def test_a_lean_the_body_does_not_follow_at_all_is_over_after_lean_start_s():
    g, ahead = stalling_planner()
    n = ticks_to_ready(g, ahead)
    assert ticks_for(STALL.lean_start_s) <= n <= ticks_for(STALL.lean_start_s) + 1


def test_a_lean_that_moved_and_stopped_is_over_after_lean_stall_s():
    g, ahead = stalling_planner()
    assert not g.double_support(ahead, measurements(ahead), RIGHT).ready  # where the lean starts
    moved = estimate(com_x=2 * STALL.lean_stall_m, tips_x=(0.42, 0.46))
    n = ticks_to_ready(g, moved)
    assert ticks_for(STALL.lean_stall_s) <= n <= ticks_for(STALL.lean_stall_s) + 1


def test_a_lean_that_stalls_short_of_the_stance_ankle_is_not_over():
    # the left foot swings over the right one at 0.06 m; the body stays at 0.0: a swing from there
    # tips it backward, so the controller waits (a stalled walk) rather than start it
    g, ahead = stalling_planner()
    for _ in range(ticks_for(3 * STALL.lean_start_s)):
        assert not g.double_support(ahead, measurements(ahead), LEFT).ready
    past = estimate(com_x=0.06 + P.lean_over_stance_m / 2, tips_x=(0.42, 0.46))
    assert ticks_to_ready(g, past, swing_leg=LEFT) <= ticks_for(STALL.lean_stall_s) + 1  # past it: the stall ends the lean


def creeping(k: int) -> Estimate:
    """The CoM lean_stall_m farther forward every lean_stall_s, less a tick."""
    return estimate(com_x=1.01 * STALL.lean_stall_m * (k // (ticks_for(STALL.lean_stall_s) - 1)), tips_x=(0.42, 0.46))


def test_a_lean_that_creeps_forward_is_not_over():
    g, _ = stalling_planner()
    for k in range(ticks_for(3 * STALL.lean_start_s)):
        creep = creeping(k)
        assert not g.double_support(creep, measurements(creep), RIGHT).ready


def test_a_body_that_creeps_on_with_a_stick_at_comfort_has_ended_its_lean():
    # the patient bears no more: the body that still creeps (arms yielding) is not leaning further
    g, _ = stalling_planner()
    ready_at = None
    for k in range(ticks_for(3 * STALL.lean_start_s)):
        creep = creeping(k)
        if g.double_support(creep, measurements(creep, sticks=(AT_COMFORT_N, LOADED_N)), RIGHT).ready:
            ready_at = k + 1
            break
    assert ready_at is not None and ready_at <= ticks_for(STALL.lean_start_s) + 1


def test_the_step_waits_for_the_tips_midpoint_ahead_of_the_front_ankle():
    # the four-point gait's older stick may stand just ahead of the front foot: the support's front
    # edge on the CoM's line is midway between the tips
    front = 0.06
    for tips_x, ready in (((front + 0.02, front + 2 * P.tips_ahead_m + 0.02), True), ((front + 0.02, front + 0.10), False)):
        g, _ = stalling_planner()
        est = estimate(tips_x=tips_x)
        states = [g.double_support(est, measurements(est), RIGHT).ready for _ in range(ticks_for(2 * STALL.lean_start_s))]
        assert any(states) == ready


def test_the_stance_foot_alone_must_be_loaded_for_the_swing():
    g, ahead = stalling_planner()
    # the rear (right, swing) foot unloaded in the lean: ready all the same
    assert ticks_to_ready(g, ahead, feet=(FOOT_N, 0.0)) <= ticks_for(STALL.lean_start_s) + 1
    g, ahead = stalling_planner()
    for _ in range(ticks_for(2 * STALL.lean_start_s)):  # the stance foot unloaded: never
        assert not g.double_support(ahead, measurements(ahead, feet=(0.0, FOOT_N)), RIGHT).ready


# -- GaitPlanner: the swing ------------------------------------------------------------------------


def swinging(length_m: float = 0.12, pitch: float = 0.0) -> tuple[GaitPlanner, Estimate]:
    est = estimate()
    g = planner(est, measurements(est))
    g.double_support(est, measurements(est), RIGHT)
    g.start_swing(RIGHT, est, length_m)
    return g, est


def test_the_stance_leg_carries_the_hips_forward_over_the_swing():
    # the split of work: the exoskeleton's stance leg advances the CoM goal hip_advance_fraction of
    # the step over the swing (minimum jerk), the body or not
    length = 0.12
    g, est = swinging(length)
    start = g.swing_from_x  # the CoM over the stance ankle when the swing started
    tau = g.dmp.tau_s
    m = measurements(est, feet=(FOOT_N, 0.0))  # the swing foot in the air: no landing
    goals = []
    for k in range(ticks_for(tau)):
        assert not g.swing(est, m).done
        goals.append(g.goal_x)
        t = (k + 1) * DT
        assert g.goal_x == pytest.approx(start + P.hip_advance_fraction * length * minimum_jerk((t - DT) / tau), abs=1e-9)
    assert all(b >= a for a, b in zip(goals, goals[1:]))
    assert goals[-1] == pytest.approx(start + P.hip_advance_fraction * length, abs=0.01 * length)
    assert g.ankle_cmd[LEFT][0] < est.ankles[LEFT][0]  # the stance ankle commanded behind: the hips ahead


def test_the_swing_legs_hip_target_takes_the_trunks_measured_pitch():
    # a stance leg holds the trunk at its pitch goal; the swing ankle goes where it is commanded,
    # whatever the trunk's pitch
    g, est = swinging()
    pitch = g.pitch_goal_rad + 0.04
    g.swing(est, measurements(est, feet=(FOOT_N, 0.0), pitch=pitch))
    hip, _ = kin.inverse(LEG, *map(float, g.ankle_cmd[RIGHT]))
    assert g.targets[2 * RIGHT] == pytest.approx(hip + pitch)
    hip, _ = kin.inverse(LEG, *map(float, g.ankle_cmd[LEFT]))
    assert g.targets[2 * LEFT] == pytest.approx(hip + g.pitch_goal_rad)


# -- GaitPlanner: foot placement -------------------------------------------------------------------


def placing(est: Estimate, gain: float = 0.5, max_offset_m: float = 0.05) -> GaitPlanner:
    """A planner with the foot placement loop on (whatever the configuration's default)."""
    return planner(est, measurements(est), replace(P, placement_gain=gain, max_aim_offset_m=max_offset_m))


def test_a_swing_aims_beyond_the_commanded_length_by_the_integrated_shortfall():
    est = estimate()
    g = placing(est)
    assert g.start_swing(RIGHT, est, 0.10) == pytest.approx(0.10)  # nothing measured yet: aim at the length
    assert g.dmp.goal[0] == pytest.approx(0.10) and g.step_length_m == 0.10
    g.placed(0.10, 0.08)  # landed 2 cm short
    offset = 0.5 * 0.02
    assert g.aim_offset_m == pytest.approx(offset)
    assert g.start_swing(LEFT, est, 0.12) == pytest.approx(0.12 + offset)
    assert g.dmp.goal[0] == pytest.approx(0.12 + offset) and g.step_length_m == 0.12  # the record keeps the commanded length
    g.placed(0.12, 0.12)  # on the mark: the offset stays
    assert g.aim_offset_m == pytest.approx(offset)
    g.placed(0.12, 0.125)  # beyond it: the offset shrinks
    assert g.aim_offset_m == pytest.approx(offset - 0.5 * 0.005)


def test_the_aim_offset_stays_within_max_aim_offset():
    est = estimate()
    g = placing(est)
    for _ in range(50):
        g.placed(0.10, 0.0)  # a foot that never gets anywhere does not make the swings aim without bound
    assert g.aim_offset_m == pytest.approx(0.05)
    for _ in range(50):
        g.placed(0.10, 0.30)
    assert g.aim_offset_m == pytest.approx(-0.05)
    g.placed(0.10, math.nan)  # a placement that could not be measured
    g.placed(math.inf, 0.10)
    assert g.aim_offset_m == pytest.approx(-0.05)


def test_without_placement_gain_a_swing_aims_at_the_commanded_length():
    est = estimate()
    g = placing(est, gain=0.0)
    g.placed(0.10, 0.07)
    assert g.aim_offset_m == 0.0 and g.start_swing(RIGHT, est, 0.10) == 0.10
