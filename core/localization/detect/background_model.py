"""People in camera images by background subtraction (02 §2).

A cv2 MOG2 background model (Zivkovic 2004) learns the empty room and keeps learning, slowly,
from the frames it detects in; shadows are dropped, a change of exposure is corrected and a
change of light relearnt (`PersonDetector`, docs/background-detector.md); each foreground blob
larger than `min_area` is a person. `PersonDetector.detect_bodies` (with the camera's
calibration) reports per blob the image of one well-defined body point, the foot of the body's
vertical axis, with a covariance that covers the body model's error: see `locate_body_axis`
(core.localization.detect.body_axis) for the geometry. `PersonDetector.detect` keeps the older
blob report (bounding box and the blob's lowest pixel), which is biased: the lowest pixel is the
near edge of the body, about one body radius from its centre towards the camera, so cameras on
different sides disagree by a body diameter. A learned person segmenter would feed
`locate_body_axis` its mask instead.

Pixel coordinates have their origin at the centre of the top-left pixel (as the renderer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization.cameras import NetworkCamera
from core.localization.detect.body_axis import BodyDetection, BodyModel, locate_body_axis

Array = NDArray[np.float64]
Image = NDArray[Any]


@dataclass(frozen=True)
class PersonDetection:
    """One person found by background subtraction (the blob, without the camera's geometry).

    foot_pixel (2,): the blob's lowest row (mean column there), distorted pixels: the body's
    near edge on the floor, not its centre (see the module docstring; `BodyDetection` is the
    unbiased report); cov (2, 2) px^2: sigma^2 I from the detector's `pixel_sigma`; bbox
    (x, y, w, h) pixels; area in pixels.
    """

    foot_pixel: Array
    cov: Array = field(repr=False)
    bbox: tuple[int, int, int, int]
    area: int


# MOG2's background ratio (its TB, OpenCV's default): a pixel's Gaussian is background once the
# weights of the Gaussians above it sum to less than this.
_MOG2_BACKGROUND_RATIO = 0.9
# The value MOG2 gives a pixel it takes for a shadow (darker, same chromaticity).
_MOG2_SHADOW = 127
# The exposure estimate reads every 4th pixel of every 4th row: 1/16 of a 640 x 480 view is
# 19,200 ratios, whose median is steady to 0.1 % between frames of one light.
_GAIN_STRIDE = 4
# Background grey levels outside this range say little of a gain (noise floor, saturation).
_GAIN_GREY = (16, 235)
# Frames between two readings of the live background for the exposure estimate: it changes
# over `still_frames` (hundreds), and reading it costs as much as a subtraction.
_GREY_REFRESH = 25


@dataclass(frozen=True)
class PersonBlobs:
    """What the background model made of one frame: `labels` (H, W) int32 connected
    components of the foreground (shadows left out), `blobs` the (label, (x, y, w, h), area)
    of those of at least `min_area` pixels, largest first, `foreground` the fraction of the
    frame that was foreground, `gain` the frame's exposure against the background's (1 when
    not estimated), and `relit` whether the frame was taken for a change of light (then no
    blob is reported and the model learns the frame again)."""

    labels: Image = field(repr=False)
    blobs: list[tuple[int, tuple[int, int, int, int], int]]
    foreground: float
    gain: float
    relit: bool


class PersonDetector:
    """People by background subtraction (cv2.createBackgroundSubtractorMOG2), one per camera.

    `learn(image)` feeds frames of the empty room (or any frames: MOG2 adapts); the foreground
    blobs larger than `min_area` pixels, opened and closed by a small kernel to remove speckle,
    are the people. `detect_bodies(image, camera)` reports each as its body axis's image
    (`locate_body_axis` with `body`, the body model); `detect(image)` as the blob and its lowest
    pixel, whose standard deviation is `pixel_sigma` (pixels).

    The model keeps learning from the frames it detects in (docs/background-detector.md):

    still_frames: frames after which something that stopped moving (a person asleep on a sofa,
    a moved chair) is background, and after which the ghost of something that stood there while
    the model learnt (a person standing at start-up who then walks off) is gone. Both are the
    time MOG2 needs to give a pixel's new colour the background's weight, so one setting sets
    both: the learning rate is alpha = -ln(0.9) / still_frames, when the older colour's weight
    (1 - alpha)^n falls below MOG2's background ratio 0.9. 300 frames is 60 s at 5 frames per
    second, 30 s at 10 and 10 s at 30; a walker covers a pixel for well under a second. None:
    no learning from live frames (the model is what `learn` taught it).
    shadows: MOG2's shadow detection (a pixel darker than the background by a factor in
    [0.5, 1], of its chromaticity), the shadows left out of the people.
    gain_tolerance: a frame's exposure against the background's is the median over the pixels
    of their grey ratio (people cover far less than half a view, so the median is the camera's
    gain); past this relative difference the frame is divided by it before the subtraction. An
    automatic exposure steps by 5-30 %; 2 % moves a mid-grey pixel by 2-3 grey levels, within
    the noise MOG2 accepts. None: no correction.
    relearn_fraction: a frame that is foreground over more than this fraction of its pixels
    (after the gain correction) saw the light change unevenly (a lamp switched on, the sun
    through a window): it reports no one, and the model learns again from it, as a new model
    does (rate 1 / (k + 1) on the k-th of `relearn_frames` frames, k from 1). People cover a
    few percent of a room camera's view and at most a fifth of a street camera's at its
    busiest; half a frame is no crowd that subtraction could part into people anyway. A walker
    covers a pixel for 2-3 frames at 5-10 frames per second (a body's 0.4 m at 0.8-1.4 m/s):
    after 50 frames their colour holds about a twentieth of that pixel's weight, under the
    tenth MOG2 leaves to background colours, so they are no part of the new background. With
    10 frames they were (a third), and the same walker coming back there was missed for
    minutes (tests/core/localization/test_background_model.py).
    """

    def __init__(
        self,
        *,
        history: int = 200,
        var_threshold: float = 25.0,
        min_area: int = 150,
        pixel_sigma: float = 2.0,
        body: BodyModel | None = None,
        still_frames: float | None = 300.0,
        shadows: bool = True,
        gain_tolerance: float | None = 0.02,
        relearn_fraction: float = 0.5,
        relearn_frames: int = 50,
    ) -> None:
        if min_area <= 0 or not pixel_sigma > 0:
            raise InvalidInput("min_area and pixel_sigma must be > 0")
        if still_frames is not None and not (math.isfinite(still_frames) and still_frames >= 1):
            raise InvalidInput(f"still_frames must be >= 1 frame or None, got {still_frames}")
        if gain_tolerance is not None and not (0 <= gain_tolerance < 1):
            raise InvalidInput(
                f"gain_tolerance must lie in [0, 1) or be None, got {gain_tolerance}"
            )
        if not 0 < relearn_fraction <= 1:
            raise InvalidInput(f"relearn_fraction must lie in (0, 1], got {relearn_fraction}")
        if relearn_frames < 1:
            raise InvalidInput(f"relearn_frames must be >= 1, got {relearn_frames}")
        self._mog = cv2.createBackgroundSubtractorMOG2(
            history=history, varThreshold=var_threshold, detectShadows=shadows
        )
        self._mog.setBackgroundRatio(_MOG2_BACKGROUND_RATIO)
        self.min_area = int(min_area)
        self.pixel_sigma = float(pixel_sigma)
        self.body = body or BodyModel()
        self.learning_rate = (
            0.0 if still_frames is None else -math.log(_MOG2_BACKGROUND_RATIO) / still_frames
        )
        self.gain_tolerance = gain_tolerance
        self.relearn_fraction = float(relearn_fraction)
        self.relearn_frames = int(relearn_frames)
        self._relearning = 0  # frames of a quick relearning still to go
        self._background: Image | None = None
        # The live model's background, grey, on the exposure grid, and frames since it was read.
        self._grey: NDArray[np.float32] | None = None
        self._grey_age = 0
        self._learnt = False

    def learn(self, image: Image) -> None:
        """Update the background model with a BGR frame (H, W, 3) of the empty room (at MOG2's
        own rate for a model learning: 1 / k on the k-th frame, then 1 / history)."""
        self._mog.apply(image, learningRate=-1)
        self._background = None
        self._grey = None
        self._learnt = True

    def background(self) -> Image | None:
        """Return the background `learn` taught (BGR, the model's most probable colour per
        pixel after the last `learn`), or None before anything is learnt. Live frames do not
        change it: it is the room as the installer showed it, without what came to rest since
        (the robot parked for minutes is background to the people, never to its marker)."""
        if self._background is None and self._learnt:
            self._background = self._mog.getBackgroundImage()
        return self._background

    def exposure(self, image: Image) -> float:
        """Return a BGR frame's exposure relative to the model's background: the median of the
        grey-level ratio frame / background over a grid of pixels (1/16 of them) whose
        background is neither dark nor saturated and whose frame is not saturated; 1 before
        anything is learnt or when fewer than 100 pixels qualify."""
        if not self._learnt:
            return 1.0
        if self._grey is None or self._grey_age >= _GREY_REFRESH:
            bg = self._mog.getBackgroundImage()
            grey = cv2.cvtColor(bg, cv2.COLOR_BGR2GRAY)[::_GAIN_STRIDE, ::_GAIN_STRIDE]
            self._grey = grey.astype(np.float32)
            self._grey_age = 0
        self._grey_age += 1
        ref = self._grey
        grid = np.ascontiguousarray(image[::_GAIN_STRIDE, ::_GAIN_STRIDE])
        cur = cv2.cvtColor(grid, cv2.COLOR_BGR2GRAY)
        ok = (ref >= _GAIN_GREY[0]) & (ref <= _GAIN_GREY[1]) & (cur < 255)
        if np.count_nonzero(ok) < 100:
            return 1.0
        return float(np.median(cur[ok].astype(np.float32) / ref[ok]))

    def segment(self, image: Image, *, learning_rate: float | None = None) -> PersonBlobs:
        """Return the foreground blobs of a BGR frame (H, W, 3), the model updated with it at
        `learning_rate` (None: the detector's own, from `still_frames`; 0: not updated).

        The frame is first brought to the background's exposure (`gain_tolerance`); a frame
        mostly foreground even so is taken for a change of light (`relearn_fraction`): it
        reports no blob and starts a quick relearning (class docstring)."""
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise InvalidInput(f"image must be (H, W, 3) uint8 BGR, got {img.shape} {img.dtype}")
        rate = self.learning_rate if learning_rate is None else float(learning_rate)
        gain = 1.0
        if self.gain_tolerance is not None and self._learnt:
            gain = self.exposure(img)
            if abs(gain - 1.0) > self.gain_tolerance and gain > 0:
                img = cv2.convertScaleAbs(img, alpha=1.0 / gain)
        if self._relearning > 0:
            k = self.relearn_frames - self._relearning + 1  # 1, 2, ... relearn_frames
            rate = max(rate, 1.0 / (k + 1))
            self._relearning -= 1
        raw = self._mog.apply(img, learningRate=rate)
        fg: Image = (raw > _MOG2_SHADOW).astype(np.uint8)  # shadows (127) are no one
        share = float(np.count_nonzero(fg)) / fg.size
        if share > self.relearn_fraction:
            # The light changed: this frame becomes the model, and the next ones refine it.
            self._mog.apply(img, learningRate=1.0)
            self._grey = None
            self._relearning = self.relearn_frames
            empty = np.zeros(fg.shape, dtype=np.int32)
            return PersonBlobs(empty, [], share, gain, True)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, kernel)
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, kernel, iterations=2)
        _, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        areas = stats[1:, cv2.CC_STAT_AREA]
        keep = np.flatnonzero(areas >= self.min_area)
        keep = keep[np.argsort(-areas[keep], kind="stable")]
        blobs = [(int(k) + 1, _xywh(stats[int(k) + 1]), int(areas[k])) for k in keep]
        return PersonBlobs(labels, blobs, share, gain, False)

    def detect(self, image: Image, *, learning_rate: float | None = None) -> list[PersonDetection]:
        """Return the people (foreground blobs) in a BGR frame (H, W, 3), largest first; the
        model learns the frame at `learning_rate` (`segment`)."""
        seg = self.segment(image, learning_rate=learning_rate)
        labels, blobs = seg.labels, seg.blobs
        out = []
        for k, (x, y, bw, bh), area in blobs:
            bottom = y + bh - 1
            cols = np.flatnonzero(labels[bottom, x : x + bw] == k) + x
            foot = np.array([float(cols.mean()), float(bottom)])
            out.append(
                PersonDetection(
                    foot_pixel=foot,
                    cov=self.pixel_sigma**2 * np.eye(2),
                    bbox=(x, y, bw, bh),
                    area=area,
                )
            )
        return out

    def detect_bodies(
        self, image: Image, camera: NetworkCamera, *, learning_rate: float | None = None
    ) -> list[BodyDetection]:
        """Return the people in a BGR frame (H, W, 3) from `camera`, each as the image of their
        body axis at `body.axis_height` with its covariance (`locate_body_axis`), largest
        first. Blobs the body model cannot place (under the camera) are left out."""
        img = np.asarray(image)
        if camera.image_size is not None and img.shape[1::-1] != camera.image_size:
            raise InvalidInput(
                f"image is {img.shape[1]} x {img.shape[0]} but camera {camera.name!r} is "
                f"{camera.image_size[0]} x {camera.image_size[1]}: pass the camera that took it"
            )
        seg = self.segment(img, learning_rate=learning_rate)
        labels, blobs = seg.labels, seg.blobs
        out = []
        for k, (x, y, bw, bh), _ in blobs:
            det = locate_body_axis(
                labels[y : y + bh, x : x + bw] == k, camera, self.body, origin=(x, y)
            )
            if det is not None:
                out.append(det)
        return out


def _xywh(stat: NDArray[Any]) -> tuple[int, int, int, int]:
    return (int(stat[0]), int(stat[1]), int(stat[2]), int(stat[3]))
