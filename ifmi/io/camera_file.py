"""The calibration file of a dataset folder: OCamCalib ``calib_results.txt`` or Kalibr ``camera.yaml``.

A DATASET folder holds exactly one of the two; :func:`calibration_path`
finds it, :func:`read_camera` reads either format by its file name, and
:func:`write_camera` writes a model in its own format.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..camera import OcamModel
from ..errors import InputError
from .calib import read_calib, write_calib
from .kalibr import read_kalibr, write_kalibr
from .text_file import refuse_special_file

__all__ = ["OCAMCALIB_FILE", "KALIBR_FILE", "calibration_path", "read_camera", "write_camera",
           "camera_file_name", "convert_calibration_file"]

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
        or the one present is a FIFO, device or socket (reading it would wait
        for a writer that never comes).
    """
    folder = Path(folder)
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


def convert_calibration_file(source: str | os.PathLike, target: str, out: str | os.PathLike, *,
                             overwrite: bool = False):
    """Fit a ``target`` model to the calibration at ``source`` and write it to ``out``.

    Parameters
    ----------
    source : path
        ``calib_results.txt``, ``camera.yaml`` or a dataset folder holding one.
    target : str
        One of :data:`ifmi.calib_fit.TARGETS`; ``ocamcalib`` is written as
        OCamCalib text, the others as a Kalibr camchain.
    out : path
    overwrite : bool, keyword-only
        Replace an existing ``out`` (otherwise an error).

    Returns
    -------
    ifmi.calib_fit.CalibrationFit

    Raises
    ------
    InputError
        Unreadable source, an existing ``out``, or a source that no model converts.
    """
    from ..calib_fit import fit_camera_model

    source, out = Path(source), Path(out)
    path = calibration_path(source) if source.is_dir() else source
    model = read_camera(path)
    if out.exists() and not overwrite:
        raise InputError(out, "exists; choose another --out or pass --force")
    try:
        fit = fit_camera_model(model, target)
    except ValueError as exc:
        raise InputError(path, str(exc)) from None
    if isinstance(fit.model, OcamModel):
        write_calib(out, fit.model)
    else:
        write_kalibr(out, fit.model)
    return fit
