"""How much of a method's per-pair rotation error on translated sets the translation direction carries.

Runs a dataset as ``ifmi estimate`` does (``--method``, default iFMI; frame or keyframe mode) and keeps
the rays each accepted frame pair was solved from. For each pair it prints
the rotation error of the estimate, and of the rotation refitted to the
estimate's inlier rays with the **true** translation direction held fixed (a robust
least-squares fit of the epipolar residuals, soft-L1 with the scale
``--refit-scale`` in units of the inlier threshold, started from the
estimate), and refitted with the direction the previous pair estimated
(a constant-velocity prior on the direction; "prev"), and, with ``--window-half H``, refitted
jointly with the H pairs before and after it under one unknown direction shared in camera 0's
frame (a camera moving steadily over the window; "window"). If the first refit is far better, the tiles measured the motion well
and the error came from a translation direction the rays fix only weakly
(short baselines: the parallax of a 1-2 cm step is a few milliradians,
about the tile noise), not from biased tile measurements. Summaries are
binned by the true step length, and split by the model the back end chose::

    python benchmarks/translation_ambiguity.py DATA/*trans* --out out/translation_ambiguity

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


def window_rotations(pairs: list, rotations_0a: np.ndarray, starts: list, *, scale: float) -> tuple:
    """Rotations of a window of consecutive pairs refitted jointly with **one** translation direction.

    The direction is shared in camera 0's frame (``t_ab = R_0a^T d``; a
    camera moving steadily over the window), unknown, and fitted with the
    rotations: a robust least-squares fit of all pairs' epipolar residuals
    (soft-L1, scale ``scale``), started from each of ``starts`` (unit
    directions in camera 0), the lowest cost kept.

    Parameters
    ----------
    pairs : list of (rays_a, rays_b, rotation_ab)
        Inlier rays ((N_i, 3) each) and the starting ``R_ab`` (3, 3) of each pair.
    rotations_0a : (W, 3, 3) ndarray
        ``R_0a`` of each pair's camera a (held fixed).
    starts : list of (3,) ndarray
    scale : float, keyword-only

    Returns
    -------
    rotations : (W, 3, 3) ndarray
    direction : (3,) ndarray
        The shared unit direction in camera 0.
    """
    count = len(pairs)

    def residuals(x):
        direction = x[3 * count:] / np.linalg.norm(x[3 * count:])
        return np.concatenate([*(epipolar_sines(x[3 * j:3 * j + 3], rays_a, rays_b, rotations_0a[j].T @ direction)
                                 for j, (rays_a, rays_b, _) in enumerate(pairs)),
                               [np.linalg.norm(x[3 * count:]) - 1.0]])

    vectors = [Rotation.from_matrix(rotation).as_rotvec() for *_, rotation in pairs]
    best = min((least_squares(residuals, np.concatenate([*vectors, start]), loss="soft_l1", f_scale=scale)
                for start in starts), key=lambda fit: fit.cost)
    rotations = Rotation.from_rotvec(best.x[:3 * count].reshape(count, 3)).as_matrix()
    return rotations, best.x[3 * count:] / np.linalg.norm(best.x[3 * count:])


def window_errors(kept: list, truth, *, half: int, scale: float) -> list:
    """Per recorded pair, the rotation error (mrad) of :func:`window_rotations` over the pairs up to
    ``half`` before and after it (a run of chained pairs; ``R_0a`` chained from the estimates);
    NaN with ``half`` 0. Started from the window's 5-point directions (else the three axes)."""
    if half == 0:
        return [[float("nan")] * 3 for _ in kept]
    rotations_0 = {kept[0][0]: np.eye(3)} if kept else {}
    for a, b, pose, *_ in kept:
        rotations_0[b] = rotations_0.get(a, np.eye(3)) @ pose.rotation
    errors = []
    for i, (a, b, *_rest) in enumerate(kept):
        window = [j for j in range(max(i - half, 0), min(i + half, len(kept) - 1) + 1)
                  if all(kept[k][1] == kept[k + 1][0] for k in range(min(i, j), max(i, j)))]
        pairs = [(kept[j][4][_inliers(kept[j])], kept[j][5][_inliers(kept[j])], kept[j][2].rotation) for j in window]
        rotations_0a = np.array([rotations_0[kept[j][0]] for j in window])
        starts = [rotations_0[kept[j][0]] @ _unit(kept[j][2].translation_direction)
                  for j in window if kept[j][3].model == "5pt"] or list(np.eye(3))
        rotations, _ = window_rotations(pairs, rotations_0a, starts, scale=scale)
        rotation_true = truth.rotations[a].T @ truth.rotations[b]
        errors.append((Rotation.from_matrix(rotation_true.T @ rotations[window.index(i)]).as_rotvec()
                       * 1e3).tolist())
    return errors


def _inliers(record) -> np.ndarray:
    return np.asarray(record[3].inlier_mask, dtype=bool)


def _unit(vector) -> np.ndarray:
    vector = np.asarray(vector, dtype=np.float64)
    return vector / np.linalg.norm(vector)


def pair_rows(dataset: str, config: EstimateConfig, *, method: str, scale: float, window_half: int = 0) -> list:
    """One row per accepted pair: step (m), model, and rotation errors (mrad) of the estimate, of the
    refit with the true translation direction, of the refit with the direction the previous pair
    estimated, turned into this pair's camera a (NaN for a sequence's first pair or after a gap), and
    of the window refit (:func:`window_errors`, ``window_half`` pairs each side; NaN with 0)."""
    truth = read_tum(Path(dataset) / "groundtruth.txt")
    kept = recorded_pairs(dataset, config, method=method)
    windowed = window_errors(kept, truth, half=window_half, scale=scale)
    rows, previous, previous_frame = [], None, None
    for (a, b, pose, info, rays_a, rays_b), window_error in zip(kept, windowed):
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
                     "window_error_mrad": window_error,
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
          f"{'RMS prev':>9}{'pairs prev':>11}{'prev deg':>9}{'RMS window':>11}")
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
            window = np.array([rows[i]["window_error_mrad"] for i in np.flatnonzero(mask)])
            held, angles = held[np.isfinite(held).all(axis=1)], angles[np.isfinite(angles)]
            entry = {"step_cm": [low * 100, high * 100], "model": model, "pairs": int(mask.sum()),
                     "rms_mrad": float(np.sqrt((est ** 2).sum(1).mean())),
                     "bias_mrad": float(np.linalg.norm(est.mean(0))),
                     "refit_rms_mrad": float(np.sqrt((refit ** 2).sum(1).mean())),
                     "refit_bias_mrad": float(np.linalg.norm(refit.mean(0))),
                     "previous_direction_pairs": len(held),
                     "previous_direction_rms_mrad": float(np.sqrt((held ** 2).sum(1).mean())) if len(held) else None,
                     "previous_direction_median_angle_deg": float(np.median(angles)) if len(angles) else None,
                     "window_rms_mrad": _finite_or_none(np.sqrt((window ** 2).sum(1).mean()))}
            summary.append(entry)
            label = f"{low * 100:.0f}-{high * 100:.0f}"
            print(f"{label:<11}{model:<10}{entry['pairs']:>6}{entry['rms_mrad']:>9.2f}{entry['bias_mrad']:>9.2f}"
                  f"{entry['refit_rms_mrad']:>10.2f}{entry['refit_bias_mrad']:>11.2f}"
                  f"{entry['previous_direction_rms_mrad'] or float('nan'):>9.2f}{len(held):>11}"
                  f"{entry['previous_direction_median_angle_deg'] or float('nan'):>9.0f}"
                  f"{entry['window_rms_mrad'] or float('nan'):>11.2f}")
    return summary


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


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
    parser.add_argument("--window-half", type=int, default=0, metavar="H",
                        help="also refit each pair with the H pairs before and after it sharing one "
                             "direction in camera 0 (column 'RMS window'; default 0: not run)")
    parser.add_argument("--out", default="out/translation_ambiguity")
    args = parser.parse_args(argv)
    base = mode_config(EstimateConfig(), args.mode)
    config = replace(base, relative_pose=replace(base.relative_pose, seed=args.seed))
    rows = []
    for dataset in args.datasets:
        threshold = estimate_threshold(dataset, config)
        rows += pair_rows(dataset, config, method=args.method, scale=args.refit_scale * threshold,
                          window_half=args.window_half)
    print("rotation error per pair (mrad): the estimate, and the rotation refitted to the estimate's inlier "
          "rays with the true translation direction held fixed, and with the previous pair's (prev)")
    summary = print_summary(rows)
    atomic_write_json(Path(args.out) / "translation_ambiguity.json",
                      {"rows": rows, "summary": summary, "argv": sys.argv if argv is None else argv})
    return 0


if __name__ == "__main__":
    sys.exit(main())
