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
from .urdf import arm_urdf

_MM = 1e-3


def _disconnect(client: int) -> None:
    if p.isConnected(client):
        p.disconnect(client)


#: Bullet's margin (m) around the convex shapes TinyRenderer tessellates (boxes keep their size;
#: cylinders grow by it).
_CONVEX_MARGIN_M = 0.001


def _local_corners(shapes) -> dict[int, np.ndarray]:
    """Per link, the corners (mm, link frame) of a box around each of its box, sphere and
    cylinder visual shapes (``getVisualShapeData`` rows), grown by the convex margin; a link
    with any other shape is left out."""
    out: dict[int, list] = {}
    other = set()
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    for s in shapes:
        link, kind, dims, pos, orn = s[1], s[2], s[3], s[5], s[6]
        if kind == p.GEOM_BOX:
            half = np.array(dims[:3]) / 2
        elif kind == p.GEOM_SPHERE:
            half = np.full(3, dims[0])
        elif kind == p.GEOM_CYLINDER:  # dims: length, radius; along the shape's z
            half = np.array([dims[1], dims[1], dims[0] / 2])
        else:
            other.add(link)
            continue
        R = np.array(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        local = (signs * (half + _CONVEX_MARGIN_M)) @ R.T + np.array(pos)
        out.setdefault(link, []).append(local / _MM)
    return {link: np.concatenate(c) for link, c in out.items() if link not in other}


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
        shapes = p.getVisualShapeData(self.body, physicsClientId=self.client)
        # each link's shapes' colours as drawn, in TinyRenderer's order (to restore a hidden link)
        self._rgba: dict[int, list] = {}
        for s in shapes:
            self._rgba.setdefault(s[1], []).append(list(s[7]))
        self._corners = self._corner_sets(shapes)
        self._bounds: tuple | None = None
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
        self._bounds = None
        q = np.radians(self.q_deg) + self._offset_rad
        for j, qj in zip(self._joints, q):
            p.resetJointState(self.body, j, float(qj), physicsClientId=self.client)

    def move(self, dq_deg: np.ndarray) -> None:
        self.set_q(self.q_deg + np.asarray(dq_deg, float))

    # ------------------------------------------------------------------ markers
    def true_markers(self) -> dict[str, np.ndarray]:
        """LED centres in mm, world frame; NaN for markers this arm does not carry."""
        return {"gripper": np.full(3, np.nan), "elbow": np.full(3, np.nan),
                **self.led_centres_mm()}

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
        """Recolour one LED (for strobing: a dark LED is drawn in the arm's colour)."""
        p.changeVisualShape(self.body, self._leds[name], rgbaColor=[*rgb, 1.0],
                            physicsClientId=self.client)
        self._rgba[self._leds[name]] = [[*rgb, 1.0] for _ in self._rgba[self._leds[name]]]

    def _corner_sets(self, shapes) -> tuple:
        """(links with corners, the base first if drawn; the moving links' corners in their
        own frames, (links, n, 3) mm; the base's in the world, homogeneous (0 or 1, n, 4): it
        is fixed). Links with fewer shapes repeat a corner."""
        corners = _local_corners(shapes)
        n = max((len(c) for c in corners.values()), default=1)
        corners = {k: np.pad(c, ((0, n - len(c)), (0, 0)), "edge") for k, c in corners.items()}
        moving = tuple(k for k in corners if k != -1)
        base = np.zeros((0, n, 4))
        if -1 in corners:  # the base's frame is its centre of mass's: URDF frame = COM * inertial^-1
            pos, orn = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
            ipos, iorn = p.getDynamicsInfo(self.body, -1, physicsClientId=self.client)[3:5]
            pos, orn = p.multiplyTransforms(pos, orn, *p.invertTransform(ipos, iorn))
            R = np.array(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
            X = corners[-1] @ R.T + np.array(pos) / _MM
            base = np.concatenate([X, np.ones((n, 1))], -1)[None]
        local = np.array([corners[k] for k in moving]).reshape(-1, n, 3)
        return ((-1,) if -1 in corners else ()) + moving, local, base

    def link_bounds_mm(self) -> tuple[tuple[int, ...], np.ndarray]:
        """Where each of the arm's drawn links can be (for a renderer to skip those a view
        cannot see): (link indices, -1 the base; corners, shape (links, n, 4), homogeneous,
        mm, world frame), the corners of a box around each of the link's visual shapes as
        TinyRenderer draws them, grown by Bullet's 1 mm convex margin (a cylinder is drawn as
        the hull of its 32-gon grown by it). Links drawn from a mesh or another shape are left
        out (never skipped). Recomputed after the joints move."""
        self._check_open()
        if self._bounds is None:
            links, local, base = self._corners
            moving = [k for k in links if k != -1]
            states = p.getLinkStates(self.body, moving, computeForwardKinematics=True,
                                     physicsClientId=self.client) if moving else []
            R = np.array([p.getMatrixFromQuaternion(s[5]) for s in states]).reshape(-1, 3, 3)
            pos = np.array([s[4] for s in states]).reshape(-1, 1, 3) / _MM
            X = np.einsum("lij,lnj->lni", R, local) + pos
            X = np.concatenate([base, np.concatenate([X, np.ones(X.shape[:2] + (1,))], -1)])
            self._bounds = links, X
        return self._bounds

    def inverse_kinematics(self, target_mm, marker: str = "gripper",
                           start_q_deg=None) -> np.ndarray:
        """One call of PyBullet's numerical IK, with its defaults (20 damped-least-squares
        iterations, stopping at a 0.1 mm residual): joint angles (deg, as :meth:`set_q` takes
        them) that move ``marker`` towards ``target_mm``, iterating from ``start_q_deg`` (default:
        the arm's present angles). Not a solution from far away: from the straight start pose
        (singular) a call leaves ~200 mm; ``bench speed`` prints its accuracy when tracking."""
        start = {} if start_q_deg is None else {
            "currentPositions": [float(v) for v in np.radians(start_q_deg) + self._offset_rad]}
        q = p.calculateInverseKinematics(self.body, self._leds[marker],
                                         [float(v) * _MM for v in target_mm],
                                         physicsClientId=self.client, **start)
        return np.degrees(q) - np.degrees(self._offset_rad)

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
               diffuse: float = 0.35, skip_links=()) -> np.ndarray:
        """Render an RGB image (uint8, shape (height, width, 3)) with TinyRenderer.

        ``view_gl`` and ``proj_gl`` are OpenGL matrices flattened column-major (16 floats), as
        made by :mod:`itg_vision.camera`. ``skip_links``: links of the arm not drawn (made
        transparent, which TinyRenderer skips whole, then given back their colours): only for
        links the view cannot see (:meth:`link_bounds_mm`), or the image changes.
        """
        c = self.client
        for link in skip_links:
            p.changeVisualShape(self.body, link, rgbaColor=[0.0, 0.0, 0.0, 0.0], physicsClientId=c)
        try:
            _, _, rgba, _, _ = p.getCameraImage(
                width, height, viewMatrix=list(view_gl), projectionMatrix=list(proj_gl),
                renderer=p.ER_TINY_RENDERER, flags=p.ER_NO_SEGMENTATION_MASK, shadow=0,
                lightDirection=list(light_direction), lightAmbientCoeff=ambient,
                lightDiffuseCoeff=diffuse, lightSpecularCoeff=0.0, physicsClientId=c)
        finally:
            for link in skip_links:
                for k, colour in enumerate(self._rgba[link]):
                    p.changeVisualShape(self.body, link, shapeIndex=k, rgbaColor=colour,
                                        physicsClientId=c)
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

