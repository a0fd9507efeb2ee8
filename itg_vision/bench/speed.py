"""python -m itg_vision.bench speed: the cost of one decision, rules against inverse kinematics.

The paper claims its rules are cheaper than trigonometry and matrix inversion. Measured here in
one run, same set points: one compiled Table 2 rule step, the closed-form two-link inverse
kinematics, PyBullet's ``calculateInverseKinematics``; then (with a camera rig available) the
vision pipeline's stages at three resolutions.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..arm import ArmSpec, forward_kinematics
from ..camera import Rig, default_rig_path
from ..controllers import two_link_ik
from ..errors import run_main
from ..feedback import Markers, VisionFeedback
from ..rules import load_rules
from .. import trajectory as traj
from ..world import World


def _per_call_us(fn, args_list, repeat: int) -> float:
    """Median over ``repeat`` passes of the mean time per call (microseconds)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for a in args_list:
            fn(*a)
        times.append((time.perf_counter() - t0) / len(args_list))
    return float(np.median(times) * 1e6)


def decision_costs(n_points: int = 720, repeat: int = 7) -> dict:
    """Microseconds per decision for the same set points and arm states (two-link arm)."""
    arm = ArmSpec.from_args("two-link")
    rb = load_rules("table2", 2, arm.links_mm, f=0.5)
    pts = traj.named("ellipse-t1", n_points).points_mm
    rng = np.random.default_rng(0)
    qs = rng.uniform(-170, 170, (n_points, 2))
    states = []
    for q in qs:
        m = forward_kinematics(arm, q)
        states.append(Markers(m["gripper"], m["elbow"]))
    rule_args = [(p, s, q) for p, s, q in zip(pts, states, qs)]
    # the compiled function alone (what a microcontroller port would run) and RuleBase.step
    raw_args = [rb.arguments(*a) for a in rule_args]
    ik_args = [(float(p[0]), float(p[1]), 100.0, 100.0) for p in pts]
    out = {
        "rules_compiled_us": _per_call_us(rb.compiled, raw_args, repeat),
        "rules_step_us": _per_call_us(rb.step, rule_args, repeat),
        "ik_closed_form_us": _per_call_us(two_link_ik, ik_args, repeat),
    }
    with World(arm) as world:
        targets = [((p[0], p[1], arm.led_standoff_mm),) for p in pts]
        out["ik_pybullet_us"] = _per_call_us(world.inverse_kinematics, targets, repeat)
    return out


def vision_costs(sizes=((320, 240), (640, 480), (1280, 960)), frames: int = 40,
                 settle: int = 20) -> list[dict]:
    """Per-stage milliseconds of the vision loop at several resolutions (stereo, one core).

    The two-link arm tracks ellipse T1 (180 points); the first ``settle`` set points (the start
    transient, where the LEDs jump farther than the detection window) are not timed.
    """
    arm = ArmSpec.from_args("two-link")
    base = Rig.from_yaml(default_rig_path(arm.name))
    rules = load_rules("table2", 2, arm.links_mm, f=0.5)
    pts = traj.named("ellipse-t1").points_mm  # the paper's 180 points: ~2 mm per step
    rows = []
    for w, h in sizes:
        rig = base.scaled(w / base.cameras[0].image_width)
        fb = VisionFeedback(rig, rig, arm)
        fb.reset(0)
        stage = {"render": [], "detect": [], "triangulate": [], "rules": [], "loop": []}
        with World(arm) as world:
            for p in pts[:settle]:  # the start transient (large jumps), untimed
                world.move(rules.step(p, fb.observe(world), world.q_deg).dq_deg)
            for p in pts[settle:settle + frames]:
                t0 = time.perf_counter()
                est = fb.observe(world)
                t1 = time.perf_counter()
                step = rules.step(p, est, world.q_deg)
                stage["rules"].append((time.perf_counter() - t1) * 1e3)
                world.move(step.dq_deg)
                stage["loop"].append((time.perf_counter() - t0) * 1e3)
                for k in ("render", "detect", "triangulate"):
                    stage[k].append(est.timing_ms.get(k, float("nan")))
        med = {k: float(np.median(v)) for k, v in stage.items()}
        rows.append({"size": f"{w}x{h}", **{f"{k}_ms": v for k, v in med.items()},
                     "loop_hz": 1e3 / med["loop"]})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m itg_vision.bench speed", description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-vision", action="store_true", help="skip the vision pipeline timings")
    ap.add_argument("--frames", type=int, default=40, help="frames per resolution (default %(default)s)")
    args = ap.parse_args(argv)

    def body() -> int:
        c = decision_costs()
        base = c["rules_compiled_us"]
        print("one decision, two-link arm, same 720 set points (median of 7 passes, one core)")
        print(f"{'method':<44}{'us/step':>10}{'x rules':>10}")
        for key, label in (("rules_compiled_us", "Table 2 rules, compiled function"),
                           ("rules_step_us", "Table 2 rules, RuleBase.step (with wrapping)"),
                           ("ik_closed_form_us", "closed-form inverse kinematics (math)"),
                           ("ik_pybullet_us", "pybullet.calculateInverseKinematics")):
            print(f"{label:<44}{c[key]:>10.3f}{c[key] / base:>10.2f}")
        if not args.no_vision:
            rows = vision_costs(frames=args.frames)
            print("\nvision loop per iteration, two LEDs, two cameras (median ms over "
                  f"{args.frames} set points of ellipse T1 after its start transient; one core)")
            print(f"{'size':<11}{'render':>9}{'detect':>9}{'triang.':>9}{'rules':>9}"
                  f"{'det+tri':>9}{'loop':>9}{'Hz':>8}")
            for r in rows:
                print(f"{r['size']:<11}{r['render_ms']:>9.2f}{r['detect_ms']:>9.3f}"
                      f"{r['triangulate_ms']:>9.3f}{r['rules_ms']:>9.4f}"
                      f"{r['detect_ms'] + r['triangulate_ms']:>9.3f}{r['loop_ms']:>9.2f}{r['loop_hz']:>8.1f}")
            print("det+tri per LED (one stereo pair, rendering excluded): "
                  + ", ".join(f"{r['size']} {(r['detect_ms'] + r['triangulate_ms']) / 2:.3f} ms" for r in rows))
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(main())
