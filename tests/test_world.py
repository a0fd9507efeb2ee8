"""The PyBullet arm against the nominal kinematic model."""

import re

import numpy as np
import pytest
from conftest import PYBULLET_RTOL, roundoff

from itg_vision.arm import ArmSpec, forward_kinematics
from itg_vision.world import World


#: Link lengths all different, so a test can tell which link a formula uses (the shipped arms'
#: links are all 100 mm: L1, L2, L3 swapped anywhere passed every other test).
UNEQUAL = {"two-link": (120.0, 70.0), "three-link": (130.0, 90.0, 70.0)}


@pytest.mark.parametrize("name, links", [("one-link", None), ("two-link", None),
                                         ("three-link", None), *UNEQUAL.items()])
def test_marker_positions_match_the_kinematic_model(name, links):
    """PyBullet's LEDs (the URDF read back) against the model's equations, the shipped arms
    and arms whose every link has its own length; the reach of the unequal ones by hand."""
    arm = ArmSpec.from_args(name, links)
    if links is not None:  # in the plane of the last two links
        assert arm.reach_mm() == (abs(links[-2] - links[-1]), links[-2] + links[-1])
    rng = np.random.default_rng(7)
    with World(arm) as world:
        for _ in range(25):
            q = rng.uniform(-180, 180, arm.n_joints)
            world.set_q(q)
            truth, model = world.true_markers(), forward_kinematics(arm, q)
            for m in arm.marker_names:
                # PyBullet's positions are float32 metres: one float32 ulp of each coordinate
                # (a coordinate near 0: the model's float64 round-off at 300 mm)
                assert np.allclose(truth[m], model[m], rtol=PYBULLET_RTOL, atol=roundoff(300)), (m, q)


def test_the_inner_reach_of_unequal_links_is_their_difference_whichever_is_longer():
    """Links 60 and 100 mm (upper arm the shorter, unlike UNEQUAL's): the gripper reaches
    40..160 mm from the base (by hand, |60 - 100| and 60 + 100); a point 10 mm out is in the
    hole."""
    arm = ArmSpec.from_args("two-link", (60.0, 100.0))
    assert arm.reach_mm() == (40.0, 160.0)
    assert not arm.reachable(np.array([10.0, 0.0, 0.0]))
    assert arm.reachable(np.array([0.0, 41.0, 0.0])) and arm.reachable(np.array([159.0, 0.0, 0.0]))


def test_start_pose_is_the_papers():
    with World(ArmSpec.from_args("two-link")) as w:
        # float32 positions (conftest.PYBULLET_RTOL); the 0: float64 round-off of cos(90 deg) 200 mm
        assert np.allclose(w.true_markers()["gripper"][:2], [0, 200], rtol=PYBULLET_RTOL,
                           atol=roundoff(300))
    with World(ArmSpec.from_args("three-link")) as w:
        assert np.allclose(w.true_markers()["gripper"], [0, -12, 300], rtol=PYBULLET_RTOL,
                           atol=roundoff(300))  # LED 12 mm towards -y


def test_joint_offset_and_link_error_move_the_true_arm_not_the_model():
    nominal = ArmSpec.from_args("two-link")
    true_arm = ArmSpec.from_args("two-link", (105.0, 104.0)).with_joint_offset((1.0, 0.0))
    q = np.array([30.0, 40.0])
    with World(true_arm, q) as w:
        assert np.allclose(w.true_markers()["gripper"], forward_kinematics(true_arm, q)["gripper"],
                           rtol=PYBULLET_RTOL, atol=roundoff(300))
        assert not np.allclose(w.true_markers()["gripper"], forward_kinematics(nominal, q)["gripper"], atol=1.0)
        assert np.allclose(w.q_deg, q, rtol=0, atol=roundoff(180))  # the encoders read the commanded angle


@pytest.mark.parametrize("links, bad", [
    ((100.0,), "needs 2"), ((100.0, -1.0), "link 2"), ((100.0, float("nan")), "link 2"),
    # links are lengths in (0, 5000] mm: 0 is none, 5000.5 beyond the bound
    ((0.0, 100.0), "link 1 must be a length in mm in (0, 5000], got 0.0"),
    ((100.0, 5000.5), "link 2 must be a length in mm in (0, 5000], got 5000.5"),
])
def test_bad_links(links, bad):
    from itg_vision.errors import UserError
    with pytest.raises(UserError, match=re.escape(bad)):
        ArmSpec.from_args("two-link", links)
    # the bound itself is a length
    assert ArmSpec.from_args("two-link", (5000.0, 5000.0)).links_mm == (5000.0, 5000.0)


def test_pybullet_ik_is_exact_at_a_solution_and_descends_near_one():
    """World.inverse_kinematics (the IK row of `bench speed`) against forward kinematics, on a
    true arm with a joint offset: started at a solution it returns it (angles as set_q takes
    them, the offset taken off), from the start angles or the present ones; started 1 deg off
    on each joint it lands within the call's 0.1 mm stop of the target."""
    arm = ArmSpec.from_args("two-link").with_joint_offset((3.0, -2.0))
    q = np.array([40.0, 70.0])
    target = forward_kinematics(arm, q)["gripper"]
    with World(arm) as w:
        assert np.allclose(w.inverse_kinematics(target, start_q_deg=q), q, rtol=0, atol=1e-9)
        w.set_q(q)
        assert np.allclose(w.inverse_kinematics(target), q, rtol=0, atol=1e-9)
        q0 = q + [1.0, -1.0]
        before = np.linalg.norm(forward_kinematics(arm, q0)["gripper"] - target)
        after = np.linalg.norm(forward_kinematics(arm, w.inverse_kinematics(target, start_q_deg=q0))
                               ["gripper"] - target)
        assert after < 0.1 < before  # 1.7 mm off at the start


def test_pybullet_ik_solves_each_set_point_of_the_speed_benchmark():
    """The IK row of `bench speed` is a baseline: it must do the job it is timed at. Started
    from the previous set point's exact solution (the closed form), as a tracking loop would
    start it, one call lands within its 0.1 mm stop of each of ellipse T1's 720 set points,
    checked by forward kinematics. With PyBullet's default damping it landed median 0.39 mm,
    max 0.50 mm away (all 20 iterations every call), and its cost made the ITG+ step look
    143x cheaper than a call that solves."""
    from itg_vision import trajectory as traj
    from itg_vision.controllers import two_link_ik

    arm = ArmSpec.from_args("two-link")
    pts = traj.named("ellipse-t1", 720).points_mm
    goals = [(x, y, arm.led_standoff_mm) for x, y, _ in pts]
    solved = [np.array(two_link_ik(x, y, *arm.links_mm)[0]) for x, y, _ in pts]
    with World(arm) as w:
        landed = [forward_kinematics(arm, w.inverse_kinematics(g, start_q_deg=q))["gripper"]
                  for g, q in zip(goals, solved[-1:] + solved[:-1])]
    miss = np.linalg.norm(np.array(landed) - np.array(goals), axis=1)
    assert miss.max() < 0.1, (np.median(miss), miss.max())


# ------------------------------------------------------------ unequal links, the shoulder
from itg_vision import trajectory as T  # noqa: E402


def test_the_three_link_shoulder_is_where_pybullet_puts_joint_q2():
    """ArmSpec.shoulder_mm (line-ab-reach's centre, the nominal geometry's shoulder) against
    the URDF read back by PyBullet: the origin of joint q2's child frame, with unequal links
    (the shipped 100/100/100 arm cannot tell L1 from L2)."""
    import pybullet as p

    arm = ArmSpec.from_args("three-link", (130.0, 90.0, 70.0))
    with World(arm) as w:
        q2 = w._joints[1]
        pos = np.array(p.getLinkState(w.body, q2, physicsClientId=w.client)[4]) * 1e3
    np.testing.assert_allclose(arm.shoulder_mm(), pos, atol=1e-3)
    # and line-ab-reach about it: A' = s + 0.42 (A - s), by hand with s = (0, 0, 130)
    t = T.named("line-ab-reach", arm=arm)
    np.testing.assert_allclose(t.points_mm[0], [21.0, 12.6, 130 + 0.42 * 90], atol=1e-9)


@pytest.mark.parametrize("name", ["two-link", "three-link"])
def test_ik_of_unequal_links_puts_the_simulators_led_on_the_point(name):
    """Closed-form IK against the simulator: every branch it returns, set in PyBullet, puts
    the gripper LED on the point."""
    from itg_vision.controllers import InverseKinematics

    arm = ArmSpec.from_args(name, UNEQUAL[name])
    q_true = np.array([35.0, 50.0]) if arm.planar else np.array([35.0, 40.0, -60.0])
    with World(arm) as world:
        world.set_q(q_true)
        target = world.true_markers()["gripper"]
        sol = InverseKinematics(arm).solve(target, np.zeros(arm.n_joints))
        assert sol is not None
        world.set_q(sol)
        got = world.true_markers()["gripper"]
    dim = 2 if arm.planar else 3
    np.testing.assert_allclose(got[:dim], target[:dim], rtol=0, atol=1e-3)


@pytest.mark.parametrize("name, q", [("one-link", [30.0]), ("two-link", [40.0, -70.0]),
                                     ("three-link", [20.0, 60.0, -30.0])])
def test_the_gripper_led_of_a_set_point_is_where_the_forward_kinematics_puts_it(name, q):
    """A set point where a pose puts the gripper: a planar arm's in the joints' plane (z = 0),
    the three-link arm's the LED itself; gripper_led_mm gives the LED the pose carries there."""
    arm = ArmSpec.from_args(name)
    led = forward_kinematics(arm, q)["gripper"]
    set_point = np.r_[led[:2], 0.0] if arm.planar else led
    np.testing.assert_allclose(arm.gripper_led_mm(set_point), led, rtol=0, atol=roundoff(200))


@pytest.mark.parametrize("q", [[90.0], [90.0, 0.0, 45.0], [[90.0, 0.0]]])
def test_forward_kinematics_refuses_angles_of_another_count(q):
    """One angle for the two-link arm was broadcast to both joints: [90] gave the pose
    (90, 90) deg, gripper (-100, 100) mm, without a word; three failed as 'operands could not
    be broadcast'."""
    arm = ArmSpec.from_args("two-link")
    with pytest.raises(ValueError, match=r"^forward_kinematics: 2 joint angles \(deg\) expected "
                                         r"for arm two-link, got shape "):
        forward_kinematics(arm, q)


def test_every_call_that_reaches_pybullet_says_when_the_world_is_closed():
    """set_q and true_markers said 'the World is closed'; inverse_kinematics, render and
    set_led_lit failed inside PyBullet as "'NoneType' object cannot be interpreted as an
    integer"."""
    w = World(ArmSpec.from_args("two-link"))
    w.close()
    for call in (lambda: w.inverse_kinematics([100.0, 50.0, 12.0]),
                 lambda: w.render(8, 6, [0.0] * 16, [0.0] * 16),
                 lambda: w.set_led_lit("gripper", (1.0, 0.0, 0.0))):
        with pytest.raises(RuntimeError, match="^the World is closed$"):
            call()
