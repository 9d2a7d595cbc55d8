"""``ifmi estimate DATASET --method M --out estimate.txt``: orientation of every frame.

Writes the TUM trajectory and, beside it, ``<stem>.frames.csv`` (per-frame
success, reason, counts, time) and ``<stem>.config.json`` (method, full
configuration, the key paths of the values derived from the camera and
frames, dataset, versions), as one set. Exit status: 0 done, 1 an output
could not be written (or would replace a dataset file or an input file:
``--config``, ``--calib``, the video), 2 bad input, 3 done but more than
half of the frames failed.

Where a configuration value comes from: an option given on the command line
wins over the ``--config`` file, which wins over the defaults; a run file's
derived values are derived again (:mod:`ifmi.io.config`). A value the camera
cannot take is reported against the option or the file that gave it.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import warnings
from pathlib import Path

from ifmi.api import estimate as estimate_run
from ifmi.errors import CalibrationFitError, InputError, InputWarning, OutputError
from ifmi.options import RejectedValues, replaced_at_paths
from ifmi.pipeline import EstimateConfig
from ifmi.tracking.methods import load_factory

# Exit status when the outputs were written but more than half of the frames failed.
EXIT_MOSTLY_FAILED = 3
# Method when neither --method nor a --config run file names one.
DEFAULT_METHOD = "ifmi"

# Options that set one configuration value: argparse destination -> key path. The option is
# "--" + the destination with "-" for "_"; a number must be finite.
_VALUE_OPTIONS = {
    "width": "ifmi.panorama.width",
    "height": "ifmi.panorama.height",
    "radius_min": "ifmi.panorama.radius_min_px",
    "radius_max": "ifmi.panorama.radius_max_px",
    "tile_size": "ifmi.tiling.tile_size",
    "overlap": "ifmi.tiling.overlap",
    "th_pr": "ifmi.registration.th_pr",
    "th_pnr": "ifmi.registration.th_pnr",
    "refine_passes": "ifmi.registration.refine_passes",
    "points_per_tile": "ifmi.rays.points_per_tile",
    "ransac_threshold": "relative_pose.ransac_threshold_rad",
    "ransac_threshold_px": "relative_pose.ransac_threshold_px",
    "seed": "relative_pose.seed",
    "keyframe_min_inliers": "keyframe.min_inliers",
    "keyframe_max_angle": "keyframe.max_angle_rad",
    "max_failures": "keyframe.max_failures",
    "rolling_shutter": "rolling_shutter.readout",
    "bundle_window": "bundle_adjustment.window",
}
# Flags: argparse destination -> (key path, value when the flag is given).
_FLAG_OPTIONS = {
    "no_rotation_scale": ("ifmi.registration.estimate_rotation_scale", False),
    "no_prior": ("ifmi.tracking.use_prior", False),
    "rotation_only": ("relative_pose.rotation_only", True),
    "keyframes": ("keyframe.enabled", True),
}
# Key paths (and prefixes) of the options only iFMI's front end reads: the tiles and their registration.
_IFMI_ONLY_KEYS = ("ifmi.tiling.", "ifmi.registration.", "ifmi.rays.points_per_tile", "ifmi.tracking.use_prior")
# Values that decide whether a tile fits its panorama (what a CalibrationFitError is about): the
# sizes first, the band radii (which set the panorama's height) only when no size was set.
_TILE_FIT_KEYS = (("ifmi.tiling.tile_size", "ifmi.panorama.width", "ifmi.panorama.height"),
                  ("ifmi.panorama.radius_min_px", "ifmi.panorama.radius_max_px"))

__all__ = ["add_parser", "run", "chosen_method", "DEFAULT_METHOD"]


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "estimate",
        help="estimate the camera orientation of every frame of a dataset",
        description="Estimate R_0k for every image of DATASET (calib_results.txt + images/) and "
                    "write a TUM trajectory plus NAME.frames.csv and NAME.config.json beside it. "
                    "Frame k is the image named by the integer k (000123.png is frame 123), and "
                    "the trajectory's timestamps are those indices. A video or a ROS bag (with "
                    "--calib; a bag's image topic with --topic) is read frame by frame, its timestamps "
                    "the frames' times in seconds. A frame that fails keeps the "
                    "previous orientation and is flagged.",
        epilog="exit status: 0 done; 1 an output could not be written or would replace a file of "
               "the dataset or an input file (--config, --calib, the video); 2 bad input (dataset, "
               "calibration, configuration, options); 3 outputs written but more than half of the "
               "frames failed.",
    )
    p.add_argument("dataset", metavar="DATASET",
                   help="dataset folder, a video file (.mp4, .avi, ...; needs --calib), or a ROS bag "
                        "(.bag, .mcap, .db3, or a ROS 2 bag folder; needs --calib)")
    p.add_argument("--calib", metavar="CALIB",
                   help="calib_results.txt (or camera.yaml) of a video's or a bag's camera (timestamps "
                        "come from the video or the messages). A dataset folder is estimated with its own "
                        "calibration: with a folder, --calib must name that file or is refused")
    p.add_argument("--topic", metavar="TOPIC",
                   help="a bag's image topic (sensor_msgs/Image or CompressedImage; default: the bag's "
                        "only image topic)")
    p.add_argument("--method", metavar="METHOD",
                   help="front end: a name that 'ifmi methods' lists, or package.module:factory "
                        "(default: the method of a --config run file, else ifmi)")
    p.add_argument("--out", required=True, metavar="ESTIMATE",
                   help="TUM file to write, with NAME.frames.csv and NAME.config.json beside it (never one "
                        "of the inputs or the dataset's files; an earlier estimate's files are replaced)")
    p.add_argument("--force", action="store_true",
                   help="also replace existing files at those paths that no estimate wrote")
    p.add_argument("--config", metavar="JSON",
                   help="start from this configuration: an estimate's NAME.config.json (which also "
                        "gives the method unless --method is given) or a to_dict() JSON. Every "
                        "option given here wins over the file. Values a run derived from its camera "
                        "and frames (the RANSAC threshold in radians, the band radii; listed under "
                        "\"derived\") are derived again for this dataset, so a run file repeats its "
                        "run and carries no camera values to another camera; other values are used "
                        "as given, and one this camera cannot give is refused naming the file")
    _add_config_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _add_config_options(p) -> None:
    """The options that override configuration values (see ``_VALUE_OPTIONS``, ``_FLAG_OPTIONS``)."""
    g = p.add_argument_group("panorama")
    g.add_argument("--width", type=int,
                   help="panorama width in pixels (default: the band's circumference, at most 2048)")
    g.add_argument("--height", type=int, help="panorama height in pixels (default: square pixels)")
    g.add_argument("--radius-min", type=float, metavar="PX", help="inner sensor radius of the band")
    g.add_argument("--radius-max", type=float, metavar="PX", help="outer sensor radius of the band")
    g = p.add_argument_group("tiles and iFMI")
    g.add_argument("--tile-size", type=float, metavar="N",
                   help="tile side: pixels if >= 1 (at least 8), else a fraction of the panorama "
                        "width giving at least 8 px (default: width / 16 within 32..64 px)")
    g.add_argument("--overlap", type=float,
                   help="tile overlap fraction in [0, 1); a layout with more tiles per frame than 1 GiB "
                        "registers (12483 of 32 px) is refused")
    g.add_argument("--th-pr", type=float, help="smallest accepted peak ratio")
    g.add_argument("--th-pnr", type=float, help="smallest accepted peak-to-noise ratio")
    g.add_argument("--points-per-tile", type=int, choices=(1, 5, 9), help="flow points per tile")
    g.add_argument("--refine-passes", type=int,
                   help="iFMI refinement passes, 0..10 (default 1; 0 is about 20%% faster)")
    g.add_argument("--no-rotation-scale", action="store_true",
                   help="measure tile translation only (no log-polar stage)")
    g.add_argument("--no-prior", action="store_true",
                   help="do not cut tiles where the predicted rotation moves them")
    g = p.add_argument_group("relative pose")
    g.add_argument("--ransac-threshold", type=float, metavar="RAD",
                   help="RANSAC threshold in radians (overrides --ransac-threshold-px)")
    g.add_argument("--ransac-threshold-px", type=float, metavar="PX",
                   help="RANSAC threshold in pixels, converted with the angle a pixel of the "
                        "calibration's mirror band subtends (default 1; replaces a radian "
                        "threshold of --config)")
    g.add_argument("--rotation-only", action="store_true", help="force the rotation-only model")
    g.add_argument("--seed", type=int, help="RANSAC seed (>= 0)")
    g = p.add_argument_group("keyframes")
    g.add_argument("--keyframes", action="store_true", help="estimate against keyframes")
    g.add_argument("--keyframe-min-inliers", type=int, metavar="N",
                   help="switch keyframes below this inlier count")
    g.add_argument("--keyframe-max-angle", type=float, metavar="RAD",
                   help="switch keyframes past this rotation from the keyframe")
    g.add_argument("--max-failures", type=int, metavar="N",
                   help="after N failed frames in a row, restart from the current frame "
                        "(default 2; 0 never)")
    g = p.add_argument_group("camera")
    g.add_argument("--rolling-shutter", type=float, metavar="READOUT",
                   help="rolling-shutter read-out: time from the first row to the last as a fraction "
                        "of the frame interval, 0..1 (read-out seconds x frames per second; default 0, "
                        "a global shutter); rays are moved to their image's middle row before each "
                        "pose is re-fitted")
    g = p.add_argument_group("trajectory")
    g.add_argument("--bundle-window", type=int, metavar="N",
                   help="refine the trajectory by bundle adjustment of the points the last N frames "
                        "share (a fixed-lag smoother; N >= 2, default 0: off). For a camera that moves: "
                        "on translated sequences it lowers the error, on a camera turning on the spot "
                        "it raises it (README, 'Bundle adjustment')")


def _option(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def _given_options(args) -> dict:
    """Key path -> (option, value) of every configuration option on the command line.

    Raises
    ------
    InputError
        A number that is NaN or infinite, naming the option.
    """
    given = {}
    for dest, key in _VALUE_OPTIONS.items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(_option(dest), f"expected a finite number, got {value}")
        given[key] = (_option(dest), value)
    for dest, (key, value) in _FLAG_OPTIONS.items():
        if getattr(args, dest, False):
            given[key] = (_option(dest), value)
    if "relative_pose.ransac_threshold_px" in given and "relative_pose.ransac_threshold_rad" not in given:
        # A pixel threshold given here replaces a radian threshold of --config: converted again.
        given["relative_pose.ransac_threshold_rad"] = ("--ransac-threshold-px", None)
    return given


def _with_values(config, values: dict):
    """``config`` with ``values`` (key path -> (option, value)) set (:func:`ifmi.options.replaced_at_paths`).

    Raises
    ------
    InputError
        A value the configuration rejects, naming the options that set its fields.
    """
    try:
        return replaced_at_paths(config, values)
    except RejectedValues as exc:
        raise InputError("/".join(exc.sources) or "command line", str(exc)) from None


def _configuration(args) -> tuple:
    """``(--config file or None, options given, configuration)``: the file's, then the options, which win."""
    from ifmi.io.config import read_config_file

    config_file = read_config_file(args.config) if args.config else None
    given = _given_options(args)
    config = _with_values(EstimateConfig() if config_file is None else config_file.config, given)
    return config_file, given, config


def chosen_method(option: str | None, config_file) -> str:
    """The method to run: ``--method``, else the ``--config`` run file's, else :data:`DEFAULT_METHOD`."""
    return option or (config_file.method if config_file else None) or DEFAULT_METHOD


_NOT_A_KEY = object()


def _value_at(config, key: str):
    """The value of ``config`` at the dotted ``key`` (None below a section that is None), or
    ``_NOT_A_KEY`` when ``key`` names no field."""
    value = config
    for part in key.split("."):
        if value is None:
            return None
        if not dataclasses.is_dataclass(value) or part not in {f.name for f in dataclasses.fields(value)}:
            return _NOT_A_KEY
        value = getattr(value, part)
    return value


def _set_in_file(config_file, key: str) -> bool:
    """Whether the configuration file sets ``key`` (or a value below it) to other than the default."""
    if config_file is None:
        return False
    value = _value_at(config_file.config, key)
    return value is not _NOT_A_KEY and value != _value_at(EstimateConfig(), key)


def _blamed(exc: InputError, given: dict, config_file) -> InputError:
    """``exc`` reported against the option or configuration file that set the value it is about.

    A configuration check names a key path (``ifmi.panorama.width``); a tile
    that does not fit its panorama names the calibration. When the values
    concerned came from the command line the option is named before the
    key path (for a tile the calibration stays named: its message names the
    options); when they came from the ``--config`` file, the file.
    """
    if isinstance(exc, CalibrationFitError):
        if any(key in given for group in _TILE_FIT_KEYS for key in group):
            return exc
        for group in _TILE_FIT_KEYS:
            keys = [key for key in group if _set_in_file(config_file, key)]
            if keys:
                return InputError(config_file.path, f"{', '.join(keys)}: {exc.problem}")
        return exc
    key = exc.path
    if "." not in key or _value_at(EstimateConfig(), key) is _NOT_A_KEY:
        return exc  # a file's error, not a configuration key's
    options = [option for k, (option, _) in given.items() if k == key or k.startswith(key + ".")]
    if options:
        return InputError("/".join(dict.fromkeys(options)), f"{key}: {exc.problem}")
    if _set_in_file(config_file, key):
        return InputError(config_file.path, f"{key}: {exc.problem}")
    return exc


def _check_folder_calib(dataset: str, calib: str) -> None:
    """Refuse a ``--calib`` other than the dataset folder's own calibration file."""
    from ifmi.io.camera_file import calibration_path

    if not Path(dataset).is_dir():
        return  # the dataset reader names what is wrong with it
    try:
        own = calibration_path(dataset)
    except InputError:
        raise InputError(calib, f"--calib is for a video; the dataset folder {dataset} is estimated with "
                                f"its own calibration (calib_results.txt or camera.yaml), which it lacks") from None
    try:
        same = os.path.samefile(own, calib)
    except OSError:
        same = False
    if not same:
        raise InputError(calib, f"is not the calibration of the dataset folder, {own}; a dataset folder is "
                                f"estimated with its own calibration (--calib is for a video): drop --calib")


def _derived_keys(config: EstimateConfig, used: EstimateConfig) -> list:
    """Key paths the run derived from the camera and frames (None in ``config``, set in ``used``)."""
    from ifmi.io.config import DERIVED_KEYS

    return [key for key in DERIVED_KEYS if _value_at(config, key) is None and _value_at(used, key) is not None]


def _warn_ignored_options(method: str, given: dict) -> None:
    """One warning line naming the options given that ``method`` (a built-in keypoint method) does not read."""
    from ifmi.tracking.methods import ignores_tiling

    if not ignores_tiling(method):
        return
    ignored = sorted({option for key, (option, _) in given.items() if key.startswith(_IFMI_ONLY_KEYS)})
    if ignored:
        warnings.warn(f"{', '.join(ignored)} only change{'s' if len(ignored) == 1 else ''} iFMI's tiles; "
                      f"--method {method} does not read {'it' if len(ignored) == 1 else 'them'}", InputWarning)


def _input_kind(args) -> tuple[bool, bool]:
    """``(bag, video or bag)`` of the DATASET argument, with its options checked.

    Raises
    ------
    InputError
        A file that is neither a video nor a bag, a video or bag without
        ``--calib``, ``--topic`` without a bag, or a folder's ``--calib``
        that is not its own calibration.
    OutputError
        ``--out`` inside a ROS 2 bag folder.
    """
    from ifmi.io.atomic import path_within
    from ifmi.io.bags import BAG_SUFFIXES, is_bag_path
    from ifmi.io.video import VIDEO_SUFFIXES, is_video_path

    bag = is_bag_path(args.dataset)
    video = bag or is_video_path(args.dataset)  # a sequence file with its own --calib
    if not video and Path(args.dataset).is_file():
        raise InputError(args.dataset, f"neither a dataset folder nor a video nor a ROS bag (expected a folder "
                                       f"with calib_results.txt or camera.yaml and images/, a video file "
                                       f"ending in {', '.join(VIDEO_SUFFIXES)}, or a bag ending in "
                                       f"{', '.join(BAG_SUFFIXES)} or a ROS 2 bag folder, with --calib)")
    if video and not args.calib:
        raise InputError(args.dataset, f"a {'bag' if bag else 'video'} needs --calib CALIB (calib_results.txt)")
    if args.topic is not None and not bag:
        raise InputError("--topic", f"is for a ROS bag; {args.dataset} is not one")
    if bag and Path(args.dataset).is_dir() and path_within(args.out, args.dataset):
        raise OutputError(args.out, f"lies in the bag folder {args.dataset}; choose a path outside it")
    if args.calib and not video:
        _check_folder_calib(args.dataset, args.calib)
    return bag, video


def run(args) -> int:
    from ifmi.io.results import check_estimate_outputs, side_file_paths

    config_file, given, config = _configuration(args)
    method = chosen_method(args.method, config_file)
    load_factory(method)  # an unknown or broken method fails before any work
    _warn_ignored_options(method, given)
    out = Path(args.out)
    bag, video = _input_kind(args)
    inputs = ((args.dataset, args.calib) if video else ()) + ((args.config,) if args.config else ())
    dataset_dir = None if video else args.dataset
    check_estimate_outputs(args.out, dataset_dir=dataset_dir, input_files=inputs, overwrite=args.force)
    try:
        estimate = estimate_run(args.dataset, method=method, config=config, calib=args.calib if video else None,
                                topic=args.topic if bag else None, progress=not args.no_progress)
    except InputError as exc:
        raise _blamed(exc, given, config_file) from None
    estimate.write(out, input_files=inputs, extra={"derived": _derived_keys(config, estimate.config)},
                   overwrite=args.force)
    failed = sum(not r.success for r in estimate.frames)
    least_certain = estimate.least_certain_frame()
    certainty = "" if least_certain is None else (
        f"; largest predicted rotation error {least_certain[1]:.2g} rad (frame {least_certain[0]})")
    print(f"{out}: {len(estimate.frames)} frames, {failed} failed{certainty}")
    if 2 * failed > len(estimate.frames):
        print(f"ifmi estimate: warning: {failed} of {len(estimate.frames)} frames failed (more than "
              f"half; see {side_file_paths(out)[0].name}); exit status {EXIT_MOSTLY_FAILED}",
              file=sys.stderr)
        return EXIT_MOSTLY_FAILED
    return 0
