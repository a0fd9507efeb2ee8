"""Cameras and stereo rigs: intrinsics, lens distortion, pose, sensor model, YAML files.

Conventions (OpenCV): camera x right, y down, z forward; the centre of pixel (i, j) is at
u = i, v = j; ``x_cam = R @ X_world + t`` with X in mm. Distortion is OpenCV's ``plumb_bob``
(k1, k2, p1, p2, k3). The OpenGL matrices handed to PyBullet are built here as pure numpy
(metres), including TinyRenderer's one-pixel shift in v (``cy_r = cy + 1``).

Rig files (``cameras/*.yaml``) use ROS ``camera_info`` names where natural::

    name: planar
    cameras:
      - name: left
        image_width: 640
        image_height: 480
        camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
        distortion_model: plumb_bob
        distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}  # or a list
        pose:                       # one of three forms
          position_mm: [x, y, z]    #   look-at: camera centre, a point on the optical axis
          look_at_mm: [x, y, z]     #   and the world direction that appears "up" in the image
          up: [0, 0, 1]
          # position_mm + rotation_deg: [rx, ry, rz]  (Rodrigues vector of R world->camera, deg)
          # rotation_matrix: {rows: 3, cols: 3, data: [9]} + translation_mm: [3]  (exact; saved
          #   with position_mm for readers, which must agree)
        sensor: {noise_sigma_gray: 2.0, exposure: 1.0}
    supersample: 2                  # optional: the vision loop's rendering factor (run's
                                    # --supersample overrides; default in feedback.py)
    calibration: {...}              # optional, written by calibration
    true_rig: cameras/planar.yaml   # optional, the rig a calibrated rig was measured from
    true_rig_sha256: 64 hex digits  # optional, written by calibration: the SHA-256 of the
                                    # true rig file it calibrated (load_true_rig checks it)

Any other key, or a pose giving more than one form, is refused (one line naming the field).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from .errors import UserError
from .inputs import Fields, file_sha256, read_yaml, resolve_relative
from .shipped import CAMERAS_DIR, YAML_SUFFIXES, names_a_path, not_found, or_a_path, rig_names

_MM = 1e-3
#: Largest image accepted (pixels per camera): rendering costs about :data:`BYTES_PER_PIXEL`.
MAX_IMAGE_PIXELS = 4096 * 4096
#: Peak memory of rendering one frame, per pixel (measured: 60 to 100 bytes at 640x480 and
#: 2560x1920: TinyRenderer's RGBA and depth buffers, the distortion margin, the remap).
BYTES_PER_PIXEL = 60
#: Largest focal length accepted (px): 1e6 px is a 0.04 degree field of view at 640 px.
MAX_FOCAL_PX = 1e6
#: Largest half field of view accepted (deg) about the principal point: a pinhole camera.
MAX_HALF_FOV_DEG = 80.0
#: Largest coordinate of a camera position accepted (mm).
MAX_POSITION_MM = 1e6
#: Largest rendering supersampling factor accepted (its cost grows as the square).
MAX_SUPERSAMPLE = 8
#: Cameras of a rig closer than this (mm) are at the same place: no stereo.
MIN_BASELINE_MM = 1.0
#: Largest sensor gain accepted (the image saturates long before).
MAX_EXPOSURE = 1000.0
#: Largest |coefficient| of plumb_bob distortion accepted.
MAX_DISTORTION = 100.0
#: Iterations of cv2.undistortPoints: the default 5 leaves ~0.1 px error in the corners.
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


# ---------------------------------------------------------------------------- rig files
def resolve_rig(name_or_path: str) -> Path:
    """``--rig``: a shipped rig by name (``cameras/<name>.yaml``) or a path to a rig file."""
    p = Path(name_or_path)
    if names_a_path(name_or_path, YAML_SUFFIXES):
        if not p.exists() and p.stem in rig_names():  # else read_text says why it cannot read it
            raise UserError(not_found(p, "rig", rig_names()))
        return p
    shipped = CAMERAS_DIR / f"{name_or_path}.yaml"
    if not shipped.exists():
        raise UserError(f"unknown rig {name_or_path!r} (shipped: {', '.join(rig_names())}; "
                        f"{or_a_path(name_or_path, 'a rig file', '.yaml')})")
    return shipped


def default_rig_path(arm, calibrated: bool = False) -> Path:
    """The rig of an arm (an `ArmSpec`, its name or its file) as its arm file's
    ``defaults.rig`` gives it (:func:`resolve_rig`: ``cameras/<rig>.yaml``, or a rig file), or
    its calibration beside it (``cameras/<rig>.calib.yaml``; ``<file>.calib.yaml``)."""
    from .arm import ArmSpec

    spec = arm if isinstance(arm, ArmSpec) else ArmSpec.from_args(arm)
    rig = resolve_rig(spec.defaults["rig"])
    return rig.with_name(f"{rig.stem}.calib{rig.suffix}") if calibrated else rig


# ---------------------------------------------------------------------------- pure functions
def look_at_rotation(position_mm, look_at_mm, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotation world->camera (OpenCV axes) of a camera at ``position_mm`` looking at a point.

    Parameters
    ----------
    position_mm, look_at_mm, up : array-like, shape (3,)

    Returns
    -------
    R : ndarray, shape (3, 3); rows are the camera x (right), y (down), z (forward) axes in
        world coordinates.

    Raises
    ------
    ValueError if the viewing direction is zero or parallel to ``up``.
    """
    z = _finite_length(np.asarray(look_at_mm, float) - np.asarray(position_mm, float))
    nz = np.linalg.norm(z)
    if nz < 1e-9:
        raise ValueError("look_at equals position")
    z = z / nz
    u = _finite_length(np.asarray(up, float))
    y = -(u - (u @ z) * z)
    ny = np.linalg.norm(y)
    if ny < 1e-9 * max(1.0, np.linalg.norm(u)):
        raise ValueError("up is parallel to the viewing direction (or zero)")
    y = y / ny
    x = np.cross(y, z)
    return np.stack([x, y, z])


def _finite_length(v: np.ndarray) -> np.ndarray:
    """``v`` (finite), or, where its length overflows to inf (a direction given with numbers
    near 1e308: a look-at point that far off), ``v`` over its largest component, the same
    direction: dividing by that inf length gave zeros, not a rotation. Any other ``v`` is
    returned as it is, so the rotations of ordinary rigs stay the same to the bit."""
    with np.errstate(over="ignore"):
        return v if np.isfinite(np.linalg.norm(v)) else v / np.max(np.abs(v))


def gl_view_matrix(R: np.ndarray, t_mm: np.ndarray) -> np.ndarray:
    """OpenGL view matrix (metres), flattened column-major, shape (16,)."""
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = np.asarray(t_mm, float) * _MM
    return (np.diag([1.0, -1.0, -1.0, 1.0]) @ M).flatten(order="F")


def gl_projection_matrix(K: np.ndarray, width: int, height: int, near_m: float,
                         far_m: float) -> np.ndarray:
    """OpenGL projection matrix for TinyRenderer, flattened column-major, shape (16,).

    Uses ``cy_r = cy + 1``: TinyRenderer puts a point at ``v = (1 - y_ndc) H / 2 - 1``.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    cy_r = cy + 1.0
    n, f = near_m, far_m
    P = np.array([
        [2 * fx / width, 0.0, 1 - 2 * cx / width, 0.0],
        [0.0, 2 * fy / height, 2 * cy_r / height - 1, 0.0],
        [0.0, 0.0, -(f + n) / (f - n), -2 * f * n / (f - n)],
        [0.0, 0.0, -1.0, 0.0],
    ])
    return P.flatten(order="F")


# ---------------------------------------------------------------------------- Camera
def _frozen(a) -> np.ndarray:
    """A read-only float array (cached camera properties must not be changed in place)."""
    out = np.array(a, float)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class Camera:
    """One camera: pinhole intrinsics, plumb_bob distortion, pose and sensor model.

    Stored as tuples so the camera is hashable (caches key on it); the array views are
    cached read-only properties.

    Attributes
    ----------
    name : str
    image_width, image_height : int, pixels.
    fx, fy, cx, cy : float, pixels.
    dist : tuple of 5 floats (k1, k2, p1, p2, k3), OpenCV order.
    rotation : 3x3 tuple, R world->camera.
    translation_mm : 3-tuple, t in ``x_cam = R X_world + t`` (mm).
    noise_sigma_gray : std of Gaussian grey-level noise (0..255 scale).
    exposure : gain multiplying the rendered intensities.
    """

    name: str
    image_width: int
    image_height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...]
    rotation: tuple[tuple[float, ...], ...]
    translation_mm: tuple[float, ...]
    noise_sigma_gray: float = 2.0
    exposure: float = 1.0

    @classmethod
    def from_arrays(cls, name: str, size: tuple[int, int], K, dist, R, t_mm,
                    noise_sigma_gray: float = 2.0, exposure: float = 1.0) -> "Camera":
        """Build from arrays: ``size`` is (width, height), K (3, 3), dist (5,), R (3, 3), t (3,)."""
        K = np.asarray(K, float)
        return cls(name, int(size[0]), int(size[1]), float(K[0, 0]), float(K[1, 1]),
                   float(K[0, 2]), float(K[1, 2]),
                   tuple(float(v) for v in np.ravel(dist)),
                   tuple(tuple(float(v) for v in row) for row in np.asarray(R, float)),
                   tuple(float(v) for v in np.ravel(t_mm)),
                   float(noise_sigma_gray), float(exposure))

    # -------------------------------------------------------------- array views
    @cached_property
    def K(self) -> np.ndarray:
        """Camera matrix, shape (3, 3)."""
        return _frozen([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @cached_property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion coefficients, shape (5,)."""
        return _frozen(self.dist)

    @cached_property
    def R(self) -> np.ndarray:
        """Rotation world->camera, shape (3, 3)."""
        return _frozen(self.rotation)

    @cached_property
    def t_mm(self) -> np.ndarray:
        """Translation (mm), shape (3,)."""
        return _frozen(self.translation_mm)

    @cached_property
    def position_mm(self) -> np.ndarray:
        """Camera centre in the world frame (mm), shape (3,): ``-R^T t``."""
        return _frozen(-self.R.T @ self.t_mm)

    @cached_property
    def P(self) -> np.ndarray:
        """Pinhole projection matrix ``K [R | t]`` (mm), shape (3, 4)."""
        return _frozen(self.K @ np.hstack([self.R, self.t_mm[:, None]]))

    @cached_property
    def rvec(self) -> np.ndarray:
        """Rodrigues vector of R (radians), shape (3, 1), as cv2.projectPoints takes it."""
        return _frozen(cv2.Rodrigues(self.R)[0])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.image_width, self.image_height

    # -------------------------------------------------------------- projection
    def to_camera(self, X_mm) -> np.ndarray:
        """World points to camera coordinates: shape (..., 3) -> (..., 3), mm."""
        X = np.asarray(X_mm, float)
        return X @ self.R.T + self.t_mm

    def project(self, X_mm, distort: bool = True) -> np.ndarray:
        """Project world points to pixels.

        Parameters
        ----------
        X_mm : array-like, shape (3,) or (n, 3)
        distort : apply the lens distortion (the image as captured) or not (pinhole).

        Returns
        -------
        uv : ndarray, shape (2,) or (n, 2)
        """
        X = np.asarray(X_mm, float)
        pts = X.reshape(-1, 1, 3)
        dist = self.dist_coeffs if distort else np.zeros(5)
        uv, _ = cv2.projectPoints(pts, self.rvec, self.t_mm, self.K, dist)
        uv = uv.reshape(-1, 2)
        return uv[0] if X.ndim == 1 else uv

    def undistort(self, uv_px) -> np.ndarray:
        """Distorted pixels to pinhole pixels: shape (2,) or (n, 2)."""
        uv = np.asarray(uv_px, float)
        out = cv2.undistortPoints(uv.reshape(-1, 1, 2), self.K, self.dist_coeffs, None, None,
                                  self.K, criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
        return out[0] if uv.ndim == 1 else out

    def back_project(self, uv_px, depth_mm, distorted: bool = True) -> np.ndarray:
        """Pixels and depths (camera z, mm) to world points.

        Parameters
        ----------
        uv_px : array-like, shape (2,) or (n, 2)
        depth_mm : float or array-like, shape (n,)
        distorted : whether ``uv_px`` are distorted (as captured) or pinhole pixels.

        Returns
        -------
        X_mm : ndarray, shape (3,) or (n, 3)
        """
        uv = np.asarray(uv_px, float)
        pts = uv.reshape(-1, 2)
        if distorted:
            pts = self.undistort(pts).reshape(-1, 2)
        x = (pts[:, 0] - self.cx) / self.fx
        y = (pts[:, 1] - self.cy) / self.fy
        z = np.broadcast_to(np.asarray(depth_mm, float), x.shape)
        Xc = np.stack([x * z, y * z, z], axis=1)
        Xw = (Xc - self.t_mm) @ self.R  # R^T (Xc - t)
        return Xw[0] if uv.ndim == 1 else Xw

    # -------------------------------------------------------------- OpenGL
    def gl_view(self) -> np.ndarray:
        """OpenGL view matrix (metres), column-major, shape (16,)."""
        return gl_view_matrix(self.R, self.t_mm)

    def gl_projection(self, near_m: float, far_m: float) -> np.ndarray:
        """OpenGL projection matrix for this image size, column-major, shape (16,); the planes
        in metres (the renders' own: :data:`itg_vision.imaging.NEAR_M`, ``FAR_M``)."""
        return gl_projection_matrix(self.K, self.image_width, self.image_height, near_m, far_m)


# ---------------------------------------------------------------------------- Rig
@dataclass(frozen=True)
class Rig:
    """A stereo rig: two cameras in the world frame.

    Attributes
    ----------
    name : str
    cameras : (Camera, Camera)
    source : the file it was read from ("" if built in code).
    calibration : optional free-form record of how the rig was calibrated.
    true_rig : optional path of the rig a calibrated rig was measured from.
    supersample : optional rendering factor of the vision loop for this rig (None: the
        default of :mod:`itg_vision.feedback`).
    true_rig_sha256 : optional SHA-256 (hex) of the true rig file as it was calibrated (None:
        not recorded, as in calibrations written before it was).
    """

    name: str
    cameras: tuple[Camera, Camera]
    source: str = ""
    calibration: dict | None = field(default=None, compare=False)
    true_rig: str | None = None
    supersample: int | None = None
    true_rig_sha256: str | None = None

    @property
    def tied_arm(self) -> str | None:
        """The arm whose LEDs tied a calibrated rig to the base (its calibration's
        ``base_frame.arm``), None for a rig not calibrated so."""
        return ((self.calibration or {}).get("base_frame") or {}).get("arm")

    def scaled(self, factor: float) -> "Rig":
        """The same rig with every image ``factor`` times larger (same field of view).

        Pixel centres sit at integer coordinates, so c' = (c + 0.5) * factor - 0.5.
        """
        cams = []
        for c in self.cameras:
            K = c.K.copy()
            K[0, 0] *= factor
            K[1, 1] *= factor
            K[0, 2] = (K[0, 2] + 0.5) * factor - 0.5
            K[1, 2] = (K[1, 2] + 0.5) * factor - 0.5
            size = (int(round(c.image_width * factor)), int(round(c.image_height * factor)))
            cams.append(Camera.from_arrays(c.name, size, K, c.dist_coeffs, c.R, c.t_mm,
                                           c.noise_sigma_gray, c.exposure))
        return Rig(self.name, tuple(cams), self.source, self.calibration, self.true_rig,
                   self.supersample, self.true_rig_sha256)

    @classmethod
    def from_yaml(cls, path) -> "Rig":
        """Read and validate a rig file; any bad field raises `UserError` naming it."""
        path = str(path)
        doc = read_yaml(path, "rig file")
        return rig_from_dict(doc, path)

    def yaml_text(self) -> str:
        """The rig file's text (exact pose as a rotation matrix), as :meth:`to_yaml` writes it."""
        doc: dict[str, Any] = {"name": self.name, "cameras": [_camera_to_dict(c)
                                                              for c in self.cameras]}
        if self.calibration is not None:
            doc["calibration"] = self.calibration
        if self.true_rig is not None:
            doc["true_rig"] = self.true_rig
        if self.true_rig_sha256 is not None:
            doc["true_rig_sha256"] = self.true_rig_sha256
        if self.supersample is not None:
            doc["supersample"] = self.supersample
        header = ("# Stereo rig (itg_vision). OpenCV conventions, mm; pose as R world->camera\n"
                  "# rows and t in x_cam = R X_world + t. See itg_vision/camera.py.\n")
        return header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)

    def to_yaml(self, path) -> None:
        """Write the rig file (:meth:`yaml_text`) atomically (`itg_vision.outputs`)."""
        from .outputs import write_text

        write_text(path, self.yaml_text())


def _camera_to_dict(c: Camera) -> dict:
    return {
        "name": c.name,
        "image_width": c.image_width,
        "image_height": c.image_height,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in c.K.ravel()]},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": list(c.dist)},
        "pose": {
            "rotation_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in c.R.ravel()]},
            "translation_mm": list(c.translation_mm),
            "position_mm": [round(float(v), 3) for v in c.position_mm],  # for readers; checked
        },
        "sensor": {"noise_sigma_gray": c.noise_sigma_gray, "exposure": c.exposure},
    }


# ---------------------------------------------------------------------------- validation
def rig_from_dict(doc: Any, path: str = "<rig>") -> Rig:
    """Validate a parsed rig document and build the `Rig` (see the module docstring)."""
    F = Fields(path)
    if not isinstance(doc, dict):
        F.fail("(top level)", "must be a mapping with 'name' and 'cameras'")
    name = F.get(doc, "name", "")  # a file without name or cameras: "name: missing", first
    name = F.text(name, "name", what="a name on one line")  # messages quote it
    cams = F.get(doc, "cameras", "")
    F.mapping(doc, "(top level)", ("name", "cameras"),
              ("supersample", "calibration", "true_rig", "true_rig_sha256"))
    if not isinstance(cams, list) or len(cams) != 2:
        F.fail("cameras", "must be a list of exactly two cameras")
    cameras = tuple(_camera_from_dict(F, c, f"cameras[{i}]") for i, c in enumerate(cams))
    if cameras[0].name == cameras[1].name:
        F.fail("cameras[1].name", f"duplicates cameras[0].name {cameras[0].name!r}")
    baseline = float(np.linalg.norm(cameras[0].position_mm - cameras[1].position_mm))
    if baseline < MIN_BASELINE_MM:
        F.fail("cameras[1].pose", f"at the same place as cameras[0] ({baseline:.2g} mm apart): "
                                  "stereo needs two viewpoints")
    calibration = doc.get("calibration")
    if calibration is not None and not isinstance(calibration, dict):
        F.fail("calibration", "must be a mapping")
    true_rig = doc.get("true_rig")
    if true_rig is not None and not isinstance(true_rig, str):
        F.fail("true_rig", "must be a path string")
    true_rig_sha256 = doc.get("true_rig_sha256")
    if true_rig_sha256 is not None:
        if not isinstance(true_rig_sha256, str) or not re.fullmatch(r"[0-9a-f]{64}",
                                                                    true_rig_sha256):
            F.fail("true_rig_sha256", "must be 64 lowercase hex digits (a SHA-256)")
        if true_rig is None:
            F.fail("true_rig_sha256", "needs true_rig, the file it is the hash of")
    supersample = doc.get("supersample")
    if supersample is not None:
        supersample = F.integer(supersample, "supersample")
        if not 1 <= supersample <= MAX_SUPERSAMPLE:
            F.fail("supersample", f"must be in 1..{MAX_SUPERSAMPLE}, got {supersample}")
    return Rig(name, cameras, path, calibration, true_rig, supersample, true_rig_sha256)


def load_true_rig(rig: Rig, rig_path) -> Rig:
    """The rig a calibrated ``rig`` (read from ``rig_path``) renders with: the file its
    ``true_rig`` names, relative to ``rig_path``'s folder. The one loader of a calibrated rig's
    truth (run, the environment, ``bench noise``'s ``rig-calibrated``).

    Raises `UserError` (one line naming ``rig_path``) if that file cannot be read, or if it no
    longer is the file that was calibrated: its SHA-256 differs from ``true_rig_sha256`` (the
    true rig was edited after calibrating; estimating with the stale calibration would be wrong
    without a word). A rig without ``true_rig_sha256`` (older calibrations) is not checked.
    """
    path = resolve_relative(rig.true_rig, Path(rig_path))
    if not path.exists() and not Path(rig.true_rig).is_absolute():  # (moved from beside it?)
        beside = os.path.normpath(Path(rig_path).parent / rig.true_rig)
        raise UserError(f"{rig_path}: true_rig: {rig.true_rig}: no such file, read from this "
                        f"file's folder ({beside}) or the current one; a calibration moved away "
                        "from its rig needs its true_rig edited, or re-run calibrate with --out "
                        "where it is to stay")
    try:
        truth = Rig.from_yaml(path)
    except UserError as exc:  # name the calibrated rig and its field, then the problem
        raise UserError(f"{rig_path}: true_rig: {exc}") from None
    if rig.true_rig_sha256 is not None and file_sha256(path) != rig.true_rig_sha256:
        shown, arm = os.path.normpath(path), rig.tied_arm
        raise UserError(f"{rig_path}: its true rig {shown} has changed since it was calibrated "
                        f"(true_rig_sha256 no longer matches); re-run python -m "
                        f"itg_vision.calibrate --rig {shown}" + (f" --arm {arm}" if arm else "")
                        + f" --out {os.path.normpath(rig_path)}")
    return truth


def _camera_from_dict(F: Fields, d: Any, where: str) -> Camera:
    F.mapping(d, where, ("name", "image_width", "image_height", "camera_matrix",
                         "distortion_coefficients", "pose"), ("distortion_model", "sensor"))
    name = F.text(d["name"], f"{where}.name", what="a name on one line")  # messages quote it
    W = F.integer(d["image_width"], f"{where}.image_width")
    H = F.integer(d["image_height"], f"{where}.image_height")
    if W <= 0:
        F.fail(f"{where}.image_width", f"must be > 0, got {W}")
    if H <= 0:
        F.fail(f"{where}.image_height", f"must be > 0, got {H}")
    if W * H > MAX_IMAGE_PIXELS:
        F.fail(where, f"a {W} x {H} px image needs about {W * H * BYTES_PER_PIXEL / 1e9:.3g} GB "
                      f"to render a frame ({BYTES_PER_PIXEL} bytes per pixel); the limit is "
                      f"{MAX_IMAGE_PIXELS / 1e6:.1f} Mpx (4096 x 4096)")
    km = f"{where}.camera_matrix"
    K = F.array(d["camera_matrix"], 9, km, shape=(3, 3)).reshape(3, 3)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for label, f in (("fx", fx), ("fy", fy)):
        if f <= 0:
            F.fail(km, f"{label} must be > 0")
        if f > MAX_FOCAL_PX:
            F.fail(km, f"{label} must be at most {MAX_FOCAL_PX:g} px (a field of view of "
                       f"hundredths of a degree), got {f:g}")
    if not 0 <= cx <= W - 1:
        F.fail(km, f"cx must be inside the image [0, {W - 1}], got {cx:g}")
    if not 0 <= cy <= H - 1:
        F.fail(km, f"cy must be inside the image [0, {H - 1}], got {cy:g}")
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        F.fail(km, "must be [fx, 0, cx, 0, fy, cy, 0, 0, 1] (no skew)")
    for label, f, c, n in (("fx", fx, cx, W), ("fy", fy, cy, H)):
        half = np.degrees(np.arctan(max(c + 0.5, n - 0.5 - c) / f))
        if half > MAX_HALF_FOV_DEG:
            F.fail(km, f"{label} = {f:g} px gives a field of view of {2 * half:.0f} deg; a "
                       f"pinhole camera here cannot exceed {2 * MAX_HALF_FOV_DEG:g} deg")
    model = d.get("distortion_model", "plumb_bob")
    if model != "plumb_bob":
        F.fail(f"{where}.distortion_model", f"only plumb_bob is supported, got {model!r}")
    dist = F.array(d["distortion_coefficients"], 5, f"{where}.distortion_coefficients")
    if np.max(np.abs(dist)) > MAX_DISTORTION:
        F.fail(f"{where}.distortion_coefficients", f"each must be within +-{MAX_DISTORTION:g}, "
                                                   f"got {np.max(np.abs(dist)):g}")
    problem, margin = _distortion_check(fx, fy, cx, cy, W, H, dist)
    if problem:
        F.fail(f"{where}.distortion_coefficients", problem)
    rendered = (W + 2 * margin) * (H + 2 * margin)
    if rendered > MAX_IMAGE_PIXELS:
        F.fail(where, f"this lens needs a {W + 2 * margin} x {H + 2 * margin} px render for a "
                      f"{W} x {H} px image, about {rendered * BYTES_PER_PIXEL / 1e9:.3g} GB per "
                      f"frame; the limit is {MAX_IMAGE_PIXELS / 1e6:.1f} Mpx")
    R, t = _pose_from_dict(F, d["pose"], f"{where}.pose")
    sensor = d.get("sensor")  # left out (or null): the defaults below; [] or 0 is refused
    sensor = F.mapping({} if sensor is None else sensor, f"{where}.sensor", (),
                       ("noise_sigma_gray", "exposure"))
    sigma = F.number(sensor.get("noise_sigma_gray", 2.0), f"{where}.sensor.noise_sigma_gray")
    if not 0 <= sigma <= 255:
        F.fail(f"{where}.sensor.noise_sigma_gray", f"must be in [0, 255] grey levels, got {sigma:g}")
    exposure = F.number(sensor.get("exposure", 1.0), f"{where}.sensor.exposure")
    if not 0 < exposure <= MAX_EXPOSURE:
        F.fail(f"{where}.sensor.exposure", f"must be in (0, {MAX_EXPOSURE:g}], got {exposure:g}")
    return Camera.from_arrays(name, (W, H), K, dist, R, t, sigma, exposure)


def plumb_bob(x, y, dist) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's lens model (plumb_bob: k1, k2, p1, p2, k3) on normalized image coordinates
    ``x, y`` (arrays): the distorted (xd, yd). What ``cv2.projectPoints`` computes (tested
    equal), in numpy because its Python binding also computes every point's Jacobian: 8x the
    time on :func:`_distortion_check`'s 216,000 rays (89 against 11 ms a camera)."""
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def _distortion_check(fx, fy, cx, cy, W, H, dist, n_angles: int = 72,
                      n_steps: int = 3000) -> tuple[str, int]:
    """Whether plumb_bob distortion ``dist`` can be simulated on this image: ('', margin_px)
    or (problem, 0).

    Along 72 rays from the principal point, the distorted image of the pinhole ray must move
    outwards monotonically until it leaves the image (otherwise the lens folds back inside the
    frame: not invertible, and rendering it blows up), and leave it within three times the
    image's half-diagonal. ``margin_px``: how far beyond the frame the pinhole rendering must
    reach (about what :func:`itg_vision.imaging.render_plan` adds on each side).
    """
    corners = np.array([[-0.5 - cx, -0.5 - cy], [W - 0.5 - cx, -0.5 - cy],
                        [-0.5 - cx, H - 0.5 - cy], [W - 0.5 - cx, H - 0.5 - cy]]) / [fx, fy]
    t = np.linspace(0.0, 3.0 * float(np.max(np.hypot(*corners.T))), n_steps)[:, None]
    a = np.linspace(0.0, 2 * np.pi, n_angles, endpoint=False)[None, :]
    x, y = t * np.cos(a), t * np.sin(a)
    with np.errstate(all="ignore"):
        xd, yd = plumb_bob(x, y, dist)
        u, v = fx * xd + cx, fy * yd + cy
        along = xd * np.cos(a) + yd * np.sin(a)
    outside = ~((u >= -0.5) & (u <= W - 0.5) & (v >= -0.5) & (v <= H - 0.5))
    margin = 0.0
    for j in range(n_angles):
        exits = np.flatnonzero(outside[:, j])
        if not exits.size:
            return ("the lens squeezes more than three times the field of view into the image: "
                    "the simulator cannot render it", 0)
        k = exits[0]
        back = np.flatnonzero(~(np.diff(along[: k + 1, j]) > 0))
        if back.size:
            r = float(np.hypot(u[back[0], j] - cx, v[back[0], j] - cy))
            return (f"the lens model folds back inside the image (not invertible, within {r:.0f} "
                    "px of the centre): the simulator cannot render it", 0)
        pu, pv = fx * x[k, j] + cx, fy * y[k, j] + cy
        margin = max(margin, -pu, pu - (W - 1), -pv, pv - (H - 1))
    return "", int(np.ceil(margin)) + 2


#: The pose forms of a rig file (see the module docstring): (required, optional) keys. The
#: exact form's position_mm is written for readers; it must agree with the pose.
POSE_FORMS = ((("position_mm", "look_at_mm"), ("up",)),
              (("position_mm", "rotation_deg"), ()),
              (("rotation_matrix", "translation_mm"), ("position_mm",)))
#: How far R R^T of a rotation_matrix may be from the identity (each element).
ROTATION_TOL = 1e-6
#: How far (mm) the exact form's position_mm may be from the pose's (written to 0.001 mm).
POSITION_TOL_MM = 0.01


def _pose_from_dict(F: Fields, d: Any, where: str) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(d, dict):
        F.fail(where, "must be a mapping")
    own = [[k for k in d if k in req + opt and k != "position_mm"] for req, opt in POSE_FORMS]
    forms = [f for f, keys in zip(POSE_FORMS, own) if keys]
    if len(forms) != 1:
        given = "; ".join(" + ".join(keys) for keys in own if keys)
        head = f"gives more than one pose form ({given}): keep one of " if forms else "needs "
        F.fail(where, head + "look_at_mm, rotation_deg or rotation_matrix + translation_mm")
    F.mapping(d, where, *forms[0])
    if "rotation_matrix" in d:
        R = F.array(d["rotation_matrix"], 9, f"{where}.rotation_matrix", shape=(3, 3)).reshape(3, 3)
        off = float(np.max(np.abs(R @ R.T - np.eye(3))))
        if not off <= ROTATION_TOL:  # (NaN-safe)
            F.fail(f"{where}.rotation_matrix", f"must be a rotation (orthonormal, det +1): R R^T "
                   f"is {off:.2g} off the identity (at most {ROTATION_TOL:g}); a rotation "
                   f"written to 4 or 5 decimals is 1e-4 to 1e-5 off: give it to 8 or more")
        if np.linalg.det(R) < 0:
            F.fail(f"{where}.rotation_matrix", "must be a rotation (orthonormal, det +1)")
        t = F.array(d["translation_mm"], 3, f"{where}.translation_mm")
        if np.max(np.abs(t)) > MAX_POSITION_MM:
            F.fail(f"{where}.translation_mm", f"each must be within +-{MAX_POSITION_MM:g} mm")
        if "position_mm" in d:
            C = -R.T @ t
            given = F.array(d["position_mm"], 3, f"{where}.position_mm")
            if np.max(np.abs(given - C)) > POSITION_TOL_MM:
                F.fail(f"{where}.position_mm", "contradicts rotation_matrix + translation_mm "
                       f"(camera centre [{', '.join(f'{v:.3f}' for v in C)}]): correct or "
                       "remove it")
        return R, t
    C = F.array(d["position_mm"], 3, f"{where}.position_mm")
    if np.max(np.abs(C)) > MAX_POSITION_MM:
        F.fail(f"{where}.position_mm", f"each must be within +-{MAX_POSITION_MM:g} mm")
    if "look_at_mm" in d:
        target = F.array(d["look_at_mm"], 3, f"{where}.look_at_mm")
        up = F.array(d.get("up", [0, 0, 1]), 3, f"{where}.up")
        if np.max(np.abs(target - C)) < 1e-9:
            F.fail(f"{where}.look_at_mm", "must differ from position_mm")
        try:
            R = look_at_rotation(C, target, up)
        except ValueError:
            if "up" in d:
                F.fail(f"{where}.up", "must not be zero or parallel to the viewing direction")
            F.fail(f"{where}.up", "not given, and its default [0, 0, 1] is parallel to the "
                                  "viewing direction (a camera looking straight down or up): "
                                  "give up, the world direction shown as up in the image")
    else:
        rv = F.array(d["rotation_deg"], 3, f"{where}.rotation_deg")
        if np.max(np.abs(rv)) > 3600:
            F.fail(f"{where}.rotation_deg", "each must be within +-3600 deg")
        R, _ = cv2.Rodrigues(np.radians(rv))
    return R, -R @ C


def perturbed(rig: Rig, seed: int, *, angle_deg: float, shift_mm: float,
              each_camera: bool = False, true_rig: str | Path | None = None) -> Rig:
    """A copy of ``rig`` whose extrinsics are off by ``angle_deg`` and ``shift_mm``.

    ``each_camera=False`` (condition ``rig-perturbed``): the rig moves as one body, turned by
    exactly ``angle_deg`` about a random axis through the midpoint of the camera centres and
    shifted by exactly ``shift_mm`` in a random direction: the stereo geometry stays consistent
    and every triangulated point lands in a wrong world frame (a badly measured base frame).
    ``each_camera=True`` (``rig-perturbed-cams``): each camera turns and moves on its own by those
    amounts (inconsistent stereo: rays no longer meet).

    The random directions come from ``numpy.random.default_rng([seed, 0x5EED])``. Intrinsics and
    distortion are unchanged. The copy's ``true_rig`` names the rig the images are rendered with
    (``true_rig``, default the original's file), so a run believing the copy renders with the
    truth and estimates with the copy.

    Parameters
    ----------
    rig : Rig
        The rig believed to be true.
    seed : int
        The run's seed; the same seed gives the same perturbation.
    angle_deg, shift_mm : float
        The size of the turn (deg) and of the shift (mm), exactly.

    Returns
    -------
    Rig
        The perturbed copy (its ``true_rig`` names the rig to render with).
    """
    rng = np.random.default_rng([int(seed), 0x5EED])

    def draw():
        axis, d = rng.normal(size=3), rng.normal(size=3)
        rvec = np.asarray(axis, float) / np.linalg.norm(axis) * math.radians(angle_deg)
        return cv2.Rodrigues(rvec)[0], shift_mm * d / np.linalg.norm(d)

    centres = [c.position_mm for c in rig.cameras]
    pivot = np.mean(centres, axis=0)
    dR, shift = draw()
    cams = []
    for cam, C in zip(rig.cameras, centres):
        if each_camera:
            dR, shift = draw()
            C_new = C + shift
        else:
            C_new = pivot + dR @ (C - pivot) + shift
        R = cam.R @ dR.T  # the camera's axes turn with the body: R' = R dR^T
        cams.append(Camera.from_arrays(cam.name, cam.size, cam.K, cam.dist_coeffs, R, -R @ C_new,
                                       cam.noise_sigma_gray, cam.exposure))
    truth = true_rig if true_rig is not None else (rig.true_rig or rig.source)
    if not truth:
        raise ValueError("perturbed: the rig has no source file; pass true_rig")
    record = {"perturbed": {"from": str(rig.source or truth), "seed": int(seed),
                            "angle_deg": float(angle_deg), "shift_mm": float(shift_mm),
                            "each_camera": bool(each_camera)}}
    return Rig(f"{rig.name}-perturbed", tuple(cams), "", record, str(Path(truth).resolve()))

