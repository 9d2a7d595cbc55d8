"""Unified-model calibration from checkerboard corners: known cameras and poses are recovered exactly."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.geometry.board_calibration import (BoardFitConfig, board_points, fit_unified_to_boards, parabolic_start,
                                             pose_from_rays)
from ifmi.geometry.camera_models import UnifiedModel

SIZE = (640, 640)
POINTS = board_points(6, 8, 0.042)
# A near-parabolic mirror with some lens distortion, its principal point off the image centre.
TRUE = UnifiedModel(0.92, (250.0, 253.0), (322.0, 315.0), SIZE, (-0.05, 0.004, 0.0006, -0.0003))


def _board_poses(rng, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boards 0.4-0.7 m away, at 30-100 degrees off the axis all round, facing the camera, tilted."""
    poses = []
    for k in range(count):
        theta = np.radians(rng.uniform(30.0, 100.0))
        phi = 2.0 * np.pi * k / count + rng.uniform(-0.3, 0.3)
        direction = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        normal = -direction  # board z axis towards the camera ...
        x_axis = np.cross([0.0, 0.0, 1.0], normal)
        x_axis /= np.linalg.norm(x_axis)
        facing = np.c_[x_axis, np.cross(normal, x_axis), normal]
        rotation = facing @ Rotation.from_rotvec(rng.uniform(-0.4, 0.4, 3)).as_matrix()  # ... tilted
        centre = POINTS.mean(axis=0)
        poses.append((rotation, rng.uniform(0.4, 0.7) * direction - rotation @ centre))
    return poses


def _corners(model, poses) -> np.ndarray:
    corners = np.stack([model.pixels_from_rays(POINTS @ r.T + t) for r, t in poses])
    assert np.isfinite(corners).all() and (corners > 0).all() and (corners < SIZE[0] - 1).all()
    return corners


def test_pose_from_exact_rays_is_the_pose(rng):
    for rotation, translation in _board_poses(rng, 6):
        found_rotation, found_translation = pose_from_rays(POINTS @ rotation.T + translation, POINTS)
        assert np.allclose(found_rotation, rotation, atol=1e-9)
        assert np.allclose(found_translation, translation, atol=1e-9)


def test_fit_from_a_parabolic_start_recovers_the_camera(rng):
    poses = _board_poses(rng, 8)
    start = parabolic_start((TRUE.principal_point[1] + 4.0, TRUE.principal_point[0] - 3.0), 290.0, SIZE)
    fit = fit_unified_to_boards(_corners(TRUE, poses), POINTS, start)
    assert fit.success and fit.rms_px < 1e-6
    assert fit.model.xi == pytest.approx(TRUE.xi, abs=1e-6)
    assert np.allclose(fit.model.focal, TRUE.focal, atol=1e-4)
    assert np.allclose(fit.model.principal_point, TRUE.principal_point, atol=1e-4)
    assert np.allclose(fit.model.distortion, TRUE.distortion, atol=1e-7)
    for (rotation, translation), (found_rotation, found_translation) in zip(poses, fit.camera_from_board):
        assert np.allclose(found_rotation, rotation, atol=1e-7)
        assert np.allclose(found_translation, translation, atol=1e-8)


def test_fit_without_distortion_and_with_noisy_corners(rng):
    true = UnifiedModel(1.0, (250.0, 250.0), (322.0, 315.0), SIZE)
    corners = _corners(true, _board_poses(rng, 8))
    noise_px = 0.2
    noisy = corners + rng.normal(0.0, noise_px, corners.shape)
    fit = fit_unified_to_boards(noisy, POINTS, parabolic_start((318.0, 325.0), 280.0, SIZE),
                                config=BoardFitConfig(distortion=False))
    assert fit.model.distortion == ()
    # The residual RMS of a least-squares fit is the noise's (2-D) RMS, a little less for the unknowns fitted.
    assert 0.8 * noise_px * np.sqrt(2) < fit.rms_px < noise_px * np.sqrt(2)
    assert fit.per_view_rms_px.shape == (8,)
    # 0.2 px of corner noise moves the principal point by under a pixel with these eight boards.
    assert abs(fit.model.xi - 1.0) < 0.05
    assert np.allclose(fit.model.principal_point, true.principal_point, atol=2.0)


def test_bad_corners_are_refused():
    start = parabolic_start((320.0, 320.0), 250.0, SIZE)
    with pytest.raises(ValueError, match=r"expected corners of shape \(V, 48, 2\)"):
        fit_unified_to_boards(np.zeros((2, 47, 2)), POINTS, start)
    corners = np.full((1, 48, 2), 100.0)
    corners[0, 3, 0] = np.nan
    with pytest.raises(ValueError, match="finite corners"):
        fit_unified_to_boards(corners, POINTS, start)
