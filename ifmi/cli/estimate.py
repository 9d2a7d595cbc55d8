"""``ifmi estimate DATASET --method M --out estimate.txt``: orientation of every frame.

Writes the TUM trajectory and, beside it, ``<stem>.frames.csv`` (per-frame
success, reason, counts, time) and ``<stem>.config.json`` (method, full
configuration, dataset, versions), as one set. Exit status: 0 done, 1 an
output could not be written (or would replace a dataset file), 2 bad input,
3 done but more than half of the frames failed.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from ..errors import InputError
from ..methods import load_factory
from ..pipeline import EstimateConfig, estimate_dataset, estimate_video

# Exit status when the outputs were written but more than half of the frames failed.
EXIT_MOSTLY_FAILED = 3

__all__ = ["add_parser", "run", "config_from_args"]


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "estimate",
        help="estimate the camera orientation of every frame of a dataset",
        description="Estimate R_0k for every image of DATASET (calib_results.txt + images/) and "
                    "write a TUM trajectory plus NAME.frames.csv and NAME.config.json beside it. "
                    "Frame k is the image named by the integer k (000123.png is frame 123), and "
                    "the trajectory's timestamps are those indices. A frame that fails keeps the "
                    "previous orientation and is flagged.",
        epilog="exit status: 0 done; 1 an output could not be written or would replace a file of "
               "the dataset; 2 bad input (dataset, calibration, options); 3 outputs written but more "
               "than half of the frames failed.",
    )
    p.add_argument("dataset", metavar="DATASET",
                   help="dataset folder, or a video file (.mp4, .avi, ...; needs --calib)")
    p.add_argument("--calib", metavar="CALIB",
                   help="calib_results.txt of a video's camera (timestamps come from the video)")
    p.add_argument("--method", default="ifmi", metavar="METHOD",
                   help="front end: a name that 'ifmi methods' lists, or package.module:factory "
                        "(default ifmi)")
    p.add_argument("--out", required=True, metavar="ESTIMATE", help="TUM file to write")
    p.add_argument("--config", metavar="JSON",
                   help="start from this configuration (an estimate's NAME.config.json or a "
                        "to_dict() JSON); the options below override it")
    g = p.add_argument_group("panorama")
    g.add_argument("--width", type=int,
                   help="panorama width in pixels (default: the band's circumference, at most 2048)")
    g.add_argument("--height", type=int, help="panorama height in pixels (default: square pixels)")
    g.add_argument("--radius-min", type=float, metavar="PX", help="inner sensor radius of the band")
    g.add_argument("--radius-max", type=float, metavar="PX", help="outer sensor radius of the band")
    g = p.add_argument_group("tiles and iFMI")
    g.add_argument("--tile-size", type=float, metavar="N",
                   help="tile side: pixels if >= 1, else a fraction of the panorama width "
                        "(default: width / 16 within 32..64 px)")
    g.add_argument("--overlap", type=float, help="tile overlap fraction in [0, 1)")
    g.add_argument("--th-pr", type=float, help="smallest accepted peak ratio")
    g.add_argument("--th-pnr", type=float, help="smallest accepted peak-to-noise ratio")
    g.add_argument("--points-per-tile", type=int, choices=(1, 5, 9), help="flow points per tile")
    g.add_argument("--refine-passes", type=int,
                   help="iFMI refinement passes (default 1; 0 is about 20%% faster)")
    g.add_argument("--no-rotation-scale", action="store_true",
                   help="measure tile translation only (no log-polar stage)")
    g.add_argument("--no-prior", action="store_true",
                   help="do not cut tiles where the predicted rotation moves them")
    g = p.add_argument_group("relative pose")
    g.add_argument("--ransac-threshold", type=float, metavar="RAD",
                   help="RANSAC threshold in radians (overrides --ransac-threshold-px)")
    g.add_argument("--ransac-threshold-px", type=float, metavar="PX",
                   help="RANSAC threshold in pixels, converted with the angle a pixel of the "
                        "calibration's mirror band subtends (default 1)")
    g.add_argument("--rotation-only", action="store_true", help="force the rotation-only model")
    g.add_argument("--seed", type=int, help="RANSAC seed")
    g = p.add_argument_group("keyframes")
    g.add_argument("--keyframes", action="store_true", help="estimate against keyframes")
    g.add_argument("--keyframe-min-inliers", type=int, metavar="N",
                   help="switch keyframes below this inlier count")
    g.add_argument("--keyframe-max-angle", type=float, metavar="RAD",
                   help="switch keyframes past this rotation from the keyframe")
    g.add_argument("--max-failures", type=int, metavar="N",
                   help="after N failed frames in a row, restart from the current frame "
                        "(default 2; 0 never)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _override(obj, **values):
    values = {k: v for k, v in values.items() if v is not None}
    return replace(obj, **values) if values else obj


def config_from_args(args) -> EstimateConfig:
    """EstimateConfig from parsed arguments (``--config`` file, then explicit options)."""
    from ..io.config import read_estimate_config

    config = read_estimate_config(args.config) if args.config else EstimateConfig()
    ifmi = config.ifmi
    try:
        ifmi = replace(
            ifmi,
            panorama=_override(ifmi.panorama, width=args.width, height=args.height,
                               radius_min_px=args.radius_min, radius_max_px=args.radius_max),
            tiling=_override(ifmi.tiling, tile_size=args.tile_size, overlap=args.overlap),
            registration=_override(ifmi.registration, th_pr=args.th_pr, th_pnr=args.th_pnr,
                                   refine_passes=args.refine_passes,
                                   estimate_rotation_scale=False if args.no_rotation_scale else None),
        )
        ifmi = _override(ifmi, points_per_tile=args.points_per_tile,
                         use_prior=False if args.no_prior else None)
        pose = _override(config.relative_pose, ransac_threshold_rad=args.ransac_threshold,
                         ransac_threshold_px=args.ransac_threshold_px,
                         rotation_only=True if args.rotation_only else None, seed=args.seed)
        keyframe = _override(config.keyframe, enabled=True if args.keyframes else None,
                             min_inliers=args.keyframe_min_inliers,
                             max_angle_rad=args.keyframe_max_angle,
                             max_failures=args.max_failures)
    except ValueError as exc:
        raise InputError("command line", str(exc)) from None
    return replace(config, ifmi=ifmi, relative_pose=pose, keyframe=keyframe)


def run(args) -> int:
    from ..io.results import check_estimate_outputs, side_file_paths, write_estimate_run
    from ..io.video import is_video_path

    load_factory(args.method)  # an unknown or broken method fails before any work
    config = config_from_args(args)
    out = Path(args.out)
    video = is_video_path(args.dataset)
    if video and not args.calib:
        raise InputError(args.dataset, "a video needs --calib CALIB (calib_results.txt)")
    inputs = (args.dataset, args.calib) if video else ()
    dataset_dir = None if video else args.dataset
    check_estimate_outputs(out, dataset_dir=dataset_dir, input_files=inputs)
    if video:
        estimate = estimate_video(args.dataset, args.calib, method=args.method, config=config,
                                  progress=not args.no_progress)
    else:
        estimate = estimate_dataset(args.dataset, method=args.method, config=config,
                                    progress=not args.no_progress)
    write_estimate_run(out, estimate, dataset_dir=dataset_dir, input_files=inputs)
    failed = sum(not r.success for r in estimate.frames)
    print(f"{out}: {len(estimate.frames)} frames, {failed} failed")
    if 2 * failed > len(estimate.frames):
        print(f"ifmi estimate: warning: {failed} of {len(estimate.frames)} frames failed (more than "
              f"half; see {side_file_paths(out)[0].name}); exit status {EXIT_MOSTLY_FAILED}",
              file=sys.stderr)
        return EXIT_MOSTLY_FAILED
    return 0
