"""python -m itg_vision.bench speed: the cost of one decision, rules against inverse kinematics.

The paper claims its rules are cheaper than trigonometry and matrix inversion. Measured here in
one run, same set points: one compiled Table 2 rule step (and ITG+'s), each at the states its
rule base reaches tracking those set points, the closed-form two-link inverse kinematics, one
call of PyBullet's ``calculateInverseKinematics`` from the previous set point's solution (with
how near its set point it lands); then the stereo loop at 640x480 with
windows around the LEDs at supersampling 1-4 beside whole frames, on the same states, with the
issue-11 targets beside the measured values.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from ..arm import ArmSpec, forward_kinematics
from ..camera import Rig, default_rig_path
from ..controllers import two_link_ik
from ..errors import ArgumentParser, UserError, at_least_one, exit_status, run_main
from ..feedback import DEFAULT_SUPERSAMPLE, VisionFeedback
from ..rules import RuleBase, load_rules
from .. import native, outputs, trajectory as traj
from ..world import IK_JOINT_DAMPING, World

import pybullet  # noqa: E402 (after world, which imports it without its build-time banner)


def _per_call_us(methods: dict, repeat: int) -> dict:
    """Median over ``repeat`` passes of the mean time per call (microseconds) of each method
    (name -> (function, argument tuples)), and beside it the mean over the passes
    (``<name>_mean``) and the slowest pass's (``<name>_max``); ``passes_us``: each method's time
    per call in each pass, for ratios pass by pass. The passes interleave the methods, so a slow
    patch of the machine falls on all of them alike and their ratios hold."""
    times: dict = {name: [] for name in methods}
    for _ in range(repeat):
        for name, (fn, args_list) in methods.items():
            t0 = time.perf_counter()
            for a in args_list:
                fn(*a)
            times[name].append((time.perf_counter() - t0) / len(args_list))
    out = {name: float(np.median(t) * 1e6) for name, t in times.items()}
    return (out | {f"{name}_mean": float(np.mean(t) * 1e6) for name, t in times.items()}
            | {f"{name}_max": float(np.max(t) * 1e6) for name, t in times.items()}
            | {"passes_us": {name: [x * 1e6 for x in t] for name, t in times.items()}})


#: Interleaved passes of the decision timings (``--passes`` is the stereo loop's).
DECISION_PASSES = 7
#: The decisions' trajectory and its set points.
DECISION_PATH, DECISION_POINTS = "ellipse-t1", 720
#: The stereo loop's default sample: states of the replay per pass, and passes.
DEFAULT_FRAMES, DEFAULT_PASSES = 40, 3


class _Recording:
    """A controller that records what each decision is given (the set point, the markers, the
    joint angles the loop passes it: None for rules that read none) and the arm's joint
    angles then, and decides as ``controller`` does."""

    def __init__(self, controller, world):
        self.controller, self.world, self.seen = controller, world, []
        self.uses_encoders = controller.uses_encoders

    def params(self) -> dict:
        return self.controller.params()

    def step(self, desired_mm, markers, q_deg):
        self.seen.append((np.array(desired_mm, float), markers,
                          None if q_deg is None else np.array(q_deg, float),
                          self.world.q_deg.copy()))
        return self.controller.step(desired_mm, markers, q_deg)


def decision_states(arm, rules, points_mm, max_step_deg: float | None) -> list[tuple]:
    """What ``rules`` is given at each decision while tracking ``points_mm`` with ``arm``
    (``itg_vision.loop.simulate``: ideal feedback, one iteration per set point, joints clipped
    to ``max_step_deg`` per iteration; None: no limit): per decision (set point (3,), markers,
    the joint angles given to the rules or None, the arm's joint angles (deg))."""
    from ..feedback import TruthFeedback
    from ..loop import simulate

    with World(arm) as world:
        rec = _Recording(rules, world)
        simulate(world, rec, TruthFeedback(), points_mm, max_step_deg=max_step_deg)
    return rec.seen


def _from_set_point_mm(states) -> np.ndarray:
    """Distance (x-y, mm) of each state's gripper from its set point."""
    return np.array([np.linalg.norm((m.gripper_mm - p)[:2]) for p, m, _, _ in states])


def decision_costs(n_points: int = DECISION_POINTS, repeat: int = DECISION_PASSES) -> dict:
    """Microseconds per decision of the two-link arm on ellipse T1's ``n_points`` set points:
    each rule base at the states it reaches tracking them (:func:`decision_states` under the
    arm file's benchmark servo limit), the inverse kinematics at the same set points."""
    arm = ArmSpec.from_args("two-link")
    servo = float(arm.benchmark["max_step_deg"])
    rb = load_rules("table2", 2, arm.links_mm, f=0.5)
    plus = load_rules(arm.defaults["itg_plus_rules"], 2, arm.links_mm, S=servo, w=0.5)
    pts = traj.named(DECISION_PATH, n_points).points_mm
    seen = {"table2": decision_states(arm, rb, pts, servo),
            "itg_plus": decision_states(arm, plus, pts, servo)}
    rule_args = [a[:3] for a in seen["table2"]]
    plus_step = [a[:3] for a in seen["itg_plus"]]
    # the compiled function alone (what a microcontroller port would run) and RuleBase.step
    raw_args = [rb.arguments(*a) for a in rule_args]
    plus_args = [plus.arguments(*a) for a in plus_step]
    ik_args = [(float(p[0]), float(p[1]), 100.0, 100.0) for p in pts]
    methods = {"rules_compiled_us": (rb.compiled, raw_args),
               "rules_step_us": (rb.step, rule_args),
               "itg_plus_compiled_us": (plus.compiled, plus_args),
               "itg_plus_arguments_us": (plus.arguments, plus_step),
               "ik_closed_form_us": (two_link_ik, ik_args)}
    try:  # the same rule bases compiled to C, called from Python with the same arguments
        nothing = RuleBase.from_text("RULE 1: IF 1 > 0 THEN q1 HOLD, q2 HOLD", 2, arm.links_mm)
        rules_c, plus_c, call_c = native.build([rb, plus, nothing])
        methods |= {"rules_native_us": (rules_c, raw_args), "itg_plus_native_us": (plus_c, plus_args),
                    "call_native_us": (call_c, plus_args)}
        native_error = None
    except native.NativeUnavailable as exc:
        native_error = str(exc)
    # PyBullet's IK as a tracking loop would call it: from the previous set point's solution,
    # through World (its mm and deg converted), and the call alone with them converted before
    goals = [tuple(arm.gripper_led_mm(p)) for p in pts]
    solved = [np.array(two_link_ik(p[0], p[1], *arm.links_mm)[0]) for p in pts]
    ik_from_previous = [(g, "gripper", q) for g, q in zip(goals, solved[-1:] + solved[:-1])]
    with World(arm) as world:
        methods["ik_pybullet_us"] = (world.inverse_kinematics, ik_from_previous)
        methods["ik_pybullet_call_us"] = (lambda args, kw: pybullet.calculateInverseKinematics(*args, **kw),
                                          [world.ik_arguments(*a) for a in ik_from_previous])
        out = _per_call_us(methods, repeat)
        landed = [forward_kinematics(arm, world.inverse_kinematics(*a))["gripper"]
                  for a in ik_from_previous]
    miss = np.linalg.norm(np.array(landed) - np.array(goals), axis=1)
    return out | {"native_error": native_error, "ik_pybullet_miss_mm": miss,
                  "max_step_deg": servo, "states": seen,
                  "from_set_point_mm": {k: _from_set_point_mm(v) for k, v in seen.items()}}


#: Vision settings timed side by side: (label, supersample, full_frame): windows at 1-4,
#: whole frames at 1 (the loop before windows) and at the default.
SETTINGS = (("windows s=1", 1, False), ("windows s=2", 2, False), ("windows s=3", 3, False),
            ("windows s=4", 4, False), ("full frame s=1", 1, True),
            (f"full frame s={DEFAULT_SUPERSAMPLE}", DEFAULT_SUPERSAMPLE, True))
#: The replay the vision settings are timed on, and the set points it settles for first.
REPLAY, SETTLE = "ellipse-t1", 20
#: The issue's targets (stereo loop at 640x480, one core).
TARGET_DEFAULT_HZ, TARGET_RATIO, TARGET_FASTEST_HZ, TARGET_DET_TRI_MS = 300.0, 10.0, 500.0, 0.5
#: Issue 13: a compiled ITG+ step at least this many times cheaper than PyBullet's IK.
SPEED_FACTOR = 50.0
#: The name --out's manifest gives this benchmark (what it may replace).
COMMAND = "bench speed"


def itg_plus_step(costs: dict) -> tuple[str, str]:
    """(the key of the compiled ITG+ step's time in ``costs``, what it was compiled to): the
    step compiled to C, or compiled to Python where no C compiler could build it."""
    if costs.get("itg_plus_native_us") is None:
        return "itg_plus_compiled_us", "Python"
    return "itg_plus_native_us", "C"


def itg_plus_speed(costs: dict) -> tuple[float, str]:
    """(PyBullet IK's time over the compiled ITG+ step's, which compiled step):
    :func:`itg_plus_step`'s."""
    key, compiled = itg_plus_step(costs)
    return costs["ik_pybullet_us"] / costs[key], compiled


def replay_states(arm, rules, points_mm, settle: int, frames: int) -> list:
    """(joint angles, set point) of the two-link arm tracking ``points_mm`` with the rules
    under ideal feedback, after ``settle`` set points: the same states for every setting."""
    seen = decision_states(arm, rules, points_mm[:settle + frames], None)
    return [(q, p) for p, _, _, q in seen[settle:]]


def vision_costs(settings=SETTINGS, frames: int = DEFAULT_FRAMES, settle: int = SETTLE,
                 passes: int = DEFAULT_PASSES) -> list[dict]:
    """CPU milliseconds per iteration of the stereo loop (640x480, two LEDs, two cameras,
    the rig's distortion and sensor noise, one OpenCV thread) for each setting, measured
    side by side: at every state of the replay each setting observes in turn (so a busy
    machine slows them alike), ``passes`` times over the states.

    One iteration = move the arm to the state, observe (capture, detect, triangulate), one
    rule step; CPU time of this thread (``time.thread_time``: the one core it runs on), and
    wall time beside it.
    """
    from ..imaging import opencv_threads

    arm = ArmSpec.from_args("two-link")
    rig = Rig.from_yaml(default_rig_path(arm.name))
    rules = load_rules("table2", 2, arm.links_mm, f=0.5)
    pts = traj.named(REPLAY).points_mm  # the paper's 180 points: ~2 mm per step
    states = replay_states(arm, rules, pts, settle, frames)
    fbs = [VisionFeedback(rig, rig, arm, supersample=s, full_frame=full)
           for _, s, full in settings]
    stage = [{"loop": [], "wall": [], "render": [], "detect": [], "triangulate": [],
              "missed": 0} for _ in settings]
    with World(arm) as world, opencv_threads(1):
        for fb in fbs:
            fb.reset(0)
            world.set_q(states[0][0])
            fb.observe(world)  # caches (remap tables, projection matrices) made untimed
        for _ in range(passes):
            for q, p in states:
                for fb, st in zip(fbs, stage):
                    c0, w0 = time.thread_time(), time.perf_counter()
                    world.set_q(q)
                    est = fb.observe(world)
                    rules.step(p, est, world.q_deg)
                    st["loop"].append(1e3 * (time.thread_time() - c0))
                    st["wall"].append(1e3 * (time.perf_counter() - w0))
                    for k in ("render", "detect", "triangulate"):
                        st[k].append(est.timing_ms[k])
                    st["missed"] += len(est.missed)
    rows = []
    for (label, s, full), st in zip(settings, stage):
        med = {k: float(np.median(v)) for k, v in st.items() if k != "missed"}
        rows.append({"setting": label, "supersample": s, "full_frame": full,
                     **{f"{k}_ms": v for k, v in med.items()},
                     "det_tri_ms": float(np.median(np.add(st["detect"], st["triangulate"]))),
                     "loop_mean_ms": float(np.mean(st["loop"])),
                     "loop_p95_ms": float(np.percentile(st["loop"], 95)),
                     "loop_max_ms": float(np.max(st["loop"])),
                     "loop_hz": 1e3 / med["loop"], "wall_hz": 1e3 / med["wall"],
                     "missed": st["missed"], "n": len(st["loop"])})
    return rows


def vision_report(rows: list[dict], default_supersample: int) -> list[str]:
    """The table and the issue's targets beside the measured values and ratios."""
    L = [f"{'setting':<16}{'capture':>9}{'detect':>9}{'triang.':>9}{'det+tri':>9}{'loop CPU':>10}"
         f"{'mean':>9}{'p95':>9}{'max':>9}{'Hz CPU':>8}{'Hz wall':>9}{'missed':>8}"]
    for r in rows:
        L.append(f"{r['setting']:<16}{r['render_ms']:>9.3f}{r['detect_ms']:>9.3f}"
                 f"{r['triangulate_ms']:>9.3f}{r['det_tri_ms']:>9.3f}{r['loop_ms']:>10.3f}"
                 f"{r['loop_mean_ms']:>9.3f}{r['loop_p95_ms']:>9.3f}{r['loop_max_ms']:>9.3f}"
                 f"{r['loop_hz']:>8.0f}{r['wall_hz']:>9.0f}{r['missed']:>8}")
    by = {(r["supersample"], r["full_frame"]): r for r in rows}
    d = by.get((default_supersample, False))
    full = by.get((default_supersample, True))
    full1 = by.get((1, True))
    win = [r for r in rows if not r["full_frame"]]
    if d is None or full is None or full1 is None or not win:
        return L
    fastest = max(win, key=lambda r: r["loop_hz"])
    det_tri = max(r["det_tri_ms"] for r in win)

    def verdict(ok):
        return "met" if ok else "NOT met"

    ratio = d["loop_hz"] / full["loop_hz"]
    L += ["", f"targets (one core, 640x480; default: windows s={default_supersample}):",
          f"  default loop >= {TARGET_DEFAULT_HZ:.0f} Hz: {d['loop_hz']:.0f} Hz "
          f"({verdict(d['loop_hz'] >= TARGET_DEFAULT_HZ)})",
          f"  default / full frame at the same settings ({full['setting']}) >= "
          f"{TARGET_RATIO:.0f}x: {ratio:.1f}x ({d['loop_hz']:.0f} / {full['loop_hz']:.1f} Hz; "
          f"{verdict(ratio >= TARGET_RATIO)})",
          f"  default / the former default, whole frames at s=1 ({full1['setting']}): "
          f"{d['loop_hz'] / full1['loop_hz']:.1f}x ({d['loop_hz']:.0f} / {full1['loop_hz']:.1f} Hz"
          f"; {verdict(d['loop_hz'] / full1['loop_hz'] >= TARGET_RATIO)})",
          f"  fastest honest setting >= {TARGET_FASTEST_HZ:.0f} Hz: {fastest['setting']} "
          f"{fastest['loop_hz']:.0f} Hz ({verdict(fastest['loop_hz'] >= TARGET_FASTEST_HZ)})",
          f"  detect + triangulate per stereo pair (both LEDs) < {TARGET_DET_TRI_MS} ms: "
          f"{det_tri:.3f} ms at most over the windowed settings "
          f"({verdict(det_tri < TARGET_DET_TRI_MS)})"]
    fast = [r for r in win if r["loop_hz"] >= TARGET_DEFAULT_HZ]
    if fast:
        L.append(f"  settings at >= {TARGET_DEFAULT_HZ:.0f} Hz: "
                 + ", ".join(r["setting"] for r in fast)
                 + f"; the largest supersampling among them, s={max(r['supersample'] for r in fast)},"
                 " is the most accurate (bench accuracy)")
    return L


def _tails(v) -> dict:
    """Median, mean, p95 and max of ``v``."""
    return {"median": float(np.median(v)), "mean": float(np.mean(v)),
            "p95": float(np.percentile(v, 95)), "max": float(np.max(v))}


def decision_header(c: dict) -> list[str]:
    """What the decision timings ran on: the states each rule base was timed at, and how far
    their grippers were from the set points (median / mean / p95 / max, mm)."""
    far = "; ".join(f"{name} {t['median']:.2f} / {t['mean']:.2f} / {t['p95']:.2f} / "
                    f"{t['max']:.1f}" for name, t in (
                        ("Table 2", _tails(c["from_set_point_mm"]["table2"])),
                        ("ITG+", _tails(c["from_set_point_mm"]["itg_plus"]))))
    n = len(c["ik_pybullet_miss_mm"])
    return [f"one decision, two-link arm, ellipse T1's {n} set points: each rule base timed at "
            "the states it reaches tracking them (its own replay: ideal feedback, one iteration "
            f"per set point, servo limit {c['max_step_deg']:g} deg per iteration), the inverse "
            "kinematics at the same set points (median, mean and slowest of "
            f"{DECISION_PASSES} interleaved passes; one core)",
            f"the replayed grippers' distance from their set points, median / mean / p95 / max "
            f"mm: {far} (each max is the start transient: the arm starts "
            f"{c['from_set_point_mm']['table2'][0]:.0f} mm from the first set point)"]


def build_parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="python -m itg_vision.bench speed",
                        description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-vision", action="store_true", help="skip the vision pipeline timings")
    ap.add_argument("--frames", type=at_least_one, metavar="N",
                    help=f"stereo loop: states of the replay per pass, at most {max_frames()} "
                         f"(default {DEFAULT_FRAMES})")
    ap.add_argument("--passes", type=at_least_one, metavar="N",
                    help=f"stereo loop: passes over the states, settings interleaved (default "
                         f"{DEFAULT_PASSES}; the decision timings always take {DECISION_PASSES})")
    ap.add_argument("--out", metavar="DIR",
                    help="also save what is printed (report.txt) and its numbers (results.json) "
                         "as this folder; it replaces only a folder this benchmark made")
    ap.add_argument("--force", action="store_true",
                    help="let --out replace a folder this benchmark did not make (kept beside it "
                         "as OUT.replaced-N)")
    return ap


def machine_line() -> str:
    """What the timings ran on: CPU, cores, the load beside this run, Python, the C compiler."""
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in
                   Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    try:
        cc = native.compiler_version() or "version unknown"
    except native.NativeUnavailable:
        cc = "none"
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"
    return (f"machine: {cpu}, {os.cpu_count()} cores, load average {load} (1, 5, 15 min); "
            f"Python {platform.python_version()}; C compiler {cc}")


def max_frames(settle: int = SETTLE) -> int:
    """Most states the replay gives: the points of ellipse T1 after its ``settle``."""
    return len(traj.named(REPLAY)) - settle


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)

    def body() -> int:
        args = build_parser().parse_args(argv)
        if args.no_vision:
            given = [o for o, v in (("--frames", args.frames), ("--passes", args.passes)) if v]
            if given:
                raise UserError(f"{given[0]}: applies to the stereo loop's timings, which "
                                "--no-vision skips")
        args.frames = DEFAULT_FRAMES if args.frames is None else args.frames
        args.passes = DEFAULT_PASSES if args.passes is None else args.passes
        most = max_frames()
        if args.frames > most:
            raise UserError(f"--frames: must be at most {most} (the set points of "
                            f"{REPLAY} after the first {SETTLE}), got {args.frames}")
        if args.out is not None:  # refuse a bad --out before the timings, not after
            outputs.check_out_dir(args.out, COMMAND, force=args.force)
        say = outputs.Transcript()
        machine = machine_line()
        say(machine)
        c = decision_costs()
        base = c["rules_compiled_us"]
        for line in decision_header(c):
            say(line)
        say(f"{'method':<44}{'us/step':>10}{'mean':>10}{'slowest':>10}{'x rules':>10}")
        for key, label in (("rules_compiled_us", "Table 2 rules, compiled to Python"),
                           ("rules_native_us", "Table 2 rules, compiled to C"),
                           ("rules_step_us", "Table 2 rules, RuleBase.step (with wrapping)"),
                           ("itg_plus_compiled_us", "ITG+ rules, compiled to Python"),
                           ("itg_plus_native_us", "ITG+ rules, compiled to C"),
                           ("call_native_us", "C rules that compute nothing (the call)"),
                           ("ik_closed_form_us", "closed-form inverse kinematics (math)"),
                           ("itg_plus_arguments_us", "ITG+ arguments packed (RuleBase.arguments)"),
                           ("ik_pybullet_us", "pybullet.calculateInverseKinematics"),
                           ("ik_pybullet_call_us", "  the call alone (metres, radians given)")):
            if key in c:
                say(f"{label:<44}{c[key]:>10.3f}{c[key + '_mean']:>10.3f}{c[key + '_max']:>10.3f}"
                    f"{c[key] / base:>10.2f}")
        if c["native_error"]:
            say(f"rules compiled to C: not timed ({c['native_error']})")
        miss = c["ik_pybullet_miss_mm"]
        say("pybullet.calculateInverseKinematics is one call (damped least squares, at most 20 "
            f"iterations, stopping within 0.1 mm; joint damping {IK_JOINT_DAMPING:g}: with "
            "PyBullet's default it never reached that stop here), through World (mm and deg "
            "converted), started from the previous set point's solution, as a tracking loop "
            f"would: it lands median {np.median(miss):.5f} / p95 {np.percentile(miss, 95):.5f} / "
            f"max {miss.max():.5f} mm from its set point; each rules row is one decision, not a "
            "solution, timed with its arguments packed before (the IK row converts its own)")
        ik = c["ik_pybullet_us"]
        for key, label in (("itg_plus_compiled_us", "ITG+ step compiled to Python"),
                           ("itg_plus_native_us", "ITG+ step compiled to C"),
                           ("rules_compiled_us", "Table 2 step compiled to Python"),
                           ("rules_native_us", "Table 2 step compiled to C")):
            if key in c:
                say(f"PyBullet IK / {label}: {ik / c[key]:.1f}x")
        if "itg_plus_native_us" in c:
            say(f"the IK call alone / ITG+ step compiled to C, neither side converting: "
                f"{c['ik_pybullet_call_us'] / c['itg_plus_native_us']:.1f}x; with both "
                f"converting (the IK row / arguments packed + the C step): {ik / (c['itg_plus_arguments_us'] + c['itg_plus_native_us']):.1f}x")
        ratio, compiled = itg_plus_speed(c)
        say(f"target: PyBullet IK / ITG+ step compiled to {compiled} >= {SPEED_FACTOR:g}x: "
            f"{ratio:.1f}x ({'met' if ratio >= SPEED_FACTOR else 'NOT met'})")
        rows = []
        if not args.no_vision:
            rows = vision_costs(frames=args.frames, passes=args.passes)
            say(f"\nstereo loop per iteration at 640x480 (two LEDs, two cameras, distortion and "
                f"noise; median ms over {args.passes} passes of {args.frames} states of ellipse "
                "T1 after its start transient, settings interleaved; CPU time of one core: "
                "median, mean, p95 and max of the loop; Hz from the median, wall Hz beside it)"
                + ("" if args.frames >= DEFAULT_FRAMES and args.passes >= DEFAULT_PASSES else
                   f"; a smaller sample than the default {DEFAULT_FRAMES} states x "
                   f"{DEFAULT_PASSES} passes: its verdicts are rougher"))
            for line in vision_report(rows, DEFAULT_SUPERSAMPLE):
                say(line)
        if args.out is not None:
            far = c["from_set_point_mm"]
            results = {"machine": machine, "decision_passes": DECISION_PASSES,
                       "decision_us": {k: v for k, v in c.items()
                                       if k.endswith(("_us", "_us_mean", "_us_max"))},
                       "decision_states": {
                           "trajectory": DECISION_PATH, "set_points": len(c["ik_pybullet_miss_mm"]),
                           "feedback": "truth", "iterations_per_set_point": 1,
                           "max_step_deg": c["max_step_deg"],
                           "gripper_from_set_point_mm": {k: _tails(v) for k, v in far.items()}},
                       "native_error": c["native_error"],
                       "ik_pybullet_miss_mm": c["ik_pybullet_miss_mm"],
                       "ik_joint_damping": IK_JOINT_DAMPING,
                       "target": {"ratio": ratio, "compiled_to": compiled,
                                  "at_least": SPEED_FACTOR, "met": ratio >= SPEED_FACTOR},
                       "stereo_loop": {"frames": args.frames, "passes": args.passes,
                                       "rows": rows, "targets": {  # those judged
                                           "default_loop_hz_at_least": TARGET_DEFAULT_HZ,
                                           "default_over_full_frame_at_least": TARGET_RATIO,
                                           "fastest_loop_hz_at_least": TARGET_FASTEST_HZ,
                                           "detect_triangulate_ms_below": TARGET_DET_TRI_MS}
                                       if rows else {}}}
            outputs.save_report(args.out, COMMAND, say.text, results, force=args.force)
            print(f"written to {args.out}", file=sys.stderr)
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(exit_status(main()))
