"""People located at their body's axis: MOG2 blobs in the twin's images, fitted with the body
model per camera (`PersonDetector.detect_bodies`), fused with `locate_ml` at the reported height,
scored against the walker's centre (the twin's truth, used for scoring only). The cameras are
the home's installed calibration (core.sim.installation: its marker drive), never the twin's;
the walker's centre is put into that calibrated frame (its rigid error against the twin's taken
out, for scoring only) so that the figures measure the detector, not the frame.

Tuned on times 0.25 + 0.5 k s (k < 34) with render seed 100: the edge sigma (the pixel
quantisation bound), the arc test's fraction and the one-sided occlusion threshold were set
looking at those frames, and the occlusion threshold (2.5) also after looking at the outliers of
TIMES / SEED below. ALL_TIMES / ALL_SEED were run once, after the last change, and not tuned on.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.camera import undistort_points
from core.localization.cameras import NetworkCamera
from core.localization.detect import BodyModel, PersonDetector, locate_body_axis
from core.localization.ground import locate_ml, locate_monocular
from core.sim import WorldState, default_scene, renderer_for, world_state
from core.sim.installation import installed_calibration
from core.sim.network_cameras import frame_alignment

# The twin's walkers are rigid vertical cylinders: a whole cylinder's silhouette edges are
# exactly the model's, so the shape and posture terms (which stand for real bodies) are zero.
# The size prior is the default adult one (0.2 m +- 0.03 m, 1.7 m +- 0.1 m), not read from the
# scene.
CYLINDER = BodyModel(shape_sigma=0.0, lateral_sigma=0.0)
# Frames where two cameras see the whole walker (not the tuning times or seed).
TIMES = 0.1 + 0.41 * np.arange(40)
SEED = 2024
# Every frame, partly hidden views included (run once, not tuned on).
ALL_TIMES = 0.3 + 0.53 * np.arange(32)
ALL_SEED = 7


@pytest.fixture(scope="module")
def twin():
    scene = default_scene()
    renderer = renderer_for(scene)
    cameras, detectors = {}, {}
    away = tuple((1e4, 1e4) for _ in scene.people)
    installed = {c.name: c for c in installed_calibration(scene).cameras}
    truth = {}
    for spec in scene.cameras:
        cm = renderer.camera(spec.name)
        cal = installed[spec.name]
        cameras[spec.name] = NetworkCamera.from_pose(
            cal.K, cal.dist, cal.T_world_camera, (cm.width, cm.height), spec.name
        )
        truth[spec.name] = NetworkCamera.from_pose(
            cm.K, cm.dist, cm.T_world_camera, (cm.width, cm.height)
        )
        det = PersonDetector()
        for i in range(3):
            det.learn(renderer.render(spec.name, WorldState(0.0, None, away), rng=i).image)
        detectors[spec.name] = det
    # The calibrated frame -> the twin's; its inverse puts true centres into the calibrated
    # frame (scoring only).
    T = frame_alignment(list(cameras.values()), list(truth.values()))
    to_frame = np.linalg.inv(T)
    return scene, renderer, cameras, detectors, to_frame, truth


def _fully_seen(renderer, name: str, camera: NetworkCamera, centre, radius, height) -> bool:
    """Whether the whole body is in view and unhidden (ground truth, to choose what to score):
    both sides at the ankles and the shoulders, the near foot, and the top."""
    toward = camera.center[:2] - centre
    toward /= np.linalg.norm(toward)
    side = np.array([-toward[1], toward[0]])
    pts = [[*(centre + radius * toward), 0.02], [*centre, height]]
    for z in (0.05, height - 0.1):
        pts += [[*(centre + 0.9 * radius * side), z], [*(centre - 0.9 * radius * side), z]]
    p = np.array(pts)
    return bool(np.all(camera.in_view(p)) and np.all(renderer.sees(name, p)))


def _frames(twin, times, seed, body: BodyModel, *, whole: bool = True):
    """Yield (centre, [(camera, BodyDetection, PersonDetection)]) for times where two or more
    cameras detect the walker (with `whole`, only the cameras that see all of it)."""
    scene, renderer, cameras, detectors, to_frame, truth = twin
    walker = scene.people[0]
    rng = np.random.default_rng(seed)
    for det in detectors.values():
        det.body = body
    for t in times:
        st = world_state(scene, float(t))
        state = WorldState(st.time, None, st.people)
        true_centre = np.array(state.people[0])
        centre = to_frame[:2, :2] @ true_centre + to_frame[:2, 2]
        seen = []
        for name, cam in cameras.items():
            if whole and not _fully_seen(
                renderer, name, cam, true_centre, walker.radius, walker.height
            ):
                continue
            image = renderer.render(name, state, rng=rng).image
            bodies = detectors[name].detect_bodies(image, cam)
            blobs = detectors[name].detect(image)
            if whole:
                assert bodies and blobs, f"walker missed by {name} at t = {t:.2f}"
            if bodies and blobs:
                # The true axis point's pixel, through the true camera: scoring only.
                axis = [*true_centre, bodies[0].height]
                seen.append((cam, bodies[0], blobs[0], truth[name].project([axis])[0]))
        if len(seen) >= 2:
            yield centre, seen


def _fuse(seen, centre) -> tuple[np.ndarray, float, np.ndarray]:
    """Return (error (2,), NEES, error of the blobs' lowest pixels (2,)) of one frame."""
    cams = [s[0] for s in seen]
    est = locate_ml(
        cams,
        np.array([s[1].pixel for s in seen]),
        seen[0][1].height,
        pixel_cov=np.array([s[1].cov for s in seen]),
    )
    e = est.xy - centre
    old = locate_ml(
        cams,
        np.array([s[2].foot_pixel for s in seen]),
        0.0,
        pixel_cov=np.array([s[2].cov for s in seen]),
    )
    return e, float(e @ np.linalg.solve(est.cov, e)), old.xy - centre


def _pixel_nees(seen) -> list[float]:
    """Return each detection's NEES in the image: its axis pixel against the true axis point's
    pixel, under the detector's own pixel covariance (chi^2(2), mean 2, when consistent)."""
    out = []
    for _, body, _, true_px in seen:
        e = body.pixel - true_px
        out.append(float(e @ np.linalg.solve(body.cov, e)))
    return out


def _rms(errors) -> float:
    return float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1))))


def test_fused_position_within_5_cm_with_consistent_covariance(twin) -> None:
    """The issue's goal: where two cameras see the walker, RMSE <= 5 cm against its centre."""
    frames = list(_frames(twin, TIMES, SEED, CYLINDER))
    fused = [_fuse(seen, centre) for centre, seen in frames]
    n = len(fused)
    assert n >= 15, f"only {n} frames with two cameras seeing the walker"
    rmse = _rms([f[0] for f in fused])
    old_rmse = _rms([f[2] for f in fused])
    # With the installed calibration's cameras: measured 0.9 cm (the blobs' lowest pixels:
    # 8.4 cm); with exact cameras the detector alone gave 0.3 cm, the rest is the cameras'
    # calibration within the frame.
    assert rmse <= 0.05, (rmse, old_rmse)
    assert rmse < 0.25 * old_rmse, (rmse, old_rmse)
    # The detector's covariance, in the image where it is stated: the NEES of each axis pixel
    # is chi^2(2), mean 2. Measured 1.4 over 40 detections: the edge sigma (the quantisation
    # bound, 0.29 px) over-states the limbs' error by ~2x in sd (their extremes run along long
    # edges), so the band's lower end is 0.3 (a covariance at most ~7x too large); its upper
    # end 4 (never over-confident by more than 2x). The fused position's covariance leaves
    # out the calibration's own uncertainty (measured fused NEES 7), so it is not asserted here.
    nees = [v for _, seen in frames for v in _pixel_nees(seen)]
    mean_nees = float(np.mean(nees))
    assert 0.3 <= mean_nees <= 4.0, (mean_nees, nees)


def test_all_frames_with_default_body_model(twin) -> None:
    """Every frame with two or more detections, partly hidden views included (the door frame,
    the bookshelf, the dining table), with the default adult body model, as a tracker would
    fuse them: the covariance stays consistent where the position cannot be as good."""
    fused = [
        _fuse(seen, centre)
        for centre, seen in _frames(twin, ALL_TIMES, ALL_SEED, BodyModel(), whole=False)
    ]
    assert len(fused) >= 25
    rmse = _rms([f[0] for f in fused])
    old_rmse = _rms([f[2] for f in fused])
    nees = [f[1] for f in fused]
    # Measured 5.0 cm (lowest pixels: 18.4 cm), dominated by views through the kitchen door
    # and behind the bookshelf where one camera fixes only a bearing.
    assert rmse < 0.08 and rmse < 0.4 * old_rmse, (rmse, old_rmse)
    # Measured 3.0 (lowest pixels: 79). Over ~30 correlated frames, with one-sided occlusion
    # tests, a band of 1 to 4 around the chi^2(2) mean of 2.
    mean_nees = float(np.mean(nees))
    assert 1.0 <= mean_nees <= 4.0, (mean_nees, nees)


def test_each_camera_places_the_axis_not_the_near_edge(twin) -> None:
    """One camera alone: the axis's floor position (the detection's pixel put back on the floor
    with locate_monocular) lies at the centre, the lowest blob pixel a body radius towards the
    camera."""
    scene = twin[0]
    radius = scene.people[0].radius
    new, old = [], []
    for centre, seen in _frames(twin, TIMES[::4], SEED + 1, CYLINDER):
        for cam, body, blob, _ in seen:
            xy = locate_monocular(cam, body.pixel[None], body.height, pixel_cov=body.cov[None])
            np.testing.assert_allclose(xy.xy[0], body.floor_xy, atol=1e-6)
            # The pixel covariance adds the projection's curvature over the range's spread,
            # negligible where the range is known to centimetres.
            np.testing.assert_allclose(xy.cov[0], body.floor_cov, rtol=1e-3, atol=1e-10)
            new.append(np.linalg.norm(body.floor_xy - centre))
            foot = locate_monocular(cam, blob.foot_pixel[None], 0.0).xy[0]
            old.append(np.linalg.norm(foot - centre))
            assert set(body.cues) == {"left", "right", "foot", "head"}
            assert not body.foot_hidden and not body.sides_hidden
    assert len(new) >= 4
    # Per camera, the range rests on the foot and the width: measured <= 1.5 cm.
    assert np.max(new) < 0.03, new
    # The old point is near the rim (measured 0.20-0.22 m): the body-model point is 4x closer.
    assert np.min(old) > 0.6 * radius and np.max(new) < 0.25 * np.min(old), (new, old)


@pytest.mark.parametrize("t", [4.3, 6.1, 7.2, 9.7, 12.4])
def test_partly_hidden_bodies_keep_honest_covariances(twin, t: float) -> None:
    """Frames where a camera sees only part of the body (the bookshelf hides the legs, a door
    frame the sides, the dining table the feet): the occlusion is recognised and widens that
    detection's covariance, so that the fused error is not far outside the fused covariance."""
    frames = list(_frames(twin, [t], SEED + 2, BodyModel(), whole=False))
    assert len(frames) == 1
    centre, seen = frames[0]
    bodies = [s[1] for s in seen]
    assert any(b.foot_hidden or b.sides_hidden or b.ends_disagree for b in bodies), bodies
    e, nees, old = _fuse(seen, centre)
    # chi^2(2) exceeds 13.8 with probability 0.001; the blobs' lowest pixels give 30-400 at
    # these times.
    assert nees < 13.8, (nees, e, old)


def _cylinder_mask(cam: NetworkCamera, centre: np.ndarray) -> np.ndarray:
    """Return the exact silhouette (480, 640) of a 0.2 m x 1.7 m cylinder: the convex hull of
    its rims in the ideal (undistorted) image, sampled at each image pixel's ideal position."""
    ang = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    ring = centre + 0.2 * np.column_stack([np.cos(ang), np.sin(ang)])
    pts = np.vstack([np.column_stack([ring, np.full(720, z)]) for z in (0.0, 1.7)])
    Xc = pts @ cam.R.T + cam.t
    off = 600.0  # the ideal image of a wide lens reaches beyond the sensor's pixels
    ideal = (Xc[:, :2] / Xc[:, 2:]) @ cam.K[:2, :2].T + cam.K[:2, 2] + off
    canvas = np.zeros((480 + 2 * int(off), 640 + 2 * int(off)), np.uint8)
    hull = cv2.convexHull(np.round(ideal * 16).astype(np.int32))
    cv2.fillConvexPoly(canvas, hull, 1, cv2.LINE_8, 4)
    v, u = np.mgrid[0:480, 0:640]
    px = np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)
    q = undistort_points(px, cam.K, cam.dist, to_pixels=True) + off
    maps = q.reshape(480, 640, 2).astype(np.float32)
    return cv2.remap(canvas, maps[..., 0], maps[..., 1], cv2.INTER_NEAREST)


def test_synthetic_cylinder_silhouette_gives_the_axis() -> None:
    """A cylinder's silhouette drawn exactly (no renderer, no MOG2): the axis within 1 cm, and
    the image border and a cut-off bottom are recognised."""
    K = np.array([[330.0, 0.0, 320.0], [0.0, 330.0, 240.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.25, 0.06, 0.0, 0.0, 0.0])
    cam = NetworkCamera.looking_at(K, dist, (0.0, 0.0, 2.8), (3.0, 2.0, 0.0), (640, 480))
    centre = np.array([2.6, 1.5])
    mask = _cylinder_mask(cam, centre)
    det = locate_body_axis(mask, cam, CYLINDER)
    assert det is not None
    # Pixel quantisation of the edges at ~3.5 m, ~1 cm per pixel: measured 0.2 cm.
    assert np.linalg.norm(det.floor_xy - centre) < 0.01
    assert set(det.cues) == {"left", "right", "foot", "head"}
    # A table top across the legs: the bottom 40 % of the blob cut by a straight edge.
    ys = np.flatnonzero(mask.any(axis=1))
    cut = mask.copy()
    cut[int(ys[0] + 0.6 * (ys[-1] - ys[0])) :] = 0
    hidden = locate_body_axis(cut, cam, CYLINDER)
    assert hidden is not None and hidden.foot_hidden and "foot" not in hidden.cues
    # Without the feet the range rests on the head and its 0.1 m height prior: a wide,
    # honest covariance (measured error 1.6 cm, NEES 0.6).
    e = hidden.floor_xy - centre
    assert float(e @ np.linalg.solve(hidden.floor_cov, e)) < 13.8
    # A crop with its origin gives the same result.
    ys, xs = np.nonzero(mask)
    crop = mask[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
    same = locate_body_axis(crop, cam, CYLINDER, origin=(int(xs.min()), int(ys.min())))
    assert same is not None
    np.testing.assert_allclose(same.pixel, det.pixel, atol=1e-9)
    # The same body cut by the image's left border (the principal point moved so that the
    # axis images at u = 8): the left limb is not used, the bearing comes from the right limb
    # and the radius, and the axis is still found.
    u_axis = float(cam.project([[*centre, 0.85]])[0, 0])
    K2 = K.copy()
    K2[0, 2] -= u_axis - 8.0
    cam2 = NetworkCamera.from_pose(K2, dist, cam.T_world_camera, (640, 480))
    edge = locate_body_axis(_cylinder_mask(cam2, centre), cam2, CYLINDER)
    assert edge is not None and "left" not in edge.cues and "right" in edge.cues
    # The radius (prior 0.2 +- 0.03 m, refined by foot and head) enters the bearing now:
    # measured 1.2 cm, bound one prior standard deviation.
    assert np.linalg.norm(edge.floor_xy - centre) < 0.03
    with pytest.raises(InvalidInput):
        locate_body_axis(mask[None], cam)
    with pytest.raises(InvalidInput):
        locate_body_axis(crop, cam, origin=(630, 470))


def test_two_bodies_in_one_blob_are_not_placed_as_one() -> None:
    """Two cylinders one behind the other make one blob. Where the near body's foot still shows,
    the near body is found. Where neither end fits one body, the width (two bodies wide) is all
    that is left, and where the blob is wider than one body at the range its one end gives, which
    body that end belongs to is unknown: the range must then spread twice as far, past what a
    tracker takes as a located body (TrackerConfig.located_std, 0.5 m)."""
    K = np.array([[330.0, 0.0, 320.0], [0.0, 330.0, 240.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.25, 0.06, 0.0, 0.0, 0.0])
    cam = NetworkCamera.looking_at(K, dist, (0.0, 0.0, 2.8), (3.0, 2.0, 0.0), (640, 480))
    near = np.array([2.0, 1.6])
    apart = _cylinder_mask(cam, near) | _cylinder_mask(cam, np.array([2.7, 2.05]))
    det = locate_body_axis(apart, cam, CYLINDER)
    assert det is not None and "foot" in det.cues
    assert np.linalg.norm(det.floor_xy - near) < 0.02  # measured 1.4 cm
    close = _cylinder_mask(cam, near) | _cylinder_mask(cam, np.array([2.8, 1.9]))
    merged = locate_body_axis(close, cam, CYLINDER)
    assert merged is not None and not {"foot", "head"} & set(merged.cues)
    # Measured 0.94 m (the width alone put it 0.75 m short of the near body).
    assert float(np.sqrt(np.linalg.eigvalsh(merged.floor_cov).max())) > 0.5
    # The near body's legs behind a table and a second body beside and behind it: one foot is
    # seen, but the blob is wider than one body at the range that foot gives. Placed between
    # the two (0.28 and 0.35 m off), it once claimed 3 cm; measured now 1.4 m.
    cut = _cylinder_mask(cam, near)
    ys = np.flatnonzero(cut.any(axis=1))
    cut[int(ys[0] + 0.6 * (ys[-1] - ys[0])) :] = 0
    wide = locate_body_axis(cut | _cylinder_mask(cam, near + np.array([0.5, -0.3])), cam, CYLINDER)
    assert wide is not None and "foot" in wide.cues
    assert float(np.sqrt(np.linalg.eigvalsh(wide.floor_cov).max())) > 0.5
