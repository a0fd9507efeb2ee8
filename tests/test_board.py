"""The calibration board (itg_vision.board): texture, pose maths, and rendered corners against
the projection of the true board."""

import numpy as np
import pytest

from itg_vision import board as brd
from itg_vision.arm import ArmSpec
from itg_vision.camera import Rig
from itg_vision.world import World

from conftest import ROOT, random_rotation, roundoff

PLANAR = ROOT / "cameras" / "planar.yaml"


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        R, q = random_rotation(rng)
        got = brd.quaternion_xyzw(R)
        assert min(np.abs(got - q).max(), np.abs(got + q).max()) < 1e-9


def test_board_texture_has_the_pattern_and_an_asymmetric_corner():
    b = brd.Board()
    tex = b.texture()
    ppm = b.px_per_mm
    x0, y0, _, _ = b.extent_mm()

    def at(x_mm, y_mm):
        return tex[int((y_mm - y0) * ppm), int((x_mm - x0) * ppm)]

    s = b.square_mm
    assert at(-s / 2, -s / 2) == 0                                  # outside corner 0: black
    assert at((b.cols - 0.5) * s, (b.rows - 0.5) * s) == 255        # outside the last: white
    assert at(-s - b.margin_mm / 2, 0) == 255                       # margin
    assert b.object_points().shape == (b.cols * b.rows, 3)


@pytest.mark.parametrize("cols, rows", [(9, 6), (8, 7)])
def test_rendered_corners_match_the_projection_of_the_true_board(cols, rows):
    """Texture orientation, UVs and the TinyRenderer pixel convention in one check: detected
    corners against the true board corners projected through the camera (with distortion).
    Measured 0.06 to 0.21 px RMS per view; a flipped texture or a UV offset gives tens of px.
    The 9 x 6 pattern is symmetric under a flip of the texture's v (its 7 rows of squares
    alternate evenly), so only the 8 x 7 board checks v."""
    rig = Rig.from_yaml(PLANAR)
    board = brd.Board(cols, rows)
    rng = np.random.default_rng(3)
    poses = brd.sample_board_poses(rig, board, 4, rng, target_mm=[0, 0, 0])[::2]  # stereo views
    with World(ArmSpec.from_args("two-link")) as world:
        views = brd.render_views(world, rig, board, poses, rng)
    for pose, corners in zip(poses, views.corners):
        for cam, c in zip(rig.cameras, corners):
            assert c is not None
            truth = cam.project(pose.points(board.object_points()))
            rms = np.sqrt(np.mean(np.sum((c.reshape(-1, 2) - truth) ** 2, axis=1)))
            assert rms < 0.25, (cam.name, rms)


@pytest.mark.parametrize("cols, rows", [(9, 7), (8, 6), (1, 6)])
def test_a_board_whose_turn_cannot_be_told_is_refused(cols, rows):
    """cols + rows even puts black squares beyond both the first and the last corner (the
    texture's rule: square (a, b) black when a + b is even), so a 180-degree turn of the board
    would be read as the board itself: refused, as is a board with no 2 x 2 grid."""
    with pytest.raises(ValueError, match=f"Board: {cols} x {rows} inner corners"):
        brd.Board(cols, rows)


def test_a_board_showing_its_back_is_not_visible():
    """A board showing its back is not posed for a camera (its back is plain; were it
    patterned, the corners would be matched in the wrong order): a pose that shows the front
    is visible, the same board turned over about its own x axis (normal reversed, centre
    kept) is not."""
    rig = Rig.from_yaml(PLANAR)
    board = brd.Board()
    pose = brd.sample_board_poses(rig, board, 1, np.random.default_rng(0), target_mm=[0, 0, 0])[0]
    cam = rig.cameras[0]
    assert brd.board_visible(cam, board, pose)
    R = pose.R @ np.diag([1.0, -1.0, -1.0])
    centre = pose.points(board.centre_mm())
    back = brd.BoardPose(R, centre - R @ board.centre_mm())
    assert np.allclose(back.points(board.centre_mm()), centre, rtol=0, atol=roundoff(1000))  # ~700 mm away
    assert not brd.board_visible(cam, board, back)


def test_the_back_of_the_board_shows_no_pattern():
    """A camera that sees the board's back finds no corners there. Its back used to show the
    pattern mirrored, and a camera facing the other across the workspace (a rig of the user's,
    cameras at x = -+550 mm, 250 mm up, looking at the base) found the board in views posed for
    the other camera alone, its corners put in the front's order by canonical_order: a
    physically turned board. Each camera's own fit took them (0.1 px) and the pair did not
    (stereo RMS 17.7 px: 'calibration inconsistent ... intrinsics disagree'). The board
    rendered turned over about its own x axis (centre kept), noise-free: front found, back not."""
    rig = Rig.from_yaml(PLANAR)
    board = brd.Board()
    pose = brd.sample_board_poses(rig, board, 1, np.random.default_rng(0), target_mm=[0, 0, 0])[0]
    R = pose.R @ np.diag([1.0, -1.0, -1.0])
    centre = pose.points(board.centre_mm())
    back = brd.BoardPose(R, centre - R @ board.centre_mm())
    with World(ArmSpec.from_args("two-link")) as world:
        front_views = brd.render_views(world, rig, board, [pose], None)
        back_views = brd.render_views(world, rig, board, [back], None)
    assert all(c is not None for c in front_views.corners[0])
    assert all(c is None for c in back_views.corners[0])


@pytest.mark.parametrize("turn_deg", [0, 30, 90, 180, 250])
def test_corners_in_any_order_opencv_returns_are_put_in_the_boards(turn_deg):
    """The board's texture warped into an image by a known similarity (turned, scaled,
    moved: seen from the front): its corners' true image positions are the warp of the object
    points. Given them in the board's order, turned by 180 degrees (reversed) or mirrored
    (each row reversed), as OpenCV may return them, canonical_order gives the board's order."""
    import cv2

    b = brd.Board()
    tex = b.texture()
    x0, y0, _, _ = b.extent_mm()
    scale = 0.6 * 640 / tex.shape[1]
    a = np.radians(turn_deg)
    R = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    centre_tex = np.array(tex.shape[1::-1]) / 2
    H = np.eye(3)
    H[:2, :2], H[:2, 2] = R, np.array([320.0, 240.0]) - R @ centre_tex
    image = cv2.warpPerspective(tex, H, (640, 480), flags=cv2.INTER_AREA, borderValue=255)
    obj = b.object_points()[:, :2]
    tex_px = (obj - [x0, y0]) * b.px_per_mm  # (pixel centres: the texture's own rule aside)
    truth = (tex_px @ R.T + H[:2, 2]).astype(np.float32)
    grid = truth.reshape(b.rows, b.cols, 2)
    for given in (grid, grid[::-1, ::-1], grid[:, ::-1], grid[::-1, :]):
        got = brd.canonical_order(given.reshape(-1, 1, 2), image, b).reshape(-1, 2)
        np.testing.assert_array_equal(got, truth)
