"""JSON files of settings: the one reader of estimate configurations (``--config``).

``ifmi estimate --config`` and ``ifmi sweep --config`` both read their file
with :func:`read_estimate_config`, which accepts either an
:meth:`~ifmi.pipeline.EstimateConfig.to_dict` document or an estimate's
``NAME.config.json`` (whose ``config`` entry is that document).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..errors import InputError

__all__ = ["read_json_object", "read_estimate_config", "estimate_config_from_document"]


def read_json_object(path: str | os.PathLike, *, what: str = "JSON file") -> dict:
    """Read a JSON file whose top level must be an object.

    Parameters
    ----------
    path : path-like
    what : str, keyword-only
        What the file is, for messages (``"configuration file"``).

    Returns
    -------
    dict

    Raises
    ------
    InputError
        Missing or unreadable file, invalid JSON (with its line), or valid
        JSON that is not an object (``[]``, a number, ...).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except IsADirectoryError:
        raise InputError(path, f"is a folder; expected a {what}") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or exc.__class__.__name__
        raise InputError(path, f"cannot read {what} ({reason})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise InputError(path, "invalid JSON: nested too deeply") from None
    if not isinstance(data, dict):
        kind = {list: "an array", str: "a string", bool: "a boolean", type(None): "null"}.get(
            type(data), "a number")
        raise InputError(path, f"expected a JSON object {{...}} at the top level, got {kind}")
    return data


def estimate_config_from_document(data: dict, *, source: str | os.PathLike):
    """:class:`~ifmi.pipeline.EstimateConfig` of a configuration document.

    ``data`` is an ``EstimateConfig.to_dict()`` mapping, or an estimate's
    ``NAME.config.json`` content (an object with ``method`` and ``config``).

    Raises
    ------
    InputError
        Named after ``source``: an unknown key, or a value of the wrong type
        or out of range (the key path, what was expected, what was got).
    """
    from ..pipeline import EstimateConfig

    if "config" in data and "method" in data:
        data = data["config"]
        if not isinstance(data, dict):
            raise InputError(source, f"invalid configuration: config: expected an object, "
                                     f"got {type(data).__name__}")
    try:
        return EstimateConfig.from_dict(data)
    except ValueError as exc:
        raise InputError(source, f"invalid configuration: {exc}") from None


def read_estimate_config(path: str | os.PathLike):
    """Read an estimate configuration file (see the module docstring).

    Returns
    -------
    ifmi.pipeline.EstimateConfig

    Raises
    ------
    InputError
        Missing or unreadable file, not a JSON object, an unknown key, or a
        value of the wrong type or out of range; one line naming the file.
    """
    return estimate_config_from_document(read_json_object(path, what="configuration file"),
                                         source=path)
