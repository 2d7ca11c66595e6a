"""Rigid motion laws of the synthetic objects (numpy only).

A motion law gives an object's pose at any time: a rotation ``R(t)`` (object -> world) and a
position ``p(t)`` in metres, so a point fixed to the object at local coordinates ``x`` is at
``R(t) @ x + p(t)`` in the world.  World frame: z up, the ground is the plane z = 0.

Kinds:
    static:   p(t) = p0, R(t) = R0                               (objects of a static scene)
    linear:   p(t) = p0 + v t                                     (slides along the ground)
    circular: p(t) = c + rho (cos(phi0 + w t), sin(phi0 + w t), 0), yaw follows the direction
    bouncing: p(t) = p0 + v t + h |sin(pi t / period + phase)| e_z  (hops)
    spinning: p(t) = p0, R(t) = Rot(axis, w t) R0                 (turns in place)
Every law may add a slow yaw spin ``yaw_rate`` (rad/s) on top.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

__all__ = ["MOTION_KINDS", "Motion", "MotionLaw", "rotation_about", "sample_motion"]

MOTION_KINDS = ("linear", "circular", "bouncing", "spinning")


def rotation_about(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues rotation matrices (..., 3, 3) about unit ``axis`` (3,) by ``angle`` (...) radians."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    angle = np.asarray(angle, dtype=np.float64)
    kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s = np.sin(angle)[..., None, None]
    c = np.cos(angle)[..., None, None]
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)


class Motion(Protocol):
    """What the renderer and the track oracle need of a rigid part's motion: :class:`MotionLaw` (one
    rigid object) and :class:`~.figures.PartMotion` (one limb of an articulated figure) are motions."""

    @property
    def kind(self) -> str: ...

    @property
    def params(self) -> dict: ...

    @property
    def moves(self) -> bool: ...

    def pose(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (T, 3, 3) local -> world and positions (T, 3) metres at ``times`` (T,) seconds."""
        ...


@dataclass(frozen=True)
class MotionLaw:
    """One object's rigid motion; :meth:`pose` evaluates it.

    Attributes:
        kind: one of "static", "linear", "circular", "bouncing", "spinning".
        p0: (3,) metres, position at t = 0 (centre of the circle for "circular").
        R0: (3, 3) rotation at t = 0 (object -> world).
        params: kind-specific numbers (velocity m/s, radius m, angular rates rad/s, ...).
    """

    kind: str
    p0: np.ndarray
    R0: np.ndarray
    params: dict = field(default_factory=dict)

    @property
    def moves(self) -> bool:
        return self.kind != "static"

    def pose(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (T, 3, 3) and positions (T, 3) in metres at ``times`` (T,) seconds."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        P = self.params
        z_axis = np.array([0.0, 0.0, 1.0])
        pos = np.repeat(self.p0[None], t.shape[0], axis=0).astype(np.float64)
        yaw = P.get("yaw_rate", 0.0) * t
        if self.kind == "linear":
            pos = pos + np.asarray(P["velocity"])[None] * t[:, None]
        elif self.kind == "circular":
            ang = P["phase"] + P["omega"] * t
            pos = pos + P["radius"] * np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], -1)
            yaw = yaw + P["omega"] * t
        elif self.kind == "bouncing":
            hop = P["height"] * np.abs(np.sin(np.pi * t / P["period"] + P["phase"]))
            pos = pos + np.asarray(P["velocity"])[None] * t[:, None] + hop[:, None] * z_axis[None]
        R = rotation_about(z_axis, yaw) @ self.R0
        if self.kind == "spinning":
            R = rotation_about(np.asarray(P["axis"]), P["omega"] * t) @ R
        return R, pos


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def sample_motion(
    rng: np.random.Generator, kind: str, *, start: np.ndarray, rest_height: float, upright: bool,
) -> MotionLaw:
    """Draw a motion law of ``kind`` ("static" or one of :data:`MOTION_KINDS`).

    ``start`` is the (x, y) ground position at t = 0; ``rest_height`` the z of the object's centre
    when it rests on the ground (for objects that tumble: their bounding radius).  ``upright``
    objects (cards, boxes) only ever turn about the vertical axis, so they never sink into the
    ground; free objects start in a random orientation and tumble when spinning.
    """
    yaw0 = rng.uniform(0, 2 * np.pi)
    R0 = rotation_about(np.array([0.0, 0.0, 1.0]), yaw0)
    if not upright:
        R0 = rotation_about(_unit(rng.standard_normal(3)), rng.uniform(0, np.pi)) @ R0
    p0 = np.array([start[0], start[1], rest_height])
    params: dict = {}
    if kind == "static":
        return MotionLaw("static", p0, R0, params)
    if rng.random() < 0.5:
        params["yaw_rate"] = float(rng.uniform(-0.8, 0.8))
    heading = rng.uniform(0, 2 * np.pi)
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    if kind == "linear":
        params["velocity"] = (direction * rng.uniform(0.3, 0.9)).tolist()
    elif kind == "circular":
        r = float(rng.uniform(0.4, 1.1))
        params.update(radius=r, omega=float(rng.choice([-1, 1]) * rng.uniform(0.8, 2.0)),
                      phase=float(heading))
        p0 = p0 - r * np.array([np.cos(heading), np.sin(heading), 0.0])  # starts at `start`
    elif kind == "bouncing":
        params.update(velocity=(direction * rng.uniform(0.0, 0.5)).tolist(),
                      height=float(rng.uniform(0.25, 0.7)), period=float(rng.uniform(0.6, 1.2)),
                      phase=float(rng.uniform(0, np.pi)))
    elif kind == "spinning":
        axis = np.array([0.0, 0.0, 1.0]) if upright else _unit(rng.standard_normal(3))
        params.update(axis=axis.tolist(), omega=float(rng.choice([-1, 1]) * rng.uniform(0.8, 2.5)))
        if not upright:
            p0 = p0 + np.array([0.0, 0.0, 0.05])  # hover a little so tumbling never touches the ground
        params.pop("yaw_rate", None)
    else:
        raise ValueError(f"unknown motion kind {kind!r}")
    return MotionLaw(kind, p0, R0, params)
