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

from .errors import ConfigError, UserError
from .inputs import FILE_TYPES, Fields, count, read_yaml, resolve_relative, show
from .shipped import (ARMS_DIR, TRAJECTORY_NAMES, YAML_SUFFIXES, names_a_path, not_found,
                      or_a_path, rig_names, rule_names, shipped_name_hint, trajectory_file_names)

#: A set point within this of the arm's reach counts as in reach (mm, on the radius; see
#: ArmSpec.reachable): the tolerance w of the paper's reach test (Table 1's RULE 0, |xd^2 + yd^2
#: - L^2| within w, read on the radius). The one-link arm reaches a circle only, and a path
#: written to a file lies off it by rounding.
REACH_TOL_MM = 0.5

#: Kinds of chain: joints all about world z, or a base yaw then two pitch joints (section 3.5).
KINDS = ("planar", "yaw-pitch-pitch")
#: The fields of an arm file, every one required.
FIELDS = ("name", "kind", "links_mm", "led_standoff_mm", "start_pose_deg", "defaults",
          "pose_ranges_deg", "benchmark", "calibration")
#: Longest link an arm file or ``--links`` may give (mm), and largest LED stand-off.
MAX_LINK_MM = 5000.0
#: Largest joint angle (and servo step per iteration) an arm file may give (deg).
MAX_ANGLE_DEG = 360.0
#: Most iterations per set point (``benchmark.iterations``; as ``run --iterations``).
MAX_ITERATIONS = 10_000
#: Most poses of a calibration sweep (each is rendered by both cameras).
MAX_SWEEP_POSES = 1000


def wrap_deg(a):
    """Angles (deg; a number or an array) wrapped into [-180, 180): the shortest turn."""
    return (np.asarray(a, float) + 180.0) % 360.0 - 180.0


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
    source : the arm file read (its path as given, or the shipped file's).
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
    source: str = field(default="", compare=False)

    @classmethod
    def from_args(cls, name: str, links_mm: tuple[float, ...] | None = None) -> "ArmSpec":
        """A shipped arm by name (or an arm file's path), optionally with other link lengths
        (bad ones: a `ConfigError` on ``links_mm``, which a command names by its option)."""
        arm = load_arm(name)
        if links_mm is None:
            return arm
        links = tuple(float(v) for v in links_mm)
        if len(links) != arm.n_joints:
            raise ConfigError("links_mm", f"arm {arm.name!r} needs {arm.n_joints} link lengths "
                                          f"in mm, got {len(links)}")
        for i, v in enumerate(links, 1):
            if not np.isfinite(v) or v <= 0 or v > MAX_LINK_MM:
                raise ConfigError("links_mm", f"link {i} must be a length in mm in "
                                              f"(0, {MAX_LINK_MM:g}], got {v}")
        return arm.with_links(links)

    # ------------------------------------------------------------------ structure
    @property
    def planar(self) -> bool:
        return self.kind == "planar"

    @property
    def label(self) -> str:
        """How a message names the arm: ``arm NAME``, and its file unless a shipped one."""
        shipped = not self.source or Path(self.source).resolve().parent == ARMS_DIR.resolve()
        return f"arm {self.name}" + ("" if shipped else f" ({self.source})")

    @property
    def n_joints(self) -> int:
        return len(self.links_mm)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(f"q{i}" for i in range(1, self.n_joints + 1))

    @property
    def marker_names(self) -> tuple[str, ...]:
        """The LEDs the arm carries: the gripper, and the elbow when there is one."""
        return arm_markers(self.n_joints)

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

    def gripper_led_mm(self, point_mm) -> np.ndarray:
        """Where the gripper's LED is with the gripper at ``point_mm``: a planar arm's set point
        lies in the joints' plane and its LED ``led_standoff_mm`` above it; the three-link
        arm's set points are its LED's, shape (3,)."""
        p = np.array(point_mm, float).reshape(3)
        if self.planar:
            p[2] = self.led_standoff_mm
        return p

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


def arm_markers(n_joints: int) -> tuple[str, ...]:
    """The LEDs an arm of ``n_joints`` carries, elbow first: the gripper, and the elbow when
    there is one."""
    return ("gripper",) if n_joints == 1 else ("elbow", "gripper")


# ---------------------------------------------------------------------------- arm files
def names_a_file(name_or_path: str) -> bool:
    """Whether ``--arm`` names an arm file (a .yaml or a path with a folder), not a shipped arm
    (whatever files the current folder holds)."""
    return names_a_path(name_or_path, YAML_SUFFIXES)


def arm_path(name_or_path: str) -> Path:
    """The arm file of a shipped arm's name, or the path given (an unknown name: a UserError)."""
    if names_a_file(name_or_path):
        p = Path(name_or_path)
        if not p.exists() and p.stem in arm_names():  # else read_text says why it cannot read it
            raise UserError(not_found(p, "arm", arm_names()))
        return p
    candidate = ARMS_DIR / f"{name_or_path}.yaml"
    if not candidate.exists():
        raise UserError(f"unknown arm {name_or_path!r} (choose from {', '.join(arm_names())}; "
                        f"{or_a_path(name_or_path, 'an arm file', '.yaml')})")
    return candidate


def load_arm(name_or_path: str) -> ArmSpec:
    """Read and check an arm file (see ``data/arms/two-link.yaml``): every field, so code
    using the spec can trust it; a bad one raises `UserError` ``<file>: <field>: <problem>``."""
    path = arm_path(name_or_path)
    return arm_from_dict(read_yaml(path, "arm file"), str(path))


def arm_from_dict(doc, path: str = "<arm>") -> ArmSpec:
    """Check a parsed arm file, every field, and build the `ArmSpec` (see :func:`load_arm`)."""
    F = Fields(path)
    F.mapping(doc, "(top level)", FIELDS)
    name = F.text(doc["name"], "name", what="a name on one line")
    kind = doc["kind"]
    if kind not in KINDS:
        F.fail("kind", f"must be one of {', '.join(KINDS)}, got {show(kind)}")
    planar = kind == "planar"
    links = F.numbers(doc["links_mm"], None, "links_mm", "lengths in mm", lo=0.0,
                      hi=MAX_LINK_MM, lo_open=True, unit=" (mm)")
    n = len(links)
    if not (1 <= n <= 2 if planar else n == 3):
        F.fail("links_mm", f"a {kind} arm has {'1 or 2' if planar else '3'} links, got {n}")
    standoff = F.number(doc["led_standoff_mm"], "led_standoff_mm", 0.0, MAX_LINK_MM, unit=" (mm)")
    angle = dict(lo=-MAX_ANGLE_DEG, hi=MAX_ANGLE_DEG, unit=" (deg)")
    start = F.numbers(doc["start_pose_deg"], n, "start_pose_deg", "angles in deg (one per joint)",
                      **angle)
    ranges = doc["pose_ranges_deg"]
    if not isinstance(ranges, list) or len(ranges) != n:
        got = count(ranges, "range") if isinstance(ranges, list) else show(ranges)
        F.fail("pose_ranges_deg", f"must be a list of {n} [lo, hi] ranges in deg (one per "
                                  f"joint), got {got}")
    ranges = tuple(F.numbers(r, 2, f"pose_ranges_deg[{i}]", "angles in deg, [lo, hi]", **angle)
                   for i, r in enumerate(ranges))
    for i, (lo, hi) in enumerate(ranges):
        if lo > hi:
            F.fail(f"pose_ranges_deg[{i}]", f"lo must be <= hi, got [{lo:g}, {hi:g}]")
    defaults = F.mapping(doc["defaults"], "defaults", ("rules", "rig", "trajectory"),
                         ("itg_plus_rules",))
    defaults = {k: _default(F, v, f"defaults.{k}", path) for k, v in defaults.items()}
    bench = F.mapping(doc["benchmark"], "benchmark", ("max_step_deg", "iterations"))
    bench = {"max_step_deg": F.number(bench["max_step_deg"], "benchmark.max_step_deg", 0.0,
                                      MAX_ANGLE_DEG, lo_open=True, unit=" (deg per iteration)"),
             "iterations": F.integer(bench["iterations"], "benchmark.iterations", 1,
                                     MAX_ITERATIONS)}
    calib = _calibration(F, doc["calibration"], n, planar)
    return ArmSpec(name, kind, links, standoff, start, (0.0,) * n, defaults, ranges, bench, calib,
                   source=path)


def _shipped(key: str) -> list[str]:
    """The shipped names a ``defaults`` entry may give: rule bases, rigs or trajectories."""
    if key == "trajectory":
        return [*TRAJECTORY_NAMES, *trajectory_file_names()]
    return rig_names() if key == "rig" else rule_names()


def _default(F: Fields, value, where: str, path: str) -> str:
    """A default of the arm file: a shipped name, which must be shipped, or a file, which must
    exist: a relative one beside the arm file (as a rig's ``true_rig``), else from the current
    folder."""
    text = F.text(value, where)
    if "/" not in text and Path(text).suffix not in FILE_TYPES:
        shipped = _shipped(where.rsplit(".", 1)[-1])
        if text not in shipped:
            F.fail(where, f"no shipped one is called {text!r} (shipped: {', '.join(shipped)}; "
                          "or give a file's path)")
        return text
    p = resolve_relative(text, Path(path))
    if not p.is_file():
        hint = (shipped_name_hint(Path(text), _shipped(where.rsplit(".", 1)[-1]))
                if Path(text).suffix else "")
        F.fail(where, f"no such file: {Path(path).parent / text}{hint}")
    return str(p)


def _calibration(F: Fields, calib, n: int, planar: bool) -> dict:
    """The arm file's ``calibration``, checked: the board's target and one sweep per joint
    swept (joint 1 always; the three-link arm's shoulder, q2, too), each moving its LEDs."""
    calib = F.mapping(calib, "calibration", ("board_target_mm", "axis_sweeps"))
    target = F.numbers(calib["board_target_mm"], 3, "calibration.board_target_mm",
                       "coordinates in mm", lo=-1e5, hi=1e5, unit=" (mm)")
    sweeps = calib["axis_sweeps"]
    if not isinstance(sweeps, list) or not sweeps:
        F.fail("calibration.axis_sweeps", f"must be a list of joint sweeps, got {show(sweeps)}")
    markers = arm_markers(n)
    out = []
    for i, sw in enumerate(sweeps):
        where = f"calibration.axis_sweeps[{i}]"
        F.mapping(sw, where, ("joint", "from_deg", "to_deg", "poses", "pose_deg", "markers"))
        joint = F.integer(sw["joint"], f"{where}.joint", 1, n)
        if any(s["joint"] == joint for s in out):
            F.fail(f"{where}.joint", f"joint {joint} is swept twice")
        lo = F.number(sw["from_deg"], f"{where}.from_deg", -MAX_ANGLE_DEG, MAX_ANGLE_DEG,
                      unit=" (deg)")
        hi = F.number(sw["to_deg"], f"{where}.to_deg", -MAX_ANGLE_DEG, MAX_ANGLE_DEG,
                      unit=" (deg)")
        if hi <= lo:
            F.fail(f"{where}.to_deg", f"must be above from_deg ({lo:g}), got {hi:g}")
        poses = F.integer(sw["poses"], f"{where}.poses", 3, MAX_SWEEP_POSES)
        pose = sw["pose_deg"]
        if not isinstance(pose, list) or len(pose) != n:
            got = count(pose, "value") if isinstance(pose, list) else show(pose)
            F.fail(f"{where}.pose_deg", f"must be a list of {n} angles in deg (null for the swept "
                                        f"joint), got {got}")
        for j, v in enumerate(pose, 1):
            if j == joint and v is not None:
                F.fail(f"{where}.pose_deg[{j - 1}]", f"must be null: joint {joint} is swept, got "
                                                     f"{show(v)}")
        pose = [None if j == joint else F.number(v, f"{where}.pose_deg[{j - 1}]", -MAX_ANGLE_DEG,
                                                 MAX_ANGLE_DEG, unit=" (deg)")
                for j, v in enumerate(pose, 1)]
        names = sw["markers"]
        if not isinstance(names, list) or not names or len(set(map(repr, names))) != len(names) \
                or not all(isinstance(m, str) and m in markers for m in names):
            F.fail(f"{where}.markers", f"must be a list of distinct LEDs of {', '.join(markers)}, "
                                       f"got {show(names)}")
        if "elbow" in names and joint == n:
            F.fail(f"{where}.markers", f"the elbow LED does not move when joint {joint} turns")
        out.append({"joint": joint, "from_deg": lo, "to_deg": hi, "poses": poses,
                    "pose_deg": pose, "markers": list(names)})
    swept = {s["joint"]: s for s in out}
    if 1 not in swept:
        F.fail("calibration.axis_sweeps", "must sweep joint 1 (the base: the world's z axis)")
    if not planar and (2 not in swept or set(swept[2]["markers"]) != {"elbow", "gripper"}):
        F.fail("calibration.axis_sweeps", "must sweep joint 2 (the shoulder) with markers "
                                          "[elbow, gripper]")
    return {"board_target_mm": list(target), "axis_sweeps": out}


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
    q = np.asarray(q_deg, float)
    if q.shape != (arm.n_joints,):  # one angle for two joints was broadcast to both
        raise ValueError(f"forward_kinematics: {arm.n_joints} joint angles (deg) expected for "
                         f"{arm.label}, got shape {q.shape}")
    q = np.radians(q + np.asarray(arm.joint_offset_deg or 0.0))
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
    side = h * model_pitch_axis(arm, q_deg[0])
    return {"gripper": np.array([rg * c, rg * s, zg]) + side,
            "elbow": np.array([re * c, re * s, ze]) + side}


def model_pitch_axis(arm: ArmSpec, q1_deg: float) -> np.ndarray:
    """The yaw-pitch-pitch arm's pitch axis at base angle ``q1_deg`` (its joint offset added):
    (sin q1, -cos q1, 0), unit. Positive q2 and q3 turn the links about it (right-hand rule),
    and the LEDs stand ``led_standoff_mm`` along it (:func:`forward_kinematics`). The model's,
    not the one the LEDs show (:func:`itg_vision.controllers.pitch_axis`)."""
    if arm.planar:
        raise ValueError(f"{arm.label} is planar: it has no pitch axis")
    q1 = math.radians(q1_deg + (arm.joint_offset_deg[0] if arm.joint_offset_deg else 0.0))
    return np.array([math.sin(q1), -math.cos(q1), 0.0])
