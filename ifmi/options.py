"""Building frozen option dataclasses from plain mappings (JSON configs)."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Mapping, TypeVar

__all__ = ["options_from_dict"]

T = TypeVar("T")


def options_from_dict(cls: type[T], data: Mapping[str, Any], *, what: str) -> T:
    """Build the options dataclass ``cls`` from ``data``; missing keys take defaults.

    Parameters
    ----------
    cls : dataclass type
    data : mapping
        Field name to value.
    what : str, keyword-only
        What the keys are, for the error message (e.g. ``"feature options"``).

    Raises
    ------
    ValueError
        ``data`` has keys that are not fields of ``cls``; the message lists
        them and the expected ones.
    """
    known = {f.name for f in fields(cls)}
    unknown = set(data) - known
    if unknown:
        raise ValueError(f"unknown {what} {sorted(unknown)}; expected {sorted(known)}")
    return cls(**data)
