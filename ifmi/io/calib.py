"""Read and write OCamCalib ``calib_results.txt`` files.

The format: five data blocks, separated by ``#`` comment lines and blank
lines, in this order:

1. direct polynomial: count, then coefficients lowest degree first;
2. inverse polynomial: count, then coefficients lowest degree first;
3. centre: ``row col`` (0-based);
4. affine parameters: ``c d e``;
5. image size: ``height width``.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..camera import OcamModel
from ..errors import InputError
from .atomic import atomic_write_text

__all__ = ["read_calib", "write_calib", "format_calib", "parse_calib"]

_BLOCKS = ("direct polynomial", "inverse polynomial", "center (row col)",
           "affine (c d e)", "image size (height width)")


def _numbers(path, block: str, line: str) -> list[float]:
    try:
        return [float(tok) for tok in line.split()]
    except ValueError:
        bad = next(tok for tok in line.split() if not _is_float(tok))
        raise InputError(path, f"{block}: non-numeric value {bad!r}") from None


def _is_float(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _polynomial(path, block: str, values: list[float]) -> tuple[float, ...]:
    count = values[0]
    if count != int(count) or count < 1:
        raise InputError(path, f"{block}: coefficient count must be a positive integer, got {count:g}")
    coeffs = values[1:]
    if len(coeffs) != int(count):
        raise InputError(path, f"{block}: expected {int(count)} coefficients, got {len(coeffs)}")
    return tuple(coeffs)


def _pair(path, block: str, values: list[float], n: int) -> tuple[float, ...]:
    if len(values) != n:
        raise InputError(path, f"{block}: expected {n} values, got {len(values)}")
    return tuple(values)


def parse_calib(text: str, *, source: str | os.PathLike = "<calib>") -> OcamModel:
    """Parse the text of a ``calib_results.txt`` file.

    Parameters
    ----------
    text : str
        File contents.
    source : str or path, keyword-only
        Name used in error messages.

    Returns
    -------
    OcamModel

    Raises
    ------
    InputError
        On a missing block, a wrong count, a non-numeric value or an
        inconsistent model.
    """
    lines = [ln.strip() for ln in text.splitlines()]
    data = [ln for ln in lines if ln and not ln.startswith("#")]
    if len(data) < len(_BLOCKS):
        missing = ", ".join(_BLOCKS[len(data):])
        raise InputError(source, f"expected {len(_BLOCKS)} data blocks, got {len(data)} (missing: {missing})")
    if len(data) > len(_BLOCKS):
        raise InputError(source, f"expected {len(_BLOCKS)} data blocks, got {len(data)}")
    values = [_numbers(source, block, line) for block, line in zip(_BLOCKS, data)]
    pol = _polynomial(source, _BLOCKS[0], values[0])
    invpol = _polynomial(source, _BLOCKS[1], values[1])
    center = _pair(source, _BLOCKS[2], values[2], 2)
    affine = _pair(source, _BLOCKS[3], values[3], 3)
    size = _pair(source, _BLOCKS[4], values[4], 2)
    if any(v != int(v) or v <= 0 for v in size):
        raise InputError(source, f"image size must be positive integers, got {size[0]:g} {size[1]:g}")
    try:
        return OcamModel(pol=pol, invpol=invpol, center=center, affine=affine,
                         size=(int(size[0]), int(size[1])))
    except ValueError as exc:
        raise InputError(source, str(exc)) from None


def read_calib(path: str | os.PathLike) -> OcamModel:
    """Read an OCamCalib ``calib_results.txt`` file.

    Raises
    ------
    InputError
        If the file is missing, unreadable or malformed; the message names it.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except FileNotFoundError:
        raise InputError(path, "calibration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read calibration file ({exc.__class__.__name__})") from None
    return parse_calib(text, source=path)


def _fmt(values) -> str:
    return " ".join(f"{v:.17g}" for v in values)


def format_calib(model: OcamModel) -> str:
    """Render ``model`` as ``calib_results.txt`` text (readable by OCamCalib's tools)."""
    return (
        "#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). "
        "These are used by cam2world\n\n"
        f"{len(model.pol)} {_fmt(model.pol)}\n\n"
        "#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). "
        "These are used by world2cam\n\n"
        f"{len(model.invpol)} {_fmt(model.invpol)}\n\n"
        '#center: "row" and "column", starting from 0 (C convention)\n\n'
        f"{model.center[0]:.17g} {model.center[1]:.17g}\n\n"
        '#affine parameters "c", "d", "e"\n\n'
        f"{model.affine[0]:.17g} {model.affine[1]:.17g} {model.affine[2]:.17g}\n\n"
        '#image size: "height" and "width"\n\n'
        f"{model.height} {model.width}\n"
    )


def write_calib(path: str | os.PathLike, model: OcamModel) -> None:
    """Write ``model`` to ``path`` atomically in ``calib_results.txt`` format."""
    atomic_write_text(path, format_calib(model))
