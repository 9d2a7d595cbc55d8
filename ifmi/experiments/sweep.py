"""Sweeps of the iFMI tiling parameters (tile size x overlap) with Dask.

Each cell of the grid (dataset, method, tile size, overlap) estimates the
dataset's trajectory, evaluates it against its ``groundtruth.txt`` (a ROS
bag: against its ground-truth topic, the frames read with the calibration
the cell names) and writes one JSON record atomically to
``OUT/cells/<cell id>.json``. A cell is keyed
by its dataset's identity: the resolved folder (in the cell id, so two
datasets of one name never share a cell) and a digest of its content
(``meta.json``, calibration, ground truth, and the image files' names,
sizes and modification times). A failed cell is recorded with ``status:
"failed"`` and the error message; a rerun skips every cell already recorded
as ``"ok"`` with the same base configuration and dataset content (failed
cells, changed datasets and unreadable records are computed again). At the end
the records are gathered into one table (``sweep.csv``, ``sweep.parquet``)
and heatmaps per dataset and metric (``heatmaps/*.png``).

The result set (:data:`SWEEP_RESULTS`: ``sweep.json``, the table and the
heatmaps) is written as one set: built in a temporary folder beside ``OUT``
and swapped in when complete (:func:`~ifmi.io.atomic.write_folder`), so a
failure leaves the previous set intact and a new grid's set never holds
heatmaps of an earlier one. The cell records and runs (resumed from) and
files of the user's in ``OUT`` are kept. An existing ``OUT`` must be new,
empty, or a sweep folder (:func:`is_sweep_dir`), checked before any work; a
new folder gets its ``sweep.json`` at once, so that an interrupted first
sweep is recognised and resumed.

Layout of ``OUT``::

    sweep.json                    grid, method, base configuration
    cells/<id>.json               one record per cell
    runs/<id>/estimate.txt        the cell's estimate (+ side files)
    runs/<id>/eval/               the cell's evaluation folder
    sweep.csv, sweep.parquet      all records
    heatmaps/<dataset>__<method>__<metric>.png
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import sys
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Sequence

from ifmi.evaluation.dataset_names import dataset_folder_id, dataset_labels, display_name, resolved_folder
from ifmi.errors import ClusterError, InputError, OutputError, json_excerpt, one_line
from ifmi.io.atomic import (atomic_write_bytes, atomic_write_json, atomic_write_text, check_output_folder,
                        folder_of_kind, probe_writable, write_folder)
from ifmi.runtime.local_workers import DEFAULT_CONNECT_TIMEOUT_S, cluster_loss, scheduler_client

__all__ = [
    "SweepCell",
    "SweepOptions",
    "CELL_NAME_DIGITS",
    "cell_value_name",
    "METRICS",
    "SWEEP_KIND",
    "SWEEP_RESULTS",
    "is_sweep_dir",
    "sweep_cells",
    "config_with_tiling",
    "run_cell",
    "run_sweep",
    "read_cells",
    "sweep_records",
    "records_table",
    "read_cell_record",
    "write_sweep_table",
    "config_digest",
    "dataset_digest",
    "cell_input_digest",
    "dataset_labels",
]

# Significant digits of a tile size or overlap in a cell's name (those of Python's "g" format, which
# named the cells of earlier sweeps); values that agree to them share one cell record.
CELL_NAME_DIGITS = 6
# Hex digits of the digest that identifies a dataset's content.
_ID_DIGITS = 12
# Allocations up to this size stay on the heap in local-cluster workers (see run_sweep).
_WORKER_MMAP_THRESHOLD_BYTES = 64 * 2**20
# Marker stored in sweep.json so that sweep folders can be recognised.
SWEEP_KIND = "ifmi-sweep"
# Keys of every sweep.json, also of one written without SWEEP_KIND.
_SWEEP_KEYS = ("cells", "base_config", "scheduler")
# Entries of a sweep folder written as one set at the end of a sweep (an old one is dropped
# even when the new set lacks it); anything else in the folder is kept: cells/ and runs/,
# which a rerun resumes from, and files of the user's.
SWEEP_RESULTS = ("sweep.json", "sweep.csv", "sweep.parquet", "heatmaps")

# Table columns drawn as heatmaps, with their display names.
METRICS = {
    "rmse_mean_rad": "mean roll/pitch/yaw RMSE [rad]",
    "rmse_geodesic_rad": "geodesic RMSE [rad]",
    "time_per_frame_s": "time per frame [s]",
    "failures": "failed frames",
}


# Leading columns of the sweep table, in this order; any others follow alphabetically.
COLUMN_ORDER = ("dataset", "dataset_path", "method", "tile_size", "overlap", "status", "rmse_roll_rad",
                "rmse_pitch_rad", "rmse_yaw_rad", "rmse_mean_rad", "rmse_geodesic_rad",
                "max_geodesic_rad", "rmse_relative_rad", "time_per_frame_s", "failures", "frames",
                "wall_s", "error", "cell_id")


def cell_value_name(value: float) -> str:
    """A tile size or overlap as a cell's name spells it (:data:`CELL_NAME_DIGITS` significant digits)."""
    return f"{value:.{CELL_NAME_DIGITS}g}"


@dataclass(frozen=True)
class SweepCell:
    """One grid cell.

    Attributes
    ----------
    dataset : str
        DATASET folder (calib_results.txt, images/, groundtruth.txt).
    method : str
        Estimation method (a name of ``ifmi methods`` or ``package.module:factory``).
    tile_size : float
        Tile side: pixels when >= 1, fraction of the panorama width when < 1.
    overlap : float
        Tile overlap fraction in [0, 1).
    label : str or None
        Name of the dataset in tables and figures (default its folder name);
        :func:`sweep_cells` makes it unique within a sweep.
    calib : str or None
        For a ROS bag as ``dataset`` (:func:`ifmi.io.bags.is_bag_path`):
        the camera's calibration file; None for a dataset folder.
    topic, gt_topic : str or None
        A bag's image topic and ground-truth topic (None: its only one).
    gt_frames : (str, str) or None
        ``(parent, child)`` of a tf ground-truth topic.
    """

    dataset: str
    method: str
    tile_size: float
    overlap: float
    label: str | None = None
    calib: str | None = None
    topic: str | None = None
    gt_topic: str | None = None
    gt_frames: tuple | None = None

    @property
    def dataset_name(self) -> str:
        return self.label or Path(self.dataset).name or str(self.dataset)

    @property
    def cell_id(self) -> str:
        """File-name-safe identifier, unique per dataset folder (resolved path), method and tiling."""
        raw = f"{self.method}__tile{cell_value_name(self.tile_size)}__overlap{cell_value_name(self.overlap)}"
        return f"{dataset_folder_id(self.dataset)}__{re.sub(r'[^A-Za-z0-9_.=-]', '_', raw)}"


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
        Worker processes of the local cluster, >= 1.
    threads_per_worker : int
        Threads per local worker, >= 1.
    progress : bool
        Show a progress bar on stderr.
    connect_timeout_s : float
        Seconds a remote scheduler has to accept the connection and answer, > 0
        (:func:`ifmi.runtime.local_workers.scheduler_client`).
    """

    scheduler: str | None = None
    n_workers: int = 2
    threads_per_worker: int = 1
    progress: bool = True
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S

    def __post_init__(self) -> None:
        if self.n_workers < 1 or self.threads_per_worker < 1:
            raise ValueError(f"expected n_workers >= 1 and threads_per_worker >= 1, got "
                             f"{self.n_workers} and {self.threads_per_worker}")
        if not self.connect_timeout_s > 0:
            raise ValueError(f"expected connect_timeout_s > 0, got {self.connect_timeout_s}")


def sweep_cells(datasets: Sequence[str], *, method: str, tile_sizes: Sequence[float],
                overlaps: Sequence[float], bag_input: dict | None = None) -> list[SweepCell]:
    """All cells of the grid, dataset-major; datasets labelled distinctly (:func:`dataset_labels`).

    ``bag_input`` (``calib``, ``topic``, ``gt_topic``, ``gt_frames``; see
    :class:`SweepCell`) is given to the cells of the datasets that are ROS bags.
    """
    from ifmi.io.bags import is_bag_path

    labels = dataset_labels([str(d) for d in datasets])
    bag_fields = dict(bag_input or {})
    if bag_fields.get("gt_frames") is not None:
        bag_fields["gt_frames"] = tuple(bag_fields["gt_frames"])
    return [SweepCell(str(d), method, float(t), float(o), label=labels[resolved_folder(d)],
                      **(bag_fields if is_bag_path(d) else {}))
            for d in datasets for t in tile_sizes for o in overlaps]


def _file_stamps(h, paths) -> None:
    """Add the names, sizes and modification times of ``paths`` (os.DirEntry or Path) to ``h``."""
    for entry in paths:
        try:
            st = entry.stat()
        except OSError:
            continue
        h.update(os.fsencode(entry.name) + f"\0{st.st_size}\0{st.st_mtime_ns}\0".encode())


def _bag_digest(cell: SweepCell) -> str:
    """Short digest of a bag cell's input: the bag's files (names, sizes, times), the calibration's
    bytes and the topics read."""
    h = hashlib.sha256(json.dumps([cell.topic, cell.gt_topic, cell.gt_frames and list(cell.gt_frames)]).encode())
    try:
        h.update(Path(cell.calib).read_bytes() if Path(cell.calib).is_file() else b"absent")
    except OSError:
        h.update(b"unreadable")
    bag = Path(cell.dataset)
    try:
        files = sorted(bag.iterdir()) if bag.is_dir() else [bag]
    except OSError:
        files = []
    _file_stamps(h, files)
    return h.hexdigest()[:_ID_DIGITS]


def cell_input_digest(cell: SweepCell) -> str:
    """Digest of a cell's input: :func:`dataset_digest` of a folder, or of a bag and its calibration."""
    return dataset_digest(cell.dataset) if cell.calib is None else _bag_digest(cell)


def dataset_digest(dataset: str | os.PathLike) -> str:
    """Short digest of a dataset's content: a changed dataset gets another one.

    Covers the bytes of ``meta.json``, the calibration and ``groundtruth.txt``
    (where present) and the names, sizes and modification times of the files
    in ``images/`` (reading every image would cost as much as estimating).
    """
    folder = Path(dataset)
    h = hashlib.sha256()
    for name in ("meta.json", "calib_results.txt", "camera.yaml", "groundtruth.txt"):
        try:
            if not (folder / name).is_file():  # a FIFO would block the read; the cell names it
                raise FileNotFoundError(folder / name)
            h.update(name.encode() + b"\0" + (folder / name).read_bytes() + b"\0")
        except OSError:
            h.update(name.encode() + b"\0absent\0")
    try:
        entries = sorted(os.scandir(folder / "images"), key=lambda e: e.name)
    except OSError:
        entries = []
    _file_stamps(h, entries)
    return h.hexdigest()[:_ID_DIGITS]


def config_with_tiling(config, *, tile_size: float, overlap: float):
    """Copy of an :class:`ifmi.pipeline.EstimateConfig` with the iFMI tiling replaced."""
    from ifmi.spectral.tiling import TilingConfig

    tiling = TilingConfig(tile_size=tile_size, overlap=overlap)
    return replace(config, ifmi=replace(config.ifmi, tiling=tiling))


def _cell_path(out_dir: Path, cell: SweepCell) -> Path:
    return out_dir / "cells" / f"{cell.cell_id}.json"


def config_digest(base_config: dict) -> str:
    """Short SHA-256 of a configuration dict (canonical JSON)."""
    text = json.dumps(base_config, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


# Entries every cell record has (failed cells included).
RECORD_KEYS = ("cell_id", "dataset", "method", "tile_size", "overlap", "status")


def _warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


def read_cell_record(path: Path, *, action: str) -> dict | None:
    """A cell's record, or None when it is missing; a record that is not a JSON object
    (truncated, ``[]``), lacks an entry of :data:`RECORD_KEYS` or holds a value of the wrong
    kind (text where a number belongs, ...) is None too, with a warning naming the file, the
    entry and ``action``."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, RecursionError) as exc:  # RecursionError: JSON nested too deeply
        _warn(f"{path}: unreadable sweep cell ({type(exc).__name__}); {action}")
        return None
    if not isinstance(record, dict):
        _warn(f"{path}: expected a JSON object, got {type(record).__name__}; {action}")
        return None
    missing = [k for k in RECORD_KEYS if k not in record]
    if missing:
        _warn(f"{path}: sweep cell without {', '.join(missing)}; {action}")
        return None
    problem = _record_type_problem(record)
    if problem:
        _warn(f"{path}: sweep cell {problem}; {action}")
        return None
    return record


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _float_of(value) -> float | None:
    """A JSON number as a float; None for an integer too large for one (10**400)."""
    try:
        return float(value)
    except OverflowError:
        return None


def _record_type_problem(record: dict) -> str:
    """What is of the wrong kind in a cell record ("" when nothing): text keys, the grid's numbers
    (finite), and the measured numbers (``*_rad``, ``*_s``, counts: not negative; null and NaN
    allowed, no integer too large for a float) of a finished cell."""
    for key in ("cell_id", "dataset", "method", "status"):
        if not isinstance(record[key], str):
            return f"{key}: expected text, got {json_excerpt(record[key])}"
    for key in ("tile_size", "overlap"):
        if not _is_number(record[key]):
            return f"{key}: expected a number, got {json_excerpt(record[key])}"
        number = _float_of(record[key])
        if number is None or not math.isfinite(number):
            return f"{key}: expected a finite number, got {json_excerpt(record[key])}"
    measured = [k for k in record if k.endswith(("_rad", "_s")) or k in ("failures", "frames")]
    for key in measured:
        value = record[key]
        if value is not None and not _is_number(value):
            return f"{key}: expected a number or null, got {json_excerpt(value)}"
        if value is not None and _float_of(value) is None:
            return f"{key}: expected a number a float holds (up to about 1.8e308) or null, got {json_excerpt(value)}"
        if value is not None and value < 0:
            return (f"{key}: expected a number >= 0 or null (errors, times and counts are never "
                    f"negative), got {json_excerpt(value)}")
    return ""


def _finished(out_dir: Path, cell: SweepCell, digest: str, data_digest: str) -> bool:
    """True when the cell's record is ``ok`` and was made with the same base configuration
    from the same dataset content."""
    record = read_cell_record(_cell_path(out_dir, cell), action="computing the cell again")
    return (record is not None and record.get("status") == "ok"
            and record.get("config_digest") == digest
            and record.get("dataset_digest") == data_digest)


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
    record = {"cell_id": cell.cell_id, "dataset": cell.dataset_name,
              "dataset_path": resolved_folder(cell.dataset),
              "dataset_digest": cell_input_digest(cell),
              "method": cell.method, "tile_size": cell.tile_size, "overlap": cell.overlap,
              "config_digest": config_digest(base_config)}
    start = time.perf_counter()
    try:
        from ifmi.evaluation.trajectory_files import summary_of
        from ifmi.pipeline import EstimateConfig

        config = config_with_tiling(EstimateConfig.from_dict(base_config),
                                    tile_size=cell.tile_size, overlap=cell.overlap)
        run_dir = out / "runs" / cell.cell_id
        meta = (_run_folder_cell if cell.calib is None else _run_bag_cell)(cell, config, run_dir)
        record.update(summary_of(meta).flat())
        record.update({"status": "ok", "error": "",
                       "evaluation": str((run_dir / "eval").relative_to(out))})
    except Exception as exc:  # a failing cell is recorded, never lost
        record.update({"status": "failed", "error": one_line(exc),
                       "traceback": traceback.format_exc(limit=6)})
    record["wall_s"] = time.perf_counter() - start
    atomic_write_json(_cell_path(out, cell), record)
    return record


def _run_folder_cell(cell: SweepCell, config, run_dir: Path) -> dict:
    """Estimate a dataset folder's cell into ``run_dir`` and evaluate it against its ``groundtruth.txt``."""
    from ifmi.evaluation.trajectory_files import evaluate_files
    from ifmi.io.results import write_estimate_run
    from ifmi.pipeline import estimate_dataset

    gt = Path(cell.dataset) / "groundtruth.txt"
    if not gt.is_file():
        raise FileNotFoundError(f"{gt}: ground truth not found")
    estimate = estimate_dataset(cell.dataset, method=cell.method, config=config)
    est_path = run_dir / "estimate.txt"
    write_estimate_run(est_path, estimate, dataset_dir=cell.dataset)
    return evaluate_files(gt, est_path, out_dir=run_dir / "eval")


def _run_bag_cell(cell: SweepCell, config, run_dir: Path) -> dict:
    """Estimate a bag's cell into ``run_dir`` and evaluate it against the bag's ground-truth topic."""
    from ifmi.evaluation.trajectory_files import evaluate_files
    from ifmi.io.results import write_estimate_run
    from ifmi.pipeline import estimate_bag

    estimate = estimate_bag(cell.dataset, cell.calib, topic=cell.topic, method=cell.method, config=config)
    est_path = run_dir / "estimate.txt"
    write_estimate_run(est_path, estimate, dataset_dir=None, input_files=(cell.dataset, cell.calib),
                       extra={"bag": resolved_folder(cell.dataset), "topic": cell.topic,
                              "calib": resolved_folder(cell.calib)})
    return evaluate_files(cell.dataset, est_path, out_dir=run_dir / "eval", gt_topic=cell.gt_topic,
                          gt_frames=cell.gt_frames)


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, disable=not enabled, file=sys.stderr, unit="cell", desc="sweep")


def is_sweep_dir(path: str | os.PathLike) -> bool:
    """True when ``path`` holds a ``sweep.json`` written by :func:`run_sweep`.

    That is a JSON object of kind :data:`SWEEP_KIND`, or one without a kind
    that has every key a sweep writes (``cells``, ``base_config``,
    ``scheduler``); an unreadable or foreign ``sweep.json`` does not count.
    """
    return folder_of_kind(path, "sweep.json", SWEEP_KIND, legacy_keys=_SWEEP_KEYS)


def _prepare_output(out_dir: str | os.PathLike, document: dict) -> Path:
    """Check and create the sweep folder before any cell runs; returns it with links resolved.

    A new or empty folder gets ``sweep.json`` at once (an interrupted sweep is
    then recognised as one). The folder's parent must be writable too: the
    result set is built beside the folder at the end. A folder inside a data
    folder of an input dataset (``images/``, ...) is refused: it would add
    entries to the frames.
    """
    from ifmi.io.dataset import refuse_output_in_datasets

    refuse_output_in_datasets(out_dir, (cell["dataset"] for cell in document["cells"]))
    out = check_output_folder(out_dir, is_own=is_sweep_dir,
                              what="a sweep folder written by ifmi sweep")
    try:
        probe_writable(out.parent / f".{out.name}.probe")
    except OutputError as exc:
        where = f" (the results are built beside it, in {out.parent})"
        raise OutputError(out_dir, exc.reason + (where if out.parent.is_dir() else "")) from None
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError.from_os_error(out_dir, exc) from None
    if not (out / "sweep.json").exists():
        atomic_write_json(out / "sweep.json", document)
    return out


def run_sweep(cells: Iterable[SweepCell], *, out_dir: str | os.PathLike, base_config: dict,
              options: SweepOptions = SweepOptions()) -> list[dict]:
    """Run every unfinished cell through Dask and write the table and heatmaps.

    Parameters
    ----------
    cells : iterable of SweepCell
    out_dir : path, keyword-only
        Sweep folder: new, empty, or an earlier sweep folder
        (:func:`is_sweep_dir`; its finished cells are reused). A symbolic
        link is written through.
    base_config : dict, keyword-only
        ``EstimateConfig.to_dict()`` shared by all cells (tiling replaced per cell).
    options : SweepOptions, keyword-only

    Returns
    -------
    list of dict
        The records of all cells of this grid (finished earlier or now).

    Raises
    ------
    OutputError
        ``out_dir`` is a file or an existing folder that is neither empty nor
        a sweep folder (checked before any cell runs), or it cannot be
        written. Writing the result set (:data:`SWEEP_RESULTS`) fails as a
        whole: the earlier set stays as it was, and the cell records stay for
        a rerun.
    InputError
        A Dask scheduler that cannot be reached, or does not answer within
        ``options.connect_timeout_s`` (nothing is printed before it).
    ClusterError
        The cluster was lost during the run; the finished cells keep their
        records, and a rerun runs the rest.
    ValueError
        Two cells of one name (:attr:`SweepCell.cell_id`), which would share one record.
    """
    cells = list(cells)
    names = [c.cell_id for c in cells]
    if len(set(names)) < len(names):
        twice = next(name for name in names if names.count(name) > 1)
        raise ValueError(f"cell {twice} given twice; expected cells of distinct datasets, methods and "
                         f"tilings (tile sizes and overlaps that differ in {CELL_NAME_DIGITS} significant digits)")
    document = {"kind": SWEEP_KIND, "cells": [c.__dict__ for c in cells],
                "base_config": base_config, "scheduler": options.scheduler or "local-cluster"}
    out = _prepare_output(out_dir, document)
    digest = config_digest(base_config)
    contents = {c.dataset: cell_input_digest(c) for c in cells}  # one input per dataset path
    pending = [c for c in cells if not _finished(out, c, digest, contents[c.dataset])]
    skipped = len(cells) - len(pending)
    if skipped and options.progress:
        print(f"sweep: {skipped} of {len(cells)} cells already finished, skipped", file=sys.stderr)
    if pending:
        _execute(pending, out_dir=str(out), base_config=base_config, options=options)
    records = read_cells(out, cells)

    def fill(folder: Path) -> None:
        write_sweep_table(folder, records)
        atomic_write_json(folder / "sweep.json", document)

    write_folder(out, fill, replaces=SWEEP_RESULTS)
    return records


def _execute(cells: list[SweepCell], *, out_dir: str, base_config: dict,
             options: SweepOptions) -> None:
    import dask

    if options.scheduler == "synchronous":
        with _progress(len(cells), options.progress) as bar:
            for cell in cells:
                task = dask.delayed(run_cell)(cell, out_dir=out_dir, base_config=base_config)
                task.compute(scheduler="synchronous")
                bar.update(1)
        return
    # Connected (or started) before the progress bar, so that a connection error is the only line.
    client, cluster = _sweep_client(options)
    try:
        with _progress(len(cells), options.progress) as bar:
            futures = [client.submit(run_cell, cell, out_dir=out_dir, base_config=base_config,
                                     pure=False, key=f"sweep-{cell.cell_id}-{time.time_ns()}")
                       for cell in cells]
            _wait_for_cells(futures, bar, options=options, out_dir=out_dir)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _sweep_client(options: SweepOptions):
    """``(client, cluster)``: a client of a new local cluster (returned too), or of ``options.scheduler``."""
    import dask
    from dask.distributed import Client, LocalCluster

    if options.scheduler is not None:
        return scheduler_client(options.scheduler, connect_timeout_s=options.connect_timeout_s), None
    # Dask's nanny sets MALLOC_TRIM_THRESHOLD_ in the workers it spawns, which turns
    # off glibc's adaptive mmap threshold: every large temporary array is then mapped
    # and zeroed afresh, and a cell's time per frame doubled (25 against 13 ms on a
    # 512 x 512 sequence). A fixed large mmap threshold keeps such arrays on the heap.
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_":
                          _WORKER_MMAP_THRESHOLD_BYTES}):
        cluster = LocalCluster(n_workers=options.n_workers, threads_per_worker=options.threads_per_worker,
                               processes=True, dashboard_address=":0")
    return Client(cluster), cluster


def _wait_for_cells(futures: list, bar, *, options: SweepOptions, out_dir: str) -> None:
    """Wait for the cells' futures, counting each on ``bar``.

    Raises
    ------
    ClusterError
        The scheduler was lost (the futures are cancelled) or a cell kept
        killing its workers; the cells finished so far keep their records.
    """
    from dask.distributed import as_completed

    done = 0
    try:
        for future in as_completed(futures):
            future.result()
            done += 1
            bar.update(1)
    except Exception as exc:
        lost = cluster_loss(exc)
        if lost is None:
            raise
        where = options.scheduler or "the local cluster"
        raise ClusterError(f"lost the Dask cluster at {where} after {done} of {len(futures)} cells ({lost}); "
                           f"the finished cells are kept in {Path(out_dir) / 'cells'}: rerun the same command "
                           f"to run the rest") from None


def read_cells(out_dir: str | os.PathLike, cells: Sequence[SweepCell] | None = None) -> list[dict]:
    """Records of ``cells`` (default: every ``cells/*.json``) in grid order.

    Missing records are skipped; unreadable ones (truncated, not a JSON
    object) too, with a warning naming the file.
    """
    out = Path(out_dir)
    if cells is None:
        paths = sorted((out / "cells").glob("*.json"))
    else:
        paths = [_cell_path(out, c) for c in cells]
    records = [read_cell_record(path, action="skipped") for path in paths]
    return [r for r in records if r is not None]


def sweep_records(sweep_dir: str | os.PathLike) -> list[dict]:
    """Records of the sweep that a folder's ``sweep.json`` describes: its grid, made with its base configuration.

    ``cells/`` keeps the record of every cell run in the folder, and a rerun
    with another grid or ``--config`` leaves the earlier records there: they
    belong to other sweeps. Records of cells that ``sweep.json`` does not
    list, or made with another base configuration than its, are left out
    with one warning saying how many; a listed cell without a readable
    record is missing, as in :func:`read_cells`.

    Parameters
    ----------
    sweep_dir : path
        A sweep folder (``sweep.json``, ``cells/``).

    Returns
    -------
    list of dict
        In the grid order of ``sweep.json``.

    Raises
    ------
    InputError
        ``sweep.json`` unreadable, or its ``cells`` or ``base_config`` not
        of the form :func:`run_sweep` writes.
    """
    from ifmi.io.config import read_json_object

    path = Path(sweep_dir) / "sweep.json"
    document = read_json_object(path, what="sweep file")
    cells = _listed_cells(path, document)
    digest = config_digest(document["base_config"])
    records, others = [], 0
    by_dataset = _records_by_dataset(Path(sweep_dir), cells)
    for cell in cells:
        record = read_cell_record(_cell_path(Path(sweep_dir), cell), action="skipped")
        if record is None:  # a folder whose dataset paths were rewritten (made relative): found by content
            record = by_dataset.get((cell.dataset_name, cell.method, cell.tile_size, cell.overlap))
        if record is not None and _of_cell(record, cell, digest):
            records.append(record)
        others += record is not None and not _of_cell(record, cell, digest)
    names = {f"{cell.cell_id}.json" for cell in cells}
    used = {record.get("cell_id") for record in records}
    others += sum(1 for path in (Path(sweep_dir) / "cells").glob("*.json")
                  if path.name not in names and path.stem not in used)
    if others > 0:
        grid = f"{len(cells)} cell{'s' if len(cells) != 1 else ''}"
        _warn(f"{sweep_dir}: {others} cell record{'s' if others > 1 else ''} in cells/ not of the grid and base "
              f"configuration of sweep.json ({grid}), left out: from earlier sweeps in this folder, or an "
              f"unfinished rerun")
    return records


def _records_by_dataset(sweep_dir: Path, cells: list) -> dict:
    """Records in ``cells/`` of no listed cell's file name, by (dataset label, method, tile size, overlap).

    A cell's file is named by its dataset's resolved folder; a sweep folder
    whose recorded dataset paths were rewritten (a report's copy, made
    relative) still holds each cell's record under its first name."""
    names = {f"{cell.cell_id}.json" for cell in cells}
    found = {}
    for path in sorted((sweep_dir / "cells").glob("*.json")):
        if path.name in names:
            continue
        record = read_cell_record(path, action="skipped")
        if record is not None:
            # A record's dataset is its cell's label, unique within a sweep (sweep_cells).
            found[(record["dataset"], record["method"], record["tile_size"], record["overlap"])] = record
    return found


def _of_cell(record: dict, cell: SweepCell, digest: str) -> bool:
    """Whether ``record`` is of ``cell`` (method and tiling) and made with the base configuration of ``digest``."""
    return (record["method"] == cell.method and record["tile_size"] == cell.tile_size
            and record["overlap"] == cell.overlap and record.get("config_digest", digest) == digest)


def _listed_cells(path: Path, document: dict) -> list[SweepCell]:
    """The cells ``sweep.json`` (``document``, read from ``path``) lists; InputError when malformed."""
    listed, base = document.get("cells"), document.get("base_config")
    if not isinstance(base, dict):
        raise InputError(path, f"base_config: expected an object, got {json_excerpt(base)}")
    if not isinstance(listed, list):
        raise InputError(path, f"cells: expected a list of cells, got {json_excerpt(listed)}")
    cells = []
    for k, cell in enumerate(listed):
        if not (isinstance(cell, dict) and isinstance(cell.get("dataset"), str)
                and isinstance(cell.get("method"), str) and _is_number(cell.get("tile_size"))
                and _is_number(cell.get("overlap")) and isinstance(cell.get("label"), (str, type(None)))):
            raise InputError(path, f"cells[{k}]: expected an object with text dataset and method, numbers "
                                   f"tile_size and overlap, and a label (text or null), got {json_excerpt(cell)}")
        bag = {key: cell.get(key) for key in ("calib", "topic", "gt_topic") if isinstance(cell.get(key), str)}
        frames = cell.get("gt_frames")
        if isinstance(frames, list) and len(frames) == 2 and all(isinstance(f, str) for f in frames):
            bag["gt_frames"] = tuple(frames)
        cells.append(SweepCell(cell["dataset"], cell["method"], float(cell["tile_size"]),
                               float(cell["overlap"]), label=cell["label"], **bag))
    return cells


def records_table(records: list[dict]):
    """Cell records as a pandas DataFrame, one row each, without their tracebacks.

    Text values are display names (:func:`~ifmi.evaluation.dataset_names.display_name`):
    a dataset path with bytes that are not UTF-8 holds lone surrogates, which
    Arrow, CSV and figure titles cannot take (the exact path stays in the
    cell's JSON).
    """
    import pandas as pd

    return pd.DataFrame([{k: display_name(v) if isinstance(v, str) else v for k, v in r.items()
                          if k != "traceback"} for r in records])


def write_sweep_table(out_dir: str | os.PathLike, records: list[dict]) -> None:
    """Write ``sweep.csv``, ``sweep.parquet`` and the heatmaps of ``records`` into ``out_dir``.

    Text values are written as :func:`records_table` gives them. Each file is
    written atomically, but not the files as a set, and heatmaps already in
    ``out_dir`` are left: :func:`run_sweep` calls this on a new temporary
    folder that it swaps in when complete.
    """
    import io

    from ifmi.experiments.plots import sweep_heatmap

    out = Path(out_dir)
    table = records_table(records)
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
            name = re.sub(r"[^A-Za-z0-9_.=-]", "_", f"{dataset}__{method}__{metric}")
            sweep_heatmap(group, metric=metric, label=label,
                          title=f"{dataset} ({method}): {label}",
                          path=out / "heatmaps" / f"{name}.png")
