"""Method rankings over RANSAC seeds: every method's geodesic ATE on every set, once per back-end seed.

One set's ATE can change 2-3x with the seed of the relative-pose RANSAC
(``relative_pose.seed``): on a hard pair one seed's minimal samples land
in a wrong basin and another's do not, and the error is carried along the
trajectory. A ranking of methods on one run of one set can therefore be
luck. This benchmark runs each method, mode and dataset once per seed,
as ``benchmarks/bench_methods.py`` runs them once (same configuration for
every method, same resolved RANSAC threshold; accuracy only, no timing
pass), and prints per mode and set:

* the median geodesic ATE (radians) of each method over the seeds;
* each method's spread, the largest ATE over the smallest;
* iFMI's median over the better feature method's median (``ATE/best``).

Then, per mode, how many sets iFMI's ATE exceeds the better feature
method's in each seed's run, and on the medians.

Usage::

    python benchmarks/bench_seeds.py DATA/* --seeds 0 1 2 --out out/bench_seeds \
        [--methods ifmi orb akaze] [--modes frame keyframe] [--config JSON]

Files: ``OUT/seed<N>/MODE/<dataset id>/`` holds each run's estimate and
evaluation (as ``bench_methods.py`` writes them, so ``ifmi report
OUT/seed0/frame`` works), and ``OUT/bench_seeds.json`` every run's row
(with its ``seed``) and the per-set summaries.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from benchlib import METHODS, MODES, labelled_datasets, mode_config, run_method
from ifmi.errors import InputError
from ifmi.io.camera_file import calibration_path, read_camera
from ifmi.io.config import read_estimate_config
from ifmi.pipeline import EstimateConfig, resolved_config
from ifmi.experiments.report import machine_info

# The methods iFMI is ranked against.
FEATURE_METHODS = ("orb", "akaze")


@dataclass(frozen=True)
class SeedSpread:
    """One method's geodesic ATE (radians) on one set and mode, one entry per seed."""

    mode: str
    dataset: str
    method: str
    seeds: tuple[int, ...]
    ates: tuple[float, ...]
    failures: tuple[int, ...]

    @property
    def median(self) -> float:
        return float(np.median(self.ates))

    @property
    def spread(self) -> float:
        """Largest ATE over the smallest (1 for a single seed)."""
        return float(max(self.ates) / min(self.ates)) if min(self.ates) > 0 else float("inf")


def seed_spreads(rows: list) -> list[SeedSpread]:
    """Group ``run_method`` rows (each with a ``seed``) by mode, set and method, in first-seen order."""
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["mode"], r["dataset"], r["method"]), []).append(r)
    return [SeedSpread(mode, dataset, method, tuple(r["seed"] for r in runs),
                       tuple(r["geodesic_rmse"] for r in runs), tuple(r["failures"] for r in runs))
            for (mode, dataset, method), runs in groups.items()]


def ifmi_misses(spreads: list[SeedSpread], mode: str) -> tuple[list[int], int, int]:
    """Sets of ``mode`` where iFMI's ATE (or a failed frame) loses to the better feature method:
    per seed, on the medians, and how many sets were compared."""
    by = {(s.dataset, s.method): s for s in spreads if s.mode == mode}
    sets = [d for d, m in by if m == "ifmi" and any((d, f) in by for f in FEATURE_METHODS)]
    per_seed = [0] * max((len(by[(d, "ifmi")].ates) for d in sets), default=0)
    on_medians = 0
    for d in sets:
        ifmi = by[(d, "ifmi")]
        rivals = [by[(d, f)] for f in FEATURE_METHODS if (d, f) in by]
        for k in range(len(ifmi.ates)):
            per_seed[k] += (ifmi.ates[k] > min(r.ates[k] for r in rivals)) or ifmi.failures[k] > 0
        on_medians += ifmi.median > min(r.median for r in rivals)
    return per_seed, on_medians, len(sets)


def print_spreads(spreads: list[SeedSpread], seeds: list[int]) -> None:
    """Per mode and set: each method's median ATE and spread over the seeds, and iFMI's ratio."""
    methods = [m for m in METHODS if any(s.method == m for s in spreads)]
    width = max([12] + [len(s.dataset) + 1 for s in spreads])
    print(f"geodesic ATE (rad), median over RANSAC seeds {', '.join(map(str, seeds))}; "
          "spread: largest over smallest ATE")
    print(f"{'mode':<9}{'dataset':<{width}}" + "".join(f"{'ATE ' + m:>11}{'spread':>8}" for m in methods)
          + f"{'ATE/best':>9}")
    for mode, dataset in dict.fromkeys((s.mode, s.dataset) for s in spreads):
        by = {s.method: s for s in spreads if s.mode == mode and s.dataset == dataset}
        line = "".join(f"{by[m].median:>11.5f}{by[m].spread:>8.2f}" if m in by else f"{'-':>11}{'-':>8}"
                       for m in methods)
        rivals = [by[m].median for m in FEATURE_METHODS if m in by]
        ratio = by["ifmi"].median / min(rivals) if "ifmi" in by and rivals else float("nan")
        print(f"{mode:<9}{dataset:<{width}}{line}{ratio:>9.3f}")
    for mode in dict.fromkeys(s.mode for s in spreads):
        per_seed, on_medians, n = ifmi_misses(spreads, mode)
        if n:
            print(f"{mode}: iFMI above the better feature method (or failing a frame) on "
                  + ", ".join(f"{c} of {n} sets with seed {seed}" for seed, c in zip(seeds, per_seed))
                  + f"; {on_medians} of {n} on the medians")


def run_seeds(args: argparse.Namespace, argv) -> int:
    """Every dataset, mode, seed and method of the parsed command line; print and write the JSON."""
    base = EstimateConfig() if args.config is None else read_estimate_config(args.config)
    out = Path(args.out)
    rows = []
    for dataset, label in labelled_datasets(args.datasets):
        model = read_camera(calibration_path(dataset))
        for mode in dict.fromkeys(args.modes):
            for seed in args.seeds:
                seeded = replace(base, relative_pose=replace(base.relative_pose, seed=seed))
                config = resolved_config(mode_config(seeded, mode), model)
                rows += [{**run_method(dataset, method, mode, config, out / f"seed{seed}", label=label),
                          "seed": seed} for method in args.methods]
    spreads = seed_spreads(rows)
    print_spreads(spreads, args.seeds)
    out.mkdir(parents=True, exist_ok=True)
    summary = [{**asdict(s), "median": s.median, "spread": s.spread} for s in spreads]
    (out / "bench_seeds.json").write_text(json.dumps({"rows": rows, "summary": summary, "seeds": args.seeds,
                                                      "machine": machine_info(),
                                                      "argv": sys.argv if argv is None else argv}, indent=2))
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2],
                        help="relative_pose.seed values, each >= 0 (default: 0 1 2)")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--config", default=None, metavar="JSON",
                        help="start every method from this configuration (as ifmi estimate --config); "
                             "its relative_pose.seed is replaced by each of --seeds")
    parser.add_argument("--out", default="out/bench_seeds")
    args = parser.parse_args(argv)
    if any(seed < 0 for seed in args.seeds) or len(set(args.seeds)) != len(args.seeds):
        parser.error(f"--seeds: expected distinct integers >= 0, got {' '.join(map(str, args.seeds))}")
    try:
        return run_seeds(args, argv)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
