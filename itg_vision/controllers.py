"""Baseline controllers that plug into the loop in place of the ITG.

- :class:`InverseKinematics`: closed-form inverse kinematics of the *nominal* model, open loop
  (it ignores the feedback): what most users would pick. Wrong when the arm differs from the
  model.
- :class:`JacobianTracker`: no kinematic model; the Jacobian's columns come from the measured
  marker positions (for a planar arm: column 1 is the gripper position turned by 90 degrees,
  column 2 the gripper-minus-elbow vector turned by 90 degrees), solved by damped least squares.

Both return :class:`itg_vision.rules.Step`, like the rule base.
"""

from __future__ import annotations

import math

import numpy as np

from .arm import ArmSpec
from .errors import UserError
from .rules import Step


def _wrap_deg(a):
    return (np.asarray(a, float) + 180.0) % 360.0 - 180.0


def two_link_ik(x: float, y: float, l1: float, l2: float) -> tuple[tuple[float, float], ...]:
    """Both closed-form solutions (q1, q2) in degrees of the planar two-link arm, or ()."""
    r2 = x * x + y * y
    c2 = (r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    if c2 < -1.0 - 1e-12 or c2 > 1.0 + 1e-12:
        return ()
    c2 = min(1.0, max(-1.0, c2))
    out = []
    for s2 in (math.sqrt(1.0 - c2 * c2), -math.sqrt(1.0 - c2 * c2)):
        q2 = math.atan2(s2, c2)
        q1 = math.atan2(y, x) - math.atan2(l2 * s2, l1 + l2 * c2)
        out.append((math.degrees(q1), math.degrees(q2)))
    return tuple(out)


class InverseKinematics:
    """Open-loop closed-form IK of the nominal model; picks the branch nearest the current q."""

    name = "ik"

    def __init__(self, model: ArmSpec):
        self.model = model

    def solve(self, desired_mm, q_deg) -> np.ndarray | None:
        L = self.model.links_mm
        x, y, z = (float(v) for v in desired_mm)
        q_now = np.asarray(q_deg, float)
        if self.model.name == "one-link":
            if abs(math.hypot(x, y) - L[0]) > 1e-6 * L[0] + 0.5:
                return None
            return np.array([math.degrees(math.atan2(y, x))])
        if self.model.name == "two-link":
            cands = [np.array(c) for c in two_link_ik(x, y, L[0], L[1])]
        else:
            r = math.hypot(x, y)
            cands = []
            for yaw, sign in ((math.degrees(math.atan2(y, x)), 1.0),
                              (math.degrees(math.atan2(-y, -x)), -1.0)):
                for q2, q3 in two_link_ik(sign * r, z - L[0], L[1], L[2]):
                    cands.append(np.array([yaw, q2, q3]))
        if not cands:
            return None
        return min(cands, key=lambda c: float(np.sum(_wrap_deg(c - q_now) ** 2)))

    def step(self, desired_mm, markers, q_deg) -> Step:
        target = self.solve(desired_mm, q_deg)
        if target is None:
            return Step(np.zeros(self.model.n_joints), (), True)
        return Step(_wrap_deg(target - np.asarray(q_deg, float)), (), False)


class JacobianTracker:
    """Damped least squares on a Jacobian built from measured marker positions only.

    ``dq = J^T (J J^T + lambda^2 I)^-1 (x_d - x_g)``, with J in mm/rad. The base axis position
    (the world origin, and the shoulder height for the three-link arm) is the only fixed
    geometry it uses: a point one measures once, not a kinematic model.
    """

    name = "jacobian"

    def __init__(self, model: ArmSpec, damping_mm: float = 5.0, max_step_deg: float = 20.0):
        self.planar = model.planar
        self.n = model.n_joints
        self.shoulder = model.shoulder_mm()
        self.damping = damping_mm
        self.max_step = max_step_deg

    def jacobian(self, g: np.ndarray, e: np.ndarray) -> np.ndarray:
        def turn(v):  # 90 degrees about z
            return np.array([-v[1], v[0]])

        if self.planar:
            cols = [turn(g[:2])] + ([turn(g[:2] - e[:2])] if self.n == 2 else [])
            return np.column_stack(cols)
        z = np.array([0.0, 0.0, 1.0])
        axis = np.cross([g[0], g[1], 0.0], z)  # pitch axis: horizontal, normal to the arm plane
        n = np.linalg.norm(axis)
        axis = axis / n if n > 1e-9 else np.array([0.0, -1.0, 0.0])
        # pitch joints turn about -axis... sign chosen so positive q lifts the link
        a = -axis
        return np.column_stack([np.cross(z, g), np.cross(a, g - self.shoulder), np.cross(a, g - e)])

    def step(self, desired_mm, markers, q_deg) -> Step:
        g, e = np.asarray(markers.gripper_mm, float), np.asarray(markers.elbow_mm, float)
        dim = 2 if self.planar else 3
        err = (np.asarray(desired_mm, float) - g)[:dim]
        if not np.all(np.isfinite(err)) or (self.n > 1 and not np.all(np.isfinite(e[:dim]))):
            return Step(np.zeros(self.n), (), False)
        J = self.jacobian(g, e)
        dq = J.T @ np.linalg.solve(J @ J.T + self.damping**2 * np.eye(dim), err)
        dq = np.degrees(dq)
        biggest = np.max(np.abs(dq))
        if biggest > self.max_step:
            dq *= self.max_step / biggest
        return Step(dq, (), False)


def make_controller(name: str, model: ArmSpec, **_):
    if name == "ik":
        return InverseKinematics(model)
    if name == "jacobian":
        return JacobianTracker(model)
    raise UserError(f"unknown controller {name!r} (choose from itg, ik, jacobian)")
