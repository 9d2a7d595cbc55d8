"""Command line of ``omnisim``: parsing only; rendering lives in :mod:`omnisim.render`."""

from __future__ import annotations

import argparse
import sys

from ifmi.errors import InputError

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
    sub.add_parser("check-llvm", help="print the LLVM drjit will use, or how to install one")
    return parser


def main(argv: list[str] | None = None) -> int:
    from .llvm import LlvmNotFoundError

    args = build_parser().parse_args(argv)
    try:
        if args.command == "check-llvm":
            from .llvm import main as llvm_main
            return llvm_main([])
        from .render import render_dataset
        if args.frames is not None and args.frames < 1:
            raise InputError(args.scene, f"--frames: expected >= 1, got {args.frames}")
        if args.spp is not None and args.spp < 1:
            raise InputError(args.scene, f"--spp: expected >= 1, got {args.spp}")
        result = render_dataset(args.scene, args.out, frames=args.frames, seed=args.seed, spp=args.spp,
                                resolution=args.resolution, progress=not args.no_progress,
                                variant=args.variant)
        spf = (f", {result.seconds_per_frame:.2f} s/frame" if result.rendered else "")
        print(f"{result.out_dir}: {result.frames} frames ({result.rendered} rendered now{spf})")
        return 0
    except InputError as exc:
        print(f"omnisim {args.command}: error: {exc}", file=sys.stderr)
        return 2
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
