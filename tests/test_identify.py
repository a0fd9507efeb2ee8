"""The start-up measurement (itg_vision/identify.py): what a run's controller learns of the arm
from the LEDs before it moves."""

import dataclasses
import json

import numpy as np
import pytest
from conftest import affine_eye

from itg_vision.arm import ArmSpec
from itg_vision.contracts import Markers
from itg_vision.feedback import TruthFeedback
from itg_vision.identify import axis_at_height, base_axis, measure_geometry
from itg_vision.runner import RunConfig, execute, prepare
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


class BlindFrom(TruthFeedback):
    """The simulator's truth for the first ``good`` looks, then every marker missed."""

    def __init__(self, good):
        super().__init__()
        self.good, self.looks = good, 0

    def observe(self, world):
        m = super().observe(world)
        self.looks += 1
        return m if self.looks <= self.good else Markers(m.gripper_mm, m.elbow_mm,
                                                          ("gripper", "elbow"))


@pytest.mark.parametrize("name, good", [("three-link", 7), ("three-link", 60), ("two-link", 7)])
def test_a_failed_start_up_leaves_the_arm_at_its_start_pose(name, good):
    """The three-link start-up moves the arm through two sweeps. A look that fails in either
    (the base sweep's second pose after 7 good looks; the shoulder sweep's second after the
    55 of the base sweep and the 5 of its first) raises StartUpFailed, and the arm is back at its start, to
    the bit: a run that goes on without the measurement (``--allow-unseen``) starts there. It
    stayed at the failing look's pose (q1 -120 deg, leaned) before. The planar start-up turns
    the base alone (blind at its second pose, -120 deg) and returns the same way."""
    from itg_vision.identify import StartUpFailed

    start = (10.0, 73.3, -10.0) if name == "three-link" else (10.0, 73.3)
    arm = dataclasses.replace(ArmSpec.from_args(name), start_pose_deg=start)
    with World(arm) as world:
        with pytest.raises(StartUpFailed, match="measured in only"):
            measure_geometry(world, BlindFrom(good), arm)
        np.testing.assert_array_equal(world.q_deg, arm.start_q_deg)


class BlindAt(TruthFeedback):
    """The simulator's truth (with ``noise_mm`` per coordinate), but every marker missed while
    the base is at one of the angles ``blind_deg``: a rig that frames part of the base sweep."""

    def __init__(self, blind_deg, noise_mm=0.0):
        super().__init__(noise_mm=noise_mm)
        self.blind = {round(a) for a in blind_deg}

    def observe(self, world):
        m = super().observe(world)
        if round(world.q_deg[0]) in self.blind:
            return Markers(m.gripper_mm, m.elbow_mm, ("gripper", "elbow"))
        return m


def test_the_arc_that_base_angles_cover():
    """360 deg less the widest gap between neighbours on the circle: the whole base sweep
    (-150..+150 in 30 deg steps) 300; three angles 120 deg apart 240; across +-180 deg
    (170, -170) 20; a half turn 180; one angle 0."""
    from itg_vision.identify import BASE_SWEEP_DEG, arc_covered_deg

    assert arc_covered_deg(BASE_SWEEP_DEG) == pytest.approx(300.0)
    assert arc_covered_deg((-150.0, -30.0, 90.0)) == pytest.approx(240.0)
    assert arc_covered_deg((170.0, -170.0)) == pytest.approx(20.0)
    assert arc_covered_deg((0.0, 180.0)) == pytest.approx(180.0)
    assert arc_covered_deg((30.0,)) == 0.0


@pytest.mark.parametrize("name", ["one-link", "two-link"])
def test_a_planar_start_up_leaves_out_the_poses_it_cannot_see(name):
    """A rig that frames the workspace but not the whole base sweep: the LEDs go unseen with
    the base at -150..-30 deg. The start-up leaves those poses out and fits the circles to the
    six it saw (0..150 deg: 150 deg of arc): with exact looks the lengths and the axis are
    exact (to 1e-4 mm: PyBullet's float32 positions, 1e-5 mm at 200 mm, through a fit on part
    of a circle), the source names the poses left out, and the arm is back at its start.
    Before, the first unseen pose failed the run."""
    arm = ArmSpec.from_args(name)
    with World(arm) as world:
        g = measure_geometry(world, BlindAt((-150, -120, -90, -60, -30)), arm)
        np.testing.assert_array_equal(world.q_deg, arm.start_q_deg)
    np.testing.assert_allclose(g.links_mm, arm.links_mm, rtol=0, atol=1e-4)
    np.testing.assert_allclose(g.base_axis_mm, (0.0, 0.0), rtol=0, atol=1e-4)
    assert ("with the base at +0..+150 deg (6 of 11 poses; not seen at -150, -120, -90, -60, "
            "-30 deg)") in g.source


@pytest.mark.parametrize("seen, ok", [((60, 90, 120), False), ((90, 120), False),
                                      ((-150, -30, 90), True), ((30, 60, 90, 120, 150), True)])
def test_a_planar_start_up_needs_its_poses_to_cover_120_deg(seen, ok):
    """The poses seen place the base axis if they are three or more and cover 120 deg of arc
    (identify.MIN_BASE_ARC_DEG; a circle's centre from a short arc is poor: from 60 deg, L1
    was off by 6 mm RMS under 1 px). Too few or too short an arc fails in one line that says
    what the start-up needs and what it saw, the arm back at its start; three poses spread
    round the circle, or five covering 120 deg, are measured exactly (exact looks; 1e-4 mm as
    above)."""
    from itg_vision.identify import BASE_SWEEP_DEG, StartUpFailed, arc_covered_deg

    arm = ArmSpec.from_args("two-link")
    blind = [a for a in BASE_SWEEP_DEG if round(a) not in seen]
    with World(arm) as world:
        if ok:
            g = measure_geometry(world, BlindAt(blind), arm)
            np.testing.assert_allclose(g.links_mm, arm.links_mm, rtol=0, atol=1e-4)
        else:
            with pytest.raises(StartUpFailed) as failed:
                measure_geometry(world, BlindAt(blind), arm)
            assert str(failed.value).endswith(
                f"the base axis needs 3 of the sweep's 11 poses covering 120 deg of arc, and the "
                f"LEDs were seen at {len(seen)}, covering {arc_covered_deg(seen):g} deg; the "
                f"arm's lengths cannot be measured")
            assert "\n" not in str(failed.value)
        np.testing.assert_array_equal(world.q_deg, arm.start_q_deg)


def test_a_rendered_start_up_leaves_out_the_poses_the_visibility_check_predicted(tmp_path):
    """Rendered, on a rig that frames the workspace but not the whole sweep (conftest.front_rig,
    clean looks): the start-up leaves out exactly the poses that visibility's model predicted
    unseen (-150..-30 deg), and measures the lengths and the axis within 0.1 mm: the clean
    eye's per-LED error here (0.03 mm RMS, the run's table) through a fit on 150 deg of arc,
    whose radius error was 1.8x the whole sweep's under 1 px (0.35 against 0.20 mm RMS, 20
    seeds): ~0.05 mm, bounded with a factor 2 (measured: 0.018 mm and 0.022 mm)."""
    from conftest import front_rig

    from itg_vision.camera import Rig
    from itg_vision.feedback import VisionFeedback
    from itg_vision.visibility import _start_up_seen

    rig, arm = Rig.from_yaml(front_rig(tmp_path / "front.yaml")), ArmSpec.from_args("two-link")
    predicted = {q[0] for _, q, _ in _start_up_seen(rig, arm)[0]}
    unseen = [q1 for q1 in (-150, -120, -90, -60, -30, 0, 30, 60, 90, 120, 150)
              if q1 not in predicted]
    eye = VisionFeedback(rig, rig, arm)
    eye.reset(0)
    with World(arm) as world:
        g = measure_geometry(world, eye, arm)
    assert f"(6 of 11 poses; not seen at {', '.join(f'{q:+g}' for q in unseen)} deg)" in g.source
    assert unseen == [-150, -120, -90, -60, -30]
    np.testing.assert_allclose(g.links_mm, arm.links_mm, rtol=0, atol=0.1)
    assert np.hypot(*g.base_axis_mm) < 0.1


@pytest.mark.slow
def test_a_run_on_a_rig_that_sees_part_of_the_sweep_tracks_and_says_what_it_left_out(
        main_in_process, tmp_path):
    """``run`` on conftest.front_rig, ITG+ on ellipse-t2, 2 laps at the benchmark's 20
    deg/iteration: exit 0, no LED missed along the path, the table names the start-up poses
    left out, and the tracking max meets issue 13's 3 mm (measured 0.144 mm, seed 0; on the
    shipped rig 0.148 mm, the worst of 3 seeds in the README's targets table)."""
    from conftest import front_rig

    rig = front_rig(tmp_path / "front.yaml")
    res = main_in_process("itg_vision.run", "--rig", rig, "--trajectory", "ellipse-t2",
                          "--rules", "itg-plus-two-link", "--laps", 2, "--max-step", 20,
                          "--out", tmp_path / "run")
    assert res.returncode == 0, res.stderr
    assert ("with the base at +0..+150 deg (6 of 11 poses; not seen at -150, -120, -90, -60, "
            "-30 deg)") in res.stdout
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["n_missed"] == 0
    assert summary["track_max_mm"] < 3.0
    assert "elbow" not in res.stderr  # both branches in view: no note


@pytest.mark.slow
def test_a_run_that_loses_the_elbow_along_its_path_says_so_and_tracks(main_in_process, tmp_path,
                                                                        monkeypatch):
    """conftest.front_rig looking 100 mm out sees the start-up at 30..150 deg and, along
    ellipse-t2, one of the elbow's two branches at some set points. The check accepts it (one
    branch in view) with a note before the run; ITG+ takes the other branch there, the looks
    miss the elbow, and a note after the run counts them: every look the run missed (the
    gripper was never lost), beyond the 10 % the note allows. Each lost elbow is turned with
    the base, and the run tracks within issue 13's 3 mm (0.15 mm measured); handed the last
    elbow measurement however old instead (the cause changed, nothing else), the same run
    flailed: max 102 mm."""
    import re

    from conftest import front_rig

    import itg_vision.runner as runner

    rig = front_rig(tmp_path / "front.yaml", look_y_mm=100.0)

    def run(out):
        res = main_in_process("itg_vision.run", "--rig", rig, "--trajectory", "ellipse-t2",
                              "--rules", "itg-plus-two-link", "--laps", 2, "--max-step", 20,
                              "--out", tmp_path / out, "--quiet")
        assert res.returncode == 0, res.stderr
        return res, json.loads((tmp_path / out / "summary.json").read_text())

    res, summary = run("run")
    before = re.search(r"note: \S+front.yaml: at (\d+) of the 360 set points in reach only some "
                       r"of the elbow LED's positions", res.stderr)
    after = re.search(r"note: the elbow LED went unseen in (\d+) of the 360 looks \(.*, turned "
                      r"with the base's commanded turn since$", res.stderr, re.M)
    assert before and after, res.stderr
    assert summary["n_at_last_aim"] == summary["n_held"] == 0
    assert int(after.group(1)) == summary["n_missed"] == summary["n_elbow_turned"] > 0.1 * 360
    assert summary["n_missed_by"] == {"gripper": 0, "elbow": summary["n_missed"]}
    from itg_vision.run import summary_table

    assert re.search(rf"^LED detections missed +{summary['n_missed']} \(gripper 0, elbow "
                     rf"{summary['n_missed']}\)$", summary_table(summary, tmp_path / "run"), re.M)
    assert summary["track_max_mm"] < 3.0
    simulate = runner.simulate
    monkeypatch.setattr(runner, "simulate",
                        lambda *a, **kw: simulate(*a, **{**kw, "base_axis_mm": None}))
    res, held = run("held")
    assert "its last measured position, however old" in res.stderr
    assert held["n_elbow_turned"] == 0 and held["track_max_mm"] > 20.0


@pytest.mark.slow
def test_on_part_of_the_sweep_the_lengths_standard_error_is_still_their_scatter():
    """Isotropic looks of 1 mm per coordinate, the sweep seen at 30..150 deg only (5 poses,
    120 deg of arc: the least the start-up takes). The circle's radius is now the uncertain
    length (from 120 deg of arc its error is several times L2's, sqrt(2 / 5) s = 0.34 mm), and
    sL, carried through the fit to first order, is its standard deviation over 300 seeds
    (within 12 %, as over the whole sweep: 3 sampling errors of a standard deviation from 300
    draws, 1 / sqrt(600), and a few per cent of the pooled scatter's own sampling error)."""
    from itg_vision.identify import BASE_SWEEP_DEG

    arm = ArmSpec.from_args("two-link")
    feedback = BlindAt([a for a in BASE_SWEEP_DEG if not 30 <= a <= 150], noise_mm=1.0)
    errors, se = [], []
    with World(arm) as world:
        for seed in range(300):
            feedback.reset(seed)
            g = measure_geometry(world, feedback, arm)
            errors.append(np.subtract(g.links_mm, arm.links_mm))
            se.append(g.length_se_mm)
    spread = np.std(errors, axis=0)
    assert spread[0] > 2 * spread[1]
    assert np.sqrt(np.mean(np.square(se))) == pytest.approx(spread[0], rel=0.12), (se, spread)


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
    hidden = ("check the rig, or the arm's led_standoff_mm, 12 mm: an LED too close beside its "
              "link is partly hidden by it")
    assert len(reasons) == 4 and said == {
        f"blob area under {fb.min_area_ratio:g} of expected: partly hidden ({hidden})"}

    def looked(cause):
        return SimpleNamespace(last_observation=SimpleNamespace(causes={"gripper": cause}),
                               dropout=0.0, noise_px=0.0, max_residual_px=2.0, arm=fb.arm)

    assert _miss_cause(looked(NOT_ROUND), "gripper") == f"not round ({hidden})"
    assert _miss_cause(looked(RESIDUAL), "gripper") == \
        "reprojection residual above 2 px (check the rig)"


def test_a_start_up_that_a_link_spoils_names_the_led_standoff():
    """A three-link arm whose LEDs stand 8 mm beside their links (the shipped file's 12 mm less
    4; led_standoff_mm allows 0..5000): its forearm (8 mm wide) hides part of the gripper LED
    (6 mm in radius, so 2 mm from the link's face) from a camera of the shipped rig in the base
    sweep's leaned pose, the blob is not round, and the start-up fails. The line used to say
    only "not round (check the rig)", though the rig sees the shipped arm's 12 mm stand-off in
    every one of those poses; it now names the arm's stand-off as a cause too."""
    from itg_vision.camera import Rig
    from itg_vision.feedback import VisionFeedback
    from itg_vision.identify import StartUpFailed
    from itg_vision.runner import CAMERAS_DIR

    arm = dataclasses.replace(ArmSpec.from_args("three-link"), led_standoff_mm=8.0)
    rig = Rig.from_yaml(CAMERAS_DIR / "three-link.yaml")
    fb = VisionFeedback(rig, rig, arm)
    fb.reset(0)
    with World(arm) as world, pytest.raises(StartUpFailed) as failed:
        measure_geometry(world, fb, arm)
    assert "not round (check the rig, or the arm's led_standoff_mm, 8 mm:" in str(failed.value)


#: 16 mm along -a at q1 = 35 deg (a = (sin q1, -cos q1, 0), the pitch axis), where line-ab-reach
#: runs (q1 ~ 31-39 deg): beyond the 12 mm stand-off h, so that a base axis assumed at x = y = 0
#: sees the LEDs on the wrong side of it, P = h a + (delta . a) a = -4 a (the arm mirrored).
DELTA_MM = -16.0 * np.array([np.sin(np.radians(35.0)), -np.cos(np.radians(35.0)), 0.0])


@pytest.mark.parametrize("controller, rules", [("itg", "itg-plus-three-link"),
                                               ("jacobian", None)])
def test_an_eye_displaced_by_more_than_the_standoff_sees_the_arm_move_the_same(controller,
                                                                              rules):
    """An eye displaced by delta (|delta| 16 mm > h), with the set points in its frame (displaced
    alike): every position the controller gets is the true frame's plus delta. Measured from
    the measured base axis (the start-up's circles are centred delta away) the rules' and the
    tracker's inputs are the true frame's to rounding, and the joints follow the same path as
    with the true frame. With the axis assumed at x = y = 0, ITG+ and DLS read the arm mirrored
    and every pitch step has the wrong sign (before the change: both diverged, tracking medians
    of 97-371 mm at the benchmark's rig-perturbed seed 2, |delta| 12.9 mm).

    Tolerances: the inputs carry the simulator's float32 rounding of the LEDs' ~300 mm
    coordinates (PYBULLET_RTOL x 300 mm ~ 4e-5 mm) through the circle fits (a few times that);
    1e-3 mm for the axis and the estimates, and 1e-3 deg for the joints (a step is at most 2 deg, from errors of a few mm),
    leave a margin and fail a path that differs by any servo step."""
    cfg = RunConfig(arm="three-link", trajectory="line-ab-reach", controller=controller,
                    rules=rules, feedback="truth", max_step_deg=2.0, iterations=5)
    clean_trace, clean = execute(prepare(cfg))
    prep = prepare(cfg)
    moved = dataclasses.replace(prep.trajectory, points_mm=prep.trajectory.points_mm + DELTA_MM)
    prep = dataclasses.replace(prep, trajectory=moved,
                               feedback_factory=lambda: affine_eye(shift_mm=DELTA_MM))
    trace, shifted = execute(prep)
    np.testing.assert_allclose(trace.q_deg, clean_trace.q_deg, rtol=0, atol=1e-3)
    est = [r.estimate.gripper_mm - DELTA_MM for r in trace.records]
    np.testing.assert_allclose(est, [r.estimate.gripper_mm for r in clean_trace.records],
                               rtol=0, atol=1e-3)
    assert clean["track_median_mm"] < 1.0  # tracking, not the same divergence twice
    np.testing.assert_allclose(shifted["geometry"]["base_axis_mm"], DELTA_MM[:2], rtol=0,
                               atol=1e-3)
    assert shifted["geometry"]["links_mm"] == pytest.approx(clean["geometry"]["links_mm"],
                                                            abs=1e-3)
    assert shifted["geometry"]["standoff_mm"] == pytest.approx(12.0, abs=1e-3)


#: A planar arm's eye displaced by 15 mm in x and -10 in y (the benchmark's rig-perturbed moves
#: the two-link arm by up to 17 mm in the eye's frame): lengths taken about the eye's x = y = 0
#: would be |elbow_xy + delta|, 88-100 mm in the benchmark's perturbed runs.
PLANAR_DELTA_MM = np.array([15.0, -10.0, 0.0])


@pytest.mark.parametrize("controller, rules", [("itg", None), ("itg", "itg-plus-two-link"),
                                               ("jacobian", None)])
def test_a_planar_arm_seen_displaced_moves_the_same(controller, rules):
    """The planar start-up turns the base and fits the LEDs' circles: the base axis it
    measures is delta, the lengths the true frame's, and every controller (the paper's Table 2,
    ITG+ with its RULE 0 reach test, DLS) then sees the same inputs, less delta, and moves the
    joints the same as with the true frame, set points displaced alike. Before, the planar
    start-up took the lengths about x = y = 0: here L1 = |(15, 90)| = 91.2 mm, and ITG+'s
    RULE 0 flagged T1's farther set points. Tolerances as in the three-link test above (float32
    LED coordinates through the fits): 1e-3 mm and 1e-3 deg."""
    cfg = RunConfig(arm="two-link", trajectory="ellipse-t1", controller=controller, rules=rules,
                    feedback="truth", max_step_deg=20.0, laps=2)
    clean_trace, clean = execute(prepare(cfg))
    prep = prepare(cfg)
    moved = dataclasses.replace(prep.trajectory,
                                points_mm=prep.trajectory.points_mm + PLANAR_DELTA_MM)
    prep = dataclasses.replace(prep, trajectory=moved,
                               feedback_factory=lambda: affine_eye(shift_mm=PLANAR_DELTA_MM))
    trace, shifted = execute(prep)
    np.testing.assert_allclose(shifted["geometry"]["base_axis_mm"], PLANAR_DELTA_MM[:2], rtol=0,
                               atol=1e-3)
    np.testing.assert_allclose(shifted["geometry"]["links_mm"], (100.0, 100.0), rtol=0,
                               atol=1e-3)
    np.testing.assert_allclose(trace.q_deg, clean_trace.q_deg, rtol=0, atol=1e-3)
    assert shifted["n_flagged"] == clean["n_flagged"] == 0
    assert clean["track_median_mm"] < 5.0  # tracking, not the same failure twice


def test_concentric_circles_closed_form():
    """Two LEDs turned about a vertical axis through (37, -21) mm on radii 51 and 101 mm, 11
    angles over 300 deg (the planar start-up's base sweep), at different heights (z is not
    read): the common centre and both radii to float64 round-off (1e-9 mm), residual ~0. With
    the outer ring's points alternately 0.3 mm out and in (11 points: one more out than in, so
    the fit is not exact), the residual is the wobble's 0.3 mm RMS and the inner radius moves
    by far less than the wobble (0.02 mm bounds both)."""
    from itg_vision.identify import concentric_circles

    a = np.radians(np.arange(-150.0, 151.0, 30.0))
    ring = lambda r, z: np.column_stack([37 + r * np.cos(a), -21 + r * np.sin(a),
                                         np.full_like(a, z)])
    centre, radii, rms = concentric_circles([ring(51.0, 12.0), ring(101.0, 40.0)])
    np.testing.assert_allclose(centre, (37.0, -21.0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(radii, (51.0, 101.0), rtol=0, atol=1e-9)
    assert rms < 1e-9
    wobble = 0.3 * np.where(np.arange(len(a)) % 2 == 0, 1.0, -1.0)
    outer = np.column_stack([37 + (101 + wobble) * np.cos(a), -21 + (101 + wobble) * np.sin(a)])
    _, radii, rms = concentric_circles([ring(51.0, 0.0), outer])
    assert rms == pytest.approx(0.3, abs=0.02)
    assert radii[0] == pytest.approx(51.0, abs=0.02)


def test_the_base_axis_at_the_shoulder_is_measured_to_a_circle_centre_under_pixel_noise():
    """On the true rig the base axis is x = y = 0. Under 1 px centroid noise each LED position
    the start-up fits is off by ~2 mm (the base sweep's circle residual at 1 px, measured
    1.6-2.4 mm RMS), and a circle's centre from n points spread round most of a turn is off by
    about that times sqrt(2 / n): 11 points, ~0.9 mm. Leaned (identify.BASE_SWEEP_POSE_DEG), the
    gripper LED circles the axis at the shoulder's height, so the axis there is such a centre,
    not an extrapolation: 1.5 mm bounds it (measured, 24 seeds: median 0.34, max 0.81 mm).
    Straight up, the +-60 deg arcs of the 12 mm circles at 200 and 300 mm extrapolated to the
    shoulder at 100 mm: seeds 0-5 were off by 0.5-3.2 mm (24 seeds: median 1.25, max 5.95)."""
    from itg_vision.camera import Rig, default_rig_path
    from itg_vision.feedback import VisionFeedback

    arm = ArmSpec.from_args("three-link")
    rig = Rig.from_yaml(default_rig_path("three-link"))
    errors = []
    for seed in range(6):
        feedback = VisionFeedback(rig, rig, arm, noise_px=1.0)
        feedback.reset(seed)
        with World(arm) as world:
            geometry = measure_geometry(world, feedback, arm)
            np.testing.assert_array_equal(world.q_deg, arm.start_q_deg)  # back exactly
        errors.append(float(np.hypot(*geometry.base_axis_mm)))
    assert max(errors) < 1.5, errors


def test_base_axis_is_the_line_through_the_circles_centres():
    """Closed form: two LEDs turned about a vertical axis through (37, -21) mm, at heights 100
    and 187 mm on radii 101 and 51 mm, 11 angles over 300 deg (the start-up's base sweep):
    the axis is that point, vertical, and the fits' residual is float64 round-off of the
    coordinates (~1e-13 mm; 1e-9 bounds it). Circles whose centres differ (a tilted axis)
    give the line through the centres, and the point on it at any height."""
    a = np.radians(np.arange(-150.0, 151.0, 30.0))
    ring = lambda c, r, z: np.column_stack([c[0] + r * np.cos(a), c[1] + r * np.sin(a),
                                            np.full_like(a, z)])
    point, direction, rms = base_axis([ring((37.0, -21.0), 101.0, 100.0),
                                       ring((37.0, -21.0), 51.0, 187.0)])
    np.testing.assert_allclose(point[:2], (37.0, -21.0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(direction, (0.0, 0.0, 1.0), rtol=0, atol=1e-12)
    assert rms < 1e-9
    # centres (0, 0, 0) and (10, 0, 100): the axis leans atan(0.1) toward +x
    point, direction, _ = base_axis([ring((0.0, 0.0), 80.0, 0.0), ring((10.0, 0.0), 60.0, 100.0)])
    np.testing.assert_allclose(direction, np.array([0.1, 0.0, 1.0]) / np.hypot(0.1, 1.0),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(axis_at_height(point, direction, 50.0), (5.0, 0.0, 50.0),
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(axis_at_height(point, direction, 0.0), (0.0, 0.0, 0.0),
                               rtol=0, atol=1e-9)


def test_the_start_up_measures_an_arm_that_starts_leaned():
    """The base sweep's pose is commanded, not relative to the start: an arm file whose start is
    leaned (q 30, 60, -30 deg; relative to it the sweep had folded the arm until the shipped rig
    lost its LEDs at the first base angle) is measured as the straight-up one is, through the
    rendered eye without noise: the axis within the eye's 0.1 mm error at 0 px (README, the
    accuracy benchmark: gripper 0.04 mm RMS, the three-link rig's oblique views 0.37 mm at worst
    for the triangulation, so 1 mm bounds a circle's centre and a fitted length; measured:
    0.07 mm and 0.1 mm), and the arm back at its start exactly."""
    from itg_vision.camera import Rig, default_rig_path
    from itg_vision.feedback import VisionFeedback

    arm = dataclasses.replace(ArmSpec.from_args("three-link"), start_pose_deg=(30.0, 60.0, -30.0))
    rig = Rig.from_yaml(default_rig_path("three-link"))
    feedback = VisionFeedback(rig, rig, arm)
    feedback.reset(0)
    with World(arm) as world:
        geometry = measure_geometry(world, feedback, arm)
        np.testing.assert_array_equal(world.q_deg, arm.start_q_deg)
    assert np.hypot(*geometry.base_axis_mm) < 1.0
    np.testing.assert_allclose(geometry.links_mm, arm.links_mm, rtol=0, atol=1.0)


# --------------------------------------------------- the start-up's fits against closed forms
import cv2  # noqa: E402

from itg_vision.camera import Rig  # noqa: E402
from itg_vision.feedback import VisionFeedback  # noqa: E402
from conftest import ROOT  # noqa: E402

PLANAR = ROOT / "cameras" / "planar.yaml"


def test_base_axis_circles_are_fitted_in_horizontal_planes():
    """LEDs on a vertical axis through (37, -21) mm whose measured heights wander along the
    arc (0.45 mm, as identify.base_axis's docstring measured): the points still lie on
    vertical cylinders about the axis, so horizontal-plane circle fits find it exactly (to
    round-off); a freely fitted plane tilts and moves the centre."""
    from itg_vision.identify import base_axis

    a = np.radians(np.arange(-60.0, 61.0, 12.0))
    ring = lambda r, z: np.column_stack([37 + r * np.cos(a), -21 + r * np.sin(a),
                                         z + 0.45 * np.sin(a)])
    point, direction, _ = base_axis([ring(12.0, 200.0), ring(12.0, 300.0)])
    np.testing.assert_allclose(point[:2], (37.0, -21.0), rtol=0, atol=1e-9)


def test_the_shoulder_is_where_a_tilted_base_axis_crosses_the_shoulder_height():
    """An eye whose frame is turned 1 deg about x (a rig tilted after calibration): the eye
    sees the base axis tilted. The start-up's shoulder is that axis at the shoulder's height:
    the true shoulder (0, 0, L1) seen through the same turn, to the circle centre's own offset
    (the LED stand-off h = 12 mm along the pitch axis moves the elbow circle's height, and so
    the crossing, by at most h sin(1 deg) tan(1 deg), 4e-3 mm); 0.02 mm bounds it. Taking the
    mean of the circles' centres (43 mm above the shoulder) is off by 0.75 mm."""
    from itg_vision.contracts import Markers
    from itg_vision.identify import measure_geometry

    R = cv2.Rodrigues(np.radians([1.0, 0.0, 0.0]))[0]

    class Tilted(TruthFeedback):
        def observe(self, world):
            m = super().observe(world)
            return Markers(R @ m.gripper_mm, R @ m.elbow_mm, m.missed)

    arm = ArmSpec.from_args("three-link")
    with World(arm) as world:
        g = measure_geometry(world, Tilted(), arm)
    S = R @ np.array([0.0, 0.0, arm.links_mm[0]])
    # the measured L1 is the height of the elbow circle's centre, not S's: compare on the axis
    expected_xy = S[:2] + (g.shoulder_mm[2] - S[2]) * (R[:2, 2] / R[2, 2])
    np.testing.assert_allclose(g.shoulder_mm[:2], expected_xy, rtol=0, atol=0.02)


def test_the_start_up_survives_a_dropout_of_thirty_percent():
    """--dropout 0.3 drops each marker's look with probability 0.3, so a look sees both LEDs
    with p = 0.49. The start-up needs SAMPLES_PER_POSE (5) good looks within
    MAX_TRIES_PER_POSE; with the documented 50 tries the chance of fewer than 5 successes is
    P(Bin(50, 0.49) <= 4) ~ 1e-9 (closed form below), so each of 5 seeds measures the arm."""
    from math import comb

    from itg_vision.identify import SAMPLES_PER_POSE, measure_geometry

    p = 0.7**2
    fail = sum(comb(50, k) * p**k * (1 - p) ** (50 - k) for k in range(SAMPLES_PER_POSE))
    assert fail < 1e-8
    arm = ArmSpec.from_args("two-link")
    rig = Rig.from_yaml(PLANAR)
    for seed in range(5):
        fb = VisionFeedback(rig, rig, arm, dropout=0.3)
        fb.reset(seed)
        with World(arm) as world:
            g = measure_geometry(world, fb, arm)
        np.testing.assert_allclose(g.links_mm, arm.links_mm, rtol=0, atol=0.5)


def test_circle_residual_counts_the_distance_out_of_the_plane():
    """fit_circle's rms_mm is the RMS distance of the points from the fitted circle (the
    geometry's residual_mm in summary.json). Points on a circle of radius 50 about the z axis,
    displaced alternately +-0.3 mm along z and fitted in the horizontal plane through their
    mean: the circle is exact in-plane, so every point is 0.3 mm from it (closed form)."""
    from itg_vision.identify import fit_circle

    a = np.radians(np.arange(0.0, 360.0, 30.0))
    dz = 0.3 * np.where(np.arange(len(a)) % 2 == 0, 1.0, -1.0)
    P = np.column_stack([50 * np.cos(a), 50 * np.sin(a), 100.0 + dz])
    centre, _, radius, rms = fit_circle(P, (0.0, 0.0, 1.0))
    np.testing.assert_allclose(centre, (0.0, 0.0, 100.0), rtol=0, atol=1e-9)
    assert radius == pytest.approx(50.0, abs=1e-9)
    assert rms == pytest.approx(0.3, abs=1e-9)


def test_median_variance_is_that_of_a_median_of_the_start_ups_looks():
    """MEDIAN_VARIANCE is the variance of the median of SAMPLES_PER_POSE normal draws (unit
    variance): drawn 400 000 times, within 1.5 % (the estimate's relative sampling error is
    about 0.3 %)."""
    from itg_vision.identify import MEDIAN_VARIANCE, SAMPLES_PER_POSE

    draws = np.random.default_rng(0).standard_normal((400_000, SAMPLES_PER_POSE))
    assert np.median(draws, axis=1).var() == pytest.approx(MEDIAN_VARIANCE, rel=0.015)


def _noisy_start_ups(name, seeds):
    """The start-up measurement of the shipped arm ``name`` from looks with 1 mm of noise per
    coordinate, seeds 0..seeds-1: the lengths' errors, shape (seeds, n), and each sL."""
    arm = ArmSpec.from_args(name)
    feedback = TruthFeedback(noise_mm=1.0)
    links, se = [], []
    with World(arm) as world:
        for seed in range(seeds):
            feedback.reset(seed)
            g = measure_geometry(world, feedback, arm)
            links.append(g.links_mm)
            se.append(g.length_se_mm)
    return np.array(links) - arm.links_mm, np.array(se)


@pytest.mark.slow
def test_the_lengths_standard_error_is_the_scatter_of_the_measured_lengths():
    """Looks with isotropic noise of 1 mm per coordinate (the simulator's truth plus seeded
    noise); each pose's position is a median of its looks, standard error s =
    sqrt(MEDIAN_VARIANCE) = 0.536 mm per coordinate. The two-link start-up turns the base through
    n = 11 poses (identify.BASE_SWEEP_DEG). L2, the mean of n distances |g_xy - e_xy| (each
    sqrt(2) s along the forearm), has the standard error sqrt(2 / n) s = 0.228 mm, and L1, a
    circle's radius, lies between that of a radius fitted on a whole circle, s / sqrt(n) =
    0.161 mm, and L2's (the 300 deg arc leaves the radius a little more uncertain; L2's is
    then the largest, sL). Over 400 seeds the lengths' errors have those standard deviations
    (within 12 %: 3.5 sampling errors of a standard deviation from 400 draws, 1 / sqrt(800)),
    and sL's mean square is L2's (within 6 %: the pooled variance of many looks, carried through
    the mean, has a relative sampling error of a few per cent at most over 400 seeds). The
    one-link arm's radius (one circle, the gripper's) is s / sqrt(n) within 12 % too."""
    from itg_vision.identify import BASE_SWEEP_DEG, MEDIAN_VARIANCE

    s, n = np.sqrt(MEDIAN_VARIANCE), len(BASE_SWEEP_DEG)
    errors, se = _noisy_start_ups("two-link", 400)
    spread = errors.std(axis=0)
    assert spread[1] == pytest.approx(np.sqrt(2 / n) * s, rel=0.12)
    assert s / np.sqrt(n) * 0.88 < spread[0] < np.sqrt(2 / n) * s * 1.12
    assert np.mean(np.square(se)) == pytest.approx(2 / n * s**2, rel=0.06)
    errors, _ = _noisy_start_ups("one-link", 400)
    assert errors.std(axis=0)[0] == pytest.approx(s / np.sqrt(n), rel=0.12)


def test_the_lengths_standard_error_of_a_three_link_start_up_is_the_scatter_of_its_lengths():
    """The three-link start-up's lengths come from a circle fit (L1 its centre's height, L2 its
    radius) and a median (L3). Looks with 1 mm of noise per coordinate, 60 seeds: sL, carried
    through the fit to first order, is within 25 % of the largest standard deviation of the
    lengths' errors (sampling error of a standard deviation from 60 draws: 9 %)."""
    errors, se = _noisy_start_ups("three-link", 60)
    spread = errors.std(axis=0).max()
    assert np.sqrt(np.mean(np.square(se))) == pytest.approx(spread, rel=0.25), (se, spread)


def test_under_the_nominal_model_and_ideal_sensors_the_lengths_are_exact():
    """sL is 0 for the nominal model's lengths and for looks without noise."""
    from itg_vision.identify import nominal_geometry

    arm = ArmSpec.from_args("two-link")
    with World(arm) as world:
        assert measure_geometry(world, TruthFeedback(), arm).length_se_mm == 0.0
    assert nominal_geometry(arm).length_se_mm == 0.0
