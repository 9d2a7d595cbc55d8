"""Command line of ``omnisim``: parsing only; rendering lives in :mod:`omnisim.render`."""

from __future__ import annotations

import argparse
import sys

from ifmi.errors import InputError, OutputError

__all__ = ["main", "build_parser"]


def _resolution(text: str):
    parts = text.lower().replace("x", " ").replace(",", " ").split()
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N or HEIGHTxWIDTH, got {text!r}") from None
    if len(values) == 1:
        return (values[0], values[0])
    if len(values) == 2:
        return tuple(values)
    raise argparse.ArgumentTypeError(f"expected N or HEIGHTxWIDTH, got {text!r}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="omnisim", description="Render catadioptric omni-image "
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
    parallel.add_argument("--workers", type=int, help="render on a local Dask cluster of N processes")
    parallel.add_argument("--scheduler", metavar="ADDRESS", help="render on the Dask cluster at ADDRESS")
    degrade = sub.add_parser("degrade", help="copy a dataset folder with capture effects "
                             "(noise, JPEG, exposure drift) applied to its images")
    degrade.add_argument("dataset", help="source DATASET folder (rendered or real)")
    degrade.add_argument("--out", required=True, help="dataset folder to write (resumed if it exists)")
    degrade.add_argument("--noise-sigma", type=float, default=0.0,
                         help="Gaussian noise, standard deviation in 8-bit grey levels (default 0)")
    degrade.add_argument("--jpeg-quality", type=int, default=0,
                         help="JPEG quality 1..100 the frames pass through; 0 = off (default)")
    degrade.add_argument("--exposure-stops", type=float, default=0.0,
                         help="bound of the exposure random walk, stops (default 0 = off)")
    degrade.add_argument("--exposure-step-stops", type=float, default=0.1,
                         help="largest exposure change between frames, stops (default 0.1)")
    degrade.add_argument("--seed", type=int, default=0, help="seed of noise and exposure walk (default 0)")
    degrade.add_argument("--no-progress", action="store_true", help="no progress bar")
    warp = sub.add_parser("warp", help="turn one omni image into a pure-rotation sequence with exact "
                          "ground truth (no Mitsuba needed)")
    warp.add_argument("image", help="omni image (PNG/JPEG) of the calibration's size: frame 0")
    warp.add_argument("--calib", required=True, help="its calib_results.txt (OCamCalib)")
    warp.add_argument("--out", required=True, help="dataset folder to write (resumed if it exists)")
    warp.add_argument("--frames", type=int, required=True, help="number of frames")
    warp.add_argument("--seed", type=int, default=0, help="motion seed (default 0)")
    warp.add_argument("--max-step-deg", type=float, default=3.0,
                      help="largest rotation between frames, degrees (default 3)")
    warp.add_argument("--max-tilt-deg", type=float, default=10.0,
                      help="bound of roll and pitch, degrees (default 10)")
    warp.add_argument("--no-progress", action="store_true", help="no progress bar")
    sub.add_parser("check-llvm", help="print the LLVM drjit will use, or how to install one")
    return parser


def _degrade(args) -> int:
    from .config import EffectsSettings
    from .degrade import degrade_dataset

    effects = EffectsSettings(noise_sigma=args.noise_sigma, exposure_stops=args.exposure_stops,
                              exposure_step_stops=args.exposure_step_stops, jpeg_quality=args.jpeg_quality)
    result = degrade_dataset(args.dataset, args.out, effects=effects, seed=args.seed,
                             progress=not args.no_progress)
    print(f"{result.out_dir}: {result.frames} frames ({result.written} written now)")
    return 0


def _warp(args) -> int:
    from .warp import WarpSettings, warp_dataset

    try:
        settings = WarpSettings(frames=args.frames, seed=args.seed, max_step_deg=args.max_step_deg,
                                max_tilt_deg=args.max_tilt_deg)
    except ValueError as exc:
        raise InputError(args.image, str(exc)) from None
    result = warp_dataset(args.image, args.calib, args.out, settings=settings, progress=not args.no_progress)
    print(f"{result.out_dir}: {result.frames} frames ({result.written} written now)")
    return 0


def main(argv: list[str] | None = None) -> int:
    from .llvm import LlvmNotFoundError

    args = build_parser().parse_args(argv)
    try:
        if args.command == "check-llvm":
            from .llvm import main as llvm_main
            return llvm_main([])
        if args.command == "degrade":
            return _degrade(args)
        if args.command == "warp":
            return _warp(args)
        from .render import render_dataset
        if args.frames is not None and args.frames < 1:
            raise InputError(args.scene, f"--frames: expected >= 1, got {args.frames}")
        if args.spp is not None and args.spp < 1:
            raise InputError(args.scene, f"--spp: expected >= 1, got {args.spp}")
        result = render_dataset(args.scene, args.out, frames=args.frames, seed=args.seed, spp=args.spp,
                                resolution=args.resolution, progress=not args.no_progress,
                                variant=args.variant, aovs=args.aov, workers=args.workers,
                                scheduler=args.scheduler)
        spf = (f", {result.seconds_per_frame:.2f} s/frame" if result.rendered else "")
        print(f"{result.out_dir}: {result.frames} frames ({result.rendered} rendered now{spf})")
        return 0
    except InputError as exc:
        print(f"omnisim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OutputError as exc:
        print(f"omnisim {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except LlvmNotFoundError as exc:
        print(f"omnisim {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except ModuleNotFoundError as exc:
        if exc.name not in ("mitsuba", "drjit", "trimesh", "skimage"):
            raise
        print(f"omnisim {args.command}: error: {exc.name} is not installed; "
              "install the simulator extra: pip install -e '.[sim]'", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"omnisim {args.command}: interrupted (rerun the same command to resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
