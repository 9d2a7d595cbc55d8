"""iFMI against ORB and AKAZE on rendered datasets: accuracy and end-to-end time per frame.

Every method runs in this process on the same frames through the same
odometry and relative-pose back end; each estimate is written and evaluated
as ``ifmi estimate`` / ``ifmi evaluate`` would, so the output folder can be
turned into a report (``ifmi report OUT --out ...``).

Usage::

    python benchmarks/bench_methods.py /work/data/office_200 /work/data/lawn_200 \
        /work/data/urban_200 --out out/bench_methods

Accuracy comes from one full run per method and dataset. Time per frame is
end to end: wall time of a run (read the PNGs, prepare, match, solve, chain)
over its frame count. Besides the full run's, it is measured in an extra
interleaved pass: ``--timing-rounds`` rounds over the first
``--timing-frames`` frames, the methods taking turns within each round so
that load from other processes on the machine hits all methods alike; the
median over the rounds is used for the ratios.

Prints, per scene and method, roll/pitch/yaw and mean RMSE, geodesic RMSE,
the median per-frame ``seconds`` and the wall time per frame of the full
run, the interleaved wall time per frame, then
the target ratios: iFMI mean RMSE / better baseline's (target <= 1/3), iFMI
time / ORB time (target <= 0.5) and iFMI time / AKAZE time (target <= 0.1).
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

from ifmi.camera import rays_from_pixels
from ifmi.evaluation import evaluate_files
from ifmi.io.calib import read_calib
from ifmi.io.dataset import read_dataset
from ifmi.io.results import write_estimate_run
from ifmi.pipeline import EstimateConfig, estimate_dataset, estimate_sequence
from ifmi.report import machine_info

METHODS = ("ifmi", "orb", "akaze")


def horizon_pixel_angle(dataset: str) -> float:
    """Angle (radians) between rays of radially adjacent pixels where the rays are horizontal."""
    model = read_calib(Path(dataset) / "calib_results.txt")
    r = np.linspace(1.0, min(model.size) / 2.0, 4000)
    z = np.polynomial.polynomial.polyval(r, model.pol)
    horizon = r[np.argmin(np.abs(z))]
    pixels = np.array([[model.center[0] + horizon, model.center[1]],
                       [model.center[0] + horizon + 1.0, model.center[1]]])
    rays = rays_from_pixels(model, pixels)
    return float(np.arccos(np.clip(rays[0] @ rays[1], -1.0, 1.0)))


def method_config(base: EstimateConfig, method: str, dataset: str,
                  baseline_threshold_px: float | None) -> EstimateConfig:
    """The configuration a method runs with (the shared one unless a sensitivity run asks)."""
    if baseline_threshold_px is None or method == "ifmi":
        return base
    threshold = baseline_threshold_px * horizon_pixel_angle(dataset)
    return replace(base, relative_pose=replace(base.relative_pose, ransac_threshold_rad=threshold))


def interleaved_timing(dataset: str, methods, configs, *, frames: int, rounds: int) -> dict:
    """Wall seconds per frame of each method's runs over the first ``frames`` frames, interleaved.

    Each run reads its images exactly as :func:`ifmi.pipeline.estimate_dataset`
    does (lazily, next image decoded in the background); its wall time over
    its frame count is the end-to-end time per frame.
    """
    data = read_dataset(dataset)
    n = min(frames, len(data.image_paths))
    walls = {m: [] for m in methods}
    for _ in range(rounds):
        for method in methods:
            start = time.perf_counter()
            estimate_sequence(islice(data.iter_images(prefetch=True), n), data.model,
                              method=method, config=configs[method])
            walls[method].append((time.perf_counter() - start) / n)
    return walls


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    parser.add_argument("--out", default="out/bench_methods")
    parser.add_argument("--keyframes", action="store_true", help="keyframe mode for every method")
    parser.add_argument("--baseline-threshold-px", type=float, default=None, metavar="PX",
                        help="sensitivity run: RANSAC threshold of orb/akaze set to PX pixels at "
                             "the horizon (default: the shared back end's threshold)")
    parser.add_argument("--timing-frames", type=int, default=50)
    parser.add_argument("--timing-rounds", type=int, default=3)
    args = parser.parse_args(argv)
    base = EstimateConfig()
    if args.keyframes:
        base = replace(base, keyframe=replace(base.keyframe, enabled=True))
    out = Path(args.out)
    rows = []
    for dataset in args.datasets:
        name = Path(dataset).name
        configs = {m: method_config(base, m, dataset, args.baseline_threshold_px)
                   for m in args.methods}
        for method in args.methods:
            start = time.perf_counter()
            estimate = estimate_dataset(dataset, method=method, config=configs[method], progress=True)
            wall = time.perf_counter() - start
            est_path = out / name / f"{method}.txt"
            write_estimate_run(est_path, estimate, dataset_dir=dataset, extra={"wall_seconds": wall})
            meta = evaluate_files(Path(dataset) / "groundtruth.txt", est_path,
                                  out_dir=out / name / f"{method}.eval")
            s = meta["summary"]
            seconds = np.array([r.seconds for r in estimate.frames[1:]])
            rows.append({"dataset": name, "scene": meta["scene"], "method": method,
                         "mean_rmse": s["mean_rmse"], "geodesic_rmse": s["geodesic"]["rmse"],
                         "roll": s["axes"]["roll"]["rmse"], "pitch": s["axes"]["pitch"]["rmse"],
                         "yaw": s["axes"]["yaw"]["rmse"],
                         "median_s": float(np.median(seconds)), "mean_s": float(seconds.mean()),
                         "wall_per_frame_s": wall / len(estimate.frames),
                         "failures": s["failures"]["count"], "frames": len(estimate.frames),
                         "ransac_threshold_rad": configs[method].relative_pose.ransac_threshold_rad})
        if args.timing_rounds > 0:
            walls = interleaved_timing(dataset, args.methods, configs, frames=args.timing_frames,
                                       rounds=args.timing_rounds)
            for r in rows:
                if r["dataset"] == name:
                    r["timed_wall_per_frame_s"] = float(np.median(walls[r["method"]]))
                    r["timed_runs_s"] = walls[r["method"]]
    key = "timed_wall_per_frame_s" if args.timing_rounds > 0 else "wall_per_frame_s"
    machine = machine_info()
    print(f"machine: {machine['cpu']}, {machine['cores']} cores, {machine['ram_gib']} GiB, "
          f"python {machine['python']}")
    print(f"{'dataset':<14}{'method':<7}{'roll':>9}{'pitch':>9}{'yaw':>9}{'mean':>9}{'geodesic':>10}"
          f"{'run ms':>9}{'wall ms':>9}{'timed ms':>10}{'fail':>8}")
    for r in rows:
        print(f"{r['dataset']:<14}{r['method']:<7}{r['roll']:>9.4f}{r['pitch']:>9.4f}{r['yaw']:>9.4f}"
              f"{r['mean_rmse']:>9.4f}{r['geodesic_rmse']:>10.4f}{r['median_s'] * 1e3:>9.1f}"
              f"{r['wall_per_frame_s'] * 1e3:>9.1f}"
              f"{r.get(key, float('nan')) * 1e3:>10.1f}{r['failures']:>4}/{r['frames']}")
    print(f"\nratios (time: {key}; targets: rmse <= 0.333, time vs ORB <= 0.5, vs AKAZE <= 0.1)")
    ratios = {}
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        by = {r["method"]: r for r in rows if r["dataset"] == dataset}
        if "ifmi" not in by:
            continue
        entry = {}
        base_rmse = [by[m]["mean_rmse"] for m in ("orb", "akaze") if m in by]
        if base_rmse:
            entry["rmse_vs_best_baseline"] = by["ifmi"]["mean_rmse"] / min(base_rmse)
        for m in ("orb", "akaze"):
            if m in by:
                entry[f"time_vs_{m}"] = by["ifmi"][key] / by[m][key]
        ratios[dataset] = entry
        print(f"{dataset:<14}" + "  ".join(f"{k} {v:.3f}" for k, v in entry.items()))
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_methods.json").write_text(json.dumps({"rows": rows, "ratios": ratios,
                                                        "time_key": key, "machine": machine},
                                                       indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
