"""The `landmark-pose` scenario (spec 04 on the twin): the landmark detector on rendered views
of the robot's head camera, beside the anchors on the same images.

The head camera, calibrated before any detection (the detector never sees the true intrinsics),
is the robot's (core.sim.head_camera: `head_camera`, `calibrate_head_camera`).

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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np
import zxingcpp
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.camera import undistort_points
from core.landmarks.artwork import make_artwork
from core.landmarks.detect import detect_landmarks
from core.landmarks.payload import ObjectMark, Signpost
from core.sim.head_camera import (
    CALIBRATION_VIEWS,
    SIZES,
    calibrate_head_camera,
    head_camera,
)
from core.sim.intrinsics import NOISE, facing
from core.sim.render.landmarks import (
    LandmarkCamera,
    LandmarkView,
    artwork_texture,
    render_landmarks,
    tag_texture,
)
from core.sim.scenarios.records import percent_or_none, percentile_or_none
from core.sim.scene import Scene

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
                    position_error_pct_median=percentile_or_none(tally.pos, 50),
                    position_error_pct_p95=percentile_or_none(tally.pos, 95),
                    normal_error_deg_median=percentile_or_none(tally.nrm, 50),
                    normal_error_deg_p95=percentile_or_none(tally.nrm, 95),
                    flips_pct=percent_or_none(sum(e > FLIP_DEG for e in tally.nrm), len(tally.nrm)),
                    decode_views=tally.dec_views,
                    decoded_pct=percent_or_none(tally.ours, tally.dec_views),
                    zxing_raw_pct=percent_or_none(tally.zx, tally.dec_views),
                    opencv_raw_pct=percent_or_none(tally.cvr, tally.dec_views),
                    tag_located_pct=100.0 * tally.tag_loc / max(tally.views, 1),
                    tag_position_error_pct_median=percentile_or_none(tally.tag_pos, 50),
                    tag_normal_error_deg_median=percentile_or_none(tally.tag_nrm, 50),
                    tag_normal_error_deg_p95=percentile_or_none(tally.tag_nrm, 95),
                    tag_flips_pct=percent_or_none(
                        sum(e > FLIP_DEG for e in tally.tag_nrm), len(tally.tag_nrm)
                    ),
                    normal_error_deg_p95_within_limit=percentile_or_none(near, 95),
                    flips_pct_within_limit=percent_or_none(
                        sum(e > FLIP_DEG for e in near), len(near)
                    ),
                    tag_normal_error_deg_p95_within_limit=percentile_or_none(near_tag, 95),
                    tag_flips_pct_within_limit=percent_or_none(
                        sum(e > FLIP_DEG for e in near_tag), len(near_tag)
                    ),
                    undecided_pct=percent_or_none(tally.undecided, tally.located),
                    decided_flips_pct=percent_or_none(
                        tally.decided_flips, tally.located - tally.undecided
                    ),
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
        g[f"{kind}_located_within_{LOCATE_LIMIT_M[kind]:g}m_pct"] = percent_or_none(
            sum(limits[kind]), len(limits[kind])
        )
        pos, nrm = at45[kind]
        g[f"{kind}_position_error_pct_median_at_45deg"] = percentile_or_none(pos, 50)
        g[f"{kind}_normal_error_deg_median_at_45deg"] = percentile_or_none(nrm, 50)
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
