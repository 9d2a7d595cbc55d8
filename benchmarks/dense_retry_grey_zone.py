"""Per pair: what the dense retry would do where the default does not run it.

iFMI re-registers a pair with a denser tile layout when at most
``recovery.dense_retry_fraction`` of the tiles pass (0.33). This benchmark
runs the default tracker unchanged and, on every pair whose kept share lies
in the grey zone above that, up to ``--upper`` (0.45), also computes the
correspondences the retry would give (the pipeline's stages before the pair
is settled change no frame state, so tracking is untouched). Both ray sets are solved with the shared back
end, and their rotation errors against the ground truth are recorded with
the model each one chose (rotation or 5-point) and its predicted error
(``RelativePoseInfo.rotation_sigma_rad``).

Printed per scene (the data set name without its ``_x<step>`` and ``_s<start>``) and mode: the pairs, the
RMS rotation error of the regular and the dense ray sets and of taking the
one with the smaller predicted error (mrad), and the share of pairs the
dense set is better on; then the same split by the models the two chose.
``OUT`` gets one JSON line per pair::

    python benchmarks/dense_retry_grey_zone.py DATA/sets/* --seeds 0 1 2 --out grey.jsonl
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path
from unittest import mock

import numpy as np

from bench_methods import MODES, mode_config
from ifmi.io.tum import read_tum
from ifmi.pipeline import EstimateConfig, estimate_dataset
from ifmi.relative_pose import relative_pose_from_rays
from ifmi.rotations import geodesic_angle
from ifmi import pair_pipeline
from ifmi.spectral_front_end import IfmiFrontEnd


@dataclass(frozen=True)
class PairSolve:
    """One ray set's relative pose against the ground truth (radians); ``model`` is '' on failure."""

    error: float
    sigma: float
    model: str


class GreyZoneRecorder(IfmiFrontEnd):
    """iFMI's front end that also solves the dense retry's rays on grey-zone pairs (see module doc).

    ``rotations_0k`` are the ground-truth ``R_0k`` of the frames in the order
    they are prepared; ``rows`` collects one dict per grey-zone pair.
    """

    def __init__(self, model, config, *, rotations_0k: np.ndarray, upper: float):
        super().__init__(model, config.ifmi)
        self.pose_options = config.relative_pose
        self.rotations_0k = rotations_0k
        self.upper = upper
        self.rows: list = []
        self._frame_of: dict = {}

    def prepare(self, image):
        state = super().prepare(image)
        self._frame_of[id(state)] = (len(self._frame_of), state)  # the state is kept: its id stays unique
        return state

    def solve_pair(self, state_a, state_b, *, prior_rotation, solve):
        if prior_rotation is not None:
            self._record(state_a, state_b, prior_rotation)
        return super().solve_pair(state_a, state_b, prior_rotation=prior_rotation, solve=solve)

    def _record(self, state_a, state_b, prior_rotation) -> None:
        """A row for a grey-zone pair: its first registration's rays and the dense retry's, each solved
        (the pipeline's stages change no frame state until the pair is settled)."""
        regular = pair_pipeline.matched(self, state_a, state_b, prior_rotation).correspondences
        kept = regular.diagnostics.get("n_tiles_kept")
        count = self.layout.count
        retry = self.config.recovery
        if (not regular.success or kept is None or "n_tiles_kept_dense" in regular.diagnostics
                or not retry.dense_retry_fraction * count < kept <= self.upper * count):
            return
        default_config = self.config
        self.config = replace(default_config, recovery=replace(retry, dense_retry_fraction=self.upper))
        try:
            dense = pair_pipeline.matched(self, state_a, state_b, prior_rotation).correspondences
        finally:
            self.config = default_config
        a, b = self._frame_of[id(state_a)][0], self._frame_of[id(state_b)][0]
        truth = self.rotations_0k[a].T @ self.rotations_0k[b]
        self.rows.append({"a": a, "b": b, "kept": kept, "count": count,
                          "regular": self._solve(regular, truth).__dict__,
                          "dense": self._solve(dense, truth).__dict__})

    def _solve(self, corr, truth: np.ndarray) -> PairSolve:
        pose, info = relative_pose_from_rays(corr.rays_a, corr.rays_b, options=self.pose_options,
                                             rays_per_measurement=corr.rays_per_measurement)
        if not info.success:
            return PairSolve(float("nan"), float("nan"), "")
        return PairSolve(float(geodesic_angle(pose.rotation, truth)), float(info.rotation_sigma_rad), info.model)


def grey_zone_rows(dataset: str, *, mode: str, seed: int, upper: float) -> tuple:
    """The grey-zone pairs (list of dicts) of one iFMI run with default options but
    ``relative_pose.seed``, and the run's ``SequenceEstimate`` (the default's)."""
    rotations_0k = read_tum(Path(dataset) / "groundtruth.txt").rotations
    base = EstimateConfig()
    config = mode_config(replace(base, relative_pose=replace(base.relative_pose, seed=seed)), mode)
    made = []

    def front_end(method, model, resolved):
        made.append(GreyZoneRecorder(model, resolved, rotations_0k=rotations_0k, upper=upper))
        return made[-1]

    with mock.patch("ifmi.pipeline.create_front_end", front_end):
        estimate = estimate_dataset(dataset, method="ifmi", config=config, prefetch=False)
    name = Path(dataset).name
    return [{"dataset": name, "mode": mode, "seed": seed, **row} for row in made[0].rows], estimate


def print_summary(rows: list) -> None:
    """RMS errors (mrad) per scene and mode, then per pair of chosen models."""
    solved = [r for r in rows if r["regular"]["model"] and r["dense"]["model"]]
    groups = defaultdict(list)
    for r in solved:
        scene = re.sub(r"_x\d+(_s\d+)?", "", r["dataset"])
        groups[(r["mode"], scene, "all")].append(r)
        groups[(r["mode"], scene, f"{r['regular']['model']} / {r['dense']['model']}")].append(r)
    print(f"{'mode':9}{'scene':14}{'models (regular / dense)':26}{'pairs':>6}{'regular':>9}{'dense':>9}"
          f"{'by sigma':>9}{'dense better':>13}")
    for (mode, scene, models), group in sorted(groups.items()):
        regular = np.array([r["regular"]["error"] for r in group])
        dense = np.array([r["dense"]["error"] for r in group])
        by_sigma = np.where([r["dense"]["sigma"] < r["regular"]["sigma"] for r in group], dense, regular)
        rms = [1e3 * float(np.sqrt(np.mean(e ** 2))) for e in (regular, dense, by_sigma)]
        print(f"{mode:9}{scene:14}{models:26}{len(group):6d}{rms[0]:9.2f}{rms[1]:9.2f}{rms[2]:9.2f}"
              f"{np.mean(dense < regular):13.2f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--upper", type=float, default=0.45,
                        help="top of the grey zone, a share of the tiles (default 0.45)")
    parser.add_argument("--out", type=Path, required=True, help="JSON lines file, one row per pair")
    args = parser.parse_args(argv)
    rows = []
    for seed in args.seeds:
        for mode in args.modes:
            for dataset in args.datasets:
                rows += grey_zone_rows(dataset, mode=mode, seed=seed, upper=args.upper)[0]
    args.out.write_text("".join(json.dumps(r) + "\n" for r in rows))
    print_summary(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
