"""Writing one camera model fitted to another calibration, never over that calibration or its dataset.

This module sits above :mod:`ifmi.io.camera_file` (which reads and writes a
calibration) and :mod:`ifmi.io.dataset` (which knows the files a dataset
holds, and itself finds its calibration through ``camera_file``): the
conversion needs both, so it lives in neither.
"""

from __future__ import annotations

import os
from pathlib import Path

from ifmi.geometry.camera import OcamModel
from ifmi.errors import InputError, OutputError
from ifmi.io.calib import write_calib
from ifmi.io.camera_file import KALIBR_FILE, OCAMCALIB_FILE, calibration_path, read_camera
from ifmi.io.dataset import refuse_output_in_datasets
from ifmi.io.kalibr import write_kalibr

__all__ = ["convert_calibration_file", "check_out_suffix", "check_out_spares_inputs"]

# Suffixes that ifmi.io.camera_file.read_camera reads as a Kalibr camchain (any other: OCamCalib
# text); the output must carry one exactly when the target is a Kalibr model, so the file reads back.
_KALIBR_SUFFIXES = (".yaml", ".yml")


def check_out_suffix(out: str | os.PathLike, target: str) -> None:
    """Refuse an output path whose suffix would make the written file read back in the other format.

    Raises
    ------
    InputError
        A Kalibr target without a ``.yaml``/``.yml`` suffix, or ``ocamcalib`` with one.
    """
    suffix = Path(out).suffix
    is_kalibr_name = suffix.lower() in _KALIBR_SUFFIXES
    if target == "ocamcalib" and is_kalibr_name:
        raise InputError(out, f"--out: an ocamcalib model is written as OCamCalib text, but a {suffix} file is "
                              f"read as Kalibr YAML; expected another suffix, e.g. calib_results.txt")
    if target != "ocamcalib" and not is_kalibr_name:
        raise InputError(out, f"--out: a {target} model is written as a Kalibr camchain, which is read back "
                              f"from a .yaml or .yml file only; expected e.g. camera.yaml, got suffix "
                              f"{suffix or '(none)'}")


def check_out_spares_inputs(source: str | os.PathLike, out: str | os.PathLike) -> None:
    """Refuse an output path that would replace the input calibration or harm its dataset.

    The dataset is ``source`` when it is a folder, else the folder of the
    calibration file when it holds ``images/``: a second calibration file
    there (camera.yaml beside calib_results.txt) would make it unreadable.

    Raises
    ------
    OutputError
        ``out`` is the input calibration file, a second calibration file of
        the dataset, or one of its files or folders
        (:func:`ifmi.io.dataset.dataset_conflict`).
    """
    source = Path(source)
    calib = calibration_path(source) if source.is_dir() else source
    try:
        same = os.path.samefile(calib, out)
    except OSError:  # out does not exist yet (or calib does not: reading it says so)
        same = False
    if same:
        raise OutputError(out, f"is the input calibration {calib}; choose another output path")
    dataset = source if source.is_dir() else calib.parent
    if not (source.is_dir() or (dataset / "images").is_dir()):
        return
    real = Path(os.path.realpath(out))
    second = real.name in (OCAMCALIB_FILE, KALIBR_FILE) and not real.exists()
    if second and real.parent == Path(os.path.realpath(dataset)):
        raise OutputError(out, f"would put a second calibration into the dataset {dataset}, which holds "
                               f"{calib.name} (a dataset holds one); choose another output path")
    refuse_output_in_datasets(out, [dataset])


def convert_calibration_file(source: str | os.PathLike, target: str, out: str | os.PathLike, *,
                             overwrite: bool = False):
    """Fit a ``target`` model to the calibration at ``source`` and write it to ``out``.

    ``out`` must carry the suffix its format reads back from
    (:func:`check_out_suffix`) and is never the input calibration nor a
    file of its dataset, with ``overwrite`` or without
    (:func:`check_out_spares_inputs`); both are checked before anything is
    read or fitted.

    Parameters
    ----------
    source : path
        ``calib_results.txt``, ``camera.yaml`` or a dataset folder holding one.
    target : str
        One of :data:`ifmi.geometry.calib_fit.TARGETS`; ``ocamcalib`` is written as
        OCamCalib text, the others as a Kalibr camchain.
    out : path
    overwrite : bool, keyword-only
        Replace an existing ``out`` (otherwise an error).

    Returns
    -------
    ifmi.geometry.calib_fit.CalibrationFit

    Raises
    ------
    InputError
        Unreadable source, an ``out`` of the other format's suffix, an
        existing ``out`` without ``overwrite``, or a source that no model converts.
    OutputError
        ``out`` would replace the input calibration or harm its dataset.
    """
    from ifmi.geometry.calib_fit import fit_camera_model

    check_out_suffix(out, target)
    check_out_spares_inputs(source, out)
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
