"""A third-party front end held to the contract of :mod:`ifmi.front_end`.

Built-in front ends are trusted; a method loaded from a plugin or a
``package.module:factory`` is wrapped by :class:`CheckedFrontEnd`, which
applies two rules:

* **What it returns must keep the contract**, or the run stops with one
  :class:`~ifmi.errors.InputError` naming the method: a result with the
  fields of :class:`~ifmi.front_end.Correspondences`, ``success`` a bool and
  ``reason`` text, rays ``(N, 3)`` finite unit vectors (norms within
  :data:`RAY_NORM_TOLERANCE` of 1, then normalised), pixels ``(N, 2)``
  finite, both frames' arrays of one length, ``rays_per_measurement`` an
  integer from 1 to N that divides N, ``diagnostics`` a mapping of one-line
  names (not empty, none of frames.csv's own columns) to JSON scalars (numbers, 64-bit integers, true/false, null or one
  line of text: each is a column of the run's frames.csv), and the rays
  of a seeded sample of :data:`RAY_SAMPLE_SIZE` matches within
  :data:`RAY_PIXEL_TOLERANCE_PX` pixels' angle of the camera model's rays
  of their pixels (``model.rays_from_pixels(pixels)``). These are
  errors of the plugin's code, the same on every frame, and a wrong result
  (pixel coordinates passed as rays, say) would otherwise come out as a
  confident wrong trajectory.
* **An exception it raises fails that frame only**, with the exception in
  the frame's reason, as a damaged image does: a matcher may fail on one
  pair of a sequence. Only the first frame must be prepared, since it is
  the reference. ``sys.exit`` inside the plugin is an error, not the end of
  the run with its status, and an ``accept_pose`` that raises stops the run
  (the pose it was told is already settled). A ``refine_correspondences`` that raises
  leaves the pair its first solution, the exception in the frame's
  diagnostics; what it returns is held to the contract as above.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ifmi.errors import InputError, one_line
from ifmi.front_end import DEFAULT_STAGE_COLUMNS, Correspondences, FrontEndBase
from ifmi.tracking.odometry import FRAME_COLUMNS, PREPARE_MS, RECOVERED_AFTER_RESET, REFINE_FAILURE

__all__ = ["RAY_NORM_TOLERANCE", "RAY_PIXEL_TOLERANCE_PX", "RAY_SAMPLE_SIZE", "CheckedFrontEnd",
           "checked_correspondences"]

# Largest |norm - 1| of a ray accepted as a unit vector (float16 rays round to about 1e-3); the rays
# are then normalised. Pixel coordinates or unnormalised directions given as rays are far outside it.
RAY_NORM_TOLERANCE = 2e-3
# Largest angle between a returned ray and the camera model's ray of its pixel, in pixels' angle
# there (the larger of the angles one row and one column away subtend). Rays a front end computes
# its own way agree with the model's to its round trip: iFMI's rays, lifted from its panorama while
# its pixels come through pixels_from_rays, are within 2.4e-6 (OCamCalib's inverse polynomial) and
# 1.6e-7 (radial-tangential, undistorted iteratively) of it on the example models; float16 rays
# within a tenth of a 160-px image's pixel; a ray lifted at the sub-pixel position of a match whose
# pixel was rounded is within 0.71. A ray of another pixel, negated, or lifted with (col, row) for
# (row, col) is many pixels off.
RAY_PIXEL_TOLERANCE_PX = 1.0
# Matches per result whose rays are checked against the camera model, and the seed of their choice.
RAY_SAMPLE_SIZE = 16
RAY_SAMPLE_SEED = 0
# Fields a front end's result must have (those of Correspondences).
_FIELDS = ("pixels_a", "pixels_b", "rays_a", "rays_b", "diagnostics", "success", "reason",
           "rays_per_measurement")
# NumPy dtype kinds of real numbers (signed, unsigned integer, float) accepted for rays and pixels.
_REAL_KINDS = "iuf"
# Bits of the largest integer a diagnostics entry may hold (that of a 64-bit integer; a longer one
# is no measurement, and Python refuses to print one of over 4300 digits).
_DIAGNOSTIC_INT_BITS = 64
# Column names of frames.csv that a diagnostics entry would lose to (the tracker's own columns).
_TAKEN_COLUMNS = FRAME_COLUMNS + (RECOVERED_AFTER_RESET, REFINE_FAILURE, PREPARE_MS) + DEFAULT_STAGE_COLUMNS
# Characters of a diagnostics key quoted in a message.
_SHOWN_KEY_CHARS = 40


@dataclass(frozen=True)
class _Prepared:
    """A frame's state from the plugin, or why ``prepare`` failed on it."""

    state: object = None
    failure: str = ""


class CheckedFrontEnd(FrontEndBase):
    """``front_end`` of the plugin ``method`` behind the checks of the module docstring.

    Parameters
    ----------
    front_end : object
        What the plugin's factory returned (it has callable ``prepare`` and
        ``correspondences``).
    method : str
        The method's name, for messages.
    model : CameraModel, optional
        The camera model the front end was made for: its rays are checked
        against ``model.rays_from_pixels`` (none without it).

    Raises
    ------
    InputError
        ``accept_pose`` or ``refine_correspondences`` present but not callable.
    """

    def __init__(self, front_end, method: str, model=None) -> None:
        self._inner, self._method, self._where = front_end, method, f"method {method}"
        self._model = model
        self.uses_prior_rotation = bool(getattr(front_end, "uses_prior_rotation", False))
        accept = getattr(front_end, "accept_pose", None)
        if accept is not None and not callable(accept):
            raise InputError(self._where, f"accept_pose is not callable (got {type(accept).__name__}); "
                                          "expected accept_pose(state, rotation) or none")
        if accept is not None:
            self.accept_pose = self._accept_pose
        refine = getattr(front_end, "refine_correspondences", None)
        if refine is not None and not callable(refine):
            raise InputError(self._where, f"refine_correspondences is not callable (got {type(refine).__name__}); "
                                          "expected refine_correspondences(state_a, state_b, first, *, rotation_ab) "
                                          "or none")
        if refine is not None:
            self.refine_correspondences = self._refine_correspondences
        self._prepared_any = False

    def _call(self, what: str, function, *args, **kwargs):
        """``function(*args, **kwargs)``; a plugin's ``sys.exit`` becomes an error naming it."""
        try:
            return function(*args, **kwargs)
        except SystemExit as exc:
            raise InputError(self._where, f"{what} called sys.exit({exc.code!r}); a method must return "
                                          "or raise") from None

    def prepare(self, image):
        """The plugin's state of ``image``, or a failure every pair with this frame reports."""
        try:
            state = _Prepared(self._call("prepare()", self._inner.prepare, image))
        except InputError:
            raise
        except Exception as exc:  # a plugin's failure on this frame
            if not self._prepared_any:
                raise InputError(self._where, f"prepare() of the first frame raised {one_line(exc)}") from None
            state = _Prepared(failure=f"prepare() raised {one_line(exc)}")
        self._prepared_any = True
        return state

    def correspondences(self, state_a: _Prepared, state_b: _Prepared, **prior) -> Correspondences:
        """The plugin's matches of a and b, checked (see the module docstring)."""
        failure = state_a.failure or state_b.failure
        if failure:
            return Correspondences.failed(f"{self._where}: {failure}")
        try:
            result = self._call("correspondences()", self._inner.correspondences, state_a.state,
                                state_b.state, **prior)
        except InputError:
            raise
        except Exception as exc:  # a plugin's failure on this pair
            return Correspondences.failed(f"{self._where}: correspondences() raised {one_line(exc)}")
        return checked_correspondences(result, method=self._method, model=self._model)

    def _refine_correspondences(self, state_a: _Prepared, state_b: _Prepared, first: Correspondences, *,
                                rotation_ab: np.ndarray) -> Correspondences | None:
        """The plugin's refined matches, checked; None as it returns None; an exception it
        raises comes back as failed correspondences (the pair keeps its first solution)."""
        try:
            result = self._call("refine_correspondences()", self._inner.refine_correspondences, state_a.state,
                                state_b.state, first, rotation_ab=rotation_ab)
        except InputError:
            raise
        except Exception as exc:  # a plugin's failure on this pair
            return Correspondences.failed(f"{self._where}: refine_correspondences() raised {one_line(exc)}")
        return None if result is None else checked_correspondences(result, method=self._method, model=self._model)

    def _accept_pose(self, state: _Prepared, rotation: np.ndarray) -> None:
        try:
            self._call("accept_pose()", self._inner.accept_pose, state.state, rotation)
        except InputError:
            raise
        except Exception as exc:
            raise InputError(self._where, f"accept_pose() raised {one_line(exc)}") from None


def checked_correspondences(result, *, method: str, model=None) -> Correspondences:
    """``result`` of a front end as :class:`~ifmi.front_end.Correspondences`, held to the contract.

    Parameters
    ----------
    result : Correspondences or an object with its fields
    method : str, keyword-only
        The method's name, for messages.
    model : CameraModel, optional, keyword-only
        The camera model: a seeded sample of the rays is checked against
        its rays of their pixels (:data:`RAY_PIXEL_TOLERANCE_PX`).

    Returns
    -------
    Correspondences
        float64 arrays, rays normalised; a failed result keeps only its
        reason (one line; "no reason given" when empty) and diagnostics.

    Raises
    ------
    InputError
        Any breach of the contract (module docstring), naming the method,
        the field, what was expected and what came.
    """
    where = f"method {method}"
    missing = [name for name in _FIELDS if not hasattr(result, name)]
    if missing:
        raise InputError(where, f"correspondences() returned {type(result).__name__} without "
                                f"{', '.join(missing)}; expected ifmi.front_end.Correspondences")
    if not isinstance(result.success, (bool, np.bool_)):
        raise InputError(where, f"correspondences() returned success={result.success!r}; expected True or False")
    if not isinstance(result.reason, str):
        raise InputError(where, f"correspondences() returned reason={result.reason!r}; expected text")
    if not isinstance(result.diagnostics, Mapping):
        raise InputError(where, f"correspondences() returned diagnostics of type "
                                f"{type(result.diagnostics).__name__}; expected a dict")
    diagnostics = _diagnostics(result.diagnostics, where)
    if not result.success:
        reason = " ".join(result.reason.split()) or "no reason given"
        return Correspondences.failed(f"{where}: {reason}", diagnostics)
    rays_a, rays_b = (_unit_rays(getattr(result, name), name, where) for name in ("rays_a", "rays_b"))
    pixels_a, pixels_b = (_array(getattr(result, name), name, 2, where) for name in ("pixels_a", "pixels_b"))
    lengths = {len(rays_a), len(rays_b), len(pixels_a), len(pixels_b)}
    if len(lengths) > 1:
        raise InputError(where, f"correspondences() returned rays_a, rays_b, pixels_a, pixels_b of "
                                f"{len(rays_a)}, {len(rays_b)}, {len(pixels_a)}, {len(pixels_b)} rows; "
                                "expected one row per match in each")
    group = _rays_per_measurement(result.rays_per_measurement, len(rays_a), where)
    if model is not None:
        _check_rays_of_pixels(rays_a, pixels_a, "rays_a", model, where)
        _check_rays_of_pixels(rays_b, pixels_b, "rays_b", model, where)
    return Correspondences(pixels_a, pixels_b, rays_a, rays_b, diagnostics, success=True, reason="",
                           rays_per_measurement=group)


def _diagnostics(value: Mapping, where: str) -> dict:
    """``value`` as a dict of one-line text keys to JSON scalars, each a column of frames.csv.

    Raises
    ------
    InputError
        A key that is not one line of text without surrounding spaces, an
        empty key or one of frames.csv's own columns (whose value would be
        lost to the tracker's), or a value that is not a number, a 64-bit integer, true/false, null or one
        line of text.
    """
    out = {}
    for key, item in value.items():
        # frames.csv strips its column names: " seconds" would be read as the seconds column.
        if not isinstance(key, str) or len(key.splitlines()) > 1 or key != key.strip():
            raise InputError(where, f"correspondences() returned a diagnostics key {_shown(key)}; "
                                    "expected one line of text without surrounding spaces (a column "
                                    "name of frames.csv)")
        if not key or key in _TAKEN_COLUMNS:
            problem = "an empty column name" if not key else "a column frames.csv has already"
            raise InputError(where, f"correspondences() returned a diagnostics key {_shown(key)}: {problem}, "
                                    f"so its values would be lost; expected a non-empty name other than "
                                    f"{', '.join(_TAKEN_COLUMNS)}")
        problem = _diagnostic_problem(item)
        if problem:
            raise InputError(where, f"correspondences() returned diagnostics entry {_shown(key)}: {problem}; "
                                    "expected a float, an integer of at most 64 bits, true/false, null or "
                                    "one line of text (a column of frames.csv)")
        out[key] = item
    return out


def _diagnostic_problem(item) -> str | None:
    """Why ``item`` cannot be a frames.csv field, or None."""
    if isinstance(item, (int, np.integer)) and not isinstance(item, (bool, np.bool_)):
        bits = int(item).bit_length()
        return None if bits <= _DIAGNOSTIC_INT_BITS else f"an integer of {bits} bits"
    if item is None or isinstance(item, (bool, np.bool_, float, np.floating)):
        return None
    if isinstance(item, str):
        lines = len(item.splitlines())
        return None if lines <= 1 else f"text of {lines} lines"
    return f"a value of type {type(item).__name__}"


def _shown(key) -> str:
    """``key`` for a message: its repr, on one line, cut short."""
    text = repr(key) if isinstance(key, str) else f"of type {type(key).__name__}"
    return text if len(text) <= _SHOWN_KEY_CHARS else text[:_SHOWN_KEY_CHARS - 3] + "..."


def _array(value, name: str, columns: int, where: str) -> np.ndarray:
    """``value`` as a finite float64 ``(N, columns)`` array."""
    try:
        array = np.asarray(value)
        if array.dtype.kind not in _REAL_KINDS:  # complex, text, objects: float64 would drop or parse them
            raise TypeError(f"values of type {array.dtype}")
        array = array.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(where, f"correspondences() returned {name} that is no numeric array "
                                f"({one_line(exc)}); expected (N, {columns}) real numbers") from None
    if array.ndim != 2 or array.shape[1] != columns:
        raise InputError(where, f"correspondences() returned {name} of shape {array.shape}; "
                                f"expected (N, {columns})")
    bad = ~np.isfinite(array).all(axis=1)
    if bad.any():
        raise InputError(where, f"correspondences() returned {name} with {int(bad.sum())} of {len(array)} "
                                "rows not finite; expected finite values (leave such matches out)")
    return array


def _unit_rays(value, name: str, where: str) -> np.ndarray:
    rays = _array(value, name, 3, where)
    norms = np.linalg.norm(rays, axis=1)
    if len(rays) and np.abs(norms - 1.0).max() > RAY_NORM_TOLERANCE:
        raise InputError(where, f"correspondences() returned {name} that are not unit vectors (norms "
                                f"{norms.min():.4g} to {norms.max():.4g}); expected unit rays in the camera "
                                "frame, lifted through the camera model (not pixel coordinates)")
    return rays / norms[:, None] if len(rays) else rays


def _angles(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angles (rad) between the unit rows of ``u`` and ``v``, (N, 3) each; accurate for small angles."""
    return 2.0 * np.arcsin(np.clip(np.linalg.norm(u - v, axis=1) / 2.0, 0.0, 1.0))


def _check_rays_of_pixels(rays: np.ndarray, pixels: np.ndarray, name: str, model, where: str) -> None:
    """Refuse rays of a seeded sample of matches that are not the model's rays of their pixels.

    Parameters
    ----------
    rays : (N, 3) ndarray
        Unit rays returned by the front end.
    pixels : (N, 2) ndarray
        Their pixels, (row, col).
    name : str
        ``rays_a`` or ``rays_b``, for the message.
    model : CameraModel
    where : str
        ``method NAME``, for the message.

    Raises
    ------
    InputError
        A sampled ray further than :data:`RAY_PIXEL_TOLERANCE_PX` pixels'
        angle from the model's ray of its pixel. Pixels the model does not
        lift (outside its valid region) are not checked.
    """
    if not len(rays):
        return
    rng = np.random.default_rng(RAY_SAMPLE_SEED)
    rows = np.sort(rng.choice(len(rays), size=min(RAY_SAMPLE_SIZE, len(rays)), replace=False))
    sample = pixels[rows]
    expected = np.asarray(model.rays_from_pixels(sample), dtype=np.float64)
    pixel_angle = np.maximum(*(_angles(expected, np.asarray(model.rays_from_pixels(sample + step), np.float64))
                               for step in ((1.0, 0.0), (0.0, 1.0))))
    off = _angles(rays[rows], expected) / pixel_angle
    checked = np.isfinite(off)
    bad = checked & (off > RAY_PIXEL_TOLERANCE_PX)
    if bad.any():
        worst = int(np.argmax(np.where(bad, off, -np.inf)))
        row, col = sample[worst]
        raise InputError(where, f"correspondences() returned {name} that are not the rays of their pixels: "
                                f"{int(bad.sum())} of {int(checked.sum())} sampled matches off the camera "
                                f"model's ray, by up to {off[worst]:.3g} pixels' angle (at pixel row {row:.6g}, "
                                f"col {col:.6g}); expected model.rays_from_pixels(pixels) within "
                                f"{RAY_PIXEL_TOLERANCE_PX:g} pixel's angle")


def _rays_per_measurement(value, n: int, where: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise InputError(where, f"correspondences() returned rays_per_measurement={value!r}; expected an "
                                "integer >= 1")
    group = int(value)
    if group < 1 or (n and (group > n or n % group)):
        raise InputError(where, f"correspondences() returned rays_per_measurement={group} for {n} matches; "
                                "expected an integer >= 1 that divides the number of matches")
    return group
