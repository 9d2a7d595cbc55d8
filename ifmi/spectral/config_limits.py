"""Limits a configuration must keep for a given camera: sizes its images can give.

Option dataclasses check what they can alone (ranges, types); what depends
on the camera -- a panorama width against the circumference of the mirror
band, a tile against the panorama, a keypoint count against the pixel count
-- is checked here before estimation starts, so a value such as a panorama
width of 1e9 ends in one line instead of exhausting memory.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ifmi.geometry.camera import OcamModel, max_image_radius
from ifmi.errors import InputError
from ifmi.spectral.fourier_mellin import TILE_MEMORY_BUDGET_BYTES, max_tile_count, registration_bytes_per_tile
from ifmi.spectral.tiling import MIN_TILE_SIZE_PX, TilingConfig, tile_grid_shape, tile_size_px, tile_step_px
from ifmi.spectral.panorama import angular_pixel_size_in_band, off_axis_band, panorama_shape, radius_band

__all__ = ["check_config_for_model"]

# Largest panorama size, as a multiple of what the image band holds: the circumference
# of its outer circle (width) and its outer radius (height). Four times already
# samples every omni pixel four-fold along each axis; beyond that memory grows
# (quadratically) without new detail. Log-polar grids are bounded by the same
# factor times the tile side.
_MAX_OVERSAMPLING = 4


def check_config_for_model(config, model, *, method: str = "ifmi", calib_path=None) -> None:
    """Refuse sizes and radii that the images of ``model`` cannot give.

    Checked: the panorama's radius band lies inside the image (and is not
    empty), its width is at most ``4 x 2 pi r_outer`` and its height at most
    ``4 r_outer`` pixels (``r_outer`` the outer radius of the calibration's
    image band; half the image diagonal for camera models other than
    OCamCalib, which take no band radii), for the ``"ifmi"`` method a tile
    given as a fraction of the panorama width has at least
    :data:`~ifmi.spectral.tiling.MIN_TILE_SIZE_PX` pixels and the log-polar grids
    are at most four times the tile side, the tiles of a frame (of the
    layout, and of the dense retry's at ``ifmi.recovery.dense_overlap``) at most
    :func:`ifmi.spectral.fourier_mellin.max_tile_count` (a tile larger than the
    panorama is reported by the front end, naming the calibration), and a feature
    front end's ``radius_band`` lies inside the image. Explicit band radii in ``config`` (e.g. decided from the frames)
    are the band checked. A bundle-adjustment window needs a global shutter.
    A RANSAC threshold in pixels converts to under pi radians.

    Parameters
    ----------
    config : ifmi.pipeline.EstimateConfig
    model : OcamModel or another camera model (:mod:`ifmi.geometry.camera_models`)
    method : str, keyword-only
    calib_path : path, optional, keyword-only
        The calibration file ``model`` was read from: a problem of the
        camera's geometry itself (no full ring of rays to unwrap) names it.

    Raises
    ------
    InputError
        Named after the configuration key (``ifmi.panorama.width``; for
        the tile count ``ifmi.spectral.tiling`` or ``ifmi.recovery.dense_overlap``): what is
        accepted for this camera and what was given; or after ``calib_path``
        (default ``ifmi.panorama``) when the camera model gives no band.
    """
    conflict = config.bundle_adjustment.shutter_conflict(config.rolling_shutter.readout)
    if conflict is not None:
        raise InputError("bundle_adjustment.window", conflict)
    if config.features is not None:
        _check_feature_sizes(config.features, model)
    pano = config.ifmi.panorama
    try:
        if isinstance(model, OcamModel):
            _check_radii(config, model)
            outer = radius_band(model, config=pano)[1]
        else:
            # Other camera models have no sensor radius: the image's half diagonal stands for it.
            _check_no_radii(config, model)
            off_axis_band(model, config=pano)
            outer = 0.5 * float(np.hypot(*model.size))
    except InputError:
        raise
    except ValueError as exc:
        if calib_path is None:
            raise InputError("ifmi.panorama", str(exc)) from None
        raise InputError(calib_path, f"{exc} (checked for the panorama with the ifmi.panorama "
                                     "settings)") from None
    limits = {"width": int(_MAX_OVERSAMPLING * 2 * np.pi * outer), "height": int(_MAX_OVERSAMPLING * outer)}
    for name, limit in limits.items():
        value = getattr(pano, name)
        if value is not None and value > limit:
            kind = "circumference" if name == "width" else "radius"
            raise InputError(f"ifmi.panorama.{name}", f"expected at most {limit} px for this camera "
                                                      f"({_MAX_OVERSAMPLING} x its image band's outer "
                                                      f"{kind}), got {value}")
    if method == "ifmi":
        _check_tiles(config, panorama_shape(model, config=pano))
    _check_pixel_threshold(config, model)


def _check_pixel_threshold(config, model) -> None:
    """A RANSAC threshold in pixels must convert to under pi radians for this camera.

    Rays are at most pi apart, so :class:`~ifmi.backend.relative_pose.RelativePoseOptions`
    takes a radian threshold in (0, pi) only; the pixel threshold is converted
    with the angle a pixel of the camera's band subtends.
    """
    pose = config.relative_pose
    if pose.ransac_threshold_rad is not None:
        return
    pixel = angular_pixel_size_in_band(model, config=config.ifmi.panorama)
    if np.isfinite(pixel) and pixel > 0 and not pose.ransac_threshold_px * pixel < np.pi:
        raise InputError("relative_pose.ransac_threshold_px",
                         f"expected under {np.pi / pixel:.4g} px for this camera (pi rad at {pixel:.3g} rad "
                         f"per pixel of its band), got {pose.ransac_threshold_px:g}")


def _check_radii(config, model: OcamModel) -> None:
    pano = config.ifmi.panorama
    reach = max_image_radius(model.size, model.center, model.affine)
    radii = {"ifmi.panorama.radius_min_px": pano.radius_min_px,
             "ifmi.panorama.radius_max_px": pano.radius_max_px}
    if config.features is not None and config.features.radius_band is not None:
        radii["features.radius_band"] = max(config.features.radius_band)
    for key, value in radii.items():
        if value is not None and value >= reach:
            raise InputError(key, f"expected a radius under {reach:.1f} px (the farthest image corner "
                                  f"from the calibration's centre), got {value:g}")


def _check_no_radii(config, model) -> None:
    pano = config.ifmi.panorama
    for name in ("radius_min_px", "radius_max_px"):
        if getattr(pano, name) is not None:
            raise InputError(f"ifmi.panorama.{name}", f"applies to OCamCalib models only; this camera is "
                                                      f"a {type(model).__name__}")


def _check_feature_sizes(features, model: OcamModel) -> None:
    """Keypoint counts, pyramids and windows at most what an image of ``model`` holds."""

    side = min(model.size)
    # A level (octave) past these has less than one pixel along the image's shorter side.
    limits = {
        "n_features": (features.n_features, model.size[0] * model.size[1], "the image's pixel count"),
        "akaze_min_keypoints": (features.akaze_min_keypoints, model.size[0] * model.size[1],
                                "the image's pixel count"),
        "orb_levels": (features.orb_levels,
                       1 + int(np.log(side) / np.log(features.orb_scale_factor))
                       if features.orb_scale_factor > 1 else 1,
                       f"levels down to one pixel at scale factor {features.orb_scale_factor:g}"),
        "akaze_octaves": (features.akaze_octaves, int(np.log2(side)), "octaves down to one pixel"),
        "orb_patch_size": (features.orb_patch_size, side, "the image's shorter side"),
        "orb_edge_threshold": (features.orb_edge_threshold, side, "the image's shorter side"),
    }
    for name, (value, limit, what) in limits.items():
        if value > limit:
            raise InputError(f"features.{name}", f"expected at most {limit} ({what}), got {value}")


def _check_tiles(config, shape: tuple[int, int]) -> None:
    """The tile size and tile counts of ``config`` for a panorama of ``shape`` ``(height, width)`` px."""
    height, width = shape
    size = config.ifmi.tiling.tile_size
    if size is not None and size < 1 and size * width < MIN_TILE_SIZE_PX:
        raise InputError("ifmi.tiling.tile_size", f"expected a tile of at least {MIN_TILE_SIZE_PX} px, got "
                                                  f"{size:g} of the {width} px panorama width "
                                                  f"({size * width:.3g} px)")
    # A tile larger than the panorama is the front end's to report (it names the calibration file).
    tile = tile_size_px(size, width)
    if tile > min(height, width):
        return
    layouts = {"ifmi.tiling": config.ifmi.tiling}
    if config.ifmi.recovery.dense_retry_fraction > 0 and config.ifmi.tracking.use_prior:
        layouts["ifmi.recovery.dense_overlap"] = replace(config.ifmi.tiling, overlap=config.ifmi.recovery.dense_overlap)
    for key, tiling in layouts.items():
        problem = _tile_count_problem(shape, tiling,
                                      config.ifmi.registration.engine_config())
        if problem:
            raise InputError(key, problem)


def _tile_count_problem(shape: tuple, tiling: TilingConfig, registration) -> str | None:
    """Why the layout ``tiling`` gives a panorama of ``shape`` too many tiles to register, or None.

    The limit is :func:`ifmi.spectral.fourier_mellin.max_tile_count`: the tiles whose registration fits
    :data:`~ifmi.spectral.fourier_mellin.TILE_MEMORY_BUDGET_BYTES`. A near-1 overlap makes steps of a pixel
    or two between tiles, and hundreds of thousands of tiles per frame.
    """
    tile = tile_size_px(tiling.tile_size, shape[1])
    count = int(np.prod(tile_grid_shape(shape, config=tiling)))
    limit = max_tile_count(tile, config=registration)
    if count <= limit:
        return None
    # The largest overlap in hundredths below the one given that keeps within the limit.
    fitting = [k / 100 for k in range(int(tiling.overlap * 100), -1, -1)
               if np.prod(tile_grid_shape(shape, config=replace(tiling, overlap=k / 100))) <= limit]
    advice = (f"an overlap of at most {fitting[0]:g} keeps within it" if fitting else "use larger tiles")
    per_tile = registration_bytes_per_tile(tile, config=registration)
    step = tile_step_px(tile, tiling.overlap)
    return (f"expected at most {limit} tiles per frame ({TILE_MEMORY_BUDGET_BYTES / 2 ** 30:g} GiB to register "
            f"a frame pair, {per_tile / 1024:.0f} KiB per {tile} px tile), got {count}: {tile} px tiles "
            f"overlapping by {tiling.overlap:g} step {step} px across the {shape[0]}x{shape[1]} px panorama; "
            f"{advice}")
