"""Tile-size x overlap sweeps: records per cell, failures kept, reruns skip finished cells."""

from __future__ import annotations

import json
import os
import threading

import numpy as np
import pandas as pd
import pytest

from ifmi.cli import main
from ifmi.io.tum import read_tum
from ifmi.pipeline import EstimateConfig
from ifmi.geometry.rotations import geodesic_angle
from ifmi.experiments.sweep import SweepOptions, config_with_tiling, run_sweep, sweep_cells

pytest.importorskip("skimage")
from ifmi.synthetic import (example_band_px, example_omni_model, synthetic_sequence,  # noqa: E402
                            write_synthetic_dataset)


def _write_dataset(folder, *, n, size, seed, max_step_rad=0.03):
    model = example_omni_model(size)
    sequence = synthetic_sequence(model, n, seed=seed, max_step_rad=max_step_rad,
                                  band_px=example_band_px(model))
    return write_synthetic_dataset(folder, sequence)


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep_data")
    good = _write_dataset(root / "tiny", n=5, size=160, seed=2, max_step_rad=0.04)
    bad = _write_dataset(root / "nogt", n=3, size=128, seed=3)
    (bad / "groundtruth.txt").unlink()
    return good, bad


def test_config_with_tiling_replaces_only_the_tiling():
    base = EstimateConfig()
    cfg = config_with_tiling(base, tile_size=48, overlap=0.25)
    assert cfg.ifmi.tiling.tile_size == 48 and cfg.ifmi.tiling.overlap == 0.25
    assert cfg.relative_pose == base.relative_pose and cfg.keyframe == base.keyframe


@pytest.mark.slow
def test_sweep_records_cells_keeps_failures_and_skips_on_rerun(datasets, tmp_path):
    good, bad = datasets
    cells = sweep_cells([str(good), str(bad)], method="ifmi", tile_sizes=[32, 48],
                        overlaps=[0.0, 0.5])
    out = tmp_path / "sweep"
    options = SweepOptions(scheduler="synchronous", progress=False)
    records = run_sweep(cells, out_dir=out, base_config=EstimateConfig().to_dict(), options=options)
    assert len(records) == 8
    ok = [r for r in records if r["status"] == "ok"]
    failed = [r for r in records if r["status"] == "failed"]
    assert {r["dataset"] for r in ok} == {"tiny"} and len(ok) == 4
    assert {r["dataset"] for r in failed} == {"nogt"} and len(failed) == 4
    assert all("ground truth not found" in r["error"] for r in failed)
    gt = read_tum(good / "groundtruth.txt")
    rms_motion = np.sqrt(np.mean(geodesic_angle(gt.rotations[:1], gt.rotations) ** 2))
    for r in ok:
        # The cells track the camera: an estimate stuck at the identity would
        # have an RMSE equal to the RMS rotation angle (about 0.09 rad here);
        # on 160-px images with 32/48-px tiles the cells stay well under it.
        assert r["frames"] == 5 and r["rmse_geodesic_rad"] < 0.7 * rms_motion
        assert r["time_per_frame_s"] > 0 and r["failures"] == 0
    table = pd.read_csv(out / "sweep.csv")
    assert len(table) == 8 and set(table["status"]) == {"ok", "failed"}
    assert len(pd.read_parquet(out / "sweep.parquet")) == 8
    assert (out / "heatmaps" / "tiny__ifmi__rmse_mean_rad.png").is_file()
    assert not list((out / "heatmaps").glob("nogt*"))

    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}
    again = run_sweep(cells, out_dir=out, base_config=EstimateConfig().to_dict(), options=options)
    assert len(again) == 8
    for p in (out / "cells").glob("*.json"):
        record = json.loads(p.read_text())
        if record["status"] == "ok":
            assert p.stat().st_mtime_ns == stamps[p.name], "finished cell was run again"
        else:
            assert p.stat().st_mtime_ns != stamps[p.name], "failed cell was not retried"


@pytest.mark.slow
def test_sweep_through_local_cluster(datasets, tmp_path):
    pytest.importorskip("dask.distributed")
    good, _ = datasets
    cells = sweep_cells([str(good)], method="ifmi", tile_sizes=[32], overlaps=[0.0, 0.5])
    records = run_sweep(cells, out_dir=tmp_path / "sweep", base_config=EstimateConfig().to_dict(),
                        options=SweepOptions(n_workers=2, progress=False))
    assert [r["status"] for r in records] == ["ok", "ok"]
    assert len(pd.read_csv(tmp_path / "sweep" / "sweep.csv")) == 2


def test_sweep_cli_synchronous(datasets, tmp_path, capsys):
    good, _ = datasets
    out = tmp_path / "cli"
    code = main(["sweep", str(good), "--tile-size", "32", "--overlap", "0", "--scheduler",
                 "synchronous", "--out", str(out), "--no-progress"])
    assert code == 0
    assert "1 cells ok, 0 failed" in capsys.readouterr().out
    assert (out / "sweep.parquet").is_file()


def test_sweep_cli_missing_dataset_is_one_line_error(tmp_path, capsys):
    code = main(["sweep", str(tmp_path / "none"), "--tile-size", "32", "--overlap", "0",
                 "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "dataset folder not found" in err and len(err.splitlines()) == 1


def test_sweep_cli_rejects_bad_overlap(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["sweep", str(tmp_path), "--tile-size", "32", "--overlap", "1.5", "--out", "x"])
    assert "overlap must be in [0, 1)" in capsys.readouterr().err


@pytest.mark.slow
def test_changed_base_config_reruns_cells(datasets, tmp_path):
    from dataclasses import replace

    good, _ = datasets
    cells = sweep_cells([str(good)], method="ifmi", tile_sizes=[32], overlaps=[0.0])
    options = SweepOptions(scheduler="synchronous", progress=False)
    out = tmp_path / "sweep"
    base = EstimateConfig()
    run_sweep(cells, out_dir=out, base_config=base.to_dict(), options=options)
    path = next((out / "cells").glob("*.json"))
    first = path.stat().st_mtime_ns
    run_sweep(cells, out_dir=out, base_config=base.to_dict(), options=options)
    assert path.stat().st_mtime_ns == first
    changed = replace(base, relative_pose=replace(base.relative_pose, seed=99))
    run_sweep(cells, out_dir=out, base_config=changed.to_dict(), options=options)
    assert path.stat().st_mtime_ns != first


@pytest.mark.slow
def test_unreachable_scheduler_is_one_line_error(datasets, tmp_path):
    from ifmi.errors import InputError

    good, _ = datasets
    cells = sweep_cells([str(good)], method="ifmi", tile_sizes=[32], overlaps=[0.0])
    # Port 9 (discard) has no Dask scheduler on this machine.
    with pytest.raises(InputError, match="cannot connect to a Dask scheduler"):
        run_sweep(cells, out_dir=tmp_path / "s", base_config=EstimateConfig().to_dict(),
                  options=SweepOptions(scheduler="tcp://127.0.0.1:9", progress=False,
                                       connect_timeout_s=1.0))


@pytest.mark.slow
def test_sweep_through_existing_scheduler_address(datasets, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    good, _ = datasets
    cells = sweep_cells([str(good)], method="ifmi", tile_sizes=[48], overlaps=[0.0])
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:
        records = run_sweep(cells, out_dir=tmp_path / "sweep",
                            base_config=EstimateConfig().to_dict(),
                            options=SweepOptions(scheduler=cluster.scheduler_address,
                                                 progress=False))
    assert [r["status"] for r in records] == ["ok"]


@pytest.mark.slow
def test_dataset_folder_named_with_a_byte_that_is_not_utf8_is_swept_and_reported(tmp_path, capsys):
    # Python holds the byte as a lone surrogate: pandas/Arrow, then Matplotlib, raised UnicodeEncodeError.
    folder = tmp_path / os.fsdecode(b"d\xff")
    _write_dataset(folder, n=4, size=128, seed=5)
    out = tmp_path / "sweep"
    assert main(["sweep", str(folder), "--tile-size", "32", "--overlap", "0", "--scheduler", "synchronous",
                 "--out", str(out), "--no-progress"]) == 0
    assert list(pd.read_parquet(out / "sweep.parquet")["dataset"]) == ["d\ufffd"]
    assert main(["report", str(out), "--out", str(tmp_path / "report"), "--no-motion-flow"]) == 0
    assert "| d\ufffd | ifmi | 32 | 0 | ok |" in (tmp_path / "report" / "README.md").read_text()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_calibration_that_is_a_fifo_fails_its_cell_instead_of_blocking(tmp_path, capsys):
    # The dataset digest read the FIFO's bytes and waited for a writer forever.
    folder = _write_dataset(tmp_path / "ds", n=3, size=128, seed=5)
    (folder / "calib_results.txt").unlink()
    os.mkfifo(folder / "calib_results.txt")
    assert main(["sweep", str(folder), "--tile-size", "32", "--overlap", "0", "--scheduler", "synchronous",
                 "--out", str(tmp_path / "sweep"), "--no-progress"]) == 1
    assert (f"InputError: {folder / 'calib_results.txt'}: is a FIFO, device or socket, not a calibration file"
            in capsys.readouterr().err)


def test_overlap_near_one_fails_its_cell_at_once_naming_the_tile_count(tmp_path, capsys):
    # Before: the cell registered 31232 tiles of 32 px per frame (1.6 GiB, about 10 s a frame pair).
    folder = _write_dataset(tmp_path / "ds", n=3, size=256, seed=5)
    assert main(["sweep", str(folder), "--tile-size", "32", "--overlap", "0.999", "--scheduler", "synchronous",
                 "--out", str(tmp_path / "sweep"), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("failed ds-") and "__tile32__overlap0.999: InputError: ifmi.tiling: expected at most " \
        "12483 tiles per frame (1 GiB to register a frame pair, 84 KiB per 32 px tile), got 31232: " in err
    assert err.endswith("an overlap of at most 0.95 keeps within it")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_config_that_is_a_fifo_is_one_line_error(datasets, tmp_path, capsys):
    # Before: the sweep waited for a writer forever.
    good, _ = datasets
    os.mkfifo(tmp_path / "c.json")
    stop = threading.Event()

    def feed() -> None:  # without the check the reader gets "{}" and the sweep runs: a failure, not a hang
        while not stop.is_set():
            try:
                fd = os.open(tmp_path / "c.json", os.O_WRONLY | os.O_NONBLOCK)
            except OSError:
                stop.wait(0.05)
                continue
            with os.fdopen(fd, "w") as pipe:
                pipe.write("{}")
            return

    threading.Thread(target=feed, daemon=True).start()
    try:
        code = main(["sweep", str(good), "--tile-size", "32", "--overlap", "0", "--scheduler", "synchronous",
                     "--config", str(tmp_path / "c.json"), "--out", str(tmp_path / "o"), "--no-progress"])
    finally:
        stop.set()
    assert code == 2
    assert capsys.readouterr().err.strip() == (f"ifmi sweep: error: {tmp_path / 'c.json'}: is a FIFO, device or "
                                               "socket, not a configuration file; expected a regular file")
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_two_datasets_of_one_name_are_distinct_cells(tmp_path):
    a = _write_dataset(tmp_path / "site_a" / "office", n=4, size=128, seed=5, max_step_rad=0.03)
    b = _write_dataset(tmp_path / "site_b" / "office", n=4, size=128, seed=6, max_step_rad=0.06)
    cells = sweep_cells([str(a), str(b)], method="ifmi", tile_sizes=[32], overlaps=[0.0])
    out = tmp_path / "sweep"
    records = run_sweep(cells, out_dir=out, base_config=EstimateConfig().to_dict(),
                        options=SweepOptions(scheduler="synchronous", progress=False))
    assert [r["dataset"] for r in records] == ["site_a/office", "site_b/office"]
    assert [r["dataset_path"] for r in records] == [str(a.resolve()), str(b.resolve())]
    assert len({r["cell_id"] for r in records}) == 2
    # Each row holds its own dataset's numbers: the second sequence turns twice as fast.
    assert records[0]["rmse_geodesic_rad"] != records[1]["rmse_geodesic_rad"]
    table = pd.read_csv(out / "sweep.csv")
    assert list(table["dataset"]) == ["site_a/office", "site_b/office"]
    assert (out / "heatmaps" / "site_a_office__ifmi__rmse_mean_rad.png").is_file()
    assert (out / "heatmaps" / "site_b_office__ifmi__rmse_mean_rad.png").is_file()


@pytest.mark.slow
def test_changed_dataset_is_recomputed_never_reused(tmp_path):
    data = _write_dataset(tmp_path / "office", n=4, size=128, seed=5)
    cells = sweep_cells([str(data)], method="ifmi", tile_sizes=[32], overlaps=[0.0])
    out = tmp_path / "sweep"
    options = SweepOptions(scheduler="synchronous", progress=False)
    first = run_sweep(cells, out_dir=out, base_config=EstimateConfig().to_dict(), options=options)
    # The same folder now holds another sequence (a re-render with another seed).
    _write_dataset(data, n=4, size=128, seed=9, max_step_rad=0.06)
    second = run_sweep(cells, out_dir=out, base_config=EstimateConfig().to_dict(), options=options)
    assert first[0]["dataset_digest"] != second[0]["dataset_digest"]
    assert first[0]["rmse_geodesic_rad"] != second[0]["rmse_geodesic_rad"]


def _one_cell_sweep(datasets, tmp_path):
    """A finished one-cell sweep of the good dataset: ``(rerun, sweep folder, the cell's record file)``."""
    good, _ = datasets
    cells = sweep_cells([str(good)], method="ifmi", tile_sizes=[32], overlaps=[0.0])
    out = tmp_path / "sweep"
    options = SweepOptions(scheduler="synchronous", progress=False)

    def rerun():
        return run_sweep(cells, out_dir=out, base_config=EstimateConfig().to_dict(), options=options)

    rerun()
    return rerun, out, next((out / "cells").glob("*.json"))


@pytest.mark.slow
@pytest.mark.parametrize("content", ["[]", '{"status": "ok", "cell_'])
def test_bad_cell_record_is_warned_and_recomputed(datasets, tmp_path, capsys, content):
    rerun, _, path = _one_cell_sweep(datasets, tmp_path)
    path.write_text(content)
    capsys.readouterr()
    records = rerun()
    err = capsys.readouterr().err
    assert str(path) in err and "computing the cell again" in err
    assert records[0]["status"] == "ok" and json.loads(path.read_text())["status"] == "ok"


def test_sweep_cli_rejects_zero_workers(datasets, tmp_path, capsys):
    good, _ = datasets
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(good), "--tile-size", "32", "--overlap", "0", "--workers", "0",
              "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert "expected an integer >= 1, got 0" in capsys.readouterr().err


def test_sweep_cli_rejects_more_workers_than_cpus(datasets, tmp_path, capsys):
    good, _ = datasets
    with pytest.raises(SystemExit) as exc:
        # With the synchronous scheduler a missing check runs the cell instead of starting workers.
        main(["sweep", str(good), "--tile-size", "32", "--overlap", "0", "--workers", "1000000",
              "--scheduler", "synchronous", "--no-progress", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert "workers (the CPUs this process may use), got 1000000" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_sweep_options_reject_zero_workers():
    with pytest.raises(ValueError, match="n_workers >= 1"):
        SweepOptions(n_workers=0)


def test_sweep_cli_unknown_method_is_one_line_error(datasets, tmp_path, capsys):
    good, _ = datasets
    code = main(["sweep", str(good), "--tile-size", "32", "--overlap", "0", "--method", "nosuch",
                 "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "unknown method" in err
    assert not (tmp_path / "o").exists()


def test_sweep_cli_out_below_a_file_is_one_line_error(datasets, tmp_path, capsys):
    good, _ = datasets
    (tmp_path / "file").write_text("x")
    code = main(["sweep", str(good), "--tile-size", "32", "--overlap", "0", "--scheduler",
                 "synchronous", "--out", str(tmp_path / "file" / "sweep"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1
    assert f"cannot write {tmp_path / 'file' / 'sweep'}" in err


def test_sweep_cli_bad_base_config_is_one_line_error(datasets, tmp_path, capsys):
    good, _ = datasets
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"keyframe": {"enabled": True, "bogus": 1}}))
    code = main(["sweep", str(good), "--tile-size", "32", "--overlap", "0", "--config", str(bad),
                 "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "bad.json" in err and "bogus" in err


@pytest.mark.parametrize("tile_size", ["0", "6", "inf", "nan"])
def test_sweep_cli_rejects_bad_tile_size(tmp_path, capsys, tile_size):
    # Fractions of the panorama in (0, 1), or at least 8 pixels: 6 px would fail inside every cell.
    with pytest.raises(SystemExit):
        main(["sweep", str(tmp_path), "--tile-size", tile_size, "--overlap", "0", "--out", "x"])
    assert "tile_size must be a fraction in (0, 1) of the panorama width or at least 8 px" in capsys.readouterr().err


def test_sweep_repeats_the_method_of_a_run_file_unless_told(tmp_path):
    import json

    from ifmi.cli.sweep import _base_config
    from ifmi.pipeline import EstimateConfig

    run_file = tmp_path / "orb.config.json"
    run_file.write_text(json.dumps({"method": "orb", "config": EstimateConfig().to_dict()}))
    assert _base_config(str(run_file), None)[1] == "orb"
    assert _base_config(str(run_file), "ifmi")[1] == "ifmi"
    assert _base_config(None, None)[1] == "ifmi"


@pytest.mark.parametrize("second", ["same", "slash", "link"])
def test_sweep_cli_refuses_a_dataset_given_twice(datasets, tmp_path, capsys, second):
    # One folder twice (also spelt otherwise) would be one cell counted as two rows of the table.
    good, _ = datasets
    other = {"same": str(good), "slash": f"{good}/", "link": str(tmp_path / "link")}[second]
    (tmp_path / "link").symlink_to(good)
    code = main(["sweep", str(good), other, "--tile-size", "32", "--overlap", "0", "--scheduler",
                 "synchronous", "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert f"{other}: dataset given twice (also as {good}); expected each dataset once" in err
    assert not (tmp_path / "o").exists()


def _sweep_with_grid(dataset, out, capsys, option, grid):
    """``(exit code, stderr)`` of a sweep over ``grid`` for ``option`` (the other option one value)."""
    values = {"--tile-size": ["32"], "--overlap": ["0"]}
    values[option] = grid
    code = main(["sweep", str(dataset), "--tile-size", *values["--tile-size"], "--overlap",
                 *values["--overlap"], "--scheduler", "synchronous", "--out", str(out), "--no-progress"])
    return code, capsys.readouterr().err.strip()


@pytest.mark.parametrize(("option", "grid", "shown"), [("--tile-size", ["32", "48", "32.0"], "32 48 32"),
                                                        ("--overlap", ["0", "0.0"], "0 0")])
def test_sweep_cli_refuses_a_grid_value_given_twice(datasets, tmp_path, capsys, option, grid, shown):
    code, err = _sweep_with_grid(datasets[0], tmp_path / "o", capsys, option, grid)
    assert code == 2 and len(err.splitlines()) == 1
    value = shown.split()[0]
    assert f"{option}: value {value} given twice; expected distinct values (got {shown})" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("option", "grid"), [("--tile-size", ["32", "32.0000001"]),
                                               ("--overlap", ["0.5", "0.50000000001"])])
def test_sweep_cli_refuses_grid_values_of_one_cell_name(datasets, tmp_path, capsys, option, grid):
    # Both values were run into one cell file: the table had two rows of the second, the first was lost.
    code, err = _sweep_with_grid(datasets[0], tmp_path / "o", capsys, option, grid)
    assert code == 2 and len(err.splitlines()) == 1
    assert (f"{option}: values {float(grid[0])!r} and {float(grid[1])!r} both name the cell value "
            f"{float(grid[0]):g} (cells are named to 6 significant digits)") in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("method", ["orb", "akaze"])
def test_sweep_cli_refuses_a_method_that_ignores_the_tiling(datasets, tmp_path, capsys, method):
    # Every cell ran the same keypoint estimate: a flat error heatmap and a time heatmap of noise, exit 0.
    good, _ = datasets
    code = main(["sweep", str(good), "--tile-size", "32", "48", "--overlap", "0", "--method", method,
                 "--scheduler", "synchronous", "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == (f"ifmi sweep: error: --method: method {method} does not use the tiling that a "
                                 "sweep varies (tile size and overlap are iFMI's): every cell would repeat one "
                                 "run; expected --method ifmi or a method of your own that reads "
                                 "config.ifmi.tiling")
    assert not (tmp_path / "o").exists()


def test_run_sweep_refuses_two_cells_of_one_name(datasets, tmp_path):
    from ifmi.experiments.sweep import SweepCell, SweepOptions, run_sweep

    good, _ = datasets
    cells = [SweepCell(str(good), "ifmi", 32.0, overlap) for overlap in (0.5, 0.5 + 1e-11)]
    with pytest.raises(ValueError, match="given twice"):
        run_sweep(cells, out_dir=tmp_path / "o", base_config=EstimateConfig().to_dict(),
                  options=SweepOptions(scheduler="synchronous", progress=False))
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("key, value, expected", [
    ("rmse_geodesic_rad", "0.1", 'rmse_geodesic_rad: expected a number or null, got "0.1"'),
    ("tile_size", None, "tile_size: expected a number, got null"),
    ("status", 1, "status: expected text, got 1"),
    pytest.param("tile_size", 10 ** 400, f"tile_size: expected a finite number, got {str(10 ** 400)[:37]}...",
                 id="tile_size-past-float"),
    ("rmse_mean_rad", -1.0, "rmse_mean_rad: expected a number >= 0 or null (errors, times and counts are never "
                            "negative), got -1.0"),
])
@pytest.mark.slow
def test_cell_record_of_the_wrong_kind_is_named_recomputed_and_left_out_of_reports(
        datasets, tmp_path, capsys, key, value, expected):
    rerun, out, path = _one_cell_sweep(datasets, tmp_path)
    edited = dict(json.loads(path.read_text()), **{key: value})
    path.write_text(json.dumps(edited))
    capsys.readouterr()
    assert main(["report", "--no-motion-flow", str(out), "--out", str(tmp_path / "rep")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and expected in err[0] and "skipped" in err[0]
    records = rerun()
    assert expected in capsys.readouterr().err
    assert records[0]["status"] == "ok" and json.loads(path.read_text())[key] != value


# A scheduler with one in-process worker, in a process of its own that the test can kill.
_SCHEDULER_PROCESS = """
import time
from distributed import LocalCluster
cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None, protocol="tcp",
                       host="127.0.0.1")
print(cluster.scheduler_address, flush=True)
while True:
    time.sleep(1)
"""


def _comparable_records(folder):
    """The cell records without their times, and the estimates' bytes, of a sweep folder."""
    records = {}
    for path in sorted((folder / "cells").glob("*.json")):
        record = json.loads(path.read_text())
        records[path.name] = {k: v for k, v in record.items() if k not in ("wall_s", "time_per_frame_s")}
    estimates = {p.relative_to(folder): p.read_bytes() for p in (folder / "runs").rglob("estimate.txt")}
    return json.dumps(records, sort_keys=True), estimates


@pytest.mark.slow
def test_sweep_losing_its_scheduler_ends_in_one_line_and_resumes_to_the_same_records(datasets, tmp_path, capsys):
    """The external scheduler is killed once the first cell is recorded: one line, exit 1, the finished
    cells kept; the rerun (here in this process) gives the records of an uninterrupted sweep."""
    import subprocess
    import sys
    import time

    good, _ = datasets
    # Nine cells, so that the kill at the first recorded cell lands mid-run on a fast machine too.
    grid = ["--tile-size", "24", "32", "40", "--overlap", "0", "0.25", "0.5"]
    process = subprocess.Popen([sys.executable, "-c", _SCHEDULER_PROCESS], stdout=subprocess.PIPE, text=True)
    try:
        address = process.stdout.readline().strip()
        assert address.startswith("tcp://127.0.0.1:")
        out = tmp_path / "out"

        def kill_after_the_first_cell():
            for _ in range(1200):  # 120 s at most
                if (out / "cells").is_dir() and any((out / "cells").glob("*.json")):
                    break
                time.sleep(0.1)
            process.kill()

        killer = threading.Thread(target=kill_after_the_first_cell, daemon=True)
        killer.start()
        code = main(["sweep", str(good), *grid, "--scheduler", address, "--no-progress", "--out", str(out)])
        killer.join(timeout=130)
    finally:
        process.kill()
        process.wait(timeout=30)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line]
    assert code == 1
    assert len(lines) == 1 and lines[0].startswith(f"ifmi sweep: error: lost the Dask cluster at {address} after ")
    assert lines[0].endswith(f"of 9 cells (the scheduler went away); the finished cells are kept in "
                             f"{out.resolve() / 'cells'}: rerun the same command to run the rest")
    kept = len(list((out / "cells").glob("*.json")))
    assert 1 <= kept < 9
    assert main(["sweep", str(good), *grid, "--scheduler", "synchronous", "--no-progress", "--out", str(out)]) == 0
    whole = tmp_path / "whole"
    assert main(["sweep", str(good), *grid, "--scheduler", "synchronous", "--no-progress", "--out", str(whole)]) == 0
    assert _comparable_records(out) == _comparable_records(whole)
