"""Speed of iFMI against ORB and AKAZE: compute per frame, ``ifmi estimate`` wall, peak RSS, ATE, stages.

One command measures, per dataset and odometry mode (``frame``,
``keyframe``), every method (``ifmi``, ``orb``, ``akaze``) in turns within
each round, so that load from other processes hits all methods alike:

* **compute**: wall and CPU ms per frame of :func:`ifmi.pipeline.estimate_sequence` on the
  frames already decoded into memory, in this process (median over
  ``--rounds``; CPU time counts all threads of the process). Each method
  first runs once, untimed, on the first frames of the first set, so that
  what a process does once (imports on first use, compiled kernels loaded
  from disk) stays out of the per-frame time; the end-to-end time below
  includes it;
* **end to end**: wall time of ``ifmi estimate`` in a child process
  (interpreter start, imports, PNG decoding and writing included), per
  frame, median over the rounds; the estimate (the same in every round:
  every method is seeded) is evaluated (geodesic ATE RMSE against
  ``groundtruth.txt``, rad);
* **peak RSS**: ``ru_maxrss`` of one ``ifmi estimate`` child per method on the
  first ``--rss-frames`` frames of the first dataset resized to
  ``--rss-size`` px (calibration scaled to match);
* **stages**: median ms per frame of each ``t_<stage>_ms`` column of the iFMI
  run's ``frames.csv``, the wall time of each stage of the per-pair pipeline
  as the estimator records it (:mod:`ifmi.spectral.pair_pipeline`).

Ratios are iFMI over each baseline; the summary takes the median over the
sets and modes. With ``--baseline JSON`` (the ``bench_speed.json`` of an
earlier run, e.g. of another tree) the ATE before and after is printed per
set and mode. The results are printed, written as JSON to
``OUT/bench_speed.json`` and as MyST Markdown to ``--report``.

Usage::

    python benchmarks/bench_speed.py DATA [DATA ...] [--modes frame keyframe] [--rounds 3] \\
        [--rss-size 2048] [--out out/bench_speed] [--report reports/speed/README.md]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import subprocess
import sys
import time
from datetime import datetime, timezone
from itertools import islice
from pathlib import Path

import cv2
import numpy as np

from benchlib import METHODS, MODES, compute_seconds, labelled_datasets, mode_config
from ifmi.cli.estimate import EXIT_MOSTLY_FAILED
from ifmi.evaluation.dataset_names import dataset_folder_id
from ifmi.errors import InputError
from ifmi.evaluation.trajectory_files import evaluate_files
from ifmi.io.atomic import atomic_write_json, atomic_write_text
from ifmi.io.camera_file import write_camera
from ifmi.io.dataset import read_dataset
from ifmi.io.tum import read_tum, write_tum
from ifmi.pipeline import EstimateConfig, estimate_sequence, resolved_config
from ifmi.experiments.report import machine_info
from ifmi.geometry.trajectory import Trajectory

# ``ru_maxrss`` unit: bytes on macOS, kibibytes elsewhere.
_RSS_BYTES = 1 if platform.system() == "Darwin" else 1024
def csv_stages(frames_csv: Path) -> dict | None:
    """Median ms per frame of each ``t_<stage>_ms`` column of a ``frames.csv`` (frame 0 left out),
    or None when it has none."""
    with open(frames_csv, newline="") as handle:
        rows = list(csv.DictReader(handle))[1:]
    columns = [c for c in (rows[0].keys() if rows else ()) if c.startswith("t_") and c.endswith("_ms")]
    if not columns:
        return None
    stages = {}
    for column in columns:
        values = [float(r[column]) for r in rows if r[column] not in ("", "nan")]
        stages[column[2:-3]] = float(np.median(values)) if values else float("nan")
    return stages


def run_estimate(dataset: Path, method: str, mode: str, out: Path) -> dict:
    """``ifmi estimate`` in a child process: its wall seconds and peak RSS (bytes).

    A run whose frames mostly failed (exit status 3) still wrote its estimate and counts;
    any other failure raises :class:`RuntimeError`.
    """
    command = [sys.executable, "-m", "ifmi.cli", "estimate", str(dataset), "--method", method,
               "--out", str(out), "--force", "--no-progress"]
    if mode == "keyframe":
        command.append("--keyframes")
    start = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    stderr = child.stderr.read()
    # wait4 gives this child's own rusage (RUSAGE_CHILDREN would keep the largest child so far).
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode not in (0, EXIT_MOSTLY_FAILED):
        raise RuntimeError(f"{' '.join(command)} failed ({child.returncode}): {stderr.strip()[-400:]}")
    return {"wall_s": wall, "rss_bytes": usage.ru_maxrss * _RSS_BYTES}


def resized_dataset(source: Path, out: Path, *, size: int, frames: int) -> Path:
    """The first ``frames`` frames of ``source`` resized to ``size`` px square, calibration scaled, in ``out``."""
    data = read_dataset(source)
    factor = size / data.model.width
    (out / "images").mkdir(parents=True, exist_ok=True)
    write_camera(out, data.model.scaled(factor))
    for path in data.image_paths[:frames]:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(out / "images" / path.name), cv2.resize(image, (size, size), interpolation=cv2.INTER_CUBIC))
    # The ground truth of the frames kept (a TUM file is in time order, one pose per frame).
    truth = read_tum(source / "groundtruth.txt")
    kept = slice(0, min(frames, len(truth)))
    write_tum(out / "groundtruth.txt", Trajectory(timestamps=truth.timestamps[kept],
                                                  positions=truth.positions[kept], rotations=truth.rotations[kept]))
    return out


def warm_up(dataset: str, *, frames: int = 3) -> None:
    """Run every method once, untimed, on the first ``frames`` frames of ``dataset`` in this process."""
    data = read_dataset(dataset)
    images = list(islice(data.iter_images(skip_unreadable=True), frames))
    config = resolved_config(EstimateConfig(), data.model)
    for method in METHODS:
        estimate_sequence(images, data.model, method=method, config=config)


def measure_set(dataset: str, label: str, mode: str, *, rounds: int, frames: int, out: Path) -> dict:
    """Every method on one dataset and mode, interleaved: compute, end to end, ATE, stages."""
    data = read_dataset(dataset)
    n = min(frames, len(data.image_paths))
    config = resolved_config(mode_config(EstimateConfig(), mode), data.model)
    folder = out / mode / dataset_folder_id(dataset)
    folder.mkdir(parents=True, exist_ok=True)
    images = list(islice(data.iter_images(skip_unreadable=True), n))
    compute, cpu, wall = ({m: [] for m in METHODS} for _ in range(3))
    for _ in range(rounds):
        for method in METHODS:
            seconds, cpu_seconds = compute_seconds(images, data.model, method, config)
            compute[method].append(seconds / n)
            cpu[method].append(cpu_seconds / n)
            run = run_estimate(Path(dataset), method, mode, folder / f"{method}.txt")
            wall[method].append(run["wall_s"] / len(data.image_paths))
    ate, failed = {}, {}
    for method in METHODS:
        meta = evaluate_files(Path(dataset) / "groundtruth.txt", folder / f"{method}.txt",
                              out_dir=folder / f"{method}.eval")
        ate[method] = meta["summary"]["geodesic"]["rmse"]
        failed[method] = meta["summary"]["failures"]["count"]
    stages = csv_stages(folder / "ifmi.frames.csv") or {}
    return {"dataset": label, "mode": mode, "frames": len(data.image_paths), "timed_frames": n,
            "size": list(data.model.size),
            "compute_ms": {m: 1e3 * float(np.median(v)) for m, v in compute.items()},
            "compute_cpu_ms": {m: 1e3 * float(np.median(v)) for m, v in cpu.items()},
            "wall_ms": {m: 1e3 * float(np.median(v)) for m, v in wall.items()},
            "ate_rad": ate, "failed_frames": failed, "stages_ms": stages}


def measure_rss(dataset: str, *, size: int, frames: int, out: Path) -> dict:
    """Peak RSS (MiB) of ``ifmi estimate`` per method on ``dataset`` resized to ``size`` px."""
    resized = resized_dataset(Path(dataset), out / f"rss_{size}", size=size, frames=frames)
    return {m: run_estimate(resized, m, "frame", out / f"rss_{size}_{m}.txt")["rss_bytes"] / 2 ** 20
            for m in METHODS}


def ratios(row: dict) -> dict:
    """iFMI over ORB and AKAZE: compute, end-to-end wall and ATE."""
    out = {}
    for key in ("compute_ms", "compute_cpu_ms", "wall_ms", "ate_rad"):
        for base in ("orb", "akaze"):
            out[f"{key}/{base}"] = row[key]["ifmi"] / row[key][base]
    return out


def summary(rows: list, rss: dict | None, baseline: dict | None) -> list:
    """``(target, value, met)`` of each target: medians over the sets and modes of the ratios."""
    median = lambda key: float(np.median([ratios(r)[key] for r in rows]))  # noqa: E731
    lines = [("compute <= 0.5x ORB (median)", median("compute_ms/orb"), median("compute_ms/orb") <= 0.5),
             ("compute <= 0.25x AKAZE (median)", median("compute_ms/akaze"), median("compute_ms/akaze") <= 0.25),
             ("(CPU time) compute <= 0.5x ORB (median)", median("compute_cpu_ms/orb"),
              median("compute_cpu_ms/orb") <= 0.5),
             ("(CPU time) compute <= 0.25x AKAZE (median)", median("compute_cpu_ms/akaze"),
              median("compute_cpu_ms/akaze") <= 0.25),
             ("ifmi estimate wall <= 1.0x ORB (median)", median("wall_ms/orb"), median("wall_ms/orb") <= 1.0)]
    if rss:
        lines.append(("peak RSS <= ORB's", rss["ifmi"] / rss["orb"], rss["ifmi"] <= rss["orb"]))
    if baseline:
        worst = max(before_after(r, baseline)[1] / before_after(r, baseline)[0] for r in rows
                    if before_after(r, baseline)[0])
        lines.append(("ATE <= 1.1x baseline's (worst set)", worst, worst <= 1.1))
    return lines


def before_after(row: dict, baseline: dict) -> tuple[float | None, float]:
    """iFMI's ATE in ``baseline`` (None if it lacks the set and mode) and in ``row``."""
    for old in baseline["rows"]:
        if old["dataset"] == row["dataset"] and old["mode"] == row["mode"]:
            return old["ate_rad"]["ifmi"], row["ate_rad"]["ifmi"]
    return None, row["ate_rad"]["ifmi"]


def _or_nan(value) -> float:
    return float("nan") if value is None else value


def _table(head: list, body: list) -> list:
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r) + " |" for r in body]


def method_tables(rows: list, baseline: dict | None) -> list:
    """Markdown lines: time per frame and ratios per set and mode, then ATE (before/after with a baseline)."""
    head = ["set", "mode", "px"] + [f"compute {m} ms" for m in METHODS] + ["/ORB", "/AKAZE"]
    head += [f"CPU {m} ms" for m in METHODS] + ["/ORB", "/AKAZE"]
    head += [f"estimate {m} ms" for m in METHODS] + ["/ORB"]
    body = []
    for r in rows:
        q = ratios(r)
        body.append([r["dataset"], r["mode"], str(r["size"][1])]
                    + [f"{r['compute_ms'][m]:.1f}" for m in METHODS]
                    + [f"{q['compute_ms/orb']:.2f}", f"{q['compute_ms/akaze']:.2f}"]
                    + [f"{r['compute_cpu_ms'][m]:.1f}" for m in METHODS]
                    + [f"{q['compute_cpu_ms/orb']:.2f}", f"{q['compute_cpu_ms/akaze']:.2f}"]
                    + [f"{r['wall_ms'][m]:.1f}" for m in METHODS] + [f"{q['wall_ms/orb']:.2f}"])
    lines = _table(head, body) + [""]
    head = ["set", "mode"] + [f"ATE {m} (failed)" for m in METHODS]
    head += ["iFMI ATE before", "after/before"] if baseline else []
    body = []
    for r in rows:
        line = [r["dataset"], r["mode"]] + [f"{_or_nan(r['ate_rad'][m]):.2e} ({r['failed_frames'][m]})"
                                            for m in METHODS]
        if baseline:
            before, after = before_after(r, baseline)
            line += ["-", "-"] if before is None else [f"{before:.2e}", f"{after / before:.3f}"]
        body.append(line)
    return lines + _table(head, body)


def stage_table(rows: list) -> list:
    """Markdown lines: iFMI's ms per frame of each stage (rows) per set and mode (columns)."""
    stages = list(dict.fromkeys(s for r in rows for s in r["stages_ms"]))
    head = ["stage"] + [f"{r['dataset']} {r['mode']}" for r in rows]
    body = [[s] + [f"{r['stages_ms'][s]:.1f}" if s in r["stages_ms"] else "-" for r in rows] for s in stages]
    note = ("Wall time of each stage of the per-pair pipeline, the median per frame of the `t_<stage>_ms` "
            "columns of the iFMI run's `frames.csv`; a stage that a pair does not take counts 0.")
    return [note, ""] + _table(head, body)


def report_text(results: dict) -> str:
    """The MyST Markdown report of one run."""
    machine = results["machine"]
    lines = ["# iFMI speed against ORB and AKAZE", "",
             f"Measured {results['date']} on {machine['cpu']} ({machine['cores']} logical cores, "
             f"{machine['ram_gib']} GiB, Python {machine['python']}, OpenCV {cv2.__version__}, "
             f"NumPy {np.__version__}); load average {results['load']} at the start.", "",
             "```bash", results["command"], "```", "",
             "*compute*: ms per frame of the estimation with the frames already in memory (median of the "
             "interleaved rounds); *CPU*: the same runs' CPU time (this process, all its threads, so OpenCV's "
             "worker threads count), steadier than wall time on a loaded machine; *estimate*: wall time of `ifmi estimate` per frame, interpreter start, "
             "decoding and writing included; ATE: geodesic RMSE (rad) of that run against the ground truth.", "",
             "## Targets", ""]
    lines += _table(["target", "measured", "met"],
                    [[t, f"{v:.3f}", "yes" if ok else "**no**"] for t, v, ok in results["targets"]])
    lines += ["", "## Per set and mode", ""] + method_tables(results["rows"], results.get("baseline"))
    if results.get("rss_mib"):
        lines += ["", f"## Peak RSS at {results['rss_size']} px", "",
                  f"`ru_maxrss` of one `ifmi estimate` child per method on {results['rss_frames']} frames of "
                  f"`{results['rss_dataset']}` resized to {results['rss_size']} px square.", ""]
        lines += _table(["method", "peak RSS MiB"], [[m, f"{v:.0f}"] for m, v in results["rss_mib"].items()])
    lines += ["", "## iFMI per stage (ms per frame)", ""] + stage_table(results["rows"])
    return "\n".join(lines) + "\n"


def _shown(arg: str) -> str:
    """A command-line argument as printed: a path relative to the working directory, or its last two
    parts when it lies outside it (no machine's folders in a report)."""
    if not os.path.isabs(arg):
        return arg
    relative = os.path.relpath(arg)
    return relative if not relative.startswith("..") else str(Path(*Path(arg).resolve().parts[-2:]))


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", help="dataset folders (images, calibration, groundtruth.txt)")
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--rounds", type=int, default=3, help="interleaved timing rounds (median taken)")
    parser.add_argument("--frames", type=int, default=60, help="frames of each set timed in memory")
    parser.add_argument("--rss-size", type=int, default=2048, metavar="PX",
                        help="image size of the peak-RSS runs (0: none)")
    parser.add_argument("--rss-frames", type=int, default=4)
    parser.add_argument("--baseline", default=None, metavar="JSON",
                        help="bench_speed.json of an earlier run: iFMI's ATE before and after")
    parser.add_argument("--out", default="out/bench_speed")
    parser.add_argument("--report", default="reports/speed/README.md", help="MyST Markdown report to write")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.frames < 2 or args.rss_frames < 2 or args.rss_size < 0:
        parser.error("expected --rounds >= 1, --frames >= 2, --rss-frames >= 2 and --rss-size >= 0")
    return args


def run(args: argparse.Namespace, argv) -> dict:
    """Measure the parsed command line; the results as written to JSON."""
    out = Path(args.out)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    sets = labelled_datasets(args.datasets)
    warm_up(sets[0][0])
    rows = [measure_set(d, label, mode, rounds=args.rounds, frames=args.frames, out=out)
            for d, label in sets for mode in dict.fromkeys(args.modes)]
    rss = None
    if args.rss_size:
        rss = measure_rss(sets[0][0], size=args.rss_size, frames=args.rss_frames, out=out)
    baseline = json.loads(Path(args.baseline).read_text()) if args.baseline else None
    words = sys.argv[1:] if argv is None else list(argv)
    return {"command": " ".join(["python benchmarks/bench_speed.py"] + [_shown(w) for w in words]),
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "machine": machine_info(),
            "load": load, "rows": rows, "rss_mib": rss, "rss_size": args.rss_size,
            "rss_frames": args.rss_frames, "rss_dataset": sets[0][1],
            "baseline": baseline and {"rows": baseline["rows"]},
            "targets": summary(rows, rss, baseline)}


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        results = run(args, argv)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    text = report_text(results)
    print(text)
    atomic_write_json(Path(args.out) / "bench_speed.json", results)
    atomic_write_text(args.report, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
