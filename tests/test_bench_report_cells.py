"""The noise benchmark's report.md cells and conclusion lines against the raw rows: each cell
is a statistic worked out here by hand or by numpy on the rows it summarizes (a mutation audit
found that the tables' order, quartiles, tie band and the conclusion's choices could change
without a test failing: the end-to-end tests check the report's structure, not its numbers)."""

from __future__ import annotations

import numpy as np

from itg_vision.bench.report import _ratio, _table, _tail_table, conclusion, summarize

COLUMNS = ("e_av_mm", "e_max_mm", "track_median_mm", "track_mean_mm", "track_p95_mm",
           "track_max_mm")


def _row(controller, condition, seed, diverged=False, **metrics):
    row = {"trajectory": "ellipse-t1", "condition": condition, "controller": controller,
           "seed": str(seed), "diverged": str(int(diverged)), "no_start": "",
           **{c: "1" for c in COLUMNS}}
    row.update({k: str(v) for k, v in metrics.items()})
    return row


def _conclusion(rows, conds, ctrls) -> list[str]:
    return conclusion(summarize(rows), ["ellipse-t1"], conds, ctrls)


def test_a_cell_is_the_median_and_quartiles_interpolated_between_seeds():
    """Two seeds (a cell whose other runs did not start): the median is their mean, the
    quartiles a quarter of the way in; three seeds 1, 2, 10: q1 1.5, median 2, q3 6 (by hand).
    numpy's 'nearest' method would give a 2-seed cell its lower seed as the median."""
    s = summarize([_row("ik", "clean", i, e_av_mm=v) for i, v in enumerate((1, 3))])
    assert s["ellipse-t1", "clean", "ik"]["e_av"] == (2.0, 1.5, 2.5)
    rows = [_row("ik", "clean", i, e_av_mm=v) for i, v in enumerate((1, 2, 10))]
    assert summarize(rows)["ellipse-t1", "clean", "ik"]["e_av"] == (2.0, 1.5, 6.0)
    assert _table(summarize(rows), "ellipse-t1", ["clean"], ["ik"], "e_av")[2] == \
        "| clean | 2 [1.5, 6] |"


def test_a_cell_under_a_hundredth_of_a_mm_keeps_three_significant_digits():
    """The one-link arm's clean tracking medians over 4 seeds, 0.0072-0.0084 mm (README):
    written "7e-03" and "8e-03", one digit, while every other cell keeps three; the `ik`
    quick-sweep cell 1.25e-06 mm read "1e-06"."""
    rows = [_row("itg-plus-vision", "clean", i, e_av_mm=v)
            for i, v in enumerate((0.0072, 0.0075, 0.0081, 0.0084))]
    med, q1, q3 = (np.median([0.0072, 0.0075, 0.0081, 0.0084]),
                   *np.percentile([0.0072, 0.0075, 0.0081, 0.0084], [25, 75]))
    assert _table(summarize(rows), "ellipse-t1", ["clean"], ["itg-plus-vision"], "e_av")[2] == \
        f"| clean | {med:.3g} [{q1:.3g}, {q3:.3g}] |"  # 0.0078 [0.00742, 0.00817]
    rows = [_row("ik", "clean", 0, e_av_mm=1.25e-6)]
    assert _table(summarize(rows), "ellipse-t1", ["clean"], ["ik"], "e_av")[2] == \
        "| clean | 1.25e-06 [1.25e-06, 1.25e-06] |"


def test_a_tail_cell_is_median_mean_p95_max_in_that_order_then_the_worst_seed():
    raw = {"track_median_mm": (1, 2, 3), "track_mean_mm": (4, 5, 60), "track_p95_mm": (7, 8, 9),
           "track_max_mm": (10, 11, 12)}
    rows = [_row("ik", "clean", i, **{c: v[i] for c, v in raw.items()}) for i in range(3)]
    line = _tail_table(summarize(rows), "ellipse-t1", ["clean"], ["ik"])[2]
    medians = " / ".join(f"{np.median(raw[c]):g}" for c in raw)
    assert line == f"| clean | {medians} ({max(raw['track_max_mm']):g}) |"  # 2 / 5 / 8 / 11 (12)


def test_a_tie_is_within_five_percent_of_the_larger_plus_a_hundredth():
    """|1 - 1.062| = 0.062 <= 0.05 x 1.062 + 0.01 = 0.0631: a tie (5 % of the smaller, 0.06,
    would call it a win)."""
    rows = [_row(k, "clean", s, **{c: v for c in COLUMNS})
            for k, v in (("itg-vision", 1.0), ("ik", 1.062)) for s in range(3)]
    text = "\n".join(_conclusion(rows, ["clean"], ["itg-vision", "ik"]))
    assert "lower in 0 of 1 cells, higher in 0, within 5 % of the larger + 0.01 mm in 1" in text


def test_the_largest_loss_is_the_largest_ratio_not_the_largest_difference():
    rows = [_row(k, c, s, **{col: v for col in COLUMNS})
            for c, pair in (("clean", (10.0, 9.0)), ("links+5%", (0.5, 0.1)))
            for k, v in zip(("itg-vision", "ik"), pair) for s in range(3)]
    text = "\n".join(_conclusion(rows, ["clean", "links+5%"], ["itg-vision", "ik"]))
    assert "largest loss: links+5% on ellipse-t1, 0.5 against 0.1 mm, 5x" in text


def test_the_tail_line_compares_the_medians_of_the_max():
    """itg-vision's max 5, 6, 7 (median 6) against ik's 1, 2, 20, 21, 22 (median 20): lower;
    its p95 is higher and its first quartile (5.5 against 2) too, so a line that read either
    would say higher."""
    rows = [_row("itg-vision", "clean", s, track_max_mm=m, track_p95_mm=9)
            for s, m in enumerate((5, 6, 7))]
    rows += [_row("ik", "clean", s, track_max_mm=m, track_p95_mm=1)
             for s, m in enumerate((1, 2, 20, 21, 22))]
    tail = next(line for line in _conclusion(rows, ["clean"], ["itg-vision", "ik"])
                if "max E_i (the tail)" in line)
    assert "lower in 1 of 1 cells" in tail


def test_the_model_error_line_is_the_change_of_the_median_under_model_conditions_only():
    rows = [_row("itg-vision", c, s, track_median_mm=med, track_mean_mm=mean)
            for c, med, mean in (("clean", 1, 5), ("links+5%", 3, 50), ("noise-1px", 1, 5))
            for s in range(3)]
    line = next(line for line in _conclusion(rows, ["clean", "links+5%", "noise-1px"],
                                             ["itg-vision"]) if "Model error on" in line)
    assert "itg-vision: links+5% +2.00." in line and "noise-1px" not in line


def test_a_single_diverged_run_is_listed():
    rows = [_row("itg-vision", "clean", s, diverged=s == 0) for s in range(3)]
    assert "itg-vision clean on ellipse-t1: 1 of 3" in "\n".join(
        _conclusion(rows, ["clean"], ["itg-vision"]))


def test_a_model_error_change_that_rounds_to_zero_has_no_minus_sign():
    """A median 0.001 mm lower under links+5% printed '-0.00' (an audit); a change that rounds
    to zero is +0.00, and one that does not keeps its sign."""
    rows = [_row("itg-vision", c, s, track_median_mm=med)
            for c, med in (("clean", 1.0), ("links+5%", 0.999), ("offset-1deg", 0.98))
            for s in range(3)]
    line = next(line for line in _conclusion(rows, ["clean", "links+5%", "offset-1deg"],
                                             ["itg-vision"]) if "Model error on" in line)
    assert "links+5% +0.00" in line and "offset-1deg -0.02" in line and "-0.00" not in line


def test_a_loss_ratio_in_prose_is_a_plain_number():
    """The conclusion's 'largest loss' ratio: two significant digits below 100, whole above,
    never in exponent form (it printed 3.6e+02x)."""
    assert [_ratio(*ab) for ab in ((3.6, 1.0), (36.4, 1.0), (36.0, 0.1), (12345.0, 1.0))] == \
        ["3.6x", "36x", "360x", "12345x"]
    assert _ratio(2.0, 1e-4) == "> 1000x" and _ratio(float("nan"), 1.0) == "n/a"
