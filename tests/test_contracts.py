"""The contracts every part speaks: Markers, Step, the Controller and FeedbackSource protocols,
checked on every shipped controller and feedback source."""

import numpy as np
import pytest

from itg_vision.arm import ArmSpec
from itg_vision.contracts import Controller, FeedbackSource, Markers, Step
from itg_vision.controllers import make_controller
from itg_vision.feedback import ModelFeedback, TruthFeedback
from itg_vision.rules import load_rules


def test_markers_get_names_each_marker_and_refuses_others():
    m = Markers(np.array([1.0, 2, 3]), np.array([4.0, 5, 6]))
    assert m.get("gripper")[0] == 1.0 and m.get("elbow")[0] == 4.0
    with pytest.raises(KeyError, match="unknown marker 'wrist'"):
        m.get("wrist")


def test_rule_bases_get_the_encoders_only_if_a_rule_reads_a_joint_angle():
    links = (100.0, 100.0)
    assert not load_rules("table2", 2, links).uses_encoders
    from itg_vision.rules import RuleBase
    rb = RuleBase.from_text("RULE 1: IF q1 > 10 THEN q1 -= 1", 2, links)
    assert rb.uses_encoders and isinstance(rb, Controller)
    # without encoders a rule reading q sees NaN: its comparison is False, nothing moves
    m = Markers(np.zeros(3), np.zeros(3))
    assert rb.step(np.zeros(3), m, None).dq_deg.tolist() == [0.0, 0.0]
    assert rb.step(np.zeros(3), m, np.array([20.0, 0.0])).dq_deg.tolist() == [-1.0, 0.0]


def test_a_controller_that_flags_nothing_has_no_set_point_flagged():
    """README (summary.json's n_flagged: set points the controller flagged out of reach) and
    contracts.Step: a step is flagged only when the controller says so, so the Step(dq) of a
    controller of one's own that holds the arm flags none of its set points."""
    from itg_vision.loop import simulate
    from itg_vision.world import World

    class Still:
        uses_encoders = False

        def params(self):
            return {}

        def step(self, desired_mm, markers, q_deg):
            return Step(np.zeros(2))

    with World(ArmSpec.from_args("two-link")) as w:
        trace = simulate(w, Still(), TruthFeedback(), np.array([[100.0, 50.0, 0.0]] * 3))
    assert not trace.out_of_reach.any()


@pytest.mark.parametrize("name", ["ik", "jacobian"])
@pytest.mark.parametrize("arm_name", ["one-link", "two-link", "three-link"])
def test_baselines_follow_the_controller_protocol(name, arm_name):
    arm = ArmSpec.from_args(arm_name)
    ctrl = make_controller(name, arm, max_step_deg=5.0)
    assert isinstance(ctrl, Controller) and isinstance(ctrl.params(), dict)
    assert ctrl.uses_encoders == (name == "ik")


@pytest.mark.parametrize("make", [lambda arm: ModelFeedback(arm), lambda arm: TruthFeedback(0.5)],
                         ids=["model", "truth"])
def test_feedback_sources_follow_the_protocol_and_reproduce_with_a_seed(make):
    from itg_vision.world import World
    arm = ArmSpec.from_args("two-link")
    fb = make(arm)
    assert isinstance(fb, FeedbackSource)
    with World(arm) as world:
        runs = []
        for _ in range(2):
            fb.reset(7)
            runs.append([fb.observe(world) for _ in range(3)])
        truth = world.true_markers()
    for a, b in zip(*runs):
        assert isinstance(a, Markers) and np.array_equal(a.gripper_mm, b.gripper_mm)
        # every source estimates the true LED: the model exactly (nominal arm), noise within 5 sigma
        assert np.linalg.norm(a.gripper_mm - truth["gripper"]) < 5 * 0.5 * np.sqrt(3)


@pytest.mark.parametrize("feedback", ["truth", "vision"])
def test_a_feedback_source_never_reset_is_seeded(feedback):
    """A loop of one's own on a feedback source just built (README, "Your own controller")
    drew its noise from the OS's entropy: two such runs of the same loop differed (by up to
    0.3 mm of E_i under vision without added noise, whose sensor noise is drawn all the same).
    Now a source is built seeded with feedback.SEED, the numbers of reset(SEED)."""
    from itg_vision import trajectory
    from itg_vision.camera import Rig, default_rig_path
    from itg_vision.feedback import SEED, VisionFeedback
    from itg_vision.identify import nominal_geometry
    from itg_vision.loop import simulate
    from itg_vision.world import World

    arm = ArmSpec.from_args("two-link")
    rig = Rig.from_yaml(default_rig_path("two-link"))
    points = trajectory.load("ellipse-t1", 6, arm=arm).points_mm

    def run(reset):
        fb = TruthFeedback(0.5) if feedback == "truth" else VisionFeedback(rig, rig, arm,
                                                                            noise_px=1.0)
        if reset:
            fb.reset(SEED)
        with World(arm) as world:
            tracker = make_controller("jacobian", arm, nominal_geometry(arm), 20.0)
            return simulate(world, tracker, fb, points, max_step_deg=20.0).error_mm()

    first, second, seeded = run(False), run(False), run(True)
    assert np.array_equal(first, second) and np.array_equal(first, seeded)
