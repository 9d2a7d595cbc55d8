"""Physical mirror mode: an orthographic camera looking at a paraboloid mirror mesh.

A convex paraboloid ``z = (rho**2 - h**2) / (2 h)`` (focus at the origin,
metric ``h``) reflects the parallel rays of an orthographic camera looking
along +z into rays whose backward extensions meet at the focus, so its image
obeys :func:`ifmi.geometry.camera.paracatadioptric_model` exactly. This mode renders
that physical setup (mirror as a finely tessellated mesh with analytic
normals and a perfect conductor BSDF) to cross-check the ``omnicam`` sensor.

The mirror is ``mirror_scale_m`` metres per image pixel, so it should be
small against the scene (the sensor's single viewpoint is the focus, while
physical rays leave from the mirror surface). The path tracer needs one more
bounce than with the sensor for the same lighting.
"""

from __future__ import annotations

import numpy as np

from ifmi.geometry.camera import pixel_offsets_from_sensor

__all__ = ["horizon_radius_from_model", "mirror_scene_entries"]


def horizon_radius_from_model(model, *, tolerance: float = 1e-9) -> float:
    """Horizon radius ``h`` (pixels) of a paracatadioptric model ``pol = (-h/2, 0, 1/(2h))``.

    Raises
    ------
    ValueError
        If the direct polynomial is not of that form.
    """
    pol = np.asarray(model.pol, dtype=np.float64)
    if len(pol) < 3 or np.any(np.abs(pol[3:]) > tolerance) or abs(pol[1]) > tolerance or pol[0] >= 0:
        raise ValueError(f"mirror mode needs a paraboloid model pol = (-h/2, 0, 1/(2h)), got {tuple(pol)}")
    h = -2.0 * pol[0]
    if abs(pol[2] * 2.0 * h - 1.0) > 1e-6:
        raise ValueError(f"mirror mode needs pol[2] = 1/(2h) = {1 / (2 * h)}, got {pol[2]}")
    return float(h)


def _paraboloid_mesh(h: float, radius: float, *, rings: int, sectors: int):
    """Mirror surface in the camera frame (pixel units), normals facing the camera (down)."""
    rho = radius * np.sqrt(np.linspace(0.0, 1.0, rings + 1))[1:]
    phi = np.linspace(0.0, 2.0 * np.pi, sectors, endpoint=False)
    rr, pp = np.meshgrid(rho, phi, indexing="ij")
    x, y = rr * np.cos(pp), rr * np.sin(pp)
    ring_pts = np.stack([x, y, (rr ** 2 - h ** 2) / (2 * h)], axis=-1).reshape(-1, 3)
    positions = np.concatenate([[[0.0, 0.0, -h / 2.0]], ring_pts])
    normals = np.stack([positions[:, 0] / h, positions[:, 1] / h, -np.ones(len(positions))], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    idx = 1 + np.arange(rings * sectors).reshape(rings, sectors)
    nxt = np.roll(idx, -1, axis=1)
    fan = np.stack([np.zeros(sectors, int), nxt[0], idx[0]], axis=1)
    a, b, c, d = idx[:-1], nxt[:-1], nxt[1:], idx[1:]
    quads = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return positions, normals, np.concatenate([fan, quads])


def mirror_scene_entries(model, *, to_world: np.ndarray, radius_max: float, spp: int,
                         mirror_scale_m: float = 1e-4, sampler: str = "multijitter",
                         rings: int = 384, sectors: int = 768, mi=None) -> dict:
    """Scene-dict entries ``sensor`` (orthographic) and ``mirror`` (conductor mesh).

    Parameters
    ----------
    model : OcamModel
        A paracatadioptric model (see :func:`ifmi.geometry.camera.paracatadioptric_model`);
        its centre and affine part place the mirror in the image.
    to_world : (4, 4) ndarray, keyword-only
        Camera-to-world pose of the model's camera frame (z = mirror axis).
    radius_max : float, keyword-only
        Mirror rim radius in sensor-plane pixels.
    spp : int, keyword-only
        Samples per pixel.
    mirror_scale_m : float, keyword-only
        Metres per pixel on the mirror.
    sampler : str, keyword-only
        Mitsuba sampler plugin.
    rings, sectors : int, keyword-only
        Tessellation of the mirror.
    mi : module
        Imported Mitsuba with its variant set.
    """
    h = horizon_radius_from_model(model)
    height, width = model.size
    # Image offsets from the centre are the affine matrix times sensor points; its columns are
    # the offsets of the sensor's unit vectors.
    m_inv = np.linalg.inv(pixel_offsets_from_sensor(model, np.eye(2)).T)
    s = float(mirror_scale_m)
    # Orthographic film -> local (x_l, y_l) = -(2/W) (col - (W-1)/2, row - (H-1)/2).
    film_to_pixels = np.array([[0.0, -width / 2.0], [-width / 2.0, 0.0]])  # (x_l, y_l) -> (d_row, d_col)
    offset = np.array([(height - 1) / 2.0 - model.center[0], (width - 1) / 2.0 - model.center[1]])
    local_to_camera = np.eye(4)
    local_to_camera[:2, :2] = s * m_inv @ film_to_pixels
    local_to_camera[:2, 3] = s * m_inv @ offset
    local_to_camera[2, 3] = -s * h  # the film plane sits below the mirror's vertex (z = -h/2)
    pose = np.asarray(to_world, dtype=np.float64)
    sensor = {
        "type": "orthographic",
        "near_clip": 1e-6, "far_clip": 1e6,
        "to_world": mi.ScalarTransform4f((pose @ local_to_camera).tolist()),
        "film": {"type": "hdrfilm", "width": int(width), "height": int(height),
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        "sampler": {"type": sampler, "sample_count": int(spp)},
    }
    positions, normals, faces = _paraboloid_mesh(h, radius_max, rings=rings, sectors=sectors)
    positions = positions * s @ pose[:3, :3].T + pose[:3, 3]
    normals = normals @ pose[:3, :3].T
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "conductor", "material": "none"})
    mesh = mi.Mesh("mirror", len(positions), len(faces), has_vertex_normals=True, props=props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(positions.astype(np.float32).ravel())
    params["vertex_normals"] = mi.Float(normals.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    return {"sensor": sensor, "mirror": mesh}
