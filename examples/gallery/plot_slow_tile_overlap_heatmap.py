"""
Tile size x overlap heatmap
===========================

Sweep iFMI's tile size and overlap on one sequence and draw the geodesic ATE
and the time per frame as heatmaps. ``ifmi sweep DATA --tile-size 32 48 64
--overlap 0 0.25 0.5 --out sweep/`` runs the same grid on Dask, one file per
cell, and draws the same heatmaps; here the grid runs in this process.

This example runs nine estimates (its name starts with ``plot_slow_``, so a
quick documentation build, ``DOCS_FAST=1 bash scripts/docs.sh``, skips it).
"""

import tempfile
from dataclasses import replace
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import ifmi
from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence, write_synthetic_dataset
from ifmi.spectral.tiling import TilingConfig

model = example_omni_model(256)
sequence = synthetic_sequence(model, 8, seed=9, band_px=example_band_px(model), noise_std=2.0)
dataset = write_synthetic_dataset(Path(tempfile.mkdtemp()) / "synthetic", sequence)

tile_sizes = (32, 48, 64)
overlaps = (0.0, 0.25, 0.5)
ate = np.full((len(tile_sizes), len(overlaps)), np.nan)
ms = np.full_like(ate, np.nan)
base = ifmi.EstimateConfig()
for i, size in enumerate(tile_sizes):
    for j, overlap in enumerate(overlaps):
        tiling = TilingConfig(tile_size=size, overlap=overlap)
        config = replace(base, ifmi=replace(base.ifmi, tiling=tiling))
        estimate = ifmi.estimate(dataset, config=config)
        ate[i, j] = ifmi.evaluate(dataset / "groundtruth.txt", estimate).ate_rad
        ms[i, j] = 1e3 * np.median(estimate.table()["seconds"][1:])
        print(f"tile {size} px, overlap {overlap}: ATE {ate[i, j]:.2e} rad, {ms[i, j]:.0f} ms/frame")

# %%
# Larger overlaps give more tiles (more flow points, more time); the best
# cell depends on the texture and the motion, which is why the sweep exists.

fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
for ax, values, title in ((axes[0], ate, "geodesic ATE [rad]"), (axes[1], ms, "time per frame [ms]")):
    shown = ax.imshow(values, cmap="viridis", origin="lower")
    ax.set_xticks(range(len(overlaps)), [str(o) for o in overlaps])
    ax.set_yticks(range(len(tile_sizes)), [str(s) for s in tile_sizes])
    ax.set_xlabel("overlap")
    ax.set_ylabel("tile size [px]")
    ax.set_title(title)
    for (i, j), value in np.ndenumerate(values):
        ax.text(j, i, f"{value:.2g}", ha="center", va="center", color="w", fontsize=8)
    fig.colorbar(shown, ax=ax)
fig.tight_layout()
plt.show()
