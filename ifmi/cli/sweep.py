"""``ifmi sweep``: error and time over a grid of tile size x overlap, through Dask."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ifmi.errors import InputError
from ifmi.runtime.local_workers import (DEFAULT_CONNECT_TIMEOUT_S, DEFAULT_LOCAL_WORKERS, connect_timeout_argument,
                             max_local_workers, quiet_dask_logs)
from ifmi.tracking.methods import ignores_tiling
from ifmi.experiments.sweep import CELL_NAME_DIGITS, SweepOptions, cell_value_name, run_sweep, sweep_cells
from ifmi.spectral.tiling import TilingConfig
from ifmi.cli.estimate import chosen_method

__all__ = ["add_parser", "run"]


def _tile_size(text: str) -> float:
    value = float(text)
    try:
        TilingConfig(tile_size=value)  # the range every tile size is checked against
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def _overlap(text: str) -> float:
    value = float(text)
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"overlap must be in [0, 1), got {text}")
    return value


def _workers(text: str) -> int:
    """A local cluster's worker count: from 1 to :func:`ifmi.runtime.local_workers.max_local_workers`."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    limit = max_local_workers()
    if value > limit:
        raise argparse.ArgumentTypeError(f"expected at most {limit} workers (the CPUs this process may "
                                         f"use), got {value}")
    return value


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="tile size x overlap grid per dataset, run through Dask",
        description="Estimate and evaluate every (dataset, tile size, overlap) cell; one JSON "
                    "per cell in OUT/cells/ (failed cells recorded, finished ones skipped on a "
                    "rerun), then OUT/sweep.json, OUT/sweep.csv, OUT/sweep.parquet and "
                    "the heatmaps in OUT/heatmaps/ as one set (built beside OUT and swapped in when "
                    "complete). An existing --out must be an earlier sweep folder (your other "
                    "files in it are kept) or empty.",
    )
    p.add_argument("datasets", nargs="+", metavar="DATASET",
                   help="dataset folders with calib_results.txt, images/ and groundtruth.txt, or ROS bags "
                        "(.bag, .mcap, .db3, ROS 2 bag folders) with --calib and their ground truth on a topic")
    g = p.add_argument_group("ROS bags")
    g.add_argument("--calib", metavar="CALIB", help="calib_results.txt or camera.yaml of the bags' camera")
    g.add_argument("--topic", metavar="TOPIC", help="the bags' image topic (default: each bag's only one)")
    g.add_argument("--gt-topic", metavar="TOPIC",
                   help="the bags' ground-truth topic: PoseStamped, PoseWithCovarianceStamped, TransformStamped, "
                        "Odometry, or a tf topic with --gt-frames (default: each bag's only pose topic)")
    g.add_argument("--gt-frames", nargs=2, metavar=("PARENT", "CHILD"),
                   help="with a tf ground-truth topic: the pose of CHILD in PARENT")
    p.add_argument("--tile-size", nargs="+", type=_tile_size, required=True, metavar="N",
                   help="tile sides: pixels (>= 1) or fractions of the panorama width (< 1)")
    p.add_argument("--overlap", nargs="+", type=_overlap, required=True, metavar="F",
                   help="tile overlaps, fractions in [0, 1)")
    p.add_argument("--method", metavar="METHOD",
                   help="estimation method: a name that 'ifmi methods' lists, or "
                        "package.module:factory (default: the method of a --config run file, "
                        "else ifmi)")
    p.add_argument("--config", metavar="JSON",
                   help="base estimate configuration (EstimateConfig JSON, or an estimate's "
                        ".config.json, whose method is used unless --method is given); the grid "
                        "replaces its tiling")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="address of a running Dask scheduler, or 'synchronous' to run in this "
                        "process (default: a local cluster)")
    p.add_argument("--connect-timeout", type=connect_timeout_argument, default=DEFAULT_CONNECT_TIMEOUT_S,
                   metavar="SECONDS",
                   help=f"how long a --scheduler has to accept the connection and answer "
                        f"(default {DEFAULT_CONNECT_TIMEOUT_S:g})")
    p.add_argument("--workers", type=_workers, default=DEFAULT_LOCAL_WORKERS,
                   help="worker processes of the local cluster (default 2, 1 thread each; at most "
                        "the CPUs this process may use)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="sweep folder (new, empty or an earlier sweep)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _base_config(path: str | None, method: str | None) -> tuple[dict, str]:
    """The base configuration as a dict, and the method: ``method``, a run file's, or ifmi."""
    from ifmi.io.config import read_config_file
    from ifmi.tracking.methods import load_factory
    from ifmi.pipeline import EstimateConfig

    config_file = None if path is None else read_config_file(path)
    method = chosen_method(method, config_file)
    load_factory(method)  # an unknown or broken method fails before any cell runs
    config = EstimateConfig() if config_file is None else config_file.config
    return config.to_dict(), method


def _refuse_repeats(args) -> None:
    """A dataset (by resolved path), tile size or overlap given twice would be two rows of one cell."""
    seen = {}
    for d in args.datasets:
        folder = Path(d).resolve()
        if folder in seen:
            raise InputError(d, f"dataset given twice (also as {seen[folder]}); expected each dataset once")
        seen[folder] = d
    for option, values in (("--tile-size", args.tile_size), ("--overlap", args.overlap)):
        repeated = sorted({v for v in values if values.count(v) > 1})
        if repeated:
            raise InputError(option, f"value {repeated[0]:g} given twice; expected distinct values "
                                     f"(got {' '.join(f'{v:g}' for v in values)})")
        _refuse_one_name(option, values)


def _refuse_one_name(option: str, values: list[float]) -> None:
    """Two values a cell's name spells alike (:attr:`ifmi.experiments.sweep.SweepCell.cell_id`) would share its record."""
    named: dict[str, float] = {}
    for value in values:
        name = cell_value_name(value)
        if name in named:
            raise InputError(option, f"values {named[name]!r} and {value!r} both name the cell value {name} "
                                     f"(cells are named to {CELL_NAME_DIGITS} significant digits), so one "
                                     f"cell's record would stand for both; expected values that differ there")
        named[name] = value


def _check_inputs(args) -> dict | None:
    """Refuse missing datasets, folders without ground truth, and bags without --calib; the bag
    options as :func:`ifmi.experiments.sweep.sweep_cells` takes them (None when no dataset is a bag)."""
    from ifmi.io.bags import is_bag_path

    bags = [d for d in args.datasets if is_bag_path(d)]
    for d in args.datasets:
        if d in bags:
            if not Path(d).exists():
                raise InputError(d, "bag not found")
            continue
        if not Path(d).is_dir():
            raise InputError(d, "dataset folder not found")
        if not (Path(d) / "groundtruth.txt").is_file():
            raise InputError(Path(d) / "groundtruth.txt", "ground truth not found (a sweep needs it)")
    options = {"--calib": args.calib, "--topic": args.topic, "--gt-topic": args.gt_topic,
               "--gt-frames": args.gt_frames}
    if not bags:
        given = [option for option, value in options.items() if value is not None]
        if given:
            raise InputError(given[0], "is for ROS bags; no DATASET is one")
        return None
    if args.calib is None:
        raise InputError(bags[0], "a bag needs --calib CALIB (calib_results.txt or camera.yaml)")
    if not Path(args.calib).is_file():
        raise InputError(args.calib, "calibration file not found")
    return {"calib": str(Path(args.calib).resolve()), "topic": args.topic, "gt_topic": args.gt_topic,
            "gt_frames": args.gt_frames}


def run(args) -> int:
    bag_input = _check_inputs(args)
    _refuse_repeats(args)
    base_config, method = _base_config(args.config, args.method)
    if ignores_tiling(method):
        raise InputError("--method" if args.method else args.config,
                         f"method {method} does not use the tiling that a sweep varies (tile size and overlap "
                         f"are iFMI's): every cell would repeat one run; expected --method ifmi or a method "
                         f"of your own that reads config.ifmi.tiling")
    cells = sweep_cells([str(Path(d).resolve()) for d in args.datasets], method=method,
                        tile_sizes=args.tile_size, overlaps=args.overlap, bag_input=bag_input)
    if args.scheduler != "synchronous":
        quiet_dask_logs()  # a lost cluster is the one line of ClusterError
    options = SweepOptions(scheduler=args.scheduler, n_workers=args.workers,
                           progress=not args.no_progress, connect_timeout_s=args.connect_timeout)
    records = run_sweep(cells, out_dir=args.out, base_config=base_config, options=options)
    failed = [r for r in records if r.get("status") != "ok"]
    print(f"sweep: {len(records) - len(failed)} cells ok, {len(failed)} failed; "
          f"table {Path(args.out) / 'sweep.csv'}")
    for r in failed:
        print(f"  failed {r['cell_id']}: {r.get('error', '')}", file=sys.stderr)
    return 0 if not failed else 1
