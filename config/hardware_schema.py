"""Schema of the ``hardware`` section: the exoskeleton and its sticks, one physical fact each, read
by the controller and by the simulation (each gets it as its ``hardware``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .loader import fail, field_spec


@dataclass(frozen=True, kw_only=True)
class JointConfig:
    lower_rad: float = field_spec(doc="Lower position limit.", unit="rad", min=-math.pi, max=math.pi)
    upper_rad: float = field_spec(doc="Upper position limit.", unit="rad", min=-math.pi, max=math.pi)
    torque_limit_nm: float = field_spec(doc="Largest torque the actuator (or the patient's muscle) applies.", unit="N.m", min=0.0, max=400.0)
    velocity_limit_rad_s: float = field_spec(doc="Largest joint speed.", unit="rad/s", min=0.1, max=30.0)

    def validate(self) -> None:
        if self.lower_rad >= self.upper_rad:
            fail("lower_rad", f"{self.lower_rad} must be below upper_rad {self.upper_rad}")


@dataclass(frozen=True, kw_only=True)
class AnkleConfig:
    lower_rad: float = field_spec(doc="Plantarflexion limit (negative: toes down).", unit="rad", min=-1.2, max=0.0)
    upper_rad: float = field_spec(doc="Dorsiflexion limit (toes up).", unit="rad", min=0.0, max=1.0)
    stiffness_nm_rad: float = field_spec(doc="Passive spring stiffness.", unit="N.m/rad", min=0.0, max=5000.0)
    rest_rad: float = field_spec(doc="Spring rest angle (positive: dorsiflexed, toes up).", unit="rad", min=-0.6, max=0.6)
    friction_nm: float = field_spec(doc="Coulomb-like damping torque (a velocity motor with zero target).", unit="N.m", min=0.0, max=50.0)

    def validate(self) -> None:
        if not self.lower_rad <= self.rest_rad <= self.upper_rad:
            fail("rest_rad", "must lie between lower_rad and upper_rad")


@dataclass(frozen=True, kw_only=True)
class ExoJointsConfig:
    """The exoskeleton's joints, in the joints' convention (docs/PROTOCOL.md)."""

    hip: JointConfig = field_spec(doc="Exoskeleton hip flexion (+) / extension (-).")
    knee: JointConfig = field_spec(doc="Exoskeleton knee flexion (+); 0 is straight.")
    ankle: AnkleConfig = field_spec(doc="Passive spring ankle.")


@dataclass(frozen=True, kw_only=True)
class FootConfig:
    heel_back_m: float = field_spec(doc="Heel contact behind the ankle.", unit="m", min=0.0, max=0.2)
    toe_front_m: float = field_spec(doc="Toe contact ahead of the ankle.", unit="m", min=0.05, max=0.35)
    half_width_m: float = field_spec(doc="Half the sole width (contacts at +-).", unit="m", min=0.01, max=0.1)
    contact_radius_m: float = field_spec(doc="Radius of the four sole contact spheres.", unit="m", min=0.005, max=0.05)


@dataclass(frozen=True, kw_only=True)
class StickConfig:
    mass_kg: float = field_spec(doc="Mass of one stick (crutch).", unit="kg", min=0.1, max=3.0)
    length_m: float = field_spec(doc="From the grip (hand) to the tip, along the forearm axis.", unit="m", min=0.3, max=1.5)
    tip_radius_m: float = field_spec(doc="Radius of the rubber tip (contact sphere).", unit="m", min=0.005, max=0.05)


@dataclass(frozen=True, kw_only=True)
class HardwareConfig:
    """The exoskeleton's joints and foot plates, and the two sticks."""

    joints: ExoJointsConfig = field_spec(doc="The exoskeleton's joints: limits, drives, the ankle springs.")
    foot: FootConfig = field_spec(doc="The foot plate's sole: its contacts around the ankle joint.")
    sticks: StickConfig = field_spec(doc="The two forearm sticks (crutches).")
