"""``ifmi report``: tables, figures and provenance from evaluation and sweep folders."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from ifmi.cli import main
from ifmi.evaluation.trajectory_files import evaluate_files
from ifmi.io.atomic import atomic_write_json
from ifmi.io.tum import Trajectory, write_tum
from ifmi.experiments.report import average_table, baseline_ratios, find_results, scene_tables
from ifmi.io.results import read_evaluation
from ifmi.geometry.rotations import matrix_from_rpy
from ifmi.experiments.sweep import SweepCell, config_digest

# Yaw error (radians) and time per frame (seconds) given to each synthetic method.
METHODS = {"ifmi": (0.002, 0.01), "orb": (0.02, 0.03), "akaze": (0.01, 0.2)}


def _make_results(root, scenes=("office", "lawn"), n=15):
    for s, scene in enumerate(scenes):
        data = root / "data" / f"{scene}_20"
        data.mkdir(parents=True)
        (data / "meta.json").write_text(json.dumps({"scene": scene}))
        rpy = np.zeros((n, 3))
        rpy[:, 0] = 0.1 * np.sin(np.arange(n) / 3)
        rpy[:, 2] = np.linspace(0, 0.4, n)
        gt = Trajectory(np.arange(n, dtype=float), np.zeros((n, 3)), matrix_from_rpy(rpy))
        write_tum(data / "groundtruth.txt", gt)
        for method, (err, seconds) in METHODS.items():
            est_rpy = rpy.copy()
            est_rpy[1:, 2] += err * (1 + s)
            est_dir = root / "runs" / scene
            est_dir.mkdir(parents=True, exist_ok=True)
            est = est_dir / f"{method}.txt"
            write_tum(est, Trajectory(gt.timestamps, gt.positions, matrix_from_rpy(est_rpy)))
            rows = ["frame,reference_frame,success,reason,n_correspondences,n_inliers,seconds"]
            rows += [f"{k},{max(k - 1, 0)},true,,40,30,{seconds}" for k in range(n)]
            (est_dir / f"{method}.frames.csv").write_text("\n".join(rows) + "\n")
            (est_dir / f"{method}.config.json").write_text(
                json.dumps({"method": method, "dataset": str(data), "config": {}}))
            evaluate_files(data / "groundtruth.txt", est, out_dir=root / "eval" / scene / method)
    # A motion-flow sample beside the iFMI evaluation of the first scene.
    rng = np.random.default_rng(0)
    pano = rng.integers(0, 255, size=(40, 200)).astype(np.float32)
    pts = np.column_stack([rng.uniform(5, 35, 10), rng.uniform(0, 199, 10)])
    np.savez(root / "eval" / scenes[0] / "ifmi" / "motion_flow.npz", panorama_a=pano,
             panorama_b=np.roll(pano, 3, axis=1), points_a=pts, points_b=pts + [0, 3],
             tile_centers=pts, tile_size=np.array(20), frames=np.array([0, 1]))
    # A finished sweep with one failed cell.
    sweep = root / "sweep"
    cells = [SweepCell(str(root / "data" / "office_20"), "ifmi", t, o, label="office_20")
             for t, o in [(32.0, 0.0), (32.0, 0.5), (64.0, 0.0), (64.0, 0.5)]]
    atomic_write_json(sweep / "sweep.json", {"kind": "ifmi-sweep", "cells": [c.__dict__ for c in cells],
                                             "base_config": {}, "scheduler": "synchronous"})
    for i, cell in enumerate(cells):
        rec = {"cell_id": cell.cell_id, "dataset": "office_20", "method": "ifmi", "tile_size": cell.tile_size,
               "overlap": cell.overlap, "status": "ok", "error": "", "rmse_mean_rad": 0.001 * (i + 1),
               "rmse_geodesic_rad": 0.002, "time_per_frame_s": 0.01 * (i + 1), "failures": 0,
               "config_digest": config_digest({})}
        if i == 3:
            rec = {**{k: rec[k] for k in ("cell_id", "dataset", "method", "tile_size", "overlap")},
                   "status": "failed", "error": "ValueError: tile larger than panorama"}
        atomic_write_json(_cell_file(sweep, cell), rec)
    return root


def _cell_file(sweep, cell):
    return sweep / "cells" / f"{cell.cell_id}.json"


def _add_cell(sweep, tile_size, overlap):
    """A cell added to the grid of a sweep's sweep.json; its record file."""
    doc = json.loads((sweep / "sweep.json").read_text())
    cell = SweepCell(doc["cells"][0]["dataset"], "ifmi", tile_size, overlap, label="office_20")
    doc["cells"].append(cell.__dict__)
    atomic_write_json(sweep / "sweep.json", doc)
    return _cell_file(sweep, cell)


def test_tables_and_ratios(tmp_path):
    root = _make_results(tmp_path)
    found = find_results([root / "eval"])
    assert len(found.evaluations) == 6 and not found.sweeps
    tables = scene_tables([read_evaluation(p) for p in found.evaluations])
    assert list(tables) == ["lawn", "office"]
    assert list(tables["office"]) == ["ifmi", "orb", "akaze"]
    n = 15
    for s, scene in enumerate(("office", "lawn")):
        for method, (err, seconds) in METHODS.items():
            row = tables[scene][method]
            assert row["rmse_yaw_rad"] == pytest.approx(err * (1 + s) * np.sqrt((n - 1) / n), rel=1e-6)
            assert row["time_per_frame_s"] == pytest.approx(seconds)
    avg = average_table(tables)
    yaw = [err * (1 + s) * np.sqrt(14 / 15) for s in range(2) for err in [METHODS["orb"][0]]]
    assert avg["orb"]["rmse_yaw_rad"]["mean"] == pytest.approx(np.mean(yaw), rel=1e-6)
    assert avg["orb"]["rmse_yaw_rad"]["std"] == pytest.approx(np.std(yaw), rel=1e-6)
    ratios = baseline_ratios(tables)
    assert ratios["office"]["rmse_ratio_to_best_baseline"] == pytest.approx(0.2, rel=1e-6)
    assert ratios["office"]["time_ratio_akaze"] == pytest.approx(0.05)


@pytest.mark.slow
def test_report_cli_writes_markdown_html_figures(tmp_path, capsys):
    root = _make_results(tmp_path)
    out = tmp_path / "report"
    assert main(["report", str(root / "eval"), str(root / "sweep"), "--out", str(out)]) == 0
    md = (out / "README.md").read_text()
    html = (out / "index.html").read_text()
    assert "Table 1" in md and "| ifmi |" in md
    # Results only: no thresholds of this project's own in a user's report.
    assert "iFMI against the baselines" in md and "Target" not in md
    assert "μ(ε)" in md and "<table>" in html
    for scene in ("office", "lawn"):
        assert (out / "figures" / f"rpy_{scene}.png").stat().st_size > 1000
        assert f"figures/rpy_{scene}.png" in md and f"figures/rpy_{scene}.png" in html
    assert (out / "figures" / "motion_flow_office.png").is_file()
    assert "failed: ValueError: tile larger than panorama" in md
    heatmaps = list((out / "figures").glob("heatmap_*.png"))
    assert len(heatmaps) == 2
    doc = json.loads((out / "report.json").read_text())
    assert doc["machine"]["cores"] >= 1 and doc["versions"]["numpy"]
    assert doc["scenes"]["office"]["ifmi"]["rmse_yaw_rad"] == pytest.approx(
        0.002 * np.sqrt(14 / 15), rel=1e-6)
    assert len(doc["sweeps"][0]["cells"]) == 4
    assert "Machine and versions" in md
    assert "report written to" in capsys.readouterr().out
    assert len(doc["series"]["lawn"]["orb"]["yaw_est"]) == 15
    # The report carries its data: it rebuilds from its own data folder.
    assert (out / "data" / "eval" / "office" / "ifmi" / "motion_flow.npz").is_file()
    assert len(list((out / "data" / "sweep" / "sweep" / "cells").glob("*.json"))) == 4
    rebuilt = tmp_path / "rebuilt"
    assert main(["report", str(out / "data"), "--out", str(rebuilt)]) == 0
    again = json.loads((rebuilt / "report.json").read_text())
    assert again["scenes"]["office"]["orb"]["rmse_yaw_rad"] == doc["scenes"]["office"]["orb"]["rmse_yaw_rad"]
    assert again["average"] == doc["average"]
    assert (rebuilt / "figures" / "motion_flow_office.png").is_file()


def test_report_of_missing_path_is_one_line_error(tmp_path, capsys):
    code = main(["report", str(tmp_path / "nothing"), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "results path not found" in err and len(err.splitlines()) == 1


def test_report_of_folder_without_results_is_one_line_error(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    code = main(["report", str(tmp_path / "empty"), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "no evaluation.json or sweep.json" in err


@pytest.mark.slow
def test_failed_report_leaves_the_old_one_intact(tmp_path, capsys, monkeypatch):
    import ifmi.experiments.report

    root = _make_results(tmp_path, scenes=("office",))
    out = tmp_path / "report"
    assert main(["report", str(root / "eval"), "--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ifmi.experiments.report, "_sweep_blocks", broken)
    code = main(["report", str(root / "eval"), str(root / "sweep"), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err == f"ifmi report: error: cannot write {out}: No space left on device"
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "eval", "report", "runs", "sweep"]


@pytest.mark.slow
def test_rebuilt_report_keeps_files_it_does_not_write(tmp_path):
    root = _make_results(tmp_path, scenes=("office",))
    out = tmp_path / "report"
    assert main(["report", str(root / "eval"), "--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")
    (out / "figures" / "stale.png").write_bytes(b"old")
    assert main(["report", str(root / "eval"), str(root / "sweep"), "--out", str(out)]) == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert not (out / "figures" / "stale.png").exists()
    assert list((out / "figures").glob("heatmap_*.png"))


def test_report_errors_name_the_subcommand(tmp_path, capsys):
    root = _make_results(tmp_path, scenes=("office",))
    (tmp_path / "file").write_text("x")
    code = main(["report", str(root / "eval"), "--out", str(tmp_path / "file" / "r"),
                 "--command", "make report"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1
    assert err.startswith("ifmi report: error: cannot write ") and "None" not in err


def test_any_method_gets_a_row_and_a_colour(tmp_path):
    from ifmi.tracking.methods import method_colors

    root = _make_results(tmp_path, scenes=("office",))
    est_dir = root / "runs" / "office"
    est = est_dir / "ifmi.txt"
    plugin = "sift_plugin:sift_front_end"
    (est_dir / "sift.txt").write_bytes(est.read_bytes())
    (est_dir / "sift.frames.csv").write_bytes((est_dir / "ifmi.frames.csv").read_bytes())
    (est_dir / "sift.config.json").write_text(json.dumps(
        {"method": plugin, "dataset": str(root / "data" / "office_20"), "config": {}}))
    evaluate_files(root / "data" / "office_20" / "groundtruth.txt", est_dir / "sift.txt",
                   out_dir=root / "eval" / "office" / "sift")
    out = tmp_path / "report"
    assert main(["report", str(root / "eval"), "--out", str(out)]) == 0
    records = [read_evaluation(p) for p in find_results([root / "eval"]).evaluations]
    assert list(scene_tables(records)["office"]) == ["ifmi", "orb", "akaze", plugin]
    md = (out / "README.md").read_text()
    assert f"| {plugin} |" in md and plugin in md.split("Average over scenes")[1].splitlines()[2]
    colors = method_colors(["ifmi", "orb", "akaze", plugin, "zz"])
    assert len(set(colors.values())) == 5 and colors["ifmi"] == "tab:red"
    assert method_colors([plugin, "orb"])[plugin] == colors[plugin]


def test_truncated_sweep_cell_is_skipped_with_a_warning(tmp_path, capsys):
    root = _make_results(tmp_path)
    c4 = _add_cell(root / "sweep", 96.0, 0.0)
    c1, c2, c3 = sorted((root / "sweep" / "cells").glob("*.json"))[1:]
    c1.write_text('{"cell_id": "c1", "dat')
    c2.write_text("[]")
    c3.write_text('{"cell_id": "c3", "status": "ok"}')
    c4.write_text("[" * 100_000 + "]" * 100_000)  # was a RecursionError
    assert main(["report", str(root / "sweep"), "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert f"{c1.name}: unreadable sweep cell" in err and f"{c2.name}: expected a JSON object" in err
    assert f"{c4.name}: unreadable sweep cell (RecursionError); skipped" in err
    assert f"{c3.name}: sweep cell without dataset, method, tile_size, overlap; skipped" in err
    assert "left out" not in err
    doc = json.loads((tmp_path / "r" / "report.json").read_text())
    assert len(doc["sweeps"][0]["cells"]) == 1


def test_report_shows_the_grid_and_configuration_of_sweep_json_only(tmp_path, capsys):
    # A rerun in one folder with another grid or --config left the earlier records in cells/, and the
    # report put them in one table and heatmap with the new ones, exit 0 (sweep.csv had the new grid).
    root = _make_results(tmp_path, scenes=("office",))
    sweep = root / "sweep"
    doc = json.loads((sweep / "sweep.json").read_text())
    earlier = SweepCell(doc["cells"][0]["dataset"], "ifmi", 48.0, 0.0, label="office_20")
    first = json.loads(sorted((sweep / "cells").glob("*.json"))[0].read_text())
    atomic_write_json(_cell_file(sweep, earlier), {**first, "cell_id": earlier.cell_id, "tile_size": 48.0})
    other_config = _add_cell(sweep, 96.0, 0.0)
    atomic_write_json(other_config, {**first, "tile_size": 96.0, "config_digest": config_digest({"x": 1})})
    assert main(["report", str(sweep), "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err.strip()
    assert err == (f"warning: {sweep}: 2 cell records in cells/ not of the grid and base configuration of "
                   "sweep.json (5 cells), left out: from earlier sweeps in this folder, or an unfinished rerun")
    cells = json.loads((tmp_path / "r" / "report.json").read_text())["sweeps"][0]["cells"]
    assert sorted((c["tile_size"], c["overlap"]) for c in cells) == [(32, 0), (32, 0.5), (64, 0), (64, 0.5)]


def test_report_refuses_a_sweep_json_without_its_grid(tmp_path, capsys):
    root = _make_results(tmp_path, scenes=("office",))
    doc = json.loads((root / "sweep" / "sweep.json").read_text())
    atomic_write_json(root / "sweep" / "sweep.json", {**doc, "cells": "all"})
    assert main(["report", str(root / "sweep"), "--out", str(tmp_path / "r")]) == 2
    assert capsys.readouterr().err.strip() == (f"ifmi report: error: {root / 'sweep' / 'sweep.json'}: cells: "
                                               'expected a list of cells, got "all"')


@pytest.mark.slow
def test_report_computes_the_motion_flow_sample_once_on_request(tmp_path):
    from ifmi.io.results import read_motion_flow, write_estimate_run
    from ifmi.pipeline import EstimateConfig, SequenceEstimate
    from ifmi.io.tum import read_tum
    pytest.importorskip("skimage")
    from ifmi.synthetic import (example_band_px, example_omni_model, synthetic_sequence,
                                write_synthetic_dataset)

    model = example_omni_model(160)
    data = write_synthetic_dataset(tmp_path / "office", synthetic_sequence(
        model, 3, seed=1, band_px=example_band_px(model)))
    gt = read_tum(data / "groundtruth.txt")
    # An exact "estimate" suffices: the sample is computed from the dataset and the config.
    run = SequenceEstimate(trajectory=gt, frames=(), config=EstimateConfig(), method="ifmi")
    est = write_estimate_run(tmp_path / "runs" / "ifmi.txt", run, dataset_dir=data)
    (tmp_path / "runs" / "ifmi.frames.csv").unlink()
    evaluate_files(data / "groundtruth.txt", est, out_dir=tmp_path / "eval" / "ifmi")
    assert not (tmp_path / "eval" / "ifmi" / "motion_flow.npz").exists()
    assert main(["report", str(tmp_path / "eval"), "--out", str(tmp_path / "plain"),
                 "--no-motion-flow"]) == 0
    assert not list((tmp_path / "plain" / "figures").glob("motion_flow_*"))
    assert main(["report", str(tmp_path / "eval"), "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "figures" / "motion_flow_office.png").is_file()
    stored = tmp_path / "r" / "data" / "eval" / "office" / "ifmi" / "motion_flow.npz"
    assert len(read_motion_flow(stored)["points_a"]) >= 3


def test_report_out_that_is_a_file_is_one_line_error(tmp_path, capsys):
    root = _make_results(tmp_path, scenes=("office",))
    (tmp_path / "r").write_text("not a folder")
    code = main(["report", str(root / "eval"), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err == f"ifmi report: error: cannot write {tmp_path / 'r'}: exists and is not a folder"
    assert (tmp_path / "r").read_text() == "not a folder"


@pytest.mark.slow
def test_report_into_a_symlinked_folder_writes_through_the_link(tmp_path):
    root = _make_results(tmp_path, scenes=("office",))
    real = tmp_path / "real_report"
    real.mkdir()
    (tmp_path / "link").symlink_to(real)
    assert main(["report", str(root / "eval"), "--out", str(tmp_path / "link")]) == 0
    (real / "notes.txt").write_text("mine")
    assert main(["report", str(root / "eval"), "--out", str(tmp_path / "link")]) == 0
    assert (tmp_path / "link").is_symlink()
    assert (real / "README.md").is_file() and (real / "notes.txt").read_text() == "mine"


def test_unreadable_dataset_gives_a_motion_flow_warning_not_an_error(tmp_path, capsys):
    root = _make_results(tmp_path, scenes=("lawn",))
    data = root / "data" / "lawn_20"
    (data / "images").mkdir()
    # The iFMI evaluation of this scene has a configuration but no stored sample.
    (root / "eval" / "lawn" / "ifmi" / "motion_flow.npz").unlink()
    (root / "eval" / "lawn" / "ifmi" / "config.json").write_text(json.dumps(
        {"method": "ifmi", "dataset": str(data), "config": {}}))
    assert main(["report", str(root / "eval"), "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "warning: no motion-flow figure for lawn:" in err and "calib" in err
    assert not list((tmp_path / "r" / "figures").glob("motion_flow_*"))


@pytest.mark.slow
def test_one_scene_from_two_dataset_folders_gets_two_rows_figures_and_folders(tmp_path):
    site_a = _make_results(tmp_path / "site_a", scenes=("office",))
    site_b = _make_results(tmp_path / "site_b", scenes=("lawn", "office"))  # office's errors doubled here
    out = tmp_path / "report"
    assert main(["report", str(site_a / "eval"), str(site_b / "eval"), "--out", str(out)]) == 0
    doc = json.loads((out / "report.json").read_text())
    names = {"site_a": "office-site_a_data_office_20", "site_b": "office-site_b_data_office_20"}
    assert sorted(doc["scenes"]) == sorted(["lawn", *names.values()])
    yaw = {site: doc["scenes"][name]["ifmi"]["rmse_yaw_rad"] for site, name in names.items()}
    assert yaw["site_b"] == pytest.approx(2 * yaw["site_a"], rel=1e-6)
    for name in names.values():
        assert (out / "figures" / f"rpy_{name}.png").is_file()
        assert (out / "data" / "eval" / name / "orb" / "evaluation.json").is_file()
    rebuilt = tmp_path / "rebuilt"
    assert main(["report", str(out / "data"), "--out", str(rebuilt)]) == 0
    again = json.loads((rebuilt / "report.json").read_text())
    assert sorted(again["scenes"]) == sorted(doc["scenes"])
    assert again["scenes"][names["site_b"]]["ifmi"]["rmse_yaw_rad"] == yaw["site_b"]


def _report_error(tmp_path, capsys, root):
    out = tmp_path / "r"
    code = main(["report", str(root / "eval"), "--out", str(out), "--no-motion-flow"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert not out.exists() and not list(tmp_path.glob(".r.new-*"))
    return err


def test_truncated_per_frame_arrays_are_one_line_error(tmp_path, capsys):
    root = _make_results(tmp_path, scenes=("office",))
    npz = root / "eval" / "office" / "orb" / "per_frame.npz"
    npz.write_bytes(npz.read_bytes()[:100])
    err = _report_error(tmp_path, capsys, root)
    assert err == (f"ifmi report: error: {npz}: cannot read per-frame arrays (truncated or corrupt "
                   "file; expected a NumPy .npz archive)")


@pytest.mark.parametrize("edit, expected", [
    (lambda a: {"timestamp": a["timestamp"]},
     "missing array(s) roll_gt, roll_est, pitch_gt, pitch_est, yaw_gt, yaw_est; got timestamp"),
    (lambda a: {**a, "timestamp": a["timestamp"][:-1]},
     "array timestamp: 14 frames, but evaluation.json has 15 associated frames; expected one row "
     "per associated frame"),
    (lambda a: {**a, "timestamp": np.zeros((15, 2))},
     "array timestamp: expected one number per frame, got float64 of shape (15, 2)"),
])
def test_per_frame_arrays_that_do_not_fit_the_summary_are_one_line_error(tmp_path, capsys, edit,
                                                                         expected):
    root = _make_results(tmp_path, scenes=("office",))
    npz = root / "eval" / "office" / "orb" / "per_frame.npz"
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(npz, **edit(arrays))
    assert _report_error(tmp_path, capsys, root) == f"ifmi report: error: {npz}: {expected}"


def _with_row(array, row, value):
    out = np.array(array, dtype=np.float64)
    out[row] = value
    return out


@pytest.mark.parametrize("edit, expected", [
    (lambda a: {**a, "timestamp": _with_row(a["timestamp"], 3, np.inf)},
     "array timestamp: value inf at row 3; expected finite numbers"),
    (lambda a: {**a, "roll_est": _with_row(a["roll_est"], 2, np.nan)},
     "array roll_est: value nan at row 2; expected finite numbers"),
    (lambda a: {**a, "timestamp": _with_row(a["timestamp"], 4, a["timestamp"][2])},
     "array timestamp: 2 at row 4 follows 3; expected increasing timestamps"),
    (lambda a: {**a, "yaw_gt": _with_row(a["yaw_gt"], 5, 90.0)},
     "array yaw_gt: 90 at row 5; expected an angle in radians within [-pi, pi]"),
])
def test_per_frame_arrays_a_report_cannot_draw_are_one_line_error(tmp_path, capsys, edit, expected):
    # They were drawn as gaps, zigzags or a flat line at 90 "rad" under a sound summary, with exit 0.
    root = _make_results(tmp_path, scenes=("office",))
    npz = root / "eval" / "office" / "orb" / "per_frame.npz"
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(npz, **edit(arrays))
    assert _report_error(tmp_path, capsys, root).startswith(f"ifmi report: error: {npz}: {expected}")


def test_frame_count_past_64_bits_is_one_line_error(tmp_path, capsys):
    root = _make_results(tmp_path, scenes=("office",))
    doc_path = root / "eval" / "office" / "orb" / "evaluation.json"
    doc = json.loads(doc_path.read_text())
    doc["summary"]["frames"].update(ground_truth=10 ** 30, estimate=10 ** 30, associated=10 ** 30)
    doc_path.write_text(json.dumps(doc))
    npz = doc_path.with_name("per_frame.npz")
    assert _report_error(tmp_path, capsys, root) == (
        f"ifmi report: error: {npz}: array timestamp: 15 frames, but evaluation.json has {10 ** 30} "
        "associated frames; expected one row per associated frame")


@pytest.mark.parametrize("edit, expected", [
    (lambda d: d.update(dataset_meta="oops"),
     'field dataset_meta: expected an object {...} or null, got a string "oops"'),
    (lambda d: d.update(scene="../../elsewhere"),
     'field scene: expected a name (a string without / or \\) or null, got a string '
     '"../../elsewhere"'),
    (lambda d: d.update(method=["orb"]),
     'field method: expected a name (a string without / or \\) or null, got an array ["orb"]'),
    (lambda d: d.update(groundtruth_path=3),
     "field groundtruth_path: expected a string or null, got a number 3"),
    (lambda d: d.pop("summary"), "field summary: missing; expected an object {...}"),
    (lambda d: d["summary"]["frames"].update(associated="15"),
     'field summary.frames.associated: expected a whole number >= 0, got a string "15"'),
    (lambda d: d["summary"]["axes"].pop("yaw"), "field summary.axes.yaw: missing; expected an "
                                                "object {...}"),
    (lambda d: d["summary"]["axes"]["roll"].update(rmse="small"),
     'field summary.axes.roll.rmse: expected a number or null, got a string "small"'),
    (lambda d: d["summary"]["geodesic"].update(rmse=-1.0),
     "field summary.geodesic.rmse: expected a number >= 0 (errors and times are never negative) or "
     "null, got a number -1.0"),
    (lambda d: d["summary"]["failures"].update(count=50),
     "field summary.failures.count: expected at most summary.failures.frames (15), got a number 50"),
    (lambda d: d["summary"]["frames"].update(associated=16),
     "field summary.frames.associated: expected at most summary.frames.ground_truth (15), got a number 16"),
    (lambda d: d["summary"].update(failures=2),
     "field summary.failures: expected an object {...} or null, got a number 2"),
    (lambda d: d["summary"]["time"].update(mean_s=[0.1]),
     "field summary.time.mean_s: expected a number or null, got an array [0.1]"),
    # Figures cannot draw it (Matplotlib raised TypeError).
    (lambda d: d.update(scene="d\udcff"),
     'field scene: expected a name without lone surrogates (\\ud800 to \\udfff), got a string "d\\udcff"'),
])
def test_evaluation_json_field_of_the_wrong_kind_is_one_line_error(tmp_path, capsys, edit,
                                                                   expected):
    root = _make_results(tmp_path, scenes=("office",))
    doc_path = root / "eval" / "office" / "orb" / "evaluation.json"
    doc = json.loads(doc_path.read_text())
    edit(doc)
    doc_path.write_text(json.dumps(doc))
    assert _report_error(tmp_path, capsys, root) == f"ifmi report: error: {doc_path}: {expected}"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_file_of_an_evaluation_that_is_a_fifo_is_one_line_error(tmp_path, capsys):
    # The read waited for a writer forever.
    root = _make_results(tmp_path, scenes=("office",))
    path = root / "eval" / "office" / "orb" / "per_frame.npz"
    path.unlink()
    os.mkfifo(path)
    assert (_report_error(tmp_path, capsys, root)
            == f"ifmi report: error: {path}: is a FIFO, device or socket, not a file of an evaluation; "
               "expected a regular file")


def test_evaluation_json_nested_too_deeply_is_one_line_error(tmp_path, capsys):
    # The JSON decoder's RecursionError was a traceback.
    root = _make_results(tmp_path, scenes=("office",))
    doc_path = root / "eval" / "office" / "orb" / "evaluation.json"
    doc_path.write_text("[" * 100_000 + "]" * 100_000)
    assert (_report_error(tmp_path, capsys, root)
            == f"ifmi report: error: {doc_path}: invalid JSON: nested too deeply")


def test_evaluation_with_a_time_stored_as_null_reads_as_unknown(tmp_path):
    # Written before an unknown time was stored as null: a time object of nulls.
    root = _make_results(tmp_path, scenes=("office",))
    doc_path = root / "eval" / "office" / "orb" / "evaluation.json"
    doc = json.loads(doc_path.read_text())
    doc["summary"]["time"] = {"mean_s": None, "median_s": None, "total_s": 0.0, "frames": 0}
    doc_path.write_text(json.dumps(doc))
    assert main(["report", str(root / "eval"), "--out", str(tmp_path / "r"),
                 "--no-motion-flow"]) == 0
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["scenes"]["office"]["orb"]["time_per_frame_s"] is None
    assert report["scenes"]["office"]["ifmi"]["time_per_frame_s"] == pytest.approx(0.01)


@pytest.mark.parametrize("damage, expected", [
    (lambda p: p.write_bytes(p.read_bytes()[:200]),
     "cannot read motion-flow file (truncated or corrupt file; expected a NumPy .npz archive)"),
    (lambda p: np.savez(p, **{**dict(np.load(p)), "tile_size": np.array([20, 20])}),
     "array tile_size: expected numbers of shape (), got int64 of shape (2,)"),
    (lambda p: np.savez(p, **{**dict(np.load(p)), "points_b": np.zeros((4, 2))}),
     "points_a is (10, 2), points_b (4, 2); expected the same shape"),
])
@pytest.mark.slow
def test_bad_motion_flow_sample_is_one_line_error(tmp_path, capsys, damage, expected):
    root = _make_results(tmp_path, scenes=("office",))
    sample = root / "eval" / "office" / "ifmi" / "motion_flow.npz"
    damage(sample)
    code = main(["report", str(root / "eval"), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == f"ifmi report: error: {sample}: {expected}"
    assert not (tmp_path / "r").exists() and not list(tmp_path.glob(".r.new-*"))


def test_two_evaluations_of_one_method_on_one_scene_are_one_line_error(tmp_path, capsys):
    # Both would be the scene's one row for the method: the report showed the last one only.
    root = _make_results(tmp_path / "run1", scenes=("office",))
    again = tmp_path / "run2" / "ifmi"
    evaluate_files(root / "data" / "office_20" / "groundtruth.txt", root / "runs" / "office" / "ifmi.txt",
                   out_dir=again)
    out = tmp_path / "r"
    code = main(["report", str(root / "eval"), str(again), "--out", str(out), "--no-motion-flow"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert err == (f"ifmi report: error: {again}: evaluates method ifmi on scene office, as "
                   f"{root / 'eval' / 'office' / 'ifmi'} does; expected one evaluation per scene and "
                   "method (report the runs separately)")
    assert not out.exists() and not list(tmp_path.glob(".r.*"))


def test_report_inside_an_evaluation_it_reads_is_one_line_error(tmp_path, capsys):
    # The evaluation folder would be copied into itself (a RecursionError before).
    root = _make_results(tmp_path, scenes=("office",))
    evaluation = root / "eval" / "office" / "orb"
    before = sorted(p.name for p in evaluation.iterdir())
    out = evaluation / "report"
    code = main(["report", str(evaluation), "--out", str(out), "--no-motion-flow"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err == (f"ifmi report: error: cannot write {out}: is inside the evaluation "
                                 f"folder {evaluation} that the report reads; choose another output path")
    assert sorted(p.name for p in evaluation.iterdir()) == before


@pytest.mark.slow
def test_report_inside_its_results_folder_leaves_out_its_own_copies_on_a_rerun(tmp_path):
    root = _make_results(tmp_path, scenes=("office",))
    out = root / "eval" / "report"
    for _ in range(2):
        assert main(["report", str(root / "eval"), "--out", str(out), "--no-motion-flow"]) == 0
    doc = json.loads((out / "report.json").read_text())
    # Inputs are recorded without the machine's folders above them (ifmi.io.portable_paths).
    assert sorted(doc["evaluations"]) == sorted(f"eval/office/{m}" for m in METHODS)


def test_two_sweeps_of_one_folder_name_get_their_own_figures_and_copies(tmp_path):
    a = _make_results(tmp_path / "site_a", scenes=("office",))
    b = _make_results(tmp_path / "site_b", scenes=("office",))
    out = tmp_path / "r"
    assert main(["report", str(a / "sweep"), str(b / "sweep"), "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "data" / "sweep").iterdir()) == ["site_a_sweep", "site_b_sweep"]
    figures = sorted(p.name for p in (out / "figures").glob("heatmap_*.png"))
    assert len(figures) == 4 and {f.split("_sweep_")[0] for f in figures} == {"heatmap_site_a",
                                                                             "heatmap_site_b"}


def test_markdown_keeps_its_structure_whatever_the_names_title_and_command():
    # A title over two lines made a second heading, a | in a name split its table cell, and a command
    # holding ``` ended its code block early: the README's structure was broken, exit 0.
    from ifmi.experiments.report import _render_markdown

    text = _render_markdown([("h1", "Report\n# not a heading"), ("code", "ifmi report x\n```\n# evil"),
                             ("table", ["scene", "RMSE"], [["office|v2", "0.1"]]),
                             ("img", "figures/a.png", "office\nlawn")])
    assert text.startswith("# Report # not a heading\n\n````\nifmi report x\n```\n# evil\n````\n\n")
    assert "| office\\|v2 | 0.1 |" in text.splitlines()
    assert text.endswith("![office lawn](figures/a.png)\n\n*office lawn*\n")


@pytest.mark.slow
def test_average_table_names_scenes_a_method_lacks(tmp_path, capsys):
    # ORB without its lawn evaluation was averaged over office alone and set beside iFMI's office-and-lawn
    # mean under "over 2 scene(s)", exit 0 and no word.
    import shutil

    root = _make_results(tmp_path)
    shutil.rmtree(root / "eval" / "lawn" / "orb")
    out = tmp_path / "r"
    assert main(["report", str(root / "eval"), "--out", str(out), "--no-motion-flow"]) == 0
    note = ("The methods were evaluated on different scenes (orb lacks lawn): each column averages its own "
            "scenes, so columns of different scenes do not compare; evaluate every method on every scene.")
    assert capsys.readouterr().err.strip() == f"warning: {note}"
    readme = (out / "README.md").read_text()
    assert note in readme and "| scenes |  | 2 | 1 | 2 |" in readme.splitlines()


@pytest.mark.slow
def test_a_report_names_its_data_sets_not_the_machines_folders(tmp_path):
    """Evaluations and sweeps record absolute paths; the report's copies and report.json hold them
    relative to the folder above all of them, and the report still rebuilds from its copies."""
    root = _make_results(tmp_path / "results")
    out = tmp_path / "report"
    assert main(["report", str(root / "eval"), str(root / "sweep"), "--out", str(out), "--no-motion-flow"]) == 0
    texts = {p: p.read_text() for p in out.rglob("*") if p.suffix in (".json", ".csv", ".md", ".html")}
    assert texts and not [p for p, text in texts.items() if str(tmp_path) in text]
    evaluation = json.loads((out / "data" / "eval" / "office" / "ifmi" / "evaluation.json").read_text())
    assert evaluation["groundtruth_path"] == "data/office_20/groundtruth.txt"
    rebuilt = tmp_path / "rebuilt"
    assert main(["report", str(out / "data"), "--out", str(rebuilt), "--no-motion-flow"]) == 0
    first, again = (json.loads((p / "report.json").read_text()) for p in (out, rebuilt))
    assert again["scenes"] == first["scenes"]
    assert [s["cells"] for s in again["sweeps"]] == [s["cells"] for s in first["sweeps"]]
