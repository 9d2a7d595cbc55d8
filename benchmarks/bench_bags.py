"""Reading frames from a ROS bag against reading the same frames from a dataset folder of PNG files.

One process writes a synthetic colour sequence as a dataset folder (PNG
files, as omnisim writes them) and exports it with ``omnisim export`` as
bags: raw ``sensor_msgs/Image`` in a ROS 2 MCAP folder and a ROS 1 file, and
``CompressedImage`` PNG in ROS 2 MCAP and SQLite3 folders. Each round reads
every frame in gray, as ``ifmi estimate`` does (folder:
:meth:`ifmi.io.dataset.Dataset.iter_images` without prefetching; bags:
:class:`ifmi.io.bags.BagFrames`), from the folder and from each bag, in turn
(order reversed every other round), after a warm-up read of each (files in
the page cache). Printed: the median seconds per frame of each and its
ratio to the folder's (target <= 1.2).

Run: python benchmarks/bench_bags.py [--frames 40] [--size 512] [--repeats 7] [--work /tmp/bench_bags]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np


def _write_folder(root: Path, frames: int, size: int) -> Path:
    """A dataset folder of ``frames`` RGB PNG frames ``size`` x ``size`` of a turning synthetic scene."""
    from ifmi.geometry.camera import paracatadioptric_model
    from ifmi.io.calib import write_calib
    from ifmi.synthetic import environment_texture, omni_from_environment, rotation_sequence

    model = paracatadioptric_model((size, size), horizon_radius_px=size * 0.3)
    environment = environment_texture(height=512, seed=1)
    (root / "images").mkdir(parents=True)
    write_calib(root / "calib_results.txt", model)
    for k, rotation in enumerate(rotation_sequence(frames, seed=2)):
        gray = omni_from_environment(environment, model, rotation, band_px=(size * 0.1, size * 0.45))
        rgb = np.stack([gray, gray // 2 + 60, 255 - gray], axis=-1)
        cv2.imwrite(str(root / "images" / f"{k:06d}.png"), rgb[..., ::-1])
    return root


def _readers(work: Path, frames: int, size: int) -> dict:
    """``{name: function reading every frame}`` of the folder and of each bag."""
    from ifmi.io.bags import BagFrames
    from ifmi.io.dataset import read_dataset
    from omnisim.export import ExportSettings, export_dataset

    folder = _write_folder(work / "dataset", frames, size)
    dataset = read_dataset(folder)
    readers = {"folder (PNG files)": lambda: list(dataset.iter_images(skip_unreadable=True))}
    kinds = {"bag ROS 2 MCAP, raw Image": ("ros2", "mcap", None, "raw_mcap"),
             "bag ROS 1, raw Image": ("ros1", "mcap", None, "raw.bag"),
             "bag ROS 2 MCAP, PNG CompressedImage": ("ros2", "mcap", "png", "png_mcap"),
             "bag ROS 2 SQLite3, PNG CompressedImage": ("ros2", "sqlite3", "png", "png_db3")}
    for name, (bag_format, storage, compressed, path) in kinds.items():
        export_dataset(folder, work / path, settings=ExportSettings(bag_format=bag_format, storage=storage,
                                                                    compressed=compressed))
        frames_of = BagFrames(work / path, size=dataset.model.size)
        readers[name] = lambda frames_of=frames_of: list(frames_of)
    return readers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--work", help="scratch folder (default: a temporary one, removed at the end)")
    args = parser.parse_args()

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench_bags."))
    if work.exists() and any(work.iterdir()):
        raise SystemExit(f"{work}: expected a new or empty scratch folder")
    try:
        readers = _readers(work, args.frames, args.size)
        reference = [frame.copy() for frame in readers["folder (PNG files)"]()]  # also the warm-up
        for name, read in readers.items():
            frames = read()
            if not all(np.array_equal(a, b) for a, b in zip(frames, reference)) or len(frames) != len(reference):
                raise SystemExit(f"{name}: frames differ from the folder's")
        seconds = {name: [] for name in readers}
        for round_ in range(args.repeats):
            order = list(readers.items()) if round_ % 2 == 0 else list(readers.items())[::-1]
            for name, read in order:
                start = time.perf_counter()
                read()
                seconds[name].append((time.perf_counter() - start) / args.frames)
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    base = statistics.median(seconds["folder (PNG files)"])
    print(f"{args.frames} frames {args.size}x{args.size} RGB, read in gray; median of {args.repeats} rounds")
    for name, values in seconds.items():
        median = statistics.median(values)
        print(f"  {name:40s} {median * 1e3:7.2f} ms/frame  ratio {median / base:.2f}")
    print("target: every bag <= 1.2 x the folder")


if __name__ == "__main__":
    main()
