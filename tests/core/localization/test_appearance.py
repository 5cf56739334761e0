"""A box's appearance: hue-saturation histograms of a person's upper and lower body, and their
Bhattacharyya distance."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.errors import InvalidInput
from core.localization.appearance import APPEARANCE_SIZE, appearance_distance, box_appearance

# Clothes as BGR colours (a red shirt and blue jeans; a green jacket and black trousers) on a
# grey, textured pavement.
RED, BLUE, GREEN, BLACK = (40, 40, 200), (160, 80, 30), (50, 160, 60), (25, 25, 25)


def _person(image, rng, x, y, h, shirt, trousers):
    """Draw a person h px tall with feet at (x, y): head, shirt, trousers, with pixel noise;
    return their box [x0, y0, x1, y1]."""
    w = int(0.4 * h)
    x0, y0 = x - w // 2, y - h
    cv2.ellipse(image, (x, y0 + h // 10), (w // 5, h // 10), 0, 0, 360, (90, 120, 170), -1)
    cv2.rectangle(image, (x0 + w // 8, y0 + h // 5), (x0 + w - w // 8, y0 + h // 2), shirt, -1)
    cv2.rectangle(image, (x0 + w // 5, y0 + h // 2), (x0 + w - w // 5, y), trousers, -1)
    noise = rng.normal(0.0, 6.0, (h, w, 3))
    patch = image[y0:y, x0 : x0 + w].astype(np.float64) + noise
    image[y0:y, x0 : x0 + w] = np.clip(patch, 0, 255).astype(np.uint8)
    return [x0, y0, x0 + w, y]


def _scene(seed, people, light=1.0):
    rng = np.random.default_rng(seed)
    image = np.clip(rng.normal(128, 12, (480, 640, 3)), 0, 255).astype(np.uint8)
    boxes = [_person(image, rng, *p) for p in people]
    if light != 1.0:
        image = np.clip(image.astype(np.float64) * light, 0, 255).astype(np.uint8)
    return image, np.array(boxes, dtype=np.float64)


def test_one_person_seen_again_is_near_and_another_far():
    # Frame 1: the red-and-blue person near and large, the green-and-black one far and small.
    image1, boxes1 = _scene(1, [(200, 400, 220, RED, BLUE), (450, 250, 70, GREEN, BLACK)])
    # Frame 2: they have moved, changed size, and the light fell by 40 % (a cloud, the shade).
    image2, boxes2 = _scene(2, [(420, 300, 120, RED, BLUE), (150, 330, 150, GREEN, BLACK)], 0.6)
    a, b = box_appearance(image1, boxes1), box_appearance(image2, boxes2)
    assert a.shape == (2, APPEARANCE_SIZE)
    np.testing.assert_allclose(a.sum(axis=1), 1.0)
    d = appearance_distance(a, b)
    # The same clothes: most of their histograms' mass shares bins (the pavement and noise
    # spill a little), whatever the size and the light; other clothes share almost none.
    assert d[0, 0] < 0.2 and d[1, 1] < 0.2, d
    assert d[0, 1] > 0.8 and d[1, 0] > 0.8, d


def test_distance_bounds_and_boxes_at_or_past_the_edge():
    image, boxes = _scene(3, [(200, 400, 220, RED, BLUE)])
    look = box_appearance(image, boxes)
    assert appearance_distance(look, look)[0, 0] == pytest.approx(0.0, abs=1e-7)
    other = np.zeros((1, APPEARANCE_SIZE))
    other[0, np.argmin(look[0])] = 1.0  # all of it in a bin the person has nothing in
    assert appearance_distance(look, other)[0, 0] == pytest.approx(1.0)
    # Nothing to compare: the distance says so by its largest value.
    assert appearance_distance(look, np.zeros((1, APPEARANCE_SIZE)))[0, 0] == 1.0
    # A box wholly outside the image has no look; one half outside, the half inside.
    edge = box_appearance(image, [[-50.0, 100.0, -10.0, 200.0], [600.0, 300.0, 700.0, 479.0]])
    assert edge[0].sum() == 0.0 and edge[1].sum() == pytest.approx(1.0)
    assert box_appearance(image, np.zeros((0, 4))).shape == (0, APPEARANCE_SIZE)


def test_bad_input_is_refused():
    image, boxes = _scene(4, [(200, 400, 220, RED, BLUE)])
    with pytest.raises(InvalidInput, match="8-bit BGR"):
        box_appearance(image[..., 0], boxes)
    with pytest.raises(InvalidInput, match="NaN"):
        box_appearance(image, [[np.nan, 0.0, 10.0, 10.0]])
    with pytest.raises(InvalidInput, match="non-negative"):
        appearance_distance(-np.ones((1, 4)), np.ones((1, 4)))
    with pytest.raises(InvalidInput, match=r"\(A, F\)"):
        appearance_distance(np.ones((1, 4)), np.ones((1, 5)))
