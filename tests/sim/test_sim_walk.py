"""The walking HHEA (patient + scripted exoskeleton gait): deterministic, and falls are reported."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from config import default_config_path, load_config, with_overrides
from sim.sweep import episode_summary
from sim.intention import StepIntention
from sim.patient import OTHER, Patient, Phase
from sim.scripted_gait import LeanTracker
from sim.walk import Walker, gait_settings, initial_pose, walk
from sim.world import GRAVITY, World
from tools.cli import main

# the steady patient (one placement every step): these tests are of the gait's physics; the
# default, noisy one is the experiments' (tests/sim/test_experiment.py)
SIM = with_overrides(load_config(default_config_path()), {"sim.mode": "sagittal", "sim.patient.intention.regime": "steady"}).sim


def _fingerprint(result):
    return [(s.leg, s.start_s, s.end_s, s.mean_stick_force_n, s.mean_arm_torque_nm) for s in result.steps], result.duration_s


def test_same_seed_same_walk_and_another_seed_differs():
    a = walk(SIM, gait_settings(SIM, step_length_m=0.12), seed=3, max_steps=2, max_time_s=12.0)
    b = walk(SIM, gait_settings(SIM, step_length_m=0.12), seed=3, max_steps=2, max_time_s=12.0)
    c = walk(SIM, gait_settings(SIM, step_length_m=0.12), seed=4, max_steps=2, max_time_s=12.0)
    assert a.steps and _fingerprint(a) == _fingerprint(b)
    assert _fingerprint(a) != _fingerprint(c)  # the patient's stick placement is noisy


def test_a_short_step_walks_in_the_plane_without_falling():
    # Before load acceptance (the patient taking the CoM from where the landing left it) this
    # fell in the shift after the second landing on every seed.
    result = walk(SIM, gait_settings(SIM, step_length_m=0.10), seed=1, max_steps=6, max_time_s=40.0)
    assert not result.fell, (result.fall_phase, result.fall_reason)
    assert result.steps_completed == 6
    assert [s.leg for s in result.steps] == ["r", "l"] * 3  # the legs alternate
    assert all(0.0 < s.mean_stick_force_n < 400.0 for s in result.steps)  # the sticks carry a share


def test_the_scripted_exoskeletons_lean_is_over_when_the_body_stops():
    """The lean ends once the CoM gets no farther forward by lean_stall_m in lean_stall_s (in
    lean_start_s before it has first moved that far); a body that keeps creeping keeps leaning."""
    g = SIM.gait
    dt = 0.02

    def ticks_until_stalled(xs) -> int | None:
        lean = LeanTracker(g)
        for n, x in enumerate(xs, 1):
            lean.update(x, dt)
            if lean.stalled:
                return n
        return None

    n = int(3 * g.lean_start_s / dt)
    still = ticks_until_stalled([0.0] * n)
    assert still is not None and abs(still * dt - g.lean_start_s) <= dt + 1e-9  # never moved
    moved = ticks_until_stalled([0.0] + [2 * g.lean_stall_m] * n)
    assert moved is not None and abs((moved - 1) * dt - g.lean_stall_s) <= dt + 1e-9  # moved, then stopped
    per = int(g.lean_stall_s / dt) - 1  # lean_stall_m farther every lean_stall_s, less a tick
    assert ticks_until_stalled([1.01 * g.lean_stall_m * (k // per) for k in range(n)]) is None


def test_a_far_too_long_step_falls_and_the_fall_is_reported():
    # (in the plane a 0.40 m step stalls: after it no stick has a place to lift from)
    cfg = dataclasses.replace(SIM, mode="full3d")
    result = walk(cfg, gait_settings(cfg, step_length_m=0.30), seed=0, max_steps=6, max_time_s=30.0)
    assert result.fell
    summary = episode_summary(result)
    assert summary["fall_reason"] and summary["fall_phase"] in {"settle", "shift", "sticks", "lean", "swing"}
    assert summary["fall_step"] >= 1 and summary["fall_margin_m"] < 0.0  # the CoM left the support polygon


def test_cli_walk_json_names_its_mode(capsys):
    assert main(["sim", "walk", "--mode", "sagittal", "--cycles", "1", "--max-time", "15", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["mode"] == "sagittal" and data["step_length_m"] == 0.12
    assert set(data) >= {"steps_completed", "fell", "fall_phase", "mean_stick_force_n", "mean_arm_torque_nm"}


def test_cli_rejects_bad_lengths(capsys):
    assert main(["sim", "sweep", "--lengths", "0.1,abc"]) == 1
    assert "--lengths" in capsys.readouterr().err


def test_json_stdout_stays_clean_of_pybullet_prints():
    import subprocess
    import sys

    from tests.conftest import ROOT

    proc = subprocess.run([sys.executable, "-m", "tools.cli", "sim", "walk", "--mode", "sagittal", "--cycles", "1",
                           "--max-time", "5", "--json"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["mode"] == "sagittal"


def test_the_gait_is_configuration_whose_errors_name_the_key():
    from config import ConfigError, default_config_path, load_config, with_overrides

    base = load_config(default_config_path())
    assert base.sim.gait.step_length_m == 0.12
    with pytest.raises(ConfigError, match=r"sim\.gait\.lean_speed_m_s: -0\.1 is below the minimum 0\.01"):
        with_overrides(base, {"sim.gait.lean_speed_m_s": -0.1})
    changed = gait_settings(base.sim, step_length_m=0.16)
    assert changed.step_length_m == 0.16 and changed.swing_time_s == base.sim.gait.swing_time_s


def _with_intention(**changes):
    patient = SIM.patient
    return dataclasses.replace(SIM, patient=dataclasses.replace(patient, intention=dataclasses.replace(patient.intention, **changes)))


@pytest.mark.parametrize("reference, ahead_m", [("com", 0.35), ("front_ankle", 0.33)])
def test_each_step_records_the_patients_intention_and_where_its_sticks_went(reference, ahead_m):
    cfg = _with_intention(regime="noisy", spread_m=0.05, reference=reference, ahead_m=ahead_m)
    result = walk(cfg, gait_settings(cfg, step_length_m=0.10), seed=2, max_steps=3, max_time_s=30.0)
    steps = result.steps
    assert len(steps) >= 2 and len({s.intention_m for s in steps}) == len(steps)  # drawn anew for each step
    for s in steps:
        if not s.clamped:  # the sticks land at the intention, give or take their own placement error
            assert s.placed_ahead_m == pytest.approx(s.intention_m, abs=4 * cfg.patient.stick_noise_m)



@pytest.mark.parametrize("lean_x, bound", [(0.40, "intention"), (0.85, "arms"), (1.0, "arms")])
def test_the_patients_lean_goal_is_its_intended_x_within_what_its_arms_hold(lean_x, bound):
    """X_CoM/X_SP along the walking direction at the CoM's lateral place, from the front foot's heel
    to the tips' line (SPEC's support polygon of the swing), and never farther than the sticks'
    lever-rule share over the ankle stays within stick_force_comfort_n each."""
    with World(SIM) as world:
        world.place(initial_pose(SIM))
        walker = Walker(world, SIM, gait_settings(SIM), np.random.default_rng(0))
        walker.start()
        p, g = walker.patient, SIM.gait
        p.plan.intention = StepIntention(SIM.patient.intention.ahead_m, lean_x)
        ankle = float(p.ankle_xy(p.front_foot())[0])
        heel = ankle - SIM.hardware.foot.heel_back_m
        (lx, ly), (rx, ry) = (p.tip_point(s)[:2] for s in "lr")
        y = float(walker.kin.com[1])
        tips = lx + (rx - lx) * (y - ly) / (ry - ly)  # the tips' line where the CoM's line crosses it
        intended = heel + min(max(lean_x, g.lean_x_min), g.lean_x_max) * (tips - heel)
        held = ankle + 2 * g.stick_force_comfort_n / (world.total_mass * GRAVITY) * (tips - ankle)
        goal = p._lean_goal()
        assert goal == pytest.approx(intended if bound == "intention" else held)
        assert goal <= min(intended, held) + 1e-12


def test_a_steady_patient_means_the_same_placement_every_step():
    steady = walk(SIM, gait_settings(SIM, step_length_m=0.10), seed=2, max_steps=2, max_time_s=20.0)
    assert {s.intention_m for s in steady.steps} == {SIM.patient.intention.ahead_m}


def test_a_stick_goal_beyond_the_arms_reach_is_clamped_and_counted():
    # 0.8 m ahead of the front ankle is out of the arm's reach (elbow at stick_reach_elbow_rad)
    cfg = _with_intention(ahead_m=0.8)
    with World(cfg) as world:
        world.place(initial_pose(SIM))  # standing with the sticks where they usually are
        walker = Walker(world, cfg, gait_settings(cfg), np.random.default_rng(0))
        walker.start()
        p = walker.patient
        p.plan.intention = p.intention.next()
        start = p.tip_point("l")
        goal = p._stick_goal("l", start)
        assert p.clamps == {"reach": 1, "advance": 0} and p.plan.clamped == 1
        assert start[0] < goal[0] < float(p.ankle_xy(p.front_foot())[0]) + 0.8
        reach = walker.body.arm_span_m(cfg.patient.stick_reach_elbow_rad)
        tip = goal + np.array([0.0, 0.0, cfg.hardware.sticks.tip_radius_m])
        assert np.linalg.norm(tip - p.shoulder("l")) == pytest.approx(reach, abs=1e-6)
        p.plan.intention = dataclasses.replace(p.plan.intention, ahead_m=-0.5)  # behind where the stick stands: it still moves on
        assert p._stick_goal("l", start)[0] == pytest.approx(start[0] + cfg.patient.stick_min_advance_m)
        assert p.clamps == {"reach": 1, "advance": 1}


@pytest.mark.parametrize(("mode", "directions"), [("full3d", {"lateral"}), ("sagittal", {"forward", "backward"})])
def test_a_stick_lifted_without_the_weight_shift_falls_and_the_fall_says_which_way(monkeypatch, mode, directions):
    """The patient lifts the rear foot's stick (the one the four-point gait leaves planted: with
    it up only the two feet and the far stick remain) at once, without shifting its weight into
    what remains. In 3-D the body rolls off toward the lifted stick's side; in the sagittal mode
    the plane spring holds the roll and the fall goes forward or backward."""

    def rear_stick_first(self):
        self.stick_queue = [OTHER[self.front_foot()]]
        self.plan.intention = self.intention.next()
        self._set_phase(Phase.SHIFT)

    monkeypatch.setattr(Patient, "_start_stick_moves", rear_stick_first)
    monkeypatch.setattr(Patient, "lift_window", lambda self, lifting: (-math.inf, math.inf))  # it feels safe to lift at once
    cfg = dataclasses.replace(SIM, mode=mode)
    result = walk(cfg, dataclasses.replace(cfg.gait, step_length_m=0.10), seed=0, max_steps=4, max_time_s=30)
    assert result.fell and result.fall_direction in directions, result.fall_reason
    assert result.fall_reason.startswith(f"{result.fall_direction} fall: ")
    assert result.steps_completed <= 1
