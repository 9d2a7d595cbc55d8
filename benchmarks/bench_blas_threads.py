"""BLAS thread limit: each method's time per frame with one BLAS thread (as estimates run) and with the library default.

``ifmi.pipeline.estimate_sequence`` tracks every sequence with one BLAS thread
(:mod:`ifmi.runtime.blas_threads`). This benchmark measures what that limit
changes: for each dataset and mode, every method runs on the frames already
in memory, with the limit and with it replaced by a null context (the BLAS
library's own thread count, one per core with OpenBLAS), in interleaved
rounds whose order alternates; the first round warms up and is not counted.
It prints, per run, the median wall and CPU milliseconds per frame (CPU time
of this process, all its threads) and the ratios default / one thread.

Run: python benchmarks/bench_blas_threads.py DATA [DATA ...] [--modes frame keyframe] [--rounds 4] [--frames 30]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
from itertools import islice

import ifmi.pipeline as pipeline
from benchlib import METHODS, MODES, compute_seconds, labelled_datasets, machine_line, mode_config, status_of
from ifmi.io.dataset import read_dataset
from ifmi.pipeline import EstimateConfig, resolved_config

# The two ways a run is made: the shipped limit, and the BLAS library's own default.
LIMITS = {"one": pipeline.single_blas_thread, "default": contextlib.nullcontext}


def timed_run(images: list, model, method: str, config: EstimateConfig, limit) -> tuple[float, float]:
    """Wall and CPU milliseconds per frame of one in-memory run with ``limit`` around the tracking."""
    pipeline.single_blas_thread = limit
    try:
        wall, cpu = compute_seconds(images, model, method, config)
        return 1e3 * wall / len(images), 1e3 * cpu / len(images)
    finally:
        pipeline.single_blas_thread = LIMITS["one"]


def measure(dataset: str, mode: str, *, rounds: int, frames: int) -> dict:
    """``{(method, limit): [(wall ms, cpu ms), ...]}`` over the counted rounds of one dataset and mode."""
    data = read_dataset(dataset)
    images = list(islice(data.iter_images(skip_unreadable=True), frames))
    config = resolved_config(mode_config(EstimateConfig(), mode), data.model)
    times = {}
    for round_index in range(rounds + 1):
        order = list(LIMITS) if round_index % 2 else list(LIMITS)[::-1]
        for method in METHODS:
            for label in order:
                measured = timed_run(images, data.model, method, config, LIMITS[label])
                if round_index:
                    times.setdefault((method, label), []).append(measured)
    return times


def table_lines(label: str, mode: str, times: dict) -> list[str]:
    """Markdown rows: per method the median wall and CPU ms per frame, default -> one, and their ratios."""
    rows = []
    for method in METHODS:
        (dw, dc), (ow, oc) = ((statistics.median(t[0] for t in times[method, k]),
                               statistics.median(t[1] for t in times[method, k])) for k in ("default", "one"))
        rows.append(f"| {label} | {mode} | {method} | {dw:.1f} | {ow:.1f} | {dw / ow:.2f} | {dc:.1f} | {oc:.1f} "
                    f"| {dc / oc:.2f} |")
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", help="dataset folders")
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--rounds", type=int, default=4, help="counted interleaved rounds (median taken)")
    parser.add_argument("--frames", type=int, default=30, help="frames of each set timed in memory")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.frames < 2:
        parser.error(f"expected --rounds >= 1 and --frames >= 2, got {args.rounds}, {args.frames}")

    def work() -> str:
        sets = labelled_datasets(args.datasets)
        print(machine_line())
        print("| set | mode | method | wall default ms | wall one ms | ratio | CPU default ms | CPU one ms | ratio |")
        print("|---|---|---|---|---|---|---|---|---|")
        for dataset, label in sets:
            for mode in args.modes:
                print("\n".join(table_lines(label, mode, measure(dataset, mode, rounds=args.rounds,
                                                                   frames=args.frames))), flush=True)
        return "ratios: default over one BLAS thread (above 1: the limit is faster)"

    return status_of(work)


if __name__ == "__main__":
    raise SystemExit(main())
