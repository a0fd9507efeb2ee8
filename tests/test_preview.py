"""Preview (itg_vision/preview.py): the plan of the line through the base, checked against an
independent search and against the physics of a line passing the base; and in the loop."""

import numpy as np
import pytest

from itg_vision.preview import GRID_DEG, plan
from itg_vision.runner import RunConfig, execute, prepare

TURN = 20.0  # deg per set point: the two-link benchmark's servo limit, one iteration


def line_past_base(c_mm, v_mm, half_mm=60.0):
    """Set points along y = c, x from -half to +half, v apart (mm)."""
    x = np.arange(-half_mm, half_mm + 1e-9, v_mm)
    return np.c_[x, np.full_like(x, c_mm), np.zeros_like(x)]


def directions(aims):
    """The line through the base of each aim (deg mod 180; a set point left as it is: its own)."""
    return np.degrees(np.arctan2(aims[:, 1], aims[:, 0])) % 180


def least_bound_by_bisection(points, turn_deg, grid_deg=GRID_DEG):
    """The least largest distance of a set point from its line, found another way: bisection on
    the distance, each tried by carrying forward the set of line directions (the same grid and
    the same half-cell allowance as the plan) that keep every set point so far within it."""
    theta = np.radians(np.arange(0.0, 180.0, grid_deg))
    r = np.hypot(points[:, 0], points[:, 1])[:, None]
    psi = np.arctan2(points[:, 1], points[:, 0])[:, None]
    off = np.abs((psi - theta + np.pi / 2) % np.pi - np.pi / 2)
    dist = r * np.sin(np.maximum(0.0, off - np.radians(grid_deg) / 2))
    reach = int(np.floor(turn_deg / grid_deg + 1e-9))

    def feasible(m):
        ok = dist[0] <= m
        for d in dist[1:]:
            grown = np.zeros_like(ok)
            for s in range(-reach, reach + 1):
                grown |= np.roll(ok, s)
            ok = grown & (d <= m)
            if not ok.any():
                return False
        return True

    lo, hi = 0.0, float(r.max())
    for _ in range(50):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if feasible(mid) else (mid, hi)
    return hi


def test_a_path_the_line_can_follow_is_left_as_it_is():
    """A circle of 50 mm about the base, 2 mm apart: the set point turns 2.3 deg per step."""
    t = np.linspace(0, 2 * np.pi, 157, endpoint=False)
    points = np.c_[50 * np.cos(t), 50 * np.sin(t), np.zeros_like(t)]
    p = plan(points, TURN)
    assert p.moved == 0 and p.largest_move_mm == 0.0
    np.testing.assert_array_equal(p.aims_mm, points)


@pytest.mark.parametrize("c, v", [(2.0, 2.0), (2.0, 1.0), (0.74, 1.5), (5.0, 4.0)])
def test_plan_on_a_line_past_the_base(c, v):
    """A line c mm from the base, v mm per set point. The set point turns about the base by up
    to v / c rad per step, above 20 deg in every case here, so the plan must move aims. Holding
    the line parallel to the path is always possible and costs c: the plan never costs more.
    Its bound is the least an independent search finds; its lines turn at most 20 deg per set
    point; each aim is the set point's projection on a line through the base."""
    points = line_past_base(c, v)
    p = plan(points, TURN)
    assert np.degrees(v / c) > TURN and p.moved > 0
    assert p.largest_move_mm <= c + 1e-9
    grid_err = 60.0 * np.sin(np.radians(GRID_DEG))  # a set point's distance from its cell's edge
    assert abs(p.largest_move_mm - least_bound_by_bisection(points, TURN)) <= grid_err
    moved = np.linalg.norm(p.aims_mm - points, axis=1) > 0
    aim = p.aims_mm[moved, :2]
    np.testing.assert_allclose(np.sum(aim * (points[moved, :2] - aim), axis=1), 0, atol=1e-9)
    lines = directions(p.aims_mm)
    turns = np.abs((np.diff(lines) + 90) % 180 - 90)
    assert turns.max() <= TURN + GRID_DEG + 1e-9


@pytest.mark.parametrize("turn", [90.0, 200.0, 1e6])
def test_a_servo_that_turns_the_line_anywhere_moves_no_aim(turn):
    """From 90 deg per set point on, every line is one set point from every other."""
    points = line_past_base(0.5, 4.0)
    p = plan(points, turn)
    assert p.moved == 0
    np.testing.assert_array_equal(p.aims_mm, points)


def test_plan_keeps_z_and_the_unmoved_set_points():
    points = line_past_base(2.0, 2.0)
    points[:, 2] = 12.0
    p = plan(points, TURN)
    assert np.all(p.aims_mm[:, 2] == 12.0)
    far = np.hypot(points[:, 0], points[:, 1]) > 30  # turning 4 deg per step at most
    np.testing.assert_array_equal(p.aims_mm[far], points[far])


def test_preview_in_the_loop_on_a_line_past_the_base(tmp_path):
    """ITG+ on a line 2 mm from the base at 2 mm per set point, fed the simulator's truth. The
    set point turns up to 57 deg per step about the base, the servo 20: without preview ITG+
    chases it round the base. With preview the rules hold within w = 0.5 mm of an aim they can
    reach in one step, and the aim is within the plan's bound of the set point, so every E_i
    is within bound + w; E_i is measured from the set point, never from the aim."""
    path = tmp_path / "line.csv"
    pts = np.r_[np.repeat(line_past_base(2.0, 2.0)[:1], 60, axis=0), line_past_base(2.0, 2.0)]
    np.savetxt(path, pts[:, :2], delimiter=",", header="x_mm,y_mm", comments="", fmt="%.6f")
    runs = {}
    for preview in (False, True):
        prep = prepare(RunConfig(trajectory=str(path), rules="itg-plus-two-link", feedback="truth",
                                 max_step_deg=TURN, preview=preview))
        trace, summary = execute(prep)
        runs[preview] = (trace, summary)
        np.testing.assert_array_equal(trace.desired_mm, prep.trajectory.points_mm)
    bound = runs[True][1]["preview"]["largest_move_mm"]
    e_on, e_off = (runs[k][0].error_mm()[60:] for k in (True, False))
    assert runs[True][1]["preview"]["moved"] > 0 and bound <= 2.0
    assert e_on.max() <= bound + 0.5
    assert e_on.max() < e_off.max()
