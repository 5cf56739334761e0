"""`landmark-pose` on a small study: a calibrated head camera, one obliquity bin, both kinds."""

from __future__ import annotations

import json

import pytest

from core.errors import InvalidInput
from core.sim.landmark_scenarios import landmark_pose


def test_landmark_pose_small_study() -> None:
    r = landmark_pose(None, 3, views_per_bin=2, bins=((40.0, 50.0),), calibration_views=6)
    d = r.to_dict()
    json.dumps(d)  # JSON-ready
    assert d["scenario"] == "landmark-pose" and d["seed"] == 3
    # Zhang calibration from six rendered chessboard views: focal length within 0.5 % and
    # principal point within 3 px of the truth (0.05 px corner noise, 640x480).
    assert abs(d["calibration_focal_error_pct"]) < 0.5
    assert d["calibration_principal_point_error_px"] < 3.0
    assert [b["kind"] for b in d["bins"]] == ["object", "signpost"]
    for b in d["bins"]:
        assert b["views"] == 2
        # 0.5-5 m at 40-50 deg: everything within each kind's limit is located; the object
        # mark beyond 3 m may be missed (not required), so at least one of two is found.
        assert b["located_pct"] >= 50.0
        assert b["position_error_pct_median"] < 1.0  # spec 04: < 1 % of distance
        assert b["normal_error_deg_median"] < 2.0  # spec 04: < 2 deg at 45 deg
        if b["decode_views"]:
            assert b["decoded_pct"] >= b["zxing_raw_pct"]
    with pytest.raises(InvalidInput):
        landmark_pose(None, 0, views_per_bin=0)
