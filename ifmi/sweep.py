"""Sweeps of the iFMI tiling parameters (tile size x overlap) with Dask.

Each cell of the grid (dataset, method, tile size, overlap) estimates the
dataset's trajectory, evaluates it against its ``groundtruth.txt`` and writes
one JSON record atomically to ``OUT/cells/<cell id>.json``. A failed cell is
recorded with ``status: "failed"`` and the error message; a rerun skips every
cell already recorded as ``"ok"`` with the same base configuration (failed
cells are tried again). At the end
the records are gathered into one table (``sweep.csv``, ``sweep.parquet``)
and heatmaps per dataset and metric (``heatmaps/*.png``).

Layout of ``OUT``::

    sweep.json                    grid, method, base configuration
    cells/<id>.json               one record per cell
    runs/<id>/estimate.txt        the cell's estimate (+ side files)
    runs/<id>/eval/               the cell's evaluation folder
    sweep.csv, sweep.parquet      all records
    heatmaps/<dataset>__<metric>.png
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Sequence

from .io.atomic import atomic_write_json

__all__ = [
    "SweepCell",
    "SweepOptions",
    "METRICS",
    "sweep_cells",
    "config_with_tiling",
    "run_cell",
    "run_sweep",
    "read_cells",
    "write_sweep_table",
    "config_digest",
]

# Allocations up to this size stay on the heap in local-cluster workers (see run_sweep).
_WORKER_MMAP_THRESHOLD_BYTES = 64 * 2**20

# Table columns drawn as heatmaps, with their display names.
METRICS = {
    "rmse_mean_rad": "mean roll/pitch/yaw RMSE [rad]",
    "rmse_geodesic_rad": "geodesic RMSE [rad]",
    "time_per_frame_s": "time per frame [s]",
    "failures": "failed frames",
}


# Leading columns of the sweep table, in this order; any others follow alphabetically.
COLUMN_ORDER = ("dataset", "method", "tile_size", "overlap", "status", "rmse_roll_rad",
                "rmse_pitch_rad", "rmse_yaw_rad", "rmse_mean_rad", "rmse_geodesic_rad",
                "max_geodesic_rad", "rmse_relative_rad", "time_per_frame_s", "failures", "frames",
                "wall_s", "error", "cell_id")


@dataclass(frozen=True)
class SweepCell:
    """One grid cell.

    Attributes
    ----------
    dataset : str
        DATASET folder (calib_results.txt, images/, groundtruth.txt).
    method : str
        Registered estimation method.
    tile_size : float
        Tile side: pixels when >= 1, fraction of the panorama width when < 1.
    overlap : float
        Tile overlap fraction in [0, 1).
    """

    dataset: str
    method: str
    tile_size: float
    overlap: float

    @property
    def dataset_name(self) -> str:
        return Path(self.dataset).name or str(self.dataset)

    @property
    def cell_id(self) -> str:
        """File-name-safe identifier, unique within a sweep."""
        raw = f"{self.dataset_name}__{self.method}__tile{self.tile_size:g}__overlap{self.overlap:g}"
        return re.sub(r"[^A-Za-z0-9_.=-]", "_", raw)


@dataclass(frozen=True)
class SweepOptions:
    """How a sweep runs.

    Attributes
    ----------
    scheduler : str or None
        ``None``: start a ``dask.distributed.LocalCluster``; ``"synchronous"``:
        run cells in this process through Dask's synchronous scheduler;
        otherwise the address of a running Dask scheduler.
    n_workers : int
        Worker processes of the local cluster.
    threads_per_worker : int
        Threads per local worker.
    progress : bool
        Show a progress bar on stderr.
    connect_timeout_s : float
        Seconds to wait for a remote scheduler before giving up.
    """

    scheduler: str | None = None
    n_workers: int = 2
    threads_per_worker: int = 1
    progress: bool = True
    connect_timeout_s: float = 10.0


def sweep_cells(datasets: Sequence[str], *, method: str, tile_sizes: Sequence[float],
                overlaps: Sequence[float]) -> list[SweepCell]:
    """All cells of the grid, dataset-major."""
    return [SweepCell(str(d), method, float(t), float(o))
            for d in datasets for t in tile_sizes for o in overlaps]


def config_with_tiling(config, *, tile_size: float, overlap: float):
    """Copy of an :class:`ifmi.pipeline.EstimateConfig` with the iFMI tiling replaced."""
    from .tiling import TilingConfig

    tiling = TilingConfig(tile_size=tile_size, overlap=overlap)
    return replace(config, ifmi=replace(config.ifmi, tiling=tiling))


def _cell_path(out_dir: Path, cell: SweepCell) -> Path:
    return out_dir / "cells" / f"{cell.cell_id}.json"


def config_digest(base_config: dict) -> str:
    """Short SHA-256 of a configuration dict (canonical JSON)."""
    text = json.dumps(base_config, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _finished(out_dir: Path, cell: SweepCell, digest: str) -> bool:
    """True when the cell's record is ``ok`` and was made with the same base configuration."""
    path = _cell_path(out_dir, cell)
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return record.get("status") == "ok" and record.get("config_digest") == digest


def run_cell(cell: SweepCell, *, out_dir: str, base_config: dict) -> dict:
    """Estimate, evaluate and record one cell; never raises for a failing cell.

    Parameters
    ----------
    cell : SweepCell
    out_dir : str, keyword-only
        Sweep folder.
    base_config : dict, keyword-only
        :meth:`ifmi.pipeline.EstimateConfig.to_dict` of the configuration
        whose tiling the cell replaces.

    Returns
    -------
    dict
        The record written to ``cells/<id>.json``.
    """
    out = Path(out_dir)
    record = {"cell_id": cell.cell_id, "dataset": cell.dataset_name, "dataset_path": cell.dataset,
              "method": cell.method, "tile_size": cell.tile_size, "overlap": cell.overlap,
              "config_digest": config_digest(base_config)}
    start = time.perf_counter()
    try:
        from .evaluation import evaluate_files
        from .io.results import write_estimate_run
        from .pipeline import EstimateConfig, estimate_dataset

        gt = Path(cell.dataset) / "groundtruth.txt"
        if not gt.is_file():
            raise FileNotFoundError(f"{gt}: ground truth not found")
        config = config_with_tiling(EstimateConfig.from_dict(base_config),
                                    tile_size=cell.tile_size, overlap=cell.overlap)
        estimate = estimate_dataset(cell.dataset, method=cell.method, config=config)
        run_dir = out / "runs" / cell.cell_id
        est_path = run_dir / "estimate.txt"
        write_estimate_run(est_path, estimate, dataset_dir=cell.dataset)
        meta = evaluate_files(gt, est_path, out_dir=run_dir / "eval")
        s = meta["summary"]
        record.update({
            "status": "ok", "error": "",
            "rmse_roll_rad": s["axes"]["roll"]["rmse"],
            "rmse_pitch_rad": s["axes"]["pitch"]["rmse"],
            "rmse_yaw_rad": s["axes"]["yaw"]["rmse"],
            "rmse_mean_rad": s["mean_rmse"],
            "rmse_geodesic_rad": s["geodesic"]["rmse"],
            "max_geodesic_rad": s["geodesic"]["max"],
            "rmse_relative_rad": s["relative_geodesic"]["rmse"],
            "time_per_frame_s": (s["time"] or {}).get("mean_s"),
            "failures": (s["failures"] or {}).get("count"),
            "frames": s["frames"]["estimate"],
            "evaluation": str((run_dir / "eval").relative_to(out)),
        })
    except Exception as exc:  # a failing cell is recorded, never lost
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        record.update({"status": "failed", "error": f"{type(exc).__name__}: {message}",
                       "traceback": traceback.format_exc(limit=6)})
    record["wall_s"] = time.perf_counter() - start
    atomic_write_json(_cell_path(out, cell), record)
    return record


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, disable=not enabled, file=sys.stderr, unit="cell", desc="sweep")


def run_sweep(cells: Iterable[SweepCell], *, out_dir: str | os.PathLike, base_config: dict,
              options: SweepOptions = SweepOptions()) -> list[dict]:
    """Run every unfinished cell through Dask and write the table and heatmaps.

    Parameters
    ----------
    cells : iterable of SweepCell
    out_dir : path, keyword-only
    base_config : dict, keyword-only
        ``EstimateConfig.to_dict()`` shared by all cells (tiling replaced per cell).
    options : SweepOptions, keyword-only

    Returns
    -------
    list of dict
        The records of all cells of this grid (finished earlier or now).
    """
    out = Path(out_dir)
    cells = list(cells)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "sweep.json", {
        "kind": "ifmi-sweep",
        "cells": [c.__dict__ for c in cells],
        "base_config": base_config,
        "scheduler": options.scheduler or "local-cluster",
    })
    digest = config_digest(base_config)
    pending = [c for c in cells if not _finished(out, c, digest)]
    skipped = len(cells) - len(pending)
    if skipped and options.progress:
        print(f"sweep: {skipped} of {len(cells)} cells already finished, skipped", file=sys.stderr)
    if pending:
        _execute(pending, out_dir=str(out), base_config=base_config, options=options)
    records = read_cells(out, cells)
    write_sweep_table(out, records)
    return records


def _execute(cells: list[SweepCell], *, out_dir: str, base_config: dict,
             options: SweepOptions) -> None:
    import dask

    bar = _progress(len(cells), options.progress)
    try:
        if options.scheduler == "synchronous":
            for cell in cells:
                task = dask.delayed(run_cell)(cell, out_dir=out_dir, base_config=base_config)
                task.compute(scheduler="synchronous")
                bar.update(1)
            return
        from dask.distributed import Client, LocalCluster, as_completed

        cluster = None
        if options.scheduler is None:
            # Dask's nanny sets MALLOC_TRIM_THRESHOLD_ in the workers it spawns, which turns
            # off glibc's adaptive mmap threshold: every large temporary array is then mapped
            # and zeroed afresh, and a cell's time per frame doubled (25 against 13 ms on a
            # 512 x 512 sequence). A fixed large mmap threshold keeps such arrays on the heap.
            with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_":
                                  _WORKER_MMAP_THRESHOLD_BYTES}):
                cluster = LocalCluster(n_workers=options.n_workers,
                                       threads_per_worker=options.threads_per_worker,
                                       processes=True, dashboard_address=":0")
            client = Client(cluster)
        else:
            try:
                client = Client(options.scheduler, timeout=f"{options.connect_timeout_s}s")
            except (OSError, TimeoutError, ValueError) as exc:
                from .errors import InputError

                raise InputError(options.scheduler, f"cannot connect to a Dask scheduler "
                                 f"({type(exc).__name__})") from None
        try:
            futures = [client.submit(run_cell, cell, out_dir=out_dir, base_config=base_config,
                                     pure=False, key=f"sweep-{cell.cell_id}-{time.time_ns()}")
                       for cell in cells]
            for future in as_completed(futures):
                future.result()
                bar.update(1)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    finally:
        bar.close()


def read_cells(out_dir: str | os.PathLike, cells: Sequence[SweepCell] | None = None) -> list[dict]:
    """Records of ``cells`` (default: every ``cells/*.json``) in grid order; missing ones skipped."""
    out = Path(out_dir)
    if cells is None:
        paths = sorted((out / "cells").glob("*.json"))
    else:
        paths = [_cell_path(out, c) for c in cells]
    records = []
    for path in paths:
        try:
            records.append(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError):
            continue
    return records


def write_sweep_table(out_dir: str | os.PathLike, records: list[dict]) -> None:
    """Write ``sweep.csv``, ``sweep.parquet`` and the heatmaps of ``records``."""
    import io

    import pandas as pd

    from .io.atomic import atomic_write_bytes, atomic_write_text
    from .plots import sweep_heatmap

    out = Path(out_dir)
    table = pd.DataFrame([{k: v for k, v in r.items() if k != "traceback"} for r in records])
    first = [c for c in COLUMN_ORDER if c in table.columns]
    table = table[first + sorted(c for c in table.columns if c not in first)]
    atomic_write_text(out / "sweep.csv", table.to_csv(index=False))
    buf = io.BytesIO()
    table.to_parquet(buf, index=False)
    atomic_write_bytes(out / "sweep.parquet", buf.getvalue())
    if table.empty or "status" not in table:
        return
    ok = table[table["status"] == "ok"]
    for (dataset, method), group in ok.groupby(["dataset", "method"]):
        for metric, label in METRICS.items():
            if metric not in group or group[metric].isna().all():
                continue
            sweep_heatmap(group, metric=metric, label=label,
                          title=f"{dataset} ({method}): {label}",
                          path=out / "heatmaps" / f"{dataset}__{method}__{metric}.png")
