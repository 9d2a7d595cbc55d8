"""iFMI of two source trees on the same frames: compute time per frame and whether the estimates agree.

Each tree (a checkout holding the ``ifmi`` package) runs in its own worker
process with that tree first on the path; the driver alternates the trees
round by round, so load from other processes on the machine hits both
alike. A worker decodes the first ``--frames`` frames of every set into
memory, runs iFMI once on each (its estimate is kept), then times
``--repeats`` further runs per set as thread-CPU time (``time.thread_time``,
the estimating thread only) and process-CPU time (``time.process_time``,
which also counts OpenCV's and the FFT's worker threads).

Usage::

    python benchmarks/bench_versions.py TREE_A TREE_B --sets SET [SET ...] \
        [--frames 40] [--rounds 5] [--repeats 1] [--mode frame] [--out result.json]

Prints per set and tree the median over the rounds of both times per frame,
the geodesic ATE RMSE and frame-to-frame RMSE against the ground truth
(rad), the failed frames, and the largest entry of the difference of the
two trees' orientation matrices (0 when they are bit-identical).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

_BENCHMARKS = Path(__file__).resolve().parent


def _worker(sets: list, frames: int, repeats: int, mode: str) -> dict:
    """Estimate and time iFMI on ``sets`` with the ``ifmi`` found on the path (run in a worker)."""
    import time
    from itertools import islice

    from ifmi.io.dataset import read_dataset
    from ifmi.io.tum import read_tum
    from ifmi.evaluation.metrics import error_stats, trajectory_errors
    from ifmi.pipeline import EstimateConfig, estimate_sequence, resolved_config

    sys.path.insert(0, str(_BENCHMARKS))
    from benchlib import mode_config

    out = {}
    for name in sets:
        data = read_dataset(name)
        n = min(frames, len(data.image_paths))
        images = list(islice(data.iter_images(skip_unreadable=True), n))
        config = resolved_config(mode_config(EstimateConfig(), mode), data.model)
        stamps = np.asarray(data.frame_indices[:n], dtype=np.float64)
        estimate = estimate_sequence(images, data.model, method="ifmi", config=config, timestamps=stamps)
        thread, process = [], []
        for _ in range(repeats):
            t0, p0 = time.thread_time(), time.process_time()
            estimate_sequence(images, data.model, method="ifmi", config=config, timestamps=stamps)
            thread.append((time.thread_time() - t0) / n)
            process.append((time.process_time() - p0) / n)
        row = {"thread_s": float(np.median(thread)), "process_s": float(np.median(process)),
               "rotations": estimate.trajectory.rotations.tolist(),
               "failures": int(sum(not r.success for r in estimate.frames))}
        if data.groundtruth_path is not None:
            errors = trajectory_errors(read_tum(data.groundtruth_path), estimate.trajectory)
            row["ate"] = error_stats(errors.geodesic).rmse
            row["f2f"] = error_stats(errors.relative_geodesic).rmse  # NaN when no pair is finite
        out[name] = row
    return out


def _run_tree(tree: str, args) -> dict:
    """One worker process with ``tree`` first on the path; its results."""
    with tempfile.TemporaryDirectory() as tmp:
        result = Path(tmp) / "result.json"
        env = dict(os.environ, PYTHONPATH=str(Path(tree).resolve()))
        subprocess.run([sys.executable, __file__, "--worker", str(result), "--sets", *args.sets,
                        "--frames", str(args.frames), "--repeats", str(args.repeats), "--mode", args.mode],
                       env=env, check=True)
        return json.loads(result.read_text())


def _worker_result(args) -> dict:
    """The worker's figures, or ``{"error": message}`` for bad input (a one-line message)."""
    from ifmi.errors import InputError

    try:
        return _worker(args.sets, args.frames, args.repeats, args.mode)
    except InputError as exc:
        return {"error": str(exc)}


def _largest_difference(rotations_a: list, rotations_b: list) -> float:
    """Largest entry of ``|R_a - R_b|`` over two lists of orientation matrices (about the angle
    between them in radians when small; 0 exactly when they are bit-identical)."""
    a, b = np.asarray(rotations_a), np.asarray(rotations_b)
    if a.shape != b.shape:
        return float("nan")
    return float(np.max(np.abs(a - b)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trees", nargs="*", help="two checkouts (baseline first)")
    parser.add_argument("--sets", nargs="+", required=True, help="dataset folders")
    parser.add_argument("--frames", type=int, default=40, help="first frames of each set")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds per tree")
    parser.add_argument("--repeats", type=int, default=1, help="timed runs per set and round")
    parser.add_argument("--mode", choices=("frame", "keyframe"), default="frame")
    parser.add_argument("--out", type=Path, help="JSON file of all figures")
    parser.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker is not None:
        args.worker.write_text(json.dumps(_worker_result(args)))
        return 0
    if len(args.trees) != 2:
        parser.error(f"expected two source trees, got {len(args.trees)}")
    runs = {tree: [] for tree in args.trees}
    for _ in range(args.rounds):
        for tree in args.trees:
            result = _run_tree(tree, args)
            if "error" in result:
                print(f"error: {result['error']}", file=sys.stderr)
                return 2
            runs[tree].append(result)
    base, new = args.trees
    summary = {}
    print(f"{'set':<28}{'thread ms':>20}{'process ms':>20}{'ATE':>24}{'f2f':>24}{'fail':>8}{'max diff':>10}")
    for name in args.sets:
        row = {}
        for tree in args.trees:
            first = runs[tree][0][name]
            row[tree] = {"thread_ms": 1e3 * float(np.median([r[name]["thread_s"] for r in runs[tree]])),
                         "process_ms": 1e3 * float(np.median([r[name]["process_s"] for r in runs[tree]])),
                         "ate": first.get("ate"), "f2f": first.get("f2f"), "failures": first["failures"]}
        row["max_rotation_difference"] = _largest_difference(runs[base][0][name]["rotations"],
                                                            runs[new][0][name]["rotations"])
        summary[name] = row
        b, a = row[base], row[new]
        label = Path(name).name
        print(f"{label:<28}{b['thread_ms']:>9.1f} ->{a['thread_ms']:>7.1f}{b['process_ms']:>11.1f} ->"
              f"{a['process_ms']:>7.1f}{b['ate'] or float('nan'):>12.3e} ->{a['ate'] or float('nan'):>9.3e}"
              f"{b['f2f'] or float('nan'):>12.3e} ->{a['f2f'] or float('nan'):>9.3e}"
              f"{b['failures']:>4} ->{a['failures']:>2}{row['max_rotation_difference']:>10.1e}")
    if args.out is not None:
        from ifmi.io.atomic import atomic_write_json
        atomic_write_json(args.out, {"trees": args.trees, "frames": args.frames, "rounds": args.rounds,
                                     "sets": summary})
    return 0


if __name__ == "__main__":
    sys.exit(main())
