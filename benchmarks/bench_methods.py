"""iFMI against ORB and AKAZE on rendered datasets: accuracy and end-to-end time per frame.

Every method runs in this process on the same frames through the same
odometry and relative-pose back end with the same options (one
configuration per mode; the RANSAC threshold is resolved once per dataset
from its calibration, ``--ransac-threshold-px`` pixels, and shared by all
methods). Each estimate is written and evaluated as ``ifmi estimate`` /
``ifmi evaluate`` would, under ``OUT/MODE/SCENE/``, so ``ifmi report
OUT/MODE --out ...`` turns one mode into a report.

Usage::

    python benchmarks/bench_methods.py DATA/standard/office_200 DATA/standard/lawn_200 \
        DATA/standard/urban_200 --out out/bench_methods [--modes frame keyframe]

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
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchlib import (METHODS, MODES, interleaved_timing, labelled_datasets, machine_line, mode_config,
                      run_method)
from ifmi.errors import InputError
from ifmi.experiments.report import machine_info
from ifmi.io.camera_file import calibration_path, read_camera
from ifmi.io.config import read_estimate_config
from ifmi.pipeline import EstimateConfig, resolved_config

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


def print_rows(rows: list, key: str) -> None:
    """Per mode, set and method: the axes' and geodesic RMSE, times, failures, models, references."""
    print(machine_line())
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
