"""python -m itg_vision.paper --out DIR: the paper's experiments 1 to 6, measured beside its claims.

Each experiment runs with the paper's setup (the arm's kinematic model as feedback, one rule
iteration per set point, start fully extended, no servo limit) unless ``--feedback`` says
otherwise, and writes a figure; ``report.md`` puts each measured figure beside the paper's
claim, with a verdict computed from a threshold written beside it. Where the paper is open we
choose, and the report says so (experiment 1's corners, the units of f, what "acceptable" is).
Mechanisms offered in the report are tested by changing the suspected cause and measuring again.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np

from . import outputs, plot
from . import trajectory as traj
from .errors import exit_status, run_main
from .feedback import Markers, ModelFeedback, TruthFeedback
from .inputs import count
from .identify import nominal_geometry
from .loop import simulate
from .rules import PARAM_DEFAULTS
from .runner import RunConfig, bind_geometry, execute, prepare
from .world import World

PAPER_F = 0.001  # the paper's f (experiment 1), units not stated
PAPER_F_AS_DEG_PER_MM = float(np.degrees(PAPER_F))  # read as rad/mm: 0.0573 deg/mm
PAPER_EXP6_E_AV_MM = 0.4

#: Thresholds of the verdicts (written into the report beside each number).
JUMP_FORGOTTEN_AGREE = 5     # exp. 1: set points after the jump until E_i is within 0.1 mm of control
JUMP_FORGOTTEN_PARTLY = 50
FOLLOWS_CLOSELY_MM = 5.0     # exp. 2: settled E_av, 2.5 % of the arm's 200 mm reach
SLOPE_RANGE = (-1.2, -0.8)   # exp. 3: "inversely proportional" (log-log slope -1)
GOOD_F_FACTOR = 1.5          # exp. 4: f whose E_av is within 1.5x of the minimum
PEAK_ANGLE_TOL_DEG = 20.0    # exp. 5: a peak "at 0/180/360 deg"
ACCEPTABLE_MM = 10.0         # exp. 5: "within acceptable limits": settled-lap E_max, 5 % of reach
FLAIL_MM = 20.0              # exp. 5: a set point of a flail
EXP6_FACTOR = 2.0            # exp. 6: agrees if E_av within 2x of the paper's 0.4 mm, all in reach


def jump_verdict(forgotten_after: int) -> str:
    """Experiment 1's verdict from the set points until the jump is forgotten."""
    return verdict(forgotten_after <= JUMP_FORGOTTEN_AGREE, forgotten_after <= JUMP_FORGOTTEN_PARTLY)


def verdict(ok: bool, partly: bool = False) -> str:
    return "agrees" if ok else ("partly" if partly else "disagrees")


class ExactModel(ModelFeedback):
    """The model's forward kinematics rounded to 1e-9 mm, so that where the paper's equations
    make two coordinates equal they are equal: at the two-link arm's straight-up start
    (q 90, 0 deg) x_g = x_e = 0, where floating point's cos 90 deg = 6e-17 puts the gripper
    6e-15 mm right of the elbow and so decides Table 2's RULE 3/4 tie. Elsewhere it moves every
    coordinate by under 1e-9 mm."""

    name = "model, rounded to 1e-9 mm"

    def observe(self, world) -> Markers:
        m = super().observe(world)
        return Markers(np.round(m.gripper_mm, 9), np.round(m.elbow_mm, 9))


def _prepare(base: RunConfig, exact: bool, in_plane: bool = False, **kw):
    """``base`` with ``kw`` prepared; ``exact``: the feedback is :class:`ExactModel`;
    ``in_plane``: :func:`in_plane_model`, unless the feedback is vision (the cameras need the
    LEDs on their posts)."""
    prep = prepare(replace(base, **kw))
    if in_plane and _paper_model_feeds(prep.config.feedback):
        prep = in_plane_model(prep)
    if exact:
        prep.feedback_factory = lambda: ExactModel(prep.model)
    return prep


def _paper_model_feeds(feedback: str) -> bool:
    """Whether experiment 6 tracks the paper's in-plane points under ``feedback``: model and
    truth do; vision tracks the LEDs on their posts, which the cameras need."""
    return feedback != "vision"


def in_plane_model(prep):
    """``prep`` with the paper's three-link model (its Case Study II equations): the gripper and
    the elbow in the arm's vertical plane, not ``led_standoff_mm`` beside it on the posts that
    show the LEDs to a camera. The stand-off moves the tracked point 12 mm sideways, and with it
    what the rules see and what E_i measures (experiment 6's line: E_av 11.5 mm in the plane,
    30.4 on the posts; measured by :func:`exp6`). Model and truth feedback only."""
    model = replace(prep.model, led_standoff_mm=0.0)
    true_arm = replace(prep.true_arm, led_standoff_mm=0.0)
    n_in_reach = sum(true_arm.reachable(p) for p in prep.trajectory.points_mm)
    out = replace(prep, model=model, true_arm=true_arm, n_in_reach=n_in_reach)
    if prep.config.feedback == "model":
        out.feedback_factory = lambda: ModelFeedback(model)
    return out


def _setup(base: RunConfig, with_f: bool = True, **kw) -> str:
    """What the runs of a figure ran with, for its title (a second line): the rules, the
    feedback, f (unless the figure varies it), the iterations and the servo limit."""
    cfg = replace(base, **kw)
    f = cfg.gain_deg_per_mm if cfg.gain_deg_per_mm is not None else PARAM_DEFAULTS["f"]
    limit = ("no servo limit" if cfg.max_step_deg is None
             else f"servo limit {cfg.max_step_deg:g} deg/iteration")
    n = cfg.iterations
    return ", ".join([f"the paper's rules, {cfg.feedback} feedback"]
                     + ([f"f = {f:g} deg/mm"] if with_f else [])
                     + [f"{count(n, 'iteration')} per set point, {limit}"])


def _run(base: RunConfig, exact: bool = False, in_plane: bool = False, **kw):
    return execute(_prepare(base, exact, in_plane, **kw))


def settle_index(e: np.ndarray, threshold_mm: float) -> int:
    """First set point from which E_i stays below the threshold for 10 set points."""
    ok = e < threshold_mm
    for i in range(len(e) - 9):  # the last window, e[-10:], included
        if ok[i:i + 10].all():
            return i
    return len(e)


def _simulate_points(base: RunConfig, points_mm: np.ndarray, exact: bool = False, **kw):
    """Run the two-link arm (or ``kw['arm']``) on raw points with the base configuration."""
    prep = _prepare(base, exact, **{"arm": "two-link", "trajectory": "ellipse-t1", **kw})
    fb = prep.feedback_factory()
    fb.reset(base.seed)
    with World(prep.true_arm) as w:
        ctl = bind_geometry(prep.controller, nominal_geometry(prep.model), prep.model)
        return simulate(w, ctl, fb, points_mm, iterations=prep.config.iterations,
                        planar=prep.model.planar, max_step_deg=prep.config.max_step_deg)


def _jump(base, exact: bool = False):
    """ABCD and its control (B-C crossed by 100 set points): the trace, its summary, E_i on C-D
    with and without the jump, and the set points until the jump is forgotten."""
    trace, s = _run(base, exact, arm="two-link", trajectory="abcd")
    e = trace.error_mm()
    n = len(e) // 2
    pts = np.asarray(trace.desired_mm)
    bridge = pts[n - 1] + np.linspace(0, 1, 102)[1:-1, None] * (pts[n] - pts[n - 1])
    control = _simulate_points(base, np.vstack([pts[:n], bridge, pts[n:]]), exact).error_mm()[-n:]
    cd = e[n:]
    return trace, s, cd, control, settle_index(np.abs(cd - control), 0.1)


EXP1_PAPER_F_ITERATIONS = (1, 10, 20)


def exp1(base, out) -> dict:
    """The jump B-C, against a control run where B-C is crossed by 100 set points."""
    trace, s, cd, control, after = _jump(base)
    e = trace.error_mm()
    n = len(e) // 2
    plot.paths_figure([("experiment 1: ABCD", trace,
                        [(n - 1, n, "B-C: the jump (no set point between)")])],
                      f"Fig. 4.1\n{_setup(base)}", out / "exp1_path.png")
    plot.lines_figure({"with the jump": (np.arange(n), cd), "control: B-C crossed by 100 set points": (np.arange(n), control)},
                      "set point on C-D", "E_i (mm)", f"experiment 1: E_i along C-D\n{_setup(base)}",
                      out / "exp1_error.png", logy=True, marker="",
                      vlines=[(JUMP_FORGOTTEN_AGREE, f"agrees if forgotten within {JUMP_FORGOTTEN_AGREE}", "C2"),
                              (JUMP_FORGOTTEN_PARTLY, f"partly within {JUMP_FORGOTTEN_PARTLY}", "C3")],
                      vspans=[(0, after, f"until forgotten ({after} set points): E_i more than 0.1 mm "
                                         "from the control's")])
    # the paper states f for this experiment only: 0.001, read as rad/mm, at 1 iteration per
    # set point (as the paper runs) and at the few of its section 3.2(i)
    papers_f = {}
    for k in EXP1_PAPER_F_ITERATIONS:
        _, _, cd_k, control_k, after_k = _jump(replace(base, gain_deg_per_mm=PAPER_F_AS_DEG_PER_MM,
                                                       iterations=k))
        papers_f[str(k)] = {"jump_e_mm": float(cd_k[0]), "forgotten_after_setpoints": int(after_k),
                            "cd_setpoints": len(cd_k), "e_av_cd_mm": float(cd_k.mean()),
                            "e_av_cd_control_mm": float(control_k.mean())}
    return {"corners_mm": [list(c) for c in traj.ABCD_MM], "at_papers_f": papers_f,
            "e_av_mm": s["e_av_mm"], "e_av_ab_last_half_mm": float(e[n // 2:n].mean()),
            "e_av_cd_mm": float(cd.mean()), "e_av_cd_control_mm": float(control.mean()),
            "jump_e_mm": float(cd[0]), "forgotten_after_setpoints": int(after), "cd_setpoints": int(n),
            "e_av_cd_after_mm": float(cd[after:].mean()) if after < n else float("nan"),
            "e_av_cd_control_after_mm": float(control[after:].mean()) if after < n else float("nan")}


def exp2(base, out) -> dict:
    """T1 as the paper runs it, then a second lap: a flail hides in the later laps of a closed
    path, so the settled part, which the verdict judges, runs to the end of the second."""
    trace, _ = _run(base, arm="two-link", trajectory="ellipse-t1", laps=2)
    e = trace.error_mm()
    n = trace.tracking_start  # where the second lap starts
    i0 = settle_index(e, 10.0)
    # a run that never settles has no settled part: nan, and its verdict disagrees
    settled = e[i0:] if i0 < len(e) else np.array([np.nan])
    plot.paths_figure([("experiment 2: ellipse T1, 180 points, 2 laps", trace)],
                      f"Fig. 4.2\n{_setup(base)}", out / "exp2_path.png", laps=2)
    plot.lines_figure({"E_i": (np.arange(len(e)), e)}, "set point i (lap 2 from 180)", "E_i (mm)",
                      f"experiment 2: E_i along T1, 2 laps (settled from set point {i0})\n{_setup(base)}",
                      out / "exp2_error.png", logy=True, marker=None,
                      hlines=[(ACCEPTABLE_MM, f"settled E_max at most {ACCEPTABLE_MM:g} mm; settling: "
                                              "below it for 10 set points in a row", "C3"),
                              (FOLLOWS_CLOSELY_MM, f"settled E_av at most {FOLLOWS_CLOSELY_MM:g} mm", "C2")]
                      + ([(float(settled.mean()), f"settled E_av, measured: {settled.mean():.2f} mm",
                           "C0")] if i0 < len(e) else []),
                      vlines=[(n - 0.5, "lap 2 begins", "C7")],
                      vspans=[(0, min(i0, len(e)) - 0.5, "start transient (before settling)")]
                      if i0 > 0 else [])
    # the paper's lap alone, settled from the same set point (nan if it settles only later)
    lap1 = e[i0:n] if i0 < n else np.array([np.nan])
    return {"e_av_mm": float(np.mean(e[:n])), "e_max_mm": float(np.max(e[:n])),  # lap 1
            "e_max_setpoint": int(np.argmax(e[:n])),
            "second_lap_e_av_mm": float(np.mean(e[n:])), "second_lap_e_max_mm": float(np.max(e[n:])),
            "settled_at": i0, "e_av_after_settling_mm": float(settled.mean()),
            "e_max_after_settling_mm": float(settled.max()),
            "papers_lap_e_av_after_settling_mm": float(lap1.mean()),
            "papers_lap_e_max_after_settling_mm": float(lap1.max())}


EXP3_GAINS = (0.1, 0.2, 0.5)


def exp3(base, out) -> dict:
    """E_av against n_t, for several gains f: the slope depends on f."""
    ns = np.arange(100, 1001, 100)
    res, series = {}, {}
    for f in EXP3_GAINS:
        eav = np.array([_run(base, arm="two-link", trajectory="ellipse-t1", points=int(n),
                             gain_deg_per_mm=f)[1]["e_av_mm"] for n in ns])
        coef, cov = np.polyfit(np.log(ns), np.log(eav), 1, cov=True)
        slope = float(coef[0])
        # the fit's standard error (residual scatter over n - 2 degrees of freedom): how far
        # the band's verdict is from turning
        res[f"{f:g}"] = {"e_av_mm": eav.tolist(), "loglog_slope": slope,
                         "loglog_slope_se": float(np.sqrt(cov[0, 0]))}
        inside = SLOPE_RANGE[0] <= slope <= SLOPE_RANGE[1]
        series[f"f = {f:g} deg/mm: slope {slope:.2f} ({'in' if inside else 'outside'} the band)"] = (ns, eav)
    # references, not measurements: slopes -1 (the claim) and the band's edges, through the
    # geometric mean of the first gain's points
    e0 = np.asarray(res[f"{EXP3_GAINS[0]:g}"]["e_av_mm"])
    anchor_n, anchor_e = np.exp(np.mean(np.log(ns))), np.exp(np.mean(np.log(e0)))
    refs = {f"slope {k:g}{' (inversely proportional)' if k == -1 else ''}, through f = "
            f"{EXP3_GAINS[0]:g}": (ns, anchor_e * (ns / anchor_n) ** k)
            for k in (-1.0, SLOPE_RANGE[0], SLOPE_RANGE[1])}
    plot.lines_figure(series, "n_t (set points)", "E_av (mm)",
                      f"Fig. 4.3: E_av against n_t (a gain agrees if its slope is in "
                      f"[{SLOPE_RANGE[0]:g}, {SLOPE_RANGE[1]:g}])\n{_setup(base, with_f=False)}",
                      out / "exp3_eav_vs_nt.png", logx=True, logy=True,
                      references=refs)
    return {"n_t": ns.tolist(), "by_gain_deg_per_mm": res}


#: Experiment 4's grid of f (deg/mm): 19 log-spaced from 0.02 to 1.2, and steps of 0.02 from
#: 0.30 to 1.00, where the optimum and the rise past it lie (the log grid alone steps 26 %
#: there: it landed on T2's isolated spike at 0.76 and so put T2's best f at 0.61, where the
#: fine grid finds 0.78).
EXP4_FINE_STEP = 0.02
_LOG_GRID = np.round(np.geomspace(0.02, 1.2, 19), 4)
EXP4_GAINS = np.concatenate([_LOG_GRID[_LOG_GRID < 0.3],
                             np.round(np.arange(0.30, 1.0 + 1e-9, EXP4_FINE_STEP), 4),
                             _LOG_GRID[_LOG_GRID > 1.0]])


def _gain_sweep(base, name: str, exact: bool = False) -> dict:
    """E_av on ``name`` over experiment 4's grid of f; the best f and the good range."""
    fs = EXP4_GAINS
    eav = np.array([_run(base, exact, arm="two-link", trajectory=name,
                         gain_deg_per_mm=float(f))[1]["e_av_mm"] for f in fs])
    ok = eav <= GOOD_F_FACTOR * eav.min()
    good = fs[ok]
    inside = (fs > good.min()) & (fs < good.max()) & ~ok  # not good, between good ones
    return {"f_deg_per_mm": fs.tolist(), "e_av_mm": eav.tolist(),
            "best_f_deg_per_mm": float(fs[int(np.argmin(eav))]),
            "good_f_range_deg_per_mm": [float(good.min()), float(good.max())],
            "not_good_inside_range_deg_per_mm": fs[inside].tolist(),
            "min_e_av_mm": float(eav.min())}


def _overlap(a, b) -> bool:
    return a[0] <= b[1] and b[0] <= a[1]


def exp4(base, out) -> dict:
    res, series = {}, {}
    for name in ("ellipse-t1", "ellipse-t2"):
        res[name] = _gain_sweep(base, name)
        series[name.replace("ellipse-", "").upper()] = (EXP4_GAINS, np.array(res[name]["e_av_mm"]))
    # the paper's f = 0.001 read as rad/mm, with a few iterations per set point (its 3.2(i))
    res["paper_f_as_rad_per_mm_e_av_t1_mm"] = {
        str(k): _run(base, arm="two-link", trajectory="ellipse-t1", gain_deg_per_mm=PAPER_F_AS_DEG_PER_MM,
                     iterations=k)[1]["e_av_mm"] for k in (1, 10, 20)}
    plot.lines_figure(series, "f (deg/mm)", "E_av (mm)",
                      f"Fig. 4.4: E_av against f\n{_setup(base, with_f=False)}",
                      out / "exp4_eav_vs_f.png", logx=True, logy=True,
                      hlines=[(GOOD_F_FACTOR * res[n]["min_e_av_mm"],
                               f"{n.replace('ellipse-', '').upper()}: {GOOD_F_FACTOR:g}x its minimum (good f below)",
                               f"C{i}") for i, n in enumerate(("ellipse-t1", "ellipse-t2"))],
                      vlines=[(res[n]["best_f_deg_per_mm"],
                               f"{n.replace('ellipse-', '').upper()}: best f, "
                               f"{res[n]['best_f_deg_per_mm']:g} deg/mm", f"C{i}")
                              for i, n in enumerate(("ellipse-t1", "ellipse-t2"))])
    return res


def _inverted(trace) -> np.ndarray:
    """Per set point: both joints' levers inverted against Table 2's pairing (q1 moves the
    gripper mostly in y, q2 mostly in x), from the true LED positions."""
    g, e = np.asarray(trace.gripper_mm), np.asarray(trace.elbow_mm)
    return (g[:, 0] ** 2 > g[:, 1] ** 2) & ((g[:, 1] - e[:, 1]) ** 2 > (g[:, 0] - e[:, 0]) ** 2)


def _two_laps(base, n, rules=None):
    t1 = traj.named("ellipse-t1", n)
    kw = {"points": n} if rules is None else {"points": n, "rules": rules}
    return _simulate_points(base, np.vstack([t1.points_mm, t1.points_mm]), **kw), t1


def exp5(base, out) -> dict:
    """Deviation against the radial angle; the settled lap's flails and their mechanism."""
    res, series_first, series_second = {}, {}, {}
    for n in (180, 360, 720):
        trace, t1 = _two_laps(base, n)
        pts, ang = t1.points_mm, t1.param_deg
        e = trace.error_mm()
        first, second = e[:n], e[n:]
        series_first[f"n_t={n}"] = (ang, first)
        series_second[f"n_t={n}"] = (ang, second)
        peaks = _peaks(second)
        centre = pts[:, :2].mean(axis=0)  # the lap's points, even in the parameter: its centre
        # flail onsets on the settled lap: E_i crosses FLAIL_MM; the pose one set point before
        k = np.flatnonzero((e[n:] > FLAIL_MM) & (e[n - 1:-1] <= FLAIL_MM)) + n
        inv = _inverted(trace)
        variants = {}
        for label, rules in (("sign of y_g instead of y_d", "table2-sign-of-yg"),
                             ("pairing swapped where both levers are inverted", "table2-pairing-swap")):
            e2 = _two_laps(base, n, rules)[0].error_mm()[n:]
            variants[label] = {"rules": rules, "second_lap_e_av_mm": float(e2.mean()),
                               "second_lap_e_max_mm": float(e2.max())}
        i1 = settle_index(first, ACCEPTABLE_MM)  # the paper's lap, from where it settles
        k1 = i1 + int(np.argmax(first[i1:])) if i1 < n else None
        res[n] = {"first_lap_max_at_deg": float(ang[int(np.argmax(first))]),
                  "first_lap_max_setpoint": int(np.argmax(first)), "first_lap_settled_at": int(i1),
                  # the paper's lap after settling: where its largest E_i lies (None: unsettled)
                  "first_lap_settled_max_at_deg": None if k1 is None else float(ang[k1]),
                  "first_lap_settled_max_e_mm": None if k1 is None else float(first[k1]),
                  # the three largest peaks, the largest first: angle, E_i and y_d there
                  "second_lap_peaks_deg": [float(ang[i]) for i in peaks],
                  "second_lap_peak_e_mm": [float(second[i]) for i in peaks],
                  "second_lap_peak_yd_mm": [float(pts[i, 1]) for i in peaks],
                  # the same peaks under two other readings of the paper's "radial angle": the
                  # polar angle of the set point about the ellipse's centre, and about the base
                  "second_lap_peaks_about_centre_deg": [_polar_deg(pts[i, :2] - centre) for i in peaks],
                  "second_lap_peaks_about_base_deg": [_polar_deg(pts[i, :2]) for i in peaks],
                  "second_lap_e_av_mm": float(second.mean()), "second_lap_e_max_mm": float(second.max()),
                  "flail_onsets": int(len(k)),
                  "flail_onsets_from_inverted_pose": int(inv[k - 1].sum()) if len(k) else 0,
                  "inverted_share_of_settled_lap": float(inv[n:].mean()),
                  "variants": variants}
    marks = {"hlines": [(ACCEPTABLE_MM, f"acceptable: {ACCEPTABLE_MM:g} mm")],
             "vspans": [(max(a - PEAK_ANGLE_TOL_DEG, 0), min(a + PEAK_ANGLE_TOL_DEG, 360),
                         f"the paper's peaks: 0, 180, 360 +- {PEAK_ANGLE_TOL_DEG:g} deg")
                        for a in (0, 180, 360)]}
    angle = "radial angle: the ellipse's parameter (deg)"
    # the start transient, per series in its colour: its peak near 0 deg is the start, not a
    # flail at the paper's 0 deg peak (the verdict reads the settled lap)
    settled = [(float(series_first[f"n_t={m}"][0][res[m]["first_lap_settled_at"]]),
                f"n_t={m}: start transient before here (set point {res[m]['first_lap_settled_at']})",
                f"C{i}") for i, m in enumerate(res) if res[m]["first_lap_settled_at"] < m]
    plot.lines_figure(series_first, angle, "E_i (mm)",
                      "Fig. 4.5: set point deviation, first lap (as the paper: from the start pose)"
                      f"\n{_setup(base)}",
                      out / "exp5_first_lap.png", logy=True, marker=None, vlines=settled, **marks)
    plot.lines_figure(series_second, angle, "E_i (mm)",
                      f"Fig. 4.5: set point deviation, second lap (settled)\n{_setup(base)}",
                      out / "exp5_second_lap.png",
                      logy=True, marker=None, **marks)
    return res


def _polar_deg(v) -> float:
    """The direction of a planar vector, deg in [0, 360)."""
    return float(np.degrees(np.arctan2(v[1], v[0])) % 360.0)


def _at_ends(angles_deg) -> bool:
    """Whether every angle lies within PEAK_ANGLE_TOL_DEG of 0, 180 or 360 deg."""
    return all(min(abs(a - 0), abs(a - 180), abs(a - 360)) <= PEAK_ANGLE_TOL_DEG for a in angles_deg)


def _peaks(e, k=3) -> np.ndarray:
    """Indices of the k largest local maxima (circular), the largest first."""
    left, right = np.roll(e, 1), np.roll(e, -1)
    idx = np.flatnonzero((e >= left) & (e >= right))
    return idx[np.argsort(e[idx], kind="stable")[::-1][:k]]


class BiasedElbow(TruthFeedback):
    """Ideal LED positions, the elbow moved ``bias_mm`` away from the base axis (horizontally):
    a deterministic stand-in for vision's sub-0.1 mm bias, to decide the straight-up tie."""

    def __init__(self, bias_mm: float):
        super().__init__()
        self.bias_mm = float(bias_mm)

    def observe(self, world) -> Markers:
        m = super().observe(world)
        e = m.elbow_mm.copy()
        r = float(np.hypot(e[0], e[1]))
        if r > 0:
            e[:2] *= (r + self.bias_mm) / r
        return Markers(m.gripper_mm, e)


TIE_BIAS_MM = 0.05
TIE_LINKS_MM = ((100.0, 100.0, 100.0), (105.0, 105.0, 105.0))


def tie_experiment(max_step_deg: float = 2.0, iterations: int = 5,
                   gain_deg_per_mm: float | None = None) -> list[dict]:
    """Three-link, line-ab-reach, ideal sensors: the straight-up start's rg2 == re2 tie decided
    by a deterministic +-0.05 mm elbow bias, for nominal and 5 % long links; f is
    ``gain_deg_per_mm`` (None: the rules' default), the run's ``--gain`` in :func:`exp6`."""
    rows = []
    for links in TIE_LINKS_MM:
        for bias in (+TIE_BIAS_MM, -TIE_BIAS_MM, 0.0):
            prep = prepare(RunConfig(arm="three-link", feedback="truth", max_step_deg=max_step_deg,
                                     iterations=iterations, true_links_mm=links,
                                     gain_deg_per_mm=gain_deg_per_mm))
            with World(prep.true_arm) as w:
                from .identify import measure_geometry

                geometry = measure_geometry(w, TruthFeedback(), prep.model)
                ctl = bind_geometry(prep.controller, geometry, prep.model)
                fb = BiasedElbow(bias)
                m0 = fb.observe(w)
                tie = float(np.sum(m0.gripper_mm[:2] ** 2) - np.sum(m0.elbow_mm[:2] ** 2))
                tr = simulate(w, ctl, fb, prep.trajectory.points_mm, iterations=iterations,
                              planar=False, max_step_deg=max_step_deg)
            rows.append({"links_mm": list(links), "elbow_bias_mm": bias, "rg2_minus_re2_mm2": tie,
                         "first_q3_rule": next((r for r in tr.fired[0] if r in (6, 7)), None),
                         **{k: tr.metrics()[k] for k in ("track_median_mm", "track_mean_mm",
                                                         "track_p95_mm", "track_max_mm")}})
    return rows


def _where_tracked(base: RunConfig) -> str:
    """The three-link point experiment 6 tracks and measures, for the report and the titles."""
    return ("gripper and elbow in the arm's plane (the paper's equations)"
            if _paper_model_feeds(base.feedback)
            else "the LEDs on their 12 mm posts beside the arm's plane (the cameras' view)")


EXP6_RUNS = (("as the paper (1 iteration, no servo limit)", {}),
             ("servo limit 2 deg/iteration, 5 iterations", {"max_step_deg": 2.0, "iterations": 5}))


def exp6(base, out) -> dict:
    """The paper's line A-B (65 of its 100 set points out of reach) and a reachable variant, on
    the paper's model (:func:`in_plane_model`, unless vision); the line again with the LEDs on
    their posts, the cause of a difference the model makes."""
    res = {}
    t_full, s_full = _run(base, in_plane=True, arm="three-link", trajectory="line-ab")
    res["line-ab"] = {"n_out_of_reach": s_full["n_out_of_reach"], "n_flagged": s_full["n_flagged"],
                      "n_setpoints": s_full["n_setpoints"], "e_av_mm": s_full["e_av_mm"]}
    if _paper_model_feeds(base.feedback):
        res["line-ab, LEDs on their posts"] = {"e_av_mm": _run(base, arm="three-link",
                                                               trajectory="line-ab")[1]["e_av_mm"]}
    e_full = t_full.error_mm()
    panels = [(f"the paper's line, its {int(t_full.in_reach.sum())} set points in reach (the "
               f"verdict's): E_av {s_full['e_av_mm']:.1f} mm", np.where(t_full.in_reach, e_full, np.nan),
               s_full["e_av_mm"])]
    for label, kw in EXP6_RUNS:
        trace, s = _run(base, in_plane=True, arm="three-link", trajectory="line-ab-reach", **kw)
        e = trace.error_mm()
        res[label] = {"e_av_mm": s["e_av_mm"], "e_max_mm": s["e_max_mm"],
                      "e_av_second_half_mm": float(e[len(e) // 2:].mean()),
                      "e_max_second_half_mm": float(e[len(e) // 2:].max()),
                      "e_max_setpoint": int(np.nanargmax(e)), "n_setpoints": int(len(e))}
        panels.append((f"line-ab-reach, {label}: E_av {s['e_av_mm']:.1f} mm", e, s["e_av_mm"]))
        plot.path_figure(trace, f"experiment 6, line-ab-reach, {label}: E_av {s['e_av_mm']:.2f} mm"
                                f"\n{_setup(base, **kw)}",
                         out / f"exp6_path_{'paper' if not kw else 'limited'}.png")
    plot.path_figure(t_full, f"experiment 6, the paper's line: {s_full['n_out_of_reach']} of "
                             f"{s_full['n_setpoints']} set points out of reach; E_av over those in "
                             f"reach {s_full['e_av_mm']:.1f} mm\n{_setup(base)}", out / "exp6_line_ab.png")
    plot.lines_figure({label: (np.arange(len(e)), e) for label, e, _ in panels}, "set point i",
                      "E_i (mm)", "experiment 6: E_i along the line; dotted, each run's E_av in its "
                      f"colour\n{_setup(base)}, unless labelled",
                      out / "exp6_error.png", logy=True, marker=None,
                      hlines=[(PAPER_EXP6_E_AV_MM, f"the paper's E_av, {PAPER_EXP6_E_AV_MM:g} mm", "C7"),
                              (EXP6_FACTOR * PAPER_EXP6_E_AV_MM, f"agrees if E_av (the mean of E_i) "
                               f"<= {EXP6_FACTOR:g} x that", "C3")]
                      + [(eav, None, f"C{i}", ":") for i, (_, _, eav) in enumerate(panels)])
    res["start_tie"] = tie_experiment(gain_deg_per_mm=base.gain_deg_per_mm)  # the run's f
    return res


TABLE2_X_TIE_RULES = (3, 4)  # Table 2's q2 rules, decided by x_g against x_e


def two_link_tie(base, out=None) -> dict:
    """The two-link straight-up start (q 90, 0 deg: x_g = x_e) is a tie of Table 2's RULE 3/4,
    which the paper resolves as 'no update'. With the model's forward kinematics in floating
    point RULE 4 fires; rounded to 1e-9 mm (:class:`ExactModel`) neither does. Experiments 1 and
    4 (those whose figures move) both ways, model feedback."""
    base = replace(base, feedback="model")
    res = {}
    for label, exact in (("floating point", False), ("exact", True)):
        trace, _, cd, control, after = _jump(base, exact)
        res[label] = {"first_rules": sorted(trace.fired[0]), "jump_e_mm": float(cd[0]),
                      "forgotten_after_setpoints": int(after), "cd_setpoints": len(cd),
                      "e_av_cd_mm": float(cd.mean()), "e_av_cd_control_mm": float(control.mean()),
                      **{name: {k: v for k, v in _gain_sweep(base, name, exact).items()
                                if k in ("best_f_deg_per_mm", "good_f_range_deg_per_mm")}
                         for name in ("ellipse-t1", "ellipse-t2")}}
    return res


def _after_best(res: dict) -> str:
    """E_av at the good range's upper end and at the next f of the grid (where it rises past
    the range), as text."""
    fs, eav = res["f_deg_per_mm"], res["e_av_mm"]
    k = fs.index(res["good_f_range_deg_per_mm"][1])
    if k + 1 >= len(fs):
        return f"{eav[k]:.1f} mm at f = {fs[k]:g} (the grid's last)"
    return f"{eav[k]:.1f} mm at f = {fs[k]:g} to {eav[k + 1]:.1f} mm at f = {fs[k + 1]:g} deg/mm"


def _holes(res: dict) -> str:
    """The f inside a good range whose E_av is not good (E_av(f) is not smooth), as text."""
    holes = res["not_good_inside_range_deg_per_mm"]
    return "" if not holes else ("; not good inside it: f = " + ", ".join(f"{f:g}" for f in holes))


def _finite(v) -> bool:
    """A measured number (not None, as results.json writes nan, nor nan)."""
    return v is not None and bool(np.isfinite(v))


def _fmt(v, d=2) -> str:
    return f"{v:.{d}f}" if _finite(v) else "n/a"


def settings(base: RunConfig) -> dict:
    """The options a paper run was made with, as results.json and the manifest record them."""
    return {"feedback": base.feedback, "gain_deg_per_mm": base.gain_deg_per_mm, "seed": base.seed}


def _options(base: RunConfig) -> str:
    opts = {"--feedback": base.feedback, "--gain": base.gain_deg_per_mm, "--seed": base.seed}
    return " ".join(f"{k} {v}" for k, v in opts.items() if v is not None)


def _where(run: dict) -> str:
    """Where a run's E_max lies, for the report: the start (its first set point) or the set
    point that has it."""
    k = run["e_max_setpoint"]
    return "the start" if k == 0 else f"at set point {k} of {run['n_setpoints']}"


def report(r: dict, base: RunConfig) -> str:
    e1, e2, e3, e4, e5, e6 = (r[k] for k in ("exp1", "exp2", "exp3", "exp4", "exp5", "exp6"))
    t1, t2 = e4["ellipse-t1"], e4["ellipse-t2"]
    asis, lim = (e6[label] for label, _ in EXP6_RUNS)
    pf = e4["paper_f_as_rad_per_mm_e_av_t1_mm"]
    L = [
        "# The paper's experiments, reproduced",
        "",
        f"Command: `python -m itg_vision.paper --out DIR {_options(base)}` (feedback `{base.feedback}`, gain f = {base.gain_deg_per_mm} deg/mm "
        f"unless swept, {base.iterations} iteration per set point, no servo limit, start fully extended, "
        "two-link 100/100 mm, three-link 100/100/100 mm). All numbers below were measured by this run; each "
        "verdict is computed from the threshold written beside it.",
        "",
        "**Units of f.** The paper gives f = 0.001 without units. Two readings: (a) rad/mm, i.e. "
        f"{PAPER_F_AS_DEG_PER_MM:.4f} deg/mm, with one iteration per set point E_av on T1 is "
        f"{_fmt(pf['1'], 1)} mm; with the few iterations per set point of its section 3.2(i), 10 and 20 "
        f"iterations give {_fmt(pf['10'], 1)} and {_fmt(pf['20'], 1)} mm; (b) deg/mm with one iteration, "
        f"tuned: the measured optimum is near {t1['best_f_deg_per_mm']:.2f} deg/mm, and past its "
        f"good range E_av on T1 rises from {_after_best(t1)}. We use f in deg/mm, default "
        f"{PARAM_DEFAULTS['f']:g}.",
        "",
        "| exp. | the paper's claim | measured here | threshold (ours) | verdict |",
        "| --- | --- | --- | --- | --- |",
    ]
    fa = e1["forgotten_after_setpoints"]
    v1 = jump_verdict(fa)
    # never within 0.1 mm of the control for 10 set points in a row on C-D: said so, not 'from set point N on'
    never1 = fa >= e1.get("cd_setpoints", fa + 1)
    L.append(
        f"| 1 | the sudden 100 mm jump B-C does not affect tracking quality (Fig. 4.1) | corners A{tuple(e1['corners_mm'][0])}, "
        f"B{tuple(e1['corners_mm'][1])}, C{tuple(e1['corners_mm'][2])}, D{tuple(e1['corners_mm'][3])} mm are our choice (the paper "
        f"gives only the 100 mm jump). E_i right after the jump {e1['jump_e_mm']:.1f} mm; "
        + (f"E_i is never within 0.1 mm of a control run that crosses B-C with 100 set points (not on C-D's {fa} set "
           "points)" if never1 else
           f"from set point {fa} of C-D on, E_i is within 0.1 mm of a control run that crosses B-C with 100 set points "
           f"(E_av there {_fmt(e1['e_av_cd_after_mm'])} vs {_fmt(e1['e_av_cd_control_after_mm'])} mm)")
        + f"; E_av on all of C-D {e1['e_av_cd_mm']:.2f} vs {e1['e_av_cd_control_mm']:.2f} mm | "
        f"agrees if the jump is forgotten within {JUMP_FORGOTTEN_AGREE} set points, partly within {JUMP_FORGOTTEN_PARTLY} | "
        f"{v1}: " + (f"never forgotten on C-D's {fa} set points" if never1 else f"a transient of {fa} set points")
        + f" (at the paper's f, read as rad/mm, as the paper runs it: "
        f"{jump_verdict(e1['at_papers_f']['1']['forgotten_after_setpoints'])}; below) |")
    def v2_of(e_av, e_max):
        return verdict(e_av <= FOLLOWS_CLOSELY_MM and e_max <= ACCEPTABLE_MM, e_av <= FOLLOWS_CLOSELY_MM)

    v2 = v2_of(e2["e_av_after_settling_mm"], e2["e_max_after_settling_mm"])
    v2p = v2_of(e2["papers_lap_e_av_after_settling_mm"], e2["papers_lap_e_max_after_settling_mm"])
    k2 = e2["e_max_setpoint"]
    L.append(
        f"| 2 | the ITG closely follows the nonlinear ellipse T1 (Fig. 4.2), no number given | E_av {e2['e_av_mm']:.2f} mm over the "
        f"180 points of the paper's lap (E_max {e2['e_max_mm']:.1f} mm, at set point {k2}"
        f"{', before settling' if k2 < e2['settled_at'] else ''}); second lap E_av "
        f"{e2['second_lap_e_av_mm']:.2f} mm, E_max {e2['second_lap_e_max_mm']:.1f} mm; settled (E_i below 10 mm for 10 set points in a row) "
        + (f"from set point {e2['settled_at']} to the end of lap 2: E_av {e2['e_av_after_settling_mm']:.2f} mm, "
           f"E_max {e2['e_max_after_settling_mm']:.1f} mm" if _finite(e2['e_av_after_settling_mm']) else
           f"never in its {e2['settled_at']} set points: no settled part")
        + f" | agrees if settled "
        f"E_av <= {FOLLOWS_CLOSELY_MM:g} mm and settled E_max <= {ACCEPTABLE_MM:g} mm; partly if only the E_av holds | "
        f"{v2} (the paper's lap alone, settled from the same set point: E_av "
        f"{_fmt(e2['papers_lap_e_av_after_settling_mm'])} mm, E_max {_fmt(e2['papers_lap_e_max_after_settling_mm'], 1)} "
        f"mm, {v2p}) |")
    slopes = {f: v["loglog_slope"] for f, v in e3["by_gain_deg_per_mm"].items()}
    ok3 = {f: SLOPE_RANGE[0] <= s <= SLOPE_RANGE[1] for f, s in slopes.items()}
    v3 = "; ".join(f"f = {f}: {verdict(ok)}" for f, ok in ok3.items())
    L.append(
        "| 3 | E_av is inversely proportional to n_t (Fig. 4.3) | log-log slope over n_t = 100..1000 (+- its standard "
        "error, the fit's scatter): "
        + ", ".join(f"{s:.2f} +- {e3['by_gain_deg_per_mm'][f]['loglog_slope_se']:.2f} at f = {f} deg/mm"
                    for f, s in slopes.items())
        + f" | slope in [{SLOPE_RANGE[0]}, {SLOPE_RANGE[1]}], per f | "
        + v3 + (": it holds for every f" if all(ok3.values()) else
                ": it holds for some gains only" if any(ok3.values()) else ": for no f") + " |")
    g1, g2 = t1["good_f_range_deg_per_mm"], t2["good_f_range_deg_per_mm"]
    v4 = verdict(_overlap(g1, g2))
    L.append(
        f"| 4 | the best range of f is the same for T1 and T2 (Fig. 4.4) | best f: T1 {t1['best_f_deg_per_mm']:.3f}, T2 "
        f"{t2['best_f_deg_per_mm']:.3f} deg/mm; good f [{g1[0]:.3f}, {g1[1]:.3f}] (T1{_holes(t1)}), "
        f"[{g2[0]:.3f}, {g2[1]:.3f}] (T2{_holes(t2)}); the grid: {len(t1['f_deg_per_mm'])} values of f, "
        f"log-spaced from 0.02 to 1.2 and {EXP4_FINE_STEP:g} deg/mm apart from 0.3 to 1 | good f: E_av within {GOOD_F_FACTOR}x of the "
        f"minimum; agrees if the two ranges overlap | {v4} |")
    # experiment 5
    firsts = ", ".join(f"{v['first_lap_max_at_deg']:.0f} (set point {v['first_lap_max_setpoint']}"
                       + (", before settling)" if v["first_lap_max_setpoint"] < v["first_lap_settled_at"]
                          else ")") for v in e5.values())
    settled1 = [v["first_lap_settled_max_at_deg"] for v in e5.values()]
    firsts_settled = ", ".join("never settles" if a is None else
                               f"{a:.0f} deg ({v['first_lap_settled_max_e_mm']:.0f} mm)"
                               for a, v in zip(settled1, e5.values()))
    v5a_p = "n/a: a lap never settles" if None in settled1 else verdict(_at_ends(settled1))
    peaks = "; ".join(f"n_t={n}: " + ", ".join(f"{m:.0f} mm at {a:.0f} deg (y_d {round(y)} mm)" for a, m, y in
                                              zip(v["second_lap_peaks_deg"], v["second_lap_peak_e_mm"],
                                                  v["second_lap_peak_yd_mm"]))
                      for n, v in e5.items())
    at_ends = _at_ends(v["second_lap_peaks_deg"][0] for v in e5.values())
    # the verdict under the two other readings of "radial angle", computed the same way
    other = {about: (", ".join(f"{v[f'second_lap_peaks_about_{about}_deg'][0]:.0f}" for v in e5.values()),
                     verdict(_at_ends(v[f"second_lap_peaks_about_{about}_deg"][0] for v in e5.values())))
             for about in ("centre", "base")}
    readings = (" Read as the polar angle of the set point instead (other readings of 'radial angle'), "
                "the largest peak (n_t " + "/".join(map(str, e5)) + ") lies at "
                + "; ".join(f"{a} deg about the {'ellipse' if k == 'centre' else 'base'}"
                            f"{chr(39)}s {'centre' if k == 'centre' else 'axis'} ({v} under that reading)"
                            for k, (a, v) in other.items()) + "; the verdict keeps the parameter "
                "angle, the reading of the paper's explanation (the path's largest curvature, at "
                "parameter angles 0 and 180 on an ellipse).")
    emax = {n: v["second_lap_e_max_mm"] for n, v in e5.items()}
    acceptable = all(m <= ACCEPTABLE_MM for m in emax.values())
    v5a, v5b = verdict(at_ends), verdict(acceptable)
    L.append(
        f"| 5a | the largest deviation is at radial angles 0, 180, 360 deg (Fig. 4.5) | first lap (from the start pose, as the "
        f"paper): largest at {firsts} deg; from where it settles (E_i below {ACCEPTABLE_MM:g} mm for 10 set points), largest "
        f"at {firsts_settled}. Settled second lap, the three largest peaks, the largest first: {peaks}.{readings} | the "
        f"settled lap's largest peak within {PEAK_ANGLE_TOL_DEG:g} deg of 0, 180 or 360 for every n_t | {v5a} (the paper's "
        f"lap alone, from where it settles: {v5a_p}) |")
    L.append(
        "| 5b | the deviation remains within acceptable limits even for small n_t | settled-lap E_max "
        + ", ".join(f"{m:.0f} mm (n_t {n})" for n, m in emax.items())
        + "; settled-lap E_av " + ", ".join(f"{v['second_lap_e_av_mm']:.1f}" for v in e5.values())
        + f" mm | acceptable: settled-lap E_max <= {ACCEPTABLE_MM:g} mm (5 % of the 200 mm reach) | "
        f"{v5b} |")
    # experiment 6, judged on the paper's own line and setup (one iteration, no servo limit);
    # the reachable variant's runs each judged by the same E_av threshold
    n_oor = e6["line-ab"]["n_out_of_reach"]
    limit6 = EXP6_FACTOR * PAPER_EXP6_E_AV_MM
    v6 = verdict(n_oor == 0 and e6["line-ab"]["e_av_mm"] <= limit6) + (
        f" as given: {n_oor} of {e6['line-ab']['n_setpoints']} set points out of reach" if n_oor else "")
    posts = e6.get("line-ab, LEDs on their posts")
    L.append(
        f"| 6 | line A(50, 30, 220) to B(250, 200, 400), 100 points, average error about {PAPER_EXP6_E_AV_MM} mm | tracked: "
        f"{_where_tracked(base)}. The paper's line: "
        f"{n_oor} of {e6['line-ab']['n_setpoints']} set points out of reach (B is 439 mm from the shoulder, z = 400 mm above "
        f"the 300 mm the arm reaches; RULE 0 flags {e6['line-ab']['n_flagged']}), E_av {e6['line-ab']['e_av_mm']:.1f} mm over "
        f"the {e6['line-ab']['n_setpoints'] - n_oor} in reach"
        + (f" ({posts['e_av_mm']:.1f} mm with the LEDs on their 12 mm posts, where the cameras see them)" if posts else "")
        + f". Reachable variant (`line-ab-reach`): as the paper, E_av {asis['e_av_mm']:.1f} mm "
        f"({verdict(asis['e_av_mm'] <= limit6)}); not the paper's setup, with a 2 deg/iteration servo limit and 5 "
        f"iterations, E_av {lim['e_av_mm']:.2f} mm ({verdict(lim['e_av_mm'] <= limit6)}; E_max {lim['e_max_mm']:.0f} mm, "
        f"{_where(lim)}; {lim['e_av_second_half_mm']:.2f} mm on the second half) | agrees if "
        f"every point of the paper's line is in reach and its E_av (as the paper: one iteration, no servo limit) <= "
        f"{EXP6_FACTOR:g} x {PAPER_EXP6_E_AV_MM} mm; each variant's run by its E_av alone | {v6} |")
    L += ["", "## Experiment 1 at the paper's f", "",
          f"The paper states f for experiment 1 only: 0.001, no unit. Read as rad/mm ({PAPER_F_AS_DEG_PER_MM:.4f} "
          "deg/mm), with one iteration per set point as the paper runs it, and with the few iterations of its "
          "section 3.2(i); the same corners, control and thresholds as the table's row 1:", "",
          "| iterations per set point | E_i right after the jump (mm) | forgotten after (set points) | E_av on C-D, "
          "with the jump / control (mm) | verdict |", "| --- | --- | --- | --- | --- |"]
    for k, row in e1["at_papers_f"].items():
        fk = row["forgotten_after_setpoints"]
        never = f"never (C-D's {row['cd_setpoints']})" if fk >= row["cd_setpoints"] else fk
        L.append(f"| {k} | {row['jump_e_mm']:.1f} | {never} | {row['e_av_cd_mm']:.2f} / "
                 f"{row['e_av_cd_control_mm']:.2f} | {jump_verdict(fk)} |")
    L += ["", "## Readings of the paper", "",
          "- Rules: at each iteration every joint takes the first of its own rules whose condition holds (one q1 "
          "rule and one q2 rule), where the paper says \"only one rule will be matched at each time\": with one "
          "rule for both joints, one joint would never move (`data/rules/table2.rules`).",
          "- RULE 0 tests the desired point, not the gripper: the paper's literal strict test flags the fully "
          "extended start (r = 200 mm).",
          "- Three-link: the paper's equations put the gripper and the elbow in the arm's vertical plane; "
          "model and truth feedback track those points here, vision the LEDs on their 12 mm posts.",
          "- The paper's text, read as its figures show: experiment 1 cites Fig. 4.3 for the jump (its Fig. "
          "4.1), experiment 3 uses \"the same path used in experiment 3\" (experiment 2's T1), and Fig. 4.5's "
          "caption reads \"Fig. 7.5\".", ""]
    L += ["## Experiment 5: where the settled lap flails, and why", ""]
    # a cause is confirmed when changing it removes the flails (every settled-lap E_max at most
    # FLAIL_MM, the height that defines a flail), refuted when a flail is left at some n_t
    yg = {n: v["variants"]["sign of y_g instead of y_d"]["second_lap_e_max_mm"] for n, v in e5.items()}
    removed_yg = all(m <= FLAIL_MM for m in yg.values())
    L.append(
        "A first explanation (ours, earlier) blamed Table 2's choice of q1's direction from the sign of y_d instead of "
        "y_g. Changed to y_g (`data/rules/table2-sign-of-yg.rules`), the settled lap's E_max is "
        + ", ".join(f"{m:.0f}" for m in yg.values())
        + " mm against " + ", ".join(f"{m:.0f}" for m in emax.values()) + " mm (n_t "
        + ", ".join(str(n) for n in e5) + f"); the cause is confirmed if every one is at most "
        f"{FLAIL_MM:g} mm (no flail left), refuted otherwise: "
        + ("confirmed." if removed_yg else "refuted."))
    L.append("")
    onsets = sum(v["flail_onsets"] for v in e5.values())
    from_inv = sum(v["flail_onsets_from_inverted_pose"] for v in e5.values())
    share = np.mean([v["inverted_share_of_settled_lap"] for v in e5.values()])
    swap = {n: v["variants"]["pairing swapped where both levers are inverted"] for n, v in e5.items()}
    L.append(
        "The measured mechanism: Table 2 pairs q1 with the x error and q2 with the y error. q1 moves the gripper along "
        "(-y_g, x_g), mostly in y once |x_g| > |y_g|; q2 moves it along (-(y_g - y_e), x_g - x_e), mostly in x once the "
        "forearm is nearer vertical than horizontal. Where both hold (near the x axis with the forearm steep), each rule's "
        "|error|-proportional step pushes the other coordinate, and the error runs away. Measured: of the "
        f"{onsets} flail onsets on the settled laps (E_i crossing {FLAIL_MM:g} mm), {from_inv} start from such an inverted "
        f"pose, which covers {100 * share:.0f} % of the settled laps' set points. Changing that cause, with the pairing "
        "swapped in exactly those poses (`data/rules/table2-pairing-swap.rules`): settled-lap E_max "
        + ", ".join(f"{s['second_lap_e_max_mm']:.1f}" for s in swap.values())
        + " mm (E_av " + ", ".join(f"{s['second_lap_e_av_mm']:.2f}" for s in swap.values())
        + " mm) for n_t " + ", ".join(str(n) for n in swap) + f"; confirmed if every E_max is at most "
        f"{FLAIL_MM:g} mm (no flail left): "
        + ("confirmed." if all(s["second_lap_e_max_mm"] <= FLAIL_MM for s in swap.values())
           else "not confirmed."))
    L += ["", "## Experiment 6: the three-link composition's straight-up tie", ""]
    tie = e6["start_tie"]
    L.append(
        "At the paper's straight-up start the gripper and elbow LEDs are equally far from the base axis (rg2 == re2: both "
        "carry only the 12 mm stand-off), so Table 2's elbow rules (RULES 6/7 of `three-link.rules`) face a tie, which the "
        "paper resolves as 'no update'. Any measurement error decides it. Deciding it on purpose, with ideal LED "
        f"positions and the elbow moved {TIE_BIAS_MM} mm outwards (+) or inwards (-), 2 deg/iteration, 5 iterations:")
    L += ["", "| links (mm) | elbow bias (mm) | rg2 - re2 at the start (mm^2) | first q3 rule | tracking median / mean / p95 / max (mm) |",
          "| --- | --- | --- | --- | --- |"]
    for row in tie:
        L.append(f"| {'/'.join(f'{v:g}' for v in row['links_mm'])} | {row['elbow_bias_mm']:+g} | "
                 f"{row['rg2_minus_re2_mm2']:+.2f} | {row['first_q3_rule']} | "
                 + " / ".join(_fmt(row[k]) for k in ("track_median_mm", "track_mean_mm",
                                                      "track_p95_mm", "track_max_mm")) + " |")
    L += ["", "The sign of rg2 - re2 at the start, not the link lengths, decides whether the arm tracks or diverges. "
          "How often noise decides it badly: `python -m itg_vision.bench noise --sweep start-tie` (40 seeds per cell).", ""]
    L += ["## Experiments 1 and 4: the two-link arm's straight-up tie", "",
          "The two-link arm starts straight up too (q 90, 0 deg), where x_g = x_e: a tie of Table 2's RULE 3/4 (q2), which "
          "the paper resolves as 'no update'. With the model's forward kinematics in floating point, cos 90 deg = 6e-17 puts "
          "the gripper 6e-15 mm right of the elbow, and RULE 4 fires at the first set point; "
          + ("the table above is that run. " if base.feedback == "model" else
             f"the table above is not that run but the {base.feedback}-fed one, whose first look decides the tie. ")
          + "With the model rounded to 1e-9 mm the tie is exact (model feedback both ways; the same thresholds):", "",
          "| start tie | rules at the first set point | exp. 1: E_i after the jump (mm) | forgotten after (set points) | "
          "exp. 1 verdict | exp. 4: best f T1 / T2 (deg/mm) | good ranges | exp. 4 verdict |",
          "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for label, row in r["two_link_tie"].items():
        fa_t = row["forgotten_after_setpoints"]
        r1, r2 = (row[n]["good_f_range_deg_per_mm"] for n in ("ellipse-t1", "ellipse-t2"))
        never = f"never (C-D's {row['cd_setpoints']})" if fa_t >= row["cd_setpoints"] else fa_t
        L.append(f"| {label} | {', '.join(map(str, row['first_rules']))} | {row['jump_e_mm']:.1f} | {never} | "
                 f"{jump_verdict(fa_t)} | "
                 f"{row['ellipse-t1']['best_f_deg_per_mm']:.2f} / {row['ellipse-t2']['best_f_deg_per_mm']:.2f} | "
                 f"{r1[0]:.2f}-{r1[1]:.2f} / {r2[0]:.2f}-{r2[1]:.2f} | {verdict(_overlap(r1, r2))} |")
    v1_tie = {label: jump_verdict(row["forgotten_after_setpoints"])
              for label, row in r["two_link_tie"].items()}
    L += ["", "The tie alone turns experiment 1's verdict: "
          + ", ".join(f"{v} ({k})" for k, v in v1_tie.items()) + "."
          if len(set(v1_tie.values())) > 1 else "The tie does not turn experiment 1's verdict.", ""]
    L += ["## The figures, each beside the paper's claim", "",
          "Each verdict is the table's, computed from the threshold beside it there; the figures draw "
          "those thresholds where they are lines or bands.", ""]
    for title, v, figs in (
            ("1. The jump B-C does not affect tracking quality (Fig. 4.1)", v1,
             (("exp1_path.png", "Experiment 1 (Fig. 4.1)"), ("exp1_error.png", "Experiment 1: E_i along C-D"))),
            ("2. The ITG closely follows the ellipse T1 (Fig. 4.2)", v2,
             (("exp2_path.png", "Experiment 2 (Fig. 4.2)"),
              ("exp2_error.png", "Experiment 2: E_i, the settling and its thresholds"))),
            ("3. E_av is inversely proportional to n_t (Fig. 4.3)", v3,
             (("exp3_eav_vs_nt.png", "Experiment 3 (Fig. 4.3)"),)),
            ("4. The best range of f is the same for T1 and T2 (Fig. 4.4)", v4,
             (("exp4_eav_vs_f.png", "Experiment 4 (Fig. 4.4)"),)),
            ("5. The largest deviation is at 0, 180, 360 deg, and stays acceptable (Fig. 4.5)",
             f"5a {v5a}, 5b {v5b}", (("exp5_first_lap.png", "Experiment 5 (Fig. 4.5), first lap"),
                                    ("exp5_second_lap.png", "Experiment 5, second lap (settled)"))),
            (f"6. The three-link line A-B, average error about {PAPER_EXP6_E_AV_MM} mm", v6,
             (("exp6_line_ab.png", "Experiment 6, the paper's line"),
              ("exp6_path_paper.png", "Experiment 6, reachable variant, as the paper"),
              ("exp6_path_limited.png", "Experiment 6, reachable variant, servo limit"),
              ("exp6_error.png", "Experiment 6: E_i on the paper's line and the reachable variant, each run's E_av, the paper's 0.4 mm")))):
        L += [f"### {title}: {v}", "", *(f"![{cap}]({name})" for name, cap in figs), ""]
    return "\n".join(L)


def main(argv: list[str] | None = None) -> int:
    def body() -> int:
        from .errors import ArgumentParser, ConfigError  # one-line option errors

        ap: argparse.ArgumentParser = ArgumentParser(prog="python -m itg_vision.paper", description=__doc__.split("\n\n")[0])
        ap.add_argument("--out", default="paper-out",
                        help="output folder (default %(default)s); replaced only if this command "
                             "made it and it holds nothing else")
        ap.add_argument("--force", action="store_true",
                        help="write --out even if it is a folder this command did not make (that "
                             "folder is kept beside it as OUT.replaced-N)")
        ap.add_argument("--feedback", default="model", choices=("model", "truth", "vision"),
                        help="feedback of every run (default: model, the paper's setup)")
        ap.add_argument("--gain", type=float, default=PARAM_DEFAULTS["f"],
                        help="f in deg/mm (default %(default)s)")
        ap.add_argument("--seed", type=int, default=0,
                        help="seed of the vision feedback's sensor noise, a whole number >= 0 "
                             "(default 0; model and truth feedback draw nothing)")
        ap.add_argument("--quiet", action="store_true",
                        help="print nothing but errors (report.md, results.json and the figures "
                             "are written to --out all the same)")
        args = ap.parse_args(argv)
        base = RunConfig(feedback=args.feedback, gain_deg_per_mm=args.gain, seed=args.seed)
        try:
            base.validate()
        except ConfigError as exc:
            raise exc.as_option({"gain_deg_per_mm": "--gain", "seed": "--seed"}) from None
        results = {"settings": settings(base)}
        with outputs.staged_dir(args.out, "paper", force=args.force,
                                key=results["settings"]) as tmp:  # text: "" is an error
            for name, fn in (("exp1", exp1), ("exp2", exp2), ("exp3", exp3), ("exp4", exp4),
                             ("exp5", exp5), ("exp6", exp6), ("two_link_tie", two_link_tie)):
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
    sys.exit(exit_status(main()))
