"""What a model-free controller may know of the arm, measured from its LEDs at start-up.

Under vision (or truth) feedback nothing from the nominal kinematic model reaches the rules or
the Jacobian tracker. The few lengths they use are measured before the trajectory starts, from
the marker estimates alone (in the eye's frame, which calibration ties to the robot's base):

- planar arms: the base joint (q1) is turned alone through most of a turn (:data:`BASE_SWEEP_DEG`,
  the other joints at the start pose), and the LEDs' circles, fitted with one centre
  (:func:`concentric_circles`), place the vertical base axis; L1 is the elbow LED's radius about
  it (one link: the gripper's), L2 the mean |gripper_xy - elbow_xy| over the sweep. A wrong
  world frame moves the arm in the eye's frame; lengths taken about the eye's x = y = 0 would
  then be off by the shift (L1 88-110 mm for 100 mm links under the benchmark's
  rig-perturbed), while the measured axis moves with the arm. A rig that frames the workspace
  but not the whole turn is enough: a pose whose LEDs the rig does not see is left out, and
  the poses seen place the axis if they cover :data:`MIN_BASE_ARC_DEG` (the lengths' standard
  error grows as the arc shrinks; the run's table names the poses left out).
- three-link arm: the base axis is measured, not assumed: with the arm leaned
  (:data:`BASE_SWEEP_POSE_DEG`) the base joint (q1) is turned alone through most of a turn,
  and the elbow and gripper LEDs' circles (:func:`base_axis`) have their centres on it,
  whatever the pose; where it crosses the shoulder's height is the point the controllers
  measure horizontal positions from (its tilt, a wrong frame's, is left to them as any frame
  error is). Then the shoulder joint (q2) is moved alone through a few angles about the start
  pose and the elbow LED's positions are fitted with a circle (:func:`fit_circle`). The
  circle's centre is the shoulder offset sideways by the LED stand-off, along the pitch axis:
  its height is L1, its distance from the measured base axis the stand-off, its radius L2;
  L3 = |gripper - elbow|. The arm is then set back to its start pose exactly, and so it is
  when a look fails (:class:`StartUpFailed`).

  A wrong world frame (a rig moved after calibration) displaces the whole arm in the eye's
  frame: the benchmark's rig-perturbed (1 deg about the cameras' midpoint and 5 mm) by up to
  17 mm at the shoulder (seeds 0-4), more than the 12 mm stand-off. An axis assumed at
  x = y = 0 then puts the LEDs on the wrong side of it: the eye sees the arm mirrored and every
  pitch step has the wrong sign. Measured, the axis moves with the arm.

The same fits tie a calibrated rig to the base (:mod:`itg_vision.calibration`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from .arm import model_pitch_axis, wrap_deg
from .errors import UserError

#: Shoulder angles (deg, relative to the start pose) at which the three-link elbow is observed.
SHOULDER_SWEEP_DEG = (-60.0, -30.0, 0.0, 30.0, 60.0)
#: The pose (q2, q3, deg, commanded: whatever the start pose) in which the base is turned to find
#: the base axis: the upper arm 60 deg above the horizontal and the forearm 60 deg below it. A
#: circle fit's centre is as good as the arc the points cover, whatever its radius: straight up,
#: the column hides an LED from a camera of the shipped rig beyond about +-80 deg, and the axis
#: extrapolated from +-60 deg arcs at the LEDs' heights (200, 300 mm) down to the shoulder
#: (100 mm) was off by up to 6 mm under 1 px noise (24 seeds). Leaned, the rig sees both LEDs at
#: every base angle in +-160 deg (measured in 20 and 30 deg steps), and the gripper LED circles
#: the axis at the shoulder's height (the elbow LED 87 mm above it): the axis at the shoulder
#: is measured, not extrapolated. Commanded, not relative to the start: from a start of one's
#: own (an arm file's ``start_pose_deg``) the same pose (relative to a start of q 30, 60, -30,
#: the LEDs were hidden from the first base angle on).
BASE_SWEEP_POSE_DEG = (60.0, -120.0)
#: Base angles (deg, commanded) at which the LEDs are observed to find the base axis: 300 deg of
#: arc, which the shipped rigs see whole (three-link: in the leaned pose; planar: the other
#: joints at the start pose).
BASE_SWEEP_DEG = (-150.0, -120.0, -90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0, 120.0, 150.0)
#: Observations averaged (per coordinate, median) at each pose, and the most tried to get them
#: (a dropped or rejected detection is tried again, as on a real rig).
SAMPLES_PER_POSE = 5
#: What a planar start-up needs of its base sweep, whose poses a rig of one's own may not all
#: see: three poses (three points place a circle; the one-link arm has one LED) covering an
#: arc of 120 deg or more (:func:`arc_covered_deg`). A circle's centre is as good as the arc
#: its points cover: two-link, 1 px, 12 seeds, the RMS error of L1 and the median / largest
#: offset of the axis were 6.05 mm and 4.8 / 13 mm from 60 deg of arc (3 poses), 1.62 mm and
#: 1.75 / 3.4 mm from 90 deg, 0.85 mm and 0.68 / 2.1 mm from 120 deg, 0.20 mm and 0.22 /
#: 0.57 mm from the whole 300 deg (20 seeds).
MIN_BASE_POSES = 3
MIN_BASE_ARC_DEG = 120.0
MAX_TRIES_PER_POSE = 50
#: The variance of the median of ``SAMPLES_PER_POSE`` (5) normal draws, in units of one draw's
#: variance (the order statistics of the normal distribution; tests/test_identify.py draws it).
MEDIAN_VARIANCE = 0.2868


@dataclass(frozen=True)
class ArmGeometry:
    """The arm as a model-free controller knows it (mm).

    Attributes
    ----------
    links_mm : link lengths bound to the rules' ``L1..Ln``; three-link: base height (the
        shoulder's height above the base), upper arm, forearm.
    shoulder_mm : shape (3,), the shoulder joint on the base axis (planar arms: the base axis
        at z = 0, (0, 0, 0) in the nominal model; three-link: where the measured base axis
        crosses the shoulder's height L1).
    standoff_mm : the LEDs' offset from the links along the pitch axis (three-link), else 0.
    source : where the numbers come from: "nominal model" or how they were measured.
    residual_mm : the largest RMS residual of the fits that produced them (0 for the nominal
        model).
    length_se_mm : the largest standard error of the lengths (mm), the rules' ``sL``: what the
        noise of the looks leaves uncertain in them, to first order (each look's scatter per
        axis, from the start-up's repeated looks, carried through the medians and the fits).
        A bias (a rig's, a rendering's: the same in every look) is not in it. 0 for the
        nominal model.
    pitch_axis : three-link, measured: the shoulder joint's (q2's) axis with the base at its
        commanded 0 deg, a unit vector oriented by the right-hand rule of a positive q2 step:
        the normal of the elbow LED's circle in the shoulder sweep, oriented so that the
        sweep's increasing q2 turns counter-clockwise about it, and turned back about the
        vertical by the base's commanded angle at the start (it turns with the base: at q1,
        turned by q1 about the vertical). The nominal model's: its axis at base angle 0.
        None: planar arms.
    elbow_seen : measured: ``(elbow_mm, q_deg)``, the elbow LED where the start-up saw it (a
        median of its looks) and the commanded joints then: the shoulder sweep's look at the
        start pose (three-link), the base sweep's look nearest the start's base angle (planar).
        A look of the run that misses the elbow before the run has seen it is turned from this
        (:class:`itg_vision.loop.Session`'s ``elbow_seen``): the eye's own last estimate is
        from the sweep's last pose, 100-193 mm from the start's elbow. None: no elbow LED, or
        not measured.
    """

    links_mm: tuple[float, ...]
    shoulder_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    standoff_mm: float = 0.0
    source: str = "nominal model"
    residual_mm: float = 0.0
    length_se_mm: float = 0.0
    pitch_axis: tuple[float, float, float] | None = None
    elbow_seen: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    @property
    def base_axis_mm(self) -> tuple[float, float]:
        """Where the vertical base axis crosses the xy plane (mm): the origin the rules and the
        Jacobian tracker measure the LEDs' horizontal positions from."""
        return self.shoulder_mm[0], self.shoulder_mm[1]

    def record(self) -> dict:
        """Plain values for ``summary.json``."""
        return {"links_mm": [round(v, 4) for v in self.links_mm],
                "base_axis_mm": [round(v, 4) for v in self.base_axis_mm],
                "shoulder_mm": [round(v, 4) for v in self.shoulder_mm],
                "standoff_mm": round(self.standoff_mm, 4),
                "pitch_axis": None if self.pitch_axis is None
                else [round(v, 6) for v in self.pitch_axis],
                "source": self.source,
                "residual_mm": round(self.residual_mm, 4),
                "length_se_mm": round(self.length_se_mm, 4)}


def nominal_geometry(arm) -> ArmGeometry:
    """The nominal model's geometry (what ``--feedback model`` and open-loop IK use); three-link:
    the model's pitch axis at base angle 0 (:func:`itg_vision.arm.model_pitch_axis`)."""
    standoff = 0.0 if arm.planar else arm.led_standoff_mm
    axis = None if arm.planar else tuple(float(v) for v in model_pitch_axis(arm, 0.0))
    return ArmGeometry(tuple(arm.links_mm), tuple(float(v) for v in arm.shoulder_mm()),
                       standoff, "nominal model", pitch_axis=axis)


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


def concentric_circles(point_sets) -> tuple[np.ndarray, tuple[float, ...], float]:
    """Circles about one vertical axis (a planar arm's LEDs as its base turns): a common centre
    and one radius per set, fitted in x, y by least squares (the algebraic form of
    :func:`fit_circle`, one constant per circle); z is not read.

    Parameters
    ----------
    point_sets : sequence of array-likes, each shape (n, 3) or (n, 2), n >= 3: one LED's
        positions (mm).

    Returns
    -------
    centre_xy : (2,), where the axis crosses the xy plane; radii_mm : one per set;
    rms_mm : the largest of the sets' RMS radial residuals.
    """
    sets = [np.asarray(p, float)[:, :2] for p in point_sets]
    A = np.zeros((sum(len(P) for P in sets), 2 + len(sets)))
    b = np.concatenate([(P * P).sum(axis=1) for P in sets])
    row = 0
    for i, P in enumerate(sets):  # x^2 + y^2 = 2 a x + 2 b y + k_i
        A[row:row + len(P), :2] = 2 * P
        A[row:row + len(P), 2 + i] = 1.0
        row += len(P)
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    centre = sol[:2]
    radii = tuple(float(np.sqrt(max(k + centre @ centre, 0.0))) for k in sol[2:])
    rms = max(float(np.sqrt(np.mean((np.linalg.norm(P - centre, axis=1) - r) ** 2)))
              for P, r in zip(sets, radii))
    return centre, radii, rms


def base_axis(point_sets) -> tuple[np.ndarray, np.ndarray, float]:
    """The axis that several LEDs at different heights turned about together (a base sweep):
    the line through their circles' centres.

    Each circle is fitted in a horizontal plane (:func:`fit_circle` with the normal z): the
    vision's height error varies along an arc (measured at rig-perturbed seed 2 straight up:
    0.45 mm over +-60 deg, which tilted a freely fitted 12 mm circle's plane by 4 deg and moved
    the axis 8 mm at the shoulder). A horizontal plane leaves the eye frame's tilt (1 deg) to
    the residual. The centres then give the axis' tilt over the height between them.

    Parameters
    ----------
    point_sets : sequence of array-likes, each shape (n, 3), n >= 3: one LED's positions (mm),
        the LEDs at different heights (or a single LED: the axis is then vertical).

    Returns
    -------
    point_mm : (3,), a point on the axis (the mean of the circles' centres); direction : (3,),
    unit, pointing up (z > 0); rms_mm : the largest circle fit's RMS residual.
    """
    fits = [fit_circle(p, (0.0, 0.0, 1.0)) for p in point_sets]
    centres = np.array([f[0] for f in fits])
    point = centres.mean(axis=0)
    direction = np.array([0.0, 0.0, 1.0])
    if len(centres) > 1:
        direction = np.linalg.svd(centres - point, full_matrices=False)[2][0]
        direction *= np.sign(direction[2])
    return point, direction, max(f[3] for f in fits)


def axis_at_height(point_mm, direction, z_mm: float) -> np.ndarray:
    """Where the axis through ``point_mm`` along ``direction`` (not horizontal) is at height
    ``z_mm``, shape (3,)."""
    point, direction = np.asarray(point_mm, float), np.asarray(direction, float)
    return point + direction * (z_mm - point[2]) / direction[2]


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
#: How a failed start-up's line ends.
CANNOT_MEASURE = "; the arm's lengths cannot be measured"


class StartUpFailed(UserError):
    """The start-up measurement saw too few LEDs: the run cannot start (the rig does not see
    the arm, or rejects every look). A user error for ``run``; an outcome of its condition for a
    benchmark sweep, which records it as a run that did not start."""


def _observe(world, feedback, names, where: str, scatter: list) -> dict[str, np.ndarray]:
    """The median of ``SAMPLES_PER_POSE`` observations in which every marker was measured; each
    marker's looks, less their mean, are appended to ``scatter`` (for :func:`look_sigma`)."""
    got: list = []
    why: Counter = Counter()  # why the looks that missed a marker missed it
    for _ in range(MAX_TRIES_PER_POSE):
        m = feedback.observe(world)
        if not any(n in m.missed or not np.all(np.isfinite(m.get(n))) for n in names):
            got.append({n: m.get(n) for n in names})
            if len(got) == SAMPLES_PER_POSE:
                looks = {n: np.array([g[n] for g in got], float) for n in names}
                scatter.extend(v - v.mean(axis=0) for v in looks.values())
                return {n: np.median(v, axis=0) for n, v in looks.items()}
        else:
            why.update({_miss_cause(feedback, n) for n in names if n in m.missed})
    causes = ", ".join(f"{c}: {k} looks" for c, k in why.most_common())
    raise StartUpFailed(f"start-up measurement: the LEDs were measured in only {len(got)} of "
                        f"{MAX_TRIES_PER_POSE} observations {where}"
                        + (f" (missed: {causes})" if causes else "")
                        + CANNOT_MEASURE)


def look_sigma(scatter) -> np.ndarray:
    """One look's standard deviation per axis (x, y, z, mm), pooled over sets of repeated looks,
    each given less its own mean (a set of n looks has n - 1 degrees of freedom). Shape (3,)."""
    dof = sum(len(d) - 1 for d in scatter)
    return np.sqrt(sum((np.asarray(d) ** 2).sum(axis=0) for d in scatter) / dof)


def length_standard_errors(lengths_of, points_mm, sigma_mm) -> np.ndarray:
    """First-order standard errors of lengths measured from points whose coordinates are
    independent with standard deviation ``sigma_mm`` per axis: the gradient of each length by
    central differences (0.001 mm), weighted by the axis' sigma.

    Parameters
    ----------
    lengths_of : function of an array shape (n, 3) (mm) returning the lengths (mm).
    points_mm : array-like, shape (n, 3), where the lengths were measured from.
    sigma_mm : shape (3,), each coordinate's standard deviation along x, y, z.
    """
    P = np.asarray(points_mm, float)
    h = 1e-3
    var = 0.0
    for i, k in np.ndindex(P.shape):
        up, down = P.copy(), P.copy()
        up[i, k] += h
        down[i, k] -= h
        grad = (np.asarray(lengths_of(up)) - np.asarray(lengths_of(down))) / (2 * h)
        var = var + (grad * sigma_mm[k]) ** 2
    return np.sqrt(var)


def _largest_se(lengths_of, points_mm, scatter) -> float:
    """The largest standard error of lengths measured from ``points_mm``, each a median of
    ``SAMPLES_PER_POSE`` looks whose scatter is ``scatter`` (:func:`look_sigma`)."""
    sigma = look_sigma(scatter) * np.sqrt(MEDIAN_VARIANCE)  # a median's, per axis
    return float(length_standard_errors(lengths_of, points_mm, sigma).max())


def _miss_cause(feedback, name: str) -> str:
    """Why ``feedback``'s last look missed marker ``name`` (its cause, not the measured value:
    one entry per cause in the failure's count), naming the option that set the cause where
    one did (``--dropout``, ``--noise-px``), else the rig's part, and for an LED partly hidden
    (not round, or a small blob) the arm's LED stand-off too: a link hides part of an LED that
    stands too close beside it."""
    from .detect import NOT_ROUND
    from .feedback import DROPPED, PARTLY_HIDDEN, RESIDUAL

    obs = getattr(feedback, "last_observation", None)
    cause = obs.causes.get(name, "") if obs is not None else ""
    if cause == DROPPED:
        return f"dropped at random (--dropout {feedback.dropout:g})"
    if cause == RESIDUAL:
        noise = getattr(feedback, "noise_px", 0.0)
        return (f"reprojection residual above {feedback.max_residual_px:g} px"
                + (f" (--noise-px {noise:g})" if noise > 0 else " (check the rig)"))
    if cause in (PARTLY_HIDDEN, NOT_ROUND):  # an LED partly hidden: by the view, or its link
        arm = getattr(feedback, "arm", None)
        hint = ("check the rig" if arm is None else
                f"check the rig, or the arm's led_standoff_mm, {arm.led_standoff_mm:g} mm: "
                "an LED too close beside its link is partly hidden by it")
        if cause == NOT_ROUND:
            return f"{cause} ({hint})"
        return (f"blob area under {feedback.min_area_ratio:g} of expected: partly hidden "
                f"({hint})")
    return f"{cause or 'not measured'} (check the rig)"


def arc_covered_deg(angles_deg) -> float:
    """The arc (deg) that base angles cover: 360 less the widest gap between neighbours on the
    circle (-150..+150 deg in 30 deg steps: 300; -150, -30, +90: 240; one angle: 0)."""
    a = np.sort(np.mod(np.asarray(angles_deg, float), 360.0))
    if len(a) < 2:
        return 0.0
    return float(360.0 - np.max(np.diff(np.append(a, a[0] + 360.0))))


def enough_of_the_sweep(angles_deg) -> bool:
    """Whether the planar base sweep's poses seen at ``angles_deg`` place the base axis
    (:data:`MIN_BASE_POSES`, :data:`MIN_BASE_ARC_DEG`)."""
    return len(angles_deg) >= MIN_BASE_POSES and arc_covered_deg(angles_deg) >= MIN_BASE_ARC_DEG


def sweep_need(seen, n_poses: int, seen_at: str = "the LEDs were seen at") -> str:
    """What the base sweep needs and got (its angles ``seen``), in words (a refusal's)."""
    return (f"the base axis needs {MIN_BASE_POSES} of the sweep's {n_poses} poses covering "
            f"{MIN_BASE_ARC_DEG:g} deg of arc, and {seen_at} {len(seen)}"
            + (f", covering {arc_covered_deg(seen):g} deg" if len(seen) > 1 else ""))


def start_up_poses(arm, start_deg) -> list[tuple[str, np.ndarray, str]]:
    """The poses the start-up measurement looks at, in order: ``(sweep, q_deg, where)`` with
    sweep "base" (the base turned through :data:`BASE_SWEEP_DEG`; planar arms: the other
    joints at ``start_deg``; three-link: leaned, :data:`BASE_SWEEP_POSE_DEG`) or "shoulder"
    (three-link: the shoulder moved through :data:`SHOULDER_SWEEP_DEG` from ``start_deg``),
    and where the arm is, in words (a failed look's message; the visibility check's)."""
    start = np.asarray(start_deg, float)
    if arm.planar:
        return [("base", np.array([q1, *start[1:]]), f"with the base at {q1:+g} deg")
                for q1 in BASE_SWEEP_DEG]
    leaned = f"leaned (q2 {BASE_SWEEP_POSE_DEG[0]:g}, q3 {BASE_SWEEP_POSE_DEG[1]:g} deg)"
    return ([("base", np.array([q1, *BASE_SWEEP_POSE_DEG]),
              f"{leaned} with the base at {q1:+g} deg") for q1 in BASE_SWEEP_DEG]
            + [("shoulder", start + [0.0, rel, 0.0],
                f"with the shoulder moved {rel:+g} deg from the start")
               for rel in SHOULDER_SWEEP_DEG])


def measure_geometry(world, feedback, arm) -> ArmGeometry:
    """Measure the lengths the rules and the Jacobian tracker use, from the LEDs alone.

    Parameters
    ----------
    world : `itg_vision.world.World` at the start pose (left there on return, and when it
        raises).
    feedback : the run's feedback source (its estimates are all this function reads).
    arm : the arm's structure (which joints and markers it has; its lengths are not read).

    Raises
    ------
    StartUpFailed : a marker was not seen (a UserError).
    """
    scatter: list = []
    start = np.array(world.q_deg, float)
    poses = start_up_poses(arm, start)
    looks: dict[str, list] = {"base": [], "shoulder": []}
    seen, unseen = [], []  # base angles (deg) seen; (angle, StartUpFailed) not (planar only)
    try:  # back at the start however it ends: a failed look leaves a sweep's pose otherwise
        for sweep, q, where in poses:
            world.set_q(q)
            try:
                looks[sweep].append(_observe(world, feedback, arm.marker_names, where, scatter))
                seen.append(float(q[0]))
            except StartUpFailed as failed:
                if not arm.planar:
                    raise
                unseen.append((float(q[0]), failed))
        if unseen and not enough_of_the_sweep(seen):
            first = str(unseen[0][1]).removesuffix(CANNOT_MEASURE)
            raise StartUpFailed(f"{first}; {sweep_need(seen, len(poses))}{CANNOT_MEASURE}")
    finally:
        world.set_q(start)
    leds = {n: [m[n] for m in looks["base"]] for n in arm.marker_names}
    if arm.planar:
        return _planar_geometry(arm, leds, scatter, seen, [q1 for q1, _ in unseen], start)
    elbows = [m["elbow"] for m in looks["shoulder"]]
    grippers = [m["gripper"] for m in looks["shoulder"]]

    def lengths_of(p):  # the five elbows, then the five grippers, of the shoulder sweep
        centre, _, radius, _ = fit_circle(p[:5])
        return float(centre[2]), radius, float(np.median([np.linalg.norm(g - e)
                                                          for e, g in zip(p[:5], p[5:])]))

    sweep = np.array(elbows + grippers)
    links = lengths_of(sweep)
    axis_point, axis_dir, axis_rms = base_axis(list(leds.values()))
    centre, normal, _, rms = fit_circle(elbows)
    pitch = turn_about([0.0, 0.0, 1.0], -start[0]) @ rotation_sense_axis(centre, normal, elbows)
    L1 = links[0]
    shoulder = axis_at_height(axis_point, axis_dir, L1)  # the axis as measured, tilt and all
    standoff = float(np.linalg.norm(np.cross(centre - shoulder, axis_dir)))
    return ArmGeometry(links, (float(shoulder[0]), float(shoulder[1]), L1), standoff,
                       "measured: base axis from the LEDs' circles with the arm leaned "
                       f"(q2 {BASE_SWEEP_POSE_DEG[0]:g}, q3 {BASE_SWEEP_POSE_DEG[1]:g} deg) and "
                       f"the base at {BASE_SWEEP_DEG[0]:+g}..{BASE_SWEEP_DEG[-1]:+g} deg; circle "
                       "through the elbow LED with the shoulder moved "
                       f"{SHOULDER_SWEEP_DEG[0]:+g}..{SHOULDER_SWEEP_DEG[-1]:+g} deg; "
                       "|gripper - elbow|", max(rms, axis_rms),
                       _largest_se(lengths_of, sweep, scatter),
                       tuple(float(v) for v in pitch),
                       _elbow_seen(elbows[SHOULDER_SWEEP_DEG.index(0.0)], start))


def _elbow_seen(elbow_mm, q_deg) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``ArmGeometry.elbow_seen``: plain floats."""
    return tuple(float(v) for v in elbow_mm), tuple(float(v) for v in q_deg)


def _planar_geometry(arm, leds: dict, scatter: list, seen, unseen, start) -> ArmGeometry:
    """A planar arm's lengths and base axis from its LEDs' positions in the base sweep
    (:func:`concentric_circles`): L1 the elbow LED's radius (one link: the gripper's), L2 the
    mean of |gripper_xy - elbow_xy| over the sweep (each pose's a median of its looks already,
    so the mean's standard error is one pose's over the square root of their number).
    ``seen`` and ``unseen`` are the sweep's base angles (deg) the LEDs were and were not seen
    at (the source names the latter); ``start`` the joints the sweep started from."""
    names = [m for m in ("elbow", "gripper") if m in arm.marker_names]  # the inner circle first
    points = np.vstack([leds[m] for m in names])  # one LED's sweep after the other

    def lengths_of(p):
        sets = np.split(p, len(names))
        radii = concentric_circles(sets)[1]
        if len(sets) == 1:
            return radii
        return radii[0], float(np.mean(np.linalg.norm(sets[1][:, :2] - sets[0][:, :2], axis=1)))

    what = ("L1 the gripper LED's radius about it" if len(names) == 1 else
            "L1 the elbow LED's radius about it, L2 |gripper_xy - elbow_xy|")
    centre, _, rms = concentric_circles(np.split(points, len(names)))
    i = int(np.argmin(np.abs(wrap_deg(np.subtract(seen, start[0])))))
    arc = f"{seen[0]:+g}..{seen[-1]:+g} deg"
    if unseen:
        arc += (f" ({len(seen)} of {len(seen) + len(unseen)} poses; not seen at "
                f"{', '.join(f'{q1:+g}' for q1 in unseen)} deg)")
    return ArmGeometry(tuple(float(v) for v in lengths_of(points)),
                       (float(centre[0]), float(centre[1]), 0.0),
                       source=f"measured: base axis from the LEDs' circles with the base at "
                              f"{arc}; {what}",
                       residual_mm=rms, length_se_mm=_largest_se(lengths_of, points, scatter),
                       elbow_seen=None if "elbow" not in leds else _elbow_seen(
                           leds["elbow"][i], [seen[i], *start[1:]]))
