"""Per-pixel ground truth beside the images: depth along the ray and surface normals.

``depth/NNNNNN.npy`` is float32 (H, W), indexed (row, col): the distance in
metres from the camera centre to the first surface along the ray of the pixel
centre, NaN where that ray hits nothing (or lies outside the mirror band).
``normal/NNNNNN.npy`` is float32 (H, W, 3): the unit shading normal of that
surface in the camera frame (x along rows, y along columns, z the mirror
axis), NaN where there is no surface.

Both come from one extra pass with Mitsuba's ``aov`` integrator: one ray per
pixel, through the pixel centre (stratified sampler, 1 spp, no jitter; with
the box filter the pixel's value is that ray's), so depth is never averaged
across an edge. The ray is traced at its row's mid-exposure time and the
normal is expressed in the camera frame of that time: without rolling
shutter the frame's ground-truth pose, with it the row's pose listed in
``rolling_shutter/NNNNNN.txt``. Hence ``depth * rays_from_pixels(pixel)``,
carried by that pose, is the surface point.
"""

from __future__ import annotations

import io

import numpy as np

__all__ = ["AOV_NAMES", "aov_names_from_text", "aov_integrator_dict", "aov_sensor_dict",
           "depth_normal_from_aov", "npy_bytes"]

AOV_NAMES = ("depth", "normal")


def aov_names_from_text(text) -> tuple:
    """AOV names from ``"depth,normal"`` (or a sequence of names), in :data:`AOV_NAMES` order.

    An empty (or blank) text or sequence means no AOVs; otherwise every
    name must be known, non-empty and given once.

    Raises
    ------
    ValueError
        An unknown name (the message lists the known ones), an empty name
        (``"depth,"``, ``",,"``) or a name given twice (``"depth,depth"``);
        the message says what was expected and what was given.
    """
    if isinstance(text, str):
        given = text if text.strip() else ""
        parts = [part.strip() for part in text.split(",")] if given else []
    else:
        parts = [str(part).strip() for part in (text or ())]
        given = ",".join(parts)
    known = ", ".join(AOV_NAMES)
    if "" in parts:
        raise ValueError(f"expected comma-separated AOV names from {known}, got an empty name in {given!r}")
    unknown = sorted(set(parts) - set(AOV_NAMES))
    if unknown:
        raise ValueError(f"expected AOV names from {known}, got {', '.join(unknown)}")
    twice = sorted({part for part in parts if parts.count(part) > 1})
    if twice:
        raise ValueError(f"expected each AOV name once, got {', '.join(twice)} more than once in {given!r}")
    return tuple(name for name in AOV_NAMES if name in parts)


def aov_integrator_dict() -> dict:
    """Mitsuba ``aov`` integrator writing distance along the ray and the world shading normal."""
    return {"type": "aov", "aovs": "dd:depth,nn:sh_normal"}


def aov_sensor_dict(config, mi) -> dict:
    """The omni sensor of ``config`` for the AOV pass: one ray per pixel centre, at mid-exposure."""
    from .capture import sensor_timing_props
    from .sensor import sensor_dict

    cam = config.camera
    sensor = sensor_dict(cam.model, to_world=np.eye(4), radius_min=cam.radius_min,
                         radius_max=cam.radius_max, spp=1, sampler="stratified", mi=mi,
                         timing=sensor_timing_props(config.capture, mid_exposure=True))
    # One stratum per pixel without jitter: the single sample sits at the pixel centre.
    sensor["sampler"]["jitter"] = False
    return sensor


def depth_normal_from_aov(image: np.ndarray, row_rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth and camera-frame normals from the AOV pass.

    Parameters
    ----------
    image : (H, W, 4) ndarray
        AOV render: distance along the ray (0 where no hit), world normal (x, y, z).
    row_rotations : (H, 3, 3) ndarray
        Camera-to-world rotation of each row at its AOV time.

    Returns
    -------
    depth : (H, W) ndarray
        float32 metres, NaN where no surface.
    normal : (H, W, 3) ndarray
        float32 unit normals in the camera frame, NaN where no surface.
    """
    image = np.asarray(image, dtype=np.float64)
    distance, world = image[..., 0], image[..., 1:4]
    length = np.linalg.norm(world, axis=-1)
    hit = (distance > 0) & (length > 0)
    camera = np.einsum("rji,rcj->rci", np.asarray(row_rotations, dtype=np.float64), world)
    with np.errstate(invalid="ignore", divide="ignore"):
        camera = camera / np.linalg.norm(camera, axis=-1, keepdims=True)
    depth = np.where(hit, distance, np.nan).astype(np.float32)
    normal = np.where(hit[..., None], camera, np.nan).astype(np.float32)
    return depth, normal


def npy_bytes(array: np.ndarray) -> bytes:
    """The ``.npy`` file bytes of ``array`` (the same array always gives the same bytes)."""
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ascontiguousarray(array), allow_pickle=False)
    return buffer.getvalue()
