"""Feedback sources: where the rules' marker positions come from.

Every source returns the same :class:`Markers`; the rules cannot tell them apart and never see
the world, the model or the encoders.

- :class:`ModelFeedback`: joint encoders + the nominal kinematic model (the paper's classical
  variant). Wrong when the true arm differs from the model.
- :class:`TruthFeedback`: the simulator's marker positions (ideal sensors).
- :class:`VisionFeedback`: render both cameras (windows around the LEDs, or whole frames),
  distort, add noise, detect, triangulate; each look is kept as an :class:`Observation`.
"""

from __future__ import annotations

import math
from time import perf_counter

import numpy as np

from .arm import ArmSpec, forward_kinematics
from .camera import MAX_SUPERSAMPLE
from .contracts import MARKERS, Markers, Observation
from .detect import Detection, locate_led_near
from .imaging import Patch
from .inputs import is_real, is_whole

#: Default supersampling of the vision loop: the most accurate setting that kept the stereo
#: loop at >= 300 Hz on one core (``python -m itg_vision.bench speed`` and ``accuracy``:
#: centroid RMS 0.024 px at s = 3, 0.021 at s = 4, 0.036 at s = 2; s = 3 ran at 276-392 Hz on
#: this project's host over several days, 300-305 Hz on 2026-12-04, s = 4 under 300 Hz).
DEFAULT_SUPERSAMPLE = 3

#: The largest centroid noise (px std) a vision run takes: far beyond any image (every look is
#: already rejected at a 2 px reprojection residual). Past ~1e50 px the triangulation's
#: arithmetic failed (OpenCV's solvePoly, a division by zero): a traceback, not a result.
MAX_NOISE_PX = 1e6
#: The largest noise (mm std per coordinate) truth feedback takes: a kilometre, far beyond any
#: arm. Past ~1e154 mm the start-up's squares overflowed: numpy's warnings, measured lengths of
#: NaN, then a rule's step of inf blamed on the rule file.
MAX_NOISE_MM = 1e6
#: The seed a feedback source is built with, a run's default (``RunConfig.seed``): a loop on a
#: source never reset drew its noise from the OS's entropy, and no two such runs agreed.
SEED = 0


def _in_range(what: str, v, lo: float, hi: float) -> float:
    """``v`` as a finite float in [lo, hi], else a ValueError naming it."""
    if not (is_real(v) and lo <= v <= hi):
        span = f">= {lo:g}" if math.isinf(hi) else f"in [{lo:g}, {hi:g}]"
        raise ValueError(f"{what} must be a finite number {span}, got {v!r}")
    return float(v)


class ModelFeedback:
    """Encoders + nominal model: the commanded joint angles through ``forward_kinematics``."""

    name = "model"

    def __init__(self, model: ArmSpec):
        self.model = model

    def reset(self, seed: int | None = None) -> None:
        pass

    def observe(self, world) -> Markers:
        m = forward_kinematics(self.model, world.q_deg)
        return Markers(m["gripper"], m["elbow"])


def check_full_frames(render_rig, supersample: int) -> None:
    """Refuse whole frames of ``render_rig``'s cameras too large to render at ``supersample``
    (:func:`itg_vision.imaging.check_whole_frame`), before anything renders."""
    from .imaging import check_whole_frame

    for camera in render_rig.cameras:
        check_whole_frame(camera, supersample, ", or windows around the LEDs instead of whole "
                                               "frames")


class TruthFeedback:
    """The simulator's LED positions: ideal sensors, or with seeded Gaussian noise.

    Parameters
    ----------
    noise_mm : std of the noise added to each coordinate of each marker (mm), drawn from the
        generator made by :meth:`reset`; 0 for ideal sensors.

    Built seeded with :data:`SEED` (a run's default seed): a loop on a source never reset
    reproduces, and gives the numbers of ``reset(SEED)``. ``reset(None)``: fresh entropy.
    """

    name = "truth"

    def __init__(self, noise_mm: float = 0.0):
        self.noise_mm = _in_range("TruthFeedback: noise_mm (mm)", noise_mm, 0.0, MAX_NOISE_MM)
        self.reset(SEED)

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def observe(self, world) -> Markers:
        m = world.true_markers()
        if self.noise_mm > 0:
            return Markers(m["gripper"] + self.rng.normal(0.0, self.noise_mm, 3),
                           m["elbow"] + self.rng.normal(0.0, self.noise_mm, 3))
        return Markers(m["gripper"], m["elbow"])


#: Why a marker was missed at the stereo stage (`Observation.causes`; the detection's own
#: causes are `itg_vision.detect`'s): its LED's window fell outside a camera's frame, it was
#: dropped at random (``dropout``), its triangulation's residual was above the gate, or its
#: blob was smaller than expected (partly hidden).
OUTSIDE, DROPPED = "outside the image", "dropped"
RESIDUAL, PARTLY_HIDDEN = "reprojection residual above the gate", "blob smaller than expected"


class VisionFeedback:
    """Stereo vision: render both cameras, distort, add noise, detect, triangulate.

    The images come from the *render* rig (the true cameras); centroids are undistorted and
    triangulated with the *estimate* rig (what the estimator believes, e.g. a calibrated rig).
    :meth:`observe` is three named steps, :meth:`capture_pair`, :meth:`detect` and
    :meth:`triangulate`; the last look is kept in :attr:`last_observation`.

    By default the renderer draws only a window around each LED in each camera (the simulator
    places it, as a renderer knows its scene, with the LED's whole image and 2 px around it;
    see :func:`itg_vision.imaging.capture_window`), in the arm's own scene, so links still
    hide LEDs. The estimator sees only the window's pixels and their offset, and rejects a
    blob that touches the window's border or is partly hidden. ``full_frame`` renders whole
    frames instead (what ``--video`` shows) and searches a window around the last estimate's
    projection first. LEDs are drawn flat (:data:`itg_vision.imaging.FLAT_LIGHT`) and
    centroided with plain intensity weights. The simulator's marker positions are never read
    by the estimation steps.

    Parameters
    ----------
    render_rig : `itg_vision.camera.Rig` used to make the images.
    estimate_rig : `itg_vision.camera.Rig` used to undistort and triangulate.
    arm : the arm spec (only its ``marker_names`` are used).
    noise_px : std of Gaussian noise added to each detected centroid coordinate (px).
    dropout : probability that a marker's detection is dropped at an iteration.
    max_residual_px : reject a triangulated marker whose RMS reprojection residual exceeds it.
    supersample : rendering factor (1 = off), then area-averaged: anti-aliased LED edges.
    strobe : image each LED in its own frame, the others dark (drawn in the arm's colour).
    min_area_ratio : reject a marker whose blob area is below this fraction of the area its
        sphere should cover at the triangulated distance (a partly hidden LED).
    full_frame : render whole frames rather than windows around the LEDs.

    Built seeded with :data:`SEED`, as :class:`TruthFeedback` is.

    Attributes
    ----------
    last_observation : the last :class:`Observation` (None before the first look).
    """

    name = "vision"

    def __init__(self, render_rig, estimate_rig, arm: ArmSpec, *, noise_px: float = 0.0,
                 dropout: float = 0.0, max_residual_px: float = 2.0,
                 supersample: int = DEFAULT_SUPERSAMPLE, strobe: bool = False,
                 min_area_ratio: float = 0.5, full_frame: bool = False):
        from .imaging import FLAT_LIGHT

        self.render_rig = render_rig
        self.estimate_rig = estimate_rig
        self.arm = arm
        self.noise_px = _in_range("VisionFeedback: noise_px", noise_px, 0.0, MAX_NOISE_PX)
        self.dropout = _in_range("VisionFeedback: dropout", dropout, 0.0, 1.0)
        self.max_residual_px = float(max_residual_px)  # inf: no residual gate
        if not self.max_residual_px > 0:
            raise ValueError(f"VisionFeedback: max_residual_px must be > 0 (inf: no gate), got "
                             f"{max_residual_px!r}")
        if not (is_whole(supersample) and 1 <= supersample <= MAX_SUPERSAMPLE):
            raise ValueError(f"VisionFeedback: supersample must be a whole number in "
                             f"1..{MAX_SUPERSAMPLE}, got {supersample!r}")
        self.supersample = int(supersample)
        self.strobe = bool(strobe)
        self.min_area_ratio = float(min_area_ratio)
        self.full_frame = bool(full_frame)
        if self.full_frame:  # refused now, not at the first look
            check_full_frames(render_rig, self.supersample)
        self.lighting = FLAT_LIGHT
        self._last: dict[str, np.ndarray] = {}
        self.last_observation: Observation | None = None
        self.reset(SEED)

    def reset(self, seed: int | np.random.SeedSequence | None = None) -> None:
        """New generator from ``seed`` (anything ``numpy.random.default_rng`` takes); forget the
        last estimates."""
        self.rng = np.random.default_rng(seed)
        self._last = {n: np.full(3, np.nan) for n in MARKERS}
        self.last_observation = None

    # -------------------------------------------------------------- the three steps
    def capture_pair(self, world) -> dict[str, tuple[Patch | None, ...]]:
        """What both cameras see: marker -> per camera a window around its LED, or the whole
        frame (see the class docstring). Sensor noise from the feedback's generator."""
        from .imaging import capture_window, led_windows
        from .urdf import ARM_RGB, LED_RADIUS_MM, LED_RGB

        cams = self.render_rig.cameras
        names = self.arm.marker_names
        s, light = self.supersample, self.lighting
        out: dict[str, tuple] = {}
        try:
            if self.full_frame and not self.strobe:
                frame = tuple(self._frame(world, c) for c in cams)
                return {n: frame for n in names}
            boxes = {}
            if not self.full_frame:
                centres = world.led_centres_mm()
                X = np.array([centres[n] for n in names])
                per_cam = [led_windows(c, X, LED_RADIUS_MM) for c in cams]
                boxes = {n: [b[k] for b in per_cam] for k, n in enumerate(names)}
            for lit in names:
                if self.strobe:
                    for n in names:
                        world.set_led_lit(n, LED_RGB[n] if n == lit else ARM_RGB)
                if self.full_frame:
                    out[lit] = tuple(self._frame(world, c) for c in cams)
                    continue
                out[lit] = tuple(None if box is None else capture_window(
                    world, c, self.rng, box, supersample=s, lighting=light)
                    for c, box in zip(cams, boxes[lit]))
        finally:
            if self.strobe:
                for n in names:
                    world.set_led_lit(n, LED_RGB[n])
        return out

    def _frame(self, world, camera) -> Patch:
        """The camera's whole frame (lens applied to the supersampled render, as in windows)."""
        from .imaging import capture

        img = capture(world, camera, self.rng, supersample=self.supersample,
                      lighting=self.lighting, lens_first=True)
        return Patch(img, (0, 0), camera.size)

    def detect(self, patches: dict) -> dict[str, tuple[Detection, ...]]:
        """Each LED's centroid in each camera, undistorted with the estimate rig: one
        ``cv2.undistortPoints`` per camera for all markers. Dropout and the added centroid
        noise (``noise_px``, on the captured pixels) are applied here."""
        from .urdf import LED_RGB

        est_cams = self.estimate_rig.cameras
        raw: dict[str, list[Detection]] = {}
        for name, ps in patches.items():
            dets = []
            for cam, patch in zip(est_cams, ps):
                if patch is None:
                    dets.append(Detection(False, np.full(2, np.nan), np.full(2, np.nan), 0.0,
                                          OUTSIDE, OUTSIDE))
                    continue
                pred = None
                if patch.full_frame and np.all(np.isfinite(self._last[name])):
                    pred = cam.project(self._last[name])
                dets.append(locate_led_near(patch, LED_RGB[name], pred, aspect=cam.fy / cam.fx))
            if all(d.ok for d in dets) and self.dropout > 0 and self.rng.random() < self.dropout:
                dets = [Detection(False, np.full(2, np.nan), d.uv_raw_px, d.area_px, DROPPED,
                                  DROPPED) for d in dets]
            if all(d.ok for d in dets) and self.noise_px > 0:
                dets = [Detection(True, d.uv_px, d.uv_raw_px + self.rng.normal(
                    0.0, self.noise_px, 2), d.area_px) for d in dets]
            raw[name] = dets
        # one undistortion per camera for all the markers it found
        out = {name: list(dets) for name, dets in raw.items()}
        for i, cam in enumerate(est_cams):
            found = [n for n, dets in raw.items() if dets[i].ok]
            if not found:
                continue
            und = cam.undistort(np.array([raw[n][i].uv_raw_px for n in found]).reshape(-1, 2))
            for n, uv in zip(found, und.reshape(-1, 2)):
                d = raw[n][i]
                out[n][i] = Detection(True, uv, d.uv_raw_px, d.area_px)
        return {n: tuple(d) for n, d in out.items()}

    def triangulate(self, detections: dict) -> tuple[dict, dict, dict, dict]:
        """Triangulate the markers seen by both cameras (one batched call) and check them.

        Returns
        -------
        points_mm : marker -> (3,) for the accepted markers.
        residual_px : marker -> RMS reprojection residual, for every triangulated marker.
        reasons : marker -> why it was missed, for people ("" if accepted).
        causes : marker -> why it was missed, a fixed phrase (a detection's cause,
            :data:`RESIDUAL` or :data:`PARTLY_HIDDEN`); "" if accepted.
        """
        from .detect import expected_area_px
        from .triangulate import triangulate
        from .urdf import LED_RADIUS_MM

        est_cams = self.estimate_rig.cameras
        first_miss = {n: next((d for d in dets if not d.ok), None) for n, dets in detections.items()}
        reasons = {n: d.reason if d else "" for n, d in first_miss.items()}
        causes = {n: d.cause if d else "" for n, d in first_miss.items()}
        both = [n for n in detections if not causes[n]]
        points: dict[str, np.ndarray] = {}
        residual: dict[str, float] = {}
        if not both:
            return points, residual, reasons, causes
        uv1 = np.array([detections[n][0].uv_px for n in both])
        uv2 = np.array([detections[n][1].uv_px for n in both])
        X, rms = triangulate(self.estimate_rig, uv1, uv2, method="optimal")
        for n, Xn, r in zip(both, X, rms):
            residual[n] = float(r)
            if not np.isfinite(r) or r > self.max_residual_px:
                reasons[n], causes[n] = f"residual {r:.2f} px", RESIDUAL
                continue
            ratio = min(d.area_px / expected_area_px(c, Xn, LED_RADIUS_MM)
                        for d, c in zip(detections[n], est_cams))
            if ratio < self.min_area_ratio:
                reasons[n] = f"blob area {ratio:.2f} of expected: partly hidden"
                causes[n] = PARTLY_HIDDEN
                continue
            points[n] = Xn
        return points, residual, reasons, causes

    def observe(self, world) -> Markers:
        """Measure the markers in the current world (see the class docstring); the full
        record is kept in :attr:`last_observation`."""
        t0 = perf_counter()
        patches = self.capture_pair(world)
        t1 = perf_counter()
        detections = self.detect(patches)
        t2 = perf_counter()
        points, residual, reasons, causes = self.triangulate(detections)
        t3 = perf_counter()
        self._last.update(points)
        missed = tuple(n for n in self.arm.marker_names if causes[n])
        timing = {"render": 1e3 * (t1 - t0), "detect": 1e3 * (t2 - t1),
                  "triangulate": 1e3 * (t3 - t2)}
        markers = Markers(self._last["gripper"].copy(), self._last["elbow"].copy(), missed,
                          residual, timing, {n: causes[n] for n in missed})
        self.last_observation = Observation(markers, patches, detections, residual, reasons,
                                            timing, causes)
        return markers
