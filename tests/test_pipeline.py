"""Pipeline: configuration round trip, registry, end-to-end estimation on exact synthetic data."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.tracking.odometry import KeyframeOptions
from ifmi.pipeline import (EstimateConfig, create_front_end, estimate_sequence, method_names,
                           resolved_config)
from ifmi.geometry.rotations import geodesic_angle
from ifmi.spectral.ifmi_front_end import (CoarseOptions, IfmiConfig, IfmiFrontEnd, RefinementOptions,
                                         RegistrationOptions)
from ifmi.spectral.tiling import TilingConfig
from ifmi.spectral.panorama import PanoramaConfig

pytest.importorskip("skimage")
from ifmi.synthetic import synthetic_sequence  # noqa: E402

MODEL = paracatadioptric_model((256, 256), horizon_radius_px=80.0, center=(130.3, 126.1),
                               affine=(1.002, 0.003, -0.002))
CONFIG = EstimateConfig(ifmi=IfmiConfig(panorama=PanoramaConfig(width=512)))


@pytest.fixture(scope="module")
def sequence():
    return synthetic_sequence(MODEL, 10, seed=3, band_px=(30.0, 125.0), noise_std=2.0)


def test_config_round_trip():
    config = replace(CONFIG, keyframe=KeyframeOptions(enabled=True, min_inliers=12),
                     ifmi=replace(CONFIG.ifmi, tiling=TilingConfig(tile_size=0.1, overlap=0.25)))
    assert EstimateConfig.from_dict(config.to_dict()) == config


def test_unknown_config_section_is_rejected():
    with pytest.raises(ValueError, match="unknown key bogus; expected ifmi, features"):
        EstimateConfig.from_dict({"ifmi": {}, "bogus": {}})


def test_unknown_method_is_rejected():
    assert "ifmi" in method_names()
    with pytest.raises(ValueError, match="unknown method"):
        create_front_end("sift", MODEL, CONFIG)


@pytest.mark.parametrize("keyframes", [False, True])
def test_end_to_end_synthetic_rotation(sequence, keyframes):
    config = replace(CONFIG, keyframe=KeyframeOptions(enabled=keyframes))
    est = estimate_sequence(sequence.images, MODEL, method="ifmi", config=config)
    assert len(est.trajectory) == 10 and all(r.success for r in est.frames)
    err = geodesic_angle(sequence.rotations, est.trajectory.rotations)
    # 512 px panorama: 1 px = 0.0123 rad; tiles register to ~0.03 px, i.e. ~4e-4 rad per
    # estimate, and at most 9 estimates are chained.
    assert err.max() < 4e-3
    assert np.sqrt(np.mean(err ** 2)) < 2.5e-3
    if keyframes:
        assert len({r.reference_frame for r in est.frames}) < 10


def test_unrelated_frames_are_flagged_and_the_trajectory_continues(sequence):
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 255, MODEL.size, dtype=np.uint8)
    images = list(sequence.images[:4]) + [noise] + list(sequence.images[4:6])
    est = estimate_sequence(images, MODEL, method="ifmi", config=CONFIG)
    assert len(est.trajectory) == 7
    assert not est.frames[4].success and est.frames[4].reason
    assert np.allclose(est.trajectory.rotations[4], est.trajectory.rotations[3])
    assert est.frames[5].success and est.frames[5].reference_frame == 3
    err = geodesic_angle(sequence.rotations[4], est.trajectory.rotations[5])
    assert err < 4e-3


def test_prior_rotation_moves_tiles_and_keeps_the_estimate(sequence):
    from ifmi.backend.relative_pose import relative_pose_from_rays
    from ifmi.spectral.ifmi_front_end import IfmiFrontEnd

    fe = IfmiFrontEnd(MODEL, CONFIG.ifmi)
    a, b = fe.prepare(sequence.images[0]), fe.prepare(sequence.images[3])
    centre = (fe.layout.tile_size - 1) / 2.0
    offsets = fe.layout.origins + centre
    linear = np.broadcast_to(np.eye(2), (fe.layout.count, 2, 2))

    def predicted_origins(rotation):
        return fe.predicted_placements(offsets, linear, rotation)[0] - centre

    assert np.allclose(predicted_origins(np.eye(3)), fe.layout.origins, atol=1e-9)
    yaw = 2 * np.pi * 5 / fe.mapping.width
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    moved = predicted_origins(rz)
    width = fe.mapping.width
    shift = np.mod(moved[:, 1] - fe.layout.origins[:, 1] + width / 2, width) - width / 2
    # R_ab turns camera b by +5 px of azimuth, so tile a's content is 5 px to the left in b.
    assert np.allclose(shift, -5.0, atol=1e-6)
    assert np.allclose(moved[:, 0], fe.layout.origins[:, 0], atol=1e-6)
    truth = sequence.rotations[0].T @ sequence.rotations[3]
    errors = []
    for prior in (None, truth):
        corr = fe.correspondences(a, b, prior_rotation=prior)
        pose, info = relative_pose_from_rays(corr.rays_a, corr.rays_b, options=resolved_config(CONFIG, MODEL).relative_pose)
        assert info.success
        errors.append(geodesic_angle(truth, pose.rotation))
    # Three frames apart: the prediction leaves only sub-pixel tile motion to measure.
    assert errors[1] < 1e-3 and errors[0] < 2e-3


# A published OCamCalib calibration of a real 748 x 480 camera: off-centre, non-identity affine.
REAL_CALIB = """#polynomial coefficients for the DIRECT mapping function
5 -2.063866e+02 0.000000e+00 2.165610e-03 -4.495456e-06 1.810639e-08

#polynomial coefficients for the inverse mapping function
12 293.052431 151.538629 -11.130942 27.892086 7.952091 -1.062672 10.373416 1.171771 -6.054173 0.762221 3.136665 0.865190

#center: "row" and "column", starting from 0 (C convention)
241.019976 385.783141

#affine parameters "c", "d", "e"
0.998881 -0.042038 0.045079

#image size: "height" and "width"
480 748
"""


def test_real_calibration_with_default_configuration():
    from ifmi.io.calib import parse_calib
    from ifmi.spectral.ifmi_front_end import IfmiFrontEnd

    model = parse_calib(REAL_CALIB)
    seq = synthetic_sequence(model, 6, seed=5, band_px=(60.0, 235.0), noise_std=2.0)
    est = estimate_sequence(seq.images, model, method="ifmi", config=EstimateConfig())
    assert all(r.success for r in est.frames)
    # Automatic band from the dark centre and the image border, width ~ its circumference.
    fe = IfmiFrontEnd(model)
    fe.prepare(seq.images[0])
    inner, outer = fe.mapping.radius_band_px
    assert 60.0 <= inner <= 75.0 and 225.0 <= outer <= 241.0
    assert fe.mapping.width == 960
    # 960 px panorama (0.0065 rad/px), tiles to ~0.05 px: ~3e-4 rad per estimate, 5 chained.
    assert geodesic_angle(seq.rotations, est.trajectory.rotations).max() < 1.5e-3


def test_angular_pixel_size_scales_with_resolution():
    from ifmi.spectral.panorama import angular_pixel_size_in_band as angular_pixel_size

    # The same mirror imaged at 256, 512 and 800 px: a pixel subtends an angle
    # inversely proportional to the resolution (to the band-sampling accuracy).
    sizes = [angular_pixel_size(MODEL.scaled(f)) for f in (1.0, 2.0, 3.125)]
    assert sizes[0] / sizes[1] == pytest.approx(2.0, rel=0.02)
    assert sizes[0] / sizes[2] == pytest.approx(3.125, rel=0.02)
    # Paraboloid: a pixel at the horizon radius h subtends 1 / h rad along and across the
    # radius; the band median is within a factor 2 of it.
    assert 0.5 / 80.0 < sizes[0] < 2.0 / 80.0


def test_pixel_threshold_is_resolved_for_the_calibration(sequence):
    from ifmi.pipeline import resolved_config
    from ifmi.spectral.panorama import angular_pixel_size_in_band

    config = replace(CONFIG, relative_pose=replace(CONFIG.relative_pose, ransac_threshold_px=1.5))
    pixel = angular_pixel_size_in_band(MODEL, config=CONFIG.ifmi.panorama)
    assert resolved_config(config, MODEL).relative_pose.ransac_threshold_rad == pytest.approx(1.5 * pixel)
    explicit = replace(CONFIG, relative_pose=replace(CONFIG.relative_pose, ransac_threshold_rad=1e-3))
    assert resolved_config(explicit, MODEL) == explicit
    est = estimate_sequence(sequence.images[:3], MODEL, method="ifmi", config=config)
    # The result's configuration records the threshold actually used.
    assert est.config.relative_pose.ransac_threshold_rad == pytest.approx(1.5 * pixel)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"bogus": {}}, r"^unknown key bogus; expected ifmi, features, relative_pose, keyframe, rolling_shutter, "
         r"bundle_adjustment, plane_twin$"),
        ({"relative_pose": {"threshold": 1.0}}, r"^relative_pose: unknown key threshold; expected "),
        ({"keyframe": {"every": 3}}, r"^keyframe: unknown key every; expected enabled, "),
        ({"ifmi": {"tiling": {"size": 64}}}, r"^ifmi.tiling: unknown key size; expected tile_size, overlap$"),
    ],
)
def test_config_from_dict_names_unknown_keys(data, message):
    with pytest.raises(ValueError, match=message):
        EstimateConfig.from_dict(data)


def test_cubic_tile_resampling_removes_the_interpolation_bias(sequence):
    # A frame registered with itself under a deliberately wrong prior: the truth is the identity,
    # and the tiles of b are cut at sub-pixel places, turned and scaled, so the error left is
    # the interpolation's (no noise, no scene change).
    from ifmi.backend.relative_pose import relative_pose_from_rays
    from ifmi.spectral.ifmi_front_end import IfmiFrontEnd

    options = resolved_config(CONFIG, MODEL).relative_pose
    rng = np.random.default_rng(2)
    priors = []
    for _ in range(6):
        axis = rng.normal(size=3)
        angle = 0.004  # rad, about half a panorama pixel here: a typical prediction error
        priors.append(Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix())
    rms = {}
    for interpolation in ("linear", "cubic", "lanczos4"):
        # Without the coarse stage, which would replace the wrong prior by its own estimate.
        config = replace(CONFIG.ifmi, registration=RegistrationOptions(resample_interpolation=interpolation),
                         coarse=CoarseOptions(enabled=False))
        fe = IfmiFrontEnd(MODEL, config)
        state = fe.prepare(sequence.images[0])
        errors = []
        for prior in priors:
            corr = fe.correspondences(state, state, prior_rotation=prior)
            pose, info = relative_pose_from_rays(corr.rays_a, corr.rays_b, options=options)
            assert info.success
            errors.append(geodesic_angle(np.eye(3), pose.rotation))
        rms[interpolation] = float(np.sqrt(np.mean(np.square(errors))))
    # Measured: rms 2.3e-4 rad (bilinear) against 3.7e-5 (bicubic) and 4.1e-5 rad (Lanczos).
    assert rms["cubic"] < rms["linear"] / 3
    assert rms["lanczos4"] < rms["linear"] / 3


def test_auto_tile_kernel_is_bicubic_on_narrow_and_lanczos_on_wide_panoramas():
    options = RegistrationOptions()
    assert options.resample_interpolation == "auto"
    assert options.engine_config().resample_interpolation == "cubic"
    assert options.engine_config(wide=True).resample_interpolation == "lanczos4"
    # A kernel named is used at every width.
    assert RegistrationOptions(resample_interpolation="linear").engine_config(wide=True).resample_interpolation == "linear"
    with pytest.raises(ValueError, match="resample_interpolation"):
        RegistrationOptions(resample_interpolation="nearest")
    image = synthetic_sequence(MODEL, 1, seed=0, band_px=(30.0, 125.0)).images[0]
    kernels = {}
    for min_width in (CONFIG.ifmi.panorama.width + 1, CONFIG.ifmi.panorama.width):
        config = replace(CONFIG.ifmi, refinement=RefinementOptions(min_width_sharp=min_width))
        front_end = IfmiFrontEnd(MODEL, config)
        front_end.prepare(image)
        kernels[min_width] = front_end.engine.config.resample_interpolation
    assert kernels == {CONFIG.ifmi.panorama.width + 1: "cubic", CONFIG.ifmi.panorama.width: "lanczos4"}


def test_config_with_unknown_feature_option_names_it():
    with pytest.raises(ValueError, match=r"features: unknown key n_feature; expected n_features"):
        EstimateConfig.from_dict({"features": {"n_feature": 10}})
    config = EstimateConfig.from_dict({"features": {"n_features": 10}})
    assert config.features.n_features == 10
    assert EstimateConfig.from_dict(config.to_dict()) == config
