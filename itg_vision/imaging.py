"""From a rendered pinhole image to what the camera sees: lens distortion and sensor noise.

PyBullet renders a pinhole image. :func:`capture` renders it slightly larger than the camera's
frame (a margin on every side, same focal length) so that barrel distortion has data for the
output corners, optionally at ``supersample`` times the resolution (then area-averaged, which
anti-aliases the LED edges), warps it with the camera's distortion through a remap table
computed once per camera, then applies the exposure gain and Gaussian grey-level noise. With
``lens_first=True`` (the vision path) the lens acts on the supersampled render and the sensor
averages after it (:func:`lens_maps`), which keeps the anti-aliased edges sharp.

:func:`capture_window` does the same for a small window of the frame (a :class:`Patch`): the
renderer draws only the s-fold pinhole pixels the window's lens map reads, with
K' = [[s fx, 0, s (cx - x0) + (s - 1) / 2], [0, s fy, s (cy - y0) + (s - 1) / 2], [0, 0, 1]]
for a pinhole region whose top-left (1x) coordinate is (x0, y0) (through the usual
K-to-projection conversion, with TinyRenderer's +1 on cy); then the window's own s-fold lens
map (:func:`window_lens_maps`, its integer part shifted by the region's origin), the s x s
average and noise on the window only. Its pixels are the frame's (``capture(..., lens_first=True)``), tested at s = 1..3.
TinyRenderer's cost is ~75 us per call plus ~0.1 us per pixel drawn, so four ~15 px windows at
s = 3 cost a twentieth of one 640x480 frame.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import cv2
import numpy as np

from .camera import (BYTES_PER_PIXEL, MAX_IMAGE_PIXELS, UNDISTORT_CRITERIA, Camera,
                     gl_projection_matrix)
from .errors import UserError


#: Lighting of the vision path: the LEDs drawn flat (ambient 1, diffuse 0, no specular), as an
#: emitter looks. A lit sphere's intensity centroid leans 0.2-0.3 px toward the light.
FLAT_LIGHT = {"ambient": 1.0, "diffuse": 0.0}
#: Near and far planes (m) of every render.
NEAR_M, FAR_M = 0.05, 5.0


@dataclass(frozen=True)
class Patch:
    """A captured image, or a window of one, as the camera sees it.

    Attributes
    ----------
    image : uint8, shape (h, w, 3), RGB.
    origin_px : (x0, y0), the camera-frame pixel of ``image[0, 0]``.
    frame_size : (W, H) of the camera's full frame.
    """

    image: np.ndarray
    origin_px: tuple[int, int]
    frame_size: tuple[int, int]

    @property
    def full_frame(self) -> bool:
        return self.origin_px == (0, 0) and self.image.shape[1::-1] == self.frame_size

    def at_frame_edge(self) -> tuple[bool, bool, bool, bool]:
        """Whether the window's left, top, right, bottom sides are the frame's."""
        (x0, y0), (W, H) = self.origin_px, self.frame_size
        h, w = self.image.shape[:2]
        return x0 == 0, y0 == 0, x0 + w == W, y0 + h == H


@contextmanager
def opencv_threads(n: int = 1):
    """Run OpenCV with ``n`` threads inside the block (the vision loop: its small images gain
    nothing from threads, which cost ~5.6 ms of CPU per frame on 2 cores), then restore."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)


@dataclass(frozen=True)
class RenderPlan:
    """How to render one camera: the enlarged pinhole frame and the distortion maps.

    Attributes
    ----------
    margin_px : int, extra pinhole pixels on every side of the camera's frame.
    supersample : int, render-resolution factor.
    width, height : int, size of the rendered (supersampled, enlarged) image.
    view_gl, proj_gl : ndarray (16,), OpenGL matrices for ``World.render``.
    map1, map2 : remap tables (fixed point) from the camera frame into the enlarged pinhole
        image at 1x; ``None`` if the camera has no distortion.
    """

    margin_px: int
    supersample: int
    width: int
    height: int
    view_gl: np.ndarray
    proj_gl: np.ndarray
    map1: np.ndarray | None
    map2: np.ndarray | None


@lru_cache(maxsize=16)
def distortion_source_map(camera: Camera) -> np.ndarray:
    """Pinhole source pixel of every distorted output pixel (cached, read-only).

    Returns
    -------
    src : ndarray, shape (H, W, 2), float32; ``src[j, i]`` is the (u, v) in the undistorted
        (pinhole) image, same K, whose light lands on distorted pixel (i, j).
    """
    W, H = camera.size
    grid = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 1, 2)
    src = cv2.undistortPoints(grid.astype(np.float64), camera.K, camera.dist_coeffs, None,
                              camera.K, criteria=UNDISTORT_CRITERIA)
    src = src.reshape(H, W, 2).astype(np.float32)
    src.flags.writeable = False
    return src


@lru_cache(maxsize=16)
def lens_maps(camera: Camera, supersample: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Remap tables (fixed point) of the lens at ``supersample``: from each sub-pixel of the
    s-fold output frame into the s-fold enlarged pinhole render of :func:`render_plan`; None
    without distortion.

    The lens acts on the optical image, before the sensor integrates it over its pixels: the
    vision path distorts the supersampled render, then area-averages (distorting after the
    average blurs the anti-aliased edge once more and costs ~0.02 px of centroid accuracy).
    Sub-pixel j of the s-fold frame sits at 1x coordinate (j - (s - 1) / 2) / s, which is
    exactly where ``cv2.resize(..., INTER_LINEAR)`` samples the smooth 1x source map (the
    outermost half pixel of the frame is clamped).
    """
    s = int(supersample)
    plan = render_plan(camera, s)
    if plan.map1 is None:
        return None
    src = distortion_source_map(camera)
    if s > 1:
        W, H = camera.size
        src = cv2.resize(src, (s * W, s * H), interpolation=cv2.INTER_LINEAR)
    src = s * (src + plan.margin_px) + (s - 1) / 2
    m1, m2 = cv2.convertMaps(src.astype(np.float32), None, cv2.CV_16SC2)
    m1.flags.writeable = False
    m2.flags.writeable = False
    return m1, m2


@lru_cache(maxsize=32)
def render_plan(camera: Camera, supersample: int = 2, near_m: float = NEAR_M,
                far_m: float = FAR_M) -> RenderPlan:
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
    return RenderPlan(margin, s, Wr, Hr, camera.gl_view(), proj, map1, map2)


def render_pinhole(world, camera: Camera, supersample: int = 2, lighting=None) -> np.ndarray:
    """Render the enlarged pinhole image at 1x.

    ``lighting``: keyword arguments of ``world.render`` (e.g. :data:`FLAT_LIGHT`); None for
    the world's default (lit) shading.

    Returns
    -------
    image : uint8, shape (H + 2 m, W + 2 m, 3), m = ``render_plan(camera).margin_px``.
    """
    plan = render_plan(camera, supersample)
    img = world.render(plan.width, plan.height, plan.view_gl, plan.proj_gl, **(lighting or {}))
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
    idx = np.frombuffer(rng.bytes(2 * math.prod(shape)), dtype=np.uint16)
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


def check_whole_frame(camera: Camera, supersample: int, hint: str = "", *, who: str = "",
                      fixed: str = "") -> None:
    """Refuse a whole frame whose render (``supersample`` times the image and its lens margin,
    each way) exceeds :data:`~itg_vision.camera.MAX_IMAGE_PIXELS`, the rig files' limit on an
    image: a frame costs about :data:`~itg_vision.camera.BYTES_PER_PIXEL` per rendered pixel,
    so a 2048 x 1536 camera at supersample 3 (6144 x 4608 rendered) would take about 2 GB.

    Raises
    ------
    UserError : naming the camera (``who``, default its name), the rendered size, the memory,
        the largest supersample that fits, and ``hint`` (another way out, where the caller has
        one); where the caller's supersample cannot be changed (``fixed``: what renders at it),
        the largest image that fits instead.
    """
    plan = render_plan(camera, supersample)
    if plan.width * plan.height <= MAX_IMAGE_PIXELS:
        return
    per_s = plan.width * plan.height / plan.supersample ** 2  # pixels at supersample 1
    fits = int(math.isqrt(int(MAX_IMAGE_PIXELS // per_s)))
    way = f"supersample {fits} at most" if fits >= 1 else "a smaller image (no supersample fits)"
    if fixed:
        way = (f"{fixed} render at supersample {plan.supersample}, so the image with its lens "
               f"margin must be at most {MAX_IMAGE_PIXELS / plan.supersample ** 2 / 1e6:.1f} Mpx "
               f"(this one is {per_s / 1e6:.1f})")
    who = who or f"camera {camera.name!r}"
    raise UserError(f"{who}: a whole frame at supersample {plan.supersample} "
                    f"renders {plan.width} x {plan.height} px, about "
                    f"{plan.width * plan.height * BYTES_PER_PIXEL / 1e9:.3g} GB; the limit is "
                    f"{MAX_IMAGE_PIXELS / 1e6:.1f} Mpx rendered: {way}{hint}")


def capture(world, camera: Camera, rng: np.random.Generator | None, *,
            supersample: int = 2, lighting=None, lens_first: bool = False) -> np.ndarray:
    """What the camera sees: render, distort, expose and add noise.

    Parameters
    ----------
    world : `itg_vision.world.World` (anything with ``render(width, height, view, proj)``).
    camera : the camera to render.
    rng : generator for the sensor noise; ``None`` for a noise-free image (exposure only).
    supersample : render at this factor and area-average down (1 = off).
    lighting : keyword arguments of ``world.render`` (:data:`FLAT_LIGHT` for the vision path);
        None for the world's default shading.
    lens_first : distort the supersampled render, then area-average (:func:`lens_maps`; the
        vision path, and what :func:`capture_window` does); False: area-average, then
        distort at 1x (the calibration images' historical order).

    Returns
    -------
    image : uint8, shape (camera.image_height, camera.image_width, 3), RGB.
    """
    check_whole_frame(camera, supersample)
    maps = lens_maps(camera, supersample) if lens_first and supersample > 1 else None
    if maps is None:
        img = distort(render_pinhole(world, camera, supersample, lighting), camera, supersample)
        return add_sensor_noise(img, camera, rng)
    plan = render_plan(camera, supersample)
    img = world.render(plan.width, plan.height, plan.view_gl, plan.proj_gl, **(lighting or {}))
    img = cv2.remap(img, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    img = cv2.resize(img, camera.size, interpolation=cv2.INTER_AREA)
    return add_sensor_noise(img, camera, rng)


# ---------------------------------------------------------------------------- windows
#: The 16 directions around a silhouette's rim that :func:`led_windows` projects.
_RIM_ANGLES = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
_RIM_COS, _RIM_SIN = np.cos(_RIM_ANGLES), np.sin(_RIM_ANGLES)
#: The y and x axes (one row each), and no rotation or translation (cv2.projectPoints in the
#: camera's frame): made once, not at every call.
_Y_AXIS, _X_AXIS, _ZERO3 = np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), np.zeros(3)


def _norms(v: np.ndarray) -> np.ndarray:
    """Row lengths of (n, 3): ``np.linalg.norm(v, axis=1)``'s arithmetic, without its cost on
    a few rows (the same floats)."""
    return np.sqrt(np.add.reduce(v * v, axis=1))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (n, 3) arrays: ``np.cross``'s arithmetic (the same floats),
    a fifth of its cost on a few rows (it spends it moving axes)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def led_windows(camera: Camera, centres_mm, radius_mm: float, margin_px: int = 2
                ) -> list[tuple[int, int, int, int] | None]:
    """The windows of the camera's frame that hold spheres' images, ``margin_px`` px around
    each: per sphere (x0, y0, x1, y1), end exclusive, clipped to the frame; None for a sphere
    behind the camera, nearer than the near plane or entirely outside the frame.

    Each is the bounding box of 16 points of the sphere's silhouette cone (its radius at the
    centre's range is r D / sqrt(D^2 - r^2)), projected through the lens distortion.

    Parameters
    ----------
    centres_mm : array-like, shape (n, 3), world frame.
    """
    Xc = camera.to_camera(np.asarray(centres_mm, float).reshape(-1, 3))
    D = _norms(Xc)
    ok = (Xc[:, 2] - radius_mm > 1e3 * NEAR_M) & (D > radius_mm)
    ray = Xc / np.where(ok, D, 1.0)[:, None]
    # two unit vectors across each ray: ray x (y or x axis), then ray x that
    pick = np.where(np.abs(ray[:, 1:2]) < 0.9, _Y_AXIS, _X_AXIS)
    e1 = _cross(ray, pick)
    e1 /= _norms(e1)[:, None]
    e2 = _cross(ray, e1)
    rho = radius_mm * D / np.sqrt(np.where(ok, D * D - radius_mm**2, 1.0))
    rim = (Xc[:, None] + rho[:, None, None] * (_RIM_COS[None, :, None] * e1[:, None]
                                               + _RIM_SIN[None, :, None] * e2[:, None]))
    uv, _ = cv2.projectPoints(rim.reshape(-1, 3), _ZERO3, _ZERO3, camera.K, camera.dist_coeffs)
    uv = np.floor(uv.reshape(-1, 16, 2) + 0.5)  # the pixels holding the rim points
    uv[~ok] = 0.0  # a sphere behind the camera has no image: its rim projects to NaN
    lo = (uv.min(axis=1).astype(int) - margin_px).tolist()
    hi = (uv.max(axis=1).astype(int) + margin_px + 1).tolist()
    W, H = camera.size
    out = []
    for (u0, v0), (u1, v1), seen in zip(lo, hi, ok.tolist()):
        x0, y0, x1, y1 = max(u0, 0), max(v0, 0), min(u1, W), min(v1, H)
        out.append((x0, y0, x1, y1) if seen and x1 - x0 >= 3 and y1 - y0 >= 3 else None)
    return out


def window_lens_maps(camera: Camera, supersample: int, box) -> tuple[np.ndarray, np.ndarray]:
    """The part of :func:`lens_maps` over the window ``box`` = (x0, y0, x1, y1), computed
    for the window alone: the 1x source map around it (one pixel more each side, clamped at
    the frame's edges as ``cv2.resize`` clamps), resampled at s-fold, cropped. The same
    numbers as slicing the whole frame's tables, without making them (~0.3 s per camera at
    s = 3, paid again by every perturbed rig of a sweep). Shapes (s h, s w, 2) and (s h, s w).
    """
    x0, y0, x1, y1 = box
    s = int(supersample)
    src = distortion_source_map(camera)
    if s == 1:
        part = src[y0:y1, x0:x1]
    else:
        H, W = src.shape[:2]
        if 0 < x0 and 0 < y0 and x1 < W and y1 < H:  # inside: a slice (no copy) does
            near = src[y0 - 1:y1 + 1, x0 - 1:x1 + 1]
        else:
            ys = np.clip(np.arange(y0 - 1, y1 + 1), 0, H - 1)
            xs = np.clip(np.arange(x0 - 1, x1 + 1), 0, W - 1)
            near = src[ys[:, None], xs[None, :]]
        part = cv2.resize(near, (s * (x1 - x0 + 2), s * (y1 - y0 + 2)),
                          interpolation=cv2.INTER_LINEAR)[s:-s, s:-s]
    part = s * (part + render_plan(camera, s).margin_px) + (s - 1) / 2  # float32 stays float32
    return cv2.convertMaps(np.asarray(part, np.float32), None, cv2.CV_16SC2)


def window_intrinsics(camera: Camera, x0: float, y0: float, supersample: int) -> np.ndarray:
    """K' of the pinhole region whose top-left pixel is (x0, y0) (1x pixels, possibly a
    fraction: a region starting mid-pixel at s-fold resolution), drawn at ``supersample``:
    pixel i of the 1x region is the mean of render pixels s i .. s i + s - 1, centred at
    s i + (s - 1) / 2, and is pixel x0 + i of the camera. Shape (3, 3)."""
    s = int(supersample)
    K = camera.K.copy()
    K[0, 0] *= s
    K[1, 1] *= s
    K[0, 2] = s * (camera.cx - x0) + (s - 1) / 2
    K[1, 2] = s * (camera.cy - y0) + (s - 1) / 2
    return K


def capture_window(world, camera: Camera, rng: np.random.Generator | None,
                   box: tuple[int, int, int, int], *, supersample: int = 2,
                   lighting=None) -> Patch:
    """What the camera sees in the window ``box`` = (x0, y0, x1, y1) of its frame (end
    exclusive): the same pixels as ``capture(..., lens_first=True)``'s frame there (up to the
    sensor noise, drawn for the window only). See the module docstring.

    The renderer draws the s-fold pinhole pixels that the window's lens map
    (:func:`window_lens_maps`) reads (bilinear: the integer parts and one more), that map
    shifted by the region's origin distorts them, then s x s blocks are averaged.
    """
    x0, y0, x1, y1 = box
    s = int(supersample)
    plan = render_plan(camera, s)
    maps = None if plan.map1 is None else window_lens_maps(camera, s, box)
    if maps is None:  # no lens: the window at s-fold is the pinhole region itself
        a, b, A, B = s * x0, s * y0, s * (x1 - x0), s * (y1 - y0)
        m = 0
    else:
        m = plan.margin_px
        map1 = maps[0]
        a, b = int(map1[..., 0].min()), int(map1[..., 1].min())
        A, B = int(map1[..., 0].max()) - a + 2, int(map1[..., 1].max()) - b + 2
    # render pixel (a, b) of the s-fold enlarged image is 1x pinhole coordinate
    # (a - (s - 1) / 2) / s - m at its centre; as a region origin: (a / s) - m
    K = window_intrinsics(camera, a / s - m, b / s - m, s)
    img = world.render(A, B, plan.view_gl, gl_projection_matrix(K, A, B, NEAR_M, FAR_M),
                       **(lighting or {}))
    if maps is not None:
        shift = np.array([a, b], np.int16)
        img = cv2.remap(img, map1 - shift, maps[1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
    if s > 1:
        img = cv2.resize(img, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    return Patch(add_sensor_noise(img, camera, rng), (x0, y0), camera.size)
