"""python -m itg_vision.calibrate: calibrate the stereo rig from rendered views of a checkerboard.

Method
------
1. **Board.** A checkerboard (default 9 x 6 inner corners, 15 mm squares, 15 mm white margin)
   is drawn with numpy into a PNG and put on a two-sided textured quad (an OBJ with UVs, made at
   run time in a temporary folder). Its outer-corner square next to inner corner (0, 0) is black
   and the opposite one white, so the corner order is unambiguous (see :func:`canonical_order`).
2. **Views.** As a person waving a board would, the board is shown at ``N`` seeded random poses
   in front of both cameras, between them and the arm's workspace, tilted up to ``tilt_deg``
   (default 45 degrees) about its two in-plane axes and turned up to 20 degrees about its
   normal. Both cameras of the *true* rig render every view through
   :func:`itg_vision.imaging.capture`: the same lens distortion and sensor noise as the LEDs.
3. **Corners.** ``cv2.findChessboardCorners`` then ``cv2.cornerSubPix`` (0.08 px RMS against
   the projected true corners; ``findChessboardCornersSB`` gave 0.4 px on these renders).
   Every other view is chosen so both cameras see the whole board (for the stereo step); the
   others may reach the image borders of one camera only (for its intrinsics).
4. **Intrinsics.** ``cv2.calibrateCameraExtended`` per camera on every view in which that camera
   found the board (K and k1, k2, p1, p2; k3 is fixed at 0: a modest lens, poorly constrained
   by a board that rarely reaches the image corners). Views whose per-view RMS exceeds
   ``3 x`` the median (and 0.3 px) are dropped and the camera recalibrated. Degenerate pose sets (board normals spanning too
   little tilt about either axis, or a focal length whose standard deviation exceeds 1 %) are
   refused.
5. **Stereo.** ``cv2.stereoCalibrate`` with ``CALIB_FIX_INTRINSIC`` on the views in which both
   cameras found the full board: camera 2 relative to camera 1 (R, T).
6. **Base frame.** Stereo calibration leaves the rig floating in camera 1's frame. It is tied to
   the robot's base by what the LEDs trace when one joint moves at a time
   (:func:`base_frame_from_axes`): the LEDs are detected (:func:`itg_vision.detect.find_led`
   with the *calibrated* cameras) and triangulated in camera-1 coordinates along each sweep,
   and circle fits give each joint's axis and centre. The base joint's axis is world z, its
   zero (commanded q1 = 0) world x; the three-link shoulder axis fixes the height of the
   shoulder. No link length is used (the LED stand-off is a mounting dimension; the three-link
   arm's base height places the unseen floor), so a wrong nominal model cannot move the frame;
   a joint-zero offset of q1 turns it (that is what q1 = 0 means). Its error: the fits' RMS
   residual (``base_frame.fit_rms_mm``) and, since the truth is known, the cameras' rotation
   and position errors.
7. **Check.** At other seeded arm poses the LEDs are triangulated with the true rig and with the
   calibrated rig from the same images; both RMS errors against the simulator's LED positions
   and their ratio are reported.

Outputs: the calibrated rig (``runs/calibrate/<rig>.calib.yaml`` by default: the shipped
``cameras/<rig>.calib.yaml`` is rewritten only when named with ``--out``), in the rig schema with
a ``calibration`` section and ``true_rig`` (the rig that rendered, relative to the file's folder),
and a picture of the detected corners of one view (``<name>.calib.png`` beside it).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from trimesh.transformations import quaternion_from_matrix

from . import outputs
from .arm import arm_names
from .camera import Camera, Rig, resolve_rig
from .errors import UserError, run_main

#: Fewest views (board found by both cameras) accepted for a calibration.
MIN_VIEWS = 6
#: Board normals must span at least this tilt (deg, full range) about two orthogonal axes
#: (measured: 70 to 80 with --tilt 45, 22 to 31 with --tilt 0).
MIN_TILT_SPAN_DEG = 40.0
#: Largest relative standard deviation of the focal length accepted (degenerate poses).
MAX_FOCAL_STD = 0.01
#: Default number of board views.
DEFAULT_VIEWS = 60
#: Board poses: the largest angle between the board's normal and a camera's line of sight.
MAX_VIEW_ANGLE_DEG = 60.0
#: cv2.cornerSubPix half window (px) and stopping rule. On rendered boards (squares ~20 px)
#: findChessboardCorners + cornerSubPix measured 0.08 px RMS against the projected corners,
#: findChessboardCornersSB with CALIB_CB_ACCURACY 0.41 px.
SUBPIX_WINDOW = (5, 5)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
#: Margin (px) the board's outline keeps from the image border.
BORDER_PX = 8.0

#: The arm whose LEDs tie a rig to the base frame, by rig name (others: two-link). The one-link
#: arm shares the planar rig but carries one LED, on one circle: too little for the base fit.
def arm_of_rig(rig_name: str) -> str:
    """The arm whose LEDs tie a shipped rig to the base: of the arms that use the rig by
    default, the one with the most LEDs (two circles per joint sweep fit better than one);
    two-link for a rig of the user's own."""
    from .arm import ArmSpec, arm_names

    arms = [ArmSpec.from_args(n) for n in arm_names()]
    users = [a for a in arms if a.defaults["rig"] == rig_name]
    return max(users, key=lambda a: len(a.marker_names)).name if users else "two-link"


# ---------------------------------------------------------------------------- the board
@dataclass(frozen=True)
class Board:
    """A checkerboard target.

    Attributes
    ----------
    cols, rows : inner corners per row and per column (OpenCV's ``patternSize``).
    square_mm : side of a square.
    margin_mm : white border around the outer squares.
    px_per_mm : texture resolution.

    The board frame has its origin at inner corner (0, 0), x along a row of corners, y along a
    column, z into the board (away from a viewer who sees the pattern).
    """

    cols: int = 9
    rows: int = 6
    square_mm: float = 15.0
    margin_mm: float = 15.0
    px_per_mm: float = 8.0

    @property
    def pattern_size(self) -> tuple[int, int]:
        return self.cols, self.rows

    def object_points(self) -> np.ndarray:
        """Inner corners in the board frame (mm), shape (rows * cols, 3), float32, row-major."""
        j, i = np.mgrid[0:self.rows, 0:self.cols]
        pts = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square_mm
        return pts.astype(np.float32)

    def extent_mm(self) -> tuple[float, float, float, float]:
        """The board's outline in its frame: x0, y0, x1, y1 (mm)."""
        s, m = self.square_mm, self.margin_mm
        return -s - m, -s - m, self.cols * s + m, self.rows * s + m

    def centre_mm(self) -> np.ndarray:
        """Centre of the inner-corner grid in the board frame (mm), shape (3,)."""
        return np.array([(self.cols - 1) / 2, (self.rows - 1) / 2, 0.0]) * self.square_mm

    def outline_mm(self) -> np.ndarray:
        """The four outline corners in the board frame (mm), shape (4, 3)."""
        x0, y0, x1, y1 = self.extent_mm()
        return np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)

    def texture(self) -> np.ndarray:
        """The board image, uint8 grey, shape (H, W); row 0 at y0, column 0 at x0.

        Square (a, b), spanning x in [(a-1) s, a s] and y in [(b-1) s, b s], is black when
        a + b is even: the square outside inner corner (0, 0) is black, the one outside the
        last corner white (the colours break the board's 180-degree symmetry).
        """
        x0, y0, x1, y1 = self.extent_mm()
        W = int(round((x1 - x0) * self.px_per_mm))
        H = int(round((y1 - y0) * self.px_per_mm))
        x = x0 + (np.arange(W) + 0.5) / self.px_per_mm
        y = y0 + (np.arange(H) + 0.5) / self.px_per_mm
        a = np.floor(x / self.square_mm).astype(int) + 1
        b = np.floor(y / self.square_mm).astype(int) + 1
        inside_x = (a >= 0) & (a <= self.cols)
        inside_y = (b >= 0) & (b <= self.rows)
        black = ((a[None, :] + b[:, None]) % 2 == 0) & inside_x[None, :] & inside_y[:, None]
        return np.where(black, 0, 255).astype(np.uint8)

    def write_assets(self, folder) -> tuple[str, str]:
        """Write the texture (PNG) and a two-sided textured quad (OBJ, metres); return paths."""
        folder = Path(folder)
        png = folder / "board.png"
        obj = folder / "board.obj"
        cv2.imwrite(str(png), self.texture())
        x0, y0, x1, y1 = (v * 1e-3 for v in self.extent_mm())
        # Texture v runs from the image's bottom row (v = 0) to its top row (v = 1): row 0 of
        # the texture (board y0) has v = 1. Checked by test_board_texture_orientation.
        lines = ["# calibration board (itg_vision.calibrate)",
                 f"v {x0:.6f} {y0:.6f} 0", f"v {x1:.6f} {y0:.6f} 0",
                 f"v {x1:.6f} {y1:.6f} 0", f"v {x0:.6f} {y1:.6f} 0",
                 "vt 0 1", "vt 1 1", "vt 1 0", "vt 0 0",
                 "vn 0 0 -1", "vn 0 0 1",
                 "f 1/1/1 3/3/1 2/2/1", "f 1/1/1 4/4/1 3/3/1",   # front (seen from -z)
                 "f 1/1/2 2/2/2 3/3/2", "f 1/1/2 3/3/2 4/4/2"]   # back
        obj.write_text("\n".join(lines) + "\n")
        return str(obj), str(png)


@dataclass(frozen=True)
class BoardPose:
    """Pose of the board frame in the world: ``X_world = R @ X_board + t_mm``."""

    R: np.ndarray
    t_mm: np.ndarray

    def points(self, X_board) -> np.ndarray:
        return np.asarray(X_board, float) @ self.R.T + self.t_mm


def quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), PyBullet's order, of a rotation matrix, shape (4,)."""
    w, x, y, z = quaternion_from_matrix(np.asarray(R, float))
    return np.array([x, y, z, w])


def _axis_rotation(axis: int, angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about world axis 0 (x), 1 (y) or 2 (z)."""
    return cv2.Rodrigues(np.eye(3)[axis] * angle_rad)[0]


def board_visible(camera: Camera, board: Board, pose: BoardPose,
                  border_px: float = BORDER_PX) -> bool:
    """Whether the board's whole outline projects inside ``camera``'s image, facing it."""
    X = pose.points(board.outline_mm())
    if np.any(camera.to_camera(X)[:, 2] <= 0):
        return False
    # facing: the board's -z (pattern side) towards the camera, not too oblique
    to_cam = camera.position_mm - pose.points(board.centre_mm())
    cosang = float(-pose.R[:, 2] @ to_cam / np.linalg.norm(to_cam))
    if cosang < np.cos(np.radians(MAX_VIEW_ANGLE_DEG)):
        return False
    uv = camera.project(X)
    W, H = camera.size
    return bool(np.all((uv >= border_px) & (uv <= np.array([W - 1, H - 1]) - border_px)))



def sample_board_poses(rig: Rig, board: Board, n: int, rng: np.random.Generator, *,
                       target_mm, tilt_deg: float = 45.0, spin_deg: float = 20.0,
                       tries: int = 200) -> list[BoardPose]:
    """Seeded random board poses in front of the cameras, as a person waving a board.

    The board's centre lies near the segment from the cameras' midpoint M to ``target_mm`` (a
    point of the arm's workspace), at 50 to 85 % of the way from M; its pattern faces M, then
    it is tilted uniformly in ``[-tilt_deg, tilt_deg]`` about its x and y axes and turned in
    ``[-spin_deg, spin_deg]`` about its normal. Even-numbered views stay within 40 mm of the
    segment and must show the whole board to both cameras (for the stereo calibration);
    odd-numbered views move up to 150 mm sideways and need only one camera (they bring the
    board near the image borders, which pins down distortion and the principal point). After
    ``tries`` failures a view takes the first candidate visible in one camera (else the last),
    so that a rig where a camera never sees the board still gets its ``n`` views and fails
    later with a clear message.

    Returns
    -------
    list of `BoardPose`, length n.
    """
    c1, c2 = rig.cameras
    M = (c1.position_mm + c2.position_mm) / 2
    target = np.asarray(target_mm, float)
    axis = target - M
    dist = float(np.linalg.norm(axis))
    axis = axis / dist
    x_ref = c1.R[0]  # camera 1's x axis in the world
    poses = []
    for k in range(n):
        stereo = k % 2 == 0
        fallback = None
        chosen = None
        for _ in range(tries):
            side = rng.uniform(-1.0, 1.0, 3) * (40.0 if stereo else 150.0)
            side -= (side @ axis) * axis
            centre = M + rng.uniform(0.5, 0.85) * dist * axis + side
            z = centre - M
            z /= np.linalg.norm(z)
            x = x_ref - (x_ref @ z) * z
            x /= np.linalg.norm(x)
            R0 = np.stack([x, np.cross(z, x), z], axis=1)  # columns: board axes in the world
            a, b = np.radians(rng.uniform(-tilt_deg, tilt_deg, 2))
            g = np.radians(rng.uniform(-spin_deg, spin_deg))
            R = R0 @ _axis_rotation(0, a) @ _axis_rotation(1, b) @ _axis_rotation(2, g)
            pose = BoardPose(R, centre - R @ board.centre_mm())
            seen = [board_visible(c, board, pose) for c in (c1, c2)]
            if all(seen) or (any(seen) and not stereo):
                chosen = pose
                break
            if fallback is None and any(seen):
                fallback = pose
        poses.append(chosen or fallback or pose)
    return poses


# ---------------------------------------------------------------------------- corners
def canonical_order(corners: np.ndarray, image_gray: np.ndarray,
                    board: Board) -> np.ndarray:
    """Put detected corners in the board's order: corner k at ``board.object_points()[k]``.

    OpenCV may return the grid mirrored or turned by 180 degrees. Mirroring is undone from the
    grid's handedness (the pattern is seen from the front, so object x, y map to an image
    basis with positive cross product), the 180-degree turn from the colour of the outer
    square beyond corner 0 (black on this board).

    Parameters
    ----------
    corners : shape (rows * cols, 1, 2) or (rows * cols, 2), float.
    image_gray : uint8, shape (H, W).

    Returns
    -------
    corners : shape (rows * cols, 1, 2), float32.
    """
    c = np.asarray(corners, np.float32).reshape(board.rows, board.cols, 2)
    a = c[0, 1] - c[0, 0]
    b = c[1, 0] - c[0, 0]
    if a[0] * b[1] - a[1] * b[0] < 0:
        c = c[:, ::-1]
    probe = c[0, 0] + 0.5 * (c[0, 0] - c[1, 1])
    H, W = image_gray.shape[:2]
    u = int(np.clip(round(float(probe[0])), 1, W - 2))
    v = int(np.clip(round(float(probe[1])), 1, H - 2))
    patch = image_gray[v - 1:v + 2, u - 1:u + 2].astype(float).mean()
    # black square expected beyond corner 0; compare with the square beyond the last corner
    probe2 = c[-1, -1] + 0.5 * (c[-1, -1] - c[-2, -2])
    u2 = int(np.clip(round(float(probe2[0])), 1, W - 2))
    v2 = int(np.clip(round(float(probe2[1])), 1, H - 2))
    patch2 = image_gray[v2 - 1:v2 + 2, u2 - 1:u2 + 2].astype(float).mean()
    if patch > patch2:
        c = c[::-1, ::-1]
    return np.ascontiguousarray(c.reshape(-1, 1, 2), dtype=np.float32)


def find_corners(image: np.ndarray, board: Board) -> np.ndarray | None:
    """Inner corners of the board in an RGB image, sub-pixel, in board order; None if not found.

    ``cv2.findChessboardCorners`` (``findChessboardCornersSB`` when it fails) to find the grid,
    ``cv2.cornerSubPix`` to refine it.

    Returns
    -------
    corners : shape (rows * cols, 1, 2), float32, distorted (raw) pixels.
    """
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCorners(gray, board.pattern_size, flags=flags)
    if not ok:
        ok, corners = cv2.findChessboardCornersSB(gray, board.pattern_size,
                                                  flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok or corners is None or len(corners) != board.rows * board.cols:
        return None
    corners = cv2.cornerSubPix(gray, np.ascontiguousarray(corners, np.float32),
                               SUBPIX_WINDOW, (-1, -1), SUBPIX_CRITERIA)
    return canonical_order(corners, gray, board)


# ---------------------------------------------------------------------------- views
@dataclass
class Views:
    """Board views as both cameras saw them.

    Attributes
    ----------
    poses : the board poses shown (all of them).
    corners : per view, a pair (camera 1, camera 2) of corner arrays (n, 1, 2) or None.
    sample : (view index, image of camera 1) of one view where the board was found, for the
        corner picture; None if none.
    """

    poses: list[BoardPose]
    corners: list[tuple[np.ndarray | None, np.ndarray | None]]
    sample: tuple[int, np.ndarray] | None = None


def render_views(world, rig: Rig, board: Board, poses: list[BoardPose],
                 rng: np.random.Generator | None, *, supersample: int = 2,
                 progress=None) -> Views:
    """Show the board at each pose, capture both cameras of ``rig``, find the corners.

    Parameters
    ----------
    world : `itg_vision.world.World`.
    rig : the rig that renders (the true cameras).
    rng : sensor-noise generator (None: noise-free).
    progress : optional callable, called once per view.
    """
    from .imaging import capture

    corners = []
    sample = None
    with tempfile.TemporaryDirectory(prefix="itg_board_") as tmp:
        obj, png = board.write_assets(tmp)
        body = world.add_mesh(obj)
        try:
            world.texture(body, png)
            for k, pose in enumerate(poses):
                world.set_pose(body, pose.t_mm, quaternion_xyzw(pose.R))
                imgs = [capture(world, c, rng, supersample=supersample) for c in rig.cameras]
                found = tuple(find_corners(img, board) for img in imgs)
                if sample is None and all(f is not None for f in found):
                    sample = (k, imgs[0])
                corners.append(found)
                if progress is not None:
                    progress()
        finally:
            world.remove(body)
    return Views(list(poses), corners, sample)


# ---------------------------------------------------------------------------- calibration
@dataclass
class StereoCalibration:
    """What the board views give: intrinsics of both cameras and camera 2 relative to camera 1.

    ``x_cam2 = R @ x_cam1 + T_mm``. ``rms_px`` and ``per_view_rms_px`` are the monocular
    reprojection errors after outlier removal; ``used`` the view indices each camera's
    calibration kept, ``stereo_views`` those of the stereo calibration (board in both).
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


def _mono(obj, img, size, flags):
    rms, K, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
        obj, img, size, None, None, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    return rms, K, dist.ravel(), rvecs, per_view.ravel(), std_in.ravel()


def calibrate_views(views: Views, board: Board, size: tuple[int, int],
                    camera_names=("camera 1", "camera 2"), *,
                    min_views: int = MIN_VIEWS) -> StereoCalibration:
    """Mono calibration of each camera, outlier views out, then stereo calibration.

    Raises
    ------
    UserError : a camera never found the board, too few views with the board in both cameras,
        or degenerate poses.
    """
    n = len(views.corners)
    found = [sum(c[i] is not None for c in views.corners) for i in range(2)]
    for i in range(2):
        if found[i] == 0:
            raise UserError(f"{camera_names[i]} never found the board in {n} views: is it "
                            f"pointed at the workspace?")
    seen = [[k for k, c in enumerate(views.corners) if c[i] is not None] for i in range(2)]
    both = [k for k in seen[0] if k in set(seen[1])]
    if len(both) < min_views:
        raise UserError(f"the board was found by both cameras in only {len(both)} of {n} views;"
                        f" need at least {min_views} (try more --views)")
    obj_board = board.object_points()
    flags = cv2.CALIB_FIX_K3
    dropped: set[int] = set()
    res = []
    for i in range(2):  # each camera: all its views, then again without its outliers
        used = seen[i]
        r = _mono([obj_board] * len(used), [views.corners[k][i] for k in used], size, flags)
        limit = max(3.0 * float(np.median(r[4])), 0.3)
        bad = {used[j] for j in np.flatnonzero(r[4] > limit)}
        if bad and len(used) - len(bad) >= min_views:
            dropped |= bad
            used = [k for k in used if k not in bad]
            r = _mono([obj_board] * len(used), [views.corners[k][i] for k in used], size, flags)
        res.append((used, r))
    both = [k for k in both if k not in dropped]
    if len(both) < min_views:
        raise UserError(f"only {len(both)} views with the board in both cameras are left after "
                        f"dropping outliers {sorted(dropped)}; need at least {min_views}")
    spans = tilt_spans_deg(res[0][1][3])
    std_rel = tuple(float(r[5][0] / r[1][0, 0]) for _, r in res)
    if min(spans) < MIN_TILT_SPAN_DEG or max(std_rel) > MAX_FOCAL_STD \
            or not all(np.isfinite(r[0]) for _, r in res):
        raise UserError(f"degenerate board poses: the board's tilt spans only "
                        f"{spans[0]:.0f} x {spans[1]:.0f} deg over {len(res[0][0])} views (need "
                        f"{MIN_TILT_SPAN_DEG:.0f} about two axes; focal std "
                        f"{100 * max(std_rel):.2f} %): tilt the board more")
    (u1, (rms1, K1, d1, _, pv1, _)), (u2, (rms2, K2, d2, _, pv2, _)) = res
    srms, K1, d1, K2, d2, R, T, _, _ = cv2.stereoCalibrate(
        [obj_board] * len(both), [views.corners[k][0] for k in both],
        [views.corners[k][1] for k in both],
        K1, d1, K2, d2, size, flags=cv2.CALIB_FIX_INTRINSIC,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    return StereoCalibration((K1, K2), (d1.ravel(), d2.ravel()), R, T.ravel(),
                             (float(rms1), float(rms2)), float(srms), (pv1, pv2),
                             (u1, u2), both, sorted(dropped), std_rel, spans,
                             (len(seen[0]), len(seen[1])))


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
def led_images(world, rig: Rig, arm, q_list, rng, *, supersample: int = 1, progress=None):
    """Capture both cameras of ``rig`` at each joint pose; yield (q, images, true LEDs)."""
    from .imaging import capture

    out = []
    for q in q_list:
        world.set_q(q)
        imgs = [capture(world, c, rng, supersample=supersample) for c in rig.cameras]
        out.append((np.asarray(q, float), imgs, world.true_markers()))
        if progress is not None:
            progress()
    return out


def triangulate_leds(rig: Rig, arm, images) -> dict[str, np.ndarray]:
    """Detect each LED in both images with ``rig``'s cameras and triangulate (rig's frame).

    Returns
    -------
    dict marker -> X_mm (3,) for the markers found in both images.
    """
    from .detect import find_led
    from .triangulate import triangulate
    from .urdf import LED_RGB

    out = {}
    for name in arm.marker_names:
        dets = [find_led(img, c, LED_RGB[name]) for img, c in zip(images, rig.cameras)]
        if all(d.ok for d in dets):
            out[name] = triangulate(rig, dets[0].uv_px, dets[1].uv_px)[0]
    return out


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


def _joint_fits(rig_c1: Rig, arm, joint: int, shots, names) -> dict[str, dict]:
    """Circle fits of the LEDs one joint's sweep moved (camera-1 coordinates)."""
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
        if len(pts[n]) < 0.75 * len(shots):
            raise UserError(f"base frame: joint q{joint + 1}'s sweep: the {n} LED was seen by "
                            f"both cameras in only {len(pts[n])} of {len(shots)} poses")
    axis = coaxial_normal([pts[n] for n in names])  # every LED turns about the same axis
    for n in names:
        centre, normal, radius, rms = fit_circle(pts[n], axis)
        out[n] = {"centre": centre, "axis": rotation_sense_axis(centre, normal, pts[n]),
                  "radius_mm": radius, "rms_mm": rms, "points": np.array(pts[n]),
                  "angles_deg": np.array(angles[n])}
    return out


def base_frame_from_axes(rig_c1: Rig, arm, sweeps: dict) -> tuple[np.ndarray, np.ndarray, dict]:
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

    Returns
    -------
    R_w, t_w : ``x_cam1 = R_w X_world + t_w``; record : the fits, for the calibration file.
    """
    from .identify import zero_direction

    fits = {j: _joint_fits(rig_c1, arm, j, shots, names) for j, (shots, names) in sweeps.items()}
    base = fits[0]
    z = np.sum([f["axis"] for f in base.values()], axis=0)
    z /= np.linalg.norm(z)
    c = np.mean([f["centre"] for f in base.values()], axis=0)
    record = {"method": "joint axes traced by the LEDs, one joint at a time (circle fits)",
              "arm": arm.name,
              "sweeps": {f"q{j + 1}": {"poses": len(shots), "markers": list(names)}
                         for j, (shots, names) in sweeps.items()},
              "fit_rms_mm": max(f["rms_mm"] for fj in fits.values() for f in fj.values())}
    if arm.planar:
        on_link1 = base["elbow"] if "elbow" in base else base["gripper"]
        x = zero_direction(c, z, on_link1["points"], on_link1["angles_deg"])
        origin = c - arm.led_standoff_mm * z
        measured = [on_link1["radius_mm"]]
        if 1 in fits:
            measured.append(fits[1]["gripper"]["radius_mm"])
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
        measured = [shoulder["elbow"]["radius_mm"], float(np.median(np.linalg.norm(
            shoulder["gripper"]["points"] - shoulder["elbow"]["points"], axis=1)))]
        record["nominal_used"] = (f"base height L1 = {arm.links_mm[0]:g} mm below the measured "
                                  "shoulder (the floor is not seen)")
    y = np.cross(z, x)
    R_w = np.column_stack([x, y, z])
    record["measured_links_mm"] = measured
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
    picture : RGB image of one view with its detected corners drawn (None if none).
    """

    rig: Rig
    record: dict
    picture: np.ndarray | None = None
    timing_s: dict = field(default_factory=dict)


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
    progress : optional callable(stage: str), called once per rendered view or arm pose.

    Raises
    ------
    UserError : see :func:`calibrate_views`, :func:`base_frame_from_axes`.
    """
    from .world import World

    rng = np.random.default_rng(seed)
    poses = sample_board_poses(true_rig, board, views, rng,
                               target_mm=arm.calibration["board_target_mm"], tilt_deg=tilt_deg)
    tick = (lambda stage: (lambda: progress(stage))) if progress else (lambda stage: None)
    t0 = time.perf_counter()
    sweep_poses = axis_sweeps(arm)
    with World(true_arm or arm) as world:
        vs = render_views(world, true_rig, board, poses, rng, supersample=supersample,
                          progress=tick("board"))
        t1 = time.perf_counter()
        size = true_rig.cameras[0].size
        cal = calibrate_views(vs, board, size, tuple(c.name for c in true_rig.cameras))
        t2 = time.perf_counter()
        name = name or f"{true_rig.name}.calib"
        rig_c1 = rig_in_camera1_frame(true_rig, cal, name)
        sweeps = {j: (led_images(world, true_rig, arm, q, rng, progress=tick("arm")), names)
                  for j, (q, names) in sweep_poses.items()}
        q_check = arm.random_poses(check_poses, rng)
        shots_check = led_images(world, true_rig, arm, q_check, rng, progress=tick("arm"))
    t3 = time.perf_counter()
    R_w, t_w, base_record = base_frame_from_axes(rig_c1, arm, sweeps)
    rig = place_rig(rig_c1, R_w, t_w, name)
    err_true = led_errors(true_rig, arm, shots_check)
    err_cal = led_errors(rig, arm, shots_check)
    common = sorted(set(err_true) & set(err_cal))
    if not common:
        raise UserError("LED check: no LED was found by both cameras at the check poses")
    rms_true = float(np.sqrt(np.mean([err_true[k] ** 2 for k in common])))
    rms_cal = float(np.sqrt(np.mean([err_cal[k] ** 2 for k in common])))
    c1, c2 = true_rig.cameras
    record = {
        "method": "checkerboard views -> cv2.calibrateCamera per camera (k3 fixed), "
                  "cv2.stereoCalibrate (CALIB_FIX_INTRINSIC); base frame from the joint axes "
                  "the LEDs trace, one joint at a time, triangulated with the calibrated pair "
                  "(circle fits)",
        "board": {"inner_corners": [board.cols, board.rows], "square_mm": board.square_mm},
        "seed": seed,
        "sensor_noise_sigma_gray": [c1.noise_sigma_gray, c2.noise_sigma_gray],
        "views_shown": views,
        "views_found": {c1.name: cal.n_found[0], c2.name: cal.n_found[1]},
        "views_used": {c1.name: len(cal.used[0]), c2.name: len(cal.used[1]),
                       "stereo": len(cal.stereo_views)},
        "views_dropped": list(cal.dropped),
        "tilt_span_deg": list(cal.tilt_span_deg),
        "reprojection_rms_px": {c1.name: cal.rms_px[0], c2.name: cal.rms_px[1]},
        "stereo_rms_px": cal.stereo_rms_px,
        "per_view_rms_px": {c1.name: cal.per_view_rms_px[0], c2.name: cal.per_view_rms_px[1]},
        "base_frame": base_record,
        "error_vs_true": rig_errors(true_rig, rig),
        "led_triangulation": {"poses": check_poses, "points": len(common),
                              "true_rig_rms_mm": rms_true, "calibrated_rig_rms_mm": rms_cal,
                              "ratio": rms_cal / rms_true if rms_true > 0 else None},
    }
    record = _plain(record)
    rig = Rig(name, rig.cameras, "", record, None)
    picture = None
    if vs.sample is not None:
        k, img = vs.sample
        picture = img.copy()
        cv2.drawChessboardCorners(picture, board.pattern_size, vs.corners[k][0], True)
        record["picture_view"] = k
    return Result(rig, record, picture,
                  {"board_s": t1 - t0, "calibrate_s": t2 - t1, "leds_s": t3 - t2,
                   "total_s": time.perf_counter() - t0})


# ---------------------------------------------------------------------------- command line
#: Where calibrations go by default (relative to the current folder, like ``runs/`` of run).
DEFAULT_OUT_DIR = Path("runs") / "calibrate"


def default_out(rig_path: Path) -> Path:
    """``cameras/planar.yaml`` -> ``runs/calibrate/planar.calib.yaml``.

    Not beside the rig: the shipped ``cameras/<rig>.calib.yaml`` is a tracked file (the
    reference calibration the README's figures and ``bench noise``'s ``rig-calibrated`` use);
    following the README must not rewrite it. ``--out cameras/planar.calib.yaml`` refreshes it
    on purpose (allowed: that file is this rig's calibration).
    """
    return DEFAULT_OUT_DIR / f"{Path(rig_path).stem}.calib.yaml"


def picture_path(out: Path) -> Path:
    """The corner picture beside the calibrated rig: ``x.calib.yaml`` -> ``x.calib.png``."""
    return out.with_name(out.name.removesuffix(".yaml").removesuffix(".yml") + ".png")


def check_out(out: Path, rig_path: Path, force: bool = False) -> None:
    """Refuse, before any work, an ``--out`` the calibration must not write (`UserError`).

    ``out`` must name a ``.yaml``/``.yml`` file (not a folder) in a folder that can be written,
    and not the true rig. An existing file there is replaced only if it is a calibration of
    this rig (its ``true_rig`` names ``rig_path``), or with ``force``; the same holds for the
    corner picture beside it.
    """
    from .outputs import check_path, probe_folder
    from .runner import resolve_relative

    check_path(out, what="file")
    if out.is_dir():
        raise UserError(f"--out {out}: is a folder; give the calibrated rig's file name, e.g. "
                        f"{out / default_out(rig_path).name}")
    if out.suffix not in (".yaml", ".yml"):
        raise UserError(f"--out {out}: must name a .yaml file (the calibrated rig)")
    if out.resolve() == Path(rig_path).resolve():
        raise UserError(f"--out: {out} would overwrite the true rig")
    ours = False
    if out.exists():
        try:
            old = Rig.from_yaml(out)
        except UserError as exc:
            if not force:
                raise UserError(f"--out {out}: exists and is not a rig file ({exc}); choose "
                                "another --out, or add --force to replace it") from None
        else:
            truth = old.true_rig and resolve_relative(old.true_rig, out)
            ours = bool(truth) and Path(truth).resolve() == Path(rig_path).resolve()
            if not ours and not force:
                what = (f"a calibration of {old.true_rig}, not of {rig_path}" if old.true_rig
                        else f"the rig file {old.name!r}, not a calibration of {rig_path}")
                raise UserError(f"--out {out}: is {what}; choose another --out, or add --force "
                                "to replace it")
    pic = picture_path(out)
    if pic.exists() and not ours and not force:
        raise UserError(f"--out {out}: {pic} exists and would be replaced by the corner "
                        "picture; choose another --out, or add --force")
    probe_folder(out.parent)


def write_result(result: Result, out: Path, true_rig_path: Path) -> Path | None:
    """Write the calibrated rig (and the corner picture beside it), each to a temporary name
    then renamed; return the picture's path."""
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        rel = os.path.relpath(Path(true_rig_path).resolve(), out.parent.resolve())
    except ValueError:  # another drive (Windows)
        rel = str(Path(true_rig_path).resolve())
    pic = None
    if result.picture is not None:
        pic = picture_path(out)
        ok, buf = cv2.imencode(".png", cv2.cvtColor(result.picture, cv2.COLOR_RGB2BGR))
        if ok:
            outputs.write_bytes(pic, buf.tobytes())
    rig = Rig(result.rig.name, result.rig.cameras, "", result.record, rel)
    rig.to_yaml(out)
    return pic


def summary_table(r: dict) -> str:
    """The calibration figures as a short text table."""
    e = r["error_vs_true"]
    names = list(e["cameras"])
    rows = [("", *names)]
    rows.append(("reprojection RMS (px)", *(f"{r['reprojection_rms_px'][n]:.3f}" for n in names)))
    rows.append(("focal length fx, fy (%)", *(
        "{:+.3f}, {:+.3f}".format(*e["cameras"][n]["focal_length_pct"]) for n in names)))
    rows.append(("principal point u, v (px)", *(
        "{:+.2f}, {:+.2f}".format(*e["cameras"][n]["principal_point_px"]) for n in names)))
    rows.append(("distortion, max over image (px)", *(
        f"{e['cameras'][n]['distortion_max_px']:.3f}" for n in names)))
    rows.append(("rotation (deg)", *(f"{e['cameras'][n]['rotation_deg']:.3f}" for n in names)))
    rows.append(("world position (mm)", *(f"{e['cameras'][n]['position_mm']:.2f}"
                                           for n in names)))
    led = r["led_triangulation"]
    u = r["views_used"]
    rows.insert(1, ("views used", *(str(u[n]) for n in names)))
    pair = [("stereo views used / shown", f"{u['stereo']} / {r['views_shown']}"
             + (f" (dropped {r['views_dropped']})" if r["views_dropped"] else "")),
            ("board tilt span (deg)", "{:.0f} x {:.0f}".format(*r["tilt_span_deg"])),
            ("stereo RMS (px)", f"{r['stereo_rms_px']:.3f}"),
            ("baseline error (mm)", f"{e['baseline_mm']:+.3f}"),
            ("relative rotation error (deg)", f"{e['relative_rotation_deg']:.4f}"),
            ("base frame error: origin (mm), rotation (deg)",
             f"{e['base_frame']['origin_mm']:.2f}, {e['base_frame']['rotation_deg']:.3f}"),
            ("base frame: joint-axis circle fits RMS (mm)",
             f"{r['base_frame']['fit_rms_mm']:.3f} (measured links "
             + ", ".join(f"{v:.2f}" for v in r["base_frame"]["measured_links_mm"]) + " mm)"),
            ("LED triangulation RMS (mm)", f"true rig {led['true_rig_rms_mm']:.3f}, calibrated "
                                           f"{led['calibrated_rig_rms_mm']:.3f}, ratio "
                                           f"{led['ratio']:.2f} ({led['points']} points)")]
    w0 = max(len(x[0]) for x in rows + pair)
    w = [max(len(row[i]) for row in rows) for i in range(1, len(rows[0]))]
    lines = ["  ".join([f"{row[0]:<{w0}}"] + [f"{v:>{w[i]}}" for i, v in enumerate(row[1:])])
             for row in rows]
    lines += [f"{k:<{w0}}  {v}" for k, v in pair]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    from .errors import ArgumentParser  # one-line option errors

    ap = ArgumentParser(
        prog="python -m itg_vision.calibrate",
        description="Calibrate a stereo rig from rendered views of a checkerboard (intrinsics, "
                    "distortion, the pair), tie it to the robot's base frame with the LEDs at "
                    "known joint angles, and write the calibrated rig (default "
                    "runs/calibrate/<rig>.calib.yaml).")
    ap.add_argument("--rig", metavar="NAME|PATH",
                    help="the true rig that renders: cameras/<NAME>.yaml or a path "
                         "(default: planar)")
    ap.add_argument("--views", type=int, default=DEFAULT_VIEWS, metavar="N",
                    help="board poses shown (default %(default)s; at least "
                         f"{MIN_VIEWS} must show the board to both cameras)")
    ap.add_argument("--seed", type=int, default=0,
                    help="seed of the board poses, sensor noise and arm poses (default 0)")
    ap.add_argument("--out", metavar="PATH",
                    help="calibrated rig file, .yaml (default: runs/calibrate/<rig>.calib.yaml; "
                         "the shipped cameras/<rig>.calib.yaml is only rewritten when named "
                         "here); the corner picture goes beside it as <name>.png. An existing "
                         "file is replaced only if it is a calibration of this rig")
    ap.add_argument("--force", action="store_true",
                    help="replace --out even if it is not a calibration of this rig")
    ap.add_argument("--arm", choices=arm_names(),
                    help="arm whose LEDs tie the rig to the base frame (default: three-link for "
                         "the three-link rig, else two-link)")
    ap.add_argument("--tilt", type=float, default=45.0, metavar="DEG",
                    help="largest board tilt about each in-plane axis (default %(default)s; "
                         "0 shows the board fronto-parallel, which is degenerate)")
    ap.add_argument("--sensor-noise", type=float, metavar="SIGMA",
                    help="override the rig's sensor noise (grey levels std) while rendering")
    ap.add_argument("--true-links", metavar="L1,L2[,L3]",
                    help="model error: the simulated arm's link lengths in mm (the base frame "
                         "comes from the joint axes, not from the lengths: try 105,105)")
    ap.add_argument("--check-poses", type=int, default=20, metavar="N",
                    help="arm poses for the LED triangulation check (default %(default)s)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    return ap


def main(argv: list[str] | None = None) -> int:
    # OpenCV's threaded reductions sum in a varying order (results differ at ~1e-10); one
    # thread makes the same seed give the same file, bit for bit.
    cv2.setNumThreads(1)

    def body() -> int:
        import dataclasses

        args = build_parser().parse_args(argv)

        from .arm import ArmSpec
        from .progress import progress

        checks = [(1 <= args.views <= 1000, f"--views: must be in 1..1000, got {args.views}"),
                  (args.seed >= 0, f"--seed: must be >= 0, got {args.seed}"),
                  (0 <= args.tilt <= 75, f"--tilt: must be in 0..75 deg, got {args.tilt}"),
                  (args.sensor_noise is None or 0 <= args.sensor_noise <= 100,
                   f"--sensor-noise: must be in 0..100, got {args.sensor_noise}"),
                  (1 <= args.check_poses <= 1000, f"--check-poses: must be in 1..1000, got "
                                                  f"{args.check_poses}")]
        for ok, msg in checks:
            if not ok:
                raise UserError(msg)
        rig_path = resolve_rig(args.rig or "planar")
        true_rig = Rig.from_yaml(rig_path)
        if true_rig.true_rig:
            raise UserError(f"{rig_path} is already a calibrated rig (of {true_rig.true_rig}); "
                            f"calibrate the true rig")
        if args.sensor_noise is not None:
            true_rig = dataclasses.replace(true_rig, cameras=tuple(
                dataclasses.replace(c, noise_sigma_gray=float(args.sensor_noise))
                for c in true_rig.cameras))
        arm = ArmSpec.from_args(args.arm or arm_of_rig(true_rig.name))
        true_arm = arm
        if args.true_links is not None:
            try:
                links = tuple(float(v) for v in args.true_links.split(","))
            except ValueError:
                raise UserError(f"--true-links: expected lengths in mm separated by commas, "
                                f"got {args.true_links!r}") from None
            try:
                true_arm = ArmSpec.from_args(arm.name, links)
            except UserError as exc:
                raise UserError(str(exc).replace("--links", "--true-links")) from None
        out = Path(args.out) if args.out else default_out(rig_path)
        check_out(out, rig_path, args.force)  # before the work, not after it
        total = args.views + sum(len(q) for q, _ in axis_sweeps(arm).values()) + args.check_poses
        bar = progress(total, "calibrate", quiet=args.quiet, unit="view")
        try:
            result = calibrate(true_rig, arm, views=args.views, seed=args.seed,
                               tilt_deg=args.tilt, true_arm=true_arm,
                               check_poses=args.check_poses,
                               name=f"{Path(out).name.removesuffix('.yaml')}",
                               progress=lambda stage: bar.update())
        finally:
            bar.close()
        pic = write_result(result, out, rig_path)
        if not args.quiet:
            print(summary_table(result.record))
            print(f"{'calibrated rig':<31}  {out}")
            if pic is not None:
                print(f"{'detected corners (view ' + str(result.record['picture_view']) + ')':<31}"
                      f"  {pic}")
            print(f"{'wall time':<31}  {result.timing_s['total_s']:.1f} s")
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(main())
