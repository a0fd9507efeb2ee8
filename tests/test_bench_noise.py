"""`python -m itg_vision.bench noise`: the sweep end to end, resume, Dask, and the claims.

Timings are not asserted here (they belong to the benchmarks).
"""

from __future__ import annotations

import csv
import math
import os
from concurrent.futures import Executor, Future
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np
import pytest
from conftest import PYBULLET_RTOL, roundoff

from itg_vision import outputs
from itg_vision.bench import execute, noise
from itg_vision.bench.execute import run_one
from itg_vision.bench.noise import main
from itg_vision.bench.store import RUN_METRICS, definition_hash, make_row
from itg_vision.arm import ArmSpec, forward_kinematics
from itg_vision.bench.sweep import (CONTROLLERS, RIG_ANGLE_DEG, RIG_SHIFT_MM, TRAJECTORIES, RunSpec,
                                    build_sweep, load_trajectory, run_config)
from itg_vision.camera import perturbed
from itg_vision.errors import UserError
from itg_vision.rules import resolve_rules_path


#: Tests of a sweep's bookkeeping (resume, order, code) plot one metric: 4 plots, not 12, which
#: are most of a short sweep's time (0.9 against 2.5 s a call)
FEW_PLOTS = ("--plot-metrics", "e_av")


def perturb_rig(rig, seed, each_camera=False):
    """The bench's rig perturbation: 1 degree and 5 mm."""
    return perturbed(rig, seed, angle_deg=RIG_ANGLE_DEG, shift_mm=RIG_SHIFT_MM,
                     each_camera=each_camera)


def _rows(out):
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def _one_line_error(capsys, what: str):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and what in err[0], err
    return err[0]


# ---------------------------------------------------------------------------- sweep
@pytest.mark.slow
def test_quick_sweep_end_to_end(tmp_path):
    out = tmp_path / "q"
    assert main(["--quick", "--out", str(out), "--workers", "2", "--quiet"]) == 0
    rows = _rows(out)
    specs = build_sweep(quick=True)
    assert len(rows) == len(specs) and len({r["run_id"] for r in rows}) == len(rows)
    assert {r["controller"] for r in rows} == set(CONTROLLERS)
    for r in rows:
        for m in ("e_av_mm", "e_max_mm", "e_rms_mm", "track_median_mm", "track_mean_mm",
                  "track_p95_mm", "track_max_mm", "wall_s"):
            assert math.isfinite(float(r[m])), (r["controller"], r["condition"], m)
        v = {m: float(r[m]) for m in ("e_av_mm", "e_max_mm", "e_rms_mm", "track_median_mm",
                                      "track_mean_mm", "track_p95_mm", "track_max_mm")}
        # a mean is at most the RMS, which is at most the largest; so are a median and a p95
        assert 0 <= v["e_av_mm"] <= v["e_rms_mm"] <= v["e_max_mm"], r
        assert 0 <= v["track_median_mm"] <= v["track_p95_mm"] <= v["track_max_mm"], r
        assert v["track_mean_mm"] <= v["track_max_mm"] and float(r["wall_s"]) > 0, r
        assert int(r["n_missed"]) >= 0 and int(r["n_out_of_reach"]) >= 0
        # which LED each miss lost, and the lost elbows turned with the joints (vision only)
        assert int(r["n_missed"]) == int(r["n_missed_gripper"]) + int(r["n_missed_elbow"]), r
        assert int(r["n_elbow_turned"]) <= int(r["n_missed_elbow"]), r
    assert any(int(r["n_missed_elbow"]) > 0 for r in rows)  # the dropout conditions lose some
    report = (out / "report.md").read_text()
    assert "## Conclusion" in report and "vs `itg-model`" in report and "vs `ik`" in report
    for k in CONTROLLERS:
        assert f"| {k} " in report or f" {k} |" in report
    assert "servo limit 20 deg/iteration" in report and "2 laps" in report
    for png in ("e_av_vs_sigma", "e_av_vs_dropout", "e_av_vs_model_error", "e_av_by_condition",
                "track_max_vs_sigma", "track_median_by_condition"):
        assert (out / f"{png}-ellipse-t1.png").stat().st_size > 1000
    # rerunning a finished sweep runs nothing and keeps every row
    before = (out / "results.csv").read_bytes()
    assert main(["--quick", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    assert (out / "results.csv").read_bytes() == before


def test_resume_after_interruption_and_a_torn_last_line(tmp_path):
    # model-fed controllers only: the resume logic is what is tested, not the rendering; one
    # plot metric (4 plots, not 12: the plots are 3/4 of a short sweep's time)
    args = ["--quick", "--controllers", "itg-model,ik", "--seeds", "3", "--out", str(tmp_path),
            "--quiet", *FEW_PLOTS]
    specs = build_sweep(quick=True, controllers=("itg-model", "ik"), seeds=3)
    assert main(args + ["--workers", "1", "--limit", "7"]) == 0
    first = (tmp_path / "results.csv").read_text()
    assert len(_rows(tmp_path)) == 7
    # an interruption in the middle of a write: a partial row without its newline
    with open(tmp_path / "results.csv", "a") as f:
        f.write(first.splitlines()[3][:25])
    assert main(args + ["--workers", "2"]) == 0
    text = (tmp_path / "results.csv").read_text()
    assert text.startswith(first)  # the finished rows are untouched, in place
    rows = _rows(tmp_path)
    ids = [r["run_id"] for r in rows]
    assert len(ids) == len(set(ids)) == len(specs)
    assert set(ids) == {s.run_id for s in specs}


def test_a_report_or_plot_the_user_changed_is_kept_aside_not_written_over(tmp_path, capsys):
    """A rerun writes report.md and the plots again: one the user changed since (their notes
    added to the report, a plot replaced) is kept as report.replaced-1.md, ... with a note on
    stderr, and the new one written; an unchanged one is written over, and a file the benchmark
    did not write is left alone. The notes were lost."""
    args = ["--quick", "--controllers", "itg-model", "--seeds", "1", "--out", str(tmp_path),
            "--quiet", "--workers", "1", *FEW_PLOTS]
    assert main(args) == 0
    report = (tmp_path / "report.md").read_text()
    plot = sorted(tmp_path.glob("*.png"))[0]
    (tmp_path / "report.md").write_text(report + "MY NOTES\n")
    plot.write_bytes(b"my own figure")
    (tmp_path / "notes.md").write_text("mine")
    capsys.readouterr()
    assert main(args) == 0
    err = capsys.readouterr().err
    assert (tmp_path / "report.replaced-1.md").read_text() == report + "MY NOTES\n"
    assert (tmp_path / f"{plot.stem}.replaced-1.png").read_bytes() == b"my own figure"
    assert (tmp_path / "report.md").read_text() == report  # written again, as before
    assert plot.read_bytes().startswith(b"\x89PNG")
    assert (tmp_path / "notes.md").read_text() == "mine"
    assert err.count("was changed since the benchmark wrote it; kept as") == 2, err
    assert main(args) == 0  # nothing changed since: nothing more kept aside
    assert "kept as" not in capsys.readouterr().err
    assert len(list(tmp_path.glob("*.replaced-*"))) == 2


def test_a_failures_log_of_the_users_is_kept_aside_not_deleted(tmp_path, capsys):
    """A rerun where no run failed deletes the failures.log an earlier run wrote: one the
    benchmark never wrote (the user's own, in the folder it resumes into) is kept as
    failures.replaced-1.log with a note instead. It was deleted."""
    args = ["--quick", "--controllers", "itg-model", "--seeds", "1", "--out", str(tmp_path),
            "--quiet", "--workers", "1", *FEW_PLOTS]
    assert main(args) == 0 and not (tmp_path / "failures.log").exists()
    (tmp_path / "failures.log").write_text("my notes on the runs\n")
    capsys.readouterr()
    assert main(args) == 0
    assert (tmp_path / "failures.replaced-1.log").read_text() == "my notes on the runs\n"
    assert "is not a file the benchmark wrote; kept as" in capsys.readouterr().err
    assert not (tmp_path / "failures.log").exists()


def test_a_plot_of_the_users_under_a_name_a_rerun_writes_is_kept_aside(tmp_path, capsys):
    """A file of the user's under a name the benchmark had not written there (a plot of a
    metric the first run did not draw) is kept aside with a note before a rerun writes that
    plot; it was written over. A plot an earlier run wrote and a later run with other
    --plot-metrics left alone is still the benchmark's: written over without a note."""
    args = ["--quick", "--controllers", "itg-model", "--seeds", "1", "--out", str(tmp_path),
            "--quiet", "--workers", "1"]
    assert main(args + list(FEW_PLOTS)) == 0
    mine = tmp_path / "track_max_by_condition-ellipse-t1.png"
    assert not mine.exists()
    mine.write_bytes(b"my own figure")
    capsys.readouterr()
    assert main(args + ["--plot-metrics", "e_av,track_max"]) == 0
    assert "is not a file the benchmark wrote; kept as" in capsys.readouterr().err
    assert (tmp_path / f"{mine.stem}.replaced-1.png").read_bytes() == b"my own figure"
    assert mine.read_bytes().startswith(b"\x89PNG")
    assert main(args + list(FEW_PLOTS)) == 0
    assert main(args + ["--plot-metrics", "e_av,track_max"]) == 0
    assert "kept as" not in capsys.readouterr().err
    assert len(list(tmp_path.glob("*.replaced-*"))) == 1


def test_a_resume_by_other_code_warns_and_keeps_every_row(tmp_path, capsys):
    """Run ids cover parameters and input files, not the code: each row records the code that
    made it, and a resume says how many rows other code made (silent when none did)."""
    args = ["--quick", "--controllers", "itg-model,ik", "--out", str(tmp_path), "--quiet",
            "--workers", "1", *FEW_PLOTS]
    assert main(args + ["--limit", "3"]) == 0
    assert main(args + ["--limit", "1"]) == 0
    assert "other code" not in capsys.readouterr().err
    rows = _rows(tmp_path)
    assert len(rows) == 4 and len({r["code"] for r in rows}) == 1 and len(rows[0]["code"]) == 12
    report = (tmp_path / "report.md").read_text()
    assert f"source): `{rows[0]['code']}` (4 rows)." in report  # the report names its code
    text = (tmp_path / "results.csv").read_text()
    (tmp_path / "results.csv").write_text(text.replace(rows[0]["code"], "000000000000", 2))
    assert main(args + ["--limit", "1"]) == 0
    err = capsys.readouterr().err
    assert "2 of its 4 earlier rows were computed by other code (000000000000; now" in err
    report = (tmp_path / "report.md").read_text()
    assert f"`{rows[0]['code']}` (3 rows), `000000000000` (2 rows): more than one" in report
    assert main(args + ["--limit", "1"]) == 0  # the new row is this code's: still 2 of 5
    assert "2 of its 5 earlier rows were computed by other code" in capsys.readouterr().err
    assert len(_rows(tmp_path)) == 6


def test_an_inline_executor_hands_each_row_over_as_it_is_made_in_order(monkeypatch):
    """With one worker a run's row is stored before the next run starts (an interruption
    loses no finished row) and rows come in the sweep's order."""
    calls = []
    monkeypatch.setattr(execute, "run_one", lambda spec: calls.append(("run", spec.run_id))
                        or {"run_id": spec.run_id})
    specs = build_sweep(quick=True)[:6]
    for spec, _ in execute.results(execute.InlineExecutor(), specs, in_flight=2):
        calls.append(("yield", spec.run_id))
    assert calls == [(kind, s.run_id) for s in specs for kind in ("run", "yield")]


@pytest.mark.slow
def test_results_csv_keeps_the_sweeps_order_whatever_order_the_runs_finish_in(tmp_path,
                                                                            monkeypatch):
    """Parallel runs finish in any order; the same sweep must give the same file (and the
    targets built from its rows the same lines)."""
    args = ["--quick", "--controllers", "itg-model,ik", "--quiet", "--workers", "1", *FEW_PLOTS]
    specs = build_sweep(quick=True, controllers=("itg-model", "ik"))
    assert main(args + ["--out", str(tmp_path / "a")]) == 0

    def finish_backwards(executor, todo, in_flight):
        yield from reversed(list(execute.results(executor, todo, in_flight)))

    monkeypatch.setattr(noise, "results", finish_backwards)
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    a, b = _rows(tmp_path / "a"), _rows(tmp_path / "b")
    assert [r["run_id"] for r in b] == [s.run_id for s in specs]
    assert [{**r, "wall_s": ""} for r in b] == [{**r, "wall_s": ""} for r in a]
    # the report's time is the runs' wall-clock seconds summed (not simulated time)
    wall = sum(float(r["wall_s"]) for r in b)
    assert f"wall-clock time of the runs, summed {wall:.0f} s" in (tmp_path / "b" / "report.md").read_text()


def test_run_ids_are_stable_and_distinct():
    a, b = build_sweep(quick=True), build_sweep(quick=True)
    assert [s.run_id for s in a] == [s.run_id for s in b]
    assert len({s.run_id for s in a}) == len(a)
    assert definition_hash(a) != definition_hash(build_sweep(quick=True, seeds=3))


def test_an_edited_rule_file_gives_its_runs_new_ids_and_leaves_the_others(tmp_path, monkeypatch):
    """A resumed sweep never reuses a result computed with an older rule base."""
    from itg_vision.bench import sweep
    from itg_vision.rules import resolve_rules_path

    copy = tmp_path / "itg-plus-two-link.rules"
    copy.write_text(resolve_rules_path("itg-plus-two-link").read_text())
    monkeypatch.setattr(sweep, "resolve_rules_path",
                        lambda name: copy if name == "itg-plus-two-link" else resolve_rules_path(name))
    kw = dict(sweep="itg-plus", seeds=1, trajectories=("ellipse-t1",), conditions=("clean",))
    before = {s.controller: s.run_id for s in build_sweep(**kw)}
    copy.write_text(copy.read_text() + "\n# an edit\n")
    after = {s.controller: s.run_id for s in build_sweep(**kw)}
    assert before["itg-plus-vision"] != after["itg-plus-vision"]
    assert before["itg-vision"] == after["itg-vision"]
    assert before["jacobian-vision"] == after["jacobian-vision"]



def test_an_edited_trajectory_or_rig_file_gives_its_runs_new_ids(tmp_path, monkeypatch):
    """The files a run reads besides its rules are in its id too (schema 5): after an edit of
    the trajectory's file or of the arm's rig, the runs that read it get new ids, the others
    keep theirs."""
    from itg_vision import camera
    from itg_vision.bench import sweep

    traj = tmp_path / "peanut.csv"
    traj.write_text(Path(sweep.trajectory_source("peanut")).read_text())
    rig = tmp_path / "rig.yaml"
    rig.write_text(camera.default_rig_path("two-link").read_text())
    source, rig_of = sweep.trajectory_source, camera.default_rig_path
    monkeypatch.setattr(sweep, "trajectory_source",
                        lambda name: str(traj) if name == "peanut" else source(name))
    monkeypatch.setattr(camera, "default_rig_path",
                        lambda arm, calibrated=False: rig if not calibrated else rig_of(arm, True))
    kw = dict(seeds=1, trajectories=("peanut", "ellipse-t1"), conditions=("clean",),
              controllers=("itg-plus-vision", "itg-plus-model", "ik"))

    def ids():
        return {(s.trajectory, s.controller): s.run_id for s in build_sweep(**kw)}

    before = ids()
    lines = traj.read_text().splitlines()
    lines[-1] = lines[-1][:-1] + str((int(lines[-1][-1]) + 1) % 10)  # the last digit, moved
    traj.write_text("\n".join(lines) + "\n")
    edited = ids()
    assert all(edited[k] != before[k] for k in before if k[0] == "peanut")
    assert all(edited[k] == before[k] for k in before if k[0] == "ellipse-t1")
    rig.write_text(rig.read_text() + "\n# an edit\n")
    vision = {s.controller for s in build_sweep(**kw) if s.vision}
    assert vision == {"itg-plus-vision"}
    rigged = ids()
    assert all((v != edited[k]) == (k[1] in vision) for k, v in rigged.items())
    from itg_vision import arm as arm_module  # the arm file: every run of its trajectories

    arm_file = tmp_path / "two-link.yaml"
    arm_file.write_text(arm_module.arm_path("two-link").read_text() + "\n# an edit\n")
    arm_path = arm_module.arm_path
    monkeypatch.setattr(arm_module, "arm_path",
                        lambda name: arm_file if name == "two-link" else arm_path(name))
    assert all(v != rigged[k] for k, v in ids().items())


def test_a_resume_refused_for_an_edited_file_names_the_file(tmp_path, capsys):
    """The same command after an edit of one of its files (here the trajectory file) is another
    sweep, refused in one line: the line names the edited file (sweep.json records each file's
    hash); it said only 'an edited rule, arm, rig or trajectory file'. A sweep.json of before
    (no hashes) keeps that general line. No row is touched."""
    import json

    mine, out = tmp_path / "mine.csv", tmp_path / "o"
    mine.write_text("x_mm,y_mm\n100,0\n0,100\n-100,0\n")
    args = ["--trajectories", str(mine), "--controllers", "itg-model", "--conditions", "clean",
            "--seeds", "1", "--workers", "1", "--quiet", "--out", str(out), *FEW_PLOTS]
    assert main(args) == 0
    rows = (out / "results.csv").read_bytes()
    mine.write_text("x_mm,y_mm\n100,0\n0,100\n-100,1\n")
    capsys.readouterr()
    assert main(args) == 2
    line = _one_line_error(capsys, "holds results of a different sweep definition")
    assert f"; edited since: {mine.resolve()}): rerun with the same options" in line, line
    doc = json.loads((out / "sweep.json").read_text())
    assert mine.resolve().as_posix() in doc["files"]
    del doc["files"]
    (out / "sweep.json").write_text(json.dumps(doc))
    assert main(args) == 2
    assert "; other options, or an edited rule, arm, rig or trajectory file" in _one_line_error(
        capsys, "different sweep definition")
    assert (out / "results.csv").read_bytes() == rows


def test_a_run_that_cannot_start_is_a_row_not_a_failure(tmp_path, capsys, monkeypatch):
    """A start-up measurement that sees no LED (as under rig-perturbed-cams, whose rays miss by
    ~10 px) is an outcome of the condition: a row naming why, metrics empty, its cell saying
    how many did not start, exit 0, and a resume does not rerun it; a stale failures.log of an
    earlier attempt goes."""
    from itg_vision import runner
    from itg_vision.identify import StartUpFailed

    prepare = runner.prepare
    why = [RuntimeError("boom")]  # the first attempt fails; its retry cannot start

    def failing(cfg, estimate_rig=None):
        if cfg.seed == 1 and cfg.feedback == "vision":
            raise why[0]
        return prepare(cfg, estimate_rig=estimate_rig)

    monkeypatch.setattr(runner, "prepare", failing)
    out = tmp_path / "o"
    args = ["--quick", "--controllers", "itg-vision,ik", "--conditions", "clean", "--seeds", "2",
            "--points", "8", "--out", str(out), "--workers", "1", "--quiet"]
    assert main(args) == 1 and (out / "failures.log").exists()
    capsys.readouterr()
    why[0] = StartUpFailed("start-up measurement: the LEDs were measured in only 0 of 50")
    assert main(args) == 0
    rows = {(r["controller"], r["seed"]): r for r in _rows(out)}
    gone = rows["itg-vision", "1"]
    assert gone["no_start"].startswith("start-up measurement: the LEDs were measured in only 0")
    assert gone["e_av_mm"] == gone["track_max_mm"] == gone["diverged"] == ""
    assert all(r["no_start"] == "" and math.isfinite(float(r["e_av_mm"]))
               for k, r in rows.items() if k != ("itg-vision", "1"))
    report = (out / "report.md").read_text()
    assert "(1 of 2 did not start)" in report
    assert "Runs that did not start (left out of the conclusions' comparisons and of the plots): " \
        "itg-vision clean on ellipse-t1: 1 of 2. Why: start-up measurement" in report
    assert not (out / "failures.log").exists()
    err = capsys.readouterr().err
    assert "1 did not start" in err and "error" not in err
    assert main(args) == 0
    assert "0 to run" in capsys.readouterr().err



def test_a_limited_resume_keeps_the_failures_it_did_not_retry(tmp_path, capsys, monkeypatch):
    """failures.log lists every run that failed and still has no row: a resume with --limit
    that retries some of them keeps the others' lines (and exits 1); it goes once none is left."""
    from itg_vision import runner

    prepare, broken = runner.prepare, [True]

    def failing(cfg, estimate_rig=None):
        if broken[0] and cfg.controller == "itg":
            raise RuntimeError("boom")
        return prepare(cfg, estimate_rig=estimate_rig)

    monkeypatch.setattr(runner, "prepare", failing)
    out = tmp_path / "o"
    args = ["--quick", "--controllers", "itg-model,ik", "--conditions", "clean", "--seeds", "3",
            "--points", "8", "--out", str(out), "--workers", "1", "--quiet"]
    assert main(args) == 1
    assert len((out / "failures.log").read_text().splitlines()) == 3
    # each failure says where, on stderr: the traceback down to the raising line
    err = capsys.readouterr().err
    assert err.count("run failed: itg-model clean") == 3 and err.count("Traceback") == 3
    assert 'raise RuntimeError("boom")' in err and "in failing" in err
    broken[0] = False
    assert main(args + ["--limit", "1"]) == 1  # one retried and done, two left untried
    assert len((out / "failures.log").read_text().splitlines()) == 2
    assert main(args) == 0 and not (out / "failures.log").exists()
    assert len(_rows(out)) == 6


def test_cells_where_a_run_did_not_start_are_named_and_left_out_of_the_comparisons():
    """The conclusion compares medians over the same seeds only: a cell where a run did not
    start (here itg-vision's rig-perturbed-cams and links+5%) is in no comparison and no
    model-error line, and no_start_lines names each such cell and each reason once."""
    from itg_vision.bench.report import conclusion, no_start_lines, summarize

    def row(k, cond, seed, e, why=""):
        return {"trajectory": "ellipse-t1", "condition": cond, "controller": k, "seed": str(seed),
                "diverged": "" if why else "0", "no_start": why,
                **{c: "" if why else str(e) for c in ("e_av_mm", "e_max_mm", "track_median_mm",
                                                       "track_mean_mm", "track_p95_mm", "track_max_mm")}}

    why = "start-up measurement: the LEDs were measured in only 0 of 50 observations"
    rows = [row(k, c, s, e) for k, e in (("itg-vision", 9.0), ("ik", 1.0))
            for c in ("clean", "links+5%", "rig-perturbed-cams") for s in range(3)]
    rows = [row(r["controller"], r["condition"], r["seed"], 0, why) if r["controller"] == "itg-vision"
            and r["condition"] in ("rig-perturbed-cams", "links+5%") and r["seed"] != "0" else r
            for r in rows]
    summary = summarize(rows)
    assert summary["ellipse-t1", "links+5%", "itg-vision"]["n"] == 1
    conds, ctrls = ["clean", "links+5%", "rig-perturbed-cams"], ["itg-vision", "ik"]
    text = "\n".join(conclusion(summary, ["ellipse-t1"], conds, ctrls))
    assert "lower in 0 of 1 cells, higher in 1" in text  # clean only
    assert "ik: links+5% +0.00" in text and "itg-vision: links+5%" not in text
    assert "nan" not in text
    lines = no_start_lines(summary)
    assert lines[0].count("itg-vision") == 2 and "links+5% on ellipse-t1: 2 of 3" in lines[0]
    assert lines[0].endswith("Why: " + why)
    assert no_start_lines(summarize([r for r in rows if not r["no_start"]])) == []


def test_cells_missing_a_run_say_so_and_are_left_out_of_the_comparisons():
    """A run that failed (or a --limit that stopped the sweep) leaves its cell over fewer seeds
    than the sweep has. The cell says so, and the conclusion compares only cells whose every
    run has its row (before, itg-vision's clean cell over seeds 0-1 was compared with ik's
    over seed 0 alone, and the note said nothing)."""
    from itg_vision.bench.report import conclusion, missing_lines, summarize, _no_start_note

    cols = ("e_av_mm", "e_max_mm", "track_median_mm", "track_mean_mm", "track_p95_mm",
            "track_max_mm")
    rows = [{"trajectory": "ellipse-t1", "condition": c, "controller": k, "seed": str(s),
             "diverged": "0", "no_start": "", **{col: str(v) for col in cols}}
            for c in ("clean", "links+5%") for k, v in (("itg-vision", 9.0), ("ik", 1.0))
            for s in range(3) if not (k == "ik" and c == "clean" and s > 0)]  # 2 ik runs failed
    expected = {("ellipse-t1", c, k): 3 for c in ("clean", "links+5%") for k in ("itg-vision", "ik")}
    summary = summarize(rows, expected)
    cell = summary["ellipse-t1", "clean", "ik"]
    assert (cell["n"], cell["missing"]) == (1, 2)
    assert _no_start_note(cell) == " (2 of 3 have no result)"
    text = "\n".join(conclusion(summary, ["ellipse-t1"], ["clean", "links+5%"], ["itg-vision", "ik"]))
    assert "lower in 0 of 1 cells, higher in 1" in text  # links+5% only
    assert "ik: links+5%" not in text  # its clean cell, the base of the deltas, is incomplete
    assert missing_lines(summary)[0].endswith("ik clean on ellipse-t1: 2 of 3.")
    assert missing_lines(summarize(rows)) == []  # without the sweep's counts nothing is missing


def test_a_cell_whose_every_run_failed_says_so_and_is_listed(tmp_path, monkeypatch):
    """A cell none of whose runs has a row (each stopped by the input, or failed) says how many
    have no result in both tables and is named among the runs without a result; it was a "-",
    the mark of a cell the sweep does not run, and no line named it."""
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "div0.rules", "RULE 1: IF 1 > 0 THEN q1 += 1 / (xd - xd), q2 HOLD\n")
    assert main(["--quick", "--conditions", "clean", "--seeds", "2", "--controllers",
                 "itg-model,div0-model", "--rules", "div0.rules", "--out", "o", "--workers",
                 "1", "--quiet", *FEW_PLOTS]) == 2
    report = (tmp_path / "o" / "report.md").read_text()
    assert report.count("| clean | ") == 2
    assert report.count(" | no result (2 of 2 have no result) |") == 2
    assert "their cells are over the other seeds" in report
    assert "div0-model clean on ellipse-t1: 2 of 2." in report


def test_the_conclusion_counts_ties_within_5_percent_plus_0_01_mm_and_names_the_largest_loss():
    """A cell is a tie when the two medians are within 5 % of the larger plus 0.01 mm (1.04
    against 1.00, and 0.02 against 0.011 by the 0.01 mm), a loss beyond it (1.10 against 1.00;
    2.0 against 1.0) and a win below; the largest loss named is the largest ratio, 2x."""
    from itg_vision.bench.report import conclusion, summarize

    cells = {"clean": (1.04, 1.00), "links+5%": (1.10, 1.00), "rig-perturbed-cams": (2.0, 1.0),
             "noise-1px": (0.5, 1.0), "offset-1deg": (0.02, 0.011)}
    cols = ("e_av_mm", "e_max_mm", "track_median_mm", "track_mean_mm", "track_p95_mm",
            "track_max_mm")
    rows = [{"trajectory": "ellipse-t1", "condition": c, "controller": k, "seed": str(s),
             "diverged": "0", "no_start": "", **{col: str(v) for col in cols}}
            for c, pair in cells.items() for k, v in zip(("itg-vision", "ik"), pair)
            for s in range(3)]
    lines = conclusion(summarize(rows), ["ellipse-t1"], list(cells), ["itg-vision", "ik"])
    compared = [line for line in lines if "vs `ik`" in line]
    assert len(compared) == 3  # E_av, tracking mean, tracking max
    for line in compared:
        assert ("vs `ik`: lower in 1 of 5 cells, higher in 2, within 5 % of the larger + 0.01 mm in 2 "
                "(largest loss: rig-perturbed-cams on ellipse-t1, 2 against 1 mm, 2x).") in line


def test_a_cells_statistic_over_seeds_is_its_median_then_its_quartiles():
    """Each statistic of a cell is (median, q1, q3) over its seeds: runs of 1, 2, 3, 4 and
    10 mm give 3, and numpy's linear quartiles 2 and 4 (the mean, 4, plays no part)."""
    from itg_vision.bench.report import STATS, summarize

    rows = [{"trajectory": "t", "condition": "clean", "controller": "ik", "seed": str(i),
             "diverged": "0", "no_start": "", **{col: str(v) for col, _ in STATS}}
            for i, v in enumerate((1, 2, 3, 4, 10))]
    cell = summarize(rows)["t", "clean", "ik"]
    assert [cell[col.removesuffix("_mm")] for col, _ in STATS] == [(3.0, 2.0, 4.0)] * len(STATS)


# ---------------------------------------------------------------------------- Dask
@pytest.mark.slow
def test_dask_path_on_a_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    # processes=True: one PyBullet client per worker process, as on a real cluster
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        code = main(["--quick", "--conditions", "clean,links+5%", "--seeds", "1",
                     "--controllers", "itg-vision,ik", "--scheduler", cluster.scheduler_address,
                     "--out", str(tmp_path), "--quiet"])
    assert code == 0
    rows = _rows(tmp_path)
    assert len(rows) == 4 and {r["controller"] for r in rows} == {"itg-vision", "ik"}
    assert all(math.isfinite(float(r["e_av_mm"])) for r in rows)
    # the same runs give the same numbers in a local pool (seeded, independent)
    local = run_one(next(s for s in build_sweep(
        quick=True, conditions=("clean",), seeds=1, controllers=("itg-vision",))))
    dask_row = next(r for r in rows if r["controller"] == "itg-vision" and r["condition"] == "clean")
    # every metric as written (6 digits), but the wall time
    same = [k for k in RUN_METRICS if k != "wall_s"]
    assert {k: dask_row[k] for k in same} == {k: local[k] for k in same}


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("opt, value, what", [
    ("--controllers", "itg-vision,pid", "unknown controller 'pid'"),
    ("--conditions", "clean,fog", "unknown condition 'fog'"),
    ("--trajectories", "circle", "unknown trajectory 'circle'"),
])
def test_unknown_names_exit_2_with_one_line(tmp_path, capsys, opt, value, what):
    assert main(["--quick", opt, value, "--out", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, what)
    assert not (tmp_path / "o").exists()


@pytest.mark.slow  # dask waits out its 5 s connect timeout (the timeout itself: the next test)
def test_unreachable_scheduler_exits_2_and_loses_no_row(tmp_path, capsys):
    pytest.importorskip("distributed")
    args = ["--quick", "--controllers", "ik", "--seeds", "1", "--out", str(tmp_path), "--quiet",
            *FEW_PLOTS]
    assert main(args + ["--workers", "1"]) == 0
    before = (tmp_path / "results.csv").read_bytes()
    capsys.readouterr()
    assert main(args + ["--scheduler", "tcp://127.0.0.1:9"]) == 2
    _one_line_error(capsys, "--scheduler tcp://127.0.0.1:9: cannot connect")
    assert (tmp_path / "results.csv").read_bytes() == before


def test_the_dask_client_is_given_a_connect_timeout(monkeypatch):
    """An unreachable scheduler is given up after a bounded wait: the Client gets a timeout
    (what it does with it is dask's; how long it takes is a benchmark's business)."""
    distributed = pytest.importorskip("distributed")
    from itg_vision.errors import UserError

    seen = {}

    def client(address, **kw):
        seen.update(kw, address=address)
        raise OSError("refused")

    monkeypatch.setattr(distributed, "Client", client)
    monkeypatch.setattr(execute, "check_scheduler_answers", lambda address, timeout_s: None)
    with pytest.raises(UserError, match="cannot connect"):
        execute.dask_executor("tcp://127.0.0.1:9", timeout_s=5.0)
    assert seen == {"address": "tcp://127.0.0.1:9", "timeout": "5.0s", "set_as_default": False}


def test_a_scheduler_without_workers_says_the_sweep_waits(monkeypatch, capsys):
    """Dask queues the runs until a worker joins: a scheduler with none gets a note saying so
    (the sweep looked hung); with workers, no note and their threads counted."""
    distributed = pytest.importorskip("distributed")

    class Client:
        def __init__(self, address, **kw):
            pass

        def scheduler_info(self):
            return {"workers": workers}

        def get_executor(self, pure):
            return "executor"

    monkeypatch.setattr(distributed, "Client", Client)
    monkeypatch.setattr(execute, "check_scheduler_answers", lambda address, timeout_s: None)
    workers = {}
    assert execute.dask_executor("tcp://127.0.0.1:8786")[:2] == ("executor", 1)
    assert capsys.readouterr().err == ("note: the scheduler at tcp://127.0.0.1:8786 has no "
                                       "workers yet: the sweep waits for them (start them with "
                                       "`dask worker tcp://127.0.0.1:8786`)\n")
    workers = {"w1": {"nthreads": 2}, "w2": {"nthreads": 3}}
    assert execute.dask_executor("tcp://127.0.0.1:8786")[:2] == ("executor", 5)
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("extra, said", [
    (["--scheduler", ""], "--scheduler : expected tcp://HOST:PORT (port 1..65535)"),
    (["--scheduler", "tcp://127.0.0.1:9", "--workers", "2"],
     "--workers: sizes the local pool, which --scheduler replaces"),
])
def test_an_empty_scheduler_or_workers_beside_one_is_refused(tmp_path, capsys, monkeypatch,
                                                              extra, said):
    """``--scheduler ""`` (an unset variable: ``--scheduler "$DASK_SCHEDULER"``) ran the sweep
    on a local pool of every CPU, and ``--workers N`` beside a scheduler was dropped without a
    word: each is one line, exit 2, before any pool or Client is made."""
    made = []
    monkeypatch.setattr(noise, "local_executor", lambda workers: made.append(workers))
    monkeypatch.setattr(noise, "dask_executor", lambda address: made.append(address))
    assert main(["--quick", "--controllers", "ik", "--seeds", "1", "--out", str(tmp_path / "o"),
                 "--quiet", *extra]) == 2
    _one_line_error(capsys, said)
    assert made == [] and not (tmp_path / "o").exists()


class _Listener:
    """A TCP server on 127.0.0.1 that accepts every connection and keeps it open: silent
    (``reply`` None: a port whose service waits for its own protocol, as a dashboard's HTTP
    server waits for a request), or sending ``reply`` first."""

    def __init__(self, reply: bytes | None = None):
        import socket
        import threading

        self.sock = socket.create_server(("127.0.0.1", 0))
        self.address = f"tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.reply, self.held = reply, []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:  # closed
                return
            self.held.append(conn)
            if self.reply is not None:
                conn.sendall(self.reply)

    def close(self):
        self.sock.close()
        for conn in self.held:
            conn.close()


@pytest.mark.parametrize("reply, said", [
    (None, "no Dask scheduler answered within 1 s (the dashboard's port, or another service?)"),
    (b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n", "what answered is not a Dask "
                                                                   "scheduler"),
])
def test_a_scheduler_address_where_no_scheduler_answers_makes_no_client(monkeypatch, reply,
                                                                          said):
    """--scheduler at a port that accepts but is no Dask scheduler (a dashboard's HTTP port,
    another service) is one line naming --scheduler, and no Client is made: one made there
    waited for ever (the dashboard's port), or failed and then printed a traceback and hung
    10 s in its __del__."""
    distributed = pytest.importorskip("distributed")
    made = []

    def client(address, **kw):  # the real one would hang on a silent port
        made.append(address)
        raise OSError("refused")

    monkeypatch.setattr(distributed, "Client", client)
    server = _Listener(reply)
    try:
        with pytest.raises(UserError) as exc:
            execute.dask_executor(server.address, timeout_s=0.5)
    finally:
        server.close()
    assert str(exc.value) == f"--scheduler {server.address}: {said}" or (
        reply is not None and str(exc.value).startswith(f"--scheduler {server.address}: {said} ("))
    assert made == []


@pytest.mark.slow
def test_a_workers_address_given_as_the_scheduler_is_one_line(tmp_path, capsys):
    """A worker's address given to --scheduler (both are tcp://HOST:PORT in Dask's logs) is said
    in one line, exit 2, nothing written: the Client made there failed on the worker's reply,
    then printed a traceback and hung 10 s."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  protocol="tcp://", dashboard_address=None) as cluster:
        worker = next(iter(cluster.scheduler.workers))
        assert main(["--quick", "--controllers", "ik", "--seeds", "1", "--scheduler", worker,
                     "--out", str(tmp_path / "o"), "--quiet"]) == 2
    _one_line_error(capsys, f"--scheduler {worker}: a Dask Worker answered, not the scheduler "
                            "(give the scheduler's address)")
    assert not (tmp_path / "o").exists()


def test_out_from_a_different_sweep_exits_2_and_loses_no_row(tmp_path, capsys):
    args = ["--quick", "--controllers", "ik", "--out", str(tmp_path), "--quiet", "--workers", "1"]
    assert main(args + ["--seeds", "1"]) == 0
    before = (tmp_path / "results.csv").read_bytes()
    capsys.readouterr()
    assert main(args + ["--seeds", "2"]) == 2
    _one_line_error(capsys, "different sweep definition")
    assert (tmp_path / "results.csv").read_bytes() == before


def test_a_stale_calibrated_rig_is_refused_before_any_run(tmp_path, monkeypatch, capsys):
    """rig-calibrated reads the calibrated rig through the loader run uses: a calibration whose
    true rig was edited after it was made (true_rig_sha256 no longer matches) stops the sweep
    before any run, in one line, exit 2 (before the hash, every run estimated with the stale
    calibration without a word)."""
    import hashlib

    from itg_vision import camera

    true = tmp_path / "planar.yaml"
    true.write_text(camera.default_rig_path("two-link").read_text())
    rig = camera.Rig.from_yaml(true)
    calib = tmp_path / "planar.calib.yaml"
    calib.write_text(camera.Rig(rig.name, rig.cameras, "", {}, "planar.yaml").yaml_text()
                     + f"true_rig_sha256: {hashlib.sha256(true.read_bytes()).hexdigest()}\n")
    true.write_text(true.read_text() + "# moved nothing, but edited\n")
    monkeypatch.setattr(camera, "default_rig_path",
                        lambda arm, calibrated=False: calib if calibrated else true)
    out = tmp_path / "o"
    code = main(["--quick", "--conditions", "rig-calibrated", "--controllers", "itg-plus-vision",
                 "--seeds", "1", "--workers", "1", "--out", str(out)])
    assert code == 2 and not out.exists()
    _one_line_error(capsys, f"{calib}: its true rig {true} has changed since it was calibrated")


@pytest.mark.parametrize("rigs, arms, given", [(".", ".", "myrig.yaml"),
                                               ("rigs", "arms", "../rigs/myrig.yaml")])
def test_a_missing_calibrated_rig_is_refused_with_the_calibrate_command_that_makes_it(
        tmp_path, capsys, rigs, arms, given):
    """An arm file whose rig has no calibration yet: rig-calibrated is refused before any run,
    and the line gives the command that makes it, with this arm (--arm): without it, calibrate
    would take the shipped arm the rig names. An arm file's '../rigs/myrig.yaml' is shown as
    the folder it names (the command said .../arms/../rigs/myrig.calib.yaml)."""
    from itg_vision import camera

    (tmp_path / rigs).mkdir(exist_ok=True)
    (tmp_path / arms).mkdir(exist_ok=True)
    rig = tmp_path / rigs / "myrig.yaml"
    rig.write_text(camera.default_rig_path("two-link").read_text())
    arm = _arm_file(tmp_path / arms / "myarm.yaml", rig=("rig: planar", f"rig: {given}"))
    path = tmp_path / "p.csv"
    path.write_text("x_mm,y_mm\n100,0\n0,100\n-100,0\n")
    out = tmp_path / "o"
    assert main(["--trajectories", str(path), "--arm", str(arm), "--conditions",
                 "rig-calibrated", "--seeds", "1", "--workers", "1", "--out", str(out)]) == 2
    assert not out.exists()
    calib = tmp_path / rigs / "myrig.calib.yaml"
    _one_line_error(capsys, f"condition rig-calibrated needs {calib}: make it with `python -m "
                            f"itg_vision.calibrate --rig {rig} --arm {arm.resolve()} --out "
                            f"{calib}`")


def test_the_report_names_the_rig_files_an_arm_file_gave_its_runs(tmp_path):
    """An arm file whose defaults.rig is a rig of the user's: the report said only
    `cameras/<rig>.calib.yaml` and never which rig rendered and estimated. It names the true
    rig and, where rig-calibrated ran, the calibration beside it; a model-fed sweep no rig."""
    import hashlib

    from itg_vision import camera
    from itg_vision.bench.report import _rigs_line

    rig = tmp_path / "myrig.yaml"
    rig.write_text(camera.default_rig_path("two-link").read_text())
    arm = _arm_file(tmp_path / "myarm.yaml", rig=("rig: planar", f"rig: {rig.name}"))
    path = tmp_path / "p.csv"
    path.write_text("x_mm,y_mm\n100,0\n0,100\n-100,0\n")
    true = camera.Rig.from_yaml(rig)  # its calibration: the true rig itself, as a calibration
    (tmp_path / "myrig.calib.yaml").write_text(
        camera.Rig(true.name, true.cameras, "", {}, rig.name).yaml_text()
        + f"true_rig_sha256: {hashlib.sha256(rig.read_bytes()).hexdigest()}\n")

    def line(conditions, controllers):
        return _rigs_line(build_sweep(trajectories=(str(path),), arm=str(arm), seeds=1,
                                      conditions=conditions, controllers=controllers))

    both = line(("clean", "rig-calibrated"), ("itg-plus-vision",))
    assert f"`{rig.resolve()}`, calibrated `{tmp_path.resolve() / 'myrig.calib.yaml'}`" in both
    assert "cameras/planar" not in both
    assert "calibrated" not in line(("clean",), ("itg-plus-vision",)).split("`")[-1]
    assert line(("clean",), ("itg-model", "ik")) == ""


def test_cli_entry_point_exit_status(cli, tmp_path):
    res = cli("itg_vision.bench", "noise", "--quick", "--controllers", "nope", "--out", tmp_path / "o")
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "unknown controller 'nope'" in res.stderr


# ---------------------------------------------------------------------------- rigs
def test_perturbed_rig_is_off_by_exactly_one_degree_and_five_mm(tmp_path):
    """The rig file keeps every float (PyYAML writes repr), so what is left is float64
    round-off: of the rotations' entries (size 1; a trace sums 3, a product chains 3), of the
    cameras' positions (size ~1000 mm), and of the angle read back through arccos of the trace,
    whose slope at 1 deg is 1 / (2 sin 1 deg)."""
    from itg_vision.camera import Rig
    from itg_vision.runner import CAMERAS_DIR

    true = Rig.from_yaml(CAMERAS_DIR / "planar.yaml")
    far = max(np.abs(c.position_mm).max() for c in true.cameras) + 5.0
    angle_tol = np.degrees(roundoff(3) / (2 * np.sin(np.radians(1.0))))
    for each in (False, True):
        rig = perturb_rig(true, seed=3, each_camera=each)
        path = tmp_path / f"p{each}.yaml"
        rig.to_yaml(path)
        back = Rig.from_yaml(path)
        assert back.true_rig == str((CAMERAS_DIR / "planar.yaml").resolve())
        for c0, c1 in zip(true.cameras, back.cameras):
            dR = c1.R @ c0.R.T
            angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
            assert angle == pytest.approx(1.0, rel=0, abs=angle_tol)
            assert c1.K.tolist() == c0.K.tolist() and c1.dist == c0.dist
            if each:
                assert np.linalg.norm(c1.position_mm - c0.position_mm) == pytest.approx(5.0, rel=0, abs=roundoff(far))
        if not each:  # one body: a rigid motion, so each camera sees the other where it did
            (a0, a1), (b0, b1) = true.cameras, back.cameras
            assert np.allclose(b0.R @ (b1.position_mm - b0.position_mm),
                               a0.R @ (a1.position_mm - a0.position_mm), rtol=0, atol=roundoff(far))
            assert np.allclose(b1.R @ b0.R.T, a1.R @ a0.R.T, rtol=0, atol=roundoff(3))
    a, b = perturb_rig(true, 1), perturb_rig(true, 1)
    assert a.cameras == b.cameras and perturb_rig(true, 2).cameras != a.cameras


def test_perturbed_rig_draws_its_turn_and_shift_from_the_documented_stream():
    """The stream is numpy's default_rng([seed, 0x5EED]), an axis then a direction, as
    camera.perturbed's docstring says: the published rig-perturbed rows are reproducible from
    that sentence alone."""
    import cv2

    from itg_vision.camera import Rig
    from itg_vision.runner import CAMERAS_DIR

    true = Rig.from_yaml(CAMERAS_DIR / "planar.yaml")
    rng = np.random.default_rng([3, 0x5EED])
    axis, d = rng.normal(size=3), rng.normal(size=3)
    dR = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(RIG_ANGLE_DEG))[0]
    shift = RIG_SHIFT_MM * d / np.linalg.norm(d)
    pivot = np.mean([c.position_mm for c in true.cameras], axis=0)
    for c0, c1 in zip(true.cameras, perturb_rig(true, seed=3).cameras):
        assert np.allclose(c1.R.T @ c0.R, dR, rtol=0, atol=roundoff(3))  # R' = R dR^T
        assert np.allclose(c1.position_mm, pivot + dR @ (c0.position_mm - pivot) + shift,
                           rtol=0, atol=roundoff(1000))


# ---------------------------------------------------------------------------- the claims
def test_jacobian_tracker_converges_from_measured_positions_alone():
    """Truth feedback (measured marker positions, no model): a constant reachable set point."""
    from itg_vision.arm import ArmSpec
    from itg_vision.controllers import JacobianTracker
    from itg_vision.feedback import TruthFeedback
    from itg_vision.identify import ArmGeometry
    from itg_vision.loop import simulate
    from itg_vision.world import World

    true = ArmSpec.from_args("two-link", (107.0, 94.0))  # the tracker never sees these
    # uses only: planar, 2 joints, the base at the origin (no lengths at all)
    tracker = JacobianTracker(ArmGeometry((1.0, 1.0), source="none"), True, 2)
    target = np.array([120.0, 60.0, 0.0])
    with World(true) as world:
        trace = simulate(world, tracker, TruthFeedback(), np.tile(target, (300, 1)))
    e = trace.error_mm()
    assert e[0] > 50  # it starts far away (the start pose is at (0, 201))
    assert e[-1] < 0.1 and np.all(e[-50:] < 0.1)  # measured: ~1e-10 mm after 300 iterations


def test_a_row_records_the_start_ups_length_standard_error():
    """results.csv's measured_length_se_mm is the run's summary.json geometry.length_se_mm, the
    sL its rules read (RULE 0's margin; the three-link elbow's band reaches 2 sL): above 0 under
    the eye's 1 px noise, 0 for the nominal model's lengths."""
    from itg_vision.runner import execute as execute_run
    from itg_vision.runner import prepare

    for ctrl, measured in (("itg-plus-vision", True), ("itg-plus-model", False)):
        spec = build_sweep(conditions=("noise-1px",), controllers=(ctrl,),
                           trajectories=("ellipse-t1",), seeds=1, points=4)[0]
        _, s = execute_run(prepare(run_config(spec)))
        se = s["geometry"]["length_se_mm"]
        assert (se > 0) == measured, se
        assert float(make_row(spec, s)["measured_length_se_mm"]) == pytest.approx(se, rel=1e-5)


@pytest.mark.slow
def test_model_error_hurts_the_model_based_controllers_not_the_vision_fed_ones():
    """Simulated links 5 % longer than the nominal model, ellipse-t1 (2 laps, seed 0).

    Physics: the true arm is the nominal one scaled by 1.05, so a controller that believes the
    model puts the gripper 5 % farther from the base than it thinks: 0.05 r, 1.5 to 5.5 mm on
    T1 (r = 30..110 mm), ~2.7 mm at the median radius. Open-loop IK shows exactly that bias.
    Vision-fed controllers see the true arm (and measure its lengths at start-up): no bias.
    (The model-fed ITG's lag, ~3.5 mm in a direction that varies, adds to the bias as a vector,
    so its median can move either way: it is not asserted here.)
    """
    res = {}
    for ctrl in ("ik", "itg-vision", "jacobian-vision"):
        for cond in ("clean", "links+5%"):
            spec = build_sweep(conditions=(cond,), controllers=(ctrl,), trajectories=("ellipse-t1",),
                               seeds=1)[0]
            row = run_one(spec)
            res[ctrl, cond] = (float(row["track_median_mm"]), row["measured_links_mm"])

    def grow(ctrl):
        return res[ctrl, "links+5%"][0] - res[ctrl, "clean"][0]

    assert 0.5 * 2.7 < grow("ik") < 1.5 * 2.7
    # measured at start-up from the LEDs: 105 mm within vision's ~0.3 mm
    links = [float(v) for v in res["itg-vision", "links+5%"][1].split(";")]
    assert links == pytest.approx([105.0, 105.0], abs=0.5)
    # vision feedback: the bias is gone; what remains is the rules' own lag (its shape changes
    # a little with the arm) and estimation noise
    assert abs(grow("itg-vision")) < 0.5
    assert abs(grow("jacobian-vision")) < 0.1


def test_run_spec_maps_controllers_and_conditions_onto_run_config():
    specs = {(s.controller, s.condition): s for s in build_sweep(
        conditions=("clean", "links+5%", "offset-1deg", "noise-1px+links+5%"),
        trajectories=("ellipse-t1", "line-ab-reach"), seeds=1)
        if s.trajectory == "ellipse-t1"}
    cfg = run_config(specs["ik", "clean"])
    # every controller of a trajectory runs under the same limits; ellipses run 2 laps
    assert {(s.iterations, s.max_step_deg, s.laps) for s in specs.values()} == {(1, 20.0, 2)}
    assert (cfg.controller, cfg.feedback, cfg.iterations, cfg.max_step_deg) == ("ik", "model", 1, 20.0)
    cfg = run_config(specs["itg-vision", "noise-1px+links+5%"])
    assert (cfg.controller, cfg.feedback, cfg.noise_px) == ("itg", "vision", 1.0)
    assert cfg.true_links_mm == (105.0, 105.0)  # 100 x 1.05 rounded to 9 decimals: exact
    # the column says its unit: links+5% is link_error_pct 5, and lengths 100 mm * 1.05 to the
    # nearest double (bit for bit what the former fraction column gave)
    assert specs["itg-vision", "links+5%"].link_error_pct == 5.0
    assert run_config(specs["itg-vision", "links+5%"]).true_links_mm == (round(100.0 * 1.05, 9),) * 2
    assert run_config(specs["jacobian-vision", "offset-1deg"]).joint_offset_deg == (1.0, 1.0)
    three = [s for s in build_sweep(trajectories=("line-ab-reach",), conditions=("clean",), seeds=1)]
    assert all(isinstance(s, RunSpec) and s.arm == "three-link" and s.max_step_deg == 2.0
               and s.iterations == 5 for s in three)


# ---------------------------------------------------------------------------- rows and failures
def test_rows_record_the_controller_parameters_the_run_used():
    """The parameters the runner reports as used (its controller_params), not a stale column."""
    from itg_vision.runner import RULE_DEFAULTS, prepare

    specs = {s.controller: s for s in build_sweep(quick=True, seeds=1, conditions=("clean",),
                                                  controllers=("itg-model", "ik"), points=4)}
    itg = run_one(specs["itg-model"])
    used = prepare(run_config(specs["itg-model"])).info["controller_params"]
    assert used and set(used) <= set(RULE_DEFAULTS)  # table2 uses its gain and tolerance
    assert itg["controller_params"] == ";".join(f"{k}={v:g}" for k, v in used.items())
    assert run_one(specs["ik"])["controller_params"] == ""  # open-loop IK takes none


def test_a_row_counts_the_points_of_one_lap_and_keeps_six_digits():
    """results.csv: ``points`` is the set points of one lap (the quick sweep runs T1 for 2 laps,
    here of 4), and the metrics keep 6 significant digits: within half a unit of the 6th (5e-6
    relative) of the same run's summary (Table 2 on the exact model: no randomness)."""
    from itg_vision.runner import execute as run, prepare

    spec = next(iter(build_sweep(quick=True, seeds=1, conditions=("clean",),
                                 controllers=("itg-model",), points=4)))
    row = run_one(spec)
    _, s = run(prepare(run_config(spec)))
    assert (spec.laps, row["points"], row["n_setpoints"]) == (2, "4", "8")
    for col in ("e_av_mm", "e_max_mm", "e_rms_mm", "track_median_mm", "track_p95_mm"):
        assert float(row[col]) == pytest.approx(s[col], rel=5e-6), col


def test_a_sweep_where_every_run_fails_reports_and_exits_1(tmp_path, capsys, monkeypatch):
    """No finished run: nothing to plot (a log axis with no value raised), report.md says so."""
    monkeypatch.setattr(execute, "run_one", lambda spec: {"run_id": spec.run_id,
                                                          "error": "RuntimeError: boom"})
    out = tmp_path / "o"
    args = ["--quick", "--controllers", "itg-model,ik", "--out", str(out), "--workers", "1",
            "--quiet"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error: 24 runs failed" in err
    assert "None: no run of this sweep has finished." in (out / "report.md").read_text()
    assert not list(out.glob("*.png"))
    assert len((out / "failures.log").read_text().splitlines()) == 24


def test_figure_titles_say_which_sweep_they_show():
    """A benchmark figure names its set points, laps, iterations, servo limit and seeds, read
    from the sweep's run specs (the quick sweep: 60 points per lap, 2 laps, 2 seeds)."""
    from itg_vision.bench.report import _sweep_line

    specs = build_sweep(quick=True)
    mine = [s for s in specs if s.trajectory == "ellipse-t1"]
    s = mine[0]
    assert (s.points, s.laps, s.iterations, s.max_step_deg) == (60, 2, 1, 20.0)
    assert len({x.seed for x in mine}) == 2
    assert _sweep_line(specs, "ellipse-t1") == ("60 set points, 2 laps, 1 iteration(s), "
                                                "servo 20 deg/iteration; 2 seeds")


def test_figure_titles_count_the_set_points_of_a_path_the_sweep_does_not_resample():
    """A path run at its own set points (a file, or the start-tie sweep's line) was titled
    "the path's set points": `bench itg-plus` on peanut (150 per lap), whose targets.md says
    150, and `--sweep start-tie` (line-ab-reach, 100)."""
    from itg_vision.bench.report import _sweep_line

    specs = build_sweep(sweep="itg-plus", trajectories=("peanut",), seeds=1)
    assert {s.points for s in specs} == {None}
    assert _sweep_line(specs, "peanut").startswith("150 set points, 2 laps, ")
    specs = build_sweep(sweep="start-tie", seeds=1)
    assert _sweep_line(specs, "line-ab-reach").startswith("100 set points, 5 iteration(s), ")


# ---------------------------------------------------------------------------- --rules
def _write_rules(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_users_rule_base_runs_beside_the_sweeps_controllers_on_the_arms_it_fits(tmp_path):
    mine = _write_rules(tmp_path / "mine.rules", Path(resolve_rules_path("table2")).read_text())
    specs = build_sweep(rules=(str(mine),))  # the robustness sweep: two- and three-link paths
    by_traj = {}
    for s in specs:
        by_traj.setdefault(s.trajectory, set()).add(s.controller)
    for t, ctrls in by_traj.items():
        two_link = TRAJECTORIES[t] == "two-link"
        assert {"mine-vision", "mine-model"} <= ctrls if two_link else not ctrls & {
            "mine-vision", "mine-model"}, t
        assert set(CONTROLLERS) <= ctrls
    ours = [s for s in specs if s.controller.startswith("mine-")]
    assert {s.rules for s in ours} == {str(mine.resolve())}
    assert {(s.rc_controller, s.feedback) for s in ours} == {("itg", "vision"), ("itg", "model")}
    # the same cells as the shipped ITG: every condition and seed, under the same limits
    theirs = {(s.trajectory, s.condition, s.seed, s.feedback, s.max_step_deg, s.iterations, s.laps)
              for s in specs if s.controller in ("itg-vision", "itg-model")
              and TRAJECTORIES[s.trajectory] == "two-link"}
    assert {(s.trajectory, s.condition, s.seed, s.feedback, s.max_step_deg, s.iterations, s.laps)
            for s in ours} == theirs
    # --controllers may name them, and then decides
    only = build_sweep(quick=True, rules=(str(mine),), controllers=("mine-vision", "ik"))
    assert {s.controller for s in only} == {"mine-vision", "ik"}


def _closed_form_tol(value_mm, start_mm):
    """How far a held arm's E_av or E_max, as a results row writes it (%.6g), may be from its
    closed form (the mean or largest distance of the set points from the start pose's gripper,
    ``start_mm``): six significant digits are within half a unit of the sixth, 5e-6 of the value;
    the run's gripper is PyBullet's float32 one, within a ulp (PYBULLET_RTOL) of the forward
    kinematics; and float64 round-off at the distances' size."""
    scale = np.linalg.norm(start_mm) + abs(value_mm)
    return 5e-6 * abs(value_mm) + PYBULLET_RTOL * np.linalg.norm(start_mm) + roundoff(scale)


@pytest.mark.slow
def test_a_users_rule_base_is_what_its_controllers_run(tmp_path):
    """A copy of Table 2 tracks exactly as the shipped ITG does (same seeds, same numbers); a
    rule base that holds every joint leaves the gripper at its start, so its E_av is the mean
    distance from the start to the set points (forward kinematics of the start pose)."""
    table2 = Path(resolve_rules_path("table2")).read_text()
    _write_rules(tmp_path / "copy.rules", table2)
    _write_rules(tmp_path / "still.rules", "RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD\n")
    out = tmp_path / "o"
    assert main(["--quick", "--conditions", "clean,noise-1px", "--seeds", "1", "--rules",
                 str(tmp_path / "copy.rules"), "--rules", str(tmp_path / "still.rules"),
                 "--controllers", "itg-vision,copy-vision,still-model", "--out", str(out),
                 "--workers", "1", "--quiet", "--plot-metrics", "e_av"]) == 0
    rows = {(r["controller"], r["condition"]): r for r in _rows(out)}
    metrics = ("e_av_mm", "e_max_mm", "track_median_mm", "track_max_mm", "n_missed")
    for cond in ("clean", "noise-1px"):
        assert [rows["copy-vision", cond][m] for m in metrics] == \
               [rows["itg-vision", cond][m] for m in metrics]
    arm = ArmSpec.from_args("two-link")
    start = forward_kinematics(arm, arm.start_q_deg)["gripper"][:2]
    lap = load_trajectory("ellipse-t1", 60).points_mm[:, :2]
    dist = np.linalg.norm(lap - start, axis=1)
    # the row keeps six digits (%.6g): the closed form agrees to that rounding
    for col, expected in (("e_av_mm", dist.mean()), ("e_max_mm", dist.max())):
        assert float(rows["still-model", "clean"][col]) == pytest.approx(
            expected, rel=0, abs=_closed_form_tol(expected, start)), col
    report = (out / "report.md").read_text()
    assert "## Conclusion for `copy-vision` (your rule base)" in report
    assert f"your rule base {(tmp_path / 'still.rules').resolve()} (--rules) fed by encoders" \
        in report


def test_the_default_out_of_a_sweep_with_rules_is_its_own(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "mine.rules", "RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD\n")
    assert main(["--quick", "--conditions", "clean", "--seeds", "1", "--controllers",
                 "mine-model", "--rules", "mine.rules", "--workers", "1", "--quiet"]) == 0
    assert (tmp_path / "runs" / "bench-noise-quick-mine" / "results.csv").is_file()
    assert not (tmp_path / "runs" / "bench-noise-quick").exists()


def test_runs_your_rule_base_stops_are_one_line_each_and_exit_2(tmp_path, monkeypatch, capsys):
    """A rule whose step is not finite stops each run the same way at every retry: each run's
    one-line reason (no traceback), failures.log lists them, and the last line says the input
    is to be fixed (exit 2), not 'rerun to retry' (exit 1, as for a run that crashed)."""
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "div0.rules", "RULE 1: IF 1 > 0 THEN q1 += 1 / (xd - xd), q2 HOLD\n")
    args = ["--quick", "--conditions", "clean", "--seeds", "1", "--controllers", "div0-model",
            "--rules", "div0.rules", "--out", "o", "--workers", "1", "--quiet", *FEW_PLOTS]
    for _ in range(2):  # a rerun of the same input stops the same runs
        assert main(args) == 2
        err = capsys.readouterr().err
        logged = (tmp_path / "o" / "failures.log").read_text().splitlines()
        failed = [line for line in err.splitlines() if line.startswith("run failed: ")]
        assert "Traceback" not in err and len(failed) == len(logged) > 0
        assert all("div0.rules:1: RULE 1 gives q1 a step of inf deg" in x for x in failed + logged)
        last = err.strip().splitlines()[-1]
        assert last.startswith(f"error: {len(logged)} of {len(logged)} failed runs were stopped by "
                               "your input") and "fix it" in last and "retry" not in last
    assert not (tmp_path / "o" / "results.csv").exists() or not _rows(tmp_path / "o")


@pytest.mark.parametrize("second", ["mine.rules", "./mine.rules"])
def test_a_rule_file_given_twice_is_refused_as_given_twice(tmp_path, monkeypatch, capsys, second):
    """The same file twice (by the same name or another path to it) was told to 'rename the
    file', which would not help; two files with the same stem still are."""
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "mine.rules", "RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD\n")
    assert main(["--quick", "--rules", "mine.rules", "--rules", second, "--out", "o",
                 "--quiet"]) == 2
    err = _one_line_error(capsys, f"--rules {second}: given twice")
    assert "rename" not in err and ("the same file" in err) == (second != "mine.rules")
    assert not (tmp_path / "o").exists()


def test_two_rule_files_with_one_stem_are_told_to_rename_one(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        _write_rules(tmp_path / d / "mine.rules", "RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD\n")
    assert main(["--quick", "--rules", "a/mine.rules", "--rules", "b/mine.rules", "--out", "o",
                 "--quiet"]) == 2
    err = _one_line_error(capsys, "--rules b/mine.rules: its controllers would be called "
                                  "mine-vision and mine-model, but mine-model is taken")
    assert err.endswith("rename the file")
    assert not (tmp_path / "o").exists()


def test_a_rule_file_whose_name_holds_a_comma_is_told_to_rename(tmp_path, monkeypatch, capsys):
    """Its controllers ('a,b-vision') could run but never be chosen: --controllers splits on
    commas ('unknown controller a'). Refused up front, before any folder is made."""
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "a,b.rules", "RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD\n")
    assert main(["--quick", "--rules", "a,b.rules", "--out", "o", "--quiet"]) == 2
    _one_line_error(capsys, "--rules a,b.rules: its controllers would be called a,b-vision and "
                            "a,b-model, which --controllers (a list separated by commas) cannot "
                            "name: rename the file")
    assert not (tmp_path / "o").exists()


def test_list_names_your_files_and_refuses_bad_ones_before_printing(tmp_path, monkeypatch,
                                                                     capsys):
    """--list lists your rule base's controllers and your trajectory files beside the shipped
    ones, and the sweep's size with them; a file the sweep would refuse is refused by --list
    too (it printed the lists, then the error), printing nothing on stdout."""
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "mine.rules", Path(resolve_rules_path("table2")).read_text())
    (tmp_path / "my path.csv").write_text("x_mm,y_mm\n120,40\n100,80\n60,60\n")
    given = ["--quick", "--rules", "mine.rules", "--trajectories", "my path.csv,ellipse-t1"]
    assert main([*given, "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert f"  yours (--rules): mine-vision, mine-model: {tmp_path / 'mine.rules'}, on the " \
           "two-link arm" in lines
    assert f"  yours (--trajectories): my path: {tmp_path / 'my path.csv'}, on the two-link " \
           "arm" in lines
    n = len(build_sweep(quick=True, rules=("mine.rules",),
                        trajectories=("my path.csv", "ellipse-t1")))
    assert lines[-1].startswith(f"sweep: {n} runs")
    for bad in (["--rules", "gone.rules"], ["--rules", "mine.rules", "--rules", "mine.rules"],
                ["--trajectories", "gone.csv"]):
        assert main(["--quick", *bad, "--list"]) == 2
        out = capsys.readouterr().out
        assert out == "", bad
    assert main(["--quick", "--rules", "mine.rules", "--rules", "./mine.rules", "--list"]) == 2
    _one_line_error(capsys, "--rules ./mine.rules: given twice")


@pytest.mark.slow
def test_rule_parameters_reach_your_rule_base_as_run_gives_them(tmp_path, capsys):
    """--gain 0.3 with a copy of Table 2: its runs give the numbers `run --rules COPY --gain
    0.3` gives under the benchmark's limits for that cell, record f = 0.3 in controller_params
    and the report's Setup line, and differ from f = 0.5, which the shipped itg controllers
    keep. The sweep is another sweep: a rerun with another f into its --out is refused."""
    import json

    from itg_vision import run

    copy = _write_rules(tmp_path / "copy.rules", Path(resolve_rules_path("table2")).read_text())
    out = tmp_path / "o"
    given = ["--quick", "--conditions", "clean,noise-1px", "--seeds", "1", "--rules", str(copy),
             "--controllers", "itg-vision,itg-model,copy-vision,copy-model", "--out", str(out),
             "--workers", "1", "--quiet", "--plot-metrics", "e_av"]
    assert main([*given, "--gain", "0.3"]) == 0
    rows = {(r["controller"], r["condition"]): r for r in _rows(out)}
    metrics = ("e_av_mm", "e_max_mm", "track_median_mm", "track_max_mm", "n_missed")
    for cond in ("clean", "noise-1px"):
        for fed in ("vision", "model"):
            mine, shipped = rows[f"copy-{fed}", cond], rows[f"itg-{fed}", cond]
            assert mine["controller_params"] == "gain_deg_per_mm=0.3"  # Table 2 reads f only
            assert shipped["controller_params"] == "gain_deg_per_mm=0.5"
            assert mine["e_av_mm"] != shipped["e_av_mm"], (fed, cond)  # f changes the steps
    spec = next(s for s in build_sweep(quick=True, conditions=("noise-1px",), seeds=1,
                                       rules=(str(copy),), controllers=("copy-vision",),
                                       rule_params={"gain_deg_per_mm": 0.3}))
    assert spec.gain_deg_per_mm == 0.3 and spec.run_id == rows["copy-vision", "noise-1px"]["run_id"]
    alone = tmp_path / "run"
    assert run.main(["--rules", str(copy), "--gain", "0.3", "--trajectory", spec.trajectory,
                     "--points", str(spec.points), "--laps", str(spec.laps), "--max-step",
                     f"{spec.max_step_deg:g}", "--iterations", str(spec.iterations),
                     "--noise-px", f"{spec.noise_px:g}", "--seed", str(spec.seed), "--out",
                     str(alone), "--quiet"]) == 0
    summary = json.loads((alone / "summary.json").read_text())
    assert summary["controller_params"] == {"gain_deg_per_mm": 0.3}
    # the row keeps six digits (%.6g)
    assert [rows["copy-vision", "noise-1px"][m] for m in metrics] == \
           [f"{summary[m]:.6g}" for m in metrics]
    report = (out / "report.md").read_text()
    assert f"rules {copy.resolve()}, gain_deg_per_mm=0.3)" in report
    assert json.loads((out / "sweep.json").read_text())["options"]["gain"] == 0.3
    before = (out / "results.csv").read_text()
    capsys.readouterr()
    assert main([*given, "--gain", "0.4"]) == 2
    _one_line_error(capsys, f"--out {out} holds results of a different sweep definition")
    assert (out / "results.csv").read_text() == before


@pytest.mark.parametrize("rules, given, what", [
    (None, ["--gain", "0.3"], "--gain: applies to your rule bases (--rules), and none is given"),
    ("copy", ["--gain", "-1"], "--gain: must be in (0, 1e6] deg/mm, got -1.0"),
    ("copy", ["--tolerance", "nan"], "--tolerance: must be in [0, 1e4] mm, got nan"),
    ("copy", ["--step", "3"], "--rules copy.rules: --step: copy.rules never uses S"),
    ("copy", ["--tolerance", "0.2"], "--rules copy.rules: --tolerance: copy.rules never uses w"),
    ("plus", ["--step", "3"], "--rules plus.rules: --step: plus.rules: S is the servo limit (20 "
                              "deg per iteration): the benchmark runs every controller"),
])
def test_rule_parameters_are_refused_as_run_refuses_them(tmp_path, monkeypatch, capsys, rules,
                                                         given, what):
    """Out of range, never used by the rules, or another S than the servo limit of a file
    that binds S to it (`#! S is the servo limit`): one line, exit 2, nothing written; and
    without --rules (the shipped controllers keep their parameters)."""
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "copy.rules", Path(resolve_rules_path("table2")).read_text())
    _write_rules(tmp_path / "plus.rules",
                 Path(resolve_rules_path("itg-plus-two-link")).read_text())
    mine = ["--rules", f"{rules}.rules"] if rules else []
    assert main(["--quick", *mine, *given, "--out", "o", "--quiet"]) == 2
    _one_line_error(capsys, what)
    assert not (tmp_path / "o").exists()
    assert main(["--quick", *mine, *given, "--list"]) == 2  # --list checks them too
    _one_line_error(capsys, what)


def test_rule_parameters_name_the_default_out_and_a_servo_step_may_repeat_the_limit(
        tmp_path, monkeypatch):
    """Without --out, other values of f, S, w go to other folders (run's labels: f0.3), so
    each sweep keeps its results; an S equal to the servo limit of a file binding S to it is
    what it runs anyway (run accepts it too): the same runs, by the same ids, as without it."""
    monkeypatch.chdir(tmp_path)
    _write_rules(tmp_path / "mine.rules", Path(resolve_rules_path("table2")).read_text())
    for f in ("0.3", "0.4"):
        assert main(["--quick", "--conditions", "clean", "--seeds", "1", "--controllers",
                     "mine-model", "--rules", "mine.rules", "--gain", f, "--workers", "1",
                     "--quiet", *FEW_PLOTS]) == 0
        rows = _rows(tmp_path / "runs" / f"bench-noise-quick-mine-f{f}")
        assert [r["controller_params"] for r in rows] == [f"gain_deg_per_mm={f}"]
    _write_rules(tmp_path / "plus.rules", Path(resolve_rules_path("itg-plus-two-link")).read_text())
    given, omitted = (build_sweep(quick=True, rules=("plus.rules",), controllers=("plus-model",),
                                  rule_params=params) for params in ({"step_deg": 20.0}, None))
    assert {(s.step_deg, s.max_step_deg) for s in given} == {(None, 20.0)}
    assert [s.run_id for s in given] == [s.run_id for s in omitted]
    from itg_vision.bench.sweep import run_config
    from itg_vision.runner import prepare

    assert prepare(run_config(given[0])).controller.S == 20.0  # S bound to the limit
    assert main(["--quick", "--conditions", "clean", "--seeds", "1", "--controllers",
                 "plus-model", "--rules", "plus.rules", "--step", "20", "--workers", "1",
                 "--quiet", *FEW_PLOTS]) == 0  # and their folder: no S20 in its name
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == [
        "bench-noise-quick-mine-f0.3", "bench-noise-quick-mine-f0.4", "bench-noise-quick-plus"]
    assert [r["run_id"] for r in _rows(tmp_path / "runs" / "bench-noise-quick-plus")] == [
        s.run_id for s in omitted if s.condition == "clean" and s.seed == 0]


def test_a_users_controller_is_unknown_without_its_rules(tmp_path, capsys):
    assert main(["--quick", "--controllers", "mine-vision", "--out", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "unknown controller 'mine-vision'")


# ---------------------------------------------------------------------------- trajectory files
def test_a_trajectory_file_in_metres_gets_runs_note_on_stderr_and_in_the_report(tmp_path,
                                                                                capsys):
    """T1 written in metres under an x_mm header (a 0.1 mm path about the base): the sweep runs
    it as written, as `run` does, and says what `run` says, on stderr and in report.md; it
    said nothing. The same path in mm gets no note."""
    from itg_vision.trajectory import read_csv, span_note

    lap = load_trajectory("ellipse-t1", 20).points_mm[:, :2]
    for name, scale in (("in-m.csv", 1e-3), ("in-mm.csv", 1.0)):
        f = tmp_path / name
        f.write_text("x_mm,y_mm\n" + "".join(f"{float(x)!r},{float(y)!r}\n" for x, y in scale * lap))
        capsys.readouterr()
        out = tmp_path / f"o-{f.stem}"
        assert main(["--trajectories", str(f), "--controllers", "itg-model", "--conditions",
                     "clean", "--seeds", "1", "--workers", "1", "--quiet", "--out", str(out),
                     *FEW_PLOTS]) == 0
        err, report = capsys.readouterr().err, (out / "report.md").read_text()
        note = span_note(read_csv(f.resolve()), ArmSpec.from_args("two-link").reach_mm()[1])
        if scale < 1:
            assert note and note.startswith("note: trajectory ") and "not metres" in note
            assert note in err.splitlines() and "N" + note[1:] in report.splitlines()
        else:
            assert note is None and "not metres" not in err + report


@pytest.mark.slow
def test_a_users_trajectory_file_is_what_the_runs_track(tmp_path, monkeypatch):
    """A copy of a shipped path gives that path's numbers; a rule base that holds every joint
    on a file of one's own gives the closed-form E_av and E_max of that file's points (the
    distance from the start pose's gripper), so the runs read the file given."""
    monkeypatch.chdir(tmp_path)
    lap = load_trajectory("ellipse-t1", 40).points_mm[:, :2]
    mine = tmp_path / "mine.csv"
    mine.write_text("x_mm,y_mm\n" + "".join(f"{float(x)!r},{float(y)!r}\n"
                                            for x, y in lap + [5.0, -7.0]))
    _write_rules(tmp_path / "still.rules", "RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD\n")
    (tmp_path / "pea.csv").write_text(
        (Path(resolve_rules_path("table2")).parents[1] / "trajectories" / "peanut.csv").read_text())
    assert main(["--conditions", "clean", "--seeds", "1", "--controllers", "still-model,itg-vision",
                 "--rules", "still.rules", "--trajectories", "mine.csv,pea.csv,peanut",
                 "--workers", "1", "--quiet", "--plot-metrics", "e_av"]) == 0
    out = tmp_path / "runs" / "bench-noise-still-mine-pea"  # its own folder
    rows = {(r["controller"], Path(r["trajectory"]).stem): r for r in _rows(out)}
    arm = ArmSpec.from_args("two-link")
    start = forward_kinematics(arm, arm.start_q_deg)["gripper"][:2]
    dist = np.linalg.norm(lap + [5.0, -7.0] - start, axis=1)
    # six digits (%.6g), as above
    for col, expected in (("e_av_mm", dist.mean()), ("e_max_mm", dist.max())):
        assert float(rows["still-model", "mine"][col]) == pytest.approx(
            expected, rel=0, abs=_closed_form_tol(expected, start)), col
    assert rows["still-model", "mine"]["trajectory"] == str(mine.resolve())
    metrics = ("e_av_mm", "e_max_mm", "track_median_mm", "track_max_mm", "laps", "points")
    assert [rows["itg-vision", "pea"][m] for m in metrics] == \
           [rows["itg-vision", "peanut"][m] for m in metrics]
    report = (out / "report.md").read_text()
    assert f"`mine` (two-link, 40 set points per lap, your file {mine.resolve()})" in report
    assert "## mine: E_av (mm)" in report and (out / "e_av_by_condition-mine.png").is_file()


def test_trajectory_files_are_tracked_by_the_arm_named(tmp_path):
    t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    circle = tmp_path / "circle.csv"  # the one-link arm's reach: its 100 mm circle
    circle.write_text("x_mm,y_mm\n" + "".join(
        f"{float(100 * np.cos(a))!r},{float(100 * np.sin(a))!r}\n" for a in t))
    specs = build_sweep(quick=True, trajectories=(str(circle),), arm="one-link")
    assert {s.arm for s in specs} == {"one-link"} and {s.laps for s in specs} == {2}
    assert {s.max_step_deg for s in specs} == {ArmSpec.from_args("one-link").benchmark["max_step_deg"]}
    # the same file on the two-link arm: other runs
    other = build_sweep(quick=True, trajectories=(str(circle),))
    assert not {s.run_id for s in specs} & {s.run_id for s in other}


def _arm_file(path: Path, **changes) -> Path:
    """A copy of the shipped two-link arm file, ``changes`` replacing lines' text."""
    from itg_vision.arm import arm_path

    text = arm_path("two-link").read_text()
    for old, new in changes.values():
        assert old in text
        text = text.replace(old, new)
    path.write_text(text)
    return path


def test_an_arm_file_tracks_your_trajectory_files_under_its_benchmark_limits(tmp_path):
    """--arm FILE (as `run --arm` takes it): an unchanged copy of the two-link arm file gives
    the two-link arm's numbers; a copy with other benchmark limits (5 deg/iteration, 2
    iterations) runs under them, giving the numbers `run --arm FILE` gives under those limits,
    and others than the 20 deg/iteration of the shipped arm (its start transient asks for
    steps of more than 5 deg)."""
    import json

    from itg_vision import run

    lap = load_trajectory("ellipse-t1", 40).points_mm[:, :2]
    mine = tmp_path / "mine.csv"
    mine.write_text("x_mm,y_mm\n" + "".join(f"{float(x)!r},{float(y)!r}\n" for x, y in lap))
    same = _arm_file(tmp_path / "same-arm.yaml")
    slow = _arm_file(tmp_path / "slow-arm.yaml", bench=(
        "benchmark: {max_step_deg: 20, iterations: 1}", "benchmark: {max_step_deg: 5, iterations: 2}"))
    rows = {}
    for arm, ctrls in (("two-link", "itg-vision,itg-model"), (same, "itg-vision,itg-model"),
                       (slow, "itg-model")):
        out = tmp_path / f"o-{Path(arm).stem}"
        assert main(["--trajectories", str(mine), "--arm", str(arm), "--controllers", ctrls,
                     "--conditions", "clean", "--seeds", "1", "--out", str(out), "--workers",
                     "1", "--quiet", *FEW_PLOTS]) == 0
        rows.update({(Path(arm).stem, r["controller"]): r for r in _rows(out)})
    metrics = ("e_av_mm", "e_max_mm", "track_median_mm", "track_max_mm", "n_missed")
    for c in ("itg-vision", "itg-model"):
        assert rows["same-arm", c]["arm"] == str(same.resolve())
        assert [rows["same-arm", c][m] for m in metrics] == [rows["two-link", c][m] for m in metrics]
    row = rows["slow-arm", "itg-model"]
    assert (row["max_step_deg"], row["iterations"]) == ("5", "2")
    assert row["e_av_mm"] != rows["two-link", "itg-model"]["e_av_mm"]
    alone = tmp_path / "run"
    assert run.main(["--arm", str(slow), "--trajectory", str(mine), "--feedback", "model",
                     "--max-step", "5", "--iterations", "2", "--laps", row["laps"], "--out",
                     str(alone), "--quiet"]) == 0
    summary = json.loads((alone / "summary.json").read_text())
    assert [row[m] for m in metrics] == [f"{summary[m]:.6g}" for m in metrics]


def test_a_rule_controllers_title_names_the_rule_base_an_arm_file_gives_it_instead():
    """The report's setup called `itg-vision` "ITG (the paper's rules)" when an arm file's
    defaults.rules named the user's own rule base: every conclusion then read as one against
    the paper's rules. The title now says which rule base ran; the shipped arms' are unchanged."""
    import dataclasses

    from itg_vision.bench.sweep import CONTROLLER_TITLES, controller_title

    specs = {s.controller: s for s in build_sweep(
        quick=True, seeds=1, conditions=("clean",),
        controllers=("itg-vision", "itg-model", "itg-plus-vision", "jacobian-vision"))}
    for name, spec in specs.items():  # the shipped two-link arm's: table2, itg-plus-two-link
        assert controller_title(spec) == CONTROLLER_TITLES[name]
    for name, key in (("itg-vision", "rules"), ("itg-model", "rules"),
                      ("itg-plus-vision", "itg_plus_rules")):
        title = controller_title(dataclasses.replace(specs[name], rules="/home/me/mine.rules"))
        assert title == (f"{CONTROLLER_TITLES[name]}; here the rule base your arm file names "
                         f"instead (defaults.{key}: /home/me/mine.rules)")


def test_an_arm_files_own_rig_file_is_what_its_vision_runs_read(tmp_path):
    """An arm file whose defaults name a rig file beside it: its vision runs hash that file
    (an edit is new vision runs; the model-fed runs keep their ids), and its calibration is
    looked for beside it (the shipped name's cameras/<rig>.yaml was joined to the file's
    path)."""
    from itg_vision.camera import CAMERAS_DIR, default_rig_path

    rig = tmp_path / "myrig.yaml"
    rig.write_text((CAMERAS_DIR / "planar.yaml").read_text())
    arm = _arm_file(tmp_path / "my-arm.yaml", rig=("rig: planar", "rig: myrig.yaml"))
    assert default_rig_path(str(arm)) == rig
    assert default_rig_path(str(arm), calibrated=True) == tmp_path / "myrig.calib.yaml"
    assert default_rig_path("two-link", calibrated=True) == CAMERAS_DIR / "planar.calib.yaml"
    mine = tmp_path / "mine.csv"
    mine.write_text("x_mm,y_mm\n120,40\n100,80\n60,60\n")

    def ids():
        specs = build_sweep(quick=True, trajectories=(str(mine),), arm=str(arm),
                            controllers=("itg-vision", "itg-model"))
        return {fed: {s.run_id for s in specs if s.feedback == fed} for fed in ("vision", "model")}

    before = ids()
    rig.write_text(rig.read_text() + "# edited\n")
    after = ids()
    assert before["model"] == after["model"] and not before["vision"] & after["vision"]


def test_points_for_a_sweep_of_files_only_is_refused_not_ignored(tmp_path, monkeypatch, capsys):
    """--points resamples the named trajectories; a file keeps its own set points. Given with
    files only it was silently ignored (80 set points ran where 20 were asked, as `run
    --points` refuses); with a named trajectory beside them it still applies to that one."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.csv").write_text("x_mm,y_mm\n120,40\n100,80\n60,60\n")
    assert main(["--quick", "--trajectories", "mine.csv,peanut", "--points", "20", "--controllers",
                 "ik", "--conditions", "clean", "--seeds", "1", "--out", "o", "--quiet"]) == 2
    _one_line_error(capsys, "--points: applies to the named trajectories only")
    assert not (tmp_path / "o").exists()
    specs = build_sweep(quick=True, trajectories=("mine.csv", "ellipse-t1"), points=20)
    assert {s.points for s in specs if s.trajectory == "ellipse-t1"} == {20}
    assert {s.points for s in specs if s.trajectory != "ellipse-t1"} == {None}


def test_a_rule_base_for_an_arm_the_sweep_lacks_is_refused_naming_its_arm(tmp_path, monkeypatch,
                                                                          capsys):
    """The quick sweep is two-link only: the three-link composition given to it was refused
    with the file's own error at its line ('L3' ... only 2 link lengths), which reads as a
    fault in the file. It fits the three-link arm: the one line says so, and how to add it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine3.rules").write_text(resolve_rules_path("three-link").read_text())
    assert main(["--quick", "--rules", "mine3.rules", "--out", "o", "--quiet"]) == 2
    _one_line_error(capsys, "--rules mine3.rules: fits the three-link arm, not the sweep's "
                            "(two-link): give --trajectories of its arm")
    assert not (tmp_path / "o").exists()
    (tmp_path / "bad.rules").write_text("RULE 1: IF xg > THEN q1 +S\n")  # fits no arm: its error
    assert main(["--quick", "--rules", "bad.rules", "--out", "o", "--quiet"]) == 2
    _one_line_error(capsys, "--rules bad.rules: bad.rules:1:")


def test_the_divergence_line_is_drawn_on_the_tracking_median_plots_only():
    """A run diverged when its tracking median exceeds DIVERGED_MM: the line saying so belongs
    on the tracking-median axis. On E_av or the max it read as a threshold those metrics do not
    have (a max of 44 mm above it, in a run that tracked)."""
    from types import SimpleNamespace

    from itg_vision.bench.report import _plots, summarize
    from itg_vision.loop import DIVERGED_MM

    def row(k, cond, seed, e, diverged):
        return {"trajectory": "ellipse-t1", "condition": cond, "controller": k, "seed": str(seed),
                "diverged": str(int(diverged)), "no_start": "",
                **{c: str(e) for c in ("e_av_mm", "e_max_mm", "track_median_mm",
                                       "track_mean_mm", "track_p95_mm", "track_max_mm")}}

    conds, ctrls = ["clean", "noise-1px"], ["itg-vision", "ik"]
    rows = [row(k, c, s, 2 * DIVERGED_MM if (k, c) == ("itg-vision", "noise-1px") else 1.0,
                (k, c) == ("itg-vision", "noise-1px")) for k in ctrls for c in conds for s in (0, 1)]
    specs = build_sweep(quick=True, conditions=tuple(conds), controllers=tuple(ctrls))
    drawn = {}
    fake = SimpleNamespace(
        lines_figure=lambda series, xl, yl, title, path, **kw: drawn.__setitem__(path.name, kw),
        grouped_dots_figure=lambda *a, **kw: None)
    _plots(Path("o"), summarize(rows), ["ellipse-t1"], conds, ctrls, fake,
           ("e_av", "track_median", "track_max"), specs)
    assert [h[0] for h in drawn["track_median_vs_sigma-ellipse-t1.png"]["hlines"]] == [DIVERGED_MM]
    assert not drawn["e_av_vs_sigma-ellipse-t1.png"]["hlines"]
    assert not drawn["track_max_vs_sigma-ellipse-t1.png"]["hlines"]


def test_a_condition_without_a_finished_run_draws_no_one_point_curve_and_says_so():
    """links+5% with no finished run (none started): its curve against the model error would
    be the clean run's point alone on a made-up axis, and its column in the dot chart was
    blank, unlabelled. No curve is drawn; the dot chart writes 'no run finished' there."""
    from types import SimpleNamespace

    from itg_vision.bench.report import _plots, summarize

    conds, ctrls = ["clean", "noise-1px", "links+5%"], ["itg-vision", "ik"]
    rows = [{"trajectory": "ellipse-t1", "condition": c, "controller": k, "seed": "0",
             "diverged": "0", "no_start": "",
             **{m: "1.0" for m in ("e_av_mm", "e_max_mm", "track_median_mm", "track_mean_mm",
                                   "track_p95_mm", "track_max_mm")}}
            for k in ctrls for c in conds[:2]]
    specs = build_sweep(quick=True, conditions=tuple(conds), controllers=tuple(ctrls))
    lines, dots = {}, {}
    fake = SimpleNamespace(
        lines_figure=lambda series, xl, yl, title, path, **kw: lines.__setitem__(path.name, series),
        grouped_dots_figure=lambda cats, values, yl, title, path, **kw: dots.__setitem__(
            path.name, (cats, values, kw)))
    _plots(Path("o"), summarize(rows), ["ellipse-t1"], conds, ctrls, fake, ("e_av",), specs)
    assert "e_av_vs_sigma-ellipse-t1.png" in lines  # clean and 1 px: a curve of two points
    assert "e_av_vs_model_error-ellipse-t1.png" not in lines
    cats, values, kw = dots["e_av_by_condition-ellipse-t1.png"]
    assert cats == conds and all(np.isnan(values[k][2]) for k in ctrls)
    assert kw["empty_label"] == "no run finished"


def test_a_report_of_files_with_spaces_links_its_plots_and_quotes_its_command(tmp_path):
    """A path of one's own named with a space: report.md's plot links are URLs (a space ends
    a Markdown link's destination, so the image did not show) and its command line reruns the
    sweep as it ran (it read as two words)."""
    import shlex

    path = tmp_path / "my dir" / "my path.csv"
    path.parent.mkdir()
    path.write_text("x_mm,y_mm\n120,40\n100,80\n60,60\n")
    out = tmp_path / "o"
    args = ["--quick", "--trajectories", str(path), "--controllers", "ik", "--conditions",
            "clean", "--seeds", "1", "--out", str(out), "--workers", "1"]
    assert main([*args, "--quiet"]) == 0
    report = (out / "report.md").read_text()
    assert (out / "e_av_by_condition-my path.png").exists()
    assert "![e_av_by_condition-my path](e_av_by_condition-my%20path.png)" in report
    command = next(line for line in report.splitlines() if line.startswith("Produced by `"))
    assert shlex.split(command[len("Produced by `"):-len("`.")])[4:] == args


def test_a_model_error_that_puts_every_set_point_out_of_reach_is_a_row_that_did_not_start(
        tmp_path, capsys):
    """The one-link arm reaches only its circle: with links 5 % long (105 mm) no set point of a
    path on the nominal 100 mm circle is in reach, whatever the controller or seed. That is an
    outcome of the condition (as a rig whose rays miss is): a row saying why, exit 0, the
    cell saying none started; not a failure retried (and its traceback printed) at every
    resume."""
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    circle = tmp_path / "circle.csv"
    circle.write_text("x_mm,y_mm\n" + "".join(
        f"{float(100 * np.cos(a))!r},{float(100 * np.sin(a))!r}\n" for a in t))
    out = tmp_path / "o"
    assert main(["--quick", "--arm", "one-link", "--trajectories", str(circle), "--controllers",
                 "itg-model,ik", "--conditions", "clean,links+5%", "--seeds", "1", "--out",
                 str(out), "--workers", "1", "--quiet"]) == 0
    assert "Traceback" not in capsys.readouterr().err and not (out / "failures.log").exists()
    rows = {(r["controller"], r["condition"]): r for r in _rows(out)}
    for c in ("itg-model", "ik"):
        assert rows[c, "clean"]["no_start"] == "" and math.isfinite(float(rows[c, "clean"]["e_av_mm"]))
        assert "is in reach of arm one-link (105 to 105 mm" in rows[c, "links+5%"]["no_start"]
        assert rows[c, "links+5%"]["e_av_mm"] == ""
    assert float(rows["ik", "clean"]["track_max_mm"]) < 1e-3  # the clean runs do track
    assert "none of 1 started" in (out / "report.md").read_text()


@pytest.mark.parametrize("arm, folder", [("one-link", "bench-noise-quick-circle-one-link"),
                                         ("two-link", "bench-noise-quick-circle")])
def test_the_default_out_of_a_path_names_its_arm_unless_the_default(tmp_path, monkeypatch,
                                                                    arm, folder):
    """The same path file tracked by another arm is another sweep: its default folder names the
    arm, so it does not collide with the two-link sweep of that file (the default arm, named or
    not, keeps the folder a sweep without --arm makes)."""
    monkeypatch.chdir(tmp_path)
    t = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    (tmp_path / "circle.csv").write_text("x_mm,y_mm\n" + "".join(
        f"{float(100 * np.cos(a))!r},{float(100 * np.sin(a))!r}\n" for a in t))
    assert main(["--quick", "--arm", arm, "--trajectories", "circle.csv", "--controllers", "ik",
                 "--conditions", "clean", "--seeds", "1", "--workers", "1", "--quiet"]) == 0
    assert [p.name for p in (tmp_path / "runs").iterdir()] == [folder]
    assert {r["arm"] for r in _rows(tmp_path / "runs" / folder)} == {arm}


def test_each_sweep_has_a_default_folder_of_its_own(tmp_path, monkeypatch):
    """Without --out every sweep, quick or not, writes to a folder named for it, none of them
    bench itg-plus's (runs/bench-itg-plus, which holds that command's two sweeps): a noise
    sweep there was refused as another command's output."""
    monkeypatch.chdir(tmp_path)
    made = []
    for sweep in ("robustness", "start-tie", "itg-plus"):
        for quick in ([], ["--quick"]):
            assert main([*quick, "--sweep", sweep, "--limit", "0", "--quiet", *FEW_PLOTS]) == 0
            made.append("bench-noise" + "-quick" * bool(quick)
                        + ("" if sweep == "robustness" else f"-{sweep}"))
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == sorted(made)
    assert "bench-itg-plus" not in made and len(set(made)) == 6


def test_an_arm_file_named_like_a_shipped_arm_gets_a_folder_of_its_own(tmp_path, monkeypatch):
    """An arm file is another arm whatever its name: a copy of two-link.yaml with longer links,
    kept elsewhere under the same name, does not write into the default arm's folder."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine").mkdir()
    _arm_file(tmp_path / "mine" / "two-link.yaml",
              links=("links_mm: [100, 100]", "links_mm: [110, 110]"))
    (tmp_path / "circle.csv").write_text("x_mm,y_mm\n120,0\n0,120\n-120,0\n0,-120\n")
    for arm in ("two-link", "mine/two-link.yaml"):
        assert main(["--quick", "--arm", arm, "--trajectories", "circle.csv", "--controllers",
                     "ik", "--conditions", "clean", "--seeds", "1", "--workers", "1",
                     "--quiet", *FEW_PLOTS]) == 0
    runs = tmp_path / "runs"
    assert sorted(p.name for p in runs.iterdir()) == [
        "bench-noise-quick-circle", "bench-noise-quick-circle-two-link"]
    assert {r["arm"] for r in _rows(runs / "bench-noise-quick-circle-two-link")} == {
        str((tmp_path / "mine" / "two-link.yaml").resolve())}


@pytest.mark.parametrize("option, text, given, what", [
    ("--rules", "RULE 1: IF xg > THEN q1 +S\n", "bad.rules", "--rules bad.rules: bad.rules:1:"),
    ("--rules", "RULE 1: IF 1 > 0 THEN q1 HOLD\n", "one.rules",
     "--rules one.rules: fits the one-link arm, not the sweep's (two-link, three-link): give "
     "--trajectories of its arm, or files of your own with --arm one-link"),
    ("--rules", None, "missing.rules", "--rules missing.rules: missing.rules: rule file not found"),
    ("--rules", "RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD\n", "itg.rules",
     "--rules itg.rules: its controllers would be called itg-vision and itg-model"),
    ("--trajectories", None, "gone.csv", "--trajectories gone.csv: gone.csv: trajectory file not found"),
    ("--trajectories", "x_mm,y_mm\n1,a\n2,3\n", "bad.csv",
     "--trajectories bad.csv: bad.csv:2: field y_mm"),
    ("--trajectories", "x_mm,y_mm\n1000,0\n1001,0\n", "far.csv",
     "--trajectories far.csv: none of its 2 set points is in reach of the two-link arm"),
    ("--trajectories", "x_mm,y_mm\n100,0\n110,0\n", "abcd.csv",
     "--trajectories abcd.csv: the report and plots would call it 'abcd', a name already taken"),
    ("--arm", None, "gone.yaml", "--arm gone.yaml: gone.yaml: cannot read arm file"),
    ("--arm", "name: x\n", "bad.yaml", "--arm bad.yaml: bad.yaml: kind: missing"),
    ("--arm", None, "nosuch", "--arm nosuch: unknown arm 'nosuch'"),
])
def test_a_file_of_yours_the_sweep_cannot_run_exits_2_with_one_line_and_writes_nothing(
        tmp_path, monkeypatch, capsys, option, text, given, what):
    monkeypatch.chdir(tmp_path)
    if text is not None:
        (tmp_path / given).write_text(text)
    assert main([option, given, "--out", "o", "--quiet"]) == 2
    _one_line_error(capsys, what)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, what", [
    (["--arm", "one-link"], "--arm one-link: applies to trajectory files given to "
                            "--trajectories, and none is given"),
    (["--rules", "{mine}", "--controllers", "itg-vision"],
     "--controllers: names none of your rule bases' controllers (mine-vision, mine-model), "
     "so --rules would run nowhere"),
    (["--rules", "{mine}", "--gain", "0.3", "--controllers", "ik,jacobian-vision"],
     "--controllers: names none of your rule bases' controllers"),
])
def test_an_option_that_would_apply_to_no_run_is_refused(tmp_path, monkeypatch, capsys, args,
                                                         what):
    """--arm without a trajectory file, and --rules (with its parameters) whose controllers
    --controllers leaves out, would change nothing: refused in one line, before any run."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.rules").write_text(resolve_rules_path("table2").read_text())
    argv = [a.replace("{mine}", "mine.rules") for a in args]
    for extra in (["--list"], ["--out", "o", "--quiet"]):
        assert main(["--quick", *argv, *extra]) == 2
        _one_line_error(capsys, what)
    assert not (tmp_path / "o").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes")
@pytest.mark.parametrize("option", ["--arm", "--rules"])
def test_a_pipe_given_as_an_input_is_refused_before_it_is_read(tmp_path, monkeypatch, capsys,
                                                               option):
    """Each run of a sweep reads its input files afresh, in a worker process, and a pipe
    (``--arm <(...)``) cannot be read again: the sweep ended with "/proc/N/fd/pipe:[M]: cannot
    read arm file" (a path no user gave). Refused in one line naming the option, before
    anything reads it (a named FIFO here, which reading would block on)."""
    monkeypatch.chdir(tmp_path)
    os.mkfifo(tmp_path / "piped")
    (tmp_path / "path.csv").write_text("x_mm,y_mm\n120,40\n125,45\n130,50\n")
    argv = {"--arm": ["--trajectories", "path.csv", "--arm", "piped"],
            "--rules": ["--rules", "piped"]}[option]
    assert main(["--quick", *argv, "--out", "o", "--quiet"]) == 2
    _one_line_error(capsys, f"{option} piped: a pipe, which the sweep cannot read again")
    assert not (tmp_path / "o").exists()


def test_ctrl_c_between_a_rows_write_and_its_record_counts_the_rows_on_disk(tmp_path, capsys,
                                                                            monkeypatch):
    """Ctrl-C landing after a row is fsynced but before the store records it in memory: the
    message counts what a resume will find on disk (it said one fewer: a flaky test)."""
    from itg_vision.bench.store import Results

    real = Results.append
    calls = []

    def append_then_interrupt(self, row):
        calls.append(row["run_id"])
        if len(calls) < 3:
            return real(self, row)
        real(self, row)
        del self.rows[row["run_id"]]  # as if interrupted before the line recording it
        raise KeyboardInterrupt

    monkeypatch.setattr(Results, "append", append_then_interrupt)
    out = tmp_path / "o"
    code = main(["--quick", "--controllers", "itg-model,ik", "--seeds", "1", "--out", str(out),
                 "--workers", "1", "--quiet"])
    assert code == 130
    on_disk = len(Results(out / "results.csv").rows)
    assert on_disk == 3
    assert f"{on_disk} of 12 runs are in {out / 'results.csv'}" in capsys.readouterr().err


# --------------------------------- what each run of a sweep is given; a worker that died
def test_rows_of_another_sweep_without_sweep_json_are_refused_and_kept(tmp_path):
    """A sweep folder that lost its sweep.json still refuses a different sweep while it holds
    rows of another, and nothing in it changes (the report would mix the two)."""
    from itg_vision.bench import noise
    from itg_vision.bench.store import Results, make_row
    from itg_vision.bench.sweep import build_sweep

    specs = build_sweep(quick=True, seeds=1, controllers=("ik",))
    other = [s for s in build_sweep(quick=True, seeds=2, controllers=("ik",)) if s.seed == 1][0]
    Results(tmp_path / "results.csv").append(make_row(other, None, no_start="x"))
    outputs.write_json(tmp_path / outputs.MANIFEST, outputs.manifest(noise.COMMAND))
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    with pytest.raises(UserError, match=r"holds 1 results of a different sweep definition "
                                        r"\(no sweep.json\)"):
        noise.run_sweep(specs, tmp_path, {}, "cmd", workers=1, limit=0, quiet=True)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_a_dropout_condition_reaches_its_vision_runs():
    """A condition's dropout reaches its vision runs (and only those: model feedback has no
    LEDs to lose)."""
    from itg_vision.bench.sweep import build_sweep, run_config

    specs = build_sweep(quick=True, seeds=1, conditions=("dropout-0.2", "noise-0.3px+dropout-0.05"))
    want = {"dropout-0.2": 0.2, "noise-0.3px+dropout-0.05": 0.05}
    assert {s.feedback for s in specs} == {"vision", "model"}
    for s in specs:
        assert run_config(s).dropout == (want[s.condition] if s.feedback == "vision" else 0.0)


def test_the_sweeps_controllers_with_memory_run_with_correction_one_half():
    """The itg-plus sweep's controllers with memory (-ff) run at correction 0.5, the others at 1."""
    from itg_vision.bench.sweep import build_sweep, run_config

    specs = build_sweep(sweep="itg-plus", seeds=1, conditions=("clean",),
                        trajectories=("ellipse-t1",))
    got = {s.controller: run_config(s).correction for s in specs}
    assert got["itg-plus-vision-ff"] == got["jacobian-vision-ff"] == 0.5
    assert got["itg-plus-vision"] == got["jacobian-vision"] == got["itg-vision"] == 1.0


def test_each_seed_of_rig_perturbed_believes_the_rig_of_its_own_seed(monkeypatch):
    """Each seed of rig-perturbed believes the rig perturbed with its own seed, so the spread
    over seeds is over rigs, not one draw."""
    from itg_vision import runner
    from itg_vision.bench.execute import run_one
    from itg_vision.bench.sweep import RIG_ANGLE_DEG, RIG_SHIFT_MM, build_sweep
    from itg_vision.camera import Rig, default_rig_path, perturbed

    believed = {}

    def prepare(cfg, estimate_rig=None, **kw):
        believed[cfg.seed] = estimate_rig
        raise RuntimeError("stop before the run")

    monkeypatch.setattr(runner, "prepare", prepare)
    specs = [s for s in build_sweep(quick=True, seeds=2, conditions=("rig-perturbed",),
                                    controllers=("itg-vision",))]
    assert sorted(s.seed for s in specs) == [0, 1]
    for s in specs:
        assert "stop before the run" in run_one(s)["error"]
    true_path = default_rig_path(specs[0].arm)
    for seed in (0, 1):
        want = perturbed(Rig.from_yaml(true_path), seed, angle_deg=RIG_ANGLE_DEG,
                         shift_mm=RIG_SHIFT_MM, true_rig=true_path)
        assert believed[seed].cameras == want.cameras
    assert believed[0].cameras != believed[1].cameras


def test_a_run_whose_worker_died_is_an_error_row_not_an_exception():
    """A worker that died (killed, out of memory) gives each of its runs an error row naming
    the cause, not a traceback that ends the sweep."""
    from itg_vision.bench.execute import results
    from itg_vision.bench.sweep import build_sweep

    class DeadPool(Executor):
        def submit(self, fn, /, *args, **kwargs):
            fut = Future()
            fut.set_exception(BrokenProcessPool("A process in the process pool was terminated"))
            return fut

    specs = build_sweep(quick=True, seeds=1, controllers=("ik",))[:3]
    rows = list(results(DeadPool(), specs, 2))
    assert [s.run_id for s, _ in rows] == [s.run_id for s in specs]
    for spec, row in rows:
        assert row == {"run_id": spec.run_id, "error": "BrokenProcessPool: A process in the "
                                                       "process pool was terminated"}


def test_a_lost_runs_error_of_several_lines_is_one_line_of_failures_log(tmp_path, capsys,
                                                                         monkeypatch):
    """An executor's error of several lines (Dask's for a worker without itg_vision: "Error
    during deserialization of the task graph. This frequently\noccurs if the Scheduler and
    Client have different environments.\n...") is one line per failed run in failures.log
    (run id, tab, why) and in the report, its words kept; it took four lines of each."""
    why = ("Error during deserialization of the task graph. This frequently\noccurs if the "
           "Scheduler and Client have different environments.\nFor more information, see\n"
           "https://docs.dask.org/en/stable/deployment-considerations.html\n")

    class WrongEnvironment(Executor):
        def submit(self, fn, /, *args, **kwargs):
            fut = Future()
            fut.set_exception(RuntimeError(why))
            return fut

    monkeypatch.setattr(noise, "local_executor", lambda workers: WrongEnvironment())
    out = tmp_path / "o"
    assert main(["--quick", "--controllers", "ik", "--conditions", "clean", "--seeds", "2",
                 "--points", "8", "--out", str(out), "--workers", "1", "--quiet", *FEW_PLOTS]) == 1
    logged = (out / "failures.log").read_text().splitlines()
    assert len(logged) == 2
    for line in logged:
        run_id, said = line.split("\t")
        assert said.endswith("RuntimeError: Error during deserialization of the task graph. This "
                             "frequently occurs if the Scheduler and Client have different "
                             "environments. For more information, see "
                             "https://docs.dask.org/en/stable/deployment-considerations.html")
    failed = [ln for ln in (out / "report.md").read_text().splitlines() if "runs failed" in ln]
    assert len(failed) == 1 and failed[0].count("different environments") == 2
    assert capsys.readouterr().err.count("run failed: ik clean") == 2


def test_the_reports_failed_runs_line_says_it_shows_the_first_three(tmp_path, monkeypatch):
    """Five runs fail (an executor that cannot run them): the report's line names three and
    said neither that they were the first 3 of 5 nor where the rest are; and it said 'rerun to
    retry', wrong where your input stopped them (the command's last line tells the two
    apart). Now it says 'the first 3 of them' and points to failures.log, which lists all 5."""
    class Broken(Executor):
        def submit(self, fn, /, *args, **kwargs):
            fut = Future()
            fut.set_exception(RuntimeError("no worker"))
            return fut

    monkeypatch.setattr(noise, "local_executor", lambda workers: Broken())
    out = tmp_path / "o"
    assert main(["--quick", "--controllers", "ik", "--conditions", "clean", "--seeds", "5",
                 "--points", "8", "--out", str(out), "--workers", "1", "--quiet", *FEW_PLOTS]) == 1
    assert len((out / "failures.log").read_text().splitlines()) == 5
    [line] = [ln for ln in (out / "report.md").read_text().splitlines() if "runs failed" in ln]
    assert line.startswith("**5 runs failed** this time (the first 3 of them; `failures.log` "
                           "lists every one and why")
    assert line.count("RuntimeError: no worker") == 3 and "rerun to retry" not in line


def test_a_dot_chart_says_why_a_controllers_cell_is_left_out(monkeypatch):
    """`--conditions ...,rig-perturbed-cams --quick`: one seed of each vision controller did not
    start there, so its cell is left out of the plots (its median is not over every seed); the
    dot chart drew nothing in its place and said nothing, beside the model controllers' dots.
    It now writes why, where the dot would be."""
    import matplotlib.pyplot as plt

    from itg_vision import plot
    from itg_vision.bench.report import _plots, summarize

    conds, ctrls = ["clean", "rig-perturbed-cams"], ["itg-vision", "itg-model"]
    rows = [{"trajectory": "ellipse-t1", "condition": c, "controller": k, "seed": str(s),
             "diverged": "0",
             "no_start": "start-up measurement" if (k, c, s) == (ctrls[0], conds[1], 1) else "",
             **{m: "1.0" for m in ("e_av_mm", "e_max_mm", "track_median_mm", "track_mean_mm",
                                   "track_p95_mm", "track_max_mm")}}
            for k in ctrls for c in conds for s in (0, 1)]
    specs = build_sweep(quick=True, conditions=tuple(conds), controllers=tuple(ctrls))
    made = []
    monkeypatch.setattr(plot, "_save", lambda fig, path: made.append(fig))
    _plots(Path("o"), summarize(rows), ["ellipse-t1"], conds, ctrls, plot, ("e_av",), specs)
    try:
        ax = made[-1].axes[0]  # the dot chart, drawn last
        dots = {ln.get_label(): ln.get_ydata() for ln in ax.lines if ln.get_label() in ctrls}
        assert np.isnan(dots["itg-vision"][1]) and dots["itg-model"][1] == 1.0
        assert [t.get_text() for t in ax.texts].count("left out: 1 of 2 did not start") == 1
    finally:
        for fig in made:
            plt.close(fig)
