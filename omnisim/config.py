"""Scene files: read a TOML scene description into frozen, validated settings.

A scene file has the tables ``[scene]`` (name, layout seed), ``[render]``
(resolution, spp, integrator depth, sampler), ``[camera]`` (a calibration
file or a direct polynomial with centre, affine and size, plus the mirror
band), ``[trajectory]``, ``[effects]``, ``[textures.*]``, ``[materials.*]``,
``[[lights]]`` and ``[[objects]]`` (geometry generators). Every problem is
reported as an :class:`ifmi.errors.InputError` naming the file and the key.
"""

from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass, field, asdict
from pathlib import Path

from ifmi.camera import OcamModel, model_from_direct_polynomial
from ifmi.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["RenderSettings", "TrajectorySettings", "EffectsSettings", "CaptureSettings", "CameraSettings",
           "SceneConfig", "load_scene_config"]


@dataclass(frozen=True)
class RenderSettings:
    """How frames are rendered.

    resolution : (height, width) in pixels; spp : samples per pixel;
    max_depth : path length of the path tracer (2 = direct light only);
    sampler : Mitsuba sampler plugin name; variant : Mitsuba variant or "" for automatic.
    """

    resolution: tuple[int, int] = (512, 512)
    spp: int = 16
    max_depth: int = 3
    sampler: str = "multijitter"
    variant: str = ""


@dataclass(frozen=True)
class TrajectorySettings:
    """Camera motion: smooth random rotation (degrees) and optional translation (metres), or a TUM file."""

    frames: int = 200
    position: tuple[float, float, float] = (0.0, 0.0, 1.2)
    max_yaw_step_deg: float = 3.0
    max_roll_deg: float = 15.0
    max_pitch_deg: float = 15.0
    max_tilt_step_deg: float = 1.5
    smoothness_frames: float = 6.0
    translation_step_m: float = 0.0
    translation_radius_m: float = 0.5
    tum: str = ""


@dataclass(frozen=True)
class EffectsSettings:
    """Sensor effects applied to the 8-bit image; all off by default.

    noise_sigma : Gaussian noise standard deviation in 8-bit grey levels;
    exposure_stops : largest exposure change from frame 0, in stops (f-stops);
    exposure_step_stops : largest change between consecutive frames, in stops;
    jpeg_quality : 1..100 to pass frames through JPEG compression, 0 for off.
    """

    noise_sigma: float = 0.0
    exposure_stops: float = 0.0
    exposure_step_stops: float = 0.1
    jpeg_quality: int = 0


@dataclass(frozen=True)
class CaptureSettings:
    """How the camera captures a frame (see :mod:`omnisim.capture`); all off by default.

    exposure : open shutter time as a fraction of the frame interval, 0..1 (motion blur);
    rolling_shutter : readout time of the rows (top to bottom) as a fraction of the frame interval, 0..1;
    vignetting : strength ``v >= 0`` of the radial fall-off ``(1 + (v * rho / rho_max)**2)**-2``.
    A frame's capture must end by the next frame: ``exposure + rolling_shutter <= 1``.
    """

    exposure: float = 0.0
    rolling_shutter: float = 0.0
    vignetting: float = 0.0

    def __post_init__(self) -> None:
        for name in ("exposure", "rolling_shutter"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name}: expected a fraction of the frame interval in [0, 1], got {value!r}")
        if self.exposure + self.rolling_shutter > 1.0:
            raise ValueError(f"exposure + rolling_shutter: expected <= 1 (a frame's capture ends by the next "
                             f"frame), got {self.exposure + self.rolling_shutter!r}")
        if not self.vignetting >= 0.0:
            raise ValueError(f"vignetting: expected >= 0, got {self.vignetting!r}")

    @property
    def timed(self) -> bool:
        """True when rays of a frame are traced at different times (motion blur or rolling shutter)."""
        return self.exposure > 0.0 or self.rolling_shutter > 0.0


@dataclass(frozen=True)
class CameraSettings:
    """Calibration at the render resolution and the mirror band (sensor-plane pixels).

    ``model`` is an OCamCalib model or, from ``kalibr = "camera.yaml"``, a
    model of :mod:`ifmi.camera_models` (band 0..inf: its valid region bounds the image).
    """

    model: OcamModel
    radius_min: float
    radius_max: float


@dataclass(frozen=True)
class SceneConfig:
    """A validated scene file."""

    path: str
    sha256: str
    name: str
    layout_seed: int
    render: RenderSettings
    trajectory: TrajectorySettings
    effects: EffectsSettings
    camera: CameraSettings
    textures: dict = field(default_factory=dict)
    materials: dict = field(default_factory=dict)
    lights: tuple = ()
    objects: tuple = ()
    capture: CaptureSettings = field(default_factory=CaptureSettings)

    def settings_dict(self) -> dict:
        """JSON-serialisable summary of everything that changes the rendered pixels."""
        return {
            "render": asdict(self.render),
            "trajectory": asdict(self.trajectory),
            "effects": asdict(self.effects),
            "camera": self._camera_dict(),
            # Only when set, so folders rendered before [capture] existed keep their identity.
            **({"capture": asdict(self.capture)} if self.capture != CaptureSettings() else {}),
        }

    def _camera_dict(self) -> dict:
        if not isinstance(self.camera.model, OcamModel):
            from ifmi.io.kalibr import kalibr_fields

            return {"kalibr": kalibr_fields(self.camera.model)}
        model = self.camera.model
        return {"pol": list(model.pol), "invpol": list(model.invpol), "center": list(model.center),
                "affine": list(model.affine), "size": list(model.size),
                "radius_min": self.camera.radius_min, "radius_max": self.camera.radius_max}


class _Reader:
    """Typed access to one table of the TOML file with one-line errors."""

    def __init__(self, path: Path, table: dict, where: str):
        self.path, self.table, self.where = path, table, where

    def fail(self, key: str, problem: str):
        raise InputError(self.path, f"[{self.where}] {key}: {problem}")

    def number(self, key, default, *, minimum=None, maximum=None, integer=False):
        value = self.table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"expected a number, got {value!r}")
        if integer and int(value) != value:
            self.fail(key, f"expected an integer, got {value!r}")
        if minimum is not None and value < minimum:
            self.fail(key, f"expected >= {minimum}, got {value!r}")
        if maximum is not None and value > maximum:
            self.fail(key, f"expected <= {maximum}, got {value!r}")
        return int(value) if integer else float(value)

    def numbers(self, key, default, *, length=None):
        value = self.table.get(key, default)
        if not isinstance(value, (list, tuple)) or any(
                isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
            self.fail(key, f"expected a list of numbers, got {value!r}")
        if length is not None and len(value) != length:
            self.fail(key, f"expected {length} numbers, got {len(value)}")
        return tuple(float(v) for v in value)

    def string(self, key, default):
        value = self.table.get(key, default)
        if not isinstance(value, str):
            self.fail(key, f"expected a string, got {value!r}")
        return value


def _table(path, data, key) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise InputError(path, f"[{key}]: expected a table, got {type(value).__name__}")
    return value


def _camera(path: Path, table: dict, resolution) -> CameraSettings:
    from ifmi.io.calib import read_calib

    r = _Reader(path, table, "camera")
    if "kalibr" in table:
        return _kalibr_camera(path, r, resolution)
    if "calib" in table:
        calib_path = Path(r.string("calib", ""))
        if not calib_path.is_absolute():
            calib_path = path.parent / calib_path
        model = read_calib(calib_path)
    else:
        for key in ("pol", "center", "size"):
            if key not in table:
                r.fail(key, "missing (give either 'calib' or 'pol', 'center', 'size')")
        pol = r.numbers("pol", None)
        size = r.numbers("size", None, length=2)
        if any(int(v) != v or v <= 0 for v in size):
            r.fail("size", f"expected two positive integers (height, width), got {list(size)}")
        try:
            model = model_from_direct_polynomial(pol, center=r.numbers("center", None, length=2),
                                                 size=(int(size[0]), int(size[1])),
                                                 affine=r.numbers("affine", (1.0, 0.0, 0.0), length=3))
        except ValueError as exc:
            r.fail("pol", str(exc))
    radius_min = r.number("radius_min", 0.0, minimum=0.0)
    radius_max = r.number("radius_max", float(max(model.size)), minimum=0.0)
    if radius_max <= radius_min:
        r.fail("radius_max", f"expected > radius_min = {radius_min}, got {radius_max}")
    height, width = resolution
    factor_h, factor_w = height / model.height, width / model.width
    if abs(factor_h - factor_w) > 1e-9:
        raise InputError(path, f"[render] resolution: expected the calibration's aspect "
                               f"{model.height}x{model.width} (height x width), got {height}x{width}")
    if abs(factor_h - 1.0) > 1e-12:
        model = model.scaled(factor_h)
        radius_min, radius_max = radius_min * factor_h, radius_max * factor_h
    return CameraSettings(model=model, radius_min=radius_min, radius_max=radius_max)


def _kalibr_camera(path: Path, r: "_Reader", resolution) -> CameraSettings:
    """``[camera] kalibr = "camera.yaml"``: a Kalibr camchain replaces the OCamCalib keys."""
    from ifmi.io.kalibr import read_kalibr

    for key in ("calib", "pol", "center", "affine", "size", "radius_min", "radius_max"):
        if key in r.table:
            r.fail(key, "not used with 'kalibr' (the Kalibr file is the whole camera; its valid "
                        "region bounds the image)")
    kalibr_path = Path(r.string("kalibr", ""))
    if not kalibr_path.is_absolute():
        kalibr_path = path.parent / kalibr_path
    model = read_kalibr(kalibr_path)
    height, width = resolution
    # The width sets the scale; the height must be the calibration's, scaled and rounded.
    factor = width / model.width
    if int(round(model.height * factor)) != height:
        raise InputError(path, f"[render] resolution: expected the calibration's aspect "
                               f"{model.height}x{model.width} (height x width), got {height}x{width}")
    if abs(factor - 1.0) > 1e-12:
        model = model.scaled(factor)
    return CameraSettings(model=model, radius_min=0.0, radius_max=float("inf"))


def _capture(path: Path, table: dict) -> CaptureSettings:
    r = _Reader(path, table, "capture")
    values = {"exposure": r.number("exposure", 0.0, minimum=0.0, maximum=1.0),
              "rolling_shutter": r.number("rolling_shutter", 0.0, minimum=0.0, maximum=1.0),
              "vignetting": r.number("vignetting", 0.0, minimum=0.0)}
    try:
        return CaptureSettings(**values)
    except ValueError as exc:
        raise InputError(path, f"[capture] {exc}") from None


def _resolution_value(path, value) -> tuple[int, int]:
    if isinstance(value, int) and not isinstance(value, bool):
        value = (value, value)
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, int) or v < 8 for v in value)):
        raise InputError(path, f"[render] resolution: expected [height, width] integers >= 8, got {value!r}")
    return int(value[0]), int(value[1])


def load_scene_config(path, *, spp: int | None = None, resolution=None,
                      frames: int | None = None) -> SceneConfig:
    """Read and validate a scene file.

    Parameters
    ----------
    path : str or path
        TOML scene file.
    spp : int, optional, keyword-only
        Overrides ``[render] spp``.
    resolution : int or (height, width), optional, keyword-only
        Overrides ``[render] resolution``; the calibration is scaled to it.
    frames : int, optional, keyword-only
        Overrides ``[trajectory] frames``.

    Raises
    ------
    InputError
        Missing or unparsable file, or a bad value (the message names the key).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "scene file not found") from None
    except OSError as exc:
        raise InputError(path, f"cannot read scene file ({exc.__class__.__name__})") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid TOML: {str(exc).splitlines()[0]}") from None

    scene = _Reader(path, _table(path, data, "scene"), "scene")
    render_t = _table(path, data, "render")
    rr = _Reader(path, render_t, "render")
    res = _resolution_value(path, resolution if resolution is not None
                            else render_t.get("resolution", [512, 512]))
    render = RenderSettings(
        resolution=res,
        spp=rr.number("spp", 16, minimum=1, integer=True) if spp is None else int(spp),
        max_depth=rr.number("max_depth", 3, minimum=1, maximum=64, integer=True),
        sampler=rr.string("sampler", "multijitter"),
        variant=rr.string("variant", ""),
    )
    if render.spp < 1:
        raise InputError(path, f"spp: expected >= 1, got {render.spp}")
    if render.sampler not in ("multijitter", "ldsampler", "stratified", "independent", "orthogonal"):
        rr.fail("sampler", f"expected a Mitsuba sampler (multijitter, ldsampler, ...), got {render.sampler!r}")

    tr = _Reader(path, _table(path, data, "trajectory"), "trajectory")
    trajectory = TrajectorySettings(
        frames=tr.number("frames", 200, minimum=1, integer=True) if frames is None else int(frames),
        position=tr.numbers("position", (0.0, 0.0, 1.2), length=3),
        max_yaw_step_deg=tr.number("max_yaw_step_deg", 3.0, minimum=0.0, maximum=90.0),
        max_roll_deg=tr.number("max_roll_deg", 15.0, minimum=0.0, maximum=90.0),
        max_pitch_deg=tr.number("max_pitch_deg", 15.0, minimum=0.0, maximum=90.0),
        max_tilt_step_deg=tr.number("max_tilt_step_deg", 1.5, minimum=0.0, maximum=90.0),
        smoothness_frames=tr.number("smoothness_frames", 6.0, minimum=0.0),
        translation_step_m=tr.number("translation_step_m", 0.0, minimum=0.0),
        translation_radius_m=tr.number("translation_radius_m", 0.5, minimum=0.0),
        tum=tr.string("tum", ""),
    )
    if trajectory.frames < 1:
        raise InputError(path, f"frames: expected >= 1, got {trajectory.frames}")
    if trajectory.tum and not Path(trajectory.tum).is_absolute():
        trajectory = TrajectorySettings(**{**asdict(trajectory), "tum": str(path.parent / trajectory.tum)})

    er = _Reader(path, _table(path, data, "effects"), "effects")
    effects = EffectsSettings(
        noise_sigma=er.number("noise_sigma", 0.0, minimum=0.0),
        exposure_stops=er.number("exposure_stops", 0.0, minimum=0.0),
        exposure_step_stops=er.number("exposure_step_stops", 0.1, minimum=0.0),
        jpeg_quality=er.number("jpeg_quality", 0, minimum=0, maximum=100, integer=True),
    )
    camera = _camera(path, _table(path, data, "camera"), res)
    capture = _capture(path, _table(path, data, "capture"))

    textures = _table(path, data, "textures")
    materials = _table(path, data, "materials")
    for kind, table in (("textures", textures), ("materials", materials)):
        for name, entry in table.items():
            if not isinstance(entry, dict):
                raise InputError(path, f"[{kind}.{name}]: expected a table")
    for name, mat in materials.items():
        tex = mat.get("texture")
        if tex is not None and tex not in textures:
            raise InputError(path, f"[materials.{name}] texture: unknown texture {tex!r}")
    lights = data.get("lights", [])
    objects = data.get("objects", [])
    for kind, items in (("lights", lights), ("objects", objects)):
        if not isinstance(items, list) or any(not isinstance(v, dict) for v in items):
            raise InputError(path, f"[[{kind}]]: expected an array of tables")
    for i, obj in enumerate(objects):
        if "generator" not in obj:
            raise InputError(path, f"[[objects]] #{i + 1}: missing 'generator'")
    return SceneConfig(
        path=str(path), sha256=hashlib.sha256(raw).hexdigest(),
        name=scene.string("name", path.stem),
        layout_seed=scene.number("seed", 0, minimum=0, integer=True),
        render=render, trajectory=trajectory, effects=effects, camera=camera,
        textures=textures, materials=materials, lights=tuple(lights), objects=tuple(objects),
        capture=capture,
    )
