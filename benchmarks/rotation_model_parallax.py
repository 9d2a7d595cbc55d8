"""Does a pair's 5-point rotation tell when the rotation model has absorbed parallax?

When the shared back end chooses the rotation model for a pair, it has fitted
the 5-point model as well (to compare them by GRIC). Under translation the
rotation model's rotation can take up part of the parallax; the 5-point
rotation should not. This benchmark runs iFMI's default tracker on each
data set (frame mode, RANSAC seed 0) and records, for every pair the back
end solves, the rotation of both fits, their errors against the ground
truth, and the angle between them over the rotation model's noise estimate
(``d / noise``). The back end is observed, not changed: its private fitting
steps are wrapped to keep their results.

Printed per scene (data set name without ``_x<step>`` and ``_s<start>``),
over the pairs where the rotation model was chosen: how many, the RMS
error of each fit's rotation (mrad), the median and 90th percentile of
``d / noise``, and the share where the 5-point rotation is the better one.
If ``d / noise`` were larger on translated scenes than on pure rotations, it
could send those pairs to the 5-point model::

    python benchmarks/rotation_model_parallax.py DATA/sets/*
"""

from __future__ import annotations

import argparse
import re
import sys
from collections import defaultdict
from pathlib import Path
from unittest import mock

import numpy as np

from bench_methods import mode_config
from ifmi import relative_pose as back_end
from ifmi.io.tum import read_tum
from ifmi.pipeline import EstimateConfig, estimate_dataset
from ifmi.rotations import geodesic_angle
from ifmi.spectral_front_end import IfmiFrontEnd


class PairNamingFrontEnd(IfmiFrontEnd):
    """iFMI's front end that tells ``pair`` (``[a, b]``, prepare order) which frames it matches."""

    def __init__(self, model, config, pair: list):
        super().__init__(model, config)
        self.pair = pair
        self._frame_of: dict = {}

    def prepare(self, image):
        state = super().prepare(image)
        self._frame_of[id(state)] = (len(self._frame_of), state)  # the state is kept: its id stays unique
        return state

    def correspondences(self, state_a, state_b, **options):
        self.pair[:] = [self._frame_of[id(state_a)][0], self._frame_of[id(state_b)][0]]
        return super().correspondences(state_a, state_b, **options)


def model_fits(dataset: str) -> list:
    """One dict per back-end solve of a default iFMI run (the last solve of a pair wins)."""
    rotations_0k = read_tum(Path(dataset) / "groundtruth.txt").rotations
    pair, fits = [], {}
    model_selection = back_end._model_selection

    def observed_choice(rays_a, rays_b, rotation_fit, five_point, *args):
        selection = model_selection(rays_a, rays_b, rotation_fit, five_point, *args)
        truth = rotations_0k[pair[0]].T @ rotations_0k[pair[1]]
        rotation, rotation_5pt, noise = rotation_fit[0], five_point[0], rotation_fit[3]
        fits[tuple(pair)] = {"chosen": "5pt" if selection.gric_5pt < selection.gric_rotation else "rotation",
                             "error_rotation": float(geodesic_angle(rotation, truth)),
                             "error_5pt": float(geodesic_angle(rotation_5pt, truth)),
                             "disagreement": float(geodesic_angle(rotation, rotation_5pt) / noise)}
        return selection

    with mock.patch.object(back_end, "_model_selection", observed_choice), \
         mock.patch("ifmi.pipeline.create_front_end",
                    lambda method, model, config: PairNamingFrontEnd(model, config.ifmi, pair)):
        estimate_dataset(dataset, method="ifmi", config=mode_config(EstimateConfig(), "frame"), prefetch=False)
    return [{"dataset": Path(dataset).name, "a": a, "b": b, **fit} for (a, b), fit in fits.items()]


def print_summary(rows: list) -> None:
    """Per scene, over the pairs solved with the rotation model (see module doc)."""
    groups = defaultdict(list)
    for r in rows:
        groups[re.sub(r"_x\d+(_s\d+)?", "", r["dataset"])].append(r)
    print(f"{'scene':14}{'rotation / all':>15}{'RMS rotation':>13}{'RMS 5pt':>9}{'d/noise 50%':>12}"
          f"{'90%':>7}{'5pt better':>11}")
    for scene, group in sorted(groups.items()):
        chosen = [r for r in group if r["chosen"] == "rotation"]
        if not chosen:
            print(f"{scene:14}{f'0 / {len(group)}':>15}")
            continue
        e_rotation = np.array([r["error_rotation"] for r in chosen])
        e_5pt = np.array([r["error_5pt"] for r in chosen])
        ratio = np.array([r["disagreement"] for r in chosen])
        print(f"{scene:14}{f'{len(chosen)} / {len(group)}':>15}{1e3 * np.sqrt(np.mean(e_rotation ** 2)):13.2f}"
              f"{1e3 * np.sqrt(np.mean(e_5pt ** 2)):9.2f}{np.median(ratio):12.2f}{np.percentile(ratio, 90):7.2f}"
              f"{np.mean(e_5pt < e_rotation):11.2f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    args = parser.parse_args(argv)
    print_summary([row for dataset in args.datasets for row in model_fits(dataset)])
    return 0


if __name__ == "__main__":
    sys.exit(main())
