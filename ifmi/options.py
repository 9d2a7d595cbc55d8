"""Building frozen option dataclasses from plain mappings (JSON configs), type-checked.

Every value is checked against its dataclass field's annotation before the
dataclass is built: ``bool`` takes only ``true``/``false``; ``int`` only
integers (not booleans, not ``1.5`` or ``1.0``); ``float`` any integer or
float except booleans and NaN; ``str`` only strings; ``X | None`` also
``null``; ``tuple[float, float]`` a list of two numbers;
``tuple[float, ...]`` a list of numbers; a nested dataclass a JSON object,
checked the same way; ``typing.Any`` anything. A wrong value is a
:class:`OptionError` naming the key path (``ifmi.tiling.overlap``), what was
expected and what was got; so is an unknown key, and the value checks of the
dataclass's ``__post_init__`` are reported under the key path of the
dataclass.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Mapping, TypeVar

from ifmi.errors import OptionError

__all__ = ["OptionError", "options_from_dict", "RejectedValues", "replaced_at_paths", "check_finite_fields"]

T = TypeVar("T")
# Longest rendering of a wrong value in a message.
_SHOWN_CHARS = 40




def _shown(value) -> str:
    text = repr(value) if not isinstance(value, bool) else ("true" if value else "false")
    if value is None:
        text = "null"
    text = text if len(text) <= _SHOWN_CHARS else text[:_SHOWN_CHARS - 3] + "..."
    kind = {dict: "object", list: "list", tuple: "list", str: "string", bool: "boolean",
            int: "integer", float: "number", type(None): "null"}.get(type(value), type(value).__name__)
    return kind if value is None else f"{kind} {text}"


def _describe(hint) -> str:
    """Words for the values a type hint accepts."""
    if hint is bool:
        return "true or false"
    if hint is int:
        return "an integer"
    if hint is float:
        return "a number"
    if hint is str:
        return "a string"
    if dataclasses.is_dataclass(hint):
        return "an object with keys " + ", ".join(f.name for f in dataclasses.fields(hint))
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        parts = [_describe(a) for a in args if a is not type(None)]
        return " or ".join(parts) + (" or null" if type(None) in args else "")
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_describe(args[0]).removeprefix('a ').removeprefix('an ')}s"
        return f"a list of {len(args)} values ({', '.join(_describe(a) for a in args)})"
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    return str(hint)


def _checked(value, hint, key: str):
    """``value`` checked against ``hint`` (and converted: int -> float, list -> tuple)."""
    if hint is Any:
        return value
    if hint is bool:
        if isinstance(value, bool):
            return value
    elif hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool) and not (
                isinstance(value, float) and math.isnan(value)):
            return float(value)
    elif hint is str:
        if isinstance(value, str):
            return value
    elif dataclasses.is_dataclass(hint):
        if isinstance(value, hint):
            return value
        if isinstance(value, Mapping):
            return options_from_dict(hint, value, what=key)
    else:
        return _checked_generic(value, hint, key)
    raise OptionError(key, f"expected {_describe(hint)}, got {_shown(value)}")


def _checked_generic(value, hint, key: str):
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            try:
                return _checked(value, options[0], key)
            except OptionError as exc:
                # A plain value's message names every accepted kind; a nested one keeps its own.
                if dataclasses.is_dataclass(options[0]) or exc.key != key:
                    raise
        for option in options:
            try:
                return _checked(value, option, key)
            except OptionError:
                continue
    elif origin is tuple:
        if isinstance(value, (list, tuple)) and len(args) == 2 and args[1] is Ellipsis:
            return tuple(_checked(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if isinstance(value, (list, tuple)) and len(value) == len(args):
            return tuple(_checked(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    elif origin is typing.Literal:
        if value in args and not isinstance(value, bool):
            return value
    else:
        raise TypeError(f"{key}: options_from_dict cannot check values of type {hint}")
    raise OptionError(key, f"expected {_describe(hint)}, got {_shown(value)}")


def options_from_dict(cls: type[T], data: Mapping[str, Any], *, what: str,
                      types_override: Mapping[str, Any] | None = None) -> T:
    """Build the options dataclass ``cls`` from ``data``; missing keys take defaults.

    Parameters
    ----------
    cls : dataclass type
    data : mapping
        Field name to value (nested dataclasses as mappings).
    what : str, keyword-only
        Key path of ``data`` for messages (``"ifmi"``, ``"relative_pose"``;
        ``""`` for the top level).
    types_override : mapping, optional, keyword-only
        Field name to the type its value is checked against, where the
        annotation is looser (e.g. ``typing.Any``).

    Returns
    -------
    cls

    Raises
    ------
    OptionError
        ``data`` is not a mapping, has keys that are not fields of ``cls``
        (the message lists the accepted ones), holds a value of the wrong
        type, or ``cls`` rejects a value (its ``__post_init__`` message,
        under the key path ``what``).
    """
    if not isinstance(data, Mapping):
        raise OptionError(what, f"expected {_describe(cls)}, got {_shown(data)}")
    known = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(known))
    if unknown:
        plural = "s" if len(unknown) > 1 else ""
        raise OptionError(what, f"unknown key{plural} {', '.join(map(str, unknown))}; "
                                f"expected {', '.join(known)}")
    hints = typing.get_type_hints(cls)
    hints.update(types_override or {})
    values = {name: _checked(value, hints[name], f"{what}.{name}" if what else name)
              for name, value in data.items()}
    try:
        return cls(**values)
    except OptionError:
        raise
    except (TypeError, ValueError) as exc:
        raise OptionError(what, str(exc)) from None


class RejectedValues(ValueError):
    """The checks of an option dataclass rejected values :func:`replaced_at_paths` set on it.

    Attributes
    ----------
    sources : tuple of str
        Where the values set directly on that dataclass came from (in order, once each).
    """

    def __init__(self, sources: tuple, message: str) -> None:
        self.sources = sources
        super().__init__(message)


def replaced_at_paths(obj, values: Mapping[str, tuple[str, Any]]):
    """The frozen dataclass ``obj`` with values set at dotted key paths below it.

    Parameters
    ----------
    obj : dataclass instance
    values : mapping of str to (str, object)
        Key path (``ifmi.tiling.overlap``) -> (where the value came from, e.g.
        an option name, and the value). Each dataclass on a path is rebuilt
        once, so its ``__post_init__`` checks all of its new values together.

    Raises
    ------
    RejectedValues
        A dataclass's checks reject its new values; names their sources.
    """
    fields, nested = {}, {}
    for key, item in values.items():
        head, _, rest = key.partition(".")
        if rest:
            nested.setdefault(head, {})[rest] = item
        else:
            fields[head] = item
    changes = {name: replaced_at_paths(getattr(obj, name), sub) for name, sub in nested.items()}
    changes.update({name: value for name, (_, value) in fields.items()})
    try:
        return dataclasses.replace(obj, **changes)
    except ValueError as exc:
        raise RejectedValues(tuple(dict.fromkeys(source for source, _ in fields.values())), str(exc)) from None


def check_finite_fields(options, names) -> None:
    """Raise ``ValueError`` naming the first of the fields ``names`` of ``options`` that is NaN or infinite.

    For ``__post_init__`` checks; a field that is ``None`` (an optional value left open) passes.
    """
    for name in names:
        value = getattr(options, name)
        if value is not None and not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value}")
