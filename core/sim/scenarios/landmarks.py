"""The landmark scenarios of the robot's head camera (spec 04 on the twin).

* `landmark-pose`: the landmark detector on rendered views, beside the anchors on the same
  images (below).
* `landmark-reading`: a landmark located and read by position-based visual servoing from
  random start poses in the home (`landmark_reading`, `HeadRobot.read`).
* `landmark-survey`: the robot tours the home, reads every landmark it can and builds the
  semantic and navigation maps (`landmark_survey`).

The head camera, calibrated before any detection (the detector never sees the true intrinsics),
is the robot's (core.sim.head_robot: `head_camera`, `calibrate_head_camera`).

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

Reading and surveying: the robot is `HeadRobot` (core.sim.head_robot), which reads a landmark
by position-based visual servoing on its odometry and head camera. The survey maps what
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
from core.geometry.rotations import wrap_angle
from core.landmarks.artwork import make_artwork
from core.landmarks.detect import LandmarkDetection, detect_landmarks
from core.landmarks.maps import (
    NavigationMap,
    NoRoute,
    SemanticMap,
    detection_in_world,
)
from core.landmarks.payload import ObjectMark, PayloadError, Signpost, decode_payload
from core.localization import NetworkCamera
from core.localization.occluders import line_of_sight
from core.sim._geometry import yaw_matrix
from core.sim.head_robot import (
    CALIBRATION_VIEWS,
    FRAME_DT,
    READ_TIMEOUT_S,
    SEARCH_TILT,
    SIZES,
    HeadRobot,
    TrackedLandmark,
    calibrate_head_camera,
    calibrate_scene_head_camera,
    floor_pose,
    head_camera,
)
from core.sim.installation import installed_cameras
from core.sim.intrinsics import NOISE, facing
from core.sim.render.landmarks import (
    LandmarkCamera,
    LandmarkView,
    artwork_texture,
    render_landmarks,
    tag_texture,
)
from core.sim.scene import Scene, default_scene
from core.sim.survey_localisation import (
    CEILING_HZ,
    CeilingLocaliser,
)

Array = NDArray[np.float64]

OBLIQUITY_BINS = tuple((float(a), float(a + 10)) for a in range(0, 70, 10))
LOCATION_RANGE = (0.5, 5.0)
READING_MODULE_PX = (1.5, 5.0)
READING_MIN_M = 0.12
LOCATE_LIMIT_M = {"object": 3.0, "signpost": 5.0}
FLIP_DEG = 15.0
MIN_DECODE_MODULE_PX = 2.0


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
        p = m[:2] + r * (yaw_matrix(b)[:2, :2] @ n[:2])
        to_mark = np.arctan2(m[1] - p[1], m[0] - p[0])
        yaw = wrap_angle(to_mark + rng.uniform(-np.pi / 2, np.pi / 2))
        if (
            robot.clearance(p) < START_CLEARANCE
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
    K, dist, rms = calibrate_scene_head_camera(sc, rng, calibration_views)
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
        T_prior[:3, :3] = yaw_matrix(float(rng.normal(0.0, READ_PRIOR_RAD))) @ T_prior[:3, :3]
        res = robot.read(TrackedLandmark(T_prior, robot.landmarks[k].kind, robot.time), timeout)
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

    def sweep(self) -> list[TrackedLandmark]:
        """Sweep the head over SWEEP_PANS; map what is read; return the unread, unknown
        landmarks located (nearest first)."""
        r = self.robot
        todo: list[tuple[float, TrackedLandmark]] = []
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
    K, dist, rms = calibrate_scene_head_camera(sc, rng, calibration_views)
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
