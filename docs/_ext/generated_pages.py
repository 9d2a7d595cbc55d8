"""Pages and figures generated when the documentation is built.

* ``_generated/how_it_works/*.png``: the pipeline figures
  (:mod:`pipeline_figures`, exact synthetic frames);
* ``_generated/benchmark_tables.md``: one table per report under
  ``reports/`` that has a ``report.json`` (written by ``ifmi report``), with
  the command, date and machine the report records.

Both are rewritten on every build, so a page can never show a number its
source no longer holds.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

# Columns of the per-scene tables: report.json key, header, scale, digits.
_COLUMNS = (("rmse_geodesic_rad", "geodesic ATE [rad]", 1.0, 4), ("rmse_roll_rad", "roll RMSE [rad]", 1.0, 4),
            ("rmse_pitch_rad", "pitch RMSE [rad]", 1.0, 4), ("rmse_yaw_rad", "yaw RMSE [rad]", 1.0, 4),
            ("time_per_frame_s", "time/frame [ms]", 1e3, 1))


def _number(value, scale: float, digits: int) -> str:
    return "n/a" if value is None else f"{value * scale:.{digits}f}"


def _generated_line(readme: Path) -> str:
    """The ``Generated ... UTC`` line of a report's README (the date the report was made)."""
    if not readme.is_file():
        return ""
    match = re.search(r"^Generated (\d{4}-\d\d-\d\d[^\n]*?UTC)", readme.read_text(encoding="utf-8"), re.M)
    return match.group(1) if match else ""


def report_section(report: Path, root: Path) -> list[str]:
    """Markdown of one report: what, when, where, the command, one table row per scene and method."""
    data = json.loads((report / "report.json").read_text(encoding="utf-8"))
    rel = report.relative_to(root).as_posix()
    machine = data.get("machine", {})
    lines = [f"## `{rel}`", "", f"**{data.get('title', rel)}**", ""]
    when = _generated_line(report / "README.md")
    lines += [f"* generated: {when}" if when else "* generated: see the report",
              f"* machine: {machine.get('cpu', '?')}, {machine.get('cores', '?')} cores, "
              f"{machine.get('ram_gib', '?')} GiB, Python {machine.get('python', '?')}",
              f"* report: `{rel}/README.md` in the repository",
              "", "Regenerate with:", "", "```bash", data.get("command", ""), "```", ""]
    header = "| scene | method | " + " | ".join(h for _, h, _, _ in _COLUMNS) + " | failed frames |"
    lines += [header, "|" + "---|" * (len(_COLUMNS) + 3)]
    for scene, methods in sorted(data.get("scenes", {}).items()):
        for method, row in methods.items():
            cells = [_number(row.get(key), scale, digits) for key, _, scale, digits in _COLUMNS]
            lines.append(f"| {scene} | {method} | " + " | ".join(cells)
                         + f" | {row.get('failures', 'n/a')} / {row.get('frames', 'n/a')} |")
    return lines + [""]


def benchmark_tables(root: Path) -> str:
    """Markdown of every report under ``root / "reports"`` with a report.json."""
    reports = sorted(p.parent for p in (root / "reports").rglob("report.json"))
    lines = []
    for report in reports:
        lines += report_section(report, root)
    return "\n".join(lines) if lines else "No report with a report.json was found under reports/.\n"


def _write_if_changed(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def generate(app) -> None:
    """``builder-inited`` hook: write the generated files under ``docs/_generated``."""
    from pipeline_figures import write_figures

    docs = Path(app.srcdir)
    out = docs / "_generated"
    _write_if_changed(out / "benchmark_tables.md", benchmark_tables(docs.parent))
    numbers = write_figures(out / "how_it_works")
    text = (f"On these two frames the camera turned {numbers['rotation_rad']:.4f} rad; "
            f"{numbers['tiles_kept']} of {numbers['tiles']} tiles passed the peak filters, and the "
            f"relative pose is {numbers['error_rad']:.1e} rad from the truth.\n")
    _write_if_changed(out / "how_it_works" / "numbers.md", text)


def setup(app):
    app.connect("builder-inited", generate)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
