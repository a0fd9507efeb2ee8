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
    """Each look's miss reason carries its measured value ('not round (0.41)'); the failure
    counts looks per cause, so one cause is one entry however the value varies."""
    from types import SimpleNamespace

    from itg_vision.identify import _miss_cause

    def looked(reason):
        return SimpleNamespace(last_observation=SimpleNamespace(reasons={"gripper": reason}),
                               dropout=0.0, noise_px=0.0, max_residual_px=2.0)

    causes = {_miss_cause(looked(f"not round ({r:.2f}): partly hidden?"), "gripper")
              for r in (0.41, 0.7, 0.69)}
    assert causes == {"not round: partly hidden? (check the rig)"}
    assert _miss_cause(looked("residual 3.10 px"), "gripper") == \
        "reprojection residual above 2 px (check the rig)"
