"""The landmark scenarios of the robot's head camera (spec 04 on the twin).

* `landmark-pose`: the landmark detector on rendered views, beside the anchors on the same
  images (below).
* `landmark-reading`: a landmark located and read by position-based visual servoing from
  random start poses in the home (`landmark_reading`, `HeadRobot.read`).
* `landmark-survey`: the robot tours the home, reads every landmark it can and builds the
  semantic and navigation maps (`landmark_survey`).

The head camera (spec 07: on the pan-tilt unit at about 1.1 m, 640x480) is the scene robot's
head camera (or its onboard camera) when the scene gives one, else `HEAD_CAMERA` (600 px focal
length, 56 deg horizontal field, barrel distortion). The detector never sees the true
intrinsics: the camera is first calibrated (core.calibration.calibrate_camera, Zhang) from
`CALIBRATION_VIEWS` rendered views of a 9x6 chessboard, with the same sensor noise, and every
detection uses that K and dist.

Views: for each kind (object mark 10 cm, signpost 20 cm) and each 10-degree obliquity bin of
0-70 deg, `views_per_bin` location views at 0.5-5 m (log-uniform) and as many reading views at the
distance where the QR modules span 1.5-5 px (uniform) along the foreshortened axis (at least
0.12 m; the symbols of the 10 cm and 20 cm patterns have 1.7-2.3 mm modules, so 2 px modules
are closer than 0.5 m at 600 px focal length): the mark's centre
at a random pixel of the central 70 % of the image, tilted about a random in-plane axis, turned
by a random angle about its normal, on a random wall. Sensor noise: `NOISE`.

Per bin: located % (a detection of the right kind within 10 % of the distance), position error
as % of distance and normal error (deg), medians and 95th percentiles, flips (normal error over
`FLIP_DEG`, the other branch of the two-fold ambiguity), the views whose image cannot decide
the pose (`undecided_pct`: a signpost reporting both of its rings' poses, core.landmarks.
ambiguity) and the flips among the decided ones (`decided_flips_pct`: a wrong pose reported
with a good pose's confidence); decoding over the views whose modules
span at least 2 px along both image axes (the smaller singular value of the projection at the
centre): ours (rectified), zxing-cpp and cv2.QRCodeDetector on the raw image. Anchor: an
AprilTag 36h11 of the same outer size at the same pose, same noise, in its own image, located
by cv2.aruco and cv2.solvePnP(SOLVEPNP_IPPE_SQUARE) with the same calibration. The p95 and flip
figures are also given over the location views within each kind's required range (3 m for
object marks, 5 m for signposts): spec 04's "no pose flip at the 95th percentile" is judged
there (`goals["no_flip_at_p95"]`).

Reading and surveying: the robot (HeadRobot) is a unicycle base with wheel slip and odometry
(core.sim.motion) and its head camera on the pan-tilt unit; frames come every FRAME_DT, rendered
from the true pose with the scene's landmarks (core.sim.render.landmarks, walls and furniture
hiding them) and detected with the calibrated K, dist; every estimate lives in the odometry
frame. PBVS: the task function e = (t - t*, theta u) is the landmark's estimated pose against
the reading pose T* (the camera on the mark's horizontal normal at the distance where a module
spans READ_MODULE_PX pixels, looking at its centre); since the base is nonholonomic and the head
keeps the mark in view, the base is driven to the floor pose under T* by the polar
pose-regulation law (Astolfi 1999) and the head's pan and tilt aim at the mark; the estimate is
refreshed every frame, and reading stops when the symbol decodes. The base gets there without
touching furniture the way a robot with a map would: the floor plan (walls, doors, furniture
footprints; a prior, like the installer's plan) is its occupancy grid (core.navigation,
inflated by the base radius and PLAN_MARGIN); a route planned on it leads to a hand-over point
on the mark's estimated normal, APPROACH_M behind the reading pose, re-planned when the
estimate moves by REPLAN_M; from there the polar law drives straight in. The survey maps what
it reads through the robot's pose estimate: the odometry, fused by an extended Kalman filter
(core.sim.survey_localisation) with the fixes a robot in this home gets without the twin's
truth: a signpost (whose payload carries its world pose) read within RELOCALISE_M, and, about
once a second while the base moves, its top marker located by the ceiling cameras of the
home's installed calibration; each correction is spread back over the reads since the
previous one (_Survey). Routes are kept on the floor plan's frame and followed through the
estimate of the moment, so a fix on the way brings the base back onto them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from itertools import combinations
from typing import Any

import cv2
import numpy as np
import zxingcpp
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.camera import undistort_points
from core.geometry.polygon import points_in_polygons
from core.geometry.rotations import quaternion_to_matrix, wrap_angle
from core.landmarks.ambiguity import PoseHypothesis, fuse_hypotheses, is_decided
from core.landmarks.artwork import make_artwork, pattern_layout
from core.landmarks.detect import LandmarkDetection, detect_landmarks
from core.landmarks.maps import (
    NavigationMap,
    NoRoute,
    SemanticMap,
    detection_in_world,
    hypotheses_in_world,
)
from core.landmarks.payload import ObjectMark, PayloadError, Signpost, decode_payload
from core.localization import NetworkCamera
from core.localization.occluders import line_of_sight
from core.navigation import (
    BlockedEndpoint,
    OccupancyGrid,
    occupancy_grid,
    plan_path,
    segment_is_free,
)
from core.navigation import NoRoute as NoPath
from core.sim.intrinsics import NOISE, calibrate_from_board_views, facing
from core.sim.motion import Pose2D, UnicycleBase
from core.sim.occluders import scene_occluders
from core.sim.render.landmarks import (
    LandmarkCamera,
    LandmarkView,
    artwork_texture,
    render_landmarks,
    render_scene_landmarks,
    scene_landmarks,
    tag_texture,
)
from core.sim.scene import CameraMount, HeadCamera, Scene, default_scene
from core.sim.survey_localisation import (
    CEILING_HZ,
    CEILING_MIN_MOVE_M,
    CeilingLocaliser,
    installed_cameras,
    kalman_update,
    propagate,
)

Array = NDArray[np.float64]

HEAD_CAMERA = LandmarkCamera(
    np.array([[600.0, 0.0, 321.5], [0.0, 600.0, 242.0], [0.0, 0.0, 1.0]]),
    np.array([-0.12, 0.05, 0.001, -0.0005, 0.0]),
    640,
    480,
)
OBLIQUITY_BINS = tuple((float(a), float(a + 10)) for a in range(0, 70, 10))
LOCATION_RANGE = (0.5, 5.0)
READING_MODULE_PX = (1.5, 5.0)
READING_MIN_M = 0.12
LOCATE_LIMIT_M = {"object": 3.0, "signpost": 5.0}
SIZES = {"object": 0.10, "signpost": 0.20}
FLIP_DEG = 15.0
MIN_DECODE_MODULE_PX = 2.0
CALIBRATION_VIEWS = 12

_CUP = ObjectMark(12, "cup", "blue cup", "kitchen", (0.08, 0.08, 0.1), hints=("fragile",))
_DOOR = Signpost(3, "kitchen door", "kitchen", (2.5, 3.0, 1.4, 0.0, 0.0, 0.7071, 0.7071), (1, 4))


@dataclass(frozen=True)
class LandmarkPoseBin:
    """One kind's figures in one obliquity bin (see the module docstring); None where a bin
    has no view to measure. The `*_within_limit` figures count only the location views within
    the kind's required range (LOCATE_LIMIT_M: 3 m for object marks, 5 m for signposts)."""

    kind: str
    obliquity_deg: tuple[float, float]
    views: int
    located_pct: float
    position_error_pct_median: float | None
    position_error_pct_p95: float | None
    normal_error_deg_median: float | None
    normal_error_deg_p95: float | None
    flips_pct: float | None
    decode_views: int
    decoded_pct: float | None
    zxing_raw_pct: float | None
    opencv_raw_pct: float | None
    tag_located_pct: float
    tag_position_error_pct_median: float | None
    tag_normal_error_deg_median: float | None
    tag_normal_error_deg_p95: float | None
    tag_flips_pct: float | None
    normal_error_deg_p95_within_limit: float | None = None
    flips_pct_within_limit: float | None = None
    tag_normal_error_deg_p95_within_limit: float | None = None
    tag_flips_pct_within_limit: float | None = None
    undecided_pct: float | None = None
    decided_flips_pct: float | None = None


@dataclass(frozen=True)
class LandmarkPoseResult:
    """Metrics of `landmark-pose`: the head camera's calibration error (focal % and principal
    point px of the calibrated K against the true one, calibration RMS px), per-bin figures,
    and the acceptance figures of spec 04 (`goals`)."""

    scenario: str
    seed: int
    views_per_bin: int
    camera_source: str
    calibration_rms_px: float
    calibration_focal_error_pct: float
    calibration_principal_point_error_px: float
    bins: tuple[LandmarkPoseBin, ...]
    goals: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def head_camera(scene: Scene | None) -> tuple[LandmarkCamera, str]:
    """Return the true head camera: the scene robot's head camera, else its onboard camera,
    else HEAD_CAMERA."""
    robot = None if scene is None else scene.robot
    mount: HeadCamera | CameraMount | None = None
    source = "scene robot"
    if robot is not None:
        mount = robot.head_camera
        if mount is None:
            mount, source = robot.onboard_camera, "scene robot's onboard camera"
    if mount is None:
        return HEAD_CAMERA, "default head camera (600 px, 640x480)"
    K = np.array(mount.intrinsics.matrix(), dtype=np.float64)
    w, h = mount.resolution
    return LandmarkCamera(K, np.array(mount.distortion.opencv()), int(w), int(h)), source


def calibrate_head_camera(
    cam: LandmarkCamera, rng: np.random.Generator, views: int = CALIBRATION_VIEWS
) -> tuple[Array, Array, float]:
    """Return (K, dist, rms px) of the camera calibrated from rendered chessboard views
    (core.sim.intrinsics)."""
    cal = calibrate_from_board_views(cam, rng, views, NOISE)
    return cal.K, cal.dist, cal.rms


def _percentile(x: list[float], q: float) -> float | None:
    return float(np.percentile(x, q)) if x else None


def _pct(k: int, n: int) -> float | None:
    return 100.0 * k / n if n else None


def _place(
    cam: LandmarkCamera, rng: np.random.Generator, distance: float, obliquity: float, size: float
) -> Array | None:
    """Return T_cam_mark with the pattern inside the image (None if this draw leaves it)."""
    u = rng.uniform(0.15, 0.85) * cam.width
    v = rng.uniform(0.15, 0.85) * cam.height
    ray = np.append(undistort_points(np.array([u, v]), cam.K, cam.dist), 1.0)
    T = np.eye(4)
    T[:3, :3] = facing(np.radians(obliquity), rng.uniform(0, 2 * np.pi), rng.uniform(-np.pi, np.pi))
    T[:3, 3] = distance * ray / np.linalg.norm(ray)
    h = size / 2 * 1.05
    corners = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]) @ T[:3, :3].T + T[:3, 3]
    if np.any(corners[:, 2] < 0.1):
        return None
    px = corners @ cam.K.T
    px = px[:, :2] / px[:, 2:]
    if np.any(px < 2) or np.any(px[:, 0] > cam.width - 3) or np.any(px[:, 1] > cam.height - 3):
        return None
    return T


@dataclass
class _Tally:
    views: int = 0
    located: int = 0
    pos: list[float] | None = None
    nrm: list[float] | None = None
    dec_views: int = 0
    ours: int = 0
    zx: int = 0
    cvr: int = 0
    tag_loc: int = 0
    tag_pos: list[float] | None = None
    tag_nrm: list[float] | None = None
    undecided: int = 0
    decided_flips: int = 0

    def __post_init__(self) -> None:
        self.pos, self.nrm, self.tag_pos, self.tag_nrm = [], [], [], []


_CV_QR = cv2.QRCodeDetector()
_ARUCO = cv2.aruco.ArucoDetector(
    cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), cv2.aruco.DetectorParameters()
)


def _normal_error(n: Array, T: Array) -> float:
    return float(np.degrees(np.arccos(np.clip(n @ T[:3, 2], -1.0, 1.0))))


def _score_ours(
    view: LandmarkView,
    T: Array,
    kind: str,
    K: Array,
    dist: Array,
    tally: _Tally,
    text: str,
    location: bool,
) -> None:
    image = view.image
    d = float(np.linalg.norm(T[:3, 3]))
    dets = detect_landmarks(image, K, dist, frame_size=SIZES["object"], ring_size=SIZES["signpost"])
    hits = [x for x in dets if x.kind == kind and np.linalg.norm(x.position - T[:3, 3]) < 0.1 * d]
    module = view.truth[0].module_px
    if location:
        tally.views += 1
        if hits:
            tally.located += 1
            assert tally.pos is not None and tally.nrm is not None
            tally.pos.append(100 * float(np.linalg.norm(hits[0].position - T[:3, 3])) / d)
            tally.nrm.append(_normal_error(hits[0].normal, T))
            if not hits[0].decided:
                tally.undecided += 1
            elif tally.nrm[-1] > FLIP_DEG:
                tally.decided_flips += 1
    if module is not None and module >= MIN_DECODE_MODULE_PX:
        tally.dec_views += 1
        tally.ours += any(h.text == text for h in hits)
        tally.zx += any(r.text == text for r in zxingcpp.read_barcodes(image))
        try:
            got, _, _ = _CV_QR.detectAndDecode(image)
        except cv2.error:
            got = ""
        tally.cvr += got == text


def _score_tag(
    image: NDArray[Any], T: Array, size: float, K: Array, dist: Array, tally: _Tally
) -> None:
    d = float(np.linalg.norm(T[:3, 3]))
    corners, ids, _ = _ARUCO.detectMarkers(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    if ids is None:
        return
    h = size / 2
    obj = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], np.float64)
    for c, i in zip(corners, ids.ravel(), strict=True):
        if i != 0:
            continue
        ok, rvec, tvec = cv2.solvePnP(
            obj, c.reshape(4, 2).astype(np.float64), K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
        if not ok:
            continue
        t = tvec.ravel()
        if np.linalg.norm(t - T[:3, 3]) >= 0.1 * d:
            continue
        tally.tag_loc += 1
        assert tally.tag_pos is not None and tally.tag_nrm is not None
        tally.tag_pos.append(100 * float(np.linalg.norm(t - T[:3, 3])) / d)
        R, _ = cv2.Rodrigues(rvec)
        tally.tag_nrm.append(_normal_error(np.asarray(R, np.float64)[:, 2], T))
        return


def landmark_pose(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    views_per_bin: int = 12,
    bins: tuple[tuple[float, float], ...] = OBLIQUITY_BINS,
    calibration_views: int = CALIBRATION_VIEWS,
) -> LandmarkPoseResult:
    """Return the metrics of `landmark-pose` (module docstring) for `seed`; `views_per_bin`,
    `bins` and `calibration_views` set the study's size (not its conditions)."""
    if views_per_bin < 1 or calibration_views < 3 or not bins:
        raise InvalidInput("landmark-pose needs views_per_bin >= 1, calibration_views >= 3, bins")
    rng = np.random.default_rng(seed)
    cam, source = head_camera(scene)
    K, dist, rms = calibrate_head_camera(cam, rng, calibration_views)
    f_true = (cam.K[0, 0] + cam.K[1, 1]) / 2
    f_err = 100 * ((K[0, 0] + K[1, 1]) / 2 - f_true) / f_true
    pp_err = float(np.linalg.norm(K[:2, 2] - cam.K[:2, 2]))
    textures = {
        "object": (artwork_texture(make_artwork(_CUP, size=SIZES["object"])), make_artwork(_CUP)),
        "signpost": (
            artwork_texture(make_artwork(_DOOR, size=SIZES["signpost"])),
            make_artwork(_DOOR),
        ),
    }
    tags = {k: tag_texture(s) for k, s in SIZES.items()}
    out = []
    limits: dict[str, list[bool]] = {"object": [], "signpost": []}
    at45: dict[str, tuple[list[float], list[float]]] = {"object": ([], []), "signpost": ([], [])}
    for kind in ("object", "signpost"):
        tex, art = textures[kind]
        module = art.module_mm / 1000.0
        for lo, hi in bins:
            tally = _Tally()
            near: list[float] = []
            near_tag: list[float] = []
            for location in (True, False):
                rlo, rhi = LOCATION_RANGE
                made = 0
                while made < views_per_bin:
                    obl = rng.uniform(lo, hi)
                    if location:
                        d = float(np.exp(rng.uniform(np.log(rlo), np.log(rhi))))
                    else:
                        # Modules of 1.5-5 px along the foreshortened axis at this obliquity.
                        target = rng.uniform(*READING_MODULE_PX)
                        d = float(cam.K[0, 0] * module * np.cos(np.radians(obl)) / target)
                        d = max(d, READING_MIN_M)
                    T = _place(cam, rng, d, obl, art.size)
                    if T is None:
                        continue
                    made += 1
                    noise_seed = int(rng.integers(2**31))
                    view = render_landmarks(
                        cam, [(tex, T, art.size, module)], noise=NOISE, rng=noise_seed
                    )
                    n_before = tally.located
                    _score_ours(view, T, kind, K, dist, tally, art.text, location)
                    if location:
                        assert tally.nrm is not None and tally.tag_nrm is not None
                        if d <= LOCATE_LIMIT_M[kind]:
                            limits[kind].append(tally.located > n_before)
                            if tally.located > n_before:
                                near.append(tally.nrm[-1])
                        if (
                            40 <= obl < 50
                            and d <= LOCATE_LIMIT_M[kind]
                            and tally.located > n_before
                        ):
                            assert tally.pos is not None and tally.nrm is not None
                            at45[kind][0].append(tally.pos[-1])
                            at45[kind][1].append(tally.nrm[-1])
                        tag_view = render_landmarks(
                            cam, [(tags[kind], T)], noise=NOISE, rng=noise_seed
                        )
                        n_tag = len(tally.tag_nrm)
                        _score_tag(tag_view.image, T, SIZES[kind], K, dist, tally)
                        if d <= LOCATE_LIMIT_M[kind] and len(tally.tag_nrm) > n_tag:
                            near_tag.append(tally.tag_nrm[-1])
            assert tally.pos is not None and tally.nrm is not None
            assert tally.tag_pos is not None and tally.tag_nrm is not None
            out.append(
                LandmarkPoseBin(
                    kind=kind,
                    obliquity_deg=(lo, hi),
                    views=tally.views,
                    located_pct=100.0 * tally.located / max(tally.views, 1),
                    position_error_pct_median=_percentile(tally.pos, 50),
                    position_error_pct_p95=_percentile(tally.pos, 95),
                    normal_error_deg_median=_percentile(tally.nrm, 50),
                    normal_error_deg_p95=_percentile(tally.nrm, 95),
                    flips_pct=_pct(sum(e > FLIP_DEG for e in tally.nrm), len(tally.nrm)),
                    decode_views=tally.dec_views,
                    decoded_pct=_pct(tally.ours, tally.dec_views),
                    zxing_raw_pct=_pct(tally.zx, tally.dec_views),
                    opencv_raw_pct=_pct(tally.cvr, tally.dec_views),
                    tag_located_pct=100.0 * tally.tag_loc / max(tally.views, 1),
                    tag_position_error_pct_median=_percentile(tally.tag_pos, 50),
                    tag_normal_error_deg_median=_percentile(tally.tag_nrm, 50),
                    tag_normal_error_deg_p95=_percentile(tally.tag_nrm, 95),
                    tag_flips_pct=_pct(
                        sum(e > FLIP_DEG for e in tally.tag_nrm), len(tally.tag_nrm)
                    ),
                    normal_error_deg_p95_within_limit=_percentile(near, 95),
                    flips_pct_within_limit=_pct(sum(e > FLIP_DEG for e in near), len(near)),
                    tag_normal_error_deg_p95_within_limit=_percentile(near_tag, 95),
                    tag_flips_pct_within_limit=_pct(
                        sum(e > FLIP_DEG for e in near_tag), len(near_tag)
                    ),
                    undecided_pct=_pct(tally.undecided, tally.located),
                    decided_flips_pct=_pct(tally.decided_flips, tally.located - tally.undecided),
                )
            )
    goals = _goals(out, limits, at45)
    return LandmarkPoseResult(
        scenario="landmark-pose",
        seed=seed,
        views_per_bin=views_per_bin,
        camera_source=source,
        calibration_rms_px=float(rms),
        calibration_focal_error_pct=float(f_err),
        calibration_principal_point_error_px=pp_err,
        bins=tuple(out),
        goals=goals,
    )


def _goals(
    bins: list[LandmarkPoseBin],
    limits: dict[str, list[bool]],
    at45: dict[str, tuple[list[float], list[float]]],
) -> dict[str, Any]:
    """Return the section-5 figures: located % within each kind's limit, medians at 40-50 deg,
    the worst bin's p95 normal error (a flip when over FLIP_DEG), decoding against zxing-cpp."""
    g: dict[str, Any] = {}
    for kind in ("object", "signpost"):
        g[f"{kind}_located_within_{LOCATE_LIMIT_M[kind]:g}m_pct"] = _pct(
            sum(limits[kind]), len(limits[kind])
        )
        pos, nrm = at45[kind]
        g[f"{kind}_position_error_pct_median_at_45deg"] = _percentile(pos, 50)
        g[f"{kind}_normal_error_deg_median_at_45deg"] = _percentile(nrm, 50)
        mine = [b for b in bins if b.kind == kind]
        p95 = [b.normal_error_deg_p95 for b in mine if b.normal_error_deg_p95 is not None]
        g[f"{kind}_normal_error_deg_p95_worst_bin"] = max(p95) if p95 else None
        tp95 = [b.tag_normal_error_deg_p95 for b in mine if b.tag_normal_error_deg_p95 is not None]
        g[f"{kind}_tag_normal_error_deg_p95_worst_bin"] = max(tp95) if tp95 else None
        lim = f"within_{LOCATE_LIMIT_M[kind]:g}m"
        w95 = [
            b.normal_error_deg_p95_within_limit
            for b in mine
            if b.normal_error_deg_p95_within_limit is not None
        ]
        g[f"{kind}_normal_error_deg_p95_worst_bin_{lim}"] = max(w95) if w95 else None
        tw95 = [
            b.tag_normal_error_deg_p95_within_limit
            for b in mine
            if b.tag_normal_error_deg_p95_within_limit is not None
        ]
        g[f"{kind}_tag_normal_error_deg_p95_worst_bin_{lim}"] = max(tw95) if tw95 else None
        ok = [
            b.decoded_pct >= b.zxing_raw_pct
            for b in mine
            if b.decoded_pct is not None and b.zxing_raw_pct is not None
        ]
        g[f"{kind}_decoded_at_least_zxing_in_every_bin"] = all(ok) if ok else None
        last = [b for b in mine if b.obliquity_deg[0] >= 60 and b.decoded_pct is not None]
        g[f"{kind}_decoded_pct_60_70deg"] = last[0].decoded_pct if last else None
    g["flip_deg"] = FLIP_DEG
    # Spec 04: no flip at the 95th percentile, over the views each kind must be located in.
    g["no_flip_at_p95"] = all(
        v is not None and v < FLIP_DEG
        for k, v in g.items()
        if "_normal_error_deg_p95_worst_bin_within_" in k and "tag" not in k
    )
    return g


# --------------------------------------------------------------------------------------------
# The head on its pan-tilt unit, and reading a landmark by PBVS

# Camera axes at pan = tilt = 0 in the robot frame: z forward (+x), x right (-y), y down (-z).
_R_ROBOT_CAM0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
FRAME_DT = 0.2  # s: the head camera's frame period while reading and surveying
BASE_DT = 0.05  # s: the base's simulation step
# QR modules the controller assumes before a symbol is read (version 5: 37 modules, payloads
# up to 84 bytes at level M); the reading distance puts such a module on READ_MODULE_PX pixels.
READ_MODULES = 37
READ_MODULE_PX = 3.3
MIN_STANDOFF = 0.22  # m: camera-to-face horizontal distance at the reading pose, at least
# Polar pose-regulation gains (Astolfi 1999; Siegwart & Nourbakhsh, Introduction to
# Autonomous Mobile Robots, sec. 3.6.2.4): k_rho > 0, k_beta < 0, k_alpha > k_rho for local
# exponential stability, and k_alpha + 5/3 k_beta - 2/pi k_rho > 0 (here 0.27) for strong
# stability (no cusp towards the goal).
K_RHO, K_ALPHA, K_BETA = 0.4, 1.2, -0.4
SEARCH_TILT = 0.05  # rad: the head's tilt while searching (marks at 0.8-1.5 m, head at 1.1 m)
# Tilts of successive search sweeps (rad): level, then up for marks near and above the head.
SEARCH_TILTS = (SEARCH_TILT, -0.3)
MATCH_RADIUS = 0.5  # m: a detection within this of the estimate is the tracked landmark
READ_TIMEOUT_S = 60.0
RELOCALISE_M = 1.5  # m: a signpost read from nearer than this corrects the odometry
RELOCALISE_GATE = (1.0, 0.35)  # m, rad: larger corrections are outliers
RELOCALISE_CHI2 = 11.34  # chi-square, 3 degrees of freedom, 99 %: the fix's consistency gate
# The approach: a collision-free route on the floor plan (walls and furniture footprints
# inflated by the base radius and PLAN_MARGIN; core.navigation) to the hand-over point,
# APPROACH_M behind the estimated reading pose on the mark's normal; there the base turns to
# face the mark and the PBVS law drives the last, straight stretch.
PLAN_RESOLUTION = 0.05  # m: the occupancy grid's cell
PLAN_MARGIN = 0.05  # m beyond the base radius where the base may stand (reading poses)
# m beyond the base radius along routes: the pose estimate drifts by several centimetres
# between two signposts (10 cm measured in the survey), so routes keep off obstacles by more
# where the floor allows (where it does not, routes fall back to PLAN_MARGIN).
TRANSIT_MARGIN = 0.15
APPROACH_M = 0.4  # m: the hand-over point's distance behind the reading pose, at most
REPLAN_M = 0.15  # m: the reading pose's estimate moving more than this re-plans the route
REPLAN_RAD = 0.3  # rad: likewise for its heading
WAYPOINT_M = 0.05  # m: a route point counts as reached within this
TURN_IN_PLACE_RAD = 0.35  # rad: larger heading errors turn the base on the spot
FACE_RAD = 0.05  # rad: heading error at the hand-over point below which PBVS takes over
FOLLOW_GAIN = 2.0  # 1/s: turn rate per radian of heading error while following the route


def _rz(a: float) -> Array:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(a: float) -> Array:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def robot_head_pose(head: HeadCamera, pan: float, tilt: float) -> Array:
    """Return T_robot_cam (4, 4) of the head camera at joint angles pan, tilt (radians)."""
    T = np.eye(4)
    T[:3, :3] = _rz(pan) @ _ry(tilt) @ _R_ROBOT_CAM0
    T[:3, 3] = head.position
    return T


def floor_pose(x: float, y: float, yaw: float) -> Array:
    """Return T_world_robot (4, 4) of a floor pose (x, y metres, yaw radians)."""
    T = np.eye(4)
    T[:3, :3] = _rz(yaw)
    T[:3, 3] = (x, y, 0.0)
    return T


def reading_standoff(kind: str, focal_px: float, dz: float) -> float:
    """Return the reading pose's horizontal distance d (m) from the camera to a vertical face
    whose centre lies dz metres below the camera: the farthest d at which a nominal module
    (READ_MODULES across the symbol) spans READ_MODULE_PX along the foreshortened axis,
    f m d / (d^2 + dz^2) = px (a quadratic in d), else d = |dz| (45 deg, where that span
    peaks); at least MIN_STANDOFF."""
    a = focal_px * pattern_layout(kind, SIZES[kind]).qr_side / READ_MODULES
    disc = a**2 - 4 * READ_MODULE_PX**2 * dz**2
    d = (a + np.sqrt(disc)) / (2 * READ_MODULE_PX) if disc >= 0 else abs(dz)
    return float(max(d, MIN_STANDOFF))


def polar_command(robot: Array, goal: Array) -> tuple[float, float, float]:
    """Return (v, omega, rho) of the polar pose-regulation law driving a unicycle at robot
    (x, y, yaw) to goal (x, y, yaw): rho, alpha, beta as in Siegwart & Nourbakhsh eq. 3.56
    (the goal frame's origin and heading), reversing when the goal lies behind."""
    dx, dy = goal[0] - robot[0], goal[1] - robot[1]
    rho = float(np.hypot(dx, dy))
    alpha = wrap_angle(np.arctan2(dy, dx) - robot[2])
    direction = 1.0
    if abs(alpha) > np.pi / 2:  # drive backwards: the same law with the heading reversed
        direction = -1.0
        alpha = wrap_angle(alpha + np.pi)
    beta = wrap_angle(goal[2] - robot[2] - alpha)
    v = direction * K_RHO * rho
    omega = K_ALPHA * alpha + K_BETA * beta
    return v, omega, rho


@dataclass
class _Track:
    """The tracked landmark in the odometry frame: T_odom_mark, its kind, last seen time, and
    the poses the views so far leave possible (core.landmarks.ambiguity, best first, T the
    first; () for a landmark known from a map, not seen yet)."""

    T: Array
    kind: str
    seen: float
    hypotheses: tuple[PoseHypothesis, ...] = ()

    @property
    def decided(self) -> bool:
        """Return whether the views decide the landmark's pose."""
        return is_decided(self.hypotheses)

    def normal(self) -> Array:
        """Return the normal to approach along (odometry frame): the pose's when decided, else
        the hypotheses' probability-weighted mean (between the two candidates: the line of
        sight, where the next views decide), never one of two undecided normals."""
        if self.decided:
            return self.T[:3, 2]
        return np.asarray(sum(h.probability * h.normal for h in self.hypotheses), dtype=np.float64)


@dataclass
class _Approach:
    """A planned approach: `target` the reading pose (x, y, yaw; odometry frame) it was
    planned for, `offset` (2,; odometry frame) from the estimated reading pose to the free one
    the route leads to (zero unless the estimate fell in an obstacle's margin), `route` (N, 2)
    ending at the hand-over point, in the world (the floor plan's frame: followed through the
    pose estimate of the moment, so a fix made on the way moves the base back onto it), the
    next route point's index, and whether PBVS drives now (`final`)."""

    target: Array
    offset: Array
    route: Array
    index: int = 1
    final: bool = False


@dataclass(frozen=True)
class ReadOutcome:
    """One PBVS reading: whether the symbol was read, when (s after the start), the decoded
    detection (None when unread) with the camera pose it was seen from (odometry frame), the
    frames processed, the final task error |t - t*| (m) and angle (deg) from the estimate."""

    read: bool
    time: float
    detection: LandmarkDetection | None
    T_odom_cam: Array | None
    frames: int
    final_translation_error: float | None
    final_rotation_error_deg: float | None


class HeadRobot:
    """The robot of the landmark scenarios: a unicycle base (true pose, odometry), the head's
    pan-tilt joints (rate limited) and its camera rendered from the true pose; the estimators
    see only the images (through the calibrated K, dist) and the odometry."""

    def __init__(
        self,
        scene: Scene,
        K: Array,
        dist: Array,
        *,
        start: Array | None = None,
        rng: np.random.Generator,
        ceiling: CeilingLocaliser | None = None,
    ) -> None:
        if scene.robot is None or scene.robot.head_camera is None:
            raise InvalidInput("the landmark scenarios need a robot with a head_camera")
        self.scene = scene
        self.robot = scene.robot
        self.head: HeadCamera = scene.robot.head_camera
        self.camera, _ = head_camera(scene)
        self.K, self.dist = K, dist
        s = Pose2D(*(self.robot.start if start is None else start))
        self.base = UnicycleBase(self.robot.limits, self.robot.slip, s, dt=BASE_DT, rng=rng)
        self.rng = rng
        self.pan = 0.0
        self.tilt = 0.0
        self.landmarks = scene_landmarks(scene)
        self.occluders = scene_occluders(scene)
        self.seen: set[int] = set()  # landmarks drawn whole in some frame (for scoring)
        self.collided = False  # the true base touched a wall or furniture (for scoring)
        # The odometry frame in the world: identity at the start (the known start pose),
        # corrected by every fix (a signpost read, relocalise; the ceiling cameras, `ceiling`).
        self.T_world_odom = np.eye(4)
        self.frames = 0
        self.drift_clock = 0.0  # metres driven plus radians turned, on the odometry
        # The pose estimate's covariance (x, y, yaw), now: zero at the known start, grown by
        # the odometry's slip and shrunk by fixes (core.sim.survey_localisation).
        self.P = np.zeros((3, 3))
        # Every correction of T_world_odom: (drift clock, before, after).
        self.fixes: list[tuple[float, Array, Array]] = []
        self.ceiling = ceiling
        self.moved = 0.0  # metres driven since the last ceiling frame
        # The floor plan (walls, doors, furniture footprints) is the robot's map, a prior.
        self.grid: OccupancyGrid = occupancy_grid(
            scene, self.robot.base_radius + PLAN_MARGIN, PLAN_RESOLUTION
        )
        self.transit: OccupancyGrid = occupancy_grid(
            scene, self.robot.base_radius + TRANSIT_MARGIN, PLAN_RESOLUTION
        )
        self.approach: _Approach | None = None

    @property
    def time(self) -> float:
        """Return the simulated time, s."""
        return self.base.clock.time

    def odom(self) -> Array:
        """Return the odometry pose (x, y, yaw)."""
        return self.base.state.odometry.as_array()

    def estimate(self) -> Array:
        """Return the base's estimated pose (x, y, yaw) in the world: T_world_odom o odometry."""
        o = self.odom()
        W = self.T_world_odom
        p = W @ np.array([o[0], o[1], 0.0, 1.0])
        return np.array([p[0], p[1], wrap_angle(o[2] + float(np.arctan2(W[1, 0], W[0, 0])))])

    def _correct(self, x: Array, P: Array) -> None:
        """Make (x, y, yaw) the base's estimated pose now, with covariance P (a fix)."""
        W = self.T_world_odom
        self.T_world_odom = floor_pose(*x) @ np.linalg.inv(floor_pose(*self.odom()))
        self.P = P
        self.fixes.append((self.drift_clock, W, self.T_world_odom))

    def T_odom_cam(self) -> Array:
        """Return the head camera's pose in the odometry frame (4, 4)."""
        o = self.odom()
        return floor_pose(*o) @ robot_head_pose(self.head, self.pan, self.tilt)

    def aim(self, pan: float, tilt: float, dt: float) -> None:
        """Move the joints towards (pan, tilt) within their limits and rate for dt seconds."""
        step = self.head.max_rate * dt
        lo, hi = self.head.pan_limits
        self.pan += float(np.clip(np.clip(pan, lo, hi) - self.pan, -step, step))
        lo, hi = self.head.tilt_limits
        self.tilt += float(np.clip(np.clip(tilt, lo, hi) - self.tilt, -step, step))

    def look(self) -> list[LandmarkDetection]:
        """Return the detections in the head camera's frame rendered now (true pose)."""
        p = self.base.state.pose
        T_world_cam = floor_pose(p.x, p.y, p.yaw) @ robot_head_pose(self.head, self.pan, self.tilt)
        view, idx = render_scene_landmarks(
            self.camera,
            T_world_cam,
            self.landmarks,
            self.occluders,
            noise=NOISE,
            rng=int(self.rng.integers(2**31)),
        )
        self.seen.update(idx)
        self.frames += 1
        up = T_world_cam[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # gravity: a level base
        return detect_landmarks(
            view.image,
            self.K,
            self.dist,
            frame_size=SIZES["object"],
            ring_size=SIZES["signpost"],
            up=up,
        )

    def drive(self, v: float, omega: float, dt: float) -> None:
        """Command the base (v m/s, omega rad/s) for dt seconds; the pose estimate's
        covariance follows the odometry (propagate), and the ceiling cameras fix it about
        CEILING_HZ times a second while the base moves (when `ceiling` is given)."""
        for _ in range(max(1, round(dt / BASE_DT))):
            before = self.base.state.odometry
            self.base.step(v, omega)
            after = self.base.state.odometry
            # The odometry's drift grows with the distance driven and the angle turned (the
            # slip model's variances are linear in both): the clock the survey spreads a
            # relocalisation's correction along.
            step = float(np.hypot(after.x - before.x, after.y - before.y))
            self.drift_clock += step + abs(wrap_angle(after.yaw - before.yaw))
            W = self.T_world_odom
            yaw = before.yaw + float(np.arctan2(W[1, 0], W[0, 0]))
            self.P = propagate(self.P, yaw, before, after, self.robot.slip)
            self.moved += step
            self.collided = self.collided or self.collides()
            c = self.ceiling
            if c is not None and self.moved >= CEILING_MIN_MOVE_M and c.due(self.time):
                self.moved = 0.0
                x = self.estimate()
                fix = c.observe(self.time, self.base.state.pose, x)
                if fix is not None:
                    k = c.update(x, self.P, fix)
                    if k.accepted:
                        self._correct(k.x, k.P)

    def collides(self) -> bool:
        """Return whether the true base overlaps a wall or a piece of furniture (scoring)."""
        p = self.base.state.pose
        return _clearance(self, np.array([p.x, p.y])) < 0.0

    def relocalise(self, det: LandmarkDetection, T_odom_cam: Array) -> bool:
        """Correct T_world_odom from a signpost read within RELOCALISE_M with its rotation
        fixed by the symbol (its payload carries its world pose): the fix T_world_cam =
        T_world_mark T_cam_mark^-1, kept planar (camera x, y and the odometry frame's yaw), with
        its covariance from the detection's (first order), is fused with the pose estimate by
        a Kalman update (core.sim.survey_localisation: the state is the base's pose now, the
        camera a point fixed on it, P the estimate's covariance grown by the odometry's slip
        since the last fix). A ring's yaw is its weakest direction (degrees), so the estimate
        keeps weight there. A correction larger than RELOCALISE_GATE (m, rad), or whose
        innovation fails the chi-square test (RELOCALISE_CHI2), is refused as an outlier.
        Return whether it was applied."""
        rec = det.record
        if not isinstance(rec, Signpost) or not det.orientation_known or not det.decided:
            return False  # (a pose the image cannot decide fixes nothing)
        if float(np.linalg.norm(det.position)) > RELOCALISE_M:
            return False
        T_world_mark = np.eye(4)
        T_world_mark[:3, :3] = quaternion_to_matrix(rec.pose[3:])
        T_world_mark[:3, 3] = rec.pose[:3]
        T_wc = T_world_mark @ np.linalg.inv(det.T_cam_mark)
        M = T_wc @ np.linalg.inv(T_odom_cam)
        W = self.T_world_odom
        new = floor_pose(M[0, 3], M[1, 3], float(np.arctan2(M[1, 0], M[0, 0])))
        D = new @ np.linalg.inv(W)
        at = D @ np.append(T_odom_cam[:3, 3], 1.0) - np.append(T_odom_cam[:3, 3], 1.0)
        dist_gate, angle_gate = RELOCALISE_GATE
        if np.hypot(at[0], at[1]) > dist_gate or abs(np.arctan2(D[1, 0], D[0, 0])) > angle_gate:
            return False
        # The fix's covariance: camera position c = -R^T t in the mark frame and the camera's
        # yaw, to first order in (rotation vector, translation) of T_cam_mark.
        R_cm, t = det.T_cam_mark[:3, :3], det.T_cam_mark[:3, 3]
        tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
        J = np.zeros((3, 6))
        J[:2] = (T_world_mark[:3, :3] @ np.hstack([-R_cm.T @ tx, -R_cm.T]))[:2]
        J[2, :3] = -T_wc[2, :3]
        R_fix = J @ det.cov @ J.T
        # The measurement model: the camera where the fix saw it, c = (x, y) + R(phi) (c_odom
        # - o), phi = yaw - yaw_odom the odometry frame's heading (the base's estimated pose
        # x = (x, y, yaw) now, o its odometry now).
        x = self.estimate()
        o = self.odom()
        phi = wrap_angle(float(x[2] - o[2]))
        r_w = _rz(phi)[:2, :2] @ (T_odom_cam[:2, 3] - o[:2])
        H = np.array([[1.0, 0.0, -r_w[1]], [0.0, 1.0, r_w[0]], [0.0, 0.0, 1.0]])
        fix = np.array([T_wc[0, 3], T_wc[1, 3], np.arctan2(M[1, 0], M[0, 0])])
        nu = fix - np.array([x[0] + r_w[0], x[1] + r_w[1], phi])
        nu[2] = wrap_angle(float(nu[2]))
        # A fix that disagrees with the estimate beyond their covariances (the rings' other
        # pose, whose yaw the wide RELOCALISE_GATE still lets through) is an outlier.
        k = kalman_update(x, self.P, nu, H, R_fix, RELOCALISE_CHI2)
        if not k.accepted:
            return False
        k.x[2] = wrap_angle(float(k.x[2]))
        self._correct(k.x, k.P)
        return True

    def locate(self, det: LandmarkDetection) -> Array:
        """Return T_odom_mark (4, 4) of a detection in the current frame."""
        return self.T_odom_cam() @ det.T_cam_mark

    def track(self, det: LandmarkDetection, track: _Track | None = None) -> _Track:
        """Return the track of a landmark after a detection of it in the current frame: a view
        that decides its pose replaces the estimate (the newest, nearest view is the best);
        one that cannot decide is fused with the track's hypotheses (core.landmarks.
        ambiguity.fuse_hypotheses), both carried until the views together decide."""
        hyps = hypotheses_in_world(det, self.T_odom_cam())
        if track is not None and track.hypotheses and not det.decided:
            hyps = fuse_hypotheses(track.hypotheses, hyps)
        return _Track(hyps[0].T, det.kind, self.time, hyps)

    def read(self, track: _Track | None, timeout: float = READ_TIMEOUT_S) -> ReadOutcome:
        """Return the outcome of reading a landmark by PBVS (spec 04 sec. 5).

        Without a track the head first sweeps its pan range with the base still
        (SEARCH_TILTS); the first located landmark (the nearest) is tracked, and never
        exchanged for another. Every frame: re-estimate T_odom_mark from the detection
        nearest the track (within MATCH_RADIUS), else keep it (the odometry moves the robot
        under it); the reading pose puts the camera on the mark's horizontal normal at the
        distance where a nominal module spans READ_MODULE_PX pixels (reading_standoff); the
        base follows a route planned on the floor plan to a point on that normal behind it
        (`_plan_approach`, re-planned when the estimate moves), turns to face the mark, and
        the polar law drives it in; the head aims at the mark throughout. Stops when the
        tracked landmark is decoded, or at `timeout`.
        """
        self.approach = None
        t0 = self.time
        frames0 = self.frames
        f = float((self.K[0, 0] + self.K[1, 1]) / 2)
        sweep = self.head.pan_limits[1]
        sweeps = 0
        if track is not None:  # a landmark located earlier: lost only if unseen from now on
            track = _Track(track.T, track.kind, self.time, track.hypotheses)
        while self.time - t0 < timeout:
            dets = self.look()
            if track is None:
                located = sorted(dets, key=lambda d: float(np.linalg.norm(d.position)))
                if located:
                    track = self.track(located[0])
                else:
                    # Sweep the pan range end to end (0.4 rad a frame, under half the field),
                    # looking level and then up in turn (a signpost near and above the head).
                    if abs(self.pan - sweep) < 1e-9:
                        sweep = -sweep
                        sweeps += 1
                    self.aim(sweep, SEARCH_TILTS[sweeps % 2], FRAME_DT)
                    self.drive(0.0, 0.0, FRAME_DT)
                    continue
            else:
                best = None
                for d in dets:
                    if d.kind != track.kind:
                        continue
                    e = float(np.linalg.norm(self.locate(d)[:3, 3] - track.T[:3, 3]))
                    if e < MATCH_RADIUS and (best is None or e < best[0]):
                        best = (e, d)
                if best is not None:
                    track = self.track(best[1], track)
                    if best[1].record is not None:
                        err = self._task_error(track, f)
                        seen_from = self.T_odom_cam()
                        self.drive(0.0, 0.0, FRAME_DT)  # brake
                        return ReadOutcome(
                            True, self.time - t0, best[1], seen_from, self.frames - frames0, *err
                        )
            self._servo(track, f)
        final: tuple[float | None, float | None] = (None, None)
        if track is not None:
            final = self._task_error(track, f)
        return ReadOutcome(False, self.time - t0, None, None, self.frames - frames0, *final)

    def _goal(self, track: _Track, f: float) -> tuple[Array, Array]:
        """Return the base's reading pose (x, y, yaw) and the camera's (3,) in the odom frame."""
        m = track.T[:3, 3]
        n = track.normal().copy()
        n[2] = 0.0
        nn = float(np.linalg.norm(n))
        if nn < 0.3:  # a mark facing up or down: approach from where the robot stands
            n = np.append(self.odom()[:2] - m[:2], 0.0)
            nn = float(np.linalg.norm(n))
        n /= nn
        d_h = reading_standoff(track.kind, f, float(self.head.position[2] - m[2]))
        cam = m + n * d_h
        cam[2] = self.head.position[2]
        base = m[:2] + n[:2] * (d_h + self.head.position[0])
        return np.array([base[0], base[1], np.arctan2(-n[1], -n[0])]), cam

    def _servo(self, track: _Track, f: float) -> None:
        """Run one frame of the approach: the route while it lasts, then the polar law; the
        base's controller runs every BASE_DT on the odometry, the head aims at the mark."""
        goal, _ = self._goal(track, f)
        ap = self.approach
        if ap is None or (
            np.hypot(*(goal[:2] - ap.target[:2])) > REPLAN_M
            or abs(wrap_angle(goal[2] - ap.target[2])) > REPLAN_RAD
        ):
            ap = self.approach = self._plan_approach(goal)
        final = goal.copy()
        if ap is not None:
            final[:2] += ap.offset

        def command() -> tuple[float, float]:
            if ap is not None and not ap.final:
                return self._follow(ap, final[2])
            o = self.odom()
            v, omega, rho = polar_command(o, final)
            if ap is None and rho > 2 * APPROACH_M:
                return 0.0, 0.0  # no route there: the polar law alone would cut through
            if rho < 0.02 and abs(wrap_angle(final[2] - o[2])) < 0.03:
                return 0.0, 0.0  # at the reading pose: wait for a read
            return v, omega

        v, omega = command()
        # Aim the head at the mark from where the base will be after this frame.
        o = self.odom()
        m_r = np.linalg.inv(floor_pose(*o)) @ np.append(track.T[:3, 3], 1.0)
        rel = m_r[:3] - np.asarray(self.head.position)
        pan = float(np.arctan2(rel[1], rel[0]) - omega * FRAME_DT)
        tilt = float(np.arctan2(-rel[2], np.hypot(rel[0], rel[1])))
        self.aim(pan, tilt, FRAME_DT)
        for k in range(max(1, round(FRAME_DT / BASE_DT))):
            if k:
                v, omega = command()
            self.drive(v, omega, BASE_DT)

    def _free(self, p: Array, grid: OccupancyGrid | None = None) -> bool:
        """Return whether the world point p (x, y) lies in a free cell of `grid` (default: the
        grid of where the base may stand)."""
        g = self.grid if grid is None else grid
        j = int(np.floor((p[0] - g.origin[0]) / g.resolution))
        i = int(np.floor((p[1] - g.origin[1]) / g.resolution))
        rows, cols = g.free.shape
        return bool(0 <= i < rows and 0 <= j < cols and g.free[i, j])

    def _sees(self, a: Array, b: Array) -> bool:
        """Return whether the straight segment a -> b (world x, y) stays in free cells."""
        o = np.asarray(self.grid.origin)
        r = self.grid.resolution
        return segment_is_free(self.grid.free, (a - o) / r, (b - o) / r)

    @staticmethod
    def _nearest_free(g: OccupancyGrid, p: Array, within: float = 0.5) -> Array | None:
        """Return the centre of the free cell of `g` nearest the world point p (x, y) within
        `within` metres, or None."""
        c = g.centres()[g.free]
        if len(c) == 0:
            return None
        d = np.linalg.norm(c - p, axis=1)
        k = int(np.argmin(d))
        return c[k] if d[k] <= within else None

    def _route_on(self, g: OccupancyGrid, a: Array, b: Array) -> Array | None:
        """Return the route (N, 2) from a to b on grid g, with straight legs from a to g's
        nearest free cell and from g's nearest free cell to b when they lie in its margin
        (None when there is no route or those legs cross where the base may not stand)."""
        s = a if self._free(a, g) else self._nearest_free(g, a)
        t = b if self._free(b, g) else self._nearest_free(g, b)
        if s is None or t is None:
            return None
        try:
            route = plan_path(g.free, s, t, resolution=g.resolution, origin=g.origin)
        except (BlockedEndpoint, NoPath):
            return None
        if s is not a:
            # Out of the margin to its nearest free cell (short; checked on the floor where
            # the base may stand, unless it already stands in that margin too).
            if self._free(a) and not self._sees(a, s):
                return None
            route = np.vstack([a, route])
        if t is not b:
            if not self._sees(t, b):
                return None
            route = np.vstack([route, b])
        return route

    def plan_route(self, target_world: Array) -> Array | None:
        """Return a collision-free route (N, 2), world (x, y), from the base's estimated
        position (odometry through T_world_odom) to `target_world`: on the grid inflated by
        TRANSIT_MARGIN where the floor allows, else on the one inflated by PLAN_MARGIN (legs
        in and out of a grid's margin straight; `_route_on`), or None when there is none."""
        W = self.T_world_odom
        o = self.odom()
        here = (W @ np.array([o[0], o[1], 0.0, 1.0]))[:2]
        goal = np.asarray(target_world, dtype=np.float64)
        if not self._free(goal):
            near = self._nearest_free(self.grid, goal)
            if near is None:
                return None
            goal = near
        route = self._route_on(self.transit, here, goal)
        return route if route is not None else self._route_on(self.grid, here, goal)

    def _plan_approach(self, goal: Array) -> _Approach | None:
        """Return the approach to the reading pose `goal` (x, y, yaw; odometry frame): the
        free pose nearest it on the mark's normal (the pose itself, unless the estimate put it
        within an obstacle's margin), else the free pose nearest it, the hand-over point up to
        APPROACH_M behind it with a free straight run in, and the route there; None when no
        free pose or route exists (the polar law then drives alone, and only the last
        2 APPROACH_M: from further it would cut through furniture)."""
        W = self.T_world_odom
        out_w = W[:2, :2] @ -np.array([np.cos(goal[2]), np.sin(goal[2])])  # away from the mark
        g0 = (W @ np.array([goal[0], goal[1], 0.0, 1.0]))[:2]
        steps = np.arange(0.0, 0.5 + 1e-9, PLAN_RESOLUTION)
        shift = next((s for s in steps if self._free(g0 + out_w * s)), None)
        if shift is not None:
            g_w = g0 + out_w * shift
        else:
            # Nothing free on the normal (a mark beside a table's corner): the free pose nearest
            # the reading pose; the head still aims at the mark from there.
            near = self._nearest_free(self.grid, g0)
            if near is None:
                return None
            g_w = near
        hand = next(
            (
                g_w + out_w * s
                for s in np.arange(APPROACH_M, -1e-9, -PLAN_RESOLUTION)
                if self._free(g_w + out_w * s) and self._sees(g_w + out_w * s, g_w)
            ),
            g_w,
        )
        route = self.plan_route(hand)
        if route is None:
            return None
        offset = np.linalg.inv(W)[:2, :2] @ (g_w - g0)
        return _Approach(goal.copy(), offset, route)

    def _follow(self, ap: _Approach, heading: float) -> tuple[float, float]:
        """Return (v, omega) following the route on the odometry: turn on the spot towards
        the next route point when off by more than TURN_IN_PLACE_RAD, else drive at it,
        braking to stop there; at the route's end turn to `heading`, then hand over to PBVS."""
        o = self.odom()
        W_inv = np.linalg.inv(self.T_world_odom)
        route = ap.route @ W_inv[:2, :2].T + W_inv[:2, 3]  # on the odometry, as now corrected
        while ap.index < len(route) and np.hypot(*(route[ap.index] - o[:2])) < WAYPOINT_M:
            ap.index += 1
        if ap.index >= len(route):
            err = wrap_angle(heading - o[2])
            if abs(err) < FACE_RAD:
                ap.final = True
                return 0.0, 0.0
            return 0.0, FOLLOW_GAIN * err
        d = route[ap.index] - o[:2]
        err = wrap_angle(float(np.arctan2(d[1], d[0])) - o[2])
        if abs(err) > TURN_IN_PLACE_RAD:
            return 0.0, FOLLOW_GAIN * err
        lim = self.robot.limits
        # Brake in time for the turn at the next point: v <= sqrt(2 (a / 2) d).
        v = min(lim.max_speed, float(np.sqrt(lim.max_acceleration * np.hypot(*d))))
        return v * float(np.cos(err)), FOLLOW_GAIN * err

    def go_to(self, target_world: Array, timeout: float = 120.0) -> bool:
        """Drive the base to the world point (x, y) along a route planned on the floor plan
        (straight when none exists); return whether it arrived within `timeout` s."""
        route = self.plan_route(np.asarray(target_world, dtype=np.float64))
        if route is None:
            route = np.asarray([target_world], dtype=np.float64)
        ap = _Approach(np.zeros(3), np.zeros(2), route, index=0)
        t0 = self.time
        while self.time - t0 < timeout:
            here = self.estimate()[:2]
            while ap.index < len(route) and np.hypot(*(route[ap.index] - here)) < WAYPOINT_M:
                ap.index += 1
            if ap.index >= len(route):
                self.drive(0.0, 0.0, 0.5)
                return True
            o = self.odom()
            self.drive(*self._follow(ap, o[2]), BASE_DT)
        return False

    def _task_error(self, track: _Track, f: float) -> tuple[float, float]:
        """Return |t - t*| (m) and theta (deg) of e = (t - t*, theta u) from the estimate:
        T* puts the camera at the reading pose looking at the mark's centre."""
        _, cam = self._goal(track, f)
        T_cam_mark = np.linalg.inv(self.T_odom_cam()) @ track.T
        z = track.T[:3, 3] - cam
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R_star = np.column_stack([x, np.cross(z, x), z])  # camera at the reading pose, no roll
        T_star = np.eye(4)
        T_star[:3, :3], T_star[:3, 3] = R_star, cam
        T_star_mark = np.linalg.inv(T_star) @ track.T
        dt = float(np.linalg.norm(T_cam_mark[:3, 3] - T_star_mark[:3, 3]))
        dR = T_cam_mark[:3, :3] @ T_star_mark[:3, :3].T
        ang = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1.0, 1.0))))
        return dt, ang


@dataclass(frozen=True)
class ReadingTrial:
    """One `landmark-reading` trial: the landmark (scene name, kind), the true start (x, y,
    yaw), its distance (m) and bearing off the mark's normal (deg), whether it was read (the
    right landmark, within the time limit, without touching a wall or furniture), the time to
    read (s, None when unread), the frames, the final task error, whether the base collided,
    and the landmark whose record it decoded (`read_landmark`: its scene name, None when
    nothing was decoded; another than `landmark` is a failure)."""

    landmark: str
    kind: str
    start: tuple[float, float, float]
    distance: float
    bearing_deg: float
    read: bool
    time_to_read: float | None
    frames: int
    final_translation_error: float | None
    final_rotation_error_deg: float | None
    collided: bool
    read_landmark: str | None = None


@dataclass(frozen=True)
class LandmarkReadingResult:
    """Metrics of `landmark-reading`: success rate (%) over the trials, times to read (median,
    95th percentile, max, s), per kind, the collisions, the trials that read another landmark
    than theirs (`wrong_landmark_reads`, failures), the landmarks for which some draw found
    no start (another landmark was drawn instead), the goal (spec 04: >= 95 % within 60 s),
    the head camera's calibration RMS (px) and every trial."""

    scenario: str
    seed: int
    trials: int
    success_pct: float
    time_to_read_median: float | None
    time_to_read_p95: float | None
    time_to_read_max: float | None
    success_pct_by_kind: dict[str, float | None]
    collisions: int
    wrong_landmark_reads: int
    landmarks_without_start: tuple[str, ...]
    calibration_rms_px: float
    goals: dict[str, Any]
    runs: tuple[ReadingTrial, ...]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


START_DISTANCE = {"object": (0.8, 2.5), "signpost": (0.8, 4.0)}  # m, horizontal, from the mark
START_BEARING_DEG = 60.0  # start within this of the mark's normal
START_CLEARANCE = 0.1  # m between the base and any wall or furniture at the start
# The trial's landmark as the robot's map holds it: off its true pose by these (per floor axis,
# and in yaw), as a survey's semantic map locates it (landmark-survey: a few centimetres).
READ_PRIOR_M = 0.1
READ_PRIOR_RAD = 0.1


def _calibrated(scene: Scene, rng: np.random.Generator, views: int) -> tuple[Array, Array, float]:
    cam, _ = head_camera(scene)
    return calibrate_head_camera(cam, rng, views)


def _start_pose(
    robot: HeadRobot, k: int, rng: np.random.Generator
) -> tuple[Array, float, float] | None:
    """Return a random free start (x, y, yaw) in front of landmark k with its distance and
    bearing, the mark in the head's line of sight (None if 200 draws find none)."""
    lm = robot.landmarks[k]
    m = lm.T_world_mark[:3, 3]
    n = lm.T_world_mark[:3, 2].copy()
    n[2] = 0.0
    n /= np.linalg.norm(n)
    lo, hi = START_DISTANCE[lm.kind]
    head = np.asarray(robot.head.position)
    for _ in range(200):
        r = rng.uniform(lo, hi)
        b = np.radians(rng.uniform(-START_BEARING_DEG, START_BEARING_DEG))
        p = m[:2] + r * (_rz(b)[:2, :2] @ n[:2])
        to_mark = np.arctan2(m[1] - p[1], m[0] - p[0])
        yaw = wrap_angle(to_mark + rng.uniform(-np.pi / 2, np.pi / 2))
        if (
            _clearance(robot, p) < START_CLEARANCE
            or not points_in_polygons(
                p[None, :2], [room.polygon for room in robot.scene.rooms]
            ).any()
        ):
            continue
        eye = floor_pose(p[0], p[1], yaw) @ np.append(head, 1.0)
        if not line_of_sight(eye[None, :3], m[None], robot.occluders)[0, 0]:
            continue
        return np.array([p[0], p[1], yaw]), float(r), float(np.degrees(b))
    return None


def _clearance(robot: HeadRobot, p: Array) -> float:
    """Return the gap (m) between the base at p (x, y) and the nearest low wall or furniture."""
    occ = robot.occluders
    low = occ.z[:, 0] < robot.robot.base_height
    d = np.asarray(p[:2]) - occ.centre
    c, s = np.cos(occ.yaw), np.sin(occ.yaw)
    local = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1))
    out = np.linalg.norm(np.maximum(local - occ.half_size, 0.0), axis=1)
    return float(np.min(np.where(low, out, np.inf))) - robot.robot.base_radius


def landmark_reading(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    trials: int = 100,
    calibration_views: int = CALIBRATION_VIEWS,
    timeout: float = READ_TIMEOUT_S,
) -> LandmarkReadingResult:
    """Return the metrics of `landmark-reading`: PBVS reading from `trials` random starts.

    Each trial picks one of the scene's landmarks at random and a free start 0.8-2.5 m
    (object marks) or 0.8-4 m (signposts) from it (another landmark when 200 draws find
    none), within 60 deg of its normal, with the mark in the head's line of sight (furniture
    may stand between the base and the reading pose: the approach is planned on the floor
    plan) and the robot turned up to 90 deg away from it. Every landmark of the home is drawn
    in every frame, as it hangs. The robot is told which landmark to read as its map holds it
    (its pose READ_PRIOR_M and READ_PRIOR_RAD off the truth, a landmark located before) and
    reads it with HeadRobot.read (calibrated head camera, odometry from the known start, the
    floor plan as its map), which tracks the detection of its kind nearest that pose (within
    MATCH_RADIUS); a trial succeeds when the decoded record is the trial's landmark's own
    (reading another is a failure, counted in `wrong_landmark_reads`), within `timeout` simulated
    seconds, and the base never touched a wall or furniture (scored on the true pose).
    """
    if trials < 1 or calibration_views < 3 or not timeout > 0:
        raise InvalidInput(
            "landmark-reading needs trials >= 1, calibration_views >= 3 and timeout > 0"
        )
    sc = scene if scene is not None else default_scene()
    rng = np.random.default_rng(seed)
    K, dist, rms = _calibrated(sc, rng, calibration_views)
    robot = HeadRobot(sc, K, dist, rng=rng)
    if not robot.landmarks:
        raise InvalidInput(f"scene {sc.name!r} has no landmarks to read")
    runs = []
    no_start: set[str] = set()
    for _ in range(trials):
        drawn = None
        for _ in range(10 * len(robot.landmarks)):
            k = int(rng.integers(len(robot.landmarks)))
            drawn = _start_pose(robot, k, rng)
            if drawn is not None:
                break
            no_start.add(robot.landmarks[k].name)
        if drawn is None:
            raise InvalidInput(f"no free start in front of any landmark of scene {sc.name!r}")
        start, r, b = drawn
        robot = HeadRobot(sc, K, dist, start=start, rng=rng)
        # The trial's landmark as the robot's map holds it (located before, READ_PRIOR_* off):
        # the robot reads the landmark it locates nearest that, never the truth itself.
        T_prior = robot.landmarks[k].T_world_mark.copy()
        T_prior[:2, 3] += rng.normal(0.0, READ_PRIOR_M, 2)
        T_prior[:3, :3] = _rz(float(rng.normal(0.0, READ_PRIOR_RAD))) @ T_prior[:3, :3]
        res = robot.read(_Track(T_prior, robot.landmarks[k].kind, robot.time), timeout)
        collided = robot.collided
        lm = robot.landmarks[k]
        text = res.detection.text if res.read and res.detection is not None else None
        right = text is not None and text == lm.text
        read_name = next((m.name for m in robot.landmarks if m.text == text), text)
        runs.append(
            ReadingTrial(
                landmark=lm.name,
                kind=lm.kind,
                start=(float(start[0]), float(start[1]), float(start[2])),
                distance=r,
                bearing_deg=b,
                read=bool(right and not collided),
                time_to_read=float(res.time) if right else None,
                frames=res.frames,
                final_translation_error=res.final_translation_error,
                final_rotation_error_deg=res.final_rotation_error_deg,
                collided=collided,
                read_landmark=read_name,
            )
        )
    times = [t.time_to_read for t in runs if t.read and t.time_to_read is not None]
    ok = sum(t.read for t in runs)
    by_kind: dict[str, float | None] = {}
    for kind in ("object", "signpost"):
        mine = [t for t in runs if t.kind == kind]
        by_kind[kind] = _pct(sum(t.read for t in mine), len(mine))
    success = 100.0 * ok / len(runs)
    return LandmarkReadingResult(
        scenario="landmark-reading",
        seed=seed,
        trials=trials,
        success_pct=success,
        time_to_read_median=_percentile(times, 50),
        time_to_read_p95=_percentile(times, 95),
        time_to_read_max=max(times) if times else None,
        success_pct_by_kind=by_kind,
        collisions=sum(t.collided for t in runs),
        wrong_landmark_reads=sum(
            t.read_landmark is not None and t.read_landmark != t.landmark for t in runs
        ),
        landmarks_without_start=tuple(sorted(no_start)),
        calibration_rms_px=float(rms),
        goals={"success_pct_min": 95.0, "within_s": timeout, "met": success >= 95.0},
        runs=tuple(runs),
    )


# --------------------------------------------------------------------------------------------
# The survey: drive the home, read every landmark, build both maps

# The default home's survey tour (x, y metres): straight legs through free floor and the doors,
# living room, kitchen, bedroom; the head sweeps at every stop.
DEFAULT_TOUR = (
    (1.0, 1.2),
    (2.5, 2.2),
    (3.3, 4.6),
    (3.0, 3.5),
    (0.8, 3.2),
    (3.8, 1.45),
    (5.2, 1.45),
    (5.2, 1.0),
    (7.3, 1.05),
    (7.3, 2.5),
    (6.55, 2.55),
    (6.55, 3.45),
    (7.3, 3.45),
    (5.2, 3.5),
    (5.2, 4.4),
)
SWEEP_PANS = tuple(float(a) for a in np.linspace(-2.8, 2.8, 15))
SURVEY_READ_TIMEOUT_S = 40.0
# Reads tried of one located landmark, at most: a read that failed (a long way round the
# furniture within the timeout, a view hidden at the reading pose) is tried again when the
# landmark is located again from a later stop.
SURVEY_READ_TRIES = 2
SEPARATE_M = 0.45  # m: a located landmark nearer than this to a known one of its kind is that one
MATCH_TRUTH_M = 0.5  # m: scoring: a map entry this near its landmark (and of its id) is right


@dataclass(frozen=True)
class SurveyRoute:
    """A route of the navigation map between two rooms: the places, their rooms, length m
    (None and `error` when there is none)."""

    from_room: str
    to_room: str
    places: tuple[int, ...] | None
    rooms: tuple[str, ...] | None
    length_m: float | None
    error: str | None = None


@dataclass(frozen=True)
class LandmarkSurveyResult:
    """Metrics of `landmark-survey`: object marks found / present / seen in the drive (drawn
    whole in at least one head-camera frame), signpost places found / present / seen, the
    semantic map's mean and max position error against the twin (m), false entries (an id no
    landmark carries, or more than MATCH_TRUTH_M from its landmark) and duplicates (two entries
    of one landmark), landmarks seen but not read, the reads attempted by PBVS and their
    successes, the drive's time (s), whether it finished the tour (not cut short by a
    duration) and whether the base ever touched a wall or furniture (scored on the true pose),
    its frames, the odometry's final drift (m) and the final pose estimate's position error
    (m), the ceiling fixes (rate, frames rendered, fixes applied and refused, cameras; empty
    without them), routes between every pair of rooms, and both maps (GeoJSON-like)."""

    scenario: str
    seed: int
    objects_present: int
    objects_seen: int
    objects_found: int
    places_present: int
    places_seen: int
    places_found: int
    position_error_mean_m: float | None
    position_error_max_m: float | None
    false_entries: int
    duplicate_entries: int
    seen_not_read: tuple[str, ...]
    reads_attempted: int
    reads_succeeded: int
    time_s: float
    completed: bool
    collided: bool
    frames: int
    odometry_drift_m: float
    pose_error_m: float
    ceiling: dict[str, float | int]
    calibration_rms_px: float
    routes: tuple[SurveyRoute, ...]
    goals: dict[str, Any]
    semantic_map: dict[str, Any]
    navigation_map: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def _se2_log(D: Array) -> Array:
    """Return (theta, u) (3,) of a planar rigid transform D (4, 4): D = exp(theta, u)."""
    th = float(np.arctan2(D[1, 0], D[0, 0]))
    V = _se2_V(th)
    return np.array([th, *np.linalg.solve(V, D[:2, 3])])


def _se2_V(th: float) -> Array:
    if abs(th) < 1e-9:
        return np.eye(2)
    a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th
    return np.array([[a, -b], [b, a]])


def _se2_exp(x: Array) -> Array:
    """Return the planar rigid transform (4, 4) exp(theta, u) of x = (theta, u)."""
    T = floor_pose(0.0, 0.0, float(x[0]))
    T[:2, 3] = _se2_V(float(x[0])) @ x[1:]
    return T


@dataclass(frozen=True)
class SurveyRead:
    """An object mark or signpost the survey read, as it enters the maps: the record, the
    mark's world pose T_world_mark (4, 4) with the (6, 6) covariance of (rotation
    perturbation, position) (the detection's, the camera pose held exact), the simulated time
    of the read (s) and the camera-to-mark distance (m)."""

    record: ObjectMark | Signpost
    T_world_mark: Array
    cov: Array
    time: float
    distance: float


@dataclass
class _Read:
    """An object mark read, kept on the odometry: the detection, the camera pose it was seen
    from (odometry frame), the time, the drift clock, and the relocalisations before it."""

    det: LandmarkDetection
    T_odom_cam: Array
    time: float
    clock: float
    fixes: int
    W: Array


class _Survey:
    """The survey's state: the robot, both maps and the places where unread landmarks were
    located (odometry frame).

    Object marks are mapped through the robot's pose estimate, the odometry corrected by every
    fix (a signpost read, HeadRobot.relocalise; the ceiling cameras while the base moves,
    core.sim.survey_localisation). The odometry drifts between two corrections; when
    the second comes, its correction D is spread back along the reads made since the first,
    in proportion to the drift clock (metres driven plus radians turned, the slip model's
    variance being linear in both): a read at a fraction lam of the way gets exp(lam log D),
    the Brownian-bridge estimate of the drift it was made with. The semantic map is rebuilt
    from the reads so corrected; reads reach `on_read` once the correction after them is
    known (or at the end of the survey)."""

    def __init__(
        self, robot: HeadRobot, on_read: Callable[[SurveyRead], None] | None = None
    ) -> None:
        self.robot = robot
        self.semantic = SemanticMap()
        self.navigation = NavigationMap()
        self.tried: list[tuple[str, Array]] = []  # (kind, world position) of failed reads
        self.attempts = 0
        self.successes = 0
        self.reads: list[_Read] = []
        self.fixes = robot.fixes  # (clock, W before, W after), HeadRobot._correct
        self.synced = 0  # the fixes the semantic map has taken in
        self.emitted = 0
        self.on_read = on_read

    def _world(self, read: _Read) -> Array:
        """Return T_world_odom at a read: its estimate then, with the next relocalisation's
        correction spread back to it (class docstring)."""
        if read.fixes >= len(self.fixes):
            return read.W
        clock, W_old, W_new = self.fixes[read.fixes]
        prev = self.fixes[read.fixes - 1][0] if read.fixes else 0.0
        lam = float(np.clip((read.clock - prev) / max(clock - prev, 1e-9), 0.0, 1.0))
        D = W_new @ np.linalg.inv(W_old)
        return _se2_exp(lam * _se2_log(D)) @ read.W

    def _entry(self, read: _Read) -> SurveyRead:
        T, C = detection_in_world(read.det, self._world(read) @ read.T_odom_cam)
        assert read.det.record is not None
        return SurveyRead(
            read.det.record, T, C, read.time, float(np.linalg.norm(read.det.position))
        )

    def _rebuild(self) -> None:
        self.semantic = SemanticMap()
        for read in self.reads:
            e = self._entry(read)
            assert isinstance(e.record, ObjectMark)
            self.semantic.observe(e.record, e.T_world_mark, e.cov, e.time)

    def flush(self, settled: bool = True) -> None:
        """Hand the reads whose pose is settled (a fix came after them), or all (`settled`
        False, at the end), to `on_read`."""
        n = len(self.reads)
        if settled:
            n = self.emitted
            while n < len(self.reads) and self.reads[n].fixes < len(self.fixes):
                n += 1
        if self.on_read is not None:
            for read in self.reads[self.emitted : n]:
                self.on_read(self._entry(read))
        self.emitted = n

    def sync(self) -> None:
        """Rebuild the semantic map when fixes came since it was built, and hand on the reads
        they settled."""
        if self.synced < len(self.fixes):
            self.synced = len(self.fixes)
            self._rebuild()
            self.flush()

    def known(self, p_odom: Array, kind: str) -> bool:
        """Return whether a located position (3,) in the odometry frame is a landmark of its
        kind ("object" or "signpost", told by the outer pattern) already mapped, or tried
        SURVEY_READ_TRIES times: an object mark may hang beside a signpost (the default
        home's clock is 0.41 m from one)."""
        self.sync()
        p = (self.robot.T_world_odom @ np.append(p_odom, 1.0))[:3]
        if kind == "object":
            near = [o.position for o in self.semantic.objects]
        else:
            g = self.navigation.graph
            near = [np.asarray(g.nodes[k]["xyz"]) for k in g]
        if any(float(np.linalg.norm(p - q)) < SEPARATE_M for q in near):
            return True
        tries = sum(
            1 for k, q in self.tried if k == kind and float(np.linalg.norm(p - q)) < SEPARATE_M
        )
        return tries >= SURVEY_READ_TRIES

    def record(self, det: LandmarkDetection, T_odom_cam: Array) -> None:
        """Put a decoded detection in its map (class docstring); a signpost read near enough
        also corrects the odometry."""
        r = self.robot
        rec = det.record
        self.sync()
        if isinstance(rec, ObjectMark):
            read = _Read(det, T_odom_cam, r.time, r.drift_clock, len(self.fixes), r.T_world_odom)
            self.reads.append(read)
            e = self._entry(read)
            self.semantic.observe(rec, e.T_world_mark, e.cov, e.time)
        elif isinstance(rec, Signpost):
            self.navigation.observe(rec)
            W = r.T_world_odom
            if self.on_read is not None:
                T, C = detection_in_world(det, W @ T_odom_cam)
                self.on_read(SurveyRead(rec, T, C, r.time, float(np.linalg.norm(det.position))))
            if r.relocalise(det, T_odom_cam):
                self.sync()

    def sweep(self) -> list[_Track]:
        """Sweep the head over SWEEP_PANS; map what is read; return the unread, unknown
        landmarks located (nearest first)."""
        r = self.robot
        todo: list[tuple[float, _Track]] = []
        for pan in SWEEP_PANS:
            while abs(r.pan - pan) > 1e-9 or abs(r.tilt - SEARCH_TILT) > 1e-9:
                r.aim(pan, SEARCH_TILT, FRAME_DT)
                r.drive(0.0, 0.0, FRAME_DT)
            for d in r.look():
                T = r.locate(d)
                if d.record is not None:
                    self.record(d, r.T_odom_cam())
                    continue
                if not self.known(T[:3, 3], d.kind) and not any(
                    t.kind == d.kind and float(np.linalg.norm(T[:3, 3] - t.T[:3, 3])) < SEPARATE_M
                    for _, t in todo
                ):
                    dist = float(np.linalg.norm(d.position))
                    todo.append((dist, r.track(d)))
            r.drive(0.0, 0.0, FRAME_DT)
        todo.sort(key=lambda x: x[0])
        return [t for _, t in todo if not self.known(t.T[:3, 3], t.kind)]

    def go(self, target: Array, timeout: float = 120.0) -> None:
        """Drive the base to a floor point (x, y), world frame, along a route planned on the
        floor plan (HeadRobot.go_to) on the odometry (corrected by T_world_odom), for at most
        `timeout` s."""
        if timeout > 0:
            self.robot.go_to(np.asarray(target, dtype=np.float64), timeout)


def landmark_survey(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    tour: tuple[tuple[float, float], ...] | None = None,
    calibration_views: int = CALIBRATION_VIEWS,
    duration_s: float | None = None,
    on_progress: Callable[[str, float], None] | None = None,
    on_read: Callable[[SurveyRead], None] | None = None,
    ceiling_hz: float = CEILING_HZ,
    cameras: Sequence[NetworkCamera] | None = None,
) -> LandmarkSurveyResult:
    """Return the metrics of `landmark-survey`: the robot drives `tour` (default: DEFAULT_TOUR
    on the default home, else the robot's patrol) along routes planned on the floor plan,
    sweeps its head at every stop, maps every landmark it reads, and reads by PBVS
    (HeadRobot.read, up to SURVEY_READ_TIMEOUT_S) every landmark it located but could not
    read, coming back to the stop afterwards. Poses come from the odometry (started at the
    robot's known start pose), corrected at signposts and by the robot's top marker located
    by the ceiling cameras (core.sim.survey_localisation, _Survey), and the calibrated head
    camera; the twin's truth only scores the maps.

    ceiling_hz: ceiling frames a second while the base moves (0: no ceiling fixes, the
    odometry and the signposts alone); cameras: the calibrated ceiling cameras (default: the
    home's installed calibration, core.sim.installation; never the twin's true cameras).

    duration_s: stop after this much simulated time (the tour cut short); on_progress(phase,
    fraction) is called as the survey goes from stop to stop and read to read; on_read gets
    every read as it enters the maps (object marks once their pose is settled, _Survey).
    """
    if calibration_views < 3:
        raise InvalidInput("landmark-survey needs calibration_views >= 3")
    if duration_s is not None and not (np.isfinite(duration_s) and duration_s > 0):
        raise InvalidInput(f"duration_s must be a positive number of seconds, got {duration_s}")
    sc = scene if scene is not None else default_scene()
    if tour is None:
        if scene is None:
            tour = DEFAULT_TOUR
        elif sc.robot is not None and sc.robot.patrol:
            tour = tuple((float(x), float(y)) for x, y in sc.robot.patrol)
        else:
            raise InvalidInput("landmark-survey needs a tour or a robot with patrol waypoints")
    stops = np.asarray(tour, dtype=np.float64)
    if stops.ndim != 2 or stops.shape[1] != 2 or len(stops) < 1:
        raise InvalidInput(f"tour must be (x, y) points, got shape {stops.shape}")
    if not (np.isfinite(ceiling_hz) and ceiling_hz >= 0):
        raise InvalidInput(f"ceiling_hz must be a number >= 0, got {ceiling_hz}")
    rng = np.random.default_rng(seed)
    K, dist, rms = _calibrated(sc, rng, calibration_views)
    ceiling = None
    if ceiling_hz > 0 and sc.robot is not None and sc.robot.marker is not None:
        cams = installed_cameras(sc) if cameras is None else list(cameras)
        ceiling = CeilingLocaliser(
            sc, cams, rate_hz=ceiling_hz, rng=np.random.default_rng([seed, 1])
        )
    robot = HeadRobot(sc, K, dist, rng=rng, ceiling=ceiling)
    survey = _Survey(robot, on_read)
    end = np.inf if duration_s is None else float(duration_s)
    n = len(stops)

    def progress(k: int, what: str) -> None:
        if on_progress is not None:
            done = max(k / n, min(robot.time / end, 1.0))
            on_progress(f"stop {k + 1} of {n}: {what}", float(done))

    completed = True
    for k, stop in enumerate(stops):
        if robot.time >= end:
            completed = False
            break
        progress(k, "driving")
        survey.go(stop, min(120.0, end - robot.time))
        if robot.time >= end:
            completed = False
            break
        progress(k, "sweeping the head")
        tracks = survey.sweep()
        for j, track in enumerate(tracks):
            if survey.known(track.T[:3, 3], track.kind):
                continue  # read meanwhile, from another reading pose
            left = end - robot.time
            if left <= 0:
                break
            progress(k, f"reading landmark {j + 1} of {len(tracks)} located")
            survey.attempts += 1
            out = robot.read(track, min(SURVEY_READ_TIMEOUT_S, left))
            if out.read and out.detection is not None and out.T_odom_cam is not None:
                survey.successes += 1
                survey.record(out.detection, out.T_odom_cam)
            else:
                survey.tried.append((track.kind, (robot.T_world_odom @ track.T[:, 3])[:3]))
            survey.go(stop, min(120.0, end - robot.time))
    survey.sync()
    survey.flush(settled=False)
    return _score_survey(sc, survey, seed, rms, completed and robot.time < end)


def _score_survey(
    sc: Scene, survey: _Survey, seed: int, rms: float, completed: bool
) -> LandmarkSurveyResult:
    robot = survey.robot
    marks = robot.landmarks
    ids: dict[int, int] = {}
    for k, lm in enumerate(marks):
        try:
            ids[decode_payload(lm.text).id] = k
        except PayloadError:
            continue
    errors: list[float] = []
    false = 0
    hits: dict[int, int] = {}
    for obj in survey.semantic.objects:
        j = ids.get(obj.id)
        if j is None or marks[j].kind != "object":
            false += 1
            continue
        k = j
        e = float(np.linalg.norm(obj.position - marks[k].T_world_mark[:3, 3]))
        if e > MATCH_TRUTH_M:
            false += 1
            continue
        errors.append(e)
        hits[k] = hits.get(k, 0) + 1
    graph = survey.navigation.graph
    for place in graph.nodes:
        j = ids.get(int(place))
        if j is None or marks[j].kind != "signpost":
            false += 1
            continue
        hits[j] = hits.get(j, 0) + 1
    duplicates = sum(n - 1 for n in hits.values())
    kinds = [lm.kind for lm in marks]
    seen = robot.seen
    rooms = [r.name for r in sc.rooms]
    routes = []
    for a, b in combinations(rooms, 2):
        try:
            rt = survey.navigation.route(a, b)
            routes.append(SurveyRoute(a, b, rt.places, rt.rooms, rt.length_m))
        except NoRoute as exc:
            routes.append(SurveyRoute(a, b, None, None, None, str(exc)))
    true = robot.base.state.pose
    odo = robot.base.state.odometry
    seen_not_read = tuple(sorted(marks[k].name for k in seen if k not in hits))
    n_obj = sum(1 for k in hits if kinds[k] == "object")
    n_place = sum(1 for k in hits if kinds[k] == "signpost")
    goals = {
        "every_seen_landmark_mapped": not seen_not_read,
        "no_false_or_duplicate_entries": false == 0 and duplicates == 0,
        "route_between_every_pair_of_rooms": all(r.places is not None for r in routes),
        "no_collision": not robot.collided,
    }
    return LandmarkSurveyResult(
        scenario="landmark-survey",
        seed=seed,
        objects_present=kinds.count("object"),
        objects_seen=sum(1 for k in seen if kinds[k] == "object"),
        objects_found=n_obj,
        places_present=kinds.count("signpost"),
        places_seen=sum(1 for k in seen if kinds[k] == "signpost"),
        places_found=n_place,
        position_error_mean_m=float(np.mean(errors)) if errors else None,
        position_error_max_m=max(errors) if errors else None,
        false_entries=false,
        duplicate_entries=duplicates,
        seen_not_read=seen_not_read,
        reads_attempted=survey.attempts,
        reads_succeeded=survey.successes,
        time_s=robot.time,
        completed=completed,
        collided=robot.collided,
        frames=robot.frames,
        odometry_drift_m=float(np.hypot(true.x - odo.x, true.y - odo.y)),
        pose_error_m=float(np.hypot(*(robot.estimate()[:2] - (true.x, true.y)))),
        ceiling=robot.ceiling.summary() if robot.ceiling is not None else {},
        calibration_rms_px=float(rms),
        routes=tuple(routes),
        goals=goals,
        semantic_map=survey.semantic.to_dict(),
        navigation_map=survey.navigation.to_dict(),
    )
