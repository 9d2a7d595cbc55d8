"""Frames per second of a Dask render (local cluster) against one process.

Renders the same frames of a scene twice through :func:`omnisim.renderer.frame_results`
-- once in this process, once with ``workers=N`` (a local cluster of N
processes sharing the cores) -- checks that every file is byte-identical and
prints, for each: the time to the first frame (scene loading, and for the
cluster its start), the steady rate (frames after the first, per second of
wall time after it) and the overall rate. On a 2-core machine expect less
than 2x: Mitsuba already uses both cores in one process.

Run: python benchmarks/bench_cluster.py [--scene scenes/office.toml] [--frames 16] [--workers 2]
     [--resolution 256] [--spp 16]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(plan, jobs, **where):
    from omnisim.renderer import frame_results

    start = time.perf_counter()
    stamps, files = [], {}
    for _, frame_files in frame_results(plan, jobs, **where):
        stamps.append(time.perf_counter() - start)
        files.update(frame_files)
    return stamps, files


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "office.toml"))
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args()

    from omnisim.renderer import frame_plan

    plan = frame_plan(args.scene, frames=args.frames, spp=args.spp, resolution=args.resolution)
    jobs = [(k, ("images",)) for k in range(args.frames)]
    runs = {"one process": _run(plan, jobs), f"{args.workers} workers": _run(plan, jobs, workers=args.workers)}
    print(f"{plan.config.name}: {args.frames} frames, {args.resolution}x{args.resolution}, {args.spp} spp")
    rates = {}
    for label, (stamps, _) in runs.items():
        steady = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 else float("nan")
        rates[label] = (steady, len(stamps) / stamps[-1])
        print(f"  {label:12s} first frame after {stamps[0]:6.2f} s   steady {steady:.3f} frames/s   "
              f"overall {rates[label][1]:.3f} frames/s")
    single, parallel = runs.values()
    (steady_1, overall_1), (steady_n, overall_n) = rates.values()
    print(f"  ratio {args.workers} workers / one process: steady {steady_n / steady_1:.2f}x, "
          f"overall {overall_n / overall_1:.2f}x; files byte-identical: {single[1] == parallel[1]}")


if __name__ == "__main__":
    main()
