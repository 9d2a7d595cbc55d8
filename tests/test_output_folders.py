"""Output folders of ``ifmi evaluate`` and ``ifmi report``: refused when foreign, written as one set."""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

import ifmi.io.atomic
import ifmi.io.results
from ifmi.cli import main
from ifmi.errors import OutputError
from ifmi.io.atomic import check_output_folder, write_folder
from ifmi.io.tum import Trajectory, write_tum
from ifmi.experiments.report import is_report_dir
from ifmi.geometry.rotations import matrix_from_rpy

# Frames of the synthetic run (tiny: the tests are about files, not numbers).
N_FRAMES = 8


def _run(tmp_path, *, side_files: bool = True):
    """Ground truth and an estimate (yaw off by 0.01 rad) with or without side files."""
    rpy = np.zeros((N_FRAMES, 3))
    rpy[:, 2] = np.linspace(0.0, 0.3, N_FRAMES)
    stamps = np.arange(N_FRAMES, dtype=float)
    write_tum(tmp_path / "groundtruth.txt",
              Trajectory(stamps, np.zeros((N_FRAMES, 3)), matrix_from_rpy(rpy)))
    rpy[1:, 2] += 0.01
    write_tum(tmp_path / "est.txt", Trajectory(stamps, np.zeros((N_FRAMES, 3)), matrix_from_rpy(rpy)))
    for name in ("est.frames.csv", "est.config.json"):
        (tmp_path / name).unlink(missing_ok=True)
    if side_files:
        rows = ["frame,reference_frame,success,reason,n_correspondences,n_inliers,seconds"]
        rows += [f"{k},{max(k - 1, 0)},true,ok,50,40,0.01" for k in range(N_FRAMES)]
        (tmp_path / "est.frames.csv").write_text("\n".join(rows) + "\n")
        (tmp_path / "est.config.json").write_text(json.dumps({"method": "orb", "config": {}}))


def _evaluate(tmp_path, out, capsys):
    code = main(["evaluate", "--gt", str(tmp_path / "groundtruth.txt"), "--est",
                 str(tmp_path / "est.txt"), "--out", str(out), "--json"])
    return code, capsys.readouterr().err.strip()


def _contents(folder):
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _hidden_leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def test_evaluate_refuses_a_folder_of_the_users(tmp_path, capsys):
    _run(tmp_path)
    proj = tmp_path / "proj"
    proj.mkdir()
    (proj / "config.json").write_text('{"mine": 1}')
    (proj / "frames.csv").write_text("a,b\n")
    code, err = _evaluate(tmp_path, proj, capsys)
    assert code == 1 and len(err.splitlines()) == 1
    assert err.startswith(f"ifmi evaluate: error: cannot write {proj}: holds config.json, frames.csv "
                          "but is not an evaluation folder")
    assert _contents(proj) == {Path("config.json"): b'{"mine": 1}', Path("frames.csv"): b"a,b\n"}


def test_evaluate_refuses_a_foreign_evaluation_json(tmp_path, capsys):
    _run(tmp_path)
    proj = tmp_path / "proj"
    proj.mkdir()
    (proj / "evaluation.json").write_text('{"kind": "other-tool"}')
    code, err = _evaluate(tmp_path, proj, capsys)
    assert code == 1 and "but is not an evaluation folder" in err
    assert (proj / "evaluation.json").read_text() == '{"kind": "other-tool"}'


def test_evaluate_writes_into_an_empty_folder(tmp_path, capsys):
    _run(tmp_path)
    (tmp_path / "empty").mkdir()
    assert _evaluate(tmp_path, tmp_path / "empty", capsys)[0] == 0
    assert (tmp_path / "empty" / "evaluation.json").is_file()
    assert _hidden_leftovers(tmp_path) == []


def test_evaluate_rewrites_its_own_folder_as_a_new_set_keeping_the_users_files(tmp_path, capsys):
    _run(tmp_path)
    out = tmp_path / "eval"
    assert _evaluate(tmp_path, out, capsys)[0] == 0
    (out / "notes.txt").write_text("mine")
    _run(tmp_path, side_files=False)
    assert _evaluate(tmp_path, out, capsys)[0] == 0
    # The side files of the earlier run are not left beside the new evaluation.
    assert sorted(p.name for p in out.iterdir()) == ["evaluation.json", "notes.txt",
                                                      "per_frame.csv", "per_frame.npz"]
    assert (out / "notes.txt").read_text() == "mine"
    assert _hidden_leftovers(tmp_path) == []


def test_evaluate_failing_midway_leaves_the_old_folder_intact(tmp_path, capsys, monkeypatch):
    _run(tmp_path)
    out = tmp_path / "eval"
    assert _evaluate(tmp_path, out, capsys)[0] == 0
    before = _contents(out)
    _run(tmp_path, side_files=False)

    def full_disk(path, obj):
        raise OutputError(path, "No space left on device")

    # per_frame.npz and per_frame.csv are written, then evaluation.json fails.
    monkeypatch.setattr(ifmi.io.results, "atomic_write_json", full_disk)
    code, err = _evaluate(tmp_path, out, capsys)
    assert code == 1
    assert err == f"ifmi evaluate: error: cannot write {out}: No space left on device"
    assert _contents(out) == before
    assert _hidden_leftovers(tmp_path) == []


def test_failed_swap_puts_the_old_folder_and_the_users_files_back(tmp_path, capsys, monkeypatch):
    _run(tmp_path)
    out = tmp_path / "eval"
    assert _evaluate(tmp_path, out, capsys)[0] == 0
    (out / "notes.txt").write_text("mine")
    before = _contents(out)

    def refused(staging, target):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(ifmi.io.atomic, "_swap_folder", refused)
    code, err = _evaluate(tmp_path, out, capsys)
    assert code == 1 and err == f"ifmi evaluate: error: cannot write {out}: Operation not permitted"
    assert _contents(out) == before
    assert _hidden_leftovers(tmp_path) == []


def test_write_folder_without_an_atomic_exchange_uses_two_renames(tmp_path, monkeypatch):
    monkeypatch.setattr(ifmi.io.atomic, "_exchange", lambda a, b: False)
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    (out / "notes.txt").write_text("mine")
    write_folder(out, lambda folder: (folder / "new.txt").write_text("new"), replaces=("old.txt",))
    assert sorted(p.name for p in out.iterdir()) == ["new.txt", "notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_write_folder_warns_when_the_old_folder_cannot_be_removed(tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    monkeypatch.setattr(ifmi.io.atomic.shutil, "rmtree", lambda *args, **kwargs: None)
    with pytest.warns(UserWarning, match="previous folder could not be removed"):
        write_folder(out, lambda folder: (folder / "new.txt").write_text("new"), replaces=("old.txt",))
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]


def test_new_output_folder_gets_the_usual_mode_not_that_of_a_temporary(tmp_path):
    out = tmp_path / "out"
    write_folder(out, lambda folder: (folder / "a.txt").write_text("a"), replaces=("a.txt",))
    umask = os.umask(0o022)
    os.umask(umask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~umask


def test_output_folder_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="exists and is not a folder"):
        check_output_folder(tmp_path / "f", is_own=lambda p: True, what="an output folder")


def _evaluation(tmp_path, capsys):
    _run(tmp_path)
    assert _evaluate(tmp_path, tmp_path / "eval", capsys)[0] == 0
    return tmp_path / "eval"


def test_report_refuses_a_folder_of_the_users(tmp_path, capsys):
    evaluation = _evaluation(tmp_path, capsys)
    proj = tmp_path / "proj"
    proj.mkdir()
    (proj / "README.md").write_text("# my project\n")
    code = main(["report", str(evaluation), "--out", str(proj), "--no-motion-flow"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1
    assert err.startswith(f"ifmi report: error: cannot write {proj}: holds README.md but is not a "
                          "report folder")
    assert sorted(p.name for p in proj.iterdir()) == ["README.md"]
    assert (proj / "README.md").read_text() == "# my project\n"


@pytest.mark.slow
def test_report_rewrites_its_own_folder(tmp_path, capsys):
    evaluation = _evaluation(tmp_path, capsys)
    out = tmp_path / "report"
    assert main(["report", str(evaluation), "--out", str(out), "--no-motion-flow"]) == 0
    assert is_report_dir(out)
    assert main(["report", str(evaluation), "--out", str(out), "--no-motion-flow"]) == 0
    assert json.loads((out / "report.json").read_text())["kind"] == "ifmi-report"


def test_reports_written_before_the_kind_existed_are_recognised(tmp_path):
    keys = {"title": "t", "scenes": {}, "average": {}, "machine": {}, "versions": {}}
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "report.json").write_text(json.dumps(keys))
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "report.json").write_text(json.dumps({"kind": "other", **keys}))
    assert is_report_dir(tmp_path / "old") and not is_report_dir(tmp_path / "other")


def test_failed_copy_of_many_files_is_one_short_line_naming_the_first(tmp_path):
    """copytree gathers one (source, destination, reason) per file; a full disk fails them all."""
    import shutil

    failures = [(f"/data/run/{k}.png", f"/out/.tmp/{k}.png", "[Errno 28] No space left on device")
                for k in range(40)]

    def fill(folder):
        raise shutil.Error(failures)

    with pytest.raises(OutputError) as caught:
        write_folder(tmp_path / "report", fill, replaces=())
    assert str(caught.value) == (f"cannot write {tmp_path / 'report'}: [Errno 28] No space left on device "
                                 "(copying /data/run/0.png and 39 more)")
    assert not (tmp_path / "report").exists() and list(tmp_path.iterdir()) == []
