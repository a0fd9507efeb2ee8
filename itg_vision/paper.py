"""python -m itg_vision.paper --out DIR: the paper's experiments 1 to 6, measured beside its claims.

Each experiment runs with the paper's setup (the arm's kinematic model as feedback, one rule
iteration per set point, start fully extended) unless ``--feedback`` says otherwise, and writes
a figure; ``report.md`` puts each measured figure beside the paper's claim.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import outputs, plot
from . import trajectory as traj
from .errors import UserError, run_main
from .loop import simulate
from .runner import RunConfig, execute, prepare
from .world import World

PAPER_F = 0.001  # the paper's f (experiment 1), units not stated
PAPER_F_AS_DEG_PER_MM = np.degrees(PAPER_F)  # read as rad/mm: 0.0573 deg/mm


def _run(base: RunConfig, **kw):
    return execute(prepare(replace(base, **kw)))


def settle_index(e: np.ndarray, threshold_mm: float) -> int:
    """First set point from which E_i stays below the threshold for 10 set points."""
    ok = e < threshold_mm
    for i in range(len(e) - 10):
        if ok[i:i + 10].all():
            return i
    return len(e)


def _simulate_points(base: RunConfig, points_mm: np.ndarray, **kw):
    """Run the two-link arm (or ``kw['arm']``) on raw points with the base configuration."""
    prep = prepare(replace(base, **{"arm": "two-link", "trajectory": "ellipse-t1", **kw}))
    fb = prep.feedback_factory()
    fb.reset(base.seed)
    with World(prep.true_arm) as w:
        return simulate(w, prep.controller, fb, points_mm, iterations=prep.config.iterations,
                        planar=prep.model.planar, max_step_deg=prep.config.max_step)


def exp1(base, out) -> dict:
    """The jump B-C, against a control run where B-C is crossed by 100 set points."""
    trace, s = _run(base, arm="two-link", trajectory="abcd")
    e = trace.error_mm()
    n = len(e) // 2
    pts = np.asarray(trace.desired_mm)
    bridge = pts[n - 1] + np.linspace(0, 1, 102)[1:-1, None] * (pts[n] - pts[n - 1])
    control = _simulate_points(base, np.vstack([pts[:n], bridge, pts[n:]])).error_mm()[-n:]
    cd = e[n:]
    after = settle_index(np.abs(cd - control), 0.1)  # set points until the jump is forgotten
    plot.paths_figure([("experiment 1: ABCD, f = %.2f deg/mm" % base.gain, trace)], "Fig. 4.1", out / "exp1_path.png")
    plot.lines_figure({"with the jump": (np.arange(n), cd), "control: B-C crossed by 100 set points": (np.arange(n), control)},
                      "set point on C-D", "E_i (mm)", "experiment 1: E_i along C-D", out / "exp1_error.png",
                      logy=True, marker="")
    return {"e_av_mm": s["e_av_mm"], "e_av_ab_last_half_mm": float(e[n // 2:n].mean()),
            "e_av_cd_mm": float(cd.mean()), "e_av_cd_control_mm": float(control.mean()),
            "jump_e_mm": float(cd[0]), "forgotten_after_setpoints": int(after),
            "e_av_cd_after_mm": float(cd[after:].mean()) if after < n else float("nan"),
            "e_av_cd_control_after_mm": float(control[after:].mean()) if after < n else float("nan")}


def exp2(base, out) -> dict:
    trace, s = _run(base, arm="two-link", trajectory="ellipse-t1")
    e = trace.error_mm()
    i0 = settle_index(e, 10.0)
    plot.paths_figure([("experiment 2: ellipse T1, 180 points", trace)], "Fig. 4.2", out / "exp2_path.png")
    return {"e_av_mm": s["e_av_mm"], "e_max_mm": s["e_max_mm"], "settled_at": i0,
            "e_av_after_settling_mm": float(np.mean(e[i0:]))}


def exp3(base, out) -> dict:
    ns = np.arange(100, 1001, 100)
    eav, near_axis = [], []
    for n in ns:
        trace, summ = _run(base, arm="two-link", trajectory="ellipse-t1", points=int(n))
        e, yd = trace.error_mm(), np.asarray(trace.desired_mm)[:, 1]
        eav.append(summ["e_av_mm"])
        near_axis.append(float(e[np.abs(yd) < 15.0].sum() / e.sum()))
    eav = np.array(eav)
    slope = float(np.polyfit(np.log(ns), np.log(eav), 1)[0])
    fit = np.exp(np.mean(np.log(eav * ns))) / ns
    plot.lines_figure({"measured E_av": (ns, eav), "c / n_t": (ns, fit)}, "n_t (set points)",
                      "E_av (mm)", f"Fig. 4.3: E_av against n_t (log-log slope {slope:.2f})",
                      out / "exp3_eav_vs_nt.png", logx=True, logy=True)
    return {"n_t": ns.tolist(), "e_av_mm": eav.tolist(), "loglog_slope": slope,
            "share_of_error_near_y0": near_axis}


def exp4(base, out) -> dict:
    fs = np.round(np.geomspace(0.02, 1.2, 19), 4)
    res, series = {}, {}
    for name in ("ellipse-t1", "ellipse-t2"):
        eav = np.array([_run(base, arm="two-link", trajectory=name, gain=float(f))[1]["e_av_mm"] for f in fs])
        best = float(fs[int(np.argmin(eav))])
        good = fs[eav <= 1.5 * eav.min()]
        res[name] = {"f": fs.tolist(), "e_av_mm": eav.tolist(), "best_f": best,
                     "good_range": [float(good.min()), float(good.max())], "min_e_av_mm": float(eav.min())}
        series[name.replace("ellipse-", "").upper()] = (fs, eav)
    paper = _run(base, arm="two-link", trajectory="ellipse-t1", gain=PAPER_F_AS_DEG_PER_MM)[1]["e_av_mm"]
    res["paper_f_as_rad_per_mm_e_av_t1_mm"] = paper
    plot.lines_figure(series, "f (deg/mm)", "E_av (mm)", "Fig. 4.4: E_av against f",
                      out / "exp4_eav_vs_f.png", logx=True, logy=True)
    return res


def exp5(base, out) -> dict:
    res, series_first, series_second = {}, {}, {}
    for n in (180, 360, 720):
        t1 = traj.named("ellipse-t1", n)
        pts, ang = t1.points_mm, t1.param_deg
        e = _simulate_points(base, np.vstack([pts, pts]), points=n).error_mm()  # two laps
        first, second = e[:n], e[n:]
        series_first[f"n_t={n}"] = (ang, first)
        series_second[f"n_t={n}"] = (ang, second)
        peaks = _peaks(ang, second)
        res[n] = {"first_lap_max_at_deg": float(ang[int(np.argmax(first))]),
                  "second_lap_peaks_deg": peaks,
                  "second_lap_peak_yd_mm": [float(pts[int(np.argmin(np.abs(ang - a))), 1]) for a in peaks],
                  "second_lap_e_av_mm": float(second.mean()), "second_lap_e_max_mm": float(second.max())}
    plot.lines_figure(series_first, "radial angle (deg)", "E_i (mm)",
                      "Fig. 4.5: set point deviation, first lap (as the paper: from the start pose)",
                      out / "exp5_first_lap.png", logy=True, marker="")
    plot.lines_figure(series_second, "radial angle (deg)", "E_i (mm)",
                      "Fig. 4.5: set point deviation, second lap (settled)", out / "exp5_second_lap.png", marker="")
    return res


def _peaks(ang, e, k=3) -> list[float]:
    """Angles of the k largest local maxima (circular)."""
    left, right = np.roll(e, 1), np.roll(e, -1)
    idx = np.flatnonzero((e >= left) & (e >= right))
    idx = idx[np.argsort(e[idx])[::-1][:k]]
    return sorted(float(ang[i]) for i in idx)


def exp6(base, out) -> dict:
    res = {}
    t_full, s_full = _run(base, arm="three-link", trajectory="line-ab")
    res["line-ab"] = {"n_out_of_reach": s_full["n_out_of_reach"], "n_setpoints": s_full["n_setpoints"],
                      "e_av_mm": s_full["e_av_mm"]}
    panels = []
    for label, kw in (("as the paper (1 iteration, no rate limit)", {}),
                      ("servo limit 2 deg/iteration, 5 iterations", {"max_step": 2.0, "iterations": 5})):
        trace, s = _run(base, arm="three-link", trajectory="line-ab-reach", **kw)
        e = trace.error_mm()
        res[label] = {"e_av_mm": s["e_av_mm"], "e_max_mm": s["e_max_mm"],
                      "e_av_second_half_mm": float(e[len(e) // 2:].mean())}
        panels.append((label, trace))
        plot.path_figure(trace, f"experiment 6, line-ab-reach, {label}: E_av {s['e_av_mm']:.2f} mm",
                         out / f"exp6_path_{'paper' if not kw else 'limited'}.png")
    plot.path_figure(t_full, f"experiment 6, the paper's line: {s_full['n_out_of_reach']} of "
                             f"{s_full['n_setpoints']} set points out of reach", out / "exp6_line_ab.png")
    return res


def report(r: dict, base: RunConfig) -> str:
    e1, e2, e3, e4, e5, e6 = (r[k] for k in ("exp1", "exp2", "exp3", "exp4", "exp5", "exp6"))
    t1, t2 = e4["ellipse-t1"], e4["ellipse-t2"]
    lim = e6["servo limit 2 deg/iteration, 5 iterations"]
    asis = e6["as the paper (1 iteration, no rate limit)"]
    lines = [
        "# The paper's experiments, reproduced",
        "",
        f"Command: `python -m itg_vision.paper --out DIR` (feedback `{base.feedback}`, gain f = {base.gain} deg/mm "
        f"unless swept, {base.iterations} iteration per set point, start fully extended, two-link 100/100 mm, "
        "three-link 100/100/100 mm). All numbers below were measured by this run.",
        "",
        "**Units of f.** The paper uses f = 0.001 without units. Read as rad/mm (0.0573 deg/mm) it tracks far "
        f"behind on T1 (E_av {e4['paper_f_as_rad_per_mm_e_av_t1_mm']:.1f} mm); the measured optimum is near "
        f"{t1['best_f']:.2f} deg/mm, and the loop turns unstable above about 0.8 deg/mm (the q1 loop gain is "
        "f * |y_g| * pi/180 per step, unstable past 2). We use f in deg/mm, default 0.5.",
        "",
        "| exp. | the paper's claim | measured here | verdict |",
        "| --- | --- | --- | --- |",
        f"| 1 | the sudden 100 mm jump B-C does not affect tracking quality (Fig. 4.1) | E_i right after the jump "
        f"{e1['jump_e_mm']:.1f} mm; from set point {e1['forgotten_after_setpoints']} of C-D on, E_i is within 0.1 mm of a "
        f"control run that crosses B-C with 100 set points (E_av there {e1['e_av_cd_after_mm']:.2f} vs "
        f"{e1['e_av_cd_control_after_mm']:.2f} mm); E_av on all of C-D {e1['e_av_cd_mm']:.2f} vs {e1['e_av_cd_control_mm']:.2f} mm | "
        + (f"partly: the jump costs a transient of {e1['forgotten_after_setpoints']} set points (E_i from "
           f"{e1['jump_e_mm']:.0f} mm down), after which the tracking is the same as without the jump |"
           if e1['forgotten_after_setpoints'] < 50 else "disagrees: the jump's effect lasts |"),
        f"| 2 | the ITG closely follows the nonlinear ellipse T1 (Fig. 4.2) | E_av {e2['e_av_mm']:.2f} mm over all 180 points "
        f"(E_max {e2['e_max_mm']:.1f} mm, the start transient from (0, 200)); after settling (set point {e2['settled_at']}) "
        f"E_av {e2['e_av_after_settling_mm']:.2f} mm | agrees in shape; the paper gives no number |",
        f"| 3 | E_av is inversely proportional to n_t (Fig. 4.3) | log-log slope {e3['loglog_slope']:.2f} over "
        f"n_t = 100..1000 (E_av {e3['e_av_mm'][0]:.2f} -> {e3['e_av_mm'][-1]:.2f} mm); set points with |y_d| < 15 mm carry "
        f"{100 * e3['share_of_error_near_y0'][0]:.0f} % of the error at n_t = 100 and {100 * e3['share_of_error_near_y0'][-1]:.0f} % at 1000 | "
        + ("agrees |" if -1.2 <= e3['loglog_slope'] <= -0.8 else
           "disagrees: E_av falls, but more slowly than 1/n_t. The lag behind the moving set point does scale as 1/n_t; the "
           "error where the ellipse crosses y = 0 does not, because Table 2 picks q1's direction from the sign of y_d and "
           "turns the wrong way until y_g changes sign too |"),
        f"| 4 | the best range of f is the same for T1 and T2 (Fig. 4.4) | best f: T1 {t1['best_f']:.3f}, T2 "
        f"{t2['best_f']:.3f} deg/mm; E_av within 1.5x of the minimum for f in [{t1['good_range'][0]:.3f}, "
        f"{t1['good_range'][1]:.3f}] (T1) and [{t2['good_range'][0]:.3f}, {t2['good_range'][1]:.3f}] (T2) | "
        f"{'agrees' if min(t1['good_range'][1], t2['good_range'][1]) >= max(t1['good_range'][0], t2['good_range'][0]) else 'disagrees'}: the ranges overlap; the upper end is set by the arm (stability), not the path |",
    ]
    peaks = "; ".join(f"n_t={n}: " + ", ".join(f"{a:.0f} deg (y_d {y:.0f} mm)" for a, y in
                                              zip(v["second_lap_peaks_deg"], v["second_lap_peak_yd_mm"]))
                      for n, v in e5.items())
    firsts = ", ".join(f"{v['first_lap_max_at_deg']:.0f}" for v in e5.values())
    at_ends = all(min(abs(a - 0), abs(a - 180), abs(a - 360)) <= 20 for v in e5.values()
                  for a in v["second_lap_peaks_deg"][:1])
    near_y0 = sum(abs(y) < 15 for v in e5.values() for y in v["second_lap_peak_yd_mm"])
    total = sum(len(v["second_lap_peak_yd_mm"]) for v in e5.values())
    lines.append(
        f"| 5 | the largest deviation is at radial angles 0, 180, 360 deg (Fig. 4.5) | first lap (from the start pose, as "
        f"the paper): largest at {firsts} deg, the start transient. Settled second lap, the three largest peaks: {peaks} | "
        + ("agrees |" if at_ends else
           f"partly: the first lap's maximum is at 0/360 deg, but only because the arm starts far from the first set point; "
           f"once settled, {near_y0} of the {total} largest peaks sit where |y_d| < 15 mm, i.e. where the path crosses the "
           f"x axis and Table 2's sign-of-y_d quirk turns q1 the wrong way, not where the path bends most |"))
    lines.append(
        f"| 6 | line A(50, 30, 220) to B(250, 200, 400), 100 points, average error about 0.4 mm | the paper's line: "
        f"{e6['line-ab']['n_out_of_reach']} of {e6['line-ab']['n_setpoints']} set points out of reach (B is 439 mm "
        f"from the shoulder, reach 200 mm): RULE 0 flags them. Reachable variant (`line-ab-reach`): as the paper, "
        f"E_av {asis['e_av_mm']:.1f} mm; with a 2 deg/iteration servo limit and 5 iterations E_av {lim['e_av_mm']:.2f} mm, "
        f"{lim['e_av_second_half_mm']:.2f} mm on the second half | "
        + ("disagrees as given: from the singular straight-up start the variable step throws the arm over the top, "
           "where the r^2 comparisons lose the sign of r, and the Table 1 rule turns the base while the arm is still "
           "upright. With a servo rate limit the composition tracks; an error near the paper's 0.4 mm holds only after "
           "the start transient |" if asis["e_av_mm"] > 2 * lim["e_av_mm"] or lim["e_av_second_half_mm"] > 1 else
           "agrees |"))
    lines += ["", "## Figures", ""]
    for name, cap in (("exp1_path.png", "Experiment 1 (Fig. 4.1)"), ("exp1_error.png", "Experiment 1: E_i"),
                      ("exp2_path.png", "Experiment 2 (Fig. 4.2)"), ("exp3_eav_vs_nt.png", "Experiment 3 (Fig. 4.3)"),
                      ("exp4_eav_vs_f.png", "Experiment 4 (Fig. 4.4)"), ("exp5_first_lap.png", "Experiment 5 (Fig. 4.5), first lap"),
                      ("exp5_second_lap.png", "Experiment 5, second lap"), ("exp6_line_ab.png", "Experiment 6, the paper's line"),
                      ("exp6_path_paper.png", "Experiment 6, reachable variant, as the paper"),
                      ("exp6_path_limited.png", "Experiment 6, reachable variant, servo limit")):
        lines.append(f"![{cap}]({name})")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    def body() -> int:
        from .errors import ArgumentParser  # one-line option errors

        ap: argparse.ArgumentParser = ArgumentParser(prog="python -m itg_vision.paper", description=__doc__.split("\n\n")[0])
        ap.add_argument("--out", default="paper-out",
                        help="output folder (default %(default)s); replaced only if this command "
                             "made it")
        ap.add_argument("--force", action="store_true",
                        help="replace --out even if it is a folder this command did not make")
        ap.add_argument("--feedback", default="model", choices=("model", "truth", "vision"),
                        help="feedback of every run (default: model, the paper's setup)")
        ap.add_argument("--gain", type=float, default=0.5, help="f in deg/mm (default %(default)s)")
        ap.add_argument("--seed", type=int, default=0)
        ap.add_argument("--quiet", action="store_true")
        args = ap.parse_args(argv)
        base = RunConfig(feedback=args.feedback, gain=args.gain, seed=args.seed)
        base.validate()
        results = {}
        with outputs.staged_dir(Path(args.out), "paper", force=args.force) as tmp:
            for name, fn in (("exp1", exp1), ("exp2", exp2), ("exp3", exp3), ("exp4", exp4),
                             ("exp5", exp5), ("exp6", exp6)):
                if not args.quiet:
                    print(f"running {name} ...", file=sys.stderr)
                results[name] = fn(base, tmp)
            outputs.write_json(tmp / "results.json", results)
            text = report(results, base)
            outputs.write_text(tmp / "report.md", text)
        if not args.quiet:
            print(text)
            print(f"written to {args.out}/")
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(main())
