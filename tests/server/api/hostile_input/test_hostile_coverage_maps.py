"""Hostile coverage map requests: grids and images over their caps are refused, the largest
accepted ones cost bounded memory, and one unusable camera is reported while the rest of the
space is served."""

from __future__ import annotations

import json
import sqlite3

import pytest

from tests.support.hostile_requests import RSS_BOUND_MB


def test_the_coverage_map_refuses_a_grid_or_image_over_its_caps(case, home):
    space = home["space"]["id"]
    # A 6400 x 4800 PNG (spacing 0.05 m, scale 40 over 8 x 6 m; a 16000 x 12000 PNG at
    # spacing 0.02 is refused for its cells already).
    status, _, problem, growth, _ = case.send(
        "GET", f"/api/v1/maps/coverage?space_id={space}&spacing=0.05&format=png&scale=40"
    )
    assert status == 422
    assert "pixels" in problem["detail"] and "limit" in problem["detail"]
    assert growth < RSS_BOUND_MB
    case.next_request_answered()
    # The finest grid: refused naming the cell limit.
    status, _, problem, growth, _ = case.send(
        "GET", f"/api/v1/maps/coverage?space_id={space}&spacing=0.02"
    )
    assert status == 422
    assert "cells" in problem["detail"] and "limit" in problem["detail"]
    case.next_request_answered()


@pytest.mark.parametrize(
    "query",
    [
        "spacing=0.022&format=json",  # 364 x 273 = 99,372 cells, 5 cameras
        "spacing=0.022&format=png&scale=7",  # the same as a 2548 x 1911 PNG
        "spacing=0.1&format=png&scale=35",  # 80 x 60 cells as a 2800 x 2100 PNG
    ],
)
def test_the_largest_coverage_maps_accepted_cost_bounded_memory(case, home, query):
    # Just inside the caps (100,000 cells, 400,000 camera-cells, 6,000,000 PNG pixels).
    space = home["space"]["id"]
    status, _, body, growth, _ = case.send("GET", f"/api/v1/maps/coverage?space_id={space}&{query}")
    assert status == 200, body
    assert growth < RSS_BOUND_MB, growth
    case.next_request_answered()


def test_one_unusable_camera_is_reported_and_the_rest_of_the_space_served(case, home, service):
    # Rows written before the checks existed (or by another tool): the read names them.
    space = home["space"]["id"]
    with sqlite3.connect(service.data_dir / "intspace.sqlite3") as db:
        db.execute(
            "INSERT INTO cameras (space_id, name, width, height, K, dist, T_world_camera, status,"
            " created_at, updated_at) VALUES (?, 'tiny-f', 1280, 720, ?, NULL, ?, 'nominal',"
            " CURRENT_TIMESTAMP, CURRENT_TIMESTAMP)",
            (
                space,
                json.dumps([[1e-300, 0, 640], [0, 1e-300, 360], [0, 0, 1]]),
                json.dumps([[1, 0, 0, 4], [0, -1, 0, 3], [0, 0, -1, 2.6], [0, 0, 0, 1]]),
            ),
        )
        (bad,) = db.execute("SELECT max(id) FROM cameras").fetchone()
    try:
        status, _, body, growth, _ = case.send("GET", f"/api/v1/maps/coverage?space_id={space}")
        assert status == 200, body
        assert sorted(body["camera_ids"]) == sorted(c["id"] for c in home["cameras"])
        assert "unusable camera model" in body["cameras_refused"][str(bad)]
        assert growth < RSS_BOUND_MB
        case.next_request_answered()
    finally:
        with sqlite3.connect(service.data_dir / "intspace.sqlite3") as db:
            db.execute("DELETE FROM cameras WHERE id = ?", (bad,))
