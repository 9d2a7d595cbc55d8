"""Report assembly: Markdown and HTML from evaluation and sweep folders.

The report reads what ``ifmi evaluate`` and ``ifmi sweep`` wrote (summary
JSON, per-frame arrays, motion-flow samples, sweep tables) and never
recomputes an estimate. It writes ``README.md``, ``index.html``,
``report.json`` (every number shown, to rebuild tables and plots) and
``figures/*.png`` into the output folder.
"""

from __future__ import annotations

import html
import os
import platform
import shutil
import sys
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import InputError
from .evaluation import MOTION_FLOW_FILE
from .io.atomic import atomic_write_json, atomic_write_text
from .io.provenance import package_versions as _package_versions
from .io.results import (EvaluationRecord, is_evaluation_dir, jsonable, read_evaluation,
                         read_motion_flow)
from .metrics import AXES

__all__ = [
    "ReportInputs",
    "find_results",
    "machine_info",
    "package_versions",
    "scene_tables",
    "average_table",
    "target_ratios",
    "build_report",
]

# Methods in report order; others follow alphabetically.
METHOD_ORDER = ("ifmi", "orb", "akaze")
# Packages whose versions the report lists.
PACKAGES = ("omnisim-ifmi", "numpy", "scipy", "opencv-python-headless", "poselib", "dask",
            "distributed", "pandas", "pyarrow", "matplotlib", "mitsuba", "drjit", "evo")
# File a sweep folder is recognised by.
SWEEP_MARKER = "sweep.json"


@dataclass
class ReportInputs:
    """Evaluation and sweep folders found under the given paths."""

    evaluations: list = field(default_factory=list)
    sweeps: list = field(default_factory=list)


def find_results(paths: Sequence[str | os.PathLike]) -> ReportInputs:
    """Find evaluation folders and sweep folders in or below ``paths``.

    Evaluation folders inside a sweep (its per-cell runs) belong to the sweep
    and are not listed as evaluations.

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


def _method_key(method: str):
    return (METHOD_ORDER.index(method) if method in METHOD_ORDER else len(METHOD_ORDER), method)


def scene_tables(records: Sequence[EvaluationRecord]) -> dict:
    """Per scene and method: per-axis RMSE and mean ± std of |error|, time, failures.

    Returns
    -------
    dict
        ``{scene: {method: row}}``; a row has ``roll``/``pitch``/``yaw`` dicts
        (``rmse``, ``mean``, ``std`` in radians), ``mean_rmse``,
        ``geodesic_rmse``, ``time_per_frame_s``, ``failures``, ``frames`` and
        ``evaluation`` (the folder).
    """
    tables: dict = {}
    for rec in records:
        s = rec.summary
        row = {axis: {k: s["axes"][axis][k] for k in ("rmse", "mean", "std")} for axis in AXES}
        row.update({
            "mean_rmse": s["mean_rmse"],
            "geodesic_rmse": s["geodesic"]["rmse"],
            "relative_rmse": s["relative_geodesic"]["rmse"],
            "translation_direction_mean": s["translation_direction"]["mean"],
            "time_per_frame_s": (s.get("time") or {}).get("mean_s"),
            "failures": (s.get("failures") or {}).get("count"),
            "frames": s["frames"]["estimate"],
            "evaluation": str(rec.path),
        })
        tables.setdefault(rec.scene, {})[rec.method] = row
    return {scene: dict(sorted(rows.items(), key=lambda kv: _method_key(kv[0])))
            for scene, rows in sorted(tables.items())}


def _mean_std(values) -> dict:
    v = np.array([np.nan if x is None else x for x in values], dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std()), "n": int(v.size)}


def average_table(tables: dict) -> dict:
    """Paper Table 1: per method, mean ± std over scenes of each axis RMSE, of their mean, and time.

    Returns
    -------
    dict
        ``{method: {"roll"|"pitch"|"yaw"|"mean_rmse"|"time_per_frame_s": {mean, std, n}}}``.
    """
    methods = sorted({m for rows in tables.values() for m in rows}, key=_method_key)
    out = {}
    for method in methods:
        rows = [rows[method] for rows in tables.values() if method in rows]
        entry = {axis: _mean_std([r[axis]["rmse"] for r in rows]) for axis in AXES}
        entry["mean_rmse"] = _mean_std([r["mean_rmse"] for r in rows])
        entry["geodesic_rmse"] = _mean_std([r["geodesic_rmse"] for r in rows])
        entry["time_per_frame_s"] = _mean_std([r["time_per_frame_s"] for r in rows])
        out[method] = entry
    return out


def target_ratios(tables: dict, *, method: str = "ifmi",
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
        base = [rows[b]["mean_rmse"] for b in baselines if b in rows and rows[b]["mean_rmse"]]
        if base:
            entry["rmse_ratio_to_best_baseline"] = rows[method]["mean_rmse"] / min(base)
        for b in baselines:
            t_m, t_b = rows[method]["time_per_frame_s"], rows.get(b, {}).get("time_per_frame_s")
            if t_m and t_b:
                entry[f"time_ratio_{b}"] = t_m / t_b
        out[scene] = entry
    return out


# -- document model: a list of blocks rendered to Markdown and HTML -----------------------------

def _md_table(header, rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _render_markdown(blocks) -> str:
    parts = []
    for kind, *rest in blocks:
        if kind == "h1":
            parts.append(f"# {rest[0]}")
        elif kind == "h2":
            parts.append(f"## {rest[0]}")
        elif kind == "h3":
            parts.append(f"### {rest[0]}")
        elif kind == "p":
            parts.append(rest[0])
        elif kind == "code":
            parts.append("```\n" + rest[0] + "\n```")
        elif kind == "table":
            parts.append(_md_table(*rest))
        elif kind == "img":
            parts.append(f"![{rest[1]}]({rest[0]})\n\n*{rest[1]}*")
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
                cells.append(f"{_f(r[axis]['rmse'])} ({_f(r[axis]['mean'])} ± {_f(r[axis]['std'])})")
            cells += [_f(r["mean_rmse"]), _f(r["geodesic_rmse"]), _ms(r["time_per_frame_s"]),
                      f"{r['failures'] if r['failures'] is not None else 'n/a'} / {r['frames']}"]
            body.append(cells)
        blocks.append(("h3", f"Scene: {scene}"))
        blocks.append(("table", header, body))
    blocks.append(("p", "Per-axis cells: RMSE (mean ± std of |error|), radians; error = wrapped "
                        "difference est − gt of roll, pitch, yaw over the trajectory."))
    return blocks


def _average_blocks(avg: dict) -> list:
    methods = list(avg)
    header = ["", ""] + methods
    body = []
    for axis in AXES:
        body.append([axis, "ε [rad]"] + [_pm(avg[m][axis]) for m in methods])
    body.append(["μ(ε)", "[rad]"] + [_pm(avg[m]["mean_rmse"]) for m in methods])
    body.append(["geodesic", "ε [rad]"] + [_pm(avg[m]["geodesic_rmse"]) for m in methods])
    body.append(["μ(t)", "[s]"] + [_pm(avg[m]["time_per_frame_s"]) for m in methods])
    n = max((avg[m]["mean_rmse"]["n"] for m in methods), default=0)
    return [("table", header, body),
            ("p", f"Mean ± standard deviation over {n} scene(s) of each scene's RMSE "
                  "(and of the time per frame), as in the paper's Table 1.")]


def _motion_flow(rec: EvaluationRecord, figures: Path) -> tuple[str, str] | None:
    from .plots import motion_flow_figure

    path = rec.path / MOTION_FLOW_FILE
    if not path.is_file():
        return None
    data = read_motion_flow(path)
    name = f"motion_flow_{rec.scene}.png"
    frames = data.get("frames", np.array([0, 1]))
    motion_flow_figure(data["panorama_a"], data["panorama_b"], points_a=data["points_a"],
                       points_b=data["points_b"], tile_centers=data["tile_centers"],
                       tile_size=int(data["tile_size"]),
                       title=f"{rec.scene}: iFMI motion flow, frames {int(frames[0])} → {int(frames[1])}",
                       path=figures / name)
    return f"figures/{name}", (f"Motion flow between panoramas of frames {int(frames[0])} and "
                               f"{int(frames[1])} ({rec.scene}): red points in the first "
                               "panorama, green their matches in the second, yellow tile outlines.")


def _sweep_blocks(sweep_dir: Path, figures: Path) -> tuple[list, dict]:
    import pandas as pd

    from .sweep import METRICS, read_cells

    from .plots import sweep_heatmap

    records = read_cells(sweep_dir)
    blocks = [("h3", f"Sweep: {sweep_dir.name}")]
    if not records:
        blocks.append(("p", "No finished cells."))
        return blocks, {"path": str(sweep_dir), "cells": []}
    table = pd.DataFrame([{k: v for k, v in r.items() if k != "traceback"} for r in records])
    header = ["dataset", "method", "tile size", "overlap", "status", "mean RMSE [rad]",
              "geodesic RMSE [rad]", "time/frame [ms]", "failed frames"]
    body = []
    for r in records:
        ok = r.get("status") == "ok"
        body.append([r["dataset"], r["method"], f"{r['tile_size']:g}", f"{r['overlap']:g}",
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
            name = f"heatmap_{sweep_dir.name}_{dataset}_{method}_{metric}.png"
            sweep_heatmap(group, metric=metric, label=METRICS[metric],
                          title=f"{dataset} ({method}): {METRICS[metric]}", path=figures / name)
            blocks.append(("img", f"figures/{name}",
                           f"{dataset}, {method}: {METRICS[metric]} over tile size and overlap"))
    return blocks, {"path": str(sweep_dir), "cells": jsonable(table.to_dict(orient="records"))}


# Files of a sweep folder copied into a report (not the per-cell runs).
SWEEP_FILES = ("sweep.json", "sweep.csv", "sweep.parquet")


def _copy_data(inputs: ReportInputs, records: Sequence[EvaluationRecord], data: Path) -> None:
    """Copy evaluation folders and sweep tables under ``data`` (skipping ones already there)."""
    data = data.resolve()
    for rec in records:
        src = rec.path.resolve()
        if data in src.parents:
            continue
        dst = data / "eval" / rec.scene / rec.method
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(src, dst)
    for sweep in inputs.sweeps:
        src = sweep.resolve()
        if data in src.parents:
            continue
        dst = data / "sweep" / sweep.name
        if dst.exists():
            shutil.rmtree(dst)
        (dst / "cells").mkdir(parents=True)
        for name in SWEEP_FILES:
            if (src / name).is_file():
                shutil.copy2(src / name, dst / name)
        for cell in (src / "cells").glob("*.json"):
            shutil.copy2(cell, dst / "cells" / cell.name)


def build_report(paths: Sequence[str | os.PathLike], *, out_dir: str | os.PathLike,
                 title: str = "Rotation estimation with omni-cameras: iFMI vs ORB vs AKAZE",
                 command: str | None = None, copy_data: bool = True) -> Path:
    """Write the report of the results found under ``paths`` into ``out_dir``.

    Parameters
    ----------
    paths : sequence of path
        Evaluation folders, sweep folders, or folders containing them.
    out_dir : path, keyword-only
    title : str, keyword-only
    command : str, optional, keyword-only
        Command line that regenerates the report, printed in it.
    copy_data : bool, keyword-only
        Copy the evaluation folders and sweep tables into ``out_dir/data``
        so that the report is self-contained (``ifmi report OUT/data --out
        OUT`` rebuilds it).

    Returns
    -------
    Path
        ``out_dir/README.md``.
    """
    from .plots import rpy_over_frames

    inputs = find_results(paths)
    out = Path(out_dir)
    figures = out / "figures"
    if figures.exists():
        shutil.rmtree(figures)
    figures.mkdir(parents=True)
    records = [read_evaluation(p) for p in inputs.evaluations]
    if copy_data:
        _copy_data(inputs, records, out / "data")
    tables = scene_tables(records)
    avg = average_table(tables)
    ratios = target_ratios(tables)

    blocks: list = [("h1", title),
                    ("p", f"Generated {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')} "
                          f"from {len(records)} evaluation(s) and {len(inputs.sweeps)} sweep(s).")]
    if command:
        blocks += [("p", "Regenerate with:"), ("code", command)]
    if records:
        blocks.append(("h2", "Average over scenes (Table 1 style)"))
        blocks += _average_blocks(avg)
        blocks.append(("h2", "Per scene"))
        blocks += _scene_blocks(tables)
    if ratios:
        blocks.append(("h2", "iFMI against the baselines"))
        header = ["scene", "iFMI RMSE / best baseline RMSE", "iFMI time / ORB time",
                  "iFMI time / AKAZE time"]
        body = [[scene, _f(r.get("rmse_ratio_to_best_baseline"), 3),
                 _f(r.get("time_ratio_orb"), 3), _f(r.get("time_ratio_akaze"), 3)]
                for scene, r in ratios.items()]
        blocks.append(("table", header, body))
        blocks.append(("p", "Targets: RMSE ratio at most 1/3 (0.333), time ratio at most 0.5 "
                            "against ORB and 0.1 against AKAZE; time is end to end per frame "
                            "(read, prepare, match, solve)."))

    plots = {}
    by_scene: dict = {}
    for rec in records:
        by_scene.setdefault(rec.scene, []).append(rec)
    if by_scene:
        blocks.append(("h2", "Orientation over frames (Fig. 4 style)"))
    for scene, recs in sorted(by_scene.items()):
        recs = sorted(recs, key=lambda r: _method_key(r.method))
        series = {r.method: r.arrays for r in recs}
        rmse = {r.method: [r.summary["axes"][a]["rmse"] for a in AXES] for r in recs}
        name = f"rpy_{scene}.png"
        rpy_over_frames(series, title=f"{scene}: roll, pitch, yaw against ground truth",
                        path=figures / name, rmse=rmse)
        plots[scene] = f"figures/{name}"
        blocks.append(("img", f"figures/{name}",
                       f"{scene}: estimated roll, pitch and yaw (radians) over frames for each "
                       "method, ground truth in black"))

    flows = [f for f in (_motion_flow(r, figures) for r in records if r.method == "ifmi") if f]
    if flows:
        blocks.append(("h2", "Motion flow (Fig. 2 style)"))
        for src, caption in flows:
            blocks.append(("img", src, caption))

    sweeps = []
    if inputs.sweeps:
        blocks.append(("h2", "Tile size × overlap sweeps"))
        for sweep_dir in inputs.sweeps:
            b, data = _sweep_blocks(sweep_dir, figures)
            blocks += b
            sweeps.append(data)

    provenance = {}
    for r in records:
        provenance.setdefault(r.meta.get("dataset", r.scene), r.meta.get("dataset_meta") or {})
    if any(provenance.values()):
        blocks.append(("h2", "Datasets"))
        keys = ["scene_name", "frames", "resolution", "spp", "seed", "variant"]
        blocks.append(("table", ["dataset"] + keys,
                       [[name] + [_cell(meta.get(k)) for k in keys]
                        for name, meta in sorted(provenance.items())]))
    machine, versions = machine_info(), package_versions()
    blocks.append(("h2", "Machine and versions"))
    blocks.append(("table", ["machine", ""], [[k, v] for k, v in machine.items()]))
    blocks.append(("table", ["package", "version"],
                   [[k, v or "not installed"] for k, v in versions.items()]))
    configs = {f"{r.scene}/{r.method}": r.config for r in records if r.config is not None}
    if configs:
        blocks.append(("h2", "Configurations"))
        blocks.append(("p", "Each estimate run's configuration is in its evaluation folder "
                            "(config.json) and in report.json."))
    series_keys = ["timestamp"] + [f"{a}_{k}" for a in AXES for k in ("gt", "est")] + [
        "geodesic_error"]
    series = {r.scene: {} for r in records}
    for r in records:
        series[r.scene][r.method] = {k: np.asarray(r.arrays[k]).tolist()
                                     for k in series_keys if k in r.arrays}
    atomic_write_json(out / "report.json", jsonable({
        "title": title, "command": command, "scenes": tables, "average": avg,
        "ratios": ratios, "plots": plots, "series": series, "sweeps": sweeps,
        "datasets": provenance, "machine": machine,
        "versions": versions, "configs": configs,
        "evaluations": [str(p) for p in inputs.evaluations],
    }))
    atomic_write_text(out / "index.html", _render_html(blocks, title))
    atomic_write_text(out / "README.md", _render_markdown(blocks))
    return out / "README.md"
