"""The start-up measurement (itg_vision/identify.py): what a run's controller learns of the arm
from the LEDs before it moves."""

import numpy as np

from itg_vision.arm import ArmSpec
from itg_vision.contracts import Markers
from itg_vision.feedback import TruthFeedback
from itg_vision.identify import measure_geometry
from itg_vision.world import World


class OneBadLook(TruthFeedback):
    """The simulator's truth, but its second look puts the gripper 40 mm farther out in y."""

    looks = 0

    def observe(self, world):
        m = super().observe(world)
        self.looks += 1
        if self.looks == 2:
            return Markers(m.gripper_mm + [0.0, 40.0, 0.0], m.elbow_mm, m.missed)
        return m


def test_start_up_takes_the_median_of_its_looks():
    """The two-link arm starts straight up (gripper at (0, 200), elbow at (0, 100)); of the
    looks at the start pose (identify.SAMPLES_PER_POSE, 5) one puts the gripper 40 mm farther
    out. Their median is a clean look, so the measured links are the clean measurement's, to
    rounding (1e-9 mm); a mean would lengthen the forearm by 40 / 5 = 8 mm."""
    arm = ArmSpec.from_args("two-link")
    with World(arm) as world:
        clean = measure_geometry(world, TruthFeedback(), arm)
        one_bad = measure_geometry(world, OneBadLook(), arm)
    np.testing.assert_allclose(one_bad.links_mm, clean.links_mm, rtol=0, atol=1e-9)


def test_a_failed_start_up_groups_its_misses_by_cause_not_by_measured_value():
    """Each look's miss reason carries its measured value ('blob area 0.30 of expected'); the
    failure counts looks per cause (the observation's cause code, not its text), so one cause
    is one entry however the value varies. The blob-area cause used to give one entry per
    ratio: its value was not in brackets, where the text's parser looked."""
    from types import SimpleNamespace

    from itg_vision.camera import Rig
    from itg_vision.detect import NOT_ROUND, Detection, expected_area_px
    from itg_vision.feedback import RESIDUAL, VisionFeedback
    from itg_vision.identify import _miss_cause
    from itg_vision.runner import CAMERAS_DIR
    from itg_vision.urdf import LED_RADIUS_MM

    rig = Rig.from_yaml(CAMERAS_DIR / "planar.yaml")
    fb = VisionFeedback(rig, rig, ArmSpec.from_args("one-link"))
    X = np.array([40.0, 120.0, 12.0])
    said, reasons = set(), set()
    for k in (0.30, 0.32, 0.33, 0.41):  # partly hidden LEDs, each a different blob area
        dets = tuple(Detection(True, c.project(X, distort=False), c.project(X),
                               k * expected_area_px(c, X, LED_RADIUS_MM)) for c in rig.cameras)
        _, _, why, causes = fb.triangulate({"gripper": dets})
        fb.last_observation = SimpleNamespace(causes=causes)
        said.add(_miss_cause(fb, "gripper"))
        reasons.add(why["gripper"])
    assert len(reasons) == 4 and said == {
        f"blob area under {fb.min_area_ratio:g} of expected: partly hidden (check the rig)"}

    def looked(cause):
        return SimpleNamespace(last_observation=SimpleNamespace(causes={"gripper": cause}),
                               dropout=0.0, noise_px=0.0, max_residual_px=2.0)

    assert _miss_cause(looked(NOT_ROUND), "gripper") == "not round (check the rig)"
    assert _miss_cause(looked(RESIDUAL), "gripper") == \
        "reprojection residual above 2 px (check the rig)"
