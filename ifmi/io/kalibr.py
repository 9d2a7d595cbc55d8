"""Read and write Kalibr camchain YAML files (``camera.yaml``).

The file holds ``cam0`` with ``camera_model``, ``intrinsics``,
``distortion_model``, ``distortion_coeffs`` and ``resolution``
``[width, height]``; other keys of a Kalibr camchain (``T_cam_imu``,
``rostopic``, ...) are allowed and ignored. Further cameras (``cam1``, ...)
are ignored with an :class:`~ifmi.errors.InputWarning`: a dataset's images
are cam0's. Intrinsics are in Kalibr's orders:

=================  ==========================  ==================================
camera_model       intrinsics                  distortion_model (coefficients)
=================  ==========================  ==================================
``pinhole``        ``[fu, fv, pu, pv]``        ``equidistant`` ``[k1, k2, k3, k4]``
                                               (Kannala-Brandt), ``radtan``
                                               ``[k1, k2, r1, r2]`` or ``none``
``omni``           ``[xi, fu, fv, pu, pv]``    ``radtan`` or ``none``
``ds``             ``[xi, alpha, fu, fv, pu,   ``none``
                   pv]``
``eucm``           ``[alpha, beta, fu, fv,     ``none``
                   pu, pv]``
``equirectangular``  ``[]``                    ``none`` (this project's extension
                                               for 360-degree cameras)
=================  ==========================  ==================================

Reading checks every value: numbers must be finite floats; ``resolution``
two integers from :data:`~ifmi.geometry.camera.MIN_IMAGE_SIDE_PX` to
:data:`~ifmi.geometry.camera.MAX_IMAGE_SIDE_PX`; and the model must image a usable
region (:func:`~ifmi.geometry.camera_models.check_usable_region`: the principal point
inside the image, the pixel there valid and of a plausible angle).

Numbers are written with Python's shortest round-trip representation, so
``read_kalibr(write_kalibr(model))`` gives back the same model bit for bit.
"""

from __future__ import annotations

import math
import os
import re
import reprlib
import warnings
from pathlib import Path

from ifmi.geometry.camera import MAX_IMAGE_SIDE_PX, MIN_IMAGE_SIDE_PX
from ifmi.geometry.camera_models import (
    DoubleSphereModel,
    EquirectangularModel,
    ExtendedUnifiedModel,
    KannalaBrandtModel,
    PinholeModel,
    UnifiedModel,
    check_usable_region,
)
from ifmi.errors import InputError, InputWarning
from ifmi.io.atomic import atomic_write_text
from ifmi.io.text_file import read_text_file

__all__ = ["read_kalibr", "parse_kalibr", "format_kalibr", "write_kalibr", "KALIBR_INTRINSICS"]

# camera_model -> names of its intrinsics, in Kalibr's order.
KALIBR_INTRINSICS = {
    "pinhole": ("fu", "fv", "pu", "pv"),
    "omni": ("xi", "fu", "fv", "pu", "pv"),
    "ds": ("xi", "alpha", "fu", "fv", "pu", "pv"),
    "eucm": ("alpha", "beta", "fu", "fv", "pu", "pv"),
    "equirectangular": (),
}
# Messages show values of the file briefly: integers longer than this by their size (a float
# reaches 2**1024), lists up to this many items, nestings this deep (cam0 lists have 6 items).
_SHOWN_INT_BITS = 1024
_SHOWN_ITEMS = 8
_SHOWN_LEVELS = 3
# camera_model -> distortion models it accepts, with their coefficient counts.
_DISTORTIONS = {
    "pinhole": {"equidistant": 4, "radtan": 4, "none": 0},
    "omni": {"radtan": 4, "none": 0},
    "ds": {"none": 0},
    "eucm": {"none": 0},
    "equirectangular": {"none": 0},
}


def _as_number(value):
    # PyYAML (YAML 1.1) reads numbers such as 1e-5 (no dot) as strings; accept them.
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


class _ShortRepr(reprlib.Repr):
    """``repr`` for messages: long lists, nestings and strings cut short, huge integers by their size."""

    def __init__(self) -> None:
        super().__init__()
        self.maxlist = self.maxtuple = self.maxdict = _SHOWN_ITEMS
        self.maxlevel = _SHOWN_LEVELS

    def repr_int(self, x, level) -> str:
        if x.bit_length() > _SHOWN_INT_BITS:
            return f"<integer of {x.bit_length()} bits>"
        return super().repr_int(x, level)


_shown = _ShortRepr().repr


def _numbers(source, key: str, value, count: int | None) -> list[float]:
    if isinstance(value, list):
        value = [_as_number(v) for v in value]
    if not isinstance(value, list) or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                          for v in value):
        raise InputError(source, f"cam0.{key}: expected a list of numbers, got {_shown(value)}")
    if count is not None and len(value) != count:
        raise InputError(source, f"cam0.{key}: expected {count} values, got {len(value)}")
    try:
        numbers = [float(v) for v in value]
    except OverflowError:  # an integer beyond the floating-point range
        numbers = [math.inf]
    if not all(math.isfinite(v) for v in numbers):
        raise InputError(source, f"cam0.{key}: expected finite numbers, got {_shown(value)}")
    return numbers


def _resolution(source, value) -> tuple[int, int]:
    if (not isinstance(value, list) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, int)
                   or not MIN_IMAGE_SIDE_PX <= v <= MAX_IMAGE_SIDE_PX for v in value)):
        raise InputError(source, f"cam0.resolution: expected [width, height] integers from {MIN_IMAGE_SIDE_PX} "
                                 f"to {MAX_IMAGE_SIDE_PX}, got {_shown(value)}")
    width, height = value
    return int(height), int(width)


def _model_from_fields(kind: str, distortion: str, p: list[float], coeffs: list[float], size):
    if kind == "pinhole" and distortion == "equidistant":
        return KannalaBrandtModel((p[0], p[1]), (p[2], p[3]), size, tuple(coeffs))
    if kind == "pinhole":
        return PinholeModel.create((p[0], p[1]), (p[2], p[3]), size, tuple(coeffs))
    if kind == "omni":
        return UnifiedModel(p[0], (p[1], p[2]), (p[3], p[4]), size, tuple(coeffs))
    if kind == "ds":
        return DoubleSphereModel(p[0], p[1], (p[2], p[3]), (p[4], p[5]), size)
    if kind == "eucm":
        return ExtendedUnifiedModel(p[0], p[1], (p[2], p[3]), (p[4], p[5]), size)
    return EquirectangularModel(size)


def _yaml_without_duplicate_keys(text: str):
    """``yaml.safe_load`` of ``text``, but a key given twice in one mapping is an error (PyYAML keeps
    the last one silently)."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    def mapping(loader, node, deep=False):
        keys = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # "<<: *anchor" entries may be overridden
                continue
            key = loader.construct_object(key_node, deep=deep)
            try:
                hash(key)
            except TypeError:  # "? [a, b]": what PyYAML's own mapping constructor says of it
                raise yaml.constructor.ConstructorError("while constructing a mapping", node.start_mark,
                                                        "found unhashable key", key_node.start_mark) from None
            if key in keys:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice in one mapping; expected each key once",
                    key_node.start_mark)
            keys.add(key)
        return loader.construct_mapping(node, deep=deep)

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    return yaml.load(text, Loader=Loader)


def _cam0(text: str, source) -> dict:
    import yaml

    try:
        data = _yaml_without_duplicate_keys(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or exc.__class__.__name__
        raise InputError(source, f"not valid YAML{where}: {problem}") from None
    except ValueError as exc:  # Python refuses integers of more than 4300 digits
        raise InputError(source, f"not valid YAML: {str(exc).split(';')[0]}") from None
    except RecursionError:  # PyYAML composes nested nodes recursively
        raise InputError(source, "not valid YAML: nested too deeply") from None
    if not isinstance(data, dict) or not isinstance(data.get("cam0"), dict):
        raise InputError(source, "expected a Kalibr camchain with a 'cam0' mapping, found none")
    others = sorted((key for key in data if isinstance(key, str) and re.fullmatch(r"cam[1-9][0-9]*", key)),
                    key=lambda key: int(key[3:]))
    if others:
        warnings.warn(f"{source}: a camchain of {len(others) + 1} cameras; the images are taken to be "
                      f"cam0's ({', '.join(others)} ignored)", InputWarning, stacklevel=4)
    cam = data["cam0"]
    for key in ("camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution"):
        if key not in cam:
            raise InputError(source, f"cam0.{key}: missing")
    return cam


def parse_kalibr(text: str, *, source: str | os.PathLike = "<camera.yaml>"):
    """Parse the text of a Kalibr camchain file into a camera model.

    Parameters
    ----------
    text : str
        File contents.
    source : str or path, keyword-only
        Name used in error messages.

    Returns
    -------
    UnifiedModel, PinholeModel, ExtendedUnifiedModel, DoubleSphereModel, KannalaBrandtModel
    or EquirectangularModel

    Raises
    ------
    InputError
        YAML syntax error, missing ``cam0`` or key, unknown camera or
        distortion model, wrong number of values, non-finite values, bad
        resolution, parameters out of the model's range, or a model that
        images no usable region.
    """
    cam = _cam0(text, source)
    kind, distortion = cam["camera_model"], cam["distortion_model"]
    if not isinstance(kind, str) or kind not in KALIBR_INTRINSICS:
        raise InputError(source, f"cam0.camera_model: expected one of {', '.join(KALIBR_INTRINSICS)}, "
                                 f"got {_shown(kind)}")
    if not isinstance(distortion, str) or distortion not in _DISTORTIONS[kind]:
        raise InputError(source, f"cam0.distortion_model: expected one of "
                                 f"{', '.join(_DISTORTIONS[kind])} for camera_model {kind}, got {_shown(distortion)}")
    intrinsics = _numbers(source, "intrinsics", cam["intrinsics"], len(KALIBR_INTRINSICS[kind]))
    coeffs = _numbers(source, "distortion_coeffs", cam["distortion_coeffs"], _DISTORTIONS[kind][distortion])
    size = _resolution(source, cam["resolution"])
    try:
        model = _model_from_fields(kind, distortion, intrinsics, coeffs, size)
    except ValueError as exc:
        raise InputError(source, f"cam0: {exc}") from None
    try:
        check_usable_region(model)
    except ValueError as exc:
        raise InputError(source, f"cam0.intrinsics: {exc}") from None
    return model


def read_kalibr(path: str | os.PathLike):
    """Read a Kalibr camchain ``camera.yaml`` (see :func:`parse_kalibr`).

    Raises
    ------
    InputError
        Missing, unreadable or malformed file; the message names it.
    """
    path = Path(path)
    return parse_kalibr(read_text_file(path, what="calibration file"), source=path)


def kalibr_fields(model) -> dict:
    """``cam0`` entries of a model: camera_model, intrinsics, distortion, resolution."""
    kind = model.kalibr_model
    if isinstance(model, EquirectangularModel):
        intrinsics = []
    elif isinstance(model, PinholeModel) or isinstance(model, KannalaBrandtModel):
        intrinsics = [*model.focal, *model.principal_point]
    elif isinstance(model, UnifiedModel):
        intrinsics = [model.xi, *model.focal, *model.principal_point]
    elif isinstance(model, DoubleSphereModel):
        intrinsics = [model.xi, model.alpha, *model.focal, *model.principal_point]
    elif isinstance(model, ExtendedUnifiedModel):
        intrinsics = [model.alpha, model.beta, *model.focal, *model.principal_point]
    else:
        raise ValueError(f"no Kalibr form for a {type(model).__name__}")
    return {"camera_model": kind, "intrinsics": [float(v) for v in intrinsics],
            "distortion_model": model.distortion_model,
            "distortion_coeffs": [float(v) for v in model.distortion],
            "resolution": [int(model.width), int(model.height)]}


def _yaml_number(value) -> str:
    # Shortest round-trip digits; YAML 1.1 reads an exponent without a dot as a string.
    text = repr(value)
    if isinstance(value, float) and "e" in text and "." not in text:
        text = text.replace("e", ".0e")
    return text


def _flow_list(values) -> str:
    return "[" + ", ".join(_yaml_number(v) for v in values) + "]"


def format_kalibr(model) -> str:
    """Kalibr camchain text of ``model`` (readable by Kalibr's tools)."""
    f = kalibr_fields(model)
    return ("cam0:\n"
            f"  camera_model: {f['camera_model']}\n"
            f"  intrinsics: {_flow_list(f['intrinsics'])}\n"
            f"  distortion_model: {f['distortion_model']}\n"
            f"  distortion_coeffs: {_flow_list(f['distortion_coeffs'])}\n"
            f"  resolution: {_flow_list(f['resolution'])}\n")


def write_kalibr(path: str | os.PathLike, model) -> None:
    """Write ``model`` to ``path`` atomically as a Kalibr camchain file."""
    atomic_write_text(path, format_kalibr(model))
