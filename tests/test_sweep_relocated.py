"""A sweep folder whose recorded dataset paths were made relative (a committed report's copy) is
still read whole: each cell's record is found by its content when its file name, which hashes the
dataset's resolved folder, no longer matches."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from ifmi.experiments.sweep import sweep_records

DEMO_SWEEP = Path(__file__).resolve().parents[1] / "reports" / "demo" / "data" / "sweep" / "sweep"


def test_relocated_sweep_keeps_every_cell(tmp_path, capsys):
    folder = shutil.copytree(DEMO_SWEEP, tmp_path / "sweep")
    listed = json.loads((folder / "sweep.json").read_text())["cells"]
    records = sweep_records(folder)
    assert capsys.readouterr().err == ""  # no record left out
    assert [(r["tile_size"], r["overlap"]) for r in records] == [(c["tile_size"], c["overlap"]) for c in listed]
    assert all(r["status"] == "ok" and r["dataset"] == "office" for r in records)


def test_a_record_of_another_grid_is_still_left_out(tmp_path, capsys):
    folder = shutil.copytree(DEMO_SWEEP, tmp_path / "sweep")
    document = json.loads((folder / "sweep.json").read_text())
    document["cells"] = document["cells"][:3]
    (folder / "sweep.json").write_text(json.dumps(document))
    records = sweep_records(folder)
    assert len(records) == 3
    assert "1 cell record in cells/ not of the grid" in capsys.readouterr().err
