"""One omni image turned into a pure-rotation sequence with exact ground truth.

A rotation of a central camera changes no ray's content, only which pixel
sees it, so one sharp omni image (a real photo, or a high-spp render) fixes
every view of the same camera turned about its centre. Frame ``k`` with
orientation ``R_0k`` is warped backward through the calibration: for every
output pixel ``p``::

    r_k = rays_from_pixels(p),   r_0 = R_0k r_k,   q = pixels_from_rays(r_0),
    frame_k(p) = source(q)

with the source image as frame 0. Pixels whose own ray, or whose source
pixel, lies outside the region of the source that images the scene, or too
close to the image edge for the interpolation kernel, are black. That
region is, for an OCamCalib calibration (``calib_results.txt``), the mirror
band of sensor radii detected on the image (:func:`ifmi.spectral.panorama.radius_band`,
with the calibration's band as fallback); for a Kalibr ``camera.yaml``
(fisheyes, pinhole, equirectangular; :mod:`ifmi.geometry.camera_models`), the lit
band of angles about the camera's panorama axis
(:func:`ifmi.spectral.panorama.lit_off_axis_band`) inside the model's valid region, so
a fisheye's black surround stays black and fixed in the image.

The random walk turns about the calibration's z axis for an OCamCalib
model (the mirror axis) and about the panorama axis for the others (the
optical axis of a fisheye, up for an equirectangular camera), so its yaw is
the heading in both; the ground truth is written in the camera's own frame.
An equirectangular image's columns wrap around.

With a rolling shutter (``WarpSettings.rolling_shutter``), row ``r`` of
frame ``k`` is warped through the walk's orientation at its own time ``k +
rolling_shutter * (r - (H - 1) / 2) / (H - 1)``: the walk is smooth in time,
and the middle row holds the ground-truth pose, as ``ifmi estimate
--rolling-shutter`` assumes.

Interpolation: cubic B-spline (``scipy.ndimage.map_coordinates`` with
``order=3`` and its prefilter), which interpolates the samples exactly and
takes the sub-pixel position in floating point (OpenCV's ``remap``
quantises it to 1/32 pixel). Its error is measured by warping a frame back
onto frame 0 with the ground truth (two interpolations); see
:func:`round_trip_error` and the README.

Importing this module does not import Mitsuba.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.spatial.transform import Rotation

from ifmi.geometry.camera import (OcamModel, angles_from_axis, angular_pixel_size, pixels_from_rays, radius_from_pixels,
                         rays_from_pixels)
from ifmi.errors import InputError
from ifmi.io.atomic import atomic_write_bytes, atomic_write_json
from ifmi.io.camera_file import camera_file_name, read_camera
from ifmi.io.dataset import read_image
from ifmi.io.provenance import package_versions
from ifmi.io.tum import write_tum
from ifmi.errors import OptionError
from ifmi.geometry.row_timing import row_time_offsets
from ifmi.geometry.trajectory import Trajectory
from ifmi.spectral.panorama import PanoramaConfig, gray_from_image, lit_off_axis_band, panorama_axis_rotation, radius_band

from .config import MAX_FRAMES
from .renderer import META_FORMAT, encode_png, open_output_folder, pending_images, write_row_poses

__all__ = ["WarpSettings", "WarpResult", "rotation_walk", "valid_source_band", "warp_image",
           "round_trip_error", "rotations_in_camera_frame", "warp_dataset"]

# Version of the warping procedure; part of an output folder's identity.
WARP_VERSION = 1
# Pixels kept clear of the image edge: the cubic B-spline reads 2 samples on each side.
_EDGE_PX = 2.0


@dataclass(frozen=True)
class WarpSettings:
    """Motion of a warped sequence.

    Attributes
    ----------
    frames : int
        Number of frames (frame 0 is the source image).
    seed : int
        Seed of the random motion.
    max_step_deg : float
        Largest rotation between consecutive frames, degrees.
    max_tilt_deg : float
        Bound of roll and pitch, degrees (the mirror band covers a limited
        elevation range; a large tilt turns most of it out of view).
    rolling_shutter : float
        Read-out of the output frames as a fraction of the frame interval,
        in ``[0, 1]``: row ``r`` of frame ``k`` sees the camera at time
        ``k + rolling_shutter * (r - (H - 1) / 2) / (H - 1)`` of the
        (continuous) walk, so the middle row holds the ground-truth pose
        (:mod:`ifmi.backend.rolling_shutter`'s convention). 0: a global shutter.
    """

    frames: int = 60
    seed: int = 0
    max_step_deg: float = 3.0
    max_tilt_deg: float = 10.0
    rolling_shutter: float = 0.0

    def __post_init__(self) -> None:
        """Raises :class:`ifmi.errors.OptionError` naming the first field out of range (NaN included)."""
        checks = (("frames", 1 <= self.frames <= MAX_FRAMES, f"1 <= frames <= {MAX_FRAMES} (as a render)"),
                  ("seed", self.seed >= 0, "seed >= 0"),
                  ("max_step_deg", 0 < self.max_step_deg <= 90, "0 < max_step_deg <= 90"),
                  ("max_tilt_deg", 0 <= self.max_tilt_deg <= 45, "0 <= max_tilt_deg <= 45"),
                  ("rolling_shutter", 0 <= self.rolling_shutter <= 1,
                   "0 <= rolling_shutter <= 1 (a fraction of the frame interval)"))
        for name, ok, expected in checks:
            if not ok:
                raise OptionError(name, f"expected {expected}, got {getattr(self, name)}")

    def identity(self) -> dict:
        """The settings that make an output folder: a global shutter is left out, as before it existed."""
        values = asdict(self)
        if values["rolling_shutter"] == 0:
            del values["rolling_shutter"]
        return values


@dataclass(frozen=True)
class WarpResult:
    """Outcome of :func:`warp_dataset`: folder, frame count, frames written in this call."""

    out_dir: str
    frames: int
    written: int


def rotation_walk(settings: WarpSettings, times: np.ndarray | None = None) -> np.ndarray:
    """Smooth random orientations ``R_0k`` (identity first), steps at most ``max_step_deg``.

    Yaw turns at a constant rate of 40 to 60 % of the largest step; roll and
    pitch each follow a sinusoid within ``+-max_tilt_deg`` whose rate is at
    most a quarter of the largest step, so a step never exceeds the bound.
    The walk is a smooth function of time, so it can be read between frames.

    Parameters
    ----------
    settings : WarpSettings
    times : (N,) ndarray, optional
        Times in frame intervals (default: the frames, ``0 .. frames - 1``).

    Returns
    -------
    (N, 3, 3) ndarray
        The orientation at each time (``(frames, 3, 3)`` by default).
    """
    rng = np.random.default_rng(settings.seed)
    step = np.radians(settings.max_step_deg)
    tilt = np.radians(settings.max_tilt_deg)
    t = np.arange(settings.frames, dtype=np.float64) if times is None else np.asarray(times, dtype=np.float64)
    yaw = rng.uniform(0.4, 0.6) * step * rng.choice([-1.0, 1.0]) * t
    angles = [yaw]
    for _ in range(2):
        # tilt * rate <= step / 4: the sinusoid's steepest step stays within a quarter of the bound.
        rate = rng.uniform(0.5, 1.0) * min(0.25 * step / tilt, 0.5) if tilt > 0 else 0.0
        angles.append(tilt * rng.choice([-1.0, 1.0]) * np.sin(rate * t))
    return Rotation.from_euler("ZYX", np.stack(angles, axis=1)).as_matrix()


def _pixel_angle(model) -> float:
    """Median angle (radians) one pixel subtends over a coarse grid of the model's valid pixels."""
    rows = np.linspace(0, model.height - 1, 33)
    cols = np.linspace(0, model.width - 1, 33)
    grid = np.stack(np.meshgrid(rows, cols, indexing="ij"), axis=-1).reshape(-1, 2)
    return float(np.nanmedian(angular_pixel_size(model, grid[model.valid_pixels(grid)])))


def valid_source_band(model, image: np.ndarray) -> tuple[float, float]:
    """Band ``(inner, outer)`` of the source image that images the scene.

    Sensor radius in pixels for an :class:`~ifmi.geometry.camera.OcamModel` (the
    mirror band, :func:`ifmi.spectral.panorama.radius_band`); off-axis angle in
    radians about the panorama axis for the other models (the lit band,
    :func:`ifmi.spectral.panorama.lit_off_axis_band`, kept ``_EDGE_PX`` pixels inside
    its edges for the interpolation kernel).

    Raises
    ------
    ValueError
        A non-OCamCalib image with no lit ring.
    """
    if isinstance(model, OcamModel):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the fallback to the calibration's band is fine here
            return radius_band(model, gray_from_image(image), config=PanoramaConfig(min_radius_fraction=0.0))
    return lit_off_axis_band(model, gray_from_image(image), margin_rad=_EDGE_PX * _pixel_angle(model))


def _shrunk(model, band: tuple[float, float], pixels: float) -> tuple[float, float]:
    """``band`` moved ``pixels`` inward at each edge that is not the axis or its opposite pole."""
    if isinstance(model, OcamModel):
        return band[0] + pixels, band[1] - pixels
    step = pixels * _pixel_angle(model)
    return (band[0] + step if band[0] > 0 else 0.0), (band[1] - step if band[1] < np.pi else np.pi)


def _wraps(model) -> bool:
    return bool(getattr(model, "wraps_columns", False))


def _inside(model, pixels: np.ndarray, band: tuple[float, float], *, rays: np.ndarray | None = None) -> np.ndarray:
    """Pixels ``(..., 2)`` inside the image (by the kernel's reach) and the source ``band``.

    ``rays`` are the pixels' rays when the caller has them already (other
    models than OCamCalib test their angle from the axis), saving a lift.
    """
    rows, cols = pixels[..., 0], pixels[..., 1]
    with np.errstate(invalid="ignore"):
        inside = (rows >= _EDGE_PX) & (rows <= model.height - 1 - _EDGE_PX)
        if not _wraps(model):
            inside &= (cols >= _EDGE_PX) & (cols <= model.width - 1 - _EDGE_PX)
        if isinstance(model, OcamModel):
            radius = radius_from_pixels(model, pixels)
            return inside & (radius >= band[0]) & (radius <= band[1])
        inside &= np.isfinite(pixels).all(axis=-1)
        inside[inside] &= model.valid_pixels(pixels[inside])
        axis = getattr(model, "panorama_axis", model.optical_axis)
        if rays is None:
            rays = rays_from_pixels(model, np.where(inside[..., None], pixels, 0.0))
        angle = angles_from_axis(rays, axis)
        return inside & (angle >= band[0]) & (angle <= band[1])


def warp_image(source: np.ndarray, model, rotation: np.ndarray, *,
               band: tuple[float, float]) -> np.ndarray:
    """The source seen by the camera turned by ``rotation`` (``R_0k``), black outside the valid region.

    Parameters
    ----------
    source : (H, W) or (H, W, 3) uint8 ndarray
        Frame 0, of the calibration's size.
    model : OcamModel or CameraModel
    rotation : (3, 3) or (H, 3, 3) ndarray
        ``R_0k``: frame-k directions to frame-0 directions, camera frame; or
        one per output row (a rolling shutter, row 0 first).
    band : (float, float), keyword-only
        Valid band of the source (:func:`valid_source_band`).

    Returns
    -------
    ndarray of uint8, the shape of ``source``
    """
    h, w = model.size
    grid = np.stack(np.mgrid[0:h, 0:w], axis=-1).astype(np.float64)
    grid_rays = rays_from_pixels(model, grid)
    rotation = np.asarray(rotation, dtype=np.float64)
    if rotation.shape == (h, 3, 3):
        where = pixels_from_rays(model, np.einsum("rij,rcj->rci", rotation, grid_rays))
    elif rotation.shape == (3, 3):
        where = pixels_from_rays(model, grid_rays @ rotation.T)
    else:
        raise ValueError(f"expected a (3, 3) rotation or one per row, ({h}, 3, 3), got {rotation.shape}")
    valid = _inside(model, grid, band, rays=grid_rays) & _inside(model, where, band)
    where = np.where(valid[..., None], where, 0.0)
    channels = source[..., None] if source.ndim == 2 else source
    pad = 0
    if _wraps(model):
        # Columns of a 360-degree image wrap around: sample a copy padded with the far side.
        pad = int(np.ceil(_EDGE_PX)) + 1
        channels = np.concatenate([channels[:, -pad:], channels, channels[:, :pad]], axis=1)
        where[..., 1] = np.mod(where[..., 1] + 0.5, w) - 0.5
    coords = [where[..., 0], where[..., 1] + pad]
    out = np.zeros(source.shape[:2] + channels.shape[2:], dtype=np.float64)
    for c in range(channels.shape[-1]):
        out[..., c] = map_coordinates(channels[..., c].astype(np.float64), coords, order=3, mode="nearest")
    out[~valid] = 0.0
    out = np.clip(np.round(out), 0, 255).astype(np.uint8)
    return out[..., 0] if source.ndim == 2 else out


def _comparable_pixels(model, band: tuple[float, float]) -> np.ndarray:
    """(H, W) mask of the source pixels a round trip compares: inside the image and ``band`` by
    three kernel reaches (:func:`round_trip_error`)."""
    h, w = model.size
    grid = np.stack(np.mgrid[0:h, 0:w], axis=-1).astype(np.float64)
    return _inside(model, grid, _shrunk(model, band, 3 * _EDGE_PX))


def round_trip_error(source: np.ndarray, frame: np.ndarray, model, rotation: np.ndarray, *,
                     band: tuple[float, float]) -> tuple[float, float]:
    """Frame ``k`` warped back onto frame 0 with its ground truth, compared with the source.

    Returns
    -------
    rms : float
        RMS gray-level difference over pixels valid in both, 8-bit levels.
    fraction : float
        Share of the source's band pixels that are compared.
    """
    back = warp_image(frame, model, np.asarray(rotation).T, band=band).astype(np.float64)
    h, w = model.size
    grid = np.stack(np.mgrid[0:h, 0:w], axis=-1).astype(np.float64)
    # Compare where frame k's pixel is valid: away from its black border by the kernel's reach.
    rays = rays_from_pixels(model, grid) @ np.asarray(rotation, dtype=np.float64)
    in_k = pixels_from_rays(model, rays)
    shrunk = _shrunk(model, band, 3 * _EDGE_PX)
    valid = _inside(model, grid, shrunk) & _inside(model, in_k, shrunk)
    a = gray_from_image(source).astype(np.float64)
    b = gray_from_image(np.clip(back, 0, 255).astype(np.uint8)).astype(np.float64)
    band_pixels = _inside(model, grid, band).sum()
    return float(np.sqrt(np.mean((a[valid] - b[valid]) ** 2))), float(valid.sum() / max(band_pixels, 1))


def rotations_in_camera_frame(model, walk: np.ndarray) -> np.ndarray:
    """Orientations ``R_0k`` (K, 3, 3) of a walk about z, turned about ``model``'s panorama axis.

    An OCamCalib model keeps its own z (the mirror axis, the walk
    unchanged); other models turn about :func:`ifmi.spectral.panorama.panorama_axis_rotation`.
    """
    if isinstance(model, OcamModel):
        return walk
    axis = panorama_axis_rotation(model)
    return axis @ walk @ axis.T


def _frame_rows(model, settings: WarpSettings, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Time (H,) in frame intervals and orientation ``R_0r`` (H, 3, 3) of every row of frame ``k``.

    One frame at a time: all frames' rows at once grow with frames x rows (a million frames of
    480 rows are 35 GB of matrices).
    """
    height = model.size[0]
    times = k + row_time_offsets(np.arange(height), height=height, readout=settings.rolling_shutter)
    return times, rotations_in_camera_frame(model, rotation_walk(settings, times))


def _band_text(model, band: tuple[float, float]) -> str:
    """``band`` for a message: sensor radii in pixels, or angles from the panorama axis in degrees."""
    if isinstance(model, OcamModel):
        return f"mirror band (radius {band[0]:.1f}..{band[1]:.1f} px)"
    return f"lit band ({np.degrees(band[0]):.1f}..{np.degrees(band[1]):.1f} degrees from the panorama axis)"


def _constant_value(pixels: np.ndarray) -> str | None:
    """The one value of ``pixels`` ((N,) gray or (N, 3) colour) in words, or None when they differ."""
    if not len(pixels) or np.any(pixels != pixels[0]):
        return None
    value = np.atleast_1d(pixels[0])
    if not value.any():
        return "0 (black)"
    return f"gray level {int(value[0])}" if len(value) == 1 else f"colour {tuple(int(v) for v in value)}"


def _usable_source_band(image_path: Path, model, source: np.ndarray) -> tuple[float, float]:
    """The source's valid band (:func:`valid_source_band`), refused when it cannot make a sequence.

    Raises
    ------
    InputError
        Named ``image_path``: no lit band (a non-OCamCalib model), a band too thin or an
        image too small for a round trip, or a band without texture: every pixel in it holds
        one value (a black or flat image), so every rotation gives the same frame and the
        ground truth could not be seen in the frames.
    """
    try:
        band = valid_source_band(model, source)
    except ValueError as exc:
        raise InputError(image_path, str(exc)) from None
    if not _comparable_pixels(model, band).any():
        raise InputError(image_path, f"image of {model.height}x{model.width} px too small to warp: no "
                                     f"pixel of its valid band lies {3 * _EDGE_PX:g} px inside the band "
                                     "and the image edges (expected a larger image)")
    h, w = model.size
    grid = np.stack(np.mgrid[0:h, 0:w], axis=-1).astype(np.float64)
    value = _constant_value(source[_inside(model, grid, band)])
    if value is not None:
        raise InputError(image_path, f"no texture: every pixel of its {_band_text(model, band)} is {value}, so "
                                     "every rotation gives the same frame (expected an image with detail there)")
    return band


def warp_dataset(image_path, calib_path, out_dir, *, settings: WarpSettings = WarpSettings(),
                 progress: bool = True) -> WarpResult:
    """Write a DATASET folder: the source warped through ``settings.frames`` orientations.

    Writes the calibration (the given file's bytes, as ``calib_results.txt``
    or ``camera.yaml`` by its format), ``images/NNNNNN.png``
    (gray or RGB like the source), ``groundtruth.txt`` (TUM, ``T_0k``, no
    translation) and ``meta.json`` (inputs' SHA-256, settings, measured
    round-trip error of the last frame, per-image SHA-256). With
    ``settings.rolling_shutter``, each output row is warped through its own
    time's orientation, ``rolling_shutter/NNNNNN.txt`` give every row's
    ``T_0r`` (listed with SHA-256 under ``rolling_shutter`` in ``meta.json``),
    and no round trip is measured. An interrupted run resumes; a folder
    holding anything else is refused.

    Raises
    ------
    InputError
        Unreadable image or calibration, an image whose size differs from
        the calibration's, an image too small for any pixel of its valid
        band to be compared after a round trip, an image without texture in
        its valid band (every pixel there one value: black or flat), or an
        output folder holding something else.
    """
    image_path, calib_path, out_dir = Path(image_path), Path(calib_path), Path(out_dir)
    model = read_camera(calib_path)
    source = read_image(image_path, size=model.size, gray=False)
    if source.ndim == 3 and source.shape[2] == 4:
        source = source[..., :3]
    identity = {
        "source_sha256": hashlib.sha256(image_path.read_bytes()).hexdigest(),
        "calib_sha256": hashlib.sha256(calib_path.read_bytes()).hexdigest(),
        "settings": settings.identity(), "format": META_FORMAT, "warp": WARP_VERSION,
    }
    band = _usable_source_band(image_path, model, source)
    meta = open_output_folder(out_dir, identity)
    rotations = rotations_in_camera_frame(model, rotation_walk(settings))
    meta.update({"source": str(image_path.resolve()), "settings": settings.identity(), "frames": settings.frames,
                 ("valid_band_px" if isinstance(model, OcamModel) else "valid_band_rad"): list(band), "interpolation": "cubic B-spline (scipy map_coordinates, order 3)",
                 "versions": package_versions(("numpy", "scipy", "opencv-python-headless", "omnisim-ifmi"))})
    atomic_write_bytes(out_dir / camera_file_name(model), calib_path.read_bytes())
    write_tum(out_dir / "groundtruth.txt",
              Trajectory(timestamps=np.arange(settings.frames, dtype=np.float64),
                         positions=np.zeros((settings.frames, 3)), rotations=rotations),
              header=f"omnisim warp of {image_path.name}: T_0k, pure rotation")
    rolling = settings.rolling_shutter > 0
    if rolling:
        meta["rolling_shutter"] = write_row_poses(
            out_dir, (Trajectory(timestamps=times, positions=np.zeros((len(times), 3)), rotations=rows)
                      for times, rows in (_frame_rows(model, settings, k) for k in range(settings.frames))),
            header=lambda k: f"omnisim warp of {image_path.name}, frame {k}: line r = row r, T_0r in camera 0 "
                             "of groundtruth.txt; time in frames")
    names = [f"{k:06d}.png" for k in range(settings.frames)]
    todo = pending_images(out_dir, meta, names)
    from tqdm import tqdm

    bar = tqdm(total=len(names), initial=len(names) - len(todo), disable=not progress, unit="frame",
               desc="warp")
    for k in todo:
        orientation = _frame_rows(model, settings, k)[1] if rolling else rotations[k]
        data = encode_png(warp_image(source, model, orientation, band=band))
        atomic_write_bytes(out_dir / "images" / names[k], data)
        meta["images"][names[k]] = hashlib.sha256(data).hexdigest()
        atomic_write_json(out_dir / "meta.json", meta)
        bar.update(1)
    bar.close()
    if settings.frames > 1 and not rolling:  # a rolling-shutter frame has no single back-warp
        last = read_image(out_dir / "images" / names[-1], size=model.size, gray=False)
        rms, fraction = round_trip_error(source, last, model, rotations[-1], band=band)
        meta["round_trip_last_frame"] = {"rms_gray_levels": rms, "compared_fraction": fraction}
    meta["images"] = dict(sorted(meta["images"].items()))
    meta["complete"] = len(meta["images"]) == len(names)
    atomic_write_json(out_dir / "meta.json", meta)
    return WarpResult(out_dir=str(out_dir), frames=settings.frames, written=len(todo))
