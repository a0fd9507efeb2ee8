"""Stereo calibration from board views, tied to the robot's base by the joint axes the LEDs trace.

The board, its poses, views and corners: :mod:`itg_vision.board`. From the corners:

1. **Intrinsics** (:func:`calibrate_views`). ``cv2.calibrateCameraExtended`` per camera on every
   view in which that camera found the board (K and k1, k2, p1, p2; k3 is fixed at 0: a modest
   lens, poorly constrained by a board that rarely reaches the image corners), from OpenCV's
   start (principal point at the image centre) and from Zhang's closed form, the lower
   reprojection RMS kept (:func:`_mono_best`: a principal point far from the centre traps the
   first in a local minimum). Views whose
   per-view RMS exceeds ``3 x`` the median (and 0.3 px) are dropped and the camera recalibrated.
   Degenerate pose sets (board normals spanning too little tilt about either axis, or a focal
   length whose standard deviation exceeds 1 %) are refused.
2. **Stereo.** ``cv2.stereoCalibrate`` with ``CALIB_FIX_INTRINSIC`` on the views in which both
   cameras found the full board: camera 2 relative to camera 1 (R, T). A stereo RMS the
   cameras' own does not explain refuses the calibration (:data:`MAX_STEREO_EXCESS_PX`).
3. **Base frame.** Stereo calibration leaves the rig floating in camera 1's frame. It is tied to
   the robot's base by what the LEDs trace when one joint moves at a time
   (:func:`base_frame_from_axes`): the LEDs are detected by the tracker's own eye
   (:class:`itg_vision.feedback.VisionFeedback`, with the *calibrated* cameras) and triangulated in camera-1 coordinates along each sweep,
   and circle fits give each joint's axis and centre. The base joint's axis is world z, its
   zero (commanded q1 = 0) world x; the three-link shoulder axis fixes the height of the
   shoulder. No link length is used (the LED stand-off is a mounting dimension; the three-link
   arm's base height places the unseen floor), so a wrong nominal model cannot move the frame;
   a joint-zero offset of q1 turns it (that is what q1 = 0 means). Its error: the fits' RMS
   residual (``base_frame.fit_rms_mm``) and, since the truth is known, the cameras' rotation
   and position errors (:func:`rig_errors`). A fit worse than the LEDs' noise allows through
   the calibrated pair refuses the calibration (:func:`check_circle_fits`): wrong intrinsics
   bend the LEDs' paths off their circles.
4. **Check.** At other seeded arm poses the LEDs are triangulated with the true rig and with the
   calibrated rig from the same images; both RMS errors against the simulator's LED positions
   and their ratio are reported.

:func:`calibrate` does it all and returns a :class:`Result`; :func:`write_result` writes the
calibrated rig (the rig schema with a ``calibration`` section and ``true_rig``, the rig that
rendered, relative to the file's folder, with ``true_rig_sha256``, its content hash) and a
picture of the detected corners of one view, titled with the rig, the camera and the view
(``<name>.png`` beside it). The command line: :mod:`itg_vision.calibrate`.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from . import outputs
from .board import Board, Views, render_views, sample_board_poses
from .camera import Camera, Rig
from .errors import UserError
from .imaging import opencv_threads
from .inputs import file_sha256

#: Fewest views (board found by both cameras) accepted for a calibration.
MIN_VIEWS = 6
#: Board normals must span at least this tilt (deg, full range) about two orthogonal axes
#: (measured: 70 to 80 with --tilt 45, 22 to 31 with --tilt 0).
MIN_TILT_SPAN_DEG = 40.0
#: Largest relative standard deviation of the focal length accepted (degenerate poses).
MAX_FOCAL_STD = 0.01
#: Default number of board views.
DEFAULT_VIEWS = 60
#: The most board views ``calibrate --views`` takes.
MAX_VIEWS = 1000
#: The LED centroid error (RMS length of the 2-D error, px) that the base tie's circle fits are
#: judged against: the largest this eye (the tracker's own, :class:`itg_vision.feedback.
#: VisionFeedback`, as the calibration uses it) is measured to make, 0.144 px on the three-link
#: arm, whose LED posts hide a strip of each sphere (``bench accuracy --arm three-link``, 250
#: poses; the planar arm's is 0.024 px). Sensor noise adds little: an intensity centroid over
#: a flat disc of contrast C grey levels has a per-axis std of sigma_gray / (2 sqrt(pi) C)
#: whatever its size, 0.003 px at the rigs' 2 grey levels (C ~ 200).
LED_CENTROID_RMS_PX = 0.15
#: How far a circle fit's RMS residual may exceed what that centroid error predicts for it
#: (:func:`circle_fit_bound_mm`). With the right rig the residuals are the triangulation noise:
#: the mean square of the 2n residual components of n >= 16 points (3/4 of a 21-25 pose sweep)
#: then exceeds 4x its expectation (2x in RMS) with probability < 1e-12 (chi-square, 32 degrees
#: of freedom, an upper bound as the fit absorbs some of them). The rest of the factor covers
#: errors that are not Gaussian (the posts' crescents are systematic). A calibration whose
#: intrinsics sit in a wrong minimum warps the triangulated paths off their circles: 1.4 to 5.3
#: mm RMS on the far-principal-point rig, 2.3 to 9 times this bound (0.56 to 0.59 mm there);
#: right calibrations measured 0.037 to 0.19 mm, 0.06 to 0.23 of it.
FIT_RMS_FACTOR = 2.0
#: The most the stereo fit's reprojection error may exceed the cameras' own (px, RMS length,
#: :func:`stereo_excess_px`). The stereo fit reprojects the same corners as the two mono fits
#: with one board pose per view instead of two: with consistent cameras its mean square exceeds
#: theirs only by the parameters it drops (6 of ~216 coordinates per view, ~3 %: 0.02-0.04 px
#: of excess measured). What exceeds that is the two lens models disagreeing about where the
#: board, and so an LED, is: it shifts an LED's two images against each other as centroid
#: error does, so it is held to the LEDs' bound: FIT_RMS_FACTOR x LED_CENTROID_RMS_PX. The
#: far-principal-point rig's local minimum: 0.61 px (stereo 0.66 against 0.25 px).
MAX_STEREO_EXCESS_PX = FIT_RMS_FACTOR * LED_CENTROID_RMS_PX

def arm_of_rig(rig_name: str) -> str:
    """The arm whose LEDs tie a shipped rig to the base: of the arms that use the rig by
    default, the one with the most LEDs (two circles per joint sweep fit better than one; the
    one-link arm shares the planar rig but carries one LED, on one circle: too little for the
    base fit); two-link for a rig of the user's own."""
    from .arm import ArmSpec, arm_names

    arms = [ArmSpec.from_args(n) for n in arm_names()]
    users = [a for a in arms if a.defaults["rig"] == rig_name]
    return max(users, key=lambda a: len(a.marker_names)).name if users else "two-link"


# ---------------------------------------------------------------------------- calibration
@dataclass
class StereoCalibration:
    """What the board views give: intrinsics of both cameras and camera 2 relative to camera 1.

    ``x_cam2 = R @ x_cam1 + T_mm``. ``rms_px`` and ``per_view_rms_px`` are the monocular
    reprojection errors after outlier removal; ``used`` the view indices each camera's
    calibration kept, ``stereo_views`` those of the stereo calibration (board in both).
    ``intrinsics_std_px``: per camera, the standard deviations of fx, fy, cx, cy (px) that
    ``cv2.calibrateCameraExtended`` estimates. A principal-point error of ``dc`` px cannot be
    told from a camera rotation of ``dc / f`` rad, so it bounds how well the camera's pose,
    and with it the base frame seen from the camera, can be known.
    """

    K: tuple[np.ndarray, np.ndarray]
    dist: tuple[np.ndarray, np.ndarray]
    R: np.ndarray
    T_mm: np.ndarray
    rms_px: tuple[float, float]
    stereo_rms_px: float
    per_view_rms_px: tuple[np.ndarray, np.ndarray]
    used: tuple[list[int], list[int]]
    stereo_views: list[int]
    dropped: list[int]
    focal_std_rel: tuple[float, float]
    tilt_span_deg: tuple[float, float]
    n_found: tuple[int, int] = (0, 0)
    intrinsics_std_px: tuple[np.ndarray, np.ndarray] | None = None
    n_found_both: int = 0  # views in which both cameras found the board (before dropping)
    start: tuple[str, str] = ("image centre", "image centre")  # each camera's winning start


def tilt_spans_deg(rvecs) -> tuple[float, float]:
    """Spread of the board's orientation over the views, about two orthogonal axes (deg).

    The board normals (camera frame) are projected on the plane perpendicular to their mean;
    the result is the full range (max - min) of the angles along the two principal directions
    of that spread, larger first. Zhang's method needs non-parallel board planes: a small
    second value means the poses are (close to) degenerate.
    """
    normals = np.array([cv2.Rodrigues(np.asarray(r, float))[0][:, 2] for r in rvecs])
    m = normals.mean(axis=0)
    m /= np.linalg.norm(m)
    d = normals - np.outer(normals @ m, m)
    if len(d) < 2:
        return 0.0, 0.0
    _, _, Vt = np.linalg.svd(d - d.mean(axis=0), full_matrices=False)
    spans = []
    for axis in Vt[:2]:
        ang = np.degrees(np.arcsin(np.clip(d @ axis, -1, 1)))
        spans.append(float(ang.max() - ang.min()))
    return spans[0], spans[1]


def zhang_camera_matrix(obj_points, img_points, size) -> np.ndarray | None:
    """Zhang's closed-form camera matrix from the views' homographies (no lens distortion).

    Each view's homography H = [h1 h2 h3] (board plane -> image, ``cv2.findHomography``) gives
    two linear constraints on B = K^-T K^-1 (h1^T B h2 = 0, h1^T B h1 = h2^T B h2); their
    least-squares solution over all views gives fx, fy, cx, cy and a skew, dropped (Zhang 2000,
    "A flexible new technique for camera calibration", sec. 3.1). Unlike OpenCV's own start
    (``initCameraMatrix2D``: the principal point at the image centre, only the focal length
    solved for), the principal point is measured. The lens bends the homographies, so it is a
    start for :func:`_mono`, not a result: 60-100 px from the truth on rigs whose principal
    points lie 250-330 px from the image centre (k1 from -0.3 to +0.2), from where the solver
    reaches the truth; from the centre it stopped 60-140 px away on those rigs.

    Parameters
    ----------
    obj_points : list of arrays, shape (n, 3), z = 0 (mm).
    img_points : list of arrays, shape (n, 1, 2) (px).
    size : (width, height) of the image.

    Returns
    -------
    K : ndarray, shape (3, 3); None if the views do not determine it (B not positive definite)
        or its principal point falls outside the image (OpenCV refuses such a start).
    """
    def v(H, i, j):
        return np.array([H[0, i] * H[0, j], H[0, i] * H[1, j] + H[1, i] * H[0, j],
                         H[1, i] * H[1, j], H[2, i] * H[0, j] + H[0, i] * H[2, j],
                         H[2, i] * H[1, j] + H[1, i] * H[2, j], H[2, i] * H[2, j]])

    rows = []
    for o, im in zip(obj_points, img_points):
        H, _ = cv2.findHomography(np.asarray(o, float)[:, :2], np.asarray(im, float).reshape(-1, 2))
        if H is None:
            continue
        H = H / np.linalg.norm(H)
        rows += [v(H, 0, 1), v(H, 0, 0) - v(H, 1, 1)]
    if len(rows) < 6:  # three views at least (five unknowns and the scale)
        return None
    B11, B12, B22, B13, B23, B33 = np.linalg.svd(np.array(rows))[2][-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        d = B11 * B22 - B12**2
        cy = (B12 * B13 - B11 * B23) / d
        lam = B33 - (B13**2 + cy * (B12 * B13 - B11 * B23)) / B11
        fx = np.sqrt(lam / B11)
        fy = np.sqrt(lam * B11 / d)
        cx = -B13 * fx**2 / lam + (-B12 * fx**2 * fy / lam) * cy / fy
    W, H = size
    if not (np.all(np.isfinite([fx, fy, cx, cy])) and 0 <= cx < W and 0 <= cy < H):
        return None
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


#: Two starts whose reprojection RMS agree to this fraction found the same minimum, and the
#: image-centre start's result is kept (a camera it calibrated right gives the same result, bit
#: for bit, as when it was the only start). Runs reaching one minimum from different starts
#: agree to 1e-15 (measured), or 1e-9 when the solver's 100 iterations end before it settles;
#: distinct minima differ by percents (0.26 against 0.13 px on the far-principal-point rig),
#: and no data could tell apart two whose RMS differ by less than its own sampling error
#: (~1 % for the ~5000 corners of 50 views).
SAME_MINIMUM_REL = 1e-6


def _mono(obj, img, size, flags, K0=None, dist0=None, start="image centre"):
    """``cv2.calibrateCameraExtended`` of one camera: from OpenCV's own start (``K0`` None) or
    from ``K0`` (and ``dist0``, default none), ``CALIB_USE_INTRINSIC_GUESS``. Returns (rms, K,
    dist, rvecs, per-view rms, std of the intrinsics, the start's name)."""
    if K0 is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
        K0 = np.array(K0, float)
        dist0 = np.zeros(5) if dist0 is None else np.array(dist0, float).ravel()[:5]
    rms, K, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
        obj, img, size, K0, dist0, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    return rms, K, dist.ravel(), rvecs, per_view.ravel(), std_in.ravel(), start


def _mono_best(obj, img, size, flags, previous=None):
    """One camera's calibration from several starts; the lowest reprojection RMS wins.

    The reprojection error of a lens whose principal point is far from the image centre has
    local minima: from OpenCV's start (principal point at the centre), the tangential terms
    p1, p2, which to first order shift the centre of the radial distortion, take up the offset
    and the solver stops there (principal points ~260 px from the centre, k1 -0.15: 0.26 px
    RMS, 110-120 px off, p2 = 0.024, against 0.13 px from the true K). So the camera is also
    calibrated from Zhang's closed-form K (:func:`zhang_camera_matrix`, principal point
    measured) coarse to fine: first with p1 = p2 = 0 (``CALIB_ZERO_TANGENT_DIST``: only the
    principal point can centre the distortion), then with everything free from there; and,
    when ``previous`` (a :func:`_mono` result on more views) is given, from that solution. A
    start OpenCV refuses (principal point driven out of the image) is skipped. The image-centre
    start keeps ties (:data:`SAME_MINIMUM_REL`). Returns :func:`_mono`'s tuple, whose last item
    names the start that won.
    """
    best = _mono(obj, img, size, flags)

    def zhang():
        K0 = zhang_camera_matrix(obj, img, size)
        if K0 is None:
            return None
        coarse = _mono(obj, img, size, flags | cv2.CALIB_ZERO_TANGENT_DIST, K0)
        return _mono(obj, img, size, flags, coarse[1], coarse[2], "Zhang's closed form, "
                     "tangential terms freed second")

    starts = [zhang]
    if previous is not None:
        starts.append(lambda: _mono(obj, img, size, flags, previous[1], previous[2],
                                    f"the solution on all views ({previous[6]})"))
    for start in starts:
        try:
            r = start()
        except cv2.error:  # e.g. "Principal point must be within the image"
            continue
        if r is not None and np.isfinite(r[0]) and r[0] < best[0] * (1 - SAME_MINIMUM_REL):
            best = r
    return best


def calibrate_views(views: Views, board: Board, sizes: tuple[tuple[int, int], ...],
                    camera_labels=("camera 1", "camera 2"), *, source: str = "",
                    min_views: int = MIN_VIEWS,
                    apart_deg: float | None = None) -> StereoCalibration:
    """Mono calibration of each camera, outlier views out, then stereo calibration.
    ``sizes``: each camera's image size (width, height), px.
    ``camera_labels``: how a message names each camera (:func:`calibrate`: its place in the
    rig, ``cameras[0] (left)``); ``source``: the rig file the messages name first;
    ``apart_deg``: the angle between the cameras' optical axes, which a message names when no
    view showed the board to both.

    Raises
    ------
    UserError : a camera never found the board, too few views with the board in both cameras,
        degenerate poses, or a stereo fit that the cameras' intrinsics do not explain
        (:data:`MAX_STEREO_EXCESS_PX`).
    """
    n = len(views.corners)
    where = f"{source}: " if source else ""
    found = [sum(c[i] is not None for c in views.corners) for i in range(2)]
    for i in range(2):
        if found[i] == 0:
            raise UserError(f"{where}{camera_labels[i]}: never found the board in {n} views: is it "
                            f"pointed at the workspace?")
    seen = [[k for k, c in enumerate(views.corners) if c[i] is not None] for i in range(2)]
    both = [k for k in seen[0] if k in set(seen[1])]
    if len(both) < min_views:
        each = ", ".join(f"{lab} {k}" for lab, k in zip(camera_labels, found))
        if not both:
            apart = f", whose axes are {apart_deg:.0f} deg apart" if apart_deg is not None else ""
            hint = (f"no view showed it to both cameras{apart}: the board, printed on one "
                    "side, faced one or the other in every view; more --views are unlikely to "
                    "help, cameras closer in angle would")
        else:  # more views, at the rate this sample showed the board to both
            need = math.ceil(n * min_views / len(both))
            hint = (f"at this rate about --views {need} would show it to both {min_views} times"
                    if need <= MAX_VIEWS else
                    f"at this rate {need} views would show it to both {min_views} times, more "
                    f"than the {MAX_VIEWS} --views allows: point the cameras at a common view")
        raise UserError(f"{where}the board was found by both cameras in only {len(both)} of {n} "
                        f"views (each camera alone: {each}); need at least {min_views} ({hint})")
    obj_board = board.object_points()
    flags = cv2.CALIB_FIX_K3
    dropped: set[int] = set()
    res = []
    for i in range(2):  # each camera: all its views, then again without its outliers
        used = seen[i]
        r = _mono_best([obj_board] * len(used), [views.corners[k][i] for k in used], sizes[i],
                       flags)
        limit = max(3.0 * float(np.median(r[4])), 0.3)
        bad = {used[j] for j in np.flatnonzero(r[4] > limit)}
        if bad and len(used) - len(bad) >= min_views:
            dropped |= bad
            used = [k for k in used if k not in bad]
            r = _mono_best([obj_board] * len(used), [views.corners[k][i] for k in used],
                           sizes[i], flags, previous=r)
        res.append((used, r))
    n_found_both = len(both)
    both = [k for k in both if k not in dropped]
    if len(both) < min_views:
        raise UserError(f"{where}only {len(both)} of the {n_found_both} views with the board in "
                        f"both cameras are left after dropping each camera's outliers "
                        f"{sorted(dropped)} (reprojection RMS over 3x its median and 0.3 px: a "
                        "board seen too obliquely, as by cameras facing it from very different "
                        f"directions, or blurred); need at least {min_views}")
    spans = tilt_spans_deg(res[0][1][3])
    std_rel = tuple(float(r[5][0] / r[1][0, 0]) for _, r in res)
    if min(spans) < MIN_TILT_SPAN_DEG or not all(np.isfinite(r[0]) for _, r in res):
        raise UserError(f"{where}degenerate board poses: the board's tilt spans only "
                        f"{spans[0]:.0f} x {spans[1]:.0f} deg over {len(res[0][0])} views (need "
                        f"{MIN_TILT_SPAN_DEG:.0f} about two axes; focal std "
                        f"{100 * max(std_rel):.2f} %): tilt the board more")
    if max(std_rel) > MAX_FOCAL_STD:  # tilted enough, and still not pinned down
        raise UserError(f"{where}degenerate board poses: the focal length's std is "
                        f"{100 * max(std_rel):.2f} % (at most {100 * MAX_FOCAL_STD:g} %) over "
                        f"{len(res[0][0])} views whose tilt spans {spans[0]:.0f} x {spans[1]:.0f} "
                        "deg, enough: the corners are too noisy or too few (more views, or the "
                        "board nearer the cameras)")
    (u1, (rms1, K1, d1, _, pv1, sd1, st1)), (u2, (rms2, K2, d2, _, pv2, sd2, st2)) = res
    srms, K1, d1, K2, d2, R, T, _, _ = cv2.stereoCalibrate(
        [obj_board] * len(both), [views.corners[k][0] for k in both],
        [views.corners[k][1] for k in both],
        K1, d1, K2, d2, sizes[0], flags=cv2.CALIB_FIX_INTRINSIC,  # size unused: intrinsics fixed
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    excess = stereo_excess_px(srms, (rms1, rms2))
    if not excess <= MAX_STEREO_EXCESS_PX:
        raise UserError(f"{where}calibration inconsistent: the pair reprojects the board with "
                        f"RMS {srms:.3f} px against its cameras' {rms1:.3f} and {rms2:.3f} px, an "
                        f"excess of {excess:.2f} px, over the {MAX_STEREO_EXCESS_PX:.2f} px the "
                        "LEDs' centroid error allows: the cameras' intrinsics disagree (at least "
                        "one is wrong)")
    return StereoCalibration((K1, K2), (d1.ravel(), d2.ravel()), R, T.ravel(),
                             (float(rms1), float(rms2)), float(srms), (pv1, pv2),
                             (u1, u2), both, sorted(dropped), std_rel, spans,
                             (len(seen[0]), len(seen[1])), (sd1[:4], sd2[:4]), n_found_both,
                             (st1, st2))


def stereo_excess_px(stereo_rms_px: float, mono_rms_px) -> float:
    """How much the stereo fit's reprojection error exceeds the cameras' own (px): the square
    root of the difference of the mean squares (the mono RMS pooled), 0 if it does not.
    Bounded by :data:`MAX_STEREO_EXCESS_PX`."""
    return float(np.sqrt(max(stereo_rms_px**2 - float(np.mean(np.square(mono_rms_px))), 0.0)))


def rig_in_camera1_frame(true_rig: Rig, cal: StereoCalibration, name: str) -> Rig:
    """The calibrated rig with camera 1 at the origin (world = camera-1 frame)."""
    cams = []
    for i, (c, R, t) in enumerate(zip(true_rig.cameras, (np.eye(3), cal.R),
                                      (np.zeros(3), cal.T_mm))):
        cams.append(Camera.from_arrays(c.name, c.size, cal.K[i], cal.dist[i], R, t,
                                       c.noise_sigma_gray, c.exposure))
    return Rig(name, (cams[0], cams[1]))


def place_rig(rig_c1: Rig, R_w: np.ndarray, t_w: np.ndarray, name: str) -> Rig:
    """Move a camera-1-frame rig into the world: ``x_cam1 = R_w X_world + t_w``."""
    cams = []
    for c in rig_c1.cameras:
        cams.append(Camera.from_arrays(c.name, c.size, c.K, c.dist_coeffs, c.R @ R_w,
                                       c.R @ t_w + c.t_mm, c.noise_sigma_gray, c.exposure))
    return Rig(name, (cams[0], cams[1]))


# ---------------------------------------------------------------------------- LEDs
def led_images(world, rig: Rig, arm, q_list, rng, *, progress=None):
    """What the tracker's eye sees of the LEDs at each joint pose: both cameras of ``rig``
    through :meth:`itg_vision.feedback.VisionFeedback.capture_pair` (sensor noise from
    ``rng``), at the rig file's supersample, as a run's eye. Returns a list of (q, patches,
    true LEDs)."""
    from .feedback import DEFAULT_SUPERSAMPLE, VisionFeedback

    eye = VisionFeedback(rig, rig, arm, supersample=rig.supersample or DEFAULT_SUPERSAMPLE)
    eye.reset(int(rng.integers(2**32)))
    out = []
    for q in q_list:
        world.set_q(q)
        out.append((np.asarray(q, float), eye.capture_pair(world), world.true_markers()))
        if progress is not None:
            progress()
    return out


def triangulate_leds(rig: Rig, arm, patches) -> dict[str, np.ndarray]:
    """The LEDs in ``patches`` (from :func:`led_images`) located, undistorted and
    triangulated with ``rig``'s cameras, by the tracker's own
    :meth:`~itg_vision.feedback.VisionFeedback.detect` and
    :meth:`~itg_vision.feedback.VisionFeedback.triangulate` (its residual and blob-area
    checks included).

    Returns
    -------
    dict marker -> X_mm (3,) (rig's frame) for the markers accepted.
    """
    from .feedback import VisionFeedback

    eye = VisionFeedback(rig, rig, arm)
    points = eye.triangulate(eye.detect(patches))[0]
    return points


def axis_sweeps(arm) -> dict[int, tuple[np.ndarray, tuple[str, ...]]]:
    """Poses that turn one joint at a time, and the LEDs that joint moves, from the arm file's
    ``calibration.axis_sweeps``.

    Returns
    -------
    {joint index (0-based): (joint angles in deg, shape (n, n_joints), marker names)}; the
    angles increase along each sweep.
    """
    out = {}
    for sw in arm.calibration["axis_sweeps"]:
        j = int(sw["joint"]) - 1
        q = np.tile([0.0 if v is None else float(v) for v in sw["pose_deg"]], (sw["poses"], 1))
        q[:, j] = np.linspace(sw["from_deg"], sw["to_deg"], sw["poses"])
        out[j] = (q, tuple(sw["markers"]))
    return out


def _sweep_seen_enough(arm, joint: int, name: str, seen: int, poses: int, source: str = "",
                       how: str = "was seen by both cameras", detail: str = "") -> None:
    """Raise `UserError` unless the ``name`` LED was seen (``how``; ``detail`` follows the count)
    in 3/4 of the ``poses`` of joint ``joint``'s sweep (0-based), the least its circle fit
    takes."""
    need = math.ceil(0.75 * poses)
    if seen < need:
        where = f"{source}: " if source else ""
        raise UserError(f"{where}base frame: {arm.label}, joint q{joint + 1}'s sweep: the {name} "
                        f"LED {how} in only {seen} of {poses} poses{detail}; need at least "
                        f"{need}: both cameras must see the LEDs over the arm's joint sweeps "
                        "(check the rig's camera poses, or narrow the sweep to what the rig "
                        "sees: the arm file's calibration.axis_sweeps)")


def sweeps_in_view(true_rig: Rig, arm, sweep_poses: dict, source: str = "",
                   true_arm=None) -> None:
    """Refuse, before anything is rendered, joint sweeps (:func:`axis_sweeps`) whose LEDs
    ``true_rig``'s cameras cannot both show in 3/4 of the poses: counted by their fields of
    view (:func:`itg_vision.visibility.in_view`), with no margin beyond the LED's disc (the
    detector rejects an LED that reaches the image border), so a pose counted out is one the
    eye misses, but at the edges of its gates (a strong barrel lens shrinks an LED near the
    border by a pixel or so; a roundness within a few hundredths of the detector's 0.75).
    ``true_arm``: the simulated arm, if it differs from ``arm``."""
    from .arm import forward_kinematics
    from .visibility import in_view

    for j, (q, names) in sweep_poses.items():
        for n in names:
            X = np.array([forward_kinematics(true_arm or arm, qk)[n] for qk in q])
            alone = [in_view([c], X, margin_px=0.0) for c in true_rig.cameras]
            each = ", ".join(f"cameras[{i}] ({c.name}) {int(k.sum())}"
                             for i, (c, k) in enumerate(zip(true_rig.cameras, alone)))
            seen = int(np.logical_and.reduce(alone).sum())  # in view of both
            _sweep_seen_enough(arm, j, n, seen, len(q), source, "is in view of both cameras",
                               f" (their fields of view, before rendering; each camera alone: "
                               f"{each})")


def _joint_fits(rig_c1: Rig, arm, joint: int, shots, names, source: str = "") -> dict[str, dict]:
    """Circle fits of the LEDs one joint's sweep moved (camera-1 coordinates); ``source``: the
    rig file a message names first."""
    from .identify import coaxial_normal, fit_circle, rotation_sense_axis

    pts: dict[str, list] = {n: [] for n in names}
    angles: dict[str, list] = {n: [] for n in names}
    for q, imgs, _ in shots:
        X = triangulate_leds(rig_c1, arm, imgs)
        for n in names:
            if n in X:
                pts[n].append(X[n])
                angles[n].append(float(q[joint]))
    out = {}
    for n in names:
        _sweep_seen_enough(arm, joint, n, len(pts[n]), len(shots), source)
    axis = coaxial_normal([pts[n] for n in names])  # every LED turns about the same axis
    for n in names:
        centre, normal, radius, rms = fit_circle(pts[n], axis)
        out[n] = {"centre": centre, "axis": rotation_sense_axis(centre, normal, pts[n]),
                  "radius_mm": radius, "rms_mm": rms, "points": np.array(pts[n]),
                  "angles_deg": np.array(angles[n])}
    return out


def circle_fit_bound_mm(rig: Rig, fit: dict) -> float:
    """The largest RMS residual (mm) a joint's circle fit may have if ``rig`` is right: the
    residual the LED centroid error :data:`LED_CENTROID_RMS_PX` predicts, times
    :data:`FIT_RMS_FACTOR`.

    A point's distance from its circle has two components, radial (in the circle's plane) and
    along the axis; the third, along the circle, slides the point on it and costs nothing. With
    centroid noise sigma per image axis, on the pixels as captured (where the eye's error
    arises), the triangulated point's covariance is the lens-aware first-order one
    (:func:`itg_vision.triangulate.predicted_covariance` with ``distort=True``, through ``rig``;
    the pinhole form, sigma^2 (J^T J)^-1, misses it by 8 % for a 190 mm circle seen through
    k1 = -0.5 lenses, by under 1 % on the shipped rigs), so the expected mean square residual
    is the mean over the fit's points of
    e_r^T C e_r + a^T C a (e_r radial, a the axis), an upper bound (the fit absorbs its six
    parameters' worth).

    Parameters
    ----------
    rig : the pair the points were triangulated with (camera-1 frame).
    fit : one LED's fit from :func:`_joint_fits` (``points`` (n, 3), ``centre``, ``axis``).
    """
    from .triangulate import predicted_covariance

    X = np.asarray(fit["points"], float)
    a = np.asarray(fit["axis"], float)
    C = predicted_covariance(rig, X, LED_CENTROID_RMS_PX / math.sqrt(2),  # per axis
                             distort=True)
    d = X - fit["centre"]
    radial = d - np.outer(d @ a, a)
    radial /= np.linalg.norm(radial, axis=1)[:, None]
    ms = np.einsum("ni,nij,nj->n", radial, C, radial) + np.einsum("i,nij,j->n", a, C, a)
    return FIT_RMS_FACTOR * float(np.sqrt(np.mean(ms)))


def check_circle_fits(rig_c1: Rig, fits: dict, source: str = "") -> dict:
    """Refuse a calibration whose joint-axis circle fits are worse than the LED noise allows.

    Every fit's RMS residual is compared with :func:`circle_fit_bound_mm`. A rig that is right
    triangulates each LED's path on its circle to within the eye's noise; one whose intrinsics
    are wrong (a principal point in a local minimum, 100 px off) bends the path off it by
    millimetres, where the board's reprojection RMS only doubles.

    Parameters
    ----------
    fits : {joint: {marker: fit}} from :func:`_joint_fits`.

    Returns
    -------
    The worst fit against its bound: {"fit", "rms_mm", "bound_mm"} (for the record).

    Raises
    ------
    UserError : one line naming the rig file, the fit, its RMS and its bound.
    """
    rows = [(f"q{j + 1}", n, f["rms_mm"], circle_fit_bound_mm(rig_c1, f))
            for j, fj in sorted(fits.items()) for n, f in fj.items()]
    joint, led, rms, bound = max(rows, key=lambda r: r[2] / r[3])
    if not rms <= bound:
        where = f"{source}: " if source else ""
        raise UserError(
            f"{where}calibration inconsistent: base frame: the {led} LED's circle about joint "
            f"{joint} fits with RMS {rms:.2f} mm, over the {bound:.2f} mm its noise allows "
            f"({FIT_RMS_FACTOR:g} x what {LED_CENTROID_RMS_PX} px of centroid error predicts "
            "through the calibrated pair): the calibrated lenses bend the LEDs' paths, their "
            "intrinsics are wrong")
    return {"fit": f"{joint} {led}", "rms_mm": rms, "bound_mm": bound}


def base_frame_from_axes(rig_c1: Rig, arm, sweeps: dict, *,
                         source: str = "") -> tuple[np.ndarray, np.ndarray, dict]:
    """World (base) frame in camera-1 coordinates from the joint axes the LEDs trace.

    Each sweep turns one joint; every LED it moves runs on a circle about that joint's axis
    (:func:`itg_vision.identify.fit_circle`), oriented by the commanded angles' order. The base
    joint's axis is the world z axis through the origin; its zero is where link 1 points at
    q1 = 0 (the elbow LED, or the one-link gripper, lies on link 1). Planar arms: the origin
    is the circles' common centre moved down by the LED stand-off (the LEDs' mounting height
    above the links). Three-link arm: the shoulder axis (a pitch joint's circle) gives the
    arm's plane at q1 = 0 (world y = minus the pitch axis) and the shoulder point on the base
    axis; the origin is the nominal base height L1 below it (the floor itself is not seen).
    No link length enters otherwise: a wrong nominal model cannot move the frame.

    Parameters
    ----------
    rig_c1 : the calibrated pair in camera-1 coordinates.
    arm : the nominal arm (its structure, stand-off and, three-link only, L1).
    sweeps : {joint: (shots, marker names)}, shots from :func:`led_images`.
    source : the rig file a message names first (:func:`calibrate`: the true rig's).

    Raises
    ------
    UserError : an LED seen by both cameras in fewer than 3/4 of a sweep's poses (one line
        naming the rig file, the arm, the joint, the LED and the count needed); a circle fit
        worse than the LED noise allows (:func:`check_circle_fits`).

    Returns
    -------
    R_w, t_w : ``x_cam1 = R_w X_world + t_w``; record : the fits, for the calibration file.
    """
    from .identify import zero_direction

    fits = {j: _joint_fits(rig_c1, arm, j, shots, names, source)
            for j, (shots, names) in sweeps.items()}
    worst = check_circle_fits(rig_c1, fits, source)
    base = fits[0]
    z = np.sum([f["axis"] for f in base.values()], axis=0)
    z /= np.linalg.norm(z)
    c = np.mean([f["centre"] for f in base.values()], axis=0)
    record = {"method": "joint axes traced by the LEDs, one joint at a time (circle fits)",
              "arm": arm.name,
              "sweeps": {f"q{j + 1}": {"poses": len(shots), "markers": list(names)}
                         for j, (shots, names) in sweeps.items()},
              "fit_rms_mm": max(f["rms_mm"] for fj in fits.values() for f in fj.values()),
              "worst_fit": worst}
    if arm.planar:
        on_link1 = base["elbow"] if "elbow" in base else base["gripper"]
        x = zero_direction(c, z, on_link1["points"], on_link1["angles_deg"])
        origin = c - arm.led_standoff_mm * z
        measured = [on_link1["radius_mm"]]
        # the elbow's circle about the base is L1 (one link: the gripper's); else the gripper's
        names = ["L1" if "elbow" in base or len(arm.links_mm) == 1 else "|gripper|"]
        if 1 in fits:
            measured.append(fits[1]["gripper"]["radius_mm"])
            names.append("L2")
        record["nominal_used"] = f"LED stand-off {arm.led_standoff_mm:g} mm (the LEDs' height above the links)"
    else:
        shoulder = fits[1]
        a = np.sum([f["axis"] for f in shoulder.values()], axis=0)
        a -= (a @ z) * z
        a /= np.linalg.norm(a)
        x = np.cross(-a, z)  # at q1 = 0 the pitch axis is world -y: x = y x z
        C2 = np.mean([f["centre"] for f in shoulder.values()], axis=0)
        S = c + ((C2 - c) @ z) * z
        origin = S - arm.links_mm[0] * z
        record["standoff_mm"] = float(np.linalg.norm(C2 - S))
        # L3: the LEDs' distance in the poses where both were seen (either may miss a few)
        gripper_at = dict(zip(shoulder["gripper"]["angles_deg"], shoulder["gripper"]["points"]))
        measured = [shoulder["elbow"]["radius_mm"], float(np.median(
            [np.linalg.norm(gripper_at[q] - e) for q, e in zip(shoulder["elbow"]["angles_deg"],
                                                              shoulder["elbow"]["points"])
             if q in gripper_at]))]
        names = ["L2", "L3"]  # L1 is the base height, not seen
        record["nominal_used"] = (f"base height L1 = {arm.links_mm[0]:g} mm below the measured "
                                  "shoulder (the floor is not seen)")
    y = np.cross(z, x)
    R_w = np.column_stack([x, y, z])
    record["measured_links_mm"] = measured
    record["measured_links"] = names
    return R_w, origin, record


def led_errors(rig: Rig, arm, shots) -> dict[tuple[int, str], float]:
    """Triangulation error (mm) of each (shot, marker) found, against the true LED positions."""
    out = {}
    for k, (_, imgs, truth) in enumerate(shots):
        for name, X in triangulate_leds(rig, arm, imgs).items():
            out[(k, name)] = float(np.linalg.norm(X - truth[name]))
    return out


# ---------------------------------------------------------------------------- errors
def _rot_angle_deg(R: np.ndarray) -> float:
    """Angle (deg) of a rotation matrix."""
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(np.asarray(R, float))[0])))


def distortion_field_error_px(true: Camera, est: Camera, n: int = 21) -> float:
    """Largest difference (px) between the two lens models over the true camera's image.

    Rays through an n x n grid of the true image are projected with the true K and each
    camera's distortion.
    """
    W, H = true.size
    u, v = np.meshgrid(np.linspace(0, W - 1, n), np.linspace(0, H - 1, n))
    uv = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(uv, true.K, true.dist_coeffs).reshape(-1, 3 - 1)
    X = np.hstack([rays, np.ones((len(rays), 1))]).reshape(-1, 1, 3)
    z = np.zeros(3)
    a = cv2.projectPoints(X, z, z, true.K, true.dist_coeffs)[0].reshape(-1, 2)
    b = cv2.projectPoints(X, z, z, true.K, est.dist_coeffs)[0].reshape(-1, 2)
    return float(np.max(np.linalg.norm(a - b, axis=1)))


def rig_errors(true: Rig, est: Rig) -> dict:
    """Errors of a calibrated rig against the true one: per camera and for the pair."""
    cams = {}
    for t, e in zip(true.cameras, est.cameras):
        cams[t.name] = {
            "focal_length_pct": [100 * (e.fx - t.fx) / t.fx, 100 * (e.fy - t.fy) / t.fy],
            "principal_point_px": [e.cx - t.cx, e.cy - t.cy],
            "distortion_coefficients": [a - b for a, b in zip(e.dist, t.dist)],
            "distortion_max_px": distortion_field_error_px(t, e),
            "rotation_deg": _rot_angle_deg(e.R @ t.R.T),
            "position_mm": float(np.linalg.norm(e.position_mm - t.position_mm)),
        }
    (t1, t2), (e1, e2) = true.cameras, est.cameras
    Rt = t2.R @ t1.R.T
    Tt = t2.t_mm - Rt @ t1.t_mm
    Re = e2.R @ e1.R.T
    Te = e2.t_mm - Re @ e1.t_mm
    # the true world's origin and axes as the calibrated rig sees them, through camera 1
    origin = e1.R.T @ (t1.t_mm - e1.t_mm)
    return {"cameras": cams,
            "base_frame": {"origin_mm": float(np.linalg.norm(origin)),
                           "origin_vector_mm": origin.tolist(),
                           "rotation_deg": _rot_angle_deg(e1.R.T @ t1.R)},
            "baseline_mm": float(np.linalg.norm(Te) - np.linalg.norm(Tt)),
            "baseline_vector_mm": float(np.linalg.norm(Te - Tt)),
            "relative_rotation_deg": _rot_angle_deg(Re @ Rt.T)}


# ---------------------------------------------------------------------------- the whole job
@dataclass
class Result:
    """A finished calibration.

    Attributes
    ----------
    rig : the calibrated rig in the world (base) frame, ``calibration`` filled in.
    record : the ``calibration`` section (plain Python types).
    picture : RGB image of one view with its detected corners drawn, under a title
        (:func:`corner_picture`; None if no view showed the board to both cameras).
    stereo : what the board views gave (intrinsics, their uncertainty, the pair).
    """

    rig: Rig
    record: dict
    picture: np.ndarray | None = None
    timing_s: dict = field(default_factory=dict)
    stereo: StereoCalibration | None = None


def _plain(obj, digits: int = 6):
    """numpy -> plain Python, floats rounded to ``digits`` significant digits (for YAML)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v, digits) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_plain(v, digits) for v in (obj.tolist() if isinstance(obj, np.ndarray) else obj)]
    if isinstance(obj, (np.integer, int)) and not isinstance(obj, bool):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return float(f"{v:.{digits}g}") if np.isfinite(v) else None
    return obj


def progress_steps(arm, views: int, check_poses: int) -> int:
    """How many times :func:`calibrate` calls its ``progress``: once per board view and per arm
    pose (the joint sweeps of ``arm`` and the check poses)."""
    return views + sum(len(q) for q, _ in axis_sweeps(arm).values()) + check_poses


@opencv_threads(1)  # OpenCV's threaded reductions sum in a varying order (results differ at
# ~1e-10): one thread makes the same seed give the same calibration, bit for bit
def calibrate(true_rig: Rig, arm, *, views: int = DEFAULT_VIEWS, seed: int = 0,
              board: Board = Board(), tilt_deg: float = 45.0,
              check_poses: int = 20, supersample: int = 2, name: str | None = None,
              true_arm=None, progress=None) -> Result:
    """Calibrate ``true_rig`` from rendered board views and tie it to the arm's base frame.

    Parameters
    ----------
    true_rig : the rig that renders (the simulator's cameras).
    arm : `itg_vision.arm.ArmSpec` whose LEDs tie the rig to the base frame (nominal model:
        only its structure, LED stand-off and, three-link, base height are used).
    views : board poses shown.
    seed : seeds one generator for the board poses, the sensor noise and the arm poses.
    tilt_deg : largest board tilt about each in-plane axis (0: fronto-parallel, degenerate).
    check_poses : arm poses for the LED check.
    true_arm : the simulated arm, if it differs from ``arm`` (model error); default ``arm``.
    supersample : rendering factor of the board views.
    progress : optional callable(stage: str), called once per rendered view or arm pose
        (:func:`progress_steps` times). OpenCV runs on one thread meanwhile (the same seed
        gives the same result, bit for bit).

    Raises
    ------
    UserError : see :func:`calibrate_views`, :func:`base_frame_from_axes`; before anything is
        rendered, :func:`itg_vision.visibility.check_cameras` and :func:`sweeps_in_view`.
    """
    from .visibility import check_cameras
    from .world import World

    rng = np.random.default_rng(seed)
    poses = sample_board_poses(true_rig, board, views, rng,
                               target_mm=arm.calibration["board_target_mm"], tilt_deg=tilt_deg)
    tick = (lambda stage: (lambda: progress(stage))) if progress else (lambda stage: None)
    t0 = time.perf_counter()
    sweep_poses = axis_sweeps(arm)
    check_cameras(true_rig)  # an LED too dark to find, a camera below the floor: before rendering
    sweeps_in_view(true_rig, arm, sweep_poses, str(true_rig.source or true_rig.name), true_arm)
    with World(true_arm or arm) as world:
        vs = render_views(world, true_rig, board, poses, rng, supersample=supersample,
                          progress=tick("board"))
        t1 = time.perf_counter()
        source = str(true_rig.source or true_rig.name)  # the rig file messages name
        axes = [c.R[2] for c in true_rig.cameras]  # each optical axis, in the world frame
        apart = float(np.degrees(np.arccos(np.clip(axes[0] @ axes[1], -1.0, 1.0))))
        labels = tuple(f"cameras[{i}] ({c.name})" for i, c in enumerate(true_rig.cameras))
        cal = calibrate_views(vs, board, tuple(c.size for c in true_rig.cameras), labels,
                              source=source, apart_deg=apart)
        t2 = time.perf_counter()
        name = name or f"{true_rig.name}.calib"
        rig_c1 = rig_in_camera1_frame(true_rig, cal, name)
        sweeps = {j: (led_images(world, true_rig, arm, q, rng, progress=tick("arm")), names)
                  for j, (q, names) in sweep_poses.items()}
        q_check = arm.random_poses(check_poses, rng)
        shots_check = led_images(world, true_rig, arm, q_check, rng, progress=tick("arm"))
    t3 = time.perf_counter()
    R_w, t_w, base_record = base_frame_from_axes(rig_c1, arm, sweeps, source=source)
    rig = place_rig(rig_c1, R_w, t_w, name)
    err_true = led_errors(true_rig, arm, shots_check)
    err_cal = led_errors(rig, arm, shots_check)
    common = sorted(set(err_true) & set(err_cal))
    if not common:
        raise UserError(f"{source}: LED check: no LED was found by both cameras at the check poses")
    e_true = np.array([err_true[k] for k in common])
    e_cal = np.array([err_cal[k] for k in common])
    rms_true, rms_cal = (float(np.sqrt(np.mean(e**2))) for e in (e_true, e_cal))
    c1, c2 = true_rig.cameras
    record = {
        "method": "checkerboard views -> cv2.calibrateCamera per camera (k3 fixed; from the "
                  "image centre and from Zhang's closed form, the lower RMS kept), "
                  "cv2.stereoCalibrate (CALIB_FIX_INTRINSIC); base frame from the joint axes "
                  "the LEDs trace, one joint at a time, triangulated with the calibrated pair "
                  "(circle fits)",
        "board": {"inner_corners": [board.cols, board.rows], "square_mm": board.square_mm},
        "seed": seed,
        "sensor_noise_sigma_gray": [c1.noise_sigma_gray, c2.noise_sigma_gray],
        "views_shown": views,
        "views_found": {c1.name: cal.n_found[0], c2.name: cal.n_found[1],
                        "both": cal.n_found_both},
        "views_used": {c1.name: len(cal.used[0]), c2.name: len(cal.used[1]),
                       "stereo": len(cal.stereo_views)},
        "views_dropped": list(cal.dropped),
        "tilt_span_deg": list(cal.tilt_span_deg),
        "reprojection_rms_px": {c1.name: cal.rms_px[0], c2.name: cal.rms_px[1]},
        "intrinsics_start": {c1.name: cal.start[0], c2.name: cal.start[1]},
        "stereo_rms_px": cal.stereo_rms_px,
        "stereo_excess_px": stereo_excess_px(cal.stereo_rms_px, cal.rms_px),
        "per_view_rms_px": {c1.name: cal.per_view_rms_px[0], c2.name: cal.per_view_rms_px[1]},
        "base_frame": base_record,
        "error_vs_true": rig_errors(true_rig, rig),
        "led_triangulation": {"poses": check_poses, "points": len(common),
                              "true_rig_rms_mm": rms_true, "calibrated_rig_rms_mm": rms_cal,
                              # the tail beside the RMS
                              "true_rig_p95_mm": float(np.percentile(e_true, 95)),
                              "true_rig_max_mm": float(e_true.max()),
                              "calibrated_rig_p95_mm": float(np.percentile(e_cal, 95)),
                              "calibrated_rig_max_mm": float(e_cal.max()),
                              "ratio": rms_cal / rms_true if rms_true > 0 else None},
    }
    record = _plain(record)
    rig = Rig(name, rig.cameras, "", record, None, true_rig.supersample)  # the eye's, kept
    picture = None
    if vs.sample is not None:
        k, img = vs.sample
        picture = corner_picture(img, board, vs.corners[k][0], [
            f"{true_rig.name} rig, {c1.name} camera: view {k} (of {views} shown), "
            f"{len(vs.corners[k][0])} corners detected",
            f"calibrated from {len(cal.used[0])} {c1.name} and {len(cal.used[1])} {c2.name} "
            f"views, {len(cal.stereo_views)} in both"])
        record["picture_view"] = k
    return Result(rig, record, picture,
                  {"board_s": t1 - t0, "calibrate_s": t2 - t1, "leds_s": t3 - t2,
                   "total_s": time.perf_counter() - t0}, cal)


# ---------------------------------------------------------------------------- the file
def corner_picture(img: np.ndarray, board: Board, corners: np.ndarray,
                   title: list[str]) -> np.ndarray:
    """``img`` (RGB, uint8, shape (H, W, 3)) with the detected ``corners`` drawn, under a white
    band holding the ``title`` lines (the font shrunk to fit the width): shape (H + band, W, 3)."""
    picture = img.copy()
    cv2.drawChessboardCorners(picture, board.pattern_size, corners, True)
    font, scale, line_px = cv2.FONT_HERSHEY_SIMPLEX, 0.5, 20
    widest = max(cv2.getTextSize(t, font, scale, 1)[0][0] for t in title)
    scale *= min(1.0, (picture.shape[1] - 16) / widest)
    band = np.full((line_px * len(title) + 8, picture.shape[1], 3), 255, np.uint8)
    band[-1] = 128  # a grey rule between the title and the view
    for i, text in enumerate(title):
        cv2.putText(band, text, (8, line_px * (i + 1)), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([band, picture])


def picture_path(out: Path) -> Path:
    """The corner picture beside the calibrated rig: ``x.calib.yaml`` -> ``x.calib.png``."""
    return out.with_name(out.name.removesuffix(".yaml").removesuffix(".yml") + ".png")


def write_result(result: Result, out: Path, true_rig_path: Path,
                 true_rig_sha256: str | None = None) -> Path | None:
    """Write the calibrated rig ``out`` and the corner picture beside it as one result
    (:func:`itg_vision.outputs.write_files`: both written to temporary names, then renamed, the
    rig last); return the picture's path (None if the result has no picture).

    The rig names ``true_rig_path`` (``true_rig``) and records ``true_rig_sha256``, the hash of
    that file as it was calibrated (default: its content now), which a run checks
    (:func:`itg_vision.camera.load_true_rig`)."""
    try:
        rel = os.path.relpath(Path(true_rig_path).resolve(), out.parent.resolve())
    except ValueError:  # another drive (Windows)
        rel = str(Path(true_rig_path).resolve())
    files = {}
    pic = None
    if result.picture is not None:
        pic = picture_path(out)
        ok, buf = cv2.imencode(".png", cv2.cvtColor(result.picture, cv2.COLOR_RGB2BGR))
        if not ok:
            raise RuntimeError("cv2.imencode could not encode the corner picture as PNG")
        files[pic] = buf.tobytes()
    sha = true_rig_sha256 if true_rig_sha256 is not None else file_sha256(true_rig_path)
    rig = Rig(result.rig.name, result.rig.cameras, "", result.record, rel,
              result.rig.supersample, sha)
    files[out] = rig.yaml_text().encode()
    outputs.write_files(files)
    return pic
