"""Whole-body kinematics of the HHEA from the world's batched link states (:meth:`World.link_states`).

For a revolute joint j with world axis a_j through the point o_j, the Jacobian column of a point p
on a link below j is ``a_j x (p - o_j)``. One ``getLinkStates`` call gives every link frame (whose
origin is its parent joint) and every link's CoM, so all Jacobians, the CoM, its velocity and the
gravity torques follow in numpy, without PyBullet's per-link ``calculateJacobian`` calls (and
without their floating-base frame pitfalls).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from sim.linalg import cross, cross_z
from sim.world import GRAVITY, World


class Kinematics:
    def __init__(self, world: World) -> None:
        self.world = world
        c, robot = world.client, world.robot
        n = c.getNumJoints(robot)
        self.n = n
        self.axis_local = np.array([c.getJointInfo(robot, j)[13] for j in range(n)], dtype=float)
        parent = [c.getJointInfo(robot, j)[16] for j in range(n)]
        # ancestors[j]: joints whose motion moves link j (j itself and every joint above it)
        self.ancestors = []
        for j in range(n):
            chain, k = [], j
            while k >= 0:
                chain.append(k)
                k = parent[k]
            self.ancestors.append(np.array(chain[::-1]))
        # subtree mask: moves[j, i] is True where joint j moves link i (links indexed base = 0, link k = k + 1)
        self.moves = np.zeros((n, n + 1), dtype=bool)
        for link in range(n):
            self.moves[self.ancestors[link], link + 1] = True
        self._moves_float = self.moves.astype(float)
        self._moved_by_links: dict[tuple[int, ...], np.ndarray] = {}
        self.masses = world.masses
        self._mass_sum = self.masses.sum()
        self._link_weights = GRAVITY * self.masses[None, :]  # (1, n + 1)
        self.update()

    def update(self) -> None:
        """Take the world's current link states (shared, read-only arrays), and the whole body's
        CoM and CoM velocity in them (read-only: a tick reads them a dozen times)."""
        links = self.world.link_states()
        self.link_com, self.link_vel, self.link_rot = links.com, links.com_velocity, links.rot
        self.joint_origin = links.origin[1:]
        # every link's rot @ axis at once (each axis is a unit vector of the joint frame: exact)
        self.joint_axis = (links.rot[1:] @ self.axis_local[:, :, None])[..., 0]
        self.com = _read_only(self.masses @ self.link_com / self._mass_sum)
        self.com_velocity = _read_only(self.masses @ self.link_vel / self._mass_sum)
        self._memo: dict[Hashable, Any] = {}

    def memo(self, key: Hashable, compute: Callable[..., Any], *args: Any) -> Any:
        """``compute(*args)``, computed once per :meth:`update`: a value derived from this state that
        several readers ask for in one tick (the patient's balance and margin, the arms, the legs'
        feed-forward). Shared between them: arrays are read-only, sequences tuples."""
        try:
            return self._memo[key]
        except KeyError:
            value = self._memo[key] = compute(*args)
            return value

    def point_jacobian(self, link: int, point: np.ndarray) -> np.ndarray:
        """(3, n) Jacobian of a world point fixed to ``link`` (a joint index; -1 = trunk) w.r.t. the joints."""
        jac = np.zeros((3, self.n))
        if link < 0:
            return jac
        idx = self.ancestors[link]
        jac[:, idx] = cross(self.joint_axis[idx], point - self.joint_origin[idx]).T
        return jac

    def generalised_force(self, links: list[int], points: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """(n,) ``sum_c point_jacobian(links[c], points[c]).T @ forces[c]``: the joint torques that
        world forces at points of links produce, all at once. Joint j's share of force f at p is
        ``a_j . ((p - o_j) x f) = a_j . (p x f - o_j x f)``, so the forces on the links j moves
        sum first: ``a_j . (sum p x f - o_j x sum f)``."""
        moved = self._moved(tuple(links))  # (n, k): joint j moves contact c's link
        points, forces = np.asarray(points, dtype=float), np.asarray(forces, dtype=float)
        moment = moved @ cross(points, forces)  # (n, 3)
        force = moved @ forces
        return np.einsum("ij,ij->i", self.joint_axis, moment - cross(self.joint_origin, force))

    def _moved(self, links: tuple[int, ...]) -> np.ndarray:
        """(n, k) 1.0 where joint j moves link ``links[c]``, 0.0 elsewhere; read-only, made once for
        each combination of links (a handful: the stance feet and the planted sticks)."""
        moved = self._moved_by_links.get(links)
        if moved is None:
            moved = self._moved_by_links[links] = _read_only(self._moves_float[:, np.asarray(links, dtype=int) + 1])
        return moved

    def gravity_torques(self) -> np.ndarray:
        """Joint torques that hold every link against gravity (``-Q``, Q the generalised gravity
        force); read-only, once per state (:meth:`memo`: the arms and the legs both ask)."""
        return self.memo("gravity_torques", self._gravity_torques)

    def _gravity_torques(self) -> np.ndarray:
        # Q_j = sum over links i moved by j of m_i (-g z) . (a_j x (c_i - o_j)); -Q sums m_i g (a_j x r)_z
        lever = self.link_com[None, :, :] - self.joint_origin[:, None, :]  # (n, n+1, 3)
        moment_z = cross_z(self.joint_axis[:, None, :], lever)  # z component of a_j x r
        return _read_only((self._link_weights * moment_z * self._moves_float).sum(axis=1))


def _read_only(a: np.ndarray) -> np.ndarray:
    """``a``, flagged read-only (a value shared through :meth:`Kinematics.memo`)."""
    a.flags.writeable = False
    return a
