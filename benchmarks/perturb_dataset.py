"""A dataset's copy with every 8-bit sample moved by -1, 0 or +1 at random: data not designed for a method.

A change of one gray level is below any render's or camera's noise, so a
method whose result on the copy differs much from its result on the
original was resting on that set's particular noise. The calibration and
ground truth are copied unchanged; the images are written as PNG (8-bit,
gray or RGB as the source), named as in the source. The same seed gives
the same copy.

Usage::

    python benchmarks/perturb_dataset.py SOURCE OUT --seed S
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

from ifmi.errors import InputError
from ifmi.io.atomic import atomic_write_text
from ifmi.io.dataset import read_dataset
from ifmi.io.images import read_image


def perturbed_image(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``image`` (uint8, (H, W) or (H, W, 3)) with each sample moved by -1, 0 or +1, clipped to 0..255."""
    step = rng.integers(-1, 2, size=image.shape)
    return np.clip(image.astype(np.int16) + step, 0, 255).astype(np.uint8)


def perturb(source: Path, out: Path, *, seed: int) -> int:
    """Write the perturbed copy of ``source`` to ``out`` (a new folder); returns the frame count."""
    data = read_dataset(source)
    if out.exists():
        raise InputError(out, "output folder exists; choose a new one")
    rng = np.random.default_rng(seed)
    (out / "images").mkdir(parents=True)
    shutil.copyfile(data.calib_path, out / data.calib_path.name)
    if data.groundtruth_path is not None:
        shutil.copyfile(data.groundtruth_path, out / "groundtruth.txt")
    for path in data.image_paths:
        image = read_image(path, size=data.model.size, gray=False)
        stored = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)  # the file's order
        if not cv2.imwrite(str(out / "images" / f"{path.stem}.png"), perturbed_image(stored, rng)):
            raise InputError(out / "images", f"cannot write {path.stem}.png")
    atomic_write_text(out / "meta.json", json.dumps(
        {"perturbed_from": str(source), "seed": seed, "step": "-1, 0 or +1 per sample",
         "frames": len(data.image_paths)}, indent=2))
    return len(data.image_paths)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("out")
    parser.add_argument("--seed", type=int, required=True, help="seed of the perturbation, >= 0")
    args = parser.parse_args(argv)
    if args.seed < 0:
        parser.error(f"--seed: expected >= 0, got {args.seed}")
    try:
        n = perturb(Path(args.source), Path(args.out), seed=args.seed)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {n} frames")
    return 0


if __name__ == "__main__":
    sys.exit(main())
