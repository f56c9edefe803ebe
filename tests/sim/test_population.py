"""Virtual patients (config/patients, tools/population.py): a patient file is a configuration whose
simulated body, arms, stick placement and controller body model are the patient's; bad patient
files fail at load with one line naming the file and the patient's key; a population is the same
for the same seed and within its documented bounds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from config import ConfigError, default_config_path, load_config
from config.patient_schema import BMI_RANGE, VirtualPatient
from sim.model import build_body
from tools import population
from tools.population import draw_population, fitted_body, load_patient, patient_config, patient_yaml, shipped_patients

BASE = load_config(default_config_path())


def _controller_value(cfg, dotted):
    section, name = dotted.split(".")[1:]
    return getattr(cfg.controller.body if section == "body" else cfg.controller.legs, name)


def _assert_body_fits(cfg, model_cfg, tol=1e-3):
    """``cfg``'s controller body model is the simulated patient of ``model_cfg``."""
    off = {}
    for key, want in fitted_body(model_cfg).items():
        got = _controller_value(cfg, key)
        if not np.allclose(np.atleast_1d(got), np.atleast_1d(want), rtol=tol, atol=tol):
            off[key] = (got, want)
    assert not off, off


def test_the_default_controller_body_is_fitted_to_the_default_patient():
    """controller.body restates the simulated patient (the controller must not import sim): a
    change to one without the other fails here, not as a drifting estimate."""
    _assert_body_fits(BASE, BASE)


def test_the_reference_patient_is_the_default_configuration():
    patient, cfg = load_patient(population.PATIENTS_DIR / "reference.yaml", BASE)
    assert cfg.sim == BASE.sim
    _assert_body_fits(cfg, BASE)
    assert dataclasses.replace(cfg.controller, body=BASE.controller.body, legs=BASE.controller.legs) == BASE.controller


@pytest.mark.parametrize("path", shipped_patients(), ids=lambda p: p.stem)
def test_every_shipped_patient_loads_and_its_body_is_built(path):
    patient, cfg = load_patient(path, BASE)
    assert patient.name == path.stem
    body = build_body(cfg.sim)
    assert cfg.sim.model.patient.mass_kg == patient.mass_kg and body.hip_height_m > 0.6
    assert cfg.sim.patient.intention.regime == patient.placement.regime


def test_a_patient_changes_the_body_the_arms_the_placement_and_the_fall_criterion():
    patient, cfg = load_patient(population.PATIENTS_DIR / "small-light.yaml", BASE)
    scale = patient.height_m / BASE.sim.model.patient.height_m
    assert cfg.sim.model.patient.height_m == patient.height_m
    assert cfg.hardware.sticks.length_m == pytest.approx(BASE.hardware.sticks.length_m * scale)
    assert cfg.sim.model.patient.hip_width_m == pytest.approx(BASE.sim.model.patient.hip_width_m * scale)
    assert cfg.sim.fall.min_hip_height_m == pytest.approx(BASE.sim.fall.min_hip_height_m * scale)
    assert cfg.sim.model.joints.elbow.torque_limit_nm == pytest.approx(BASE.sim.model.joints.elbow.torque_limit_nm * 0.7)
    assert cfg.sim.patient.arm_stiffness_nm_rad == pytest.approx(BASE.sim.patient.arm_stiffness_nm_rad * 0.7)
    assert cfg.hardware.joints == BASE.hardware.joints  # the exoskeleton's motors are the device's
    assert (cfg.sim.patient.intention.regime, cfg.sim.patient.stick_noise_m) == ("steady", 0.015)


def test_the_controllers_body_model_is_the_patient_as_measured_with_the_fits_errors():
    patient, cfg = load_patient(population.PATIENTS_DIR / "small-light.yaml", BASE)  # lengths 2 % long, 2 kg light
    true = build_body(cfg.sim)
    assert cfg.controller.legs.thigh_m == pytest.approx(true.thigh_m * 1.02)
    assert cfg.controller.body.elbow_to_tip_m == pytest.approx((true.forearm_m + true.grip_m + true.stick_m) * 1.02)
    total = (cfg.controller.body.trunk_kg + 2 * (cfg.controller.body.thigh_kg + cfg.controller.body.shank_kg
                                                   + cfg.controller.body.foot_kg + cfg.controller.body.upper_arm_kg
                                                   + cfg.controller.body.forearm_kg))
    assert total == pytest.approx(true.total_mass_kg - 2.0, abs=1e-6)


BAD = {
    "a mass of 0": ({"mass_kg": 0}, "mass_kg: 0 is below the minimum 35"),
    "a negative spread": ({"placement": {"spread_m": -0.01}}, "placement.spread_m: -0.01 is below the minimum 0"),
    "sticks that cannot reach the floor": ({"stick_length_m": 0.55}, "stick_length_m: the sticks cannot reach the ground"),
    "an implausible mass for the height": ({"mass_kg": 150, "height_m": 1.50}, "mass_kg: 150.0 kg at 1.5 m is a body mass index of 66.7"),
    "a misspelt key": ({"arm_strenght": 1.0}, "arm_strenght"),
    "a regime we do not know": ({"placement": {"regime": "wobbly"}}, "placement.regime"),
    "a name with a slash": ({"name": "a/b"}, "name: 'a/b': give a name without slashes"),
}


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_a_bad_patient_fails_at_load_naming_the_file_and_the_key(case, tmp_path):
    import yaml

    change, message = BAD[case]
    data = yaml.safe_load((population.PATIENTS_DIR / "reference.yaml").read_text())
    for key, value in change.items():
        if isinstance(value, dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_patient(path, BASE)
    text = str(err.value)
    assert text.startswith(str(path)) and message in text and "\n" not in text, text


def test_a_population_is_the_same_for_its_seed_and_each_patient_independent_of_its_size():
    eight = draw_population(8, seed=3)
    assert eight == draw_population(8, seed=3)
    assert draw_population(20, seed=3)[:8] == eight
    assert eight != draw_population(8, seed=4)
    assert [p.name for p in eight] == [f"pop3-{i:04d}" for i in range(8)]
    with pytest.raises(ConfigError, match="at least one patient"):
        draw_population(0, seed=3)


def test_a_large_population_follows_its_documented_distributions():
    people = draw_population(600, seed=0)
    heights = np.array([p.height_m for p in people])
    bmi = np.array([p.mass_kg / p.height_m**2 for p in people])
    assert population.HEIGHT_RANGE_M[0] <= heights.min() and heights.max() <= population.HEIGHT_RANGE_M[1]
    # a mix of the sexes' heights weighted by MALE_SHARE
    mean = sum(share * population.HEIGHT_M[sex][0] for sex, share in (("male", population.MALE_SHARE), ("female", 1 - population.MALE_SHARE)))
    assert heights.mean() == pytest.approx(mean, abs=0.015)
    assert bmi.mean() == pytest.approx(population.BMI[0], abs=0.6) and BMI_RANGE[0] <= bmi.min() and bmi.max() <= BMI_RANGE[1]
    regimes = [p.placement.regime for p in people]
    for regime, share in population.REGIMES.items():
        assert regimes.count(regime) / len(people) == pytest.approx(share, abs=0.06), regime
    assert all(p.placement.spread_m == 0 for p in people if p.placement.regime == "steady")


def test_the_draws_extremes_are_valid_patients():
    """The corners of the draw's ranges (the tallest heaviest patient leaning the most on a stick,
    the shortest lightest leaning the least) pass the patient schema's bounds."""
    from config.loader import build

    for height, bmi, comfort in ((population.HEIGHT_RANGE_M[1], population.BMI_DRAW_RANGE[1], population.COMFORT_RANGE[1]),
                                 (population.HEIGHT_RANGE_M[0], population.BMI_DRAW_RANGE[0], population.COMFORT_RANGE[0])):
        mass = round(bmi * height**2, 1)
        data = {"name": "corner", "mass_kg": mass, "height_m": height, "arm_strength": 1.0,
                "comfortable_stick_force_n": round(comfort * mass * population.GRAVITY, 1),
                "placement": {"regime": "noisy", "spread_m": 0.06, "stick_noise_m": 0.02},
                "fit": {"length_error_fraction": 0.0, "mass_error_kg": 0.0}}
        build(VirtualPatient, data)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), index=st.integers(0, 10_000))
def test_every_drawn_patient_makes_a_valid_configuration_and_round_trips_as_a_file(seed, index, tmp_path_factory):
    patient = population.draw_patient(np.random.default_rng(np.random.SeedSequence([seed, index])), f"p{index}")
    cfg = patient_config(BASE, patient)
    assert build_body(cfg.sim).total_mass_kg > patient.mass_kg  # with the exoskeleton and sticks
    path = tmp_path_factory.mktemp("pop") / "p.yaml"
    path.write_text(patient_yaml(patient))
    again, again_cfg = load_patient(path, BASE)
    assert again == patient and again_cfg == cfg


def test_walk_walks_a_virtual_patient_in_process_only(capsys):
    import json

    from tools.cli import main

    path = str(population.PATIENTS_DIR / "small-light.yaml")
    assert main(["walk", "--virtual-patient", path, "--steps", "1", "--json", "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["virtual_patient"] == "small-light" and summary["cycles_completed"] == 1 and summary["falls"] == 0
    assert main(["walk", "--virtual-patient", path, "--bus", "udp_multicast", "--channel", "239.74.163.2:40000", "--steps", "1"]) == 1
    assert "--virtual-patient needs the simulation in this process" in capsys.readouterr().err


def test_population_draw_writes_patient_files_that_load_as_drawn(tmp_path, capsys):
    import json

    from tools.cli import main

    out = tmp_path / "pop"
    assert main(["population", "draw", "--patients", "3", "--seed", "5", "--out", str(out), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [p["name"] for p in listed["patients"]] == ["pop5-0000", "pop5-0001", "pop5-0002"]
    for drawn, path in zip(draw_population(3, seed=5), sorted(out.glob("*.yaml"))):
        assert load_patient(path, BASE)[0] == drawn
    assert main(["population", "draw", "--patients", "3", "--seed", "5", "--out", str(out)]) == 1
    assert "exists (and 2 more): give --overwrite" in capsys.readouterr().err
    assert main(["population", "draw", "--patients", "3", "--seed", "5", "--out", str(out), "--overwrite"]) == 0


def test_updates_to_converge_is_the_first_update_from_which_the_cost_stays_within_5_percent():
    from tools.experiment.learn import LearningRun, Update
    from tools.experiment.population import updates_to_converge

    def run(costs, last_end="walked"):
        r = LearningRun(start="A", seed=0, theta0=(-1.0, 0.6))
        r.updates = [Update(index=i, theta=(0, 0), evaluation_theta=(0, 0), evaluation_cost=c, evaluation_cycles=10,
                            evaluation_end="walked" if i < len(costs) - 1 else last_end) for i, c in enumerate(costs)]
        return r

    assert updates_to_converge(run([5000, 300, 210, 200, 205])) == 2
    assert updates_to_converge(run([300, 300, 300])) == 0
    assert updates_to_converge(run([5000, 300, 5000], last_end="backward fall")) is None  # nothing to converge to


def test_a_walk_that_raises_ends_only_its_own_run_and_is_reported_with_its_seed():
    import concurrent.futures as cf

    from tools.experiment.runner import WalkJob
    from tools.experiment.schedule import RunFailed, batch, drive

    class Pool:
        cache_dir = None

        def submit(self, job):
            f = cf.Future()
            if job.seed == 13:
                f.set_exception(RuntimeError("pybullet said no"))
            else:
                f.set_result({"seed": job.seed})
            return f

    good, bad = [WalkJob(seed=1, cycles=1, fixed_m=0.12)], [WalkJob(seed=13, cycles=1, fixed_m=0.14)]
    out = drive(Pool(), {"good": batch(good), "bad": batch(bad)}, keep_going=True)
    assert out["good"] == [{"seed": 1}]
    assert out["bad"] == RunFailed("bad", "fixed 0.14 m, seed 13", "pybullet said no")
    with pytest.raises(RuntimeError, match="pybullet said no"):  # without keep_going: the experiment ends
        drive(Pool(), {"good": batch(good), "bad": batch(bad)})


def _gait(name, cycles_done, force, cycles=10):
    """A gait's comparison walks: one per entry of ``cycles_done`` (fewer than ``cycles``: a fall)."""
    from tools.experiment.compare import ADAPTIVE, GaitStats

    walks = [{"cycles_completed": c, "mean_stick_force_n": force, "mean_arm_torque_nm": 50.0, "step_lengths_m": [0.12],
              "fell": c < cycles, "end": "walked" if c == cycles else "backward fall", "job": {"seed": i}}
             for i, c in enumerate(cycles_done)]
    return GaitStats(name, (-0.3, 0.6) if name == ADAPTIVE else None, None if name == ADAPTIVE else float(name), walks)


@pytest.mark.parametrize("adaptive, fixed, walks_every, below, beats", [
    # walks every walk, below the cheapest fall-free length (0.12 m at 300 N; 0.20 m falls)
    ([10, 10], {"0.10": ([10, 10], 320.0), "0.12": ([10, 10], 300.0), "0.20": ([3, 10], 200.0)}, True, True, True),
    # one walk falls; above a fall-free length
    ([10, 4], {"0.10": ([10, 10], 250.0)}, False, False, False),
    # no fixed length is fall-free: below them all by definition, but none to beat
    ([10, 10], {"0.10": ([2, 10], 250.0)}, True, True, False),
])
def test_a_patients_summary_says_whether_its_learned_gait_walks_every_walk_below_every_fall_free_length(adaptive, fixed, walks_every, below, beats):
    from tools.experiment.compare import ADAPTIVE
    from tools.experiment.learn import LearningRun, Update
    from tools.experiment.population import PatientOutcome

    run = LearningRun(start="A", seed=0, theta0=(-1.0, 0.6))
    run.updates = [Update(index=0, theta=(-0.3, 0.6), evaluation_theta=(-0.3, 0.6), evaluation_cost=1500.0, evaluation_cycles=10,
                          evaluation_end="walked")]
    gaits = [_gait(ADAPTIVE, adaptive, 280.0)] + [_gait(name, done, force) for name, (done, force) in fixed.items()]
    patient, _ = load_patient(population.PATIENTS_DIR / "reference.yaml", BASE)
    s = PatientOutcome(patient, run, (-0.3, 0.6), gaits).summary(10)
    assert (s["adaptive_walks_every_walk"], s["adaptive_below_fall_free_fixed"]) == (walks_every, below)
    assert s["adaptive_beats_best_fixed"] is beats
