"""Trajectory generators (geometry, the quintic) and the CSV reader."""

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import roundoff

from itg_vision import trajectory as T
from itg_vision.arm import ArmSpec
from itg_vision.errors import UserError


@pytest.mark.parametrize("name, centre, a, b", [("ellipse-t1", (20, -30), 65, 40),
                                                ("ellipse-t2", (-30, 40), 62.5, 50)])
def test_ellipses_lie_on_the_paper_ellipse(name, centre, a, b):
    t = T.named(name)
    assert len(t) == 180
    p = t.points_mm[:, :2] - centre
    c, s = math.cos(math.radians(-45)), math.sin(math.radians(-45))
    u, v = c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]  # into the ellipse's axes
    # cos^2 + sin^2 through a rotation: float64 round-off of 1
    assert np.allclose((u / a) ** 2 + (v / b) ** 2, 1.0, rtol=0, atol=roundoff(1.0))
    assert np.allclose(np.diff(t.param_deg), 2.0, rtol=0, atol=roundoff(360))
    # uniform in angle: centred, to the round-off of summing 180 points of ~a mm
    assert np.allclose(p.mean(axis=0), 0.0, rtol=0, atol=roundoff(a, ulps=180))
    assert all(ArmSpec.from_args("two-link").reachable(q) for q in t.points_mm)


def test_points_option_changes_spacing():
    t = T.named("ellipse-t1", 720)
    assert len(t) == 720 and np.allclose(np.diff(t.param_deg), 0.5, rtol=0, atol=roundoff(360))


def test_abcd_has_the_jump_and_no_point_between():
    t = T.named("abcd")
    p = t.points_mm
    assert len(p) == 200
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert steps[99] == pytest.approx(100.0)  # B -> C: 100 mm with no set point between
    assert np.all(np.delete(steps, 99) < 1.3)
    assert all(ArmSpec.from_args("two-link").reachable(q) for q in p)


def test_quintic_boundary_conditions():
    lam = T.quintic
    h = 1e-5
    assert lam(0.0) == 0.0 and lam(1.0) == pytest.approx(1.0) and lam(0.5) == pytest.approx(0.5)
    for s0 in (0.0, 1.0):  # zero velocity and acceleration at both ends (one-sided differences)
        sgn = 1 if s0 == 0 else -1
        v = (lam(s0 + sgn * h) - lam(s0)) / (sgn * h)
        acc = (lam(s0 + 2 * sgn * h) - 2 * lam(s0 + sgn * h) + lam(s0)) / h**2
        assert abs(v) < 1e-8 and abs(acc) < 1e-3
    s = np.linspace(0, 1, 1001)
    vel = np.gradient(lam(s), s)
    assert np.argmax(vel) == 500  # peak speed at t_r / 2
    assert np.all(np.diff(lam(s)) >= 0)


def test_line_ab_is_straight_and_b_is_out_of_reach():
    t = T.named("line-ab")
    a, b = np.array(T.LINE_AB_MM)
    assert len(t) == 100 and t.t_s[-1] == 10.0
    tol = roundoff(400)  # float64 round-off at B's 400 mm
    assert np.allclose(t.points_mm[0], a, rtol=0, atol=tol) and np.allclose(t.points_mm[-1], b, rtol=0, atol=tol)
    d = (t.points_mm - a) / np.linalg.norm(b - a)
    assert np.allclose(np.cross(d, (b - a) / np.linalg.norm(b - a)), 0, rtol=0, atol=roundoff(1.0))
    arm = ArmSpec.from_args("three-link")
    assert np.linalg.norm(b - [0, 0, 100]) == pytest.approx(438.75, abs=0.005)  # sqrt(192500), to 2 decimals
    assert not arm.reachable(b) and arm.reachable(a)
    r = T.named("line-ab-reach")
    assert all(arm.reachable(q) for q in r.points_mm)


def test_a_path_run_for_laps_is_tracked_from_its_second_lap():
    """A closed path run for laps repeats its set points, and its tracking phase is every lap
    after the first: T1's 180 set points, 3 laps, from set point 180 of 540. Run once: its
    second half, from 90."""
    t = T.load("ellipse-t1")
    three = t.repeated(3)
    assert len(three) == 540 and np.array_equal(three.points_mm[360:], t.points_mm)
    assert (t.tracking_start, three.tracking_start) == (90, 180)


def test_a_path_that_repeats_its_start_shares_it_between_laps(tmp_path):
    """A square written with its start repeated as its last point, run for 2 laps: the start is
    one set point at the seam, not two in a row (both counted in the metrics), the times go
    on by one period, and the tracking phase starts at the second lap's first point."""
    f = tmp_path / "square.csv"
    f.write_text("x_mm,y_mm,t_s\n50,10,0\n100,10,1\n100,60,2\n50,60,3\n50,10,4\n")
    t = T.read_csv(f)
    assert t.closed and len(t) == 5
    two = t.repeated(2)
    assert two.points_mm[:, :2].tolist() == [[50, 10], [100, 10], [100, 60], [50, 60],
                                             [50, 10], [100, 10], [100, 60], [50, 60], [50, 10]]
    assert two.t_s.tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 8]
    assert two.tracking_start == 4 and two.points_mm[4].tolist() == [50, 10, 0]
    # without the repeat, every lap has all its points and the clock steps on by one step
    f.write_text("x_mm,y_mm,t_s\n50,10,0\n100,10,1\n100,60,2\n50,60,3\n")
    two = T.read_csv(f).repeated(2)
    assert len(two) == 8 and two.t_s.tolist() == [0, 1, 2, 3, 4, 5, 6, 7]
    assert two.tracking_start == 4


def test_csv_reader_good(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("x_mm,y_mm,z_mm,t_s\n1,2,3,0\n4,5,6,0.5\n\n")
    t = T.read_csv(f)
    assert not t.planar and t.points_mm.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert t.t_s.tolist() == [0, 0.5]
    f.write_text("x_mm,y_mm\n1,2\n3,4\n")
    assert T.read_csv(f).planar
    f.write_text('x_mm,y_mm\n"1",+2.\n.5e1,-4E-1\n')  # quotes, sign, point, exponent: numbers
    assert T.read_csv(f).points_mm[:, :2].tolist() == [[1, 2], [5, -0.4]]
    for newline in ("\r\n", "\r"):  # Windows' and old Macs' line ends read alike
        f.write_bytes(newline.join(["x_mm,y_mm", "1,2", "3,4", ""]).encode())
        assert T.read_csv(f).points_mm[:, :2].tolist() == [[1, 2], [3, 4]]
    # a header typed by hand, spaces after its commas, is read as its cells (' 2') are
    f.write_text("x_mm, y_mm , z_mm\n1, 2, 3\n4, 5, 6\n")
    t = T.read_csv(f)
    assert not t.planar and t.points_mm.tolist() == [[1, 2, 3], [4, 5, 6]]


def test_a_csv_is_3d_exactly_when_it_has_a_z_mm_column(tmp_path):
    """README: header x_mm,y_mm[,z_mm][,t_s]; a file with z_mm is 3-D whatever its time
    column, one without is planar (z = 0): by the header alone, with and without t_s."""
    f = tmp_path / "t.csv"
    f.write_text("x_mm,y_mm,z_mm\n100,0,150\n110,0,160\n")
    t = T.read_csv(f)
    assert not t.planar and t.points_mm[:, 2].tolist() == [150, 160] and t.t_s is None
    f.write_text("x_mm,y_mm,t_s\n100,0,0\n110,0,1\n")
    t = T.read_csv(f)
    assert t.planar and t.points_mm[:, 2].tolist() == [0, 0] and t.t_s.tolist() == [0, 1]


@pytest.mark.parametrize("text, expect", [
    ("", "empty file"),
    ("x,y\n1,2\n", ":1: header must be x_mm,y_mm"),
    # a hint where the slip is clear; none where it is not
    ("x,y\n1,2\n", "got 'x,y': the columns are named x_mm, y_mm, z_mm (in mm) and t_s (in s)"),
    ("X_MM,Y_MM\n1,2\n", "got 'X_MM,Y_MM': the columns are named x_mm"),
    ("# path\nx_mm,y_mm\n1,2\n", "got '# path': a comment line is not read; the header comes "
                                 "first"),
    ("x_mm;y_mm\n1;2\n", "got 'x_mm;y_mm': fields are separated by commas, not semicolons"),
    ("x_mm\ty_mm\n1\t2\n", "got 'x_mm\\ty_mm': fields are separated by commas, not tabs"),
    ("y_mm,x_mm\n1,2\n", "got 'y_mm,x_mm': the columns in that order"),
    ("a,b\n1,2\n", "got 'a,b'\n"),
    ("x_mm,y_mm\n1,2\n3,abc\n", ":3: field y_mm: not a number: 'abc'"),
    ("x_mm,y_mm\n1,nan\n", ":2: field y_mm: must be finite"),
    ("x_mm,y_mm\n1,2,3\n", ":2: expected 2 fields, got 3"),
    ("x_mm,y_mm\n", "no set points after the header; a trajectory needs at least 2"),
    ("x_mm,y_mm\n120,40\n", "1 set point after the header; a trajectory needs at least 2"),
    # what Python's float() takes but no spreadsheet writes: refused, not read as a number
    ("x_mm,y_mm\n1,2\n1_20,40\n", ":3: field x_mm: not a number: '1_20'"),
    ("x_mm,y_mm\n1,2\n\uff11\uff12\uff10,40\n", ":3: field x_mm: not a number"),  # full-width
    ("x_mm,y_mm\n1,2\n\u0661\u0662\u0660,40\n", ":3: field x_mm: not a number"),  # Arabic-Indic
    ("x_mm,y_mm\n1,2\n0x10,40\n", ":3: field x_mm: not a number: '0x10'"),
    # quotes: an unclosed one at the line it opens on, a stray one at its line
    ("x_mm,y_mm\n1,2\n3,4\n100,\"60\n", ":4: not CSV (unexpected end of data)"),
    ("x_mm,y_mm\n\"1\"2,3\n4,5\n", ":2: not CSV (',' expected after '\"')"),
    ("x_mm,y_mm,t_s\n1,2,1\n1,2,0\n", ":3: field t_s: times must not decrease"),
    # blank lines before it: still the line of the time that decreases
    ("x_mm,y_mm,t_s\n50,50,0\n\n60,60,1\n70,70,0.5\n", ":5: field t_s: times must not decrease"),
    ("x_mm,y_mm\n1,2\n1e308,0\n", ":3: field x_mm: 1e308 is beyond +-1e+06 mm"),
    ("x_mm,y_mm\n1,2\f\n3,abc\n", ":3: field y_mm: not a number"),  # a form feed ends no line
    ("x_mm,y_mm\n1,2\n1,-1000001\n", ":3: field y_mm: -1000001 is beyond"),
    # after a quoted field over two lines, the line a row starts on (it said 3)
    ("x_mm,y_mm\n\"50\n\",50\n60,abc\n", ":4: field y_mm: not a number: 'abc'"),
    # blank lines then the header: not "empty file"
    ("\n\nx_mm,y_mm\n50,50\n60,60\n", ":1: blank; the first line must be the header"),
    ("\n\n\n", "empty file"),
])
def test_csv_reader_bad_input_names_file_and_line(tmp_path, text, expect):
    f = tmp_path / "bad.csv"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(UserError) as exc:
        T.read_csv(f)
    assert str(exc.value).startswith(str(f)) and expect in str(exc.value) + "\n"


def test_a_path_is_closed_when_its_last_point_is_followed_by_its_first():
    t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    loop = np.c_[100 + 50 * np.cos(t), 50 * np.sin(t)]
    assert T.is_closed(loop)  # sampled without repeating its start
    assert not T.is_closed(loop[:50])  # an arc: the gap is 11 steps
    assert not T.is_closed(loop[:3])
    # a path that jumps from a home point to an arc ending near home is not closed by the jump
    home = np.array([[100.0, -60.0]])
    arc = np.c_[100 + 50 * np.cos(t[5:40]), 50 * np.sin(t[5:40])]
    assert np.linalg.norm(arc[-1] - home[0]) < 1.5 * np.linalg.norm(arc[0] - home[0])
    assert not T.is_closed(np.vstack([home, arc]))
    # nor a home point 30 mm beyond D put before abcd (a jump to A, the B-C jump inside)
    abcd = T.load("abcd").points_mm[:, :2]
    with_home = np.vstack([abcd[-1] + [0.0, -30.0], abcd])
    assert not T.is_closed(with_home) and not T.is_closed(with_home[::-1])
    # a loop that dwells at its ends (its first and last points repeated), or at every point,
    # is closed: a repeated point is no step
    assert T.is_closed(np.vstack([loop[:1], loop, loop[-1:]]))
    assert T.is_closed(np.vstack([loop[:1], loop[:1], loop]))
    assert T.is_closed(np.repeat(loop, 2, axis=0)) and T.is_closed(np.repeat(loop, 3, axis=0))
    data = Path(__file__).resolve().parents[1] / "data" / "trajectories"
    # dense in the corners, sparse along the sides: it closes with a side's step (9.2 mm),
    # which the median step (1.6 mm) and its last step (3.8 mm) do not cover
    square = np.loadtxt(data / "rounded-square.csv", delimiter=",", skiprows=1)
    steps = np.linalg.norm(np.diff(square, axis=0), axis=1)
    assert 1.5 * np.median(steps) < np.linalg.norm(square[-1] - square[0]) <= 1.5 * steps[0]
    assert T.load(str(data / "rounded-square.csv")).closed
    assert T.is_closed(np.vstack([square[:1], square, square[-1:]]))  # dwelling at its ends
    for name in ("peanut", "limacon", "rose", "lemniscate", "ellipse-by-base", "trefoil",
                 "gerono", "lemniscate-2", "limacon-2", "thin-ellipse"):
        assert T.load(str(data / f"{name}.csv")).closed, name
    for name in ("abcd", "line-ab", "line-ab-reach"):
        assert not T.load(name).closed, name
    assert T.load("ellipse-t1").closed


# ------------------------------------------ the named paths against the README, closed paths
from itg_vision.arm import forward_kinematics  # noqa: E402
from itg_vision.errors import ConfigError  # noqa: E402


@pytest.mark.parametrize("name, centre, axes", [("ellipse-t1", (20.0, -30.0), (130.0, 80.0)),
                                                ("ellipse-t2", (-30.0, 40.0), (125.0, 100.0))])
def test_named_ellipse_point_k_is_the_papers_parametric_point_at_2k_deg(name, centre, axes):
    """README: centre, axes, -45 deg orientation, 180 set points 2 deg apart in the ellipse's
    parameter angle theta, from theta = 0. Point k, by hand: c + R(-45 deg) (a cos theta_k,
    b sin theta_k), theta_k = 2k deg. The ellipse test above checks the points lie on the ellipse, not
    where on it nor in which direction: reversing it (ITG, model feedback: T1 E_av 6.976 ->
    11.5 mm, the README's published 6.976) or starting it at the other end of the major axis
    passed."""
    t = T.named(name)
    a, b = axes[0] / 2, axes[1] / 2
    th = np.radians(2.0 * np.arange(180))
    phi = math.radians(-45.0)
    u, v = a * np.cos(th), b * np.sin(th)
    expect = np.c_[centre[0] + math.cos(phi) * u - math.sin(phi) * v,
                   centre[1] + math.sin(phi) * u + math.cos(phi) * v]
    np.testing.assert_allclose(t.points_mm[:, :2], expect, rtol=0, atol=1e-9)
    assert t.param_deg[0] == 0.0
    # first point by hand, T1: (20 + 65 cos 45, -30 - 65 sin 45)
    if name == "ellipse-t1":
        np.testing.assert_allclose(t.points_mm[0, :2], [20 + 65 / math.sqrt(2),
                                                        -30 - 65 / math.sqrt(2)], atol=1e-9)


def test_abcd_runs_a_to_b_then_c_to_d_at_the_papers_corners():
    """README: A(-60, 120) to B(60, 120), a 100 mm jump to C(60, 20), then to D(-60, 20). The
    other tests check the jump's length and the steps only: the corners shifted 10 mm (ITG, model
    feedback: tracking max 21.7 -> 23.9 mm) or the path mirrored (21.7 -> 70.0 mm) passed."""
    p = T.named("abcd").points_mm
    np.testing.assert_allclose(p[[0, 99, 100, 199], :2],
                               [[-60, 120], [60, 120], [60, 20], [-60, 20]], atol=1e-9)


def test_line_ab_reach_ends_are_the_readmes_a_and_b_primed():
    """README: A'(21, 12.6, 150.4) to B'(105, 84, 226), the paper's A, B scaled by 0.42 about
    the shoulder (0, 0, 100); with other links, about the shoulder at height L1."""
    t = T.named("line-ab-reach")
    np.testing.assert_allclose(t.points_mm[0], [21.0, 12.6, 150.4], atol=1e-9)
    np.testing.assert_allclose(t.points_mm[-1], [105.0, 84.0, 226.0], atol=1e-9)


def test_arc_runs_clockwise_from_plus_y_over_270_deg():
    """The one-link arc: 270 deg of the circle of radius L from +y clockwise, ending at -x:
    by hand, first (0, L), last (-L, 0), the second at 90 - 270 / (n - 1) deg."""
    L = 100.0
    t = T.named("arc")
    n = len(t)
    np.testing.assert_allclose(t.points_mm[0, :2], [0.0, L], atol=1e-9)
    np.testing.assert_allclose(t.points_mm[-1, :2], [-L, 0.0], atol=1e-9)
    a1 = math.radians(90.0 - 270.0 / (n - 1))
    np.testing.assert_allclose(t.points_mm[1, :2], [L * math.cos(a1), L * math.sin(a1)], atol=1e-9)


def _square_short_of_closing(gap_steps):
    """A 40 mm square perimeter walked in 1 mm steps from (0, 0), stopping gap_steps short."""
    pts = [(float(i), 0.0) for i in range(10)] + [(10.0, float(i)) for i in range(10)] + \
          [(10.0 - i, 10.0) for i in range(10)] + [(0.0, 10.0 - i) for i in range(10)]
    return np.array(pts[:len(pts) - gap_steps + 1])


def test_closed_means_the_closing_step_is_at_most_one_and_a_half_steps():
    """README / is_closed: closed when the step back to the start is at most 1.5 times the
    median step, or within a factor 1.5 of the first or last step. Every step 1 mm: a 1 mm
    gap closes, a 2 mm gap does not (by hand)."""
    assert T.is_closed(_square_short_of_closing(1))
    assert not T.is_closed(_square_short_of_closing(2))


def test_three_points_are_never_a_closed_path():
    tri = np.array([[0.0, 0.0], [10.0, 0.0], [5.0, 8.66]])
    assert not T.is_closed(tri)


def test_an_open_csv_path_is_not_closed_and_runs_once(tmp_path):
    """A straight line in a file: its end is 4 steps from its start, so not closed, and
    --laps 2 is refused (helix.csv, open, gets 1 lap in the benchmarks by this flag). The same
    for a 3-D line straight up (x, y fixed, z 100..180 mm in 20 mm steps: its end 80 mm, 4
    steps, from its start), which seen from above is one point: closedness is judged in 3-D."""
    f = tmp_path / "line.csv"
    for text in ("x_mm,y_mm\n100,0\n110,0\n120,0\n130,0\n140,0\n",
                 "x_mm,y_mm,z_mm\n100,0,100\n100,0,120\n100,0,140\n100,0,160\n100,0,180\n"):
        f.write_text(text)
        t = T.read_csv(f)
        assert not t.closed, text
        with pytest.raises(ConfigError):
            t.repeated(2)
    root = Path(T.__file__).resolve().parents[1]
    assert not T.load(str(root / "data" / "trajectories" / "helix.csv")).closed


def test_a_missing_csv_file_is_not_found_whatever_the_case_of_its_suffix(tmp_path):
    """A path ending in .csv (or .CSV: the suffix's case is not looked at) is a file, never a
    trajectory's name: missing, it is 'not found', not an unknown trajectory."""
    for name in ("gone.csv", "GONE.CSV"):
        with pytest.raises(UserError) as exc:
            T.load(str(tmp_path / name))
        assert str(exc.value) == f"{tmp_path / name}: trajectory file not found"


def test_a_shipped_trajectory_file_is_loaded_by_its_name_as_the_benchmark_names_it(tmp_path,
                                                                                  monkeypatch):
    """`run --trajectory peanut` (and an arm file's defaults.trajectory: helix) read
    data/trajectories/peanut.csv, as `bench noise --trajectories peanut` does; both were
    refused as unknown. A shipped name wins over a file of that name in the current folder
    (./peanut for that one), as with rule bases; --points is refused for it as for any file; an
    unknown name lists the shipped files too."""
    from itg_vision.shipped import TRAJECTORIES_DIR, trajectory_file_names

    assert {"peanut", "helix", "rounded-square"} <= set(trajectory_file_names())
    for name in trajectory_file_names():
        by_name = T.load(name)
        assert by_name.file == (TRAJECTORIES_DIR / f"{name}.csv").resolve()
        assert np.array_equal(by_name.points_mm, T.read_csv(TRAJECTORIES_DIR / f"{name}.csv").points_mm)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "peanut").write_text("x_mm,y_mm\n100,0\n110,0\n")
    assert T.load("peanut").file == (TRAJECTORIES_DIR / "peanut.csv").resolve()
    assert len(T.load("./peanut")) == 2
    with pytest.raises(ConfigError) as exc:
        T.load("peanut", n_points=10)
    assert exc.value.field == "points"
    with pytest.raises(UserError) as exc:
        T.load("spiral")
    assert "the shipped files ellipse-by-base, gerono, helix," in str(exc.value)


def test_points_is_refused_for_a_csv_file(tmp_path):
    """README: `--points` resamples the named trajectories only (a file keeps its set
    points): 10 points of a 3-point file is a ConfigError on points, not ignored."""
    f = tmp_path / "t.csv"
    f.write_text("x_mm,y_mm\n100,0\n110,0\n120,0\n")
    with pytest.raises(ConfigError) as exc:
        T.load(str(f), n_points=10)
    assert exc.value.field == "points" and "named trajectories only" in exc.value.message


def test_equal_times_do_not_decrease(tmp_path):
    """README: t_s 'must not decrease': a repeated time (a dwell) is read."""
    f = tmp_path / "t.csv"
    f.write_text("x_mm,y_mm,t_s\n100,0,0\n110,0,0\n120,0,1\n")
    assert T.read_csv(f).t_s.tolist() == [0, 0, 1]


def test_laps_of_a_path_without_its_start_repeated_go_on_by_the_median_step(tmp_path):
    f = tmp_path / "sq.csv"
    f.write_text("x_mm,y_mm,t_s\n50,10,0\n100,10,1\n100,60,2\n50,60,5\n")
    two = T.read_csv(f).repeated(2)
    assert two.t_s.tolist() == [0, 1, 2, 5, 6, 7, 8, 11]  # period 5 + median step 1, by hand


def test_the_arc_lies_on_the_one_link_leds_circle_of_any_length():
    """--links 140 on the one-link arm: the arc is placed on its reach (forward kinematics:
    the LED's circle of radius 140)."""
    arm = ArmSpec.from_args("one-link", (140.0,))
    t = T.named("arc", arm=arm)
    r = np.hypot(*forward_kinematics(arm, [12.0])["gripper"][:2])
    np.testing.assert_allclose(np.hypot(t.points_mm[:, 0], t.points_mm[:, 1]), r, atol=1e-9)


def test_a_short_csv_path_asked_for_laps_says_it_is_too_short(tmp_path):
    """Fewer than 4 set points cannot tell a closed path: laps are refused for that, not with
    "its last point is not next to its first" (false for a point written twice); a named
    closed path of 3 points still laps."""
    f = tmp_path / "two.csv"
    f.write_text("x_mm,y_mm\n100,100\n100,100\n")
    with pytest.raises(ConfigError, match=r"has 2 set points; a path run in laps needs at least 4"):
        T.read_csv(f).repeated(2)
    assert len(T.named("ellipse-t1", 3).repeated(2).points_mm) == 6


def test_a_robot_log_over_a_mebibyte_is_read_and_one_over_max_points_is_refused(tmp_path):
    """A 12000-row x, y, z, t log at numpy's full precision (1.2 MB) is a trajectory; the limit
    is MAX_POINTS set points (as --points), said with its number, not a file size."""
    from itg_vision.errors import MAX_POINTS

    k = np.arange(12000)
    log = np.column_stack([100 + 20 * np.cos(k / 100), 20 * np.sin(k / 100), 150 + k * 1e-3, k * 0.01])
    big = tmp_path / "log.csv"
    np.savetxt(big, log, delimiter=",", header="x_mm,y_mm,z_mm,t_s", comments="")
    assert big.stat().st_size > 1 << 20
    assert len(T.read_csv(big).points_mm) == 12000
    many = tmp_path / "many.csv"
    many.write_text("x_mm,y_mm\n" + "1,2\n" * (MAX_POINTS + 1))
    with pytest.raises(UserError, match=rf"many.csv: {MAX_POINTS + 1} set points; a trajectory "
                                        rf"holds at most {MAX_POINTS} \(as --points\)"):
        T.read_csv(many)


def test_a_point_held_at_the_base_gets_no_metres_note(tmp_path):
    """span_note's rule: a path within 1 % of the reach of the base may be in metres; a point
    held (every set point the same) has no scale to judge, even at the base itself (it said
    the path 'lies within 0 mm of the base'); a tiny path about the base still gets the note."""
    held = tmp_path / "held.csv"
    held.write_text("x_mm,y_mm\n0,0\n0,0\n0,0\n")
    assert T.span_note(T.read_csv(held), 200.0) is None
    tiny = tmp_path / "tiny.csv"
    tiny.write_text("x_mm,y_mm\n0.1,0\n0,0.1\n-0.1,0\n")
    assert T.span_note(T.read_csv(tiny), 200.0).startswith("note: trajectory ")


def test_laps_are_refused_past_max_points_set_points_in_all(tmp_path):
    """A run holds at most MAX_POINTS set points, laps included: `--points 100000 --laps 1000`
    made 1e8 set points, allocated 2.2 GiB before the first step and would have run out of
    memory (a traceback) after hours in start-up with nothing printed. The refusal names
    --laps, the set points it would make and the most laps of that path; a path that repeats
    its start shares it at each seam, so it fits one lap more than its count suggests."""
    from itg_vision.errors import MAX_POINTS

    t1 = T.named("ellipse-t1")  # 180 set points
    assert len(t1.repeated(MAX_POINTS // 180).points_mm) == 180 * (MAX_POINTS // 180)
    with pytest.raises(ConfigError) as exc:
        t1.repeated(MAX_POINTS // 180 + 1)
    assert exc.value.field == "laps"
    assert exc.value.message == (
        f"{MAX_POINTS // 180 + 1} laps of the 180 set points of trajectory ellipse-t1 make "
        f"{180 * (MAX_POINTS // 180 + 1)}; a run holds at most {MAX_POINTS} set points (as "
        f"--points): at most {MAX_POINTS // 180} laps of this path")
    with pytest.raises(ConfigError, match=r"make 100000000; .* at most 1 lap of this path$"):
        T.named("ellipse-t1", MAX_POINTS).repeated(1000)
    f = tmp_path / "loop.csv"  # 201 set points, the last its first: 200 more a lap
    a = np.radians(np.arange(201) * 1.8)
    np.savetxt(f, np.c_[100 * np.cos(a), 100 * np.sin(a)], fmt="%.6f", delimiter=",",
               header="x_mm,y_mm", comments="")
    loop = T.read_csv(f)
    assert loop.closed and len(loop.repeated(499).points_mm) == 499 * 200 + 1 <= MAX_POINTS
    with pytest.raises(ConfigError, match=r"make 100001; .* at most 499 laps of this path$"):
        loop.repeated(500)


def test_times_beyond_max_time_s_are_refused_and_a_thousand_laps_stay_finite(tmp_path):
    """t_s was read up to the largest double: a closed path timed up to 1.7e308 s, in 3 laps,
    wrote 'inf' times into trace.csv (numpy's overflow warning on stderr). A time is refused
    beyond MAX_TIME_S at its line, as a coordinate beyond MAX_COORD_MM; at that bound the
    most laps (1000) keep every time finite."""
    a = np.radians(np.arange(20) * 18.0)
    x, y = 60 + 40 * np.cos(a), 60 + 40 * np.sin(a)
    f = tmp_path / "timed.csv"
    np.savetxt(f, np.c_[x, y, np.linspace(0, 1.7e308, 20)], fmt="%.17g", delimiter=",",
               header="x_mm,y_mm,t_s", comments="")
    with pytest.raises(UserError, match=r"timed.csv:3: field t_s: 8\.94.* is beyond \+-1e\+18 s$"):
        T.read_csv(f)
    np.savetxt(f, np.c_[x, y, np.linspace(-T.MAX_TIME_S, T.MAX_TIME_S, 20)], fmt="%.17g",
               delimiter=",", header="x_mm,y_mm,t_s", comments="")
    laps = T.read_csv(f).repeated(1000)
    assert np.all(np.isfinite(laps.t_s)) and np.all(np.diff(laps.t_s) >= 0)
