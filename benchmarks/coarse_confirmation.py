"""The coarse stage's confirming search, pair by pair: which start's result is right, and by how much it wins.

When the search from the prediction moves it by more than
``GlobalMotionConfig.confirm_angle_rad``, the coarse stage searches from
the identity as well and chooses between the results
(:meth:`ifmi.global_motion.GlobalMotionEstimator.estimate`). This runs
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


from bench_methods import MODES, mode_config
import ifmi.global_motion as global_motion
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum
from ifmi.methods import create_front_end
from ifmi.odometry import track_sequence
from ifmi.pipeline import EstimateConfig, resolved_config
from ifmi.rotations import geodesic_angle


class _Recorder:
    """While entered, records every search of each pair the coarse stage searches from two starts
    (its ``estimate`` and ``_search`` wrapped; both restored on exit)."""

    def __init__(self, out):
        self.out, self.pair, self.searches = out, None, []
        self._estimate = global_motion.GlobalMotionEstimator.estimate
        self._search = global_motion.GlobalMotionEstimator._search

    def __enter__(self) -> "_Recorder":
        recorder = self

        def search(estimator, reference, coarse_b, start):
            found, start_score = recorder._search(estimator, reference, coarse_b, start)
            recorder.searches.append((start, found, start_score))
            return found, start_score

        def estimate(estimator, coarse_a, coarse_b, *, priors=(None,)):
            recorder.searches = []
            result = recorder._estimate(estimator, coarse_a, coarse_b, priors=priors)
            if len(recorder.searches) > 1 and recorder.pair is not None:
                recorder.write(result)
            return result

        global_motion.GlobalMotionEstimator._search = search
        global_motion.GlobalMotionEstimator.estimate = estimate
        return self

    def __exit__(self, *exc) -> None:
        global_motion.GlobalMotionEstimator._search = self._search
        global_motion.GlobalMotionEstimator.estimate = self._estimate

    def write(self, result) -> None:
        name, mode, (a, b), truth = self.pair
        searches = [{"start_err": float(geodesic_angle(start, truth)), "err": float(geodesic_angle(found.rotation, truth)),
                     "score": found.score, "start_score": start_score, "success": found.success}
                    for start, found, start_score in self.searches]
        self.out.write(json.dumps({"set": name, "mode": mode, "pair": [a, b],
                                   "chosen_err": float(geodesic_angle(result.rotation, truth)),
                                   "searches": searches}) + "\n")


def record_dataset(path: str, mode: str, recorder: _Recorder) -> None:
    """Track ``path`` with iFMI's defaults in ``mode``, telling ``recorder`` each pair's frames and truth."""
    data = read_dataset(path)
    truth = read_tum(data.groundtruth_path).rotations
    config = mode_config(resolved_config(EstimateConfig(), data.model), mode)
    front_end = create_front_end("ifmi", data.model, config)
    prepare, correspondences, count = front_end.prepare, front_end.correspondences, [0]

    def prepared(image):
        state = prepare(image)
        state.frame_index = count[0]
        count[0] += 1
        return state

    def matched(state_a, state_b, **kwargs):
        a, b = state_a.frame_index, state_b.frame_index
        recorder.pair = (Path(path).name, mode, (a, b), truth[a].T @ truth[b])
        return correspondences(state_a, state_b, **kwargs)

    front_end.prepare, front_end.correspondences = prepared, matched
    track_sequence(data.iter_images(), front_end, pose_options=config.relative_pose, keyframe=config.keyframe)


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
    with open(args.out, "w") as out, _Recorder(out) as recorder:
        for mode in args.modes:
            for path in args.datasets:
                record_dataset(path, mode, recorder)
    summarize([json.loads(line) for line in open(args.out)], args.right_rad)
    return 0


if __name__ == "__main__":
    sys.exit(main())
