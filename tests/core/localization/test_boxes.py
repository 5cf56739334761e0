"""box_foot: the foot point of a detector's box and its covariance model."""

import numpy as np
import pytest

from core.errors import InvalidInput
from core.localization import (
    BOX_SIDES,
    Box,
    BoxNoise,
    NetworkCamera,
    Occluders,
    box_foot,
    cut_mask,
    foot_on_axis,
    locate_monocular,
)
from core.localization.detect import BodyModel


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


# A ceiling camera 2.6 m up in a room's corner looking across it, 640 x 480, with some barrel
# distortion: the geometry of the twin's home cameras.
_K = np.array([[420.0, 0.0, 320.0], [0.0, 420.0, 240.0], [0.0, 0.0, 1.0]])


# The boxes below are drawn from the rigid cylinder BodyModel() describes (a twin's walker):
# the fit is given that body, not a real walking person's box (DETECTOR_BOX_BODY).
TRUNK = BodyModel()


def _camera():
    return NetworkCamera.looking_at(
        _K, [-0.08, 0.01, 0, 0, 0], [0.0, 0.0, 2.6], [3.0, 2.0, 0.0], (640, 480)
    )


def _rim_box(camera, xy, height=1.7, radius=0.2):
    """The box (pixel edges) of a standing cylinder: the extremes of its rims' images, drawn
    independently of the fit (OpenCV's projection of 720 rim points)."""
    a = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    rim = np.c_[xy[0] + radius * np.cos(a), xy[1] + radius * np.sin(a)]
    pts = np.r_[np.c_[rim, np.zeros(len(a))], np.c_[rim, np.full(len(a), height)]]
    px = camera.project(pts)
    # The camera model's pixel i is centred at i; a box's edges are pixel edges (+0.5).
    return np.r_[px.min(axis=0), px.max(axis=0)] + 0.5


def _floor(camera, fit):
    return locate_monocular(camera, fit.pixel, 0.0).point[:, :2]


def test_the_axis_of_a_standing_body_is_found_from_its_box():
    camera = _camera()
    where = np.array([[2.0, 1.0], [3.5, 2.5], [1.2, 2.4]])
    boxes = np.array([_rim_box(camera, xy) for xy in where])
    fit = foot_on_axis(boxes, box_foot(boxes), camera, body=TRUNK)
    assert fit.measured.all()
    # A box drawn from the body the fit assumes gives its axis back: to a millimetre (the
    # 32-point rims of the fit against the 720 of the drawing move an edge by < 0.1 px).
    np.testing.assert_allclose(_floor(camera, fit), where, atol=2e-3)
    # A body 0.1 m taller (one prior sigma) still lands within a few centimetres, and its
    # position error is inside 3 of the covariance's standard deviations.
    tall = np.array([_rim_box(camera, xy, height=1.8) for xy in where])
    fit = foot_on_axis(tall, box_foot(tall), camera, body=TRUNK)
    got = locate_monocular(camera, fit.pixel, 0.0, pixel_cov=fit.cov)
    err = got.point[:, :2] - where
    assert np.all(np.linalg.norm(err, axis=1) < 0.05)
    chi2 = np.einsum("ni,nij,nj->n", err, np.linalg.inv(got.point_cov[:, :2, :2]), err)
    assert np.all(chi2 < 9.21)


def test_a_bottom_hidden_by_known_furniture_is_cut_and_an_odd_end_is_dropped():
    camera = _camera()
    xy = np.array([3.0, 2.0])
    whole = _rim_box(camera, xy)
    # A table 0.75 m high between the camera and the body hides the feet: the box stops at
    # the table's top (the image of the body's near edge at 0.75 m).
    u = xy / np.linalg.norm(xy)
    legs = camera.project(np.r_[xy - 0.2 * u, 0.75][None])[0] + 0.5
    hidden = whole.copy()
    hidden[3] = legs[1]
    table = Occluders.build(boxes=[Box(centre=tuple(xy - 0.6 * u), size=(0.8, 0.8, 0.75))])
    fit = foot_on_axis(hidden[None], box_foot(hidden[None]), camera, occluders=table, body=TRUNK)
    assert not fit.measured[0]
    # Without the floor plan the raised bottom disagrees with one standing body (all four
    # edges fail the chi-square test). Without the bottom the box is one body, to the
    # millimetre; without the top it nearly passes too (a shorter, wider body farther away),
    # so which end is wrong is unknown: the mean of the two, with their gap as spread. The
    # truth lies inside that spread, where the bottom centre's ray puts the body 1.2 m off.
    fit = foot_on_axis(hidden[None], box_foot(hidden[None]), camera, body=TRUNK)
    assert fit.measured[0]
    got = locate_monocular(camera, fit.pixel, 0.0, pixel_cov=fit.cov)
    err = got.point[0, :2] - xy
    assert err @ np.linalg.solve(got.point_cov[0, :2, :2], err) < 9.21
    naive = _floor(camera, box_foot(hidden[None]))[0]
    assert np.linalg.norm(naive - xy) > 1.0 > np.linalg.norm(err)
    # A second person 0.6 m behind raises the top: the fit drops the top.
    behind = _rim_box(camera, xy + 0.6 * u)
    merged = np.r_[np.minimum(whole[:2], behind[:2]), np.maximum(whole[2:], behind[2:])]
    fit = foot_on_axis(merged[None], box_foot(merged[None]), camera, body=TRUNK)
    assert fit.measured[0]
    assert np.linalg.norm(_floor(camera, fit)[0] - xy) < 0.1


def test_cut_sides_are_not_used_and_no_body_means_no_floor_position():
    camera = _camera()
    box = _rim_box(camera, [2.5, 1.5])
    shifted = box - np.array([30.0, 0.0, 0.0, 0.0])  # the left edge wrong, and declared cut
    cut = cut_mask([["left"]])
    fit = foot_on_axis(shifted[None], box_foot(shifted[None], cut), camera, cut=cut, body=TRUNK)
    assert fit.measured[0]
    assert np.linalg.norm(_floor(camera, fit)[0] - [2.5, 1.5]) < 0.05
    # A box 4x too narrow and half as tall for a person where it stands: no fit explains it.
    odd = np.array([[300.0, 200.0, 310.0, 240.0]])
    assert not foot_on_axis(odd, box_foot(odd), camera, body=TRUNK).measured[0]


def test_a_walking_persons_box_is_measured_with_the_detector_box_body():
    # A walking person seen from the side mid-stride: the trunk's cylinder (0.2 m) with the
    # feet and hands 0.35 m either side of the axis, so the box is as wide as a 0.35 m
    # cylinder's. The trunk's body (0.2 +- 0.03 m) finds no standing body that wide; a
    # detector's box body (0.3 +- 0.1 m, the default) does.
    camera = _camera()
    where = np.array([[2.0, 1.0], [3.5, 2.5], [1.2, 2.4]])
    trunk = np.array([_rim_box(camera, xy) for xy in where])
    wide = np.array([_rim_box(camera, xy, radius=0.35) for xy in where])
    box = np.c_[wide[:, 0], trunk[:, 1], wide[:, 2], trunk[:, 3]]
    # (The nearest, seen large, passes the trunk's fit with one end dropped.)
    assert (~foot_on_axis(box, box_foot(box), camera, body=TRUNK).measured).sum() >= 2
    fit = foot_on_axis(box, box_foot(box), camera)
    assert fit.measured.all()
    # Within 0.2 m: the drawn feet are the trunk's near edge (0.2 m from the axis), the fit
    # puts them a fitted radius (~0.3 m) from it, 0.15 m farther here.
    assert np.all(np.linalg.norm(_floor(camera, fit) - where, axis=1) < 0.2)


def test_a_box_whose_fit_leaves_the_lens_model_is_not_measured_and_raises_nothing():
    # A 640 x 480 ceiling camera with a strong barrel lens (k1 = -0.28): the box at the image's
    # left edge (its left side cut) starts fits whose cylinders fall where the lens's
    # polynomial no longer holds; their normal equations overflow (1e40) or are singular.
    # Such a fit says nothing of the box: it is refused, not raised (the box came from a
    # detector or an API client and must never crash the service).
    cam = NetworkCamera(
        K=np.array([[331.085861, 0.0, 319.814627], [0.0, 330.529733, 241.135733], [0, 0, 1]]),
        dist=np.array([-0.280678, 0.070224, -0.000439, 0.000202, -0.001963]),
        R=np.array(
            [
                [0.664754, -0.747061, 0.001443],
                [-0.55918, -0.498852, -0.662166],
                [0.495398, 0.439371, -0.749356],
            ]
        ),
        t=np.array([-2.973063, 4.633093, -0.357088]),
        image_size=(640, 480),
    )
    box = np.array([[2.0, 406.0, 98.0, 476.0], [300.0, 200.0, 340.0, 330.0]])
    cut = np.array([[False, False, True, False], [False, False, False, False]])
    foot = box_foot(box, cut)
    out = foot_on_axis(box, foot, cam, cut=cut)
    assert np.all(np.isfinite(out.pixel))
    # The box in the middle of the image is measured as before: the other row's failure does
    # not spread to it.
    assert out.measured[1]
    alone = foot_on_axis(box[1:], box_foot(box[1:], cut[1:]), cam, cut=cut[1:])
    np.testing.assert_allclose(out.pixel[1], alone.pixel[0])
    np.testing.assert_allclose(out.cov[1], alone.cov[0])
    # What is measured has a floor position: a symmetric positive definite covariance.
    c = out.cov[out.measured]
    assert np.array_equal(c, c.transpose(0, 2, 1)) and np.all(np.linalg.det(c) > 0)
