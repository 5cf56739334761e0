"""A person's look in one camera: colour histograms of a detector's box, and how far apart two
are.

On the floor, two people who walk side by side or cross stand inside each other's gates for
several frames; position alone then cannot say which detection is whose, and a tracker that
guesses swaps their identities. Their clothes usually can: `box_appearance` describes a box by
the hue-saturation histograms of its upper and lower body (the shirt, the trousers or skirt),
taken from the box's central columns (the background beside a person fills the box's sides)
and without its top and bottom tenths (hair, and the floor between the feet). Hue and
saturation, not brightness: a person walking from light into shade keeps the colours of their
clothes while their brightness changes.

`appearance_distance` is the Bhattacharyya distance of two such descriptors, 0 for the same
histograms and 1 for histograms with no bin in common. The tracker (core.localization.tracking)
compares a detection's descriptor with the descriptor each track had in the same camera (colour
responses differ from camera to camera, so descriptors of different cameras are never
compared).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput

Array = NDArray[np.float64]

# Hue x saturation bins of each part's histogram: 8 hues tell the colours of clothes apart,
# 4 saturations grey from coloured; finer bins split a small box's few pixels too thinly.
HUE_BINS = 8
SATURATION_BINS = 4
# The body's parts, top to bottom, between these fractions of the box's height, and the
# central columns of the box taken (fractions of its width).
PARTS = ((0.1, 0.5), (0.5, 0.9))
COLUMNS = (0.2, 0.8)
# Length of a descriptor: one histogram per part.
APPEARANCE_SIZE = len(PARTS) * HUE_BINS * SATURATION_BINS


def box_appearance(image: NDArray[np.uint8], boxes: ArrayLike) -> Array:
    """Return the appearance descriptor (N, APPEARANCE_SIZE) of each box (N, 4) [x0, y0, x1, y1]
    (pixels) in a BGR image: per part (PARTS) a hue-saturation histogram of the box's central
    columns, each part's histogram summing to 1 / len(PARTS), so a descriptor sums to 1. A part
    with no pixel inside the image gives zeros (a descriptor summing to less than 1: compared
    only on what it has)."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidInput(f"image must be an 8-bit BGR image (H, W, 3), got {img.shape}")
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    if not np.all(np.isfinite(b)):
        raise InvalidInput("boxes contain NaN or infinite values")
    out = np.zeros((b.shape[0], APPEARANCE_SIZE))
    if b.shape[0] == 0:
        return out
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    height, width = img.shape[:2]
    size = HUE_BINS * SATURATION_BINS
    for n, (x0, y0, x1, y1) in enumerate(b):
        w, h = x1 - x0, y1 - y0
        xa = int(np.clip(round(x0 + COLUMNS[0] * w), 0, width))
        xb = int(np.clip(round(x0 + COLUMNS[1] * w), 0, width))
        for k, (top, bottom) in enumerate(PARTS):
            ya = int(np.clip(round(y0 + top * h), 0, height))
            yb = int(np.clip(round(y0 + bottom * h), 0, height))
            if xb <= xa or yb <= ya:
                continue
            hist = cv2.calcHist(
                [np.ascontiguousarray(hsv[ya:yb, xa:xb])],
                [0, 1],
                None,
                [HUE_BINS, SATURATION_BINS],
                [0, 180, 0, 256],
            ).ravel()
            total = float(hist.sum())
            if total > 0:
                out[n, k * size : (k + 1) * size] = hist / (total * len(PARTS))
    return out


def appearance_distance(a: ArrayLike, b: ArrayLike) -> Array:
    """Return the Bhattacharyya distance (A, B) in [0, 1] between descriptors a (A, F) and
    b (B, F), each non-negative: sqrt(1 - sum sqrt(a_i b_i) / sqrt(|a| |b|)), with |.| a
    descriptor's sum; 1 where either is all zeros (nothing to compare)."""
    A = np.asarray(a, dtype=np.float64)
    B = np.asarray(b, dtype=np.float64)
    if A.ndim != 2 or B.ndim != 2 or A.shape[1] != B.shape[1]:
        raise InvalidInput(f"descriptors must be (A, F) and (B, F), got {A.shape} and {B.shape}")
    if np.any(A < 0) or np.any(B < 0) or not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise InvalidInput("appearance descriptors are histograms: finite and non-negative")
    coefficient = np.sqrt(A) @ np.sqrt(B).T
    norm = np.sqrt(A.sum(axis=1)[:, None] * B.sum(axis=1)[None, :])
    with np.errstate(divide="ignore", invalid="ignore"):
        similar = np.where(norm > 0, coefficient / norm, 0.0)
    return np.asarray(np.sqrt(np.clip(1.0 - similar, 0.0, 1.0)))
