"""The semantic and navigation maps: re-reads update and never duplicate; routes between rooms."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.rotations import rotvec_to_matrix
from core.landmarks import ObjectMark, Signpost
from core.landmarks.detect import LandmarkDetection
from core.landmarks.maps import NavigationMap, NoRoute, SemanticMap, detection_in_world

CUP = ObjectMark(1, "cup", "blue cup", "kitchen")


def _T(p: list[float], rv: list[float] | None = None) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(rv or [0.0, 0.0, 0.0])
    T[:3, 3] = p
    return T


def test_rereading_fuses_and_never_duplicates() -> None:
    m = SemanticMap()
    rng = np.random.default_rng(0)
    truth = np.array([2.0, 1.0, 0.8])
    sd = 0.01
    cov = np.diag([1e-4] * 3 + [sd**2] * 3)
    errs = []
    for k in range(16):
        obj = m.observe(CUP, _T(list(truth + rng.normal(0, sd, 3))), cov, float(k))
        errs.append(np.linalg.norm(obj.position - truth))
    assert len(m) == 1 and m[1].reads == 16 and m[1].last_seen == 15.0
    # Sixteen equal-weight reads: the fused covariance is the single one over 16, and the
    # fused position is their mean (standard error 1 cm / 4 per axis).
    assert np.allclose(np.diag(m[1].cov)[3:], sd**2 / 16)
    assert errs[-1] < 4 * sd / 4 * np.sqrt(3)
    assert m[1].confidence == pytest.approx(1 - 0.5**16)
    # A re-read with new payload fields updates them.
    m.observe(ObjectMark(1, "mug", "blue mug", "lounge"), _T(list(truth)), cov, 20.0)
    assert len(m) == 1 and m[1].name == "blue mug" and m[1].room == "lounge"
    m.observe(ObjectMark(2, "remote", "tv remote", "lounge"), _T([5, 1, 0.5]), cov, 21.0)
    assert len(m) == 2
    fc = m.to_dict()
    json.dumps(fc)
    assert [f["properties"]["id"] for f in fc["features"]] == [1, 2]


def test_fusion_weights_by_information() -> None:
    m = SemanticMap()
    precise = np.diag([1e-4] * 3 + [1e-6] * 3)
    rough = np.diag([1e-2] * 3 + [1e-2] * 3)
    m.observe(CUP, _T([1.0, 0.0, 0.0]), precise, 0.0)
    obj = m.observe(CUP, _T([2.0, 0.0, 0.0], [0.0, 0.0, 0.5]), rough, 1.0)
    # Position weights 1e6 and 1e2, rotation weights 1e4 and 1e2: information-weighted means.
    assert obj.position[0] == pytest.approx(1.0 + 1e2 / (1e6 + 1e2))
    angle = np.linalg.norm(np.array([0.0, 0.0, 0.5]) * 1e2 / (1e4 + 1e2))
    R = obj.T_world_mark[:3, :3]
    assert np.degrees(np.arccos((np.trace(R) - 1) / 2)) == pytest.approx(np.degrees(angle))


def test_maps_reject_the_other_kind_and_bad_input() -> None:
    cov = np.eye(6) * 1e-4
    with pytest.raises(InvalidInput):
        SemanticMap().observe(Signpost(1, "door", "hall"), _T([0, 0, 0]), cov, 0.0)  # type: ignore[arg-type]
    with pytest.raises(InvalidInput):
        NavigationMap().observe(CUP)  # type: ignore[arg-type]
    with pytest.raises(InvalidInput):
        SemanticMap().observe(CUP, np.eye(4) * 2, cov, 0.0)
    with pytest.raises(InvalidInput):
        SemanticMap().observe(CUP, np.eye(4), -cov, 0.0)


def _places() -> list[Signpost]:
    # hall (10) -- kitchen door (11) -- kitchen (12); hall (10) -- lounge door (13) -- lounge
    # (14); the kitchen and the lounge joined only through the hall.
    q = (0.0, 0.0, 0.0, 1.0)
    return [
        Signpost(10, "hall", "hall", (0.0, 0.0, 1.2, *q), (11, 13)),
        Signpost(11, "kitchen door", "hall", (3.0, 0.0, 1.2, *q), (10, 12)),
        Signpost(12, "kitchen", "kitchen", (4.0, 0.0, 1.2, *q), (11,)),
        Signpost(13, "lounge door", "hall", (0.0, 3.0, 1.2, *q), (10, 14)),
        Signpost(14, "lounge", "lounge", (0.0, 4.0, 1.2, *q), (13,)),
    ]


def test_routes_between_rooms() -> None:
    nav = NavigationMap()
    for p in _places():
        assert nav.observe(p)
    assert not nav.observe(_places()[0])  # re-read: no new place
    assert len(nav) == 5 and nav.rooms == ["hall", "kitchen", "lounge"]
    r = nav.route("kitchen", "lounge")
    # kitchen -> kitchen door -> lounge door (same room: the hall is open) -> lounge.
    assert r.places == (12, 11, 13, 14)
    assert r.length_m == pytest.approx(1.0 + np.hypot(3.0, 3.0) + 1.0)
    assert nav.route("hall", "kitchen").places[-1] == 12
    fc = nav.to_dict()
    json.dumps(fc)
    kinds = [f["properties"]["kind"] for f in fc["features"]]
    assert kinds.count("place") == 5 and kinds.count("edge") == 5
    with pytest.raises(NoRoute):
        nav.route("kitchen", "garage")


def test_edges_wait_for_both_ends() -> None:
    nav = NavigationMap()
    p = _places()
    nav.observe(p[2])  # kitchen, neighbour 11 not yet read
    nav.observe(p[4])  # lounge
    with pytest.raises(NoRoute):
        nav.route("kitchen", "lounge")
    for s in [*p[:2], p[3]]:
        nav.observe(s)
    assert nav.route("kitchen", "lounge").places == (12, 11, 13, 14)


def test_detection_in_world_composes_pose_and_rotates_covariance() -> None:
    T_cam_mark = _T([0.1, 0.0, 1.0], [0.0, 0.3, 0.0])
    cov = np.diag([1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 3e-6])
    det = LandmarkDetection("object", np.zeros((4, 2)), T_cam_mark, cov, CUP, None)
    T_world_cam = _T([1.0, 2.0, 1.1], [0.0, 0.0, np.pi / 2])
    T, C = detection_in_world(det, T_world_cam)
    assert np.allclose(T, T_world_cam @ T_cam_mark)
    # A quarter turn about z swaps the x and y position variances.
    assert np.allclose(np.diag(C)[3:], [2e-6, 1e-6, 3e-6])
