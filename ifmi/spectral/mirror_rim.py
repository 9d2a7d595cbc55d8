"""The mirror's outer rim (or a lens's image circle) in the images, against the calibration's centre.

A catadioptric image is lit inside the mirror's outer rim and dark outside
it, and the rim is a circle about the calibration's centre (OCamCalib: the
distortion centre; Kalibr models: the principal point, for a fisheye lens
its image circle). When a mirror or clip-on lens is mounted again after
calibration, the image moves under the calibration: the estimator then
runs as usual and its rotations are biased. On the demo office rendered at
256 px (rim radius 123 px), a centre 5 px off gave a geodesic ATE of 0.031
rad instead of 0.0005, 10 px 0.061, 20 px 0.12, every frame "successful".

:func:`rim_circle_from_frames` finds the rim along rays from the
calibration's centre and fits a circle to it, so the offset of the rim's
centre from the calibration's can be reported. Pixels are ``(row, col)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Callable, Sequence

import numpy as np

from ifmi.geometry.camera import OcamModel, pixel_offsets_from_sensor, pixels_from_sensor
from ifmi.spectral.panorama import denoised_gray_from_image  # pixels are judged lit as for the radius band

__all__ = ["RimCircle", "model_images_a_rim", "rim_circle_from_frames"]

# Rays from the calibration's centre along which the rim is looked for, and their radial step (px).
_RIM_AZIMUTHS = 360
_RIM_STEP_PX = 0.5
# A ray counts as seeing the rim when at least this many dark samples inside the image follow
# its last lit sample (the image border is not a rim).
_DARK_SAMPLES_AFTER = 4
# Circle fit: RANSAC over three-point circles (this many, seeded), inliers within this distance
# (px) of the circle. The rim must be a circle along at least this share of all rays, with no
# gap between them wider than this (degrees, about the circle's centre), or the circle is not
# pinned down. Dark objects at the rim only pull edge points inward; a rim clipped by the image
# sides (a Kalibr camera's) leaves arcs all round; an image warped from a tilted view (omnisim
# warp) has a lit region that is no circle about the centre, and a circle RANSAC finds in it
# covers one side only (measured gaps 196-204 degrees where the centre came out wrong).
_FIT_SAMPLES = 200
_FIT_SEED = 0
_INLIER_PX = 1.0
_MIN_CIRCLE_SHARE = 0.25
_MAX_GAP_DEG = 150.0


@dataclass(frozen=True)
class RimCircle:
    """The mirror's outer rim fitted in a sequence's frames.

    Attributes
    ----------
    centre_offset_px : (float, float)
        ``(row, col)`` of the rim's centre minus the calibration's centre,
        pixels (through the calibration's affine part).
    radius_px : float
        Rim radius in the plane of :func:`_centre_plane`, pixels.
    rms_px : float
        RMS radial distance of the kept edge points from the circle, pixels.
    n_rays : int
        Rays (of :data:`_RIM_AZIMUTHS`) that saw the rim.
    n_kept : int
        Edge points within 1 px of the circle.
    """

    centre_offset_px: tuple[float, float]
    radius_px: float
    rms_px: float
    n_rays: int
    n_kept: int

    @property
    def offset_px(self) -> float:
        """Distance of the rim's centre from the calibration's, pixels."""
        return float(np.hypot(*self.centre_offset_px))


def _lit_mask(frames: Sequence[np.ndarray], dark_level: float) -> np.ndarray:
    """(H, W) bool: pixels brighter than ``dark_level`` in at least half of the median-filtered frames."""
    return np.mean([denoised_gray_from_image(image) > dark_level for image in frames], axis=0) >= 0.5


def _centre_plane(model) -> tuple[Callable, Callable] | None:
    """``(pixels_from_plane, pixel_offsets_from_plane)`` of the plane the rim is a circle in, or None.

    OCamCalib: its sensor plane about the distortion centre (affine part
    included). Kalibr models: pixel offsets from the principal point scaled
    by the focal lengths to their mean, ``(row - pv, col - pu) * f / (fv, fu)``.
    Models without a principal point (equirectangular) image no rim.
    """
    if isinstance(model, OcamModel):
        return partial(pixels_from_sensor, model), partial(pixel_offsets_from_sensor, model)
    if not hasattr(model, "principal_point"):
        return None
    (fu, fv), (pu, pv) = model.focal, model.principal_point
    per_unit = np.array([fv, fu]) / (0.5 * (fu + fv))  # (row, col) pixels per plane unit
    centre = np.array([pv, pu])

    def offsets(plane):
        return np.asarray(plane, dtype=np.float64) * per_unit

    return (lambda plane: centre + offsets(plane)), offsets


def model_images_a_rim(model) -> bool:
    """Whether ``model`` has a centre a rim can be judged about (OCamCalib or a Kalibr model
    with a principal point; not the equirectangular model)."""
    return _centre_plane(model) is not None


def _rim_edges(pixels_from_plane: Callable, lit: np.ndarray) -> np.ndarray:
    """(K, 2) plane points of the last lit sample along each ray (from the centre) that sees the rim."""
    height, width = lit.shape
    radii = np.arange(0.0, float(np.hypot(height, width)), _RIM_STEP_PX)
    phi = np.linspace(0.0, 2.0 * np.pi, _RIM_AZIMUTHS, endpoint=False)
    sensor = np.stack([radii[:, None] * np.cos(phi), radii[:, None] * np.sin(phi)], axis=-1)
    pixels = pixels_from_plane(sensor)  # (radii, azimuths, 2) as (row, col)
    inside = ((pixels[..., 0] >= 0) & (pixels[..., 0] <= height - 1)
              & (pixels[..., 1] >= 0) & (pixels[..., 1] <= width - 1))
    rows = np.clip(np.rint(pixels[..., 0]).astype(int), 0, height - 1)
    cols = np.clip(np.rint(pixels[..., 1]).astype(int), 0, width - 1)
    seen = lit[rows, cols] & inside
    edges = []
    for a in np.flatnonzero(seen.any(axis=0)):
        last = int(np.flatnonzero(seen[:, a])[-1])
        if inside[last + 1:, a].sum() >= _DARK_SAMPLES_AFTER:
            # The rim lies between the last lit sample and the next: half a step out.
            edges.append(sensor[last, a] * (1.0 + 0.5 * _RIM_STEP_PX / max(radii[last], _RIM_STEP_PX)))
    return np.asarray(edges, dtype=np.float64).reshape(-1, 2)


def _circle_through(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (2,) and radius of the least-squares circle ``x^2 + y^2 + D x + E y + F = 0`` of (K, 2) points."""
    x, y = points[:, 0], points[:, 1]
    design = np.stack([x, y, np.ones_like(x)], axis=1)
    (d, e, f), *_ = np.linalg.lstsq(design, -(x * x + y * y), rcond=None)
    centre = np.array([-d / 2.0, -e / 2.0])
    return centre, float(np.sqrt(max(centre @ centre - f, 0.0)))


def _ransac_circle(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre (2,), radius and inlier mask (K,) of the circle most of the (K, 2) points lie on.

    Circles through three points drawn with a fixed seed are scored by
    their points within ``_INLIER_PX``; the best is refitted on its inliers.
    """
    rng = np.random.default_rng(_FIT_SEED)
    best = np.zeros(len(points), dtype=bool)
    for _ in range(_FIT_SAMPLES):
        sample = points[rng.choice(len(points), 3, replace=False)]
        centre, radius = _circle_through(sample)
        inliers = np.abs(np.linalg.norm(points - centre, axis=1) - radius) < _INLIER_PX
        if inliers.sum() > best.sum():
            best = inliers
    centre, radius = _circle_through(points[best])
    inliers = np.abs(np.linalg.norm(points - centre, axis=1) - radius) < _INLIER_PX
    if inliers.sum() >= 3:
        centre, radius = _circle_through(points[inliers])
    return centre, radius, inliers


def _largest_gap_deg(points: np.ndarray, centre: np.ndarray) -> float:
    """Widest azimuth range (degrees, about ``centre``) with none of the (K, 2) ``points``."""
    azimuths = np.sort(np.degrees(np.arctan2(points[:, 1] - centre[1], points[:, 0] - centre[0])) % 360.0)
    return float(np.max(np.diff(np.append(azimuths, azimuths[0] + 360.0))))


def rim_circle_from_frames(model: OcamModel, frames: Sequence[np.ndarray], *,
                           dark_level: float) -> RimCircle | None:
    """Fit the mirror's outer rim in ``frames`` and give its centre relative to the calibration's.

    A pixel is lit when brighter than ``dark_level`` (after a 5 px median
    filter) in at least half of the frames, so a dark object crossing the
    rim in one frame does not move it. Along 360 rays from the
    calibration's centre (in the plane of :func:`_centre_plane`), the rim
    is the last lit sample followed by dark samples inside the image; a
    circle is fitted to these points by RANSAC (fixed seed: the same
    frames give the same circle) and refitted on those within 1 px.

    Parameters
    ----------
    model : OcamModel or Kalibr camera model
    frames : sequence of (H, W) or (H, W, 3) uint8 ndarray
        A few frames of the sequence, indexed ``[row, col]``, the size the
        calibration names.
    dark_level : float, keyword-only
        Gray level (0-255) at or below which a pixel is dark.

    Returns
    -------
    RimCircle or None
        None when the rim is a circle along fewer than a quarter of the rays
        or leaves a gap of over 150 degrees: the image is lit up to its
        border (a fisheye image filling the frame), objects darker than
        ``dark_level`` lie along much of the rim, or the lit region is no
        circle about the centre (a view warped from a tilted one). Also
        None for a model without a centre (equirectangular) or without
        frames.

    Raises
    ------
    ValueError
        A frame whose size is not the calibration's.
    """
    if not len(frames):
        return None
    for k, image in enumerate(frames):
        if np.shape(image)[:2] != tuple(model.size):
            raise ValueError(f"frames[{k}]: expected {model.size[0]}x{model.size[1]} pixels (the calibration's "
                             f"size), got shape {np.shape(image)}")
    plane = _centre_plane(model)
    if plane is None:
        return None
    edges = _rim_edges(plane[0], _lit_mask(frames, dark_level))
    if len(edges) < _MIN_CIRCLE_SHARE * _RIM_AZIMUTHS:
        return None
    centre, radius, inliers = _ransac_circle(edges)
    if inliers.sum() < _MIN_CIRCLE_SHARE * _RIM_AZIMUTHS or _largest_gap_deg(edges[inliers], centre) > _MAX_GAP_DEG:
        return None
    residual = np.linalg.norm(edges[inliers] - centre, axis=1) - radius
    offset = plane[1](centre)
    return RimCircle(centre_offset_px=(float(offset[0]), float(offset[1])), radius_px=radius,
                     rms_px=float(np.sqrt(np.mean(residual ** 2))), n_rays=len(edges),
                     n_kept=int(inliers.sum()))
