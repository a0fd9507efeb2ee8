"""What a model-free controller may know of the arm, measured from its LEDs at start-up.

Under vision (or truth) feedback nothing from the nominal kinematic model reaches the rules or
the Jacobian tracker. The few lengths they use are measured before the trajectory starts, from
the marker estimates alone (in the world frame, which calibration ties to the robot's base: the
base axis is the world z axis through x = y = 0):

- planar arms: L1 = |elbow_xy| (the elbow LED turns about the base axis), L2 = |gripper_xy -
  elbow_xy|; one observation, no motion.
- three-link arm: the shoulder joint (q2) is moved alone through a few angles about the start
  pose and the elbow LED's positions are fitted with a circle (:func:`fit_circle`). The circle's
  centre is the shoulder offset sideways by the LED stand-off, along the pitch axis: its height
  is L1, its distance from the base axis the stand-off, its radius L2; L3 = |gripper - elbow|.
  The arm then returns to its start pose exactly (the same increments, reversed).

The same fits tie a calibrated rig to the base (:mod:`itg_vision.calibration`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from .errors import UserError

#: Shoulder angles (deg, relative to the start pose) at which the three-link elbow is observed.
SHOULDER_SWEEP_DEG = (-60.0, -30.0, 0.0, 30.0, 60.0)
#: Observations averaged (per coordinate, median) at each pose, and the most tried to get them
#: (a dropped or rejected detection is tried again, as on a real rig).
SAMPLES_PER_POSE = 5
MAX_TRIES_PER_POSE = 50


@dataclass(frozen=True)
class ArmGeometry:
    """The arm as a model-free controller knows it (mm).

    Attributes
    ----------
    links_mm : link lengths bound to the rules' ``L1..Ln``; three-link: base height (the
        shoulder's height above the base), upper arm, forearm.
    shoulder_mm : shape (3,), the shoulder joint on the base axis ((0, 0, 0) for planar arms).
    standoff_mm : the LEDs' offset from the links along the pitch axis (three-link), else 0.
    source : where the numbers come from: "nominal model" or how they were measured.
    residual_mm : RMS residual of the fit that produced them (0 for a single observation).
    """

    links_mm: tuple[float, ...]
    shoulder_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    standoff_mm: float = 0.0
    source: str = "nominal model"
    residual_mm: float = 0.0

    def record(self) -> dict:
        """Plain values for ``summary.json``."""
        return {"links_mm": [round(v, 4) for v in self.links_mm],
                "shoulder_mm": [round(v, 4) for v in self.shoulder_mm],
                "standoff_mm": round(self.standoff_mm, 4), "source": self.source,
                "residual_mm": round(self.residual_mm, 4)}


def nominal_geometry(arm) -> ArmGeometry:
    """The nominal model's geometry (what ``--feedback model`` and open-loop IK use)."""
    standoff = 0.0 if arm.planar else arm.led_standoff_mm
    return ArmGeometry(tuple(arm.links_mm), tuple(float(v) for v in arm.shoulder_mm()),
                       standoff, "nominal model")


# ---------------------------------------------------------------------------- fits
def fit_plane(points_mm) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares plane through points.

    Parameters
    ----------
    points_mm : array-like, shape (n, 3), n >= 3, not all on a line.

    Returns
    -------
    centroid : (3,); normal : (3,) unit (sign arbitrary); rms_mm : RMS distance to the plane.
    """
    P = np.asarray(points_mm, float)
    c = P.mean(axis=0)
    _, s, Vt = np.linalg.svd(P - c, full_matrices=False)
    return c, Vt[2], float(s[2] / np.sqrt(len(P)))


def coaxial_normal(point_sets) -> np.ndarray:
    """The common normal of several circles about one axis (parallel planes): the least-squares
    plane normal of all the points, each set centred on its own mean. Unit, shape (3,)."""
    centred = np.vstack([np.asarray(p, float) - np.mean(p, axis=0) for p in point_sets])
    return np.linalg.svd(centred, full_matrices=False)[2][2]


def fit_circle(points_mm, normal=None) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Least-squares circle through 3-D points: plane fit, then an algebraic (Kasa) fit in it.

    Parameters
    ----------
    points_mm : array-like, shape (n, 3), n >= 3, not all on a line.
    normal : optional, shape (3,): the plane's normal when it is known (e.g. from
        :func:`coaxial_normal`); the plane then passes through the points' mean.

    Returns
    -------
    centre : (3,); normal : (3,) unit normal of the circle's plane (sign arbitrary);
    radius_mm : float; rms_mm : RMS distance of the points from the fitted circle.
    """
    P = np.asarray(points_mm, float)
    if normal is None:
        c, n, _ = fit_plane(P)
    else:
        c, n = P.mean(axis=0), np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross(n, [1.0, 0.0, 0.0])
    if np.linalg.norm(u) < 0.5:
        u = np.cross(n, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    x, y = (P - c) @ u, (P - c) @ v
    # x^2 + y^2 = 2 a x + 2 b y + k: linear in (a, b, k)
    A = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    (a, b, k), *_ = np.linalg.lstsq(A, x * x + y * y, rcond=None)
    radius = float(np.sqrt(max(k + a * a + b * b, 0.0)))
    centre = c + a * u + b * v
    d = P - centre
    in_plane = d - np.outer(d @ n, n)
    resid = np.hypot(np.linalg.norm(in_plane, axis=1) - radius, d @ n)
    return centre, n, radius, float(np.sqrt(np.mean(resid**2)))


def rotation_sense_axis(centre_mm, normal, points_mm) -> np.ndarray:
    """The circle's normal oriented so the points, in the order given (increasing joint
    angle), turn counter-clockwise about it (the right-hand rule of a positive joint step)."""
    d = np.asarray(points_mm, float) - np.asarray(centre_mm, float)
    turn = float(np.sum(np.cross(d[:-1], d[1:]) @ np.asarray(normal, float)))
    return np.asarray(normal, float) * (1.0 if turn >= 0 else -1.0)


def turn_about(axis, angle_deg: float) -> np.ndarray:
    """Rotation matrix by ``angle_deg`` about the unit ``axis`` (right-hand rule), (3, 3)."""
    import cv2

    return cv2.Rodrigues(np.asarray(axis, float) * np.radians(angle_deg))[0]


def zero_direction(centre_mm, axis, points_mm, angles_deg) -> np.ndarray:
    """Where a point turning about ``axis`` points at joint angle 0: each point's direction
    from the centre, turned back by its commanded angle, averaged. Unit vector ⟂ axis, (3,)."""
    axis = np.asarray(axis, float)
    acc = np.zeros(3)
    for p, q in zip(np.asarray(points_mm, float), angles_deg):
        d = p - centre_mm
        d -= (d @ axis) * axis
        acc += turn_about(axis, -float(q)) @ (d / np.linalg.norm(d))
    acc -= (acc @ axis) * axis
    return acc / np.linalg.norm(acc)


# ---------------------------------------------------------------------------- start-up
class StartUpFailed(UserError):
    """The start-up measurement saw too few LEDs: the run cannot start (the rig does not see
    the arm, or rejects every look). A user error for ``run``; an outcome of its condition for a
    benchmark sweep, which records it as a run that did not start."""


def _observe(world, feedback, names, where: str) -> dict[str, np.ndarray]:
    """The median of ``SAMPLES_PER_POSE`` observations in which every marker was measured."""
    got: list = []
    why: Counter = Counter()  # why the looks that missed a marker missed it
    for _ in range(MAX_TRIES_PER_POSE):
        m = feedback.observe(world)
        if not any(n in m.missed or not np.all(np.isfinite(m.get(n))) for n in names):
            got.append({n: m.get(n) for n in names})
            if len(got) == SAMPLES_PER_POSE:
                return {n: np.median([g[n] for g in got], axis=0) for n in names}
        else:
            why.update({_miss_cause(feedback, n) for n in names if n in m.missed})
    causes = ", ".join(f"{c}: {k} looks" for c, k in why.most_common())
    raise StartUpFailed(f"start-up measurement: the LEDs were measured in only {len(got)} of "
                        f"{MAX_TRIES_PER_POSE} observations {where}"
                        + (f" (missed: {causes})" if causes else "")
                        + "; the arm's lengths cannot be measured")


def _miss_cause(feedback, name: str) -> str:
    """Why ``feedback``'s last look missed marker ``name`` (its cause, not the measured value:
    one entry per cause in the failure's count), naming the option that set the cause where
    one did (``--dropout``, ``--noise-px``), else the rig's part."""
    from .feedback import DROPPED, PARTLY_HIDDEN, RESIDUAL

    obs = getattr(feedback, "last_observation", None)
    cause = obs.causes.get(name, "") if obs is not None else ""
    if cause == DROPPED:
        return f"dropped at random (--dropout {feedback.dropout:g})"
    if cause == RESIDUAL:
        noise = getattr(feedback, "noise_px", 0.0)
        return (f"reprojection residual above {feedback.max_residual_px:g} px"
                + (f" (--noise-px {noise:g})" if noise > 0 else " (check the rig)"))
    if cause == PARTLY_HIDDEN:
        return (f"blob area under {feedback.min_area_ratio:g} of expected: partly hidden "
                "(check the rig)")
    return f"{cause or 'not measured'} (check the rig)"


def measure_geometry(world, feedback, arm) -> ArmGeometry:
    """Measure the lengths the rules and the Jacobian tracker use, from the LEDs alone.

    Parameters
    ----------
    world : `itg_vision.world.World` at the start pose (left there on return).
    feedback : the run's feedback source (its estimates are all this function reads).
    arm : the arm's structure (which joints and markers it has; its lengths are not read).

    Raises
    ------
    StartUpFailed : a marker was not seen (a UserError).
    """
    if arm.planar:
        m = _observe(world, feedback, arm.marker_names, "at the start pose")
        g = m["gripper"][:2]
        if arm.n_joints == 1:
            return ArmGeometry((float(np.linalg.norm(g)),), source="measured: |gripper_xy|")
        e = m["elbow"][:2]
        links = (float(np.linalg.norm(e)), float(np.linalg.norm(g - e)))
        return ArmGeometry(links, source="measured: |elbow_xy|, |gripper_xy - elbow_xy|")
    elbows, forearm = [], []
    at = 0.0
    for rel in SHOULDER_SWEEP_DEG:
        world.move([0.0, rel - at, 0.0])
        at = rel
        m = _observe(world, feedback, arm.marker_names,
                     f"with the shoulder moved {rel:+g} deg from the start")
        elbows.append(m["elbow"])
        forearm.append(float(np.linalg.norm(m["gripper"] - m["elbow"])))
    world.move([0.0, -at, 0.0])
    centre, _, radius, rms = fit_circle(elbows)
    standoff = float(np.linalg.norm(centre[:2]))
    L1 = float(centre[2])
    links = (L1, radius, float(np.median(forearm)))
    return ArmGeometry(links, (0.0, 0.0, L1), standoff,
                       "measured: circle through the elbow LED with the shoulder moved "
                       f"{SHOULDER_SWEEP_DEG[0]:+g}..{SHOULDER_SWEEP_DEG[-1]:+g} deg; "
                       "|gripper - elbow|", rms)
