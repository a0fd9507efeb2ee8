"""The accuracy benchmark's claims, on fewer poses (issue 4, section 7)."""

import pytest

from itg_vision.arm import ArmSpec
from itg_vision.bench.accuracy import measure
from itg_vision.camera import Rig
from itg_vision.runner import CAMERAS_DIR


@pytest.mark.slow
def test_estimation_error_matches_first_order_prediction():
    """Measured RMS within 1.3x of sigma_total^2 (J^T J)^-1 for 0.1-1 px, and <= 0.5 mm at zero
    added noise (bench measured 0.29 mm, ratios 0.92-1.04 on 60 poses). With 20 poses (40
    marker estimates, 120 squared error components) the RMS itself scatters by ~7 %."""
    r = measure(ArmSpec.from_args("two-link"), Rig.from_yaml(CAMERAS_DIR / "planar.yaml"),
                (0.0, 0.1, 0.3, 1.0), n_poses=20, seed=5)
    rows = {row["sigma_px"]: row for row in r["rows"]}
    assert rows[0.0]["measured_rms_mm"] <= 0.5
    for s in (0.1, 0.3, 1.0):
        assert 1 / 1.3 <= rows[s]["ratio"] <= 1.3, rows[s]
    assert r["centroid_rms_px"] < 0.3  # sub-pixel: TECHNICAL.md measures ~0.1-0.2 px
    # the tail: for Gaussian-like errors the 95th percentile of an error's length lies between
    # 1.6 (isotropic in 3-D) and 2.0 (one dominant axis, the depth) times its RMS; an outlier
    # (a wrong match, a rim pixel) or a mis-computed tail would fall outside [1.0, 2.5]
    g = r["marker_p95_mm"]["gripper"] / r["marker_rms_mm"]["gripper"]
    assert 1.0 < g < 2.5 and r["marker_max_mm"]["gripper"] >= r["marker_p95_mm"]["gripper"], g
