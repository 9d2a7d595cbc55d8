"""Every k-th frame of a dataset as a new dataset: faster motion with exact ground truth.

Frames ``0, k, 2k, ...`` of SOURCE are copied to OUT as frames ``0, 1, 2, ...``
with the calibration; the ground truth is re-expressed relative to the new
frame 0 (``T'_0j = T_{0,0}^-1 T_{0,jk}``, which is the identity on frame 0
of the source) and its timestamps become the new frame indices.

Usage::

    python benchmarks/subsample_dataset.py SOURCE OUT --step K
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from ifmi.io.atomic import atomic_write_text
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum, write_tum
from ifmi.geometry.trajectory import Trajectory


def subsample(source: Path, out: Path, step: int, *, start: int = 0) -> int:
    """Write frames ``start, start + step, ...`` of ``source`` to ``out``; returns the frame count."""
    data = read_dataset(source)
    paths = data.image_paths[start::step]
    (out / "images").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(data.calib_path, out / "calib_results.txt")
    for j, path in enumerate(paths):
        shutil.copyfile(path, out / "images" / f"{j:06d}{path.suffix.lower()}")
    if data.groundtruth_path is not None:
        gt = read_tum(data.groundtruth_path)
        index = np.arange(start, len(gt), step)[:len(paths)]
        r0, p0 = gt.rotations[start], gt.positions[start]
        rotations = np.einsum("ji,njk->nik", r0, gt.rotations[index])
        positions = (gt.positions[index] - p0) @ r0
        write_tum(out / "groundtruth.txt",
                  Trajectory(timestamps=np.arange(len(index), dtype=np.float64),
                             positions=positions, rotations=rotations),
                  header=f"every {step}th frame of {source} from frame {start}")
    atomic_write_text(out / "meta.json", json.dumps(
        {"subsampled_from": str(source), "step": step, "start": start, "frames": len(paths)}, indent=2))
    return len(paths)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("out")
    parser.add_argument("--step", type=int, required=True)
    parser.add_argument("--start", type=int, default=0)
    args = parser.parse_args(argv)
    n = subsample(Path(args.source), Path(args.out), args.step, start=args.start)
    print(f"{args.out}: {n} frames")
    return 0


if __name__ == "__main__":
    sys.exit(main())
