"""The calibration target: a checkerboard, where it is shown, and its corners in the images.

1. **Board** (:class:`Board`). A checkerboard (default 9 x 6 inner corners, 15 mm squares, 15 mm
   white margin) is drawn with numpy into a PNG and put on a quad textured on its front, plain
   white behind (an OBJ with UVs, made at run time in a temporary folder). Its outer-corner
   square next to inner corner (0, 0) is black and the opposite one white, so the corner order
   is unambiguous (see :func:`canonical_order`).
2. **Poses** (:func:`sample_board_poses`). As a person waving a board would, the board is shown
   at ``N`` seeded random poses in front of both cameras, between them and the arm's
   workspace, tilted up to ``tilt_deg`` (default 45 degrees) about its two in-plane axes and
   turned up to 20 degrees about its normal. Every other view is chosen so both cameras see the
   whole board (for the stereo step); the others may reach the image borders of one camera only
   (for its intrinsics).
3. **Views** (:func:`render_views`). Both cameras of the *true* rig render every view through
   :func:`itg_vision.imaging.capture`: the same lens distortion and sensor noise as the LEDs.
4. **Corners** (:func:`find_corners`). ``cv2.findChessboardCorners`` then ``cv2.cornerSubPix``
   (0.08 px RMS against the projected true corners; ``findChessboardCornersSB`` gave 0.4 px on
   these renders).

What the views are used for: :mod:`itg_vision.calibration`.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from trimesh.transformations import quaternion_from_matrix

from .camera import Camera, Rig

#: Board poses: the largest angle between the board's normal and a camera's line of sight.
MAX_VIEW_ANGLE_DEG = 60.0
#: cv2.cornerSubPix half window (px) and stopping rule. On rendered boards (squares ~20 px)
#: findChessboardCorners + cornerSubPix measured 0.08 px RMS against the projected corners,
#: findChessboardCornersSB with CALIB_CB_ACCURACY 0.41 px.
SUBPIX_WINDOW = (5, 5)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
#: Margin (px) the board's outline keeps from the image border.
BORDER_PX = 8.0


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

    def __post_init__(self):
        if self.cols < 2 or self.rows < 2 or (self.cols + self.rows) % 2 == 0:
            raise ValueError(
                f"Board: {self.cols} x {self.rows} inner corners; need at least 2 x 2 and "
                "cols + rows odd (else the outer squares beyond the first and the last corner "
                "are both black and a 180-degree turn of the board cannot be told)")

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
        """Write the texture (PNG) and a quad textured on its front, white behind (OBJ, metres);
        return paths."""
        folder = Path(folder)
        png = folder / "board.png"
        obj = folder / "board.obj"
        cv2.imwrite(str(png), self.texture())
        x0, y0, x1, y1 = (v * 1e-3 for v in self.extent_mm())
        # Texture v runs from the image's bottom row (v = 0) to its top row (v = 1): row 0 of
        # the texture (board y0) has v = 1. Checked by
        # test_rendered_corners_match_the_projection_of_the_true_board (an 8 x 7 board's
        # pattern is not symmetric under a flip of v; the default 9 x 6 board's is).
        # The back is plain white (every vertex at one texel of the white margin), as a real
        # board's back shows no pattern: a camera that sees the back must not find corners
        # there, whose order would be the mirror of the front's (a rig whose cameras face
        # each other across the workspace saw it, and its stereo fit failed by ~18 px).
        u_white = 0.5 * self.margin_mm / (x1 - x0) * 1e-3
        v_white = 1.0 - u_white * (x1 - x0) / (y1 - y0)
        lines = ["# calibration board (itg_vision.board)",
                 f"v {x0:.6f} {y0:.6f} 0", f"v {x1:.6f} {y0:.6f} 0",
                 f"v {x1:.6f} {y1:.6f} 0", f"v {x0:.6f} {y1:.6f} 0",
                 "vt 0 1", "vt 1 1", "vt 1 0", "vt 0 0",
                 f"vt {u_white:.6f} {v_white:.6f}",
                 "vn 0 0 -1", "vn 0 0 1",
                 "f 1/1/1 3/3/1 2/2/1", "f 1/1/1 4/4/1 3/3/1",   # front (seen from -z)
                 "f 1/5/2 2/5/2 3/5/2", "f 1/5/2 3/5/2 4/5/2"]   # back: plain white
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
    from .imaging import capture, check_whole_frame

    for i, camera in enumerate(rig.cameras):  # refused before any view is rendered
        check_whole_frame(camera, supersample, who=f"{rig.source or rig.name}: cameras[{i}] "
                                                   f"({camera.name})",
                          fixed="the calibration's board views")
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
