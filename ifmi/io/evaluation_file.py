"""Checks of an evaluation folder's files against what their readers take from them.

``evaluation.json`` and ``per_frame.npz`` are written by ``ifmi evaluate``
(:func:`ifmi.io.results.write_evaluation`) and read back by reports; the
estimate run's ``NAME.config.json`` gives the evaluation its method and
dataset. A file
edited by hand, written by another tool or left over from an older version
is refused here with one line naming the file, the field (as a dotted path,
``summary.frames.associated``), what was expected and what was got, rather
than failing somewhere inside a report.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ifmi.evaluation.dataset_names import display_name
from ifmi.errors import InputError, json_excerpt
from ifmi.evaluation.metrics import AXES

__all__ = ["check_evaluation_document", "check_per_frame_arrays", "check_run_config",
           "PER_FRAME_REQUIRED"]

# Statistics of one error in the summary (besides ``count``); each a number, or null for NaN.
_STATS_NUMBERS = ("rmse", "mean", "std", "median", "max")
# Error statistics of the summary beside the per-axis ones.
_SUMMARY_STATS = ("geodesic", "relative_geodesic", "translation_direction")
# Pose counts of ``summary.frames``.
_FRAME_COUNTS = ("ground_truth", "estimate", "associated")
# Times of ``summary.time`` (seconds), each a number or null.
_TIME_NUMBERS = ("mean_s", "median_s", "total_s")
# Top-level entries used as names of folders and figures in a report.
_NAME_FIELDS = ("method", "scene")
# What a name field must be.
_NAME = "a name (a string without / or \\) or null"
# Top-level entries read as text (labels, paths).
_TEXT_FIELDS = ("dataset", "dataset_path", "groundtruth_path")
# Per-frame arrays a report draws (orientation over frames).
PER_FRAME_REQUIRED = ("timestamp",) + tuple(f"{a}_{k}" for a in AXES for k in ("gt", "est"))
# Largest |roll|, |pitch|, |yaw| of a drawn angle, radians (Euler angles lie in [-pi, pi]; the margin
# covers rounding, far below a value written in degrees).
_MAX_ANGLE_RAD = math.pi + 1e-9


def _describe(value) -> str:
    """A JSON value for a message: its kind and (the start of) its text."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return json.dumps(value)
    kind = ("a string" if isinstance(value, str) else "a number" if isinstance(value, (int, float))
            else "an array" if isinstance(value, list) else "an object")
    return f"{kind} {json_excerpt(value)}"


def _refuse(path: Path, field: str, expected: str, value) -> InputError:
    return InputError(path, f"field {field}: expected {expected}, got {_describe(value)}")


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_count(value) -> bool:
    # An int is compared as an int: one too large for a float (10**400) has no finite float value.
    if isinstance(value, int) and not isinstance(value, bool):
        return value >= 0
    return isinstance(value, float) and value >= 0 and value.is_integer()


def _object(path: Path, parent: dict, key: str, where: str, *, optional: bool = False) -> dict | None:
    """``parent[key]`` as an object; None when ``optional`` and it is null or absent."""
    field = f"{where}.{key}" if where else key
    if key not in parent and not optional:
        raise InputError(path, f"field {field}: missing; expected an object {{...}}")
    value = parent.get(key)
    if value is None and optional:
        return None
    if not isinstance(value, dict):
        raise _refuse(path, field, "an object {...}" + (" or null" if optional else ""), value)
    return value


def _numbers(path: Path, parent: dict, keys, where: str) -> None:
    """Each of ``keys`` of ``parent`` is a number >= 0 (an error statistic of absolute errors, or
    a time), or null (NaN written out)."""
    for key in keys:
        if key not in parent:
            raise InputError(path, f"field {where}.{key}: missing; expected a number or null")
        value = parent[key]
        if value is not None and not _is_number(value):
            raise _refuse(path, f"{where}.{key}", "a number or null", value)
        if value is not None and value < 0:
            raise _refuse(path, f"{where}.{key}", "a number >= 0 (errors and times are never negative) "
                                                  "or null", value)


def _count(path: Path, parent: dict, key: str, where: str, *, optional: bool = False) -> None:
    value = parent.get(key)
    if (value is None and optional) or _is_count(value):
        return
    expected = "a whole number >= 0" + (" or null" if optional else "")
    if key not in parent:
        raise InputError(path, f"field {where}.{key}: missing; expected {expected}")
    raise _refuse(path, f"{where}.{key}", expected, value)


def _at_most(path: Path, parent: dict, key: str, bound: str, where: str) -> None:
    """The count ``parent[key]`` is at most the count ``parent[bound]`` (both checked counts)."""
    if parent[key] > parent[bound]:
        raise _refuse(path, f"{where}.{key}", f"at most {where}.{bound} ({parent[bound]})", parent[key])


def _stats(path: Path, parent: dict, key: str, where: str) -> None:
    stats = _object(path, parent, key, where)
    _numbers(path, stats, _STATS_NUMBERS, f"{where}.{key}")
    _count(path, stats, "count", f"{where}.{key}", optional=True)


def _check_summary(path: Path, doc: dict) -> None:
    summary = _object(path, doc, "summary", "")
    axes = _object(path, summary, "axes", "summary")
    for axis in AXES:
        _stats(path, axes, axis, "summary.axes")
    for name in _SUMMARY_STATS:
        _stats(path, summary, name, "summary")
    frames = _object(path, summary, "frames", "summary")
    for key in _FRAME_COUNTS:
        _count(path, frames, key, "summary.frames")
    for key in ("ground_truth", "estimate"):
        _at_most(path, frames, "associated", key, "summary.frames")
    failures = _object(path, summary, "failures", "summary", optional=True)
    if failures is not None:
        for key in ("count", "frames"):
            _count(path, failures, key, "summary.failures")
        _at_most(path, failures, "count", "frames", "summary.failures")
    time = _object(path, summary, "time", "summary", optional=True)
    if time is not None:
        _numbers(path, time, _TIME_NUMBERS, "summary.time")
        _count(path, time, "frames", "summary.time")


def check_evaluation_document(path: str | Path, doc: dict) -> None:
    """Check the entries of an ``evaluation.json`` that reports read.

    Parameters
    ----------
    path : path
        The file, for messages.
    doc : dict
        Its content (a JSON object).

    Raises
    ------
    InputError
        ``summary`` or one of its statistics, pose counts, ``failures`` or
        ``time`` missing or of the wrong kind; a statistic or time below 0;
        more associated poses than either file has, or more failed frames
        than frames; ``method`` or ``scene`` not a
        name usable as a folder name (a string without ``/``); ``dataset``,
        ``dataset_path`` or ``groundtruth_path`` not a string;
        ``dataset_meta`` not an object. Optional entries may be null or
        absent.
    """
    path = Path(path)
    _check_summary(path, doc)
    _check_top_level(path, doc, names=_NAME_FIELDS, texts=_TEXT_FIELDS)
    _object(path, doc, "dataset_meta", "", optional=True)


def check_run_config(path: str | Path, config: dict) -> None:
    """Check the entries of an estimate run's ``NAME.config.json`` that an evaluation takes.

    Parameters
    ----------
    path : path
        The file, for messages.
    config : dict
        Its content (a JSON object).

    Raises
    ------
    InputError
        ``method`` not a name (a string without ``/``), or ``dataset`` not
        a string; either may be null or absent.
    """
    _check_top_level(Path(path), config, names=("method",), texts=("dataset",))


def _is_name(value) -> bool:
    return (isinstance(value, str) and "/" not in value and "\\" not in value
            and value not in (".", ".."))


def _check_top_level(path: Path, doc: dict, *, names, texts) -> None:
    """Top-level ``names`` (see :func:`_is_name`) and ``texts`` (strings), each also null or absent."""
    for key in names:
        value = doc.get(key)
        if value is not None and not _is_name(value):
            raise _refuse(path, key, _NAME, value)
        if value is not None and value != display_name(value):  # figures cannot draw them
            raise _refuse(path, key, "a name without lone surrogates (\\ud800 to \\udfff)", value)
    for key in texts:
        value = doc.get(key)
        if value is not None and not isinstance(value, str):
            raise _refuse(path, key, "a string or null", value)


def check_per_frame_arrays(path: str | Path, arrays: dict, *, associated: int) -> None:
    """Check the arrays of a ``per_frame.npz`` against its ``evaluation.json``.

    Parameters
    ----------
    path : path
        The ``.npz`` file, for messages.
    arrays : dict of str -> ndarray
    associated : int, keyword-only
        Associated frames of the evaluation (``summary.frames.associated``).

    Raises
    ------
    InputError
        A missing array of :data:`PER_FRAME_REQUIRED`, an array that is not
        one number per frame, or a length other than ``associated``; a drawn
        array (:data:`PER_FRAME_REQUIRED`) with a value that is not finite,
        timestamps that do not increase, or an angle outside [-pi, pi].
    """
    path = Path(path)
    missing = [k for k in PER_FRAME_REQUIRED if k not in arrays]
    if missing:
        raise InputError(path, f"missing array(s) {', '.join(missing)}; got "
                               f"{', '.join(arrays) or 'none'}")
    for name, array in arrays.items():
        if array.ndim != 1 or array.dtype.kind not in "biuf":
            raise InputError(path, f"array {name}: expected one number per frame, got "
                                   f"{array.dtype} of shape {array.shape}")
        if len(array) != associated:
            raise InputError(path, f"array {name}: {len(array)} frames, but evaluation.json "
                                   f"has {associated} associated frames; expected one row per "
                                   "associated frame")
    _check_drawn_arrays(path, arrays)


def _check_drawn_arrays(path: Path, arrays: dict) -> None:
    """The arrays a report draws: finite, timestamps increasing, angles in radians within [-pi, pi]."""
    for name in PER_FRAME_REQUIRED:
        values = np.asarray(arrays[name], dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise InputError(path, f"array {name}: value {values[bad[0]]} at row {bad[0]}; expected finite "
                                   "numbers (evaluate writes them for every associated frame)")
        if name == "timestamp":
            back = np.flatnonzero(np.diff(values) <= 0)
            if back.size:
                raise InputError(path, f"array timestamp: {values[back[0] + 1]:g} at row {back[0] + 1} "
                                       f"follows {values[back[0]]:g}; expected increasing timestamps")
        elif values.size and np.abs(values).max() > _MAX_ANGLE_RAD:
            row = int(np.abs(values).argmax())
            raise InputError(path, f"array {name}: {values[row]:g} at row {row}; expected an angle in "
                                   "radians within [-pi, pi]")
