"""python -m itg_vision.paper end to end, and the pieces of its analysis."""

import json

import numpy as np
import pytest

from itg_vision.paper import settle_index


def test_settle_index():
    e = np.array([9, 8, 7, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1.0])
    assert settle_index(e, 2.0) == 3
    assert settle_index(np.full(30, 5.0), 2.0) == 30


@pytest.mark.slow
def test_paper_writes_every_figure_and_a_report(cli, tmp_path):
    res = cli("itg_vision.paper", "--out", tmp_path / "p", "--quiet")
    assert res.returncode == 0, res.stderr
    out = tmp_path / "p"
    r = json.loads((out / "results.json").read_text())
    assert set(r) == {"exp1", "exp2", "exp3", "exp4", "exp5", "exp6"}
    assert r["exp6"]["line-ab"]["n_out_of_reach"] > 0  # B of the paper's line is out of reach
    assert r["exp3"]["e_av_mm"][0] > r["exp3"]["e_av_mm"][-1]  # more set points, less error
    text = (out / "report.md").read_text()
    for k in range(1, 7):
        assert f"| {k} |" in text
    for png in ("exp1_path", "exp3_eav_vs_nt", "exp4_eav_vs_f", "exp5_second_lap", "exp6_line_ab"):
        assert (out / f"{png}.png").stat().st_size > 5000
