"""How much of a method's per-pair rotation error on translated sets the translation direction carries.

Runs a dataset as ``ifmi estimate`` does (``--method``, default iFMI; frame or keyframe mode) and keeps
the rays each accepted frame pair was solved from. For each pair it prints
the rotation error of the estimate, and of the rotation refitted to the
estimate's inlier rays with the **true** translation direction held fixed (a robust
least-squares fit of the epipolar residuals, soft-L1 with the scale
``--refit-scale`` in units of the inlier threshold, started from the
estimate), and refitted with the direction the previous pair estimated
(a constant-velocity prior on the direction; "prev"). If the first refit is far better, the tiles measured the motion well
and the error came from a translation direction the rays fix only weakly
(short baselines: the parallax of a 1-2 cm step is a few milliradians,
about the tile noise), not from biased tile measurements. Summaries are
binned by the true step length, and split by the model the back end chose::

    python benchmarks/translation_ambiguity.py /work/data/sets36/*trans* --out out/translation_ambiguity

Errors are rotation vectors of ``R_ab_true^T R_ab`` in camera a, milliradians;
"bias" is the length of their mean vector over a bin; "prev deg" the median
angle between the previous pair's direction and the true one. Needs each dataset's
``groundtruth.txt``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from bench_methods import mode_config
from ifmi.io.atomic import atomic_write_json
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum
from ifmi.methods import create_front_end
from ifmi.odometry import track_sequence
from ifmi.pipeline import EstimateConfig, estimate_dataset, resolved_config
from ifmi.relative_pose import relative_pose_from_rays

# Step-length bins of the summary (metres; the renders' scale).
STEP_BINS_M = (0.0, 0.02, 0.05, np.inf)


def epipolar_sines(rotation_vector: np.ndarray, rays_a: np.ndarray, rays_b: np.ndarray,
                   translation: np.ndarray) -> np.ndarray:
    """Sine of each ray pair's angle to its epipolar plane for ``R_ab`` = exp(rotation_vector)
    and the unit translation ``t_ab`` (camera a); (N,) for (N, 3) rays."""
    rotation = Rotation.from_rotvec(rotation_vector).as_matrix()
    normals = np.cross(translation, rays_a)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return np.einsum("ij,ij->i", normals, rays_b @ rotation.T)


def rotation_with_translation(rays_a: np.ndarray, rays_b: np.ndarray, translation: np.ndarray,
                              start: np.ndarray, *, scale: float) -> np.ndarray:
    """``R_ab`` (3, 3) refitted to the rays with the translation direction held at ``translation``."""
    fit = least_squares(epipolar_sines, Rotation.from_matrix(start).as_rotvec(),
                        args=(rays_a, rays_b, translation), loss="soft_l1", f_scale=scale)
    return Rotation.from_rotvec(fit.x).as_matrix()


def recorded_pairs(dataset: str, config: EstimateConfig, *, method: str) -> tuple:
    """Run ``dataset`` and return, per accepted frame, (reference, frame, pose, info, rays_a, rays_b).

    The tracker may solve a frame more than once (against the last good
    frame after a poor keyframe match, on recovery); the last solve before
    the frame's record is the one it kept.
    """
    data = read_dataset(dataset)
    decided = estimate_dataset(dataset, method=method, config=config).config  # the band, as the CLI decides it
    front_end = create_front_end(method, data.model, decided)
    last, kept = {}, []

    def solver(rays_a, rays_b, *, options, rays_per_measurement=1):
        pose, info = relative_pose_from_rays(rays_a, rays_b, options=options,
                                             rays_per_measurement=rays_per_measurement)
        last.update(pose=pose, info=info, rays=(rays_a, rays_b))
        return pose, info

    def on_frame(record):
        if record.success and last:
            kept.append((record.reference_frame, record.frame, last["pose"], last["info"], *last["rays"]))
        last.clear()

    track_sequence(data.iter_images(), front_end, pose_options=decided.relative_pose, keyframe=decided.keyframe,
                   pose_solver=solver, on_frame=on_frame)
    return kept


def pair_rows(dataset: str, config: EstimateConfig, *, method: str, scale: float) -> list:
    """One row per accepted pair: step (m), model, and rotation errors (mrad) of the estimate, of the
    refit with the true translation direction, and of the refit with the direction the previous pair
    estimated, turned into this pair's camera a (NaN for a sequence's first pair or after a gap)."""
    truth = read_tum(Path(dataset) / "groundtruth.txt")
    rows, previous, previous_frame = [], None, None
    for a, b, pose, info, rays_a, rays_b in recorded_pairs(dataset, config, method=method):
        rotation_true = truth.rotations[a].T @ truth.rotations[b]
        translation = truth.rotations[a].T @ (truth.positions[b] - truth.positions[a])
        step = float(np.linalg.norm(translation))
        held = previous if previous_frame == a else None
        previous = _direction_in_b(pose, info, held)
        previous_frame = b
        if step == 0.0:
            continue  # no translation direction to hold
        inliers = np.asarray(info.inlier_mask, dtype=bool)

        def error_of(rotation):
            return (Rotation.from_matrix(rotation_true.T @ rotation).as_rotvec() * 1e3).tolist()

        def refit(direction):
            if direction is None:
                return [float("nan")] * 3
            return error_of(rotation_with_translation(rays_a[inliers], rays_b[inliers], direction,
                                                      pose.rotation, scale=scale))

        rows.append({"dataset": Path(dataset).name, "pair": [int(a), int(b)], "step_m": step,
                     "model": info.model, "error_mrad": error_of(pose.rotation),
                     "refit_error_mrad": refit(translation / step),
                     "previous_direction_error_mrad": refit(held),
                     "previous_direction_angle_deg": float("nan") if held is None else
                     float(np.degrees(np.arccos(np.clip(held @ translation / step, -1.0, 1.0))))})
    return rows


def _direction_in_b(pose, info, held: np.ndarray | None) -> np.ndarray | None:
    """The pair's translation direction in camera b: the 5-point model's, else the held one carried
    through the rotation (None if neither)."""
    direction = np.asarray(pose.translation_direction, dtype=np.float64)
    if info.model == "5pt" and np.linalg.norm(direction) > 0:
        return pose.rotation.T @ (direction / np.linalg.norm(direction))
    return None if held is None else pose.rotation.T @ held


def print_summary(rows: list) -> list:
    """Per step bin and model: pairs, RMS and bias of the estimate and of the refit; the summary rows."""
    summary = []
    print(f"{'step (cm)':<11}{'model':<10}{'pairs':>6}{'RMS est':>9}{'bias est':>9}{'RMS refit':>10}{'bias refit':>11}"
          f"{'RMS prev':>9}{'pairs prev':>11}{'prev deg':>9}")
    steps = np.array([r["step_m"] for r in rows])
    models = np.array([r["model"] for r in rows])
    for low, high in zip(STEP_BINS_M[:-1], STEP_BINS_M[1:]):
        for model in ("all", "rotation", "5pt"):
            mask = (steps >= low) & (steps < high) & ((models == model) if model != "all" else True)
            if not mask.any():
                continue
            est = np.array([rows[i]["error_mrad"] for i in np.flatnonzero(mask)])
            refit = np.array([rows[i]["refit_error_mrad"] for i in np.flatnonzero(mask)])
            held = np.array([rows[i]["previous_direction_error_mrad"] for i in np.flatnonzero(mask)])
            angles = np.array([rows[i]["previous_direction_angle_deg"] for i in np.flatnonzero(mask)])
            held, angles = held[np.isfinite(held).all(axis=1)], angles[np.isfinite(angles)]
            entry = {"step_cm": [low * 100, high * 100], "model": model, "pairs": int(mask.sum()),
                     "rms_mrad": float(np.sqrt((est ** 2).sum(1).mean())),
                     "bias_mrad": float(np.linalg.norm(est.mean(0))),
                     "refit_rms_mrad": float(np.sqrt((refit ** 2).sum(1).mean())),
                     "refit_bias_mrad": float(np.linalg.norm(refit.mean(0))),
                     "previous_direction_pairs": len(held),
                     "previous_direction_rms_mrad": float(np.sqrt((held ** 2).sum(1).mean())) if len(held) else None,
                     "previous_direction_median_angle_deg": float(np.median(angles)) if len(angles) else None}
            summary.append(entry)
            label = f"{low * 100:.0f}-{high * 100:.0f}"
            print(f"{label:<11}{model:<10}{entry['pairs']:>6}{entry['rms_mrad']:>9.2f}{entry['bias_mrad']:>9.2f}"
                  f"{entry['refit_rms_mrad']:>10.2f}{entry['refit_bias_mrad']:>11.2f}"
                  f"{entry['previous_direction_rms_mrad'] or float('nan'):>9.2f}{len(held):>11}"
                  f"{entry['previous_direction_median_angle_deg'] or float('nan'):>9.0f}")
    return summary


def estimate_threshold(dataset: str, config: EstimateConfig) -> float:
    """The inlier threshold (rad) the back end uses on ``dataset``'s calibration."""
    return resolved_config(config, read_dataset(dataset).model).relative_pose.ransac_threshold_rad



def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--method", default="ifmi", help="ifmi, orb, akaze or package.module:factory")
    parser.add_argument("--mode", choices=("frame", "keyframe"), default="frame")
    parser.add_argument("--seed", type=int, default=0, help="relative_pose.seed (RANSAC)")
    parser.add_argument("--refit-scale", type=float, default=1 / 6,
                        help="soft-L1 scale of the refit, in inlier thresholds (default 1/6: 2 mrad at 256 px)")
    parser.add_argument("--out", default="out/translation_ambiguity")
    args = parser.parse_args(argv)
    base = mode_config(EstimateConfig(), args.mode)
    config = replace(base, relative_pose=replace(base.relative_pose, seed=args.seed))
    rows = []
    for dataset in args.datasets:
        threshold = estimate_threshold(dataset, config)
        rows += pair_rows(dataset, config, method=args.method, scale=args.refit_scale * threshold)
    print("rotation error per pair (mrad): the estimate, and the rotation refitted to the estimate's inlier "
          "rays with the true translation direction held fixed, and with the previous pair's (prev)")
    summary = print_summary(rows)
    atomic_write_json(Path(args.out) / "translation_ambiguity.json",
                      {"rows": rows, "summary": summary, "argv": sys.argv if argv is None else argv})
    return 0


if __name__ == "__main__":
    sys.exit(main())
