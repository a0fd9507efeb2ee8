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
    """Everything recorded along a run, one entry per set point.

    Per set point: the desired point; the estimate the controller used at the set point's last
    iteration (``*_est_mm``) beside the simulator's truth at the same instant (``*_true_mm``:
    compare these two for the estimation error); the truth after the set point's iterations
    (``*_after_mm``: E_i uses it); joints, rules fired, flags.
    """

    planar: bool
    n_joints: int
    tracking_start: int = 0
    desired_mm: list = field(default_factory=list)
    gripper_mm: list = field(default_factory=list)  # truth after the move (E_i)
    elbow_mm: list = field(default_factory=list)
    gripper_est_mm: list = field(default_factory=list)  # estimate used for the last move
    elbow_est_mm: list = field(default_factory=list)
    gripper_true_mm: list = field(default_factory=list)  # truth when that estimate was taken
    elbow_true_mm: list = field(default_factory=list)
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

    def tracking_errors_mm(self) -> np.ndarray:
        """E_i over the tracking phase (from ``tracking_start``), set points in reach only."""
        e = self.error_mm()
        k = self.tracking_start
        return e[k:][~np.asarray(self.out_of_reach, bool)[k:]]

    def metrics(self) -> dict:
        """E_av, E_max, E_rms over the set points in reach (the paper's metric, start transient
        included), and the tracking phase's median, mean, 95th percentile and max."""
        e = self.error_mm()
        ok = ~np.asarray(self.out_of_reach, bool)
        ein = e[ok]
        late = self.tracking_errors_mm()

        def stat(fn, v):
            return float(fn(v)) if v.size else None

        def rms(v):
            v = np.asarray(v, float)
            v = v[np.isfinite(v)]
            return float(np.sqrt(np.mean(v**2))) if v.size else None

        return {
            "e_av_mm": stat(np.mean, ein),
            "e_max_mm": stat(np.max, ein),
            "e_rms_mm": rms(ein),
            "tracking_from": int(self.tracking_start),
            "track_median_mm": stat(np.median, late),
            "track_mean_mm": stat(np.mean, late),
            "track_p95_mm": stat(lambda v: np.percentile(v, 95), late),
            "track_max_mm": stat(np.max, late),
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
        xyz = ("x", "y", "z")
        groups = [("d", "", self.desired_mm)]
        for m, arrs in (("g", (self.gripper_est_mm, self.gripper_true_mm, self.gripper_mm)),
                        ("e", (self.elbow_est_mm, self.elbow_true_mm, self.elbow_mm))):
            groups += [(m, "_est", arrs[0]), (m, "_true", arrs[1]), (m, "_after", arrs[2])]
        cols = ["k", "tracking"] + [f"{a}{m}{s}_mm" for m, s, _ in groups for a in xyz] \
            + qcols + ["e_mm", "rules_fired", "flags"]
        e = self.error_mm()
        out = []
        for k in range(len(e)):
            vals = [k, int(k >= self.tracking_start)]
            for _, _, arr in groups:
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
             tracking_start: int | None = None,
             progress: Callable[[int], None] | None = None, recorder=None) -> Trace:
    """Track ``points_mm`` (shape (n, 3)) and return the trace.

    ``feedback.observe(world)`` is the controller's only view of the arm. ``world.true_markers()``
    is read here for evaluation only (E_i and the estimation error), never handed to the
    controller. ``max_step_deg`` is a servo rate limit: no joint moves more per iteration,
    whatever the controller. ``tracking_start``: first set point of the tracking phase
    (default: the second half).
    """
    trace = Trace(planar, world.arm.n_joints,
                  len(points_mm) // 2 if tracking_start is None else int(tracking_start))
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
        trace.gripper_true_mm.append(seen["gripper"])
        trace.elbow_true_mm.append(seen["elbow"])
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
