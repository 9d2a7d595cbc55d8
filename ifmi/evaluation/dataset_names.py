"""Names of dataset folders in results: a unique folder id and a short display label.

Two dataset folders may share a name (``site_a/office``, ``site_b/office``).
Everything that files or tabulates results per dataset names them through
this module, so that such folders never share a file or a table row:

* :func:`dataset_folder_id` -- a file-name-safe id, the folder's name and a
  digest of its resolved path (``office-3f2a9c0d1b7e``), for output files
  and folders;
* :func:`dataset_labels` -- display names for tables and figures: the folder
  name, with as many parent folders as it takes to tell the given folders
  apart (``site_a/office``).
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path
from typing import Sequence

__all__ = ["dataset_folder_id", "dataset_labels", "display_name", "resolved_folder"]

# Hex digits of the digest of the resolved folder path in a folder id.
_ID_DIGITS = 12
# Characters that a folder id keeps; every other character becomes "_".
_UNSAFE = re.compile(r"[^A-Za-z0-9_.=-]")
# Lone surrogates: Python's stand-ins for the bytes of a file name that are not UTF-8 (os.fsdecode).
_SURROGATE = re.compile("[\ud800-\udfff]")
# What a display name shows in place of such a byte (as ls and file managers do).
_REPLACEMENT_CHARACTER = "\ufffd"


def display_name(text: str) -> str:
    """``text`` with every lone surrogate replaced by U+FFFD, for tables, figures and JSON.

    A folder name with bytes that are not UTF-8 reaches Python with lone
    surrogates, which neither UTF-8 files nor Matplotlib's text can hold.
    """
    return _SURROGATE.sub(_REPLACEMENT_CHARACTER, text)


def resolved_folder(dataset: str | os.PathLike) -> str:
    """The absolute, symlink-free path of a dataset folder, the key of the other functions."""
    return str(Path(dataset).resolve())


def dataset_folder_id(dataset: str | os.PathLike) -> str:
    """File-name-safe id of a dataset folder, unique per resolved path.

    Parameters
    ----------
    dataset : str or path-like
        Dataset folder (need not exist).

    Returns
    -------
    str
        ``NAME-DIGEST``: the folder's name and the first 12 hex digits of
        the SHA-256 of its resolved path, characters other than letters,
        digits and ``_.=-`` replaced by ``_``.
    """
    folder = resolved_folder(dataset)
    digest = hashlib.sha256(os.fsencode(folder)).hexdigest()[:_ID_DIGITS]  # the name's bytes, UTF-8 or not
    return _UNSAFE.sub("_", f"{Path(folder).name}-{digest}")


def dataset_labels(datasets: Sequence[str | os.PathLike]) -> dict[str, str]:
    """Distinct display names of dataset folders: the folder name, with parents where needed.

    Two folders of one name (``a/office``, ``b/office``) are told apart by
    as many parent folders as it takes (``a/office``, ``b/office``); all
    labels of one call use the same number of path parts. A folder given
    twice gets one label.

    Returns
    -------
    dict
        Resolved folder (str, :func:`resolved_folder`) -> label.
    """
    folders = list(dict.fromkeys(resolved_folder(d) for d in datasets))
    depth = 1
    while True:
        labels = {f: display_name("/".join(Path(f).parts[-depth:])) for f in folders}
        if len(set(labels.values())) == len(folders) or depth > max(len(Path(f).parts) for f in folders):
            return labels
        depth += 1
