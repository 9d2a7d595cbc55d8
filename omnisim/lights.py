"""Lights of ``[[lights]]``: settings of each type and their Mitsuba emitter dicts.

Types: ``sky`` (a procedural gradient sky), ``sun`` (a directional light),
``constant`` (uniform environment radiance) and ``envmap`` (a latitude-longitude
image file: HDR, EXR or PNG). World frame: metres, z up.

An ``envmap`` with ``rotation_deg = [0, 0, 0]`` has its top image row straight
up (+z); its left edge column faces +y, the column a quarter across faces +x
and the middle column faces -y (Mitsuba's lat-long convention turned z-up).
``rotation_deg`` = [roll, pitch, yaw] then turns it about the world axes with
``R = Rz(yaw) Ry(pitch) Rx(roll)`` (the project's ZYX convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


from omnisim.settings import MAX_RADIANCE, SettingError, check_fields, setting

__all__ = ["SkyLight", "SunLight", "ConstantLight", "EnvmapLight", "LIGHT_TYPES", "ENVIRONMENT_LIGHT_TYPES", "sky_image",
           "emitter_dict", "envmap_file_problem"]

# Mitsuba's lat-long maps have their pole on +y; this turn about x puts it on the world's +z.
LATLONG_POLE_TURN_DEG = 90.0
# Width of the procedural sky image, pixels (height is half of it).
SKY_WIDTH = 256


@dataclass(frozen=True)
class SkyLight:
    """``type = "sky"``: a gradient from the horizon to the zenith colour, uniform ground below."""

    zenith: tuple[float, float, float] = setting((0.25, 0.45, 0.9), "linear RGB radiance straight up",
                                                 minimum=0.0, maximum=MAX_RADIANCE)
    horizon: tuple[float, float, float] = setting((0.8, 0.85, 0.95), "linear RGB radiance at the horizon",
                                                  minimum=0.0, maximum=MAX_RADIANCE)
    ground: tuple[float, float, float] = setting((0.3, 0.3, 0.3), "linear RGB radiance below the horizon",
                                                 minimum=0.0, maximum=MAX_RADIANCE)
    scale: float = setting(1.0, "radiance multiplier", minimum=0.0, maximum=MAX_RADIANCE)

    def __post_init__(self):
        check_fields(self)
        brightest = self.scale * max(self.zenith + self.horizon + self.ground)
        if brightest > MAX_RADIANCE:
            raise SettingError("scale", f"expected scale times the brightest radiance <= {MAX_RADIANCE:g} "
                                        f"(the renderer sums samples in float32), got {brightest:.4g}")


@dataclass(frozen=True)
class SunLight:
    """``type = "sun"``: a directional light."""

    azimuth_deg: float = setting(40.0, "direction towards the sun, degrees from +x towards +y")
    elevation_deg: float = setting(45.0, "sun height above the horizon, degrees", minimum=-90.0, maximum=90.0)
    irradiance: tuple[float, float, float] = setting((3.0, 2.9, 2.7), "linear RGB irradiance", minimum=0.0,
                                                     maximum=MAX_RADIANCE)

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class ConstantLight:
    """``type = "constant"``: the same radiance from every direction."""

    radiance: tuple[float, float, float] = setting((0.2, 0.2, 0.2), "linear RGB radiance", minimum=0.0,
                                                   maximum=MAX_RADIANCE)

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class EnvmapLight:
    """``type = "envmap"``: a latitude-longitude environment image (HDR, EXR or PNG)."""

    file: str = setting(doc="image file, relative to the scene file")
    scale: float = setting(1.0, "radiance multiplier (times the brightest pixel at most 1e27)", minimum=0.0,
                           maximum=MAX_RADIANCE)
    rotation_deg: tuple[float, float, float] = setting((0.0, 0.0, 0.0),
                                                       "[roll, pitch, yaw] about world x, y, z, degrees")

    def __post_init__(self):
        check_fields(self)


# The classes a light table's ``type`` key selects.
LIGHT_TYPES = {"sky": SkyLight, "sun": SunLight, "constant": ConstantLight, "envmap": EnvmapLight}
# The light types that are Mitsuba environment emitters, of which a scene holds one at most.
ENVIRONMENT_LIGHT_TYPES = ("sky", "constant", "envmap")


# Leading bytes of the high-dynamic-range files Mitsuba reads that Pillow does not: OpenEXR,
# Radiance RGBE (.hdr) and PFM. Other formats (PNG, JPEG, ...) are checked through Pillow.
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_RGBE_MAGICS = (b"#?RADIANCE", b"#?RGBE")
_PFM_MAGICS = (b"PF", b"Pf")
# Leading bytes of PNG and JPEG files (checked through Pillow).
_PILLOW_SIGNATURES = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8")
# Bytes of a header read to find an image's size (an EXR header is a few hundred bytes; a long
# RGBE comment block is refused as damaged rather than read on).
_HEADER_BYTES = 65536


def envmap_file_problem(path) -> str:
    """Why the environment image at ``path`` cannot be loaded ("" when it can be tried).

    Read from the header alone, before Mitsuba loads the pixels: a file that is
    no image (Mitsuba then reports a failed seek), a damaged header, or a size
    beyond the one the mesh texture reader accepts (twice Pillow's
    ``MAX_IMAGE_PIXELS``), whose pixels would be allocated before the file is
    found to be short.

    Parameters
    ----------
    path : str or path
        The envmap file.

    Returns
    -------
    str
        The problem, worded to follow the file's name; "" when the header is sound.
    """
    from PIL import Image

    from omnisim.meshes import image_open_problem

    with open(path, "rb") as fh:
        head = fh.read(_HEADER_BYTES)
    limit = 2 * Image.MAX_IMAGE_PIXELS
    if head.startswith(_EXR_MAGIC) or head.startswith(_RGBE_MAGICS) or head[:2] in _PFM_MAGICS:
        size = _hdr_header_size(head)
        if size is None:
            return "is a damaged image file (its header gives no size)"
        if size[0] * size[1] > limit:
            return (f"is too large to be read ({size[0]} x {size[1]} pixels, width x height, in its header; "
                    f"at most {limit} pixels)")
        return ""
    with open(path, "rb") as fh:
        problem = image_open_problem(fh.read())
    if problem and not head.startswith(_PILLOW_SIGNATURES):
        return "is no image file (expected EXR, HDR, PFM, PNG or JPEG)"
    return problem


def _hdr_header_size(head: bytes) -> tuple[int, int] | None:
    """``(width, height)`` from the header of an OpenEXR, RGBE or PFM file, or None when it has none."""
    import re
    import struct

    if head.startswith(_EXR_MAGIC):
        at = 8  # magic number and version
        while at < len(head) and head[at] != 0:
            name_end = head.find(b"\0", at)
            type_end = head.find(b"\0", name_end + 1)
            if name_end < 0 or type_end < 0 or type_end + 4 > len(head):
                return None
            (length,) = struct.unpack_from("<i", head, type_end + 1)
            value = type_end + 5
            if head[at:name_end] == b"dataWindow" and length == 16 and value + 16 <= len(head):
                x_min, y_min, x_max, y_max = struct.unpack_from("<4i", head, value)
                return x_max - x_min + 1, y_max - y_min + 1
            at = value + max(length, 0)
        return None
    if head.startswith(_RGBE_MAGICS):
        match = re.search(rb"\n\n[-+]([XY]) (\d+) [-+]([XY]) (\d+)\s", head)
        if match is None:
            return None
        first, second = int(match[2]), int(match[4])
        return (second, first) if match[1] == b"Y" else (first, second)
    match = re.match(rb"P[Ff]\s+(\d+)\s+(\d+)\s", head)
    return None if match is None else (int(match[1]), int(match[2]))


def sky_image(*, zenith, horizon, ground, width: int = SKY_WIDTH) -> np.ndarray:
    """Latitude-longitude sky, ``(width/2, width, 3)`` float32: row 0 is straight up (linear RGB)."""
    height = width // 2
    elevation = (0.5 - (np.arange(height) + 0.5) / height) * math.pi
    t = np.clip(np.sin(elevation), 0, 1)[:, None] ** 0.5
    sky = (1 - t) * np.asarray(horizon)[None, :] + t * np.asarray(zenith)[None, :]
    sky = np.where((elevation < 0)[:, None], np.asarray(ground)[None, :], sky)
    return np.ascontiguousarray(np.repeat(sky[:, None, :], width, axis=1).astype(np.float32))


def emitter_dict(mi, light) -> dict:
    """Mitsuba emitter dict of validated light settings.

    Parameters
    ----------
    mi : module
        Imported Mitsuba with its variant set.
    light : SkyLight, SunLight, ConstantLight or EnvmapLight
        An envmap's ``file`` is an absolute path.
    """
    pole_up = mi.ScalarTransform4f().rotate([1, 0, 0], LATLONG_POLE_TURN_DEG)
    if isinstance(light, SkyLight):
        image = sky_image(zenith=light.zenith, horizon=light.horizon, ground=light.ground)
        return {"type": "envmap", "bitmap": mi.Bitmap(image), "scale": light.scale, "to_world": pole_up}
    if isinstance(light, SunLight):
        az, el = math.radians(light.azimuth_deg), math.radians(light.elevation_deg)
        direction = [-math.cos(el) * math.cos(az), -math.cos(el) * math.sin(az), -math.sin(el)]
        return {"type": "directional", "direction": direction,
                "irradiance": {"type": "rgb", "value": list(light.irradiance)}}
    if isinstance(light, ConstantLight):
        return {"type": "constant", "radiance": {"type": "rgb", "value": list(light.radiance)}}
    from ifmi.geometry.rotations import matrix_from_rpy  # scipy: imported when a scene is built

    turn = np.eye(4)
    turn[:3, :3] = matrix_from_rpy(np.radians(np.asarray(light.rotation_deg, dtype=np.float64)))
    return {"type": "envmap", "filename": light.file, "scale": light.scale,
            "to_world": mi.ScalarTransform4f(turn.tolist()) @ pole_up}
