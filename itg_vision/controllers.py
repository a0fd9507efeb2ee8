"""Baseline controllers that plug into the loop in place of the ITG.

- :class:`InverseKinematics`: closed-form inverse kinematics of the *nominal* model, open loop
  (it ignores the feedback): what most users would pick. Wrong when the arm differs from the
  model.
- :class:`JacobianTracker`: no kinematic model; the Jacobian's columns come from the measured
  marker positions (each joint's axis crossed with its lever to the gripper LED), solved by
  damped least squares.

Both return :class:`itg_vision.rules.Step`, like the rule base.
"""

from __future__ import annotations

import math

import numpy as np

from .arm import REACH_TOL_MM, ArmSpec, wrap_deg
from .errors import UserError
from .contracts import Step


def two_link_ik(x: float, y: float, l1: float, l2: float, tol_mm: float = 0.0
                ) -> tuple[tuple[float, float], ...]:
    """Both closed-form solutions (q1, q2) in degrees of the planar two-link arm, or ().

    A point out of reach by at most ``tol_mm`` on the radius (:data:`itg_vision.arm.REACH_TOL_MM`
    for the metrics' "in reach") is solved as the nearest point the arm reaches, on the same
    ray: the arm stretched (or folded) towards it."""
    r = math.hypot(x, y)
    if r > l1 + l2 + tol_mm or r < abs(l1 - l2) - tol_mm:
        return ()
    c2 = (r * r - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    c2 = min(1.0, max(-1.0, c2))
    out = []
    for s2 in (math.sqrt(1.0 - c2 * c2), -math.sqrt(1.0 - c2 * c2)):
        q2 = math.atan2(s2, c2)
        q1 = math.atan2(y, x) - math.atan2(l2 * s2, l1 + l2 * c2)
        out.append((math.degrees(q1), math.degrees(q2)))
    return tuple(out)


def three_link_ik(p_mm, links_mm, standoff_mm=0.0, tol_mm: float = 0.0
                  ) -> tuple[tuple[float, float, float], ...]:
    """Closed-form solutions (q1, q2, q3) in degrees putting the three-link gripper LED at ``p``
    (a point out of reach by at most ``tol_mm`` on a radius: the nearest one reached, as
    :func:`two_link_ik` does).

    The LED sits ``standoff_mm`` beside the forearm's tip along the pitch axis
    a = (sin q1, -cos q1, 0) (see :func:`itg_vision.arm.forward_kinematics`), so its horizontal
    position is r d + h a with d = (cos q1, sin q1): |p_xy|^2 = r^2 + h^2 and
    q1 = atan2(p_y, p_x) + atan2(h, r), for r = +-sqrt(|p_xy|^2 - h^2) (reaching forwards or
    over the top); (r, z - L1) is then the planar two-link problem of links L2, L3.
    """
    x, y, z = (float(v) for v in p_mm)
    L1, L2, L3 = links_mm
    h = float(standoff_mm)
    rho2 = x * x + y * y - h * h
    if math.hypot(x, y) < h - tol_mm:
        return ()
    rho2 = max(rho2, 0.0)
    out = []
    for r in ((math.sqrt(rho2), -math.sqrt(rho2)) if rho2 > 0 else (0.0,)):
        yaw = math.degrees(math.atan2(y, x) + math.atan2(h, r))
        for q2, q3 in two_link_ik(r, z - L1, L2, L3, tol_mm):
            out.append((yaw, q2, q3))
    return tuple(out)


class InverseKinematics:
    """Open-loop closed-form IK of the nominal model, aimed at the tracked point (the gripper
    LED, stand-off included); picks the branch nearest the current q."""

    name = "ik"
    uses_encoders = True  # open loop: the commanded angles are all it has
    uses_markers = False  # so a look that missed the gripper does not hold it

    def __init__(self, model: ArmSpec):
        self.model = model

    def solve(self, desired_mm, q_deg) -> np.ndarray | None:
        L = self.model.links_mm
        x, y, _ = (float(v) for v in desired_mm)
        q_now = np.asarray(q_deg, float)
        if self.model.n_joints == 1:
            if abs(math.hypot(x, y) - L[0]) > REACH_TOL_MM:
                return None
            return np.array([math.degrees(math.atan2(y, x))])
        if self.model.planar:
            cands = [np.array(c) for c in two_link_ik(x, y, L[0], L[1], REACH_TOL_MM)]
        else:
            cands = [np.array(c) for c in three_link_ik(desired_mm, L, self.model.led_standoff_mm,
                                                        REACH_TOL_MM)]
        if not cands:
            return None
        return min(cands, key=lambda c: float(np.sum(wrap_deg(c - q_now) ** 2)))

    def params(self) -> dict:
        """The parameters it runs with (none: the nominal model is all it knows)."""
        return {}

    def step(self, desired_mm, markers, q_deg) -> Step:
        target = self.solve(desired_mm, q_deg)
        if target is None:
            return Step(np.zeros(self.model.n_joints), (), True)
        return Step(wrap_deg(target - np.asarray(q_deg, float)), (), False)


#: Below this horizontal forearm length (mm) the three-link tracker takes the pitch axis from
#: the elbow LED and the stand-off instead of from the forearm (whose direction noise decides).
VERTICAL_FOREARM_MM = 20.0


def pitch_axis(g_mm, e_mm, standoff_mm: float, previous=None) -> np.ndarray:
    """The three-link arm's pitch axis a (unit, horizontal) from the two LED positions.

    Positive q2/q3 turn the links about +a = (sin q1, -cos q1, 0), which is also the side on
    which the LEDs sit, ``standoff_mm`` off the arm's plane: a . g_xy = a . e_xy = h. When the
    forearm is not vertical, a is perpendicular to (g - e)_xy, with the sign nearer
    ``previous`` (without one: the sign that puts the LEDs on its positive side). That side
    test extrapolates the LEDs' line back to the base axis: its error is the line's tilt times
    the elbow's reach, which under 4 px (reach ~95 mm, the forearm ~25 mm across) passed h and
    flipped the axis. When it is (the straight-up start is one such pose), a follows from
    the elbow alone: e_xy = r_e d + h a with d = a turned by +90 deg and r_e = +-sqrt(|e_xy|^2 -
    h^2), the elbow's signed horizontal reach (negative: the upper arm leans back past
    vertical). The LEDs cannot tell the two roots apart (the elbow LED lies on one of the two
    tangents from it to the circle of radius h about the base axis, and the gripper LED straight
    above it), so the root is the one whose axis is nearer ``previous``, the axis of the
    decision before (the arm moves a few degrees between decisions); without one, r_e >= 0
    (the roots coincide at the straight-up start).

    Parameters
    ----------
    g_mm, e_mm : shape (3,), gripper and elbow LED centres (mm), relative to the base axis.
    standoff_mm : the LED stand-off h (mm), measured at start-up.
    previous : shape (3,), the axis used at the previous decision, or None.

    Returns
    -------
    a : shape (3,), unit, z = 0.
    """
    g, e = np.asarray(g_mm, float)[:2], np.asarray(e_mm, float)[:2]
    u = g - e
    nu = float(np.hypot(*u))
    if nu >= VERTICAL_FOREARM_MM:
        a = np.array([u[1], -u[0]]) / nu
        candidates = (a, -a) if a @ e >= 0 else (-a, a)  # first: the LEDs on its positive side
    else:
        h = float(standoff_mm)
        ne2 = float(e @ e)
        if ne2 < 1e-12:
            return np.array([0.0, -1.0, 0.0])  # no information at all: the start's q1 = 0 side
        r = math.sqrt(max(ne2 - h * h, 0.0))
        # e = r d + h a, with d = (-a_y, a_x): solve the 2x2 rotation for a, for each root
        roots = (np.array([h * e[0] + s * e[1], h * e[1] - s * e[0]]) for s in (r, -r))
        candidates = tuple(c / np.linalg.norm(c) for c in roots)  # first: r >= 0
    if previous is None:
        a = candidates[0]
    else:
        p = np.asarray(previous, float)[:2]
        a = max(candidates, key=lambda c: c @ p)
    return np.array([a[0], a[1], 0.0])


#: The Jacobian tracker's damping lambda (mm) unless given (``run --damping``). On the two-link
#: ellipses it gives DLS its lowest clean tracking median of 0.5-20 mm; 0.5-2 mm give smaller
#: clean maxima there but far larger ones near the base (README, "The baselines' settings").
DEFAULT_DAMPING_MM = 5.0

class JacobianTracker:
    """Damped least squares on a Jacobian built from measured marker positions only.

    ``dq = J^T (J J^T + lambda^2 I)^-1 (x_d - x_g)``, with J in mm/rad. Each column is a joint's
    axis crossed with the lever from that joint to the gripper LED: planar arms turn about z
    through the base (q1: lever g) and through the elbow LED (q2: lever g - e); the three-link
    arm turns its base about the vertical base axis (q1: lever g less the axis point) and its
    pitch joints about the measured pitch axis (:func:`pitch_axis`, from the LEDs relative to
    the base axis) through the shoulder (q2: g - shoulder) and the elbow LED (q3: g - e; the
    LED's stand-off lies along the axis and drops out of the cross product). Of the two axes
    the LEDs allow (:func:`pitch_axis`) it takes the one nearer the axis the loop keeps
    (:attr:`itg_vision.contracts.Markers.pitch_axis`, the start-up's turned with the base's
    commanded angle), or, given none, the one nearer the last decision's, so one tracker
    follows one run. The loop's cannot keep a wrong start: nearer the last decision's, a sign
    misread at the noisy straight-up start (where the forearm is near vertical and the choice
    rests on the stand-off) was kept for the run: given to ITG+ under 4 px, 8 of 100
    line-ab-reach runs and 3 of 100 helix runs diverged (docs/robustness.md). Taking the
    loop's axis outright, the tracker did no better under 4 px (paired over seeds 0-19, the
    tracking maxima +1.0, +1.3 and +1.5 mm on line-ab-reach, the helix and reach-loop, each
    within two standard errors), so it keeps measuring the direction; nearer the loop's axis
    instead of the last decision's, +1.7, +0.7 and -0.6 mm (the same). A look that missed either LED keeps the last axis: the
    elbow's held estimate is from an earlier pose, and a missed gripper is the loop's last aim,
    not a measurement. Measured (vision): re-measured from a held elbow the axis flipped by
    170 deg and stayed (helix, 4 seeds: tracking max 55-60 mm; kept, 0.54 mm); from a
    gripper put at the last aim, 87 deg (line-ab-reach, 4 px, 5 seeds: worst max 89 mm, one
    run diverged; kept, 20.4 mm, against 29.8 mm before the axis followed the upper arm).
    The only geometry it uses is what :func:`itg_vision.identify.measure_geometry` measures at
    start-up (the shoulder point, whose x, y place the vertical base axis, and the LED
    stand-off): no model.

    Parameters
    ----------
    geometry : `itg_vision.identify.ArmGeometry`, measured (or nominal, for a model-fed run).
    planar, n_joints : the arm's structure.
    damping_mm : lambda.
    max_step_deg : the servo rate limit it plans for (deg per iteration): a step whose largest
        joint increment exceeds it is scaled down as a whole, keeping its direction (the loop
        clips each joint on its own, which would bend the step). The runner sets it to the
        run's ``max_step_deg``, the limit every controller in a comparison runs under; None: no limit.
        Measured (three-link, line-ab-reach, ideal sensors, 2 deg/iteration): with the scaling
        the tracker settles at 0.0 mm; with per-joint clipping alone it chatters about the
        singular start (q2/q3 alternating by 2 deg) and never leaves it (E_track 141 mm). Two-link
        (13 paths, 20 deg/iteration): per-joint clipping alone raised E_av on 12 of them
        (README, "The baselines' settings").

    Attributes
    ----------
    axis : three-link: the pitch axis of the last decision, shape (3,); None before the first.
    """

    name = "jacobian"
    uses_encoders = False  # the Jacobian is built from the markers alone

    def __init__(self, geometry, planar: bool, n_joints: int,
                 damping_mm: float = DEFAULT_DAMPING_MM,
                 max_step_deg: float | None = None):
        self.planar = planar
        self.n = n_joints
        self.shoulder = np.asarray(geometry.shoulder_mm, float)
        self.base = np.array([*geometry.base_axis_mm, 0.0])  # a point on the vertical base axis
        self.standoff = float(geometry.standoff_mm)
        self.damping = damping_mm
        self.max_step = max_step_deg
        self.axis = None  # three-link: the pitch axis of the last decision (None before one)

    def params(self) -> dict:
        """The parameters it runs with, for the record."""
        return {"damping_mm": self.damping, "max_step_deg": self.max_step}

    def pitch_axis(self, g: np.ndarray, e: np.ndarray, previous=None) -> np.ndarray:
        """The three-link pitch axis from the LEDs (world frame, mm): :func:`pitch_axis`."""
        return pitch_axis(np.asarray(g, float) - self.base, np.asarray(e, float) - self.base,
                          self.standoff, previous)

    def jacobian(self, g: np.ndarray, e: np.ndarray, axis=None) -> np.ndarray:
        """d(gripper)/dq in mm/rad from the LED positions: shape (2, n) planar, (3, 3) else.
        Three-link: ``axis`` is the pitch axis (None: from these LEDs alone)."""
        g, e = np.asarray(g, float), np.asarray(e, float)
        if self.planar:
            def turn(v):  # z x v, in the plane
                return np.array([-v[1], v[0]])

            cols = [turn(g[:2] - self.base[:2])] + ([turn(g[:2] - e[:2])] if self.n == 2 else [])
            return np.column_stack(cols)
        z = np.array([0.0, 0.0, 1.0])
        a = self.pitch_axis(g, e) if axis is None else np.asarray(axis, float)
        return np.column_stack([np.cross(z, g - self.base), np.cross(a, g - self.shoulder),
                                np.cross(a, g - e)])

    def step(self, desired_mm, markers, q_deg) -> Step:
        g, e = np.asarray(markers.gripper_mm, float), np.asarray(markers.elbow_mm, float)
        dim = 2 if self.planar else 3
        err = (np.asarray(desired_mm, float) - g)[:dim]
        if not np.all(np.isfinite(err)) or (self.n > 1 and not np.all(np.isfinite(e[:dim]))):
            return Step(np.zeros(self.n), (), False)
        if not self.planar and (self.axis is None or not markers.missed):
            kept = markers.pitch_axis  # the loop's, which cannot flip; else the last decision's
            self.axis = self.pitch_axis(g, e, self.axis if kept is None else kept)
        J = self.jacobian(g, e, self.axis)
        dq = np.degrees(J.T @ np.linalg.solve(J @ J.T + self.damping**2 * np.eye(dim), err))
        if self.max_step is not None:
            biggest = np.max(np.abs(dq))
            if biggest > self.max_step:
                dq *= self.max_step / biggest
        return Step(dq, (), False)


def make_controller(name: str, model: ArmSpec, geometry=None, max_step_deg: float | None = None,
                    damping_mm: float | None = None):
    """A baseline by name: ``ik`` (nominal model) or ``jacobian`` (``geometry``: what was
    measured at start-up, the nominal geometry if None; ``max_step_deg``: the servo limit;
    ``damping_mm``: its lambda, None for :data:`DEFAULT_DAMPING_MM`)."""
    if name == "ik":
        return InverseKinematics(model)
    if name == "jacobian":
        from .identify import nominal_geometry

        return JacobianTracker(geometry or nominal_geometry(model), model.planar, model.n_joints,
                               DEFAULT_DAMPING_MM if damping_mm is None else damping_mm,
                               max_step_deg=max_step_deg)
    raise UserError(f"unknown controller {name!r} (choose from itg, ik, jacobian)")
