"""Calibration (itg_vision.calibration and its command, itg_vision.calibrate): the geometry
helpers, a full calibration against the known rig, the failure cases and tracking on a
calibrated rig. The board itself: test_board.py."""

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from itg_vision import calibration as cal
from itg_vision.calibrate import measured_links, summary_table
from itg_vision.arm import ArmSpec
from itg_vision.board import Board
from itg_vision.camera import Camera, Rig
from itg_vision.errors import UserError
from itg_vision.world import World

from conftest import ROOT, random_rotation, roundoff

PLANAR = ROOT / "cameras" / "planar.yaml"


def test_circle_fit_recovers_centre_axis_and_radius():
    from itg_vision.identify import fit_circle, rotation_sense_axis, zero_direction

    rng = np.random.default_rng(1)
    R, _ = random_rotation(rng)
    centre = rng.uniform(-300, 300, 3)
    q = np.linspace(-150, 150, 23)  # a joint sweep, increasing
    ring = np.c_[80 * np.cos(np.radians(q + 20)), 80 * np.sin(np.radians(q + 20)), np.zeros(23)]
    P = ring @ R.T + centre
    c, n, r, rms = fit_circle(P)
    # exact points: float64 round-off of the fit at the points' size (~270 mm); a direction is
    # off by that over the 80 mm lever of the radius, plus its own round-off as a unit vector
    at = roundoff(np.abs(P).max())
    turned = at / 80 + roundoff(1.0)
    assert np.allclose(c, centre, rtol=0, atol=at) and r == pytest.approx(80, abs=at) and rms < at
    axis = rotation_sense_axis(c, n, P)
    assert np.allclose(axis, R[:, 2], rtol=0, atol=turned)  # counter-clockwise with increasing angle
    # at q = 0 the point sat 20 deg past the ring's x axis
    assert np.allclose(zero_direction(c, axis, P, q),
                       R @ [np.cos(np.radians(20)), np.sin(np.radians(20)), 0], rtol=0, atol=turned)
    # 0.3 mm noise per coordinate on 23 points: the centre within ~0.3 / sqrt(23 / 2) ~ 0.1 mm
    c2, _, r2, rms2 = fit_circle(P + rng.normal(0, 0.3, P.shape))
    assert np.linalg.norm(c2 - centre) < 0.4 and abs(r2 - 80) < 0.4 and 0.1 < rms2 < 0.6


def _camera1_frame(rig):
    """The rig re-expressed with camera 1 at the origin (what stereo calibration yields)."""
    from itg_vision.camera import Camera

    c1, c2 = rig.cameras
    R = c2.R @ c1.R.T
    cams = [Camera.from_arrays(c1.name, c1.size, c1.K, c1.dist_coeffs, np.eye(3), np.zeros(3)),
            Camera.from_arrays(c2.name, c2.size, c2.K, c2.dist_coeffs, R, c2.t_mm - R @ c1.t_mm)]
    return Rig("c1", tuple(cams))


@pytest.mark.parametrize("arm_name, rig_name", [("one-link", "planar"), ("two-link", "planar"),
                                                ("three-link", "three-link")])
def test_base_frame_from_joint_axes_ignores_the_link_lengths(arm_name, rig_name):
    """The base frame from the joint axes the LEDs trace, with the true pair: within 1 mm /
    0.1 deg of the truth, whether the simulated links are nominal or 5 % long. The three-link
    origin sits the nominal base height below the measured shoulder: it moves by the base
    height's own error (5 mm up), and only in z."""
    true_rig = Rig.from_yaml(ROOT / "cameras" / f"{rig_name}.yaml")
    rig_c1 = _camera1_frame(true_rig)
    nominal = ArmSpec.from_args(arm_name)
    cam1 = true_rig.cameras[0]
    for scale in (1.0, 1.05):
        true_arm = ArmSpec.from_args(arm_name, tuple(scale * v for v in nominal.links_mm))
        rng = np.random.default_rng(0)
        with World(true_arm) as world:
            sweeps = {j: (cal.led_images(world, true_rig, nominal, q, rng), names)
                      for j, (q, names) in cal.axis_sweeps(nominal).items()}
        R_w, t_w, rec = cal.base_frame_from_axes(rig_c1, nominal, sweeps)
        angle = np.degrees(np.linalg.norm(__import__("cv2").Rodrigues(R_w @ cam1.R.T)[0]))
        origin_shift = R_w.T @ (t_w - cam1.t_mm)  # true-world coordinates of the found origin
        expect = [0, 0, (scale - 1) * nominal.links_mm[0] if arm_name == "three-link" else 0]
        # LEDs triangulated to ~0.3 mm; 19-23 poses per circle: the fits average it down
        assert angle < 0.1, (scale, angle)
        assert np.linalg.norm(origin_shift - expect) < 1.0, (scale, origin_shift)
        assert rec["fit_rms_mm"] < 1.0
        # each measured length is the simulated link its name says (three-link: L2, L3; the
        # base height L1 is not seen)
        assert rec["measured_links"] == {"one-link": ["L1"], "two-link": ["L1", "L2"],
                                         "three-link": ["L2", "L3"]}[arm_name]
        for name, got in zip(rec["measured_links"], rec["measured_links_mm"]):
            assert got == pytest.approx(true_arm.links_mm[int(name[1:]) - 1], abs=0.5), name


def _synthetic_views(rig, board, tilts_deg, noise_px, seed=0):
    """Board views as exact projections of the true corners plus Gaussian pixel noise, no
    rendering: the board faces the cameras, tilted by (about its x, about its y) in deg."""
    from itg_vision import board as brd
    rng = np.random.default_rng(seed)
    front = brd.sample_board_poses(rig, board, 1, rng, target_mm=[0, 0, 0], tilt_deg=0,
                                   spin_deg=0)[0]
    centre = front.points(board.centre_mm())
    poses, corners = [], []
    for a, b in tilts_deg:
        R = front.R @ cv2.Rodrigues(np.radians([a, b, 0.0]))[0]
        pose = brd.BoardPose(R, centre - R @ board.centre_mm())
        assert all(brd.board_visible(c, board, pose, border_px=0) for c in rig.cameras)
        uv = [c.project(pose.points(board.object_points())) for c in rig.cameras]
        poses.append(pose)
        corners.append(tuple((x + rng.normal(0, noise_px, x.shape)).astype(np.float32)
                             .reshape(-1, 1, 2) for x in uv))
    return brd.Views(poses, corners)


def test_every_led_a_joint_moves_is_fitted_about_one_axis(monkeypatch):
    """A joint's sweep moves its LEDs on circles about one axis: they are fitted about the
    axis all their points give (coaxial_normal), so each LED's circle has that same axis
    (fitted alone, the short circle's plane tilts with its own noise). Synthetic LEDs about a known axis,
    tilted 3 deg, radii 100 and 30 mm, 0.05 mm noise (the eye's), stand in for the
    triangulated ones."""
    rng = np.random.default_rng(2)
    axis = cv2.Rodrigues(np.radians([3.0, -2.0, 0.0]))[0] @ [0.0, 0.0, 1.0]
    e1 = np.cross(axis, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    angles = np.radians(np.linspace(-120, 120, 25))
    radius = {"gripper": 100.0, "elbow": 30.0}
    centre = np.array([10.0, -20.0, 600.0])
    points = {n: [centre + 12 * axis + r * (np.cos(a) * e1 + np.sin(a) * e2)
                  + rng.normal(0, 0.05, 3) for a in angles] for n, r in radius.items()}
    monkeypatch.setattr(cal, "triangulate_leds",  # a shot's "images": its index here
                        lambda rig, arm, i: {n: p[i] for n, p in points.items()})
    shots = [(np.array([np.degrees(a), 0.0]), i, None) for i, a in enumerate(angles)]
    fits = cal._joint_fits(None, ArmSpec.from_args("two-link"), 0, shots, ("gripper", "elbow"))
    a_g, a_e = fits["gripper"]["axis"], fits["elbow"]["axis"]
    assert abs(a_g @ a_e) == pytest.approx(1.0, abs=roundoff(1))
    # the truth to the noise's reach (0.05 mm over a 200 mm chord: ~0.01 deg; bound 0.05 deg)
    assert np.degrees(np.arccos(min(1.0, abs(a_g @ axis)))) < 0.05


def test_poses_tilted_about_one_axis_only_are_refused():
    """Zhang's method needs board planes turned about two axes. Twelve views tilted over 60 deg
    about the board's x axis alone (0.05 px corner noise, the detector's order) are refused by
    the tilt-span gate, whose smaller span is 0: the focal std (0.19 %) would pass its own 1 %
    gate. The same views spread over both axes (60 x 50 deg) calibrate."""
    rig, board = Rig.from_yaml(PLANAR), Board()
    one_axis = [(a, 0.0) for a in np.linspace(-30, 30, 12)]
    with pytest.raises(UserError, match=r"degenerate board poses: the board's tilt spans only "
                                        r"60 x 0 deg over 12 views"):
        cal.calibrate_views(_synthetic_views(rig, board, one_axis, 0.05), board,
                            tuple(c.size for c in rig.cameras))
    two_axes = ([(a, 0.0) for a in np.linspace(-30, 30, 6)]
                + [(0.0, b) for b in np.linspace(-25, 25, 6)])
    res = cal.calibrate_views(_synthetic_views(rig, board, two_axes, 0.05), board,
                              tuple(c.size for c in rig.cameras))
    assert min(res.tilt_span_deg) >= cal.MIN_TILT_SPAN_DEG
    # the fit leaves the noise: 0.05 px per axis over n = 12 * 54 * 2 coordinates, less the
    # p = 8 + 6 * 12 parameters fitted (fx, fy, cx, cy, k1, k2, p1, p2; a pose per view); the
    # RMS's own scatter is ~1 / sqrt(2 n) = 2 % of it
    n, p_fit = 12 * board.rows * board.cols * 2, 8 + 6 * 12
    expected = 0.05 * np.sqrt(2 * (1 - p_fit / n))
    assert res.rms_px == pytest.approx((expected, expected), rel=0.06)


def test_distortion_field_error_is_the_radial_change_at_the_farthest_ray():
    """Changing k1 by d moves a ray at undistorted normalised radius r by d r^2 (x, y) in the
    normalised plane, (fx x, fy y) d r^2 in pixels: largest at an image corner. Identical lens
    models give 0."""
    cam = Rig.from_yaml(PLANAR).cameras[0]
    assert cal.distortion_field_error_px(cam, cam) == 0.0
    d = 0.01
    other = Camera.from_arrays(cam.name, cam.size, cam.K, cam.dist_coeffs + [d, 0, 0, 0, 0],
                               cam.R, cam.t_mm, cam.noise_sigma_gray, cam.exposure)
    W, H = cam.size
    corners = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]], float)
    x, y = cv2.undistortPoints(corners.reshape(-1, 1, 2), cam.K, cam.dist_coeffs).reshape(-1, 2).T
    expected = np.max(d * (x**2 + y**2) * np.hypot(cam.fx * x, cam.fy * y))
    # the change is linear in k1, so exact up to float64 round-off of the pixel positions (~640 px)
    assert cal.distortion_field_error_px(cam, other) == pytest.approx(expected, rel=0,
                                                                      abs=roundoff(max(W, H)))


# ---------------------------------------------------------------------------- full calibration
def _base_frame_bounds(res, true_rig):
    """Bounds on the base frame's error, (rotation deg, origin mm), from the calibration's own
    uncertainty rather than a fixed 0.1 deg / 1 mm (which seed 0 met and 8 of seeds 0-9 did not:
    0.03 to 0.21 deg, 0.5 to 2.0 mm).

    The frame is found from the LEDs triangulated with the calibrated pair and compared with
    the truth through camera 1. A principal-point error dc of camera 1 cannot be told from a
    camera rotation of dc / f (both give the same images), so the frame seen from camera 1
    turns by it (measured: the rotation error follows the principal-point error, 1.2 dc / f),
    and its origin, at distance d from the camera, moves by d times that angle; a baseline
    error dB scales depths by dB / B. OpenCV's standard deviations of cx, cy give
    sigma = hypot(s_cx / fx, s_cy / fy) rad (0.10 to 0.13 deg with 60 views). Bounds: the fit's
    own 0.1 deg / 1 mm with the true pair (test_base_frame_from_joint_axes_...) plus 3 sigma,
    and for the origin d * hypot(3 sigma, dB / B) with this run's baseline error dB (bounded on
    its own by the baseline target). Seeds 0-9 reached at most 1.9 sigma in rotation and half
    the origin bound.
    """
    cam1, cam2 = true_rig.cameras
    s = res.stereo.intrinsics_std_px[0]  # fx, fy, cx, cy
    sigma_rad = float(np.hypot(s[2] / cam1.fx, s[3] / cam1.fy))
    d_mm = float(np.linalg.norm(cam1.position_mm))
    b_mm = float(np.linalg.norm(cam2.position_mm - cam1.position_mm))
    db_mm = res.record["error_vs_true"]["baseline_mm"]
    return (0.1 + 3 * np.degrees(sigma_rad),
            1.0 + d_mm * float(np.hypot(3 * sigma_rad, db_mm / b_mm)))


@pytest.fixture(scope="module")
def planar_result():
    """The default number of views (60; ~15-25 s): fewer views (30-40) measured focal errors up
    to 0.37 %, above the 0.2 % target."""
    rig = Rig.from_yaml(PLANAR)
    return rig, cal.calibrate(rig, ArmSpec.from_args("two-link"), views=cal.DEFAULT_VIEWS,
                              seed=0, check_poses=15)


@pytest.mark.slow
def test_calibration_recovers_the_true_rig_within_the_targets(planar_result):
    true_rig, res = planar_result
    r = res.record
    e = r["error_vs_true"]
    for name in ("left", "right"):
        # Target 0.15 px: the corner detector's own error on these renders is ~0.09 px RMS.
        assert r["reprojection_rms_px"][name] <= 0.15
        c = e["cameras"][name]
        assert max(abs(v) for v in c["focal_length_pct"]) <= 0.2            # target
        # Not targets; bounds from the measured 0.2-0.5 px and 0.04-0.4 deg, 0.7-3 mm
        # (cx couples with the rotation about y; the base fit uses ~0.3 mm LED positions).
        assert max(abs(v) for v in c["principal_point_px"]) <= 2.5
        assert c["rotation_deg"] <= 0.5
        assert c["position_mm"] <= 4.0
        # the lens models' largest difference (test_distortion_field_error_...), at the image
        # corners, which the board reaches least: measured 0.48 and 0.82 px (seed 0)
        assert 0 < c["distortion_max_px"] <= 2.5
    assert abs(e["baseline_mm"]) <= 0.5                                     # target
    led = r["led_triangulation"]
    assert led["points"] >= 20
    # The eye's own target (issue 11: gripper <= 0.1 mm RMS) holds on the calibrated rig. The
    # older target "ratio to the true rig <= 1.2" dates from an eye 6x less accurate (0.28 mm):
    # the calibration now adds ~0.03-0.07 mm in quadrature to a 0.05 mm eye (ratio 1.2-1.7
    # over seeds 0-2 at 60 and 120 views), so the ratio is reported, not asserted.
    assert led["true_rig_rms_mm"] <= 0.1 and led["calibrated_rig_rms_mm"] <= 0.1  # target
    # the two rigs triangulate differently (a focal error of >= 1e-4 moves depths ~0.06 mm)
    assert abs(led["ratio"] - 1) > 1e-6
    assert r["base_frame"]["fit_rms_mm"] < 1.0
    rot_bound_deg, origin_bound_mm = _base_frame_bounds(res, true_rig)
    assert e["base_frame"]["rotation_deg"] < rot_bound_deg, rot_bound_deg
    assert e["base_frame"]["origin_mm"] < origin_bound_mm, origin_bound_mm
    # the calibrated rig differs from the true one (it was estimated, not copied)
    assert res.rig.cameras[0].fx != true_rig.cameras[0].fx


@pytest.mark.slow
def test_calibration_with_links_five_percent_long_keeps_the_base_frame():
    """The simulated arm 5 % longer than the nominal model: the base frame comes from the joint
    axes, not from the lengths, so it stays within the bounds the calibration's own
    uncertainty sets (see _base_frame_bounds), and the joint-axis fits measure the true
    lengths."""
    rig = Rig.from_yaml(PLANAR)
    res = cal.calibrate(rig, ArmSpec.from_args("two-link"), views=cal.DEFAULT_VIEWS, seed=0,
                        check_poses=5, true_arm=ArmSpec.from_args("two-link", (105.0, 105.0)))
    e = res.record["error_vs_true"]
    rot_bound_deg, origin_bound_mm = _base_frame_bounds(res, rig)
    assert e["base_frame"]["rotation_deg"] < rot_bound_deg, rot_bound_deg
    assert e["base_frame"]["origin_mm"] < origin_bound_mm, origin_bound_mm
    assert res.record["base_frame"]["measured_links_mm"] == pytest.approx([105, 105], abs=0.5)


@pytest.mark.slow
def test_written_rig_round_trips_and_tracks(planar_result, tmp_path, cli):
    _, res = planar_result
    out = tmp_path / "planar.calib.yaml"
    pic = cal.write_result(res, out, PLANAR)
    # the picture on disk is the result's, pixel for pixel (PNG: lossless), in RGB
    assert np.array_equal(cv2.cvtColor(cv2.imread(str(pic)), cv2.COLOR_BGR2RGB), res.picture)
    back = Rig.from_yaml(out)
    assert back.true_rig and (out.parent / back.true_rig).resolve() == PLANAR.resolve()
    assert back.calibration["views_shown"] == cal.DEFAULT_VIEWS
    # the YAML keeps every float's repr: the same numbers back
    assert np.array_equal(back.cameras[1].K, res.rig.cameras[1].K)
    assert np.allclose(back.cameras[1].R, res.rig.cameras[1].R, rtol=0, atol=roundoff(1.0))
    proc = cli("itg_vision.run", "--rig", out, "--points", 12, "--quiet",
               "--out", tmp_path / "run")
    assert proc.returncode == 0, proc.stderr
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["estimate_rig"] == str(out)
    assert s["render_rig"].endswith("planar.yaml")
    # The estimate's error, not E_av (12 set points are a coarse trajectory either way):
    # measured 0.30 mm RMS with the calibrated rig against 0.21 mm with the true rig.
    assert s["est_gripper_rms_mm"] < 1.0


@pytest.mark.slow
def test_summary_table_lists_the_figures(planar_result):
    text = summary_table(planar_result[1].record)
    for word in ("reprojection RMS", "focal length", "principal point", "baseline",
                 "rotation", "world position", "LED triangulation", "worst view", "p95 / max",
                 "stereo excess over the cameras' RMS / bound", "LED-noise bound"):
        assert word in text


@pytest.mark.slow
def test_the_views_shown_found_dropped_and_used_add_up(planar_result):
    """The stereo views used are those both cameras found the board in, less the outliers
    dropped; the table says both counts (it listed the outliers only, so that 54 of 60 with
    two dropped left four views unexplained)."""
    res = planar_result[1]
    r, st = res.record, res.stereo
    assert set(st.stereo_views) == set(st.used[0]) & set(st.used[1])  # each camera's, kept
    assert not set(st.stereo_views) & set(st.dropped)
    # the views both found: the ones used, and some of the dropped (others one camera alone found)
    assert r["views_found"]["both"] == st.n_found_both
    assert len(st.stereo_views) <= st.n_found_both <= len(st.stereo_views) + len(st.dropped)
    assert st.n_found_both <= min(st.n_found) <= max(st.n_found) <= r["views_shown"]
    line = next(x for x in summary_table(r).splitlines() if x.startswith("stereo views used"))
    assert f"{len(st.stereo_views)} / {r['views_shown']} (found by both cameras in " \
           f"{st.n_found_both})" in line


def test_summary_table_names_the_measured_links():
    """Three-link: the fits measure L2 and L3 (L1 is the base height, not seen); the table
    names them, and reads an older file without the names as before."""
    bf = {"measured_links_mm": [99.8983, 99.9691], "measured_links": ["L2", "L3"]}
    assert measured_links(bf) == "measured L2 99.90, L3 99.97 mm"
    assert measured_links({"measured_links_mm": [99.9]}) == "measured links 99.90 mm"


def test_summary_table_labels_the_errors_against_the_true_rig():
    """The rows comparing with the true rig say so ("error"), as the README's table does; the
    values are the file's error_vs_true (calibrated - true)."""
    record = Rig.from_yaml(ROOT / "cameras" / "planar.calib.yaml").calibration
    rows = {line[:45].strip(): line[45:].split() for line in summary_table(record).splitlines()}
    cams = record["error_vs_true"]["cameras"]
    names = list(cams)

    def shown(row):  # the row's numbers, one list per camera (fx, fy or one value each)
        v = [float(x.rstrip(",")) for x in rows[row]]
        k = len(v) // len(names)
        return [v[k * i:k * (i + 1)] for i in range(len(names))]

    for row, key, digits in (("focal length error fx, fy (%)", "focal_length_pct", 3),
                             ("principal point error u, v (px)", "principal_point_px", 2),
                             ("distortion error, max over image (px)", "distortion_max_px", 3),
                             ("rotation error (deg)", "rotation_deg", 3),
                             ("world position error (mm)", "position_mm", 2)):
        for got, n in zip(shown(row), names):  # the shapes must match too
            np.testing.assert_allclose(got, np.atleast_1d(cams[n][key]),
                                       atol=0.51 * 10.0**-digits, rtol=0, err_msg=row)
    worst = [max(record["per_view_rms_px"][n]) for n in names]
    np.testing.assert_allclose([v for vs in shown("worst view's reprojection RMS (px)") for v in vs],
                               worst, atol=5.1e-4, rtol=0)


def test_corner_picture_has_a_title_above_the_view():
    """The picture is the view with its corners drawn, under a band with the title's lines."""
    board = cal.Board()
    img = np.full((480, 640, 3), 200, np.uint8)
    cols, rows = board.pattern_size
    corners = np.array([[[100 + 20 * i, 100 + 20 * j]] for j in range(rows) for i in range(cols)],
                       np.float32)
    title = ["planar rig, left camera: view 0 (of 60 shown), 54 corners detected", "second line"]
    pic = cal.corner_picture(img, board, corners, title)
    band = pic.shape[0] - 480
    assert band == 20 * len(title) + 8 and pic.shape[1:] == (640, 3)
    assert pic[:21].min() < 100 and pic[21:band].min() < 100  # each line's dark text
    assert (pic[band:] != img).any()  # the corners drawn on the view
    assert (pic[band:, 300:] == img[:, 300:]).all()  # nowhere else: the title is above it


def test_progress_counts_the_poses_it_renders(tmp_path, monkeypatch, main_in_process):
    """The bar's total is every rendered pose (board views, then the arm's sweeps and check
    poses) and says so: it read "126/126 view" for 60 views."""
    from itg_vision import calibrate as command

    def fake_calibrate(true_rig, arm, *, progress, **kw):
        for _ in range(cal.progress_steps(arm, 60, 20)):
            progress("board")
        raise UserError("stop")

    monkeypatch.setattr(command, "calibrate", fake_calibrate)
    proc = main_in_process("itg_vision.calibrate", "--out", tmp_path / "x.calib.yaml")
    sweeps = sum(len(q) for q, _ in cal.axis_sweeps(ArmSpec.from_args("two-link")).values())
    n = 60 + sweeps + 20  # 126
    assert proc.stderr.splitlines()[-2].startswith(
        f"calibrate (60 board + {sweeps + 20} arm poses): {n}/{n} pose (100%), ")


def test_arm_may_be_an_arm_file_with_true_links(tmp_path):
    """--arm takes a shipped arm or an arm file, as run's; --true-links applies to that file
    (it reloaded the arm by its name, unknown outside data/arms)."""
    from itg_vision.calibrate import Job, build_parser

    text = (ROOT / "data" / "arms" / "two-link.yaml").read_text()
    mine = tmp_path / "mine.yaml"
    mine.write_text(text.replace("name: two-link", "name: mine"))
    job = Job.from_args(build_parser().parse_args(["--arm", str(mine), "--true-links", "105,95"]))
    assert (job.arm.name, job.arm.source, job.arm.links_mm) == ("mine", str(mine), (100.0, 100.0))
    assert (job.true_arm.name, job.true_arm.links_mm) == ("mine", (105.0, 95.0))


# ---------------------------------------------------------------------------- failures
def _camera_looking_away(tmp_path):
    d = yaml.safe_load(PLANAR.read_text())
    d["cameras"][1]["pose"]["look_at_mm"] = [2000.0, 0.0, 620.0]
    d["name"] = "away"
    path = tmp_path / "away.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.parametrize("args, expect", [
    (["--views", "2"], "planar.yaml: the board was found by both cameras in only 1 of 2 views "
                       "(each camera alone: cameras[0] (left) 1, cameras[1] (right) 2); need at least 6 "
                       "(at this rate about --views 12 would show it to both 6 times)"),
    # every message names the rig file first (this one did not before)
    (["--views", "12", "--tilt", "0"], "planar.yaml: degenerate board poses: the board's tilt "
                                       "spans only"),
    # names the rig file and the camera's place in it (the file was not named before); a
    # camera looking away from the arm is refused before anything is rendered (it rendered the
    # board's views first, then said it never found the board)
    (["--views", "6", "--rig", "AWAY"], "away.yaml: base frame: arm two-link, joint q1's sweep: "
                                        "the elbow LED is in view of both cameras in only 0 of "
                                        "23 poses (their fields of view, before rendering; each "
                                        "camera alone: cameras[0] (left) 23, cameras[1] (right) "
                                        "0); need at least 18"),
    (["--views", "0"], "--views"),
    (["--rig", "no-such-rig"], "unknown rig 'no-such-rig' (shipped: planar,"),
])
def test_failures_exit_2_with_one_line_and_keep_the_old_file(cli, tmp_path, args, expect):
    out = tmp_path / "old.calib.yaml"
    out.write_text("old\n")
    args = [str(_camera_looking_away(tmp_path)) if a == "AWAY" else a for a in args]
    # --force: the old file is not a calibration of this rig (refused before any work without it)
    proc = cli("itg_vision.calibrate", *args, "--quiet", "--force", "--out", out)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and expect in lines[0], proc.stderr
    assert out.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) in (["old.calib.yaml"],
                                                          ["away.yaml", "old.calib.yaml"])


def test_a_camera_that_never_finds_the_board_is_named_with_its_rig_file():
    """(The command reaches this only with the arm's sweeps in view of both cameras, which a
    camera looking away is not: its own refusal comes first, before rendering.)"""
    from itg_vision.board import Views

    views = Views([None] * 6, [(np.zeros((54, 1, 2), np.float32), None)] * 6)
    with pytest.raises(UserError) as exc:
        cal.calibrate_views(views, Board(), ((640, 480), (640, 480)),
                            ("cameras[0] (left)", "cameras[1] (right)"), source="away.yaml")
    assert str(exc.value) == ("away.yaml: cameras[1] (right): never found the board in 6 views: "
                              "is it pointed at the workspace?")


SWEEP_HINT = ("both cameras must see the LEDs over the arm's joint sweeps (check the rig's camera "
              "poses, or narrow the sweep to what the rig sees: the arm file's "
              "calibration.axis_sweeps)")


@pytest.mark.parametrize("seen", [7, 17])
def test_a_sweep_seen_in_too_few_poses_names_the_rig_the_arm_and_the_count_needed(monkeypatch,
                                                                                 seen):
    """An LED seen by both cameras in fewer than 3/4 of a sweep's 23 poses (18): one line naming
    the rig file, the arm, the joint, the LED, the count needed and what to change; it named no
    file, no arm and no need. (The eye stubbed: the gripper seen in the first ``seen`` poses.)"""
    def eye(rig, arm, k):
        return {"elbow": np.zeros(3), **({"gripper": np.zeros(3)} if k < seen else {})}

    monkeypatch.setattr(cal, "triangulate_leds", eye)
    shots = [(np.zeros(2), k, None) for k in range(23)]
    with pytest.raises(UserError) as exc:
        cal.base_frame_from_axes(Rig.from_yaml(PLANAR), ArmSpec.from_args("two-link"),
                                 {0: (shots, ("elbow", "gripper"))}, source="nearrig.yaml")
    assert str(exc.value) == (
        f"nearrig.yaml: base frame: arm two-link, joint q1's sweep: the gripper LED was seen by "
        f"both cameras in only {seen} of 23 poses; need at least 18: {SWEEP_HINT}")


def test_a_rig_that_sees_the_sweeps_poorly_fails_in_one_line_naming_its_file(cli, tmp_path):
    """The right camera lowered to z = 300 mm has the gripper over q1's sweep in view in only 7
    of 23 poses (7 seen, rendered): the command's one line names the rig file, as its board
    error does, and comes before anything is rendered (it came after 18 s of work)."""
    near = tmp_path / "nearrig.yaml"
    near.write_text(PLANAR.read_text().replace("[180.0, -60.0, 620.0]", "[180.0, -60.0, 300.0]"))
    out = tmp_path / "near.calib.yaml"
    proc = cli("itg_vision.calibrate", "--rig", near, "--quiet", "--out", out)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [
        f"error: {near}: base frame: arm two-link, joint q1's sweep: the gripper LED is in view "
        "of both cameras in only 7 of 23 poses (their fields of view, before rendering; each "
        f"camera alone: cameras[0] (left) 23, cameras[1] (right) 7); need at least 18: "
        f"{SWEEP_HINT}"], proc.stderr
    assert not out.exists()


def test_sweeps_out_of_view_are_refused_before_rendering_and_a_narrowed_one_is_not(tmp_path):
    """conftest.front_rig has the gripper in view of both cameras over the shipped two-link q1
    sweep (-165..+165 deg) in 14 of its 23 poses (14 seen, rendered: README): refused from the
    fields of view alone (it was refused after rendering 60 board views and the sweeps, 15 s);
    with the sweep narrowed to 0..+150 deg, as the README's copy of the arm file, nothing is
    refused (calibrated, rendered: base frame 0.41 mm, 0.036 deg)."""
    from conftest import front_rig

    rig = Rig.from_yaml(front_rig(tmp_path / "front.yaml"))
    shipped = ArmSpec.from_args("two-link")
    with pytest.raises(UserError) as exc:
        cal.sweeps_in_view(rig, shipped, cal.axis_sweeps(shipped), "front.yaml")
    assert str(exc.value) == (
        "front.yaml: base frame: arm two-link, joint q1's sweep: the gripper LED is in view of "
        "both cameras in only 14 of 23 poses (their fields of view, before rendering; each camera "
        f"alone: cameras[0] (left) 15, cameras[1] (right) 15); need at least 18: {SWEEP_HINT}")
    copy = tmp_path / "two-link-front.yaml"
    copy.write_text((ROOT / "data" / "arms" / "two-link.yaml").read_text().replace(
        "from_deg: -165, to_deg: 165", "from_deg: 0, to_deg: 150"))
    narrowed = ArmSpec.from_args(str(copy))
    cal.sweeps_in_view(rig, narrowed, cal.axis_sweeps(narrowed), "front.yaml")


def test_calibrate_help(cli):
    proc = cli("itg_vision.calibrate", "--help")
    assert proc.returncode == 0 and "--views" in proc.stdout and "--rig" in proc.stdout


# ---------------------------------------------------------------------------- --out, checked first
def _this_rigs_calibration(path):
    """A calibration of planar.yaml at ``path`` (its true_rig names it absolutely)."""
    text = (ROOT / "cameras" / "planar.calib.yaml").read_text()
    doc = yaml.safe_load(text)
    doc["true_rig"] = str(PLANAR)
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("force, existing", [(True, False), (False, True)])
def test_a_folder_where_the_picture_goes_is_refused_before_any_work(tmp_path, force, existing):
    """The corner picture x.calib.png beside x.calib.yaml cannot replace a folder: refused by
    check_out, even with --force and when x.calib.yaml is this rig's calibration (it failed
    with IsADirectoryError, exit 1, after all the work)."""
    from itg_vision.calibrate import check_out

    out = tmp_path / "cal" / "x.calib.yaml"
    (tmp_path / "cal" / "x.calib.png").mkdir(parents=True)
    if existing:
        _this_rigs_calibration(out)
    with pytest.raises(UserError) as exc:
        check_out(out, PLANAR, force=force)
    assert str(exc.value) == (f"--out {out}: {out.parent / 'x.calib.png'} is a folder, where the "
                              "corner picture goes; choose another --out")


def test_a_name_too_long_for_the_temporary_file_is_refused_before_any_work(tmp_path):
    from itg_vision.calibrate import check_out

    with pytest.raises(UserError, match=r"the file name is too long \(245 bytes; at most 241"):
        check_out(tmp_path / ("c" * 240 + ".yaml"), PLANAR)
    assert list(tmp_path.iterdir()) == []


def test_a_write_that_fails_after_the_work_is_one_line_and_keeps_the_old_files(
        tmp_path, monkeypatch, main_in_process):
    """What check_out cannot foresee (the picture's place made a folder meanwhile, a full disk)
    is still one line naming the file, exit 2, with the old rig kept and no temporary file."""
    from types import SimpleNamespace

    from itg_vision import calibrate as command

    out = _this_rigs_calibration(tmp_path / "x.calib.yaml")
    old = out.read_text()
    pic = tmp_path / "x.calib.png"

    def fake_calibrate(true_rig, *a, **k):
        pic.mkdir()  # after check_out
        return SimpleNamespace(picture=np.zeros((4, 4, 3), np.uint8), rig=true_rig,
                               record={}, timing_s={"total_s": 0.0})

    monkeypatch.setattr(command, "calibrate", fake_calibrate)
    proc = main_in_process("itg_vision.calibrate", "--quiet", "--out", out)
    assert proc.returncode == 2
    assert proc.stderr == f"error: --out {out}: cannot write {pic} (Is a directory)\n"
    assert out.read_text() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.calib.png", "x.calib.yaml"]


def test_force_keeps_the_files_it_replaces_beside_the_new_ones(tmp_path, monkeypatch,
                                                              main_in_process):
    """A successful run never deletes a user's file: --force over a file that is not this
    rig's calibration (and the picture beside it) renames each to <stem>.replaced-N<suffix>,
    says so, and writes the calibration; a calibration of this rig is replaced as before."""
    from types import SimpleNamespace

    from itg_vision import calibrate as command
    from itg_vision.camera import Rig

    def fake_calibrate(true_rig, *a, **k):
        return SimpleNamespace(picture=np.zeros((4, 4, 3), np.uint8), rig=true_rig,
                               record={}, timing_s={"total_s": 0.0})

    monkeypatch.setattr(command, "calibrate", fake_calibrate)
    out, pic = tmp_path / "x.calib.yaml", tmp_path / "x.calib.png"
    out.write_text("my: settings\n")
    pic.write_bytes(b"my picture")
    proc = main_in_process("itg_vision.calibrate", "--quiet", "--out", out, "--force")
    assert proc.returncode == 0, proc.stderr
    kept_yaml, kept_png = tmp_path / "x.calib.replaced-1.yaml", tmp_path / "x.calib.replaced-1.png"
    assert kept_yaml.read_text() == "my: settings\n" and kept_png.read_bytes() == b"my picture"
    assert proc.stderr == (f"note: --out: {out} was not this rig's calibration; kept as {kept_yaml}\n"
                           f"note: --out: {pic} was not this rig's calibration; kept as {kept_png}\n")
    assert Rig.from_yaml(out).true_rig and pic.read_bytes().startswith(b"\x89PNG")
    # now the file is this rig's calibration: replaced, nothing more kept
    proc = main_in_process("itg_vision.calibrate", "--quiet", "--out", out, "--force")
    assert (proc.returncode, proc.stderr) == (0, "")
    assert len(list(tmp_path.iterdir())) == 4


def test_out_empty_is_an_error_not_the_default_file(tmp_path, monkeypatch, main_in_process):
    monkeypatch.chdir(tmp_path)
    proc = main_in_process("itg_vision.calibrate", "--quiet", "--out", "")
    assert (proc.returncode, proc.stderr) == (2, "error: --out: empty path\n")
    assert list(tmp_path.iterdir()) == []


def test_a_calibration_whose_true_rig_was_edited_is_refused(tmp_path, monkeypatch,
                                                             main_in_process):
    """calibrate records the true rig file's hash (true_rig_sha256). Once that file is edited
    (a camera moved 30 mm), a run on the calibration rendered with the edited rig and estimated
    with the stale one: exit 0, no word (a real calibration, 12 points: estimation RMS 0.055 ->
    0.63 mm). Now it is refused: one line naming both files and saying to re-run calibrate,
    exit 2, nothing written; re-run, the calibration is accepted again. (A stub calibration: the
    true rig as it was read.)"""
    import hashlib
    from types import SimpleNamespace

    from itg_vision import calibrate as command
    from itg_vision.runner import RunConfig, prepare

    def fake_calibrate(true_rig, *a, **k):
        return SimpleNamespace(picture=None, rig=true_rig, record={}, timing_s={"total_s": 0.0})

    monkeypatch.setattr(command, "calibrate", fake_calibrate)
    monkeypatch.chdir(tmp_path)
    true = Path("myrig.yaml")
    true.write_text(PLANAR.read_text())
    out = Path("runs") / "calibrate" / "myrig.calib.yaml"
    proc = main_in_process("itg_vision.calibrate", "--rig", true, "--quiet")
    assert (proc.returncode, proc.stderr) == (0, "")
    assert prepare(RunConfig(rig=str(out), points=4)).info["render_rig"] == \
        "runs/calibrate/../../myrig.yaml"

    calibrated = hashlib.sha256(true.read_bytes()).hexdigest()
    true.write_text(true.read_text().replace("[180.0, -60.0, 620.0]", "[180.0, -30.0, 620.0]"))
    proc = main_in_process("itg_vision.run", "--rig", out, "--points", 4, "--quiet",
                           "--out", "run")
    assert (proc.returncode, proc.stderr) == (2, (
        f"error: {out}: its true rig myrig.yaml has changed since it was calibrated "
        f"(true_rig_sha256 no longer matches); re-run python -m itg_vision.calibrate --rig "
        f"myrig.yaml --out {out}\n"))
    assert not Path("run").exists()
    assert yaml.safe_load(out.read_text())["true_rig_sha256"] == calibrated

    proc = main_in_process("itg_vision.calibrate", "--rig", true, "--out", out, "--quiet")
    assert (proc.returncode, proc.stderr) == (0, "")
    assert Rig.from_yaml(out).true_rig_sha256 == hashlib.sha256(true.read_bytes()).hexdigest()
    prepare(RunConfig(rig=str(out), points=4))


def test_calibrate_runs_opencv_on_one_thread_and_restores_it(monkeypatch):
    """OpenCV's threaded reductions sum in a varying order: calibrate runs on one thread (the
    same seed, the same calibration bit for bit) and gives the setting back, even on an error."""
    import cv2

    from itg_vision import calibration
    from itg_vision.arm import ArmSpec
    from itg_vision.camera import Rig
    from itg_vision.runner import CAMERAS_DIR

    seen = []

    def record(*args, **kwargs):
        seen.append(cv2.getNumThreads())
        raise RuntimeError("stop here")

    monkeypatch.setattr(calibration, "sample_board_poses", record)
    before = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        with pytest.raises(RuntimeError, match="stop here"):
            calibration.calibrate(Rig.from_yaml(CAMERAS_DIR / "planar.yaml"),
                                  ArmSpec.from_args("two-link"))
        assert seen == [1] and cv2.getNumThreads() == 2
    finally:
        cv2.setNumThreads(before)



@pytest.mark.parametrize("sigma_px, refused", [(0.05, False), (1.0, True)])
def test_views_that_leave_the_focal_length_uncertain_by_over_one_percent_are_refused(
        sigma_px, refused):
    """calibration.MAX_FOCAL_STD, 1 %: twelve views tilted over 50 deg about both axes (the
    tilt gate passes; the whole board in both cameras) with corners off by sigma px. OpenCV's
    own standard deviation of fx grows as sigma (measured 0.17 % at 0.05 px, 3.5 % at 1 px):
    the first is calibrated, the second refused in one line naming the focal std."""
    from itg_vision import board as brd

    rig, board = Rig.from_yaml(PLANAR), brd.Board()
    tilts = [(a, 0.0) for a in np.linspace(-25, 25, 6)] + [(0.0, b) for b in
                                                          np.linspace(-25, 25, 6)]
    views = _synthetic_views(rig, board, tilts, sigma_px)
    sizes = tuple(c.size for c in rig.cameras)
    if refused:
        with pytest.raises(UserError, match=r"degenerate board poses: the focal length's std is "
                                            r"[1-9][.0-9]* % \(at most 1 %\) over 12 views whose "
                                            r"tilt spans 5\d x 4\d deg, enough: "):
            cal.calibrate_views(views, board, sizes)
    else:
        st = cal.calibrate_views(views, board, sizes)
        assert max(st.focal_std_rel) < cal.MAX_FOCAL_STD == 0.01


def test_board_poses_spanning_less_than_forty_degrees_about_an_axis_are_refused():
    """calibration.MIN_TILT_SPAN_DEG, 40 deg (measured 22-31 deg with --tilt 0, degenerate):
    exact projections (0.05 px noise) of views tilted over 60 deg about the board's x axis
    and 30 deg about its y axis are refused, naming the 30 deg span."""
    from itg_vision import calibration as cal
    from itg_vision import board as brd
    from itg_vision.errors import UserError

    rig, board = Rig.from_yaml(PLANAR), brd.Board()
    tilts = [(a, 0.0) for a in np.linspace(-30, 30, 6)] + [(0.0, b) for b in
                                                          np.linspace(-15, 15, 6)]
    views = _synthetic_views(rig, board, tilts, 0.05)
    with pytest.raises(UserError, match=r"tilt spans only 60 x 30 deg"):
        cal.calibrate_views(views, board, tuple(c.size for c in rig.cameras))


# ------------------------- each camera's result, the record, the table, what calibrate replaces
TWO_AXES = ([(a, 0.0) for a in np.linspace(-30, 30, 6)]
            + [(0.0, b) for b in np.linspace(-25, 25, 6)])


def _mono_reference(obj, corners, size):
    """OpenCV directly, as the calibration's contract says (k3 fixed)."""
    return cv2.calibrateCameraExtended([obj] * len(corners), corners, size, None, None,
                                       flags=cv2.CALIB_FIX_K3,
                                       criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS,
                                                 100, 1e-12))


def _views_with_an_outlier_and_a_miss():
    """13 views (12 over two axes + 1): camera 1's view 0 off by 1 px (an outlier: dropped),
    camera 2 misses views 11 and 12 (found by camera 1 alone)."""
    rig, board = Rig.from_yaml(PLANAR), Board()
    views = _synthetic_views(rig, board, TWO_AXES + [(15.0, 15.0)], 0.05)
    rng = np.random.default_rng(5)
    c1, c2 = views.corners[0]
    views.corners[0] = ((c1 + rng.normal(0, 1.0, c1.shape)).astype(np.float32), c2)
    for k in (11, 12):
        views.corners[k] = (views.corners[k][0], None)
    return rig, board, views


def test_each_cameras_calibration_is_opencvs_on_its_own_views_and_the_pair_is_the_true_one():
    """Camera 1 (view 0 an outlier) and camera 2 (views 11, 12 missed) each get OpenCV's mono
    calibration of exactly the views it kept, bit for bit (its image-centre start wins: the
    other starts reach the same minimum, calibration.SAME_MINIMUM_REL); the stereo pair is the
    true rig's relative pose (exact projections, 0.05 px noise); counts: found 13 / 11, both
    11, stereo 10 (view 0 dropped)."""
    rig, board, views = _views_with_an_outlier_and_a_miss()
    sizes = tuple(c.size for c in rig.cameras)
    st = cal.calibrate_views(views, board, sizes)
    assert st.start == ("image centre", "image centre")
    assert st.dropped == [0]
    assert st.used == (list(range(1, 13)), list(range(11)))
    assert st.n_found == (13, 11) and st.n_found_both == 11
    assert st.stereo_views == list(range(1, 11))
    obj = board.object_points()
    for i in range(2):
        rms, K, dist, rvecs, _, std_in, _, pv = _mono_reference(
            obj, [views.corners[k][i] for k in st.used[i]], sizes[i])
        np.testing.assert_allclose(st.K[i], K, rtol=1e-9, atol=0)
        np.testing.assert_allclose(st.dist[i], dist.ravel()[:5], rtol=1e-7, atol=1e-12)
        assert st.rms_px[i] == pytest.approx(rms, rel=1e-9)
        np.testing.assert_allclose(st.per_view_rms_px[i], pv.ravel(), rtol=1e-9)
        np.testing.assert_allclose(st.intrinsics_std_px[i], std_in.ravel()[:4], rtol=1e-9)
        assert st.focal_std_rel[i] == pytest.approx(std_in.ravel()[0] / K[0, 0], rel=1e-9)
        if i == 0:
            assert st.tilt_span_deg == pytest.approx(cal.tilt_spans_deg(rvecs), rel=1e-9)
        # the true lens, to the noise's reach
        assert K[0, 0] == pytest.approx(rig.cameras[i].fx, rel=0.01)
    c1, c2 = rig.cameras
    R_true = c2.R @ c1.R.T
    T_true = c2.t_mm - R_true @ c1.t_mm
    angle = np.degrees(np.linalg.norm(cv2.Rodrigues(st.R @ R_true.T)[0]))
    assert angle < 0.1 and np.linalg.norm(st.T_mm - T_true) < 2.0


def test_exactly_the_minimum_number_of_views_is_accepted():
    """"need at least N": N views in both cameras calibrate."""
    rig, board = Rig.from_yaml(PLANAR), Board()
    st = cal.calibrate_views(_synthetic_views(rig, board, TWO_AXES, 0.05), board,
                             tuple(c.size for c in rig.cameras), min_views=len(TWO_AXES))
    assert len(st.stereo_views) == len(TWO_AXES)


def test_too_few_views_left_after_each_camera_drops_its_outliers_is_a_user_error():
    """8 views, 7 needed: camera 1 drops view 0, camera 2 view 1 (each keeps 7), so only 6
    are left in both: one UserError naming the outliers (exit 2 on the command line)."""
    rig, board = Rig.from_yaml(PLANAR), Board()
    tilts = [(a, 0.0) for a in (-30, -10, 10, 30)] + [(0.0, b) for b in (-25, -8, 8, 25)]
    views = _synthetic_views(rig, board, tilts, 0.05)
    rng = np.random.default_rng(3)
    for k, i in ((0, 0), (1, 1)):
        c = list(views.corners[k])
        c[i] = (c[i] + rng.normal(0, 1.0, c[i].shape)).astype(np.float32)
        views.corners[k] = tuple(c)
    with pytest.raises(UserError, match=r"only 6 of the 8 views with the board in both cameras "
                                        r"are left after dropping each camera's outliers \[0, 1\] "
                                        r"\(reprojection RMS over 3x its median and 0.3 px: a "
                                        r"board seen too obliquely, .*\); need at least 7$"):
        cal.calibrate_views(views, board, tuple(c.size for c in rig.cameras), min_views=7)


@pytest.fixture(scope="module")
def quick_result():
    """calibrate() with the board views replaced by _synthetic_views (13 views, camera 1's
    view 0 an outlier, camera 2 missing views 11 and 12, the corner picture's view 2), the LEDs
    rendered as usual: a few seconds instead of ~20."""
    mp = pytest.MonkeyPatch()
    rig, board, views = _views_with_an_outlier_and_a_miss()
    views.sample = (2, np.full((480, 640, 3), 200, np.uint8))
    seen_errors = []
    led_errors = cal.led_errors

    def fake_render(world, true_rig, board, poses, rng, *, supersample=2, progress=None):
        assert len(poses) == len(views.corners)
        return views

    def spy(rig_, arm, shots):
        out = led_errors(rig_, arm, shots)
        seen_errors.append(out)
        return out

    mp.setattr(cal, "render_views", fake_render)
    mp.setattr(cal, "led_errors", spy)
    try:
        res = cal.calibrate(rig, ArmSpec.from_args("two-link"), views=13, seed=0, check_poses=8)
    finally:
        mp.undo()
    return rig, views, res, seen_errors


def test_quick_calibration_places_both_cameras_and_reports_their_errors(quick_result):
    """The calibrated cameras sit where the true ones do (world frame, mm and deg), and the
    record's error_vs_true is that difference, computed here from the two rigs directly."""
    true_rig, _, res, _ = quick_result
    e = res.record["error_vs_true"]
    for t, c in zip(true_rig.cameras, res.rig.cameras):
        dpos = float(np.linalg.norm(c.position_mm - t.position_mm))
        drot = float(np.degrees(np.linalg.norm(cv2.Rodrigues(c.R @ t.R.T)[0])))
        assert dpos < 5.0 and drot < 0.5, (t.name, dpos, drot)
        rec = e["cameras"][t.name]
        assert rec["position_mm"] == pytest.approx(dpos, rel=1e-4, abs=1e-6)
        assert rec["rotation_deg"] == pytest.approx(drot, rel=1e-4, abs=1e-6)
        assert rec["focal_length_pct"] == pytest.approx(
            [100 * (c.fx - t.fx) / t.fx, 100 * (c.fy - t.fy) / t.fy], rel=1e-4, abs=1e-9)
    (t1, t2), (c1, c2) = true_rig.cameras, res.rig.cameras
    baseline = (np.linalg.norm(c2.position_mm - c1.position_mm)
                - np.linalg.norm(t2.position_mm - t1.position_mm))
    assert e["baseline_mm"] == pytest.approx(baseline, rel=1e-4, abs=1e-6)
    assert abs(e["baseline_mm"]) < 2.0
    led = res.record["led_triangulation"]
    assert led["calibrated_rig_rms_mm"] < 1.0


def test_quick_calibration_record_counts_and_figures(quick_result):
    """The record's counts are those of the views given (13 shown; left found 13, right 11,
    both 11; left used 12 (view 0 dropped), right 11, stereo 10); the RMS per camera is
    OpenCV's on that camera's views; the LED figures are those of the errors measured."""
    true_rig, views, res, seen_errors = quick_result
    r = res.record
    assert r["views_shown"] == 13 and r["views_dropped"] == [0]
    assert r["views_found"] == {"left": 13, "right": 11, "both": 11}
    assert r["views_used"] == {"left": 12, "right": 11, "stereo": 10}
    assert r["board"] == {"inner_corners": [9, 6], "square_mm": 15.0}
    assert r["picture_view"] == 2
    obj = Board().object_points()
    for i, name in enumerate(("left", "right")):
        used = [k for k in range(13) if views.corners[k][i] is not None and (i, k) != (0, 0)]
        rms = _mono_reference(obj, [views.corners[k][i] for k in used], true_rig.cameras[i].size)[0]
        assert r["reprojection_rms_px"][name] == pytest.approx(rms, rel=1e-5)
    err_true, err_cal = seen_errors
    common = sorted(set(err_true) & set(err_cal))
    e_t = np.array([err_true[k] for k in common])
    e_c = np.array([err_cal[k] for k in common])
    led = r["led_triangulation"]
    assert led["points"] == len(common)
    assert led["true_rig_p95_mm"] == pytest.approx(np.percentile(e_t, 95), rel=1e-5)
    assert led["calibrated_rig_p95_mm"] == pytest.approx(np.percentile(e_c, 95), rel=1e-5)
    rms_t, rms_c = np.sqrt(np.mean(e_t**2)), np.sqrt(np.mean(e_c**2))
    assert led["ratio"] == pytest.approx(rms_c / rms_t, rel=1e-5)


def test_no_led_found_at_the_check_poses_is_a_user_error(monkeypatch):
    rig, board, views = _views_with_an_outlier_and_a_miss()
    monkeypatch.setattr(cal, "render_views", lambda *a, **k: views)
    monkeypatch.setattr(cal, "led_errors", lambda rig_, arm, shots: {})
    with pytest.raises(UserError, match=r"planar.yaml: LED check: no LED was found"):
        cal.calibrate(rig, ArmSpec.from_args("two-link"), views=13, check_poses=1)


def test_write_result_records_the_hash_of_the_true_rig_as_read(tmp_path):
    """The hash the command read the true rig with, not the file's content after the work."""
    rig = Rig.from_yaml(PLANAR)
    res = cal.Result(rig, {"seed": 0})
    out = tmp_path / "planar.calib.yaml"
    assert cal.write_result(res, out, PLANAR, "ab" * 32) is None
    assert yaml.safe_load(out.read_text())["true_rig_sha256"] == "ab" * 32


def test_write_result_keeps_the_rig_file_s_supersample(tmp_path):
    """The rig file's supersample (the eye's rendering factor, README 'Camera rigs') goes into
    its calibration, which a run reads it from: it was dropped, and a run on the calibration
    of a rig saying 1 rendered at the default 3."""
    rig = dataclasses.replace(Rig.from_yaml(PLANAR), supersample=1)
    out = tmp_path / "planar.calib.yaml"
    cal.write_result(cal.Result(rig, {"seed": 0}), out, PLANAR, "ab" * 32)
    assert Rig.from_yaml(out).supersample == 1


def test_the_calibration_s_eye_renders_at_the_rig_file_s_supersample(monkeypatch):
    """The joint sweeps are seen by the tracker's own eye, at the rig's supersample as in a
    run (it rendered them at the default 3 whatever the rig said)."""
    from itg_vision import feedback

    made = []

    class Eye(feedback.VisionFeedback):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self.supersample)

    monkeypatch.setattr(feedback, "VisionFeedback", Eye)
    rig = dataclasses.replace(Rig.from_yaml(PLANAR), supersample=1)
    arm = ArmSpec.from_args("two-link")
    with World(arm) as world:
        cal.led_images(world, rig, arm, [np.array(arm.start_q_deg, float)],
                       np.random.default_rng(0))
    assert made == [1]


@pytest.mark.slow
def test_a_run_on_the_calibration_renders_at_the_rig_file_s_supersample(cli, tmp_path):
    """calibrate, then run, on a rig file saying supersample: 1: the run's summary says 1 (it
    said 3). 12 board views and 3 check poses (16 s of work down to 5): what is checked is the
    supersample carried through, not the calibration's accuracy (the tests above)."""
    rig = tmp_path / "ss1.yaml"
    rig.write_text(PLANAR.read_text().replace("name: planar", "name: ss1") + "supersample: 1\n")
    out = tmp_path / "ss1.calib.yaml"
    proc = cli("itg_vision.calibrate", "--rig", rig, "--views", 12, "--check-poses", 3, "--quiet",
               "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert Rig.from_yaml(out).supersample == 1
    proc = cli("itg_vision.run", "--rig", out, "--points", 12, "--quiet", "--out",
               tmp_path / "run")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["feedback_params"]["supersample"] == 1


def test_check_out_replaces_this_rigs_calibration_only(tmp_path):
    """Re-calibrating over this rig's calibration and its picture needs no --force; a
    calibration of another rig is refused without it; the true rig itself always."""
    from itg_vision.calibrate import check_out

    out = _this_rigs_calibration(tmp_path / "x.calib.yaml")
    (tmp_path / "x.calib.png").write_bytes(b"old picture")
    assert check_out(out, PLANAR) == []
    other = ROOT / "cameras" / "three-link.yaml"
    with pytest.raises(UserError, match=r"is a calibration of .*, not of "):
        check_out(out, other)
    with pytest.raises(UserError, match=r"would overwrite the true rig"):
        check_out(PLANAR, PLANAR, force=True)


def test_summary_table_shows_the_records_baseline_error():
    from itg_vision.calibrate import summary_table

    record = Rig.from_yaml(ROOT / "cameras" / "planar.calib.yaml").calibration
    line = next(x for x in summary_table(record).splitlines() if x.startswith("baseline error"))
    assert float(line.split()[-1]) == pytest.approx(record["error_vs_true"]["baseline_mm"],
                                                    abs=5.1e-4)


def test_even_numbered_board_poses_show_the_whole_board_to_both_cameras():
    from itg_vision import board as brd

    rig, board = Rig.from_yaml(PLANAR), Board()
    arm = ArmSpec.from_args("two-link")
    poses = brd.sample_board_poses(rig, board, 30, np.random.default_rng(0),
                                   target_mm=arm.calibration["board_target_mm"])
    assert all(brd.board_visible(c, board, p) for p in poses[::2] for c in rig.cameras)
    assert all(any(brd.board_visible(c, board, p) for c in rig.cameras) for p in poses[1::2])


def test_sensor_noise_overrides_both_cameras():
    from itg_vision.calibrate import Job, build_parser

    job = Job.from_args(build_parser().parse_args(["--sensor-noise", "7.5"]))
    assert [c.noise_sigma_gray for c in job.true_rig.cameras] == [7.5, 7.5]


def test_a_three_link_shoulder_sweep_with_one_led_missed_in_one_pose_still_measures_l3(
        monkeypatch):
    """L3 is the LEDs' distance over the shoulder sweep's poses where both were seen: with the
    gripper missed in one pose (as `calibrate --rig planar --arm three-link` met: 24 gripper
    points against 25 elbow points) it is still the simulated link, within the 0.5 mm of the
    frame test above, and the frame is the one all poses give to well within that test's
    tolerances; it raised a numpy broadcast error."""
    true_rig = Rig.from_yaml(ROOT / "cameras" / "three-link.yaml")
    rig_c1 = _camera1_frame(true_rig)
    arm = ArmSpec.from_args("three-link")
    with World(arm) as world:
        sweeps = {j: (cal.led_images(world, true_rig, arm, q, np.random.default_rng(0)), names)
                  for j, (q, names) in cal.axis_sweeps(arm).items()}
    R_all, t_all, _ = cal.base_frame_from_axes(rig_c1, arm, sweeps)
    real, dropped = cal.triangulate_leds, sweeps[1][0][5][1]  # the shoulder sweep's 6th pose

    def eye(rig, arm_, imgs):
        X = real(rig, arm_, imgs)
        return {n: p for n, p in X.items() if not (imgs is dropped and n == "gripper")}

    monkeypatch.setattr(cal, "triangulate_leds", eye)
    R_w, t_w, rec = cal.base_frame_from_axes(rig_c1, arm, sweeps)
    assert rec["measured_links"] == ["L2", "L3"]
    assert rec["measured_links_mm"][1] == pytest.approx(arm.links_mm[2], abs=0.5)
    # one point fewer of 25 on the gripper's circle: the frame moves far less than 0.1 deg / 1 mm
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(R_w @ R_all.T)[0])) < 0.05
    assert np.linalg.norm(t_w - t_all) < 0.5


# ------------------------------------------- a principal point far from the centre; consistency
#: A rig whose principal points lie 256 and 267 px from the image centres (k1 -0.15, -0.12).
PP_FAR = ROOT / "tests" / "data" / "pp-far.yaml"
#: The corner detector's error on the rendered boards, per image axis: 0.13 px RMS length
#: against the projected true corners (0.128 px at zero sensor noise, 0.149 at 20 grey levels;
#: the rigs use 2), over sqrt(2).
CORNER_SIGMA_PX = 0.09


def _corners_at(rig, board, poses, noise_px, rng):
    """Each camera's corners of the board at ``poses`` where it sees the whole board: exact
    projections through its lens plus Gaussian noise of ``noise_px`` per axis (else None)."""
    from itg_vision.board import board_visible

    out = []
    for pose in poses:
        pair = []
        for c in rig.cameras:
            uv = c.project(pose.points(board.object_points()))
            pair.append((uv + rng.normal(0, noise_px, uv.shape)).astype(np.float32)
                        .reshape(-1, 1, 2) if board_visible(c, board, pose) else None)
        out.append(tuple(pair))
    return out


def _sampled_views(rig, board, n, noise_px, seed=0):
    """Board views at the poses calibrate() would sample for ``rig`` (the two-link arm's target),
    their corners from :func:`_corners_at`, no rendering."""
    from itg_vision.board import Views, sample_board_poses

    rng = np.random.default_rng(seed)
    poses = sample_board_poses(rig, board, n, rng, target_mm=ArmSpec.from_args(
        "two-link").calibration["board_target_mm"])
    return Views(poses, _corners_at(rig, board, poses, noise_px, rng))


def test_zhangs_closed_form_recovers_a_pinhole_camera():
    """calibration.zhang_camera_matrix from exact projections of a lens without distortion:
    the true K (principal point 256 px from the centre), to the homographies' round-off."""
    import dataclasses

    rig = Rig.from_yaml(PP_FAR)
    pinhole = Rig(rig.name, tuple(dataclasses.replace(c, dist=(0.0,) * 5) for c in rig.cameras))
    board = Board()
    views = _sampled_views(pinhole, board, 20, 0.0)
    cam = pinhole.cameras[0]
    img = [c[0] for c in views.corners if c[0] is not None]
    K = cal.zhang_camera_matrix([board.object_points()] * len(img), img, cam.size)
    # float32 corners (2^-24 relative at 600 px: 4e-5 px) through the homographies and a
    # least-squares fit: 1e-4 to 2e-4 px measured
    np.testing.assert_allclose(K, cam.K, rtol=0, atol=0.01)


@pytest.mark.slow
def test_a_principal_point_far_from_the_image_centre_is_found():
    """The pp-far rig, 30 sampled views, corners with the detector's noise. From OpenCV's own
    start (principal point at the image centre) alone each camera stops in a local minimum
    over 50 px from the truth, at more than 1.5x the noise's RMS (measured 110-120 px, 1.9x);
    calibrate_views, taking the best of its starts (Zhang's closed form), finds the principal
    point and the focal lengths within 4 of OpenCV's own standard deviations (1-2 px here),
    with the RMS the noise alone leaves: sqrt(2) sigma less the fit's parameters, 3 % covering
    the sampling error of ~1400 corners (2 %). The pair then agrees with its cameras. (Before,
    the calibration was OpenCV's from the centre: 110-120 px off.)"""
    rig, board = Rig.from_yaml(PP_FAR), Board()
    views = _sampled_views(rig, board, 30, CORNER_SIGMA_PX)
    st = cal.calibrate_views(views, board, tuple(c.size for c in rig.cameras))
    noise_rms = np.sqrt(2) * CORNER_SIGMA_PX
    for i, cam in enumerate(rig.cameras):
        rms, K0 = _mono_reference(board.object_points(),
                                  [views.corners[k][i] for k in st.used[i]], cam.size)[:2]
        assert np.hypot(K0[0, 2] - cam.cx, K0[1, 2] - cam.cy) > 50 and rms > 1.5 * noise_rms
        K, (s_fx, s_fy, s_cx, s_cy) = st.K[i], st.intrinsics_std_px[i]
        assert abs(K[0, 2] - cam.cx) < 4 * s_cx and abs(K[1, 2] - cam.cy) < 4 * s_cy, K
        assert abs(K[0, 0] - cam.fx) < 4 * s_fx and abs(K[1, 1] - cam.fy) < 4 * s_fy, K
        assert st.rms_px[i] < 1.03 * noise_rms
        assert st.start[i].startswith("Zhang's closed form")
    # the parameters the pair drops alone leave sqrt(~3 %) of the noise's RMS, ~0.02 px
    # (measured 0.028; a camera in the local minimum: 0.57)
    assert cal.stereo_excess_px(st.stereo_rms_px, st.rms_px) < 0.5 * noise_rms


@pytest.mark.slow
def test_calibration_of_a_rig_with_far_principal_points_meets_the_targets():
    """The pp-far rig end to end (rendered boards and LEDs, ~16 s): it calibrated to a local
    minimum before, 108 px and 2-3 % off, base frame 128 mm off, LED triangulation 4.0 mm RMS.
    Now the planar rig's targets hold: reprojection RMS 0.15 px (the corner detector's own
    error is 0.13), focal length within 0.2 %, baseline within 0.5 mm, the LEDs within the
    eye's 0.1 mm on the calibrated rig; the principal point within 4 of OpenCV's standard
    deviations, and the base frame within the bounds its own uncertainty sets."""
    rig = Rig.from_yaml(PP_FAR)
    res = cal.calibrate(rig, ArmSpec.from_args("two-link"), views=cal.DEFAULT_VIEWS, seed=0,
                        check_poses=15)
    r, e = res.record, res.record["error_vs_true"]
    for i, cam in enumerate(rig.cameras):
        c = e["cameras"][cam.name]
        assert r["reprojection_rms_px"][cam.name] <= 0.15
        assert max(abs(v) for v in c["focal_length_pct"]) <= 0.2
        s = res.stereo.intrinsics_std_px[i]
        assert abs(c["principal_point_px"][0]) < 4 * s[2]
        assert abs(c["principal_point_px"][1]) < 4 * s[3]
    assert abs(e["baseline_mm"]) <= 0.5
    assert r["led_triangulation"]["calibrated_rig_rms_mm"] <= 0.1
    rot_bound_deg, origin_bound_mm = _base_frame_bounds(res, rig)
    assert e["base_frame"]["rotation_deg"] < rot_bound_deg, rot_bound_deg
    assert e["base_frame"]["origin_mm"] < origin_bound_mm, origin_bound_mm
    fit = r["base_frame"]["worst_fit"]
    assert fit["rms_mm"] < fit["bound_mm"] and r["stereo_excess_px"] < cal.MAX_STEREO_EXCESS_PX


def _refused_from_the_centre_alone(monkeypatch, main_in_process, tmp_path) -> str:
    """The command on the pp-far rig as it calibrated before: each camera from OpenCV's start
    alone (the local minimum), board views sampled (30, as _sampled_views, no rendering), the
    LEDs rendered as usual (one check pose). Asserts that it exits 2 with one line on stderr,
    writing nothing; returns the line."""
    from itg_vision.board import Views

    rng = np.random.default_rng(0)
    monkeypatch.setattr(cal, "_mono_best", lambda obj, img, size, flags, previous=None:
                        cal._mono(obj, img, size, flags), raising=False)
    monkeypatch.setattr(cal, "render_views", lambda world, rig, board, poses, rng_, **kw: Views(
        poses, _corners_at(rig, board, poses, CORNER_SIGMA_PX, rng)))
    proc = main_in_process("itg_vision.calibrate", "--rig", PP_FAR, "--out",
                           tmp_path / "pp-far.calib.yaml", "--quiet", "--views", 30,
                           "--check-poses", 1)
    assert proc.returncode == 2, proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert list(tmp_path.iterdir()) == []
    return lines[0]


@pytest.mark.slow
def test_a_pair_that_its_cameras_do_not_explain_is_refused_in_one_line(tmp_path, monkeypatch,
                                                                      main_in_process):
    """Made bad on purpose: each camera of the pp-far rig calibrated from the image centre
    alone (see _refused_from_the_centre_alone). The stereo fit's RMS then exceeds the
    cameras' by more than the LEDs' bound (measured 0.57 px of excess against 0.02-0.04 with
    right intrinsics): exit 2, one line naming the measure, its value and its bound, nothing
    written. (Before, this wrote the rig, LED triangulation ~4 mm RMS, exit 0.)"""
    import re

    line = _refused_from_the_centre_alone(monkeypatch, main_in_process, tmp_path)
    m = re.fullmatch(
        rf"error: {re.escape(str(PP_FAR))}: calibration inconsistent: the pair reprojects the "
        r"board with RMS ([\d.]+) px against its cameras' ([\d.]+) and ([\d.]+) px, an excess "
        r"of ([\d.]+) px, over the 0\.30 px the LEDs' centroid error allows: the cameras' "
        r"intrinsics disagree \(at least one is wrong\)", line)
    assert m, line
    stereo, rms1, rms2, excess = map(float, m.groups())
    assert excess == pytest.approx(cal.stereo_excess_px(stereo, (rms1, rms2)), abs=0.01)
    assert excess > cal.MAX_STEREO_EXCESS_PX == 2 * 0.15


def test_wrong_intrinsics_the_stereo_check_lets_through_bend_the_led_circles(
        tmp_path, monkeypatch, main_in_process):
    """The same bad calibration with the stereo check off: the LEDs triangulated with it leave
    their circles about the joint axes by millimetres (measured 1.4-5.3 mm RMS, against
    0.03-0.19 mm for right calibrations and a bound of ~0.6 mm): exit 2, one line naming the
    fit, its RMS and its bound, nothing written. (On a rig where only one camera falls in the
    local minimum, 63 px off, the stereo check passes and this one refuses: 0.91 mm, bound
    0.54.)"""
    import re

    monkeypatch.setattr(cal, "MAX_STEREO_EXCESS_PX", float("inf"), raising=False)
    line = _refused_from_the_centre_alone(monkeypatch, main_in_process, tmp_path)
    m = re.fullmatch(
        rf"error: {re.escape(str(PP_FAR))}: calibration inconsistent: base frame: the "
        r"(elbow|gripper) LED's circle about joint (q[12]) fits with RMS ([\d.]+) mm, over the "
        r"([\d.]+) mm its noise allows \(2 x what 0\.15 px of centroid error predicts through "
        r"the calibrated pair\): the calibrated lenses bend the LEDs' paths, their intrinsics "
        r"are wrong", line)
    assert m, line
    assert float(m[3]) > float(m[4]) > 0


@pytest.mark.parametrize("radius_mm, k1", [(100.0, None), (190.0, -0.5)])
def test_the_circle_fit_bound_is_the_residual_that_centroid_noise_leaves(radius_mm, k1):
    """calibration.circle_fit_bound_mm against a Monte Carlo: an LED on a circle about the
    planar arm's base (23 poses over 240 deg), both images as captured perturbed by Gaussian
    centroid noise of LED_CENTROID_RMS_PX (RMS length), undistorted, triangulated by the eye's
    refinement and fitted. Over 300 trials the fits' RMS is the bound over FIT_RMS_FACTOR, less
    the six parameters a circle fit absorbs of its 46 residual components (sqrt(40/46)), to the
    trials' sampling error (~0.6 %, bound 3 %); no trial reaches the bound. On the shipped
    lenses (100 mm circle) a pinhole bound is within 1 % of the lens-aware one; with k1 = -0.5
    on both cameras and the circle at 190 mm (0.27-0.31 focal lengths off axis, where the lens
    magnifies ~13 % less) it misses the Monte Carlo by 8.5 % (measured), which this fails. A
    path bent by 1 mm per 100 mm of radius (a radial sin(2 theta)) is refused by check_circle_fits, naming the fit,
    its RMS and its bound."""
    import math
    from dataclasses import replace

    from itg_vision.identify import fit_circle
    from itg_vision.triangulate import triangulate

    rig = Rig.from_yaml(PLANAR)
    if k1 is not None:
        rig = replace(rig, cameras=tuple(replace(c, dist=(k1, 0.0, 0.0, 0.0, 0.0))
                                         for c in rig.cameras))
    theta = np.radians(np.linspace(-120, 120, 23))
    X = np.stack([radius_mm * np.cos(theta), radius_mm * np.sin(theta),
                  np.full_like(theta, 12.0)], axis=1)
    centre, normal, _, _ = fit_circle(X)
    bound = cal.circle_fit_bound_mm(rig, {"points": X, "centre": centre, "axis": normal})
    sigma = cal.LED_CENTROID_RMS_PX / math.sqrt(2)  # per image axis
    rng = np.random.default_rng(0)
    uv = [c.project(X) for c in rig.cameras]  # as captured: through the lens
    rms = []
    for _ in range(300):
        P, _ = triangulate(rig, *(c.undistort(u + rng.normal(0, sigma, u.shape))
                                  for c, u in zip(rig.cameras, uv)))
        rms.append(fit_circle(P)[3])
    expected = bound / cal.FIT_RMS_FACTOR * math.sqrt(1 - 6 / (2 * len(X)))
    assert np.sqrt(np.mean(np.square(rms))) == pytest.approx(expected, rel=0.03)
    assert max(rms) < bound
    radial = np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], axis=1)
    bent = X + radius_mm / 100 * np.sin(2 * theta)[:, None] * radial  # 1 mm per 100
    c, n, _, r = fit_circle(bent)
    bent_bound = cal.circle_fit_bound_mm(rig, {"points": bent, "centre": c, "axis": n})
    assert r > bent_bound
    fits = {0: {"gripper": {"points": bent, "centre": c, "axis": n, "rms_mm": r}}}
    with pytest.raises(UserError, match=rf"^planar.yaml: calibration inconsistent: base frame: "
                                        rf"the gripper LED's circle about joint q1 fits with RMS "
                                        rf"{r:.2f} mm, over the {bent_bound:.2f} mm its noise "
                                        r"allows"):
        cal.check_circle_fits(rig, fits, "planar.yaml")
    # the exact circle passes, and the worst fit is what the record keeps
    exact = {"points": X, "centre": centre, "axis": normal, "rms_mm": 0.0}
    assert cal.check_circle_fits(rig, {0: {"gripper": exact}}) == {
        "fit": "q1 gripper", "rms_mm": 0.0, "bound_mm": bound}


def test_a_run_on_a_rig_tied_by_another_arm_says_so(tmp_path, capsys):
    """A calibration ties the base frame by one arm's joint axes (calibrate --arm; a rig of the
    user's own gets two-link unless told): a run of another arm on it says which arm tied it
    (an auditor's three-link rig, renamed, was tied by the two-link arm: gripper estimate 0.55
    mm RMS against 0.14 with --arm three-link). The shipped calibration with its own arm, and
    the one-link arm (one LED: it cannot tie a base frame) on the planar one, say nothing."""
    from itg_vision.run import main as run_main

    (tmp_path / "three-link.yaml").write_bytes((ROOT / "cameras" / "three-link.yaml").read_bytes())
    doc = (ROOT / "cameras" / "three-link.calib.yaml").read_text()
    assert doc.count("    arm: three-link\n") == 1
    other = tmp_path / "mine.calib.yaml"
    other.write_text(doc.replace("    arm: three-link\n", "    arm: two-link\n"))
    notes = {}
    for arm, rig in (("three-link", other), ("three-link", ROOT / "cameras" / "three-link.calib.yaml"),
                     ("one-link", ROOT / "cameras" / "planar.calib.yaml")):
        assert run_main(["--arm", arm, "--rig", str(rig), "--points", "2", "--quiet",
                         "--out", str(tmp_path / f"out-{len(notes)}")]) == 0
        notes[len(notes)] = [x for x in capsys.readouterr().err.splitlines() if "tied" in x]
    assert notes[0] == [f"note: {other} was tied to the base by the two-link arm's LEDs; "
                        "calibrating with --arm three-link ties it by this arm's own joint axes"]
    assert notes[1] == notes[2] == []
    # and calibrate's table names the arm beside the base frame's fits
    row = next(x for x in summary_table(yaml.safe_load(doc)["calibration"]).splitlines()
               if x.startswith("base frame: joint-axis circle fits"))
    assert row.endswith("(the three-link arm's LEDs, --arm; measured L2 99.90, L3 99.97 mm)"), row


@pytest.mark.parametrize("seen_by_both, hint", [
    (0, "(no view showed it to both cameras, whose axes are 130 deg apart: the board, printed on "
        "one side, faced one or the other in every view; more --views are unlikely to help, "
        "cameras closer in angle would)"),
    (2, "(at this rate about --views 60 would show it to both 6 times)"),
    (-1, "(at this rate 1200 views would show it to both 6 times, more than the 1000 --views "
         "allows: point the cameras at a common view)"),
])
def test_too_few_views_seen_by_both_say_whether_more_views_would_help(seen_by_both, hint):
    """20 views, each camera alone sees the board in 10 (a rig whose cameras face each other:
    the audit's 130 deg rig saw it in 0 of 60 and 0 of 300 views with both): with none seen by
    both the message says more views are unlikely to help and gives the cameras' angle; with
    2 of 20 it gives the views that would show 6 at that rate (20 x 6 / 2); with 1 of 200 that
    number, 1200, is over what --views allows, and it says so."""
    from itg_vision.board import Views

    n = 200 if seen_by_both < 0 else 20  # -1: one of 200, which needs 1200 views at that rate
    pts = np.zeros((4, 1, 2), np.float32)
    corners = [(pts, None) if k % 2 else (None, pts) for k in range(n)]
    for k in range(abs(seen_by_both)):
        corners[k] = (pts, pts)
    views = Views([None] * n, corners, None)
    with pytest.raises(UserError) as exc:
        cal.calibrate_views(views, Board(), ((640, 480), (640, 480)), apart_deg=129.9)
    assert str(exc.value).endswith(hint), str(exc.value)


@pytest.mark.parametrize("edit, expect", [
    (("position_mm: [180.0, -60.0, 620.0]", "position_mm: [180.0, -60.0, -620.0]"),
     "cameras[1] (right): is below the floor the arm stands on (z = -620 mm)"),
    (("exposure: 1.0}", "exposure: 0.1}"),
     "cameras[0] (left): exposure 0.1 makes an LED at most 25.5 grey levels bright; the "
     "detector needs 46 (threshold 40 + 3 x noise 2)"),
])
def test_a_camera_that_cannot_see_an_led_at_all_is_refused_before_rendering(monkeypatch,
                                                                           tmp_path, edit,
                                                                           expect):
    """A camera below the floor, or too dark for the detector to find an LED (exposure 0.1:
    25.5 grey levels against the 40 + 3 x 2 it needs): `run` refuses such a rig before
    rendering (visibility), and so does `calibrate` now, with the same line naming the rig
    file and the camera. It rendered its 60 board views first and ended 18-49 s later on a
    message about the board or the joint sweeps."""
    def rendered(*args, **kwargs):
        raise AssertionError("rendered")

    monkeypatch.setattr(cal, "render_views", rendered)
    rig_file = tmp_path / "mine.yaml"
    rig_file.write_text(PLANAR.read_text().replace(*edit, 1))
    with pytest.raises(UserError) as exc:
        cal.calibrate(Rig.from_yaml(rig_file), ArmSpec.from_args("two-link"))
    assert str(exc.value) == f"{rig_file}: {expect}"


@pytest.mark.parametrize("target", ["nowhere/x.yaml", "keep/x.calib.yaml"])
def test_a_symbolic_link_as_out_is_refused_and_with_force_kept_aside(tmp_path, target):
    """A link given as --out (dangling, or to this rig's calibration) was replaced by the new
    file without a word, the link deleted; as run's --out: refused in one line, and with
    --force kept aside as <name>.replaced-N, never its target."""
    from itg_vision.calibrate import check_out

    (tmp_path / "keep").mkdir()
    real = _this_rigs_calibration(tmp_path / "keep" / "x.calib.yaml")
    before = real.read_bytes()
    out = tmp_path / "x.calib.yaml"
    out.symlink_to(target)
    with pytest.raises(UserError) as exc:
        check_out(out, PLANAR)
    assert str(exc.value) == (f"--out {out}: is a symbolic link (to {target}); give the file "
                              "itself or another --out, or add --force to write there anyway "
                              "(the link is kept)")
    assert check_out(out, PLANAR, force=True) == [out]  # kept aside before the write
    assert out.is_symlink() and real.read_bytes() == before
