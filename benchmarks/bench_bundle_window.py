"""What a bundle-adjustment window changes: accuracy from two bench_seeds runs, and compute per frame.

Accuracy (``compare``): two ``bench_seeds.json`` files of the same sets, one
without and one with the window (``bench_seeds.py ... --config ba3.json``
where ``ba3.json`` is ``{"bundle_adjustment": {"window": 3}}``). Per mode
and group of sets (translated, rotation only, other cameras; designed or
held-out start frames ``*_s<k>``) it prints each method's geometric mean of
the ATE ratio with over without (medians over the seeds both runs share),
how many sets fell or rose by more than 10 %, and on how many sets iFMI's
ATE exceeds the better feature method's, each method with the same back end::

    python benchmarks/bench_bundle_window.py compare out/seeds_base/bench_seeds.json \
        out/seeds_ba3/bench_seeds.json

Compute (``time``): every method on each set's frames decoded in memory,
without and with the window, interleaved round by round in one process;
prints the median ms per frame and their ratio (the machine's load hits
both alike)::

    python benchmarks/bench_bundle_window.py time DATA/lawn_trans_x3 DATA/office_x5 --window 3 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from dataclasses import dataclass
from itertools import islice

import numpy as np

from ifmi.backend.bundle_adjustment import BundleAdjustmentOptions
from ifmi.io.dataset import read_dataset
from ifmi.pipeline import EstimateConfig, estimate_sequence

FEATURE_METHODS = ("orb", "akaze")
# A set counts as changed when its ATE moved by more than this fraction.
CHANGED = 0.1


@dataclass(frozen=True)
class GroupChange:
    """One method's change over one group of sets."""

    sets: int
    geometric_mean_ratio: float
    lower: int
    higher: int


def _medians(path: str) -> dict:
    """{(mode, dataset, method): {seed: ATE}} of a bench_seeds.json."""
    runs = defaultdict(dict)
    for row in json.loads(open(path, encoding="utf-8").read())["rows"]:
        runs[(row["mode"], row["dataset"], row["method"])][row["seed"]] = row["geodesic_rmse"]
    return runs


def _group(dataset: str) -> tuple[str, str]:
    kind = "cameras" if dataset.startswith(("ds_", "eucm_", "mei_")) else \
        "translated" if "_trans_" in dataset else "rotation only"
    return kind, "held out" if "_s" in dataset.rsplit("_x", 1)[-1] else "designed"


def compare(before_path: str, after_path: str) -> dict:
    """Per (mode, kind, designed/held out): {method: GroupChange} and iFMI's misses (sets, before, after)."""
    before, after = _medians(before_path), _medians(after_path)
    ratios, misses = defaultdict(lambda: defaultdict(list)), defaultdict(lambda: [0, 0, 0])
    medians = {}
    for key in after:
        seeds = sorted(set(after[key]) & set(before.get(key, {})))
        if seeds:
            medians[key] = tuple(float(np.median([run[s] for s in seeds])) for run in (before[key], after[key]))
            ratios[(key[0], *_group(key[1]))][key[2]].append(medians[key][1] / medians[key][0])
    for mode, dataset in {(k[0], k[1]) for k in medians}:
        keys = [(mode, dataset, m) for m in ("ifmi", *FEATURE_METHODS)]
        if all(k in medians for k in keys):
            count = misses[(mode, *_group(dataset))]
            count[0] += 1
            for i in (0, 1):
                count[1 + i] += medians[keys[0]][i] > min(medians[k][i] for k in keys[1:])
    changes = {group: {method: GroupChange(len(v), float(np.exp(np.mean(np.log(v)))),
                                           sum(r < 1 - CHANGED for r in v), sum(r > 1 + CHANGED for r in v))
                       for method, v in methods.items()} for group, methods in ratios.items()}
    return {"changes": changes, "misses": dict(misses)}


def time_window(dataset: str, *, window: int, rounds: int, frames: int) -> dict:
    """{method: (ms per frame without, with)}: medians over ``rounds`` interleaved runs in memory."""
    data = read_dataset(dataset)
    images = list(islice(data.iter_images(skip_unreadable=True), frames))
    configs = {w: EstimateConfig(bundle_adjustment=BundleAdjustmentOptions(window=w)) for w in (0, window)}
    walls = defaultdict(list)
    for _ in range(rounds):
        for method in ("ifmi", *FEATURE_METHODS):
            for w, config in configs.items():
                start = time.perf_counter()
                estimate_sequence(images, data.model, method=method, config=config)
                walls[(method, w)].append((time.perf_counter() - start) / len(images) * 1e3)
    return {m: (float(np.median(walls[(m, 0)])), float(np.median(walls[(m, window)])))
            for m in ("ifmi", *FEATURE_METHODS)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("compare")
    p.add_argument("before")
    p.add_argument("after")
    p = sub.add_parser("time")
    p.add_argument("datasets", nargs="+")
    p.add_argument("--window", type=int, default=3)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--frames", type=int, default=40)
    args = parser.parse_args(argv)
    if args.command == "compare":
        result = compare(args.before, args.after)
        print("mode, sets, method: geometric mean of ATE with/without, sets lower / higher by 10 %")
        for group, methods in sorted(result["changes"].items()):
            print(", ".join(group) + ": " + "; ".join(
                f"{m} {c.geometric_mean_ratio:.3f} ({c.sets} sets, {c.lower} lower, {c.higher} higher)"
                for m, c in sorted(methods.items())))
        print("iFMI above the better feature method (sets, without, with):")
        for group, count in sorted(result["misses"].items()):
            print(", ".join(group) + f": {count[0]} sets, {count[1]} -> {count[2]}")
        return 0
    for dataset in args.datasets:
        for method, (without, with_window) in time_window(dataset, window=args.window, rounds=args.rounds,
                                                          frames=args.frames).items():
            print(f"{dataset} {method}: {without:.1f} -> {with_window:.1f} ms/frame, ratio "
                  f"{with_window / without:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
