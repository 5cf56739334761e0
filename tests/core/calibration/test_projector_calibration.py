"""Projector extrinsic calibration: exact without noise, efficient with it, degenerate sets."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from core.calibration.projector import DegenerateSpots, calibrate_projector, mount_errors
from core.errors import NotEnoughPoints
from core.geometry.rotations import rotvec_to_matrix
from core.projector import PanTiltProjector


def _nominal() -> PanTiltProjector:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [2.25, 3.0, 2.75]
    return PanTiltProjector(T, tilt_limits=(0.0, 1.35))


def _truth(rng: np.random.Generator, tilt_offset: float = -0.008) -> PanTiltProjector:
    nom = _nominal()
    dT = np.eye(4)
    dT[:3, :3] = rotvec_to_matrix(rng.normal(0, math.radians(1.0), 3))
    dT[:3, 3] = rng.normal(0, 0.03, 3)
    return replace(nom, T_world_base=nom.T_world_base @ dT, theta=np.array([0.0, tilt_offset]))


def _targets(nx: int = 4, ny: int = 3) -> np.ndarray:
    # 12 spots over the living room (4.5 m x 6 m) around the projector's foot.
    gx, gy = np.meshgrid(np.linspace(0.4, 4.1, nx), np.linspace(0.4, 5.6, ny))
    return np.column_stack([gx.ravel(), gy.ravel()])


def test_noise_free_spots_give_the_exact_mount_and_tilt_offset() -> None:
    nom = _nominal()
    truth = _truth(np.random.default_rng(0))
    q = nom.aim(_targets())
    cal = calibrate_projector(nom, q, truth.spot(q), estimate_tilt_offset=True)
    pos, rot = mount_errors(cal.T_world_base, truth.T_world_base)
    assert pos < 1e-9 and rot < 1e-7
    assert cal.tilt_offset == pytest.approx(-0.008, abs=1e-10)
    assert cal.rms < 1e-10


def test_twelve_spots_with_one_centimetre_noise_meet_their_covariance() -> None:
    nom = _nominal()
    pos_err, rot_err, pos_std = [], [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        truth = _truth(rng, tilt_offset=0.0)
        q = nom.aim(_targets())
        X = truth.spot(q) + rng.normal(0.0, 0.01, (12, 2))
        cal = calibrate_projector(nom, q, X, spot_sigma=0.01)
        p, r = mount_errors(cal.T_world_base, truth.T_world_base)
        pos_err.append(p)
        rot_err.append(r)
        pos_std.append(float(np.linalg.norm(cal.position_std)))
    rms_pos = math.sqrt(np.mean(np.square(pos_err)))
    # The ML estimate attains its first-order covariance: the empirical RMS position error
    # matches the predicted root trace within the Monte Carlo spread (40 trials: ~11 %;
    # 25 % allowed).
    assert rms_pos == pytest.approx(np.mean(pos_std), rel=0.25)
    # Spec 03: orientation within 0.2 deg from 12 spots with 1 cm noise (RMS over trials).
    assert math.sqrt(np.mean(np.square(rot_err))) < 0.2
    # Position: this geometry's bound is ~1.3 cm RMS at 12 spots and 1 cm noise (the spec's
    # 1 cm needs about 20 spots); the estimate stays within 2.5 bound-sigmas in every trial.
    assert max(pos_err) < 2.5 * np.mean(pos_std)


def test_degenerate_spot_sets_are_refused_by_name() -> None:
    nom = _nominal()
    q = nom.aim(_targets())
    X = nom.spot(q)
    with pytest.raises(NotEnoughPoints):
        calibrate_projector(nom, q[:3], X[:3])
    line = np.column_stack([np.linspace(0.5, 4.0, 8), np.full(8, 1.0)])
    with pytest.raises(DegenerateSpots, match="collinear"):
        calibrate_projector(nom, nom.aim(line), line)
    cluster = np.array([2.0, 1.0]) + np.random.default_rng(1).normal(0, 0.05, (8, 2))
    with pytest.raises(DegenerateSpots, match="clustered"):
        calibrate_projector(nom, nom.aim(cluster), cluster)
