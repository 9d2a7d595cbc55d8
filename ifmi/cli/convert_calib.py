"""``ifmi convert-calib``: fit one camera model to another calibration and write it."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ..calib_fit import TARGETS, percent_below
from ..errors import InputError, OutputError
from ..io.camera_file import KALIBR_FILE, OCAMCALIB_FILE, calibration_path, convert_calibration_file
from ..io.dataset import refuse_output_in_datasets

__all__ = ["add_parser", "run", "fit_summary", "check_out_suffix", "check_out_spares_inputs",
           "frame_change_note"]

# Suffixes that ifmi.io.camera_file.read_camera reads as a Kalibr camchain (any other: OCamCalib
# text); --out must carry one exactly when the target is a Kalibr model, so the file reads back.
_KALIBR_SUFFIXES = (".yaml", ".yml")


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "convert-calib",
        help="fit another camera model (Kalibr ds, eucm, omni, kb, pinhole, or OCamCalib) to a calibration",
        description="Least-squares fit of the --to model to the rays of IN over IN's valid image "
                    "region; prints the fit's largest and median reprojection error in pixels. "
                    "Kalibr models are written as camchain YAML, ocamcalib as calib_results.txt text.",
    )
    p.add_argument("calib", metavar="IN", help="calib_results.txt, camera.yaml, or a DATASET folder")
    p.add_argument("--to", required=True, choices=TARGETS, help="model to fit")
    p.add_argument("--out", required=True, help="calibration file to write: .yaml/.yml for a Kalibr model, "
                                                "another suffix (calib_results.txt) for ocamcalib")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run)


def fit_summary(fit) -> str:
    """The fit's errors and the region they are measured over, e.g. ``max reprojection error 0.1 px, ...``."""
    region = ("over the valid region" if fit.coverage == 1.0 else
              f"over the {percent_below(fit.coverage)} % of the valid region that the model sees")
    return (f"max reprojection error {fit.max_error_px:.4f} px, median {fit.median_error_px:.4f} px "
            f"{region}")


def check_out_suffix(out, target: str) -> None:
    """Refuse an ``--out`` whose suffix would make the written file read back in the other format.

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


def check_out_spares_inputs(source, out) -> None:
    """Refuse an ``--out`` that would replace the input calibration or harm its dataset, --force or not.

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


def run(args) -> int:
    check_out_suffix(args.out, args.to)
    check_out_spares_inputs(args.calib, args.out)
    fit = convert_calibration_file(args.calib, args.to, args.out, overwrite=args.force)
    print(f"{args.out}: {args.to} fitted to {args.calib}: {fit_summary(fit)}")
    if not fit.success:
        print(f"ifmi convert-calib: warning: {fit.reason}", file=sys.stderr)
    if fit.changes_frame:
        print(f"ifmi convert-calib: warning: {frame_change_note(args.out, args.to)}", file=sys.stderr)
    return 0


def frame_change_note(out, target: str) -> str:
    """One line: ``out`` keeps another toolbox's camera frame than its source, so poses differ."""
    new, old = (("OCamCalib", "Kalibr") if target == "ocamcalib" else ("Kalibr", "OCamCalib"))
    return (f"{out}: the {new} camera frame is not the {old} one of the source (x and y swapped, z "
            "reversed): rotations estimated with it are T R T^T of the source's, T = [[0,1,0],[1,0,0],"
            "[0,0,-1]], so a dataset's groundtruth.txt made for the source does not fit it")
