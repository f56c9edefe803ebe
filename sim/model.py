"""The HHEA body: segment geometry and masses from the configuration, and its URDF.

Frames: x forward, y left, z up. The base link is the trunk, its frame at the midpoint of the hip
joints. Joint angle conventions (positive):

* hip: flexion (thigh forward), knee: flexion (shank back), ankle: dorsiflexion (toes up);
* shoulder_flexion: arm forward, shoulder_abduction: arm away from the body, elbow: flexion.

18 degrees of freedom: 6 of the floating trunk, 3 per leg (hip and knee motorised by the
exoskeleton, a passive spring ankle), 3 per arm (2-DOF shoulder and an elbow, moved by the patient).
Each stick is rigid with its forearm and continues the forearm's axis beyond the grip; its tip is a
contact sphere. Each sole has four contact spheres (heel and toe, inside and outside).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from config.sim_schema import SegmentConfig, SimConfig

SIDES = ("l", "r")
LEG_JOINTS = ("hip", "knee", "ankle")
ARM_JOINTS = ("shoulder_flexion", "shoulder_abduction", "elbow")
#: joints driven by the exoskeleton's node boards, in node order (left hip, left knee, right hip, right knee)
EXO_JOINTS = ("hip_l", "knee_l", "hip_r", "knee_r")
ANKLE_JOINTS = ("ankle_l", "ankle_r")
ARM_JOINT_NAMES = tuple(f"{j}_{s}" for s in SIDES for j in ARM_JOINTS)
#: every revolute joint, in URDF (and PyBullet index) order
JOINT_ORDER = tuple(f"{j}_{s}" for s in SIDES for j in LEG_JOINTS) + ARM_JOINT_NAMES

_SIGN = {"l": 1.0, "r": -1.0}


@dataclass(frozen=True)
class Link:
    name: str
    mass_kg: float
    com_xyz: tuple[float, float, float]  # in the link frame
    inertia_diag: tuple[float, float, float]  # about the CoM, in the link frame


@dataclass(frozen=True)
class Body:
    """Derived dimensions of one patient in the exoskeleton (metres, kilograms)."""

    thigh_m: float
    shank_m: float
    ankle_height_m: float
    upper_arm_m: float
    forearm_m: float
    grip_m: float  # from the wrist to the grip (the hand's CoM)
    stick_m: float
    hip_half_width_m: float
    shoulder_half_width_m: float
    shoulder_above_hip_m: float
    links: tuple[Link, ...]

    @property
    def total_mass_kg(self) -> float:
        return sum(link.mass_kg for link in self.links)

    @property
    def hip_height_m(self) -> float:
        """Hip joint height standing with straight legs and the ankle at rest angle 0."""
        return self.ankle_height_m + self.shank_m + self.thigh_m

    @property
    def arm_reach_m(self) -> tuple[float, float]:
        """(upper arm, elbow to stick tip) lengths of the 2-link arm."""
        return self.upper_arm_m, self.forearm_m + self.grip_m + self.stick_m

    def arm_span_m(self, elbow_rad: float) -> float:
        """Shoulder to stick tip with the elbow ``elbow_rad`` bent (the 2-link arm's reach)."""
        upper, lower = self.arm_reach_m
        return math.sqrt(upper**2 + lower**2 + 2 * upper * lower * math.cos(elbow_rad))

    def link(self, name: str) -> Link:
        return next(link for link in self.links if link.name == name)


def _rod_inertia(mass: float, length: float, gyration_fraction: float) -> tuple[float, float, float]:
    """Diagonal inertia of a limb segment along z: radius of gyration about transverse axes."""
    transverse = mass * (gyration_fraction * length) ** 2
    return (transverse, transverse, max(transverse * 0.1, 1e-4))


def _segment(seg: SegmentConfig, body_mass: float, height: float) -> tuple[float, float]:
    return seg.mass_fraction * body_mass, seg.length_fraction * height


def build_body(sim: SimConfig) -> Body:
    """All segment dimensions and link inertias of the configured patient and exoskeleton."""
    cfg, hw = sim.model, sim.hardware
    p, exo, stick = cfg.patient, cfg.exoskeleton, hw.sticks
    mass, height = p.mass_kg, p.height_m
    m_thigh, l_thigh = _segment(p.thigh, mass, height)
    m_shank, l_shank = _segment(p.shank, mass, height)
    m_foot, _ = _segment(p.foot, mass, height)
    m_ua, l_ua = _segment(p.upper_arm, mass, height)
    m_fa, l_fa = _segment(p.forearm, mass, height)
    m_hand, l_hand = _segment(p.hand, mass, height)
    ankle_h = p.ankle_height_fraction * height
    shoulder_above_hip = p.shoulder_height_fraction * height - (ankle_h + l_shank + l_thigh)
    grip = p.hand.com_fraction * l_hand
    limbs = 2 * (m_thigh + m_shank + m_foot + m_ua + m_fa + m_hand)
    m_trunk_patient = mass - limbs

    links: list[Link] = []
    # Trunk: the patient's trunk, head and neck plus the exoskeleton's backpack and pelvis frame.
    m_trunk = m_trunk_patient + exo.trunk_kg
    cx = exo.trunk_kg * exo.trunk_com_offset_m[0] / m_trunk
    cz = (m_trunk_patient * p.trunk_com_above_hip_m + exo.trunk_kg * exo.trunk_com_offset_m[1]) / m_trunk
    depth, width, length = p.trunk_depth_m, p.shoulder_width_m, max(shoulder_above_hip, 0.2) + 0.25
    links.append(Link("trunk", m_trunk, (cx, 0.0, cz), (
        m_trunk / 12 * (width**2 + length**2), m_trunk / 12 * (depth**2 + length**2), m_trunk / 12 * (depth**2 + width**2))))
    for s in SIDES:
        m = m_thigh + exo.thigh_kg
        links.append(Link(f"thigh_{s}", m, (0.0, 0.0, -p.thigh.com_fraction * l_thigh), _rod_inertia(m, l_thigh, p.thigh.gyration_fraction)))
        m = m_shank + exo.shank_kg
        links.append(Link(f"shank_{s}", m, (0.0, 0.0, -p.shank.com_fraction * l_shank), _rod_inertia(m, l_shank, p.shank.gyration_fraction)))
        m = m_foot + exo.foot_kg
        foot_len = hw.foot.heel_back_m + hw.foot.toe_front_m
        fx = (hw.foot.toe_front_m - hw.foot.heel_back_m) / 2
        i_foot = m * (p.foot.gyration_fraction * foot_len) ** 2
        links.append(Link(f"foot_{s}", m, (fx, 0.0, -ankle_h / 2), (i_foot * 0.3, i_foot, i_foot)))
    for s in SIDES:
        links.append(Link(f"shoulder_{s}", 0.05, (0.0, 0.0, 0.0), (1e-4, 1e-4, 1e-4)))
        links.append(Link(f"upper_arm_{s}", m_ua, (0.0, 0.0, -p.upper_arm.com_fraction * l_ua), _rod_inertia(m_ua, l_ua, p.upper_arm.gyration_fraction)))
        # Forearm, hand and stick are one rigid body.
        z_fa, z_hand, z_stick = -p.forearm.com_fraction * l_fa, -(l_fa + grip), -(l_fa + grip + stick.length_m / 2)
        m = m_fa + m_hand + stick.mass_kg
        cz_arm = (m_fa * z_fa + m_hand * z_hand + stick.mass_kg * z_stick) / m
        i_t = (m_fa * ((p.forearm.gyration_fraction * l_fa) ** 2 + (z_fa - cz_arm) ** 2)
               + m_hand * (z_hand - cz_arm) ** 2
               + stick.mass_kg * (stick.length_m**2 / 12 + (z_stick - cz_arm) ** 2))
        links.append(Link(f"forearm_{s}", m, (0.0, 0.0, cz_arm), (i_t, i_t, max(i_t * 0.02, 1e-4))))
    return Body(
        thigh_m=l_thigh, shank_m=l_shank, ankle_height_m=ankle_h, upper_arm_m=l_ua, forearm_m=l_fa, grip_m=grip,
        stick_m=stick.length_m, hip_half_width_m=p.hip_width_m / 2, shoulder_half_width_m=p.shoulder_width_m / 2,
        shoulder_above_hip_m=shoulder_above_hip, links=tuple(links),
    )


# -- URDF ----------------------------------------------------------------------------------------


def _v(xyz) -> str:
    return " ".join(f"{float(c):.6g}" for c in xyz)


def _inertial(link: Link) -> str:
    ixx, iyy, izz = link.inertia_diag
    return (f'<inertial><origin xyz="{_v(link.com_xyz)}"/><mass value="{link.mass_kg:.6g}"/>'
            f'<inertia ixx="{ixx:.6g}" iyy="{iyy:.6g}" izz="{izz:.6g}" ixy="0" ixz="0" iyz="0"/></inertial>')


def _sphere(xyz, radius: float, collision: bool = True, rgba: str = "0.2 0.2 0.2 1") -> str:
    out = f'<visual><origin xyz="{_v(xyz)}"/><geometry><sphere radius="{radius:.6g}"/></geometry><material name="m{rgba.replace(" ", "_")}"><color rgba="{rgba}"/></material></visual>'
    if collision:
        out += f'<collision><origin xyz="{_v(xyz)}"/><geometry><sphere radius="{radius:.6g}"/></geometry></collision>'
    return out


def _cylinder(z0: float, z1: float, radius: float, rgba: str, collision: bool = False) -> str:
    length, mid = abs(z1 - z0), (z0 + z1) / 2
    geometry = f'<geometry><cylinder radius="{radius:.6g}" length="{length:.6g}"/></geometry>'
    out = f'<visual><origin xyz="0 0 {mid:.6g}"/>{geometry}<material name="m{rgba.replace(" ", "_")}"><color rgba="{rgba}"/></material></visual>'
    if collision:
        out += f'<collision><origin xyz="0 0 {mid:.6g}"/>{geometry}</collision>'
    return out


def _joint(name: str, parent: str, child: str, xyz, axis, lower: float, upper: float, effort: float, velocity: float) -> str:
    return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{_v(xyz)}"/><axis xyz="{_v(axis)}"/>'
            f'<limit lower="{lower:.6g}" upper="{upper:.6g}" effort="{effort:.6g}" velocity="{velocity:.6g}"/></joint>')


def urdf(sim: SimConfig, body: Body | None = None) -> str:
    """URDF text of the HHEA (deterministic for a configuration)."""
    body = body or build_body(sim)
    cfg, hw = sim.model, sim.hardware
    j, arms, foot = hw.joints, cfg.joints, hw.foot
    skin, exo_colour, stick_colour = "0.85 0.7 0.6 1", "0.3 0.45 0.75 1", "0.6 0.6 0.6 1"
    parts = ['<?xml version="1.0"?>', '<robot name="hhea">']
    trunk = body.link("trunk")
    t_len = body.shoulder_above_hip_m + 0.25
    box = f'<geometry><box size="{cfg.patient.trunk_depth_m:.6g} {cfg.patient.shoulder_width_m * 0.8:.6g} {t_len:.6g}"/></geometry>'
    box_origin = f'<origin xyz="0 0 {body.shoulder_above_hip_m / 2 + 0.05:.6g}"/>'
    parts.append(f'<link name="trunk">{_inertial(trunk)}<visual>{box_origin}{box}<material name="trunk"><color rgba="{exo_colour}"/></material></visual>'
                 f'<collision>{box_origin}{box}</collision>'
                 + _sphere((0, 0, body.shoulder_above_hip_m + 0.15), 0.1, collision=True, rgba=skin) + '</link>')
    for s in SIDES:
        y = _SIGN[s] * body.hip_half_width_m
        thigh, shank, foot_link = body.link(f"thigh_{s}"), body.link(f"shank_{s}"), body.link(f"foot_{s}")
        parts.append(f'<link name="thigh_{s}">{_inertial(thigh)}{_cylinder(-0.05, -body.thigh_m + 0.05, 0.07, exo_colour, collision=True)}</link>')
        parts.append(f'<link name="shank_{s}">{_inertial(shank)}{_cylinder(-0.05, -body.shank_m + 0.15, 0.05, exo_colour, collision=True)}</link>')
        sole = -body.ankle_height_m + foot.contact_radius_m
        spheres = "".join(
            _sphere((x, yy, sole), foot.contact_radius_m, rgba="0.15 0.15 0.15 1")
            for x in (-foot.heel_back_m, foot.toe_front_m) for yy in (-foot.half_width_m, foot.half_width_m)
        )
        plate = (f'<visual><origin xyz="{(foot.toe_front_m - foot.heel_back_m) / 2:.6g} 0 {sole + 0.01:.6g}"/>'
                 f'<geometry><box size="{foot.toe_front_m + foot.heel_back_m:.6g} {2 * foot.half_width_m:.6g} 0.02"/></geometry>'
                 f'<material name="sole"><color rgba="0.2 0.2 0.2 1"/></material></visual>')
        parts.append(f'<link name="foot_{s}">{_inertial(foot_link)}{spheres}{plate}</link>')
        parts.append(_joint(f"hip_{s}", "trunk", f"thigh_{s}", (0, y, 0), (0, -1, 0), j.hip.lower_rad, j.hip.upper_rad, j.hip.torque_limit_nm, j.hip.velocity_limit_rad_s))
        parts.append(_joint(f"knee_{s}", f"thigh_{s}", f"shank_{s}", (0, 0, -body.thigh_m), (0, 1, 0), j.knee.lower_rad, j.knee.upper_rad, j.knee.torque_limit_nm, j.knee.velocity_limit_rad_s))
        parts.append(_joint(f"ankle_{s}", f"shank_{s}", f"foot_{s}", (0, 0, -body.shank_m), (0, -1, 0), j.ankle.lower_rad, j.ankle.upper_rad, 0.0, 20.0))
    for s in SIDES:
        y = _SIGN[s] * body.shoulder_half_width_m
        ua, fa = body.link(f"upper_arm_{s}"), body.link(f"forearm_{s}")
        tip_z = -(body.forearm_m + body.grip_m + body.stick_m)
        parts.append(f'<link name="shoulder_{s}">{_inertial(body.link(f"shoulder_{s}"))}</link>')
        parts.append(f'<link name="upper_arm_{s}">{_inertial(ua)}{_cylinder(0, -body.upper_arm_m, 0.04, skin)}</link>')
        parts.append(f'<link name="forearm_{s}">{_inertial(fa)}{_cylinder(0, -body.forearm_m, 0.035, skin)}'
                     f'{_cylinder(-body.forearm_m - body.grip_m, tip_z, 0.012, stick_colour)}'
                     f'{_sphere((0, 0, tip_z), hw.sticks.tip_radius_m, rgba="0.1 0.1 0.1 1")}</link>')
        sf, sa, el = arms.shoulder_flexion, arms.shoulder_abduction, arms.elbow
        parts.append(_joint(f"shoulder_flexion_{s}", "trunk", f"shoulder_{s}", (0, y, body.shoulder_above_hip_m), (0, -1, 0), sf.lower_rad, sf.upper_rad, sf.torque_limit_nm, sf.velocity_limit_rad_s))
        parts.append(_joint(f"shoulder_abduction_{s}", f"shoulder_{s}", f"upper_arm_{s}", (0, 0, 0), (_SIGN[s], 0, 0), sa.lower_rad, sa.upper_rad, sa.torque_limit_nm, sa.velocity_limit_rad_s))
        parts.append(_joint(f"elbow_{s}", f"upper_arm_{s}", f"forearm_{s}", (0, 0, -body.upper_arm_m), (0, -1, 0), el.lower_rad, el.upper_rad, el.torque_limit_nm, el.velocity_limit_rad_s))
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def urdf_file(cfg: SimConfig, directory: Path) -> Path:
    """Write the URDF once per configuration (content-addressed) and return its path."""
    text = urdf(cfg)
    path = directory / f"hhea-{hashlib.sha256(text.encode()).hexdigest()[:16]}.urdf"
    if not path.exists():
        directory.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(path)
    return path


# -- kinematics of the arm (the leg's: protocol.geometry), used for the initial pose and the drivers --


def arm_ik(tip_rel_shoulder: np.ndarray, upper_m: float, lower_m: float, side: str) -> tuple[float, float, float]:
    """(shoulder flexion, shoulder abduction, elbow) placing the stick tip at a point given in the
    trunk frame relative to the shoulder joint. Raises ValueError when out of reach."""
    d = np.asarray(tip_rel_shoulder, dtype=float)
    dist2 = float(d @ d)
    c = (dist2 - upper_m**2 - lower_m**2) / (2 * upper_m * lower_m)
    if not -1.0 <= c <= 1.0:
        raise ValueError(f"stick tip target {np.round(d, 3)} m is out of the arm's reach")
    elbow = math.acos(c)
    vx, vz = lower_m * math.sin(elbow), -upper_m - lower_m * math.cos(elbow)
    sin_abd = _SIGN[side] * d[1] / -vz
    if not -1.0 <= sin_abd <= 1.0:
        raise ValueError("stick tip target too far to the side")
    abd = math.asin(sin_abd)
    wz = vz * math.cos(abd)
    flexion = math.atan2(d[2], d[0]) - math.atan2(wz, vx)
    flexion = (flexion + math.pi) % (2 * math.pi) - math.pi
    return flexion, abd, elbow
