"""iFMI against ORB and AKAZE on rendered datasets: accuracy and end-to-end time per frame.

Every method runs in this process on the same frames through the same
odometry and relative-pose back end with the same options (one
configuration per mode; the RANSAC threshold is resolved once per dataset
from its calibration, ``--ransac-threshold-px`` pixels, and shared by all
methods). Each estimate is written and evaluated as ``ifmi estimate`` /
``ifmi evaluate`` would, under ``OUT/MODE/SCENE/``, so ``ifmi report
OUT/MODE --out ...`` turns one mode into a report.

Usage::

    python benchmarks/bench_methods.py DATA/office_200 DATA/lawn_200 \
        DATA/urban_200 --out out/bench_methods [--modes frame keyframe]

Modes: ``frame`` (frame to frame) and ``keyframe`` (estimates against
keyframes); both by default.

Accuracy comes from one full run per method, mode and dataset. Time per
frame is end to end: wall time of a run (read the PNGs, prepare, match,
solve, chain) over its frame count. Besides the full run's, it is measured
in an extra interleaved pass per mode: ``--timing-rounds`` rounds over the
first ``--timing-frames`` frames, the methods taking turns within each round
so that load from other processes on the machine hits all methods alike; the
median over the rounds is used for the ratios.

Each timing round also reads and decodes the frames alone (no estimation),
the part of every method's end-to-end time that no front end can remove;
its time over AKAZE's (``read_vs_akaze``) is the lowest iFMI/AKAZE ratio
possible on the machine. And each round runs every method once more on
the same frames already decoded into memory: that *compute* time per frame
leaves the decoding out.

Prints, per mode, scene and method, roll/pitch/yaw and mean RMSE, geodesic
RMSE, the median per-frame ``seconds``, the wall time per frame of the full
run, the interleaved wall time per frame and the failures, then per mode and
scene the ratios: iFMI RMSE / the better baseline's (mean of the axes and
geodesic), iFMI time / ORB time end to end, and iFMI compute time / AKAZE
compute time with the frames in memory; and last one summary table over
all sets (geodesic ATE, frame-to-frame geodesic RMSE, failed frames, ms
per frame end to end and in memory, and those ratios).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from itertools import islice
from pathlib import Path

import numpy as np

from ifmi.dataset_names import dataset_folder_id, dataset_labels, resolved_folder
from ifmi.errors import InputError
from ifmi.evaluation import evaluate_files
from ifmi.io.camera_file import calibration_path, read_camera
from ifmi.io.config import read_estimate_config
from ifmi.io.dataset import read_dataset
from ifmi.io.results import write_estimate_run
from ifmi.io.tum import read_tum
from ifmi.pipeline import EstimateConfig, estimate_dataset, estimate_sequence, resolved_config
from ifmi.methods import builtin_method_names
from ifmi.metrics import MIN_ASSOCIATED
from ifmi.report import machine_info

METHODS = builtin_method_names()
# Odometry modes: estimates against the previous frame, or against keyframes.
MODES = ("frame", "keyframe")


def mode_config(base: EstimateConfig, mode: str) -> EstimateConfig:
    """The shared configuration of one mode (keyframes on or off, nothing else changes)."""
    return replace(base, keyframe=replace(base.keyframe, enabled=(mode == "keyframe")))


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
    ground-truth poses as an evaluation needs (:data:`ifmi.metrics.MIN_ASSOCIATED`)."""
    frames = len(read_dataset(folder).image_paths)
    if frames < MIN_ASSOCIATED:
        raise InputError(folder, f"a benchmark set needs at least {MIN_ASSOCIATED} frames, found {frames}")
    poses = len(read_tum(folder / "groundtruth.txt"))
    if poses < MIN_ASSOCIATED:
        raise InputError(folder / "groundtruth.txt",
                         f"a benchmark set needs at least {MIN_ASSOCIATED} poses, found {poses}")


def _or_nan(value) -> float:
    return float("nan") if value is None else value


def print_summary(rows: list, ratios: dict, key: str) -> None:
    """One line per mode and set: geodesic ATE, failures and times of each method, and the ratios."""
    methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
    width = max([12] + [len(r["dataset"]) + 1 for r in rows])
    head = "".join(f"{'ATE ' + m:>11}" for m in methods) + "".join(f"{'f2f ' + m:>11}" for m in methods)
    head += "".join(f"{'fail ' + m:>11}" for m in methods)
    head += "".join(f"{'ms ' + m:>10}" for m in methods) + "".join(f"{'mem ' + m:>11}" for m in methods)
    print(f"\nsummary (geodesic ATE RMSE and frame-to-frame (f2f) geodesic RMSE in rad; ms per frame end to "
          f"end ({key}) and with frames in memory)")
    print(f"{'mode':<9}{'dataset':<{width}}{head}{'ATE/best':>9}{'e2e/ORB':>9}{'mem/AKAZE':>10}")
    for mode, dataset in dict.fromkeys((r["mode"], r["dataset"]) for r in rows):
        by = {r["method"]: r for r in rows if r["dataset"] == dataset and r["mode"] == mode}
        # A one-frame set has no frame-to-frame error (None).
        line = "".join(f"{_or_nan(by[m]['geodesic_rmse']):>11.5f}" if m in by else f"{'-':>11}" for m in methods)
        line += "".join(f"{_or_nan(by[m]['relative_rmse']):>11.2e}" if m in by else f"{'-':>11}" for m in methods)
        line += "".join(f"{str(by[m]['failures']) + '/' + str(by[m]['frames']):>11}" if m in by else f"{'-':>11}"
                        for m in methods)
        line += "".join(f"{by[m].get(key, float('nan')) * 1e3:>10.1f}" if m in by else f"{'-':>10}"
                        for m in methods)
        line += "".join(f"{by[m].get('memory_per_frame_s', float('nan')) * 1e3:>11.1f}" if m in by
                        else f"{'-':>11}" for m in methods)
        entry = ratios.get(f"{mode}/{dataset}", {})
        line += "".join(f"{entry.get(k, float('nan')):>{w}.3f}" for k, w in
                        (("rmse_geodesic_vs_best", 9), ("time_vs_orb", 9), ("compute_vs_akaze", 10)))
        print(f"{mode:<9}{dataset:<{width}}{line}")


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


def print_rows(rows: list, key: str) -> None:
    """Per mode, set and method: the axes' and geodesic RMSE, times, failures, models, references."""
    machine = machine_info()
    print(f"machine: {machine['cpu']}, {machine['cores']} cores, {machine['ram_gib']} GiB, "
          f"python {machine['python']}")
    print("RMSE in radians; times in ms per frame; 'rot/5pt': frames solved by each model")
    width = max([12] + [len(r["dataset"]) + 1 for r in rows])
    print(f"{'mode':<9}{'dataset':<{width}}{'method':<7}{'roll':>8}{'pitch':>8}{'yaw':>8}{'mean':>8}"
          f"{'geodesic':>9}{'run ms':>8}{'wall ms':>8}{'timed ms':>9}{'fail':>8}{'rot/5pt':>9}"
          f"{'refs':>6}")
    for r in rows:
        print(f"{r['mode']:<9}{r['dataset']:<{width}}{r['method']:<7}{r['roll']:>8.4f}{r['pitch']:>8.4f}"
              f"{r['yaw']:>8.4f}{r['mean_rmse']:>8.4f}{r['geodesic_rmse']:>9.4f}"
              f"{r['median_s'] * 1e3:>8.1f}{r['wall_per_frame_s'] * 1e3:>8.1f}"
              f"{r.get(key, float('nan')) * 1e3:>9.1f}{r['failures']:>4}/{r['frames']:<3}"
              f"{r['rotation_model_frames']:>5}/{r['five_point_frames']:<3}{r['references']:>6}")
    reads = {r["dataset"]: r["read_per_frame_s"] for r in rows if "read_per_frame_s" in r}
    if reads:
        print("reading + decoding the images alone (ms per frame, median of the timing rounds): "
              + ", ".join(f"{k} {v * 1e3:.1f}" for k, v in reads.items()))
    thresholds = {(r["dataset"]): r["ransac_threshold_rad"] for r in rows}
    print("RANSAC threshold (rad, all methods): "
          + ", ".join(f"{k} {v:.5f}" for k, v in thresholds.items()))


def ratio_table(rows: list, key: str) -> dict:
    """iFMI's ratios against the baselines per mode and set (printed, and returned by ``MODE/SET``)."""
    width = max([12] + [len(r["dataset"]) + 1 for r in rows])
    print(f"\nratios (time: {key}; compute: frames in memory)")
    ratios = {}
    for mode, dataset in dict.fromkeys((r["mode"], r["dataset"]) for r in rows):
        by = {r["method"]: r for r in rows if r["dataset"] == dataset and r["mode"] == mode}
        if "ifmi" not in by:
            continue
        entry = {}
        if "read_per_frame_s" in by["ifmi"] and "akaze" in by:
            # A time ratio cannot go below reading the image over the other method's time.
            entry["read_vs_akaze"] = by["ifmi"]["read_per_frame_s"] / by["akaze"][key]
        baselines = [m for m in ("orb", "akaze") if m in by]
        if baselines:
            entry["rmse_mean_vs_best"] = by["ifmi"]["mean_rmse"] / min(by[m]["mean_rmse"] for m in baselines)
            entry["rmse_geodesic_vs_best"] = (by["ifmi"]["geodesic_rmse"]
                                              / min(by[m]["geodesic_rmse"] for m in baselines))
        for m in baselines:
            entry[f"time_vs_{m}"] = by["ifmi"][key] / by[m][key]
        if "akaze" in by and "memory_per_frame_s" in by["akaze"]:
            entry["compute_vs_akaze"] = by["ifmi"]["memory_per_frame_s"] / by["akaze"]["memory_per_frame_s"]
        ratios[f"{mode}/{dataset}"] = entry
        print(f"{mode:<9}{dataset:<{width}}" + "  ".join(f"{k} {v:.3f}" for k, v in entry.items()))
    return ratios


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES,
                        help="odometry modes to measure (default: both)")
    parser.add_argument("--keyframes", action="store_true", help="same as --modes keyframe")
    parser.add_argument("--out", default="out/bench_methods")
    parser.add_argument("--ransac-threshold-px", type=float, default=None, metavar="PX",
                        help="RANSAC threshold of every method in pixels (default: the back "
                             "end's default, converted per calibration)")
    parser.add_argument("--rolling-shutter", type=float, default=None, metavar="READOUT",
                        help="rolling-shutter read-out of every method, a fraction of the frame "
                             "interval (default: a global shutter; see ifmi estimate --rolling-shutter)")
    parser.add_argument("--config", default=None, metavar="JSON",
                        help="start every method from this configuration (as ifmi estimate --config: "
                             "a to_dict() JSON or a run's NAME.config.json), e.g. "
                             "'{\"features\": {\"akaze_min_keypoints\": 500}}' in a file; the options "
                             "above win over it")
    parser.add_argument("--timing-frames", type=int, default=50)
    parser.add_argument("--timing-rounds", type=int, default=5)
    args = parser.parse_args(argv)
    try:
        return run_benchmark(args, argv)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def run_benchmark(args: argparse.Namespace, argv) -> int:
    """Measure every dataset, mode and method of the parsed command line; write the JSON."""
    modes = ["keyframe"] if args.keyframes else list(dict.fromkeys(args.modes))
    base = EstimateConfig() if args.config is None else read_estimate_config(args.config)
    if args.ransac_threshold_px is not None:
        base = replace(base, relative_pose=replace(base.relative_pose,
                                                   ransac_threshold_px=args.ransac_threshold_px))
    if args.rolling_shutter is not None:
        base = replace(base, rolling_shutter=replace(base.rolling_shutter, readout=args.rolling_shutter))
    out = Path(args.out)
    rows = []
    for dataset, label in labelled_datasets(args.datasets):
        model = read_camera(calibration_path(dataset))
        for mode in modes:
            # One configuration for every method of this mode and dataset.
            config = resolved_config(mode_config(base, mode), model)
            these = [run_method(dataset, method, mode, config, out, label=label) for method in args.methods]
            if args.timing_rounds > 0:
                walls = interleaved_timing(dataset, args.methods, {m: config for m in args.methods},
                                           frames=args.timing_frames, rounds=args.timing_rounds)
                for r in these:
                    r["timed_wall_per_frame_s"] = float(np.median(walls[r["method"]]))
                    r["timed_runs_s"] = walls[r["method"]]
                    r["memory_per_frame_s"] = float(np.median(walls[f"{r['method']}_memory"]))
                    r["read_per_frame_s"] = float(np.median(walls["read"]))
            rows += these
    key = "timed_wall_per_frame_s" if args.timing_rounds > 0 else "wall_per_frame_s"
    print_rows(rows, key)
    ratios = ratio_table(rows, key)
    print_summary(rows, ratios, key)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_methods.json").write_text(json.dumps({"rows": rows, "ratios": ratios,
                                                        "time_key": key, "machine": machine_info(),
                                                        "argv": sys.argv if argv is None else argv},
                                                       indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
