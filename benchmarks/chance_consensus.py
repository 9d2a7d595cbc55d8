"""How often the relative-pose back end accepts unrelated rays, with and without its chance check.

For every count ``n`` and angular threshold, ``--draws`` sets of ``n`` ray
pairs drawn uniformly on the sphere (no motion relates them; set ``s`` of
a cell is drawn with seed ``1000 + s`` and solved with RANSAC seed ``s``)
go through :func:`ifmi.backend.relative_pose.relative_pose_from_rays` twice: with
the default options, and with ``min_draw_success=0`` (the chance check
off). Every accepted pair is a wrong pose reported as a success.

Usage::

    python benchmarks/chance_consensus.py [--draws 40]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np

from ifmi.backend.relative_pose import RelativePoseOptions, relative_pose_from_rays

COUNTS = (20, 50, 100, 200, 500, 1000, 2000)
THRESHOLDS_RAD = (0.003, 0.01, 0.02)


def accepted_counts(n: int, threshold: float, draws: int) -> tuple[int, int, int]:
    """Accepted pairs of ``draws`` random sets with the check, without it, and the most inliers accepted without it."""
    with_check = without = most = 0
    for s in range(draws):
        rays = np.random.default_rng(1000 + s).normal(size=(2, n, 3))
        rays /= np.linalg.norm(rays, axis=2, keepdims=True)
        options = RelativePoseOptions(ransac_threshold_rad=threshold, seed=s)
        _, checked = relative_pose_from_rays(rays[0], rays[1], options=options)
        _, unchecked = relative_pose_from_rays(rays[0], rays[1], options=replace(options, min_draw_success=0.0))
        with_check += checked.success
        without += unchecked.success
        most = max(most, unchecked.n_inliers if unchecked.success else 0)
    return with_check, without, most


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=40, help="random sets per cell (default 40)")
    args = parser.parse_args(argv)
    if args.draws < 1:
        parser.error(f"--draws: expected an integer >= 1, got {args.draws}")
    totals = np.zeros(2, dtype=int)
    print(f"{'threshold':>9} {'n':>5} {'accepted':>9} {'unchecked':>9} {'most inliers':>12}")
    for threshold in THRESHOLDS_RAD:
        for n in COUNTS:
            with_check, without, most = accepted_counts(n, threshold, args.draws)
            totals += (with_check, without)
            print(f"{threshold:9.3f} {n:5d} {with_check:9d} {without:9d} {most:12d}", flush=True)
    cells = len(THRESHOLDS_RAD) * len(COUNTS) * args.draws
    print(f"accepted: {totals[0]} of {cells} with the chance check, {totals[1]} without")
    return 0


if __name__ == "__main__":
    sys.exit(main())
