"""The start-up check that the cameras can see the arm (pure geometry, nothing rendered)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import front_rig, roundoff

from itg_vision.arm import ArmSpec, forward_kinematics
from itg_vision.camera import Camera, Rig, default_rig_path
from itg_vision.detect import MIN_ROUNDNESS, MIN_SCORE
from itg_vision.errors import UserError
from itg_vision.trajectory import load, named
from itg_vision.urdf import LED_RADIUS_MM
from itg_vision.visibility import (MARGIN_PX, MIN_LED_RADIUS_PX, _render_range_mm, _visible,
                                   check_visible, elbow_partly_seen, led_points, led_roundness)


ROOT_CAMERAS = Path(__file__).resolve().parents[1] / "cameras"
SHIPPED_CURVES = ("ellipse-by-base", "gerono", "lemniscate", "lemniscate-2", "limacon",
                  "limacon-2", "peanut", "rose", "rounded-square", "thin-ellipse", "trefoil")


@pytest.mark.parametrize("arm, trajectory", [("one-link", "arc"), ("two-link", "ellipse-t1"),
                                             ("two-link", "ellipse-t2"), ("two-link", "abcd"),
                                             ("three-link", "line-ab"), ("three-link", "line-ab-reach"),
                                             ("three-link", "helix"), ("three-link", "reach-loop"),
                                             *(("two-link", c) for c in SHIPPED_CURVES)])
@pytest.mark.parametrize("calibrated", [False, True])
def test_the_shipped_rigs_see_every_shipped_trajectory(arm, trajectory, calibrated):
    """And every branch of the elbow at every set point: no run of theirs is told that a
    branch is out of view (elbow_partly_seen). The shipped trajectory files too (data/)."""
    a, rig = ArmSpec.from_args(arm), Rig.from_yaml(default_rig_path(arm, calibrated))
    points = load(trajectory, arm=a).points_mm
    check_visible(rig, a, points)
    assert elbow_partly_seen(rig, a, points) is None


def test_led_points_are_the_arm_s_leds_at_the_set_points_and_its_ik_elbows():
    arm = ArmSpec.from_args("two-link")
    pts = named("ellipse-t1", 12).points_mm
    gripper, elbows = led_points(arm, pts, start_up=False)
    tol = roundoff(200)  # float64 round-off of FK and IK on the 200 mm arm
    assert len(gripper) == 13
    assert np.allclose(gripper[0], forward_kinematics(arm, arm.start_q_deg)["gripper"], rtol=0, atol=tol)
    assert np.allclose(gripper[1:, :2], pts[:, :2], rtol=0, atol=tol)
    assert np.allclose(gripper[1:, 2], arm.led_standoff_mm, rtol=0, atol=tol)
    for p, branches in zip(pts, elbows[1:]):
        assert branches.shape == (2, 3)
        # independent check: each elbow is L1 from the shoulder and L2 from the set point
        assert np.allclose(np.linalg.norm(branches[:, :2], axis=1), 100.0, rtol=0, atol=tol)
        assert np.allclose(np.linalg.norm(branches[:, :2] - p[:2], axis=1), 100.0, rtol=0, atol=tol)


def test_out_of_reach_set_points_are_not_required_to_be_seen():
    arm = ArmSpec.from_args("two-link")
    far = np.array([[5000.0, 0.0, 0.0], [0.0, 150.0, 0.0]])
    gripper, elbows = led_points(arm, far, start_up=False)
    assert len(gripper) == 2 and len(elbows) == 2  # the start pose and the reachable point


def _moved(rig, cam, **kw):
    cams = list(rig.cameras)
    cams[cam] = dataclasses.replace(cams[cam], **kw)
    return dataclasses.replace(rig, cameras=tuple(cams))


def test_a_camera_turned_away_or_too_dark_is_refused_naming_it():
    rig = Rig.from_yaml(default_rig_path("two-link"))
    arm = ArmSpec.from_args("two-link")
    pts = named("ellipse-t1", 20).points_mm
    cam = rig.cameras[1]
    R = np.diag([-1.0, 1.0, -1.0]) @ cam.R  # turned half round about its own y axis, same place
    away = dict(rotation=tuple(map(tuple, R)), translation_mm=tuple(-R @ cam.position_mm))
    with pytest.raises(UserError, match=r"cameras\[1\] \(right\): cannot see the gripper LED at 32 "
                                        r"of 32 positions; at the start pose, .* behind the camera"):
        check_visible(_moved(rig, 1, **away), arm, pts)
    with pytest.raises(UserError, match=r"cameras\[0\] \(left\): exposure 0.1 makes an LED at most 25.5"):
        check_visible(_moved(rig, 0, exposure=0.1), arm, pts)
    check_visible(_moved(rig, 0, exposure=0.25), arm, pts)  # 63.8 grey levels: enough


def test_long_links_take_the_elbow_out_of_view():
    rig = Rig.from_yaml(default_rig_path("two-link"))
    pts = named("ellipse-t1", 20).points_mm
    with pytest.raises(UserError, match="cannot see the gripper LED at 12 of 32 positions; at the start pose"):
        check_visible(rig, ArmSpec.from_args("two-link", (1000.0, 1000.0)), pts)
    # the same trajectory with links the rig frames is fine
    check_visible(rig, ArmSpec.from_args("two-link", (110.0, 90.0)), pts)


def _down(x_mm, y_mm, depth_mm, size=(200, 200), f_px=600.0):
    """A distortion-free camera named "down", ``depth_mm`` straight above (x, y) on the planar
    arms' LED plane (z = 12 mm), image up = world +y: at depth 600 mm and f = 600 px one pixel
    is 1 mm and an LED (radius 6 mm) images with radius 6 px."""
    W, H = size
    R = np.diag([1.0, -1.0, -1.0])
    t = -R @ [x_mm, y_mm, 12.0 + depth_mm]
    return Camera.from_arrays("down", size, [[f_px, 0, (W - 1) / 2], [0, f_px, (H - 1) / 2],
                                             [0, 0, 1]], np.zeros(5), R, t)


def _two_link(camera=None):
    """The two-link arm, ellipse-t1 (20 points) and its rig, camera 0 replaced by ``camera``."""
    rig = Rig.from_yaml(default_rig_path("two-link"))
    if camera is not None:
        rig = dataclasses.replace(rig, cameras=(camera, rig.cameras[1]))
    return rig, ArmSpec.from_args("two-link"), named("ellipse-t1", 20).points_mm


def test_the_image_margin_grows_with_the_led_s_projected_radius():
    """An LED's centre must stay its projected radius r + MARGIN_PX inside the frame. At 600 mm
    with f = 600 px, r = 6 px: the margin is 8 px. Half a pixel inside it (7.5 px from either
    side) is refused, half a pixel beyond it (8.5 px) accepted; a margin of MARGIN_PX alone
    would accept all four."""
    cam = _down(0.0, 0.0, 600.0, size=(640, 480))
    m = cam.fx * LED_RADIUS_MM / 600.0 + MARGIN_PX
    us = (m - 0.5, 639 - m + 0.5, m + 0.5, 639 - m - 0.5)
    why = _visible(cam, [cam.back_project([u, cam.cy], 600.0) for u in us], *_render_range_mm())
    assert all(w and w.endswith("outside the 640 x 480 px image less a 8 px margin")
               for w in why[:2]), why
    assert why[2:] == [None, None], why
    vs = (m - 0.5, 479 - m + 0.5, m + 0.5, 479 - m - 0.5)  # the same along v
    why = _visible(cam, [cam.back_project([cam.cx, v], 600.0) for v in vs], *_render_range_mm())
    assert all(w and w.endswith("8 px margin") for w in why[:2]) and why[2:] == [None, None], why


def test_with_non_square_pixels_each_axis_keeps_the_led_s_own_radius_along_it():
    """fx = 1000, fy = 400 px at 600 mm: the LED images 10 px wide and 4 px tall. The margin
    was min(fx, fy) r / z + MARGIN_PX = 6 px on both axes, so a centre 7 px from the left edge
    passed though its disc reached 3 px past it (a rig of the user's: the start pose's gripper
    LED 6 px from the edge passed the check, then every look at start-up missed it 'at the
    image border'). Now 12 px across and 6 px down: 11.5 px from the side refused, 12.5
    accepted; along v 5.5 refused, 6.5 accepted."""
    W, H = 640, 480
    R = np.diag([1.0, -1.0, -1.0])
    t = -R @ [0.0, 0.0, 612.0]
    cam = Camera.from_arrays("down", (W, H), [[1000.0, 0, 319.5], [0, 400.0, 239.5], [0, 0, 1]],
                             np.zeros(5), R, t)
    us = (7.0, 11.5, 639 - 11.5, 12.5, 639 - 12.5)
    why = _visible(cam, [cam.back_project([u, cam.cy], 600.0) for u in us], *_render_range_mm())
    assert all(w and w.endswith("outside the 640 x 480 px image less a 12 px (u) and 6 px (v) "
                                "margin") for w in why[:3]), why
    assert why[3:] == [None, None], why
    vs = (5.5, 479 - 5.5, 6.5, 479 - 6.5)
    why = _visible(cam, [cam.back_project([cam.cx, v], 600.0) for v in vs], *_render_range_mm())
    assert all(w for w in why[:2]) and why[2:] == [None, None], why


def test_an_led_must_image_large_enough_for_the_detector_s_roundness_gate():
    """f = 200 px at 600 mm images an LED (radius 6 mm) 2.0 px in radius, below
    MIN_LED_RADIUS_PX (2.1 px): refused; f = 220 px, 2.2 px: seen. The check took 1 px, which
    passed rigs whose LEDs the detector then missed in a quarter of its looks."""
    assert MIN_LED_RADIUS_PX == 2.1
    X = [[0.0, 0.0, 12.0]]
    small = _visible(_down(0.0, 0.0, 600.0, f_px=200.0), X, *_render_range_mm())[0]
    assert small == "an LED there would be 4 px across (the detector needs 4.2)", small
    assert _visible(_down(0.0, 0.0, 600.0, f_px=220.0), X, *_render_range_mm()) == [None]


def _grid_roundness(r_px: float, phases: int, s: int = 16) -> np.ndarray:
    """The detector's roundness of a disc of radius ``r_px`` at ``phases`` x ``phases``
    sub-pixel positions: each pixel's coverage by area (``s`` x ``s`` samples a pixel), the
    pixels at half the peak coverage or more (the detector's half-peak mask), their moments'
    axis ratio (detect._roundness)."""
    import cv2

    from itg_vision.detect import _roundness

    n = int(2 * r_px) + 5
    jj, ii = (np.mgrid[0:n * s, 0:n * s] + 0.5) / s
    out = []
    for pu in np.arange(phases) / phases:
        for pv in np.arange(phases) / phases:
            inside = (ii - n / 2 - pu) ** 2 + (jj - n / 2 - pv) ** 2 <= r_px**2
            cover = inside.reshape(n, s, n, s).mean(axis=(1, 3))
            core = (cover >= 0.5 * cover.max()).astype(np.uint8)
            out.append(_roundness(cv2.moments(core, binaryImage=True)))
    return np.array(out)


def test_min_led_radius_is_where_the_pixel_grid_stops_failing_the_roundness_gate():
    """MIN_LED_RADIUS_PX is the smallest radius from which a disc's half-peak pixel set is
    MIN_ROUNDNESS round at every sub-pixel position, computed independently of the detector's
    images: at 2.0 px some positions fall under the gate (0.748), from 2.1 px (up to 4 px here,
    6 px in visibility.py's derivation) none does, on a 12 x 12 grid of positions."""
    assert _grid_roundness(2.0, 12).min() < MIN_ROUNDNESS
    for r in np.arange(MIN_LED_RADIUS_PX, 4.0, 0.1):
        assert _grid_roundness(r, 12).min() >= MIN_ROUNDNESS, r


@pytest.mark.parametrize("r_px, missed", [(1.9, True), (MIN_LED_RADIUS_PX + 0.05, False)])
def test_rendered_leds_below_the_min_radius_are_missed_above_it_seen(r_px, missed):
    """The rendered eye agrees: two cameras straight above the two-link arm, at 30 random
    sub-pixel positions of the LEDs, f chosen for an LED radius of ``r_px`` at 600 mm. At 1.9 px
    (refused by the check) some looks miss an LED, as not round; at 2.15 px none does."""
    from itg_vision.feedback import VisionFeedback
    from itg_vision.world import World

    arm = ArmSpec.from_args("two-link")
    world = World(arm, np.array([30.0, 60.0]))
    c = (world.true_markers()["gripper"] + world.true_markers()["elbow"]) / 2
    f = r_px * 600.0 / LED_RADIUS_MM
    size = (int(0.8 * f) | 1,) * 2  # both LEDs (100 mm apart) in the frame
    rng = np.random.default_rng(1)
    reasons = []
    try:
        for _ in range(30):
            du, dv = rng.uniform(0.0, 1.0, 2) * 600.0 / f  # a pixel at 600 mm
            rig = Rig("t", (_down(c[0] - 40 + du, c[1] + dv, 600.0, size, f),
                            _down(c[0] + 40 + dv, c[1] + du, 600.0, size, f)))
            why = [w for cam in rig.cameras for w in _visible(cam, [c], *_render_range_mm())]
            assert all((w is None) != missed for w in why), why  # the check says it first
            eye = VisionFeedback(rig, rig, arm, supersample=1)
            eye.reset(0)
            eye.observe(world)
            reasons += [v for v in eye.last_observation.reasons.values() if v]
    finally:
        world.close()
    assert bool(reasons) == missed, reasons
    assert all(v.startswith("not round") for v in reasons), reasons


def test_an_led_far_off_the_optical_axis_images_too_elongated_for_the_detector():
    """A sphere seen t off the optical axis images as an ellipse sqrt(cos^2 t - sin^2 a) / cos a
    as wide as long (a its angular radius): beyond about 41 deg it is less round than the
    detector's gate, MIN_ROUNDNESS (0.75), which takes it for a partly hidden LED. A camera 100
    mm above the LED plane: 45 deg off (0.706) refused, 35 deg off (0.818) seen; both inside
    the image (f = 100 px: 100 and 70 px from the centre). They were both 'seen', and a rig so
    close and wide passed the check and failed at start-up after rendering."""
    cam = _down(0.0, 0.0, 100.0, size=(640, 480), f_px=100.0)
    X = np.array([[100.0, 0.0, 12.0], [70.0, 0.0, 12.0]])
    t = np.arctan2(X[:, 0], 100.0)
    sin_a = LED_RADIUS_MM / np.hypot(X[:, 0], 100.0)
    expect = np.sqrt(np.cos(t) ** 2 - sin_a ** 2) / np.sqrt(1 - sin_a ** 2)
    # the lens's Jacobian by central differences of step h = 1e-6: round-off eps / h
    assert np.allclose(led_roundness(cam, X), expect, rtol=0, atol=np.finfo(float).eps / 1e-6)
    assert expect[0] < MIN_ROUNDNESS == 0.75 < expect[1]
    why = _visible(cam, X, *_render_range_mm())
    assert why == ["images as an ellipse 0.71 as wide as long (45 deg off the optical axis, at "
                   "(420, 240) px): the detector takes a blob 0.75 round or more as an LED",
                   None], why


@pytest.mark.parametrize("dist, aspect", [((-0.3, 0.1, 0.0, 0.0, 0.0), 1.0),
                                          ((0.15, 0.0, 0.002, -0.001, 0.0), 1.0),
                                          ((0.0,) * 5, 1.5)])
def test_led_roundness_is_what_the_camera_makes_of_the_sphere_s_outline(dist, aspect):
    """Independent of led_roundness's closed form and lens Jacobian: the sphere's outline (the
    circle where the cone from the camera centre touches it) projected by Camera.project, lens
    included, v divided by fy / fx as the detector does; its points' second moments give the
    axes. led_roundness takes the lens as linear over the LED's image (its Jacobian at the
    centre): it may be off by as much as that Jacobian changes across the outline, relative to
    its smaller singular value (0.02 to 0.2 at k1 = -0.3 here, where the two agreed to 0.007;
    0 without a lens, where they agreed to 3e-11: round-off, eps over the difference step
    1e-6)."""
    from itg_vision.camera import plumb_bob

    def jacobian(x, y, h=1e-6):
        return np.column_stack([(np.array(plumb_bob(x + h * e[0], y + h * e[1], cam.dist))
                                 - np.array(plumb_bob(x - h * e[0], y - h * e[1], cam.dist)))
                                / (2 * h) for e in np.eye(2)])

    cam = dataclasses.replace(_down(0.0, 0.0, 130.0, size=(640, 480), f_px=130.0),
                              dist=tuple(dist))
    cam = dataclasses.replace(cam, fy=cam.fx * aspect)
    rng = np.random.default_rng(3)
    X = np.c_[rng.uniform(-120, 120, (40, 2)), np.full(40, 12.0)]
    C = cam.position_mm
    for x, got in zip(X, led_roundness(cam, X)):
        d = x - C
        D = np.linalg.norm(d)
        u = d / D
        a = np.arcsin(LED_RADIUS_MM / D)
        e1 = np.cross(u, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        phi = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)[:, None]
        outline = C + D * np.cos(a) * (np.cos(a) * u + np.sin(a) * (np.cos(phi) * e1
                                                                    + np.sin(phi) * e2))
        uv = cam.project(outline) * [1.0, cam.fx / cam.fy]
        lo, hi = np.linalg.eigvalsh(np.cov(uv.T))
        xc, xo = cam.to_camera(x), cam.to_camera(outline)
        J0 = jacobian(*(xc[:2] / xc[2]))
        change = max(np.linalg.norm(jacobian(*(p[:2] / p[2])) - J0, 2) for p in xo[::30])
        tol = change / np.linalg.svd(J0, compute_uv=False)[-1] + np.finfo(float).eps / 1e-6
        assert got == pytest.approx(np.sqrt(lo / hi), abs=tol)


def test_a_rig_too_close_and_wide_for_round_leds_is_refused_before_rendering(tmp_path):
    """Cameras 150 mm above the plane, f = 150 px on 640 x 480 (130 deg across): the two-link
    arm's gripper at its start pose, 49 deg off the left camera's axis, images 0.71 as wide as
    long (its lens's barrel rounds the pinhole's 0.66); the check refuses the run in one line,
    and the eye, rendered, finds the LED not round there (the run passed the check and failed
    at start-up after rendering)."""
    from itg_vision.detect import NOT_ROUND
    from itg_vision.feedback import VisionFeedback
    from itg_vision.world import World

    text = (ROOT_CAMERAS / "planar.yaml").read_text()
    for x in ("-180.0", "180.0"):
        text = text.replace(f"position_mm: [{x}, -60.0, 620.0]",
                            f"position_mm: [{float(x) / 3:.1f}, -20.0, 150.0]")
    text = text.replace("600.0, 0.0, 319.5, 0.0, 600.0", "150.0, 0.0, 319.5, 0.0, 150.0")
    text = text.replace("605.0, 0.0, 322.0, 0.0, 603.0", "150.0, 0.0, 322.0, 0.0, 150.0")
    path = tmp_path / "wide.yaml"
    path.write_text(text)
    rig, arm = Rig.from_yaml(path), ArmSpec.from_args("two-link")
    with pytest.raises(UserError) as exc:
        check_visible(rig, arm, named("ellipse-t1", 20).points_mm)
    assert str(exc.value).startswith(
        f"{path}: cameras[0] (left): cannot see the gripper LED at "), exc.value
    assert ("at the start pose, (0.0, 200.0, 12.0) mm images as an ellipse 0.71 as wide as long "
            "(49 deg off the optical axis, at (323, 88) px): the detector takes a blob 0.75 round "
            "or more as an LED; --allow-unseen runs anyway") in str(exc.value), exc.value
    with World(arm, np.array(arm.start_q_deg, float)) as world:
        eye = VisionFeedback(rig, rig, arm)
        eye.observe(world)
        assert eye.last_observation.causes["gripper"] == NOT_ROUND


def test_the_image_check_reads_the_distorted_projection():
    """Barrel distortion (k1 = -0.3, 640 x 480, f = 600 px) draws a point 330 px right of
    the centre on the pinhole image (outside the frame) 0.55 (1 - 0.3 x 0.55^2) x 600 = 300 px
    right, inside it: seen. A point 300 px right on the pinhole image lands 251 px right."""
    cam = dataclasses.replace(_down(0.0, 0.0, 600.0, size=(640, 480)),
                              dist=(-0.3, 0.0, 0.0, 0.0, 0.0))
    X = cam.back_project([[cam.cx + 330.0, cam.cy]], 600.0, distorted=False)
    assert cam.project(X, distort=False)[0, 0] > 639 and cam.project(X)[0, 0] < 631
    assert _visible(cam, X, *_render_range_mm()) == [None]


def test_sensor_noise_raises_the_exposure_an_led_needs():
    """The exposure must lift an LED's score (255 x exposure) to the detector's threshold
    MIN_SCORE plus 3 sigma of sensor noise: 40 + 30 = 70 grey levels at sigma = 10. Exposure
    0.25 (63.75, above the threshold alone) is refused; 0.3 (76.5) passes."""
    rig, arm, pts = _two_link()
    need = MIN_SCORE + 3 * 10.0
    assert MIN_SCORE < 255 * 0.25 < need < 255 * 0.3
    with pytest.raises(UserError, match=rf"exposure 0.25 makes an LED at most 63.8 grey levels "
                                        rf"bright; the detector needs {need:g} \(threshold "
                                        rf"{MIN_SCORE} \+ 3 x noise 10\)"):
        check_visible(_moved(rig, 0, exposure=0.25, noise_sigma_gray=10.0), arm, pts)
    check_visible(_moved(rig, 0, exposure=0.3, noise_sigma_gray=10.0), arm, pts)


def test_no_exposure_lifts_an_led_above_255_grey_levels():
    """8-bit pixels saturate: exposure 2 makes an LED 255 grey levels bright, not 510, so noise
    whose 3 sigma puts the detector's need above 255 is refused however long the exposure."""
    rig, arm, pts = _two_link()
    sigma = (255.0 - MIN_SCORE) / 3.0 + 1.0
    with pytest.raises(UserError, match=r"exposure 2 makes an LED at most 255 grey levels"):
        check_visible(_moved(rig, 0, exposure=2.0, noise_sigma_gray=sigma), arm, pts)


def test_the_elbow_needs_one_inverse_kinematics_branch_in_view():
    """At set point (0, 150) mm the two-link arm's elbow LED is at (66.1, 75) or (-66.1, 75)
    (the two IK branches): one of them must be in view, not both. A camera 600 mm above the LED
    plane (1 mm per px, LED radius 6 px, so the usable image is the frame less 8 px each side):
    200 px wide centred on x = 35 mm sees x in [-56.5, 126.5] mm, the + branch only: accepted.
    130 px wide centred on x = 0 sees [-56.5, 56.5], neither branch: refused. Both are 200 px
    high around y = 130 mm ([38.5, 221.5] mm), framing the start pose's LEDs (0, 100), (0, 200)
    and the gripper at the set point. Such a camera does not frame the start-up measurement's
    base sweep (the next test), so the set points are checked alone (``start_up=False``)."""
    p = np.array([[0.0, 150.0, 0.0]])
    check_visible(*_two_link(_down(35.0, 130.0, 600.0))[:2], p, start_up=False)
    with pytest.raises(UserError, match=r"cameras\[0\] \(down\): cannot see the elbow LED at set "
                                        r"point k = 0 \(trace.csv's k\): \(66.1, 75.0, 12.0\) mm"):
        check_visible(*_two_link(_down(0.0, 130.0, 600.0, size=(130, 200)))[:2], p, start_up=False)
    # the set point is named by its index in the trajectory (trace.csv's k), out-of-reach points
    # before it counted (it said "set point 1 of those in reach", the count among those kept)
    with pytest.raises(UserError, match=r"elbow LED at set point k = 2 \(trace.csv's k\)"):
        check_visible(*_two_link(_down(0.0, 130.0, 600.0, size=(130, 200)))[:2],
                      np.vstack([[[500.0, 0.0, 0.0], [0.0, 300.0, 0.0]], p]), start_up=False)
    check_visible(*_two_link(_down(-35.0, 130.0, 600.0))[:2], p, start_up=False)  # - branch


def test_the_elbow_branch_in_view_must_be_the_same_for_both_cameras():
    """The eye triangulates an LED that both cameras see. Camera 0 around x = 35 mm sees the
    elbow's + branch at set point (0, 150) only ((66.1, 75) mm; x in [-57, 127]), a camera
    around x = -35 mm the - branch only ((-66.1, 75); x in [-127, 57]): each camera sees a
    branch, but whichever the arm takes, one camera misses the elbow. Refused, naming what
    each camera sees; the check accepted it before (it asked each camera for a branch of its
    own). Both cameras around x = 35 mm: accepted."""
    p = np.array([[0.0, 150.0, 0.0]])
    rig, arm, _ = _two_link(_down(35.0, 130.0, 600.0))
    crossed = dataclasses.replace(rig, cameras=(_down(35.0, 130.0, 600.0),
                                                _down(-35.0, 130.0, 600.0)))
    with pytest.raises(UserError, match=r"no position of the elbow LED at set point k = 0 "
                                        r"\(trace.csv's k\) is seen by both cameras \(cameras\[0\] "
                                        r"\(down\) only \(66.1, 75.0, 12.0\) mm, cameras\[1\] "
                                        r"\(down\) only \(-66.1, 75.0, 12.0\) mm\): the eye "
                                        r"measures an LED that both see; --allow-unseen runs "
                                        r"anyway$"):
        check_visible(crossed, arm, p, start_up=False)
    same = dataclasses.replace(rig, cameras=(_down(35.0, 130.0, 600.0),) * 2)
    check_visible(same, arm, p, start_up=False)


def test_a_rig_that_sees_one_elbow_branch_is_accepted_with_a_note():
    """The previous test's camera around (35, 130) mm sees the + branch's elbow (66.1, 75) mm
    only: the check accepts it (a controller may take that branch), and elbow_partly_seen says
    in one line that at that set point a branch is out of view. 300 px wide around x = 0
    (x in [-142, 142] mm after the margin) it sees both: no note."""
    p = np.array([[0.0, 150.0, 0.0]])
    rig, arm, _ = _two_link(_down(35.0, 130.0, 600.0))
    note = elbow_partly_seen(rig, arm, p)
    assert note.startswith("note: ") and "\n" not in note
    assert ("at 1 of the 1 set points in reach only some of the elbow LED's positions (the "
            "arm's inverse-kinematics branches) are in view of every camera, the first at k = 0 "
            "(trace.csv's k)") in note
    assert elbow_partly_seen(*_two_link(_down(0.0, 130.0, 600.0, size=(300, 200)))[:2], p) is None


def test_a_rig_that_frames_the_path_but_not_the_start_up_sweep_is_refused_naming_the_pose():
    """The start-up measurement turns the base through -150..+150 deg (identify.start_up_poses):
    the two-link gripper LED runs round a 200 mm circle. The previous test's camera (200 x 200
    px, 1 mm per px, around (35, 130) mm: x in [-57, 127], y in [38, 222] mm after its 8 px
    margin) frames the start pose and the set point (0, 150) but not the sweep's first pose,
    base -150 deg, gripper at (-173.2, -100) mm. Of the 13 gripper positions (the start, 11
    sweep poses, the set point) it sees the sweep's at base 60 and 90 deg ((100, 173.2) and
    (0, 200) mm; at 120 deg x = -100 is outside), the start and the set point: 9 refused, the
    first named. The sweep's poses are where the start-up looks, so a rig that misses them
    used to fail only once the run began."""
    p = np.array([[0.0, 150.0, 0.0]])
    with pytest.raises(UserError, match=r"cameras\[0\] \(down\): cannot see the gripper LED at 9 "
                                        r"of 13 positions; in the start-up measurement, with the "
                                        r"base at -150 deg, \(-173.2, -100.0, 12.0\) mm projects"):
        check_visible(*_two_link(_down(35.0, 130.0, 600.0))[:2], p)


def test_a_rig_that_frames_part_of_the_start_up_sweep_is_asked_for_the_part_it_sees(tmp_path):
    """The planar start-up leaves out the base sweep's poses it does not see and needs the rest
    to cover 120 deg of arc (identify.enough_of_the_sweep). conftest.front_rig sees both LEDs,
    in both cameras, at 0..150 deg of the sweep: the check asks for those six poses (and the
    start and the path) and accepts ellipse-t1 and ellipse-t2, where it refused the rig at
    base -150 deg before. The previous test's camera sees two poses (60, 90 deg): refused,
    the line saying what the start-up needs and what that rig gives."""
    from itg_vision.visibility import _start_up_seen

    rig, arm = Rig.from_yaml(front_rig(tmp_path / "front.yaml")), ArmSpec.from_args("two-link")
    seen, words = _start_up_seen(rig, arm)
    assert [q[0] for _, q, _ in seen] == [0.0, 30.0, 60.0, 90.0, 120.0, 150.0] and words == ""
    for name in ("ellipse-t1", "ellipse-t2"):
        check_visible(rig, arm, named(name).points_mm)
    with pytest.raises(UserError, match=r"; in the start-up, the base axis needs 3 of the "
                                        r"sweep's 11 poses covering 120 deg of arc, and every "
                                        r"camera sees every LED at 2, covering 30 deg; "
                                        r"--allow-unseen runs anyway$"):
        check_visible(*_two_link(_down(35.0, 130.0, 600.0))[:2], np.array([[0.0, 150.0, 0.0]]))


def test_a_camera_beyond_the_renderer_s_far_plane_is_refused():
    """The renderer draws nothing beyond its far plane (imaging.FAR_M, 5000 mm). A camera 6000 mm
    above the LEDs with f = 2000 px would otherwise do: LEDs of radius 2000 x 6 / 6000 = 2 px
    (>= MIN_LED_RADIUS_PX), the image 1920 x 1440 mm around the arm. At 4900 mm it is accepted."""
    with pytest.raises(UserError, match=r"cameras\[0\] \(down\): cannot see the gripper LED at 32 "
                                        r"of 32 positions; at the start pose, .* mm farther than "
                                        r"the renderer's 5000 mm \(depth 6000 mm\)"):
        check_visible(*_two_link(_down(0.0, 0.0, 6000.0, (640, 480), 2000.0)))
    check_visible(*_two_link(_down(0.0, 0.0, 4900.0, (640, 480), 2000.0)))


def test_the_check_and_the_windows_share_the_near_plane():
    """The renderer clips at its near plane (imaging.NEAR_M, 50 mm), and both the check and
    led_windows ask it of the LED's near side: an LED centred 40 mm, or 53 mm (its near side
    47 mm), in front of a camera is refused by the check and gets no window to render; at 70 mm
    (its near side 64 mm away, its image r = 600 x 6 / 70 = 51 px, inside the frame with its
    margin) both take it."""
    from itg_vision.imaging import led_windows

    cam = _down(0.0, 0.0, 600.0, size=(640, 480))
    X = [cam.back_project([cam.cx, cam.cy], z) for z in (40.0, 53.0, 70.0)]
    why = _visible(cam, X, *_render_range_mm())
    assert why[0] == ("behind the camera or nearer than 50 mm (depth 40 mm, the LED's near side "
                      "34 mm)")
    assert why[1].startswith("behind the camera or nearer than 50 mm (depth 53 mm")
    assert why[2] is None
    assert [w is None for w in led_windows(cam, X, LED_RADIUS_MM)] == [True, True, False]


def test_an_led_beyond_the_lens_fold_is_not_seen_as_the_renderer_does_not_draw_it():
    """k1 = -0.3 (640 x 480, f = 600 px; the rig file allows it: its fold, at normalised radius
    1 / sqrt(0.9), lies beyond the frame) maps the pinhole radius 1.6 to 1.6 (1 - 0.3 x 1.6^2) =
    0.371, 223 px from the centre: inside the frame, though 960 px off it on the pinhole image
    (within the 2 W the check used to allow). The renderer draws that pixel from radius about
    0.4 (0.4 maps to 0.381, 228 px), undistorting it: an LED there is drawn (the control), the
    LED beyond the fold is not, and the check now says so. Rendered: the two-link arm's start
    pose (the gripper LED at (0, 200) mm) under a camera 600 mm above the LED plane, 240 or
    960 mm to its -x side."""
    from itg_vision.camera import _distortion_check
    from itg_vision.detect import score_image
    from itg_vision.imaging import FLAT_LIGHT, capture
    from itg_vision.urdf import LED_RGB
    from itg_vision.world import World

    arm = ArmSpec.from_args("two-link")
    leds = forward_kinematics(arm, arm.start_q_deg)
    seen = {}
    with World(arm) as world:
        for offset in (240.0, 960.0):
            cam = dataclasses.replace(_down(-offset, 200.0, 600.0, size=(640, 480)),
                                      dist=(-0.3, 0.0, 0.0, 0.0, 0.0))
            assert _distortion_check(cam.fx, cam.fy, cam.cx, cam.cy, 640, 480, cam.dist)[0] == ""
            why = _visible(cam, [leds["gripper"]], *_render_range_mm())[0]
            score = score_image(capture(world, cam, None, supersample=1, lighting=FLAT_LIGHT),
                                LED_RGB["gripper"])
            seen[offset] = why, int((score > MIN_SCORE).sum()), cam.project(leds["gripper"])
    (why_near, drawn_near, uv_near), (why_far, drawn_far, uv_far) = seen[240.0], seen[960.0]
    np.testing.assert_allclose([uv_far[0], uv_near[0]], 319.5 + 600 * np.array(
        [1.6 * (1 - 0.3 * 1.6**2), 0.4 * (1 - 0.3 * 0.4**2)]), atol=1e-6)  # both in the frame
    assert why_near is None and drawn_near > 50  # an LED 6 mm in radius images ~6 px in radius
    assert drawn_far == 0
    assert why_far.startswith("lies outside the field of view (pinhole (1280, 240) px)"), why_far
