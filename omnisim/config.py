"""Scene files: read a TOML scene description into frozen, validated settings.

A scene file has the tables ``[scene]`` (name, layout seed, an optional
Mitsuba scene file), ``[render]`` (resolution, spp, integrator depth,
sampler), ``[camera]`` (a calibration file or a direct polynomial with
centre, affine and size, plus the mirror band), ``[trajectory]``,
``[effects]``, ``[capture]``, ``[textures.*]``, ``[materials.*]``,
``[[lights]]`` and ``[[objects]]`` (geometry generators,
:mod:`omnisim.generators`). Every default is written once, in the settings
dataclasses below, and every check once, in their ``__post_init__``; an
unknown section or key, a value of the wrong type or range, an unknown
material, texture, generator or photograph, or a missing file is one
:class:`ifmi.errors.InputError` line naming the file, the section and the key.
"""

from __future__ import annotations

import hashlib
import sys
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from ifmi.geometry.camera import (INVERSE_TOLERANCE_PX, OcamModel, check_affine, check_center_inside, check_image_size,
                         max_image_radius, model_from_direct_polynomial)
from ifmi.errors import InputError, first_line
from ifmi.io.text_file import refuse_special_file

from omnisim import meshes, procedural  # noqa: F401  (register the built-in generators)
from omnisim.generators import object_from_table, registered_generators
from omnisim.lights import ENVIRONMENT_LIGHT_TYPES, LIGHT_TYPES, EnvmapLight, envmap_file_problem
from omnisim.materials import MaterialSettings
from omnisim.settings import MAX_CAMERA_REACH_M, SettingError, check_fields, setting, settings_from_table
from omnisim.textures import TEXTURE_SOURCES

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["SceneSettings", "RenderSettings", "TrajectorySettings", "EffectsSettings", "CaptureSettings",
           "CameraTable", "CameraSettings", "SceneConfig", "SECTIONS", "SUPPORTED_VARIANTS",
           "load_scene_config", "write_scene_with_kalibr_camera"]

# Mitsuba variants the omni sensor and the dataset writer are made for (RGB output).
SUPPORTED_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")
# Largest image side, pixels: a film this size holds 16384^2 RGBA float32 = 4 GiB.
MAX_RESOLUTION = 16384
# Samplers that can drive the sensor (low-discrepancy ones first).
SAMPLERS = ("multijitter", "ldsampler", "stratified", "independent", "orthogonal")
# Largest samples per pixel: Mitsuba's sample_count is a 32-bit unsigned integer and its samplers
# round a count up (to a square, a power of two, a prime's square); from 2^30 every rounding stays under 2^32.
MAX_SPP = 2 ** 30
# Largest frame count: a million frames (over 9 hours at 30 fps) is beyond any render here; the
# trajectory holds a few arrays per frame, so a mistyped 10^19 would fail allocating them.
MAX_FRAMES = 1_000_000
# Longest correlation of the random motion, frames: its smoothing kernel draws 16x this many
# samples per signal (roll and pitch use 4x the length, 4 sigma each side); beyond a thousand
# frames the motion is a constant rate over any sequence rendered.
MAX_SMOOTHNESS_FRAMES = 1000.0
# Largest noise standard deviation, 8-bit grey levels: the whole 8-bit range; a wider Gaussian only
# saturates the frame to black and white.
MAX_NOISE_SIGMA = 255.0
# Largest exposure drift, stops: 8-bit sRGB spans log2(255 * 12.92) = 11.7 stops from its darkest
# non-zero level to white, so a gain of 2**12 turns every lit pixel white and 2**-12 every pixel black.
MAX_EXPOSURE_STOPS = 12.0
# Largest vignetting strength v: the fall-off (1 + v**2)**-2 at the band's outer edge is then
# 2**-MAX_EXPOSURE_STOPS, the darkest level 8 bits hold; a stronger one blackens the outer band.
MAX_VIGNETTING = (2.0 ** (MAX_EXPOSURE_STOPS / 2) - 1.0) ** 0.5


@dataclass(frozen=True)
class SceneSettings:
    """``[scene]``: name, layout seed and an optional Mitsuba 3 scene file to start from."""

    name: str = setting("", "dataset name (default: the file name)")
    seed: int = setting(0, "layout seed of the generators; also the default motion seed", minimum=0)
    mitsuba_xml: str = setting("", "Mitsuba 3 scene file (relative to this file) whose shapes, materials, "
                                   "emitters and integrator are used; its sensors are ignored")

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class RenderSettings:
    """``[render]``: how frames are rendered.

    resolution : (height, width) in pixels (one integer for a square); spp :
    samples per pixel; max_depth : path length of the path tracer (2 = direct
    light only); sampler : Mitsuba sampler plugin; variant : Mitsuba variant or
    "" for automatic.
    """

    resolution: tuple[int, int] = setting((512, 512), "[height, width] pixels; the calibration is scaled to it",
                                          minimum=8, maximum=MAX_RESOLUTION)
    spp: int = setting(16, "samples per pixel", minimum=1, maximum=MAX_SPP)
    max_depth: int = setting(3, "path length of the path tracer (2 = direct light only)", minimum=1, maximum=64)
    sampler: str = setting("multijitter", "Mitsuba sampler", choices=SAMPLERS)
    variant: str = setting("", "Mitsuba variant; empty for automatic", choices=("",) + SUPPORTED_VARIANTS)

    def __post_init__(self):
        if isinstance(self.resolution, int) and not isinstance(self.resolution, bool):
            object.__setattr__(self, "resolution", (self.resolution, self.resolution))
        check_fields(self)


# The [trajectory] position of a TUM trajectory that does not write one: its positions as they are.
_NO_OFFSET_M = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class TrajectorySettings:
    """``[trajectory]``: smooth random rotation (degrees) and optional translation (metres), or a TUM file."""

    frames: int = setting(200, "number of frames", minimum=1, maximum=MAX_FRAMES)
    position: tuple[float, float, float] = setting(
        (0.0, 0.0, 1.2), "camera centre in the world, metres (within 1e4 m of the origin); with tum, an offset "
                         "added to the file's positions, none unless written")
    max_yaw_step_deg: float = setting(3.0, "peak yaw rate, degrees per frame", minimum=0.0, maximum=90.0)
    max_roll_deg: float = setting(15.0, "roll bound, degrees", minimum=0.0, maximum=90.0)
    max_pitch_deg: float = setting(15.0, "pitch bound, degrees", minimum=0.0, maximum=90.0)
    max_tilt_step_deg: float = setting(1.5, "largest roll/pitch change per frame, degrees",
                                       minimum=0.0, maximum=90.0)
    smoothness_frames: float = setting(6.0, "correlation length of the motion, frames", minimum=0.0,
                                       maximum=MAX_SMOOTHNESS_FRAMES)
    translation_step_m: float = setting(0.0, "largest translation per frame, metres (0 = pure rotation)",
                                        minimum=0.0)
    translation_radius_m: float = setting(0.5, "largest distance from position, metres", minimum=0.0)
    tum: str = setting("", "camera-to-world poses from a TUM file instead (relative to the scene file)")

    def __post_init__(self):
        check_fields(self)
        if self.tum:  # the file's positions, offset by position, are checked as it is read
            return
        # The walk stays within translation_radius_m of position; with a radius of 0 it is unbounded.
        key, reach = "position", 0.0
        if self.translation_step_m > 0:
            key = "translation_radius_m" if self.translation_radius_m > 0 else "translation_step_m"
            reach = self.translation_radius_m or (self.frames - 1) * self.translation_step_m
        if max(abs(p) for p in self.position) + reach > MAX_CAMERA_REACH_M:
            raise SettingError(key, f"expected the camera to stay within {MAX_CAMERA_REACH_M:.0e} m of the origin "
                                    f"(the renderer places it in float32, to 0.5 mm there; move the scene's origin "
                                    f"near the camera), got position {list(self.position)} and a walk of up to "
                                    f"{reach:.4g} m from it")


@dataclass(frozen=True)
class EffectsSettings:
    """``[effects]`` (and ``omnisim degrade``): sensor effects on the 8-bit image; all off by default.

    noise_sigma : Gaussian noise standard deviation in 8-bit grey levels, at most 255 (the whole range);
    exposure_stops : largest exposure change from frame 0, in stops (f-stops), at most 12 (beyond the
    11.7 stops 8-bit sRGB spans, every frame is black or white);
    exposure_step_stops : largest change between consecutive frames, in stops, at most 24 (the walk's span);
    jpeg_quality : 1..100 to pass frames through JPEG compression, 0 for off.
    """

    noise_sigma: float = setting(0.0, "Gaussian noise, standard deviation in 8-bit grey levels (0..255)",
                                 minimum=0.0, maximum=MAX_NOISE_SIGMA)
    exposure_stops: float = setting(0.0, "bound of the exposure random walk, stops (0 = off; at most 12)",
                                    minimum=0.0, maximum=MAX_EXPOSURE_STOPS)
    # A step may cross the walk's whole span, from -exposure_stops to +exposure_stops.
    exposure_step_stops: float = setting(0.1, "largest exposure change between frames, stops (at most 24)",
                                         minimum=0.0, maximum=2 * MAX_EXPOSURE_STOPS)
    jpeg_quality: int = setting(0, "JPEG quality 1..100 the frames pass through; 0 = off", minimum=0,
                                maximum=100)

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class CaptureSettings:
    """``[capture]``: how the camera captures a frame (see :mod:`omnisim.capture`); all off by default.

    exposure : open-shutter time as a fraction of the frame interval, 0..1 (motion blur);
    rolling_shutter : readout time of the rows (top to bottom) as a fraction of the frame interval, 0..1;
    vignetting : strength ``v >= 0`` of the radial fall-off ``(1 + (v * rho / rho_max)**2)**-2``, at most
    ``sqrt(2**6 - 1)`` = 7.9, where the band's outer edge falls 12 stops (below the darkest 8-bit level).
    A frame's capture must end by the next frame: ``exposure + rolling_shutter <= 1``.
    """

    exposure: float = setting(0.0, "open-shutter time, fraction of the frame interval", minimum=0.0, maximum=1.0)
    rolling_shutter: float = setting(0.0, "row readout time, fraction of the frame interval",
                                     minimum=0.0, maximum=1.0)
    vignetting: float = setting(0.0, "radial fall-off strength (0 = none; at most 7.9, where the band's "
                                     "outer edge falls 12 stops)", minimum=0.0, maximum=MAX_VIGNETTING)

    def __post_init__(self):
        check_fields(self)
        if self.exposure + self.rolling_shutter > 1.0:
            total = self.exposure + self.rolling_shutter
            raise SettingError("exposure + rolling_shutter", f"expected <= 1 (a frame's capture ends by the "
                                                             f"next frame), got {total!r}")

    @property
    def timed(self) -> bool:
        """True when the rays of a frame are traced at different times (motion blur or rolling shutter)."""
        return self.exposure > 0.0 or self.rolling_shutter > 0.0


@dataclass(frozen=True)
class CameraTable:
    """``[camera]`` as written: a Kalibr file, an OCamCalib file, or a direct polynomial with centre and size.

    All lengths in sensor-plane pixels of the calibration's own size.
    """

    kalibr: str = setting("", "Kalibr camchain camera.yaml (relative to the scene file); replaces every "
                              "other key")
    calib: str = setting("", "OCamCalib calib_results.txt (relative to the scene file)")
    pol: tuple[float, ...] | None = setting(None, "cam2world polynomial, lowest degree first")
    center: tuple[float, float] | None = setting(None, "(row, col) of the image centre, pixels")
    size: tuple[int, int] | None = setting(None, "[height, width] the calibration is for, pixels", minimum=1)
    affine: tuple[float, float, float] = setting((1.0, 0.0, 0.0), "affine parameters c, d, e")
    radius_min: float = setting(0.0, "inner edge of the mirror band, pixels (black inside)", minimum=0.0)
    radius_max: float | None = setting(None, "outer edge of the mirror band, pixels (default: the larger "
                                             "image side)", minimum=0.0)

    def __post_init__(self):
        check_fields(self)
        if self.kalibr:
            for f in fields(self):
                if f.name != "kalibr" and getattr(self, f.name) != f.default:
                    raise SettingError(f.name, "not used with 'kalibr' (the Kalibr file is the whole camera; "
                                               "its valid region bounds the image)")
            return
        if not self.calib:
            for key in ("pol", "center", "size"):
                if getattr(self, key) is None:
                    raise SettingError(key, "missing (give either 'calib' or 'pol', 'center', 'size')")
        if self.pol == ():
            raise SettingError("pol", "expected at least one coefficient (lowest degree first), got []")
        if self.radius_max is not None and self.radius_max <= self.radius_min:
            raise SettingError("radius_max", f"expected > radius_min = {self.radius_min}, got {self.radius_max}")


@dataclass(frozen=True)
class CameraSettings:
    """Calibration at the render resolution and the mirror band (sensor-plane pixels).

    ``model`` is an OCamCalib model or, from ``kalibr = "camera.yaml"``, a
    model of :mod:`ifmi.geometry.camera_models` (band 0..inf: its valid region bounds the image).
    """

    model: OcamModel
    radius_min: float
    radius_max: float


@dataclass(frozen=True)
class SceneConfig:
    """A validated scene file.

    textures : name -> PhotoTexture or NoiseTexture; materials : name ->
    MaterialSettings; lights : light settings in file order; objects :
    ObjectSpec in file order; mitsuba_xml : absolute path of the Mitsuba
    scene file or ""; assets : (path, sha256) of every file the scene reads
    besides itself (mesh, image and Mitsuba files it names, and the material
    and texture files beside its meshes).
    """

    path: str
    sha256: str
    name: str
    layout_seed: int
    render: RenderSettings
    trajectory: TrajectorySettings
    effects: EffectsSettings
    camera: CameraSettings
    capture: CaptureSettings = field(default_factory=CaptureSettings)
    textures: dict = field(default_factory=dict)
    materials: dict = field(default_factory=dict)
    lights: tuple = ()
    objects: tuple = ()
    mitsuba_xml: str = ""
    assets: tuple = ()

    def settings_dict(self) -> dict:
        """JSON-serialisable summary of everything that changes the rendered pixels.

        ``capture`` and ``assets`` appear only when set, so folders rendered
        before they existed keep their identity.
        """
        return {
            "render": asdict(self.render),
            "trajectory": asdict(self.trajectory),
            "effects": asdict(self.effects),
            "camera": self._camera_dict(),
            **({"capture": asdict(self.capture)} if self.capture != CaptureSettings() else {}),
            **({"assets": [[Path(file).name, sha] for file, sha in self.assets]} if self.assets else {}),
        }

    def _camera_dict(self) -> dict:
        if not isinstance(self.camera.model, OcamModel):
            from ifmi.io.kalibr import kalibr_fields

            return {"kalibr": kalibr_fields(self.camera.model)}
        model = self.camera.model
        return {"pol": list(model.pol), "invpol": list(model.invpol), "center": list(model.center),
                "affine": list(model.affine), "size": list(model.size),
                "radius_min": self.camera.radius_min, "radius_max": self.camera.radius_max}


# Top-level tables of a scene file and what each holds.
SECTIONS = {
    "scene": "name, layout seed, Mitsuba scene file",
    "render": "resolution, spp, path length, sampler, variant",
    "camera": "calibration and mirror band",
    "trajectory": "camera motion",
    "effects": "noise, exposure drift, JPEG",
    "capture": "exposure (motion blur), rolling shutter, vignetting",
    "textures": "[textures.NAME] images",
    "materials": "[materials.NAME] BSDFs",
    "lights": "[[lights]] emitters",
    "objects": "[[objects]] geometry generators",
}


def _read_toml(path: Path) -> tuple[bytes, dict]:
    refuse_special_file(path, what="scene file")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "scene file not found") from None
    except OSError as exc:
        raise InputError(path, f"cannot read scene file ({exc.strerror or exc.__class__.__name__})") from None
    try:
        data = tomllib.loads(raw.decode("utf-8-sig"))  # a byte-order mark of Windows editors is skipped
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not valid TOML: {first_line(exc)}") from None
    for key in data:
        if key not in SECTIONS:
            raise InputError(path, f"[{key}]: unknown section; accepted sections: {', '.join(SECTIONS)}")
    return raw, data


def _relative_file(path: Path, name: str, where: str) -> str:
    """Absolute path of a file named in the scene file (relative to its folder; it must exist).

    Absolute, so processes started elsewhere (cluster workers) find it too.
    """
    resolved = Path(name) if Path(name).is_absolute() else (path.parent / name).absolute()
    if not resolved.is_file():
        raise InputError(path, f"{where}: file not found: {resolved}")
    return str(resolved)


def _camera(path: Path, table, resolution, *, key: str = "[render] resolution") -> CameraSettings:
    """The ``[camera]`` table as a calibration scaled to the render ``resolution`` (height, width).

    ``key`` names the resolution in errors (the table's key or the command-line option).
    """
    from ifmi.io.calib import read_calib

    spec = settings_from_table(CameraTable, table, path=path, section="[camera]")
    if spec.kalibr:
        return _kalibr_camera(path, spec.kalibr, resolution, key=key)
    if spec.calib:
        model = read_calib(_relative_file(path, spec.calib, "[camera] calib"))
    else:
        model = _polynomial_camera(path, spec)
    radius_min = spec.radius_min
    radius_max = float(max(model.size)) if spec.radius_max is None else spec.radius_max
    if radius_max <= radius_min:
        raise InputError(path, f"[camera] radius_max: expected > radius_min = {radius_min}, got {radius_max}")
    _check_band(path, model, radius_min)
    height, width = resolution
    factor_h, factor_w = height / model.height, width / model.width
    if abs(factor_h - factor_w) > 1e-9:
        raise InputError(path, f"{key}: expected the calibration's aspect "
                               f"{model.height}x{model.width} (height x width), got {height}x{width}")
    if abs(factor_h - 1.0) > 1e-12:
        model = model.scaled(factor_h)
        radius_min, radius_max = radius_min * factor_h, radius_max * factor_h
    _check_written_inverse(path, model, "[camera] calib" if spec.calib else "[camera] pol")
    return CameraSettings(model=model, radius_min=radius_min, radius_max=radius_max)


def _check_written_inverse(path: Path, model: OcamModel, where: str) -> None:
    """Refuse a calibration, at the size rendered, that the dataset's readers would refuse: its inverse
    polynomial off its direct one by more than :data:`ifmi.geometry.camera.INVERSE_TOLERANCE_PX` (the check of
    :func:`ifmi.io.calib.read_calib`). ``pol = [-1e-30, 0, 1e-30]`` rendered with exit 0 a dataset
    whose calib_results.txt no reader took (its fitted inverse was 20 px off)."""
    from ifmi.spectral.panorama import inverse_polynomial_error

    try:
        error, radius = inverse_polynomial_error(model)
    except ValueError as exc:
        raise InputError(path, f"{where}: {exc}") from None
    if not error <= INVERSE_TOLERANCE_PX:
        raise InputError(path, f"{where}: expected an inverse polynomial within {INVERSE_TOLERANCE_PX} px of the "
                               f"direct one at the {model.height}x{model.width} rendered (as readers of the "
                               f"dataset check), got a round-trip error of {error:.3g} px at radius {radius:.1f} px")


def _polynomial_camera(path: Path, spec: CameraTable) -> OcamModel:
    """The OCamCalib model of ``[camera]`` pol, center, size and affine, checked as calibration files are."""
    for key, check, args in (("size", check_image_size, (spec.size,)), ("affine", check_affine, (spec.affine,)),
                             ("center", check_center_inside, (spec.center, spec.size))):
        try:
            check(*args)
        except ValueError as exc:
            raise InputError(path, f"[camera] {key}: {exc}") from None
    try:
        return model_from_direct_polynomial(spec.pol, center=spec.center, size=spec.size, affine=spec.affine)
    except ValueError as exc:
        raise InputError(path, f"[camera] pol: {exc}") from None


def _check_band(path: Path, model: OcamModel, radius_min: float) -> None:
    """Refuse a mirror band that images no pixel: it must start inside the image and the calibration's range."""
    reach = min(max_image_radius(model.size, model.center, model.affine), model.monotonic_radius)
    if not radius_min < reach:
        raise InputError(path, f"[camera] radius_min: expected under {reach:.1f} px (where the image or the "
                               f"calibration's monotonic range ends, so the mirror band holds pixels), "
                               f"got {radius_min:g}")


def _kalibr_camera(path: Path, name: str, resolution, *, key: str) -> CameraSettings:
    """``[camera] kalibr = "camera.yaml"``: a Kalibr camchain scaled to the render ``resolution`` (named ``key``)."""
    from ifmi.io.kalibr import read_kalibr

    model = read_kalibr(_relative_file(path, name, "[camera] kalibr"))
    height, width = resolution
    # The width sets the scale; the height must be the calibration's, scaled and rounded.
    factor = width / model.width
    if int(round(model.height * factor)) != height:
        raise InputError(path, f"{key}: expected the calibration's aspect "
                               f"{model.height}x{model.width} (height x width), got {height}x{width}")
    if abs(factor - 1.0) > 1e-12:
        model = model.scaled(factor)
    return CameraSettings(model=model, radius_min=0.0, radius_max=float("inf"))


def _named_tables(path: Path, data: dict, section: str) -> dict:
    tables = data.get(section, {})
    if not isinstance(tables, dict) or any(not isinstance(v, dict) for v in tables.values()):
        raise InputError(path, f"[{section}]: expected [{section}.NAME] tables")
    return tables


def _textures(path: Path, data: dict) -> dict:
    out = {}
    for name, table in _named_tables(path, data, "textures").items():
        source = table.get("source")
        if source not in TEXTURE_SOURCES:
            raise InputError(path, f"[textures.{name}] source: expected one of {', '.join(TEXTURE_SOURCES)}, "
                                   f"got {source!r}")
        out[name] = settings_from_table(TEXTURE_SOURCES[source], table, path=path,
                                        section=f"[textures.{name}]", ignore=("source",))
    return out


def _materials(path: Path, data: dict, textures: dict) -> dict:
    out = {}
    for name, table in _named_tables(path, data, "materials").items():
        material = settings_from_table(MaterialSettings, table, path=path, section=f"[materials.{name}]")
        if material.texture and material.texture not in textures:
            raise InputError(path, f"[materials.{name}] texture: unknown texture {material.texture!r} "
                                   f"([textures.*]: {', '.join(sorted(textures)) or 'none defined'})")
        out[name] = material
    return out


def _array_of_tables(path: Path, data: dict, section: str) -> list:
    items = data.get(section, [])
    if not isinstance(items, list) or any(not isinstance(v, dict) for v in items):
        raise InputError(path, f"[[{section}]]: expected an array of tables")
    return items


def _lights(path: Path, data: dict) -> tuple:
    out, environments = [], []
    for index, table in enumerate(_array_of_tables(path, data, "lights")):
        kind = table.get("type")
        where = f"[[lights]] #{index + 1}"
        if kind not in LIGHT_TYPES:
            raise InputError(path, f"{where} type: expected one of {', '.join(LIGHT_TYPES)}, got {kind!r}")
        light = settings_from_table(LIGHT_TYPES[kind], table, path=path, section=f"{where} ({kind})",
                                    ignore=("type",))
        if isinstance(light, EnvmapLight):
            light = replace(light, file=_relative_file(path, light.file, f"{where} (envmap) file"))
            problem = envmap_file_problem(light.file)
            if problem:
                raise InputError(light.file, f"{where} (envmap) of {path}: {problem}")
        out.append(light)
        if kind in ENVIRONMENT_LIGHT_TYPES:
            environments.append(f"#{index + 1} ({kind})")
    if len(environments) > 1:
        raise InputError(path, f"[[lights]] {' and '.join(environments)}: expected at most one environment "
                               f"light ({', '.join(ENVIRONMENT_LIGHT_TYPES)}); Mitsuba takes one per scene")
    return tuple(out)


def _objects(path: Path, data: dict, materials: dict) -> tuple:
    return tuple(object_from_table(table, index=index, path=path, materials=materials)
                 for index, table in enumerate(_array_of_tables(path, data, "objects")))


def _mitsuba_side_files(xml_path: str, seen: frozenset = frozenset()) -> list[str]:
    """Files a Mitsuba scene file names (``<string name="filename">``, ``<include>``), in file order.

    Names are relative to the file's folder, as Mitsuba finds them; only
    files that are there are listed (Mitsuba refuses a missing one when it
    loads the scene), included files with the files they name. A name
    built from a ``$parameter`` is not followed; an unreadable file names
    nothing (its loading refuses it).
    """
    from xml.etree import ElementTree

    try:
        root = ElementTree.parse(xml_path).getroot()
    except (ElementTree.ParseError, OSError):
        return []
    found = []
    for element in root.iter():
        name = element.get("filename") if element.tag == "include" else (
            element.get("value") if element.tag == "string" and element.get("name") == "filename" else None)
        if not name or "$" in name:
            continue
        file = Path(name) if Path(name).is_absolute() else Path(xml_path).parent / name
        if file.is_file() and str(file.absolute()) not in seen | {xml_path}:
            found.append(str(file.absolute()))
            if element.tag == "include":
                found += _mitsuba_side_files(found[-1], seen | {xml_path})
    return list(dict.fromkeys(found))


def _asset_files(objects: tuple, lights: tuple, mitsuba_xml: str, tum: str) -> list[str]:
    """Files the scene reads besides itself, in a fixed order: trajectory, Mitsuba file (and the files
    it names), meshes (each followed by its material and texture files,
    :func:`omnisim.meshes.mesh_side_files`), images."""
    files = [tum] if tum else []
    if mitsuba_xml:
        files += [mitsuba_xml] + _mitsuba_side_files(mitsuba_xml)
    generators = registered_generators()
    for obj in objects:
        for name in [obj.params[p.name] for p in generators[obj.generator].params
                     if p.kind == "file" and obj.params[p.name] is not None]:
            files += [name] + meshes.mesh_side_files(name)
    files += [light.file for light in lights if isinstance(light, EnvmapLight)]
    return files


def _sha256_of(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or exc.__class__.__name__})") from None


def load_scene_config(path, *, spp: int | None = None, resolution=None, frames: int | None = None,
                      variant: str | None = None) -> SceneConfig:
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
    variant : str, optional, keyword-only
        Overrides ``[render] variant``.

    Raises
    ------
    InputError
        Missing or unparsable file, an unknown section or key, a bad value, an
        unknown texture, material, generator or photograph, or a missing file
        (the message names the section and the key). Every table is checked in
        full, also the values the overrides replace; the calibration's aspect
        is checked against the resolution rendered, the override's if given
        (a scene file may leave the rescaling to ``--resolution``, as
        :func:`write_scene_with_kalibr_camera` does).
    """
    path = Path(path)
    raw, data = _read_toml(path)
    scene = settings_from_table(SceneSettings, data.get("scene", {}), path=path, section="[scene]")
    render = settings_from_table(RenderSettings, data.get("render", {}), path=path, section="[render]",
                                 spp=spp, resolution=resolution, variant=variant)
    trajectory = settings_from_table(TrajectorySettings, data.get("trajectory", {}), path=path,
                                     section="[trajectory]", frames=frames)
    if trajectory.tum:
        trajectory = replace(trajectory, tum=_relative_file(path, trajectory.tum, "[trajectory] tum"))
        if "position" not in data.get("trajectory", {}):
            # A TUM file's positions are used as written (a render's own poses_world.txt fed back in
            # gives the same camera); position offsets them only when the table names it.
            trajectory = replace(trajectory, position=_NO_OFFSET_M)
    textures = _textures(path, data)
    materials = _materials(path, data, textures)
    lights = _lights(path, data)
    objects = _objects(path, data, materials)
    mitsuba_xml = _relative_file(path, scene.mitsuba_xml, "[scene] mitsuba_xml") if scene.mitsuba_xml else ""
    files = _asset_files(objects, lights, mitsuba_xml, trajectory.tum)
    assets = tuple((file, _sha256_of(file)) for file in files)
    return SceneConfig(
        path=str(path), sha256=hashlib.sha256(raw).hexdigest(), name=scene.name or path.stem,
        layout_seed=scene.seed, render=render, trajectory=trajectory,
        effects=settings_from_table(EffectsSettings, data.get("effects", {}), path=path, section="[effects]"),
        capture=settings_from_table(CaptureSettings, data.get("capture", {}), path=path, section="[capture]"),
        camera=_camera(path, data.get("camera", {}), render.resolution,
                       key="[render] resolution" if resolution is None else "--resolution"),
        textures=textures, materials=materials, lights=lights, objects=objects,
        mitsuba_xml=mitsuba_xml, assets=assets,
    )


def write_scene_with_kalibr_camera(scene_file, camera_model, folder) -> Path:
    """Copy a scene file with its ``[camera]`` table replaced by a Kalibr camera.

    Parameters
    ----------
    scene_file : path-like
        A scene TOML; every table but ``[camera]`` is copied line for line.
    camera_model : Kalibr camera model
        Written to ``folder/camera.yaml`` (:func:`ifmi.io.kalibr.write_kalibr`).
    folder : path-like
        Made if missing; receives ``scene.toml`` and ``camera.yaml``.

    Returns
    -------
    Path
        ``folder/scene.toml``, whose ``[camera]`` holds ``kalibr = "camera.yaml"``.
    """
    from ifmi.io.atomic import atomic_write_text
    from ifmi.io.kalibr import write_kalibr

    folder = Path(folder)
    out, skipping = [], False
    for line in Path(scene_file).read_text(encoding="utf-8-sig").splitlines():
        if line.startswith("["):
            skipping = line.strip() == "[camera]"
            if skipping:
                out += ["[camera]", 'kalibr = "camera.yaml"', ""]
                continue
        if not skipping:
            out.append(line)
    folder.mkdir(parents=True, exist_ok=True)
    write_kalibr(folder / "camera.yaml", camera_model)
    atomic_write_text(folder / "scene.toml", "\n".join(out) + "\n")
    return folder / "scene.toml"
