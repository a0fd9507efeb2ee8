"""The hot loop: desired point -> feedback -> controller -> joint step -> world; and the trace.

E_i is the Euclidean distance between the desired point and the *true* gripper after the
iterations of set point i (planar arms: in the x-y plane). E_av is their mean over the set
points in reach (the paper's definition; out-of-reach points are counted and skipped). A set
point is in reach when the simulated arm (its true links) can reach it: the same set points for
every controller, whatever a controller flags out of reach from the links it measured or was
given (a rule base's RULE 0). A flagged set point that the arm can reach counts, with the error
the controller left there. "Can reach" allows :data:`itg_vision.arm.REACH_TOL_MM` on the radius,
the paper's reach tolerance.

:class:`Session` is the one place where a run advances: it observes through the feedback,
applies a joint step under the servo limit and records each finished set point in the
:class:`Trace`. :func:`simulate` drives it with a controller; :class:`itg_vision.env.TrackingEnv`
drives the same session with a user's actions.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from .contracts import MARKERS, Controller, Markers, Step
from .errors import UserError
from .identify import turn_about
from .inputs import is_real, is_whole
from .outputs import unsigned_zero

#: The marker whose lost look (the feedback then hands on its last estimate) the loop answers
#: with the last decision's aim: the gripper is taken to be where that decision asked it to go.
#: The error d - g is what a step answers, and the last estimate's error was answered by the
#: step before: deciding on it again repeated that step open-loop, once per lost look (under
#: 4 px noise the eye rejects about 1 LED detection in 3); holding the joints instead lagged a
#: set point. At the aim, only the set point's own motion since then is answered (measured in
#: docs/robustness.md, "Lost looks"). Before the first decision there is no aim: the joints
#: hold. After a step flagged out of reach (it holds the arm) the gripper is taken to be where
#: that decision saw it. An open-loop controller (``uses_markers = False``: IK) reads no
#: estimate and is neither held nor given the aim (unless a correction < 1 makes its aim read
#: the gripper). A lost elbow: see :class:`Session`'s ``base_axis_mm`` and ``pitch_axis_mm``.
AIM_ON_LOST = "gripper"

#: Why a look missed a marker when its feedback did not say (``Markers.missed_why`` empty).
NOT_SAID = "not said by the feedback"

#: A run "diverged" when the median E_i of its tracking phase exceeds this (mm): 10 % of the
#: two- and three-link arms' 200 mm reach (a line, not a gap in the data: README, "Diverged runs").
DIVERGED_MM = 20.0

_UP = np.array([0.0, 0.0, 1.0])  # the vertical base axis's direction


def aim_mm(desired_mm, previous_mm, gripper_mm, correction: float, planar: bool) -> np.ndarray:
    """Where the controller is asked to go: the set point, less ``1 - correction`` of the error
    measured now against the previous decision's set point (``previous_mm``).

    ``correction`` = 1 (the default everywhere): the set point itself. Below 1 the set point's
    own motion is fed forward whole while the error left behind is corrected by that fraction
    only; the arm integrates the measurements, so the true error obeys
    ``e_k = (1 - correction) e_(k-1) - correction n_k`` (n: the eye's error): the eye's noise
    reaches the gripper scaled by ``correction`` (variance ``correction / (2 - correction)`` of
    the eye's), while an error of the controller's own step takes ``1 / correction`` steps to
    correct. With several iterations per set point, its later iterations measure against the
    set point itself. ``previous_mm`` None (the first decision) or an unmeasured gripper: the
    set point. Planar arms: x and y only (z is the LED's stand-off, not an error).
    :func:`simulate` judges reach on the set point, never on the aim: a rule base that finds
    the aim out of reach is asked again with the set point itself.
    """
    desired = np.asarray(desired_mm, float)
    if previous_mm is None or correction == 1.0:
        return desired
    left = np.asarray(previous_mm, float) - np.asarray(gripper_mm, float)
    if planar:
        left[2] = 0.0
    if not np.all(np.isfinite(left)):
        return desired
    return desired - (1.0 - correction) * left


def distance_mm(a, b, planar: bool):
    """|a - b| in the plane (x, y) for a planar arm, in space otherwise (mm): a float for two
    points, an array for two arrays of points (..., 3)."""
    d = np.asarray(a, float) - np.asarray(b, float)
    e = np.linalg.norm(d[..., :2] if planar else d, axis=-1)
    return float(e) if e.ndim == 0 else e


@dataclass(frozen=True)
class SetPointRecord:
    """What one set point left behind (mm, deg).

    Attributes
    ----------
    desired_mm : (3,) the set point.
    aim_mm : (3,) where the controller was asked to go at the set point's last iteration: the set
        point, unless a correction or a preview moved it (see :func:`simulate`).
    estimate : the marker estimates the controller used at the set point's last iteration.
    true_at_estimate_mm : {"gripper", "elbow"} -> (3,): the simulator's truth at that instant.
    true_after_mm : {"gripper", "elbow"} -> (3,): the truth after the set point's iterations
        (E_i uses it).
    q_deg : (n_joints,) commanded joint angles after the iterations.
    fired : rules fired over the iterations (first firing order).
    flags : "out_of_reach", "aim_out_of_reach" (the controller flagged the aim out of reach and
        was asked again with the set point), "missed:<marker>", "at_last_aim" (a look missed the
        gripper: the controller was given the last decision's aim for it, :data:`AIM_ON_LOST`),
        "held" (the same before the first decision: the joints held for that iteration),
        "elbow_turned" (a look missed the elbow: its last measured position turned with the
        joints was used, :class:`Session`'s ``base_axis_mm`` and ``pitch_axis_mm``).
    out_of_reach : whether the controller flagged the set point out of reach.
    in_reach : whether the simulated arm can reach the set point (the metrics count it).
    """

    desired_mm: np.ndarray
    aim_mm: np.ndarray
    estimate: Markers
    true_at_estimate_mm: dict
    true_after_mm: dict
    q_deg: np.ndarray
    fired: tuple[int, ...]
    flags: tuple[str, ...]
    out_of_reach: bool
    in_reach: bool


@dataclass
class Trace:
    """Everything recorded along a run: one :class:`SetPointRecord` per set point, and per
    observation the estimation error and the stage timings.

    Per set point: the desired point; the estimate the controller used at the set point's last
    iteration (``*_est_mm``) beside the simulator's truth at the same instant (``*_true_mm``:
    compare these two for the estimation error); the truth after the set point's iterations
    (``*_after_mm``: E_i uses it); joints, rules fired, flags.
    """

    planar: bool
    n_joints: int
    tracking_start: int = 0
    records: list[SetPointRecord] = field(default_factory=list)
    est_err_mm: dict = field(default_factory=lambda: {m: [] for m in MARKERS})
    #: looks that missed each marker, by cause: marker -> {why (the feedback's
    #: ``missed_why``): looks} (:attr:`missed_by` and :attr:`n_missed` are its sums)
    missed_why: dict = field(default_factory=lambda: {m: {} for m in MARKERS})
    n_at_last_aim: int = 0
    n_held: int = 0
    #: looks whose missed elbow was turned with the joints (:class:`Session`'s ``base_axis_mm``,
    #: ``pitch_axis_mm``)
    n_elbow_turned: int = 0
    timing_ms: dict = field(default_factory=dict)
    #: the largest joint increment applied in one iteration (deg, after the servo limit), its
    #: joint and set point (k, as trace.csv numbers them): a run can say that a step turned a
    #: joint a full turn
    largest_step: tuple[float, int, int] = (0.0, 0, 0)

    @property
    def missed_by(self) -> dict[str, int]:
        """Looks that missed each marker, whatever the cause."""
        return {m: sum(why.values()) for m, why in self.missed_why.items()}

    @property
    def n_missed(self) -> int:
        """LED detections missed, all markers."""
        return sum(self.missed_by.values())

    def record(self, rec: SetPointRecord) -> None:
        self.records.append(rec)

    def observed(self, estimate: Markers, truth: dict) -> None:
        """One observation: its timings, missed markers and error against the truth it saw."""
        for stage, ms in estimate.timing_ms.items():
            self.time(stage, ms)
        for name in estimate.missed:
            why = self.missed_why.setdefault(name, {})
            cause = estimate.missed_why.get(name) or NOT_SAID
            why[cause] = why.get(cause, 0) + 1
        for name, out in self.est_err_mm.items():
            if name in estimate.missed:
                continue
            err = float(np.linalg.norm(estimate.get(name) - truth[name]))
            if np.isfinite(err):
                out.append(err)

    def time(self, stage: str, ms: float) -> None:
        self.timing_ms.setdefault(stage, []).append(float(ms))

    # ------------------------------------------------------------------ arrays
    @property
    def desired_mm(self) -> np.ndarray:
        """Set points, shape (n, 3)."""
        return np.array([r.desired_mm for r in self.records]).reshape(-1, 3)

    @property
    def gripper_mm(self) -> np.ndarray:
        """True gripper after each set point's iterations, shape (n, 3)."""
        return np.array([r.true_after_mm["gripper"] for r in self.records]).reshape(-1, 3)

    @property
    def elbow_mm(self) -> np.ndarray:
        return np.array([r.true_after_mm["elbow"] for r in self.records]).reshape(-1, 3)

    @property
    def q_deg(self) -> np.ndarray:
        return np.array([r.q_deg for r in self.records]).reshape(-1, self.n_joints)

    @property
    def fired(self) -> list[tuple[int, ...]]:
        return [r.fired for r in self.records]

    @property
    def out_of_reach(self) -> np.ndarray:
        """Whether the controller flagged each set point out of reach, shape (n,)."""
        return np.array([r.out_of_reach for r in self.records], bool)

    @property
    def in_reach(self) -> np.ndarray:
        """Whether the simulated arm can reach each set point (the metrics count these),
        shape (n,)."""
        return np.array([r.in_reach for r in self.records], bool)

    @property
    def aim_mm(self) -> np.ndarray:
        """Where the controller was asked to go at each set point's last iteration, shape (n, 3)."""
        return np.array([r.aim_mm for r in self.records]).reshape(-1, 3)

    def error_mm(self) -> np.ndarray:
        """E_i per set point, shape (n,)."""
        return distance_mm(self.desired_mm, self.gripper_mm, self.planar)

    def tracking_errors_mm(self) -> np.ndarray:
        """E_i over the tracking phase (from ``tracking_start``), set points in reach only."""
        k = self.tracking_start
        return self.error_mm()[k:][self.in_reach[k:]]

    def metrics(self) -> dict:
        """E_av, E_max, E_rms over the set points in reach (the paper's metric, start transient
        included), and the tracking phase's median, mean, 95th percentile and max;
        ``diverged``: that median is above :data:`DIVERGED_MM` (None without a tracking phase).
        ``n_out_of_reach``: set points the simulated arm cannot reach (left out of them all);
        ``n_flagged``: set points the controller flagged out of reach; ``n_missed_by``: looks that
        missed each marker (their sum is ``n_missed``), ``n_missed_why`` the same by cause,
        the most frequent first; ``n_aim_out_of_reach``:
        set points whose aim (moved by a correction or a preview) the controller flagged, and
        was asked again with the set point."""
        e = self.error_mm()
        ok = self.in_reach
        ein = e[ok]
        late = self.tracking_errors_mm()
        median = float(np.median(late)) if late.size else None

        def stat(fn, v):
            return float(fn(v)) if v.size else None

        def rms(v):
            v = np.asarray(v, float)
            v = v[np.isfinite(v)]
            return float(np.sqrt(np.mean(v**2))) if v.size else None

        return {
            "e_av_mm": stat(np.mean, ein),
            "e_max_mm": stat(np.max, ein),
            "e_rms_mm": rms(ein),
            "tracking_from": int(self.tracking_start),
            "track_median_mm": median,
            "track_mean_mm": stat(np.mean, late),
            "track_p95_mm": stat(lambda v: np.percentile(v, 95), late),
            "track_max_mm": stat(np.max, late),
            "diverged": None if median is None else median > DIVERGED_MM,
            "n_setpoints": int(len(e)),
            "n_out_of_reach": int((~ok).sum()),
            "n_flagged": int(self.out_of_reach.sum()),
            "n_aim_out_of_reach": sum("aim_out_of_reach" in r.flags for r in self.records),
            "n_missed": int(self.n_missed),
            "n_missed_by": {m: int(v) for m, v in self.missed_by.items()},
            "n_missed_why": {m: dict(sorted(why.items(), key=lambda kv: (-kv[1], kv[0])))
                             for m, why in self.missed_why.items()},
            "n_at_last_aim": int(self.n_at_last_aim),
            "n_held": int(self.n_held),
            "n_elbow_turned": int(self.n_elbow_turned),
            "est_gripper_rms_mm": rms(self.est_err_mm["gripper"]),
            "est_elbow_rms_mm": rms(self.est_err_mm["elbow"]),
            "timing_ms": {k: float(np.median(v)) for k, v in self.timing_ms.items() if v},
        }

    def rows(self) -> tuple[list[str], list[list]]:
        """The trace as CSV columns and rows (units in the column names)."""
        qcols = [f"q{i}_deg" for i in range(1, self.n_joints + 1)]
        xyz = ("x", "y", "z")
        groups = [("d", "", lambda r: r.desired_mm), ("a", "", lambda r: r.aim_mm)]
        for m, name in (("g", "gripper"), ("e", "elbow")):
            groups += [(m, "_est", lambda r, n=name: r.estimate.get(n)),
                       (m, "_true", lambda r, n=name: r.true_at_estimate_mm[n]),
                       (m, "_after", lambda r, n=name: r.true_after_mm[n])]
        cols = (["k", "tracking", "in_reach"] + [f"{a}{m}{s}_mm" for m, s, _ in groups for a in xyz]
                + qcols + ["e_mm", "rules_fired", "flags"])
        e = self.error_mm()
        out = []
        for k, r in enumerate(self.records):
            vals = [k, int(k >= self.tracking_start), int(r.in_reach)]
            for _, _, get in groups:
                vals += [_fmt(v) for v in get(r)]
            vals += [_fmt(v) for v in r.q_deg]
            vals += [_fmt(e[k]), ";".join(str(n) for n in r.fired), ";".join(r.flags)]
            out.append(vals)
        return cols, out


def _fmt(v) -> str:
    """A trace value at 4 decimals; one that rounds to zero is "0.0000", never "-0.0000"."""
    v = float(v)
    return "" if not np.isfinite(v) else unsigned_zero(f"{v:.4f}")


def _checked(step):
    """``step`` if it is a :class:`Step`, else a one-line TypeError (the controller contract)."""
    if not isinstance(step, Step):
        raise TypeError(f"controller.step must return itg_vision.contracts.Step, got "
                        f"{type(step).__name__}")
    return step


def _shown(value) -> str:
    """A wrong value's type, and the offending positions or ``missed`` and ``missed_why`` if
    that is what is wrong."""
    if isinstance(value, Markers):
        shapes = [f"{m}_mm of shape {np.shape(value.get(m))}" for m in MARKERS
                  if np.shape(value.get(m)) != (3,)]
        return "Markers with " + (", ".join(shapes) if shapes else
                                  f"missed={value.missed!r}, missed_why={value.missed_why!r}")
    return type(value).__name__


def _is_markers(value) -> bool:
    """Whether a feedback source's ``observe`` kept the contract: positions of shape (3,), and
    ``missed`` a tuple of marker names, ``missed_why`` a dict of phrases."""
    return (isinstance(value, Markers) and isinstance(value.missed, tuple)
            and all(m in MARKERS for m in value.missed)
            and isinstance(value.missed_why, dict)
            and all(isinstance(w, str) for w in value.missed_why.values())
            and all(np.shape(value.get(m)) == (3,) for m in MARKERS))


class Session:
    """One tracking run in progress: where the loop and the Gymnasium environment meet.

    Call :meth:`observe` (what the controller may see), then :meth:`apply` with the joint step;
    after ``iterations`` such steps the set point is recorded in :attr:`trace` and the next one
    becomes :attr:`desired_mm`. ``world.true_markers()`` is read for evaluation only (E_i, the
    estimation error), never handed to the controller.

    Parameters
    ----------
    world : `itg_vision.world.World`.
    feedback : a feedback source (``observe(world) -> Markers``).
    points_mm : shape (n, 3), the set points.
    iterations : steps per set point.
    planar : E_i in the x-y plane; None (the default): the world's arm's (``world.arm.planar``),
        the only value accepted.
    max_step_deg : the servo rate limit: no joint moves more per iteration, whatever the
        controller (None: no limit).
    tracking_start : first set point of the tracking phase (default: the second half).
    base_axis_mm : (x, y), the base's axis as measured (planar arms only). A look that misses
        the elbow then gives its last measured position turned about that axis by the base's
        commanded turn since, where a planar arm's elbow is (it moves with q1 alone), flagged
        ``elbow_turned``. None (the default): the feedback's last elbow estimate, however old;
        an elbow out of view for a stretch (on a branch the rig does not frame) then misled
        every controller: ITG+ max 102 mm, the Jacobian tracker 79 (README, "Arms").
    pitch_axis_mm : ``(shoulder_mm, direction)``, the three-link arm's shoulder axis as measured
        (:attr:`itg_vision.identify.ArmGeometry.pitch_axis`): a point on it, the shoulder on
        the vertical base axis (mm), and its unit direction with the base at its commanded
        0 deg (the right-hand rule of a positive q2 step). A look that misses the elbow then
        gives its last measured position turned about the shoulder axis (as the base had
        turned it then) by the shoulder's commanded turn since, and about the vertical base
        axis through the shoulder by the base's: where a three-link arm's elbow is (it moves
        with q1 and q2 alone), flagged ``elbow_turned``. Every look also carries the pitch
        axis the loop keeps from it (:meth:`kept_pitch_axis`). None (the default): the
        feedback's last estimate, and no kept axis.
    elbow_seen : ``(elbow_mm, q_deg)``, an elbow measured before the session and the commanded
        joints then (the start-up's: :attr:`itg_vision.identify.ArmGeometry.elbow_seen`), with
        ``base_axis_mm`` or ``pitch_axis_mm``: a look that misses the elbow before the session
        has seen it is turned from there. None: such a look gives the feedback's last estimate
        (after the start-up, from the last pose of its sweep).
    progress : called with 1 when a set point is done.
    recorder : optional video recorder (``frame(feedback, desired_mm, label)`` per set point, labelled ``k N`` as trace.csv).
    rules_at : ``rules_at(numbers) -> str``, where the rules of those numbers are (a rule base's
        :meth:`~itg_vision.rules.RuleBase.rules_at`: ``FILE:LINE``), for the one error a step
        can cause here (a joint angle overflowing); None: the numbers alone.
    """

    def __init__(self, world, feedback, points_mm, *, iterations: int = 1, planar: bool | None = None,
                 max_step_deg: float | None = None, tracking_start: int | None = None,
                 base_axis_mm=None, pitch_axis_mm=None, elbow_seen=None,
                 progress: Callable[[int], None] | None = None, recorder=None,
                 rules_at: Callable[[tuple[int, ...]], str] | None = None):
        self.world = world
        self.feedback = feedback
        points = np.asarray(points_mm, float)
        if points.ndim != 2 or points.shape[1] != 3 or not len(points):
            # (n, 2) x, y pairs were read three numbers at a time, as other points
            raise ValueError(f"points_mm: shape (n, 3) expected (x, y, z in mm; z = 0 for a "
                             f"planar arm), got shape {points.shape}")
        if not np.isfinite(points).all():
            i = int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
            raise ValueError(f"points_mm: set point {i + 1} is not finite: {points[i].tolist()}")
        self.points_mm = points
        if not (is_whole(iterations) and iterations >= 1):
            raise ValueError(f"iterations must be a whole number >= 1, got {iterations!r}")
        if max_step_deg is not None and not (is_real(max_step_deg) and max_step_deg > 0):
            raise ValueError(f"max_step_deg must be a finite number > 0 (deg) or None for no "
                             f"limit, got {max_step_deg!r}")  # 0 used to mean no limit
        if planar is None:
            planar = world.arm.planar
        elif bool(planar) != world.arm.planar:  # a three-link run measured in x-y looks fine
            raise ValueError(f"planar={planar!r}, but arm {world.arm.name} is "
                             f"{'' if world.arm.planar else 'not '}planar (leave planar out)")
        self.planar = bool(planar)
        # a lost elbow turns about the vertical base axis through _pivot (planar: the base axis
        # at z = 0; three-link: the shoulder), and about the shoulder's axis, _pitch at q1 = 0
        self._pivot: np.ndarray | None = None
        self._pitch: np.ndarray | None = None
        if base_axis_mm is not None:
            if not self.planar:  # its elbow moves with q2 too, about an axis that turns with q1
                raise ValueError(f"base_axis_mm turns a planar arm's lost elbow; arm "
                                 f"{world.arm.name} is not planar (give pitch_axis_mm)")
            base_axis_mm = np.asarray(base_axis_mm, float)
            if base_axis_mm.shape != (2,) or not np.isfinite(base_axis_mm).all():
                raise ValueError(f"base_axis_mm: (x, y) in mm expected, got {base_axis_mm!r}")
            self._pivot = np.array([*base_axis_mm, 0.0])
        if pitch_axis_mm is not None:
            if self.planar or world.arm.n_joints != 3:
                raise ValueError(f"pitch_axis_mm turns a three-link arm's lost elbow; arm "
                                 f"{world.arm.name} is not one (give base_axis_mm)")
            point, direction = (np.asarray(v, float) for v in pitch_axis_mm)
            if (point.shape != (3,) or direction.shape != (3,)
                    or not np.isfinite([*point, *direction]).all()
                    or not abs(np.linalg.norm(direction) - 1.0) < 1e-6
                    or not np.hypot(*direction[:2]) >= 0.5):  # a shoulder axis is horizontal
                raise ValueError(f"pitch_axis_mm: (shoulder (x, y, z) in mm, unit direction "
                                 f"within 60 deg of horizontal) expected, got {pitch_axis_mm!r}")
            self._pivot, self._pitch = point, direction
        self._elbow_seen: tuple[np.ndarray, np.ndarray] | None = None  # and the joints then
        if elbow_seen is not None:
            elbow, q = (np.asarray(v, float) for v in elbow_seen)
            if (elbow.shape != (3,) or q.shape != (world.arm.n_joints,)
                    or not np.isfinite([*elbow, *q]).all()):
                raise ValueError(f"elbow_seen: (elbow (x, y, z) in mm, the {world.arm.n_joints} "
                                 f"joint angles in deg) expected, got {elbow_seen!r}")
            self._elbow_seen = (elbow, q)
        self.iterations = int(iterations)
        self.max_step_deg = max_step_deg
        self.progress = progress
        self.recorder = recorder
        self.rules_at = rules_at
        n = len(self.points_mm)
        if tracking_start is not None and not (is_whole(tracking_start)
                                               and 0 <= tracking_start < n):
            # -1 measured the tracking phase on the last set point alone, 2.7 from the third
            raise ValueError(f"tracking_start must be a whole number in 0..{n - 1} (the index of "
                             f"a set point), got {tracking_start!r}")
        self.trace = Trace(self.planar, world.arm.n_joints,
                           n // 2 if tracking_start is None else int(tracking_start))
        self.k = 0
        self.last_error_mm = float("nan")
        self._iteration = 0
        self._estimate: Markers | None = None
        self._aim: np.ndarray | None = None
        self._seen: dict | None = None
        self._fired: list[int] = []
        self._flags: list[str] = []
        self._oor = False

    @property
    def done(self) -> bool:
        return self.k >= len(self.points_mm)

    @property
    def desired_mm(self) -> np.ndarray:
        """The current set point, shape (3,) (the last one once done)."""
        return self.points_mm[min(self.k, len(self.points_mm) - 1)]

    def observe(self) -> Markers:
        """The feedback's estimate of the markers now (the controller's only view)."""
        self._seen = self.world.true_markers()  # evaluation only
        self._estimate = self.feedback.observe(self.world)
        if not _is_markers(self._estimate):  # (2,) x, y broke deep in the trace's arithmetic
            raise TypeError("feedback.observe must return itg_vision.contracts.Markers (positions "
                            "of shape (3,), mm; missed: a tuple of marker names; "
                            "missed_why: a dict, marker -> phrase), got "
                            f"{_shown(self._estimate)}")
        self.trace.observed(self._estimate, self._seen)
        for m in self._estimate.missed:
            self.flag(f"missed:{m}")
        self._estimate = self._elbow_on_lost(self._estimate)
        if self._pitch is not None:
            self._estimate = replace(self._estimate, pitch_axis=self.kept_pitch_axis())
        return self._estimate

    def kept_pitch_axis(self) -> np.ndarray | None:
        """Three-link: the pitch axis the loop keeps, given to the controllers with each look
        (:attr:`itg_vision.contracts.Markers.pitch_axis`): ``pitch_axis_mm``'s direction turned
        about the vertical by the base's commanded angle, made horizontal and unit, shape (3,).
        The LEDs tell the axis's direction at most poses, but its sign only from which side of
        the base axis their line passes, 12 mm off, and under 4 px that sign was wrong at a
        median 6.7 % of reach-loop's decisions (docs/robustness.md): every pitch step then
        turns the wrong way. This copy cannot flip. None without ``pitch_axis_mm``."""
        if self._pitch is None:
            return None
        a = self._pitch_at(self.world.q_deg[0])
        a[2] = 0.0
        return a / np.linalg.norm(a)

    def _pitch_at(self, q1_deg: float) -> np.ndarray:
        """``pitch_axis_mm``'s direction with the base at commanded angle ``q1_deg``: turned
        about the vertical with it."""
        return turn_about(_UP, q1_deg) @ self._pitch

    def _elbow_on_lost(self, estimate: Markers) -> Markers:
        """``estimate`` with a missed elbow turned with the joints since it was last seen (see
        ``base_axis_mm``, ``pitch_axis_mm``); the angles are the ones the loop commanded."""
        if self._pivot is None:  # nothing to turn: no copy per look
            return estimate
        q = np.array(self.world.q_deg, float)
        if "elbow" not in estimate.missed:
            self._elbow_seen = (np.array(estimate.elbow_mm, float), q)
            return estimate
        if self._elbow_seen is None:
            return estimate
        elbow, q_then = self._elbow_seen
        self.trace.n_elbow_turned += 1
        self.flag("elbow_turned")
        return replace(estimate, elbow_mm=self._turned(elbow, q_then, q))

    def _turned(self, elbow: np.ndarray, q_then: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Where ``elbow``, seen at joints ``q_then``, is at ``q``: turned about the shoulder's
        axis (as the base had turned it at ``q_then``) by q2's turn since, then about the
        vertical base axis by q1's. Both axes pass through the shoulder, so the order is
        immaterial as long as the shoulder's axis is the one of ``q_then``."""
        turn = turn_about(_UP, q[0] - q_then[0])  # q1 turns the arm counter-clockwise from above
        if self._pitch is not None:
            pitch_then = self._pitch_at(q_then[0])
            turn = turn @ turn_about(pitch_then, q[1] - q_then[1])
        return self._pivot + turn @ (elbow - self._pivot)

    def flag(self, name: str) -> None:
        """Add ``name`` to the current set point's flags (once)."""
        if name not in self._flags:
            self._flags.append(name)

    def apply(self, step: Step, decide_ms: float | None = None,
              aim_mm: np.ndarray | None = None) -> float:
        """Move the joints by ``step.dq_deg`` (clipped to the servo limit); return E_i (mm)
        after the move. Records the set point after its last iteration. ``aim_mm``: where the
        controller was asked to go (None: the set point), for the trace."""
        if self.done:
            raise RuntimeError("the trajectory is finished")
        if decide_ms is not None:
            self.trace.time("rules", decide_ms)
        raw = np.asarray(_checked(step).dq_deg)
        # as the env's actions: "1" or True read as 1 deg, and 1+1j as 1 deg with a warning
        if raw.shape != (self.world.arm.n_joints,) or raw.dtype.kind not in "iuf":
            raise ValueError(f"Step.dq_deg: {self.world.arm.n_joints} real joint increments (deg) "
                             f"expected, got shape {raw.shape} of {raw.dtype}")
        dq = raw.astype(float)
        if self.max_step_deg is not None:
            dq = np.clip(dq, -self.max_step_deg, self.max_step_deg)
        j = int(np.argmax(np.abs(dq)))
        if abs(dq[j]) > self.trace.largest_step[0]:  # NaN: the check below stops the run
            self.trace.largest_step = (float(abs(dq[j])), j + 1, self.k)
        # in Python floats: an overflow is inf without a warning (finite steps whose sum is not:
        # rules like q1 += q1), and the check costs what set_q's own does
        q = [a + b for a, b in zip(self.world.q_deg.tolist(), dq.tolist())]
        if not all(map(math.isfinite, q)):
            j = next(j for j, v in enumerate(q) if not math.isfinite(v))
            fired = "" if not step.fired else "; rules fired: " + (
                self.rules_at(step.fired) if self.rules_at else ", ".join(map(str, step.fired)))
            fix = ("the controller's step is not a number (NaN): the step itself is wrong"
                   if math.isnan(dq[j]) else "bound each step with the servo limit "
                   "(max_step_deg; run's --max-step)")
            raise UserError(f"set point k = {self.k}: joint q{j + 1} would turn to {q[j]} deg (from "
                            f"{self.world.q_deg[j]:.6g} by {dq[j]:.6g}{fired}): no joint angle is "
                            f"that; {fix}")
        self.world.set_q(q)
        self._aim = self.desired_mm.copy() if aim_mm is None else np.asarray(aim_mm, float).copy()
        self._fired += [r for r in step.fired if r not in self._fired]
        self._oor |= bool(step.out_of_reach)
        truth = self.world.true_markers()
        self.last_error_mm = distance_mm(self.desired_mm, truth["gripper"], self.trace.planar)
        self._iteration += 1
        if self._iteration == self.iterations:
            self._finish_set_point(truth)
        return self.last_error_mm

    def assume_gripper_at(self, aim_mm) -> Markers:
        """The look missed the gripper (:data:`AIM_ON_LOST`): take it to be at ``aim_mm``, the
        last decision's aim, or where it saw the gripper if it flagged its set point out of reach
        (planar arms: x and y; the height is the LED's stand-off, kept).
        Flagged ``at_last_aim``, counted in the trace's ``n_at_last_aim``; return the estimate
        the controller is to use, recorded as the one it used."""
        g = np.asarray(aim_mm, float).copy()
        if self.planar:
            g[2] = self._estimate.gripper_mm[2]
        self._estimate = replace(self._estimate, gripper_mm=g)
        self.trace.n_at_last_aim += 1
        self.flag("at_last_aim")
        return self._estimate

    def hold(self) -> float:
        """Keep the joints where they are for this iteration (the look missed the gripper
        before any decision had an aim: :data:`AIM_ON_LOST`), flagged ``held`` and counted in
        the trace's ``n_held``; return E_i (mm) as :meth:`apply` does."""
        self.trace.n_held += 1
        self.flag("held")
        return self.apply(Step(np.zeros(self.world.arm.n_joints)))

    def _finish_set_point(self, truth: dict) -> None:
        if self.recorder is not None:
            self.recorder.frame(self.feedback, self.desired_mm, label=f"k {self.k}")
        flags = (["out_of_reach"] if self._oor else []) + self._flags
        estimate = self._estimate if self._estimate is not None else Markers(
            np.full(3, np.nan), np.full(3, np.nan), tuple(truth))
        self.trace.record(SetPointRecord(
            self.desired_mm.copy(), self._aim, estimate, self._seen or truth, truth,
            self.world.q_deg.copy(), tuple(self._fired), tuple(flags), self._oor,
            self.world.arm.reachable(self.desired_mm)))
        self.k += 1
        self._iteration = 0
        self._fired, self._flags, self._oor = [], [], False
        if self.progress is not None:
            self.progress(1)


def simulate(world, controller: Controller, feedback, points_mm: np.ndarray, *,
             iterations: int = 1, planar: bool | None = None, max_step_deg: float | None = None,
             tracking_start: int | None = None, correction: float = 1.0,
             aims_mm: np.ndarray | None = None, base_axis_mm=None, pitch_axis_mm=None,
             elbow_seen=None, progress: Callable[[int], None] | None = None,
             recorder=None) -> Trace:
    """Track ``points_mm`` (shape (n, 3)) with ``controller`` and return the trace.

    See :class:`Session` for the parameters, :func:`aim_mm` for ``correction``. ``aims_mm``
    (shape (n, 3), one per set point; None: the set points): where the controller is asked to go
    instead of the set point (a preview's plan, :mod:`itg_vision.preview`), before the
    correction. E_i is measured from the set point whatever the aim. The loop, top to bottom:
    observe through the feedback, aim, let the controller decide, apply the step under the
    servo limit. A look that did not measure the gripper gives the controller the last
    decision's aim for it, whatever the controller (:data:`AIM_ON_LOST`; after a step flagged
    out of reach, the gripper that decision saw; before the first decision the joints hold), but
    an open-loop one (``uses_markers = False``: IK), which ignores the estimates.
    """
    if not (is_real(correction) and 0 < correction <= 1):  # NaN aimed every decision at NaN
        raise ValueError(f"correction must be a finite number in (0, 1] (the fraction of the "
                         f"measured error corrected per decision), got {correction!r}")
    reads_gripper = getattr(controller, "uses_markers", True) or correction != 1  # aim_mm's
    session = Session(world, feedback, points_mm, iterations=iterations, planar=planar,
                      max_step_deg=max_step_deg, tracking_start=tracking_start,
                      base_axis_mm=base_axis_mm, pitch_axis_mm=pitch_axis_mm,
                      elbow_seen=elbow_seen, progress=progress, recorder=recorder,
                      rules_at=getattr(controller, "rules_at", None))
    if aims_mm is not None:  # one short ran its set points, then failed as an IndexError
        aims_mm = np.asarray(aims_mm, float)
        if aims_mm.shape != session.points_mm.shape or not np.isfinite(aims_mm).all():
            raise ValueError(f"aims_mm: one finite aim per set point, shape "
                             f"{session.points_mm.shape}, expected, got shape {aims_mm.shape}"
                             + ("" if aims_mm.shape != session.points_mm.shape
                                else " with a value that is not finite"))
    previous = None  # the set point (or planned aim) of the previous decision
    last_aim = None
    while not session.done:
        estimate = session.observe()
        desired = session.desired_mm
        # no new error measured (an open-loop controller reads none: it goes on)
        if AIM_ON_LOST in estimate.missed and reads_gripper:
            if last_aim is None:
                session.hold()
                continue
            estimate = session.assume_gripper_at(last_aim)
        target = desired if aims_mm is None else aims_mm[session.k]
        aim = aim_mm(target, previous, estimate.gripper_mm, correction, session.planar)
        previous = target
        t0 = time.perf_counter()
        q_deg = world.q_deg if controller.uses_encoders else None
        step = _checked(controller.step(aim, estimate, q_deg))
        if step.out_of_reach and not np.array_equal(aim, desired):
            session.flag("aim_out_of_reach")  # reach is the set point's, not the aim's: ask again
            aim = desired
            step = _checked(controller.step(aim, estimate, q_deg))
        session.apply(step, decide_ms=1e3 * (time.perf_counter() - t0), aim_mm=aim)
        # a step flagged out of reach aimed at nothing (the rule bases and IK hold the arm there):
        # the arm is where that decision saw it, not at the set point it refused
        last_aim = estimate.gripper_mm if step.out_of_reach else aim
    return session.trace
