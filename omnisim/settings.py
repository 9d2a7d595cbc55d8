"""Declared settings: typed, documented fields of frozen dataclasses, checked in one place.

Every settings class of a scene file (``[render]``, ``[trajectory]``, a
material, a light, ...) is a frozen dataclass whose fields are declared with
:func:`setting`: a default (written once, here), a one-line doc and bounds.
Its ``__post_init__`` calls :func:`check_fields`, which checks and normalises
each value against the field's type (``int``, ``float``, ``bool``, ``str``,
``tuple[float, float, float]``, ``tuple[float, ...]``, ``tuple[str, ...]``,
optionally ``| None``) and bounds, and raises :class:`SettingError` naming the
key, what was expected and what was got. :func:`settings_from_table` builds a
class from one TOML table and turns every problem -- an unknown key included
-- into a one-line :class:`~ifmi.errors.InputError` naming the file, the
section and the key.
"""

from __future__ import annotations

import types
import typing
from dataclasses import MISSING, field, fields
from functools import lru_cache
from typing import Any, Mapping

import numpy as np

from ifmi.errors import InputError

# Largest magnitude of a decimal setting: Mitsuba stores scene values as float32, whose largest
# finite value this is; a larger one turns into inf there (garbage pixels, or a NaN pose).
FLOAT32_MAX = float(np.finfo(np.float32).max)
# Largest radiance (or irradiance) of a light, times its scale, linear RGB. The film sums a pixel's
# samples in float32: up to 2**30 samples (the spp bound) of paths of up to 64 bounces (the
# max_depth bound), so contributions below FLOAT32_MAX / 2**36 = 4.9e27 keep the sum finite; a
# larger one can overflow to inf, which comes out as NaN -- black pixels.
MAX_RADIANCE = 1e27
# Farthest a camera may be from the world origin, metres. The renderer places the camera and the
# geometry around it in float32, whose spacing at 1e4 m is 2**-10 m (0.98 mm): a camera there lies
# within 0.5 mm of its ground-truth position, which a 1024 px frame cannot see at 1 m (6 mm per
# pixel). The spacing doubles with each doubling of the distance (0.5 m at 1e7 m, as UTM
# coordinates are), and at 1e8 m the ground under the camera renders as speckle, with no error.
MAX_CAMERA_REACH_M = 1e4

__all__ = ["FLOAT32_MAX", "MAX_CAMERA_REACH_M", "MAX_RADIANCE", "SettingError", "setting", "check_fields", "check_value", "check_bounds",
           "settings_from_table",
           "type_name", "field_docs"]


class SettingError(ValueError):
    """A setting that does not fit its declaration; ``key`` and ``problem`` ("expected X, got Y")."""

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f"{key}: {problem}")


def setting(default=MISSING, doc: str = "", *, minimum=None, maximum=None, above=None,
            choices=None):
    """A dataclass field with a default, a doc line and bounds checked by :func:`check_fields`.

    Parameters
    ----------
    default : object
        The default value (the only place it is written); leave out for a required field.
    doc : str
        One line for users, with the unit.
    minimum, maximum : float, optional, keyword-only
        Inclusive bounds of a number (of each element of a tuple of numbers).
    above : float, optional, keyword-only
        Exclusive lower bound.
    choices : sequence, optional, keyword-only
        The allowed values.
    """
    metadata = {"doc": doc, "minimum": minimum, "maximum": maximum, "above": above,
                "choices": tuple(choices) if choices is not None else None}
    return field(default=default, metadata=metadata)


def type_name(hint) -> str:
    """User-facing name of a declared type (``float``, ``[float, float, float]``, ``[str, ...]``)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return f"{type_name(inner[0])} or none"
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"[{type_name(args[0])}, ...]"
        return "[" + ", ".join(type_name(a) for a in args) + "]"
    return getattr(hint, "__name__", str(hint))


def _scalar(hint, value, key):
    if hint is bool:
        if not isinstance(value, bool):
            raise SettingError(key, f"expected true or false, got {value!r}")
        return value
    if hint in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SettingError(key, f"expected {'an integer' if hint is int else 'a number'}, got {value!r}")
        if value != value or value in (float("inf"), float("-inf")):
            raise SettingError(key, f"expected a finite number, got {value!r}")
        if hint is int:
            if int(value) != value:
                raise SettingError(key, f"expected an integer, got {value!r}")
            return int(value)
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise SettingError(key, f"expected a string, got {value!r}")
        return value
    if isinstance(hint, type) and isinstance(value, hint):
        return value
    raise SettingError(key, f"expected {type_name(hint)}, got {value!r}")


def check_value(hint, value, key: str):
    """``value`` checked against the declared type ``hint`` and normalised (lists become tuples)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None:
            return None
        return check_value([a for a in args if a is not type(None)][0], value, key)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise SettingError(key, f"expected {type_name(hint)}, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            element_types = [args[0]] * len(value)
        else:
            element_types = list(args)
            if len(value) != len(args):
                raise SettingError(key, f"expected {len(args)} values {type_name(hint)}, got {list(value)!r}")
        try:
            return tuple(_scalar(t, v, key) for t, v in zip(element_types, value))
        except SettingError:
            raise SettingError(key, f"expected {type_name(hint)}, got {list(value)!r}") from None
    return _scalar(hint, value, key)


def check_bounds(value, key: str, *, minimum=None, maximum=None, above=None, choices=None) -> None:
    """Check a checked ``value`` (a number, or each number of a tuple) against declared bounds.

    Parameters
    ----------
    value : object
        The value, already of its declared type (non-numbers are skipped by the number bounds).
    key : str
        The key named in the error.
    minimum, maximum : float, optional, keyword-only
        Inclusive bounds.
    above : float, optional, keyword-only
        Exclusive lower bound.
    choices : sequence, optional, keyword-only
        The allowed values.

    Raises
    ------
    SettingError
        A value out of bounds ("expected >= 0.0, got [-1.0, 2.0]"), or a decimal
        value beyond float32's range (:data:`FLOAT32_MAX`), which the renderer stores.
    """
    values = value if isinstance(value, tuple) else (value,)
    for v in values:
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        if isinstance(v, float) and abs(v) > FLOAT32_MAX:
            raise SettingError(key, f"expected magnitudes <= {FLOAT32_MAX:.4g} (the renderer stores float32), "
                                    f"got {_show(value)}")
        if minimum is not None and v < minimum:
            raise SettingError(key, f"expected >= {minimum}, got {_show(value)}")
        if maximum is not None and v > maximum:
            raise SettingError(key, f"expected <= {maximum}, got {_show(value)}")
        if above is not None and v <= above:
            raise SettingError(key, f"expected > {above}, got {_show(value)}")
    if choices is not None:
        for v in values:
            if v not in choices:
                shown = ", ".join(repr(c) if isinstance(c, str) else str(c) for c in choices)
                raise SettingError(key, f"expected one of {shown}, got {v!r}")


def _show(value):
    return list(value) if isinstance(value, tuple) else repr(value)


@lru_cache(maxsize=None)
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def check_fields(obj) -> None:
    """Check and normalise every declared field of the frozen dataclass ``obj`` in place.

    Raises
    ------
    SettingError
        The first field whose value does not fit its type or bounds.
    """
    hints = _hints(type(obj))
    for f in fields(obj):
        if not f.init:
            continue
        value = check_value(hints[f.name], getattr(obj, f.name), f.name)
        if value is not None:
            check_bounds(value, f.name, minimum=f.metadata.get("minimum"), maximum=f.metadata.get("maximum"),
                         above=f.metadata.get("above"), choices=f.metadata.get("choices"))
        object.__setattr__(obj, f.name, value)


def field_docs(cls) -> list[tuple[str, str, Any, str]]:
    """``(name, type name, default, doc)`` of every init field of a settings class."""
    hints = _hints(cls)
    out = []
    for f in fields(cls):
        if not f.init:
            continue
        default = f.default if f.default is not MISSING else None
        out.append((f.name, type_name(hints[f.name]), default, f.metadata.get("doc", "")))
    return out


def settings_from_table(cls, table: Mapping, *, path, section: str, ignore=(), **extra):
    """Build the settings class ``cls`` from one TOML table of the file ``path``.

    Parameters
    ----------
    cls : dataclass type
        A frozen dataclass whose ``__post_init__`` raises :class:`SettingError`.
    table : mapping
        The table's keys and values.
    path : path, keyword-only
        The scene file, named in errors.
    section : str, keyword-only
        How the table is written in messages, e.g. ``"[render]"``.
    ignore : sequence of str, keyword-only
        Keys of ``table`` read elsewhere (e.g. a type selector).
    **extra
        Values that replace the table's (command-line overrides; None means not given).
        Errors in them name the option (``--key``). The table is checked as
        written first, so a bad value in the file is an error even where an
        override replaces it.

    Raises
    ------
    InputError
        A key that is not a field (the message lists the accepted keys), a
        missing required key, or a value of the table or of an override that
        does not fit (the message names the key or the option).
    """
    if not isinstance(table, Mapping):
        raise InputError(path, f"{section}: expected a table, got {type(table).__name__}")
    accepted = [f.name for f in fields(cls) if f.init]
    for key in table:
        if key not in accepted and key not in ignore:
            raise InputError(path, f"{section} {key}: unknown key; accepted keys: "
                                   f"{', '.join(list(ignore) + accepted)}")
    values = {k: v for k, v in table.items() if k not in ignore}
    missing = [f.name for f in fields(cls) if f.init and f.default is MISSING
               and f.default_factory is MISSING and f.name not in values]
    if missing:
        raise InputError(path, f"{section} {missing[0]}: missing (required)")
    # The table as written is checked in full, the values an option replaces included:
    # a scene file must stay valid without the command line it was rendered with.
    settings = _build(cls, values, path=path, section=section, overrides={})
    overrides = {k: v for k, v in extra.items() if v is not None}
    if not overrides:
        return settings
    return _build(cls, {**values, **overrides}, path=path, section=section, overrides=overrides)


def _build(cls, values: dict, *, path, section: str, overrides: Mapping):
    """``cls(**values)``, a :class:`SettingError` turned into the file's one-line :class:`InputError`.

    The error names the option (``--key``) when the bad key is one of ``overrides``.
    """
    try:
        return cls(**values)
    except SettingError as exc:
        where = f"--{exc.key.replace('_', '-')}" if exc.key in overrides else f"{section} {exc.key}"
        raise InputError(path, f"{where}: {exc.problem}") from None
