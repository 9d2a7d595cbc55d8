"""Evaluate an estimate run against ground truth and save the result as files.

Reads the TUM files and the run's side files, computes the errors of
:mod:`ifmi.metrics` and writes an evaluation folder
(:func:`ifmi.io.results.write_evaluation`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .errors import InputError
from .io.results import jsonable, read_estimate_side_files, write_evaluation, write_motion_flow
from .io.tum import read_tum
from .metrics import AXES, summary_from_errors, trajectory_errors

__all__ = ["EvaluateOptions", "default_evaluation_dir", "evaluate_files", "format_summary_table",
           "dataset_label", "dataset_provenance", "motion_flow_sample", "MOTION_FLOW_FILE"]

# File name of the motion-flow sample written beside an iFMI evaluation.
MOTION_FLOW_FILE = "motion_flow.npz"


@dataclass(frozen=True)
class EvaluateOptions:
    """Options of an evaluation.

    Attributes
    ----------
    max_time_difference : float
        Largest timestamp difference (timestamp units, frames or seconds)
        for two poses to be associated.
    motion_flow : bool
        For an iFMI run whose dataset images are at hand, also save the tile
        flow of one frame pair (``motion_flow.npz``) for the report's figure.
    motion_flow_frames : (int, int)
        The frame pair of that sample.
    """

    max_time_difference: float = 1e-3
    motion_flow: bool = True
    motion_flow_frames: tuple[int, int] = (0, 1)

    def to_dict(self) -> dict:
        return {"max_time_difference": self.max_time_difference, "motion_flow": self.motion_flow,
                "motion_flow_frames": list(self.motion_flow_frames)}


def default_evaluation_dir(estimate_path: str | os.PathLike) -> Path:
    """``DIR/NAME.eval`` for the estimate ``DIR/NAME.txt``."""
    p = Path(estimate_path)
    return p.with_name((p.stem if p.suffix else p.name) + ".eval")


def dataset_label(dataset_dir: str | os.PathLike | None) -> tuple[str, str]:
    """``(dataset, scene)`` names of a dataset folder.

    The dataset name is the folder name; the scene is the ``scene_name`` (or
    ``scene``: a string, or a mapping with ``name``) entry of its
    ``meta.json`` when present, otherwise the dataset name.
    """
    if dataset_dir is None:
        return "unknown", "unknown"
    folder = Path(dataset_dir)
    name = folder.name or str(folder)
    scene = name
    meta_path = folder / "meta.json"
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            meta = {}
        value = None
        if isinstance(meta, dict):
            value = meta.get("scene_name") or meta.get("scene")
        if isinstance(value, dict):
            value = value.get("name")
        if isinstance(value, str) and value:
            scene = Path(value).stem
    return name, scene


def motion_flow_sample(dataset_dir: str | os.PathLike, *, config, frames: tuple[int, int] = (0, 1)) -> dict:
    """Tile flow of the iFMI front end between two frames of a dataset (for Fig. 2-style plots).

    Parameters
    ----------
    dataset_dir : path
        DATASET folder.
    config : ifmi.pipeline.EstimateConfig, keyword-only
        Configuration of the run (its ``ifmi`` part is used).
    frames : (int, int), keyword-only
        Frame indices ``(a, b)``.

    Returns
    -------
    dict of ndarray
        ``panorama_a``, ``panorama_b`` (H, W) uint8; ``points_a``,
        ``points_b`` (M, 2) panorama ``(row, col)`` of the kept tiles' centre
        flow (b's tile centre and where the flow equation puts it in a);
        ``tile_centers`` (T, 2) panorama ``(row, col)``; ``tile_size``;
        ``tiles_kept``; ``frames``.
    """
    from .flow import flow_from_tile_motion, flow_sample_points
    from .io.dataset import read_dataset, read_image
    from .spectral_front_end import IfmiFrontEnd
    from .unwarp import panorama_image_from_omni_image

    dataset = read_dataset(dataset_dir)
    a, b = (int(f) for f in frames)
    if not (0 <= a < len(dataset.image_paths) and 0 <= b < len(dataset.image_paths)):
        raise InputError(dataset_dir, f"frames {a}, {b} outside 0..{len(dataset.image_paths) - 1}")
    image_a = read_image(dataset.image_paths[a], size=dataset.model.size)
    image_b = read_image(dataset.image_paths[b], size=dataset.model.size)
    front = IfmiFrontEnd(dataset.model, config.ifmi)
    state_a, state_b = front.prepare(image_a), front.prepare(image_b)
    motion, origins_b = front.register(state_a, state_b)
    centre = flow_sample_points(front.layout.tile_size, points_per_tile=1)
    pairs = flow_from_tile_motion(motion, front.layout, front.mapping, points_b=centre,
                                  origins_b=origins_b)

    def pano(image):
        return np.clip(panorama_image_from_omni_image(front.mapping, image) + 0.5, 0, 255).astype(np.uint8)

    return {"panorama_a": pano(image_a), "panorama_b": pano(image_b),
            "points_a": pairs.panorama_a, "points_b": pairs.panorama_b,
            "tile_centers": front.layout.centers, "tile_size": np.array(front.layout.tile_size),
            "tiles_kept": np.array(int(motion.valid.sum())), "frames": np.array([a, b])}


# Entries of a dataset's meta.json carried into evaluations (provenance shown in reports).
DATASET_META_KEYS = ("scene_name", "frames", "resolution", "spp", "seed", "variant")


def dataset_provenance(dataset_dir: str | os.PathLike | None) -> dict:
    """Selected ``meta.json`` entries of a dataset folder (empty when unavailable)."""
    if dataset_dir is None:
        return {}
    try:
        meta = json.loads((Path(dataset_dir) / "meta.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(meta, dict):
        return {}
    return {k: meta[k] for k in DATASET_META_KEYS if k in meta}


def evaluate_files(gt_path: str | os.PathLike, est_path: str | os.PathLike, *,
                   out_dir: str | os.PathLike | None = None,
                   options: EvaluateOptions = EvaluateOptions()) -> dict:
    """Evaluate ``est_path`` against ``gt_path`` and write an evaluation folder.

    Parameters
    ----------
    gt_path, est_path : path
        TUM trajectory files (``R_0k``, frame 0 the identity).
    out_dir : path, optional, keyword-only
        Output folder; default :func:`default_evaluation_dir` of ``est_path``.
    options : EvaluateOptions, keyword-only

    Returns
    -------
    dict
        The content of ``evaluation.json`` (``summary`` holds the statistics).

    Raises
    ------
    InputError
        Missing or malformed input files, or no frame in common.
    """
    gt_path, est_path = Path(gt_path), Path(est_path)
    gt = read_tum(gt_path)
    est = read_tum(est_path)
    side = read_estimate_side_files(est_path)
    reference_t = None
    success = seconds = None
    if side.frames is not None:
        frames = side.frames
        success, seconds = frames.success, frames.seconds
        ref = frames.reference_frame
        if ref is not None and len(frames) == len(est):
            # Frame k of the estimate file is row k; map reference rows to timestamps.
            ref_rows = np.asarray(ref, dtype=np.float64)
            ok = np.isfinite(ref_rows) & (ref_rows >= 0) & (ref_rows < len(est))
            reference_t = np.full(len(est), np.nan)
            order = np.argsort(frames.frame)
            row_of_frame = {int(f): i for i, f in enumerate(frames.frame[order])}
            for i in np.flatnonzero(ok):
                j = row_of_frame.get(int(ref_rows[i]))
                if j is not None and j != i:
                    reference_t[i] = est.timestamps[j]
    try:
        errors = trajectory_errors(gt, est, max_time_difference=options.max_time_difference,
                                   reference_timestamps=reference_t)
    except ValueError as exc:
        raise InputError(est_path, str(exc)) from None
    summary = summary_from_errors(errors, n_gt=len(gt), n_est=len(est), frame_success=success,
                                  frame_seconds=seconds)
    config = side.config or {}
    dataset_dir = config.get("dataset") or str(gt_path.parent)
    dataset, scene = dataset_label(dataset_dir)
    meta = {
        "summary": summary,
        "method": config.get("method", "unknown"),
        "dataset": dataset,
        "scene": scene,
        "dataset_path": str(dataset_dir),
        "dataset_meta": dataset_provenance(dataset_dir),
        "groundtruth_path": str(gt_path.resolve()),
        "estimate_path": str(est_path.resolve()),
        "options": options.to_dict(),
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "per_frame_columns": list(errors.arrays()),
    }
    out = Path(out_dir) if out_dir is not None else default_evaluation_dir(est_path)
    flow = None
    if options.motion_flow and meta["method"] == "ifmi" and config.get("config") is not None \
            and Path(dataset_dir, "images").is_dir():
        from .pipeline import EstimateConfig

        try:
            flow = motion_flow_sample(dataset_dir, config=EstimateConfig.from_dict(config["config"]),
                                      frames=options.motion_flow_frames)
            meta["motion_flow"] = MOTION_FLOW_FILE
        except Exception as exc:  # the figure's data is optional; the evaluation stands
            meta["motion_flow"] = None
            meta["motion_flow_error"] = f"{type(exc).__name__}: {exc}"
    write_evaluation(out, meta=meta, arrays=errors.arrays(), side_files=side)
    if flow is not None:
        write_motion_flow(out / MOTION_FLOW_FILE, flow)
    meta = jsonable(meta)
    meta["path"] = str(out)
    return meta


def _fmt(v, scale: float = 1.0, digits: int = 4) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    return f"{v * scale:.{digits}f}"


def format_summary_table(meta: dict) -> str:
    """Readable plain-text table of an evaluation summary (radians and degrees)."""
    s = meta["summary"]
    deg = 180.0 / np.pi
    lines = [f"method {meta.get('method')}  dataset {meta.get('dataset')}  "
             f"frames {s['frames']['associated']}/{s['frames']['ground_truth']} associated",
             f"{'error':<24}{'RMSE rad':>10}{'mean rad':>10}{'std rad':>10}{'max rad':>10}"
             f"{'RMSE deg':>10}"]

    def row(name, st):
        lines.append(f"{name:<24}{_fmt(st['rmse']):>10}{_fmt(st['mean']):>10}{_fmt(st['std']):>10}"
                     f"{_fmt(st['max']):>10}{_fmt(st['rmse'], deg, 3):>10}")

    for axis in AXES:
        row(axis, s["axes"][axis])
    lines.append(f"{'mean of roll/pitch/yaw':<24}{_fmt(s['mean_rmse']):>10}")
    row("geodesic", s["geodesic"])
    row("relative (per frame)", s["relative_geodesic"])
    row("translation direction", s["translation_direction"])
    if s.get("failures") is not None:
        lines.append(f"failed frames: {s['failures']['count']} of {s['failures']['frames']}")
    if s.get("time") is not None:
        lines.append(f"time per frame: {s['time']['mean_s'] * 1e3:.2f} ms mean, "
                     f"{s['time']['median_s'] * 1e3:.2f} ms median")
    return "\n".join(lines)
