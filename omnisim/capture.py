"""How the omni camera captures a frame: motion blur, rolling shutter, vignetting.

Time model (times in frame intervals; frame ``k`` starts at time ``k``):

* The trajectory is sampled at the frame times: pose ``k`` of the trajectory is
  the camera at time ``k``. Between two samples the pose is interpolated,
  slerp for rotation and lerp for position (:func:`omnisim.motion.poses_at_times`).
* Row ``r`` of an ``H``-row image starts its exposure ``rolling_shutter * r / (H - 1)``
  after the frame time (rows are read top to bottom; row 0 at the frame
  time, the last row ``rolling_shutter`` later) and stays exposed for
  ``exposure``. Each ray of the row gets a time drawn uniformly in that
  window. Since ``exposure + rolling_shutter <= 1``, a frame is captured
  between poses ``k`` and ``k + 1``.
* The ground truth of frame ``k`` is the pose at the mid-exposure of the
  middle row (row ``(H - 1) / 2``, between the two middle rows when ``H`` is even), time ``k + (rolling_shutter + exposure) / 2``: exactly the pose
  the ray of the image's middle row at mid-exposure sees. Row ``r``'s own pose
  is the one at ``k + rolling_shutter * r / (H - 1) + exposure / 2``.

With both fractions 0 every ray is traced at the frame time and frames are
rendered as before (the sensor then contains no timing code at all).

Vignetting multiplies the linear radiance of pixel ``(row, col)`` by
``V = (1 + (v * rho / rho_max)**2)**-2``, the cos^4 law of a lens that sees
the pixel under the angle ``atan(v * rho / rho_max)``: ``rho`` is the pixel
centre's sensor-plane radius (:func:`ifmi.geometry.camera.radius_from_pixels`) and
``rho_max`` the outer radius of the mirror band, so ``v`` is the tangent of
the lens' field angle at the mirror rim. It is applied per pixel to the
rendered linear image, before exposure gain, tone mapping and quantisation.

The sensor-side helpers (:class:`RayTiming`) work on Dr.Jit arrays inside
``sample_ray``; every value that changes from frame to frame is an opaque
JIT variable, so a sequence compiles its kernel once.
"""

from __future__ import annotations

import numpy as np

from .config import CaptureSettings

__all__ = ["row_start_times", "row_mid_times", "ground_truth_time", "sensor_timing_props",
           "vignetting_from_pixels", "RayTiming"]


def row_start_times(height: int, capture: CaptureSettings) -> np.ndarray:
    """Start of each row's exposure after the frame time, in frame intervals; (height,) float64."""
    if height < 2:
        return np.zeros(height)
    return capture.rolling_shutter * np.arange(height) / (height - 1)


def row_mid_times(height: int, capture: CaptureSettings) -> np.ndarray:
    """Mid-exposure time of each row after the frame time, in frame intervals; (height,) float64."""
    return row_start_times(height, capture) + 0.5 * capture.exposure


def ground_truth_time(capture: CaptureSettings) -> float:
    """Time after the frame time of the frame's ground truth: mid-exposure of the middle row."""
    return 0.5 * (capture.rolling_shutter + capture.exposure)


def sensor_timing_props(capture: CaptureSettings, *, mid_exposure: bool = False) -> dict:
    """Sensor properties that make the omni sensor trace rays at their capture times.

    Parameters
    ----------
    capture : CaptureSettings
    mid_exposure : bool, keyword-only
        Trace every ray at its row's mid-exposure instead of a random time
        in the exposure (for ground-truth passes such as depth and normals).

    Returns
    -------
    dict
        Empty for an instantaneous global shutter (the sensor stays as it
        was), else Mitsuba's ``shutter_open``/``shutter_close`` (the
        integrator draws each ray's time uniformly between them) and the
        readout fraction ``rolling_shutter``.
    """
    if not capture.timed:
        return {}
    if mid_exposure:
        opening = closing = 0.5 * capture.exposure
    else:
        opening, closing = 0.0, capture.exposure
    return {"shutter_open": float(opening), "shutter_close": float(closing),
            "rolling_shutter": float(capture.rolling_shutter)}


def vignetting_from_pixels(model, *, strength: float, radius_max: float) -> np.ndarray:
    """Vignetting factor of every pixel centre: ``(1 + (strength * rho / radius_max)**2)**-2``.

    Parameters
    ----------
    model : OcamModel
        Calibration; the image is ``model.size`` (height rows, width columns).
    strength : float, keyword-only
        ``v >= 0``; 0 gives all ones.
    radius_max : float, keyword-only
        Normalising sensor-plane radius in pixels (the mirror band's outer radius).

    Returns
    -------
    (H, W) ndarray
        float32 factors in (0, 1], indexed (row, col).
    """
    from ifmi.geometry.camera import radius_from_pixels

    if strength < 0 or radius_max <= 0:
        raise ValueError(f"expected strength >= 0 and radius_max > 0, got {strength}, {radius_max}")
    height, width = model.size
    rows, cols = np.mgrid[0:height, 0:width]
    rho = radius_from_pixels(model, np.stack([rows, cols], axis=-1))
    return ((1.0 + (strength * rho / radius_max) ** 2) ** -2).astype(np.float32)


def _host_matrix(transform) -> np.ndarray:
    """(4, 4) float64 copy of a width-1 ``Transform4f``, read entry by entry.

    Converting the whole matrix at once would run a small kernel holding the
    entries as constants, compiled anew for every pose.
    """
    matrix = transform.matrix
    return np.array([[float(matrix[i][j][0]) for j in range(4)] for i in range(4)])


class RayTiming:
    """Capture time and camera pose of each ray of the omni sensor (Dr.Jit, inside ``sample_ray``).

    The sensor's ``to_world`` is the pose at the frame time; ``to_world_end``
    (exposed through ``traverse``) the pose one frame interval later. A ray
    at time ``tau`` (frame intervals after the frame time) leaves from
    ``p0 + tau (p1 - p0)`` along ``R0 Rot(a, tau theta) d``, where ``a, theta``
    is the axis and angle of ``R0^T R1`` -- the slerp of the two rotations.

    Parameters
    ----------
    mi : module
        Imported Mitsuba (variant set).
    props : mitsuba.Properties
        The sensor's properties: ``shutter_open``, ``shutter_close`` (frame
        intervals), ``rolling_shutter`` (readout fraction), ``to_world_end``.
    height : int
        Rows of the full film.
    to_world : (4, 4) ndarray
        The frame's pose, also the end pose when ``props`` gives none (the camera stands still).
    """

    def __init__(self, mi, props, height: int, to_world: np.ndarray):
        import drjit as dr

        self.mi, self.dr = mi, dr
        readout = float(props.get("rolling_shutter", 0.0))
        opening, closing = (float(props.get(k, 0.0)) for k in ("shutter_open", "shutter_close"))
        self.enabled = readout > 0.0 or closing > 0.0 or opening > 0.0
        self.row_step = mi.Float(readout / (height - 1) if height > 1 else 0.0)
        self.last_row = float(height - 1)
        matrix = np.asarray(to_world, dtype=np.float32)
        if "to_world_end" in props:
            matrix = np.array(props["to_world_end"].matrix, dtype=np.float32)
        self.to_world_end = mi.Transform4f(np.ascontiguousarray(matrix))
        self.axis, self.angle, self.step = mi.Vector3f(1.0, 0.0, 0.0), mi.Float(0.0), mi.Vector3f(0.0)

    def traverse(self, callback) -> None:
        callback.put("to_world_end", self.to_world_end, self.mi.ParamFlags.NonDifferentiable)

    def update(self, to_world) -> None:
        """Recompute the motion of the frame interval from the two poses (on the host)."""
        from scipy.spatial.transform import Rotation

        start, end = _host_matrix(to_world), _host_matrix(self.to_world_end)
        rotvec = Rotation.from_matrix(start[:3, :3].T @ end[:3, :3]).as_rotvec()
        angle = float(np.linalg.norm(rotvec))
        axis = rotvec / angle if angle > 0 else np.array([1.0, 0.0, 0.0])
        mi = self.mi

        def device(values):  # opaque from the start: a literal would be baked into the kernel
            return [self.dr.opaque(mi.Float, float(v)) for v in np.atleast_1d(values)]

        self.axis = mi.Vector3f(*device(axis))
        [self.angle] = device(angle)
        self.step = mi.Vector3f(*device(end[:3, 3] - start[:3, 3]))
        self.dr.make_opaque(self.row_step)

    def ray_times(self, time, sample2, film):
        """Time of each ray after the frame time: its exposure time plus its row's readout delay."""
        dr, mi = self.dr, self.mi
        crop_size = mi.ScalarVector2f(film.crop_size())
        crop_offset = mi.ScalarVector2f(film.crop_offset())
        row = dr.clip(dr.floor(dr.fma(sample2.y, crop_size.y, crop_offset.y)), 0.0, self.last_row)
        return dr.fma(row, self.row_step, time)

    def posed_ray(self, to_world, time, sample2, film, direction):
        """World origin and direction of camera-frame ``direction`` (unit) at each ray's time."""
        dr, mi = self.dr, self.mi
        tau = self.ray_times(time, sample2, film)
        sin, cos = dr.sincos(self.angle * tau)
        axis = self.axis
        turned = (direction * cos + dr.cross(axis, direction) * sin
                  + axis * (dr.dot(axis, direction) * (1.0 - cos)))
        origin = to_world @ mi.Point3f(0.0, 0.0, 0.0) + self.step * tau
        return origin, to_world @ turned
