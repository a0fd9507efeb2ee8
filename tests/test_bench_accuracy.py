"""The accuracy benchmark's claims against its own targets (issue 4, section 7; issue 11)."""

import re

import numpy as np
import pytest

from itg_vision.arm import ArmSpec
from itg_vision.bench.accuracy import (TARGET_CENTROID_PX, TARGET_GRIPPER_MM, TARGET_RATIO,
                                       measure)
from itg_vision.camera import Rig
from itg_vision.runner import CAMERAS_DIR


@pytest.mark.slow
def test_estimation_error_matches_first_order_prediction():
    """The benchmark's own targets, at the default setting (windows, supersample 3), 250 poses
    (500 marker estimates per noise level, ~5 s): centroid RMS at zero added noise <=
    TARGET_CENTROID_PX, gripper RMS <= TARGET_GRIPPER_MM, and the measured RMS within the
    sample's scatter of the first-order prediction (through the lens) for 0.1-1 px, which is within TARGET_RATIO.
    Measured (seed 5): centroid 0.0249 px RMS (sigma_render 0.0176 px per axis), gripper
    0.048 mm, elbow 0.047 mm; ratios 1.000, 1.001, 1.001 (0.1, 0.3, 1 px; 1.011-1.012 with
    the pinhole prediction, before the lens was in it). Supersample 1
    would give ~0.093 px and ~0.14 mm: both targets fail."""
    r = measure(ArmSpec.from_args("two-link"), Rig.from_yaml(CAMERAS_DIR / "planar.yaml"),
                (0.0, 0.1, 0.3, 1.0), n_poses=250, seed=5)
    assert r["n_missed"] == 0
    rows = {row["sigma_px"]: row for row in r["rows"]}
    assert r["centroid_rms_px"] <= TARGET_CENTROID_PX, r["centroid_rms_px"]
    assert r["marker_rms_mm"]["gripper"] <= TARGET_GRIPPER_MM, r["marker_rms_mm"]
    for s in (0.1, 0.3, 1.0):
        # scatter of the ratio: on this rig the depth axis carries ~87 % of each estimate's
        # predicted variance and the prediction varies little over the workspace, so each
        # squared error is ~ sigma_depth^2 chi2(1) (relative variance 2): the mean square of n
        # estimates has relative standard error sqrt(2 / n), their RMS half of it,
        # 1 / sqrt(2 n) (0.032 for n = 500; the exact sqrt(2 sum tr C^2) / (2 sum tr C) is
        # 0.028). Bound 3 of it, 0.095: tighter than the target TARGET_RATIO - 1 = 0.1, so
        # meeting it meets the target. (20 poses would give 0.34: the target untestable.)
        tol = 3 / np.sqrt(2 * rows[s]["n"])
        assert rows[s]["n"] == 500 and tol <= TARGET_RATIO - 1
        # the benchmark's own sampling error: no less than the isotropic 1/sqrt(6n) (a bound),
        # and here, where the prediction varies little over the workspace, below 1/sqrt(2n)
        assert 1 / np.sqrt(6 * rows[s]["n"]) <= r["ratio_se"] <= 1 / np.sqrt(2 * rows[s]["n"])
        assert abs(rows[s]["ratio"] - 1) <= tol, rows[s]
    # the tail: for Gaussian-like errors the 95th percentile of an error's length lies between
    # 1.6 (isotropic in 3-D) and 2.0 (one dominant axis, the depth) times its RMS; an outlier
    # (a wrong match, a rim pixel) or a mis-computed tail would fall outside [1.0, 2.5]
    g = r["marker_p95_mm"]["gripper"] / r["marker_rms_mm"]["gripper"]
    assert 1.0 < g < 2.5 and r["marker_max_mm"]["gripper"] >= r["marker_p95_mm"]["gripper"], g


def test_noise_streams_are_independent_of_the_poses_stream():
    """Each pose's noise comes from its own stream, none the poses' own: the former seeds
    (seed * 100003 + k) gave pose 0 of seed 0 the poses' generator itself, so its image noise
    was a function of the poses drawn. Same seed, same streams."""
    from itg_vision.bench.accuracy import streams

    first = {}
    for seed in (0, 1, 100003):
        rng, noise = streams(seed, 50)
        draws = [np.random.default_rng(ss).random(4).tobytes() for ss in noise]
        poses_draw = rng.random(4).tobytes()
        assert poses_draw not in draws and len(set(draws)) == 50
        for d in draws:
            assert d not in first, (seed, first.get(d))  # no stream shared across seeds either
            first[d] = seed
        again = [np.random.default_rng(ss).random(4).tobytes() for ss in streams(seed, 50)[1]]
        assert again == draws


def test_the_three_link_eyes_centroid_error_is_its_led_posts(monkeypatch):
    """docs/benchmarks.md ("What bench accuracy measures"): the three-link rig misses the
    centroid target because each LED's post, 1.5 mm in radius, lies across the cameras' view of
    its 6 mm sphere (it runs sideways to the link, along the pitch axis; a planar arm's posts
    stand below their LEDs, hidden by them). Side-on it hides a strip 2 x 1.5 mm wide from the centre to the rim,
    2 (1.5 / 6) / pi = 16 % of the disc (blob areas 0.83-0.88 of the sphere's were measured at
    the largest errors), and shifts the centroid by up to ~0.4 px at the ~4.5 px radius the
    LEDs image at. Changed alone, the cause goes: posts 0.01 mm thin bring the centroid's 95th
    percentile down at least 3-fold (measured 3.9-4.5x, seeds 5, 0, 1, 100 poses) to within 2x
    of the planar rig's in the same test (measured 1.19-1.55x: smaller blobs, 65 against 93 px,
    and links that hide an LED at a few poses)."""
    import itg_vision.urdf as urdf

    def p95(arm_name, rig_name):
        return measure(ArmSpec.from_args(arm_name), Rig.from_yaml(CAMERAS_DIR / rig_name),
                       (0.0,), n_poses=100, seed=5)["centroid_p95_px"]

    planar = p95("two-link", "planar.yaml")
    posts = p95("three-link", "three-link.yaml")
    monkeypatch.setattr(urdf, "LED_POST_RADIUS_MM", 0.01)
    thin = p95("three-link", "three-link.yaml")
    assert posts >= 3 * thin and thin <= 2 * planar, (posts, thin, planar)


def test_targets_are_not_judged_on_the_few_looks_the_eye_kept(tmp_path, capsys):
    """A rig that loses most LEDs (here the left camera turned away from the arm) used to print
    both targets 'met' on the looks it kept (an auditor's rig: 88 of 120 missed). Over 5 % of
    the marker looks missed, every target says undecided and how many were missed."""
    import yaml

    from itg_vision.bench.accuracy import main

    rig = yaml.safe_load((CAMERAS_DIR / "planar.yaml").read_text())
    rig["cameras"][0]["pose"]["look_at_mm"] = [400.0, 400.0, 0.0]
    path = tmp_path / "away.yaml"
    path.write_text(yaml.safe_dump(rig))
    assert main(["--rig", str(path), "--poses", "5", "--seed", "0"]) == 0
    out = capsys.readouterr().out
    targets = out[out.index("targets"):].splitlines()[1:]
    assert len(targets) == 3, targets
    for line in targets:
        assert re.search(r"\(undecided: (\d+) of 10 marker looks missed, more than 5%", line), line
    assert "met)" not in out[out.index("targets"):]


def test_a_calibrated_rig_is_refused_not_rendered_as_if_it_were_true(main_in_process):
    """bench accuracy --rig cameras/planar.calib.yaml rendered with the calibration's own
    cameras and estimated with them (gripper 0.042 mm RMS at 20 poses, the true rig's figure;
    run on that calibration: 0.063 mm), its true_rig ignored without a word. Refused now, in
    one line naming the file, its true rig and the command that measures a calibration."""
    from conftest import ROOT

    calib = ROOT / "cameras" / "planar.calib.yaml"
    r = main_in_process("itg_vision.bench.accuracy", "--rig", calib, "--poses", 5)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert r.stderr.startswith(f"error: {calib}: a calibrated rig (of planar.yaml): ")
    assert f"python -m itg_vision.run --rig {calib}" in r.stderr
    # given with '..' (as an arm file's ../cameras/x.calib.yaml is read): the command without
    r = main_in_process("itg_vision.bench.accuracy", "--rig",
                        ROOT / "data" / ".." / "cameras" / calib.name, "--poses", 5)
    assert r.returncode == 2 and r.stderr.endswith(f"python -m itg_vision.run --rig {calib}\n")


def test_a_rig_that_sees_no_led_is_refused_after_the_noise_free_looks(tmp_path, monkeypatch):
    """A rig whose left camera is turned away sees no LED: the error came only after every
    pose had been looked at with every added noise too (4 looks a pose, 2.3-2.8 s at the
    default 250 poses); the noise-free looks decide it, so it comes after them (one a pose,
    1.0 s). Counted, not timed."""
    import yaml

    from itg_vision.errors import UserError
    from itg_vision.feedback import VisionFeedback

    rig = yaml.safe_load((CAMERAS_DIR / "planar.yaml").read_text())
    rig["cameras"][0]["pose"]["look_at_mm"] = [-180.0, -60.0, 1620.0]  # straight up
    path = tmp_path / "away.yaml"
    path.write_text(yaml.safe_dump(rig))
    looks = []
    observe = VisionFeedback.observe
    monkeypatch.setattr(VisionFeedback, "observe",
                        lambda fb, world: looks.append(fb.noise_px) or observe(fb, world))
    with pytest.raises(UserError, match=r"away\.yaml: no LED was seen by both cameras at any of "
                                        r"the 5 random poses of arm two-link \(10 looks missed\)"):
        measure(ArmSpec.from_args("two-link"), Rig.from_yaml(path), (0.0, 0.1, 0.3, 1.0),
                n_poses=5, seed=0)
    assert looks == [0.0] * 5
