"""Command line of ``omnisim``: parsing only; rendering lives in :mod:`omnisim.renderer`."""

from __future__ import annotations

import argparse
import re
import sys

from ifmi.runtime.parser import OneLineValueErrors
from ifmi.runtime.warning_lines import input_warnings_as_lines
from ifmi.errors import ClusterError, InputError, OutputError
from ifmi.runtime.interrupts import caused_by_interrupt, interrupts_recorded, report_interrupt
from ifmi.runtime.local_workers import DEFAULT_CONNECT_TIMEOUT_S, connect_timeout_argument

# Everything heavier (numpy, the scene settings, Mitsuba) is imported inside main(),
# after its interrupt handler is in place.

__all__ = ["main", "build_parser"]


def _resolution(text: str):
    """``N`` (square), ``HEIGHTxWIDTH`` or ``HEIGHT,WIDTH``: every part a number, none left empty."""
    parts = re.split(r"\s*[x,]\s*", text.strip().lower())
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N or HEIGHTxWIDTH, got {text!r}") from None
    if len(values) == 1:
        return (values[0], values[0])
    if len(values) == 2:
        return tuple(values)
    raise argparse.ArgumentTypeError(f"expected N or HEIGHTxWIDTH, got {text!r}")


def _add_export_parser(sub) -> None:
    """The ``export`` command's options (:mod:`omnisim.export`)."""
    export = sub.add_parser("export", help="write a dataset folder as a ROS bag (ROS 2 MCAP/SQLite3 folder "
                            "or ROS 1 .bag): images, ground truth, world poses on /tf")
    export.add_argument("dataset", help="source DATASET folder")
    export.add_argument("--out", required=True,
                        help="bag to write: a folder (ros2) or a .bag file (ros1); must not exist")
    export.add_argument("--format", dest="bag_format", choices=("ros2", "ros1"), default="ros2",
                        help="ros2: a bag folder (default); ros1: a .bag file")
    export.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                        help="storage of a ROS 2 bag (default mcap)")
    export.add_argument("--compressed", choices=("png", "jpeg"),
                        help="images as sensor_msgs/CompressedImage of this format (png is lossless); "
                             "default raw sensor_msgs/Image")
    export.add_argument("--start-time", type=float, default=0.0, metavar="S",
                        help="stamp of frame 0 in seconds (default 0: stamps equal groundtruth.txt's times "
                             "with the default interval)")
    export.add_argument("--frame-interval", type=float, default=1.0, metavar="S",
                        help="seconds between frames (default 1); frame k is stamped start + k x interval")
    export.add_argument("--no-progress", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    from omnisim.config import EffectsSettings
    from omnisim.settings import field_docs

    parser = OneLineValueErrors(prog="omnisim", description="Render catadioptric omni-image "
                                     "sequences with exact ground truth (Mitsuba 3).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    render = sub.add_parser("render", help="render a scene file into a dataset folder")
    render.add_argument("scene", help="scene file (TOML), e.g. scenes/office.toml")
    render.add_argument("--out", required=True, help="dataset folder to write (resumed if it exists)")
    render.add_argument("--frames", type=int, help="number of frames (default: the scene's)")
    render.add_argument("--seed", type=int, help="motion/sampling/effects seed (default: the scene's)")
    render.add_argument("--spp", type=int, help="samples per pixel (default: the scene's)")
    render.add_argument("--resolution", type=_resolution,
                        help="image size N or HEIGHTxWIDTH (default: the scene's); the calib is scaled")
    render.add_argument("--variant", help="Mitsuba variant (default: cuda_ad_rgb with a GPU, else llvm_ad_rgb)")
    render.add_argument("--no-progress", action="store_true", help="no progress bar")
    render.add_argument("--aov", default="", metavar="NAMES",
                        help="per-pixel ground truth to write, comma-separated: depth, normal")
    parallel = render.add_mutually_exclusive_group()
    parallel.add_argument("--workers", type=int,
                          help="render on a local Dask cluster of N processes (at most the CPUs this "
                               "process may use)")
    parallel.add_argument("--scheduler", metavar="ADDRESS", help="render on the Dask cluster at ADDRESS")
    render.add_argument("--connect-timeout", type=connect_timeout_argument, default=DEFAULT_CONNECT_TIMEOUT_S,
                        metavar="SECONDS",
                        help=f"how long a --scheduler has to accept the connection and answer "
                             f"(default {DEFAULT_CONNECT_TIMEOUT_S:g})")
    degrade = sub.add_parser("degrade", help="copy a dataset folder with capture effects "
                             "(noise, JPEG, exposure drift) applied to its images")
    degrade.add_argument("dataset", help="source DATASET folder (rendered or real)")
    degrade.add_argument("--out", required=True, help="dataset folder to write (resumed if it exists)")
    # One option per effect; types, defaults and docs come from EffectsSettings.
    for name, kind, default, doc in field_docs(EffectsSettings):
        degrade.add_argument(f"--{name.replace('_', '-')}", dest=name, type=int if kind == "int" else float,
                             help=f"{doc} (default {default})")
    degrade.add_argument("--vignetting", type=float, default=0.0, metavar="V",
                         help="radial fall-off (1 + (V rho / rho_max)^2)^-2 about the mirror centre, rho_max the "
                              "image's largest circle (0 = none, the default; at most 7.9)")
    degrade.add_argument("--seed", type=int, help="seed of noise and exposure walk (default 0)")
    degrade.add_argument("--no-progress", action="store_true", help="no progress bar")
    warp = sub.add_parser("warp", help="turn one omni image into a pure-rotation sequence with exact "
                          "ground truth (no Mitsuba needed)")
    warp.add_argument("image", help="omni image (PNG/JPEG) of the calibration's size: frame 0")
    warp.add_argument("--calib", required=True,
                      help="its calib_results.txt (OCamCalib) or camera.yaml (Kalibr: fisheye, pinhole, equirectangular)")
    warp.add_argument("--out", required=True, help="dataset folder to write (resumed if it exists)")
    warp.add_argument("--frames", type=int, required=True, help="number of frames")
    warp.add_argument("--seed", type=int, default=0, help="motion seed (default 0)")
    warp.add_argument("--max-step-deg", type=float, default=3.0,
                      help="largest rotation between frames, degrees (default 3)")
    warp.add_argument("--max-tilt-deg", type=float, default=10.0,
                      help="bound of roll and pitch, degrees (default 10)")
    warp.add_argument("--rolling-shutter", type=float, default=0.0, metavar="READOUT",
                      help="read the output rows one after another over READOUT frame intervals "
                           "(0..1; default 0, a global shutter); the middle row holds the ground truth")
    warp.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_export_parser(sub)
    sub.add_parser("check-llvm", help="print the LLVM drjit will use, or how to install one")
    sub.add_parser("generators", help="list the [[objects]] generators of scene files and their parameters")
    return parser


def _degrade(args) -> int:
    from omnisim.config import EffectsSettings
    from omnisim.degrade import degrade_dataset
    from omnisim.settings import SettingError, field_docs

    given = {name: getattr(args, name) for name, *_ in field_docs(EffectsSettings)
             if getattr(args, name) is not None}
    try:
        effects = EffectsSettings(**given)
    except SettingError as exc:
        raise InputError(f"--{exc.key.replace('_', '-')}", f"{exc.key}: {exc.problem}") from None
    seed = {} if args.seed is None else {"seed": args.seed}
    result = degrade_dataset(args.dataset, args.out, effects=effects, vignetting=args.vignetting,
                             progress=not args.no_progress, **seed)
    print(f"{result.out_dir}: {result.frames} frames ({result.written} written now)")
    return 0


def _render(args) -> int:
    from omnisim.api import render

    if args.workers or args.scheduler:
        from ifmi.runtime.local_workers import quiet_dask_logs

        quiet_dask_logs()  # a lost cluster is the one line of ClusterError

    result = render(args.scene, args.out, frames=args.frames, seed=args.seed, spp=args.spp,
                    resolution=args.resolution, progress=not args.no_progress, variant=args.variant,
                    aovs=args.aov, workers=args.workers, scheduler=args.scheduler,
                    connect_timeout_s=args.connect_timeout)
    spf = (f", {result.seconds_per_frame:.2f} s/frame" if result.rendered else "")
    print(f"{result.out_dir}: {result.frames} frames ({result.rendered} rendered now{spf})")
    return 0


def _warp(args) -> int:
    from ifmi.errors import OptionError

    from omnisim.warp import WarpSettings, warp_dataset

    try:
        settings = WarpSettings(frames=args.frames, seed=args.seed, max_step_deg=args.max_step_deg,
                                max_tilt_deg=args.max_tilt_deg, rolling_shutter=args.rolling_shutter)
    except OptionError as exc:  # named by its option: --max-step-deg for max_step_deg
        raise InputError("--" + exc.key.replace("_", "-"), exc.problem) from None
    result = warp_dataset(args.image, args.calib, args.out, settings=settings, progress=not args.no_progress)
    print(f"{result.out_dir}: {result.frames} frames ({result.written} written now)")
    return 0


def _export(args) -> int:
    from omnisim.export import ExportSettings, export_dataset

    settings = ExportSettings(bag_format=args.bag_format, storage=args.storage, compressed=args.compressed,
                              start_time=args.start_time, frame_interval=args.frame_interval)
    result = export_dataset(args.dataset, args.out, settings=settings, progress=not args.no_progress)
    print(f"{result.out}: {result.frames} frames; topics {', '.join(result.topics)}")
    return 0


def _generators(args) -> int:
    from omnisim.generators import describe_generators

    print(describe_generators(), end="")
    return 0


def _check_llvm(args) -> int:
    from omnisim.llvm import main as llvm_main

    return llvm_main([])


COMMANDS = {"render": _render, "degrade": _degrade, "warp": _warp, "export": _export, "generators": _generators,
            "check-llvm": _check_llvm}


def _exit_status(exc: BaseException, *, interrupted: bool, command: str) -> int | None:
    """Print the one-line report of ``exc`` and return the exit status, or None for a bug (re-raised)."""
    from omnisim.llvm import BackendError

    command = f"omnisim {command}".strip()
    if interrupted or caused_by_interrupt(exc):
        return report_interrupt(f"{command}: interrupted (rerun the same command to resume)")
    if isinstance(exc, InputError):
        print(f"{command}: error: {exc}", file=sys.stderr)
        return 2
    if isinstance(exc, (OutputError, ClusterError, BackendError)):
        print(f"{command}: error: {exc}", file=sys.stderr)
        return 1
    if isinstance(exc, ModuleNotFoundError) and exc.name in ("mitsuba", "drjit", "trimesh", "skimage"):
        print(f"{command}: error: {exc.name} is not installed; "
              "install the simulator extra: pip install -e '.[sim]'", file=sys.stderr)
        return 1
    return None


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status.

    0 done; 1 cannot write, a Dask cluster lost, or Mitsuba cannot run here; 2 bad input; 130 interrupted.
    """
    with interrupts_recorded() as flag:
        command = ""  # known once the arguments are parsed
        try:
            args = build_parser().parse_args(argv)
            command = args.command
            with input_warnings_as_lines(lambda: f"omnisim {command}"):
                status = COMMANDS[command](args)
            if flag.seen:  # library code caught the KeyboardInterrupt and went on
                raise KeyboardInterrupt
            return status
        except BaseException as exc:
            status = _exit_status(exc, interrupted=flag.seen, command=command)
            if status is None:
                raise
            return status


if __name__ == "__main__":
    sys.exit(main())
