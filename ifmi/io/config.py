"""JSON files of settings: the one reader of estimate configurations (``--config``).

``ifmi estimate --config`` and ``ifmi sweep --config`` both read their file
with :func:`read_config_file` (or :func:`read_estimate_config`), which
accepts either an :meth:`~ifmi.config.EstimateConfig.to_dict` document or
an estimate's ``NAME.config.json`` (whose ``config`` entry is that document,
beside the run's ``method``).

Every value of a ``to_dict()`` document is used as it stands. An estimate's
``NAME.config.json`` also holds values the run derived from its camera and
frames (:data:`DERIVED_KEYS`: the RANSAC threshold in radians converted from
the one in pixels, the band radii detected in the frames); the file lists
them under ``derived``, and the reader sets them back to ``None`` so that
they are derived again for the camera and frames at hand. A file without
that list (written by a sweep, a benchmark or an older version) counts all
of :data:`DERIVED_KEYS` as derived. So a run's file repeats the run on its
own dataset and carries no camera's values to another camera.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ifmi.errors import InputError
from ifmi.options import replaced_at_paths
from ifmi.io.text_file import read_text_file

if TYPE_CHECKING:
    from ifmi.config import EstimateConfig

__all__ = ["read_json_object", "read_estimate_config", "read_config_file",
           "ConfigFile", "DERIVED_KEYS"]

# Configuration values an estimate derives from its camera and frames when they are None; an
# estimate's NAME.config.json lists the ones it derived under "derived" (see the module docstring).
DERIVED_KEYS = ("relative_pose.ransac_threshold_rad", "ifmi.panorama.radius_min_px",
                "ifmi.panorama.radius_max_px")
# Largest JSON file read: a configuration document (EstimateConfig.to_dict()) is about 3 kB and an
# estimate's NAME.config.json about 4 kB, so 1 MiB is over 250 times either and reads in
# milliseconds; a 300 MB file named by mistake took 0.7 GB and 4 s before its keys were refused.
_MAX_JSON_BYTES = 2 ** 20
# Most digits of a JSON integer (Python's limit for converting text to int, 4300 by default).
_MAX_INT_DIGITS = sys.get_int_max_str_digits() if hasattr(sys, "get_int_max_str_digits") else 4300


class _TooManyDigits(Exception):
    def __init__(self, digits: int) -> None:
        super().__init__(digits)
        self.digits = digits


class _DuplicateKey(Exception):
    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def _object_without_duplicates(pairs: list) -> dict:
    """A JSON object's mapping; a key written twice (the last would silently win) is refused."""
    seen = {}
    for key, value in pairs:
        if key in seen:
            raise _DuplicateKey(key)
        seen[key] = value
    return seen


def _json_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if _MAX_INT_DIGITS and digits > _MAX_INT_DIGITS:
        raise _TooManyDigits(digits)
    return int(text)


@dataclass(frozen=True)
class ConfigFile:
    """A configuration file as read by :func:`read_config_file`.

    Attributes
    ----------
    path : Path
    config : ifmi.config.EstimateConfig
        With the values the file's run derived set back to ``None``.
    method : str or None
        The run's method (an estimate's ``NAME.config.json``); ``None`` for
        a ``to_dict()`` document.
    """

    path: Path
    config: "EstimateConfig"
    method: str | None


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
        Missing or unreadable file, a folder, a FIFO, device or socket
        (reading it could wait forever), a file over 1 MiB, text that is not
        UTF-8, invalid JSON (with its line; also an integer of more digits
        than Python converts), or valid JSON that is not an object (``[]``,
        a number, ...).
    """
    path = Path(path)
    # A byte-order mark of Windows editors is skipped.
    text = read_text_file(path, what=what, encoding="utf-8-sig", max_bytes=_MAX_JSON_BYTES)
    try:
        data = json.loads(text, parse_int=_json_int, object_pairs_hook=_object_without_duplicates)
    except _DuplicateKey as exc:
        raise InputError(path, f"invalid JSON: key {json.dumps(exc.key)} given twice in one object; expected "
                               "each key once") from None
    except json.JSONDecodeError as exc:
        raise InputError(path, f"invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise InputError(path, "invalid JSON: nested too deeply") from None
    except _TooManyDigits as exc:
        raise InputError(path, f"invalid JSON: an integer of {exc.digits} digits; expected at most "
                               f"{_MAX_INT_DIGITS}") from None
    if not isinstance(data, dict):
        kind = {list: "an array", str: "a string", bool: "a boolean", type(None): "null"}.get(
            type(data), "a number")
        raise InputError(path, f"expected a JSON object {{...}} at the top level, got {kind}")
    return data


def _config_document(data: dict, *, source) -> tuple:
    """``(EstimateConfig, method or None)`` of a configuration document."""
    from ifmi.config import EstimateConfig

    method, derived = None, ()
    if "config" in data and "method" in data:
        method, derived = _run_method(data, source), _run_derived(data, source)
        data = data["config"]
        if not isinstance(data, dict):
            raise InputError(source, f"invalid configuration: config: expected an object, "
                                     f"got {type(data).__name__}")
    try:
        config = EstimateConfig.from_dict(data)
    except ValueError as exc:
        raise InputError(source, f"invalid configuration: {exc}") from None
    return _without_derived(config, derived), method


def _run_method(data: dict, source) -> str:
    method = data["method"]
    if not isinstance(method, str) or not method:
        raise InputError(source, f"invalid configuration: method: expected a method name (a string), "
                                 f"got {json.dumps(method)[:40]}")
    return method


def _run_derived(data: dict, source) -> tuple:
    derived = data.get("derived", list(DERIVED_KEYS))
    if not isinstance(derived, list) or any(key not in DERIVED_KEYS for key in derived):
        raise InputError(source, f"invalid configuration: derived: expected a list of "
                                 f"{', '.join(DERIVED_KEYS)}, got {json.dumps(derived)[:60]}")
    return tuple(derived)


def _without_derived(config, derived: tuple):
    """``config`` with the values of the ``derived`` key paths set to ``None``."""
    return replaced_at_paths(config, {key: ("derived", None) for key in derived})


def read_config_file(path: str | os.PathLike) -> ConfigFile:
    """Read a configuration file with the method an estimate's ``NAME.config.json`` records.

    Returns
    -------
    ConfigFile

    Raises
    ------
    InputError
        As :func:`read_estimate_config`; also a ``method`` that is not a
        string or a ``derived`` entry that is not a list of
        :data:`DERIVED_KEYS`.
    """
    data = read_json_object(path, what="configuration file")
    config, method = _config_document(data, source=path)
    return ConfigFile(path=Path(path), config=config, method=method)


def read_estimate_config(path: str | os.PathLike):
    """Read an estimate configuration file (see the module docstring).

    Returns
    -------
    ifmi.config.EstimateConfig

    Raises
    ------
    InputError
        Missing or unreadable file, not a JSON object, an unknown key, or a
        value of the wrong type or out of range; one line naming the file.
    """
    return read_config_file(path).config
