"""Reading a whole text file with the io layer's one-line errors."""

from __future__ import annotations

import os
from pathlib import Path

from ifmi.errors import InputError

__all__ = ["read_text_file", "read_failure", "number_from_text", "refuse_special_file"]


def read_text_file(path: str | os.PathLike, *, what: str, encoding: str = "utf-8",
                   errors: str = "strict", max_bytes: int | None = None) -> str:
    """The text of a file, or an :class:`~ifmi.errors.InputError` naming it.

    Parameters
    ----------
    path : path-like
    what : str, keyword-only
        What the file is, for messages (``"calibration file"``).
    encoding, errors : str, keyword-only
        As for :meth:`pathlib.Path.read_text` (line ends are read as ``\\n`` too).
    max_bytes : int, optional, keyword-only
        Largest file accepted; a larger one is refused before it is read
        (from its size on disk, or after ``max_bytes + 1`` bytes when it
        grows meanwhile), so a huge file named by mistake costs no memory.

    Returns
    -------
    str

    Raises
    ------
    InputError
        A FIFO, device or socket (:func:`refuse_special_file`), a file over
        ``max_bytes``, or as :func:`read_failure` words it.
    """
    path = Path(path)
    refuse_special_file(path, what=what)
    try:
        if max_bytes is None:
            return path.read_text(encoding=encoding, errors=errors)
        data = _bytes_within(path, max_bytes, what=what)
        # Universal newlines, as read_text reads them.
        return data.decode(encoding, errors).replace("\r\n", "\n").replace("\r", "\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise read_failure(path, exc, what=what, encoding=encoding) from None


def _bytes_within(path: Path, max_bytes: int, *, what: str) -> bytes:
    """The bytes of the file at ``path``; an :class:`~ifmi.errors.InputError` when there are more than ``max_bytes``."""
    with open(path, "rb") as file:
        size = os.fstat(file.fileno()).st_size
        data = b"" if size > max_bytes else file.read(max_bytes + 1)
    if size > max_bytes or len(data) > max_bytes:
        found = f"{size} bytes" if size > max_bytes else f"over {max_bytes} bytes"
        raise InputError(path, f"is {found}; expected a {what} of at most {max_bytes} bytes")
    return data


def refuse_special_file(path: str | os.PathLike, *, what: str) -> None:
    """Refuse a ``path`` that exists but is a FIFO, device or socket (reading it could block forever).

    Serves files a command finds by name (side files, files of a result
    folder) and the text files a user names (calibration, trajectory and
    configuration files, through :func:`read_text_file`): a FIFO with no
    writer blocks ``open`` forever. A pipe of the shell's ``<(...)`` is
    refused too; such text is passed as a regular file.

    Raises
    ------
    InputError
        ``path`` is neither a regular file, a folder nor missing.
    """
    path = Path(path)
    if path.exists() and not (path.is_file() or path.is_dir()):
        article = "an" if what[:1].lower() in "aeiou" else "a"
        raise InputError(path, f"is a FIFO, device or socket, not {article} {what}; expected a regular file")


def read_failure(path, exc: Exception, *, what: str, encoding: str = "utf-8") -> InputError:
    """The one-line error for ``exc``, raised while reading the ``what`` at ``path``.

    A missing file is "``what`` not found", a folder "is a folder", text in
    another encoding says which (UTF-16, or the first byte that is not
    ``encoding``), any other failure gives the system's reason.
    """
    if isinstance(exc, FileNotFoundError):
        return InputError(path, f"{what} not found")
    if isinstance(exc, IsADirectoryError):
        return InputError(path, f"is a folder; expected a {what}")
    if isinstance(exc, UnicodeDecodeError):
        # utf-8-sig is UTF-8 with an optional byte-order mark: it is UTF-8 to the user.
        name = "UTF-8" if encoding.lower().replace("_", "-") in ("utf-8", "utf8", "utf-8-sig") else encoding
        if exc.object[:2] in (b"\xff\xfe", b"\xfe\xff"):
            found = "UTF-16 text"
        else:
            found = f"byte 0x{exc.object[exc.start]:02x} at offset {exc.start} is not {name} text"
        return InputError(path, f"cannot read {what}: {found}; expected {name} text")
    return InputError(path, f"cannot read {what} ({getattr(exc, 'strerror', None) or exc.__class__.__name__})")


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
