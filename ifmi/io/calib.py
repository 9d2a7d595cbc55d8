"""Read and write OCamCalib ``calib_results.txt`` files.

The format: five data blocks, separated by ``#`` comment lines and blank
lines, in this order:

1. direct polynomial: count, then coefficients lowest degree first;
2. inverse polynomial: count, then coefficients lowest degree first;
3. centre: ``row col`` (0-based);
4. affine parameters: ``c d e``;
5. image size: ``height width``.

Reading checks more than the layout: every value must be finite; the image
sides must be integers from :data:`~ifmi.geometry.camera.MIN_IMAGE_SIDE_PX` to
:data:`~ifmi.geometry.camera.MAX_IMAGE_SIDE_PX`; the affine part must be close to the
identity (:data:`~ifmi.geometry.camera.AFFINE_MAX_DEVIATION`); the centre must lie
inside the image; and the inverse polynomial must invert the direct one over
the image band to within :data:`INVERSE_TOLERANCE_PX` (see
:func:`inverse_polynomial_error`). A missing block is named from the comment
line above each block (OCamCalib writes them) or, without comments, from the
shapes of the remaining lines.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import numpy as np

from ifmi.geometry.camera import INVERSE_TOLERANCE_PX, OcamModel, check_affine, check_center_inside, check_image_size
from ifmi.errors import InputError
from ifmi.spectral.panorama import inverse_polynomial_error
from ifmi.io.atomic import atomic_write_text
from ifmi.io.text_file import number_from_text, read_text_file

__all__ = ["read_calib", "write_calib", "format_calib", "parse_calib", "inverse_polynomial_error",
           "INVERSE_TOLERANCE_PX"]

_BLOCKS = ("direct polynomial", "inverse polynomial", "center (row col)",
           "affine (c d e)", "image size (height width)")
# Words of OCamCalib's comment line above each block, in block order.
_BLOCK_WORDS = (("direct", "cam2world"), ("inverse", "world2cam"), ("center", "centre"),
                ("affine",), ("size",))
# The inverse polynomial check: INVERSE_TOLERANCE_PX, the largest accepted round-trip error,
# over a band from INVERSE_CHECK_INNER_FRACTION of its outer radius out (both in ifmi.geometry.camera,
# with their reasons).


def _numbers(path, block: str, line: str) -> list[float]:
    try:
        return [number_from_text(tok) for tok in line.split()]
    except ValueError:
        bad = next(tok for tok in line.split() if not _is_float(tok))
        raise InputError(path, f"{block}: non-numeric value {bad!r}") from None


def _is_float(tok: str) -> bool:
    try:
        number_from_text(tok)
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
        On binary text (NUL bytes), a missing block, a wrong count, a
        non-numeric value or an inconsistent model.
    """
    if "\x00" in text:
        # OCamCalib writes ASCII; NUL bytes mean an image, an archive or UTF-16 text.
        raise InputError(source, "not a text calibration file (it holds NUL bytes: binary data such as an "
                                 "image, or UTF-16 text); expected OCamCalib's calib_results.txt text")
    data, comments = _data_lines(text)
    if len(data) < len(_BLOCKS):
        raise InputError(source, f"expected {len(_BLOCKS)} data blocks, got {len(data)} "
                                 f"(missing: {_missing_blocks(data, comments)})")
    if len(data) > len(_BLOCKS):
        raise InputError(source, f"expected {len(_BLOCKS)} data blocks, got {len(data)}")
    values = [_numbers(source, block, line) for block, line in zip(_BLOCKS, data)]
    for block, numbers in zip(_BLOCKS, values):
        bad = [i for i, v in enumerate(numbers) if not np.isfinite(v)]
        if bad:
            raise InputError(source, f"{block}: value {bad[0] + 1} is {numbers[bad[0]]} "
                                     f"(every value must be finite)")
    pol = _polynomial(source, _BLOCKS[0], values[0])
    invpol = _polynomial(source, _BLOCKS[1], values[1])
    center = _pair(source, _BLOCKS[2], values[2], 2)
    affine = _pair(source, _BLOCKS[3], values[3], 3)
    size = _pair(source, _BLOCKS[4], values[4], 2)
    if any(v != int(v) or v <= 0 for v in size):
        raise InputError(source, f"image size must be positive integers, got {size[0]:g} {size[1]:g}")
    _checked(source, _BLOCKS[4], check_image_size, size)
    try:
        model = OcamModel(pol=pol, invpol=invpol, center=center, affine=affine,
                          size=(int(size[0]), int(size[1])))
    except ValueError as exc:
        raise InputError(source, str(exc)) from None
    _checked(source, _BLOCKS[3], check_affine, affine)
    _checked(source, _BLOCKS[2], check_center_inside, center, model.size)
    _check_inverse(source, model)
    return model


def _checked(source, block: str, check, *args) -> None:
    """Run a ``check`` of :mod:`ifmi.geometry.camera` on ``args``; its ``ValueError`` becomes a one-line error on ``block``."""
    try:
        check(*args)
    except ValueError as exc:
        raise InputError(source, f"{block}: {exc}") from None


def _data_lines(text: str) -> tuple[list[str], list[str]]:
    """Data lines and, for each, the last comment line above it (lower case, or '')."""
    data, comments, comment = [], [], ""
    for line in (ln.strip() for ln in text.splitlines()):
        if line.startswith("#"):
            comment = line.lower()
        elif line:
            data.append(line)
            comments.append(comment)
            comment = ""
    return data, comments


def _fits(block: int, line: str) -> bool:
    """Whether a data line has the shape of ``_BLOCKS[block]`` (a non-numeric line fits any)."""
    try:
        values = [number_from_text(tok) for tok in line.split()]
    except ValueError:
        return True
    if block < 2:
        return len(values) >= 2 and values[0] == len(values) - 1
    if block == 4:
        return len(values) == 2 and all(v == int(v) and v > 0 for v in values)
    return len(values) == (2 if block == 2 else 3)


def _missing_blocks(data: list[str], comments: list[str]) -> str:
    """Names of the blocks absent from ``data``, from its comment lines or else its shapes."""
    named = [next((b for b, words in enumerate(_BLOCK_WORDS) if any(w in c for w in words)), None)
             for c in comments]
    if None not in named and len(set(named)) == len(named):
        return ", ".join(b for i, b in enumerate(_BLOCKS) if i not in named)
    candidates = sorted(tuple(i for i in range(len(_BLOCKS)) if i not in present)
                        for present in itertools.combinations(range(len(_BLOCKS)), len(data))
                        if all(_fits(block, line) for block, line in zip(present, data)))
    # More than two readings name nearly every block: say so instead of listing them all.
    if not candidates or len(candidates) > 2:
        return "cannot tell which from the values"
    return " or ".join(", ".join(_BLOCKS[i] for i in missing) for missing in candidates)


def _check_inverse(source, model: OcamModel) -> None:
    try:
        error, radius = inverse_polynomial_error(model)
    except ValueError:
        raise InputError(source, "direct polynomial: the ray elevation does not grow with the radius "
                                 "from the centre, so no image band can be inverted (check the signs "
                                 "of the coefficients)") from None
    if not error <= INVERSE_TOLERANCE_PX:
        raise InputError(source, f"inverse polynomial does not invert the direct one: round-trip error "
                                 f"{error:.3g} px at radius {radius:.1f} px (at most "
                                 f"{INVERSE_TOLERANCE_PX} px accepted)")


def read_calib(path: str | os.PathLike) -> OcamModel:
    """Read an OCamCalib ``calib_results.txt`` file.

    Raises
    ------
    InputError
        If the file is missing, unreadable or malformed; the message names it.
    """
    path = Path(path)
    # Comments may be in any encoding (only numbers are read); a byte-order mark is skipped.
    text = read_text_file(path, what="calibration file", encoding="utf-8-sig", errors="replace")
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
