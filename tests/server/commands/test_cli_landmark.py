"""`intspace landmark make|detect` end to end on a rendered photo, and its error messages."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import zxingcpp

from core.calibration.io import CalibrationRecord, to_opencv_yaml
from core.geometry.rotations import rotvec_to_matrix
from core.landmarks import ObjectMark, decode_payload
from core.landmarks.artwork import make_artwork
from core.sim.render import SensorNoise
from core.sim.render.landmarks import artwork_texture, render_landmarks
from server.commands import landmark
from tests.support.landmark_views import HEAD_CAMERA as CAM


def run(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="intspace")
    landmark.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(list(argv))
    return int(args.func(args))


def make(kind: str, mark_id: str, name: str, *options: str, out: Path) -> int:
    """Run `intspace landmark make` for a mark of `kind`, `mark_id` and `name` with `options`,
    written to `out`; return its exit code."""
    return run(
        "landmark",
        "make",
        "--kind",
        kind,
        "--id",
        mark_id,
        "--name",
        name,
        *options,
        "--out",
        str(out),
    )


def camera_file(folder: Path) -> Path:
    """Write the head camera's calibration (OpenCV YAML) into `folder`; return its path."""
    cam = folder / "head.yaml"
    cam.write_text(to_opencv_yaml(CalibrationRecord(CAM.K, CAM.dist, (640, 480))))
    return cam


def test_make_writes_every_format(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for ext in ("svg", "pdf", "png"):
        out = tmp_path / f"cup.{ext}"
        assert (
            make("object", "7", "blue cup", "--room", "kitchen", "--object-class", "cup", out=out)
            == 0
        )
        assert out.stat().st_size > 500
    assert 'width="120mm"' in (tmp_path / "cup.svg").read_text()  # 100 mm frame + margins
    img = cv2.imread(str(tmp_path / "cup.png"))
    (read,) = zxingcpp.read_barcodes(img)
    rec = decode_payload(read.text)
    assert rec == ObjectMark(7, "cup", "blue cup", "kitchen")
    assert (
        make(
            "signpost",
            "3",
            "hall door",
            "--size",
            "0.3",
            "--pose",
            "1,2,1.4,0,0,0,1",
            "--neighbours",
            "1,2",
            out=tmp_path / "door.svg",
        )
        == 0
    )
    assert 'width="360mm"' in (tmp_path / "door.svg").read_text()
    assert "wrote" in capsys.readouterr().out


def test_detect_reads_a_rendered_photo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = ObjectMark(9, "remote", "tv remote", "living room")
    art = make_artwork(rec)
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix([0.0, np.radians(35), 0.0]) @ rotvec_to_matrix([np.pi, 0, 0])
    T[:3, 3] = [0.03, -0.02, 0.3]
    view = render_landmarks(CAM, [(artwork_texture(art), T)], noise=SensorNoise(), rng=4)
    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), view.image)
    cam = camera_file(tmp_path)
    assert run("landmark", "detect", str(photo), "--camera", str(cam), "--json") == 0
    out = json.loads(capsys.readouterr().out)
    (det,) = out["detections"]
    assert det["kind"] == "object" and det["reason"] is None
    assert det["record"]["name"] == "tv remote" and det["record"]["id"] == 9
    # Position within 1 % of the 0.3 m distance (spec 04's bound).
    assert np.linalg.norm(np.array(det["position"]) - T[:3, 3]) < 0.003
    assert np.array(det["cov"]).shape == (6, 6)
    assert run("landmark", "detect", str(photo), "--camera", str(cam)) == 0
    assert "tv remote" in capsys.readouterr().out


def test_bad_input_exits_2_with_a_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert make("object", "1", "x", out=tmp_path / "x.jpg") == 2
    assert "must end in .svg" in capsys.readouterr().err
    assert make("object", "-4", "x", out=tmp_path / "x.svg") == 2
    assert "id must be" in capsys.readouterr().err
    cam = camera_file(tmp_path)
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image")
    assert run("landmark", "detect", str(junk), "--camera", str(cam)) == 2
    assert "not an image" in capsys.readouterr().err
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 120, 3), np.uint8))
    assert run("landmark", "detect", str(small), "--camera", str(cam)) == 2
    assert "calibrated at 640x480" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("%YAML:1.0\n---\nfoo: 1\n")
    assert run("landmark", "detect", str(small), "--camera", str(bad)) == 2
    assert capsys.readouterr().err.startswith("intspace landmark detect: error:")
