"""The arm and its LED markers as URDF text (metres, URDF primitives).

Planar arms turn about world z; their LEDs sit on short posts ``led_standoff_mm`` above the
joints so the links never hide them from cameras above. The three-link arm has a base yaw joint
and two pitch joints; its LEDs sit on posts beside the elbow and the gripper, along the pitch
axis towards the cameras.
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

from .arm import ArmSpec

#: LED colours (RGB in [0, 1]): distinct saturated hues, none the colour of the arm.
LED_RGB: dict[str, tuple[float, float, float]] = {
    "gripper": (1.0, 0.0, 0.0),
    "elbow": (0.0, 1.0, 0.0),
}
LED_RADIUS_MM = 6.0
ARM_RGB = (0.35, 0.36, 0.40)
LINK_WIDTH_MM = 8.0
#: The radius of the post that holds each LED (grey, the arm's colour). On the three-link arm
#: the posts lie across the cameras' view and hide part of their own LED's image: the eye's
#: centroid error there is the post's (docs/benchmarks.md, "What bench accuracy measures").
LED_POST_RADIUS_MM = 1.5

_MM = 1e-3


def _material(name: str, rgb: tuple[float, float, float]) -> str:
    r, g, b = rgb
    return f'<material name="{name}"><color rgba="{r:g} {g:g} {b:g} 1"/></material>'


def _box_link(name: str, length_mm: float, axis: str) -> str:
    """A link drawn as a box from its frame origin along +x (``axis='x'``) or +z."""
    w = LINK_WIDTH_MM * _MM
    L = length_mm * _MM
    size, xyz = ((L, w, 0.75 * w), (L / 2, 0, 0)) if axis == "x" else ((w, w, L), (0, 0, L / 2))
    return (
        f'<link name="{name}"><visual><origin xyz="{xyz[0]:g} {xyz[1]:g} {xyz[2]:g}"/>'
        f'<geometry><box size="{size[0]:g} {size[1]:g} {size[2]:g}"/></geometry>'
        f'<material name="arm"/></visual>'
        f'<inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>'
        f"</link>"
    )


def _led_link(name: str, standoff_mm: float, post_axis: str = "z") -> str:
    """An LED sphere on a post of length ``standoff_mm`` reaching back to the joint along
    -z (``post_axis='z'``) or +y (``'y'``: the three-link arm's LEDs sit at -y of the link)."""
    r = LED_RADIUS_MM * _MM
    h = standoff_mm * _MM
    post = ""
    if h > 0:
        xyz, rpy = ((0, 0, -h / 2), (0, 0, 0)) if post_axis == "z" else ((0, h / 2, 0), (1.5707963, 0, 0))
        post = (f'<visual><origin xyz="{xyz[0]:g} {xyz[1]:g} {xyz[2]:g}" rpy="{rpy[0]:g} {rpy[1]:g} {rpy[2]:g}"/>'
                f'<geometry><cylinder radius="{LED_POST_RADIUS_MM * _MM:g}" length="{h:g}"/></geometry>'
                f'<material name="arm"/></visual>')
    return (
        f'<link name="{name}_led"><visual><geometry><sphere radius="{r:g}"/></geometry>'
        f'<material name="{name}_led"/></visual>{post}'
        f'<inertial><mass value="0.001"/><inertia ixx="1e-7" iyy="1e-7" izz="1e-7" ixy="0" ixz="0" iyz="0"/></inertial>'
        f"</link>"
    )


def _joint(name: str, kind: str, parent: str, child: str, xyz_mm=(0, 0, 0), axis=(0, 0, 1)) -> str:
    x, y, z = (v * _MM for v in xyz_mm)
    ax = f'<axis xyz="{axis[0]:g} {axis[1]:g} {axis[2]:g}"/>' if kind != "fixed" else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{x:g} {y:g} {z:g}"/>{ax}</joint>')


def arm_urdf(arm: ArmSpec) -> str:
    """URDF text of the arm: joints ``q1..qn``, LED links ``gripper_led`` (and ``elbow_led``)."""
    L = arm.links_mm
    h = arm.led_standoff_mm
    parts = [f'<?xml version="1.0"?><robot name={quoteattr(arm.name)}>', _material("arm", ARM_RGB)]
    parts += [_material(f"{n}_led", LED_RGB[n]) for n in arm.marker_names]
    parts.append(
        '<link name="base"><visual><origin xyz="0 0 -0.006"/><geometry><cylinder radius="0.015" '
        'length="0.012"/></geometry><material name="arm"/></visual>'
        '<inertial><mass value="1"/><inertia ixx="1e-3" iyy="1e-3" izz="1e-3" ixy="0" ixz="0" iyz="0"/>'
        '</inertial></link>')
    if arm.planar:
        parent = "base"
        for i, length in enumerate(L, 1):
            origin = (0, 0, 0) if i == 1 else (L[i - 2], 0, 0)
            parts.append(_box_link(f"link{i}", length, "x"))
            parts.append(_joint(f"q{i}", "continuous", parent, f"link{i}", origin))
            parent = f"link{i}"
        if "elbow" in arm.marker_names:
            parts.append(_led_link("elbow", h))
            parts.append(_joint("elbow_mount", "fixed", "link1", "elbow_led", (L[0], 0, h)))
        parts.append(_led_link("gripper", h))
        parts.append(_joint("gripper_mount", "fixed", parent, "gripper_led", (L[-1], 0, h)))
    else:
        pitch = (0, -1, 0)  # positive angle lifts the link from horizontal towards +z
        parts.append(_box_link("column", L[0], "z"))
        parts.append(_joint("q1", "continuous", "base", "column", (0, 0, 0), (0, 0, 1)))
        parts.append(_box_link("upper_arm", L[1], "x"))
        parts.append(_joint("q2", "continuous", "column", "upper_arm", (0, 0, L[0]), pitch))
        parts.append(_box_link("forearm", L[2], "x"))
        parts.append(_joint("q3", "continuous", "upper_arm", "forearm", (L[1], 0, 0), pitch))
        # local +y is the pitch axis reversed: world +y at q1 = 0; the cameras are at -y
        parts.append(_led_link("elbow", h, "y"))
        parts.append(_joint("elbow_mount", "fixed", "upper_arm", "elbow_led", (L[1], -h, 0)))
        parts.append(_led_link("gripper", h, "y"))
        parts.append(_joint("gripper_mount", "fixed", "forearm", "gripper_led", (L[2], -h, 0)))
    parts.append("</robot>")
    return "\n".join(parts)
