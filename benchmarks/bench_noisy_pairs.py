"""iFMI with and without the band-limited search of noise-dominated pairs: ATE and compute, in one process.

The registration engine searches a pair again on a band-limited correlation
surface when fewer than ``noisy_pair_fraction`` of its tiles pass the noise
filters on the phase-only surface
(:attr:`ifmi.spectral.fourier_mellin.FourierMellinConfig.noisy_pair_fraction`),
on block-compressed captures only (:mod:`ifmi.spectral.compression`).
This benchmark runs every dataset and mode twice, with the default and with
the phase-only search alone (the fraction 0), and prints both ATEs; then the
compute per frame of both, frames decoded into memory, in ``--rounds``
rounds taking turns (thread CPU time, steadier than wall time on a loaded
machine)::

    python benchmarks/bench_noisy_pairs.py DATA/rough/office_all DATA/raw512/office --out out/bench_noisy_pairs

A set whose pairs all keep at least that fraction of their tiles, or whose
frames show no block grid, gives the same estimates bit for bit (``same`` in
the table).

With ``--features`` (the ``bench_methods.json`` of ORB and AKAZE on the same
sets) and ``--table FILE`` it also writes a Markdown table of iFMI's ATE over
the better feature method's, and counts the runs at or under a third of it
and under it; sets given with ``--clean`` are run and listed but not
counted.
"""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchlib import mode_config, run_method
from ifmi.evaluation.dataset_names import dataset_labels, resolved_folder
from ifmi.io.atomic import atomic_write_json
from ifmi.io.camera_file import calibration_path, read_camera
from ifmi.io.dataset import read_dataset
from ifmi.pipeline import EstimateConfig, estimate_sequence, resolved_config
from ifmi.spectral.ifmi_front_end import RegistrationOptions

# The two searches compared: the default, and the phase-only surface alone.
SEARCHES = ("default", "phase_only")
# Goal of the rough-capture table: iFMI's ATE at most this share of the better feature method's.
GOAL_SHARE = 1.0 / 3.0


@contextmanager
def search(name: str):
    """Within it, the iFMI registration engine uses search ``name`` (one of :data:`SEARCHES`)."""
    original = RegistrationOptions.engine_config
    if name == "phase_only":
        RegistrationOptions.engine_config = lambda self, **kw: replace(original(self, **kw), noisy_pair_fraction=0.0)
    try:
        yield
    finally:
        RegistrationOptions.engine_config = original


def compute_cpu(dataset: str, config: EstimateConfig, *, rounds: int) -> dict:
    """Median thread-CPU seconds per frame of each search, frames in memory, the searches taking turns."""
    data = read_dataset(dataset)
    frames = list(data.iter_images(skip_unreadable=True))
    cpu = {name: [] for name in SEARCHES}
    for _ in range(rounds):
        for name in SEARCHES:
            with search(name):
                start = time.thread_time()
                estimate_sequence(frames, data.model, method="ifmi", config=config)
                cpu[name].append((time.thread_time() - start) / len(frames))
    return {name: float(np.median(values)) for name, values in cpu.items()}


def _estimates(folder: Path) -> list[str]:
    return [line for line in (folder / "ifmi.txt").read_text().splitlines() if not line.startswith("#")]


def feature_ates(path: str) -> dict:
    """``{(dataset, mode): (orb, akaze)}`` geodesic ATEs (rad) of a ``bench_methods.json``."""
    import json

    ates = {}
    for row in json.loads(Path(path).read_text(encoding="utf-8"))["rows"]:
        ates.setdefault((row["dataset"], row["mode"]), {})[row["method"]] = row["geodesic_rmse"]
    return {key: (value["orb"], value["akaze"]) for key, value in ates.items() if {"orb", "akaze"} <= set(value)}


def goal_table(rows: list[dict], features: dict, clean: set[str]) -> str:
    """Markdown table of each run's ATEs and its ratios to the better feature method, and the goal counts.

    Rows of a dataset in ``clean`` are listed, marked, and not counted; a
    row without feature ATEs in ``features`` is an error (a KeyError naming it).
    """
    lines = ["| set | mode | iFMI phase-only | iFMI default | default/phase-only | ORB | AKAZE "
             "| phase-only/best | default/best |", "|---|---|---|---|---|---|---|---|---|"]
    counted = [0, 0, 0, 0, 0]  # runs, default <= goal, phase-only <= goal, default < 1, phase-only < 1
    for row in sorted(rows, key=lambda r: r["dataset"] in clean):
        orb, akaze = features[(row["dataset"], row["mode"])]
        phase, default = row["ate_phase_only"], row["ate_default"]
        best = min(orb, akaze)
        name = f"{row['dataset']} (clean)" if row["dataset"] in clean else row["dataset"]
        same = " (same)" if row["same_estimates"] else ""
        lines.append(f"| {name} | {row['mode']} | {phase:.5f} | {default:.5f} | {default / phase:.2f}{same} "
                     f"| {orb:.5f} | {akaze:.5f} | {phase / best:.2f} | {default / best:.2f} |")
        if row["dataset"] not in clean:
            hits = (True, default <= GOAL_SHARE * best, phase <= GOAL_SHARE * best, default < best, phase < best)
            counted = [c + bool(h) for c, h in zip(counted, hits)]
    n, goal_default, goal_phase, under_default, under_phase = counted
    lines += ["", f"Runs counted (not clean): {n}. At or under 1/3 of the better feature method: default "
              f"{goal_default}, phase-only {goal_phase}. Under 1x: default {under_default}, phase-only {under_phase}."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--modes", nargs="+", choices=("frame", "keyframe"), default=["frame", "keyframe"])
    parser.add_argument("--rounds", type=int, default=3, help="compute rounds (0: ATE only)")
    parser.add_argument("--out", default="out/bench_noisy_pairs")
    parser.add_argument("--clean", nargs="*", default=[], metavar="DATASET",
                        help="further datasets, run and listed in the table but not counted toward the goal")
    parser.add_argument("--features", default=None, metavar="JSON",
                        help="bench_methods.json of ORB and AKAZE on the same datasets (for --table)")
    parser.add_argument("--table", default=None, metavar="FILE", help="Markdown table against ORB and AKAZE")
    args = parser.parse_args(argv)
    if (args.features is None) != (args.table is None):
        parser.error("--features and --table go together")
    features = feature_ates(args.features) if args.features else None
    out = Path(args.out)
    rows = []
    print("ATE: geodesic RMSE (rad); ms: thread CPU per frame, frames in memory; ratio: default / phase-only")
    print(f"{'dataset':<26}{'mode':<9}{'ATE phase-only':>15}{'ATE default':>12}{'ratio':>7}{'same':>6}"
          f"{'ms phase-only':>14}{'ms default':>11}{'ratio':>7}")
    datasets = list(args.datasets) + list(args.clean)
    labels = dataset_labels(datasets)
    clean = {labels[resolved_folder(d)] for d in args.clean}
    for dataset in datasets:
        label = labels[resolved_folder(dataset)]
        model = read_camera(calibration_path(dataset))
        for mode in args.modes:
            config = resolved_config(mode_config(EstimateConfig(), mode), model)
            ate, folders = {}, {}
            for name in SEARCHES:
                with search(name):
                    row = run_method(dataset, "ifmi", mode, config, out / name, label=label)
                ate[name] = row["geodesic_rmse"]
                folders[name] = out / name / mode / row["dataset_id"]
            same = _estimates(folders["default"]) == _estimates(folders["phase_only"])
            cpu = compute_cpu(dataset, config, rounds=args.rounds) if args.rounds > 0 else None
            timing = (f"{cpu['phase_only'] * 1e3:>14.2f}{cpu['default'] * 1e3:>11.2f}"
                      f"{cpu['default'] / cpu['phase_only']:>7.3f}" if cpu else "")
            print(f"{label:<26}{mode:<9}{ate['phase_only']:>15.5f}{ate['default']:>12.5f}"
                  f"{ate['default'] / ate['phase_only']:>7.2f}{'yes' if same else 'no':>6}{timing}", flush=True)
            rows.append({"dataset": label, "mode": mode, "ate_phase_only": ate["phase_only"],
                         "ate_default": ate["default"], "same_estimates": same, "cpu_s": cpu})
    atomic_write_json(out / "bench_noisy_pairs.json", {"rows": rows, "rounds": args.rounds,
                                                       "argv": sys.argv if argv is None else argv})
    if args.table:
        from ifmi.io.atomic import atomic_write_text

        atomic_write_text(Path(args.table), goal_table(rows, features, clean))
        print(f"table written to {args.table}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
