"""LED centroids in a camera image, to sub-pixel accuracy.

Each LED has a saturated colour with one dominant channel (red, green, ...). Its score image is
that channel minus the largest other channel (``R - max(G, B)`` for red), clipped at 0: the
light background and the grey arm score about 0, the LED about its brightness. The blob is the
connected component above a low threshold; its centroid is weighted by the score clipped at
0.7 of the blob's peak ("coverage" weights: interior pixels count about equally whatever the
shading, edge pixels by the fraction of the LED they hold, which anti-aliasing encodes).
Measured on rendered LEDs at 640x480 (60 detections, sensor noise 2 grey levels), RMS error
against the projection: coverage 0.155 px (supersample 1) / 0.128 px (supersample 2); clip
at 0.5 peak 0.18 / 0.13; binary mask 0.22 / 0.17; raw intensity weights 0.23 / 0.21 (biased
~0.1 px by the shading). Hence coverage with clip 0.7 for lit LEDs (find_led's default).

The vision loop draws its LEDs flat (:data:`itg_vision.imaging.FLAT_LIGHT`), as an emitter
looks; with no shading the plain intensity weights are unbiased: ``method="intensity"``
weights every pixel of the blob's neighbourhood by its score, above :data:`WEIGHT_FLOOR` (the
sensor noise of the background). Flat LED, intensity weights: 0.087 px RMS at supersample 1,
0.034 at 2, 0.019 at 3 (TECHNICAL.md). :func:`locate_led` finds an LED in a window of the frame
(an :class:`itg_vision.imaging.Patch`) and leaves undistortion to the caller (one batched
``cv2.undistortPoints`` per camera).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from .camera import Camera
from .imaging import Patch

#: Lowest score (grey levels) counted as LED: well above sensor noise (a few grey levels).
MIN_SCORE = 40
#: A blob smaller than this (px) is noise, not an LED.
MIN_AREA_PX = 3.0
#: Coverage weights saturate at this fraction of the blob's peak score (see module doc).
COVERAGE_CLIP = 0.7
#: Least roundness (minor/major axis ratio of the half-peak mask) of an LED's blob: a rounder
#: one is an LED, a less round one partly hidden (by its link, the other LED, the frame).
MIN_ROUNDNESS = 0.75
#: Half-size of the search window around a predicted position (px).
HALF_WINDOW_PX = 24
#: Intensity weights count scores from this level (grey levels): 4 sigma of a background
#: pixel's score under 2 grey levels of sensor noise, ~4 % of a flat LED's 255.
WEIGHT_FLOOR = 8


#: Why a detection failed: :attr:`Detection.cause`, a fixed phrase code can branch on (its
#: ``reason`` may add the measured value).
NOT_FOUND, TOO_SMALL, SEVERAL = "not found", "too small", "several candidates"
WINDOW_BORDER, IMAGE_BORDER, NOT_ROUND = ("touches the window border", "at the image border",
                                          "not round")
_BORDER = "touches the border"  # blob_centroid's, before locate_led tells which border


@dataclass(frozen=True)
class Detection:
    """One LED in one image.

    Attributes
    ----------
    ok : whether the LED was found and passed the checks.
    uv_px : ndarray (2,), undistorted (pinhole) centroid; NaN if not ok.
    uv_raw_px : ndarray (2,), centroid in the captured (distorted) image; NaN if none.
    area_px : float, blob area (px) at the half-peak level (0 if none).
    reason : why it was rejected, for people ("" if ok): its cause, perhaps with the value.
    cause : why it was rejected, one of a fixed set of phrases (this module's ``NOT_FOUND``
        ..., and ``itg_vision.feedback``'s ``OUTSIDE``, ``DROPPED``); "" if ok.
    """

    ok: bool
    uv_px: np.ndarray
    uv_raw_px: np.ndarray
    area_px: float = 0.0
    reason: str = ""
    cause: str = ""


def _nan2() -> np.ndarray:
    return np.full(2, np.nan)


def score_image(image: np.ndarray, rgb) -> np.ndarray:
    """Colour-difference score: dominant channel minus the largest other, clipped at 0.

    Parameters
    ----------
    image : uint8, shape (H, W, 3), RGB.
    rgb : the LED colour, 3 floats in [0, 1] with one dominant channel.

    Returns
    -------
    score : uint8, shape (H, W).
    """
    c = max(range(3), key=lambda i: rgb[i])  # the first largest, as np.argmax
    planes = cv2.split(image)  # contiguous planes: one call, not three strided copies
    o1, o2 = (planes[i] for i in range(3) if i != c)
    return cv2.subtract(planes[c], cv2.max(o1, o2))


def blob_centroid(score: np.ndarray, method: str = "coverage", aspect: float = 1.0
                  ) -> tuple[np.ndarray, float, float, str]:
    """Find the single LED blob in a score image and its sub-pixel centroid.

    Parameters
    ----------
    score : uint8, shape (h, w).
    method : "coverage" (weights min(score, 0.7 peak)), "binary" (mask at peak/2) or
        "intensity" (weights = score, from :data:`WEIGHT_FLOOR`).
    aspect : the camera's fy / fx: a pixel's height over its width in the scene, by which a
        round LED's image is stretched along v (its roundness is judged with it undone).

    Returns
    -------
    uv : ndarray (2,), centroid in the coordinates of ``score`` (NaN if none).
    area_px : float, pixels at or above half the peak.
    roundness : float, minor/major axis ratio of that half-peak mask, v scaled by 1 / aspect
        (1 for a disc seen by any camera).
    reason : "" if a single blob was found, else why not.
    """
    mask = (score >= MIN_SCORE).view(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return _nan2(), 0.0, 0.0, NOT_FOUND
    areas = stats[1:, cv2.CC_STAT_AREA].tolist()  # Python ints from here: no numpy scalars
    biggest = max(areas)
    best = areas.index(biggest) + 1  # the first largest, as np.argmax
    if biggest < MIN_AREA_PX:
        return _nan2(), float(biggest), 0.0, TOO_SMALL
    if n > 2 and sorted(areas)[-2] >= max(MIN_AREA_PX, 0.2 * biggest):
        return _nan2(), float(biggest), 0.0, SEVERAL
    x, y, w, h = stats[best, :4].tolist()
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    x1, y1 = min(x + w + 1, score.shape[1]), min(y + h + 1, score.shape[0])
    s = score[y0:y1, x0:x1].astype(np.float32)
    lab = labels[y0:y1, x0:x1]
    if method == "intensity":  # other blobs out; the rim below MIN_SCORE stays
        if n > 2:
            s[(lab != best) & (lab != 0)] = 0
    else:  # coverage and binary count the blob's own pixels only (find_led's default)
        s[lab != best] = 0
    peak = float(s.max())
    core = (s >= 0.5 * peak).view(np.uint8)
    if method == "binary":
        wgt = core.astype(np.float32)
    elif method == "intensity":
        wgt = np.where(s >= WEIGHT_FLOOR, s, np.float32(0))
    else:
        wgt = np.minimum(s, COVERAGE_CLIP * peak)
    m = _moments(wgt)
    uv = np.array([m["m10"] / m["m00"] + x0, m["m01"] / m["m00"] + y0])
    mc = cv2.moments(core, binaryImage=True)
    area = float(mc["m00"])
    rnd = _roundness(mc, aspect)
    if x == 0 or y == 0 or x + w >= score.shape[1] or y + h >= score.shape[0]:
        return uv, area, rnd, _BORDER
    return uv, area, rnd, ""


def _moments(weights: np.ndarray) -> dict:
    """``cv2.moments`` of a float image. OpenCV takes a float array two columns wide for a list
    of points (a contour), not an image: such a crop (a one-pixel-wide sliver cut by the frame
    or the window) gets a zero column on its right, which adds no mass and moves no moment."""
    if weights.shape[1] == 2:
        weights = np.pad(weights, ((0, 0), (0, 1)))
    return cv2.moments(weights)


def _roundness(m: dict, aspect: float = 1.0) -> float:
    """Minor/major axis ratio of a pixel set's second moments (1 for a disc), from its
    ``cv2.moments``; each pixel's own extent (1/12 px^2 per axis) included; v divided by
    ``aspect`` (fy / fx: with non-square pixels a sphere images as an ellipse of that ratio)."""
    n = m["m00"]
    if n < 3:
        return 0.0
    # the sample covariance (n - 1), as np.cov
    a, b, c = m["mu20"] / (n - 1) + 1 / 12, m["mu02"] / (n - 1) + 1 / 12, m["mu11"] / (n - 1)
    b, c = b / aspect**2, c / aspect
    mean, d = 0.5 * (a + b), np.hypot(0.5 * (a - b), c)
    return float(np.sqrt(max(mean - d, 0.0) / (mean + d)))


def expected_area_px(camera: Camera, X_mm, radius_mm: float) -> float:
    """Projected area (px) of a sphere of ``radius_mm`` at world point ``X_mm`` (pinhole)."""
    z = float(camera.to_camera(X_mm)[2])
    return float(np.pi * camera.fx * camera.fy * (radius_mm / z) ** 2)


def locate_led(patch, rgb, *, method: str = "intensity", min_roundness: float = MIN_ROUNDNESS,
               aspect: float = 1.0) -> Detection:
    """Find one LED in a window of the frame, without undistorting it.

    Parameters
    ----------
    patch : `itg_vision.imaging.Patch`, the window (or the whole frame) as captured.
    rgb : the LED colour.
    method : centroid weighting, see :func:`blob_centroid`.
    min_roundness : reject blobs less round than this (partly hidden LEDs).
    aspect : the camera's fy / fx (:func:`blob_centroid`).

    Returns
    -------
    Detection with ``uv_raw_px`` in the frame's (distorted) pixels and ``uv_px`` NaN (the
    caller undistorts the detections of a camera together). A blob touching a side of the
    window is rejected: "at the image border" where that side is the frame's, else "touches
    the window border" (the window was placed to hold the whole LED with a margin).
    """
    score = score_image(patch.image, rgb)
    uv, area, rnd, cause = blob_centroid(score, method, aspect)
    uv = uv + np.asarray(patch.origin_px, float)
    reason = cause
    if cause == _BORDER:
        cause = reason = WINDOW_BORDER
        if any(patch.at_frame_edge()) and _touches_frame_edge(score, patch):
            cause = reason = IMAGE_BORDER
    elif not cause and rnd < min_roundness:
        cause, reason = NOT_ROUND, f"{NOT_ROUND} ({rnd:.2f}): partly hidden?"
    if cause:
        return Detection(False, _nan2(), uv, area, reason, cause)
    return Detection(True, _nan2(), uv, area)


def _touches_frame_edge(score: np.ndarray, patch) -> bool:
    """Whether the LED's pixels reach a side of the window that is the frame's side."""
    lit = score >= MIN_SCORE
    left, top, right, bottom = patch.at_frame_edge()
    return bool((left and lit[:, 0].any()) or (top and lit[0].any())
                or (right and lit[:, -1].any()) or (bottom and lit[-1].any()))


def locate_led_near(patch, rgb, predicted_uv, *, half_window: int = HALF_WINDOW_PX,
                    **locate) -> Detection:
    """:func:`locate_led` in a window of ``half_window`` px around ``predicted_uv`` (frame
    pixels) first (if given and finite), the whole ``patch`` (a frame or a window of one) if
    the LED is not found there; ``locate``: its options (``method``, ``min_roundness``,
    ``aspect``)."""
    if predicted_uv is not None and np.all(np.isfinite(predicted_uv)):
        (ox, oy), img = patch.origin_px, patch.image
        h, w = img.shape[:2]
        u, v = (int(round(float(c))) for c in predicted_uv)
        x0, y0 = max(u - ox - half_window, 0), max(v - oy - half_window, 0)  # in the patch
        x1, y1 = min(u - ox + half_window + 1, w), min(v - oy + half_window + 1, h)
        if x1 - x0 > 2 and y1 - y0 > 2:
            d = locate_led(Patch(img[y0:y1, x0:x1], (ox + x0, oy + y0), patch.frame_size), rgb,
                           **locate)
            if d.ok or d.cause == SEVERAL:
                return d
    return locate_led(patch, rgb, **locate)


def find_led(image: np.ndarray, camera: Camera, rgb, *, predicted_uv=None,
             half_window: int = HALF_WINDOW_PX, method: str = "coverage",
             min_roundness: float = MIN_ROUNDNESS) -> Detection:
    """Detect one LED in a whole captured frame (:func:`locate_led_near`) and undistort its
    centroid.

    Parameters
    ----------
    image : uint8, shape (H, W, 3), as captured (distorted).
    camera : the camera that took it (its K and distortion undistort the centroid).
    rgb : the LED colour.
    predicted_uv : optional (2,) raw pixel where the LED is expected; search a window of
        ``half_window`` px around it first, the full frame if it is not found there.
    method : centroid weighting, see :func:`blob_centroid`.
    min_roundness : reject blobs less round than this (partly hidden LEDs).

    Returns
    -------
    Detection
    """
    H, W = image.shape[:2]
    d = locate_led_near(Patch(image, (0, 0), (W, H)), rgb, predicted_uv, half_window=half_window,
                        method=method, min_roundness=min_roundness, aspect=camera.fy / camera.fx)
    return replace(d, uv_px=camera.undistort(d.uv_raw_px)) if d.ok else d
