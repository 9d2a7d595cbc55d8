"""How well the predicted rotation error of each frame pair matches its true error.

Every estimate's ``frames.csv`` holds ``rotation_sigma_rad``, the RMS error
of the frame's rotation from its reference frame that the relative-pose fit
predicts (:attr:`ifmi.backend.relative_pose.RelativePoseInfo.rotation_sigma_rad`).
This benchmark reads the runs of ``benchmarks/bench_seeds.py`` (or of
``bench_methods.py``, whose folders have the same layout), takes each
successful frame's true error of that same rotation from the dataset's
ground truth (``R_gt,ref^T R_gt,k`` against ``R_est,ref^T R_est,k``) and
prints per method, mode and model:

* the pairs, the RMS of the true and of the predicted errors;
* percentiles of the true error over the predicted one (``z``); for a
  three-axis Gaussian error whose RMS the prediction gives, the median of
  ``z`` is 0.89 and 1 % of pairs exceed 1.94 (isotropic error);
* the share of pairs with ``z`` above 3 (more than noise explains).

Usage::

    python benchmarks/bench_uncertainty.py out/bench_seeds/bench_seeds.json [--json out/uncertainty.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ifmi.io.results import read_frames_csv
from ifmi.io.tum import read_tum
from ifmi.evaluation.metrics import associate_timestamps
from ifmi.geometry.rotations import geodesic_angle

# Ground-truth and estimate timestamps (frame indices) associate within this difference.
_MAX_TIME_DIFFERENCE = 1e-3
# True error over predicted error above which a pair counts as more than noise.
_FAR_Z = 3.0


@dataclass(frozen=True)
class PairErrors:
    """True and predicted rotation errors (radians) of one run's successful frame pairs."""

    method: str
    mode: str
    models: tuple
    true_rad: np.ndarray
    predicted_rad: np.ndarray


@dataclass(frozen=True)
class CalibrationSummary:
    """Figures of one method, mode and model over all its pairs."""

    method: str
    mode: str
    model: str
    pairs: int
    rms_true_rad: float
    rms_predicted_rad: float
    z_median: float
    z_p90: float
    z_p99: float
    share_far: float


def _run_folder(bench_json: Path, row: dict) -> Path:
    seed = f"seed{row['seed']}" if "seed" in row else ""
    return bench_json.parent / seed / row["mode"] / row["dataset_id"]


def pair_errors_of_run(est_path: Path, frames_path: Path, gt_path: Path, *, method: str, mode: str) -> PairErrors:
    """Each successful frame's true error of its rotation from its reference frame, and the prediction."""
    gt, est = read_tum(gt_path), read_tum(est_path)
    gi, ei = associate_timestamps(gt.timestamps, est.timestamps, max_difference=_MAX_TIME_DIFFERENCE)
    gt_row = dict(zip(ei.tolist(), gi.tolist()))
    frames = read_frames_csv(frames_path)
    sigma, model = frames.columns["rotation_sigma_rad"], frames.columns["model"]
    row_of_frame = {int(f): i for i, f in enumerate(frames.frame)}
    true, predicted, models = [], [], []
    for i, reference in enumerate(frames.reference_frame):
        ref = row_of_frame.get(int(reference))
        if not frames.success[i] or ref is None or ref == i or i not in gt_row or ref not in gt_row \
                or not np.isfinite(sigma[i]):
            continue
        rel_gt = gt.rotations[gt_row[ref]].T @ gt.rotations[gt_row[i]]
        rel_est = est.rotations[ref].T @ est.rotations[i]
        true.append(float(geodesic_angle(rel_gt, rel_est)))
        predicted.append(float(sigma[i]))
        models.append(str(model[i]))
    return PairErrors(method, mode, tuple(models), np.array(true), np.array(predicted))


def calibration_summaries(runs: list) -> list:
    """One :class:`CalibrationSummary` per method, mode and model (``"all"`` too) over ``runs``."""
    out = []
    keys = sorted({(p.method, p.mode) for p in runs})
    for method, mode in keys:
        chosen = [p for p in runs if (p.method, p.mode) == (method, mode)]
        true = np.concatenate([p.true_rad for p in chosen])
        predicted = np.concatenate([p.predicted_rad for p in chosen])
        models = np.array(sum((list(p.models) for p in chosen), []))
        for model in ("all", "rotation", "5pt"):
            keep = np.isfinite(predicted) & ((models == model) if model != "all" else True)
            if not keep.any():
                continue
            z = true[keep] / predicted[keep]
            p50, p90, p99 = np.percentile(z, [50, 90, 99])
            out.append(CalibrationSummary(method, mode, model, int(keep.sum()),
                                          float(np.sqrt(np.mean(true[keep] ** 2))),
                                          float(np.sqrt(np.mean(predicted[keep] ** 2))),
                                          float(p50), float(p90), float(p99), float(np.mean(z > _FAR_Z))))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bench_json", type=Path, help="bench_seeds.json (or bench_methods' rows JSON)")
    parser.add_argument("--json", type=Path, default=None, help="write the summaries here")
    args = parser.parse_args(argv)
    data = json.loads(args.bench_json.read_text())
    runs = []
    for row in data["rows"]:
        folder = _run_folder(args.bench_json, row)
        est_path = folder / f"{row['method']}.txt"
        runs.append(pair_errors_of_run(est_path, est_path.with_suffix(".frames.csv"),
                                       Path(row["dataset_path"]) / "groundtruth.txt",
                                       method=row["method"], mode=row["mode"]))
    summaries = calibration_summaries(runs)
    print("true rotation error of each successful pair over its predicted RMS error (z); RMS in mrad")
    print(f"{'method':<7}{'mode':<9}{'model':<9}{'pairs':>6}{'RMS true':>10}{'RMS pred':>10}"
          f"{'z 50%':>7}{'z 90%':>7}{'z 99%':>7}{'z>3':>7}")
    for s in summaries:
        print(f"{s.method:<7}{s.mode:<9}{s.model:<9}{s.pairs:>6}{s.rms_true_rad * 1e3:>10.3f}"
              f"{s.rms_predicted_rad * 1e3:>10.3f}{s.z_median:>7.2f}{s.z_p90:>7.2f}{s.z_p99:>7.2f}"
              f"{s.share_far:>7.3f}")
    if args.json is not None:
        args.json.write_text(json.dumps([asdict(s) for s in summaries], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
