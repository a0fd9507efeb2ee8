"""The noise benchmark's report: summaries over seeds, tables, a conclusion computed from the
numbers, ``report.md`` and the plots (drawn by :mod:`itg_vision.plot`)."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from pathlib import Path
from urllib.parse import quote

import numpy as np

from .. import outputs
from ..inputs import count
from ..loop import DIVERGED_MM
from .store import params_cell, started
from ..trajectory import names_a_csv_file
from .sweep import (CONDITIONS, CONTROLLER_TITLES, Condition, RunSpec, _default_points,
                    controller_title, span_notes, trajectory_label)

def _float(v: str) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _stats(values) -> tuple[float, float, float]:
    v = np.asarray([x for x in values if math.isfinite(x)], float)
    if not v.size:
        return (float("nan"),) * 3
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return float(med), float(q1), float(q3)


def _fmt_mm(v: float) -> str:
    if not math.isfinite(v):
        return "n/a"
    if v == 0:
        return "0"
    # three significant digits below 0.01 mm too: one ("7e-03", "8e-03") hid the spread of a
    # one-link arm's clean medians, 0.0072-0.0084 mm
    return f"{v:.3g}" if abs(v) < 100 else f"{v:.0f}"


def _signed(d: float) -> str:
    """A change to two decimals with its sign; one that rounds to zero is +0.00, never -0.00."""
    return outputs.unsigned_zero(f"{d:+.2f}", "+")


def _ratio(a: float, b: float) -> str:
    """How many times ``a`` is ``b`` (both errors in mm), for prose."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return "n/a"
    if b < 1e-3:
        return "> 1000x" if a >= 1.0 else f"{a / max(b, 1e-9):.3g}x"
    r = a / b
    return f"{r:.2g}x" if abs(r) < 100 else f"{r:.0f}x"  # 360x, not 3.6e+02x


#: Per-run statistics summarised over seeds: (column, short label).
STATS = (("e_av_mm", "E_av"), ("e_max_mm", "E_max"), ("track_median_mm", "median"),
         ("track_mean_mm", "mean"), ("track_p95_mm", "p95"), ("track_max_mm", "max"))
#: What the plots can show (``--plot-metrics``).
PLOT_METRICS = {"e_av": "E_av", "track_median": "tracking median E_i",
                "track_mean": "tracking mean E_i", "track_p95": "tracking p95 E_i",
                "track_max": "tracking max E_i"}
#: What the plots show unless told otherwise.
DEFAULT_PLOT_METRICS = ("e_av", "track_median", "track_max")


def summarize(rows: list[dict], expected: dict | None = None) -> dict:
    """(trajectory, condition, controller) -> per-run statistics over seeds.

    ``s["track_max"] = (median, q1, q3)`` over seeds of each run's statistic (keys: the
    ``STATS`` columns without ``_mm``), ``worst_max`` the largest tracking-phase E_i of any
    seed, ``diverged`` and ``n`` the number of diverged runs and of runs that started,
    ``no_start`` the number that did not start (``why``: their reasons), ``missing`` the number
    of runs ``expected`` (a cell's count of runs in the sweep) has that have no row (failed, or
    not run yet). The statistics are over the runs that started.
    """
    groups: dict[tuple, list[dict]] = {key: [] for key in expected or {}}  # a cell without rows
    for r in rows:
        groups.setdefault((trajectory_label(r["trajectory"]), r["condition"], r["controller"]),
                          []).append(r)
    out = {}
    for key, rs in groups.items():
        ran = started(rs)
        s = {col.removesuffix("_mm"): _stats(_float(r[col]) for r in ran) for col, _ in STATS}
        s.update({"worst_max": worst(ran), "diverged": sum(r["diverged"] == "1" for r in ran),
                  "n": len(ran), "no_start": len(rs) - len(ran),
                  "missing": max(0, (expected or {}).get(key, 0) - len(rs)),
                  "why": sorted({r["no_start"] for r in rs if r["no_start"]})})
        out[key] = s
    return out


def _no_start_note(s) -> str:
    """`` (3 of 5 did not start)`` for a cell whose runs did not all start, `` (1 of 5 have no
    result)`` for one whose runs have not all a row, else ``""``."""
    total = s["n"] + s["no_start"] + s["missing"]
    parts = ([f"{s['no_start']} of {total} did not start"] if s["no_start"] else []) \
        + ([f"{s['missing']} of {total} have no result"] if s["missing"] else [])
    return f" ({'; '.join(parts)})" if parts else ""


def complete(s) -> bool:
    """Every run of the cell started and has its row: its medians are over every seed, so it
    may be compared with another cell."""
    return not s["no_start"] and not s["missing"]


def _no_start_cell(s) -> str:
    """A cell none of whose runs started or has a row (every run failed, or none ran yet)."""
    if s["missing"]:
        return "no result" + _no_start_note(s)
    return f"none of {s['no_start']} started"


def worst(rows: list[dict], col: str = "track_max_mm") -> float:
    """The largest finite ``col`` of the rows (NaN when none is)."""
    return max((w for w in (_float(r[col]) for r in rows) if math.isfinite(w)), default=float("nan"))


def _limits_line(specs: list[RunSpec], traj: str) -> str:
    s = next(s for s in specs if trajectory_label(s.trajectory) == traj)
    phase = (f"{s.laps} laps, tracking phase = laps 2..{s.laps}" if s.laps > 1
             else "tracking phase = second half of the set points")
    limit = ("no servo limit" if s.max_step_deg is None
             else f"servo limit {s.max_step_deg:g} deg/iteration")
    return (f"Every controller: {limit} (each joint), {s.iterations} iteration(s) per set point, "
            f"{phase}.")


def _grid(summary, traj, conds, ctrls, cell) -> list[str]:
    """A markdown table, a row per condition and a column per controller: ``cell(s)``."""
    lines = ["| condition | " + " | ".join(ctrls) + " |", "|---|" + "---|" * len(ctrls)]
    for c in conds:
        cells = [cell(summary[(traj, c, k)]) if (traj, c, k) in summary else "-" for k in ctrls]
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    return lines


def _table(summary, traj, conds, ctrls, metric) -> list[str]:
    """Median [first quartile, third quartile] over seeds of one per-run statistic."""
    def cell(s):
        if not s["n"]:
            return _no_start_cell(s)
        med, q1, q3 = s[metric]
        return f"{_fmt_mm(med)} [{_fmt_mm(q1)}, {_fmt_mm(q3)}]" + _no_start_note(s)

    return _grid(summary, traj, conds, ctrls, cell)


def _tail_table(summary, traj, conds, ctrls) -> list[str]:
    """Tracking phase per cell: median / mean / p95 / max of E_i (medians over seeds), the
    worst max of any seed, and the diverged runs."""
    def cell(s):
        if not s["n"]:
            return _no_start_cell(s)
        text = " / ".join(_fmt_mm(s[m][0]) for m in ("track_median", "track_mean", "track_p95",
                                                     "track_max"))
        text += f" ({_fmt_mm(s['worst_max'])})"
        text += _no_start_note(s)
        return text + (f" **{s['diverged']}/{s['n']} diverged**" if s["diverged"] else "")

    return _grid(summary, traj, conds, ctrls, cell)


def _compare(med, trajs, conds, a_ctrl, b_ctrl):
    wins, losses, ties = [], [], []
    for t in trajs:
        for c in conds:
            a, b = med.get((t, c, a_ctrl)), med.get((t, c, b_ctrl))
            if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)):
                continue
            item = (t, c, a, b)
            if abs(a - b) <= 0.05 * max(a, b) + 0.01:
                ties.append(item)
            elif a < b:
                wins.append(item)
            else:
                losses.append(item)
    return wins, losses, ties


def conclusion(summary, trajs, conds, ctrls, subject: str = "itg-vision") -> list[str]:
    """Plain-words findings computed from the medians over seeds (thresholds stated inline).
    A cell where a run did not start or has no row is left out (its median is over fewer seeds
    than the others'); :func:`no_start_lines` names it."""
    out = []
    if subject not in ctrls:
        return [f"({subject} not in this sweep: no comparison.)"]
    for metric, label in (("e_av", "E_av (the paper's metric, start transient included)"),
                          ("track_mean", "tracking-phase mean E_i"),
                          ("track_max", "tracking-phase max E_i (the tail)")):
        med = {k: v[metric][0] for k, v in summary.items() if complete(v)}
        parts = []
        for other in [c for c in ctrls if c != subject]:
            wins, losses, ties = _compare(med, trajs, conds, subject, other)
            n = len(wins) + len(losses) + len(ties)
            if not n:
                continue
            text = (f"vs `{other}`: lower in {len(wins)} of {n} cells, higher in "
                    f"{len(losses)}, within 5 % of the larger + 0.01 mm in {len(ties)}")
            if losses:
                t, c, a, b = max(losses, key=lambda w: w[2] / max(w[3], 1e-9))
                text += (f" (largest loss: {c} on {t}, {_fmt_mm(a)} against {_fmt_mm(b)} mm, "
                         f"{_ratio(a, b)})")
            parts.append(text)
        if parts:
            out.append(f"- **{label}**, median over seeds, `{subject}`: " + "; ".join(parts) + ".")
    if "clean" in conds:
        model_conds = [c for c in conds if not CONDITIONS[c].vision_only]
        for t in trajs:
            parts = []
            for k in ctrls:
                base = summary.get((t, "clean", k))
                if base is None or not complete(base) or not math.isfinite(base["track_median"][0]):
                    continue
                deltas = [f"{c} {_signed(summary[(t, c, k)]['track_median'][0] - base['track_median'][0])}"
                          for c in model_conds if (t, c, k) in summary
                          and complete(summary[(t, c, k)])
                          and math.isfinite(summary[(t, c, k)]["track_median"][0])]
                if deltas:
                    parts.append(f"{k}: " + ", ".join(deltas))
            if parts:
                out.append(f"- **Model error on {t}**, alone and with noise or a moved rig "
                           "(change of the median tracking E_i from clean, mm; a combined "
                           "condition's change holds its other error's too): "
                           + "; ".join(parts) + ".")
    div = [(key, s) for key, s in summary.items() if s["diverged"]]
    if div:
        out.append(f"- **Diverged runs** (tracking-phase median E_i > {DIVERGED_MM:g} mm): "
                   + "; ".join(f"{k} {c} on {t}: {s['diverged']} of {s['n']}"
                               for (t, c, k), s in sorted(div)) + ".")
    elif summary:
        out.append(f"- No run diverged (tracking-phase median E_i > {DIVERGED_MM:g} mm).")
    return out


def no_start_lines(summary) -> list[str]:
    """The cells where runs did not start, and why (each reason once); [] when every run did."""
    gone = sorted((key, s) for key, s in summary.items() if s["no_start"])
    if not gone:
        return []
    cells = "; ".join(f"{k} {c} on {t}: {s['no_start']} of {s['n'] + s['no_start']}"
                      for (t, c, k), s in gone)
    why = sorted({w for _, s in gone for w in s["why"]})
    return [f"Runs that did not start (left out of the conclusions' comparisons and of the "
            f"plots): {cells}. Why: " + " / ".join(why), ""]


def missing_lines(summary) -> list[str]:
    """The cells with runs that have no row (failed, or not run yet); [] when none has."""
    cells = "; ".join(f"{k} {c} on {t}: {s['missing']} of {s['n'] + s['no_start'] + s['missing']}"
                      for (t, c, k), s in sorted(summary.items()) if s["missing"])
    return [f"Runs without a result (failed, or not run yet: the same command runs them; their "
            f"cells are over the other seeds, left out of the conclusions' comparisons and of "
            f"the plots): {cells}.", ""] if cells else []


def write_report(out: Path, rows: list[dict], specs: list[RunSpec], command: str,
                 failures: dict[str, str], plot_metrics=DEFAULT_PLOT_METRICS,
                 keep=lambda path: None) -> list[Path]:
    """report.md and the plots from the rows of this sweep; returns the plot paths. ``keep``
    is called with each path before it is written (to keep a file of the user's aside)."""
    from .. import plot

    ids = {s.run_id for s in specs}
    rows = [r for r in rows if r["run_id"] in ids]
    trajs = list(dict.fromkeys(trajectory_label(s.trajectory) for s in specs))
    conds = list(dict.fromkeys(s.condition for s in specs))
    ctrls = list(dict.fromkeys(s.controller for s in specs))
    summary = summarize(rows, Counter((trajectory_label(s.trajectory), s.condition, s.controller)
                                      for s in specs))
    seeds = sorted({s.seed for s in specs})
    ran = started(rows)
    pts = {t: sorted({int(_float(r["points"])) for r in ran if trajectory_label(r["trajectory"]) == t})
           for t in trajs}
    wall = sum(_float(r["wall_s"]) for r in ran)
    n_gone = len(rows) - len(ran)
    L = ["# Noise-robustness benchmark", "",
         f"Produced by `{command}`.", "",
         f"{len(rows)} of {len(specs)} runs in `results.csv`"
         + (f", {n_gone} of which did not start (listed below)" if n_gone else "")
         + (" (partial sweep: rerun the command to finish it)" if len(rows) < len(specs) else "")
         + f"; {count(seeds, 'seed')} per cell; wall-clock time of the runs, summed {wall:.0f} s "
         "(with several workers the sweep took less).", ""]
    codes = Counter(r["code"] for r in rows)
    if codes:
        L += ["Code that computed the rows (`code` in results.csv, a hash of the package's "
              "source): " + ", ".join(f"`{c}` ({n} rows)" for c, n in codes.most_common())
              + ("." if len(codes) == 1 else
                 ": more than one, so the rows may not be comparable; rerun into a new --out "
                 "for rows of one code."), ""]
    L += no_start_lines(summary) + missing_lines(summary)
    if failures:
        shown = min(3, len(failures))
        L += [f"**{len(failures)} runs failed** this time ("
              + (f"the first {shown} of them" if shown < len(failures) else "each")
              + "; `failures.log` lists every one and why, and the command's last line says "
              "whether rerunning it retries them or your input must be fixed first): "
              + "; ".join(f"{k}: {v}" for k, v in list(failures.items())[:shown]), ""]
    L += ["## Setup", "",
          "Controllers, on the same runs (same trajectory, condition, seed, servo limit):", ""]
    first = {}
    for s in specs:
        first.setdefault(s.controller, s)
    L += [f"- `{k}`: {controller_title(s)} (RunConfig controller={s.rc_controller}, "
          f"feedback={s.feedback}" + (f", rules {s.rules}" if s.rules else "")
          + (f", {params_cell(s.rule_params)}" if s.rule_params else "") + ")"
          + _arms_note(specs, s) for k, s in first.items()]
    L += ["", "Trajectories: " + ", ".join(
        f"`{t}` ({spec_limits(specs, t)['arm']}, {'/'.join(map(str, pts[t])) or '?'} set points "
        f"per lap{_file_note(specs, t)})" for t in trajs) + ".", ""]
    rigs = _rigs_line(specs)
    L += [rigs, ""] if rigs else []
    L += [f"- `{t}`: {_limits_line(specs, t)}" for t in trajs]
    notes = span_notes(specs)  # a file likely written in metres
    if notes:
        L += [""] + ["N" + n[1:] for n in notes]
    L += ["", "Under vision (or truth) feedback the rules' link lengths and the Jacobian "
          "tracker's shoulder and LED stand-off are measured from the LEDs at start-up "
          "(`measured_links_mm` in results.csv, their largest standard error, the ITG+ rules' sL, "
          "`measured_length_se_mm`); only the `-model` controllers and `ik` use the "
          "nominal model. The ITG+ rules' S is the servo limit (`controller_params` in "
          "results.csv). "
          "The Jacobian tracker scales a step whose largest joint increment exceeds the servo "
          "limit as a whole (keeping its direction); the loop clips every controller's joints "
          "to the same limit.", "",
          "Conditions: `noise-Spx` adds Gaussian noise of S px std to each centroid coordinate; "
          "`dropout-P` drops each LED detection with probability P; `rig-calibrated` estimates "
          "with the calibrated rig (the rig file's calibration beside it, `<rig>.calib.yaml`: "
          "Rigs, above); `rig-perturbed` with the true "
          "rig moved as one body by 1 degree and 5 mm (a wrong world frame, consistent stereo); "
          "`rig-perturbed-cams` with each camera turned by 1 degree and moved by 5 mm on its own "
          "(inconsistent stereo); random directions drawn from the seed; `links+X%` makes every "
          "link of the simulated arm X % longer than the nominal model; `offset-1deg` puts every "
          "simulated joint 1 degree off its command; `a+b` combines both. Images are always "
          "rendered with the true rig.", "",
          "Vision-only conditions (noise, dropout, rig) cannot affect the `-model` controllers and `ik` "
          "(no rendering): they are run anyway, a few ms each, so every cell comes from real "
          "runs (their numbers equal clean). `ik` is deterministic: its quartiles equal its median.", "",
          "Over seeds: the median and, in brackets, the first and third quartiles (numpy's "
          "linear interpolation between the sorted seeds: with 2 seeds the median is their mean "
          "and the quartiles lie a quarter of the way in from each, so [q1, q3] spans half their "
          "range; use more seeds for a spread).", "",
          "E_i = distance from the set point to the true gripper after the set point's "
          "iterations (x-y for planar arms). E_av and E_max: mean and maximum over all set "
          "points in reach (the paper's definition, start transient included). Tracking phase: "
          "the laps after the first on closed paths, else the second half; per run its median, "
          "mean, 95th percentile and max of E_i. Tables give the median over seeds of each "
          f"run's statistic, mm; a run diverged when its tracking median exceeds {DIVERGED_MM:g} mm.",
          ""]
    L += ["## Conclusion", ""] + conclusion(summary, trajs, conds, ctrls) + [""]
    if "itg-plus-vision" in ctrls:
        L += ["## Conclusion for ITG+", ""] + conclusion(summary, trajs, conds, ctrls,
                                                           subject="itg-plus-vision") + [""]
    for k, s in first.items():  # a user's rule bases (--rules), fed by vision
        if k not in CONTROLLER_TITLES and s.feedback == "vision":
            L += [f"## Conclusion for `{k}` (your rule base)", ""] + conclusion(
                summary, trajs, conds, ctrls, subject=k) + [""]
    for t in trajs:
        lim = _limits_line(specs, t)
        L += [f"## {t}: E_av (mm), median [q1, q3] over seeds", "", lim, ""] \
            + _table(summary, t, conds, ctrls, "e_av") + [""]
        L += [f"## {t}: tracking phase (mm): median / mean / p95 / max of E_i (worst seed's max)",
              "", lim, ""] + _tail_table(summary, t, conds, ctrls) + [""]
    plots = _plots(out, summary, trajs, conds, ctrls, plot, plot_metrics, specs, keep)
    if plots:
        L += ["## Plots", ""] + [f"![{p.stem}]({quote(p.name)})" for p in plots] + [""]
    elif not rows:
        L += ["## Plots", "", "None: no run of this sweep has finished.", ""]
    keep(out / "report.md")
    outputs.write_text(out / "report.md", "\n".join(L))
    return plots


def _file_note(specs: list[RunSpec], traj: str) -> str:
    """``, your file PATH`` for a user's trajectory file (``--trajectories FILE``), else ``""``."""
    path = next(s.trajectory for s in specs if trajectory_label(s.trajectory) == traj)
    return f", your file {path}" if names_a_csv_file(path) else ""


def _rigs_line(specs: list[RunSpec]) -> str:
    """Which rig files the vision runs used, per arm (its arm file's ``defaults.rig``): the true
    rig, which renders every image and estimates but under ``rig-calibrated``, and the
    calibration where that condition ran; ``""`` without a vision run."""
    from ..camera import default_rig_path
    from ..runner import shown_path

    parts = []
    for arm in dict.fromkeys(s.arm for s in specs if s.feedback == "vision"):
        part = f"the {arm} arm's `{shown_path(str(default_rig_path(arm)))}`"
        if any(s.arm == arm and s.rig == "calibrated" for s in specs):
            part += f", calibrated `{shown_path(str(default_rig_path(arm, calibrated=True)))}`"
        parts.append(part)
    return ("Rigs (the arm file's `defaults.rig`; images are always rendered with the true rig): "
            + "; ".join(parts) + ".") if parts else ""


def _arms_note(specs: list[RunSpec], spec: RunSpec) -> str:
    """`` (only on the two-link arm's trajectories)`` for a controller that skips some of the
    sweep's trajectories (a rule base for one arm), else ``""``."""
    all_arms = list(dict.fromkeys(s.arm for s in specs))
    its = list(dict.fromkeys(s.arm for s in specs if s.controller == spec.controller))
    if its == all_arms:
        return ""
    return f" (only on the {' and '.join(its)} arm's trajectories: the rule base fits no other)"


def spec_limits(specs: list[RunSpec], traj: str) -> dict:
    """What the runs of ``traj`` ran under, from their specs (every controller alike): its arm,
    set points per lap (the path's own where the sweep gives none), laps, iterations, servo
    limit (as text) and the number of seeds."""
    mine = [s for s in specs if trajectory_label(s.trajectory) == traj]
    s = mine[0]
    servo = "no servo limit" if s.max_step_deg is None else f"servo {s.max_step_deg:g} deg/iteration"
    return {"arm": s.arm, "per_lap": s.points or _default_points(s.trajectory), "laps": s.laps,
            "iterations": s.iterations, "servo": servo, "seeds": len({x.seed for x in mine})}


def _sweep_line(specs: list[RunSpec], traj: str) -> str:
    """What a figure of ``traj`` shows, for its title: set points, laps, seeds, limits."""
    lim = spec_limits(specs, traj)
    pts = f"{lim['per_lap']} set points"  # the path's own when the sweep gives none
    laps = f", {lim['laps']} laps" if lim["laps"] > 1 else ""
    return (f"{pts}{laps}, {lim['iterations']} iteration(s), {lim['servo']}; "
            f"{count(lim['seeds'], 'seed')}")


def _plots(out: Path, summary, trajs, conds, ctrls, plot, metrics, specs,
           keep=lambda path: None) -> list[Path]:
    made = []

    def cell(t, c, k, metric):  # (median, q1, q3); NaN where a run did not start or has no row
        s = summary.get((t, c, k))
        return s[metric] if s and complete(s) else (float("nan"),) * 3

    def left_out(t, c, k):  # why a cell with runs has no dot ("" if it has one or no runs)
        s = summary.get((t, c, k))
        return f"left out: {_no_start_note(s).strip(' ()')}" if s and not complete(s) else ""

    def diverged(t, c, k):
        s = summary.get((t, c, k))
        return bool(s and s["diverged"])

    def curve(t, k, pairs, metric):
        xs, ys = [], []
        for x, c in pairs:
            y = cell(t, c, k, metric)
            if math.isfinite(y[0]):
                xs.append(x)
                ys.append(y)
        return (xs, *np.array(ys, float).reshape(-1, 3).T)

    for t in trajs:
        about = _sweep_line(specs, t)
        for name, field_, xlabel in (("sigma", "noise_px", "centroid noise sigma (px)"),
                                     ("dropout", "dropout", "LED dropout probability"),
                                     ("model_error", "link_error", "link length error (%)")):
            pairs = [(0.0, "clean")] if "clean" in conds else []
            for c in conds:
                cd = CONDITIONS[c]
                others = dataclasses.replace(cd, name="", **{field_: Condition.__dataclass_fields__[field_].default})
                if getattr(cd, field_) and others == Condition(""):  # this factor alone
                    x = getattr(cd, field_) * (100 if field_ == "link_error" else 1)
                    pairs.append((x, c))
            if len(pairs) < 2:
                continue
            pairs.sort()
            for metric in metrics:
                label = PLOT_METRICS[metric]
                series = {k: curve(t, k, pairs, metric) for k in ctrls}
                series = {k: v for k, v in series.items() if v[0]}
                if max((len(v[0]) for v in series.values()), default=0) < 2:
                    continue  # no run of its conditions but one finished: no curve to draw
                gone = sorted({k for k in ctrls for _, c in pairs if diverged(t, c, k)})
                path = out / f"{metric}_vs_{name}-{t}.png"
                keep(path)
                plot.lines_figure(series, xlabel, f"{label} (mm), median over seeds",
                                  f"{t}: {label} against {xlabel}\n{about}"
                                  + (f"\ndiverged runs (tracking median > {DIVERGED_MM:g} mm) in: "
                                     + ", ".join(gone) if gone else ""), path, logy=True,
                                  hlines=[(DIVERGED_MM, f"diverged above ({DIVERGED_MM:g} mm)",
                                           "C3")] if gone and metric == "track_median" else ())
                made.append(path)
        for metric in metrics:
            cells = {k: [cell(t, c, k, metric) for c in conds] for k in ctrls}
            values = {k: [v[0] for v in vs] for k, vs in cells.items()}
            if not any(math.isfinite(v) for vs in values.values() for v in vs):
                continue  # no finished run: a log axis has nothing to scale
            path = out / f"{metric}_by_condition-{t}.png"
            keep(path)
            plot.grouped_dots_figure(
                conds, values, f"{PLOT_METRICS[metric]} (mm), median over seeds",
                f"{t}: {PLOT_METRICS[metric]} per controller and condition\n{about}", path,
                logy=True, spread={k: ([v[1] for v in vs], [v[2] for v in vs])
                                   for k, vs in cells.items()},
                flagged={k: [diverged(t, c, k) for c in conds] for k in ctrls},
                flag_label=f"a run diverged (tracking median > {DIVERGED_MM:g} mm)",
                empty_label="no run finished",
                notes={k: [left_out(t, c, k) for c in conds] for k in ctrls})
            made.append(path)
    return made
