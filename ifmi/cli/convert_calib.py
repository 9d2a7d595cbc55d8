"""``ifmi convert-calib``: fit one camera model to another calibration and write it."""

from __future__ import annotations

import sys

from ..calib_fit import TARGETS
from ..io.camera_file import convert_calibration_file

__all__ = ["add_parser", "run", "fit_summary"]


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
    p.add_argument("--out", required=True, help="calibration file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run)


def fit_summary(fit) -> str:
    """The fit's errors and the region they are measured over, e.g. ``max reprojection error 0.1 px, ...``."""
    region = ("over the valid region" if fit.coverage == 1.0 else
              f"over the {100 * fit.coverage:.1f} % of the valid region that the model sees")
    return (f"max reprojection error {fit.max_error_px:.4f} px, median {fit.median_error_px:.4f} px "
            f"{region}")


def run(args) -> int:
    fit = convert_calibration_file(args.calib, args.to, args.out, overwrite=args.force)
    print(f"{args.out}: {args.to} fitted to {args.calib}: {fit_summary(fit)}")
    if not fit.success:
        print(f"ifmi convert-calib: warning: {fit.reason}", file=sys.stderr)
    return 0
