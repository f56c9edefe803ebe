"""The simulated HHEA as the node boards drive it (their plant): the PyBullet world with the
exoskeleton and the patient, its four exoskeleton joints driven by the boards' commands, and one
physics tick at a time with the sensors read after it.

The emulated boards (:mod:`nodes.host`) own the bus and the firmware; what they drive and what
they measure is this. It knows no CAN frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from config.sim_schema import SimConfig
from protocol.commands import JointCommand
from protocol.enums import JointMode
from sim.actuation import Mode
from sim.sensors import Reading
from sim.walk import Walker, initial_pose
from sim.world import World


class Plant:
    """The HHEA in its initial pose, its patient ready to walk when told (``walking``)."""

    def __init__(self, cfg: SimConfig, rng: np.random.Generator, *, gui: bool = False) -> None:
        self.cfg = cfg
        self.world = World(cfg, gui=gui)
        try:
            self.world.place(initial_pose(cfg))
            self.patient = Walker(self.world, cfg, cfg.gait, rng, scripted_exo=False)
            self.reading: Reading = self.patient.start()
        except Exception:
            self.world.close()
            raise
        self.ticks = 0
        self.fall_at: dict[str, Any] | None = None  # when the HHEA first fell: the caller's tick and the simulated time

    def close(self) -> None:
        self.world.close()

    @property
    def walking(self) -> bool:
        return self.patient.walking

    @walking.setter
    def walking(self, on: bool) -> None:
        """The patient walks (moves the sticks, leans) while the exoskeleton does."""
        self.patient.walking = on

    def drive(self, joint: int, cmd: JointCommand) -> None:
        """A board's command to its joint (0-3: left hip, left knee, right hip, right knee). Hold
        and quick stop hold the measured position (latched by the drive loop); the joint interface
        checks again at its boundary (and counts what it rejects)."""
        exo = self.world.exo
        if cmd.mode == JointMode.TRACK:
            exo.command(joint, Mode.TRACK, cmd.position_rad, cmd.velocity_rad_s, cmd.torque_nm, cmd.torque_limit_nm)
        else:
            q = min(max(float(self.reading.joint_position_rad[joint]), exo.lower[joint]), exo.upper[joint])
            exo.command(joint, Mode(int(cmd.mode)), q, 0.0, 0.0, min(cmd.torque_limit_nm, exo.rated[joint]))

    def tick(self, at_tick: int) -> Reading:
        """One physics tick; the sensors after it. ``at_tick``: the caller's tick, kept with a fall."""
        self.reading = self.patient.tick(self.reading)
        self.ticks += 1
        if self.fall_at is None and self.patient.fall:
            self.fall_at = {"sync_tick": at_tick, "sim_time_s": round(self.patient.t, 3)}
        return self.reading

    def truth(self, body: Any | None) -> dict[str, Any]:
        """The ground truth now (never measured by a sensor): X_CoM/X_SP by the contact thresholds of
        the controller's ``body`` model (nan without one), the simulated time and the fall."""
        ratio = (self.patient.x_ratio_truth(body.foot_loaded_n, body.stick_loaded_n, body.min_support_m)
                 if body is not None else float("nan"))
        return {"t_s": round(self.patient.t, 3), "x_ratio": ratio, "fall": self.patient.fall}


class PlantTickTimer:
    """Accumulates the time of the plant's ticks (benchmarks): the bare simulation measured inside
    the same run as everything around it."""

    def __init__(self, plant: Plant, clock: Any) -> None:
        self.ns = 0
        inner = plant.patient.tick

        def timed(reading: Reading) -> Reading:
            start = clock.now_ns()
            out = inner(reading)
            self.ns += clock.now_ns() - start
            return out

        plant.patient.tick = timed  # type: ignore[method-assign]  # an instance attribute shadows the method
