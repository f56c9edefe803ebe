"""Schema of a virtual patient (``config/patients/*.yaml``): one simulated patient of a population.

A virtual patient is the few numbers that make patients differ: body mass and height (the segment
masses and lengths follow from the anthropometric tables of ``sim.model.patient``), arm strength,
the stick force the patient finds comfortable, how variable their stick placement is, and how well
the exoskeleton's per-patient set-up (the controller's body model) fits them. Everything else is
the base configuration's. :func:`tools.population.patient_config` turns one into a configuration;
docs/POPULATION.md says what each field changes and where the population's distributions come from.

Not to be confused with ``controller.learned_dir``: the learned theta of a real patient.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from .loader import fail, field_spec

#: body mass index bounds (kg/m²) of a plausible adult; beyond them a mass and height pair is a typo
BMI_RANGE = (14.0, 50.0)


@dataclass(frozen=True, kw_only=True)
class PlacementConfig:
    """How variable the patient's stick placement is (``sim.patient.intention``, ``sim.patient.stick_noise_m``)."""

    regime: Literal["steady", "noisy", "drifting", "obstacle"] = field_spec(
        doc="steady: always the same placement; noisy: Gaussian white noise about it (the paper's); drifting: a pace "
            "that wanders slowly; obstacle: now and then a deliberately short or long placement.")
    spread_m: float = field_spec(doc="noisy and drifting: standard deviation of the intended placement.", unit="m", min=0.0, max=0.2)
    stick_noise_m: float = field_spec(doc="Standard deviation of each stick's placement about the intention.", unit="m",
                                      min=0.0, max=0.1)


@dataclass(frozen=True, kw_only=True)
class FitConfig:
    """How far the controller's body model (``controller.body``, ``controller.legs``: the lengths and
    masses measured when the exoskeleton is set up for the patient) is off the patient."""

    length_error_fraction: float = field_spec(
        doc="Every length of the controller's model (legs, arms, sticks, widths) is this fraction longer than the patient's.",
        min=-0.15, max=0.15)
    mass_error_kg: float = field_spec(doc="The controller's model of the patient is this much heavier.", unit="kg",
                                      min=-30.0, max=30.0)


@dataclass(frozen=True, kw_only=True)
class VirtualPatient:
    name: str = field_spec(doc="Name of the patient (file stem by convention).")
    mass_kg: float = field_spec(doc="Body mass of the patient, without the exoskeleton.", unit="kg", min=35.0, max=160.0)
    height_m: float = field_spec(doc="Body height of the patient.", unit="m", min=1.40, max=2.10)
    arm_strength: float = field_spec(
        doc="The arms' strength against the reference patient's: their torque limits, stiffness and damping are scaled by it.",
        min=0.2, max=2.5)
    comfortable_stick_force_n: float = field_spec(
        doc="Mean force on each stick the patient finds comfortable over a step (the population report compares against it).",
        unit="N", min=10.0, max=600.0)
    stick_length_m: float | None = field_spec(
        doc="The sticks' length from grip to tip; absent: fitted to the height, as the reference patient's.",
        unit="m", min=0.5, max=1.3, default=None)
    placement: PlacementConfig = field_spec(doc="How variable the stick placement is.")
    fit: FitConfig = field_spec(doc="How far the controller's body model is off the patient.")

    def validate(self) -> None:
        if not self.name.strip() or any(c in self.name for c in "/\\\0"):
            fail("name", f"{self.name!r}: give a name without slashes")
        bmi = self.mass_kg / self.height_m**2
        if not BMI_RANGE[0] <= bmi <= BMI_RANGE[1]:
            fail("mass_kg", f"{self.mass_kg} kg at {self.height_m} m is a body mass index of {bmi:.1f} kg/m², "
                            f"outside {BMI_RANGE[0]:g}-{BMI_RANGE[1]:g}")
