"""box_foot: the foot point of a detector's box and its covariance model."""

import numpy as np
import pytest

from core.errors import InvalidInput
from core.localization import BOX_SIDES, BoxNoise, box_foot, cut_mask


def test_foot_is_the_bottom_centre_with_a_covariance_from_the_size():
    fit = box_foot([[100.0, 50.0, 140.0, 250.0], [0.0, 0.0, 4.0, 10.0]])
    np.testing.assert_allclose(fit.pixel, [[120.0, 250.0], [2.0, 10.0]])
    # 40 x 200 px: sigma_u = 0.10 * 40 = 4 px, sigma_v = 0.04 * 200 = 8 px.
    np.testing.assert_allclose(fit.cov[0], np.diag([16.0, 64.0]))
    # A tiny box keeps the 1 px floor on both axes.
    np.testing.assert_allclose(fit.cov[1], np.eye(2))
    assert fit.measured.tolist() == [True, True]


def test_a_cut_bottom_is_not_measured_and_a_cut_side_widens_u():
    cut = cut_mask([["bottom"], ["left"], ["top"]])
    assert cut.shape == (3, len(BOX_SIDES))
    fit = box_foot(np.tile([10.0, 10.0, 50.0, 110.0], (3, 1)), cut, noise=BoxNoise(0.1, 0.05, 1))
    assert fit.measured.tolist() == [False, True, True]
    # Left cut: half the visible width (20 px) instead of 0.1 * 40 = 4 px.
    assert fit.cov[1, 0, 0] == pytest.approx(400.0)
    assert fit.cov[2, 0, 0] == pytest.approx(16.0)
    assert fit.cov[2, 1, 1] == pytest.approx(25.0)


@pytest.mark.parametrize(
    "boxes", [[[10.0, 10.0, 5.0, 20.0]], [[0.0, 0.0, 1.0, np.nan]], [[1.0, 2.0, 3.0]]]
)
def test_bad_boxes_are_refused(boxes):
    with pytest.raises(InvalidInput):
        box_foot(boxes)


def test_unknown_side_is_refused():
    with pytest.raises(InvalidInput, match="middle"):
        cut_mask([["middle"]])
