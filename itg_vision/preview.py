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
conservative there. A smooth path turns slowly there and the plan leaves it alone; a jump does
not (``abcd``'s 100 mm step from B to C turns the set point 45 deg about the base in one set
point, 134 and 63 mm from it), and there the plan moves the aims either side of the jump too,
by 18.5 mm, though the arm is not folded and its model is only q1's share of the motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

#: The plan's grid of line directions (deg), finer for a servo limit below 8 cells per set point.
GRID_DEG = 0.25
#: The most set points x cells one plan takes (about 30 bytes each: 1.5 GB).
MAX_CELLS = 50_000_000


@dataclass(frozen=True)
class Preview:
    """A plan: ``aims_mm`` (n, 3), where the controller is asked to go at each set point;
    ``moved``: the set points whose aim is not the set point; ``largest_move_mm``: the largest
    distance between a set point and its aim (the plan's bound, under its model of the arm);
    ``turn_deg``: the line's largest turn per set point it was planned for."""

    aims_mm: np.ndarray
    moved: int
    largest_move_mm: float
    turn_deg: float

    def record(self) -> dict:
        """What a run's summary says of the plan."""
        return {"turn_deg_per_set_point": self.turn_deg, "moved": self.moved,
                "largest_move_mm": round(self.largest_move_mm, 4)}


def plan(points_mm, turn_deg: float, grid_deg: float = GRID_DEG) -> Preview:
    """Plan the aims of ``points_mm`` (n, 3; x and y about the base, z kept), the line through
    the base turning at most ``turn_deg`` per set point. See the module's docstring.

    The directions are cells of a grid (``grid_deg``, or an eighth of ``turn_deg`` if that is
    finer); consecutive set points' cells are at most ``turn_deg`` apart (centre to centre). A
    set point's line is the direction in its cell nearest the set point's own: the set point
    itself when its direction lies in the cell, else the cell's edge nearer to it. So the lines
    of consecutive set points may differ by ``turn_deg`` plus one cell (at most 1/8 of it).
    A plan of more than :data:`MAX_CELLS` set points x cells raises ValueError.
    """
    points = np.asarray(points_mm, float).reshape(-1, 3)
    if not (math.isfinite(turn_deg) and turn_deg > 0):
        raise ValueError(f"turn_deg must be finite and > 0, got {turn_deg}")
    if len(points) == 0:
        return Preview(points, 0, 0.0, turn_deg)
    grid = min(grid_deg, turn_deg / 8)
    if len(points) * 180.0 / grid > MAX_CELLS:
        raise ValueError(f"{len(points)} set points x {180.0 / grid:.0f} cells of {grid:g} deg "
                         f"(an eighth of the turn of {turn_deg:g} deg per set point) exceed the "
                         f"plan's {MAX_CELLS:.0e}: fewer set points or a larger turn")
    theta = np.radians(np.arange(0.0, 180.0, grid) + grid / 2)  # cell centres, mod 180 deg
    half = np.radians(grid) / 2
    x, y = points[:, :1], points[:, 1:2]
    r, psi = np.hypot(x, y), np.arctan2(y, x)
    off = (psi - theta + np.pi / 2) % np.pi - np.pi / 2  # set point's direction - cell centre
    cost = r * np.sin(np.maximum(0.0, np.abs(off) - half))  # distance to the cell's line, mm
    # cells the line may turn per set point (half the circle of lines: any line)
    reach = min(int(np.floor(turn_deg / grid + 1e-9)), len(theta) // 2)

    def windows(v):  # for each cell, the values of the cells one set point can turn from
        return sliding_window_view(np.concatenate([v[-reach:], v, v[:reach]]) if reach else v,
                                   2 * reach + 1)

    worst = cost[0]
    for c in cost[1:]:  # the least possible largest distance, set point by set point
        worst = np.maximum(c, windows(worst).min(axis=1))
    bound = worst.min()
    sq = np.where(cost <= bound, cost ** 2, np.inf)  # within the bound: least squares
    total, came = sq[0], []
    for c in sq[1:]:
        w = windows(total)
        i = w.argmin(axis=1)
        came.append(i.astype(np.int16))  # offset + reach of the cell each cell came from
        total = c + w[np.arange(len(i)), i]
    idx = np.empty(len(points), int)
    idx[-1] = int(np.argmin(total))
    for k in range(len(points) - 1, 0, -1):
        idx[k - 1] = (idx[k] + int(came[k - 1][idx[k]]) - reach) % len(theta)
    k = np.arange(len(points))
    line = theta[idx] + np.clip(off[k, idx], -half, half)  # the cell's direction nearest psi
    moved = cost[k, idx] > 1e-9  # mm: rounding, not a move
    unit = np.stack([np.cos(line), np.sin(line)], axis=1)[moved]
    aims = points.copy()
    aims[moved, :2] = np.sum(points[moved, :2] * unit, axis=1, keepdims=True) * unit
    return Preview(aims, int(moved.sum()), float(cost[k, idx][moved].max(initial=0.0)), turn_deg)
