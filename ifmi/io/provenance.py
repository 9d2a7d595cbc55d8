"""Provenance of results: versions of the installed packages that shape them."""

from __future__ import annotations

from importlib import metadata
from typing import Iterable

__all__ = ["package_versions"]


def package_versions(names: Iterable[str]) -> dict[str, str | None]:
    """Installed version of each distribution in ``names`` (``None`` where it is not installed)."""
    out: dict[str, str | None] = {}
    for name in names:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
