"""A detector's boxes against the node's own pixel path, on the twin's rendered walkers, and
the box noise model against the scatter of real boxes (PETS 2009)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from core.calibration import place_camera
from core.localization import DEFAULT_BOX_NOISE, box_foot, foot_on_axis
from core.localization.detect import BodyModel
from core.localization.detections import FrameDetection
from core.sim.camera_frames import rendered_frames
from core.sim.occluders import scene_occluders
from core.sim.scenarios import multi_target_tracking as ts
from tests.support.twin_calibration import stored_calibrated_cameras

# The twin's walkers are rigid cylinders of a trunk's size: their boxes are the trunk's.
WALKER = BodyModel()
SEED = 17
MINUTES = 0.15


def test_boxes_of_the_twins_walkers_track_like_the_pixel_path():
    scene = ts.tracking_scene()
    # The home's network calibration for seed 17 as calibrated_cameras computes it (the
    # robot's marker drive and the signposts' registration, ~45 s), stored once by
    # tests/support/twin_calibration.py; the values are the ones computed here before (same
    # floats, so the same figures below). Nothing is easier for it: both paths still run on
    # these same estimated cameras (with their calibration errors, never the twin's truth),
    # the same rendered walkers and the same tracker, and the bounds are unchanged. The file
    # is refused if the scene changes.
    calibrated = stored_calibrated_cameras(scene, SEED)
    frames, drive = rendered_frames(scene, SEED, calibrated, minutes=MINUTES)
    pixel_path = ts.track_rendered(scene, SEED, frames, drive, calibrated, minutes=MINUTES)
    # The same people as a box detector would give them: each person blob's box only (4
    # numbers, no silhouette), through the one box function and the camera's geometry, with
    # the home's floor plan (its furniture and walls, which the service knows; the tracker
    # is given the same).
    plan = scene_occluders(scene)
    boxed = []
    for f in frames:
        found = []
        for d in f.found:
            if d.kind != "person" or d.bbox is None:
                found.append(d)
                continue
            x, y, w, h = d.bbox
            box = [x, y, x + w, y + h]
            foot = foot_on_axis(
                box, box_foot(box), calibrated.cameras[f.camera], occluders=plan, body=WALKER
            )
            if foot.measured[0]:
                found.append(FrameDetection("person", foot.pixel[0], foot.cov[0], 0.0, d.bbox))
        boxed.append(dataclasses.replace(f, found=tuple(found)))
    box_path = ts.track_rendered(scene, SEED, boxed, drive, calibrated, minutes=MINUTES)
    print(
        f"pixel path: IDF1 {pixel_path.idf1:.3f} RMSE {pixel_path.person_rmse_m:.3f} m; "
        f"boxes: IDF1 {box_path.idf1:.3f} RMSE {box_path.person_rmse_m:.3f} m"
    )
    # The same identities.
    assert box_path.idf1 >= pixel_path.idf1 - 0.02
    assert box_path.mota >= pixel_path.mota - 0.03
    # Positions within 1.2x of the pixel path. A cylinder fitted to the box's
    # four edges, with ends hidden by the floor plan's furniture or inconsistent with one body
    # dropped (core.localization.foot_on_axis), measured 0.031 m against 0.028 m here (1.09x;
    # the bottom centre gave 0.102 m, 3.6x), 1.16x on seed 5 (seen while the consistency
    # test's level was chosen) and 0.94x on seed 23 (run once, on the final code). The bound
    # leaves ~10 % over this seed's ratio, above every seed measured.
    assert box_path.person_rmse_m <= 1.2 * pixel_path.person_rmse_m


def _pets(shared_data_dir):
    gt = np.loadtxt(shared_data_dir / "pets2009-s2l1" / "gt-frames-001-400.txt", delimiter=",")
    gt = gt[gt[:, 6] == 1]
    boxes = np.c_[gt[:, 2], gt[:, 3], gt[:, 2] + gt[:, 4], gt[:, 3] + gt[:, 5]]
    return gt[:, 0], boxes, gt[:, 7:9]


def test_box_noise_covers_the_scatter_of_real_boxes(shared_data_dir):
    frame, boxes, floor = _pets(shared_data_dir)
    foot = box_foot(boxes)
    given = np.isin(frame, np.arange(1, 400, 50))
    placed = place_camera(floor[given], foot.pixel[given], (768, 576))
    R = placed.T_world_camera[:3, :3].T
    t = -R @ placed.T_world_camera[:3, 3]
    other = ~given
    world = np.c_[floor[other], np.zeros(other.sum())]
    proj = cv2.projectPoints(world, cv2.Rodrigues(R)[0], t, placed.K, None)[0][:, 0]
    r = foot.pixel[other] - proj
    w = boxes[other, 2] - boxes[other, 0]
    h = boxes[other, 3] - boxes[other, 1]
    z = r / np.sqrt(np.stack([foot.cov[other, 0, 0], foot.cov[other, 1, 1]], 1))
    chi2 = np.sum(z**2, axis=1)
    ku, kv = np.std(r[:, 0] / w), np.std(r[:, 1] / h)
    print(
        f"PETS ground-truth boxes: sigma_u = {ku:.4f} w, sigma_v = {kv:.4f} h; normalised by "
        f"BoxNoise {DEFAULT_BOX_NOISE}: std z = {z.std(0).round(3)}, mean chi2 {chi2.mean():.3f}"
    )
    # The model is not optimistic on real boxes: the chi-square (2 dof) of the foot's residual
    # under BoxNoise has a mean of at most 2 and under 1 % beyond its 99 % point (9.21).
    assert chi2.mean() <= 2.0
    assert np.mean(chi2 > 9.21) <= 0.01
    # What the annotated boxes measure (their world positions were made from the same feet,
    # so this is the annotation's consistency, a floor under any detector's error): sigma_u
    # 0.035 w and sigma_v 0.0044 h on 2,177 boxes. The model's k_u = 0.10 and k_v = 0.04 sit
    # above both, as a detector's jitter must; the bounds fail if the data or the foot moved.
    assert 0.02 < ku < 0.05 and 0.002 < kv < 0.008
    assert DEFAULT_BOX_NOISE.k_u >= ku and DEFAULT_BOX_NOISE.k_v >= kv
