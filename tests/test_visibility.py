"""The start-up check that the cameras can see the arm (pure geometry, nothing rendered)."""

import dataclasses

import numpy as np
import pytest

from itg_vision.arm import ArmSpec, forward_kinematics
from itg_vision.camera import Rig, default_rig_path
from itg_vision.errors import UserError
from itg_vision.trajectory import named
from itg_vision.visibility import check_visible, led_points


@pytest.mark.parametrize("arm, trajectory", [("one-link", "arc"), ("two-link", "ellipse-t1"),
                                             ("two-link", "ellipse-t2"), ("two-link", "abcd"),
                                             ("three-link", "line-ab"), ("three-link", "line-ab-reach")])
@pytest.mark.parametrize("calibrated", [False, True])
def test_the_shipped_rigs_see_every_shipped_trajectory(arm, trajectory, calibrated):
    a = ArmSpec.from_args(arm)
    check_visible(Rig.from_yaml(default_rig_path(arm, calibrated)), a, named(trajectory).points_mm)


def test_led_points_are_the_arm_s_leds_at_the_set_points_and_its_ik_elbows():
    arm = ArmSpec.from_args("two-link")
    pts = named("ellipse-t1", 12).points_mm
    gripper, elbows = led_points(arm, pts)
    assert len(gripper) == 13 and np.allclose(gripper[0], forward_kinematics(arm, arm.start_q_deg)["gripper"])
    assert np.allclose(gripper[1:, :2], pts[:, :2]) and np.allclose(gripper[1:, 2], arm.led_standoff_mm)
    for p, branches in zip(pts, elbows[1:]):
        assert branches.shape == (2, 3)
        # independent check: each elbow is L1 from the shoulder and L2 from the set point
        assert np.allclose(np.linalg.norm(branches[:, :2], axis=1), 100.0)
        assert np.allclose(np.linalg.norm(branches[:, :2] - p[:2], axis=1), 100.0)


def test_out_of_reach_set_points_are_not_required_to_be_seen():
    arm = ArmSpec.from_args("two-link")
    far = np.array([[5000.0, 0.0, 0.0], [0.0, 150.0, 0.0]])
    gripper, elbows = led_points(arm, far)
    assert len(gripper) == 2 and len(elbows) == 2  # the start pose and the reachable point


def _moved(rig, cam, **kw):
    cams = list(rig.cameras)
    cams[cam] = dataclasses.replace(cams[cam], **kw)
    return dataclasses.replace(rig, cameras=tuple(cams))


def test_a_camera_turned_away_or_too_dark_is_refused_naming_it():
    rig = Rig.from_yaml(default_rig_path("two-link"))
    arm = ArmSpec.from_args("two-link")
    pts = named("ellipse-t1", 20).points_mm
    cam = rig.cameras[1]
    R = np.diag([-1.0, 1.0, -1.0]) @ cam.R  # turned half round about its own y axis, same place
    away = dict(rotation=tuple(map(tuple, R)), translation_mm=tuple(-R @ cam.position_mm))
    with pytest.raises(UserError, match=r"cameras\[1\] \(right\): cannot see the gripper LED at 21 "
                                        r"of 21 positions; at the start pose, .* behind the camera"):
        check_visible(_moved(rig, 1, **away), arm, pts)
    with pytest.raises(UserError, match=r"cameras\[0\] \(left\): exposure 0.1 makes an LED at most 25.5"):
        check_visible(_moved(rig, 0, exposure=0.1), arm, pts)
    check_visible(_moved(rig, 0, exposure=0.25), arm, pts)  # 63.8 grey levels: enough


def test_long_links_take_the_elbow_out_of_view():
    rig = Rig.from_yaml(default_rig_path("two-link"))
    pts = named("ellipse-t1", 20).points_mm
    with pytest.raises(UserError, match="cannot see the gripper LED at 1 of 21 positions; at the start pose"):
        check_visible(rig, ArmSpec.from_args("two-link", (1000.0, 1000.0)), pts)
    # the same trajectory with links the rig frames is fine
    check_visible(rig, ArmSpec.from_args("two-link", (110.0, 90.0)), pts)
