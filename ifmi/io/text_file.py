"""Reading a whole text file with the io layer's one-line errors."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputError

__all__ = ["read_text_file", "number_from_text"]


def read_text_file(path: str | os.PathLike, *, what: str, encoding: str = "utf-8",
                   errors: str = "strict") -> str:
    """The text of a file, or an :class:`~ifmi.errors.InputError` naming it.

    Parameters
    ----------
    path : path-like
    what : str, keyword-only
        What the file is, for messages (``"calibration file"``).
    encoding, errors : str, keyword-only
        As for :meth:`pathlib.Path.read_text`.

    Returns
    -------
    str

    Raises
    ------
    InputError
        ``"{what} not found"`` for a missing file; ``"cannot read {what}
        (ErrorName)"`` for any other read or decoding failure.
    """
    path = Path(path)
    try:
        return path.read_text(encoding=encoding, errors=errors)
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read {what} ({exc.__class__.__name__})") from None


def number_from_text(text: str) -> float:
    """The number a text field holds, as :class:`float` reads it but without digit separators.

    Python's ``float`` reads ``12_8.45`` as 128.45; in a data file an
    underscore is a typing error, never a separator, so it is refused.

    Raises
    ------
    ValueError
        Not a number, or a number with an underscore.
    """
    if "_" in text:
        raise ValueError(f"could not convert string to float: {text!r}")
    return float(text)
