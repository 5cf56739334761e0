"""detect_landmarks on rendered views with known truth (core.sim.render.landmarks)."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.camera import as_distortion, undistort_points
from core.landmarks import ObjectMark, Signpost
from core.landmarks._view import ImageView
from core.landmarks.artwork import make_artwork
from core.landmarks.detect import detect_landmarks
from core.sim.render import SensorNoise
from core.sim.render.landmarks import (
    artwork_texture,
    lens_canvas_size,
    render_landmarks,
    wall_background,
)
from tests.support.landmark_views import HEAD_CAMERA as CAM
from tests.support.landmark_views import mark_pose

CUP = ObjectMark(7, "cup", "blue cup", "kitchen", (0.08, 0.08, 0.1), hints=("fragile",))
DOOR = Signpost(3, "kitchen door", "kitchen", (1.0, 2.0, 1.2, 0, 0, 0, 1), (1, 2))
# Noise as the twin's default (0.5 px blur, sigma 2 grey levels).
NOISE = SensorNoise()


def _errors(det, T: np.ndarray) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    d = float(np.linalg.norm(T[:3, 3]))
    pos = 100 * float(np.linalg.norm(det.position - T[:3, 3])) / d
    normal = float(np.degrees(np.arccos(np.clip(det.normal @ T[:3, 2], -1, 1))))
    return pos, normal


@pytest.mark.parametrize(
    ("record", "distance"),
    [(CUP, 3.0), (DOOR, 5.0)],
)
def test_located_at_the_far_limit_at_45_deg(record: ObjectMark | Signpost, distance: float) -> None:
    # Spec 04: object marks (10 cm) located up to 3 m, signposts (20 cm) up to 5 m, position
    # error < 1 % of distance and normal error < 2 deg at 45 deg obliquity.
    art = make_artwork(record)
    t = np.array([0.2, -0.1, 1.0])
    T = mark_pose(70.0, 45.0, list(distance * t / np.linalg.norm(t)))
    view = render_landmarks(CAM, [(artwork_texture(art), T, art.size, None)], noise=NOISE, rng=5)
    dets = detect_landmarks(view.image, CAM.K, CAM.dist)
    assert len(dets) == 1 and dets[0].kind == record.kind
    pos, normal = _errors(dets[0], T)
    assert pos < 1.0 and normal < 2.0, (pos, normal)
    # Far away the modules are ~0.5 px: no read, and the reason says so.
    assert dets[0].record is None and dets[0].reason == "too small"
    # The outline is where the truth projects the pattern (within a pixel).
    if record.kind == "object":
        d = np.linalg.norm(dets[0].outline[:, None] - view.truth[0].corners[None], axis=2)
        assert d.min(1).max() < 1.0


@pytest.mark.parametrize("record", [CUP, DOOR])
def test_read_on_the_rectified_patch_at_60_deg(record: ObjectMark | Signpost) -> None:
    # Modules of ~2 px across the foreshortened direction at 60 deg: read after rectification.
    art = make_artwork(record)
    d = 0.28 if record.kind == "object" else 0.40
    T = mark_pose(20.0, 60.0, [0.02, -0.03, d], psi=2.0)
    view = render_landmarks(
        CAM, [(artwork_texture(art), T, art.size, art.module_mm / 1000)], noise=NOISE, rng=2
    )
    assert view.truth[0].module_px is not None and view.truth[0].module_px > 1.9
    (det,) = detect_landmarks(view.image, CAM.K, CAM.dist)
    assert det.record == record and det.reason is None
    assert det.orientation_known
    # x along the symbol's rows: the full rotation is right, not only the normal.
    R_err = det.T_cam_mark[:3, :3].T @ T[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1)))
    assert angle < 2.0
    pos, _ = _errors(det, T)
    assert pos < 1.0
    # The covariance is a valid 6x6 covariance.
    assert det.cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(det.cov) > -1e-12)


def test_position_error_within_the_reported_covariance() -> None:
    # Twelve noise draws at one pose: the spread of the position is no larger than the
    # reported standard deviations allow (3 sigma per axis; the renderer's own edge bias is
    # ~0.1 % of the distance, inside it at 1.5 m).
    art = make_artwork(CUP)
    T = mark_pose(10.0, 40.0, [0.1, 0.05, 1.5])
    tex = artwork_texture(art)
    errs, stds = [], []
    for seed in range(6):
        view = render_landmarks(CAM, [(tex, T, art.size, None)], noise=NOISE, rng=seed)
        (det,) = detect_landmarks(view.image, CAM.K, CAM.dist)
        errs.append(det.position - T[:3, 3])
        stds.append(np.sqrt(np.diag(det.cov)[3:]))
    e, s = np.array(errs), np.mean(stds, 0)
    assert np.all(np.abs(e - e.mean(0)) < 3 * s)
    assert np.all(np.abs(e.mean(0)) < 3 * s + 0.001 * 1.5)


def test_foreign_payload_is_reported_not_mapped() -> None:
    art = make_artwork("https://example.com/p/42", kind="object", label="foreign")
    T = mark_pose(0.0, 10.0, [0.0, 0.0, 0.3])
    view = render_landmarks(CAM, [(artwork_texture(art), T, art.size, None)], noise=NOISE, rng=1)
    (det,) = detect_landmarks(view.image, CAM.K, CAM.dist)
    assert det.record is None and det.reason == "foreign payload"
    assert det.text == "https://example.com/p/42"


def test_nothing_found_on_a_plain_wall_and_bad_input_rejected() -> None:
    w, h = lens_canvas_size(CAM)
    bg = wall_background(w, h, np.random.default_rng(0))
    view = render_landmarks(CAM, [], noise=NOISE, rng=0, background=bg)
    assert detect_landmarks(view.image, CAM.K, CAM.dist) == []
    with pytest.raises(InvalidInput):
        detect_landmarks(view.image[..., 0], CAM.K)
    with pytest.raises(InvalidInput):
        detect_landmarks(view.image, np.eye(2))
    with pytest.raises(InvalidInput):
        detect_landmarks(view.image, CAM.K, frame_size=0.0)


@pytest.mark.parametrize("psi", [0.3, 2.0, -2.5])
def test_frame_with_large_modules_read_on_a_coarser_patch(psi: float) -> None:
    # Modules of ~3.5 px facing the camera: the frame's patch has 4 px modules, about one patch
    # pixel per image pixel (not 2.5), and still reads with the rotation about the normal right.
    art = make_artwork(CUP)
    T = mark_pose(30.0, 15.0, [0.01, 0.02, 0.33], psi=psi)
    view = render_landmarks(
        CAM, [(artwork_texture(art), T, art.size, art.module_mm / 1000)], noise=NOISE, rng=4
    )
    assert view.truth[0].module_px is not None and view.truth[0].module_px > 3.0
    (det,) = detect_landmarks(view.image, CAM.K, CAM.dist)
    assert det.record == CUP and det.reason is None and det.orientation_known
    R_err = det.T_cam_mark[:3, :3].T @ T[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1)))
    assert angle < 2.0  # as at 60 deg: a quarter-turn error would be 90


def test_edge_points_undistorted_from_the_grid_as_by_newton_alone() -> None:
    # The grid-started Newton converges to the same points as Newton from the distorted pixels
    # (core.geometry.camera.undistort_points to machine precision): within 1e-9 px over the
    # whole image, corners included (float64 rounding on ~1000 px coordinates is ~1e-13).
    rng = np.random.default_rng(0)
    px = np.concatenate(
        [
            rng.uniform([0, 0], [CAM.width - 1, CAM.height - 1], (5000, 2)),
            [[0, 0], [CAM.width - 1, 0], [CAM.width - 1, CAM.height - 1], [0, CAM.height - 1]],
        ]
    )
    image = np.zeros((CAM.height, CAM.width, 3), np.uint8)
    ctx = ImageView(image, image[..., 0], CAM.K, as_distortion(CAM.dist), None, True)
    ideal = ctx.undistort(px)
    reference = undistort_points(px, CAM.K, CAM.dist, to_pixels=True)
    assert np.max(np.abs(ideal - reference)) < 1e-9
    # Without distortion there is nothing to undo.
    plain = ImageView(image, image[..., 0], CAM.K, np.zeros(5), None, True)
    assert np.array_equal(plain.undistort(px), px)


def test_threads_and_frame_sizes_do_not_share_the_full_frame_planes() -> None:
    # The full-frame planes are kept per thread from one call to the next: two threads reading
    # different views at once, and a frame of another size in between, find what each view
    # alone gives (shared planes would mix one view's scores into the other's, and an old
    # size would not fit the new frame).
    from concurrent.futures import ThreadPoolExecutor

    art = make_artwork(CUP)
    views = [
        render_landmarks(
            CAM, [(artwork_texture(art), mark_pose(a, 20.0, t), art.size, None)], noise=NOISE, rng=k
        ).image
        for k, (a, t) in enumerate([(0.0, [-0.05, 0.02, 0.35]), (60.0, [0.06, -0.03, 0.45])])
    ]
    # 480 x 400 of the first view, the mark inside: the same lens, its principal point moved.
    small = np.ascontiguousarray(views[0][40:440, 80:560])
    K_small = CAM.K - np.array([[0, 0, 80.0], [0, 0, 40.0], [0, 0, 0]])
    cams = [CAM.K, CAM.K, K_small]
    alone = [detect_landmarks(v, K, CAM.dist) for v, K in zip([*views, small], cams, strict=True)]
    assert [len(d) for d in alone] == [1, 1, 1]

    def run(k: int) -> list[np.ndarray]:
        out = []
        for _ in range(4):
            (det,) = detect_landmarks(views[k], CAM.K, CAM.dist)
            out.append(det.T_cam_mark)
            (det,) = detect_landmarks(small, K_small, CAM.dist)
            out.append(det.T_cam_mark)
        return out

    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(run, [0, 1]))
    for k, poses in enumerate(results):
        for i, T in enumerate(poses):
            expected = alone[k if i % 2 == 0 else 2][0].T_cam_mark
            assert np.array_equal(T, expected)
