"""How much one frame pair's dense-retry estimate rests on single tiles.

Registers frames K-1 and K of a dataset with the dense retry's layout, at
the coarse stage's rotation (searched from the identity, as for a
sequence's first pair) or at the true rotation, and solves the relative
pose from all kept tiles and from every set that leaves one tile out.
Printed: the prior's error, the kept tiles, the rotation error of the
estimate with all tiles and the median and largest error over the
leave-one-out sets (radians). When the leave-one-out median is far from the
all-tiles error, the pair's figure is luck: any change to which tiles the
retry registers moves it::

    python benchmarks/retry_pair_stability.py /work/data/sets36/office_trans_x10 --pair 1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bench_methods import mode_config
from ifmi.flow import flow_from_placements, flow_sample_points
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum
from ifmi.pipeline import EstimateConfig, resolved_config
from ifmi.relative_pose import relative_pose_from_rays
from ifmi.rotations import geodesic_angle
from ifmi.spectral_front_end import _POINT_SPREAD, IfmiFrontEnd


def pose_errors(rays_a: np.ndarray, rays_b: np.ndarray, per_tile: int, truth: np.ndarray, options) -> tuple:
    """Rotation error (rad) of the pose from all tiles, and of each leave-one-tile-out set."""
    def error(keep):
        rows = np.repeat(keep, per_tile)
        pose, info = relative_pose_from_rays(rays_a[rows], rays_b[rows], options=options,
                                             rays_per_measurement=per_tile)
        return float(geodesic_angle(pose.rotation, truth)) if info.success else float("nan")

    tiles = len(rays_a) // per_tile
    every = np.ones(tiles, dtype=bool)
    return error(every), [error(np.arange(tiles) != left_out) for left_out in range(tiles)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("--pair", type=int, required=True, help="frame K: the pair is K-1, K")
    args = parser.parse_args(argv)
    data = read_dataset(args.dataset)
    if not 1 <= args.pair < len(data.image_paths):
        parser.error(f"--pair: expected 1..{len(data.image_paths) - 1}, got {args.pair}")
    images = list(data.iter_images())
    config = resolved_config(mode_config(EstimateConfig(), "frame"), data.model)
    ifmi = config.ifmi
    truth_poses = read_tum(Path(args.dataset) / "groundtruth.txt").rotations
    truth = truth_poses[args.pair - 1].T @ truth_poses[args.pair]
    front_end = IfmiFrontEnd(data.model, ifmi)
    state_a, state_b = front_end.prepare(images[args.pair - 1]), front_end.prepare(images[args.pair])
    coarse = front_end.global_stage.estimate(state_a.coarse_panorama, state_b.coarse_panorama,
                                             priors=(np.eye(3), None)).rotation
    points = flow_sample_points(front_end.dense_layout.tile_size, points_per_tile=ifmi.rays.points_per_tile,
                                spread=_POINT_SPREAD)
    for name, prior in (("coarse", coarse), ("truth", truth)):
        offsets_a, linear_a, placed = front_end.register_dense(state_a, state_b, rotation=prior)
        pairs = flow_from_placements(offsets_a, linear_a, placed.offsets, placed.linear, placed.valid,
                                     front_end.mapping, points=points, tile_size=front_end.dense_layout.tile_size)
        whole, left_out = pose_errors(pairs.rays_a, pairs.rays_b, len(points), truth, config.relative_pose)
        print(f"prior {name:<7} error {geodesic_angle(prior, truth):.4f}  tiles kept {int(placed.valid.sum()):3d}  "
              f"estimate error {whole:.4f}  leave-one-out median {np.nanmedian(left_out):.4f} "
              f"max {np.nanmax(left_out):.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
