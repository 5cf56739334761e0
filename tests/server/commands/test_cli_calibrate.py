"""`intspace calibrate` end to end on rendered photos, and its error messages."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import pytest

from core.calibration.detect import CharucoSpec, CircleGrid, board_object_points
from core.calibration.io import from_opencv_yaml, from_ros_yaml
from server.cli import main

REPO = Path(__file__).resolve().parents[3]


def _renderer() -> ModuleType:
    # The photo renderer lives with the detection tests; loaded by path so that it does not
    # depend on which conftest module pytest last imported under the name "conftest".
    path = REPO / "tests" / "core" / "calibration" / "conftest.py"
    spec = importlib.util.spec_from_file_location("_calibration_photos", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


render = _renderer()


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "server.cli", "calibrate", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.fixture(scope="module")
def photo_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five photos of a 9x6 board, one photo without it, one broken file and a note."""
    folder = tmp_path_factory.mktemp("photos")
    render.write_views(render.render_chessboard_views(n=5, seed=21), folder)
    cv2.imwrite(str(folder / "wall.jpg"), np.full((480, 640), 128, np.uint8))
    (folder / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n but not really")
    (folder / "notes.txt").write_text("not a photo")
    return folder


def test_json_output_and_written_files(photo_dir: Path, tmp_path: Path) -> None:
    yaml_path, ros_path = tmp_path / "cam.yaml", tmp_path / "cam_ros.yaml"
    proc = run_cli(
        str(photo_dir),
        "--chessboard",
        "9x6",
        "--square",
        "0.025",
        "--json",
        "--output-yaml",
        str(yaml_path),
        "--ros-yaml",
        str(ros_path),
    )
    assert proc.returncode == 0, proc.stderr
    assert "broken.png" in proc.stderr and "Traceback" not in proc.stderr
    out = json.loads(proc.stdout)
    assert {"K", "dist", "rms", "std_intrinsics", "views", "skipped"} <= out.keys()
    K = np.array(out["K"])
    # Five views x 54 corners at ~0.05 px detection noise: fx, fy to ~0.05 %, cx, cy to ~0.5 px
    # (the reported standard deviations); 0.3 % and 2 px leave room for one unlucky seed.
    assert np.allclose(np.diag(K)[:2], np.diag(render.TRUE_K)[:2], rtol=3e-3)
    assert np.allclose(K[:2, 2], render.TRUE_K[:2, 2], atol=2.0)
    assert abs(out["dist"][0] - render.TRUE_DIST[0]) < 0.01
    assert out["rms"] < 0.1
    assert out["std_intrinsics"]["fx"] > 0.0
    assert [v["file"] for v in out["views"]] == [f"view_{i:02d}.png" for i in range(5)]
    assert all(0.0 < v["rms"] < 0.1 and v["points"] == 54 for v in out["views"])
    assert {(s["file"], s["reason"]) for s in out["skipped"]} == {
        ("broken.png", "unreadable"),
        ("wall.jpg", "pattern not found"),
    }
    # The written files hold the same numbers, and OpenCV reads them.
    assert np.array_equal(from_opencv_yaml(yaml_path.read_text()).K, K)
    assert np.array_equal(from_ros_yaml(ros_path.read_text()).dist, out["dist"])
    fs = cv2.FileStorage(str(yaml_path), cv2.FILE_STORAGE_READ)
    assert np.array_equal(fs.getNode("camera_matrix").mat(), K)
    fs.release()


def test_summary_output(photo_dir: Path) -> None:
    proc = run_cli(str(photo_dir), "--chessboard", "9x6", "--square", "0.025")
    assert proc.returncode == 0, proc.stderr
    assert "Calibrated from 5 of 6 photos" in proc.stdout
    assert "RMS reprojection error" in proc.stdout
    assert "view_04.png" in proc.stdout
    assert "Pattern not found in: wall.jpg" in proc.stdout
    assert "broken.png (unreadable)" in proc.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{missing}", "--chessboard", "9x6", "--square", "0.025"], "does not exist"),
        (["{photos}", "--chessboard", "9by6", "--square", "0.025"], "expected COLSxROWS"),
        (["{few}", "--chessboard", "9x6", "--square", "0.025"], "found in 1 of 2 photos"),
    ],
    ids=["missing-folder", "bad-pattern-syntax", "too-few-views"],
)
def test_errors_exit_2_with_a_message(
    photo_dir: Path, tmp_path: Path, args: list[str], message: str
) -> None:
    few = tmp_path / "few"
    few.mkdir()
    for name in ("view_00.png", "wall.jpg"):
        (few / name).write_bytes((photo_dir / name).read_bytes())
    fill = {"missing": str(tmp_path / "nope"), "photos": str(photo_dir), "few": str(few)}
    proc = run_cli(*(a.format(**fill) for a in args))
    assert proc.returncode == 2
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr


# The remaining error paths run in-process (same code, no interpreter start-up): an exception
# escaping main() is what would print a traceback.


def test_empty_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "readme.txt").write_text("no photos here")
    assert main(["calibrate", str(tmp_path), "--chessboard", "9x6", "--square", "0.025"]) == 2
    assert "no photos in" in capsys.readouterr().err


def test_folder_is_a_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "a.png"
    f.write_bytes(b"")
    assert main(["calibrate", str(f), "--chessboard", "9x6", "--square", "0.025"]) == 2
    assert "is not a folder" in capsys.readouterr().err


def test_no_readable_photos(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("a.png", "b.jpg", "c.gif"):
        (tmp_path / name).write_bytes(b"garbage")
    assert main(["calibrate", str(tmp_path), "--chessboard", "9x6", "--square", "0.025"]) == 2
    err = capsys.readouterr().err
    assert "none of the 3 image files" in err
    assert "warning: cannot read" in err


def test_too_few_views(photo_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("view_00.png", "view_01.png", "wall.jpg"):
        (tmp_path / name).write_bytes((photo_dir / name).read_bytes())
    args = ["calibrate", str(tmp_path), "--chessboard", "9x6", "--square", "0.025"]
    # Two views are enough without skew (Zhang: 2 constraints per view, 4 intrinsics) ...
    assert main([*args, "--json"]) == 0
    capsys.readouterr()
    # ... but not with it (5 intrinsics need 3 views).
    assert main([*args, "--skew"]) == 2
    assert "found in 2 of 3 photos" in capsys.readouterr().err
    (tmp_path / "view_01.png").unlink()
    assert main(args) == 2
    assert "found in 1 of 2 photos" in capsys.readouterr().err


def test_unknown_distortion_model(photo_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = [str(photo_dir), "--chessboard", "9x6", "--square", "0.025", "--distortion", "fisheye"]
    assert main(["calibrate", *args]) == 2
    assert "unknown distortion model 'fisheye'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--chessboard", "9x1", "--square", "0.025"], "expected COLSxROWS"),
        (["--chessboard", "9x6", "--square", "-1"], "positive length"),
        (["--chessboard", "9x6"], "--square"),
        (["--square", "0.025"], "one of the arguments"),
        (["--charuco", "8x6", "--square", "0.03", "--dictionary", "DICT_NOPE"], "dictionary"),
    ],
)
def test_bad_arguments(
    photo_dir: Path, args: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        code = main(["calibrate", str(photo_dir), *args])
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    assert code == 2
    assert message in capsys.readouterr().err


def test_square_in_millimetres_is_refused_with_the_metres_hint(
    photo_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 25 typed for 25 mm: a 25 m square is no calibration board; nothing is calibrated.
    assert main(["calibrate", str(photo_dir), "--chessboard", "9x6", "--square", "25"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "metres: did you mean 0.025" in lines[0]
    # The largest plausible square (1 m) is accepted as it was.
    assert main(["calibrate", str(photo_dir), "--chessboard", "9x6", "--square", "1"]) == 0


def test_unwritable_output(
    photo_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "no" / "such" / "dir" / "cam.yaml"
    args = ["calibrate", str(photo_dir), "--chessboard", "9x6", "--square", "0.025"]
    assert main([*args, "--output-yaml", str(target)]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_mixed_image_sizes_keep_the_common_one(
    photo_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in ("view_00.png", "view_01.png", "view_02.png"):
        (tmp_path / name).write_bytes((photo_dir / name).read_bytes())
    small = cv2.resize(cv2.imread(str(photo_dir / "view_03.png")), (320, 240))
    cv2.imwrite(str(tmp_path / "small.png"), small)
    args = ["calibrate", str(tmp_path), "--chessboard", "9x6", "--square", "0.025", "--json"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "small.png is 320x240 px, the others 640x480" in captured.err
    out = json.loads(captured.out)
    assert out["image_size"] == [640, 480] and len(out["views"]) == 3
    assert out["skipped"] == [{"file": "small.png", "reason": "different image size"}]


@pytest.mark.parametrize("kind", ["charuco", "asymmetric-circles"])
def test_other_patterns(kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(4)
    if kind == "charuco":
        board = cv2.aruco.CharucoBoard(
            (8, 6), 0.03, 0.0225, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
        )
        tex = render.charuco_texture(board)
        model = board_object_points(CharucoSpec(8, 6), 0.03)
        pattern_args = ["--charuco", "8x6", "--square", "0.03"]
    else:
        tex = render.circle_grid_texture(4, 11, 0.02, symmetric=False)
        model = board_object_points(CircleGrid(4, 11, symmetric=False), 0.02)
        pattern_args = ["--circles", "4x11", "--asymmetric", "--square", "0.02"]
    poses = render.board_poses(model.mean(axis=0), 0.42, 4)
    views = [render.render_view(tex, model, rv, tv, rng) for rv, tv in poses]
    render.write_views(views, tmp_path)
    assert main(["calibrate", str(tmp_path), *pattern_args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["views"]) == 4
    # Four views of 35-44 points at 0.02-0.07 px: fx, fy within 0.3 % as for the chessboard.
    K = np.array(out["K"])
    assert np.allclose(np.diag(K)[:2], np.diag(render.TRUE_K)[:2], rtol=3e-3)
    assert np.allclose(K[:2, 2], render.TRUE_K[:2, 2], atol=2.0)
    # Poses in metres: the board 0.42 m in front of the camera.
    assert np.allclose([v["tvec"] for v in out["views"]], [t for _, t in poses], atol=2e-3)
