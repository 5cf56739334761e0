"""Landmarks rendered into a camera image, with their ground truth (for scoring only).

A landmark's PNG artwork (core.landmarks.artwork) is a texture on its plane; the ideal pinhole
image is rasterised at 2x supersampling by cv2.warpPerspective with the plane's homography
H = Ks [r1 r2 t] A (A maps texture pixels to mark-plane metres, Ks the supersampled canvas
intrinsics; H&Z eq. 8.1), composited over a wall-like background with the warped coverage as
alpha, reduced by area averaging, then the lens distortion is applied by one remap (each
distorted pixel reads the ideal pixel it sees, core.geometry.camera.undistort_points), then
optical blur, exposure gain and Gaussian sensor noise (core.sim.render.SensorNoise), all seeded.
A texture pyramid level is chosen per landmark so that a canvas pixel spans about one texel.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core._validate import as_matrix
from core.errors import InvalidInput
from core.geometry.camera import as_distortion, project_points, undistort_points
from core.geometry.rotations import matrix_to_rotvec
from core.landmarks.artwork import Artwork, make_artwork, to_png_image
from core.landmarks.payload import PayloadError, decode_payload
from core.localization.occluders import Occluders, line_of_sight
from core.sim._geometry import pose_matrix
from core.sim.render._camera import SensorNoise
from core.sim.scene import Scene

Array = NDArray[np.float64]
Image = NDArray[Any]

_SS = 2  # supersampling of the ideal canvas
_NEAR = 0.05  # metres: no landmark corner may come nearer the camera


@dataclass(frozen=True, eq=False)
class LandmarkCamera:
    """A camera for landmark views: K (3, 3) pixels, dist (5,) OpenCV order, size (W, H)."""

    K: Array
    dist: Array
    width: int
    height: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", as_matrix(self.K, (3, 3), "K"))
        object.__setattr__(self, "dist", as_distortion(self.dist))
        if self.width <= 0 or self.height <= 0:
            raise InvalidInput(f"camera size must be positive, got {self.width} x {self.height}")


@dataclass(frozen=True, eq=False)
class Texture:
    """A planar texture: image (H, W, 3) BGR uint8 whose pixel (i, j) centre lies at
    ((j + 0.5) / ppm - cx, -((i + 0.5) / ppm - cy)) metres in the mark frame (x right, y up);
    ppm pixels per metre; centre (cx, cy) metres from the image's top-left corner."""

    image: Image
    ppm: float
    centre: tuple[float, float]
    pyramid: tuple[Image, ...] = field(default=(), repr=False)

    def __post_init__(self) -> None:
        levels = [self.image]
        while min(levels[-1].shape[:2]) > 16:
            levels.append(cv2.pyrDown(levels[-1]))
        object.__setattr__(self, "pyramid", tuple(levels))

    def plane_map(self, level: int) -> Array:
        """Return A (3, 3) mapping texture pixels of pyramid `level` to mark-plane metres."""
        p = self.ppm / 2**level
        cx, cy = self.centre
        return np.array([[1 / p, 0, 0.5 / p - cx], [0, -1 / p, cy - 0.5 / p], [0, 0, 1]])


def artwork_texture(art: Artwork, pixels_per_metre: float = 5000.0) -> Texture:
    """Return the texture of a landmark's artwork (its PNG at `pixels_per_metre`)."""
    img = to_png_image(art, pixels_per_metre)
    ppm = img.shape[1] / (art.page_mm[0] / 1000.0)
    return Texture(img, ppm, (art.centre_mm[0] / 1000.0, art.centre_mm[1] / 1000.0))


def tag_texture(
    side: float, tag_id: int = 0, dictionary: int = cv2.aruco.DICT_APRILTAG_36h11
) -> Texture:
    """Return the texture of an ArUco/AprilTag marker of outer (black border) side `side`
    metres with a white margin of one eighth of the side (10 px per cell)."""
    d = cv2.aruco.getPredefinedDictionary(dictionary)
    cells = d.markerSize + 2
    px = 10 * cells
    marker = cv2.aruco.generateImageMarker(d, tag_id, px, borderBits=1)
    pad = px // 8
    img = cv2.copyMakeBorder(marker, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    ppm = px / side
    c = (pad + px / 2) / ppm
    return Texture(img, ppm, (c, c))


@dataclass(frozen=True)
class LandmarkTruth:
    """One rendered landmark's truth: T_cam_mark (4, 4); corners (4, 2) distorted pixels of
    the pattern's bounding square (+-size/2, mark frame (x, y): (-,-), (+,-), (+,+), (-,+));
    centre_px (2,); module_px: the smallest image extent of one QR module (pixels, at the
    centre: module side times the smaller singular value of the projection's Jacobian), None
    for textures without a symbol; distance metres; obliquity_deg: angle between the mark's
    normal and the ray to its centre."""

    T_cam_mark: Array
    corners: Array
    centre_px: Array
    module_px: float | None
    distance: float
    obliquity_deg: float


@dataclass(frozen=True, eq=False)
class LandmarkView:
    """A rendered image (H, W, 3) BGR uint8 and the truth of every landmark in it."""

    image: Image
    truth: tuple[LandmarkTruth, ...]


_LENS_CACHE: dict[
    bytes, tuple[Array, NDArray[np.float32], NDArray[np.float32], tuple[int, int]]
] = {}


def _lens(
    cam: LandmarkCamera,
) -> tuple[Array, NDArray[np.float32], NDArray[np.float32], tuple[int, int]]:
    key = cam.K.tobytes() + cam.dist.tobytes() + bytes(f"{cam.width}x{cam.height}", "ascii")
    hit = _LENS_CACHE.get(key)
    if hit is not None:
        return hit
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height))
    ideal = undistort_points(np.stack([u, v], -1).reshape(-1, 2), cam.K, cam.dist, to_pixels=True)
    lo = np.floor(ideal.min(0)) - 2
    hi = np.ceil(ideal.max(0)) + 3
    size = (int(hi[0] - lo[0]), int(hi[1] - lo[1]))
    Kc = cam.K.copy()
    Kc[0, 2] -= lo[0]
    Kc[1, 2] -= lo[1]
    mx = (ideal[:, 0] - lo[0]).reshape(cam.height, cam.width).astype(np.float32)
    my = (ideal[:, 1] - lo[1]).reshape(cam.height, cam.width).astype(np.float32)
    if len(_LENS_CACHE) > 8:
        _LENS_CACHE.clear()
    _LENS_CACHE[key] = (Kc, mx, my, size)
    return Kc, mx, my, size


def lens_canvas_size(camera: LandmarkCamera) -> tuple[int, int]:
    """Return the (width, height) of the ideal canvas the distorted image is read from."""
    return _lens(camera)[3]


def wall_background(width: int, height: int, rng: np.random.Generator) -> Image:
    """Return a wall-like background (H, W, 3): a light, unsaturated grey-beige with smooth
    shading and a few darker grey rectangles (furniture, frames), no blue and no red."""
    base = rng.uniform(150, 215)
    small = rng.normal(0, 12, (max(2, height // 40), max(2, width // 40)))
    shade = cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    grey = np.clip(base + shade, 40, 250)
    img = np.repeat(grey[..., None], 3, -1)
    img *= np.array([0.97, 1.0, 1.03])  # slightly warm; saturation stays below 10 %
    for _ in range(int(rng.integers(2, 6))):
        x0, y0 = int(rng.integers(0, width)), int(rng.integers(0, height))
        w, h = int(rng.integers(20, width // 3)), int(rng.integers(20, height // 3))
        g = float(rng.uniform(50, 130))
        cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), (g, g, g), -1)
    return np.clip(img, 0, 255).astype(np.uint8)


def render_landmarks(
    camera: LandmarkCamera,
    placements: Sequence[tuple[Any, ...]],
    *,
    noise: SensorNoise | None = None,
    rng: np.random.Generator | int | None = None,
    background: Image | None = None,
) -> LandmarkView:
    """Return the image of textured landmarks seen by `camera`, with their truth.

    placements: (texture, T_cam_mark (4, 4)[, size metres, module metres or None]) per
    landmark, drawn in the given order (later ones over earlier ones); size and module give the
    truth's corners and module_px (default: the texture's width and no module).
    noise: blur, gain and pixel noise (None: an ideal image); background: the ideal canvas
    behind the landmarks (default: a random wall from `rng`; `lens_canvas_size` gives its
    size). Raises InvalidInput when a landmark is behind the camera or nearer than 5 cm.
    """
    gen = np.random.default_rng(rng)
    Kc, mx, my, (cw, ch) = _lens(camera)
    S = np.array([[_SS, 0, (_SS - 1) / 2], [0, _SS, (_SS - 1) / 2], [0, 0, 1]])
    Ks = S @ Kc
    if background is None:
        canvas = wall_background(cw, ch, gen)
    else:
        canvas = np.asarray(background)
        if canvas.shape != (ch, cw, 3) or canvas.dtype != np.uint8:
            raise InvalidInput(f"background must be a ({ch}, {cw}, 3) uint8 image")
    big = cv2.resize(canvas, (cw * _SS, ch * _SS), interpolation=cv2.INTER_NEAREST).astype(
        np.float32
    )
    truths = []
    for item in placements:
        tex, T = item[0], as_matrix(item[1], (4, 4), "T_cam_mark")
        size = float(item[2]) if len(item) > 2 else tex.image.shape[1] / tex.ppm
        module = item[3] if len(item) > 3 else None
        R, t = T[:3, :3], T[:3, 3]
        h0, w0 = tex.image.shape[:2]
        A0 = tex.plane_map(0)
        page = A0 @ np.array([[0, 0, 1], [w0, 0, 1], [w0, h0, 1], [0, h0, 1]], float).T
        page[0] -= 0.5 / tex.ppm
        page[1] += 0.5 / tex.ppm
        Xc = (R[:, :2] @ page[:2] + t[:, None]).T
        if np.any(Xc[:, 2] < _NEAR):
            raise InvalidInput("a landmark is behind the camera or nearer than 5 cm; move it")
        G = Ks @ np.column_stack([R[:, 0], R[:, 1], t])
        # Texture level: about one texel per canvas pixel along the page's width.
        uv = G @ page
        uv = uv[:2] / uv[2]
        span = max(np.linalg.norm(uv[:, 1] - uv[:, 0]), np.linalg.norm(uv[:, 3] - uv[:, 0]), 1.0)
        level = int(np.clip(np.floor(np.log2(max(w0, h0) / span)), 0, len(tex.pyramid) - 1))
        img = tex.pyramid[level]
        # Warp and composite within the page's bounding box only (the same pixels as a
        # full-canvas warp, H shifted by the box's corner).
        x0, y0 = (max(int(np.floor(uv[k].min())) - 2, 0) for k in (0, 1))
        x1 = min(int(np.ceil(uv[0].max())) + 3, cw * _SS)
        y1 = min(int(np.ceil(uv[1].max())) + 3, ch * _SS)
        if x1 > x0 and y1 > y0:
            shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
            H = shift @ G @ tex.plane_map(level)
            box = (x1 - x0, y1 - y0)
            warped = cv2.warpPerspective(
                img, H, box, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
            ).astype(np.float32)
            ones = np.ones(img.shape[:2], np.float32)
            alpha = cv2.warpPerspective(ones, H, box, flags=cv2.INTER_LINEAR)
            roi = big[y0:y1, x0:x1]
            roi *= 1 - alpha[..., None]
            roi += warped
        truths.append(_truth(camera, T, size, module))
    ideal = cv2.resize(big, (cw, ch), interpolation=cv2.INTER_AREA)
    img = cv2.remap(ideal, mx, my, cv2.INTER_LINEAR)
    img = np.clip(img, 0, 255)
    if noise is not None:
        if noise.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), noise.blur_sigma)
        gain = noise.gain * (1.0 + noise.gain_jitter * float(gen.standard_normal()))
        img = img * max(gain, 0.0)
        if noise.sigma > 0:
            img = img + noise.sigma * gen.standard_normal(img.shape, dtype=np.float32)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return LandmarkView(image=out, truth=tuple(truths))


def _truth(cam: LandmarkCamera, T: Array, size: float, module: float | None) -> LandmarkTruth:
    R, t = T[:3, :3], T[:3, 3]
    h = size / 2
    corners3 = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0], [0, 0, 0]])
    pr = project_points(corners3, matrix_to_rotvec(R), t, cam.K, cam.dist, jacobians=False)
    module_px = None
    if module is not None:
        # d(pixel)/d(x, y) of the ideal projection at the centre.
        z = t[2]
        J = cam.K[:2, :2] @ (R[:2, :2] * z - np.outer(t[:2], R[2, :2])) / z**2
        module_px = float(module * np.linalg.svd(J, compute_uv=False)[-1])
    ray = t / np.linalg.norm(t)
    obl = float(np.degrees(np.arccos(np.clip(-ray @ R[:, 2], -1, 1))))
    return LandmarkTruth(
        T_cam_mark=T.copy(),
        corners=pr.points[:4],
        centre_px=pr.points[4],
        module_px=module_px,
        distance=float(np.linalg.norm(t)),
        obliquity_deg=obl,
    )


@dataclass(frozen=True, eq=False)
class SceneLandmark:
    """A scene's landmark ready to render: name; kind "object" or "signpost"; T_world_mark
    (4, 4) (mark frame: x right, y up on the print, z out of the face); size metres (frame side
    or outer ring diameter); module metres (one QR module); text (the payload); texture."""

    name: str
    kind: str
    T_world_mark: Array = field(repr=False)
    size: float
    module: float
    text: str
    texture: Texture = field(repr=False)


# Texels per metre of a scene landmark's texture: a 1.7 mm QR module spans 5 texels, finer than
# a canvas pixel down to 0.2 m at 600 px focal length (supersampled twice).
TEXTURE_PPM = 3000.0

_SCENE_LANDMARKS: dict[int, tuple[Scene, tuple[SceneLandmark, ...]]] = {}


def scene_landmarks(scene: Scene) -> tuple[SceneLandmark, ...]:
    """Return the landmarks of a core.sim Scene with their artwork textures (cached per scene).

    A payload that decodes is drawn from its record (label "#id name"); any other text (a
    foreign QR code) is drawn as given with the landmark's name as label.
    """
    hit = _SCENE_LANDMARKS.get(id(scene))
    if hit is not None and hit[0] is scene:
        return hit[1]
    out = []
    for lm in scene.landmarks:
        kind = "object" if lm.kind == "object_mark" else "signpost"
        try:
            art = make_artwork(decode_payload(lm.payload), size=lm.size)
        except PayloadError:
            art = make_artwork(lm.payload or lm.name, kind, lm.size, label=lm.name)
        if art.kind != kind:
            raise InvalidInput(
                f"landmark {lm.name!r} is a {lm.kind} but its payload is a {art.kind}'s"
            )
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = pose_matrix(lm.pose)
        out.append(
            SceneLandmark(
                name=lm.name,
                kind=kind,
                T_world_mark=T,
                size=float(lm.size),
                module=art.module_mm / 1000.0,
                text=art.text,
                texture=artwork_texture(art, TEXTURE_PPM),
            )
        )
    res = tuple(out)
    if len(_SCENE_LANDMARKS) > 4:
        _SCENE_LANDMARKS.clear()
    _SCENE_LANDMARKS[id(scene)] = (scene, res)
    return res


def visible_landmarks(
    camera: LandmarkCamera,
    T_world_cam: Array,
    landmarks: Sequence[SceneLandmark],
    occluders: Occluders | None = None,
    *,
    margin_px: float = 2.0,
) -> list[int]:
    """Return the indices of the landmarks a camera at T_world_cam (4, 4) sees whole: the
    printed face towards the camera, every corner of the pattern's square at least 10 cm in
    front, inside the image by `margin_px`, and (with `occluders`, a
    core.localization.occluders.Occluders) not hidden by a wall or a piece of furniture."""
    Twc = as_matrix(T_world_cam, (4, 4), "T_world_cam")
    Tcw = np.linalg.inv(Twc)
    keep = []
    for k, lm in enumerate(landmarks):
        T = Tcw @ lm.T_world_mark
        if float(T[:3, 2] @ T[:3, 3]) >= 0:  # the face looks away from the camera
            continue
        h = lm.size / 2
        sq = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0], [0, 0, 0]])
        Xc = sq @ T[:3, :3].T + T[:3, 3]
        if np.any(Xc[:, 2] < 0.1):
            continue
        px = project_points(
            sq, matrix_to_rotvec(T[:3, :3]), T[:3, 3], camera.K, camera.dist, jacobians=False
        ).points
        m = margin_px
        if np.any(px < m) or np.any(px[:, 0] > camera.width - 1 - m):
            continue
        if np.any(px[:, 1] > camera.height - 1 - m):
            continue
        if occluders is not None:
            Xw = sq @ lm.T_world_mark[:3, :3].T + lm.T_world_mark[:3, 3]
            if not np.all(line_of_sight(Twc[None, :3, 3], Xw, occluders)):
                continue
        keep.append(k)
    return keep


def render_scene_landmarks(
    camera: LandmarkCamera,
    T_world_cam: Array,
    landmarks: Sequence[SceneLandmark],
    occluders: Occluders | None = None,
    *,
    noise: SensorNoise | None = None,
    rng: np.random.Generator | int | None = None,
) -> tuple[LandmarkView, list[int]]:
    """Return the view of a camera at T_world_cam (4, 4) of the landmarks it sees whole
    (visible_landmarks), drawn far to near over a random wall, and their indices in
    `landmarks` (the order of the view's truth)."""
    Tcw = np.linalg.inv(as_matrix(T_world_cam, (4, 4), "T_world_cam"))
    idx = visible_landmarks(camera, T_world_cam, landmarks, occluders)
    dist = [float(np.linalg.norm((Tcw @ landmarks[k].T_world_mark)[:3, 3])) for k in idx]
    idx = [idx[j] for j in np.argsort(dist)[::-1]]
    placements = [
        (
            landmarks[k].texture,
            Tcw @ landmarks[k].T_world_mark,
            landmarks[k].size,
            landmarks[k].module,
        )
        for k in idx
    ]
    return render_landmarks(camera, placements, noise=noise, rng=rng), idx
