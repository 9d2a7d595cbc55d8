"""``ifmi convert-calib``: fit one camera model to another calibration and write it."""

from __future__ import annotations

import sys

from ifmi.geometry.calib_fit import TARGETS, percent_below
from ifmi.io.calibration_conversion import convert_calibration_file

__all__ = ["add_parser", "run", "fit_summary", "frame_change_note"]


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


def run(args) -> int:
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
