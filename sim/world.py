"""One simulated world: a PyBullet client with the floor and the HHEA, stepped at the physics rate.

Every world has its own physics client (never PyBullet's global one) and is disconnected when
closed; a new episode builds a new world, so runs with the same seed and commands are
bit-identical. Joints are torque-driven only: the exoskeleton's four joints through the node
boards' impedance loop (:class:`sim.actuation.JointImpedance`, driven by whoever plays the node
firmware's client), the arms through the patient's, the ankles by their springs. The trunk is
never moved after the initial pose; in the sagittal mode a spring-damper (an external wrench)
holds it to the walking plane.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def _import_pybullet_quietly():
    """``import pybullet`` without the "pybullet build time" banner its C code writes to stderr
    (file descriptor 2, which Python's redirections do not reach): a command's stderr is its own."""
    saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)
    return pybullet


pybullet = _import_pybullet_quietly()
import pybullet_data  # noqa: E402
from pybullet_utils.bullet_client import BulletClient  # noqa: E402

from config.sim_schema import SimConfig
from protocol.geometry import leg_inverse
from sim.actuation import LAW_ROWS, Gains, JointImpedance, law_torques, spring_law
from sim.linalg import rpy_from_matrix
from sim.model import (
    ANKLE_JOINTS,
    ARM_JOINT_NAMES,
    EXO_JOINTS,
    JOINT_ORDER,
    Body,
    arm_ik,
    build_body,
    urdf_file,
)

GRAVITY = 9.81
URDF_CACHE = Path(tempfile.gettempdir()) / "aider-exo-urdf"


@contextlib.contextmanager
def _c_stdout_to_devnull():
    """PyBullet's C code prints ("argv[0]=") on connecting: keep it off our stdout (--json output)."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


class BoundClient(BulletClient):
    """A :class:`BulletClient` that binds each PyBullet function to its client id once.

    ``BulletClient.__getattr__`` builds a ``functools.partial`` on every call (hundreds of
    thousands per walk); here the first lookup of a name keeps its partial as an instance
    attribute, which later lookups find without ``__getattr__``. The calls are the same.
    """

    def __getattr__(self, name: str):
        attribute = super().__getattr__(name)
        if isinstance(attribute, functools.partial) and name != "disconnect":
            self.__dict__[name] = attribute
        return attribute


class PhysicsTimer:
    """Accumulates the time of PyBullet's own ``stepSimulation`` in ``world`` (benchmarks and
    profiles): the bare physics measured inside the same run as everything around it. ``clock``
    has ``now_ns()`` (:class:`protocol.clock.MonotonicClock`). In a profile, ``physics_step`` is
    the physics' own entry (PyBullet's other C functions are called through ``functools.partial``,
    which a profiler attributes to their Python caller)."""

    def __init__(self, world: World, clock) -> None:
        self.ns = 0
        self._inner, self._clock = world.client.stepSimulation, clock
        world.client.stepSimulation = self.physics_step  # an instance attribute shadows the client's lookup

    def physics_step(self) -> None:
        start = self._clock.now_ns()
        self._inner()
        self.ns += self._clock.now_ns() - start


@dataclass(frozen=True)
class StancePose:
    """An initial posture: where the feet and stick tips are, and how the trunk leans."""

    foot_x_m: tuple[float, float]  # left, right ankle x
    tip_xy_m: tuple[tuple[float, float], tuple[float, float]]  # left, right stick tip (x, y)
    trunk_pitch_rad: float = 0.05
    knee_rad: float = 0.08
    hip_x_m: float | None = None  # default: midway between the ankles


@dataclass(frozen=True)
class LinkStates:
    """One state of the HHEA's links, base first (index 0, link k at k + 1): CoM positions and
    velocities, frame origins (a link's frame is at its parent joint; the base's frame is the
    trunk's, not its inertial frame) and frame rotations; the base's angular velocity, and the trunk's
    roll, pitch and yaw (:func:`sim.linalg.rpy_from_matrix`: the sensors, the patient, the legs and
    the fall check all read them)."""

    com: np.ndarray  # (n + 1, 3)
    com_velocity: np.ndarray  # (n + 1, 3)
    origin: np.ndarray  # (n + 1, 3)
    rot: np.ndarray  # (n + 1, 3, 3)
    base_angular_velocity: np.ndarray  # (3,)
    trunk_rpy: np.ndarray  # (3,)


class World:
    """The floor, the HHEA, its joint loops and the physics clock."""

    def __init__(self, cfg: SimConfig, *, gui: bool = False) -> None:
        self.cfg = cfg
        self.body: Body = build_body(cfg)
        self.dt = 1.0 / cfg.physics.rate_hz
        self._sagittal = cfg.mode == "sagittal"
        self.steps = 0
        with _c_stdout_to_devnull():
            self.client = BoundClient(connection_mode=pybullet.GUI if gui else pybullet.DIRECT)
        c = self.client
        c.setAdditionalSearchPath(pybullet_data.getDataPath())
        c.setPhysicsEngineParameter(
            fixedTimeStep=self.dt, numSolverIterations=cfg.physics.solver_iterations, deterministicOverlappingPairs=1
        )
        c.setGravity(0, 0, -GRAVITY)
        self.floor = c.loadURDF("plane.urdf")
        path = urdf_file(cfg, URDF_CACHE)
        self.robot = c.loadURDF(str(path), [0, 0, 2], flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
        self.joint_index = {c.getJointInfo(self.robot, i)[1].decode(): i for i in range(c.getNumJoints(self.robot))}
        assert tuple(self.joint_index) == JOINT_ORDER, "URDF joint order changed"
        self.link_index = {c.getJointInfo(self.robot, i)[12].decode(): i for i in range(c.getNumJoints(self.robot))}
        self.link_index["trunk"] = -1
        self._link_name = {i: n for n, i in self.link_index.items()}
        self.masses = np.array([c.getDynamicsInfo(self.robot, i)[0] for i in range(-1, c.getNumJoints(self.robot))])
        self.total_mass = float(self.masses.sum())
        self._base_com_local = np.array(c.getDynamicsInfo(self.robot, -1)[3])  # the trunk's inertial frame offset
        mu = cfg.model.friction
        c.changeDynamics(self.floor, -1, lateralFriction=mu)
        for i in range(-1, c.getNumJoints(self.robot)):
            c.changeDynamics(self.robot, i, lateralFriction=mu)
        all_joints = list(range(len(JOINT_ORDER)))
        # The default velocity motors would fight the torque control: switch them off ...
        c.setJointMotorControlArray(self.robot, all_joints, pybullet.VELOCITY_CONTROL, forces=[0.0] * len(all_joints))
        # ... except at the ankles, where a weak one is the damper (implicit, stable at 250 Hz).
        ankles = [self.joint_index[n] for n in ANKLE_JOINTS]
        c.setJointMotorControlArray(self.robot, ankles, pybullet.VELOCITY_CONTROL, targetVelocities=[0, 0],
                                    forces=[cfg.hardware.joints.ankle.friction_nm] * 2)
        self._exo_idx = np.array([self.joint_index[n] for n in EXO_JOINTS])
        self._arm_idx = np.array([self.joint_index[n] for n in ARM_JOINT_NAMES])
        self._ankle_idx = np.array(ankles)
        self._torque_idx = list(self._exo_idx) + list(self._arm_idx) + list(self._ankle_idx)
        self._torque_idx_array = np.array(self._torque_idx)
        self._all_joints = list(range(len(JOINT_ORDER)))
        j = cfg.hardware.joints
        fw = cfg.firmware
        # One law for every torque-driven joint, in the order of _torque_idx (exoskeleton, arms,
        # ankles): the node boards' and the arms' loops own their columns, the ankle springs are
        # fixed; each physics step computes every torque at once (law_torques).
        n_exo, n_arm = len(self._exo_idx), len(self._arm_idx)
        self._law = np.zeros((LAW_ROWS, len(self._torque_idx)))
        self._law[:, n_exo + n_arm:] = spring_law(np.full(len(ankles), j.ankle.stiffness_nm_rad), np.full(len(ankles), j.ankle.rest_rad))
        self._law_rows = tuple(self._law)
        self._exo_slice, self._arm_slice = slice(0, n_exo), slice(n_exo, n_exo + n_arm)
        exo_specs = [j.hip, j.knee, j.hip, j.knee]
        self.exo = JointImpedance(
            EXO_JOINTS,
            np.array([s.lower_rad for s in exo_specs]), np.array([s.upper_rad for s in exo_specs]),
            np.array([s.torque_limit_nm for s in exo_specs]),
            Gains(np.full(4, fw.stiffness_nm_rad), np.full(4, fw.damping_nms_rad), np.full(4, fw.hold_stiffness_nm_rad),
                  np.full(4, fw.hold_damping_nms_rad), np.full(4, fw.hold_torque_limit_nm)),
            law=self._law[:, self._exo_slice],
        )
        arms = cfg.model.joints
        arm_specs = [arms.shoulder_flexion, arms.shoulder_abduction, arms.elbow] * 2
        pc = cfg.patient
        self.arms = JointImpedance(
            ARM_JOINT_NAMES,
            np.array([s.lower_rad for s in arm_specs]), np.array([s.upper_rad for s in arm_specs]),
            np.array([s.torque_limit_nm for s in arm_specs]),
            Gains(np.full(6, pc.arm_stiffness_nm_rad), np.full(6, pc.arm_damping_nms_rad), np.full(6, pc.arm_stiffness_nm_rad),
                  np.full(6, pc.arm_damping_nms_rad), np.array([s.torque_limit_nm for s in arm_specs])),
            law=self._law[:, self._arm_slice],
        )
        self.q = np.zeros(len(JOINT_ORDER))
        self.qd = np.zeros(len(JOINT_ORDER))
        self.tau = np.zeros(len(JOINT_ORDER))
        # the base's linear velocity after the last step and the one before, and its angular velocity
        self._base_velocity = self._base_velocity_before = (0.0, 0.0, 0.0)
        self._base_angular_velocity = (0.0, 0.0, 0.0)
        self._links: LinkStates | None = None  # this state's link frames, fetched on first use
        self._contacts: dict[int, list[tuple]] | None = None  # this state's floor contacts by link

    # -- lifecycle -------------------------------------------------------------------------------

    def close(self) -> None:
        if self.client is not None:
            self.client.disconnect()
            self.client = None  # type: ignore[assignment]

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def time_s(self) -> float:
        return self.steps * self.dt

    # -- initial pose ----------------------------------------------------------------------------

    def place(self, pose: StancePose) -> None:
        """Put the HHEA in ``pose``, at rest, with every joint loop holding that posture.

        The only time the base is moved: before the first step of an episode.
        """
        c, b = self.client, self.body
        theta = pose.trunk_pitch_rad
        hip_x = pose.hip_x_m if pose.hip_x_m is not None else sum(pose.foot_x_m) / 2
        # Leg length from the knee bend; hip height so that the soles touch the floor.
        q = dict.fromkeys(JOINT_ORDER, 0.0)
        # The hip height at which the farther foot has the given knee bend; the nearer bends more.
        reach = math.sqrt(b.thigh_m**2 + b.shank_m**2 + 2 * b.thigh_m * b.shank_m * math.cos(pose.knee_rad))
        hip_z = min(b.ankle_height_m + math.sqrt(max(reach**2 - (fx - hip_x) ** 2, 0.0)) for fx in pose.foot_x_m)
        for side, foot_x in zip("lr", pose.foot_x_m):
            h_world, knee = leg_inverse(b.thigh_m, b.shank_m, foot_x - hip_x, b.ankle_height_m - hip_z)
            q[f"hip_{side}"] = h_world + theta
            q[f"knee_{side}"] = knee
            q[f"ankle_{side}"] = theta - q[f"hip_{side}"] + knee  # sole flat
        rot = np.array(c.getMatrixFromQuaternion(c.getQuaternionFromEuler([0, theta, 0]))).reshape(3, 3)
        hip_world = np.array([hip_x, 0.0, hip_z])
        upper, lower = b.arm_reach_m
        for side, (tx, ty) in zip("lr", pose.tip_xy_m):
            sign = 1.0 if side == "l" else -1.0
            shoulder = hip_world + rot @ np.array([0.0, sign * b.shoulder_half_width_m, b.shoulder_above_hip_m])
            tip = np.array([tx, ty, self.cfg.hardware.sticks.tip_radius_m + 0.002])
            flex, abd, elbow = arm_ik(rot.T @ (tip - shoulder), upper, lower, side)
            q[f"shoulder_flexion_{side}"], q[f"shoulder_abduction_{side}"], q[f"elbow_{side}"] = flex, abd, elbow
        com_local = np.array(c.getDynamicsInfo(self.robot, -1)[3])  # base inertial frame offset
        c.resetBasePositionAndOrientation(
            self.robot, (hip_world + rot @ com_local + np.array([0, 0, 0.002])).tolist(), c.getQuaternionFromEuler([0, theta, 0])
        )
        c.resetBaseVelocity(self.robot, [0, 0, 0], [0, 0, 0])
        for name, value in q.items():
            c.resetJointState(self.robot, self.joint_index[name], value, 0.0)
        self.read_joints()
        for i, name in enumerate(EXO_JOINTS):
            self.exo.command(i, 1, q[name], 0.0, 0.0)
        for i, name in enumerate(ARM_JOINT_NAMES):
            self.arms.command(i, 1, q[name], 0.0, 0.0)
        self._base_velocity = self._base_velocity_before = (0.0, 0.0, 0.0)
        self._base_angular_velocity = (0.0, 0.0, 0.0)
        self._changed()

    # -- stepping ------------------------------------------------------------------------------

    def read_joints(self) -> None:
        q, qd, *_ = zip(*self.client.getJointStates(self.robot, self._all_joints))
        self.q[:] = q
        self.qd[:] = qd

    def step(self, n: int = 1) -> None:
        """``n`` physics steps, each the joint loops (firmware, muscles, ankle springs), then the
        physics. The base's velocity is read after a step where it is used: after every step in
        the sagittal mode (the plane's spring-damper reads it), after the last two otherwise (the
        trunk IMU's acceleration and the link states read it)."""
        c = self.client
        idx = self._torque_idx_array
        for k in range(n):
            self.read_joints()
            q = self.q[idx]  # the law's order
            if self.exo.latch_pending:
                self.exo.latch(q[self._exo_slice])
            if self.arms.latch_pending:
                self.arms.latch(q[self._arm_slice])
            forces = law_torques(self._law_rows, q, self.qd[idx])
            self.exo.applied, self.arms.applied = forces[self._exo_slice], forces[self._arm_slice]
            self.tau[idx] = forces
            c.setJointMotorControlArray(self.robot, self._torque_idx, pybullet.TORQUE_CONTROL, forces=forces.tolist())
            if self._sagittal:
                self._hold_to_plane()
            c.stepSimulation()
            self.steps += 1
            if self._sagittal or k >= n - 2:
                self._base_velocity_before = self._base_velocity
                self._base_velocity, self._base_angular_velocity = c.getBaseVelocity(self.robot)
        self._changed()

    @property
    def base_acceleration(self) -> np.ndarray:
        """The base's linear acceleration over the last physics step (what the trunk IMU senses)."""
        return (np.array(self._base_velocity) - np.array(self._base_velocity_before)) / self.dt

    def _changed(self) -> None:
        """The world moved (a physics step, a placement): what was read of it is stale."""
        self._links = None
        self._contacts = None

    def _hold_to_plane(self) -> None:
        c, s = self.client, self.cfg.sagittal
        pos, orn = c.getBasePositionAndOrientation(self.robot)
        lin, ang = self._base_velocity, self._base_angular_velocity  # as read after the last step
        roll, _, yaw = c.getEulerFromQuaternion(orn)
        fy = -s.lateral_stiffness_n_m * pos[1] - s.lateral_damping_ns_m * lin[1]
        c.applyExternalForce(self.robot, -1, [0, fy, 0], pos, pybullet.WORLD_FRAME)
        tx = -s.rotational_stiffness_nm_rad * roll - s.rotational_damping_nms_rad * ang[0]
        tz = -s.rotational_stiffness_nm_rad * yaw - s.rotational_damping_nms_rad * ang[2]
        c.applyExternalTorque(self.robot, -1, [tx, 0, tz], pybullet.WORLD_FRAME)

    # -- queries -------------------------------------------------------------------------------
    # Every query of the state between two physics steps reads one batched PyBullet query, made on
    # first use: a 20 ms tick reads the same few frames and contacts a dozen times (sensors,
    # patient, ground truth), and each PyBullet call costs microseconds of argument handling.

    def link_states(self) -> LinkStates:
        """Every link's frame, CoM and CoM velocity in this state (one ``getLinkStates`` call)."""
        if self._links is None:
            c = self.client
            base_pos, base_orn = c.getBasePositionAndOrientation(self.robot)
            base_lin, base_ang = self._base_velocity, self._base_angular_velocity
            states = c.getLinkStates(self.robot, self._all_joints, computeLinkVelocity=1)
            matrix = c.getMatrixFromQuaternion
            com = np.array([base_pos] + [st[0] for st in states])
            vel = np.array([base_lin] + [st[6] for st in states])
            rot = np.array([matrix(base_orn)] + [matrix(st[5]) for st in states]).reshape(-1, 3, 3)
            origin = np.array([(0.0, 0.0, 0.0)] + [st[4] for st in states])
            origin[0] = com[0] - rot[0] @ self._base_com_local
            trunk_rpy = rpy_from_matrix(rot[0])
            for a in (com, vel, origin, rot, trunk_rpy):
                a.flags.writeable = False
            self._links = LinkStates(com, vel, origin, rot, np.array(base_ang), trunk_rpy)
        return self._links

    def link_positions(self) -> np.ndarray:
        """World positions of every link's centre of mass, base first: (n_links + 1, 3)."""
        return self.link_states().com

    def com(self) -> np.ndarray:
        return self.masses @ self.link_positions() / self.total_mass

    def _floor_contacts(self) -> dict[int, list[tuple]]:
        """This state's robot-floor contact points by robot link index (one ``getContactPoints``
        call; each link's points in PyBullet's order, as a query for that link alone gives them)."""
        if self._contacts is None:
            self._contacts = {}
            for cp in self.client.getContactPoints(bodyA=self.robot, bodyB=self.floor):
                self._contacts.setdefault(cp[3], []).append(cp)
        return self._contacts

    def contacts(self, link: str) -> list[tuple]:
        """PyBullet contact points between a robot link and the floor."""
        return self._floor_contacts().get(self.link_index[link], [])

    def contact_normal_force(self, link: str) -> float:
        return float(sum(cp[9] for cp in self.contacts(link)))

    def touching_links(self) -> set[str]:
        return {self._link_name[i] for i in self._floor_contacts()}

    def link_frame(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World position of the link frame's origin and its rotation matrix (read-only arrays)."""
        i = self.link_index[link] + 1
        links = self.link_states()
        return links.origin[i], links.rot[i]
