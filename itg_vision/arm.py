"""Arm specifications and the nominal kinematic model (millimetres, degrees).

Every fact about an arm lives in its file, ``data/arms/<name>.yaml`` (links, kind of chain, LED
placement, start pose, the rules, rig and trajectory it uses by default, the pose ranges its rig
sees, its calibration sweeps, the benchmark's limits), read here into an :class:`ArmSpec`. Code
elsewhere asks the spec (``arm.planar``, ``arm.marker_names``, ``arm.shoulder_mm()``...), never
the arm's name.

The kinematic model here is what the *classical* variant of the ITG uses (encoders + model) and
what the tests compare the simulator against. The vision loop never calls it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .errors import UserError

#: A set point within this of the arm's reach counts as in reach (mm, on the radius; see
#: ArmSpec.reachable): the tolerance w of the paper's reach test (Table 1's RULE 0, |xd^2 + yd^2
#: - L^2| within w, read on the radius). The one-link arm reaches a circle only, and a path
#: written to a file lies off it by rounding.
REACH_TOL_MM = 0.5

#: The shipped arm files.
ARMS_DIR = Path(__file__).resolve().parent.parent / "data" / "arms"
#: Kinds of chain: joints all about world z, or a base yaw then two pitch joints (section 3.5).
KINDS = ("planar", "yaw-pitch-pitch")


def arm_names() -> list[str]:
    """The shipped arms, by name."""
    return sorted(p.stem for p in ARMS_DIR.glob("*.yaml"))


@dataclass(frozen=True)
class ArmSpec:
    """A kinematic chain of the paper, as its arm file describes it.

    Attributes
    ----------
    name : the arm's name (its file's stem).
    kind : "planar" (joints about world z, LEDs ``led_standoff_mm`` above the joints) or
        "yaw-pitch-pitch" (base yaw, two pitch joints; LEDs along the pitch axis).
    links_mm : link lengths; yaw-pitch-pitch: (base height L1, upper arm L2, forearm L3).
    led_standoff_mm : the LEDs' offset from the joints.
    start_pose_deg : the paper's initial pose.
    joint_offset_deg : added to every commanded joint angle by the *true* arm (model error).
    defaults : {"rules", "rig", "trajectory"}: what a run of this arm uses unless told; and
        "itg_plus_rules", the arm's ITG+ rule base (issue 13; the benchmark's itg-plus-*).
    pose_ranges_deg : per joint (lo, hi): random poses the arm's rig sees.
    benchmark : {"max_step_deg", "iterations"}: the limits of the noise benchmark.
    calibration : {"board_target_mm", "axis_sweeps"}: see itg_vision/calibration.py.
    """

    name: str
    kind: str
    links_mm: tuple[float, ...]
    led_standoff_mm: float
    start_pose_deg: tuple[float, ...]
    joint_offset_deg: tuple[float, ...] = ()
    defaults: dict = field(default_factory=dict, compare=False, hash=False)
    pose_ranges_deg: tuple[tuple[float, float], ...] = ()
    benchmark: dict = field(default_factory=dict, compare=False, hash=False)
    calibration: dict = field(default_factory=dict, compare=False, hash=False)

    @classmethod
    def from_args(cls, name: str, links_mm: tuple[float, ...] | None = None) -> "ArmSpec":
        """A shipped arm by name (or an arm file's path), optionally with other link lengths."""
        arm = load_arm(name)
        if links_mm is None:
            return arm
        links = tuple(float(v) for v in links_mm)
        if len(links) != arm.n_joints:
            raise UserError(f"--links: arm {arm.name!r} needs {arm.n_joints} link lengths in mm, "
                            f"got {len(links)}")
        for i, v in enumerate(links, 1):
            if not np.isfinite(v) or v <= 0 or v > 5000:
                raise UserError(f"--links: link {i} must be a length in mm in (0, 5000], got {v}")
        return arm.with_links(links)

    # ------------------------------------------------------------------ structure
    @property
    def planar(self) -> bool:
        return self.kind == "planar"

    @property
    def n_joints(self) -> int:
        return len(self.links_mm)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(f"q{i}" for i in range(1, self.n_joints + 1))

    @property
    def marker_names(self) -> tuple[str, ...]:
        """The LEDs the arm carries: the gripper, and the elbow when there is one."""
        return ("gripper",) if self.n_joints == 1 else ("elbow", "gripper")

    @property
    def start_q_deg(self) -> np.ndarray:
        """The paper's initial pose (fully extended along +y, or straight up), shape (n,)."""
        return np.array(self.start_pose_deg, float)

    def with_links(self, links_mm: tuple[float, ...]) -> "ArmSpec":
        return replace(self, links_mm=tuple(float(v) for v in links_mm))

    def with_joint_offset(self, offset_deg: tuple[float, ...]) -> "ArmSpec":
        return replace(self, joint_offset_deg=tuple(float(v) for v in offset_deg))

    def random_poses(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` joint poses (deg) drawn uniformly in ``pose_ranges_deg``, shape (n, n_joints)."""
        lo, hi = np.array(self.pose_ranges_deg, float).T
        return rng.uniform(lo, hi, size=(n, self.n_joints))

    # ------------------------------------------------------------------ workspace
    def reach_mm(self) -> tuple[float, float]:
        """Inner and outer radius of the arm's reach about the shoulder, in the plane of its last
        two links (mm); where its LED reaches: :meth:`reachable`."""
        L = self.links_mm
        if self.n_joints == 1:
            return L[0], L[0]
        a, b = L[-2], L[-1]
        return abs(a - b), a + b

    def shoulder_mm(self) -> np.ndarray:
        """The joint the last two links turn about: the base (planar) or the shoulder atop the
        base column (yaw-pitch-pitch), shape (3,)."""
        return np.array([0.0, 0.0, 0.0 if self.planar else self.links_mm[0]])

    def reachable(self, p_mm: np.ndarray, tol_mm: float = REACH_TOL_MM) -> bool:
        """Whether the gripper LED can reach the point, within ``tol_mm`` on each radius below
        (planar arms: its x, y only, the LED sits above the joint: the distance from the base).
        The three-link arm's LED sits ``led_standoff_mm`` (h) beside the arm's vertical plane,
        so it reaches a point at distance rho from the base axis when rho >= h and the arm, in
        its plane, reaches the point's in-plane position: sqrt(rho^2 - h^2) out, z - L1 up."""
        p = np.asarray(p_mm, float)
        lo, hi = self.reach_mm()
        rho = math.hypot(p[0], p[1])
        if self.planar:
            r = rho
        else:
            h = self.led_standoff_mm
            if rho < h - tol_mm:
                return False
            r = math.hypot(math.sqrt(max(rho * rho - h * h, 0.0)), p[2] - self.links_mm[0])
        return lo - tol_mm <= r <= hi + tol_mm


# ---------------------------------------------------------------------------- arm files
def arm_path(name_or_path: str) -> Path:
    """The arm file of a shipped arm's name, or the path given (an unknown name: a UserError)."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or "/" in name_or_path:
        return p
    candidate = ARMS_DIR / f"{name_or_path}.yaml"
    if not candidate.exists():
        raise UserError(f"unknown arm {name_or_path!r} (choose from {', '.join(arm_names())}, "
                        "or give an arm file's path)")
    return candidate


def load_arm(name_or_path: str) -> ArmSpec:
    """Read and check an arm file (see ``data/arms/two-link.yaml``); a bad field raises
    `UserError` naming the file and the field."""
    import yaml

    from .inputs import read_text

    path = arm_path(name_or_path)
    try:
        doc = yaml.safe_load(read_text(path, "arm file"))
    except yaml.YAMLError as exc:
        raise UserError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None

    def fail(where, msg):
        raise UserError(f"{path}: {where}: {msg}")

    if not isinstance(doc, dict):
        fail("(top level)", "must be a mapping")

    def get(key, kind=None):
        if key not in doc:
            fail(key, "missing")
        return doc[key]

    def numbers(v, where, n=None):
        if not isinstance(v, list) or (n is not None and len(v) != n) or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v):
            fail(where, f"must be a list of {n or 'some'} finite numbers, got {v!r}")
        return tuple(float(x) for x in v)

    kind = get("kind")
    if kind not in KINDS:
        fail("kind", f"must be one of {', '.join(KINDS)}, got {kind!r}")
    links = numbers(get("links_mm"), "links_mm")
    n = len(links)
    if not (1 <= n <= 2 if kind == "planar" else n == 3):
        fail("links_mm", f"a {kind} arm has {'1 or 2' if kind == 'planar' else '3'} links, got {n}")
    if any(v <= 0 for v in links):
        fail("links_mm", "lengths must be > 0")
    standoff = float(numbers([get("led_standoff_mm")], "led_standoff_mm")[0])
    if standoff < 0:
        fail("led_standoff_mm", f"must be >= 0 (mm), got {standoff:g}")
    start = numbers(get("start_pose_deg"), "start_pose_deg", n)
    ranges = tuple(numbers(r, f"pose_ranges_deg[{i}]", 2) for i, r in enumerate(get("pose_ranges_deg")))
    if len(ranges) != n:
        fail("pose_ranges_deg", f"needs one [lo, hi] per joint ({n})")
    defaults = get("defaults")
    if not isinstance(defaults, dict) or not (
            {"rules", "rig", "trajectory"} <= set(defaults) <= {"rules", "rig", "trajectory",
                                                                 "itg_plus_rules"}):
        fail("defaults", "must name the default rules, rig and trajectory (and may name the "
                         "itg_plus_rules)")
    bench = get("benchmark")
    if not isinstance(bench, dict) or set(bench) != {"max_step_deg", "iterations"}:
        fail("benchmark", "must give max_step_deg and iterations")
    calib = get("calibration")
    if not isinstance(calib, dict) or "axis_sweeps" not in calib or "board_target_mm" not in calib:
        fail("calibration", "must give board_target_mm and axis_sweeps")
    numbers(calib["board_target_mm"], "calibration.board_target_mm", 3)
    return ArmSpec(str(get("name")), kind, links, standoff, start, (0.0,) * n, dict(defaults),
                   ranges, dict(bench), dict(calib))


def forward_kinematics(arm: ArmSpec, q_deg: np.ndarray) -> dict[str, np.ndarray]:
    """Marker positions in mm for joint angles in degrees (the paper's equations).

    Parameters
    ----------
    arm : the arm.
    q_deg : array-like, shape (n_joints,)

    Returns
    -------
    dict with ``gripper`` and ``elbow``, each shape (3,), in mm; the LED centres (planar arms
    carry them ``led_standoff_mm`` above the joint, the three-link arm beside it along the pitch
    axis, (sin q1, -cos q1, 0)). One-link arms have no elbow marker: NaN.
    """
    q = np.radians(np.asarray(q_deg, float) + np.asarray(arm.joint_offset_deg or 0.0))
    L = arm.links_mm
    h = arm.led_standoff_mm
    if arm.planar and arm.n_joints == 1:
        g = np.array([L[0] * np.cos(q[0]), L[0] * np.sin(q[0]), h])
        return {"gripper": g, "elbow": np.full(3, np.nan)}
    if arm.planar:
        e = np.array([L[0] * np.cos(q[0]), L[0] * np.sin(q[0]), h])
        g = e + np.array([L[1] * np.cos(q[0] + q[1]), L[1] * np.sin(q[0] + q[1]), 0.0])
        return {"gripper": g, "elbow": e}
    # yaw-pitch-pitch: base yaw q1, shoulder pitch q2 (from horizontal), elbow pitch q3
    re = L[1] * np.cos(q[1])
    ze = L[0] + L[1] * np.sin(q[1])
    rg = re + L[2] * np.cos(q[1] + q[2])
    zg = ze + L[2] * np.sin(q[1] + q[2])
    c, s = np.cos(q[0]), np.sin(q[0])
    side = h * np.array([s, -c, 0.0])
    return {"gripper": np.array([rg * c, rg * s, zg]) + side,
            "elbow": np.array([re * c, re * s, ze]) + side}
