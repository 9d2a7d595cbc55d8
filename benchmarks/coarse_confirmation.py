"""The coarse stage's confirming search, pair by pair: which start's result is right, and by how much it wins.

When the search from the prediction moves it by more than
``GlobalMotionConfig.confirm_angle_rad``, the coarse stage searches from
the identity as well and chooses between the results
(:meth:`ifmi.spectral.global_motion.GlobalMotionEstimator.estimate`). This runs
iFMI's default tracker unchanged on each set and mode and, for every such
call, records each start's result: its angle to the ground-truth ``R_ab``
of the pair, its panorama match (``score``) and the start's own. It then
prints, over the pairs where one result lies within ``--right-rad`` of the
truth and the other further, the mismatch ratio ``(1 - score_other) / (1 -
score_first)`` of the later start's result to the first's, split by which
one was right: the figure ``confirm_mismatch_ratio`` is chosen from::

    python benchmarks/coarse_confirmation.py DATA/* --out confirm.jsonl [--modes frame keyframe]

``--out`` holds one JSON line per call (set, mode, pair, the chosen
result's error, each search's figures).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from unittest import mock

import numpy as np

from bench_methods import MODES, mode_config
from ifmi.spectral.global_motion import GlobalMotionEstimator
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum
from ifmi.tracking.odometry import track_sequence
from ifmi.pipeline import EstimateConfig, resolved_config
from ifmi.geometry.rotations import geodesic_angle
from rotation_model_parallax import PairNamingFrontEnd


def record_dataset(path: str, mode: str, out) -> None:
    """Track ``path`` with iFMI's defaults in ``mode`` and write to ``out`` one JSON line per coarse
    estimate that searched from two starts (the coarse stage observed, its results unchanged)."""
    data = read_dataset(path)
    truth = read_tum(data.groundtruth_path).rotations
    config = mode_config(resolved_config(EstimateConfig(), data.model), mode)
    pair, searches = [], []
    search, estimate = GlobalMotionEstimator._search, GlobalMotionEstimator.estimate

    def observed_search(estimator, reference, coarse_b, start):
        found, start_score = search(estimator, reference, coarse_b, start)
        searches.append({"start": start, "found": found, "start_score": start_score})
        return found, start_score

    def observed_estimate(estimator, coarse_a, coarse_b, *, priors=(None,)):
        searches.clear()
        result = estimate(estimator, coarse_a, coarse_b, priors=priors)
        if len(searches) > 1:
            out.write(json.dumps(_record(Path(path).name, mode, pair, truth[pair[0]].T @ truth[pair[1]],
                                         result, searches)) + "\n")
        return result

    with mock.patch.object(GlobalMotionEstimator, "_search", observed_search), \
         mock.patch.object(GlobalMotionEstimator, "estimate", observed_estimate):
        track_sequence(data.iter_images(), PairNamingFrontEnd(data.model, config.ifmi, pair),
                       pose_options=config.relative_pose, keyframe=config.keyframe)


def _record(name: str, mode: str, pair: list, truth: np.ndarray, result, searches: list) -> dict:
    """One call's line: the pair, the chosen result's error and each search's figures (radians)."""
    return {"set": name, "mode": mode, "pair": list(pair),
            "chosen_err": float(geodesic_angle(result.rotation, truth)),
            "searches": [{"start_err": float(geodesic_angle(s["start"], truth)),
                          "err": float(geodesic_angle(s["found"].rotation, truth)), "score": s["found"].score,
                          "start_score": s["start_score"], "success": s["found"].success} for s in searches]}


def summarize(lines: list, right_rad: float) -> None:
    """Print the mismatch ratios of the pairs where exactly one of the two first results is right."""
    ratios = {True: [], False: []}  # keyed by: the later start's result is the right one
    for line in lines:
        first = line["searches"][0]
        for other in line["searches"][1:]:
            if (first["err"] < right_rad) == (other["err"] < right_rad):
                continue
            ratio = (1.0 - other["score"]) / max(1.0 - first["score"], 1e-12)
            ratios[other["err"] < right_rad].append((ratio, line["set"], line["mode"], line["pair"]))
    print(f"{len(lines)} calls searched from two starts")
    for later_right, label in ((True, "later start right"), (False, "first start right")):
        values = sorted(ratios[later_right])
        print(f"{label}: {len(values)} pairs, mismatch ratios "
              + " ".join(f"{r:.3f}" for r, *_ in values))
        for ratio, name, mode, pair in values if not later_right else []:
            print(f"  {name} {mode} {tuple(pair)}: {ratio:.3f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--right-rad", type=float, default=0.1,
                        help="a result this close to the truth (radians) counts as right")
    parser.add_argument("--out", type=Path, required=True, help="JSON lines, one per call")
    args = parser.parse_args(argv)
    with open(args.out, "w") as out:
        for mode in args.modes:
            for path in args.datasets:
                record_dataset(path, mode, out)
    summarize([json.loads(line) for line in open(args.out)], args.right_rad)
    return 0


if __name__ == "__main__":
    sys.exit(main())
