"""The hot loop: desired point -> feedback -> controller -> joint step -> world; and the trace.

E_i is the Euclidean distance between the desired point and the *true* gripper after the
iterations of set point i (planar arms: in the x-y plane). E_av is their mean over the set
points in reach (the paper's definition; out-of-reach points are counted and skipped).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np


class Controller(Protocol):
    def step(self, desired_mm: np.ndarray, markers, q_deg: np.ndarray): ...


@dataclass
class Trace:
    """Everything recorded along a run, one entry per set point."""

    planar: bool
    n_joints: int
    desired_mm: list = field(default_factory=list)
    gripper_mm: list = field(default_factory=list)
    elbow_mm: list = field(default_factory=list)
    gripper_est_mm: list = field(default_factory=list)
    elbow_est_mm: list = field(default_factory=list)
    q_deg: list = field(default_factory=list)
    fired: list = field(default_factory=list)
    flags: list = field(default_factory=list)
    out_of_reach: list = field(default_factory=list)
    # per observation (every iteration), for estimation error and timing
    est_err_gripper_mm: list = field(default_factory=list)
    est_err_elbow_mm: list = field(default_factory=list)
    n_missed: int = 0
    timing_ms: dict = field(default_factory=dict)

    def error_mm(self) -> np.ndarray:
        """E_i per set point, shape (n,)."""
        d, g = np.asarray(self.desired_mm), np.asarray(self.gripper_mm)
        diff = (d - g)[:, :2] if self.planar else d - g
        return np.linalg.norm(diff, axis=1)

    def tracking_error_mm(self) -> float | None:
        """Median E_i over the second half of the set points in reach: the error once the start
        transient is over (E_av and E_max include it)."""
        e = self.error_mm()
        half = len(e) // 2
        late = e[half:][~np.asarray(self.out_of_reach, bool)[half:]]
        return float(np.median(late)) if late.size else None

    def metrics(self) -> dict:
        e = self.error_mm()
        ok = ~np.asarray(self.out_of_reach, bool)
        ein = e[ok]

        def rms(v):
            v = np.asarray(v, float)
            v = v[np.isfinite(v)]
            return float(np.sqrt(np.mean(v**2))) if v.size else None

        return {
            "e_av_mm": float(np.mean(ein)) if ein.size else None,
            "e_max_mm": float(np.max(ein)) if ein.size else None,
            "e_rms_mm": float(np.sqrt(np.mean(ein**2))) if ein.size else None,
            "n_setpoints": int(len(e)),
            "n_out_of_reach": int((~ok).sum()),
            "n_missed": int(self.n_missed),
            "est_gripper_rms_mm": rms(self.est_err_gripper_mm),
            "est_elbow_rms_mm": rms(self.est_err_elbow_mm),
            "timing_ms": {k: float(np.median(v)) for k, v in self.timing_ms.items() if v},
        }

    def rows(self) -> tuple[list[str], list[list]]:
        """The trace as CSV columns and rows (units in the column names)."""
        qcols = [f"q{i}_deg" for i in range(1, self.n_joints + 1)]
        cols = (["k", "xd_mm", "yd_mm", "zd_mm", "xg_mm", "yg_mm", "zg_mm",
                 "xg_est_mm", "yg_est_mm", "zg_est_mm", "xe_mm", "ye_mm", "ze_mm",
                 "xe_est_mm", "ye_est_mm", "ze_est_mm"] + qcols + ["e_mm", "rules_fired", "flags"])
        e = self.error_mm()
        out = []
        for k in range(len(e)):
            vals = [k]
            for arr in (self.desired_mm, self.gripper_mm, self.gripper_est_mm, self.elbow_mm,
                        self.elbow_est_mm):
                vals += [_fmt(v) for v in arr[k]]
            vals += [_fmt(v) for v in self.q_deg[k]]
            vals += [_fmt(e[k]), ";".join(str(r) for r in self.fired[k]), ";".join(self.flags[k])]
            out.append(vals)
        return cols, out


def _fmt(v) -> str:
    v = float(v)
    return "" if not np.isfinite(v) else f"{v:.4f}"


def simulate(world, controller: Controller, feedback, points_mm: np.ndarray, *,
             iterations: int = 1, planar: bool = True, max_step_deg: float | None = None,
             progress: Callable[[int], None] | None = None, recorder=None) -> Trace:
    """Track ``points_mm`` (shape (n, 3)) and return the trace.

    ``feedback.observe(world)`` is the controller's only view of the arm. ``world.true_markers()``
    is read here for evaluation only (E_i and the estimation error), never handed to the
    controller. ``max_step_deg`` is a servo rate limit: no joint moves more per iteration.
    """
    trace = Trace(planar, world.arm.n_joints)
    timing = {"render": [], "detect": [], "triangulate": [], "rules": []}
    for k, desired in enumerate(points_mm):
        fired, flags, oor = [], [], False
        for _ in range(iterations):
            seen = world.true_markers()  # evaluation only: what the feedback looked at
            estimate = feedback.observe(world)
            t0 = time.perf_counter()
            step = controller.step(desired, estimate, world.q_deg)
            timing["rules"].append((time.perf_counter() - t0) * 1e3)
            dq = step.dq_deg
            if max_step_deg:
                dq = np.clip(dq, -max_step_deg, max_step_deg)
            world.move(dq)

            for stage, ms in estimate.timing_ms.items():
                timing.setdefault(stage, []).append(ms)
            trace.n_missed += len(estimate.missed)
            flags += [f"missed:{m}" for m in estimate.missed if f"missed:{m}" not in flags]
            fired += [r for r in step.fired if r not in fired]
            oor |= step.out_of_reach
            _record_estimate_error(trace, estimate, seen)
        truth = world.true_markers()
        if recorder is not None:
            recorder.frame(feedback, desired)
        if oor:
            flags.insert(0, "out_of_reach")
        trace.desired_mm.append(np.asarray(desired, float))
        trace.gripper_mm.append(truth["gripper"])
        trace.elbow_mm.append(truth["elbow"])
        trace.gripper_est_mm.append(estimate.gripper_mm)
        trace.elbow_est_mm.append(estimate.elbow_mm)
        trace.q_deg.append(world.q_deg.copy())
        trace.fired.append(tuple(fired))
        trace.flags.append(tuple(flags))
        trace.out_of_reach.append(oor)
        if progress is not None:
            progress(1)
    trace.timing_ms = {k: v for k, v in timing.items() if v}
    return trace


def _record_estimate_error(trace: Trace, estimate, seen: dict) -> None:
    """Estimation error of the observation just made, against the truth it observed."""
    for name, out in (("gripper", trace.est_err_gripper_mm), ("elbow", trace.est_err_elbow_mm)):
        if name in estimate.missed:
            continue
        err = np.linalg.norm(estimate.get(name) - seen[name])
        if np.isfinite(err):
            out.append(float(err))
