"""Articulated human figures for the synthetic room scenes (numpy only).

A figure is a skeleton of rigid parts (torso, head, upper arms, forearms, thighs, shins), each an
ellipsoid, posed by forward kinematics from joint angles that are smooth functions of time:

    walk:    the root (the pelvis) moves along an arc at walking speed; legs and arms swing in a gait
             cycle, knees and elbows bend, the pelvis bobs and the torso twists with the stride;
    gesture: the figure stands, sways and turns; both arms rise, fall and bend at their own slow
             rhythms, the torso leans and turns, the head looks around; one hand may hold a board
             (a flat card, like the calibration target people wave at real camera rigs);
    still:   the pose of a gesture at t = 0, held (a static scene).

Every part moves rigidly, so exact flow, tracks and masks follow from its pose as for any rigid object
(:mod:`.render`, :mod:`.tracks`).  Figure frame: x forward, y left, z up; the root is the pelvis.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .motion import rotation_about

__all__ = ["FIGURE_ACTIONS", "FIGURE_PARTS", "Figure", "PartMotion", "sample_figure"]

FIGURE_ACTIONS = ("walk", "gesture", "still")

# part -> (parent, joint position in the parent's frame at scale 1 (m), ellipsoid radii (x, y, z) (m),
# ellipsoid centre in the part's own frame (m)).  A part's frame sits at its joint; limbs hang along -z.
FIGURE_PARTS: dict[str, tuple[str, tuple[float, float, float], tuple[float, float, float],
                              tuple[float, float, float]]] = {
    "torso": ("root", (0.0, 0.0, 0.0), (0.12, 0.18, 0.29), (0.0, 0.0, 0.27)),
    "head": ("torso", (0.0, 0.0, 0.55), (0.10, 0.088, 0.118), (0.012, 0.0, 0.13)),
    "upper_arm_l": ("torso", (0.0, 0.21, 0.47), (0.05, 0.05, 0.155), (0.0, 0.0, -0.14)),
    "forearm_l": ("upper_arm_l", (0.0, 0.0, -0.28), (0.043, 0.043, 0.145), (0.0, 0.0, -0.13)),
    "upper_arm_r": ("torso", (0.0, -0.21, 0.47), (0.05, 0.05, 0.155), (0.0, 0.0, -0.14)),
    "forearm_r": ("upper_arm_r", (0.0, 0.0, -0.28), (0.043, 0.043, 0.145), (0.0, 0.0, -0.13)),
    "thigh_l": ("root", (0.0, 0.095, -0.02), (0.078, 0.078, 0.235), (0.0, 0.0, -0.21)),
    "shin_l": ("thigh_l", (0.0, 0.0, -0.43), (0.058, 0.058, 0.235), (0.0, 0.0, -0.215)),
    "thigh_r": ("root", (0.0, -0.095, -0.02), (0.078, 0.078, 0.235), (0.0, 0.0, -0.21)),
    "shin_r": ("thigh_r", (0.0, 0.0, -0.43), (0.058, 0.058, 0.235), (0.0, 0.0, -0.215)),
}
PELVIS_HEIGHT = 0.02 + 0.43 + 0.215 + 0.235   # hip joint drop + thigh + shin centre + shin half length
BOARD_HALF = (0.16, 0.21)                     # the held board's half width and height (m) at scale 1
_X, _Y, _Z = np.eye(3)


def _pitch(a: np.ndarray) -> np.ndarray:
    """Rotations that swing a limb hanging along -z forwards (towards +x) by ``a`` radians."""
    return rotation_about(_Y, -np.asarray(a, dtype=np.float64))


def _roll(a: np.ndarray) -> np.ndarray:
    """Rotations that swing a limb hanging along -z sideways, towards +y (the figure's left), by ``a``."""
    return rotation_about(_X, np.asarray(a, dtype=np.float64))


def _yaw(a: np.ndarray) -> np.ndarray:
    return rotation_about(_Z, np.asarray(a, dtype=np.float64))


def _wave(t: np.ndarray, p: dict, name: str) -> np.ndarray:
    """``base + amp * sin(2 pi freq t + phase)`` with the named parameters of ``p``."""
    return p[name + "_base"] + p[name + "_amp"] * np.sin(2 * np.pi * p[name + "_freq"] * t + p[name + "_phase"])


@dataclass(frozen=True)
class Figure:
    """One articulated figure.

    Attributes:
        action: one of :data:`FIGURE_ACTIONS`.
        scale: body size relative to the 1.75 m figure of :data:`FIGURE_PARTS`.
        p0: (3,) the pelvis position at t = 0 (m); ``heading`` the direction it faces (rad, about z).
        params: the action's numbers (speeds m/s, angles rad, frequencies Hz, phases rad).
        board: whether the left hand holds a board (a card; pose from :meth:`poses` under ``"board"``).
    """

    action: str
    scale: float
    p0: np.ndarray
    heading: float
    params: dict = field(default_factory=dict)
    board: bool = False

    def _joints(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Root rotation (T, 3, 3), root position (T, 3) and each part's joint rotation (T, 3, 3)."""
        p = self.params
        n = len(t)
        if self.action == "walk":
            phase = 2 * np.pi * p["step_freq"] * t + p["step_phase"]
            turn = p["turn_rate"]
            head = self.heading + turn * t
            if abs(turn) > 1e-6:   # an arc of radius speed / turn_rate, in closed form
                dx = p["speed"] / turn * (np.sin(head) - np.sin(self.heading))
                dy = p["speed"] / turn * (np.cos(self.heading) - np.cos(head))
            else:
                dx, dy = p["speed"] * t * np.cos(head), p["speed"] * t * np.sin(head)
            bob = p["bob"] * np.cos(2 * phase)
            pos = self.p0[None] + np.stack([dx, dy, bob], -1)
            root = _yaw(head)
            hip, knee, arm = p["hip_amp"], p["knee_amp"], p["arm_amp"]
            angles = {
                "torso": _yaw(p["twist"] * np.sin(phase)) @ _pitch(np.full(n, p["lean"])),
                "head": _yaw(-0.5 * p["twist"] * np.sin(phase)),
                "thigh_l": _pitch(hip * np.sin(phase)),
                "thigh_r": _pitch(hip * np.sin(phase + np.pi)),
                "shin_l": _pitch(-knee * 0.5 * (1 - np.cos(phase + 1.0))),
                "shin_r": _pitch(-knee * 0.5 * (1 - np.cos(phase + np.pi + 1.0))),
                "upper_arm_l": _pitch(arm * np.sin(phase + np.pi)) @ _roll(np.full(n, 0.08)),
                "upper_arm_r": _pitch(arm * np.sin(phase)) @ _roll(np.full(n, -0.08)),
                "forearm_l": _pitch(0.25 + 0.2 * (0.5 - 0.5 * np.cos(phase))),
                "forearm_r": _pitch(0.25 + 0.2 * (0.5 + 0.5 * np.cos(phase))),
            }
            return root, pos, angles
        tt = t if self.action == "gesture" else np.zeros_like(t)
        sway = np.stack([p["sway"] * np.sin(2 * np.pi * p["sway_freq"] * tt + p["sway_phase"]),
                         p["sway"] * np.cos(2 * np.pi * p["sway_freq"] * tt + 0.7 * p["sway_phase"]),
                         np.zeros(n)], -1)
        pos = self.p0[None] + sway
        root = _yaw(self.heading + _wave(tt, p, "turn"))
        angles = {
            "torso": _yaw(_wave(tt, p, "twist")) @ _pitch(_wave(tt, p, "lean")),
            "head": _yaw(_wave(tt, p, "look")) @ _pitch(_wave(tt, p, "nod")),
            "upper_arm_l": _pitch(_wave(tt, p, "shoulder_l")) @ _roll(_wave(tt, p, "spread_l")),
            "upper_arm_r": _pitch(_wave(tt, p, "shoulder_r")) @ _roll(-_wave(tt, p, "spread_r")),
            "forearm_l": _pitch(_wave(tt, p, "elbow_l")),
            "forearm_r": _pitch(_wave(tt, p, "elbow_r")),
            "thigh_l": _roll(np.full(n, 0.05)), "thigh_r": _roll(np.full(n, -0.05)),
            "shin_l": _pitch(np.zeros(n)), "shin_r": _pitch(np.zeros(n)),
        }
        return root, pos, angles

    def poses(self, times: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each part's ellipsoid pose at ``times`` (T,) s: rotation (T, 3, 3) local -> world and centre (T, 3)
        metres; with :attr:`board` also ``"board"``, the held card's pose (its plane is local z = 0)."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        root_R, root_p, angles = self._joints(t)
        frames: dict[str, tuple[np.ndarray, np.ndarray]] = {"root": (root_R, root_p)}
        out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        s = self.scale
        for name, (parent, joint, _, centre) in FIGURE_PARTS.items():   # parents come before children
            R_par, p_par = frames[parent]
            R = R_par @ angles[name]
            p = p_par + s * (R_par @ np.asarray(joint))
            frames[name] = (R, p)
            out[name] = (R, p + s * (R @ np.asarray(centre)))
        if self.board:
            R_arm, p_elbow = frames["forearm_l"]
            hand = p_elbow + s * (R_arm @ np.array([0.0, 0.0, -0.27]))
            # the board hangs from the hand along the forearm, its face towards where the forearm points
            R_board = R_arm @ rotation_about(_X, np.pi / 2)
            out["board"] = (R_board, hand + s * (R_arm @ np.array([0.0, 0.0, -BOARD_HALF[1]])))
        return out

    @property
    def part_names(self) -> list[str]:
        return list(FIGURE_PARTS) + (["board"] if self.board else [])


@dataclass(frozen=True)
class PartMotion:
    """The motion of one part of a :class:`Figure` (a :class:`~.motion.Motion`)."""

    figure: Figure
    part: str
    index: int = 0   # which figure of the scene, for descriptions

    @property
    def kind(self) -> str:
        return "articulated"

    @property
    def params(self) -> dict:
        return {"figure": self.index, "part": self.part, "action": self.figure.action}

    @property
    def moves(self) -> bool:
        return self.figure.action != "still"

    def pose(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.figure.poses(times)[self.part]


def sample_figure(rng: np.random.Generator, action: str, *, position: np.ndarray, heading: float,
                  board: bool = False) -> Figure:
    """Draw a figure doing ``action`` ("walk", "gesture" or "still") that stands at the ground point
    ``position`` (2,) at t = 0, facing ``heading`` (rad)."""
    if action not in FIGURE_ACTIONS:
        raise ValueError(f"unknown figure action {action!r}")
    scale = float(rng.uniform(0.9, 1.08))
    p0 = np.array([position[0], position[1], PELVIS_HEIGHT * scale])
    if action == "walk":
        params = dict(speed=float(rng.uniform(0.35, 0.8)), turn_rate=float(rng.uniform(-0.35, 0.35)),
                      step_freq=float(rng.uniform(0.75, 1.05)), step_phase=float(rng.uniform(0, 2 * np.pi)),
                      hip_amp=float(rng.uniform(0.3, 0.5)), knee_amp=float(rng.uniform(0.5, 0.9)),
                      arm_amp=float(rng.uniform(0.2, 0.45)), bob=float(rng.uniform(0.01, 0.025)),
                      twist=float(rng.uniform(0.05, 0.15)), lean=float(rng.uniform(0.0, 0.08)))
        return Figure("walk", scale, p0, float(heading), params, False)

    def wave(name: str, base: tuple[float, float], amp: tuple[float, float], freq: tuple[float, float]) -> dict:
        return {name + "_base": float(rng.uniform(*base)), name + "_amp": float(rng.uniform(*amp)),
                name + "_freq": float(rng.uniform(*freq)), name + "_phase": float(rng.uniform(0, 2 * np.pi))}

    params = dict(sway=float(rng.uniform(0.0, 0.06)), sway_freq=float(rng.uniform(0.15, 0.4)),
                  sway_phase=float(rng.uniform(0, 2 * np.pi)))
    hold = board or rng.random() < 0.5   # arms raised in front (holding or showing something)
    params.update(wave("turn", (-0.1, 0.1), (0.0, 0.35), (0.1, 0.3)))
    params.update(wave("twist", (-0.15, 0.15), (0.0, 0.3), (0.15, 0.5)))
    params.update(wave("lean", (0.0, 0.25), (0.0, 0.12), (0.1, 0.4)))
    params.update(wave("look", (-0.3, 0.3), (0.1, 0.5), (0.15, 0.5)))
    params.update(wave("nod", (-0.1, 0.25), (0.0, 0.2), (0.2, 0.6)))
    for side in ("l", "r"):
        params.update(wave("shoulder_" + side, (0.7, 1.4) if hold else (0.0, 0.6), (0.15, 0.6), (0.2, 0.7)))
        params.update(wave("spread_" + side, (0.05, 0.35), (0.0, 0.25), (0.2, 0.6)))
        params.update(wave("elbow_" + side, (0.3, 1.3), (0.1, 0.5), (0.2, 0.8)))
    return Figure(action, scale, p0, float(heading), params, bool(board))
