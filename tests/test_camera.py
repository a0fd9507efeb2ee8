"""Camera maths: projection round trips, OpenGL matrices, rig files, workspace coverage."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import roundoff
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from itg_vision.camera import (UNDISTORT_CRITERIA, Camera, Rig, gl_projection_matrix,
                               gl_view_matrix, look_at_rotation)
from itg_vision.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
PLANAR = ROOT / "cameras" / "planar.yaml"
THREE = ROOT / "cameras" / "three-link.yaml"


@pytest.fixture(scope="module")
def rig() -> Rig:
    return Rig.from_yaml(PLANAR)


def _undistort_tol_px(cam, uv_px):
    """How far cv2.undistortPoints may leave pinhole pixels ``uv_px`` (n, 2): it stops once the
    point, distorted again, is within UNDISTORT_CRITERIA's epsilon (px) of the captured one, which
    is that epsilon over the distortion's least stretch there (the least singular value of its
    Jacobian, by central differences), plus float64 round-off at ~650 px."""
    def distort(uv):
        x = (uv - cam.K[:2, 2]) / [cam.fx, cam.fy]
        return cv2.projectPoints(np.c_[x, np.ones(len(x))], np.zeros(3), np.zeros(3), cam.K,
                                 cam.dist_coeffs)[0].reshape(-1, 2)

    h = 1e-3  # px
    J = np.stack([(distort(uv_px + h * e) - distort(uv_px - h * e)) / (2 * h) for e in np.eye(2)],
                 axis=2)
    return UNDISTORT_CRITERIA[2] / np.linalg.svd(J, compute_uv=False).min() + roundoff(1000)


def _points(rng, n):
    """World points in front of the planar rig (its workspace and beyond)."""
    return rng.uniform([-250, -250, -50], [250, 250, 200], (n, 3))


def test_look_at_rotation_is_a_rotation_and_looks_at_the_target():
    R = look_at_rotation([100, -300, 500], [10, 20, 30], up=[0, 0, 1])
    assert np.allclose(R @ R.T, np.eye(3), rtol=0, atol=roundoff(1.0))
    assert np.isclose(np.linalg.det(R), 1.0)
    cam = Camera.from_arrays("c", (640, 480), [[600, 0, 320], [0, 600, 240], [0, 0, 1]],
                             np.zeros(5), R, -R @ np.array([100, -300, 500.0]))
    # float64 round-off at ~700 mm from the camera, ~600 px
    assert np.allclose(cam.project([10, 20, 30]), [320, 240], rtol=0, atol=roundoff(1000))
    # a point above the target (world up) appears above the centre: smaller v
    assert cam.project([10, 20, 60])[1] < 240


def test_look_at_rotation_takes_directions_given_with_huge_numbers():
    """look_at and up give directions: a look-at point 1e308 mm off, or an up of [0, 1e308,
    1e308], is as good as a near one (a rig file's finite numbers). Their lengths overflowed to
    inf and the 'rotation' came out zero rows (a rig file so read said its camera at z = 620 mm
    was below the floor, at z = 0)."""
    C = np.array([-180.0, -60.0, 620.0])
    for target, up, same_target, same_up in (
            ([0.0, 0.0, 1e308], [0.0, 1.0, 0.0], C + [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
            ([0.0, 0.0, 0.0], [0.0, 1e308, 1e308], [0.0, 0.0, 0.0], [0.0, 1.0, 1.0])):
        R = look_at_rotation(C, target, up)
        # (1e308 - 620 is 1e308: the direction is exactly +z); unit vectors' round-off
        assert np.allclose(R, look_at_rotation(C, same_target, same_up), rtol=0,
                           atol=roundoff(1.0))


def test_an_ordinary_look_at_pose_is_the_same_rotation_to_the_bit():
    """Directions of ordinary size are used as they are (the shipped rigs' rotations, and so
    their renders and the benchmarks' numbers, unchanged): z / |z|, the up vector unscaled."""
    C, T, up = np.array([-180.0, -60.0, 620.0]), np.zeros(3), np.array([0.0, 1.0, 0.0])
    z = (T - C) / np.linalg.norm(T - C)
    y = -(up - (up @ z) * z)
    y = y / np.linalg.norm(y)
    assert np.array_equal(look_at_rotation(C, T, up), np.stack([np.cross(y, z), y, z]))


def test_a_rig_file_looking_at_a_far_off_point_is_read_as_a_rotation(tmp_path):
    doc = yaml.safe_load(PLANAR.read_text())
    doc["cameras"][0]["pose"]["look_at_mm"] = [0.0, 0.0, -1e308]  # straight down, y up
    path = tmp_path / "far-look.yaml"
    path.write_text(yaml.safe_dump(doc))
    cam = Rig.from_yaml(path).cameras[0]
    assert np.allclose(cam.R @ cam.R.T, np.eye(3), rtol=0, atol=roundoff(1.0))
    # its centre where the file puts it (float64 round-off at 620 mm)
    assert np.allclose(cam.position_mm, [-180.0, -60.0, 620.0], rtol=0, atol=roundoff(1000))
    assert np.allclose(cam.R[2], [0.0, 0.0, -1.0], rtol=0, atol=roundoff(1.0))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_project_back_project_round_trip(seed):
    cam = Rig.from_yaml(PLANAR).cameras[seed % 2]
    X = _points(np.random.default_rng(seed), 20)
    depth = cam.to_camera(X)[:, 2]
    for distorted in (True, False):
        uv = cam.project(X, distort=distorted)
        back = cam.back_project(uv, depth, distorted=distorted)
        # the pixel error of undistortPoints (none without distortion), at the depth over f,
        # and float64 round-off at ~650 mm
        px = _undistort_tol_px(cam, cam.project(X, distort=False)) if distorted else 0.0
        assert np.allclose(back, X, rtol=0, atol=px * depth.max() / min(cam.fx, cam.fy) + roundoff(1000))


def test_undistort_inverts_distortion(rig):
    rng = np.random.default_rng(1)
    for cam in rig.cameras:
        X = _points(rng, 500)
        pinhole = cam.project(X, distort=False)
        assert np.allclose(cam.undistort(cam.project(X)), pinhole, rtol=0,
                           atol=_undistort_tol_px(cam, pinhole))


def test_projection_matrix_matches_project(rig):
    rng = np.random.default_rng(2)
    X = _points(rng, 100)
    for cam in rig.cameras:
        h = np.hstack([X, np.ones((len(X), 1))]) @ cam.P.T
        assert np.allclose(h[:, :2] / h[:, 2:], cam.project(X, distort=False), rtol=0,
                           atol=roundoff(1000))  # float64 round-off at ~650 px
        assert np.allclose(cam.to_camera(cam.position_mm), 0, rtol=0, atol=roundoff(1000))  # ~700 mm


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_gl_matrices_match_opencv_with_tinyrenderer_rule(seed):
    """PyBullet's matrices put a point where TinyRenderer draws it: u = (x_ndc + 1) W / 2,
    v = (1 - y_ndc) H / 2 - 1 (measured); that must equal the pinhole projection."""
    rng = np.random.default_rng(seed)
    cam = Rig.from_yaml(THREE if seed % 2 else PLANAR).cameras[seed % 2]
    X = _points(rng, 30)
    view = cam.gl_view().reshape(4, 4, order="F")
    proj = cam.gl_projection(0.05, 5.0).reshape(4, 4, order="F")
    clip = (proj @ view @ np.hstack([X * 1e-3, np.ones((len(X), 1))]).T).T
    ndc = clip[:, :3] / clip[:, 3:]
    W, H = cam.size
    uv = np.stack([(ndc[:, 0] + 1) * W / 2, (1 - ndc[:, 1]) * H / 2 - 1], axis=1)
    # float64 round-off through view, projection and the divide, at ~650 px
    assert np.allclose(uv, cam.project(X, distort=False), rtol=0, atol=roundoff(1000))
    assert np.all(np.abs(ndc[:, 2]) < 1)  # inside the near/far range


def test_gl_projection_puts_the_near_and_far_planes_at_the_clip_range(rig):
    """OpenGL clips at ndc z = -1 and +1: points at the near and far depths given (camera z,
    anywhere across the image) must land there, and midway depths inside; a wrong depth row
    moves the planes the renderer clips at (and the check in visibility.py relies on)."""
    cam = rig.cameras[0]
    near, far = 0.05, 5.0
    proj = cam.gl_projection(near, far).reshape(4, 4, order="F")
    for depth, ndc_z in ((near, -1.0), (far, 1.0), (0.5, None)):
        for x, y in ((0.0, 0.0), (0.3, -0.2)):
            clip = proj @ np.array([x * depth, y * depth, -depth, 1.0])  # GL camera looks down -z
            z = clip[2] / clip[3]
            if ndc_z is None:
                assert -1.0 < z < 1.0
            else:
                assert abs(z - ndc_z) < 1e-12, (depth, z)


def test_gl_functions_are_the_methods(rig):
    cam = rig.cameras[0]
    assert np.array_equal(cam.gl_view(), gl_view_matrix(cam.R, cam.t_mm))
    assert np.array_equal(cam.gl_projection(0.1, 3.0),
                          gl_projection_matrix(cam.K, 640, 480, 0.1, 3.0))


def test_yaml_round_trip_is_exact(rig, tmp_path):
    out = tmp_path / "rig.yaml"
    cal = Rig(rig.name, rig.cameras, "", {"rms_px": 0.12}, str(PLANAR))
    cal.to_yaml(out)
    back = Rig.from_yaml(out)
    assert back.cameras == rig.cameras  # exact float equality, field by field
    assert back.calibration == {"rms_px": 0.12} and back.true_rig == str(PLANAR)
    assert not (tmp_path / "rig.yaml.tmp").exists()
    # a calibrated rig's camera centres are off the 0.1 mm grid: the position_mm it writes for
    # readers, which must agree with its pose within 0.01 mm (README), is written to 0.001 mm
    calib = Rig.from_yaml(ROOT / "cameras" / "planar.calib.yaml")
    C = calib.cameras[0].position_mm
    assert np.max(np.abs(C * 10 - np.round(C * 10))) > 0.1  # off the 0.1 mm grid
    calib.to_yaml(tmp_path / "saved.yaml")
    again = Rig.from_yaml(tmp_path / "saved.yaml")
    assert again.cameras == calib.cameras
    saved = yaml.safe_load((tmp_path / "saved.yaml").read_text())
    for cam, d in zip(again.cameras, saved["cameras"]):
        # half of 0.001 mm, and float64 round-off at ~650 mm
        assert np.max(np.abs(np.array(d["pose"]["position_mm"]) - cam.position_mm)) <= \
            0.0005 + roundoff(1000)


def test_true_rig_hash_round_trips_and_checks_the_true_rig(rig, tmp_path):
    """A calibrated rig's true_rig_sha256 is written and read back; load_true_rig returns the
    true rig while the file is as hashed, and refuses it, in one line naming both files and
    what to do, once it has changed (it rendered with the edited rig, without a word)."""
    from itg_vision.camera import load_true_rig
    from itg_vision.inputs import file_sha256

    true = tmp_path / "true.yaml"
    true.write_text(PLANAR.read_text())
    out = tmp_path / "cal" / "true.calib.yaml"
    out.parent.mkdir()
    Rig(rig.name, rig.cameras, "", {}, "../true.yaml", None, file_sha256(true)).to_yaml(out)
    back = Rig.from_yaml(out)
    assert back.true_rig_sha256 == file_sha256(true)
    assert load_true_rig(back, out).cameras == rig.cameras
    true.write_text(PLANAR.read_text().replace("[-180.0, -60.0, 620.0]", "[-180.0, -60.0, 650.0]"))
    with pytest.raises(UserError) as exc:
        load_true_rig(back, out)
    assert str(exc.value) == (
        f"{out}: its true rig {true} has changed since it was calibrated (true_rig_sha256 no "
        f"longer matches); re-run python -m itg_vision.calibrate --rig {true} --out {out}")
    # read by a path with '..' (an arm file's ../rigs/x.calib.yaml): the command's paths without
    with pytest.raises(UserError) as exc:
        load_true_rig(back, tmp_path / "cal" / ".." / "cal" / out.name)
    assert str(exc.value).endswith(f"--rig {true} --out {out}")
    # tied to the base by an arm's LEDs (calibrate --arm): the command names that arm again
    tied = dataclasses.replace(back, calibration={"base_frame": {"arm": "three-link"}})
    with pytest.raises(UserError) as exc:
        load_true_rig(tied, out)
    assert str(exc.value).endswith(f"--rig {true} --arm three-link --out {out}")
    # a calibration without the hash (older files, the shipped ones) is not checked
    old = Rig(rig.name, rig.cameras, "", {}, "../true.yaml")
    # the position comes back through R and t: float64 round-off at ~650 mm
    assert load_true_rig(old, out).cameras[0].position_mm[2] == pytest.approx(650.0, rel=0,
                                                                             abs=roundoff(1000))
    shipped = ROOT / "cameras" / "planar.calib.yaml"
    assert Rig.from_yaml(shipped).true_rig_sha256 is None
    load_true_rig(Rig.from_yaml(shipped), shipped)


def test_rotation_deg_form_equals_look_at_form(rig, tmp_path):

    doc = yaml.safe_load(PLANAR.read_text())
    cam = rig.cameras[0]
    rv = np.degrees(cv2.Rodrigues(cam.R)[0].ravel())
    doc["cameras"][0]["pose"] = {"position_mm": cam.position_mm.tolist(),
                                 "rotation_deg": rv.tolist()}
    path = tmp_path / "rv.yaml"
    path.write_text(yaml.safe_dump(doc))
    other = Rig.from_yaml(path).cameras[0]
    assert np.allclose(other.R, cam.R, rtol=0, atol=roundoff(1.0))  # Rodrigues and back
    assert np.allclose(other.t_mm, cam.t_mm, rtol=0, atol=roundoff(1000))  # ~700 mm


def test_a_rig_files_camera_matrix_is_the_cameras_and_projects_as_opencv_does(tmp_path):
    """fy unlike fx (660 against 600; the shipped right camera's differ by 2 px): the camera
    holds the file's matrix, and a point projects where cv2.projectPoints puts it with the
    file's K and distortion."""
    doc = yaml.safe_load(PLANAR.read_text())
    K = np.array([[600.0, 0, 319.5], [0, 660.0, 241.0], [0, 0, 1]])
    doc["cameras"][0]["camera_matrix"]["data"] = K.ravel().tolist()
    path = tmp_path / "fy.yaml"
    path.write_text(yaml.safe_dump(doc))
    cam = Rig.from_yaml(path).cameras[0]
    assert np.array_equal(cam.K, K)
    X = _points(np.random.default_rng(5), 20)
    dist = np.array(doc["cameras"][0]["distortion_coefficients"]["data"])
    expected = cv2.projectPoints(X, cv2.Rodrigues(cam.R)[0], cam.t_mm, K, dist)[0].reshape(-1, 2)
    assert np.allclose(cam.project(X), expected, rtol=0, atol=roundoff(1000))


def test_plumb_bob_is_opencvs_lens_model():
    """The distortion check's lens model, in numpy, against cv2.projectPoints (K = I) for
    random normalized points and lenses, each coefficient alone and all together."""
    from itg_vision.camera import plumb_bob

    rng = np.random.default_rng(8)
    xy = rng.uniform(-1.2, 1.2, (500, 2))
    lenses = [np.eye(5)[i] * c for i in range(5) for c in (-0.3, 0.2)]
    lenses += [rng.normal(0, [0.3, 0.2, 0.02, 0.02, 0.2]) for _ in range(10)]
    for dist in lenses:
        expected = cv2.projectPoints(np.c_[xy, np.ones(len(xy))], np.zeros(3), np.zeros(3),
                                     np.eye(3), dist)[0].reshape(-1, 2)
        got = np.stack(plumb_bob(xy[:, 0], xy[:, 1], dist), axis=1)
        assert np.allclose(got, expected, rtol=0, atol=roundoff(10)), dist


def test_a_look_at_pose_without_up_has_the_world_z_up(tmp_path):
    """'up' may be left out: the world's z is then up in the image, so a point 100 mm above
    the looked-at point images above the principal point (v < cy), and the pose is the one
    written with up [0, 0, 1]."""
    doc = yaml.safe_load(THREE.read_text())
    pose = {"position_mm": [0.0, -600.0, 150.0], "look_at_mm": [0.0, 0.0, 150.0]}
    doc["cameras"][0]["pose"] = pose
    path = tmp_path / "no-up.yaml"
    path.write_text(yaml.safe_dump(doc))
    cam = Rig.from_yaml(path).cameras[0]
    doc["cameras"][0]["pose"] = {**pose, "up": [0.0, 0.0, 1.0]}
    path.write_text(yaml.safe_dump(doc))
    assert np.array_equal(cam.R, Rig.from_yaml(path).cameras[0].R)
    u, v = cam.project(np.array([[0.0, 0.0, 250.0]]), distort=False)[0]
    # closed form: straight above, 600 mm away, 100 mm up: fy * 100 / 600 px above cy
    assert u == pytest.approx(cam.cx, abs=roundoff(1000))
    assert v == pytest.approx(cam.cy - cam.fy * 100 / 600, abs=roundoff(1000))


def _set(doc, keys, value):
    d = doc
    for k in keys[:-1]:
        d = d[k]
    if value is _DELETE:
        del d[keys[-1]]
    else:
        d[keys[-1]] = value


def _refusal(doc, path) -> str:
    """``doc`` written to ``path`` as YAML: the one line ``Rig.from_yaml`` refuses it with."""
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(UserError) as exc:
        Rig.from_yaml(path)
    return str(exc.value)


_DELETE = object()
_K = [600.0, 0.0, 319.5, 0.0, 600.0, 239.5, 0.0, 0.0, 1.0]


@pytest.mark.parametrize("keys, value, expected", [
    (("cameras", 1, "camera_matrix"), {"rows": 3, "cols": 3, "data": [-600.0] + _K[1:]},
     "cameras[1].camera_matrix: fx must be > 0"),
    (("cameras", 0, "camera_matrix"), _K[:2] + [900.0] + _K[3:],
     "cameras[0].camera_matrix: cx must be inside the image [0, 639], got 900"),
    (("cameras", 0, "camera_matrix"), _K[:1] + [50.0] + _K[2:],
     "cameras[0].camera_matrix: must be [fx, 0, cx, 0, fy, cy, 0, 0, 1] (no skew)"),
    (("cameras", 0, "camera_matrix"), _K[:8],
     "cameras[0].camera_matrix: must be a list of 9 numbers, got 8 values"),
    (("cameras", 0, "image_width"), 0, "cameras[0].image_width: must be > 0, got 0"),
    (("cameras", 0, "image_height"), 0, "cameras[0].image_height: must be > 0, got 0"),
    (("cameras", 1, "image_height"), "tall",
     "cameras[1].image_height: must be an integer, got 'tall'"),
    (("cameras", 0, "distortion_coefficients"), [0.1, 0.0, 0.0],
     "cameras[0].distortion_coefficients: must be a list of 5 numbers, got 3 values"),
    (("cameras", 0, "distortion_coefficients"), [0.1, "x", 0.0, 0.0, 0.0],
     "cameras[0].distortion_coefficients[1]: must be a finite number, got 'x'"),
    (("cameras", 0, "distortion_coefficients"), [0.0, 0.0, 0.0, 0.0, 150.0],
     "cameras[0].distortion_coefficients: each must be within +-100, got 150"),
    (("cameras", 1, "pose", "look_at_mm"), [180.0, -60.0, 620.0],
     "cameras[1].pose.look_at_mm: must differ from position_mm"),
    (("cameras", 0, "pose", "position_mm"), _DELETE, "cameras[0].pose.position_mm: missing"),
    (("cameras", 0, "sensor", "noise_sigma_gray"), -1,
     "cameras[0].sensor.noise_sigma_gray: must be in [0, 255] grey levels, got -1"),
    (("cameras", 0, "sensor", "exposure"), 0.0,
     "cameras[0].sensor.exposure: must be in (0, 1000], got 0"),
    # a sensor that is no mapping is refused, not read as the default sensor
    (("cameras", 0, "sensor"), [],
     "cameras[0].sensor: must be a mapping of noise_sigma_gray, exposure, got []"),
    (("cameras", 1, "sensor"), False,
     "cameras[1].sensor: must be a mapping of noise_sigma_gray, exposure, got False"),
    (("cameras", 0, "distortion_model"), "fisheye",
     "cameras[0].distortion_model: only plumb_bob is supported, got 'fisheye'"),
    (("cameras",), [], "cameras: must be a list of exactly two cameras"),
    (("cameras", 1, "name"), "left", "cameras[1].name: duplicates cameras[0].name 'left'"),
    (("name",), _DELETE, "name: missing"),
    (("supersample",), 0, "supersample: must be in 1..8, got 0"),
    (("supersample",), 1.5, "supersample: must be an integer, got 1.5"),
    (("true_rig",), 5, "true_rig: must be a path string"),  # (a TypeError traceback in run)
    # unknown and contradicting keys (they ran, ignored, before)
    (("supersampel",), 1,
     "supersampel: unknown field (known: name, cameras, supersample, calibration, true_rig, "
     "true_rig_sha256)"),
    (("true_rig_sha256",), "abc",
     "true_rig_sha256: must be 64 lowercase hex digits (a SHA-256)"),
    (("true_rig_sha256",), "0" * 64, "true_rig_sha256: needs true_rig, the file it is the hash of"),
    (("cameras", 0, "sensor", "noise_sigma_grey"), 20,
     "cameras[0].sensor.noise_sigma_grey: unknown field (known: noise_sigma_gray, exposure)"),
    (("cameras", 1, "focal_mm"), 8, "cameras[1].focal_mm: unknown field (known: name, "
     "image_width, image_height, camera_matrix, distortion_coefficients, pose, "
     "distortion_model, sensor)"),
    (("cameras", 0, "pose", "rotation_deg"), [180, 0, 0], "cameras[0].pose: gives more than "
     "one pose form (look_at_mm + up; rotation_deg): keep one of look_at_mm, rotation_deg or "
     "rotation_matrix + translation_mm"),
    (("cameras", 1, "pose", "translation_mm"), [0, 0, 600],
     "cameras[1].pose: gives more than one pose form (look_at_mm + up; translation_mm): keep "
     "one of look_at_mm, rotation_deg or rotation_matrix + translation_mm"),
])
def test_bad_rig_file_names_the_field(tmp_path, keys, value, expected):
    """One field of planar.yaml set wrong (or removed): the whole message, one line, is the
    file, the field and what it must be."""
    doc = yaml.safe_load(PLANAR.read_text())
    _set(doc, keys, value)
    path = tmp_path / "x.yaml"
    assert _refusal(doc, path) == f"{path}: {expected}"


def test_optional_rig_fields_take_the_shipped_values_and_a_noise_free_sensor_is_a_sensor(tmp_path):
    """distortion_model (plumb_bob, the only one) and sensor ({noise_sigma_gray: 2.0,
    exposure: 1.0}, camera.py's docstring and every shipped rig) may be left out: the same
    cameras. A noise-free sensor (sigma 0 grey levels, in [0, 255]) is accepted."""
    doc = yaml.safe_load(PLANAR.read_text())
    for c in doc["cameras"]:
        assert c["distortion_model"] == "plumb_bob"
        assert c["sensor"] == {"noise_sigma_gray": 2.0, "exposure": 1.0}
        del c["distortion_model"], c["sensor"]
    path = tmp_path / "bare.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert Rig.from_yaml(path).cameras == Rig.from_yaml(PLANAR).cameras
    doc = yaml.safe_load(PLANAR.read_text())
    doc["cameras"][0]["sensor"]["noise_sigma_gray"] = 0.0
    path.write_text(yaml.safe_dump(doc))
    assert Rig.from_yaml(path).cameras[0].noise_sigma_gray == 0.0


def test_a_mirrored_rotation_matrix_is_refused(tmp_path):
    """A rotation_matrix with det -1 (one row negated, and its translation, so the camera
    centre -R^T t is where it was) is a mirror image, not a camera pose: one line naming it."""
    doc = yaml.safe_load((ROOT / "cameras" / "planar.calib.yaml").read_text())
    pose = doc["cameras"][0]["pose"]
    pose["rotation_matrix"]["data"][3:6] = [-v for v in pose["rotation_matrix"]["data"][3:6]]
    pose["translation_mm"][1] = -pose["translation_mm"][1]
    path = tmp_path / "mirror.yaml"
    assert _refusal(doc, path) == (
        f"{path}: cameras[0].pose.rotation_matrix: must be a rotation (orthonormal, det +1)")


def test_a_rotation_matrix_written_with_too_few_digits_says_how_far_off_it_is(tmp_path):
    """A rotation_matrix copied to 5 decimals (as a printout gives it) is ~7e-6 off
    orthonormal, over the 1e-6 the loader allows: refused, and the one line says by how much,
    the bound, and what to do (it said only 'must be a rotation (orthonormal, det +1)', which
    a user reads as a wrong matrix). The same matrix to 8 decimals loads."""
    rig = Rig.from_yaml(PLANAR)
    doc = yaml.safe_load(PLANAR.read_text())
    for digits in (5, 8):
        for c, cam in zip(doc["cameras"], rig.cameras):
            data = [round(float(v), digits) for v in cam.R.ravel()]
            c["pose"] = {"rotation_matrix": {"rows": 3, "cols": 3, "data": data},
                         "translation_mm": [float(v) for v in cam.t_mm]}
        path = tmp_path / f"r{digits}.yaml"
        if digits == 8:
            path.write_text(yaml.safe_dump(doc))
            assert np.allclose(Rig.from_yaml(path).cameras[0].R, rig.cameras[0].R, atol=1e-8)
            continue
        assert _refusal(doc, path) == (
            f"{path}: cameras[0].pose.rotation_matrix: must be a rotation (orthonormal, det +1): "
            "R R^T is 7.1e-06 off the identity (at most 1e-06); a rotation written to 4 or 5 "
            "decimals is 1e-4 to 1e-5 off: give it to 8 or more")


def test_a_camera_looking_straight_down_without_up_is_told_the_default_is_the_problem(tmp_path):
    """A camera straight above the base looking down, pose without up (optional, default
    [0, 0, 1], parallel to that view): the line said 'cameras[0].pose.up: must not be zero or
    parallel to the viewing direction' of a field the file does not have. It now says the
    default was used and what to give. With up written [0, 0, 1] the old words stand."""
    doc = yaml.safe_load(PLANAR.read_text())
    doc["cameras"][0]["pose"] = {"position_mm": [0.0, 0.0, 700.0], "look_at_mm": [0.0, 0.0, 0.0]}
    path = tmp_path / "down.yaml"
    assert _refusal(doc, path) == (
        f"{path}: cameras[0].pose.up: not given, and its default [0, 0, 1] is parallel to the "
        "viewing direction (a camera looking straight down or up): give up, the world "
        "direction shown as up in the image")
    doc["cameras"][0]["pose"]["up"] = [0.0, 0.0, 1.0]
    assert _refusal(doc, path) == (
        f"{path}: cameras[0].pose.up: must not be zero or parallel to the viewing direction")


def _mappings(doc):
    """Where a key can go in a rig document: (place in the message, the mapping)."""
    yield "", doc
    for i, cam in enumerate(doc["cameras"]):
        yield f"cameras[{i}].", cam
        yield f"cameras[{i}].pose.", cam["pose"]
        yield f"cameras[{i}].sensor.", cam["sensor"]


@pytest.mark.parametrize("path", sorted((ROOT / "cameras").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_rigs_load_and_an_unknown_key_anywhere_is_refused(path, tmp_path):
    """Every key the shipped rigs and calibrations use is known (they load); a key added to any
    mapping of theirs is one line naming the file and the key."""
    Rig.from_yaml(path)
    text, bad = path.read_text(), tmp_path / path.name
    for k in range(len(list(_mappings(yaml.safe_load(text))))):
        doc = yaml.safe_load(text)
        place, mapping = list(_mappings(doc))[k]
        mapping["colour"] = 1
        assert _refusal(doc, bad).startswith(f"{bad}: {place}colour: unknown field (known: ")


def test_a_saved_pose_whose_position_contradicts_it_is_refused(tmp_path):
    """The exact pose form also writes position_mm, for readers: edited (to move the camera), it
    would be ignored; it is refused instead."""
    doc = yaml.safe_load((ROOT / "cameras" / "planar.calib.yaml").read_text())
    doc["cameras"][1]["pose"]["position_mm"][0] += 10.0
    path = tmp_path / "moved.yaml"
    assert _refusal(doc, path) == (
        f"{path}: cameras[1].pose.position_mm: contradicts rotation_matrix + translation_mm "
        "(camera centre [179.873, -59.845, 619.432]): correct or remove it")


def test_unreadable_rig_file(tmp_path):
    with pytest.raises(UserError, match="cannot read"):
        Rig.from_yaml(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("cameras: [\n")
    with pytest.raises(UserError, match="not valid YAML"):
        Rig.from_yaml(bad)


def _workspace(kind: str) -> np.ndarray:
    """A dense grid over every place an LED can be (mm)."""
    if kind == "planar":  # disc r = 200 mm at the LED height 12 mm
        g = np.linspace(-200, 200, 81)
        x, y = np.meshgrid(g, g)
        keep = x**2 + y**2 <= 200**2
        return np.stack([x[keep], y[keep], np.full(keep.sum(), 12.0)], axis=1)
    g = np.linspace(-200, 200, 41)  # ball r = 200 mm about the shoulder (0, 0, 100)
    x, y, z = np.meshgrid(g, g, g)
    P = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    return P[np.linalg.norm(P, axis=1) <= 200] + [0, 0, 100]


@pytest.mark.parametrize("path, kind", [(PLANAR, "planar"), (THREE, "three")])
def test_shipped_rigs_see_the_whole_workspace(path, kind):
    rig = Rig.from_yaml(path)
    X = _workspace(kind)
    for cam in rig.cameras:
        z = cam.to_camera(X)[:, 2]
        assert z.min() > 300  # well in front of the camera
        uv = cam.project(X)
        # margin: LED radius in px (6 mm * 600 px / 600 mm ~ 6 px) + the +-24 px search
        # window + a few px of slack = 40 px from every edge
        r_px = 6.0 * cam.fx / z.min()
        margin = r_px + 24 + 8
        W, H = cam.size
        assert uv[:, 0].min() > margin and uv[:, 0].max() < W - 1 - margin
        assert uv[:, 1].min() > margin and uv[:, 1].max() < H - 1 - margin
    B = np.linalg.norm(rig.cameras[0].position_mm - rig.cameras[1].position_mm)
    assert 300 <= B <= 400


@pytest.mark.parametrize("factor", [0.5, 2.0, 3.0])
def test_scaled_rig_keeps_the_field_of_view_at_pixel_centres(rig, factor):
    """Rig.scaled(k): the same world point lands on the same place of the picture; pixel
    (i, j)'s centre is at (i, j), so a point at u maps to (u + 0.5) k - 0.5 (with distortion:
    it acts on normalised coordinates, which scaling leaves alone)."""
    scaled = rig.scaled(factor)
    X = np.random.default_rng(2).uniform([-150, -150, 0], [150, 150, 50], (20, 3))
    for c0, c1 in zip(rig.cameras, scaled.cameras):
        assert c1.size == (round(c0.image_width * factor), round(c0.image_height * factor))
        assert np.allclose(c1.project(X), (c0.project(X) + 0.5) * factor - 0.5, rtol=0,
                           atol=roundoff(2000))  # float64 round-off at up to 1900 px
        # scaling leaves the pose alone: the same numbers
        assert np.array_equal(c1.R, c0.R) and np.array_equal(c1.t_mm, c0.t_mm) and c1.dist == c0.dist
