"""Virtual patients and populations of them: a patient file as a configuration, and a seeded
population drawn from documented distributions (docs/POPULATION.md).

:func:`patient_config` applies a :class:`config.patient_schema.VirtualPatient` to a base
configuration: the simulated patient's body (and what scales with it: widths, sticks, the fall
criterion, the placement ahead), the arms' strength, the stick placement's variability, and the
controller's body model as the exoskeleton's set-up would measure it (:func:`fitted_body` on the
patient with the fit's errors). :func:`draw_population` draws N patients for a seed.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from config import Config, ConfigError, build, config_to_dict, default_config_path, load_as, with_overrides
from config.patient_schema import VirtualPatient

#: the folder of the patient files shipped with the package
PATIENTS_DIR = default_config_path().with_name("patients")

ARM_JOINTS = ("shoulder_flexion", "shoulder_abduction", "elbow")


def fitted_body(cfg: Config) -> dict[str, Any]:
    """``controller.body`` and ``controller.legs`` (as overrides) fitted to the simulated patient of
    ``cfg``: the lengths, masses and centres of mass the controller's estimator models, taken from
    the simulation's own body (what a clinic measures when it sets the exoskeleton up)."""
    from sim.model import build_body

    body = build_body(cfg.sim)
    trunk, foot = body.link("trunk"), body.link("foot_l")
    upper_arm, shoulder = body.link("upper_arm_l"), body.link("shoulder_l")
    upper_arm_kg = upper_arm.mass_kg + shoulder.mass_kg  # the shoulder's small link sits at the joint
    return {
        "controller.legs.thigh_m": body.thigh_m,
        "controller.legs.shank_m": body.shank_m,
        "controller.legs.ankle_height_m": body.ankle_height_m,
        "controller.body.hip_half_width_m": body.hip_half_width_m,
        "controller.body.shoulder_xyz_m": [0.0, body.shoulder_half_width_m, body.shoulder_above_hip_m],
        "controller.body.upper_arm_m": body.upper_arm_m,
        "controller.body.elbow_to_tip_m": body.forearm_m + body.grip_m + body.stick_m,
        "controller.body.trunk_kg": trunk.mass_kg,
        "controller.body.trunk_com_xz_m": [trunk.com_xyz[0], trunk.com_xyz[2]],
        "controller.body.thigh_kg": body.link("thigh_l").mass_kg,
        "controller.body.thigh_com_m": -body.link("thigh_l").com_xyz[2],
        "controller.body.shank_kg": body.link("shank_l").mass_kg,
        "controller.body.shank_com_m": -body.link("shank_l").com_xyz[2],
        "controller.body.foot_kg": foot.mass_kg,
        "controller.body.foot_com_xz_m": [foot.com_xyz[0], foot.com_xyz[2]],
        "controller.body.upper_arm_kg": upper_arm_kg,
        "controller.body.upper_arm_com_m": -upper_arm.com_xyz[2] * upper_arm.mass_kg / upper_arm_kg,
        "controller.body.forearm_kg": body.link("forearm_l").mass_kg,
        "controller.body.forearm_com_m": -body.link("forearm_l").com_xyz[2],
    }


def _body_overrides(base: Config, *, mass_kg: float, height_m: float, stick_m: float, length_scale: float) -> dict[str, Any]:
    """The simulated patient of ``base`` at ``mass_kg`` and ``height_m``, its absolute widths and
    depths scaled with its lengths (``length_scale`` over the base patient's), sticks ``stick_m`` long."""
    ref, scale = base.sim.model.patient, length_scale
    return {
        "sim.model.patient.mass_kg": mass_kg,
        "sim.model.patient.height_m": height_m,
        "sim.model.patient.hip_width_m": ref.hip_width_m * scale,
        "sim.model.patient.shoulder_width_m": ref.shoulder_width_m * scale,
        "sim.model.patient.trunk_com_above_hip_m": ref.trunk_com_above_hip_m * scale,
        "sim.model.patient.trunk_depth_m": ref.trunk_depth_m * scale,
        "hardware.sticks.length_m": stick_m,
    }


def patient_config(base: Config, patient: VirtualPatient, *, source: str = "<patient>") -> Config:
    """``base`` with the simulated patient, its behaviour and the controller's body model of
    ``patient`` (docs/POPULATION.md says what each field changes). Errors name the patient's key
    and ``source``."""
    if base.sim is None or base.controller is None:
        raise ConfigError("a virtual patient needs the sim and controller sections", key="sim", source=source)
    ref = base.sim.model.patient
    scale = patient.height_m / ref.height_m  # every length of the body scales with the height
    stick_m = patient.stick_length_m if patient.stick_length_m is not None else base.hardware.sticks.length_m * scale
    body = _body_overrides(base, mass_kg=patient.mass_kg, height_m=patient.height_m, stick_m=stick_m, length_scale=scale)
    joints = base.sim.model.joints
    strength = patient.arm_strength
    arms = {f"sim.model.joints.{j}.torque_limit_nm": getattr(joints, j).torque_limit_nm * strength for j in ARM_JOINTS}
    control = base.sim.patient
    behaviour = {
        "sim.patient.arm_stiffness_nm_rad": control.arm_stiffness_nm_rad * strength,
        "sim.patient.arm_damping_nms_rad": control.arm_damping_nms_rad * strength,
        "sim.patient.intention.regime": patient.placement.regime,
        "sim.patient.intention.spread_m": patient.placement.spread_m,
        "sim.patient.intention.ahead_m": control.intention.ahead_m * scale,
        "sim.patient.stick_noise_m": patient.placement.stick_noise_m,
        "sim.patient.stick_half_width_m": control.stick_half_width_m * scale,
        "sim.fall.min_hip_height_m": base.sim.fall.min_hip_height_m * scale,  # the same crouch, relative to the legs
    }
    cfg = _apply(base, {**body, **arms, **behaviour}, source)
    fit = patient.fit
    measured_scale = scale * (1 + fit.length_error_fraction)
    measured = _estimated(base, mass_kg=patient.mass_kg + fit.mass_error_kg, height_m=ref.height_m * measured_scale,
                          stick_m=stick_m * (1 + fit.length_error_fraction), length_scale=measured_scale, source=source)
    return _apply(cfg, measured, source)


def estimated_body(base: Config, *, mass_kg: float, height_m: float, stick_m: float, source: str = "<body>") -> dict[str, Any]:
    """``controller.legs`` and ``controller.body`` (as overrides) of a person of ``mass_kg`` and
    ``height_m`` with sticks ``stick_m`` long: the simulated patient of ``base`` built to those
    measures (Winter's tables, widths and depths scaled with the height), then :func:`fitted_body`.
    What a clinic starts from before it measures (``aider-exo config body``)."""
    if base.sim is None:
        raise ConfigError("the body is estimated with the simulation's anthropometric model", key="sim", source=source)
    return _estimated(base, mass_kg=mass_kg, height_m=height_m, stick_m=stick_m,
                      length_scale=height_m / base.sim.model.patient.height_m, source=source)


def _estimated(base: Config, *, mass_kg: float, height_m: float, stick_m: float, length_scale: float, source: str) -> dict[str, Any]:
    body = _body_overrides(base, mass_kg=mass_kg, height_m=height_m, stick_m=stick_m, length_scale=length_scale)
    return fitted_body(_apply(base, body, source))


def _apply(cfg: Config, overrides: dict[str, Any], source: str) -> Config:
    try:
        return with_overrides(cfg, overrides, source=source)
    except ConfigError as exc:
        raise ConfigError(_patient_message(exc), key=_patient_key(exc.key), source=source) from None


#: the configuration's keys that a patient's field sets, for errors in the patient's terms
_PATIENT_KEYS = {
    "hardware.sticks.length_m": "stick_length_m",
    "sim.model.patient.mass_kg": "mass_kg",
    "sim.model.patient.height_m": "height_m",
    "sim.patient.intention.spread_m": "placement.spread_m",
    "sim.patient.stick_noise_m": "placement.stick_noise_m",
}


def _patient_key(key: str | None) -> str | None:
    if key is None:
        return None
    for prefix, field in _PATIENT_KEYS.items():
        if key.startswith(prefix):
            return field
    return key


def _patient_message(exc: ConfigError) -> str:
    return f"{exc.message} (as {exc.key} of the configuration)" if exc.key and _patient_key(exc.key) != exc.key else exc.message


def load_patient(path: str | os.PathLike[str], base: Config) -> tuple[VirtualPatient, Config]:
    """The virtual patient in the YAML file ``path`` and ``base`` configured for it; every error
    (a bad value, a body the model cannot build, sticks that cannot reach the floor) is one line
    naming the file and the patient's key."""
    patient = load_as(VirtualPatient, path)
    return patient, patient_config(base, patient, source=os.fspath(path))


def shipped_patients() -> list[Path]:
    """The patient files of ``config/patients`` (sorted)."""
    return sorted(PATIENTS_DIR.glob("*.yaml"))


# -- populations ---------------------------------------------------------------------------------

#: the population's distributions (docs/POPULATION.md gives each one's source or says it is ours)
MALE_SHARE = 0.78  # of people with a spinal cord injury (NSCISC Facts and Figures)
HEIGHT_M = {"male": (1.754, 0.075), "female": (1.615, 0.070)}  # mean, sd (NHANES 2015-2018, adults)
HEIGHT_RANGE_M = (1.50, 2.00)
BMI = (25.5, 4.0)  # mean, sd (kg/m²)
BMI_DRAW_RANGE = (18.0, 36.0)
ARM_STRENGTH_SD_LOG = 0.25
ARM_STRENGTH_RANGE = (0.5, 1.8)
COMFORT_BODY_WEIGHT_FRACTION = (0.25, 0.05)  # per stick: mean, sd
COMFORT_RANGE = (0.15, 0.35)
REGIMES = {"steady": 0.15, "noisy": 0.60, "drifting": 0.15, "obstacle": 0.10}
SPREAD_RANGE_M = (0.02, 0.10)
STICK_NOISE_RANGE_M = (0.01, 0.03)
FIT_LENGTH_SD, FIT_LENGTH_LIMIT = 0.02, 0.05
FIT_MASS_SD_KG, FIT_MASS_LIMIT_KG = 3.0, 10.0
GRAVITY = 9.81


def _clipped_normal(rng: np.random.Generator, mean: float, sd: float, bounds: tuple[float, float]) -> float:
    return float(np.clip(rng.normal(mean, sd), *bounds))


def draw_patient(rng: np.random.Generator, name: str) -> VirtualPatient:
    """One patient drawn from the population's distributions with ``rng``."""
    sex = "male" if rng.random() < MALE_SHARE else "female"
    height = round(_clipped_normal(rng, *HEIGHT_M[sex], HEIGHT_RANGE_M), 3)
    bmi = _clipped_normal(rng, *BMI, BMI_DRAW_RANGE)
    mass = round(bmi * height**2, 1)
    strength = round(float(np.clip(rng.lognormal(0.0, ARM_STRENGTH_SD_LOG), *ARM_STRENGTH_RANGE)), 3)
    comfort = round(_clipped_normal(rng, *COMFORT_BODY_WEIGHT_FRACTION, COMFORT_RANGE) * mass * GRAVITY, 1)
    regime = str(rng.choice(list(REGIMES), p=list(REGIMES.values())))
    spread = round(float(rng.uniform(*SPREAD_RANGE_M)), 3)
    data = {
        "name": name, "mass_kg": mass, "height_m": height, "arm_strength": strength, "comfortable_stick_force_n": comfort,
        "placement": {"regime": regime, "spread_m": 0.0 if regime == "steady" else spread,
                      "stick_noise_m": round(float(rng.uniform(*STICK_NOISE_RANGE_M)), 3)},
        "fit": {"length_error_fraction": round(_clipped_normal(rng, 0.0, FIT_LENGTH_SD, (-FIT_LENGTH_LIMIT, FIT_LENGTH_LIMIT)), 4),
                "mass_error_kg": round(_clipped_normal(rng, 0.0, FIT_MASS_SD_KG, (-FIT_MASS_LIMIT_KG, FIT_MASS_LIMIT_KG)), 1)},
    }
    return build(VirtualPatient, data)


def draw_population(n: int, seed: int) -> list[VirtualPatient]:
    """``n`` patients for ``seed`` (the same for the same seed, each independent of ``n``: patient
    ``i`` of 8 is patient ``i`` of 1000), named ``pop<seed>-<i>``."""
    if n <= 0:
        raise ConfigError(f"a population needs at least one patient, got {n}", key="patients")
    return [draw_patient(np.random.default_rng(np.random.SeedSequence([seed, i])), f"pop{seed}-{i:04d}") for i in range(n)]


def patient_yaml(patient: VirtualPatient) -> str:
    """The patient as a patient file (read back by :func:`load_patient`)."""
    data = config_to_dict(patient)
    if data.get("stick_length_m") is None:
        data.pop("stick_length_m", None)
    return yaml.safe_dump(data, sort_keys=False)


__all__ = ["PATIENTS_DIR", "draw_patient", "draw_population", "estimated_body", "fitted_body", "load_patient", "patient_config",
           "patient_yaml", "shipped_patients"]
