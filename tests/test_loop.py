"""The loop: the servo limit, the set-point bookkeeping, and the trace's records."""

import dataclasses
import re
import time

import numpy as np
import pytest
from conftest import PYBULLET_RTOL, roundoff

from itg_vision.arm import REACH_TOL_MM, ArmSpec, forward_kinematics
from itg_vision.feedback import TruthFeedback
from itg_vision.loop import NOT_SAID, Session, Trace, simulate
from itg_vision.contracts import Controller, Markers, Step
from itg_vision.errors import UserError
from itg_vision.runner import RunConfig, execute, prepare
from itg_vision.trajectory import named
from itg_vision.world import World


class Constant:
    """A controller that always asks for the same joint step (deg); it records the joint
    angles it was given."""

    def __init__(self, dq, uses_encoders=False):
        self.dq = np.asarray(dq, float)
        self.uses_encoders = uses_encoders
        self.seen_q = []

    def params(self):
        return {}

    def step(self, desired_mm, markers, q_deg):
        self.seen_q.append(q_deg)
        return Step(self.dq.copy(), (7,), False)


@pytest.mark.parametrize("uses_encoders", [False, True])
def test_encoders_reach_only_controllers_that_declare_them(uses_encoders):
    arm = ArmSpec.from_args("two-link")
    ctrl = Constant([1.0, 0.0], uses_encoders=uses_encoders)
    assert isinstance(ctrl, Controller)
    with World(arm) as world:
        q0 = world.q_deg.copy()
        simulate(world, ctrl, TruthFeedback(), np.zeros((2, 3)), iterations=1)
    if uses_encoders:
        assert np.allclose(ctrl.seen_q[0], q0, rtol=0, atol=roundoff(180))
        assert np.allclose(ctrl.seen_q[1], q0 + [1.0, 0.0], rtol=0, atol=roundoff(180))
    else:
        assert ctrl.seen_q == [None, None]


@pytest.mark.parametrize("limit", [None, 0.5, 3.0])
def test_servo_limit_clips_each_joint_on_its_own(limit):
    arm = ArmSpec.from_args("two-link")
    pts = np.zeros((4, 3))
    with World(arm) as world:
        q0 = world.q_deg.copy()
        trace = simulate(world, Constant([10.0, -1.0]), TruthFeedback(), pts, iterations=3,
                         max_step_deg=limit)
    per_iteration = np.array([10.0, -1.0]) if limit is None else np.clip([10.0, -1.0], -limit, limit)
    moved = np.diff(np.vstack([q0, trace.q_deg]), axis=0)
    assert np.allclose(moved, 3 * per_iteration, rtol=0, atol=roundoff(180))  # 3 iterations per set point


@pytest.mark.parametrize("limit", [0, 0.0, -1.0, float("nan"), float("inf"), "2"])
def test_a_servo_limit_no_servo_has_is_refused_not_read_as_none(limit):
    """0 used to mean 'no limit' (a joint moved 119.6 deg in one iteration); None is no limit."""
    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(ValueError, match="max_step_deg must be a finite number > 0"):
            simulate(world, Constant([10.0, -1.0]), TruthFeedback(), np.zeros((2, 3)),
                     max_step_deg=limit)
        with pytest.raises(ValueError, match="iterations must be a whole number >= 1"):
            simulate(world, Constant([10.0, -1.0]), TruthFeedback(), np.zeros((2, 3)),
                     iterations=0)


def test_trace_records_one_entry_per_set_point_with_the_truth_after_it():
    arm = ArmSpec.from_args("two-link")
    pts = np.array([[100.0, 50.0, 0.0], [90.0, 60.0, 0.0], [80.0, 70.0, 0.0]])
    with World(arm) as world:
        trace = simulate(world, Constant([1.0, 2.0]), TruthFeedback(), pts, iterations=2,
                         tracking_start=1)
        after = world.true_markers()["gripper"]
    assert len(trace.records) == 3 and trace.fired == [(7,)] * 3
    assert np.allclose(trace.gripper_mm[-1], after, rtol=0, atol=roundoff(300))
    assert np.allclose(trace.error_mm(), np.linalg.norm((pts - trace.gripper_mm)[:, :2], axis=1),
                       rtol=0, atol=roundoff(300))
    m = trace.metrics()
    assert m["tracking_from"] == 1 and m["n_setpoints"] == 3
    assert m["track_max_mm"] == trace.error_mm()[1:].max()  # numpy's max of the same errors
    # estimates seen by the controller are ideal here: the estimation error is zero
    assert m["est_gripper_rms_mm"] == 0.0


def test_tracking_statistics_by_hand():
    """The held two-link gripper sits at (0, 200) (start pose straight up); set points e = 1,
    2, 3, 4, 100 mm below it leave E_i = e. Median: the 3rd of 5 (3; the mean is 22); p95:
    linear interpolation at rank 0.95 x 4 = 3.8, 4 + 0.8 x 96 = 80.8. The simulator's
    float32 positions: one ulp at 200 mm, 2.4e-5 mm (measured: 3.0e-6, 0.2 m in float32)."""
    e = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    pts = np.c_[np.zeros(5), 200.0 - e, np.zeros(5)]
    with World(ArmSpec.from_args("two-link")) as world:
        m = simulate(world, Constant([0.0, 0.0]), TruthFeedback(), pts, tracking_start=0).metrics()
    got = [m[f"track_{k}_mm"] for k in ("median", "mean", "p95", "max")]
    # each E_i within a float32 ulp of the gripper's 200 mm (PYBULLET_RTOL), and each statistic
    # a convex combination of E_i: that, plus float64 round-off at 200 mm
    tol = PYBULLET_RTOL * 200 + roundoff(200)
    assert got == pytest.approx([3.0, 22.0, 80.8, 100.0], rel=0, abs=tol)


def test_a_missed_marker_adds_no_estimation_error():
    """A missed marker's estimate is the held last one, not a measurement: it is counted as
    missed and left out of its estimation RMS (here 50 mm off the truth)."""
    trace = Trace(True, 2)
    truth = {"gripper": np.zeros(3), "elbow": np.zeros(3)}
    trace.observed(Markers(np.zeros(3), np.full(3, 50.0), missed=("elbow",)), truth)
    assert trace.est_err_mm == {"gripper": [0.0], "elbow": []} and trace.n_missed == 1


# ----------------------------------------------------------------- correction (loop.aim_mm)
def test_aim_is_the_set_point_at_full_correction_and_at_the_first_decision():
    from itg_vision.loop import aim_mm

    d, prev, g = np.array([10.0, 20.0, 0.0]), np.array([9.0, 19.0, 0.0]), np.array([8.0, 21.0, 12.0])
    assert np.array_equal(aim_mm(d, prev, g, 1.0, True), d)
    assert np.array_equal(aim_mm(d, None, g, 0.5, True), d)
    assert np.array_equal(aim_mm(d, prev, np.full(3, np.nan), 0.5, True), d)
    # the set point's motion (1, 1) fed forward, half the error left (1, -2) corrected: planar
    # arms leave z alone (the LED's stand-off), 3-D arms correct it too
    assert np.allclose(aim_mm(d, prev, g, 0.5, True), [9.5, 21.0, 0.0], rtol=0, atol=roundoff(21))
    assert np.allclose(aim_mm(d, prev, g, 0.5, False), [9.5, 21.0, 6.0], rtol=0, atol=roundoff(21))


@pytest.mark.parametrize("k", [1.0, 0.5, 0.25])
def test_correction_scales_the_eyes_noise_as_its_closed_form(k):
    """A fixed set point, an eye with Gaussian error sigma per axis, a tracker whose step lands
    where it aims (DLS, ~1 mm moves at 100 mm levers: 0.005 mm off). The true error then obeys
    e_k = (1 - k) e_(k-1) - k n_k, so in the plane E|e|^2 = 2 sigma^2 k / (2 - k): 2 sigma^2 at
    k = 1, a third of it at 0.5. Tolerance: |e|^2 is exponential (its std is its mean); each
    axis is AR(1) with coefficient 1 - k, so |e|^2 correlates from one set point to the next as
    r = (1 - k)^2, and the mean of n = 1900 has relative std sqrt((1 + r) / ((1 - r) n)): 2.3,
    3.0 and 4.3 % at k = 1, 0.5, 0.25. Bound: 4 of them (a noise 8 % too large fails at k = 1;
    the former flat 20 % let it pass)."""
    from itg_vision.controllers import JacobianTracker
    from itg_vision.identify import ArmGeometry

    sigma = 0.5
    tracker = JacobianTracker(ArmGeometry((1.0, 1.0), source="none"), True, 2)
    feedback = TruthFeedback(noise_mm=sigma)
    feedback.reset(7)
    with World(ArmSpec.from_args("two-link")) as world:
        trace = simulate(world, tracker, feedback, np.tile([120.0, 60.0, 0.0], (2000, 1)),
                         correction=k)
    e2 = trace.error_mm()[100:] ** 2
    expected = 2 * sigma**2 * k / (2 - k)
    r = (1 - k) ** 2
    tol = 4 * np.sqrt((1 + r) / ((1 - r) * len(e2)))
    assert abs(e2.mean() / expected - 1) < tol, (e2.mean(), expected, tol)


def test_reach_is_judged_on_the_set_point_not_on_the_aim():
    """The one-link arm's set points all lie on its circle, where Table 1's reach test allows
    w = 0.5 mm: with 0.5 mm of eye noise per axis, the aim at correction 0.5 leaves the circle
    by more than that now and then. Judged on the aim, those reachable set points were flagged
    and skipped (10 of the arc's set points at this seed, before the fix); judged on the set
    point, none is, as at correction 1. (ITG+ one-link no longer has the ring test.)"""
    counts = []
    for k in (1.0, 0.5):
        _, s = execute(prepare(RunConfig(arm="one-link", rules="table1", feedback="truth",
                                         noise_mm=0.5, correction=k, seed=3)))
        counts.append((s["n_flagged"], s["n_aim_out_of_reach"]))
    assert counts[0] == (0, 0) and counts[1][0] == 0
    assert counts[1][1] > 0  # the aims the rules refused are counted, and asked again


def test_set_points_on_the_circle_count_whatever_aims_off_it_the_tracker_keeps():
    """DLS never flags, so it keeps every aim. At correction 0.5 an aim is the set point less
    half the measured error, the eye's 2 mm per axis included: 1 mm of radial spread, so most
    aims leave the one-link arm's circle by more than REACH_TOL_MM. Its set points all lie on
    the circle: every one is in reach and counts."""
    trace, s = execute(prepare(RunConfig(arm="one-link", controller="jacobian", feedback="truth",
                                         noise_mm=2.0, correction=0.5, seed=3)))
    off = np.abs(np.hypot(trace.aim_mm[:, 0], trace.aim_mm[:, 1]) - 100.0)
    assert (off > REACH_TOL_MM).sum() > len(off) / 4
    assert s["n_out_of_reach"] == 0 and trace.in_reach.all()


def test_trace_rows_give_the_aim_beside_the_set_point():
    """trace.csv's xa_mm and ya_mm columns are where the controller was asked to go (here moved
    off the set point by a correction of 0.5 under 0.5 mm of eye noise), to the 4 decimals
    written (5e-5 mm)."""
    trace, _ = execute(prepare(RunConfig(feedback="truth", noise_mm=0.5, correction=0.5,
                                         points=60)))
    cols, rows = trace.rows()
    xy = np.array([[float(r[cols.index(c)]) for c in ("xa_mm", "ya_mm", "xd_mm", "yd_mm")]
                   for r in rows])
    # half the 4th decimal, plus the float64 round-off of writing and parsing ~100 mm
    written = 5e-5 + roundoff(100)
    np.testing.assert_allclose(xy[:, :2], trace.aim_mm[:, :2], rtol=0, atol=written)
    np.testing.assert_allclose(xy[:, 2:], trace.desired_mm[:, :2], rtol=0, atol=written)
    assert np.abs(xy[:, :2] - xy[:, 2:]).max() > 0.1


class ReachTest:
    """A controller with a reach test: it flags (and holds) any target farther than 150 mm from
    the base; otherwise it turns q1 by a tenth of the target's x (deg per mm). It records the
    targets it was asked for."""

    uses_encoders = False

    def __init__(self):
        self.asked = []

    def params(self):
        return {}

    def step(self, desired_mm, markers, q_deg):
        self.asked.append(np.array(desired_mm, float))
        far = float(np.linalg.norm(desired_mm[:2])) > 150.0
        return Step(np.array([0.0 if far else 0.1 * desired_mm[0], 0.0]), (1,), far)


def test_an_aim_out_of_reach_is_asked_again_with_the_set_point_and_recorded():
    """Aims 4x the set points (all out of this controller's reach, the set points in it): every
    decision is asked again with the set point, so the run is the run without aims, and the
    trace records the set point as the aim and the flag on every set point. Aims in reach are
    recorded as they were asked."""
    arm = ArmSpec.from_args("two-link")
    pts = np.array([[40.0, 30.0, 0.0], [-20.0, 60.0, 0.0], [10.0, -50.0, 0.0]])
    runs = []
    for aims in (None, 4 * pts, 1.5 * pts):
        with World(arm) as world:
            ctrl = ReachTest()
            runs.append((simulate(world, ctrl, TruthFeedback(), pts, aims_mm=aims), ctrl.asked))
    (plain, _), (far, asked), (near, _) = runs
    np.testing.assert_array_equal(far.q_deg, plain.q_deg)
    np.testing.assert_array_equal(far.aim_mm, pts)
    np.testing.assert_array_equal(plain.aim_mm, pts)
    np.testing.assert_array_equal(np.array(asked), np.repeat(pts, 2, axis=0) * np.tile([[4.0], [1.0]], (3, 1)))
    assert [r.flags for r in far.records] == [("aim_out_of_reach",)] * 3
    assert far.metrics()["n_aim_out_of_reach"] == 3 and far.metrics()["n_flagged"] == 0
    np.testing.assert_array_equal(near.aim_mm, 1.5 * pts)
    assert near.metrics()["n_aim_out_of_reach"] == 0
    assert not np.array_equal(near.q_deg, plain.q_deg)


def test_metrics_count_the_set_points_the_arm_reaches_whatever_the_controller_flags():
    """Table 2 told links of 40/40 mm (reach 80) drives the 100/100 mm arm along T1 (radius 24
    to 101 mm from the base): its RULE 0 flags the set points beyond 80 mm, which the arm
    reaches. They count, with the error the held arm left there."""
    trace, s = execute(prepare(RunConfig(feedback="model", links_mm=(40.0, 40.0),
                                         true_links_mm=(100.0, 100.0), points=60)))
    d = trace.desired_mm
    beyond = np.hypot(d[:, 0], d[:, 1]) > 80.0
    assert np.array_equal(trace.out_of_reach, beyond) and beyond.any()
    assert s["n_flagged"] == beyond.sum() and s["n_out_of_reach"] == 0
    assert s["e_av_mm"] == trace.error_mm().mean()  # numpy's mean of the same errors: exact


def test_every_controller_leaves_out_the_same_set_points_those_the_arm_cannot_reach():
    """An arm of 60/30 mm reaches 30 to 90 mm from the base; T1 runs 24 to 101 mm. Table 2 told
    the nominal 100/100 mm flags none; DLS flags nothing ever. Both leave out exactly the set
    points the arm cannot reach, counted by hand from the annulus (widened by REACH_TOL_MM);
    the tracking statistics too (T1's second half, the tracking phase, has some)."""
    out = {}
    for ctl in ("itg", "jacobian"):
        trace, s = execute(prepare(RunConfig(controller=ctl, feedback="truth" if ctl == "jacobian"
                                             else "model", true_links_mm=(60.0, 30.0),
                                             points=60)))
        r = np.hypot(trace.desired_mm[:, 0], trace.desired_mm[:, 1])
        outside = (r < 30.0 - REACH_TOL_MM) | (r > 90.0 + REACH_TOL_MM)
        assert outside.any() and not outside.all()
        assert np.array_equal(~trace.in_reach, outside)
        inside = trace.error_mm()[~outside]
        # the summary's numpy statistics of the same errors: exact once the set is the same
        assert s["e_av_mm"] == inside.mean()
        assert s["e_max_mm"] == inside.max()
        assert s["e_rms_mm"] == np.sqrt(np.mean(inside**2))
        k = trace.tracking_start
        late = trace.error_mm()[k:][~outside[k:]]
        assert outside[k:].any() and s["track_max_mm"] == late.max()
        assert s["track_median_mm"] == np.median(late)
        assert s["track_mean_mm"] == late.mean()
        assert s["track_p95_mm"] == np.percentile(late, 95)
        out[ctl] = s["n_out_of_reach"]
    assert out["itg"] == out["jacobian"] == outside.sum()


def test_the_three_link_led_reaches_what_its_pose_puts_it_at_and_no_farther():
    """The LED sits h = 12 mm beside the arm's plane: from the shoulder it reaches between
    sqrt((L2 - L3)^2 + h^2) and sqrt((L2 + L3)^2 + h^2), and never within h of the base axis."""
    from itg_vision.arm import forward_kinematics

    arm = ArmSpec.from_args("three-link")
    h, (L1, L2, L3) = arm.led_standoff_mm, arm.links_mm
    q = np.random.default_rng(0).uniform(-180, 180, (500, 3))
    assert all(arm.reachable(forward_kinematics(arm, p)["gripper"], 1e-6) for p in q)
    far = np.hypot(L2 + L3, h)
    for tol in (0.0, REACH_TOL_MM):  # the tolerance widens each boundary by itself, on the radius
        assert arm.reachable([far + tol - 1e-3, 0, L1], tol)
        assert not arm.reachable([far + tol + 1e-3, 0, L1], tol)
        assert arm.reachable([h - tol + 1e-3, 0, L1 + 150], tol)
        assert not arm.reachable([h - tol - 1e-3, 0, L1 + 150], tol)


def test_a_one_link_path_rounded_in_its_file_is_in_reach_and_one_a_mm_off_is_not(tmp_path):
    """The one-link arm reaches only its 100 mm circle. A circle written with 2 decimals lies
    off it by up to 0.007 mm: in reach (REACH_TOL_MM, the paper's w = 0.5 mm). A circle of
    101 mm is 1 mm off: every set point out of reach, and a run of it alone is refused."""
    a = np.radians(np.linspace(0.0, 90.0, 30))

    def run(radius, extra=""):
        path = tmp_path / f"circle-{radius:g}.csv"
        path.write_text("x_mm,y_mm\n" + extra + "".join(
            f"{radius * np.cos(t):.2f},{radius * np.sin(t):.2f}\n" for t in a))
        return execute(prepare(RunConfig(arm="one-link", feedback="model",
                                         trajectory=str(path))))[1]["n_out_of_reach"]

    far = 100.0 + 2 * REACH_TOL_MM
    assert run(100.0) == 0
    assert run(far, extra="0,100\n") == len(a)  # one set point on the circle first
    with pytest.raises(UserError, match=f"none of the {len(a)} set points of .* is in reach"):
        run(far)


def test_planar_comes_from_the_arm_and_a_contradiction_is_refused():
    """simulate's planar used to default to True: a three-link run was scored in x-y (a helper
    measured E_av 3.6 against 25.3 mm in space). It now comes from the world's arm; a value
    that contradicts the arm is refused."""
    arm = ArmSpec.from_args("three-link")
    pts = np.tile(forward_kinematics(arm, arm.start_q_deg)["gripper"] + [0.0, 0.0, -30.0], (3, 1))
    with World(arm) as world:
        trace = simulate(world, Constant([0.0, 0.0, 0.0]), TruthFeedback(), pts)
    assert not trace.planar
    # straight down: 0 in x-y; the gripper a float32 ulp off at its 270 mm from the base
    reach = np.linalg.norm(pts[0])
    assert trace.error_mm() == pytest.approx([30.0] * 3, rel=0,
                                             abs=PYBULLET_RTOL * reach + roundoff(reach))
    with World(arm) as world:
        with pytest.raises(ValueError, match="planar=True, but arm three-link is not planar"):
            simulate(world, Constant([0.0, 0.0, 0.0]), TruthFeedback(), pts, planar=True)


class _Returns:
    uses_encoders = False

    def __init__(self, value):
        self.value = value

    def params(self):
        return {}

    def step(self, desired_mm, markers, q_deg):
        return self.value


class _Sees:
    def __init__(self, value):
        self.value = value

    def observe(self, world):
        return self.value(world.true_markers())


@pytest.mark.parametrize("returned, error, said", [
    (np.zeros(2), TypeError, "controller.step must return itg_vision.contracts.Step, got ndarray"),
    (Step(np.array([5.0])), ValueError, r"Step.dq_deg: 2 real joint increments \(deg\) expected, "
                                        r"got shape \(1,\) of float64"),
    (Step(np.zeros(3)), ValueError, r"got shape \(3,\)"),
    (Step(np.array(["1", "2"])), ValueError, r"got shape \(2,\) of <U1"),
    (Step([True, False]), ValueError, r"got shape \(2,\) of bool"),
    (Step(np.array([1 + 1j, 0])), ValueError, r"got shape \(2,\) of complex128"),
])
def test_a_controller_that_breaks_the_contract_is_told_in_one_line(returned, error, said):
    """A one-element step used to move every joint (broadcast), a three-element one failed
    deep in the world, an array failed as a missing attribute; "1" and True moved a joint by
    1 deg, and 1+1j by 1 deg with a ComplexWarning (the env refused them as actions)."""
    with World(ArmSpec.from_args("two-link")) as world:
        q0 = world.q_deg.copy()
        with pytest.raises(error, match=said):
            simulate(world, _Returns(returned), TruthFeedback(), np.zeros((2, 3)))
        assert np.array_equal(world.q_deg, q0)  # nothing moved


@pytest.mark.parametrize("seen, said", [
    (lambda t: t, "got dict"),
    (lambda t: Markers(t["gripper"], t["elbow"], missed="gripper"), "missed='gripper'"),
    (lambda t: Markers(t["gripper"][:2], t["elbow"][:2]),
     r"gripper_mm of shape \(2,\), elbow_mm of shape \(2,\)"),
    (lambda t: Markers(t["gripper"], t["elbow"], missed=("grip",)), r"missed=\('grip',\)"),
    (lambda t: Markers(t["gripper"], t["elbow"], missed=("elbow",), missed_why="hidden"),
     "missed_why='hidden'"),
])
def test_a_feedback_that_breaks_the_contract_is_told_in_one_line(seen, said):
    """A dict used to fail as a missing 'timing_ms'; missed='gripper' (a string) counted five
    misses per look, one per letter; x, y alone (shape (2,)) failed deep in the trace as
    'operands could not be broadcast'; a missed 'grip' left the gripper taken as measured; a
    missed_why that is not a dict would fail as the trace counts it."""
    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(TypeError, match=f"feedback.observe must return itg_vision.contracts"
                                            f".Markers .*{said}"):
            simulate(world, Constant([0.0, 0.0]), _Sees(seen), np.zeros((2, 3)))


class _LosesLooks(TruthFeedback):
    """The simulator's LEDs, but the looks numbered by ``lost`` (1-based; default every second
    one: the 2nd, 4th, ...) miss ``marker`` and hand on its last estimate, as the stereo eye
    does when it loses an LED (NaN before any look saw it)."""

    def __init__(self, marker, lost=lambda n: n % 2 == 0):
        super().__init__()
        self.marker, self.lost, self.looks, self.last = marker, lost, 0, None

    def observe(self, world):
        m = super().observe(world)
        self.looks += 1
        if not self.lost(self.looks):
            self.last = m
            return m
        field = f"{self.marker}_mm"
        last = np.full(3, np.nan) if self.last is None else getattr(self.last, field)
        return dataclasses.replace(m, **{field: last}, missed=(self.marker,))


class _Spy(Constant):
    """A Constant controller that also records the aims and the gripper estimates it was given."""

    def __init__(self, dq):
        super().__init__(dq)
        self.aims, self.grippers = [], []

    def step(self, desired_mm, markers, q_deg):
        self.aims.append(np.array(desired_mm, float))
        self.grippers.append(np.array(markers.gripper_mm, float))
        return super().step(desired_mm, markers, q_deg)


def test_a_look_that_lost_the_gripper_is_given_the_last_aim():
    """The error d - g is what a step answers, and the stale estimate's error was answered by
    the step before: at a look that missed the gripper the controller is given, for the
    gripper, where its last decision aimed (a preview's plan here, not the set point), x and y
    for a planar arm with the LED's height kept; every other look gets the eye's estimate."""
    arm = ArmSpec.from_args("two-link")
    points = np.column_stack([np.linspace(120.0, 150.0, 6), np.linspace(40.0, 80.0, 6),
                              np.zeros(6)])
    aims = points + [3.0, -2.0, 5.0]
    ctrl = _Spy([1.0, -1.0])
    with World(arm) as world:
        trace = simulate(world, ctrl, _LosesLooks("gripper"), points, aims_mm=aims)
    assert np.allclose(ctrl.aims, aims)
    seen = [r.true_at_estimate_mm["gripper"] for r in trace.records]
    for k in range(6):
        if k % 2 == 0:  # measured (truth feedback)
            assert np.allclose(ctrl.grippers[k], seen[k])
            assert "at_last_aim" not in trace.records[k].flags
        else:
            assert np.allclose(ctrl.grippers[k][:2], aims[k - 1][:2])
            assert ctrl.grippers[k][2] == pytest.approx(seen[k - 1][2])  # the stale LED's height
            assert not np.allclose(ctrl.grippers[k][:2], seen[k][:2], atol=1.0)
            assert {"at_last_aim", "missed:gripper"} <= set(trace.records[k].flags)
            assert np.allclose(trace.records[k].estimate.gripper_mm, ctrl.grippers[k])  # recorded
    assert (trace.metrics()["n_at_last_aim"], trace.metrics()["n_held"]) == (3, 0)
    assert np.allclose(trace.records[-1].q_deg - trace.records[0].q_deg, [5.0, -5.0])  # all decide


class _ElbowSpy(Constant):
    """A Constant controller that records the elbow estimates it was given."""

    def __init__(self, dq):
        super().__init__(dq)
        self.elbows = []

    def step(self, desired_mm, markers, q_deg):
        self.elbows.append(np.array(markers.elbow_mm, float))
        return super().step(desired_mm, markers, q_deg)


@pytest.mark.parametrize("offset_deg", [0.0, 7.0])
def test_a_lost_elbow_is_its_last_measured_position_turned_with_the_base(offset_deg):
    """A planar arm's elbow moves with q1 alone: from its last measured position turned about
    the base axis by q1's commanded turn since, it is where the simulator has it (PyBullet's
    float32, a few ulps at 100 mm), whatever q2 did, and with a joint offset the commanded
    angles do not know of (7 deg: only turns count). Looks 3-8 lose it (6 in a row: 1.5 deg
    of q1 a look, 9 deg in all); the first look and the others measure it. Left out, the
    controller is handed the last measurement however old: at the sixth lost look, the chord of
    9 deg at L1 = 100 mm, 2 x 100 x sin(4.5 deg) = 15.7 mm off."""
    arm = dataclasses.replace(ArmSpec.from_args("two-link"), joint_offset_deg=(offset_deg, 0.0))
    points = np.zeros((10, 3))
    lost = lambda n: 3 <= n <= 8  # noqa: E731

    def run(base_axis_mm):
        ctrl = _ElbowSpy([1.5, -4.0])
        with World(arm) as world:
            trace = simulate(world, ctrl, _LosesLooks("elbow", lost), points,
                             base_axis_mm=base_axis_mm)
        return ctrl.elbows, trace

    elbows, trace = run((0.0, 0.0))
    truth = [r.true_at_estimate_mm["elbow"] for r in trace.records]
    tol = 8 * PYBULLET_RTOL * 100.0
    for k in range(10):
        assert np.allclose(elbows[k], truth[k], rtol=0, atol=tol), (k, elbows[k] - truth[k])
        assert ("elbow_turned" in trace.records[k].flags) == lost(k + 1)
    assert trace.metrics()["n_elbow_turned"] == 6
    assert trace.metrics()["n_missed_by"] == {"gripper": 0, "elbow": 6}  # which LED was missed
    # a feedback that does not say why (Markers.missed_why empty): counted as such
    assert trace.metrics()["n_missed_why"] == {"gripper": {}, "elbow": {NOT_SAID: 6}}
    held, trace = run(None)
    off = np.linalg.norm(held[7] - truth[7])
    assert off == pytest.approx(2 * 100.0 * np.sin(np.radians(4.5)), abs=tol)
    assert trace.metrics()["n_elbow_turned"] == 0
    assert all(np.allclose(held[k], held[1]) for k in range(2, 8))


def test_a_lost_elbow_is_turned_about_the_axis_given():
    """The turn is about the base axis given (the one the start-up measured), not the world's
    origin: with the axis 10 mm off, the turned elbow is off the truth by the chord that offset
    sweeps, 2 x 10 x sin(turn / 2) (closed form), at each of the lost looks."""
    arm = ArmSpec.from_args("two-link")
    ctrl = _ElbowSpy([2.0, 0.0])
    with World(arm) as world:
        trace = simulate(world, ctrl, _LosesLooks("elbow", lambda n: n >= 2), np.zeros((5, 3)),
                         base_axis_mm=(10.0, 0.0))
    truth = [r.true_at_estimate_mm["elbow"] for r in trace.records]
    for k in range(1, 5):
        chord = 2 * 10.0 * np.sin(np.radians(2.0 * k) / 2)
        assert np.linalg.norm(ctrl.elbows[k] - truth[k]) == pytest.approx(chord, abs=1e-4)


def test_each_arm_is_given_the_axes_its_elbow_turns_about():
    """A planar arm's elbow turns about the base axis alone; the three-link elbow about the
    shoulder's axis too, which turns with the base: each refuses the other's."""
    with World(ArmSpec.from_args("three-link")) as world:
        with pytest.raises(ValueError, match="base_axis_mm turns a planar arm's lost elbow.*"
                                             "give pitch_axis_mm"):
            simulate(world, Constant([0.0, 0.0, 0.0]), TruthFeedback(), np.zeros((2, 3)),
                     base_axis_mm=(0.0, 0.0))
        with pytest.raises(ValueError, match="unit direction"):
            simulate(world, Constant([0.0, 0.0, 0.0]), TruthFeedback(), np.zeros((2, 3)),
                     pitch_axis_mm=((0.0, 0.0, 100.0), (2.0, 0.0, 0.0)))
    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(ValueError, match="pitch_axis_mm turns a three-link arm's lost elbow"):
            simulate(world, Constant([0.0, 0.0]), TruthFeedback(), np.zeros((2, 3)),
                     pitch_axis_mm=((0.0, 0.0, 100.0), (1.0, 0.0, 0.0)))
        with pytest.raises(ValueError, match=r"elbow_seen: \(elbow \(x, y, z\) in mm, the 2 "):
            simulate(world, Constant([0.0, 0.0]), TruthFeedback(), np.zeros((2, 3)),
                     base_axis_mm=(0.0, 0.0), elbow_seen=((100.0, 0.0, 0.0), (0.0, 0.0, 0.0)))


def _three_link_axes(arm):
    """The three-link shoulder axis as the start-up measures it, from the simulator's LEDs, with
    the arm straight up and the base at 25 deg (the axis is turned back to the base's 0)."""
    from itg_vision.identify import measure_geometry

    with World(arm) as world:
        world.set_q([25.0, 90.0, 0.0])
        geometry = measure_geometry(world, TruthFeedback(), arm)
    return np.array(geometry.shoulder_mm), np.array(geometry.pitch_axis)


@pytest.mark.parametrize("offset_deg", [0.0, 7.0])
def test_the_measured_shoulder_axis_moves_the_elbow_as_the_simulator_does(offset_deg):
    """The start-up's shoulder axis a (the elbow's circle's normal, oriented by the sweep)
    against finite differences of the simulator: a small q2 step moves the elbow LED by
    a x (elbow - shoulder) dq2, with the base at 0 and at 40 deg (a turned with it from the
    base's 0), and with joint offsets the commanded angles do not know of. A reversed axis is
    off by twice the motion, an axis 25 deg off (as the start-up saw it, not turned back to the
    base's 0) by 2 sin(12.5 deg) = 0.43 of it."""
    from itg_vision.identify import turn_about

    arm = dataclasses.replace(ArmSpec.from_args("three-link"),
                              joint_offset_deg=(offset_deg, -offset_deg, 0.0))
    shoulder, axis = _three_link_axes(arm)
    dq = 0.01  # deg: the motion 100 x 1.7e-4 = 0.017 mm, its second order 1.5e-6 mm
    with World(arm) as world:
        for q1 in (0.0, 40.0):
            q = np.array([q1, 60.0, -30.0])
            world.set_q(q)
            e0 = world.true_markers()["elbow"]
            world.set_q(q + [0.0, dq, 0.0])
            moved = world.true_markers()["elbow"] - e0
            a = turn_about([0.0, 0.0, 1.0], q1) @ axis
            predicted = np.radians(dq) * np.cross(a, e0 - shoulder)
            # float32 positions: a few ulps of 200 mm in each look and in the start-up's fits
            tol = 8 * PYBULLET_RTOL * 200.0
            assert np.allclose(moved, predicted, rtol=0, atol=tol), (q1, moved, predicted)
            assert np.linalg.norm(moved) > 0.015


@pytest.mark.parametrize("offset_deg", [0.0, 7.0])
def test_a_three_link_lost_elbow_is_turned_with_the_shoulder_and_the_base(offset_deg):
    """The three-link elbow moves with q1 and q2 alone: its last measured position turned about
    the measured shoulder axis (as the base had turned it then) by q2's commanded turn since,
    and about the base axis by q1's, is where the simulator has it (to the float32 of its
    looks and of the start-up's fits), with joint offsets the commanded angles do not know of.
    The base turns before the elbow is lost (looks 1-2), so an axis left as the start-up saw it
    would be wrong. Looks 3-8 lose it (q1 1.5, q2 -4, q3 3 deg a look); held instead, it is
    tens of mm off: 24 deg of q2 at 100 mm is a 41.6 mm chord."""
    arm = dataclasses.replace(ArmSpec.from_args("three-link"),
                              joint_offset_deg=(offset_deg, -offset_deg, offset_deg))
    shoulder, axis = _three_link_axes(arm)
    lost = lambda n: 3 <= n <= 8  # noqa: E731

    def run(pitch_axis_mm):
        ctrl = _ElbowSpy([1.5, -4.0, 3.0])
        with World(arm) as world:
            world.set_q([10.0, 60.0, -30.0])
            trace = simulate(world, ctrl, _LosesLooks("elbow", lost), np.zeros((10, 3)),
                             pitch_axis_mm=pitch_axis_mm)
        return ctrl.elbows, trace

    elbows, trace = run((shoulder, axis))
    truth = [r.true_at_estimate_mm["elbow"] for r in trace.records]
    tol = 8 * PYBULLET_RTOL * 200.0  # float32 looks (ulps of 200 mm), and the fits on them
    for k in range(10):
        assert np.allclose(elbows[k], truth[k], rtol=0, atol=tol), (k, elbows[k] - truth[k])
        assert ("elbow_turned" in trace.records[k].flags) == lost(k + 1)
    assert trace.metrics()["n_elbow_turned"] == 6
    held, trace = run(None)
    assert np.linalg.norm(held[7] - truth[7]) > 30.0
    assert trace.metrics()["n_elbow_turned"] == 0


class _AxisSpy(Constant):
    """A Constant controller that records the pitch axis each look carried, and the joints."""

    def __init__(self, dq):
        super().__init__(dq, uses_encoders=True)
        self.axes, self.q = [], []

    def step(self, desired_mm, markers, q_deg):
        self.axes.append(None if markers.pitch_axis is None else np.array(markers.pitch_axis))
        self.q.append(np.array(q_deg, float))
        return super().step(desired_mm, markers, q_deg)


@pytest.mark.parametrize("offset_deg", [0.0, 7.0])
def test_each_three_link_look_carries_the_pitch_axis_turned_with_the_base(offset_deg):
    """The pitch axis the loop keeps (Session.kept_pitch_axis): the start-up's measured shoulder
    axis turned about the vertical by the base's commanded angle is the simulator's own,
    arm.model_pitch_axis at the true base angle, look by look while the base turns 25 deg a look
    through a full turn and more, with joint offsets the commanded angles do not know of. The
    start-up's fit from float32 looks leaves it within 1e-4 rad; an axis not turned with the
    base is 25 deg off after one look, a reversed one 180. Without pitch_axis_mm no look
    carries one."""
    from itg_vision.arm import model_pitch_axis

    arm = dataclasses.replace(ArmSpec.from_args("three-link"),
                              joint_offset_deg=(offset_deg, -offset_deg, offset_deg))
    shoulder, axis = _three_link_axes(arm)
    ctrl = _AxisSpy([25.0, -1.0, 1.0])
    with World(arm) as world:
        world.set_q([10.0, 60.0, -30.0])
        simulate(world, ctrl, TruthFeedback(), np.zeros((18, 3)), pitch_axis_mm=(shoulder, axis))
    for kept, q in zip(ctrl.axes, ctrl.q):
        true = model_pitch_axis(arm, q[0])
        assert kept[2] == 0.0 and np.linalg.norm(kept) == pytest.approx(1.0, abs=1e-12)
        assert np.degrees(np.arccos(min(1.0, kept @ true))) < np.degrees(1e-4), (q, kept, true)
    assert ctrl.q[-1][0] - ctrl.q[0][0] == pytest.approx(17 * 25.0)  # more than a full turn
    ctrl = _AxisSpy([25.0, -1.0, 1.0])
    with World(arm) as world:
        simulate(world, ctrl, TruthFeedback(), np.zeros((3, 3)))
    assert ctrl.axes == [None] * 3


def test_a_look_lost_before_any_decision_holds_the_joints():
    """No decision yet, no aim: the joints hold for that iteration, flagged and counted."""
    arm = ArmSpec.from_args("two-link")
    ctrl = _Spy([1.0, -1.0])

    class LosesTheFirstLook(TruthFeedback):
        looks = 0

        def observe(self, world):
            self.looks += 1
            m = super().observe(world)
            return dataclasses.replace(m, missed=("gripper",)) if self.looks == 1 else m

    with World(arm) as world:
        q0 = world.q_deg.copy()
        trace = simulate(world, ctrl, LosesTheFirstLook(), np.zeros((3, 3)))
    assert len(ctrl.aims) == 2
    assert np.allclose(trace.records[0].q_deg, q0) and "held" in trace.records[0].flags
    assert (trace.metrics()["n_held"], trace.metrics()["n_at_last_aim"]) == (1, 0)


def _itg_plus_on_t1(**config):
    """``itg-plus-two-link`` on T1 with ideal LEDs under the arm file's 20 deg servo limit,
    bound to the nominal lengths: (the prepared run, the controller)."""
    from itg_vision.identify import nominal_geometry
    from itg_vision.runner import bind_geometry

    prep = prepare(RunConfig(rules="itg-plus-two-link", feedback="truth", max_step_deg=20.0,
                             **config))
    return prep, bind_geometry(prep.controller, nominal_geometry(prep.model), prep.model, 20.0)


def test_a_lost_look_after_the_aim_was_reached_repeats_no_step():
    """Acting on the stale estimate repeated the step already taken (the T1 start's 20 deg steps
    twice over). A rule base that reaches its aim within its dead band, given two iterations
    per set point whose second look loses the gripper, is asked the same set point again from
    its aim and steps nothing: the one-iteration run, joint for joint."""
    prep, ctrl = _itg_plus_on_t1(points=24)
    points = prep.trajectory.points_mm
    with World(prep.model) as world:
        lossy = simulate(world, ctrl, _LosesLooks("gripper"), points, iterations=2,
                         max_step_deg=20.0)
    with World(prep.model) as world:
        clean = simulate(world, ctrl, TruthFeedback(), points, iterations=1, max_step_deg=20.0)
    assert np.array_equal(np.array([r.q_deg for r in lossy.records]),
                          np.array([r.q_deg for r in clean.records]))
    assert all("at_last_aim" in r.flags and "missed:gripper" in r.flags for r in lossy.records)
    assert (lossy.metrics()["n_at_last_aim"], clean.metrics()["n_at_last_aim"]) == (len(points), 0)
    assert np.max(np.abs(np.diff([r.q_deg for r in clean.records], axis=0))) > 5.0  # it moves


def test_losing_every_second_gripper_look_costs_a_tracker_that_reaches_its_aims_little():
    """ITG+ on T1 (2 laps, ideal LEDs, the arm file's 20 deg servo limit) losing the gripper at
    every second look. Answered with the last aim, an unseen look leaves the error the seen one
    left plus the rules' own error on one more step, so the tracking max is at most twice the
    clean run's. Holding the joints lagged the path by a set point's spacing (1.4-2.3 mm here:
    max 2.35 mm measured on the hold's code), deciding on the stale estimate repeated steps."""
    prep, ctrl = _itg_plus_on_t1(laps=2)
    points = prep.trajectory.points_mm
    runs = {}
    for name, eye in (("clean", TruthFeedback()), ("lossy", _LosesLooks("gripper"))):
        with World(prep.model) as world:
            runs[name] = simulate(world, ctrl, eye, points, max_step_deg=20.0).metrics()
    assert runs["lossy"]["n_at_last_aim"] == len(points) // 2
    assert runs["lossy"]["track_max_mm"] <= 2.0 * runs["clean"]["track_max_mm"]
    spacing = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1).min()
    assert 2.0 * runs["clean"]["track_max_mm"] < 0.2 * spacing  # the bound tells the hold apart


def test_a_look_that_lost_only_the_elbow_decides():
    """An elbow estimate one look old still gives the levers: the controller is asked at every
    look, and the arm moves at every iteration (a pose that hides the elbow for good would
    stall a loop that held on it)."""
    arm = ArmSpec.from_args("two-link")
    ctrl = Constant([1.0, -1.0])
    with World(arm) as world:
        trace = simulate(world, ctrl, _LosesLooks("elbow"), np.zeros((3, 3)),
                         iterations=2)
    assert len(ctrl.seen_q) == 6
    assert np.allclose(trace.records[-1].q_deg - trace.records[0].q_deg, [2.0 * 2, -2.0 * 2])
    assert not any({"held", "at_last_aim"} & set(r.flags) for r in trace.records)
    assert all("missed:elbow" in r.flags for r in trace.records)


def test_an_open_loop_controller_is_not_held_by_a_missed_first_look():
    """IK ignores the estimates (``uses_markers = False``), yet a first look that missed the
    gripper held it for a step, as it holds every closed-loop controller: `run --controller ik
    --dropout 0.5` had E_av 1.58 mm where the clean run has 1.5e-06 (an audit's finding). Now
    its run is the clean run's, joint for joint, and nothing is flagged held; a closed-loop
    controller is still held."""
    from itg_vision.controllers import InverseKinematics

    def loses_first():  # the first look misses the gripper, as no look before
        return _LosesLooks("gripper", lost=lambda n: n == 1)

    arm = ArmSpec.from_args("two-link")
    points = np.array([[120.0, 40.0, 0.0], [125.0, 45.0, 0.0], [130.0, 50.0, 0.0]])
    runs = {}
    for name, eye in (("clean", TruthFeedback()), ("lost", loses_first())):
        with World(arm) as world:
            runs[name] = simulate(world, InverseKinematics(arm), eye, points)
    assert runs["lost"].n_held == 0 and "missed:gripper" in runs["lost"].records[0].flags
    assert not any("held" in r.flags or "at_last_aim" in r.flags for r in runs["lost"].records)
    assert np.array_equal(np.array([r.q_deg for r in runs["lost"].records]),
                          np.array([r.q_deg for r in runs["clean"].records]))
    with World(arm) as world:  # a closed-loop controller: held
        held = simulate(world, Constant([1.0, -1.0]), loses_first(), points)
    assert held.n_held == 1 and "held" in held.records[0].flags
    with World(arm) as world:  # IK whose aim a correction < 1 makes read the gripper: held
        held = simulate(world, InverseKinematics(arm), loses_first(), points, correction=0.5)
    assert held.n_held == 1


def test_a_look_lost_after_a_set_point_out_of_reach_is_given_where_the_arm_stayed():
    """A step flagged out of reach holds the arm (the rule bases return zeros): it aimed at
    nothing. A lost look right after it is given, for the gripper, where that decision saw it,
    not the set point it refused (260 mm out on a 200 mm arm: the rules then answered an error
    from a point the arm never reached). With ideal LEDs that is where the arm is, so the run
    follows the joint path of the run whose look was not lost, to the last bit."""
    prep, ctrl = _itg_plus_on_t1()
    points = np.array([[120.0, 40.0, 0.0], [260.0, 0.0, 0.0], [125.0, 45.0, 0.0],
                       [130.0, 50.0, 0.0]])
    runs = {}
    lose_third = _LosesLooks("gripper", lost=lambda n: n == 3)
    for name, eye in (("clean", TruthFeedback()), ("lossy", lose_third)):
        with World(prep.model) as world:
            runs[name] = simulate(world, ctrl, eye, points, max_step_deg=20.0)
    lossy, clean = runs["lossy"], runs["clean"]
    assert "out_of_reach" in lossy.records[1].flags
    assert np.array_equal(lossy.records[1].q_deg, lossy.records[0].q_deg)  # it held
    assert {"at_last_aim", "missed:gripper"} <= set(lossy.records[2].flags)
    assert np.allclose(lossy.records[2].estimate.gripper_mm, lossy.records[1].estimate.gripper_mm)
    assert np.array_equal(np.array([r.q_deg for r in lossy.records]),
                          np.array([r.q_deg for r in clean.records]))


def test_finite_steps_that_overflow_a_joint_angle_are_one_line():
    """Each step finite, their sum not: q1 += 1e308 twice (no servo limit) ended in World's
    ValueError traceback, exit 1. Now a UserError naming the set point, the joint and the rules
    that fired, with their file and line (they were numbers alone, the file unnamed: an
    audit's finding), before the arm moves."""
    from itg_vision.rules import RuleBase

    arm = ArmSpec.from_args("two-link")
    rb = RuleBase.from_text("# mine\nRULE 7: IF 1 > 0 THEN q1 += 1e308, q2 HOLD", 2, arm.links_mm,
                            source="mine.rules")
    with World(arm) as world:
        with pytest.raises(UserError, match=r"^set point k = 1: joint q1 would turn to inf deg "
                                            r"\(from 1e\+308 by 1e\+308; rules fired: RULE 7 "
                                            r"\(mine\.rules:2\)\): no "
                                            r"joint angle is that; bound each step with "
                                            r"the servo limit \(max_step_deg; run's "
                                            r"--max-step\)$"):
            simulate(world, rb, TruthFeedback(), np.array([[100.0, 0.0, 0.0]] * 3))
        assert np.all(np.isfinite(world.q_deg))


def test_a_step_that_is_not_a_number_is_said_to_be_the_controllers_not_a_missing_limit():
    """A controller of one's own returning a NaN step was told to bound its steps with
    --max-step, a command-line option no library caller has and no servo limit can mend."""

    class NaNStep:
        uses_encoders = False

        def step(self, desired_mm, markers, q_deg):
            return Step(np.array([np.nan, 0.0]))

    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(UserError, match=r"^set point k = 0: joint q1 would turn to nan deg .*: "
                                            r"no joint angle is that; the controller's step is "
                                            r"not a number \(NaN\): the step itself is wrong$"):
            simulate(world, NaNStep(), TruthFeedback(), np.array([[100.0, 0.0, 0.0]] * 2),
                     max_step_deg=20.0)


class _Hold:
    """Holds every joint: E_i is where each set point was put."""

    uses_encoders = False

    def step(self, desired_mm, markers, q_deg):
        return Step(np.zeros(2))


def _held_metrics(e_mm, tracking_start):
    """The two-link gripper held at (0, 200) mm, set points e mm below it: E_i = e."""
    e = np.asarray(e_mm, float)
    points = np.c_[np.zeros(len(e)), 200.0 - e, np.zeros(len(e))]
    with World(ArmSpec.from_args("two-link")) as world:
        return simulate(world, _Hold(), TruthFeedback(), points,
                        tracking_start=tracking_start).metrics()


def test_diverged_is_the_tracking_median_above_the_line_not_the_mean():
    """E_i 1, 2, 3, 50, 100: median 3, mean 31.2 (above 20): a run with a tail, not a
    divergence (18 stored sweep rows are such); 1, 30, 30, 30, 1: median 30, diverged."""
    assert _held_metrics([1, 2, 3, 50, 100], 0)["diverged"] is False
    assert _held_metrics([1, 30, 30, 30, 1], 0)["diverged"] is True


def test_e_max_is_over_the_whole_run_and_the_tracking_max_over_its_phase():
    """E_max includes the start's transient (the paper's E_max: experiment 6 quotes it as
    the start's); the tracking max does not."""
    m = _held_metrics([100, 1, 2, 3, 4], 3)
    tol = PYBULLET_RTOL * 200  # PyBullet's float32 link frames, at 200 mm from the base
    assert m["e_max_mm"] == pytest.approx(100, abs=tol)
    assert m["track_max_mm"] == pytest.approx(4, abs=tol)


# ------------------------------------------------- each set point's own records, units, E_i
class _Counting(Constant):
    """Call i fires rule i and flags out of reach where ``flag(i)`` says; it may take
    ``sleep_s`` to decide."""

    def __init__(self, dq, flag=lambda i: False, sleep_s=0.0):
        super().__init__(dq)
        self.flag, self.sleep_s, self.calls = flag, sleep_s, 0

    def step(self, desired_mm, markers, q_deg):
        i, self.calls = self.calls, self.calls + 1
        time.sleep(self.sleep_s)
        return Step(self.dq.copy(), (i,), bool(self.flag(i)))


def test_apply_returns_e_i_after_the_move_from_the_forward_kinematics():
    """Session.apply's E_i (the env's reward) is the distance from the set point to the
    gripper after the step: the forward kinematics of the start (90, 0) deg plus the step."""
    arm = ArmSpec.from_args("two-link")
    pts = np.array([[120.0, 80.0, 0.0], [100.0, 90.0, 0.0]])
    with World(arm) as world:
        s = Session(world, TruthFeedback(), pts)
        s.observe()
        e = s.apply(Step(np.array([-30.0, 20.0]), (), False))
    g = forward_kinematics(arm, [60.0, 20.0])["gripper"]
    assert e == pytest.approx(np.hypot(*(pts[0, :2] - g[:2])), rel=0, abs=PYBULLET_RTOL * 200)


def test_ideal_sensors_have_no_estimation_error_for_either_marker():
    arm = ArmSpec.from_args("two-link")
    with World(arm) as world:
        trace = simulate(world, Constant([1.0, -1.0]), TruthFeedback(),
                         named("ellipse-t1", 10).points_mm)
    m = trace.metrics()
    assert m["est_gripper_rms_mm"] == 0.0 and m["est_elbow_rms_mm"] == 0.0


def test_trace_rows_joint_columns_are_degrees_that_put_the_gripper_where_the_after_columns_say():
    """The forward kinematics of each row's q1_deg, q2_deg (written to 4 decimals: 5e-5 deg,
    2e-4 mm at 200 mm) gives that row's xg_after_mm, yg_after_mm."""
    trace, _ = execute(prepare(RunConfig(feedback="model", points=20)))
    cols, rows = trace.rows()
    arm = ArmSpec.from_args("two-link")
    for r in rows:
        q = [float(r[cols.index(c)]) for c in ("q1_deg", "q2_deg")]
        g = [float(r[cols.index(c)]) for c in ("xg_after_mm", "yg_after_mm")]
        np.testing.assert_allclose(forward_kinematics(arm, q)["gripper"][:2], g, rtol=0, atol=1e-3)


def test_each_set_point_records_the_rules_and_flags_of_its_own_iterations():
    """Two iterations per set point: call i fires rule i, so set point k fired (2k, 2k+1); the
    controller flags out of reach at call 0 only, the first iteration of set point 0."""
    arm = ArmSpec.from_args("two-link")
    pts = np.array([[0.0, 190.0, 0.0], [0.0, 180.0, 0.0], [0.0, 170.0, 0.0]])
    with World(arm) as world:
        trace = simulate(world, _Counting([0.0, 0.0], flag=lambda i: i == 0), TruthFeedback(),
                         pts, iterations=2)
    assert trace.fired == [(0, 1), (2, 3), (4, 5)]
    assert trace.out_of_reach.tolist() == [True, False, False]
    assert trace.metrics()["n_flagged"] == 1


def test_a_set_point_flagged_at_full_correction_is_asked_once_and_not_called_an_aim():
    """Without --correction the aim is the set point: a flagged decision is not asked again."""
    arm = ArmSpec.from_args("two-link")
    pts = np.array([[0.0, 190.0, 0.0], [0.0, 400.0, 0.0], [0.0, 180.0, 0.0]])
    ctl = _Counting([0.0, 0.0], flag=lambda i: i == 1)
    with World(arm) as world:
        trace = simulate(world, ctl, TruthFeedback(), pts)
    assert ctl.calls == 3
    assert trace.metrics()["n_aim_out_of_reach"] == 0
    assert trace.records[1].flags == ("out_of_reach",)


def test_the_rules_stage_is_timed_in_milliseconds():
    """A decision that sleeps 5 ms is timed at >= 5 (ms), not 0.005."""
    arm = ArmSpec.from_args("two-link")
    with World(arm) as world:
        trace = simulate(world, _Counting([0.0, 0.0], sleep_s=0.005), TruthFeedback(),
                         np.zeros((3, 3)))
    assert trace.metrics()["timing_ms"]["rules"] >= 5.0


@pytest.mark.parametrize("points, said", [
    (np.array([[100.0, 50.0], [90.0, 60.0], [80.0, 70.0]]), r"got shape \(3, 2\)"),
    (np.array([100.0, 50.0, 0.0]), r"got shape \(3,\)"),
    (np.zeros((0, 3)), r"got shape \(0, 3\)"),
])
def test_set_points_of_another_shape_are_refused_not_reshaped(points, said):
    """A planar path given as x, y pairs, shape (3, 2), was reshaped to (2, 3): two set points
    (100, 50, 90) and (60, 80, 70) tracked without a word; no set point at all ran and
    measured nothing (E_av None)."""
    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(ValueError, match=r"^points_mm: shape \(n, 3\) expected \(x, y, z in "
                                             r"mm; z = 0 for a planar arm\), " + said + "$"):
            simulate(world, Constant([0.0, 0.0]), TruthFeedback(), points)


def test_a_set_point_that_is_not_finite_is_refused():
    """A NaN set point was tracked as out of reach, left out of every metric without a word."""
    points = np.array([[100.0, 50.0, 0.0], [np.nan, 60.0, 0.0]])
    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(ValueError, match=r"^points_mm: set point 2 is not finite: "
                                             r"\[nan, 60.0, 0.0\]$"):
            Session(world, TruthFeedback(), points)


@pytest.mark.parametrize("tracking_start", [-1, 5, 2.7, True])
def test_a_tracking_start_that_is_no_set_points_index_is_refused(tracking_start):
    """tracking_start=-1 measured the tracking phase on the last set point alone, 2.7 from the
    third, and 5 of 5 set points on none (every tracking metric None), each without a word."""
    points = np.array([[100.0, 50.0, 0.0]] * 5)
    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(ValueError, match=r"^tracking_start must be a whole number in 0\.\.4 "
                                             r"\(the index of a set point\), got "
                                             + re.escape(repr(tracking_start)) + "$"):
            simulate(world, Constant([0.0, 0.0]), TruthFeedback(), points,
                     tracking_start=tracking_start)
        assert simulate(world, Constant([0.0, 0.0]), TruthFeedback(), points,
                        tracking_start=np.int64(4)).metrics()["tracking_from"] == 4


@pytest.mark.parametrize("correction", [float("nan"), 0.0, 1.5, "0.5"])
def test_a_correction_outside_zero_to_one_is_refused(correction):
    """RunConfig refuses these, simulate took them: NaN aimed every decision after the first at
    NaN, which the Jacobian tracker answers by holding the arm (E_av 227 mm on ellipse-t1,
    without a word); 0 never corrects the error, 1.5 overshoots it."""
    with World(ArmSpec.from_args("two-link")) as world:
        with pytest.raises(ValueError, match=r"^correction must be a finite number in \(0, 1\] "
                                             r"\(the fraction of the measured error corrected "
                                             r"per decision\), got " + re.escape(repr(correction))):
            simulate(world, Constant([0.0, 0.0]), TruthFeedback(),
                     np.array([[100.0, 50.0, 0.0]] * 3), correction=correction)


@pytest.mark.parametrize("aims, said", [
    (np.zeros((1, 3)), r"got shape \(1, 3\)$"),
    (np.zeros((3, 2)), r"got shape \(3, 2\)$"),
    (np.full((3, 3), np.nan), r"got shape \(3, 3\) with a value that is not finite$"),
])
def test_aims_that_are_not_one_per_set_point_are_refused_before_the_arm_moves(aims, said):
    """One aim for three set points ran the first set point, then failed as 'index 1 is out of
    bounds'; NaN aims reached the controller."""
    points = np.array([[100.0, 50.0, 0.0]] * 3)
    with World(ArmSpec.from_args("two-link")) as world:
        q0 = world.q_deg.copy()
        with pytest.raises(ValueError, match=r"^aims_mm: one finite aim per set point, shape "
                                             r"\(3, 3\), expected, " + said):
            simulate(world, Constant([1.0, 0.0]), TruthFeedback(), points, aims_mm=aims)
        assert np.array_equal(world.q_deg, q0)  # nothing moved


def test_a_three_link_run_turns_a_lost_elbow_about_the_axes_its_start_up_measured():
    """Through the runner: the start-up measures the shoulder axis and the loop turns a lost
    elbow about it. Every third look after the start-up (80 looks) loses the elbow; the
    estimate used there is the simulator's elbow (float32 looks through the start-up's fits),
    where the last measurement held is the elbow of a look ago (each joint up to 1 deg off)."""
    prep = prepare(RunConfig(arm="three-link", trajectory="helix", controller="jacobian",
                             feedback="truth", max_step_deg=1.0))
    prep.feedback_factory = lambda: _LosesLooks("elbow", lambda n: n > 100 and n % 3 == 0)
    trace, summary = execute(prep)
    turned = [r for r in trace.records if "elbow_turned" in r.flags]
    assert summary["n_elbow_turned"] == summary["n_missed_by"]["elbow"] == len(turned) >= 5
    assert summary["geometry"]["pitch_axis"] is not None
    for r in turned:
        assert np.allclose(r.estimate.elbow_mm, r.true_at_estimate_mm["elbow"], rtol=0,
                           atol=8 * PYBULLET_RTOL * 200.0)


@pytest.mark.parametrize("arm_name", ["two-link", "three-link"])
def test_a_lost_elbow_before_the_run_has_seen_one_is_turned_from_the_start_up_s(arm_name):
    """The run's first three looks miss the elbow. The eye's own last estimate is from the
    start-up's last pose, far from the start (the base at +150 deg: 193 mm off; the shoulder at
    +60: 100 mm); the loop turns the start-up's look nearest the start instead (the base's at
    0 deg; the shoulder sweep's at the start), which puts it where the simulator has it."""
    from itg_vision.identify import SAMPLES_PER_POSE, start_up_poses

    arm = ArmSpec.from_args(arm_name)
    n0 = len(start_up_poses(arm, arm.start_q_deg)) * SAMPLES_PER_POSE  # truth misses no look
    prep = prepare(RunConfig(arm=arm_name, controller="jacobian", feedback="truth",
                             max_step_deg=1.0))
    prep.feedback_factory = lambda: _LosesLooks("elbow", lambda n: n0 < n <= n0 + 3)
    trace, summary = execute(prep)
    assert summary["n_elbow_turned"] == summary["n_missed_by"]["elbow"] == 3
    for r in trace.records[:3]:
        assert "elbow_turned" in r.flags
        assert np.allclose(r.estimate.elbow_mm, r.true_at_estimate_mm["elbow"], rtol=0,
                           atol=8 * PYBULLET_RTOL * 200.0)
