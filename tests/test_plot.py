"""The figures say what they show: values on log axes are dots (not bars) with their numbers,
values under the axis' floor are marked as such and not joined to a curve, log ticks are plain
decimals, laps and missed markers are told apart, the desired path stays visible, and a 3-D
path has one scale. Each figure is caught before it is written (``plot._save``)."""

from __future__ import annotations

import numpy as np
import pytest

from itg_vision import plot
from itg_vision.contracts import Markers
from itg_vision.loop import SetPointRecord, Trace


@pytest.fixture
def figures(monkeypatch):
    """The figures the module would save, kept open to be read; closed after the test."""
    import matplotlib.pyplot as plt

    made = []
    monkeypatch.setattr(plot, "_save", lambda fig, path: made.append(fig))
    yield made
    for fig in made:
        plt.close(fig)


def _trace(desired, actual, *, planar=True, missed=(), tracking_start=0, gone=(), flagged=()):
    """A trace whose set points ``gone`` the arm cannot reach and ``flagged`` the controller
    flagged out of reach (``missed``: the gripper's marker missed there)."""
    t = Trace(planar=planar, n_joints=2, tracking_start=tracking_start)
    for i, (d, g) in enumerate(zip(desired, actual)):
        d, g = np.asarray(d, float), np.asarray(g, float)
        t.record(SetPointRecord(d, d, Markers(g, g), {"gripper": g, "elbow": g},
                                {"gripper": g, "elbow": g}, np.zeros(2), (),
                                ("missed:gripper",) if i in missed else (),
                                i in flagged or i in gone, i not in gone))
    return t


def test_dots_on_a_log_axis_write_their_values_and_mark_the_floor_and_the_flagged(figures):
    plot.grouped_dots_figure(["clean", "noise"], {"a": [0.5, 1e-6], "b": [20.0, float("nan")]},
                             "E (mm)", "t", "x.png", logy=True,
                             spread={"a": ([0.4, 1e-7], [0.6, 2e-6]), "b": ([10, np.nan], [30, np.nan])},
                             flagged={"a": [False, False], "b": [True, False]}, flag_label="diverged")
    ax = figures[0].axes[0]
    assert not ax.patches  # no bars: a bar's length on a log axis means nothing
    texts = sorted(t.get_text() for t in ax.texts)
    assert texts == ["0.5", "20", "<0.001"]  # NaN: no dot, no number
    # the value under the floor: an open triangle at the floor, not a dot at a made-up value
    below = [ln for ln in ax.lines if ln.get_marker() == "v" and len(ln.get_xdata())]
    assert len(below) == 1 and list(below[0].get_ydata()) == [plot.FLOOR_MM]
    ringed = [ln for ln in ax.lines if ln.get_markersize() == 11 and len(ln.get_xdata())]
    assert len(ringed) == 1 and list(ringed[0].get_ydata()) == [20.0]  # b's clean cell
    labels = ax.get_legend_handles_labels()[1]
    assert "diverged" in labels and "below 0.001 mm, drawn there" in labels
    assert len(ax.collections) == 2  # the whiskers (interquartile ranges) of both series


def test_eight_series_keep_eight_colours_and_an_empty_category_says_so(figures):
    """Each red ring of a flagged series took the next colour of the cycle, so that with
    three flagged among 8 controllers the eighth took the first's blue; a category without a
    value was a blank column."""
    names = [f"k{i}" for i in range(8)]
    values = {k: [1.0 + i, float("nan")] for i, k in enumerate(names)}
    flagged = {k: [i < 3, False] for i, k in enumerate(names)}  # three rings: 11 colours drawn
    plot.grouped_dots_figure(["clean", "links+5%"], values, "E (mm)", "t", "x.png", logy=True,
                             flagged=flagged, flag_label="diverged", empty_label="no run finished")
    plot.lines_figure({k: ([0, 1], [1.0 + i, 2.0 + i]) for i, k in enumerate(names)}, "s",
                      "E (mm)", "t", "y.png", hlines=[(5.0, "limit")])
    for fig in figures:
        ax = fig.axes[0]
        colours = {ln.get_label(): ln.get_color() for ln in ax.lines if ln.get_label() in names}
        assert len(set(colours.values())) == 8, colours
    texts = [t.get_text() for t in figures[0].axes[0].texts]
    assert texts.count("no run finished") == 1


def test_a_curve_is_not_joined_to_a_value_drawn_at_the_floor(figures):
    plot.lines_figure({"ik": ([0, 1, 2], [1e-6, 0.3, 2.0]), "x": ([0, 1, 2], [0.2, 0.3, 0.4])},
                      "s", "E (mm)", "t", "x.png", logy=True)
    ax = figures[0].axes[0]
    ik = next(ln for ln in ax.lines if ln.get_label() == "ik")
    assert np.isnan(ik.get_ydata()[0]) and list(ik.get_ydata()[1:]) == [0.3, 2.0]
    # two series lying on each other stay told apart: their markers differ
    x = next(ln for ln in ax.lines if ln.get_label() == "x")
    assert ik.get_marker() != x.get_marker()


def test_many_laps_share_a_colour_map_and_name_only_the_first_and_last(figures):
    """Past MAX_NAMED_LAPS laps the legend names the first and the last lap only (100 laps
    made a 2019 px tall legend, and colours repeated every 10), each lap still drawn in its own
    colour of a map; the error figure marks about ten lap starts, not 999."""
    a = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    lap = np.c_[100 + 50 * np.cos(a), 50 * np.sin(a), np.zeros(8)]
    d = np.vstack([lap] * 100)
    plot.path_figure(_trace(d, d + [0.5, 0, 0]), "t", "x.png", laps=100)
    ax = figures[0].axes[0]
    named = [t.get_text() for t in ax.get_legend().get_texts()]
    assert [n for n in named if n.startswith("actual")] == [
        "actual gripper, lap 1 (of 100; laps between in the colours between)",
        "actual gripper, lap 100"]
    dots = [ln for ln in ax.lines if ln.get_marker() == "."]
    assert len(dots) == 100 and len({tuple(np.round(ln.get_color(), 6)) for ln in dots}) == 100
    assert list(plot.marked_laps(1000)) == list(range(100, 1000, 100))
    assert list(plot.marked_laps(4)) == [1, 2, 3]  # each lap after the first, as before
    assert plot.lap_style(3, 4) == ("C3", "actual gripper, lap 4")


@pytest.mark.parametrize("planar", [True, False])
def test_a_path_figures_legend_lies_beside_its_axes_and_ticks(figures, planar):
    """Past MAX_NAMED_LAPS laps the first lap's label is long: inside the equal-scaled axes the
    legend was wider than them (``run --laps 12``: it hid a start dot and the y tick 150; a 3-D
    path's hid its top z tick)."""
    a = np.linspace(0, 2 * np.pi, 20, endpoint=False)
    lap = np.c_[20 + 50 * np.cos(a), -30 + 50 * np.sin(a), 150 + 50 * np.sin(a)]
    d = np.vstack([lap] * 12)
    g = d.copy()
    g[:4] = [[100, 170, 250], [160, 95, 300], [170, 0, 280], [130, -80, 200]]  # the start
    plot.path_figure(_trace(d, g, planar=planar), "t", "x.png", laps=12)
    fig = figures[0]
    fig.canvas.draw()
    ax = fig.axes[0]
    box = ax.get_legend().get_window_extent()
    assert not box.overlaps(ax.get_window_extent())
    ticks = [t for axis in (ax.xaxis, ax.yaxis, *((ax.zaxis,) if not planar else ()))
             for t in axis.get_ticklabels() if t.get_text()]
    assert ticks and not any(box.overlaps(t.get_window_extent()) for t in ticks)


def test_log_ticks_are_plain_decimals(figures):
    plot.lines_figure({"a": ([1, 2], [0.002, 60.0])}, "s", "E (mm)", "t", "x.png", logy=True)
    fmt = figures[0].axes[0].yaxis.get_major_formatter()
    assert [fmt(v, 0) for v in (0.005, 0.05, 1.0, 20.0, 50.0)] == ["0.005", "0.05", "1", "20", "50"]


def _labelled_ticks(ax) -> list[float]:
    """The values of the y axis' labelled ticks inside its limits, as drawn."""
    ax.figure.canvas.draw()
    lo, hi = ax.get_ylim()
    return [t.get_position()[1] for t in ax.yaxis.get_ticklabels()
            if t.get_text() and lo <= t.get_position()[1] <= hi]


def test_a_log_axis_under_a_decade_labels_values_across_it(figures):
    """`bench noise --quick`'s E_av against sigma, dropout and link error spans 5.7-42 mm: its
    log axis was labelled at 10 and 20 alone, so the ITG's 36-42 mm could not be read (the dot
    charts write each value beside its dot)."""
    plot.lines_figure({"itg": ([0, 1], [35.7, 41.8]), "ik": ([0, 1], [5.7, 5.7])}, "p",
                      "E_av (mm)", "t", "x.png", logy=True)
    ticks = _labelled_ticks(figures[0].axes[0])
    assert len(ticks) >= 3 and min(ticks) < 10 and max(ticks) > 20, ticks
    # over several decades the 1-2-5 ticks stay
    plot.lines_figure({"a": ([1, 2], [0.002, 60.0])}, "s", "E (mm)", "t", "z.png", logy=True)
    assert _labelled_ticks(figures[-1].axes[0]) == pytest.approx(
        [0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100])


def test_references_are_drawn_without_markers_and_apart_from_the_measurements(figures):
    plot.lines_figure({"f = 0.1": ([100, 1000], [5.0, 0.5])}, "n", "E (mm)", "t", "x.png",
                      logx=True, logy=True, references={"slope -1": ([100, 1000], [4.0, 0.4])})
    ref = next(ln for ln in figures[0].axes[0].lines if ln.get_label() == "slope -1")
    assert ref.get_marker() in ("None", None, "") and ref.get_linestyle() != "-"


def test_a_planar_path_draws_the_desired_path_over_the_laps_it_colours_apart(figures):
    a = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    lap = np.c_[100 + 50 * np.cos(a), 50 * np.sin(a), np.zeros(8)]
    d = np.vstack([lap, lap])
    plot.path_figure(_trace(d, d + [0.5, 0, 0]), "t", "x.png", laps=2)
    ax = figures[0].axes[0]
    by = {ln.get_label(): ln for ln in ax.lines}
    lap1, lap2, desired = (by["actual gripper, lap 1"], by["actual gripper, lap 2"],
                           by["desired"])
    assert len(lap1.get_xdata()) == len(lap2.get_xdata()) == 8
    assert lap1.get_color() != lap2.get_color()
    assert desired.get_zorder() > lap1.get_zorder() > by["base"].get_zorder()


def test_a_3d_path_has_one_scale_for_x_y_and_z(figures):
    d = np.c_[np.linspace(50, 100, 5), np.linspace(0, 20, 5), np.linspace(200, 300, 5)]
    plot.path_figure(_trace(d, d, planar=False), "t", "x.png")
    ax = figures[0].axes[0]
    spans = np.array([np.ptp(ax.get_xlim3d()), np.ptp(ax.get_ylim3d()), np.ptp(ax.get_zlim3d())])
    aspect = np.asarray(ax.get_box_aspect(), float)
    # the box's sides are in the ratio of the millimetres they show (the base at 0 included)
    assert np.allclose(aspect / aspect[2], spans / spans[2], rtol=1e-6)
    assert np.ptp(ax.get_zlim3d()) >= 300  # from the base, z = 0, to the path's top


def test_the_error_figure_marks_missed_markers_and_names_its_scale(figures):
    d = np.c_[np.arange(10.0), np.zeros(10), np.zeros(10)]
    plot.error_figure(_trace(d, d + [0, 1, 0], missed=(3, 7), tracking_start=5), "t", "x.png",
                      laps=2)
    ax = figures[0].axes[0]
    missed = next(ln for ln in ax.lines if ln.get_label().startswith("a marker missed"))
    assert list(missed.get_xdata()) == [3, 7] and "(2 set points)" in missed.get_label()
    assert "linear below 0.01" in ax.get_ylabel()
    assert [t.get_text() for t in ax.texts] == ["lap 2"]


def test_paths_figure_draws_a_jump_dashed_and_leaves_it_out_of_the_desired_path(figures):
    d = np.array([[0, 0, 0], [10, 0, 0], [50, 50, 0], [60, 50, 0]], float)
    plot.paths_figure([("abcd", _trace(d, d), [(1, 2, "jump")])], "t", "x.png")
    ax = figures[0].axes[0]
    desired = [ln for ln in ax.lines if ln.get_color() == "k"]
    assert sorted(len(ln.get_xdata()) for ln in desired) == [2, 2]  # cut between 1 and 2
    jump = next(ln for ln in ax.lines if ln.get_label() == "jump")
    assert jump.get_linestyle() == "--" and list(jump.get_xdata()) == [10, 50]


def test_paths_figure_colours_the_laps_apart(figures):
    """Experiment 2's figure drew two laps as one series: a second lap's flail could not be
    told from the first lap's start transient."""
    a = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    lap = np.c_[100 + 50 * np.cos(a), 50 * np.sin(a), np.zeros(6)]
    d = np.vstack([lap, lap])
    plot.paths_figure([("t1", _trace(d, d + [0.5, 0, 0]))], "t", "x.png", laps=2)
    by = {ln.get_label(): ln for ln in figures[0].axes[0].lines}
    lap1, lap2 = by["actual, lap 1"], by["actual, lap 2"]
    assert len(lap1.get_xdata()) == len(lap2.get_xdata()) == 6
    assert lap1.get_color() != lap2.get_color()


def test_log_axes_say_so_and_thresholds_can_be_drawn_along_x(figures):
    """Ticks 5 and 10 alone read as a linear axis: a log axis's label says log scale. A
    threshold in set points (experiment 1's 5 and 50) is a dashed vertical line."""
    plot.lines_figure({"a": ([1, 2], [0.5, 60.0])}, "n", "E (mm)", "t", "x.png", logx=True,
                      logy=True, vlines=[(1.5, "within 1.5", "C2")])
    plot.grouped_dots_figure(["p"], {"s": [3.0]}, "E (mm)", "t", "y.png", logy=True)
    plot.grouped_dots_figure(["p"], {"s": [3.0]}, "E (mm)", "t", "z.png")
    ax = figures[0].axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("n, log scale", "E (mm), log scale")
    v = next(ln for ln in ax.lines if ln.get_label() == "within 1.5")
    assert list(v.get_xdata()) == [1.5, 1.5] and v.get_linestyle() == "--"
    assert [f.axes[0].get_ylabel() for f in figures[1:]] == ["E (mm), log scale", "E (mm)"]


def test_a_title_holding_bytes_that_are_not_utf8_is_drawn(figures):
    """A file name with a Latin-1 byte reaches the title as a lone surrogate, which matplotlib
    cannot draw: it becomes U+FFFD."""
    d = np.c_[np.arange(3.0), np.zeros(3), np.zeros(3)]
    plot.path_figure(_trace(d, d), "two-link traj\udce9 (table2)", "x.png")
    assert figures[0].axes[0].get_title() == "two-link traj\ufffd (table2)"


# ------------------------------------------------- what each figure draws, in mm
def test_a_planar_path_draws_gripper_desired_and_reach_marks_where_they_are_in_mm(figures):
    """The gripper's laps, the desired path, an unreachable set point (x) and a flagged but
    reachable one (+) are drawn at their own millimetres, the last lap keeping the odd point."""
    n = 7  # odd: two laps of 3 and 4 set points
    d = np.c_[np.linspace(50, 110, n), np.linspace(10, 40, n), np.zeros(n)]
    g = d + [3.0, -2.0, 0.0]
    plot_trace = _trace(d, g, gone=(1,), flagged=(4,))
    plot.path_figure(plot_trace, "t", "x.png", laps=2)
    ax = figures[0].axes[0]
    by = {ln.get_label(): ln for ln in ax.lines}
    lap1, lap2 = by["actual gripper, lap 1"], by["actual gripper, lap 2"]
    np.testing.assert_array_equal(np.r_[lap1.get_xdata(), lap2.get_xdata()], g[:, 0])
    np.testing.assert_array_equal(np.r_[lap1.get_ydata(), lap2.get_ydata()], g[:, 1])
    np.testing.assert_array_equal(by["desired"].get_xydata(), d[:, :2])
    out, flag = by["out of reach"], by["flagged out of reach, reachable"]
    assert out.get_marker() == "x" and out.get_xydata().tolist() == [d[1, :2].tolist()]
    assert flag.get_marker() == "+" and flag.get_xydata().tolist() == [d[4, :2].tolist()]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (mm)", "y (mm)")


def test_a_3d_path_labels_every_axis_in_mm(figures):
    """x, y and z are all in mm."""
    d = np.c_[np.linspace(50, 100, 5), np.linspace(0, 20, 5), np.linspace(200, 300, 5)]
    plot.path_figure(_trace(d, d, planar=False), "t", "x.png")
    ax = figures[0].axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("x (mm)", "y (mm)", "z (mm)")


def test_the_error_figure_draws_e_i_in_mm_its_marks_and_the_tracking_phases_numbers(figures):
    """E_i in mm, a gap at an unreachable set point, missed markers at their E_i, the tracking
    phase's line between its first set point and the one before, its p95 in the legend (numpy's,
    on the set points in reach), log above 0.01 mm."""
    d = np.c_[np.arange(12.0), np.zeros(12), np.zeros(12)]
    off = np.r_[0.005, 0.02, 0.1, 0.5, 1, 2, 3, 4, 5, 6, 50, 7]
    g = d + np.c_[np.zeros(12), off, np.zeros(12)]
    t = _trace(d, g, gone=(10,), missed=(3, 7), tracking_start=6)
    plot.error_figure(t, "t", "x.png")
    ax = figures[0].axes[0]
    curve = ax.lines[0]
    expect = np.where(np.arange(12) == 10, np.nan, off)
    np.testing.assert_allclose(curve.get_ydata(), expect, rtol=1e-12)
    missed = next(ln for ln in ax.lines if ln.get_label().startswith("a marker missed"))
    np.testing.assert_allclose(missed.get_ydata(), off[[3, 7]], rtol=1e-12)
    late = off[6:][np.arange(6, 12) != 10]  # the tracking phase, in reach
    track = next(ln for ln in ax.lines if ln.get_label().startswith("tracking phase"))
    assert list(track.get_xdata()) == [5.5, 5.5]  # between set points 5 and 6
    assert f"p95 {np.percentile(late, 95):.3g} " in track.get_label()
    assert ax.get_ylabel().startswith("E_i (mm)")
    assert ax.yaxis.get_transform().linthresh == 0.01


def test_paths_figure_draws_the_actual_gripper_and_the_jump_between_set_points(figures):
    """The actual path is the gripper's, the jump joins its two set points, x and y in mm."""
    d = np.array([[0, 0, 0], [10, 0, 0], [50, 50, 0], [60, 50, 0]], float)
    g = d + [1.0, 2.0, 0.0]
    plot.paths_figure([("abcd", _trace(d, g), [(1, 2, "jump")])], "t", "x.png")
    ax = figures[0].axes[0]
    by = {ln.get_label(): ln for ln in ax.lines}
    np.testing.assert_array_equal(by["actual"].get_xydata(), g[:, :2])
    np.testing.assert_array_equal(by["jump"].get_xydata(), d[[1, 2], :2])
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (mm)", "y (mm)")


def test_lines_figure_floors_and_says_log_only_on_a_log_y_axis(figures):
    """On a linear y axis (log x) the label says nothing of log and small values are drawn as
    they are."""
    plot.lines_figure({"a": ([1, 2, 3], [0.0, 1e-4, 2.0])}, "n", "E (mm)", "t", "x.png",
                       logx=True)
    ax = figures[0].axes[0]
    assert ax.get_ylabel() == "E (mm)"  # linear
    np.testing.assert_array_equal(ax.lines[0].get_ydata(), [0.0, 1e-4, 2.0])
