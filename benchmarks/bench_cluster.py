"""Frames per second of a Dask render (local cluster) against one process.

Renders the same frames of a scene into two fresh dataset folders, once in
this process and once with ``--workers N`` (a local cluster of N
single-threaded processes), checks that the files are byte-identical and
prints frames per second of each and their ratio. Wall time includes loading
the scene (once per process) and, for the cluster, starting it. Each process
renders with all the machine's cores, so on a 2-core machine the ratio stays
below 2 (the cores are shared, and Mitsuba already uses both in one process).

Run: python benchmarks/bench_cluster.py [--scene scenes/office.toml] [--frames 8] [--workers 2]
     [--resolution 256] [--spp 16] [--out /tmp/bench_cluster]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _files(folder: Path) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file() and p.name != "meta.json"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "office.toml"))
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--out", help="scratch folder (default: a temporary one, removed afterwards)")
    args = parser.parse_args()

    from omnisim.render import render_dataset

    scratch = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_cluster_"))
    common = dict(frames=args.frames, spp=args.spp, resolution=args.resolution, progress=False)
    try:
        results = {}
        for label, extra in (("one process", {}), (f"{args.workers} workers", {"workers": args.workers})):
            out = scratch / label.replace(" ", "_")
            shutil.rmtree(out, ignore_errors=True)
            start = time.perf_counter()
            render_dataset(args.scene, out, **common, **extra)
            results[label] = (time.perf_counter() - start, out)
        (single, single_out), (parallel, parallel_out) = results.values()
        same = _files(single_out) == _files(parallel_out)
        print(f"{Path(args.scene).stem}: {args.frames} frames, {args.resolution}x{args.resolution}, {args.spp} spp")
        for label, (seconds, _) in results.items():
            print(f"  {label:12s} {seconds:7.2f} s   {args.frames / seconds:.3f} frames/s")
        print(f"  ratio {args.workers} workers / one process: {single / parallel:.2f}x frames per second; "
              f"files byte-identical: {same}")
    finally:
        if not args.out:
            shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
