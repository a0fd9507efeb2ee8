"""From a rendered pinhole image to what the camera sees: lens distortion and sensor noise.

PyBullet renders a pinhole image. :func:`capture` renders it slightly larger than the camera's
frame (a margin on every side, same focal length) so that barrel distortion has data for the
output corners, optionally at ``supersample`` times the resolution (then area-averaged, which
anti-aliases the LED edges), warps it with the camera's distortion through a remap table
computed once per camera, then applies the exposure gain and Gaussian grey-level noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import cv2
import numpy as np

from .camera import UNDISTORT_CRITERIA, Camera, gl_projection_matrix


@dataclass(frozen=True)
class RenderPlan:
    """How to render one camera: the enlarged pinhole frame and the distortion maps.

    Attributes
    ----------
    margin_px : int, extra pinhole pixels on every side of the camera's frame.
    supersample : int, render-resolution factor.
    width, height : int, size of the rendered (supersampled, enlarged) image.
    K_render : ndarray (3, 3), intrinsics of the rendered image.
    view_gl, proj_gl : ndarray (16,), OpenGL matrices for ``World.render``.
    map1, map2 : remap tables (fixed point) from the camera frame into the enlarged pinhole
        image at 1x; ``None`` if the camera has no distortion.
    """

    margin_px: int
    supersample: int
    width: int
    height: int
    K_render: np.ndarray
    view_gl: np.ndarray
    proj_gl: np.ndarray
    map1: np.ndarray | None
    map2: np.ndarray | None


def distortion_source_map(camera: Camera) -> np.ndarray:
    """Pinhole source pixel of every distorted output pixel.

    Returns
    -------
    src : ndarray, shape (H, W, 2), float32; ``src[j, i]`` is the (u, v) in the undistorted
        (pinhole) image, same K, whose light lands on distorted pixel (i, j).
    """
    W, H = camera.size
    grid = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 1, 2)
    src = cv2.undistortPoints(grid.astype(np.float64), camera.K, camera.dist_coeffs, None,
                              camera.K, criteria=UNDISTORT_CRITERIA)
    return src.reshape(H, W, 2).astype(np.float32)


@lru_cache(maxsize=32)
def render_plan(camera: Camera, supersample: int = 2, near_m: float = 0.05,
                far_m: float = 5.0) -> RenderPlan:
    """The cached rendering recipe of a camera (remap tables are computed once)."""
    s = int(supersample)
    W, H = camera.size
    if any(camera.dist):
        src = distortion_source_map(camera)
        over = max(0.0, -float(src[..., 0].min()), float(src[..., 0].max()) - (W - 1),
                   -float(src[..., 1].min()), float(src[..., 1].max()) - (H - 1))
        margin = int(np.ceil(over)) + 2  # +2: bilinear neighbours stay inside rendered data
        map1, map2 = cv2.convertMaps(src + margin, None, cv2.CV_16SC2)
    else:
        margin, map1, map2 = 0, None, None
    Wr, Hr = s * (W + 2 * margin), s * (H + 2 * margin)
    # Pixel i of the 1x image is the mean of pixels s*i .. s*i+s-1 of the render, whose centre
    # is s*i + (s-1)/2: hence the principal point below.
    K = camera.K.copy()
    K[0, 0] *= s
    K[1, 1] *= s
    K[0, 2] = s * (camera.cx + margin) + (s - 1) / 2
    K[1, 2] = s * (camera.cy + margin) + (s - 1) / 2
    proj = gl_projection_matrix(K, Wr, Hr, near_m, far_m)
    return RenderPlan(margin, s, Wr, Hr, K, camera.gl_view(), proj, map1, map2)


def render_pinhole(world, camera: Camera, supersample: int = 2) -> np.ndarray:
    """Render the enlarged pinhole image at 1x.

    Returns
    -------
    image : uint8, shape (H + 2 m, W + 2 m, 3), m = ``render_plan(camera).margin_px``.
    """
    plan = render_plan(camera, supersample)
    img = world.render(plan.width, plan.height, plan.view_gl, plan.proj_gl)
    if plan.supersample > 1:
        W, H = camera.size
        size = (W + 2 * plan.margin_px, H + 2 * plan.margin_px)
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    return img


def distort(pinhole: np.ndarray, camera: Camera, supersample: int = 2) -> np.ndarray:
    """Warp an enlarged pinhole image (from :func:`render_pinhole`) into the camera's frame.

    Returns
    -------
    image : same dtype, shape (H, W, 3).
    """
    plan = render_plan(camera, supersample)
    if plan.map1 is None:
        m = plan.margin_px
        return pinhole[m:pinhole.shape[0] - m, m:pinhole.shape[1] - m]
    return cv2.remap(pinhole, plan.map1, plan.map2, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


@lru_cache(maxsize=8)
def _gaussian_table(sigma_gray: float) -> np.ndarray:
    """Quantiles of N(0, sigma^2) at the 65536 mid-points, float32 (inverse-CDF sampling)."""
    q = (np.arange(65536) + 0.5) / 65536
    z = np.array([NormalDist().inv_cdf(float(x)) for x in q])
    return (sigma_gray * z).astype(np.float32)


def gaussian_noise(shape, sigma_gray: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise (float32, std ``sigma_gray``) drawn from ``rng`` by inverse-CDF lookup.

    Two random bytes per value index a table of 65536 quantiles: a Gaussian truncated at
    4.3 sigma, about 2x faster than ``rng.standard_normal`` for a full frame.
    """
    return _draw(_gaussian_table(float(sigma_gray)), shape, rng)


def _draw(table: np.ndarray, shape, rng: np.random.Generator) -> np.ndarray:
    """Values of a 65536-entry table at two random bytes per value, shape ``shape``."""
    idx = np.frombuffer(rng.bytes(2 * int(np.prod(shape))), dtype=np.uint16)
    return table[idx].reshape(shape)


def add_sensor_noise(image: np.ndarray, camera: Camera,
                     rng: np.random.Generator | None) -> np.ndarray:
    """Exposure gain and Gaussian grey-level noise (std ``camera.noise_sigma_gray``), uint8.

    Parameters
    ----------
    image : uint8, shape (H, W, 3)
    camera : supplies ``exposure`` and ``noise_sigma_gray``.
    rng : the run's generator; ``None`` applies the exposure only (no noise).
    """
    noisy = rng is not None and camera.noise_sigma_gray > 0
    if not noisy and camera.exposure == 1.0:
        return image
    if camera.exposure == 1.0:
        # Integer path (2x faster): rounding the noise first equals rounding the sum, as the
        # image is integer.
        out = image.astype(np.int16)
        out += _rounded_noise(out.shape, camera.noise_sigma_gray, rng)
        np.clip(out, 0, 255, out=out)
        return out.astype(np.uint8)
    out = image.astype(np.float32) * np.float32(camera.exposure)
    if noisy:
        out += gaussian_noise(out.shape, camera.noise_sigma_gray, rng)
    np.clip(out, 0, 255, out=out)
    return np.rint(out).astype(np.uint8)


def _rounded_noise(shape, sigma_gray: float, rng: np.random.Generator) -> np.ndarray:
    """`gaussian_noise` rounded to integers, int16."""
    return _draw(_rounded_table(float(sigma_gray)), shape, rng)


@lru_cache(maxsize=8)
def _rounded_table(sigma_gray: float) -> np.ndarray:
    return np.rint(_gaussian_table(sigma_gray)).astype(np.int16)


def capture(world, camera: Camera, rng: np.random.Generator | None, *,
            supersample: int = 2) -> np.ndarray:
    """What the camera sees: render, distort, expose and add noise.

    Parameters
    ----------
    world : `itg_vision.world.World` (anything with ``render(width, height, view, proj)``).
    camera : the camera to render.
    rng : generator for the sensor noise; ``None`` for a noise-free image (exposure only).
    supersample : render at this factor and area-average down (1 = off).

    Returns
    -------
    image : uint8, shape (camera.image_height, camera.image_width, 3), RGB.
    """
    img = distort(render_pinhole(world, camera, supersample), camera, supersample)
    return add_sensor_noise(img, camera, rng)
