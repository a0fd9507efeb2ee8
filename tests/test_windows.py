"""Windows around the LEDs against whole frames; the vision loop's named steps and its
Observation."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import flat_disc, roundoff

from itg_vision.arm import ArmSpec, arm_names
from itg_vision.camera import Rig, default_rig_path
from itg_vision.detect import locate_led
from itg_vision.feedback import Markers, Observation, VisionFeedback
from itg_vision.imaging import FLAT_LIGHT, Patch, capture, capture_window, led_windows
from itg_vision.urdf import LED_RADIUS_MM, LED_RGB
from itg_vision.world import World

ROOT = Path(__file__).resolve().parents[1]


def _noise_free(rig: Rig) -> Rig:
    return replace(rig, cameras=tuple(replace(c, noise_sigma_gray=0.0) for c in rig.cameras))


@pytest.mark.parametrize("arm_name, supersample", [(a, 1) for a in arm_names()]
                         + [("two-link", 3)])
def test_windowed_centroids_equal_the_full_frames(arm_name, supersample):
    """Without sensor noise a window's pixels are the full frame's (the same rasteriser with K
    shifted by the window's origin, the same remap table sliced; at s > 1 the lens on the
    supersampled render, then the sensor's average, in both): centroids agree within 0.002 px
    (the issue's bound; measured 0 here, TECHNICAL.md saw 4e-4 px from one grey level in one
    pixel of 92k), on random poses of every arm, both cameras, and at the default s = 3 (a
    full frame averaged before its lens was 0.022 px off)."""
    arm = ArmSpec.from_args(arm_name)
    rig = _noise_free(Rig.from_yaml(default_rig_path(arm)))
    win = VisionFeedback(rig, rig, arm, supersample=supersample)
    full = VisionFeedback(rig, rig, arm, supersample=supersample, full_frame=True)
    n = 0
    with World(arm) as world:
        for q in arm.random_poses(6, np.random.default_rng(21)):
            world.set_q(q)
            for fb in (win, full):
                fb.reset(0)
                fb.observe(world)
            a, b = win.last_observation, full.last_observation
            assert all(p.full_frame for ps in b.patches.values() for p in ps)
            assert not any(p.full_frame for ps in a.patches.values() for p in ps)
            for name in arm.marker_names:
                assert a.reasons[name] == b.reasons[name]
                for da, db in zip(a.detections[name], b.detections[name]):
                    if da.ok:
                        assert np.abs(da.uv_raw_px - db.uv_raw_px).max() < 0.002
                        assert np.abs(da.uv_px - db.uv_px).max() < 0.002
                        assert da.area_px == db.area_px
                        n += 1
    assert n >= 6 * 2 * len(arm.marker_names) * 0.8


@pytest.mark.parametrize("supersample", [1, 2, 3])
def test_window_pixels_equal_the_frame_pixels(supersample):
    """The windows' pixels themselves, at every supersampling factor (the area average of
    s x s blocks is the same on both), with the rig's lens distortion."""
    arm = ArmSpec.from_args("three-link")
    rig = Rig.from_yaml(default_rig_path(arm))
    with World(arm) as world:
        world.set_q([40.0, 60.0, -70.0])
        X = np.array(list(world.led_centres_mm().values()))
        for cam in rig.cameras:
            frame = capture(world, cam, None, supersample=supersample, lighting=FLAT_LIGHT,
                            lens_first=True)
            for box in led_windows(cam, X, LED_RADIUS_MM):
                x0, y0, x1, y1 = box
                p = capture_window(world, cam, None, box, supersample=supersample,
                                   lighting=FLAT_LIGHT)
                assert p.origin_px == (x0, y0) and p.image.shape == (y1 - y0, x1 - x0, 3)
                diff = np.abs(p.image.astype(int) - frame[y0:y1, x0:x1].astype(int))
                assert diff.max() <= 1 and np.count_nonzero(diff) <= 2


def test_known_point_projects_the_same_both_ways():
    """A sphere at a known point (the gripper LED), rendered in a window and in the whole
    frame: both centroids sit on the camera model's projection of its centre (K [R | t] and
    the distortion). The error budget at supersample 2: 0.04 px RMS rendering, ~0.02 px
    perspective (a sphere images as an ellipse); TinyRenderer's v convention wrong by its
    1 px would show as 1 px. Bound: 0.15 px each."""
    arm = ArmSpec.from_args("two-link")
    rig = _noise_free(Rig.from_yaml(default_rig_path(arm)))
    with World(arm) as world:
        for q in ([20.0, 30.0], [-120.0, 75.0]):
            world.set_q(q)
            X = world.led_centres_mm()["gripper"]
            for cam in rig.cameras:
                uv = cam.project(X)
                box = led_windows(cam, X[None], LED_RADIUS_MM)[0]
                x0, y0, x1, y1 = box
                assert x0 < uv[0] < x1 - 1 and y0 < uv[1] < y1 - 1
                p = capture_window(world, cam, None, box, lighting=FLAT_LIGHT)
                frame = Patch(capture(world, cam, None, lighting=FLAT_LIGHT, lens_first=True),
                              (0, 0), cam.size)
                for patch in (p, frame):
                    d = locate_led(patch, LED_RGB["gripper"])
                    assert d.ok and np.linalg.norm(d.uv_raw_px - uv) < 0.15, (d, uv)


def test_occlusion_is_real_in_windows():
    """The windows are drawn in the arm's own scene: at this folded three-link pose the
    forearm hides part of the elbow LED from the left camera. The window path misses it with
    a reason, as the whole frame does, and sees the gripper."""
    arm = ArmSpec.from_args("three-link")
    rig = Rig.from_yaml(default_rig_path(arm))
    with World(arm) as world:
        world.set_q([70.6, -74.6, -179.5])
        for full_frame in (False, True):
            fb = VisionFeedback(rig, rig, arm, full_frame=full_frame)
            fb.reset(0)
            m = fb.observe(world)
            obs = fb.last_observation
            assert m.missed == ("elbow",)
            assert "partly hidden" in obs.reasons["elbow"]
            assert obs.reasons["gripper"] == ""


def _disc_patch(centre, origin, frame_size, size=(21, 21), radius=4.0):
    """A white window with a flat red disc (anti-aliased: drawn at 8x, area-averaged)."""
    return Patch(flat_disc(centre, radius, size, s=8), origin, frame_size)


def test_blob_touching_the_window_border_is_rejected():
    """A blob cut by a side of its window is not an LED's whole image: rejected, and said
    whether the side is the frame's or only the window's. Whole inside: found, at the right
    place in frame coordinates (a flat disc with intensity weights: within 0.01 px)."""
    red = LED_RGB["gripper"]
    ok = locate_led(_disc_patch((10.3, 9.6), (100, 50), (640, 480)), red)
    assert ok.ok and np.abs(ok.uv_raw_px - [110.3, 59.6]).max() < 0.01
    cut = locate_led(_disc_patch((1.5, 10.0), (100, 50), (640, 480)), red)
    assert not cut.ok and cut.reason == "touches the window border"
    edge = locate_led(_disc_patch((1.5, 10.0), (0, 50), (640, 480)), red)
    assert not edge.ok and edge.reason == "at the image border"
    # a window at the frame's left edge, the blob cut by its right side: the window's border
    inner = locate_led(_disc_patch((19.5, 10.0), (0, 50), (640, 480)), red)
    assert inner.reason == "touches the window border"


def test_observation_contents():
    """observe() = capture_pair, detect, triangulate; the Observation keeps each step's
    result, and nothing else of the feedback changes between looks."""
    arm = ArmSpec.from_args("two-link")
    rig = Rig.from_yaml(default_rig_path(arm))
    fb = VisionFeedback(rig, rig, arm, noise_px=0.0)
    assert fb.last_observation is None
    fb.reset(1)
    attrs = set(vars(fb))
    with World(arm) as world:
        world.set_q([35.0, -80.0])
        m = fb.observe(world)
        truth = world.true_markers()
    obs = fb.last_observation
    assert set(vars(fb)) == attrs  # nothing set outside __init__
    assert isinstance(obs, Observation) and obs.markers is m and isinstance(m, Markers)
    assert set(obs.patches) == set(obs.detections) == set(obs.reasons) == {"gripper", "elbow"}
    assert obs.reasons == {"gripper": "", "elbow": ""} and m.missed == ()
    assert set(obs.residual_px) == {"gripper", "elbow"} and obs.residual_px == m.residual_px
    assert set(obs.timing_ms) == {"render", "detect", "triangulate"} == set(m.timing_ms)
    assert obs.frames() is None  # windows only
    for name in ("gripper", "elbow"):
        for cam, patch, det in zip(rig.cameras, obs.patches[name], obs.detections[name]):
            assert not patch.full_frame and patch.image.shape[0] < 40
            x0, y0 = patch.origin_px
            h, w = patch.image.shape[:2]
            assert x0 <= det.uv_raw_px[0] <= x0 + w - 1 and y0 <= det.uv_raw_px[1] <= y0 + h - 1
            assert np.abs(det.uv_px - cam.project(truth[name], distort=False)).max() < 0.3
        assert np.linalg.norm(m.get(name) - truth[name]) < 0.4  # see test_vision
    with pytest.raises(KeyError):
        m.get("wrist")
    # the named steps, by hand, give the same estimate from the same pixels
    dets = fb.detect(obs.patches)
    points, residual, reasons, causes = fb.triangulate(dets)
    assert np.allclose(points["gripper"], m.gripper_mm, rtol=0, atol=roundoff(300)) and reasons == obs.reasons
    assert causes == obs.causes == {"gripper": "", "elbow": ""}
    full = VisionFeedback(rig, rig, arm, full_frame=True)
    full.reset(1)
    with World(arm) as world:
        full.observe(world)
    frames = full.last_observation.frames()
    assert len(frames) == 2 and frames[0].shape == (480, 640, 3)


def test_supersample_option_rig_file_and_default(tmp_path, capsys):
    """--supersample beats the rig file's ``supersample``, which beats the default; bad values
    are one line naming the option or the field, exit 2."""
    import yaml

    from itg_vision.errors import UserError
    from itg_vision.feedback import DEFAULT_SUPERSAMPLE
    from itg_vision.run import main
    from itg_vision.runner import RunConfig, feedback_params, prepare

    doc = yaml.safe_load((ROOT / "cameras" / "planar.yaml").read_text())
    doc["supersample"] = 2
    rig_file = tmp_path / "ss2.yaml"
    rig_file.write_text(yaml.safe_dump(doc))
    assert Rig.from_yaml(rig_file).supersample == 2
    assert prepare(RunConfig()).feedback_factory().supersample == DEFAULT_SUPERSAMPLE
    assert prepare(RunConfig(rig=str(rig_file))).feedback_factory().supersample == 2
    fb = prepare(RunConfig(rig=str(rig_file), supersample=1, full_frame=True)).feedback_factory()
    assert (fb.supersample, fb.full_frame) == (1, True)
    assert feedback_params(RunConfig(), 3)["supersample"] == 3
    doc["supersample"] = 9
    rig_file.write_text(yaml.safe_dump(doc))
    with pytest.raises(UserError, match="supersample: must be in 1..8"):
        Rig.from_yaml(rig_file)
    for args, expect in ((["--supersample", "0"], "--supersample"),
                         (["--feedback", "model", "--full-frame"], "--full-frame")):
        assert main([*args, "--out", str(tmp_path / "r"), "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expect in err[0], err


def test_the_windows_row_arithmetic_is_numpys_bit_for_bit():
    """led_windows writes its cross products and lengths out (np.cross and np.linalg.norm spent
    two thirds of its 0.2 ms moving axes on two rows); the floats must be numpy's exactly,
    since a window one pixel larger draws more sensor noise and shifts every later draw."""
    from itg_vision.imaging import _cross, _norms

    rng = np.random.default_rng(2)
    for n in (1, 2, 5):
        a, b = rng.normal(0, 300, (n, 3)), rng.normal(0, 1, (n, 3))
        assert np.array_equal(_cross(a, b), np.cross(a, b))
        assert np.array_equal(_norms(a), np.linalg.norm(a, axis=1))


def test_a_sphere_behind_the_camera_has_no_window_and_no_warning():
    """A rig turned away from the arm (bench accuracy's random poses put LEDs behind a camera):
    the rims of spheres behind the camera project through the lens to NaN, whose cast to pixels
    printed "RuntimeWarning: invalid value encountered in cast" with its source lines beside the
    benchmark's one-line error. Behind the camera there is no window, and nothing to warn of."""
    import warnings

    cam = Rig.from_yaml(default_rig_path("two-link")).cameras[0]
    uv = np.array([[u, v] for u in (0.0, 320.0, 639.0) for v in (0.0, 240.0, 479.0)])
    behind = cam.back_project(uv, -600.0, distorted=False)
    assert (cam.to_camera(behind)[:, 2] < 0).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert led_windows(cam, behind, LED_RADIUS_MM) == [None] * len(uv)
