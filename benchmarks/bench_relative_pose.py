"""Relative-pose back end: time and accuracy against a baseline revision, on the same ray sets.

The baseline is ``ifmi/relative_pose.py`` as of a git revision (``--baseline``,
by default the last revision before the back end was reworked for speed),
loaded from ``git show`` into a module of its own, so both run in this
process on identical inputs:

* dataset pairs: the front end of ``--method`` (iFMI by default; default
  configuration) on consecutive frames ``k - 1, k`` of each DATASET
  (``--pairs`` pairs), its rays with the threshold of the dataset's
  calibration; ground truth ``R_ab = R_0a^T R_0b`` from the dataset's
  ``groundtruth.txt``;
* synthetic pairs (``--synthetic`` of each kind): random scene points at 2 to 6
  units seen from two cameras, pure rotation and a translating camera, with
  ray noise and a fraction of gross outliers.

With ``--odometry`` each DATASET is also estimated end to end
(:func:`ifmi.pipeline.estimate_dataset`, default configuration: motion
prior, keyframes) once with each back end (the odometry's reference to it
is swapped for the run and restored), printing the frame-to-frame and
absolute rotation RMSE against the ground truth and the wall time per
frame. The front end is steered by the motion prior, so rounding-level
differences between the back ends can change later frames' rays; the
spread this causes is shown by re-running the baseline with its input
rays perturbed by 1e-15 (relative), ``--odometry`` times with different
seeds.

Each call is timed ``--repeats`` times, baseline and new alternating (which
goes first alternates too), and the fastest of each counts, which damps
the load of other processes. Prints per group of pairs the median number
of rays, the mean milliseconds per call of each, the ratio new / baseline
(target <= 0.5), the RMS rotation error of each against the ground truth,
the models chosen and how many pairs differ in model or inlier set, and the
largest angle between the two estimates.

Usage::

    python benchmarks/bench_relative_pose.py [DATASET ...] [--method ifmi] [--pairs 30]
        [--synthetic 10] [--repeats 5] [--baseline REV] [--odometry N] [--options JSON]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ifmi.odometry import track_sequence
from ifmi.io.dataset import read_dataset, read_image
from ifmi.io.tum import read_tum
from ifmi.pipeline import EstimateConfig, create_front_end, method_names, resolved_config
from ifmi.relative_pose import RelativePoseOptions, relative_pose_from_rays
from ifmi.rotations import geodesic_angle

# Last revision of the back end before the speed work (the default baseline).
BASELINE_REVISION = "14b6bb94f4dcda893b8df02ed9cad3562c0a2927"
DEFAULT_DATASETS = ("DATA/office_200", "DATA/lawn_200")
# Synthetic pairs: rays, outlier fraction, ray noise and threshold (radians; the
# threshold is about one pixel of the 800 x 800 datasets, the noise a fraction of it).
SYNTHETIC_RAYS = (300, 600)
SYNTHETIC_OUTLIERS = 0.1
SYNTHETIC_NOISE_RAD = 8e-4
SYNTHETIC_THRESHOLD_RAD = 6e-3
SYNTHETIC_TRANSLATION = (0.3, -0.2, 0.1)
# Relative size of the perturbation of the baseline's input rays that shows the odometry's
# sensitivity to rounding (a few units in the last place of a double).
ROUNDING_PERTURBATION = 1e-15


def load_baseline(revision: str):
    """``ifmi/relative_pose.py`` at ``revision`` as a module ``ifmi.relative_pose_baseline`` (inside the
    package, so that its relative imports resolve to the current ``ifmi``)."""
    root = Path(__file__).resolve().parents[1]
    source = subprocess.run(["git", "-C", str(root), "show", f"{revision}:ifmi/relative_pose.py"],
                            check=True, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory(prefix="bench_relative_pose_") as folder:
        path = Path(folder) / "relative_pose_baseline.py"
        path.write_text(source)
        spec = importlib.util.spec_from_file_location("ifmi.relative_pose_baseline", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
    return module


def dataset_cases(root: str, method: str, pairs: int) -> list[tuple]:
    """``(rays_a, rays_b, R_ab, threshold_rad)`` of the first ``pairs`` consecutive frame pairs."""
    dataset = read_dataset(root)
    config = resolved_config(EstimateConfig(), dataset.model)
    front_end = create_front_end(method, dataset.model, config)
    truth = read_tum(dataset.groundtruth_path).rotations
    threshold = config.relative_pose.ransac_threshold_rad
    cases, previous = [], None
    for k in range(min(pairs + 1, len(dataset.image_paths))):
        state = front_end.prepare(read_image(dataset.image_paths[k], size=dataset.model.size))
        if previous is not None:
            corr = front_end.correspondences(previous, state)
            if corr.success:
                cases.append((corr.rays_a, corr.rays_b, truth[k - 1].T @ truth[k], threshold))
        previous = state
    return cases


def synthetic_case(n: int, translation, seed: int) -> tuple:
    """Rays of ``n`` scene points from two cameras with noise and outliers, and ``R_ab``."""
    rng = np.random.default_rng(seed)
    points_b = rng.normal(size=(n, 3))
    points_b *= rng.uniform(2.0, 6.0, (n, 1)) / np.linalg.norm(points_b, axis=1, keepdims=True)
    rotation = Rotation.from_rotvec(rng.normal(0.0, 0.05, 3)).as_matrix()
    rays_a = points_b @ rotation.T + np.asarray(translation)
    rays_b = points_b.copy()
    for rays in (rays_a, rays_b):
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        rays += rng.normal(0.0, SYNTHETIC_NOISE_RAD / np.sqrt(2.0), rays.shape)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    bad = rng.choice(n, int(SYNTHETIC_OUTLIERS * n), replace=False)
    junk = rng.normal(size=(len(bad), 3))
    rays_a[bad] = junk / np.linalg.norm(junk, axis=1, keepdims=True)
    return rays_a, rays_b, rotation, SYNTHETIC_THRESHOLD_RAD


def compare(cases, baseline, repeats: int, options: dict | None = None) -> dict:
    """Fastest time, estimate and diagnostics of each case under both implementations.

    ``options``: :class:`RelativePoseOptions` fields for the new implementation (the threshold is
    the case's), e.g. ``{"refine_hypotheses": 3}``; the baseline runs with its defaults.
    """
    options = dict(options or {})
    times = {"old": np.full(len(cases), np.inf), "new": np.full(len(cases), np.inf)}
    results = {"old": [None] * len(cases), "new": [None] * len(cases)}
    solvers = {
        "old": lambda a, b, thr: baseline.relative_pose_from_rays(
            a, b, options=baseline.RelativePoseOptions(ransac_threshold_rad=thr)),
        "new": lambda a, b, thr: relative_pose_from_rays(
            a, b, options=RelativePoseOptions(**{**options, "ransac_threshold_rad": thr})),
    }
    for repeat in range(repeats):
        for i, (rays_a, rays_b, _, threshold) in enumerate(cases):
            for name in (("old", "new") if (repeat + i) % 2 == 0 else ("new", "old")):
                start = time.perf_counter()
                result = solvers[name](rays_a, rays_b, threshold)
                times[name][i] = min(times[name][i], time.perf_counter() - start)
                results[name][i] = result
    return {"times": times, "results": results}


def summary(label: str, cases, outcome) -> tuple[float, float]:
    """Print one group's line; return its summed fastest times (baseline, new)."""
    times, results = outcome["times"], outcome["results"]
    errors = {name: np.array([geodesic_angle(case[2], pose.rotation)
                              for case, (pose, _) in zip(cases, results[name])]) for name in results}
    models = {name: [info.model if info.success else "fail" for _, info in results[name]] for name in results}
    differ = sum(not (o[1].model == n[1].model and np.array_equal(o[1].inlier_mask, n[1].inlier_mask))
                 for o, n in zip(results["old"], results["new"]))
    apart = max(geodesic_angle(o[0].rotation, n[0].rotation) for o, n in zip(results["old"], results["new"]))
    count = {name: {m: models[name].count(m) for m in ("rotation", "5pt", "fail")} for name in models}
    old, new = times["old"].sum(), times["new"].sum()
    rays = int(np.median([len(case[0]) for case in cases]))
    print(f"{label:<22} {len(cases):>5} {rays:>5} {1e3 * old / len(cases):>8.3f} {1e3 * new / len(cases):>8.3f} "
          f"{new / old:>6.3f} {np.sqrt(np.mean(errors['old'] ** 2)):>10.3e} "
          f"{np.sqrt(np.mean(errors['new'] ** 2)):>10.3e}  "
          f"{count['old']['rotation']}/{count['old']['5pt']}/{count['old']['fail']:<3} "
          f"{count['new']['rotation']}/{count['new']['5pt']}/{count['new']['fail']:<3} {differ:>6} {apart:>9.1e}")
    return old, new


def perturbed_solver(solver, seed: int):
    """``solver`` with its ``rays_a`` scaled row-wise by ``1 + ROUNDING_PERTURBATION * N(0, 1)``."""
    rng = np.random.default_rng(seed)

    def solve(rays_a, rays_b, *, options):
        scale = 1.0 + ROUNDING_PERTURBATION * rng.standard_normal((len(rays_a), 1))
        return solver(rays_a * scale, rays_b, options=options)

    return solve


def odometry_comparison(root: str, method: str, baseline, seeds: int) -> None:
    """Print end-to-end accuracy and time per frame of ``root`` with each back end."""
    truth = read_tum(read_dataset(root).groundtruth_path).rotations
    runs = [("baseline", baseline.relative_pose_from_rays), ("new", relative_pose_from_rays)]
    runs += [(f"baseline, rays +-1e-15 ({seed})", perturbed_solver(baseline.relative_pose_from_rays, seed))
             for seed in range(seeds)]
    data = read_dataset(root)
    config = resolved_config(EstimateConfig(), data.model)
    for label, solver in runs:
        start = time.perf_counter()
        trajectory, _ = track_sequence(data.iter_images(prefetch=True, skip_unreadable=True),
                                       create_front_end(method, data.model, config),
                                       pose_options=config.relative_pose, keyframe=config.keyframe,
                                       pose_solver=solver)
        wall = (time.perf_counter() - start) / len(trajectory)
        rotations = trajectory.rotations
        step = [geodesic_angle(truth[k - 1].T @ truth[k], rotations[k - 1].T @ rotations[k])
                for k in range(1, len(rotations))]
        absolute = [geodesic_angle(truth[k], rotations[k]) for k in range(len(rotations))]
        name = f"{Path(root).name} {method} {label}"
        print(f"{name:<48} {np.sqrt(np.mean(np.square(step))):>12.4e} "
              f"{np.sqrt(np.mean(np.square(absolute))):>12.4e} {1e3 * wall:>9.2f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="*", default=list(DEFAULT_DATASETS))
    parser.add_argument("--method", default="ifmi", choices=method_names(),
                        help="front end that matches the dataset frames")
    parser.add_argument("--pairs", type=int, default=30, help="frame pairs per dataset")
    parser.add_argument("--synthetic", type=int, default=10, help="synthetic pairs per kind and size")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline", default=BASELINE_REVISION, metavar="REV",
                        help="git revision of the baseline ifmi/relative_pose.py")
    parser.add_argument("--odometry", type=int, default=None, metavar="N",
                        help="also estimate each dataset end to end with both back ends, and N "
                             "times with the baseline on rays perturbed at rounding level")
    parser.add_argument("--options", default="{}", metavar="JSON",
                        help='RelativePoseOptions fields for the new back end, e.g. \'{"refine_hypotheses": 3}\'')
    args = parser.parse_args(argv)
    try:
        options = json.loads(args.options)
        if not isinstance(options, dict):
            raise ValueError(f"expected a JSON object, got {type(options).__name__}")
        RelativePoseOptions(**{**options, "ransac_threshold_rad": 1e-3})
    except (ValueError, TypeError) as exc:
        parser.error(f"--options: {exc}")
    baseline = load_baseline(args.baseline)

    groups = []
    for root in args.datasets:
        groups.append((f"{Path(root).name} {args.method}", dataset_cases(root, args.method, args.pairs)))
    for n in SYNTHETIC_RAYS if args.synthetic > 0 else ():
        groups.append((f"synthetic rotation {n}",
                       [synthetic_case(n, (0.0, 0.0, 0.0), seed) for seed in range(args.synthetic)]))
        groups.append((f"synthetic translate {n}",
                       [synthetic_case(n, SYNTHETIC_TRANSLATION, seed) for seed in range(args.synthetic)]))

    print(f"baseline: ifmi/relative_pose.py at {args.baseline[:12]}; new: options {options}; fastest of {args.repeats} "
          "interleaved runs per call; rotation errors in radians; models rotation/5pt/fail")
    print(f"{'group':<22} {'pairs':>5} {'rays':>5} {'old ms':>8} {'new ms':>8} {'ratio':>6} "
          f"{'rmse old':>10} {'rmse new':>10}  {'old r/5/f':<9} {'new r/5/f':<9} {'differ':>6} {'max apart':>9}")
    totals = {}
    for label, cases in groups:
        if not cases:
            print(f"{label:<22} no usable pairs")
            continue
        old, new = summary(label, cases, compare(cases, baseline, args.repeats, options))
        kind = "datasets" if not label.startswith("synthetic") else "synthetic"
        totals.setdefault(kind, [0.0, 0.0])
        totals[kind][0] += old
        totals[kind][1] += new
    for kind, (old, new) in totals.items():
        print(f"time ratio new / baseline, {kind}: {new / old:.3f} (target <= 0.5)")
    if args.odometry is not None:
        print("\nend to end (rotation RMSE in radians, wall ms per frame)")
        print(f"{'dataset method back end':<48} {'frame rmse':>12} {'abs rmse':>12} {'ms/frame':>9}")
        for root in args.datasets:
            odometry_comparison(root, args.method, baseline, args.odometry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
