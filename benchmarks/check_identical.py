"""Whether two source trees of the project estimate the same trajectories, bit for bit.

Runs ``ifmi estimate`` of both trees (``python -m ifmi.cli`` with the
tree first on ``PYTHONPATH``) on each DATASET, for each method and mode
(frame to frame, ``--keyframes``), and compares the written TUM files and
the rotation columns of ``frames.csv``. Prints one line per set, mode and
method: ``identical``, or the largest angle between the two trees' poses
``R_0k`` (radians) and the frames that differ.

Usage::

    python benchmarks/check_identical.py --base OTHER_TREE DATASET [DATASET ...]
        [--methods ifmi orb akaze] [--modes frames keyframes] [--work DIR] [--config JSON]

``--base`` is a checkout of the other version (``git worktree add DIR COMMIT``);
the current tree is the one this script lies in, or ``--tree``. The
estimates are kept under ``--work`` (default a temporary folder); the base
tree's estimates found there are reused.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ifmi.evaluation.dataset_names import dataset_labels, resolved_folder

MODES = {"frames": [], "keyframes": ["--keyframes"]}


def _estimate(tree: Path, dataset: Path, out: Path, method: str, mode: str, config: Path | None) -> Path:
    """Run ``ifmi estimate`` of ``tree`` (with ``--config config`` when given); the written TUM path."""
    out.parent.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(tree)}
    command = [sys.executable, "-m", "ifmi.cli", "estimate", str(dataset), "--method", method,
               "--out", str(out), "--force", "--no-progress", *MODES[mode]]
    if config is not None:
        command += ["--config", str(config)]
    done = subprocess.run(command, env=env, capture_output=True, text=True, cwd=str(tree))
    # Status 3: written, but more than half the frames failed (still an estimate to compare).
    if done.returncode not in (0, 3):
        raise RuntimeError(f"{tree}: {' '.join(command)} failed:\n{done.stderr}")
    return out


def _rotations(path: Path) -> np.ndarray:
    """``(N, 3, 3)`` rotations of a TUM file (qx qy qz qw in columns 4-7)."""
    from scipy.spatial.transform import Rotation

    rows = np.loadtxt(path, comments="#", ndmin=2)
    return Rotation.from_quat(rows[:, 4:8]).as_matrix()


def compared(base: Path, tree: Path) -> str:
    """``identical`` or the largest pose angle between two TUM files and the frames that differ."""
    if base.read_bytes() == tree.read_bytes():
        return "identical"
    a, b = _rotations(base), _rotations(tree)
    if len(a) != len(b):
        return f"different frame counts {len(a)} and {len(b)}"
    relative = np.einsum("kji,kjl->kil", a, b)
    angle = np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1) / 2, -1, 1))
    frames = np.flatnonzero(angle > 0)
    return f"max rotation difference {angle.max():.3g} rad, {len(frames)} frames differ (first {frames[:5].tolist()})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--base", type=Path, required=True, help="the other source tree")
    parser.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1],
                        help="this source tree (default: the one holding this script)")
    parser.add_argument("--methods", nargs="+", default=["ifmi"])
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    parser.add_argument("--work", type=Path, default=None, help="folder for the estimates")
    parser.add_argument("--config", type=Path, default=None,
                        help="configuration file given to both trees' ifmi estimate --config")
    args = parser.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="check_identical_"))
    # Distinct names for folders of one name (sweep sets are all ".../SET/dataset"): the kept base
    # estimates are found by name.
    labels = dataset_labels(args.datasets)
    all_same = True
    for dataset in args.datasets:
        label = labels[resolved_folder(dataset)]
        for mode in args.modes:
            for method in args.methods:
                tag = "" if args.config is None else f"_{args.config.stem}"
                name = f"{label.replace('/', '_')}_{mode}_{method}{tag}.txt"
                base = work / "base" / name
                if not base.exists():  # the base tree's estimates are kept for later runs
                    _estimate(args.base.resolve(), dataset.resolve(), base, method, mode, args.config)
                tree = _estimate(args.tree.resolve(), dataset.resolve(), work / "tree" / name, method, mode,
                                 args.config)
                verdict = compared(base, tree)
                all_same &= verdict == "identical"
                print(f"{label:24s} {mode:9s} {method:6s} {verdict}", flush=True)
    return 0 if all_same else 1


if __name__ == "__main__":
    sys.exit(main())
