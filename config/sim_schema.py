"""Schema of the ``sim`` section: the HHEA model (patient + exoskeleton + sticks), its physics,
the patient's own control, sensors and fall criteria.

Segment tables are Winter (2009, after Dempster): mass as a fraction of body mass, length as a
fraction of body height (Drillis and Contini), centre of mass from the proximal joint and radius
of gyration about the centre of mass as fractions of the segment length.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from .hardware_schema import HardwareConfig, JointConfig
from .loader import fail, field_spec


@dataclass(frozen=True, kw_only=True)
class SegmentConfig:
    """One body segment from an anthropometric table."""

    mass_fraction: float = field_spec(doc="Segment mass / body mass.", min=0.0, max=1.0)
    length_fraction: float = field_spec(doc="Segment length / body height.", min=0.0, max=1.0)
    com_fraction: float = field_spec(doc="Centre of mass from the proximal end / segment length.", min=0.0, max=1.0)
    gyration_fraction: float = field_spec(doc="Radius of gyration about the CoM / segment length.", min=0.0, max=1.0)

    def validate(self) -> None:
        for key in ("mass_fraction", "length_fraction", "gyration_fraction"):
            if getattr(self, key) <= 0:
                fail(key, "must be positive")


@dataclass(frozen=True, kw_only=True)
class PatientBodyConfig:
    mass_kg: float = field_spec(doc="Body mass of the patient.", unit="kg", min=30.0, max=160.0)
    height_m: float = field_spec(doc="Body height of the patient.", unit="m", min=1.40, max=2.10)
    thigh: SegmentConfig = field_spec(doc="Thigh segment.")
    shank: SegmentConfig = field_spec(doc="Shank (leg) segment.")
    foot: SegmentConfig = field_spec(doc="Foot segment (length = heel to toe).")
    upper_arm: SegmentConfig = field_spec(doc="Upper arm segment.")
    forearm: SegmentConfig = field_spec(doc="Forearm segment.")
    hand: SegmentConfig = field_spec(doc="Hand segment (the grip sits at its CoM).")
    ankle_height_fraction: float = field_spec(doc="Ankle joint height / body height.", min=0.01, max=0.1)
    shoulder_height_fraction: float = field_spec(doc="Shoulder joint height / body height, standing.", min=0.6, max=0.9)
    hip_width_m: float = field_spec(doc="Distance between the hip joint centres.", unit="m", min=0.1, max=0.4)
    shoulder_width_m: float = field_spec(doc="Distance between the shoulder joint centres.", unit="m", min=0.2, max=0.6)
    trunk_com_above_hip_m: float = field_spec(doc="Height of the trunk+head CoM above the hip joints.", unit="m", min=0.0, max=0.6)
    trunk_depth_m: float = field_spec(doc="Front-back depth of the trunk (for its inertia).", unit="m", min=0.1, max=0.5)

    def validate(self) -> None:
        limbs = 2 * sum(
            s.mass_fraction for s in (self.thigh, self.shank, self.foot, self.upper_arm, self.forearm, self.hand)
        )
        if limbs >= 0.8:
            fail("thigh.mass_fraction", f"limb mass fractions sum to {limbs:.3f}: nothing is left for the trunk")
        if self.shoulder_width_m <= self.hip_width_m * 0.5:
            fail("shoulder_width_m", "must be wider than half the hip width")


@dataclass(frozen=True, kw_only=True)
class ExoskeletonConfig:
    trunk_kg: float = field_spec(doc="Backpack, pelvis frame, batteries and hip motors on the trunk.", unit="kg", min=0.0, max=40.0)
    trunk_com_offset_m: tuple[float, float] = field_spec(
        doc="Offset (x forward, z up) of the backpack's CoM from the hip joint midpoint.", unit="m", min=-0.5, max=0.8
    )
    thigh_kg: float = field_spec(doc="Exoskeleton thigh link with the knee motor, per leg.", unit="kg", min=0.0, max=10.0)
    shank_kg: float = field_spec(doc="Exoskeleton shank link, per leg.", unit="kg", min=0.0, max=10.0)
    foot_kg: float = field_spec(doc="Exoskeleton foot plate and shoe, per leg.", unit="kg", min=0.0, max=5.0)


@dataclass(frozen=True, kw_only=True)
class ArmJointsConfig:
    """The patient's arm joints (the exoskeleton's: ``hardware.joints``)."""

    MOVED_KEYS: ClassVar[dict[str, str]] = {"hip": "hardware.joints.hip", "knee": "hardware.joints.knee", "ankle": "hardware.joints.ankle"}

    shoulder_flexion: JointConfig = field_spec(doc="Patient's shoulder flexion (+, arm forward).")
    shoulder_abduction: JointConfig = field_spec(doc="Patient's shoulder abduction (+, arm out to the side).")
    elbow: JointConfig = field_spec(doc="Patient's elbow flexion (+).")


@dataclass(frozen=True, kw_only=True)
class ModelConfig:
    """The patient's body and arms, and the exoskeleton's masses (its joints, feet and the sticks:
    the top-level ``hardware`` section, which the controller reads too)."""

    MOVED_KEYS: ClassVar[dict[str, str]] = {"sticks": "hardware.sticks", "foot": "hardware.foot"}

    patient: PatientBodyConfig = field_spec(doc="Anthropometrics of the patient.")
    exoskeleton: ExoskeletonConfig = field_spec(doc="Masses of the exoskeleton parts.")
    joints: ArmJointsConfig = field_spec(doc="The patient's arm joints: limits and strengths.")
    friction: float = field_spec(doc="Friction coefficient of soles, stick tips and floor.", min=0.1, max=2.0)


@dataclass(frozen=True, kw_only=True)
class PhysicsConfig:
    rate_hz: int = field_spec(doc="Physics step rate; the node firmware's joint loop runs at this rate.", unit="Hz", min=200, max=2000)
    solver_iterations: int = field_spec(doc="Constraint solver iterations per step.", min=5, max=200)

    def validate(self) -> None:
        if self.rate_hz % 50:
            fail("rate_hz", "must be a multiple of 50 (whole physics steps per 20 ms tick)")


@dataclass(frozen=True, kw_only=True)
class FirmwareConfig:
    """The node boards' joint impedance loop (PD to torque at the physics rate, torque-limited)."""

    stiffness_nm_rad: float = field_spec(doc="Track mode position gain.", unit="N.m/rad", min=0.0, max=10000.0)
    damping_nms_rad: float = field_spec(doc="Track mode velocity gain.", unit="N.m.s/rad", min=0.0, max=200.0)
    hold_stiffness_nm_rad: float = field_spec(doc="Hold and quick-stop position gain.", unit="N.m/rad", min=0.0, max=10000.0)
    hold_damping_nms_rad: float = field_spec(doc="Hold and quick-stop velocity gain.", unit="N.m.s/rad", min=0.0, max=200.0)
    hold_torque_limit_nm: float = field_spec(doc="Torque limit while holding after a quick stop.", unit="N.m", min=0.0, max=400.0)


@dataclass(frozen=True, kw_only=True)
class SensorsConfig:
    encoder_resolution_rad: float = field_spec(doc="Joint encoder resolution.", unit="rad", min=1e-6, max=0.01)
    imu_orientation_noise_rad: float = field_spec(doc="IMU orientation noise (std).", unit="rad", min=0.0, max=0.1)
    imu_orientation_resolution_rad: float = field_spec(doc="IMU orientation output resolution.", unit="rad", min=1e-6, max=0.01)
    gyro_noise_rad_s: float = field_spec(doc="Gyroscope noise (std).", unit="rad/s", min=0.0, max=0.5)
    gyro_resolution_rad_s: float = field_spec(doc="Gyroscope output resolution.", unit="rad/s", min=1e-6, max=0.1)
    accel_noise_m_s2: float = field_spec(doc="Accelerometer noise (std).", unit="m/s^2", min=0.0, max=2.0)
    accel_resolution_m_s2: float = field_spec(doc="Accelerometer output resolution.", unit="m/s^2", min=1e-5, max=0.5)
    force_noise_n: float = field_spec(doc="Stick load cell and plantar sensor noise (std).", unit="N", min=0.0, max=50.0)
    force_resolution_n: float = field_spec(doc="Stick load cell and plantar sensor resolution.", unit="N", min=0.01, max=10.0)


@dataclass(frozen=True, kw_only=True)
class IntentionConfig:
    """Where the patient means to place the sticks and how far it means to lean onto them, step by
    step (:mod:`sim.intention`)."""

    regime: Literal["steady", "noisy", "drifting", "obstacle"] = field_spec(
        doc="steady: always ahead_m; noisy: Gaussian white noise (the paper's); drifting: a pace that wanders slowly; "
            "obstacle: now and then a deliberately short or long placement.")
    reference: Literal["com", "front_ankle"] = field_spec(
        doc="What the placement is ahead of: the CoM when the stick lifts, or the front foot's ankle (the stance foot of the next swing).")
    ahead_m: float = field_spec(doc="Mean intended stick placement ahead of the reference.", unit="m", min=0.1, max=0.8)
    spread_m: float = field_spec(doc="noisy and drifting: standard deviation of the intention about ahead_m.", unit="m", min=0.0, max=0.3)
    lean_x: float = field_spec(
        doc="Mean X_CoM/X_SP (stance heel 0 to stick tips 1) the patient leans to before a swing.", min=0.2, max=1.0)
    lean_spread: float = field_spec(doc="noisy and drifting: standard deviation of the lean's X_CoM/X_SP about lean_x.", min=0.0, max=0.3)
    drift_steps: float = field_spec(doc="drifting: correlation length of the wander.", unit="steps", min=1.0, max=1000.0)
    obstacle_probability: float = field_spec(doc="obstacle: chance of a short or long placement at a step.", min=0.0, max=1.0)
    obstacle_offset_m: float = field_spec(doc="obstacle: that placement this much shorter or longer than ahead_m.", unit="m", min=0.0, max=0.4)


@dataclass(frozen=True, kw_only=True)
class PatientControlConfig:
    """The patient's part of the walk: where the sticks go, and the arms' balance control."""

    intention: IntentionConfig = field_spec(doc="Where the patient means to place the sticks and how far it leans, per step.")
    stick_noise_m: float = field_spec(doc="Std of each stick's placement error about the intention.", unit="m", min=0.0, max=0.2)
    stick_reach_elbow_rad: float = field_spec(
        doc="A stick goal farther from the shoulder than the arm reaches with the elbow this far bent is clamped (and counted).",
        unit="rad", min=0.0, max=1.5)
    stick_min_advance_m: float = field_spec(
        doc="A moved stick lands at least this far ahead of where it stood (the gait moves the sticks forward).",
        unit="m", min=0.0, max=0.3)
    stick_half_width_m: float = field_spec(doc="Lateral distance of the stick tips from the midline.", unit="m", min=0.1, max=0.6)
    arm_stiffness_nm_rad: float = field_spec(doc="Arm joint stiffness of the patient's posture control.", unit="N.m/rad", min=0.0, max=5000.0)
    arm_damping_nms_rad: float = field_spec(doc="Arm joint damping of the patient's posture control.", unit="N.m.s/rad", min=0.0, max=100.0)
    stick_mode: Literal["together", "alternating", "four_point"] = field_spec(
        doc="Per double support: both sticks at once (the paper's words), both one at a time, or one, the stick on the "
            "front foot's side (the four-point crutch gait; docs/SIM.md says which and why).")


@dataclass(frozen=True, kw_only=True)
class GaitConfig:
    """The walk's behaviour: the patient's stick moves, shift and lean, and the scripted
    exoskeleton gait that stands in for the controller in ``aider-exo sim`` (docs/SIM.md)."""

    step_length_m: float = field_spec(doc="Step length of the scripted gait (a sweep overrides it).", unit="m", min=0.02, max=0.6)
    swing_time_s: float = field_spec(doc="Duration of the swing trajectory.", unit="s", min=0.3, max=5.0)
    swing_clearance_m: float = field_spec(doc="Peak lift of the swing ankle.", unit="m", min=0.01, max=0.3)
    hip_advance_fraction: float = field_spec(
        doc="The scripted stance leg carries the hip this share of the step length forward during a swing.", min=0.0, max=1.0)
    stick_move_time_s: float = field_spec(doc="Time the patient takes to move a stick.", unit="s", min=0.1, max=5.0)
    stick_lift_m: float = field_spec(doc="Peak lift of a moving stick tip.", unit="m", min=0.0, max=0.3)
    unload_time_s: float = field_spec(doc="Time the patient takes to unload a stick before lifting it.", unit="s", min=0.0, max=3.0)
    lean_speed_m_s: float = field_spec(doc="Speed of the lean toward the sticks (the patient's, and the scripted gait's plan).",
                                       unit="m/s", min=0.01, max=1.0)
    lean_lead_m: float = field_spec(doc="A lean's CoM goal runs at most this far ahead of the CoM (the patient's and the scripted gait's).",
                                    unit="m", min=0.0, max=0.3)
    lean_stall_m: float = field_spec(doc="The scripted gait's lean is over when the CoM gets no farther by this ...", unit="m",
                                     min=0.0005, max=0.1)
    lean_stall_s: float = field_spec(doc="... in this time (once it has moved that far) ...", unit="s", min=0.05, max=5.0)
    lean_start_s: float = field_spec(doc="... or in this time before it has.", unit="s", min=0.05, max=5.0)
    lean_x_min: float = field_spec(doc="The patient leans at least to this X_CoM/X_SP, whatever its intention ...", min=0.0, max=1.0)
    lean_x_max: float = field_spec(doc="... and at most to this one.", min=0.0, max=1.0)
    stick_force_comfort_n: float = field_spec(doc="The patient leans no further while a stick carries more.", unit="N", min=10.0, max=2000.0)
    strut_spread: float = field_spec(
        doc="A stick's force lies within this half-width (tangent) of the line from its tip to the shoulder: the arm pushes along itself.",
        min=0.0, max=1.0)
    swing_trigger_stick_n: float = field_spec(doc="Both sticks above this load let the scripted gait swing.", unit="N", min=0.0, max=1000.0)
    stick_planted_n: float = field_spec(doc="A placed stick carrying this much is planted.", unit="N", min=1.0, max=500.0)
    foot_contact_n: float = field_spec(doc="A foot carrying more than this is on the floor.", unit="N", min=1.0, max=1000.0)
    foot_lift_s: float = field_spec(doc="Patient-only mode: a foot unloaded this long ...", unit="s", min=0.0, max=2.0)
    foot_raise_m: float = field_spec(doc="... and raised this far off the floor is swinging.", unit="m", min=0.0, max=0.2)
    shift_margin_m: float = field_spec(doc="Margin of the CoM in the support that remains before a stick lifts.", unit="m", min=0.0, max=0.2)
    balance_margin_m: float = field_spec(
        doc="Before a stick lifts the CoM stays at least this far ahead of the ankles' midpoint, leaning on the other stick "
            "(behind it the body rocks backward off its passive ankles, and sticks only push).", unit="m", min=0.0, max=0.2)
    shift_speed_m_s: float = field_spec(doc="Speed of the patient's shift before a stick lifts.", unit="m/s", min=0.005, max=1.0)
    shift_min_s: float = field_spec(doc="Shortest shift before a stick lifts.", unit="s", min=0.0, max=5.0)
    shift_still_speed_m_s: float = field_spec(doc="The CoM must be slower than this before a stick lifts.", unit="m/s", min=0.0, max=1.0)
    trunk_pitch_rad: float = field_spec(doc="Trunk pitch the patient keeps.", unit="rad", min=-0.5, max=0.8)
    leg_reach_m: float = field_spec(doc="Hip-to-ankle distance the stance legs do not exceed.", unit="m", min=0.3, max=1.2)
    settle_s: float = field_spec(doc="Standing time before the first stick move.", unit="s", min=0.0, max=30.0)
    min_contact_n: float = field_spec(doc="Smallest normal force the balance distribution gives a loaded contact.", unit="N", min=0.0, max=200.0)
    hip_speed_m_s: float = field_spec(doc="Fastest the scripted stance legs carry the hip toward the patient's goal.", unit="m/s", min=0.01, max=2.0)
    hip_lead_m: float = field_spec(
        doc="The scripted stance legs command the hip at most this far from where it is (no wind-up when the body does not follow).",
        unit="m", min=0.0, max=0.2)
    target_step_rad: float = field_spec(doc="Largest change of a scripted stance leg's joint target per tick.", unit="rad", min=0.001, max=0.5)

    def validate(self) -> None:
        if self.lean_x_max < self.lean_x_min:
            fail("lean_x_max", f"must not be below lean_x_min {self.lean_x_min}")


@dataclass(frozen=True, kw_only=True)
class FallConfig:
    tilt_limit_rad: float = field_spec(doc="Trunk roll or pitch beyond this is a fall.", unit="rad", min=0.2, max=1.5)
    min_hip_height_m: float = field_spec(doc="Hip joints lower than this is a fall (collapse).", unit="m", min=0.1, max=1.2)


@dataclass(frozen=True, kw_only=True)
class SagittalConfig:
    """The spring-damper that holds the trunk to the walking plane in the sagittal mode."""

    lateral_stiffness_n_m: float = field_spec(doc="Against sideways motion of the trunk.", unit="N/m", min=0.0, max=1e6)
    lateral_damping_ns_m: float = field_spec(doc="Against sideways velocity of the trunk.", unit="N.s/m", min=0.0, max=1e5)
    rotational_stiffness_nm_rad: float = field_spec(doc="Against trunk roll and yaw.", unit="N.m/rad", min=0.0, max=1e6)
    rotational_damping_nms_rad: float = field_spec(doc="Against trunk roll and yaw rates.", unit="N.m.s/rad", min=0.0, max=1e5)


@dataclass(frozen=True, kw_only=True)
class SimConfig:
    mode: Literal["full3d", "sagittal"] = field_spec(
        doc="full3d: the 3-D model (the paper's 18 DOF); sagittal: the same model with the trunk held to the walking plane."
    )
    physics: PhysicsConfig = field_spec(doc="Physics engine settings.")
    sagittal: SagittalConfig = field_spec(doc="Plane constraint of the sagittal mode.")
    model: ModelConfig = field_spec(doc="The HHEA model.")
    firmware: FirmwareConfig = field_spec(doc="Emulated node-board joint loop.")
    sensors: SensorsConfig = field_spec(doc="Sensor noise and resolution.")
    patient: PatientControlConfig = field_spec(doc="The patient model.")
    gait: GaitConfig = field_spec(doc="The walk: the patient's behaviour and the scripted exoskeleton gait.")
    fall: FallConfig = field_spec(doc="Fall detection (ground truth).")
    hardware: HardwareConfig | None = field_spec(doc="The exoskeleton and the sticks: the top-level hardware section.", derived=True)
