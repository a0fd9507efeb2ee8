"""Can the cameras see the arm? A start-up check, so a run that cannot work is refused before it
renders a frame (instead of ending with every detection missed and a meaningless E_av).

:func:`check_visible` looks at every camera of the rig that renders and raises one
:class:`~itg_vision.errors.UserError` line for the first problem it finds:

- **sensor**: the exposure must make an LED stand out from the background by at least the
  detector's threshold (:data:`itg_vision.detect.MIN_SCORE` grey levels) plus three noise
  standard deviations. The LEDs render as saturated primaries, so an LED's score is
  ``min(255, 255 * exposure)`` grey levels.
- **place**: the camera must be above the floor the arm stands on (z > 0 mm).
- **points**: the gripper LED at every set point in reach, both LEDs at the start pose and at
  every pose of the start-up measurement (:func:`itg_vision.identify.start_up_poses`; a planar
  arm's base sweep: enough of its poses to place the base axis,
  :func:`itg_vision.identify.enough_of_the_sweep`, every camera seeing every LED there, as the
  start-up leaves out the poses it does not see), and the elbow LED of at least one of the
  inverse-kinematics branches at each set point in reach (the same branch for both cameras,
  as the eye triangulates an LED both see) must lie in front of the camera between the
  renderer's near and far planes, project inside the image with a margin (the LED's
  projected radius, fx r / z across and fy r / z down, + :data:`MARGIN_PX`) on the lens's
  invertible part (see :func:`_visible`), and look large enough to be detected (projected
  radius at least :data:`MIN_LED_RADIUS_PX`) and round enough (:func:`led_roundness` at least
  the detector's :data:`~itg_vision.detect.MIN_ROUNDNESS`: far off the optical axis an LED
  images as an ellipse the detector takes for a partly hidden one).

Pure numpy and the camera model: nothing is rendered. ``--allow-unseen`` skips the check
(to measure the failure). Where only some of the elbow's branches are in view,
:func:`elbow_partly_seen` words a note for the run to print: which branch a model-free
controller takes is not known before it runs.
"""

from __future__ import annotations

import numpy as np

from .arm import REACH_TOL_MM, ArmSpec, forward_kinematics
from .detect import MIN_ROUNDNESS
from .errors import UserError

#: Pixels kept free between an LED's projected disc and the image border.
MARGIN_PX = 2.0
#: Smallest projected LED radius (px) the detector takes at every sub-pixel position. Its gate
#: on a blob's roundness (``detect.MIN_ROUNDNESS``, of the half-peak pixel set) sees the pixel
#: grid: a disc of radius 1.7-2.08 px falls under it at some positions (10-28 % of them, 0.727
#: at worst), one of 2.1 px or more at none (computed on a 16 x 16 grid of positions for radii
#: up to 6 px: tests/test_visibility.py). Rendered, LEDs of 1.8 and 2.0 px were missed in 29
#: and 24 % of looks (supersample 1; 30 and 26 % at 3), of 2.1-2.6 px in none of 120 each.
MIN_LED_RADIUS_PX = 2.1


def _render_range_mm() -> tuple[float, float]:
    """The near and far planes (mm) of every render (:data:`itg_vision.imaging.NEAR_M`,
    ``FAR_M``, in metres as PyBullet takes them)."""
    from .imaging import FAR_M, NEAR_M

    return 1e3 * NEAR_M, 1e3 * FAR_M


def led_points(arm: ArmSpec, points_mm: np.ndarray,
               start_up: bool = True) -> tuple[np.ndarray, list[np.ndarray]]:
    """Where the LEDs must be seen (``start_up``: at the start-up measurement's poses too).

    Returns
    -------
    gripper : ndarray, shape (m, 3): the gripper LED at the start pose, at the start-up
        measurement's poses and at each set point in reach (planar arms carry it
        ``led_standoff_mm`` above the plane).
    elbows : list of ndarray, each shape (k, 3), k in {0, 1, 2}: the elbow LED at the start
        pose and at the start-up's poses (one each), then per set point in reach its
        inverse-kinematics branches (two; one of them must be seen). Empty for an arm without
        an elbow LED.
    """
    return _led_points(arm, points_mm, start_up)[:2]


def _led_points(arm: ArmSpec, points_mm: np.ndarray, start_up=True):
    """:func:`led_points`, and for each of its gripper and elbow rows the index of its set
    point in ``points_mm`` (trace.csv's k; None for the start pose; a start-up pose's words).
    ``start_up``: True (every start-up pose), False (none) or the list of poses
    (:func:`itg_vision.identify.start_up_poses`'s items) to check."""
    from .controllers import three_link_ik, two_link_ik

    from .identify import start_up_poses

    nominal = arm.with_joint_offset((0.0,) * arm.n_joints)
    if start_up is True:
        start_up = start_up_poses(arm, arm.start_q_deg)
    poses = [(None, arm.start_q_deg)] + [(f"in the start-up measurement, {where}", q)
                                         for _, q, where in (start_up or [])]
    pts = np.asarray(points_mm, float).reshape(-1, 3)
    has_elbow = "elbow" in arm.marker_names
    gripper, g_k, elbows, e_k = [], [], [], []
    for label, q in poses:
        leds = forward_kinematics(arm, q)
        gripper.append(leds["gripper"])
        g_k.append(label)
        if has_elbow:
            elbows.append(leds["elbow"][None])
            e_k.append(label)
    for k, p in enumerate(pts):
        if not arm.reachable(p):
            continue
        gripper.append(arm.gripper_led_mm(p))
        g_k.append(k)
        if not has_elbow:
            continue
        if arm.planar:
            qs = [np.array(q) for q in two_link_ik(p[0], p[1], *arm.links_mm, REACH_TOL_MM)]
        else:  # base yaw towards the point, then the pitch plane's branches (the LED is the tool)
            qs = [np.array(q) for q in three_link_ik(p, arm.links_mm, arm.led_standoff_mm,
                                                     REACH_TOL_MM)]
        e = [forward_kinematics(nominal, q)["elbow"] for q in qs]
        if e:
            elbows.append(np.array(e))
            e_k.append(k)
    return np.array(gripper), elbows, g_k, e_k


#: How far (px) undistorting a point's distorted pixel may land from its pinhole pixel for the
#: renderer to draw it there (on the lens's invertible part the round trip is exact to
#: ~1e-10 px; beyond a fold the two preimages of a pixel lie tens to hundreds of px apart).
FOLD_TOL_PX = 0.5


def _visible(camera, X_mm: np.ndarray, near_mm: float, far_mm: float,
             margin_px: float = MARGIN_PX):
    """Per point: None if seen, else why not (a short phrase). ``margin_px``: the pixels kept
    free between the LED's projected disc and the image border.

    A lens whose polynomial turns back outside the frame (k1 = -0.3, say: the rig file allows
    it, as its fold lies beyond the image) brings points far outside the field of view back
    inside the image. The renderer draws each pixel from the one pinhole point undistorting it
    gives (:func:`itg_vision.imaging.distortion_source_map`), the one on the lens's invertible
    part; so a point is seen only where that round trip returns its own pinhole pixel."""
    from .urdf import LED_RADIUS_MM

    X = np.asarray(X_mm, float).reshape(-1, 3)
    z = camera.to_camera(X)[:, 2]
    W, H = camera.size
    with np.errstate(all="ignore"):
        r_px = min(camera.fx, camera.fy) * LED_RADIUS_MM / np.where(z > 0, z, np.nan)
        pin = camera.project(X, distort=False)
        uv = camera.project(X)
        drawn_from = camera.undistort(np.where(np.isfinite(uv), uv, 0.0))
        Xc = camera.to_camera(X)
        roundness = led_roundness(camera, X)
    out = []
    for k in range(len(X)):
        if not z[k] - LED_RADIUS_MM > near_mm:  # the LED's near side, as led_windows asks
            out.append(f"behind the camera or nearer than {near_mm:g} mm (depth {z[k]:.0f} mm, "
                       f"the LED's near side {z[k] - LED_RADIUS_MM:.0f} mm)")
        elif z[k] > far_mm:
            out.append(f"farther than the renderer's {far_mm:g} mm (depth {z[k]:.0f} mm)")
        elif not r_px[k] >= MIN_LED_RADIUS_PX:
            out.append(f"an LED there would be {2 * r_px[k]:.2g} px across (the detector needs "
                       f"{2 * MIN_LED_RADIUS_PX:g})")
        else:
            # the LED images as an ellipse fx r / z wide and fy r / z tall (non-square pixels)
            mu = r_px[k] * camera.fx / min(camera.fx, camera.fy) + margin_px
            mv = r_px[k] * camera.fy / min(camera.fx, camera.fy) + margin_px
            u, v = uv[k]
            inside = mu <= u <= W - 1 - mu and mv <= v <= H - 1 - mv
            if not inside:
                margin = (f"{mu:.0f} px" if round(mu) == round(mv) else
                          f"{mu:.0f} px (u) and {mv:.0f} px (v)")
                out.append(f"projects to ({u:.0f}, {v:.0f}) px, outside the {W} x {H} px image "
                           f"less a {margin} margin")
            elif not np.hypot(*(drawn_from[k] - pin[k])) <= FOLD_TOL_PX:
                pu, pv = pin[k]
                out.append(f"lies outside the field of view (pinhole ({pu:.0f}, {pv:.0f}) px), "
                           f"where the lens model folds back to ({u:.0f}, {v:.0f}) px: the "
                           "renderer draws that pixel from the lens's near side")
            elif not roundness[k] >= MIN_ROUNDNESS:
                off = np.degrees(np.arccos(np.clip(z[k] / np.linalg.norm(Xc[k]), -1.0, 1.0)))
                out.append(f"images as an ellipse {roundness[k]:.2f} as wide as long ({off:.0f} "
                           f"deg off the optical axis, at ({u:.0f}, {v:.0f}) px): the detector "
                           f"takes a blob {MIN_ROUNDNESS:g} round or more as an LED")
            else:
                out.append(None)
    return out


def led_roundness(camera, X_mm) -> np.ndarray:
    """Per point (shape (n, 3), mm, in front of the camera): the minor/major axis ratio of an
    LED's image there, as the detector judges it (v divided by fy / fx,
    :func:`itg_vision.detect.blob_centroid`). Shape (n,).

    A sphere of angular radius a seen t off the optical axis images (pinhole, on the plane at
    unit depth) as an ellipse with semi-axes sin a cos a / (cos^2 t - sin^2 a) along the
    radial direction and sin a / sqrt(cos^2 t - sin^2 a) across it: ratio about cos t (0.75 at
    41 deg). The lens then stretches it by its local Jacobian (a barrel lens squeezes the
    radial axis near the edge: rounder)."""
    from .camera import plumb_bob
    from .urdf import LED_RADIUS_MM

    Xc = camera.to_camera(np.asarray(X_mm, float).reshape(-1, 3))
    D = np.linalg.norm(Xc, axis=1)
    sin_a = np.minimum(LED_RADIUS_MM / D, 1.0)
    cos_t = Xc[:, 2] / D
    with np.errstate(all="ignore"):
        rest = np.sqrt(np.maximum(cos_t ** 2 - sin_a ** 2, 0.0))
        radial, across = sin_a * np.sqrt(1 - sin_a ** 2) / rest ** 2, sin_a / rest
        x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    out = np.zeros(len(Xc))
    k = np.flatnonzero((rest > 0) & (Xc[:, 2] > 0))  # all points at once: no loop per point
    x, y = x[k], y[k]
    rho = np.hypot(x, y)
    off_axis = (rho > 0)[:, None]
    e_r = np.where(off_axis, np.column_stack([x, y]) / np.where(off_axis, rho[:, None], 1.0),
                   [1.0, 0.0])
    e_t = np.column_stack([-e_r[:, 1], e_r[:, 0]])
    h = 1e-6  # the lens's Jacobian by central differences (normalized coordinates)
    J = np.stack([(np.array(plumb_bob(x + h * dx, y + h * dy, camera.dist))
                   - np.array(plumb_bob(x - h * dx, y - h * dy, camera.dist))).T / (2 * h)
                  for dx, dy in np.eye(2)], axis=2)  # (n, 2, 2): d(xd, yd) / d(x, y)
    axes = np.stack([radial[k, None] * e_r, across[k, None] * e_t], axis=2)
    s = np.linalg.svd(J @ axes, compute_uv=False)  # the axes, imaged: their lengths
    out[k] = s[:, 1] / s[:, 0]
    return out


def in_view(cameras, X_mm, margin_px: float = MARGIN_PX) -> np.ndarray:
    """Per point of ``X_mm`` (shape (n, 3), mm): whether an LED there is in view of every one of
    ``cameras`` (:func:`_visible`; ``margin_px`` beyond its disc). Shape (n,), bool."""
    near_mm, far_mm = _render_range_mm()
    X = np.asarray(X_mm, float).reshape(-1, 3)
    whys = [_visible(cam, X, near_mm, far_mm, margin_px) for cam in cameras]
    return np.array([all(why[k] is None for why in whys) for k in range(len(X))], bool)


def _start_up_seen(rig, arm: ArmSpec) -> tuple[list, str]:
    """The start-up poses the check asks the rig to see, and words to add to a refusal at one
    of them. All of them, but for a planar arm's base sweep only the poses at which every
    camera sees every LED if they place the base axis
    (:func:`~itg_vision.identify.enough_of_the_sweep`; the start-up leaves out the others);
    if they do not, all of them (the first unseen is named) and the words say what the
    start-up needs."""
    from .identify import enough_of_the_sweep, start_up_poses, sweep_need

    poses = start_up_poses(arm, arm.start_q_deg)
    if not arm.planar:
        return poses, ""

    def sees(q) -> bool:
        leds = forward_kinematics(arm, q)
        return bool(in_view(rig.cameras, [leds[name] for name in arm.marker_names]).all())

    seen = [pose for pose in poses if sees(pose[1])]
    angles = [float(q[0]) for _, q, _ in seen]
    if enough_of_the_sweep(angles):
        return seen, ""
    return poses, ("; in the start-up, "
                   + sweep_need(angles, len(poses), "every camera sees every LED at"))


def check_cameras(rig, hint: str = "") -> None:
    """Raise `UserError` (one line naming the rig file and the camera, then ``hint``) unless
    every camera of ``rig`` can see an LED at all: its exposure makes an LED stand out from
    the sensor's noise by the detector's threshold, and it is above the floor (the module
    docstring's **sensor** and **place**). Needs no arm: ``calibrate`` asks it before it
    renders."""
    from .detect import MIN_SCORE

    for i, cam in enumerate(rig.cameras):
        who = f"{rig.source or rig.name}: cameras[{i}] ({cam.name})"
        score = min(255.0, 255.0 * cam.exposure)
        need = MIN_SCORE + 3.0 * cam.noise_sigma_gray
        if score < need:
            raise UserError(f"{who}: exposure {cam.exposure:g} makes an LED at most {score:.3g} "
                            f"grey levels bright; the detector needs {need:g} (threshold "
                            f"{MIN_SCORE} + 3 x noise {cam.noise_sigma_gray:g}){hint}")
        if not cam.position_mm[2] > 0:
            raise UserError(f"{who}: is below the floor the arm stands on (z = "
                            f"{cam.position_mm[2]:.0f} mm){hint}")


def _branch_views(rig, elbows, near_mm: float, far_mm: float) -> list[list[list]]:
    """For each set of elbow positions (:func:`_led_points`' ``elbows``), per camera of
    ``rig``, per position: None if seen, else why not. One :func:`_visible` call a camera for
    all of them (a call per set point cost seconds on long paths)."""
    if not elbows:
        return []
    flat = np.vstack(elbows)
    cuts = np.cumsum([len(b) for b in elbows])[:-1]
    per_cam = [np.split(np.array(_visible(cam, flat, near_mm, far_mm), dtype=object), cuts)
               for cam in rig.cameras]
    return [[list(whys[k]) for whys in per_cam] for k in range(len(elbows))]


def _seen_by_all(views) -> list[bool]:
    """Per elbow position: whether every camera sees it (``views``: one set's per camera)."""
    return [all(why[i] is None for why in views) for i in range(len(views[0]))]


def _partly_seen_note(rig, e_k, views) -> str | None:
    """:func:`elbow_partly_seen`'s note from the set points' branch views."""
    at = [(k, v) for k, v in zip(e_k, views) if isinstance(k, int)]
    partly = [k for k, v in at if not all(_seen_by_all(v))]
    if not partly:
        return None
    return (f"note: {rig.source or rig.name}: at {len(partly)} of the {len(at)} set points in "
            "reach only some of the elbow LED's positions (the arm's inverse-kinematics "
            f"branches) are in view of every camera, the first at k = {partly[0]} (trace.csv's "
            "k): a controller on a branch out of view loses the elbow LED there, and is given "
            "its last measured position, turned with the joints' commanded turns since")


def check_leds_apart(arm: ArmSpec, true_links: bool = False, hint: str = "") -> None:
    """Raise `UserError` if the arm's last link is shorter than an LED's diameter: its elbow
    and gripper LEDs then overlap in every image. ``true_links``: the lengths are the simulated
    arm's own (``true_links_mm``, ``--true-links``), not the model's, as the message names them."""
    from .urdf import LED_RADIUS_MM

    if arm.n_joints > 1 and arm.links_mm[-1] < 2 * LED_RADIUS_MM:
        given = "true_links_mm or --true-links" if true_links else "links_mm or --links"
        raise UserError(f"{arm.label}: its last link, {arm.links_mm[-1]:g} mm ({given}), is "
                        f"shorter than an LED's diameter ({2 * LED_RADIUS_MM:g} mm): the elbow "
                        f"and gripper LEDs overlap in every image{hint}")


def check_visible(rig, arm: ArmSpec, points_mm: np.ndarray, start_up: bool = True,
                  true_links: bool = False) -> str | None:
    """Raise `UserError` unless every camera of ``rig`` (the rig that renders) can show the
    arm's LEDs along ``points_mm`` (shape (n, 3), mm): see the module docstring.
    ``start_up=False`` leaves out the start-up measurement's poses (the start pose and the set
    points alone). ``true_links``: as :func:`check_leds_apart`'s. Returns
    :func:`elbow_partly_seen`'s note (None if every branch is seen), from the same look at the
    elbow's positions."""
    hint = "; --allow-unseen runs anyway"
    check_leds_apart(arm, true_links, hint)
    near_mm, far_mm = _render_range_mm()
    poses, too_few = _start_up_seen(rig, arm) if start_up else ([], "")
    gripper, elbows, g_k, e_k = _led_points(arm, points_mm, poses)

    def at(k: int | str | None) -> str:
        if isinstance(k, str):
            return k
        return "at the start pose" if k is None else f"at set point k = {k} (trace.csv's k)"

    def more(k: int | str | None) -> str:  # the start-up's need, after a start-up pose's refusal
        return too_few if isinstance(k, str) else ""

    where = rig.source or rig.name
    check_cameras(rig, hint)
    views = _branch_views(rig, elbows, near_mm, far_mm)
    for i, cam in enumerate(rig.cameras):
        who = f"{where}: cameras[{i}] ({cam.name})"
        why = _visible(cam, gripper, near_mm, far_mm)
        bad = [k for k, w in enumerate(why) if w]
        if bad:
            k = bad[0]
            what = at(g_k[k])
            raise UserError(f"{who}: cannot see the gripper LED at {len(bad)} of {len(why)} "
                            f"positions; {what}, {tuple(round(float(v), 1) for v in gripper[k])} mm "
                            f"{why[k]}{more(g_k[k])}{hint}")
        for k, branches in enumerate(elbows):
            whys = views[k][i]
            if all(whys):
                what = at(e_k[k])
                raise UserError(f"{who}: cannot see the elbow LED {what}: "
                                f"{tuple(round(float(v), 1) for v in branches[0])} mm "
                                f"{whys[0]}{more(e_k[k])}{hint}")
    for k, branches in enumerate(elbows):  # the eye triangulates what both cameras see
        if not any(_seen_by_all(views[k])):
            first_seen = [[w is None for w in whys].index(True) for whys in views[k]]
            only = ", ".join(f"cameras[{c}] ({cam.name}) only "
                             f"{tuple(round(float(v), 1) for v in branches[first_seen[c]])} mm"
                             for c, cam in enumerate(rig.cameras))
            raise UserError(f"{where}: no position of the elbow LED {at(e_k[k])} is seen by "
                            f"both cameras ({only}): the eye measures an LED that both see"
                            f"{more(e_k[k])}{hint}")
    return _partly_seen_note(rig, e_k, views)


def elbow_partly_seen(rig, arm: ArmSpec, points_mm: np.ndarray) -> str | None:
    """A note (one line) if at some set points in reach only some of the elbow LED's positions
    (the arm's inverse-kinematics branches) are in view of every camera of ``rig``; else None.
    :func:`check_visible` asks for one, as a model-free controller may take either branch and
    the check cannot know which: on a branch out of view the run loses the elbow LED there,
    and the controller is given its last measured position, turned with the joints' commanded
    turns since (:class:`itg_vision.loop.Session`). (:func:`check_visible` returns
    the same note from its own look: a run asks that alone.)"""
    _, elbows, _, e_k = _led_points(arm, points_mm, start_up=False)
    return _partly_seen_note(rig, e_k, _branch_views(rig, elbows, *_render_range_mm()))
