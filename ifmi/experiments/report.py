"""Report assembly: Markdown and HTML from evaluation and sweep folders.

The report reads what ``ifmi evaluate`` and ``ifmi sweep`` wrote (summary
JSON, per-frame arrays, sweep tables) and never recomputes an estimate. The
one sample it computes, on request, is the iFMI motion flow between two
frames of each scene for the Fig. 2-style figure (once per scene, kept in
the report's data). It writes ``README.md``, ``index.html``, ``report.json``
(every number shown, to rebuild tables and plots) and ``figures/*.png``: into
a temporary folder beside the output folder, swapped in only when complete,
so a failed report leaves the previous one intact. An existing output folder
is replaced only when it holds a report (``report.json`` of kind
:data:`REPORT_KIND`) or nothing; files of the user's in a report folder are
kept.
"""

from __future__ import annotations

import html
import os
import platform
import re
import shutil
import sys
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Sequence

import numpy as np

from ifmi.evaluation.dataset_names import dataset_labels, resolved_folder
from ifmi.errors import InputError, OutputError
from ifmi.io.atomic import (atomic_write_json, atomic_write_text, check_output_folder, folder_of_kind,
                        path_within, write_folder)
from ifmi.io.provenance import package_versions as _package_versions
from ifmi.io.results import (EvaluationRecord, is_evaluation_dir, jsonable, read_evaluation,
                         read_motion_flow, write_motion_flow)
from ifmi.tracking.methods import method_sort_key
from ifmi.evaluation.metrics import AXES, EvaluationSummary
from ifmi.experiments.motion_flow import MOTION_FLOW_FILE

__all__ = [
    "ReportInputs",
    "find_results",
    "machine_info",
    "package_versions",
    "scene_tables",
    "average_table",
    "baseline_ratios",
    "ReportOptions",
    "build_report",
    "is_report_dir",
    "REPORT_KIND",
]

# Packages whose versions the report lists.
PACKAGES = ("omnisim-ifmi", "numpy", "scipy", "opencv-python-headless", "poselib", "dask",
            "distributed", "pandas", "pyarrow", "matplotlib", "mitsuba", "drjit", "evo")
# File a sweep folder is recognised by.
SWEEP_MARKER = "sweep.json"
# Marker stored in report.json so that report folders can be recognised.
REPORT_KIND = "ifmi-report"
# Keys of every report.json, also of those written before REPORT_KIND existed.
_REPORT_KEYS = ("title", "scenes", "average", "machine", "versions")


@dataclass
class ReportInputs:
    """Evaluation and sweep folders found under the given paths."""

    evaluations: list = field(default_factory=list)
    sweeps: list = field(default_factory=list)


def find_results(paths: Sequence[str | os.PathLike], *,
                 skip: str | os.PathLike | None = None) -> ReportInputs:
    """Find evaluation folders and sweep folders in or below ``paths``.

    Evaluation folders inside a sweep (its per-cell runs) belong to the sweep
    and are not listed as evaluations.

    Parameters
    ----------
    paths : sequence of path
    skip : path, optional, keyword-only
        The report folder about to be replaced: the copies in its ``data/``
        are left out where found below a path outside it (``ifmi report
        results --out results/report`` run twice), and read where a path
        lies inside it (``ifmi report OUT/data --out OUT``).

    Raises
    ------
    InputError
        A path that does not exist or holds no results.
    """
    found = ReportInputs()
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise InputError(path, "results path not found")
        sweeps = [p.parent for p in ([path / SWEEP_MARKER] if (path / SWEEP_MARKER).is_file()
                                     else sorted(path.rglob(SWEEP_MARKER)))]
        if is_evaluation_dir(path):
            evals = [path]
        else:
            evals = [p.parent for p in sorted(path.rglob("evaluation.json"))]
        evals = [e for e in evals if not any(s in e.parents for s in sweeps)]
        if skip is not None and not path_within(path, Path(skip)):
            sweeps = [s for s in sweeps if not path_within(s, Path(skip))]
            evals = [e for e in evals if not path_within(e, Path(skip))]
        if not sweeps and not evals:
            raise InputError(path, "no evaluation.json or sweep.json found in or below it")
        found.sweeps.extend(s for s in sweeps if s not in found.sweeps)
        found.evaluations.extend(e for e in evals if e not in found.evaluations)
    return found


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _ram_gib() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except (OSError, ValueError, IndexError):
        pass
    return None


def machine_info() -> dict:
    """CPU model, logical cores, RAM (GiB), OS and Python of this machine."""
    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "ram_gib": _ram_gib(),
            "os": platform.platform(), "python": sys.version.split()[0]}


def package_versions() -> dict:
    """Installed versions of the packages that shape the results (None if absent)."""
    return _package_versions(PACKAGES)


def records_with_distinct_scenes(records: Sequence[EvaluationRecord]) -> list[EvaluationRecord]:
    """The records, with scene names made distinct where datasets of one scene meet.

    The report groups evaluations by scene. When evaluations of one scene
    come from different dataset folders (``office_200`` and
    ``office_200_phone``, or ``site_a/office`` and ``site_b/office``), each
    such record's scene becomes ``SCENE-LABEL`` (LABEL the folder's
    distinct display name, :func:`ifmi.evaluation.dataset_names.dataset_labels`, with
    ``/`` as ``_``) so that no row, figure or copied folder replaces another.
    A scene evaluated on a single dataset keeps its name.
    """
    def folder(rec: EvaluationRecord) -> str:
        gt = rec.meta.get("groundtruth_path")
        return str(Path(gt).parent) if gt else str(rec.meta.get("dataset") or rec.path)

    folders_by_scene: dict = {}
    for rec in records:
        folders_by_scene.setdefault(rec.scene, set()).add(folder(rec))
    shared = {scene for scene, folders in folders_by_scene.items() if len(folders) > 1}
    if not shared:
        return list(records)
    labels = dataset_labels(sorted({folder(r) for r in records if r.scene in shared}))
    out = []
    for rec in records:
        if rec.scene in shared:
            label = labels[resolved_folder(folder(rec))].replace("/", "_")
            rec = replace(rec, meta={**rec.meta, "scene": f"{rec.scene}-{label}"})
        out.append(rec)
    return out


def _refuse_repeated_evaluations(records: Sequence[EvaluationRecord]) -> None:
    """Two evaluations of one method on one scene would share a row: one would be dropped."""
    first: dict = {}
    for rec in records:
        key = (rec.scene, rec.method)
        if key in first:
            raise InputError(rec.path, f"evaluates method {rec.method} on scene {rec.scene}, as "
                                       f"{first[key]} does; expected one evaluation per scene and "
                                       "method (report the runs separately)")
        first[key] = rec.path


def scene_tables(records: Sequence[EvaluationRecord]) -> dict:
    """Per scene and method: the evaluation's flat summary row.

    Returns
    -------
    dict
        ``{scene: {method: row}}``; a row is
        :meth:`ifmi.evaluation.metrics.EvaluationSummary.flat` (``rmse_roll_rad``,
        ``mean_roll_rad``, ``std_roll_rad``, ..., ``rmse_mean_rad``,
        ``rmse_geodesic_rad``, ``time_per_frame_s``, ``failures``,
        ``frames``) plus ``evaluation`` (the folder). Methods are in
        :func:`ifmi.tracking.methods.method_sort_key` order, any name included.
    """
    tables: dict = {}
    for rec in records:
        row = EvaluationSummary.from_dict(rec.summary).flat()
        row["evaluation"] = str(rec.path)
        tables.setdefault(rec.scene, {})[rec.method] = row
    return {scene: dict(sorted(rows.items(), key=lambda kv: method_sort_key(kv[0])))
            for scene, rows in sorted(tables.items())}


def _mean_std(values) -> dict:
    v = np.array([np.nan if x is None else x for x in values], dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std()), "n": int(v.size)}


# Columns of the scene rows averaged over scenes (paper Table 1).
AVERAGE_COLUMNS = tuple(f"rmse_{a}_rad" for a in AXES) + ("rmse_mean_rad", "rmse_geodesic_rad",
                                                           "time_per_frame_s")


def average_table(tables: dict) -> dict:
    """Paper Table 1: per method, mean ± std over scenes of each axis RMSE, of their mean, and time.

    Returns
    -------
    dict
        ``{method: {column: {mean, std, n}}}`` for the columns of
        :data:`AVERAGE_COLUMNS` (names of :meth:`EvaluationSummary.flat`).
    """
    methods = sorted({m for rows in tables.values() for m in rows}, key=method_sort_key)
    out = {}
    for method in methods:
        rows = [rows[method] for rows in tables.values() if method in rows]
        out[method] = {col: _mean_std([r[col] for r in rows]) for col in AVERAGE_COLUMNS}
    return out


def baseline_ratios(tables: dict, *, method: str = "ifmi",
                    baselines: Sequence[str] = ("orb", "akaze")) -> dict:
    """Accuracy and speed of ``method`` relative to the baselines, per scene.

    Returns
    -------
    dict
        ``{scene: {"rmse_ratio_to_best_baseline", "time_ratio_<baseline>"...}}``
        where an RMSE ratio is ``method``'s mean-axis RMSE over the better
        baseline's, and a time ratio is its time per frame over the
        baseline's.
    """
    out = {}
    for scene, rows in tables.items():
        if method not in rows:
            continue
        entry = {}
        base = [rows[b]["rmse_mean_rad"] for b in baselines if b in rows and rows[b]["rmse_mean_rad"]]
        if base:
            entry["rmse_ratio_to_best_baseline"] = rows[method]["rmse_mean_rad"] / min(base)
        for b in baselines:
            t_m, t_b = rows[method]["time_per_frame_s"], rows.get(b, {}).get("time_per_frame_s")
            if t_m and t_b:
                entry[f"time_ratio_{b}"] = t_m / t_b
        out[scene] = entry
    return out


# -- document model: a list of blocks rendered to Markdown and HTML -----------------------------

# Backticks of the shortest Markdown code fence.
_MIN_FENCE = 3

def _md_cell(value) -> str:
    """``value`` as one Markdown table cell: one line, its ``|`` escaped (it would end the cell)."""
    return _md_line(str(value)).replace("|", "\\|")


def _md_line(text: str) -> str:
    """``text`` on one line (a heading or cell ends at a line break; the rest would be body text)."""
    return " ".join(str(text).split())


def _md_fence(text: str) -> str:
    """A code fence longer than any run of backticks in ``text``, so that none ends the block early."""
    longest = max((len(run) for run in re.findall(r"`+", text)), default=0)
    return "`" * max(_MIN_FENCE, longest + 1)


def _md_table(header, rows) -> str:
    lines = ["| " + " | ".join(_md_cell(c) for c in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _render_markdown(blocks) -> str:
    parts = []
    for kind, *rest in blocks:
        if kind == "h1":
            parts.append(f"# {_md_line(rest[0])}")
        elif kind == "h2":
            parts.append(f"## {_md_line(rest[0])}")
        elif kind == "h3":
            parts.append(f"### {_md_line(rest[0])}")
        elif kind == "p":
            parts.append(rest[0])
        elif kind == "code":
            fence = _md_fence(rest[0])
            parts.append(f"{fence}\n{rest[0]}\n{fence}")
        elif kind == "table":
            parts.append(_md_table(*rest))
        elif kind == "img":
            caption = _md_line(rest[1])
            parts.append(f"![{caption}]({rest[0]})\n\n*{caption}*")
    return "\n\n".join(parts) + "\n"


def _render_html(blocks, title: str) -> str:
    body = []
    for kind, *rest in blocks:
        if kind in ("h1", "h2", "h3"):
            body.append(f"<{kind}>{html.escape(rest[0])}</{kind}>")
        elif kind == "p":
            body.append(f"<p>{html.escape(rest[0]).replace('`', '')}</p>")
        elif kind == "code":
            body.append(f"<pre>{html.escape(rest[0])}</pre>")
        elif kind == "table":
            header, rows = rest
            head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
            trs = "".join("<tr>" + "".join(f"<td>{html.escape(str(c)).replace('**', '')}</td>"
                                           for c in row) + "</tr>" for row in rows)
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{trs}</tbody></table>")
        elif kind == "img":
            body.append(f'<figure><img src="{html.escape(rest[0])}" alt="{html.escape(rest[1])}">'
                        f"<figcaption>{html.escape(rest[1])}</figcaption></figure>")
    style = ("body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em}"
             "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
             "padding:3px 8px;text-align:right}th{background:#eee}img{max-width:100%}"
             "figure{margin:1em 0}figcaption{font-style:italic;color:#444}")
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}"
            f"</title><style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def _f(v, digits: int = 4) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def _pm(entry: dict, digits: int = 4) -> str:
    if entry.get("mean") is None:
        return "n/a"
    return f"{entry['mean']:.{digits}f} ± {entry['std']:.{digits}f}"


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, (list, tuple)):
        return " x ".join(str(x) for x in v)
    return str(v)


def _ms(v) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v * 1e3:.1f}"


def _scene_blocks(tables: dict) -> list:
    blocks = []
    header = ["method", "roll RMSE [rad]", "pitch RMSE [rad]", "yaw RMSE [rad]",
              "mean RMSE [rad]", "geodesic RMSE [rad]", "time/frame [ms]", "failed frames"]
    for scene, rows in tables.items():
        body = []
        for method, r in rows.items():
            cells = [method]
            for axis in AXES:
                cells.append(f"{_f(r[f'rmse_{axis}_rad'])} ({_f(r[f'mean_{axis}_rad'])} ± "
                             f"{_f(r[f'std_{axis}_rad'])})")
            cells += [_f(r["rmse_mean_rad"]), _f(r["rmse_geodesic_rad"]), _ms(r["time_per_frame_s"]),
                      f"{r['failures'] if r['failures'] is not None else 'n/a'} / {r['frames']}"]
            body.append(cells)
        blocks.append(("h3", f"Scene: {scene}"))
        blocks.append(("table", header, body))
    blocks.append(("p", "Per-axis cells: RMSE (mean ± std of |error|), radians; error = wrapped "
                        "difference est − gt of roll, pitch, yaw over the trajectory."))
    return blocks


def _average_blocks(avg: dict, tables: dict) -> list:
    methods = list(avg)
    header = ["", ""] + methods
    body = []
    for axis in AXES:
        body.append([axis, "ε [rad]"] + [_pm(avg[m][f"rmse_{axis}_rad"]) for m in methods])
    body.append(["μ(ε)", "[rad]"] + [_pm(avg[m]["rmse_mean_rad"]) for m in methods])
    body.append(["geodesic", "ε [rad]"] + [_pm(avg[m]["rmse_geodesic_rad"]) for m in methods])
    body.append(["μ(t)", "[s]"] + [_pm(avg[m]["time_per_frame_s"]) for m in methods])
    n = max((avg[m]["rmse_mean_rad"]["n"] for m in methods), default=0)
    note = _unlike_scenes_note(tables, methods)
    if note:
        body.append(["scenes", ""] + [str(sum(m in rows for rows in tables.values())) for m in methods])
        print(f"warning: {note}", file=sys.stderr)
    return [("table", header, body),
            ("p", f"Mean ± standard deviation over {n} scene(s) of each scene's RMSE "
                  "(and of the time per frame), as in the paper's Table 1." + (f" {note}" if note else ""))]


def _unlike_scenes_note(tables: dict, methods: list) -> str:
    """A sentence naming the scenes some methods lack ("" when every method has every scene)."""
    lacking = {m: [scene for scene, rows in tables.items() if m not in rows] for m in methods}
    lacking = {m: scenes for m, scenes in lacking.items() if scenes}
    if not lacking:
        return ""
    shown = "; ".join(f"{m} lacks {', '.join(sorted(scenes))}" for m, scenes in lacking.items())
    return (f"The methods were evaluated on different scenes ({shown}): each column averages its own "
            "scenes, so columns of different scenes do not compare; evaluate every method on every scene.")


def _ratio_blocks(ratios: dict) -> list:
    if not ratios:
        return []
    header = ["scene", "iFMI RMSE / best baseline RMSE", "iFMI time / ORB time",
              "iFMI time / AKAZE time"]
    body = [[scene, _f(r.get("rmse_ratio_to_best_baseline"), 3),
             _f(r.get("time_ratio_orb"), 3), _f(r.get("time_ratio_akaze"), 3)]
            for scene, r in ratios.items()]
    return [("h2", "iFMI against the baselines"), ("table", header, body),
            ("p", "RMSE: mean of the roll, pitch and yaw RMSEs; time is end to end per frame "
                  "(read, prepare, match, solve).")]


def _rpy_blocks(records: Sequence[EvaluationRecord], figures: Path) -> tuple[list, dict]:
    """Fig. 4-style orientation plots, one per scene with every method in it."""
    from ifmi.experiments.plots import rpy_over_frames

    by_scene: dict = {}
    for rec in records:
        by_scene.setdefault(rec.scene, []).append(rec)
    blocks, plots = [], {}
    if by_scene:
        blocks.append(("h2", "Orientation over frames (Fig. 4 style)"))
    for scene, recs in sorted(by_scene.items()):
        recs = sorted(recs, key=lambda r: method_sort_key(r.method))
        series = {r.method: r.arrays for r in recs}
        rmse = {r.method: [EvaluationSummary.from_dict(r.summary).axis(a).rmse for a in AXES]
                for r in recs}
        name = f"rpy_{scene}.png"
        rpy_over_frames(series, title=f"{scene}: roll, pitch, yaw against ground truth",
                        path=figures / name, rmse=rmse)
        plots[scene] = f"figures/{name}"
        blocks.append(("img", f"figures/{name}",
                       f"{scene}: estimated roll, pitch and yaw (radians) over frames for each "
                       "method, ground truth in black"))
    return blocks, plots


def _flow_sample(rec: EvaluationRecord, *, compute: bool, store: Path | None) -> dict | None:
    """The motion-flow sample of an iFMI evaluation: stored beside it, or computed once now.

    A computed sample is written to ``store`` (the report's copy of the
    evaluation) so that a report rebuilt from its data has it. Without the
    dataset's images there is no sample; a dataset that cannot be read is a
    warning, not an error.
    """
    from ifmi.experiments.motion_flow import motion_flow_sample

    stored = rec.path / MOTION_FLOW_FILE
    if stored.is_file():
        return read_motion_flow(stored)
    dataset = rec.meta.get("dataset_path")
    if (not compute or not rec.config or rec.config.get("config") is None or not dataset
            or not Path(dataset, "images").is_dir()):
        return None
    from ifmi.pipeline import EstimateConfig

    try:
        sample = motion_flow_sample(dataset, config=EstimateConfig.from_dict(rec.config["config"]))
    except (InputError, ValueError) as exc:
        print(f"warning: no motion-flow figure for {rec.scene}: {exc}", file=sys.stderr)
        return None
    if store is not None:
        write_motion_flow(store / MOTION_FLOW_FILE, sample)
    return sample


def _motion_flow_blocks(records: Sequence[EvaluationRecord], figures: Path, *, compute: bool,
                        data: Path | None) -> list:
    from ifmi.experiments.plots import motion_flow_figure

    blocks = []
    for rec in records:
        if rec.method != "ifmi":
            continue
        store = None if data is None else data / "eval" / rec.scene / rec.method
        sample = _flow_sample(rec, compute=compute, store=store)
        if sample is None:
            continue
        name = f"motion_flow_{rec.scene}.png"
        a, b = (int(f) for f in sample.get("frames", np.array([0, 1])))
        motion_flow_figure(sample["panorama_a"], sample["panorama_b"], points_a=sample["points_a"],
                           points_b=sample["points_b"], tile_centers=sample["tile_centers"],
                           tile_size=int(sample["tile_size"]),
                           title=f"{rec.scene}: iFMI motion flow, frames {a} → {b}",
                           path=figures / name)
        blocks.append(("img", f"figures/{name}",
                       f"Motion flow between panoramas of frames {a} and {b} ({rec.scene}): red "
                       "points in the first panorama, green their matches in the second, yellow "
                       "tile outlines."))
    return ([("h2", "Motion flow (Fig. 2 style)")] + blocks) if blocks else []


def _sweep_names(sweeps: Sequence[Path]) -> dict:
    """Distinct names of sweep folders for titles, figures and copies: the folder name, with
    parents where two share one (``site_a/sweep`` and ``site_b/sweep``: ``site_a_sweep``, ...).

    Returns
    -------
    dict
        Sweep folder (as given) -> name.
    """
    labels = dataset_labels(sweeps) if sweeps else {}
    return {s: labels[resolved_folder(s)].replace("/", "_") for s in sweeps}


def _sweep_blocks(sweep_dir: Path, figures: Path, *, name: str) -> tuple[list, dict]:
    from ifmi.experiments.plots import sweep_heatmap
    from ifmi.experiments.sweep import METRICS, records_table, sweep_records

    records = sweep_records(sweep_dir)
    blocks = [("h3", f"Sweep: {name}")]
    if not records:
        blocks.append(("p", "No finished cells."))
        return blocks, {"path": str(sweep_dir), "cells": []}
    table = records_table(records)
    header = ["dataset", "method", "tile size", "overlap", "status", "mean RMSE [rad]",
              "geodesic RMSE [rad]", "time/frame [ms]", "failed frames"]
    body = []
    for r in records:
        ok = r.get("status") == "ok"
        body.append([r.get("dataset", "?"), r.get("method", "?"), f"{r.get('tile_size', 0):g}",
                     f"{r.get('overlap', 0):g}",
                     r.get("status", "?") if ok else f"failed: {r.get('error', '')}",
                     _f(r.get("rmse_mean_rad")) if ok else "", _f(r.get("rmse_geodesic_rad")) if ok else "",
                     _ms(r.get("time_per_frame_s")) if ok else "",
                     r.get("failures", "") if ok else ""])
    blocks.append(("table", header, body))
    ok = table[table["status"] == "ok"] if "status" in table else table.iloc[0:0]
    for (dataset, method), group in ok.groupby(["dataset", "method"]):
        for metric in ("rmse_mean_rad", "time_per_frame_s"):
            if metric not in group or group[metric].isna().all():
                continue
            file = _file_name(f"heatmap_{name}_{dataset}_{method}_{metric}") + ".png"
            sweep_heatmap(group, metric=metric, label=METRICS[metric],
                          title=f"{dataset} ({method}): {METRICS[metric]}", path=figures / file)
            blocks.append(("img", f"figures/{file}",
                           f"{dataset}, {method}: {METRICS[metric]} over tile size and overlap"))
    return blocks, {"path": str(sweep_dir), "cells": jsonable(table.to_dict(orient="records"))}


def _file_name(text: str) -> str:
    """``text`` with every character that is not safe in a file name replaced by ``_``."""
    return "".join(c if c.isalnum() or c in "_.=-" else "_" for c in text)


def _provenance_blocks(records: Sequence[EvaluationRecord]) -> tuple[list, dict]:
    provenance = {}
    for r in records:
        provenance.setdefault(r.meta.get("dataset", r.scene), r.meta.get("dataset_meta") or {})
    if not any(provenance.values()):
        return [], provenance
    keys = ["scene_name", "frames", "resolution", "spp", "seed", "variant"]
    return [("h2", "Datasets"),
            ("table", ["dataset"] + keys, [[name] + [_cell(meta.get(k)) for k in keys]
                                           for name, meta in sorted(provenance.items())])], provenance


def _machine_blocks(machine: dict, versions: dict) -> list:
    return [("h2", "Machine and versions"),
            ("table", ["machine", ""], [[k, v] for k, v in machine.items()]),
            ("table", ["package", "version"],
             [[k, v or "not installed"] for k, v in versions.items()])]


# Files of a sweep folder copied into a report (not the per-cell runs).
SWEEP_FILES = ("sweep.json", "sweep.csv", "sweep.parquet")


def _copy_data(inputs: ReportInputs, records: Sequence[EvaluationRecord], data: Path) -> None:
    """Copy evaluation folders and sweep tables under ``data`` (a new, empty folder)."""
    for rec in records:
        dst = data / "eval" / rec.scene / rec.method
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(rec.path, dst)
    names = _sweep_names(inputs.sweeps)
    for sweep in inputs.sweeps:
        dst = data / "sweep" / names[sweep]
        if dst.exists():
            shutil.rmtree(dst)
        (dst / "cells").mkdir(parents=True)
        for name in SWEEP_FILES:
            if (sweep / name).is_file():
                shutil.copy2(sweep / name, dst / name)
        for cell in (sweep / "cells").glob("*.json"):
            shutil.copy2(cell, dst / "cells" / cell.name)


def _portable_paths(data: Path | None, document: dict):
    """The rewriter of the machine paths in ``document`` (``report.json``) and the JSON files of
    ``data`` (:mod:`ifmi.io.portable_paths`): a report names its data sets, not one machine's folders."""
    from ifmi.io.portable_paths import PortablePaths, absolute_paths_in, read_json_or_none

    paths = absolute_paths_in(document)
    for path in [] if data is None else sorted(data.rglob("*.json")):
        paths |= absolute_paths_in(read_json_or_none(path))
    return PortablePaths.for_paths(paths, base=Path.cwd())


def _make_data_portable(data: Path, portable) -> None:
    """Rewrite the copied JSON files and sweep tables under ``data`` with ``portable``."""
    for path in sorted(data.rglob("*.json")):
        portable.rewrite_json_file(path)
    for sweep in sorted(data.glob("sweep/*")):
        portable.rewrite_table_files(sweep / "sweep.csv", sweep / "sweep.parquet")


def _series(records: Sequence[EvaluationRecord]) -> dict:
    keys = ["timestamp"] + [f"{a}_{k}" for a in AXES for k in ("gt", "est")] + ["geodesic_error"]
    series = {r.scene: {} for r in records}
    for r in records:
        series[r.scene][r.method] = {k: np.asarray(r.arrays[k]).tolist() for k in keys if k in r.arrays}
    return series


@dataclass(frozen=True)
class ReportOptions:
    """What a report contains.

    Attributes
    ----------
    title : str
    command : str or None
        Command line that regenerates the report, printed in it.
    copy_data : bool
        Copy the evaluation folders and sweep tables into ``OUT/data`` so
        that the report is self-contained (``ifmi report OUT/data --out
        OUT`` rebuilds it).
    motion_flow : bool
        For each iFMI evaluation without a stored motion-flow sample whose
        dataset is at hand, compute the sample (frames 0 and 1) once for the
        Fig. 2-style figure.
    """

    title: str = "Rotation estimation with omni-cameras: iFMI vs ORB vs AKAZE"
    command: str | None = None
    copy_data: bool = True
    motion_flow: bool = True


def _write_report(inputs: ReportInputs, records: list[EvaluationRecord], out: Path,
                  options: ReportOptions) -> None:
    """Write every file of the report of ``records`` (read from ``inputs``) into the new ``out``."""
    figures = out / "figures"
    figures.mkdir(parents=True)
    data = out / "data" if options.copy_data else None
    if data is not None:
        _copy_data(inputs, records, data)
    tables = scene_tables(records)
    avg, ratios = average_table(tables), baseline_ratios(tables)
    blocks: list = [("h1", options.title),
                    ("p", f"Generated {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')} "
                          f"from {len(records)} evaluation(s) and {len(inputs.sweeps)} sweep(s).")]
    if options.command:
        blocks += [("p", "Regenerate with:"), ("code", options.command)]
    if records:
        blocks += [("h2", "Average over scenes (Table 1 style)"), *_average_blocks(avg, tables),
                   ("h2", "Per scene"), *_scene_blocks(tables)]
    blocks += _ratio_blocks(ratios)
    rpy, plots = _rpy_blocks(records, figures)
    blocks += rpy
    blocks += _motion_flow_blocks(records, figures, compute=options.motion_flow, data=data)
    sweeps = []
    if inputs.sweeps:
        blocks.append(("h2", "Tile size × overlap sweeps"))
        names = _sweep_names(inputs.sweeps)
        for sweep_dir in inputs.sweeps:
            b, sweep_data = _sweep_blocks(sweep_dir, figures, name=names[sweep_dir])
            blocks += b
            sweeps.append(sweep_data)
    provenance_blocks, provenance = _provenance_blocks(records)
    machine, versions = machine_info(), package_versions()
    blocks += provenance_blocks + _machine_blocks(machine, versions)
    configs = {f"{r.scene}/{r.method}": r.config for r in records if r.config is not None}
    if configs:
        blocks += [("h2", "Configurations"),
                   ("p", "Each estimate run's configuration is in its evaluation folder "
                         "(config.json) and in report.json.")]
    document = jsonable({
        "kind": REPORT_KIND, "title": options.title, "command": options.command, "scenes": tables, "average": avg,
        "ratios": ratios, "plots": plots, "series": _series(records), "sweeps": sweeps,
        "datasets": provenance, "machine": machine, "versions": versions, "configs": configs,
        "evaluations": [str(p) for p in inputs.evaluations],
    })
    portable = _portable_paths(data, document)
    if data is not None:
        _make_data_portable(data, portable)
    atomic_write_json(out / "report.json", portable.value(document))
    atomic_write_text(out / "index.html", _render_html(blocks, options.title))
    atomic_write_text(out / "README.md", _render_markdown(blocks))


# Entries of a report folder that a new report replaces; anything else in it is kept.
REPORT_ENTRIES = ("README.md", "index.html", "report.json", "figures", "data")


def is_report_dir(path: str | os.PathLike) -> bool:
    """True when ``path`` holds a ``report.json`` written by :func:`build_report`.

    That is a JSON object of kind :data:`REPORT_KIND`, or (reports written
    before the kind was stored) one without a kind that has every key a
    report has.
    """
    return folder_of_kind(path, "report.json", REPORT_KIND, legacy_keys=_REPORT_KEYS)


def build_report(paths: Sequence[str | os.PathLike], *, out_dir: str | os.PathLike,
                 options: ReportOptions = ReportOptions()) -> Path:
    """Write the report of the results found under ``paths`` into ``out_dir``.

    The report is built in a temporary folder beside ``out_dir`` and swapped
    in only when complete (:func:`~ifmi.io.atomic.write_folder`): a failure
    leaves an existing report unchanged. An existing ``out_dir`` must be a
    report folder or empty; files of the user's in it are kept.

    Parameters
    ----------
    paths : sequence of path
        Evaluation folders, sweep folders, or folders containing them.
    out_dir : path, keyword-only
    options : ReportOptions, keyword-only

    Returns
    -------
    Path
        ``out_dir/README.md``.

    Raises
    ------
    InputError
        A results path that is missing or holds no results, or a malformed
        one (:func:`~ifmi.io.results.read_evaluation`), or two evaluations
        of one method on one scene; every evaluation is read before anything
        is written.
    OutputError
        ``out_dir`` is a file, an existing folder that is neither empty nor
        a report folder, or inside an evaluation folder it reads (checked
        before any work), or the report cannot
        be written (names ``out_dir`` and the OS reason).
    """
    inputs = find_results(paths, skip=out_dir)
    for folder in inputs.evaluations:
        if path_within(Path(out_dir), folder):  # the report would copy the folder into itself
            raise OutputError(out_dir, f"is inside the evaluation folder {folder} that the report "
                                       "reads; choose another output path")
    # A symlinked report folder is written through, not replaced.
    out = check_output_folder(out_dir, is_own=is_report_dir,
                              what="a report folder written by ifmi report")
    records = records_with_distinct_scenes([read_evaluation(p) for p in inputs.evaluations])
    _refuse_repeated_evaluations(records)
    write_folder(out, lambda folder: _write_report(inputs, records, folder, options),
                 replaces=REPORT_ENTRIES)
    return Path(out_dir) / "README.md"
