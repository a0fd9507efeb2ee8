"""Lens distortion by remap, sensor noise, and capture through the simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from itg_vision.camera import Camera, Rig
from itg_vision.imaging import (add_sensor_noise, capture, distort, distortion_source_map,
                                gaussian_noise, render_plan)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cam() -> Camera:
    return Rig.from_yaml(ROOT / "cameras" / "planar.yaml").cameras[0]


def test_source_map_is_undistortion(cam):
    src = distortion_source_map(cam)
    rng = np.random.default_rng(0)
    ij = rng.integers([0, 0], [cam.image_width, cam.image_height], (200, 2))
    # the map is float32: values of 512-1024 px are rounded to half an ulp, 2**-15 px; one ulp
    f32 = 2.0**-14
    assert np.allclose(src[ij[:, 1], ij[:, 0]], cam.undistort(ij.astype(float)), rtol=0, atol=f32)
    # and distorting the source gives the pixel back (distortion/undistortion round trip)
    X = cam.back_project(src[ij[:, 1], ij[:, 0]], 500.0, distorted=False)
    assert np.allclose(cam.project(X), ij, rtol=0, atol=f32)


def test_margin_covers_the_corners(cam):
    plan = render_plan(cam, 1)
    src = distortion_source_map(cam) + plan.margin_px
    W, H = cam.size
    assert src.min() >= 1 and src[..., 0].max() <= W + 2 * plan.margin_px - 2
    assert src[..., 1].max() <= H + 2 * plan.margin_px - 2


def test_remap_moves_a_dot_to_its_distorted_projection(cam):
    """A smooth Gaussian dot drawn at a pinhole position must land at the distorted
    projection. Bilinear remap of a sigma = 2 px dot keeps its centroid to ~0.01 px; the
    distortion's curvature across the dot adds < 0.01 px; 0.03 px tolerance."""
    plan = render_plan(cam, 1)
    m = plan.margin_px
    W, H = cam.size
    jj, ii = np.mgrid[0:H + 2 * m, 0:W + 2 * m]
    for uv_d in ([30.0, 25.0], [320.3, 240.7], [600.2, 450.9]):
        X = cam.back_project(np.array(uv_d), 500.0)
        u, v = cam.project(X, distort=False) + m
        dot = 200 * np.exp(-((ii - u) ** 2 + (jj - v) ** 2) / (2 * 2.0**2))
        img = np.repeat(dot[..., None], 3, axis=2).astype(np.float32)
        out = distort(img, cam, 1)[..., 0]
        win = out[int(uv_d[1]) - 12:int(uv_d[1]) + 13, int(uv_d[0]) - 12:int(uv_d[0]) + 13]
        y, x = np.mgrid[int(uv_d[1]) - 12:int(uv_d[1]) + 13, int(uv_d[0]) - 12:int(uv_d[0]) + 13]
        c = np.array([(win * x).sum(), (win * y).sum()]) / win.sum()
        assert np.allclose(c, uv_d, rtol=0, atol=0.03), (c, uv_d)


def test_sensor_noise_statistics_and_seed(cam):
    img = np.full((120, 160, 3), 128, np.uint8)
    a = add_sensor_noise(img, cam, np.random.default_rng(3))
    b = add_sensor_noise(img, cam, np.random.default_rng(3))
    assert np.array_equal(a, b) and a.dtype == np.uint8
    d = a.astype(float) - 128
    # 57600 samples: the std's standard error is ~0.3 %; rounding adds 1/12 grey^2
    assert abs(d.std() - np.hypot(cam.noise_sigma_gray, np.sqrt(1 / 12))) < 0.05
    assert abs(d.mean()) < 0.05
    assert np.array_equal(add_sensor_noise(img, cam, None), img)
    n = gaussian_noise((100000,), 3.0, np.random.default_rng(0))
    assert abs(n.std() - 3.0) < 0.05


def test_exposure_gain_and_clipping(cam):
    from dataclasses import replace

    bright = replace(cam, exposure=1.5, noise_sigma_gray=0.0)
    img = np.array([[[100, 200, 0]]], np.uint8)
    assert add_sensor_noise(img, bright, None).tolist() == [[[150, 255, 0]]]


def test_capture_shape_and_background():
    from itg_vision.arm import ArmSpec
    from itg_vision.world import World

    cam = Rig.from_yaml(ROOT / "cameras" / "planar.yaml").cameras[1]
    with World(ArmSpec.from_args("one-link")) as world:
        img = capture(world, cam, np.random.default_rng(0), supersample=1)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    assert np.median(img) > 150  # light background everywhere, corners included
    assert img[:5, :5].mean() > 150 and img[-5:, -5:].mean() > 150


# ---------------------------------------------------- the windows' sensor noise (closed form)
from itg_vision.arm import ArmSpec  # noqa: E402
from itg_vision.imaging import FLAT_LIGHT, capture_window  # noqa: E402
from itg_vision.world import World  # noqa: E402

PLANAR = ROOT / "cameras" / "planar.yaml"


def test_window_pixels_carry_the_cameras_sensor_noise():
    """capture_window with the run's generator against the same window without one. The
    background renders at 255, so the sensor's N(0, sigma^2) grey-level noise, rounded and
    clipped at 255, leaves a pixel below 255 with probability Phi(-0.5 / sigma) (0.40 at the
    rig's 2 grey levels) and moves it by sum_{k<=-1} k P(round(n) = k) on average (closed
    forms of the camera's noise model). 60 x 60 x 3 samples: the fraction's standard error is
    0.005; bounds 0.03 and 0.05 grey levels."""
    from statistics import NormalDist

    rig = Rig.from_yaml(PLANAR)
    cam = rig.cameras[0]
    sigma = cam.noise_sigma_gray
    assert sigma > 0
    with World(ArmSpec.from_args("two-link")) as world:
        box = (20, 20, 80, 80)  # a corner of the frame: background only
        noisy = capture_window(world, cam, np.random.default_rng(0), box, supersample=3,
                               lighting=FLAT_LIGHT)
        clean = capture_window(world, cam, None, box, supersample=3, lighting=FLAT_LIGHT)
    assert np.all(clean.image == 255)
    d = noisy.image.astype(float) - 255.0
    N = NormalDist(0.0, sigma)
    frac = N.cdf(-0.5)
    mean = sum(k * (N.cdf(k + 0.5) - N.cdf(k - 0.5)) for k in range(-int(10 * sigma) - 1, 0))
    assert abs(np.mean(d < 0) - frac) < 0.03, (np.mean(d < 0), frac)
    assert abs(d.mean() - mean) < 0.05, (d.mean(), mean)


class _NoRender:
    """A world that must not be asked to render."""

    def render(self, *args, **kwargs):
        raise AssertionError("rendered")


def test_a_whole_frame_beyond_the_image_limit_is_refused_before_it_is_rendered(cam):
    """A whole frame renders supersample x (image + lens margin) each way, about
    BYTES_PER_PIXEL bytes per rendered pixel: capture refuses one over MAX_IMAGE_PIXELS (the rig
    files' limit on an image) before rendering, naming the camera, the rendered size and the
    largest supersample that fits; that one fits and the next does not (the shipped 640 x 480
    camera with its 24 px lens margin: 6 fits, 7 renders 4816 x 3696 px)."""
    from itg_vision.camera import MAX_IMAGE_PIXELS
    from itg_vision.errors import UserError
    from itg_vision.imaging import check_whole_frame

    def pixels(s):
        plan = render_plan(cam, s)
        return plan.width * plan.height

    fits = max(s for s in range(1, 9) if pixels(s) <= MAX_IMAGE_PIXELS)
    assert pixels(fits + 1) > MAX_IMAGE_PIXELS
    check_whole_frame(cam, fits)
    plan = render_plan(cam, fits + 1)
    with pytest.raises(UserError) as exc:
        capture(_NoRender(), cam, None, supersample=fits + 1)
    msg = str(exc.value)
    assert f"camera {cam.name!r}" in msg and f"{plan.width} x {plan.height} px" in msg
    assert f"supersample {fits} at most" in msg and "\n" not in msg


def test_calibration_refuses_a_rig_whose_frames_are_too_large_before_rendering_a_view(cam):
    """The calibration's board views are whole frames at supersample 2: a 2900 x 2900 camera
    (8.4 Mpx, within the rig files' limit) renders 5800 x 5800 and more, refused before a view."""
    import dataclasses

    from itg_vision.board import Board, render_views
    from itg_vision.errors import UserError

    big = dataclasses.replace(cam, image_width=2900, image_height=2900, cx=1450.0, cy=1450.0,
                              dist=(0.0,) * 5)
    rig = Rig("big", (big, big))
    with pytest.raises(UserError, match="supersample 2 renders 5800 x 5800 px"):
        render_views(_NoRender(), rig, Board(), [], None, supersample=2)


def test_a_calibration_too_large_to_render_names_the_rig_file_and_the_image_that_fits(cam):
    """The calibration cannot change its supersample (2, no option): its refusal names the rig
    file and the camera's place in it, and the largest image that fits, MAX_IMAGE_PIXELS / 2^2
    = 4.2 Mpx with the lens margin (a 4096 x 3072 camera without distortion, margin 0: 12.6
    Mpx). It named the camera alone and said 'supersample 1 at most', which calibrate cannot
    be asked for."""
    import dataclasses

    from itg_vision.board import Board, render_views
    from itg_vision.errors import UserError

    big = dataclasses.replace(cam, name="wide", image_width=4096, image_height=3072, cx=2047.5,
                              cy=1535.5, dist=(0.0,) * 5)
    rig = Rig("big", (cam, big), source="rigs/big.yaml")
    with pytest.raises(UserError) as exc:
        render_views(_NoRender(), rig, Board(), [], None, supersample=2)
    assert str(exc.value) == (
        "rigs/big.yaml: cameras[1] (wide): a whole frame at supersample 2 renders 8192 x 6144 px, "
        "about 3.02 GB; the limit is 16.8 Mpx rendered: the calibration's board views render at "
        "supersample 2, so the image with its lens margin must be at most 4.2 Mpx (this one is "
        "12.6)")
