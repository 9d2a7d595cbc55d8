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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--modes", nargs="+", choices=("frame", "keyframe"), default=["frame", "keyframe"])
    parser.add_argument("--rounds", type=int, default=3, help="compute rounds (0: ATE only)")
    parser.add_argument("--out", default="out/bench_noisy_pairs")
    args = parser.parse_args(argv)
    out = Path(args.out)
    rows = []
    print("ATE: geodesic RMSE (rad); ms: thread CPU per frame, frames in memory; ratio: default / phase-only")
    print(f"{'dataset':<26}{'mode':<9}{'ATE phase-only':>15}{'ATE default':>12}{'ratio':>7}{'same':>6}"
          f"{'ms phase-only':>14}{'ms default':>11}{'ratio':>7}")
    labels = dataset_labels(args.datasets)
    for dataset in args.datasets:
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
