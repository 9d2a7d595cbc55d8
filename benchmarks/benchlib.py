"""What every benchmark shares: the methods and modes, the data-set checks, one evaluated run, timing.

The benchmark scripts beside this module import it (``python benchmarks/NAME.py`` puts this folder
on the path). Each measures through the project's public pipeline -- the same reading, odometry and
back end as ``ifmi estimate`` -- and writes what it measured as files that reports read.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from itertools import islice
from pathlib import Path

import numpy as np

from ifmi.errors import InputError, OutputError
from ifmi.evaluation.dataset_names import dataset_folder_id, dataset_labels, resolved_folder
from ifmi.evaluation.metrics import MIN_ASSOCIATED
from ifmi.evaluation.trajectory_files import evaluate_files
from ifmi.experiments.report import machine_info
from ifmi.io.dataset import read_dataset
from ifmi.io.results import write_estimate_run
from ifmi.io.tum import read_tum
from ifmi.pipeline import EstimateConfig, estimate_dataset, estimate_sequence
from ifmi.tracking.methods import builtin_method_names


def status_of(work) -> int:
    """Run ``work()`` (returns the line to print on success) as a script's main: 0 and that line on
    stdout; a bad input is one ``error:`` line and 2, an output that cannot be written one line and 1."""
    try:
        line = work()
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (OutputError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(line)
    return 0


def machine_line() -> str:
    """One line naming the machine a benchmark ran on (CPU, cores, memory, Python)."""
    machine = machine_info()
    return (f"machine: {machine['cpu']}, {machine['cores']} cores, {machine['ram_gib']} GiB, "
            f"python {machine['python']}")


METHODS = builtin_method_names()
# Odometry modes: estimates against the previous frame, or against keyframes.
MODES = ("frame", "keyframe")


def mode_config(base: EstimateConfig, mode: str) -> EstimateConfig:
    """The shared configuration of one mode (keyframes on or off, nothing else changes)."""
    return replace(base, keyframe=replace(base.keyframe, enabled=(mode == "keyframe")))


def compute_seconds(images: list, model, method: str, config: EstimateConfig) -> tuple[float, float]:
    """Wall and CPU seconds (this process, all its threads) of one in-memory run of ``method``."""
    wall, cpu = time.perf_counter(), time.process_time()
    estimate_sequence(images, model, method=method, config=config)
    return time.perf_counter() - wall, time.process_time() - cpu


def interleaved_timing(dataset: str, methods, configs, *, frames: int, rounds: int) -> dict:
    """Wall seconds per frame of each method's runs over the first ``frames`` frames, interleaved.

    Each run reads its images exactly as :func:`ifmi.pipeline.estimate_dataset`
    does (lazily, next image decoded in the background); its wall time over
    its frame count is the end-to-end time per frame.
    """
    data = read_dataset(dataset)
    n = min(frames, len(data.image_paths))
    walls = {m: [] for m in methods}
    walls.update({f"{m}_memory": [] for m in methods})
    walls["read"] = []
    in_memory = list(islice(data.iter_images(skip_unreadable=True), n))
    for _ in range(rounds):
        # Reading and decoding the images alone, in this thread: the share of every method's
        # end-to-end time that no front end can remove.
        start = time.perf_counter()
        for _image in islice(data.iter_images(), n):
            pass
        walls["read"].append((time.perf_counter() - start) / n)
        for method in methods:
            start = time.perf_counter()
            estimate_sequence(islice(data.iter_images(prefetch=True), n), data.model,
                              method=method, config=configs[method])
            walls[method].append((time.perf_counter() - start) / n)
            start = time.perf_counter()
            estimate_sequence(in_memory, data.model, method=method, config=configs[method])
            walls[f"{method}_memory"].append((time.perf_counter() - start) / n)
    return walls


def labelled_datasets(paths) -> list[tuple[str, str]]:
    """``(dataset, label)`` once per folder, in the order given: a folder given twice (under two
    spellings too) is measured once; labels tell apart sets of one name (:func:`dataset_labels`).

    Every folder is checked before any is measured: a dataset (calibration and images) of at
    least two frames with a ground truth of at least two poses; else :class:`InputError`.
    """
    labels = dataset_labels(paths)
    chosen = [(d, labels[folder]) for folder, d in {resolved_folder(d): d for d in paths}.items()]
    for dataset, _ in chosen:
        _check_benchmark_dataset(Path(dataset))
    return chosen


def _check_benchmark_dataset(folder: Path) -> None:
    """:class:`InputError` unless ``folder`` can be estimated and evaluated: as many frames and
    ground-truth poses as an evaluation needs (:data:`ifmi.evaluation.metrics.MIN_ASSOCIATED`)."""
    frames = len(read_dataset(folder).image_paths)
    if frames < MIN_ASSOCIATED:
        raise InputError(folder, f"a benchmark set needs at least {MIN_ASSOCIATED} frames, found {frames}")
    poses = len(read_tum(folder / "groundtruth.txt"))
    if poses < MIN_ASSOCIATED:
        raise InputError(folder / "groundtruth.txt",
                         f"a benchmark set needs at least {MIN_ASSOCIATED} poses, found {poses}")


def run_method(dataset: str, method: str, mode: str, config: EstimateConfig, out: Path, *,
               label: str) -> dict:
    """One full run of ``method`` on ``dataset``, written and evaluated; its row of figures.

    The files go to ``out/mode/<dataset id>/``; the row names the dataset ``label``.
    """
    folder = out / mode / dataset_folder_id(dataset)
    start = time.perf_counter()
    estimate = estimate_dataset(dataset, method=method, config=config, progress=True)
    wall = time.perf_counter() - start
    est_path = folder / f"{method}.txt"
    write_estimate_run(est_path, estimate, dataset_dir=dataset, extra={"wall_seconds": wall})
    meta = evaluate_files(Path(dataset) / "groundtruth.txt", est_path, out_dir=folder / f"{method}.eval")
    s = meta["summary"]
    seconds = np.array([r.seconds for r in estimate.frames[1:]])
    models = [r.model for r in estimate.frames[1:] if r.success]
    return {"mode": mode, "dataset": label, "dataset_path": resolved_folder(dataset),
            "dataset_id": folder.name, "scene": meta["scene"], "method": method,
            "mean_rmse": s["mean_rmse"], "geodesic_rmse": s["geodesic"]["rmse"],
            "relative_rmse": s["relative_geodesic"]["rmse"],
            "roll": s["axes"]["roll"]["rmse"], "pitch": s["axes"]["pitch"]["rmse"],
            "yaw": s["axes"]["yaw"]["rmse"],
            # Frame 0 has no pair: a one-frame set has no times (nan).
            "median_s": float(np.median(seconds)) if len(seconds) else float("nan"),
            "mean_s": float(seconds.mean()) if len(seconds) else float("nan"),
            "wall_per_frame_s": wall / len(estimate.frames),
            "failures": s["failures"]["count"], "frames": len(estimate.frames),
            "rotation_model_frames": models.count("rotation"), "five_point_frames": models.count("5pt"),
            "references": len({r.reference_frame for r in estimate.frames}),
            "ransac_threshold_rad": config.relative_pose.ransac_threshold_rad}


