"""Figures of evaluations, sweeps and motion flow (matplotlib, Agg backend, headless).

Every function draws from data it is given and writes one PNG atomically.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ifmi.io.atomic import atomic_write_bytes  # noqa: E402
from ifmi.tracking.methods import method_colors  # noqa: E402

__all__ = ["save_figure", "rpy_over_frames", "sweep_heatmap", "motion_flow_figure"]

# Resolution of saved figures, dots per inch.
DPI = 110


def save_figure(fig, path: str | os.PathLike) -> Path:
    """Save ``fig`` as PNG to ``path`` atomically and close it."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


def rpy_over_frames(series: Mapping[str, Mapping[str, np.ndarray]], *, title: str,
                    path: str | os.PathLike, rmse: Mapping[str, Sequence[float]] | None = None) -> Path:
    """Roll, pitch and yaw over frames of several methods against ground truth.

    Parameters
    ----------
    series : mapping method -> mapping
        Per method: ``timestamp`` (N,), ``roll_est``/``pitch_est``/``yaw_est``
        (N,) and ``roll_gt``/``pitch_gt``/``yaw_gt`` (N,), radians; the
        ground truth is drawn from the first method. Any method name is drawn,
        in its colour of :func:`ifmi.tracking.methods.method_colors`.
    title : str, keyword-only
    path : path, keyword-only
        PNG to write.
    rmse : mapping method -> (3,) sequence, optional, keyword-only
        Per-axis RMSE (radians) shown in the legend.
    """
    axes_names = ("roll", "pitch", "yaw")
    colors = method_colors(series)
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.6), sharex=True)
    first = next(iter(series.values()))
    for i, (ax, axis) in enumerate(zip(axes, axes_names)):
        ax.plot(first["timestamp"], first[f"{axis}_gt"], color="black", lw=2.2, label="ground truth")
        for method, data in series.items():
            label = method
            if rmse is not None and method in rmse:
                label = f"{method} (RMSE {rmse[method][i]:.4f} rad)"
            ax.plot(data["timestamp"], data[f"{axis}_est"], lw=1.2,
                    color=colors[method], label=label)
        ax.set_title(axis)
        ax.set_xlabel("frame")
        ax.set_ylabel(f"{axis} [rad]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def sweep_heatmap(table, *, metric: str, label: str, title: str, path: str | os.PathLike) -> Path:
    """Heatmap of one metric over tile size (rows) and overlap (columns).

    Parameters
    ----------
    table : pandas.DataFrame
        Columns ``tile_size``, ``overlap`` and ``metric`` (one row per cell).
    metric, label, title : str, keyword-only
    path : path, keyword-only
    """
    grid = table.pivot_table(index="tile_size", columns="overlap", values=metric, aggfunc="mean")
    values = grid.to_numpy(dtype=float)
    fig, ax = plt.subplots(figsize=(1.6 + 1.3 * values.shape[1], 1.4 + 0.8 * values.shape[0]))
    im = ax.imshow(values, cmap="viridis", aspect="auto", origin="lower")
    ax.set_xticks(range(values.shape[1]), [f"{v:g}" for v in grid.columns])
    ax.set_yticks(range(values.shape[0]), [f"{v:g}" for v in grid.index])
    ax.set_xlabel("overlap (fraction of a tile)")
    ax.set_ylabel("tile size (px, or fraction of width if < 1)")
    finite = values[np.isfinite(values)]
    mid = (finite.min() + finite.max()) / 2 if finite.size else 0
    for (r, c), v in np.ndenumerate(values):
        if np.isfinite(v):
            ax.text(c, r, f"{v:.3g}", ha="center", va="center", fontsize=8,
                    color="white" if v < mid else "black")
    fig.colorbar(im, ax=ax, label=label)
    ax.set_title(title, fontsize=9)
    return save_figure(fig, path)


def motion_flow_figure(panorama_a: np.ndarray, panorama_b: np.ndarray, *,
                       points_a: np.ndarray, points_b: np.ndarray, tile_centers: np.ndarray,
                       tile_size: int, title: str, path: str | os.PathLike,
                       arrow_scale: float | None = None) -> Path:
    """Paper-style motion-flow figure: two panoramas, tile grid, flow arrows.

    Parameters
    ----------
    panorama_a, panorama_b : (H, W) ndarray
        Panoramas of the two frames.
    points_a, points_b : (N, 2) ndarray
        Panorama ``(row, col)`` of corresponding points (flow from a to b).
    tile_centers : (T, 2) ndarray
        Panorama ``(row, col)`` of the tile centres.
    tile_size : int
        Tile side in pixels (outlines drawn on the panoramas).
    title : str, keyword-only
    path : path, keyword-only
    arrow_scale : float, optional, keyword-only
        Arrow length multiplier in the flow panel (stated in its title);
        default: the median arrow is drawn half a tile long.
    """
    h, w = panorama_a.shape
    fig, axes = plt.subplots(3, 1, figsize=(12, 3 * max(1.2, 3.0 * h / w) + 1.0))
    half = tile_size / 2.0
    for ax, pano, name in ((axes[0], panorama_a, "first panorama"),
                           (axes[1], panorama_b, "second panorama")):
        ax.imshow(pano, cmap="gray", vmin=0, vmax=255)
        for r, c in tile_centers:
            ax.add_patch(plt.Rectangle((c - half, r - half), tile_size, tile_size, fill=False,
                                       ec="yellow", lw=0.5, alpha=0.6))
        ax.set_title(name, fontsize=9)
        ax.set_axis_off()
    axes[0].plot(points_a[:, 1], points_a[:, 0], ".", color="red", ms=3)
    axes[1].plot(points_b[:, 1], points_b[:, 0], ".", color="lime", ms=3)
    ax = axes[2]
    ax.imshow(panorama_a, cmap="gray", vmin=0, vmax=255, alpha=0.45)
    d = points_b - points_a
    d[:, 1] = (d[:, 1] + w / 2) % w - w / 2  # shortest way across the 360-degree seam
    if arrow_scale is None:
        median = float(np.median(np.linalg.norm(d, axis=1))) if len(d) else 0.0
        arrow_scale = max(1.0, round(0.5 * tile_size / median)) if median > 0 else 1.0
    ax.quiver(points_a[:, 1], points_a[:, 0], d[:, 1] * arrow_scale, d[:, 0] * arrow_scale,
              angles="xy", scale_units="xy", scale=1, color="red", width=0.002)
    ax.plot(points_a[:, 1], points_a[:, 0], ".", color="red", ms=3)
    ax.plot(tile_centers[:, 1], tile_centers[:, 0], "+", color="yellow", ms=5)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_title(f"motion flow field (arrows x{arrow_scale:g})", fontsize=9)
    ax.set_axis_off()
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)
