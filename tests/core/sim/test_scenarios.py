"""Named scenarios of the twin: network calibration from rendered images, localisation."""

from __future__ import annotations

import pytest

from core.errors import InvalidInput
from core.sim.scenarios import SCENARIOS, localization, network_calibration, run_scenario


@pytest.mark.parametrize("seed", [0, 1])
def test_network_calibration_meets_the_targets(seed: int) -> None:
    r = network_calibration(seed=seed)
    assert r.target_kind == "marker"
    assert not r.rejected
    assert len(r.cameras) == 4
    for c in r.cameras:
        # The spec's targets for the marker kind: focal within 1 %, centre within 2 cm,
        # orientation within 0.3 degrees.
        assert abs(c.focal_error_pct) < 1.0, c
        assert c.position_error_m < 0.02, c
        assert c.rotation_error_deg < 0.3, c
        assert c.poses_seen >= 8
        assert c.rms_px < 1.0


def test_a_camera_seeing_too_few_poses_is_reported_by_name() -> None:
    r = network_calibration(seed=2, spacing=0.6, camera_poses={"cam_kitchen": 3})
    reasons = {x.name: x.reason for x in r.rejected}
    assert "too few poses: saw 3" in reasons["cam_kitchen"]
    # The others still calibrate (the sparse programme may leave the bedroom short too).
    assert {"cam_living_sw", "cam_living_ne"} <= {c.name for c in r.cameras}


def test_localization_ml_reaches_the_bound() -> None:
    r = localization(seed=0)
    assert r.samples >= 1000
    assert r.sigma_px == 0.5
    # ML is efficient: its Monte Carlo RMSE within 5 % of the bound over >= 1000 points
    # (the RMSE's own sampling error is about 1 / sqrt(2 * 1000) ~ 2 %).
    assert abs(r.rmse_m["ml"] / r.crb_rmse_m - 1) < 0.05
    assert r.rmse_m["constrained"] < r.rmse_m["linear"]
    assert r.rmse_m["ml"] <= r.rmse_m["constrained"] * 1.01


def test_unknown_scenario_names_the_known_ones() -> None:
    with pytest.raises(InvalidInput, match="network-calibration"):
        run_scenario("nope")
    assert set(SCENARIOS) >= {"network-calibration", "localization", "localization-images"}
