"""The calibration file of a dataset folder: OCamCalib ``calib_results.txt`` or Kalibr ``camera.yaml``.

A DATASET folder holds exactly one of the two; :func:`calibration_path`
finds it, :func:`read_camera` reads either format by its file name, and
:func:`write_camera` writes a model in its own format. Converting one
model into another is :mod:`ifmi.io.calibration_conversion`'s.
"""

from __future__ import annotations

import os
from pathlib import Path

from ifmi.geometry.camera import OcamModel
from ifmi.errors import InputError
from ifmi.io.calib import read_calib, write_calib
from ifmi.io.kalibr import read_kalibr, write_kalibr
from ifmi.io.text_file import refuse_special_file

__all__ = ["OCAMCALIB_FILE", "KALIBR_FILE", "calibration_path", "read_camera", "write_camera",
           "camera_file_name"]

OCAMCALIB_FILE = "calib_results.txt"
KALIBR_FILE = "camera.yaml"
# Suffixes read as Kalibr camchain YAML; anything else is read as OCamCalib text.
_YAML_SUFFIXES = (".yaml", ".yml")


def calibration_path(folder: str | os.PathLike) -> Path:
    """The one calibration file of a dataset folder.

    Raises
    ------
    InputError
        Neither or both of ``calib_results.txt`` and ``camera.yaml`` present,
        either a link to a missing file, or the one present a FIFO, device or
        socket (reading it would wait for a writer that never comes).
    """
    folder = Path(folder)
    for name in (OCAMCALIB_FILE, KALIBR_FILE):
        if (folder / name).is_symlink() and not (folder / name).exists():
            # Passed over, the other file (or "not found") would stand in for the calibration meant.
            raise InputError(folder / name, f"is a link to a missing file ({os.readlink(folder / name)})")
    # Whatever exists under either name is the calibration: a folder of that name is then named as one.
    found = [folder / name for name in (OCAMCALIB_FILE, KALIBR_FILE) if (folder / name).exists()]
    if not found:
        raise InputError(folder / OCAMCALIB_FILE, f"calibration file not found (expected "
                                                  f"{OCAMCALIB_FILE} or {KALIBR_FILE})")
    if len(found) > 1:
        raise InputError(folder, f"holds both {OCAMCALIB_FILE} and {KALIBR_FILE}; keep exactly one")
    refuse_special_file(found[0], what="calibration file")  # a folder is named as one when it is read
    return found[0]


def read_camera(path: str | os.PathLike):
    """Camera model of a calibration file: Kalibr YAML (``.yaml``/``.yml``) or OCamCalib text."""
    path = Path(path)
    return read_kalibr(path) if path.suffix.lower() in _YAML_SUFFIXES else read_calib(path)


def camera_file_name(model) -> str:
    """File name a dataset uses for ``model``: ``calib_results.txt`` (OCamCalib) or ``camera.yaml``."""
    return OCAMCALIB_FILE if isinstance(model, OcamModel) else KALIBR_FILE


def write_camera(folder: str | os.PathLike, model) -> Path:
    """Write ``model`` into a dataset folder in its own format; returns the file's path."""
    path = Path(folder) / camera_file_name(model)
    if isinstance(model, OcamModel):
        write_calib(path, model)
    else:
        write_kalibr(path, model)
    return path
