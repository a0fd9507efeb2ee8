"""Preview: where to aim near the base of a planar arm, planned over the whole path ahead.

Near the base of a planar two-link arm the arm is folded: the gripper lies on a line through
the base that q1 turns, and q2 slides it along that line (through the base when q2 passes the
fold). A path passing the base at a distance c with a step v per set point turns about the base
by up to v / c rad per set point, more than the servo lets q1 turn the line (20 deg per
iteration in the benchmark) once c is a few millimetres. A one-step tracker then chases the set
point round the base, lags, and is left far off as the path leaves the base (the lemniscate's
tracking max; README, "ITG+ against issue 13's targets").

The plan looks ahead instead. It picks, for every set point, the direction of the line (modulo
180 degrees: the gripper may lie on either side of the base) so that consecutive directions
differ by at most the line's largest turn per set point (q1's servo limit times the iterations)
and the largest distance of a set point from its line is as small as it can be; among such
plans, the one with the least sum of squared distances. The controller is then asked to go to
the set point's projection on its line. Where the set point's own direction is within reach of
the plan (far from the base, or where the path turns slowly), the aim is the set point itself.

This is a planner over the path, outside the rules, and it uses angles (dynamic programming on
a grid of ``grid_deg``). It assumes nothing of the arm but a first joint at the base, turning
about the z axis, at most ``turn_deg`` per set point: no link length. Far from the base the
arm can turn the gripper about the base faster than q1 alone (q2 turns it too), so the plan is
conservative there; paths turn slowly there and it leaves them alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

#: The plan's grid of line directions (deg). A set point within half a cell of its line counts
#: as on it; at 100 mm from the base that is 0.2 mm, and the aim is then the set point itself.
GRID_DEG = 0.25


@dataclass(frozen=True)
class Preview:
    """A plan: ``aims_mm`` (n, 3), where the controller is asked to go at each set point;
    ``moved``: the set points whose aim is not the set point; ``largest_move_mm``: the largest
    distance between a set point and its aim (the plan's bound, under its model of the arm)."""

    aims_mm: np.ndarray
    moved: int
    largest_move_mm: float


def plan(points_mm, turn_deg: float, grid_deg: float = GRID_DEG) -> Preview:
    """Plan the aims of ``points_mm`` (n, 3; x and y about the base, z kept), the line through
    the base turning at most ``turn_deg`` per set point. See the module's docstring."""
    points = np.asarray(points_mm, float).reshape(-1, 3)
    if not turn_deg > 0:
        raise ValueError(f"turn_deg must be > 0, got {turn_deg}")
    theta = np.radians(np.arange(0.0, 180.0, grid_deg))  # line directions, mod 180 deg
    x, y = points[:, :1], points[:, 1:2]
    r, psi = np.hypot(x, y), np.arctan2(y, x)
    off = np.abs((psi - theta + np.pi / 2) % np.pi - np.pi / 2)  # angle set point - line
    cost = r * np.sin(np.maximum(0.0, off - np.radians(grid_deg) / 2))  # (n, lines), mm
    # cells the line may turn per set point (half the circle of lines: any line)
    reach = min(int(np.floor(turn_deg / grid_deg + 1e-9)), len(theta) // 2)

    def best_before(v):  # for each line, the best of the lines one set point can turn from
        wrapped = np.concatenate([v[-reach:], v, v[:reach]]) if reach else v
        return sliding_window_view(wrapped, 2 * reach + 1).min(axis=1)

    worst = cost[0]
    for c in cost[1:]:  # the least possible largest distance, set point by set point
        worst = np.maximum(c, best_before(worst))
    bound = worst.min()
    sq = np.where(cost <= bound + 1e-9, cost ** 2, np.inf)  # within the bound: least squares
    total = [sq[0]]
    for c in sq[1:]:
        total.append(c + best_before(total[-1]))
    idx = np.empty(len(points), int)
    idx[-1] = int(np.argmin(total[-1]))
    for k in range(len(points) - 1, 0, -1):
        turns = (idx[k] + np.arange(-reach, reach + 1)) % len(theta)
        idx[k - 1] = turns[np.argmin(total[k - 1][turns])]
    line = np.stack([np.cos(theta[idx]), np.sin(theta[idx])], axis=1)
    moved = cost[np.arange(len(points)), idx] > 0
    aims = points.copy()
    aims[moved, :2] = np.sum(points[moved, :2] * line[moved], axis=1, keepdims=True) * line[moved]
    moves = np.linalg.norm(aims[:, :2] - points[:, :2], axis=1)
    return Preview(aims, int(moved.sum()), float(moves.max(initial=0.0)))
