"""Landmarks over REST: printable artwork at true size, detection in an uploaded image (rendered
by the twin's landmark renderer with known truth), and the semantic and navigation maps stored
in the database (SQLite and PostgreSQL)."""

from __future__ import annotations

import re
import struct
from functools import cache

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from core.landmarks import ObjectMark, Signpost, encode_payload
from core.landmarks.artwork import make_artwork
from core.sim.render import SensorNoise
from core.sim.render.landmarks import artwork_texture, render_landmarks
from server.app import create_app
from tests.support.landmark_views import HEAD_CAMERA as CAM
from tests.support.landmark_views import HEAD_DIST as DIST
from tests.support.landmark_views import HEAD_K as K
from tests.support.landmark_views import mark_pose

CUP = ObjectMark(7, "cup", "blue cup", "kitchen", (0.08, 0.08, 0.1), hints=("fragile",))
DOOR = Signpost(3, "kitchen door", "kitchen", (1.0, 2.0, 1.2, 0, 0, 0, 1), (4,))
HALL = Signpost(4, "hall door", "hall", (3.0, 2.0, 1.2, 0, 0, 0, 1), (3,))
BED = Signpost(9, "bedroom door", "bedroom", (6.0, 5.0, 1.2, 0, 0, 0, 1), ())


T_CUP = mark_pose(20.0, 30.0, [-0.12, 0.0, 0.45], 0.3)
T_DOOR = mark_pose(80.0, 30.0, [0.16, 0.0, 0.55], -0.4)


@cache
def _view_png() -> bytes:
    """Return a PNG of the cup's object mark and the kitchen door's signpost, 30 deg oblique,
    with the twin's default sensor noise (seed 3); lossless, so the service sees the pixels
    the truth describes."""
    arts = [make_artwork(CUP), make_artwork(DOOR)]
    view = render_landmarks(
        CAM,
        [(artwork_texture(a), T, a.size, None) for a, T in zip(arts, (T_CUP, T_DOOR), strict=True)],
        noise=SensorNoise(),
        rng=3,
    )
    ok, buf = cv2.imencode(".png", view.image)
    assert ok
    return buf.tobytes()


def _landmark(client: TestClient, admin, payload: str, size: float, kind: str = "qr") -> int:
    body = {"kind": kind, "payload": payload, "size_m": size}
    response = client.post("/api/v1/landmarks", json=body, headers=admin)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _field(response) -> str:
    return response.json()["errors"][0]["field"]


# Printing


def test_print_svg_pdf_png_at_true_size(client: TestClient, admin) -> None:
    cup = _landmark(client, admin, encode_payload(CUP), 0.10)
    svg = client.get(f"/api/v1/landmarks/{cup}/print.svg", headers=admin)
    assert svg.status_code == 200 and svg.headers["content-type"].startswith("image/svg+xml")
    # The page: the 100 mm frame, a 10 mm margin each side and a 20 mm label band.
    assert re.search(r'<svg [^>]*width="120mm" height="140mm" viewBox="0 0 120 140"', svg.text)
    # The blue frame's outer square measures 100 mm in the file's millimetre units.
    assert re.search(r'id="frame" fill="#0000ff"[^>]* d="M10 10h100v100h-100z', svg.text)
    assert "#7 blue cup" in svg.text

    door = _landmark(client, admin, encode_payload(DOOR), 0.20)
    svg = client.get(f"/api/v1/landmarks/{door}/print.svg", headers=admin).text
    # The outer ring's outer edge: radius 100 mm (a 200 mm diameter) around the centre.
    assert '<circle cx="120" cy="120" r="100" fill="#ff0000"/>' in svg

    pdf = client.get(f"/api/v1/landmarks/{cup}/print.pdf", headers=admin)
    assert pdf.status_code == 200 and pdf.headers["content-type"] == "application/pdf"
    assert pdf.content.startswith(b"%PDF")
    box = re.search(rb"/MediaBox \[0 0 ([0-9.]+) ([0-9.]+)\]", pdf.content)
    assert box is not None
    # 120 x 140 mm in points (72 per inch), to the 0.01 pt fpdf2 prints.
    assert abs(float(box[1]) - 120 / 25.4 * 72) < 0.01
    assert abs(float(box[2]) - 140 / 25.4 * 72) < 0.01

    png = client.get(f"/api/v1/landmarks/{cup}/print.png?pixels_per_metre=4000", headers=admin)
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    width, height = struct.unpack(">II", png.content[16:24])
    assert (width, height) == (480, 560)  # 120 x 140 mm at 4 px/mm
    i = png.content.index(b"pHYs")
    assert struct.unpack(">IIB", png.content[i + 4 : i + 13]) == (4000, 4000, 1)
    image = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_COLOR)
    # Pure blue along the frame's band (row 60 px = 15 mm: inside the 12 mm band from 10 mm).
    assert tuple(image[60, 240]) == (255, 0, 0)


def test_print_refuses_what_cannot_be_printed(client: TestClient, admin) -> None:
    foreign = _landmark(client, admin, "https://example.com/p/42", 0.1)
    response = client.get(f"/api/v1/landmarks/{foreign}/print.svg", headers=admin)
    assert response.status_code == 422 and _field(response) == "payload"
    assert "foreign" in response.json()["errors"][0]["reason"]

    text = encode_payload(CUP)
    corrupt = _landmark(client, admin, text.replace("blue", "bleu"), 0.1)
    response = client.get(f"/api/v1/landmarks/{corrupt}/print.pdf", headers=admin)
    assert response.status_code == 422 and "checksum" in response.json()["errors"][0]["reason"]

    aruco = _landmark(client, admin, text, 0.1, kind="aruco")
    response = client.get(f"/api/v1/landmarks/{aruco}/print.png", headers=admin)
    assert response.status_code == 422 and _field(response) == "kind"

    huge = _landmark(client, admin, text, 50.0)  # the registry takes it; no artwork is 50 m
    response = client.get(f"/api/v1/landmarks/{huge}/print.svg", headers=admin)
    assert response.status_code == 422 and _field(response) == "size_m"

    sign = _landmark(client, admin, encode_payload(DOOR), 1.0)
    response = client.get(f"/api/v1/landmarks/{sign}/print.png", headers=admin)
    assert response.status_code == 422 and _field(response) == "pixels_per_metre"

    assert client.get("/api/v1/landmarks/999/print.svg", headers=admin).status_code == 404
    assert client.get(f"/api/v1/landmarks/{sign}/print.svg").status_code == 401


# Detection


def _rotation_deg(R: np.ndarray, R_true: np.ndarray) -> float:
    c = (np.trace(R.T @ R_true) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def test_detect_with_K_locates_and_reads_both_kinds(client: TestClient, admin) -> None:
    import json

    files = {"image": ("view.png", _view_png(), "image/png")}
    data = {"K": json.dumps(K), "dist": json.dumps(DIST)}
    response = client.post("/api/v1/landmarks/detect", files=files, data=data, headers=admin)
    assert response.status_code == 200, response.text
    body = response.json()
    assert (body["width"], body["height"]) == (640, 480)
    found = {d["kind"]: d for d in body["detections"]}
    assert sorted(found) == ["object", "signpost"] and len(body["detections"]) == 2
    for kind, record, T in (("object", CUP, T_CUP), ("signpost", DOOR, T_DOOR)):
        det = found[kind]
        assert det["reason"] is None and det["record"]["id"] == record.id
        assert det["record"]["kind"] == kind and det["record"]["name"] == record.name
        assert det["text"] == encode_payload(record)
        est = np.array(det["T_cam_mark"])
        d = np.linalg.norm(T[:3, 3])
        # Spec 04's bounds (position < 1 % of distance, orientation < 2 deg, met there at 45 deg
        # and 3-5 m); measured on this view over noise seeds 1-10: 0.058-0.070 % and
        # < 0.11 deg (both decoded every time).
        assert np.linalg.norm(est[:3, 3] - T[:3, 3]) / d < 0.01
        assert _rotation_deg(est[:3, :3], T[:3, :3]) < 2.0
        cov = np.array(det["cov"])
        assert cov.shape == (6, 6) and np.linalg.eigvalsh(cov).min() > 0
        assert len(det["outline"]) >= 4
        # The symbol is read here: the image decides the pose. A signpost gives both of its
        # rings' poses, the first the reported one, their probabilities summing to 1.
        assert det["decided"] is True
        hyps = det["hypotheses"]
        if kind == "object":
            assert hyps == []
        else:
            assert len(hyps) == 2 and np.allclose(hyps[0]["T_cam_mark"], est)
            assert hyps[0]["probability"] >= 0.99
            assert abs(sum(h["probability"] for h in hyps) - 1.0) < 1e-9


def test_detect_with_a_registered_camera_and_bad_input(client: TestClient, admin) -> None:
    url = "/api/v1/landmarks/detect"
    png = _view_png()
    bare = client.post(
        "/api/v1/cameras", json={"name": "head", "width": 640, "height": 480}, headers=admin
    ).json()["id"]
    files = {"image": ("view.png", png, "image/png")}
    response = client.post(url, files=files, data={"camera_id": bare}, headers=admin)
    assert response.status_code == 409 and "no intrinsics" in response.text
    cam = client.post(
        "/api/v1/cameras",
        json={"name": "head2", "width": 640, "height": 480, "K": K, "dist": DIST},
        headers=admin,
    ).json()["id"]
    response = client.post(url, files=files, data={"camera_id": cam}, headers=admin)
    assert response.status_code == 200, response.text
    assert sorted(d["record"]["id"] for d in response.json()["detections"]) == [3, 7]

    # Neither or both of camera_id and K; a malformed K; an unknown camera.
    response = client.post(url, files=files, headers=admin)
    assert response.status_code == 422 and _field(response) == "camera_id"
    response = client.post(url, files=files, data={"camera_id": cam, "K": "[]"}, headers=admin)
    assert response.status_code == 422
    response = client.post(url, files=files, data={"K": "[[1, 2], [3]]"}, headers=admin)
    assert response.status_code == 422 and _field(response) == "K"
    response = client.post(url, files=files, data={"K": "[[0,0,1],[0,1,1],[0,0,1]]"}, headers=admin)
    assert response.status_code == 422 and _field(response) == "K"
    assert client.post(url, files=files, data={"camera_id": 999}, headers=admin).status_code == 404
    # An image of another size than the camera's.
    small = cv2.imencode(".png", np.zeros((100, 120, 3), np.uint8))[1].tobytes()
    response = client.post(
        url, files={"image": ("s.png", small, "image/png")}, data={"camera_id": cam}, headers=admin
    )
    assert response.status_code == 409 and _field(response) == "image"
    # Not an image: 415; a header declaring a huge image: 413, refused before decoding.
    response = client.post(
        url,
        files={"image": ("x.png", b"not an image", "image/png")},
        data={"K": str(K)},
        headers=admin,
    )
    assert response.status_code == 415
    huge = bytearray(png[:33])
    huge[16:24] = struct.pack(">II", 100_000, 100_000)
    response = client.post(
        url,
        files={"image": ("h.png", bytes(huge), "image/png")},
        data={"K": str(K)},
        headers=admin,
    )
    assert response.status_code == 413
    # A truncated PNG whose header is fine: OpenCV cannot decode it.
    response = client.post(
        url,
        files={"image": ("t.png", png[:2000], "image/png")},
        data={"K": str(K)},
        headers=admin,
    )
    assert response.status_code == 415
    # Writes need a token.
    assert client.post(url, files=files, data={"K": str(K)}).status_code == 401


# The maps

POSE_CAM = np.eye(4)
POSE_CAM[:3, 3] = [1.0, 2.0, 1.5]


def _observation(record, T_cam_mark: np.ndarray, sd_m: float, **extra) -> dict:
    cov = np.diag([1e-4] * 3 + [sd_m**2] * 3)
    return {
        "payload": encode_payload(record),
        "T_cam_mark": T_cam_mark.tolist(),
        "cov": cov.tolist(),
        **extra,
    }


def _space(client: TestClient, admin) -> int:
    return client.post("/api/v1/spaces", json={"name": "home"}, headers=admin).json()["id"]


def test_rereading_fuses_never_duplicates_and_survives_a_restart(
    client: TestClient, admin, make_settings
) -> None:
    space = _space(client, admin)
    url = "/api/v1/maps/observations"
    T1 = T_CUP.copy()
    T2 = T_CUP.copy()
    T2[:3, 3] += [0.02, 0.0, 0.0]  # a second read 2 cm off, equally certain
    first = client.post(
        url,
        json={"observations": [_observation(CUP, T1, 0.01, T_world_camera=POSE_CAM.tolist())]},
        headers=admin,
    )
    assert first.status_code == 200, first.text
    assert first.json()["changes"] == [{"map": "semantic", "mark_id": 7, "change": "added"}]
    again = client.post(
        url,
        json={
            "space_id": space,
            "observations": [
                _observation(CUP, T2, 0.01, T_world_camera=POSE_CAM.tolist(), time=2e9)
            ],
        },
        headers=admin,
    )
    assert again.json()["changes"][0]["change"] == "updated"
    features = client.get("/api/v1/maps/semantic", headers=admin).json()["features"]
    assert len(features) == 1
    p = features[0]["properties"]
    assert (p["id"], p["class"], p["room"], p["reads"]) == (7, "cup", "kitchen", 2)
    assert p["confidence"] == 0.75 and p["last_seen"] == 2e9
    # Two equally certain reads: the fused position is their mean (information weighting),
    # in the world: the camera at (1, 2, 1.5) with the identity rotation.
    want = POSE_CAM[:3, 3] + (T1[:3, 3] + T2[:3, 3]) / 2
    assert np.allclose(np.array(p["T_world_mark"])[:3, 3], want, atol=1e-9)
    assert features[0]["geometry"]["coordinates"] == pytest.approx(want[:2].tolist())
    # Fusing two equal reads halves the variance: sd 1 cm -> 0.707 cm.
    assert p["position_sd_m"] == pytest.approx([0.01 / np.sqrt(2)] * 3, rel=1e-9)

    # A foreign payload and a camera without a pose: 422 naming them, nothing stored changes.
    bad = _observation(CUP, T1, 0.01, T_world_camera=POSE_CAM.tolist())
    bad["payload"] = "https://example.com"
    good = _observation(CUP, T1, 0.01, T_world_camera=POSE_CAM.tolist())
    response = client.post(url, json={"observations": [good, bad]}, headers=admin)
    assert response.status_code == 422 and _field(response) == "observations.1.payload"
    cam = client.post(
        "/api/v1/cameras", json={"name": "c", "width": 640, "height": 480}, headers=admin
    ).json()["id"]
    response = client.post(
        url, json={"observations": [_observation(CUP, T1, 0.01, camera_id=cam)]}, headers=admin
    )
    assert response.status_code == 422 and "no pose" in response.text
    response = client.post(
        url,
        json={"observations": [_observation(CUP, T1, 0.01)]},  # neither pose nor camera
        headers=admin,
    )
    assert response.status_code == 422
    after = client.get("/api/v1/maps/semantic", headers=admin).json()["features"]
    assert after == features

    # A new app on the same database (a restart) serves the same map.
    with TestClient(create_app(make_settings())) as restarted:
        again_features = restarted.get("/api/v1/maps/semantic", headers=admin).json()["features"]
    assert again_features == features


def test_navigation_map_and_routes_between_rooms(client: TestClient, admin) -> None:
    url = "/api/v1/maps/observations"
    assert client.get("/api/v1/maps/navigation", headers=admin).status_code == 409  # no space
    _space(client, admin)
    observations = [
        _observation(r, T_DOOR, 0.01, T_world_camera=POSE_CAM.tolist()) for r in (DOOR, BED)
    ]
    response = client.post(url, json={"observations": observations}, headers=admin)
    assert response.status_code == 200, response.text
    assert response.json()["navigation_edges"] == 0
    # The hall is not in the map yet: 404 naming it; the bedroom is, but unconnected: 422.
    route = "/api/v1/maps/navigation/route"
    response = client.get(route, params={"from": "kitchen", "to": "hall"}, headers=admin)
    assert response.status_code == 404 and "'hall'" in response.text
    response = client.get(route, params={"from": "kitchen", "to": "bedroom"}, headers=admin)
    assert response.status_code == 422 and "not connected" in response.text

    # Reading the hall door (twice: no duplicate) joins kitchen and hall by their neighbour
    # fields.
    hall = [_observation(HALL, T_DOOR, 0.01, T_world_camera=POSE_CAM.tolist())] * 2
    response = client.post(url, json={"observations": hall}, headers=admin)
    assert [c["change"] for c in response.json()["changes"]] == ["added", "updated"]
    assert response.json()["navigation_edges"] == 1
    nav = client.get("/api/v1/maps/navigation", headers=admin).json()
    places = [f for f in nav["features"] if f["properties"]["kind"] == "place"]
    edges = [f for f in nav["features"] if f["properties"]["kind"] == "edge"]
    assert sorted(p["properties"]["id"] for p in places) == [3, 4, 9]
    assert nav["rooms"] == ["bedroom", "hall", "kitchen"]
    assert len(edges) == 1 and edges[0]["properties"]["via"] == "neighbour"
    assert edges[0]["geometry"]["coordinates"] == [[1.0, 2.0], [3.0, 2.0]]
    response = client.get(route, params={"from": "kitchen", "to": "hall"}, headers=admin)
    assert response.status_code == 200, response.text
    body = response.json()
    # Door to door: from (1, 2, 1.2) to (3, 2, 1.2), 2 m.
    assert body["places"] == [3, 4] and body["rooms"] == ["kitchen", "hall"]
    assert body["length_m"] == pytest.approx(2.0, abs=1e-9)
    assert body["features"]["geometry"]["coordinates"] == [[1.0, 2.0], [3.0, 2.0]]
    assert client.get(route, params={"from": "kitchen"}, headers=admin).status_code == 422
