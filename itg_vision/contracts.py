"""The types every part of itg_vision speaks: what a feedback source returns, what a controller
reads and returns.

Data flow of one iteration (see ``loop.simulate``)::

    FeedbackSource.observe(world) -> Markers
    Controller.step(desired_mm, markers, q_deg or None) -> Step
    Session.apply(step)            (servo limit, then the world moves)

A controller reads the desired point and the marker estimates. It is given the joint angles
only if it declares ``uses_encoders = True`` (the model-based IK, or a rule base whose rules
read ``q1..qn``); otherwise it gets ``None`` and cannot peek at the encoders.

Units: mm for positions, deg for joint angles and increments.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

#: The markers an arm carries, in the order the rules and the trace name them.
MARKERS = ("gripper", "elbow")


@dataclass(frozen=True)
class Markers:
    """Marker position estimates in mm (world frame), as the controllers see them.

    Attributes
    ----------
    gripper_mm, elbow_mm : shape (3,); NaN where the arm has no such marker.
    missed : markers not measured at this iteration (value held from the last good estimate).
    residual_px : reprojection residual of each triangulated marker (vision only).
    timing_ms : per-stage wall time of this observation (vision only).
    missed_why : marker -> why it was missed, for the markers in ``missed`` (vision: the
        :class:`Observation`'s cause, a fixed phrase); a feedback may leave it empty.
    pitch_axis : three-link, the pitch axis the loop keeps: the start-up's measured shoulder
        axis turned about the vertical by the base's commanded angle, made horizontal and unit,
        shape (3,) with z = 0 (:class:`itg_vision.loop.Session`'s ``pitch_axis_mm``). The LEDs
        alone tell its direction but not always its sign; the loop's copy cannot flip. None:
        not kept (planar arms; a feedback's own estimate before the loop adds it).
    """

    gripper_mm: np.ndarray
    elbow_mm: np.ndarray
    missed: tuple[str, ...] = ()
    residual_px: dict[str, float] = field(default_factory=dict)
    timing_ms: dict[str, float] = field(default_factory=dict)
    missed_why: dict[str, str] = field(default_factory=dict)
    pitch_axis: np.ndarray | None = None

    def get(self, name: str) -> np.ndarray:
        """The estimate of marker ``name`` (one of :data:`MARKERS`), shape (3,) mm."""
        if name == "gripper":
            return self.gripper_mm
        if name == "elbow":
            return self.elbow_mm
        raise KeyError(f"unknown marker {name!r} (markers: {', '.join(MARKERS)})")


@dataclass(frozen=True)
class Step:
    """A controller's decision at one iteration.

    Attributes
    ----------
    dq_deg : (n_joints,) joint increments (deg), before the servo limit. The loop applies them
        as given (under the servo limit), out of reach or not: a controller that holds the arm
        at a set point it judges out of reach returns zeros, as the rule bases and IK do.
    fired : numbers of the rules that fired (rule bases; empty for other controllers).
    out_of_reach : the controller judges the set point out of reach (counted in ``n_flagged``).
    """

    dq_deg: np.ndarray
    fired: tuple[int, ...] = ()
    out_of_reach: bool = False


@dataclass(frozen=True)
class Observation:
    """One look of the stereo eye: what :meth:`itg_vision.feedback.VisionFeedback.observe` saw and decided.

    Attributes
    ----------
    markers : the eye's estimates (held values for missed markers; ``run``'s loop gives its
        controller the last decision's aim for a missed gripper, but an open-loop one's:
        :data:`itg_vision.loop.AIM_ON_LOST`).
    patches : marker -> per camera the image the LED was looked for in: a window around it,
        or the whole frame (``--full-frame``, ``--video``); None where the LED's window falls
        outside the frame. Whole frames are shared between markers unless strobing.
    detections : marker -> per camera the `itg_vision.detect.Detection` (raw centroid in the
        captured image, undistorted centroid, blob area, reason).
    residual_px : marker -> RMS reprojection residual of its triangulation (markers that were
        triangulated only).
    reasons : marker -> why it was missed at this look, for people ("" if measured).
    timing_ms : wall time of the steps: "render" (capture: render, distort, noise), "detect",
        "triangulate".
    causes : marker -> why it was missed, one of a fixed set of phrases for code to branch on
        (`itg_vision.detect.Detection.cause`'s, or ``itg_vision.feedback``'s ``RESIDUAL``,
        ``PARTLY_HIDDEN``); "" if measured.
    """

    markers: Markers
    patches: dict
    detections: dict
    residual_px: dict
    reasons: dict
    timing_ms: dict
    causes: dict = field(default_factory=dict)

    def frames(self) -> tuple[np.ndarray, ...] | None:
        """The whole frames of both cameras (the first marker's when strobing), or None if
        only windows were captured."""
        for ps in self.patches.values():
            if all(p is not None and p.full_frame for p in ps):
                return tuple(p.image for p in ps)
            return None
        return None


@runtime_checkable
class Controller(Protocol):
    """Anything that turns a desired point and marker estimates into joint increments.

    The tracking loop (:func:`itg_vision.loop.simulate`) reads ``uses_encoders`` (whether
    :meth:`step` needs the joint angles; else it gets ``None``) and calls :meth:`step`, which
    must return a :class:`Step` with one increment per joint (else a one-line TypeError or
    ValueError). ``params()``: the parameters it runs with, units in their names, which the
    runner records in summaries. ``uses_markers`` (optional, True if absent): False declares an
    open-loop controller that ignores the estimates (the model-based IK), which a look that
    missed the gripper then neither holds nor hands the last aim. The runner, ``run`` and
    ``TrackingEnv`` build their controllers from names (``itg``, ``ik``, ``jacobian``), so a
    controller of your own runs through :func:`~itg_vision.loop.simulate` (README, "Your own
    controller").
    """

    uses_encoders: bool

    def params(self) -> dict: ...

    def step(self, desired_mm: np.ndarray, markers: Markers,
             q_deg: np.ndarray | None) -> Step: ...


@runtime_checkable
class FeedbackSource(Protocol):
    """Where marker estimates come from (model, truth, vision). ``observe(world)`` returns the
    estimates now, a :class:`Markers` (the loop reads only this; anything else is a one-line
    TypeError); ``reset(seed)`` makes its randomness reproducible (the runner calls it, the
    loop does not). ``run`` and ``TrackingEnv`` build their feedback from names (``vision``,
    ``model``, ``truth``): a source of your own runs through :func:`itg_vision.loop.simulate`."""

    name: str

    def reset(self, seed: int | None = None) -> None: ...

    def observe(self, world) -> Markers: ...
