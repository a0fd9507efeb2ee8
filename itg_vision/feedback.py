"""Feedback sources: where the rules' marker positions come from.

Every source returns the same :class:`Markers`; the rules cannot tell them apart and never see
the world, the model or the encoders.

- :class:`ModelFeedback`: joint encoders + the nominal kinematic model (the paper's classical
  variant). Wrong when the true arm differs from the model.
- :class:`TruthFeedback`: the simulator's marker positions (ideal sensors).
- ``VisionFeedback``: render both cameras, distort, add noise, detect, triangulate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .arm import ArmSpec, forward_kinematics
from .contracts import Markers


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


class TruthFeedback:
    """The simulator's LED positions: ideal sensors, or with seeded Gaussian noise.

    Parameters
    ----------
    noise_mm : std of the noise added to each coordinate of each marker (mm), drawn from the
        generator made by :meth:`reset`; 0 for ideal sensors.
    """

    name = "truth"

    def __init__(self, noise_mm: float = 0.0):
        self.noise_mm = float(noise_mm)
        self.rng = np.random.default_rng(None)

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def observe(self, world) -> Markers:
        m = world.true_markers()
        if self.noise_mm > 0:
            return Markers(m["gripper"] + self.rng.normal(0.0, self.noise_mm, 3),
                           m["elbow"] + self.rng.normal(0.0, self.noise_mm, 3))
        return Markers(m["gripper"], m["elbow"])


class VisionFeedback:
    """Stereo vision: render both cameras, distort, add noise, detect, triangulate.

    The images come from the *render* rig (the true cameras); centroids are undistorted and
    triangulated with the *estimate* rig (what the estimator believes, e.g. a calibrated rig).
    The simulator's true marker positions are never read.

    Parameters
    ----------
    render_rig : `itg_vision.camera.Rig` used to make the images.
    estimate_rig : `itg_vision.camera.Rig` used to undistort and triangulate.
    arm : the arm spec (only its ``marker_names`` are used).
    noise_px : std of Gaussian noise added to each detected centroid coordinate (px).
    dropout : probability that a marker's detection is dropped at an iteration.
    max_residual_px : reject a triangulated marker whose RMS reprojection residual exceeds it.
    supersample : rendering factor (1 = off; 2 halves the centroid error but costs ~5x).
    strobe : image each LED in its own frame, the others dark (drawn in the arm's colour).
    min_area_ratio : reject a marker whose blob area is below this fraction of the area its
        sphere should cover at the triangulated distance (a partly hidden LED).
    windowed : search a window around the last estimate's projection first.

    Attributes
    ----------
    reasons : dict marker -> why it was missed at the last observation ("" if measured).
    """

    name = "vision"

    def __init__(self, render_rig, estimate_rig, arm: ArmSpec, *, noise_px: float = 0.0,
                 dropout: float = 0.0, max_residual_px: float = 2.0, supersample: int = 1,
                 strobe: bool = False, min_area_ratio: float = 0.5, windowed: bool = True):
        self.render_rig = render_rig
        self.estimate_rig = estimate_rig
        self.arm = arm
        self.noise_px = float(noise_px)
        self.dropout = float(dropout)
        self.max_residual_px = float(max_residual_px)
        self.supersample = int(supersample)
        self.strobe = bool(strobe)
        self.min_area_ratio = float(min_area_ratio)
        self.windowed = bool(windowed)
        self.reset(None)

    def reset(self, seed: int | None = None) -> None:
        """New generator from ``seed``; forget the last estimates."""
        self.rng = np.random.default_rng(seed)
        self._last = {n: np.full(3, np.nan) for n in ("gripper", "elbow")}
        self.reasons: dict[str, str] = {}

    # -------------------------------------------------------------- one observation
    def _images(self, world) -> dict[str | None, list[np.ndarray]]:
        """Captured images per camera: keyed by marker when strobing, else by None."""
        from .imaging import capture
        from .urdf import ARM_RGB, LED_RGB

        cams = self.render_rig.cameras
        if not self.strobe:
            return {None: [capture(world, c, self.rng, supersample=self.supersample)
                           for c in cams]}
        out = {}
        names = self.arm.marker_names
        try:
            for lit in names:
                for n in names:
                    world.set_led_lit(n, LED_RGB[n] if n == lit else ARM_RGB)
                out[lit] = [capture(world, c, self.rng, supersample=self.supersample)
                            for c in cams]
        finally:
            for n in names:
                world.set_led_lit(n, LED_RGB[n])
        return out

    def observe(self, world) -> Markers:
        """Measure the markers in the current world (see the class docstring)."""
        from time import perf_counter

        from .detect import expected_area_px, find_led
        from .triangulate import triangulate
        from .urdf import LED_RADIUS_MM, LED_RGB

        t0 = perf_counter()
        images = self._images(world)
        self.last_images = images
        self.last_uv_raw: dict[str, list] = {}
        t1 = perf_counter()
        est_cams = self.estimate_rig.cameras
        found: dict[str, tuple] = {}
        self.reasons = {}
        for name in self.arm.marker_names:
            imgs = images[name if self.strobe else None]
            last = self._last[name]
            dets = []
            for cam, img in zip(est_cams, imgs):
                pred = cam.project(last) if self.windowed and np.all(np.isfinite(last)) else None
                dets.append(find_led(img, cam, LED_RGB[name], predicted_uv=pred))
            self.last_uv_raw[name] = [d.uv_raw_px if d.ok else None for d in dets]
            bad = [d.reason for d in dets if not d.ok]
            if bad:
                self.reasons[name] = bad[0]
                continue
            if self.dropout > 0 and self.rng.random() < self.dropout:
                self.reasons[name] = "dropped"
                continue
            raw = [d.uv_raw_px for d in dets]
            if self.noise_px > 0:
                raw = [r + self.rng.normal(0.0, self.noise_px, 2) for r in raw]
                uv = [c.undistort(r) for c, r in zip(est_cams, raw)]
            else:
                uv = [d.uv_px for d in dets]
            found[name] = (uv, [d.area_px for d in dets])
        t2 = perf_counter()
        residual: dict[str, float] = {}
        for name, (uv, areas) in found.items():
            X, rms = triangulate(self.estimate_rig, uv[0], uv[1])
            residual[name] = rms
            if not np.isfinite(rms) or rms > self.max_residual_px:
                self.reasons[name] = f"residual {rms:.2f} px"
                continue
            ratio = min(a / expected_area_px(c, X, LED_RADIUS_MM) for a, c in zip(areas, est_cams))
            if ratio < self.min_area_ratio:
                self.reasons[name] = f"blob area {ratio:.2f} of expected: partly hidden"
                continue
            self._last[name] = X
        t3 = perf_counter()
        missed = tuple(n for n in self.arm.marker_names if n in self.reasons)
        for n in self.arm.marker_names:
            self.reasons.setdefault(n, "")
        timing = {"render": 1e3 * (t1 - t0), "detect": 1e3 * (t2 - t1),
                  "triangulate": 1e3 * (t3 - t2)}
        return Markers(self._last["gripper"].copy(), self._last["elbow"].copy(), missed,
                       residual, timing)
