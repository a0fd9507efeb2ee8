"""`bench speed --out` and `bench accuracy --out`: the folder holds exactly what was printed
(report.txt) and the printed figures (results.json), and replaces only what it made."""

import json

import numpy as np
import pytest
from conftest import PYBULLET_RTOL, roundoff

from itg_vision.bench import accuracy, speed
from itg_vision.outputs import MANIFEST


def _run(main, argv, capsys):
    rc = main(argv)
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.slow
def test_accuracy_out_saves_what_it_printed(tmp_path, capsys):
    out = tmp_path / "acc"
    rc, printed, err = _run(accuracy.main, ["--poses", "5", "--out", str(out)], capsys)
    assert rc == 0, err
    assert (out / "report.txt").read_text() == printed
    r = json.loads((out / "results.json").read_text())
    assert (r["poses"], r["seed"], r["arm"]) == (5, 0, "two-link")
    # every setting's row in the printout is the figure in results.json
    for label, s in r["settings"].items():
        row = next(line for line in printed.splitlines() if line.startswith(label))
        assert f"{s['centroid_rms_px']:.4f}/{s['centroid_p95_px']:.3f}" in row, (label, row)
        assert s["n_poses"] == 5
    assert set(r["settings"]) == {label for label, *_ in accuracy.SETTINGS}
    default = r["settings"][r["default"]]
    for row in default["rows"]:
        assert f"{row['measured_rms_mm']:.4f}" in printed
    # 5 poses cannot judge the ratio's 10 % band (its sampling error is ~0.2): no verdict
    ratio_line = next(line for line in printed.splitlines() if "first-order prediction" in line)
    assert "(undecided;" in ratio_line and "too few to judge" in ratio_line
    assert default["ratio_se"] > (accuracy.TARGET_RATIO - 1) / 2
    # a second run replaces its own folder; the same seed gives the same figures
    rc, printed2, err = _run(accuracy.main, ["--poses", "5", "--out", str(out)], capsys)
    assert rc == 0, err
    assert json.loads((out / "results.json").read_text())["settings"] == r["settings"]


def test_accuracy_out_refuses_a_users_folder_before_rendering(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    rc, printed, err = _run(accuracy.main, ["--poses", "5", "--out", str(mine)], capsys)
    assert rc == 2 and printed == "" and err.count("\n") == 1 and "--out" in err, err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    assert (mine / "notes.txt").read_text() == "keep me"
    rc, printed, err = _run(accuracy.main, ["--poses", "5", "--out", str(mine), "--force"],
                            capsys)
    assert rc == 0, err
    assert sorted(p.name for p in mine.iterdir()) == sorted([MANIFEST, "report.txt",
                                                             "results.json"])


def test_speed_out_saves_what_it_printed(tmp_path, capsys):
    out = tmp_path / "speed"
    rc, printed, err = _run(speed.main, ["--no-vision", "--out", str(out)], capsys)
    assert rc == 0, err
    assert (out / "report.txt").read_text() == printed
    r = json.loads((out / "results.json").read_text())
    us = r["decision_us"]
    assert r["machine"] == printed.splitlines()[0]
    # the target's ratio is the two saved times' ratio, and its verdict the threshold's
    key = "itg_plus_native_us" if r["target"]["compiled_to"] == "C" else "itg_plus_compiled_us"
    # JSON keeps a float's every digit (repr): the same division of the same numbers, bit for bit
    assert r["target"]["ratio"] == us["ik_pybullet_us"] / us[key]
    assert r["target"]["met"] == (r["target"]["ratio"] >= r["target"]["at_least"])
    assert f"{us['ik_pybullet_us']:.3f}" in printed
    assert len(r["ik_pybullet_miss_mm"]) == 720 and r["stereo_loop"]["rows"] == []
    assert r["stereo_loop"]["targets"] == {}  # none judged: the loop was not timed
    # beside each median the mean and the slowest pass, printed and saved
    for key in ("rules_compiled_us", "itg_plus_compiled_us", "ik_pybullet_us"):
        assert us[f"{key}_mean"] <= us[f"{key}_max"]
        assert f"{us[key]:.3f}{us[key + '_mean']:>10.3f}{us[key + '_max']:>10.3f}" in printed
    states = r["decision_states"]
    assert (states["trajectory"], states["set_points"], states["max_step_deg"]) == \
        ("ellipse-t1", 720, 20.0)
    far = states["gripper_from_set_point_mm"]
    assert set(far) == {"table2", "itg_plus"}
    assert f"Table 2 {far['table2']['median']:.2f} / {far['table2']['mean']:.2f}" in printed


def test_speed_out_records_the_stereo_loops_limits_it_judged(tmp_path, capsys):
    """results.json holds the limits of every target report.txt judges: the stereo loop's
    (default loop, its ratio to whole frames, the fastest setting, detect + triangulate) beside
    its rows, as accuracy's results.json holds its targets; it held only the IK ratio's."""
    out = tmp_path / "speed"
    rc, printed, err = _run(speed.main, ["--frames", "1", "--passes", "1", "--out", str(out)],
                            capsys)
    assert rc == 0, err
    loop = json.loads((out / "results.json").read_text())["stereo_loop"]
    assert loop["targets"] == {"default_loop_hz_at_least": 300.0,
                               "default_over_full_frame_at_least": 10.0,
                               "fastest_loop_hz_at_least": 500.0,
                               "detect_triangulate_ms_below": 0.5}
    assert "  default loop >= 300 Hz: " in printed
    assert ">= 10x: " in printed and "fastest honest setting >= 500 Hz: " in printed
    assert "detect + triangulate per stereo pair (both LEDs) < 0.5 ms: " in printed


def test_speed_times_each_rule_base_at_the_states_it_reaches():
    """The decision timings feed each rule base what it is given while tracking ellipse T1
    (its own replay: ideal feedback, the arm file's servo limit), not unrelated poses: the
    set points in order; markers that are the forward kinematics of the joint angles (ideal
    feedback); consecutive joint angles one servo-limited step apart (random poses are ~113
    deg apart per joint); and each gripper where the previous decision left it, so within
    E_(k-1) + |p_k - p_(k-1)| of its set point, E from the loop's own trace of the same rule
    base and limit."""
    from itg_vision.arm import ArmSpec, forward_kinematics
    from itg_vision.feedback import TruthFeedback
    from itg_vision.loop import simulate
    from itg_vision.rules import load_rules
    from itg_vision import trajectory as traj
    from itg_vision.world import World

    n = 120
    c = speed.decision_costs(n_points=n, repeat=1)
    arm = ArmSpec.from_args("two-link")
    servo = float(arm.benchmark["max_step_deg"])
    assert c["max_step_deg"] == servo
    pts = traj.named("ellipse-t1", n).points_mm
    step = np.linalg.norm(pts - np.roll(pts, 1, axis=0), axis=1)
    for name, rules in (("table2", load_rules("table2", 2, arm.links_mm, f=0.5)),
                        ("itg_plus", load_rules(arm.defaults["itg_plus_rules"], 2, arm.links_mm,
                                                S=servo, w=0.5))):
        states = c["states"][name]
        assert len(states) == n
        assert np.array_equal(np.array([s[0] for s in states]), pts)
        q = np.array([s[3] for s in states])
        for (_, m, _, _), qk in zip(states, q):
            fk = forward_kinematics(arm, qk)
            # the states' markers are PyBullet's float32 positions (conftest.PYBULLET_RTOL)
            assert np.allclose(m.gripper_mm, fk["gripper"], rtol=PYBULLET_RTOL, atol=roundoff(200))
            assert np.allclose(m.elbow_mm, fk["elbow"], rtol=PYBULLET_RTOL, atol=roundoff(200))
        # a step of at most the servo added to angles up to |q|: round-off at |q| (729 deg)
        assert np.abs(np.diff(q, axis=0)).max() <= servo + roundoff(np.abs(q).max())
        with World(arm) as world:
            trace = simulate(world, rules, TruthFeedback(), pts, max_step_deg=servo)
        e = trace.error_mm()
        far = c["from_set_point_mm"][name]
        # the same simulation, the same float32 positions: round-off of three distances (~300 mm)
        slack = roundoff(far.max() + e.max() + step.max())
        assert np.all(far[1:] <= e[:-1] + step[1:] + slack), name


@pytest.mark.parametrize("made_by", ["user", "bench accuracy"])
def test_speed_out_refuses_a_folder_it_did_not_make_before_timing(tmp_path, capsys, made_by):
    other = tmp_path / "other"
    if made_by == "user":
        other.mkdir()
        (other / "notes.txt").write_text("keep me")
    else:
        assert accuracy.main(["--poses", "5", "--out", str(other)]) == 0
        capsys.readouterr()
    before = {p.name: p.read_bytes() for p in other.iterdir()}
    rc, printed, err = _run(speed.main, ["--no-vision", "--out", str(other)], capsys)
    assert rc == 2 and printed == "" and err.count("\n") == 1 and "--out" in err, err
    assert {p.name: p.read_bytes() for p in other.iterdir()} == before


def test_bench_help_says_what_each_benchmark_measures(capsys):
    """`python -m itg_vision.bench --help` printed one usage line: it now names each benchmark
    with what it measures."""
    from itg_vision.bench import __main__ as bench

    assert bench.main(["--help"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == bench.USAGE
    for name in bench.NAMES:
        assert sum(ln.split()[:1] == [name] and len(ln.split()) > 4 for ln in lines) == 1, name
