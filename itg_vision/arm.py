"""Arm specifications and the nominal kinematic model (millimetres, degrees).

The kinematic model here is what the *classical* variant of the ITG uses (encoders + model) and
what the tests compare the simulator against. The vision loop never calls it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import UserError

#: The paper's arms: link lengths in mm, number of joints, planar or spatial.
ARMS: dict[str, tuple[float, ...]] = {
    "one-link": (100.0,),
    "two-link": (100.0, 100.0),
    "three-link": (100.0, 100.0, 100.0),  # base height, upper arm, forearm (section 3.5)
}

#: LED stand-off so the links never hide it: planar arms carry the LEDs this far above the
#: joints (world +z); the three-link arm carries them this far along the pitch axis, towards
#: the cameras (world -y at q1 = 0). The tracked tool point is the gripper LED's centre.
LED_STANDOFF_MM = 12.0


@dataclass(frozen=True)
class ArmSpec:
    """A kinematic chain of the paper.

    Attributes
    ----------
    name : one of ``ARMS``.
    links_mm : link lengths in mm; for ``three-link`` (base height L1, upper arm L2, forearm L3).
    led_standoff_mm : LED stand-off from the joints: above them (planar arms) or along the
        pitch axis towards the cameras (three-link arm).
    joint_offset_deg : added to every commanded joint angle by the *true* arm (model error).
    """

    name: str
    links_mm: tuple[float, ...]
    led_standoff_mm: float = 0.0
    joint_offset_deg: tuple[float, ...] = ()

    @classmethod
    def from_args(cls, name: str, links_mm: tuple[float, ...] | None = None) -> "ArmSpec":
        if name not in ARMS:
            raise UserError(f"unknown arm {name!r} (choose from {', '.join(ARMS)})")
        default = ARMS[name]
        links = tuple(float(v) for v in (links_mm if links_mm is not None else default))
        if len(links) != len(default):
            raise UserError(
                f"--links: arm {name!r} needs {len(default)} link lengths in mm, got {len(links)}")
        for i, v in enumerate(links, 1):
            if not np.isfinite(v) or v <= 0 or v > 5000:
                raise UserError(f"--links: link {i} must be a length in mm in (0, 5000], got {v}")
        standoff = LED_STANDOFF_MM
        return cls(name, links, standoff, (0.0,) * len(default))

    # ------------------------------------------------------------------ structure
    @property
    def planar(self) -> bool:
        return self.name != "three-link"

    @property
    def n_joints(self) -> int:
        return len(self.links_mm)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(f"q{i}" for i in range(1, self.n_joints + 1))

    @property
    def marker_names(self) -> tuple[str, ...]:
        return ("gripper",) if self.name == "one-link" else ("elbow", "gripper")

    @property
    def start_q_deg(self) -> np.ndarray:
        """The paper's initial pose: fully extended along +y (planar) or straight up."""
        if self.name == "three-link":
            return np.array([0.0, 90.0, 0.0])
        return np.array([90.0] + [0.0] * (self.n_joints - 1))

    def with_links(self, links_mm: tuple[float, ...]) -> "ArmSpec":
        return ArmSpec(self.name, tuple(links_mm), self.led_standoff_mm, self.joint_offset_deg)

    def with_joint_offset(self, offset_deg: tuple[float, ...]) -> "ArmSpec":
        return ArmSpec(self.name, self.links_mm, self.led_standoff_mm, tuple(offset_deg))

    # ------------------------------------------------------------------ workspace
    def reach_mm(self) -> tuple[float, float]:
        """Inner and outer radius of the workspace about the shoulder (mm)."""
        L = self.links_mm
        if self.name == "one-link":
            return L[0], L[0]
        a, b = (L[0], L[1]) if self.name == "two-link" else (L[1], L[2])
        return abs(a - b), a + b

    def shoulder_mm(self) -> np.ndarray:
        return np.array([0.0, 0.0, self.links_mm[0] if self.name == "three-link" else 0.0])

    def reachable(self, p_mm: np.ndarray, tol_mm: float = 1e-9) -> bool:
        """Whether the gripper can reach the point (planar arms: its x, y only)."""
        p = np.asarray(p_mm, float)
        d = p[:2] if self.planar else p[:3]
        s = self.shoulder_mm()[: d.size]
        r = float(np.linalg.norm(d - s))
        lo, hi = self.reach_mm()
        return lo - tol_mm <= r <= hi + tol_mm


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
    if arm.name == "one-link":
        g = np.array([L[0] * np.cos(q[0]), L[0] * np.sin(q[0]), h])
        return {"gripper": g, "elbow": np.full(3, np.nan)}
    if arm.name == "two-link":
        e = np.array([L[0] * np.cos(q[0]), L[0] * np.sin(q[0]), h])
        g = e + np.array([L[1] * np.cos(q[0] + q[1]), L[1] * np.sin(q[0] + q[1]), 0.0])
        return {"gripper": g, "elbow": e}
    # three-link: base yaw q1, shoulder pitch q2 (from horizontal), elbow pitch q3
    re = L[1] * np.cos(q[1])
    ze = L[0] + L[1] * np.sin(q[1])
    rg = re + L[2] * np.cos(q[1] + q[2])
    zg = ze + L[2] * np.sin(q[1] + q[2])
    c, s = np.cos(q[0]), np.sin(q[0])
    side = h * np.array([s, -c, 0.0])
    return {"gripper": np.array([rg * c, rg * s, zg]) + side,
            "elbow": np.array([re * c, re * s, ze]) + side}
