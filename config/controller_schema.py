"""Schema of the ``controller`` section: leg geometry, the DMP swing, step-length bounds, learning."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from .hardware_schema import HardwareConfig
from .loader import fail, field_spec


@dataclass(frozen=True, kw_only=True)
class LegConfig:
    """The exoskeleton leg as set to the patient (from the fitting; its joints' ranges: ``hardware.joints``)."""

    MOVED_KEYS: ClassVar[dict[str, str]] = {
        "hip_min_rad": "hardware.joints.hip.lower_rad", "hip_max_rad": "hardware.joints.hip.upper_rad",
        "knee_min_rad": "hardware.joints.knee.lower_rad", "knee_max_rad": "hardware.joints.knee.upper_rad",
    }

    thigh_m: float = field_spec(doc="Hip to knee joint distance.", unit="m", min=0.2, max=0.7)
    shank_m: float = field_spec(doc="Knee to ankle joint distance.", unit="m", min=0.2, max=0.7)
    ankle_height_m: float = field_spec(doc="Ankle joint above the sole.", unit="m", min=0.02, max=0.2)

    @property
    def length_m(self) -> float:
        """The leg length, hip joint to floor standing straight: what the step lengths are fractions of."""
        return self.thigh_m + self.shank_m + self.ankle_height_m


@dataclass(frozen=True, kw_only=True)
class SwingConfig:
    """The swing-ankle DMP and its demonstration."""

    duration_scaled: float = field_spec(doc="Swing duration tau in units of sqrt(leg length / g) (dynamic similarity, Hof 1996): one value serves every leg length; seconds in `aider-exo config check`.", unit="-", min=1.0, max=16.0)
    demonstration_duration_s: float = field_spec(doc="Duration of the demonstration the DMP is fitted to (the fit does not depend on it: a DMP scales in time).", unit="s", min=0.3, max=5.0)
    clearance_m: float = field_spec(doc="Peak ankle lift of the demonstration.", unit="m", min=0.02, max=0.3)
    demonstration_step_m: float = field_spec(doc="Step length of the demonstration the DMP is fitted to (goals shorter than it make the foot dip backward first: the Pastor form does not scale the shape).", unit="m", min=0.02, max=0.6)
    n_basis: int = field_spec(doc="Gaussian basis functions per dimension.", min=3, max=200)
    stiffness: float = field_spec(doc="DMP spring K (damping is critical, 2 sqrt(K)).", min=1.0, max=10000.0)
    alpha_s: float = field_spec(doc="Phase decay (ln 100: phase 0.01 at t = tau).", min=0.1, max=50.0)
    regularisation: float = field_spec(doc="Ridge regularisation of the weight fit.", min=0.0, max=1.0)
    substeps: int = field_spec(doc="RK4 substeps per 20 ms tick.", min=1, max=100)


@dataclass(frozen=True, kw_only=True)
class StepConfig:
    """Step length: the uncompensated goal and the hard safety clamp, as fractions of the leg
    length (``controller.legs``: hip to floor), so that one configuration serves every patient."""

    init_fraction: float = field_spec(doc="g_init: step length without compensation.", unit="leg lengths", min=0.02, max=0.6)
    min_fraction: float = field_spec(doc="Shortest step ever commanded.", unit="leg lengths", min=0.02, max=0.6)
    max_fraction: float = field_spec(doc="Longest step ever commanded.", unit="leg lengths", min=0.02, max=0.6)

    def validate(self) -> None:
        if self.min_fraction > self.max_fraction:
            fail("min_fraction", f"must not exceed max_fraction {self.max_fraction}")
        if not self.min_fraction <= self.init_fraction <= self.max_fraction:
            fail("init_fraction", f"must lie between min_fraction {self.min_fraction} and max_fraction {self.max_fraction}")


@dataclass(frozen=True, kw_only=True)
class LearningConfig:
    """PI² over theta = (alpha, Xhat_CoM) of the step-length compensation."""

    method: Literal["pi2", "pibb"] = field_spec(doc="PI² (the paper's) or PI^BB.")
    rollouts_per_update: int = field_spec(doc="K: roll-outs per update (paper: 5).", min=2, max=100)
    steps_per_rollout: int = field_spec(doc="N: gait cycles per roll-out (paper: 10).", min=1, max=100)
    temperature_h: float = field_spec(doc="Sharpness of the cost-to-weight exponent.", min=0.1, max=100.0)
    initial_alpha: float = field_spec(doc="Start value of alpha (paper A: -1.0, B: -0.4).", min=-100.0, max=100.0)
    initial_xhat: float = field_spec(doc="Start value of Xhat_CoM (paper A: 0.6, B: 0.9).", min=-1.0, max=2.0)
    noise_alpha: float = field_spec(doc="Exploration std of alpha at the start.", min=0.0, max=20.0)
    noise_xhat: float = field_spec(doc="Exploration std of Xhat_CoM at the start.", min=0.0, max=1.0)
    noise_decay: float = field_spec(doc="Exploration factor per accepted update.", min=0.01, max=1.0)
    noise_floor: float = field_spec(doc="Smallest exploration, as a fraction of the start.", min=0.0, max=1.0)
    average_last: int = field_spec(doc="The evaluated and deployed theta is the mean of the last M updates.", min=1, max=100)
    alpha_min: float = field_spec(doc="Lower bound of alpha.", min=-100.0, max=100.0)
    alpha_max: float = field_spec(doc="Upper bound of alpha.", min=-100.0, max=100.0)
    xhat_min: float = field_spec(doc="Lower bound of Xhat_CoM.", min=-1.0, max=2.0)
    xhat_max: float = field_spec(doc="Upper bound of Xhat_CoM.", min=-1.0, max=2.0)
    fall_cost: float = field_spec(doc="lambda1: cost of falling at the first step.", min=0.0, max=1e7)
    force_cost: float = field_spec(doc="lambda2: weight of the summed per-step stick force.", min=0.0, max=1e3)
    reuse_best: int = field_spec(doc="The best roll-outs of a batch carried into the next one (0: none, the paper's).", min=0, max=99)
    max_consecutive_rejections: int = field_spec(doc="Updates rejected in a row (non-finite or out of bounds) that disable learning for the run (docs/FAULTS.md F28).", min=1, max=100)

    def validate(self) -> None:
        if self.alpha_min >= self.alpha_max:
            fail("alpha_min", "must be below alpha_max")
        if self.xhat_min >= self.xhat_max:
            fail("xhat_min", "must be below xhat_max")
        if not self.alpha_min <= self.initial_alpha <= self.alpha_max:
            fail("initial_alpha", "must lie within alpha_min..alpha_max")
        if not self.xhat_min <= self.initial_xhat <= self.xhat_max:
            fail("initial_xhat", "must lie within xhat_min..xhat_max")
        if self.reuse_best >= self.rollouts_per_update:
            fail("reuse_best", "must be below rollouts_per_update")


@dataclass(frozen=True, kw_only=True)
class BodyConfig:
    """The patient in the exoskeleton as the controller models it (from the fitting session): what
    the state estimator needs to place the stick tips and the centre of mass from the sensors.

    Frames as the exoskeleton's: x forward, y left, z up, in the trunk (backpack IMU) frame with its
    origin midway between the hip joints. The patient's arm is a 2-DOF shoulder and an elbow whose
    axis is the forearm's y axis; the stick is rigid with the forearm (a forearm crutch's cuff).
    Masses include the exoskeleton's segments."""

    MOVED_KEYS: ClassVar[dict[str, str]] = {
        "tip_radius_m": "hardware.sticks.tip_radius_m", "foot_heel_m": "hardware.foot.heel_back_m",
        "foot_toe_m": "hardware.foot.toe_front_m", "foot_half_width_m": "hardware.foot.half_width_m",
        "ankle_stiffness_nm_rad": "hardware.joints.ankle.stiffness_nm_rad", "ankle_rest_rad": "hardware.joints.ankle.rest_rad",
    }

    hip_half_width_m: float = field_spec(doc="Hip joint from the trunk midline.", unit="m", min=0.03, max=0.3)
    shoulder_xyz_m: tuple[float, float, float] = field_spec(
        doc="Left shoulder joint from the hip midpoint (x, y, z; the right one mirrored).", unit="m", min=-1.0, max=1.5
    )
    upper_arm_m: float = field_spec(doc="Shoulder to elbow.", unit="m", min=0.15, max=0.5)
    elbow_to_tip_m: float = field_spec(doc="Elbow to the centre of the stick's tip.", unit="m", min=0.5, max=2.0)
    elbow_min_rad: float = field_spec(doc="Elbow flexion range, lower end.", unit="rad", min=-0.5, max=3.0)
    elbow_max_rad: float = field_spec(doc="Elbow flexion range, upper end.", unit="rad", min=0.0, max=3.0)
    trunk_kg: float = field_spec(doc="Trunk, head and arms' share carried by the trunk, with the backpack.", unit="kg", min=5.0, max=200.0)
    trunk_com_xz_m: tuple[float, float] = field_spec(doc="Trunk CoM from the hip midpoint (x, z).", unit="m", min=-0.5, max=1.0)
    thigh_kg: float = field_spec(doc="One thigh with its exoskeleton segment.", unit="kg", min=1.0, max=40.0)
    thigh_com_m: float = field_spec(doc="Thigh CoM below the hip joint, along the thigh.", unit="m", min=0.0, max=0.7)
    shank_kg: float = field_spec(doc="One shank with its exoskeleton segment.", unit="kg", min=0.5, max=30.0)
    shank_com_m: float = field_spec(doc="Shank CoM below the knee, along the shank.", unit="m", min=0.0, max=0.7)
    foot_kg: float = field_spec(doc="One foot with its shoe and plate.", unit="kg", min=0.2, max=10.0)
    foot_com_xz_m: tuple[float, float] = field_spec(doc="Foot CoM from the ankle (x, z), foot flat.", unit="m", min=-0.3, max=0.3)
    upper_arm_kg: float = field_spec(doc="One upper arm.", unit="kg", min=0.2, max=10.0)
    upper_arm_com_m: float = field_spec(doc="Upper arm CoM from the shoulder.", unit="m", min=0.0, max=0.5)
    forearm_kg: float = field_spec(doc="One forearm, hand and stick.", unit="kg", min=0.2, max=10.0)
    forearm_com_m: float = field_spec(doc="Forearm-and-stick CoM from the elbow.", unit="m", min=0.0, max=1.5)
    stick_loaded_n: float = field_spec(doc="A stick carrying more than this is on the ground.", unit="N", min=1.0, max=500.0)
    foot_loaded_n: float = field_spec(doc="A foot whose heel and toe carry more than this is on the ground.", unit="N", min=1.0, max=800.0)
    foot_flat_n: float = field_spec(doc="A loaded foot whose heel and toe each carry more than this is flat: the floor lies ankle height below its ankle.", unit="N", min=1.0, max=800.0)
    min_support_m: float = field_spec(
        doc="X_CoM/X_SP is undefined (nan) for a support polygon shorter than this fore-aft (feet side by side).",
        unit="m", min=0.01, max=0.5,
    )

    def validate(self) -> None:
        if self.elbow_min_rad >= self.elbow_max_rad:
            fail("elbow_min_rad", "must be below elbow_max_rad")


@dataclass(frozen=True, kw_only=True)
class EnvelopeConfig:
    """The safety envelope every joint command passes before it is encoded (docs/FAULTS.md I1).

    A value beyond the envelope is clamped and reported; beyond it by more than the excess
    allowance it is a fault (a wrong trajectory is not hidden by saturation)."""

    position_margin_rad: float = field_spec(doc="Keep-out band inside each joint limit.", unit="rad", min=0.0, max=0.3)
    max_velocity_rad_s: float = field_spec(doc="Largest commanded joint speed (feed-forward).", unit="rad/s", min=0.1, max=10.0)
    max_step_rad: float = field_spec(doc="Largest change of a position setpoint from one tick to the next.", unit="rad", min=0.001, max=0.5)
    max_torque_nm: float = field_spec(doc="Largest torque feed-forward and torque limit sent.", unit="N.m", min=1.0, max=200.0)
    position_excess_rad: float = field_spec(doc="A setpoint this far beyond the envelope is a fault.", unit="rad", min=0.0, max=1.0)
    rate_excess_factor: float = field_spec(
        doc="A speed, setpoint step or torque this many times its bound is a fault (docs/FAULTS.md F17: 1.2).", min=1.0, max=5.0
    )


@dataclass(frozen=True, kw_only=True)
class SafetyConfig:
    """Detection budgets of the fault table (docs/FAULTS.md section 3, docs/SAFETY.md), each with a hard bound."""

    lost_ticks: int = field_spec(doc="A node without a valid JOINT_STATUS for this many ticks in a row is lost: FAULT (F1-F3, F9; docs/FAULTS.md: at most 5).", min=1, max=5)
    integrity_errors: int = field_spec(doc="This many frames of the nodes rejected for their CRC or counter sequence ...", min=1, max=10)
    integrity_window_ticks: int = field_spec(doc="... within this many ticks: FAULT (F6-F8; docs/FAULTS.md: 2 in 5). Any error frame in the window: no new step (F11).", min=1, max=50)
    send_failure_ticks: int = field_spec(doc="A send that fails in this many ticks in a row: FAULT (F12, F13).", min=1, max=5)
    overrun_limit: int = field_spec(doc="This many overrun ticks ...", min=1, max=50)
    overrun_window_ticks: int = field_spec(doc="... within this many ticks, or one overrun of more than overrun_max_ticks: HOLD (F25).", min=10, max=1000)
    overrun_max_ticks: int = field_spec(doc="An overrun that skips more ticks than this: HOLD at once (F25: 3).", min=1, max=50)
    stuck_ticks: int = field_spec(doc="An encoder reading exactly the same for this many ticks ...", min=2, max=25)
    stuck_motion_rad: float = field_spec(doc="... with its setpoint this much further from the reading than when the reading froze: ENCODER_STUCK, FAULT (F14).", unit="rad", min=0.005, max=0.5)
    fall_tilt_rad: float = field_spec(doc="Trunk roll or pitch beyond this ...", unit="rad", min=0.1, max=1.2)
    fall_ticks: int = field_spec(doc="... for this many ticks: a fall, FAULT (F18).", min=1, max=5)
    stick_unloaded_n: float = field_spec(doc="A stick carrying less than this ...", unit="N", min=0.0, max=50.0)
    stick_unloaded_ticks: int = field_spec(doc="... for this many ticks in a row of a swing: HOLD once the swing has landed (F19).", min=2, max=50)
    supply_warn_v: float = field_spec(doc="The lowest supply voltage the nodes report below this ...", unit="V", min=5.0, max=60.0)
    supply_warn_ticks: int = field_spec(doc="... for this many ticks: a warning, no change (F29).", min=1, max=500)
    supply_critical_v: float = field_spec(doc="Below this (under supply_warn_v) ...", unit="V", min=5.0, max=60.0)
    supply_critical_ticks: int = field_spec(doc="... for this many ticks: no new step, HOLD in double support (a swing lands first) (F29).", min=1, max=100)
    hold_torque_nm: float = field_spec(doc="Torque limit of every HOLD command.", unit="N.m", min=1.0, max=200.0)
    reset_healthy_ticks: int = field_spec(doc="An operator reset leaves FAULT only after the nodes were healthy this long (I4: 25).", min=5, max=1000)

    def validate(self) -> None:
        if self.supply_critical_v >= self.supply_warn_v:
            fail("supply_critical_v", f"must be below supply_warn_v {self.supply_warn_v}")


@dataclass(frozen=True, kw_only=True)
class GaitConfig:
    """The legs through the gait cycle (controller/gait.py, docs/CONTROLLER.md): the weight shift
    and lean of double support, the stick moves that gate them, and the end of the swing."""

    shift_margin_m: float = field_spec(doc="Weight shift: the CoM at least this far inside the support that stays when a stick lifts.",
                                       unit="m", min=0.0, max=0.2)
    balance_margin_m: float = field_spec(doc="Weight shift: the CoM at least this far ahead of the ankles' midpoint.", unit="m", min=0.0, max=0.2)
    shift_speed_m_s: float = field_spec(doc="Weight shift: top speed of the CoM goal.", unit="m/s", min=0.005, max=0.5)
    lean_speed_m_s: float = field_spec(doc="Lean: speed of the CoM goal toward the sticks.", unit="m/s", min=0.005, max=0.5)
    lean_lead_m: float = field_spec(doc="Lean: the CoM goal at most this far ahead of the CoM.", unit="m", min=0.0, max=0.3)
    lean_over_stance_m: float = field_spec(doc="A lean that stalls with the CoM less than half this past the stance ankle is not over.",
                                           unit="m", min=0.0, max=0.2)
    comfort_stick_n: float = field_spec(doc="The lean pauses while a stick carries this.", unit="N", min=10.0, max=1000.0)
    swing_stick_n: float = field_spec(doc="A step is ready with both sticks carrying this.", unit="N", min=1.0, max=500.0)
    tips_ahead_m: float = field_spec(doc="... the tips' midpoint this far ahead of the front ankle ...", unit="m", min=0.0, max=0.6)
    stick_moves: Literal["both", "stance_side"] = field_spec(
        doc="The sticks the patient moves in each double support: both, or the one on the next swing's stance side "
            "(the four-point crutch gait). It is the patient's trained pattern: set it as the patient walks.")
    lean_stall_m: float = field_spec(doc="... and the lean over: the CoM no farther forward by this ...", unit="m", min=0.001, max=0.1)
    lean_stall_s: float = field_spec(doc="... in this long, once the lean has moved this far forward ...", unit="s", min=0.1, max=10.0)
    lean_start_s: float = field_spec(doc="... or in this long before (the body, still coming back from the stick moves, takes up to half a second to follow the lean).", unit="s", min=0.1, max=10.0)
    stick_lifted_n: float = field_spec(doc="A stick whose filtered force stays below this ...", unit="N", min=0.0, max=100.0)
    stick_lift_s: float = field_spec(doc="... this long has been lifted.", unit="s", min=0.02, max=2.0)
    stick_placed_n: float = field_spec(doc="A lifted stick carrying this again has moved.", unit="N", min=1.0, max=500.0)
    stick_filter_s: float = field_spec(doc="Time constant of the stick-force filter of the stick-move detection.", unit="s", min=0.0, max=1.0)
    max_lead_m: float = field_spec(doc="The hips are commanded at most this far fore-aft from where they are.", unit="m", min=0.001, max=0.1)
    hip_advance_fraction: float = field_spec(doc="Swing: the stance leg carries the CoM goal this share of the step length forward.",
                                             min=0.0, max=1.0)
    velocity_filter_s: float = field_spec(doc="Time constant of the CoM's and the hips' velocity filters.", unit="s", min=0.0, max=1.0)
    max_target_step_rad: float = field_spec(doc="No joint target moves more than this per tick (below the envelope's bound).", unit="rad", min=0.001, max=0.5)
    reach_margin_m: float = field_spec(doc="Stance legs stay this much short of full reach (the hips lower).", unit="m", min=0.0, max=0.1)
    height_speed_m_s: float = field_spec(doc="Speed at which the hips lower or rise.", unit="m/s", min=0.005, max=0.5)
    foot_contact_n: float = field_spec(doc="A foot carrying this is on the floor (a swing foot: has landed).", unit="N", min=1.0, max=800.0)
    landing_fraction: float = field_spec(doc="A landing counts after this fraction of the swing's duration.", min=0.1, max=1.0)
    landing_blend_s: float = field_spec(doc="A landed foot takes its share of the body's load over this time.", unit="s", min=0.0, max=2.0)
    landing_depth_m: float = field_spec(doc="The swing's goal lies this far below the stance ankle.", unit="m", min=0.0, max=0.05)
    swing_timeout_s: float = field_spec(doc="A swing with no landing ends this long after its duration.", unit="s", min=0.0, max=5.0)
    placement_gain: float = field_spec(
        doc="Foot placement: each step's shortfall (commanded less as placed) adds this fraction of itself to how far "
            "beyond the commanded length the next swings aim (0: aim at the commanded length).", min=0.0, max=1.0)
    max_aim_offset_m: float = field_spec(doc="Foot placement: a swing aims at most this far beyond or short of the commanded length.",
                                         unit="m", min=0.0, max=0.1)

    def validate(self) -> None:
        if self.stick_placed_n <= self.stick_lifted_n:
            fail("stick_placed_n", f"must be above stick_lifted_n {self.stick_lifted_n}")


@dataclass(frozen=True, kw_only=True)
class BalanceConfig:
    """The wrench the stance legs' torque feed-forward asks for at the CoM (controller/balance.py)."""

    com_stiffness_n_m: float = field_spec(doc="Fore-aft spring toward the gait's CoM goal.", unit="N/m", min=0.0, max=20000.0)
    com_damping_ns_m: float = field_spec(doc="Fore-aft damping of the CoM over the floor.", unit="N.s/m", min=0.0, max=5000.0)
    height_stiffness_n_m: float = field_spec(doc="Spring of the hips toward the stance height.", unit="N/m", min=0.0, max=50000.0)
    height_damping_ns_m: float = field_spec(doc="Damping of the hips' height.", unit="N.s/m", min=0.0, max=5000.0)
    tilt_stiffness_nm_rad: float = field_spec(doc="Roll and pitch spring of the trunk toward upright and its pitch goal.", unit="N.m/rad",
                                              min=0.0, max=20000.0)
    tilt_damping_nms_rad: float = field_spec(doc="Roll and pitch damping of the trunk (IMU rates).", unit="N.m.s/rad", min=0.0, max=2000.0)
    friction: float = field_spec(doc="Friction coefficient the distribution allows a foot.", min=0.05, max=1.5)
    min_foot_n: float = field_spec(doc="Smallest load the distribution gives a stance foot's contact.", unit="N", min=0.0, max=200.0)


@dataclass(frozen=True, kw_only=True)
class CompensationConfig:
    """theta = (alpha, Xhat_CoM) of the step-length compensation when no learned patient file is loaded."""

    alpha: float = field_spec(doc="alpha: step length per unit of X_CoM/X_SP (over the stance ankle and both stick tips at the swing's start).", unit="m", min=-100.0, max=100.0)
    xhat_com: float = field_spec(doc="Xhat_CoM: the CoM ratio at which the step is g_init.", min=-1.0, max=2.0)


@dataclass(frozen=True, kw_only=True)
class ControllerConfig:
    MOVED_KEYS: ClassVar[dict[str, str]] = {"patients_dir": "controller.learned_dir"}

    legs: LegConfig = field_spec(doc="Exoskeleton leg geometry and joint limits.")
    swing: SwingConfig = field_spec(doc="The DMP swing generator.")
    step: StepConfig = field_spec(doc="Step length and its safety clamp.")
    learning: LearningConfig = field_spec(doc="Online learning of the step-length compensation.")
    envelope: EnvelopeConfig = field_spec(doc="The safety envelope of every joint command.")
    safety: SafetyConfig = field_spec(doc="Fault detection budgets (docs/SAFETY.md).")
    body: BodyConfig = field_spec(doc="The patient-plus-exoskeleton model of the state estimator.")
    gait: GaitConfig = field_spec(doc="The legs through the gait cycle.")
    balance: BalanceConfig = field_spec(doc="The stance legs' torque feed-forward.")
    compensation: CompensationConfig = field_spec(doc="The step-length compensation's theta without a patient file.")
    learned_dir: str = field_spec(doc="Directory of the learned parameters per patient, <learned_dir>/<NAME>.json (relative: to the folder of the configuration file).")
    hardware: HardwareConfig | None = field_spec(doc="The exoskeleton and the sticks: the top-level hardware section.", derived=True)

    def validate(self) -> None:
        if self.safety.hold_torque_nm > self.envelope.max_torque_nm:
            fail("safety.hold_torque_nm", f"must not exceed envelope.max_torque_nm {self.envelope.max_torque_nm}")
        if self.gait.max_target_step_rad > self.envelope.max_step_rad:
            fail("gait.max_target_step_rad", f"must not exceed envelope.max_step_rad {self.envelope.max_step_rad}")
