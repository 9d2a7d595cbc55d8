"""The output folder of ``ifmi sweep``: refused when foreign, its result set written as one.

The cells are computed by a stand-in for :func:`ifmi.experiments.sweep.run_cell` that writes a
record as the real one does (tests/test_sweep.py runs real cells): these tests are
about the files, and stay fast.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import ifmi.experiments.sweep
from ifmi.cli import main
from ifmi.errors import OutputError
from ifmi.io.atomic import atomic_write_json
from ifmi.experiments.sweep import (SweepOptions, config_digest, dataset_digest, is_sweep_dir, run_sweep,
                        sweep_cells)

OPTIONS = SweepOptions(scheduler="synchronous", progress=False)
# Sweep folders committed with the reports; `ifmi sweep` must accept them as its own.
COMMITTED_SWEEPS = ("reports/demo/data/sweep/sweep",
                    "reports/benchmark_200/frame_to_frame/data/sweep/sweep_final")


def _dataset(root: Path, name: str) -> Path:
    folder = root / "data" / name
    folder.mkdir(parents=True)
    (folder / "groundtruth.txt").write_text("0 0 0 0 0 0 0 1\n")
    return folder


@pytest.fixture
def calls(monkeypatch):
    """Cell ids computed, in order; cells write an ``ok`` record without estimating."""
    computed: list[str] = []

    def fake_run_cell(cell, *, out_dir, base_config):
        computed.append(cell.cell_id)
        record = {"cell_id": cell.cell_id, "dataset": cell.dataset_name,
                  "dataset_path": str(cell.dataset), "dataset_digest": dataset_digest(cell.dataset),
                  "method": cell.method, "tile_size": cell.tile_size, "overlap": cell.overlap,
                  "config_digest": config_digest(base_config), "status": "ok", "error": "",
                  "rmse_mean_rad": 0.001 * cell.tile_size, "wall_s": 0.0}  # one heatmap
        atomic_write_json(Path(out_dir) / "cells" / f"{cell.cell_id}.json", record)
        return record

    monkeypatch.setattr(ifmi.experiments.sweep, "run_cell", fake_run_cell)
    return computed


def _sweep_cli(data: Path, out: Path, capsys, *tile_sizes: str) -> tuple[int, str]:
    code = main(["sweep", str(data), "--tile-size", *(tile_sizes or ("32",)), "--overlap", "0",
                 "--scheduler", "synchronous", "--no-progress", "--out", str(out)])
    return code, capsys.readouterr().err.strip()


def _contents(folder: Path) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _result_set(folder: Path) -> dict:
    return {k: v for k, v in _contents(folder).items() if k.parts[0] in ifmi.experiments.sweep.SWEEP_RESULTS}


def _hidden_leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def test_cli_refuses_a_folder_of_the_users(tmp_path, capsys, calls):
    data = _dataset(tmp_path, "office")
    out = tmp_path / "OUT"
    out.mkdir()
    for name, text in (("sweep.csv", "a,b\n"), ("sweep.json", '{"mine": 1}'), ("notes.txt", "x")):
        (out / name).write_text(text)
    before = _contents(out)
    code, err = _sweep_cli(data, out, capsys, "32", "48")
    assert code == 1 and len(err.splitlines()) == 1
    assert err.startswith(f"ifmi sweep: error: cannot write {out}: holds notes.txt, sweep.csv, "
                          "sweep.json but is not a sweep folder")
    assert _contents(out) == before and calls == []
    assert _hidden_leftovers(tmp_path) == []


def test_foreign_sweep_json_is_refused(tmp_path, calls):
    data = _dataset(tmp_path, "office")
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "sweep.json").write_text(json.dumps({"kind": "other-tool", "cells": [],
                                                "base_config": {}, "scheduler": "x"}))
    cells = sweep_cells([str(data)], method="ifmi", tile_sizes=[32], overlaps=[0.0])
    with pytest.raises(OutputError, match="but is not a sweep folder"):
        run_sweep(cells, out_dir=out, base_config={}, options=OPTIONS)
    assert calls == [] and sorted(p.name for p in out.iterdir()) == ["sweep.json"]


def test_sweep_json_without_kind_is_accepted_only_with_every_key(tmp_path):
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    (legacy / "sweep.json").write_text(json.dumps({"cells": [], "base_config": {},
                                                   "scheduler": "synchronous"}))
    partial = tmp_path / "partial"
    partial.mkdir()
    (partial / "sweep.json").write_text(json.dumps({"cells": []}))
    assert is_sweep_dir(legacy) and not is_sweep_dir(partial)
    root = Path(__file__).resolve().parents[1]
    committed = [root / p for p in COMMITTED_SWEEPS if (root / p).is_dir()]
    assert all(is_sweep_dir(p) for p in committed)


def test_empty_folder_is_written(tmp_path, calls):
    data = _dataset(tmp_path, "office")
    out = tmp_path / "empty"
    out.mkdir()
    cells = sweep_cells([str(data)], method="ifmi", tile_sizes=[32], overlaps=[0.0])
    records = run_sweep(cells, out_dir=out, base_config={}, options=OPTIONS)
    assert [r["status"] for r in records] == ["ok"]
    assert json.loads((out / "sweep.json").read_text())["kind"] == ifmi.experiments.sweep.SWEEP_KIND
    assert (out / "sweep.parquet").is_file() and (out / "heatmaps").is_dir()
    assert _hidden_leftovers(tmp_path) == []


def test_rerun_with_another_grid_replaces_the_set_and_keeps_the_users_files(tmp_path, calls, capsys):
    office, lawn = _dataset(tmp_path, "office"), _dataset(tmp_path, "lawn")
    out = tmp_path / "sweep"
    assert _sweep_cli(office, out, capsys)[0] == 0
    assert list((out / "heatmaps").glob("office__*"))
    (out / "notes.txt").write_text("mine")
    assert _sweep_cli(lawn, out, capsys, "48")[0] == 0
    # The earlier grid's heatmaps do not linger beside the new table.
    heatmaps = sorted(p.name for p in (out / "heatmaps").iterdir())
    assert heatmaps and all(name.startswith("lawn__") for name in heatmaps)
    assert [c["dataset"] for c in json.loads((out / "sweep.json").read_text())["cells"]] == [str(lawn)]
    assert (out / "sweep.csv").read_text().count("\n") == 2
    assert (out / "notes.txt").read_text() == "mine"
    assert _hidden_leftovers(tmp_path) == []


def test_failure_writing_the_set_leaves_the_old_set_and_the_cells(tmp_path, calls, capsys, monkeypatch):
    data = _dataset(tmp_path, "office")
    out = tmp_path / "sweep"
    assert _sweep_cli(data, out, capsys)[0] == 0
    before = _result_set(out)

    def full_disk(path, data):
        raise OutputError(path, "No space left on device")

    # sweep.csv is written, then sweep.parquet fails.
    monkeypatch.setattr(ifmi.experiments.sweep, "atomic_write_bytes", full_disk)
    code, err = _sweep_cli(data, out, capsys, "32", "48")
    assert code == 1 and err == f"ifmi sweep: error: cannot write {out}: No space left on device"
    assert _result_set(out) == before
    assert _hidden_leftovers(tmp_path) == []
    # The new cell's record stays: the rerun writes the set without computing it again.
    monkeypatch.undo()
    monkeypatch.setattr(ifmi.experiments.sweep, "run_cell", lambda *a, **k: pytest.fail("cell computed again"))
    assert _sweep_cli(data, out, capsys, "32", "48")[0] == 0
    assert (out / "sweep.csv").read_text().count("\n") == 3


def test_interrupted_first_sweep_is_resumed(tmp_path, calls, monkeypatch):
    data = _dataset(tmp_path, "office")
    out = tmp_path / "sweep"
    cells = sweep_cells([str(data)], method="ifmi", tile_sizes=[32, 48], overlaps=[0.0])
    computed = ifmi.experiments.sweep.run_cell

    def interrupted_at_the_second(cell, **kwargs):
        if calls:
            raise KeyboardInterrupt
        return computed(cell, **kwargs)

    monkeypatch.setattr(ifmi.experiments.sweep, "run_cell", interrupted_at_the_second)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(cells, out_dir=out, base_config={}, options=OPTIONS)
    assert is_sweep_dir(out) and not (out / "sweep.csv").exists()
    monkeypatch.setattr(ifmi.experiments.sweep, "run_cell", computed)
    records = run_sweep(cells, out_dir=out, base_config={}, options=OPTIONS)
    assert [r["status"] for r in records] == ["ok", "ok"]
    assert calls == [c.cell_id for c in cells]


def test_unwritable_parent_is_refused_before_any_cell(tmp_path, calls, capsys, monkeypatch):
    data = _dataset(tmp_path, "office")
    out = tmp_path / "sweep"

    def refused(path):
        raise OutputError(path, "Permission denied")

    monkeypatch.setattr(ifmi.experiments.sweep, "probe_writable", refused)
    code, err = _sweep_cli(data, out, capsys)
    assert code == 1 and len(err.splitlines()) == 1 and calls == [] and not out.exists()
    assert err == (f"ifmi sweep: error: cannot write {out}: Permission denied (the results are "
                   f"built beside it, in {tmp_path})")


@pytest.mark.parametrize("through_link", [False, True])
def test_out_inside_the_images_of_an_input_dataset_is_refused_before_any_cell(tmp_path, calls, capsys,
                                                                               through_link):
    # A sweep folder in images/ would be an entry among the frames of the dataset it measures.
    data = _dataset(tmp_path, "office")
    (data / "images").mkdir()
    (data / "images" / "000000.png").write_bytes(b"frame")
    images = data / "images"
    if through_link:
        (tmp_path / "link").symlink_to(images)
        images = tmp_path / "link"
    out = images / "sweep"
    code, err = _sweep_cli(data, out, capsys)
    assert code == 1 and len(err.splitlines()) == 1 and calls == []
    assert err == (f"ifmi sweep: error: cannot write {out}: would write into images/ of the input "
                   f"dataset {data}; choose another output path")
    assert sorted(p.name for p in (data / "images").iterdir()) == ["000000.png"]
