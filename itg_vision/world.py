"""The simulator: the only module that imports pybullet. Metres and radians stay in here.

Joints are set kinematically (``resetJointState``): the paper's experiments need no dynamics.
"""

from __future__ import annotations

import math
import os
import tempfile
import weakref

import cv2
import numpy as np

from .stdio import quiet_c_streams


with quiet_c_streams("stdout", "stderr"):
    import pybullet as p


from .arm import ArmSpec
from .contracts import MARKERS
from .urdf import arm_urdf

#: The joints' damping in PyBullet's IK. With its default the call closes about 1 % of the gap
#: per iteration: started at the previous set point's solution of ellipse T1 (720 points) it
#: runs all 20 and lands median 0.39 mm (max 0.50) from a set point 0.47 mm away, and costs
#: 3x more; at 1e-5 (0.1, 1e-2, 1e-3 leave median 0.26, 0.069, 0.015 mm) it lands within
#: 0.0002 mm of every one of them.
IK_JOINT_DAMPING = 1e-5
_MM = 1e-3


def _disconnect(client: int) -> None:
    if p.isConnected(client):
        p.disconnect(client)


class World:
    """One PyBullet DIRECT client holding the true arm.

    Parameters
    ----------
    arm : the *true* arm (its links and joint offset may differ from the controller's model).
    q_deg : initial joint angles, default the paper's start pose.
    """

    def __init__(self, arm: ArmSpec, q_deg: np.ndarray | None = None):
        self.arm = arm
        with quiet_c_streams("stdout", "stderr"):
            self.client = p.connect(p.DIRECT)
        # a World dropped without close() still frees its client (~28 MB) when collected
        self._disconnect = weakref.finalize(self, _disconnect, self.client)
        fd, path = tempfile.mkstemp(suffix=".urdf", prefix="itg_")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(arm_urdf(arm))
            self.body = p.loadURDF(path, useFixedBase=True, physicsClientId=self.client)
        finally:
            os.unlink(path)
        names = {}
        for j in range(p.getNumJoints(self.body, physicsClientId=self.client)):
            info = p.getJointInfo(self.body, j, physicsClientId=self.client)
            names[info[1].decode()] = j
            names[info[12].decode()] = j  # child link name -> link index
        self._joints = [names[n] for n in arm.joint_names]
        self._leds = {m: names[f"{m}_led"] for m in arm.marker_names}
        self._offset_rad = np.radians(np.asarray(arm.joint_offset_deg or (0.0,) * arm.n_joints))
        self._offset_deg = np.degrees(self._offset_rad)  # what IK's radians give back, once
        self._ik_damping = [IK_JOINT_DAMPING] * len(self._joints)  # one per degree of freedom
        self.q_deg = np.zeros(arm.n_joints)
        self.set_q(arm.start_q_deg if q_deg is None else q_deg)

    # ------------------------------------------------------------------ joints
    def set_q(self, q_deg: np.ndarray) -> None:
        """Command joint angles (deg); the true arm adds its joint offset."""
        q_deg = np.array(q_deg, float)
        # per element in Python: np.isfinite costs 2 us on two angles, a third of this call
        if q_deg.shape != (self.arm.n_joints,) or not all(map(math.isfinite, q_deg.tolist())):
            raise ValueError(f"World.set_q: {self.arm.n_joints} finite joint angles (deg) "
                             f"expected, got {q_deg.tolist()}")
        self._check_open()
        self.q_deg = q_deg
        q = np.radians(self.q_deg) + self._offset_rad
        for j, qj in zip(self._joints, q):
            p.resetJointState(self.body, j, float(qj), physicsClientId=self.client)

    def move(self, dq_deg: np.ndarray) -> None:
        """Command the joints ``dq_deg`` (deg) from where they are."""
        self.set_q(self.q_deg + np.asarray(dq_deg, float))

    # ------------------------------------------------------------------ markers
    def true_markers(self) -> dict[str, np.ndarray]:
        """LED centres in mm, world frame; NaN for markers this arm does not carry."""
        return {**{name: np.full(3, np.nan) for name in MARKERS}, **self.led_centres_mm()}

    def led_centres_mm(self) -> dict[str, np.ndarray]:
        """Where the LEDs are, for the renderer to place its windows (as a renderer knows its
        scene); the same numbers as :meth:`true_markers`, for the markers this arm carries."""
        self._check_open()
        out = {}
        for name, link in self._leds.items():
            pos = p.getLinkState(self.body, link, computeForwardKinematics=True,
                                 physicsClientId=self.client)[4]
            out[name] = np.array(pos) / _MM
        return out

    def set_led_lit(self, name: str, rgb: tuple[float, float, float]) -> None:
        """Recolour one LED's sphere (for strobing: a dark LED is drawn in the arm's colour).
        Its post keeps the arm's colour: the sphere is its link's first visual shape
        (:func:`itg_vision.urdf._led_link`), and a call without ``shapeIndex`` recolours every
        visual of the link, so the post was drawn lit too, from the first strobed look on."""
        self._check_open()
        p.changeVisualShape(self.body, self._leds[name], shapeIndex=0, rgbaColor=[*rgb, 1.0],
                            physicsClientId=self.client)

    def ik_arguments(self, target_mm, marker: str = "gripper", start_q_deg=None) -> tuple:
        """``(args, kwargs)`` of the ``pybullet.calculateInverseKinematics`` call that
        :meth:`inverse_kinematics` makes (metres, radians), for timing the call alone."""
        self._check_open()
        start = {} if start_q_deg is None else {
            "currentPositions": [float(v) for v in np.radians(start_q_deg) + self._offset_rad]}
        return ((self.body, self._leds[marker], [float(v) * _MM for v in target_mm]),
                {"jointDamping": self._ik_damping, "physicsClientId": self.client, **start})

    def inverse_kinematics(self, target_mm, marker: str = "gripper",
                           start_q_deg=None) -> np.ndarray:
        """One call of PyBullet's numerical IK (damped least squares, 20 iterations at most,
        stopping at a 0.1 mm residual; the joints' damping :data:`IK_JOINT_DAMPING`): joint
        angles (deg, as :meth:`set_q` takes them) that move ``marker`` to ``target_mm``,
        iterating from ``start_q_deg`` (default: the arm's present angles). Not a solution from
        far away: from the straight start pose (singular) a call does not get there."""
        args, kwargs = self.ik_arguments(target_mm, marker, start_q_deg)
        return np.degrees(p.calculateInverseKinematics(*args, **kwargs)) - self._offset_deg

    # ------------------------------------------------------------------ extra bodies
    def add_mesh(self, path: str, scale: float = 1.0, rgba=(1, 1, 1, 1)) -> int:
        """A visual-only mesh body (OBJ file with UVs, in metres times ``scale``)."""
        vis = p.createVisualShape(p.GEOM_MESH, fileName=path, meshScale=[scale] * 3,
                                  rgbaColor=list(rgba), physicsClientId=self.client)
        return p.createMultiBody(baseMass=0, baseVisualShapeIndex=vis, physicsClientId=self.client)

    def texture(self, body: int, png_path: str) -> None:
        tex = p.loadTexture(png_path, physicsClientId=self.client)
        p.changeVisualShape(body, -1, textureUniqueId=tex, physicsClientId=self.client)

    def set_pose(self, body: int, position_mm, quaternion_xyzw) -> None:
        p.resetBasePositionAndOrientation(body, [v * _MM for v in position_mm],
                                          list(quaternion_xyzw), physicsClientId=self.client)

    def remove(self, body: int) -> None:
        p.removeBody(body, physicsClientId=self.client)

    # ------------------------------------------------------------------ camera
    def render(self, width: int, height: int, view_gl, proj_gl, *,
               light_direction=(0.3, -0.4, 1.0), ambient: float = 0.75,
               diffuse: float = 0.35) -> np.ndarray:
        """Render an RGB image (uint8, shape (height, width, 3)) with TinyRenderer.

        ``view_gl`` and ``proj_gl`` are OpenGL matrices flattened column-major (16 floats), as
        made by :mod:`itg_vision.camera`.
        """
        self._check_open()
        _, _, rgba, _, _ = p.getCameraImage(
            width, height, viewMatrix=list(view_gl), projectionMatrix=list(proj_gl),
            renderer=p.ER_TINY_RENDERER, flags=p.ER_NO_SEGMENTATION_MASK, shadow=0,
            lightDirection=list(light_direction), lightAmbientCoeff=ambient,
            lightDiffuseCoeff=diffuse, lightSpecularCoeff=0.0, physicsClientId=self.client)
        rgba = np.reshape(np.asarray(rgba, dtype=np.uint8), (height, width, 4))
        return cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)  # 20x faster than a strided copy

    def close(self) -> None:
        self._disconnect()  # once: later calls do nothing
        self.client = None

    def _check_open(self) -> None:
        if self.client is None:
            raise RuntimeError("the World is closed")

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

