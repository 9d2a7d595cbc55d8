"""Mitsuba sensor plugin ``omnicam``: the OCamCalib camera model, and every other model, exactly.

Kalibr and equirectangular models (:mod:`ifmi.geometry.camera_models`) take the same
route with their own pixel->direction code (:mod:`omnisim.camera_rays`),
chosen by the ``camera_model`` property; their calibration is one list
``params`` (Kalibr's values, exposed through ``traverse``), from which the
sensor derives the ray code's scalars and lookup table on the host
(:func:`omnisim.camera_rays.kernel_data`, again whenever ``params``
changes), all opaque; samples outside the model's valid region are black.

Each film sample is mapped to a ``(row, col)`` pixel coordinate (film x is the
column, film y the row; pixel centres at integers, so the film position
``x + 0.5`` is column ``x``), lifted to a camera-frame ray with the same
``cam2world`` formula as :func:`ifmi.geometry.camera.rays_from_pixels`, and carried to
the world by ``to_world``. The camera frame is the model's: x along image
rows, y along image columns, z the mirror axis.

Samples whose sensor-plane radius lies outside the mirror band
``[radius_min, radius_max]`` (the camera's own reflection in the middle, the
housing beyond the rim) carry zero weight and are not traced, so those pixels
are black.

Performance notes: ``sample2`` is normalised over the film's crop window; the
calibration values are opaque JIT variables, so a new calibration (of the
same polynomial length) reuses the compiled kernel; ``to_world`` and the
calibration are exposed through ``traverse`` so a frame's pose is set with
``mi.traverse(scene)`` and ``params.update()``.

Capture timing (motion blur, rolling shutter) lives in :mod:`omnisim.capture`:
with ``shutter_close > 0`` or ``rolling_shutter > 0`` each ray is traced at
its own time, with the pose interpolated between ``to_world`` (the frame
time) and ``to_world_end`` (one frame interval later).
"""

from __future__ import annotations

import numpy as np

from ifmi.geometry.camera import OcamModel

__all__ = ["PLUGIN_NAME", "register_omni_sensor", "sensor_dict", "to_world_matrix"]

PLUGIN_NAME = "omnicam"

# Polynomials are zero-padded to at least this many coefficients so that
# calibrations of different degree share one compiled kernel.
MIN_POLY_COEFFS = 8


def _parse_floats(text: str) -> list[float]:
    return [float(tok) for tok in str(text).replace(",", " ").split()]


def to_world_matrix(rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world matrix from a rotation ``R_wc`` (3,3) and a position (3,) in metres."""
    m = np.eye(4)
    m[:3, :3] = np.asarray(rotation, dtype=np.float64)
    m[:3, 3] = np.asarray(position, dtype=np.float64)
    return m


def sensor_dict(model, *, to_world: np.ndarray, radius_min: float, radius_max: float,
                spp: int, sampler: str = "multijitter", seed: int = 0, mi=None,
                timing: dict | None = None) -> dict:
    """Mitsuba scene-dict entry of the omni sensor for an :class:`ifmi.geometry.camera.OcamModel`.

    Parameters
    ----------
    model : OcamModel or ifmi.geometry.camera.CameraModel
        Calibration; the film gets its ``size`` (height rows, width columns).
    to_world : (4, 4) ndarray, keyword-only
        Camera-to-world transform (camera frame of the model).
    radius_min, radius_max : float, keyword-only
        Mirror band in sensor-plane pixels; outside it pixels are black
        (OCamCalib only; other models are black outside their valid region).
    spp : int, keyword-only
        Samples per pixel.
    sampler : str, keyword-only
        Mitsuba sampler plugin (a low-discrepancy one by default).
    seed : int, keyword-only
        Sampler seed.
    mi : module
        The imported ``mitsuba`` module (variant already set).
    timing : dict, optional, keyword-only
        Capture timing properties (:func:`omnisim.capture.sensor_timing_props`);
        none for an instantaneous global shutter.
    """
    height, width = model.size
    sampler_dict = {"type": sampler, "sample_count": int(spp), "seed": int(seed)}
    if not isinstance(model, OcamModel):
        from .camera_rays import ray_kind, ray_parameters

        return {"type": PLUGIN_NAME, "camera_model": ray_kind(model),
                "params": " ".join(repr(v) for v in ray_parameters(model)),
                "to_world": mi.ScalarTransform4f(np.asarray(to_world, dtype=np.float64).tolist()),
                "film": _film_dict(width, height), "sampler": sampler_dict, **(timing or {})}
    c, d, e = model.affine
    return {
        "type": PLUGIN_NAME,
        "pol": " ".join(repr(float(v)) for v in model.pol),
        "center_row": float(model.center[0]),
        "center_col": float(model.center[1]),
        "affine_c": float(c), "affine_d": float(d), "affine_e": float(e),
        "radius_min": float(radius_min),
        "radius_max": float(radius_max),
        "to_world": mi.ScalarTransform4f(np.asarray(to_world, dtype=np.float64).tolist()),
        "film": _film_dict(width, height),
        "sampler": sampler_dict,
        **(timing or {}),
    }


def _film_dict(width: int, height: int) -> dict:
    return {"type": "hdrfilm", "width": int(width), "height": int(height),
            "rfilter": {"type": "box"}, "pixel_format": "rgb"}


class _OmniSensorMethods:
    """The ``omnicam`` sensor's methods; :func:`register_omni_sensor` copies them into a ``mi.Sensor`` subclass.

    ``self._mi`` is the imported ``mitsuba`` module (its variant set) the sensor was registered with.
    """

    def _setup(self, props):
        # A pinhole-like viewpoint: no aperture sample is drawn (as Mitsuba's perspective camera).
        self.m_needs_sample_3 = False
        self.camera_model = props.get("camera_model", "ocamcalib")
        if self.camera_model != "ocamcalib":
            self._setup_model_params(props)
        else:
            self._setup_polynomial(props)
        self._setup_pose(props)

    def _setup_polynomial(self, props):
        mi = self._mi
        pol = _parse_floats(props.get("pol", "1"))
        if len(pol) < 1:
            raise ValueError("omnicam: 'pol' needs at least one coefficient")
        self.n_coeffs = max(len(pol), MIN_POLY_COEFFS)
        pol = pol + [0.0] * (self.n_coeffs - len(pol))
        self.pol = mi.Float(pol)
        self._coeffs = []
        self.center = mi.Point2f(props.get("center_row", 0.0), props.get("center_col", 0.0))
        self.affine = mi.Vector3f(props.get("affine_c", 1.0), props.get("affine_d", 0.0),
                                  props.get("affine_e", 0.0))
        self.band = mi.Vector2f(props.get("radius_min", 0.0),
                                props.get("radius_max", float("inf")))

    def _setup_model_params(self, props):
        from .camera_rays import RAY_KINDS, parameter_count

        if self.camera_model not in RAY_KINDS:
            raise ValueError(f"omnicam: unknown camera_model {self.camera_model!r}; expected "
                             f"ocamcalib or one of {RAY_KINDS}")
        values = _parse_floats(props.get("params", ""))
        self.n_coeffs = parameter_count(self.camera_model)
        if len(values) != self.n_coeffs:
            raise ValueError(f"omnicam: {self.camera_model} expects {self.n_coeffs} params, "
                             f"got {len(values)}")
        self.params = self._mi.Float(values)

    def _setup_pose(self, props):
        from .capture import RayTiming

        mi = self._mi
        matrix = np.eye(4, dtype=np.float32)
        if "to_world" in props:
            matrix = np.array(props["to_world"].matrix, dtype=np.float32)
        self.to_world = mi.Transform4f(np.ascontiguousarray(matrix))
        self.timing = RayTiming(mi, props, self.film().size().y, matrix)
        self._make_opaque()

    def _kernel_data(self):
        """Scalars (width-1 opaque variables) and lookup table of the model's ray code."""
        import drjit as dr

        from .camera_rays import kernel_data, model_from_parameters

        size = self.film().size()
        model = model_from_parameters(self.camera_model, np.array(self.params, dtype=np.float64),
                                      (size.y, size.x))
        scalars, table = kernel_data(model)
        self.table = self._mi.Float(table)
        self._coeffs = [self._mi.Float(v) for v in scalars]
        dr.make_opaque(self.table)

    def _make_opaque(self, calibration_changed: bool = True):
        import drjit as dr

        if self.camera_model != "ocamcalib":
            dr.make_opaque(self.params, self.to_world)
            # Derived from the calibration (and the film size) on the host: a new calibration
            # gives new values of the same opaque variables, not a new kernel. A new pose alone
            # keeps them (building a radtan table takes up to seconds).
            if calibration_changed:
                self._kernel_data()
        else:
            dr.make_opaque(self.pol, self.center, self.affine, self.band, self.to_world)
            # One width-1 opaque variable per coefficient: a kernel parameter, not a per-lane gather.
            self._coeffs = [dr.gather(self._mi.Float, self.pol, i) for i in range(self.n_coeffs)]
        dr.make_opaque(*self._coeffs)
        if self.timing.enabled:
            self.timing.update(self.to_world)

    def traverse(self, callback):
        flag = self._mi.ParamFlags.NonDifferentiable
        callback.put("to_world", self.to_world, flag)
        if self.camera_model != "ocamcalib":
            callback.put("params", self.params, flag)
        else:
            callback.put("pol", self.pol, flag)
            callback.put("center", self.center, flag)
            callback.put("affine", self.affine, flag)
            callback.put("band", self.band, flag)
        self.timing.traverse(callback)

    def parameters_changed(self, keys=None):
        import drjit as dr

        if self.camera_model != "ocamcalib" and dr.width(self.params) != self.n_coeffs:
            raise ValueError(f"omnicam: expected {self.n_coeffs} {self.camera_model} params, "
                             f"got {dr.width(self.params)}")
        if self.camera_model == "ocamcalib" and dr.width(self.pol) != self.n_coeffs:
            raise ValueError(f"omnicam: expected {self.n_coeffs} polynomial coefficients "
                             f"(zero-padded), got {dr.width(self.pol)}")
        self._make_opaque(calibration_changed=not keys or "params" in keys)

    def _camera_ray(self, sample2):
        import drjit as dr

        mi = self._mi
        film = self.film()
        crop_size = mi.ScalarVector2f(film.crop_size())
        crop_offset = mi.ScalarVector2f(film.crop_offset())
        # Film position in pixels; pixel centres sit at x + 0.5, hence the shift.
        col = dr.fma(sample2.x, crop_size.x, crop_offset.x - 0.5)
        row = dr.fma(sample2.y, crop_size.y, crop_offset.y - 0.5)
        if self.camera_model != "ocamcalib":
            from .camera_rays import rays_from_film

            return rays_from_film(dr, mi, self.camera_model, self._coeffs, self.table, row, col)
        c, d, e = self.affine.x, self.affine.y, self.affine.z
        inv_det = dr.rcp(c - d * e)
        dr_ = row - self.center.x
        dc_ = col - self.center.y
        xp = (dr_ - d * dc_) * inv_det
        yp = (c * dc_ - e * dr_) * inv_det
        radius = dr.sqrt(dr.fma(xp, xp, yp * yp))
        zp = self._coeffs[-1]
        for coeff in self._coeffs[-2::-1]:
            zp = dr.fma(zp, radius, coeff)
        in_band = (radius >= self.band.x) & (radius <= self.band.y)
        direction = dr.normalize(mi.Vector3f(xp, yp, zp))
        return direction, in_band

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        import drjit as dr

        mi = self._mi
        wavelengths, wav_weight = self.sample_wavelengths(
            dr.zeros(mi.SurfaceInteraction3f), sample1, active)
        direction, in_band = self._camera_ray(sample2)
        if self.timing.enabled:
            origin, world_dir = self.timing.posed_ray(self.to_world, time, sample2, self.film(), direction)
        else:
            origin = self.to_world @ mi.Point3f(0.0, 0.0, 0.0)
            world_dir = self.to_world @ direction
        maxt = dr.select(in_band, dr.largest(mi.Float), 0.0)
        ray = mi.Ray3f(origin, world_dir, maxt, time, wavelengths)
        weight = dr.select(in_band, wav_weight, 0.0)
        return ray, weight

    def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
        ray, weight = self.sample_ray(time, sample1, sample2, sample3, active)
        ray_diff = self._mi.RayDifferential3f(ray)
        ray_diff.has_differentials = False
        return ray_diff, weight

    def to_string(self):
        return f"OmniSensor[{self.camera_model}, n_coeffs={self.n_coeffs}]"


def register_omni_sensor(mi) -> None:
    """Register the ``omnicam`` sensor plugin with the imported Mitsuba module (its variant set)."""

    def __init__(self, props):
        mi.Sensor.__init__(self, props)
        self._mi = mi
        self._setup(props)

    # nanobind types take one base: the methods are copied into the subclass of mi.Sensor.
    methods = {k: v for k, v in vars(_OmniSensorMethods).items() if callable(v) and not k.startswith("__")}
    OmniSensor = type("OmniSensor", (mi.Sensor,), {**methods, "__init__": __init__,
                                                  "__doc__": _OmniSensorMethods.__doc__})
    mi.register_sensor(PLUGIN_NAME, lambda props: OmniSensor(props))
