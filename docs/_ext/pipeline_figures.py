"""Figures of the "How it works" page, made at build time from exact synthetic frames.

Two frames of :mod:`ifmi.synthetic` (a textured environment seen by a
paracatadioptric camera, turned by a known rotation) go through the iFMI
front end step by step: the omni image and its mirror band, the panorama,
the tiles, the phase-correlation surfaces of a few tiles, the flow, and
the inliers of the relative-pose fit.

Run by ``docs/conf.py``; ``python docs/_ext/pipeline_figures.py OUT`` writes
the same files.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

# Image side of the synthetic frames (pixels) and panorama width: small enough for seconds.
IMAGE_SIDE = 256
PANORAMA_WIDTH = 512
# Tiles whose correlation surfaces are shown.
SHOWN_TILES = 4


def _frames():
    from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence

    model = example_omni_model(IMAGE_SIDE)
    band = example_band_px(model)
    sequence = synthetic_sequence(model, 2, seed=4, band_px=band, max_step_rad=0.06, noise_std=1.0)
    return model, band, sequence


def _front_end(model, band):
    from ifmi.pipeline import EstimateConfig, resolved_config
    from ifmi.spectral.ifmi_front_end import IfmiFrontEnd
    from ifmi.spectral.panorama import PanoramaConfig

    config = EstimateConfig()
    panorama = PanoramaConfig(width=PANORAMA_WIDTH, radius_min_px=band[0], radius_max_px=band[1])
    config = resolved_config(replace(config, ifmi=replace(config.ifmi, panorama=panorama)), model)
    return IfmiFrontEnd(model, config.ifmi), config


def _band_figure(image, panorama, model, band, path):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), gridspec_kw={"width_ratios": [1, 2.2]})
    axes[0].imshow(image, cmap="gray")
    centre_row, centre_col = model.center
    for radius, colour in zip(band, ("tab:orange", "tab:red")):
        axes[0].add_patch(plt.Circle((centre_col, centre_row), radius, fill=False, ec=colour, lw=1.2))
    axes[0].set_title("omni image and mirror band", fontsize=9)
    axes[1].imshow(panorama, cmap="gray")
    axes[1].set_title("panorama: azimuth across, elevation down", fontsize=9)
    for ax in axes:
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _tiles_figure(panorama, layout, path):
    fig, ax = plt.subplots(figsize=(10, 2.4))
    ax.imshow(panorama, cmap="gray")
    size = layout.tile_size
    for k, (row, col) in enumerate(layout.origins):
        ax.add_patch(plt.Rectangle((col - 0.5, row - 0.5), size, size, fill=False,
                                   ec="yellow" if k % 2 else "cyan", lw=0.7))
    ax.set_title(f"{len(layout.origins)} tiles of {size} px ({layout.grid_shape[0]} rows x {layout.grid_shape[1]} columns)", fontsize=9)
    ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _peaks_figure(panorama_a, panorama_b, layout, path):
    from ifmi.spectral.phase_correlation import phase_correlation
    from ifmi.spectral.tiling import tiles_from_panorama

    index = np.linspace(0, len(layout.origins) - 1, SHOWN_TILES).round().astype(int)
    tiles_a = tiles_from_panorama(panorama_a, layout, index=index)
    tiles_b = tiles_from_panorama(panorama_b, layout, index=index)
    shift, peaks = phase_correlation(tiles_a, tiles_b)
    fig, axes = plt.subplots(2, SHOWN_TILES, figsize=(10, 5))
    for k in range(SHOWN_TILES):
        axes[0, k].imshow(np.hstack([tiles_a[k], tiles_b[k]]), cmap="gray")
        axes[0, k].set_title(f"tile {index[k]}: frame a | frame b", fontsize=8)
        surface = _surface(tiles_a[k], tiles_b[k])
        axes[1, k].imshow(np.fft.fftshift(surface), cmap="magma")
        centre = np.array(surface.shape) / 2
        axes[1, k].plot(centre[1] + shift[k, 1], centre[0] + shift[k, 0], "c+", ms=12)
        axes[1, k].set_title(f"shift ({shift[k, 0]:+.2f}, {shift[k, 1]:+.2f}) px\n"
                             f"peak ratio {peaks.peak_ratio[k]:.1f}, PNR {peaks.peak_to_noise[k]:.0f}",
                             fontsize=8)
    for ax in axes.ravel():
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _surface(a, b):
    """Phase-correlation surface of two tiles (Hann window, normalised cross-power spectrum)."""
    from ifmi.spectral.phase_correlation import correlation_surface, hann_window, normalized_cross_power, windowed_spectra

    window = hann_window(a.shape)
    fa = windowed_spectra(np.asarray(a, np.float32)[None], window)
    fb = windowed_spectra(np.asarray(b, np.float32)[None], window)
    return correlation_surface(normalized_cross_power(fa, fb), a.shape)[0]


def _inliers_figure(image_b, correspondences, inliers, path):
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.imshow(image_b, cmap="gray")
    pixels = correspondences.pixels_b
    ax.plot(pixels[inliers, 1], pixels[inliers, 0], ".", color="lime", ms=3, label="inlier")
    ax.plot(pixels[~inliers, 1], pixels[~inliers, 0], "x", color="red", ms=4, label="outlier")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"{int(inliers.sum())} of {len(inliers)} flow points are inliers", fontsize=9)
    ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_figures(out_dir) -> dict:
    """Write the figures into ``out_dir``; returns the measured numbers the page quotes."""
    from ifmi.spectral.flow import flow_from_tile_motion, flow_sample_points
    from ifmi.experiments.plots import motion_flow_figure
    from ifmi.backend.relative_pose import relative_pose_from_rays
    from ifmi.geometry.rotations import geodesic_angle
    from ifmi.spectral.panorama import panorama_image_from_omni_image

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model, band, sequence = _frames()
    image_a, image_b = sequence.images
    front, config = _front_end(model, band)
    state_a, state_b = front.prepare(image_a), front.prepare(image_b)
    pano_a = panorama_image_from_omni_image(front.mapping, image_a)
    pano_b = panorama_image_from_omni_image(front.mapping, image_b)
    _band_figure(image_a, pano_a, model, band, out / "band.png")
    _tiles_figure(pano_a, front.layout, out / "tiles.png")
    _peaks_figure(pano_a, pano_b, front.layout, out / "peaks.png")
    motion, origins_b = front.register(state_a, state_b)
    pairs = flow_from_tile_motion(motion, front.layout, front.mapping,
                                  points_b=flow_sample_points(front.layout.tile_size, points_per_tile=1),
                                  origins_b=origins_b)
    motion_flow_figure(pano_a, pano_b, points_a=pairs.panorama_a, points_b=pairs.panorama_b,
                       tile_centers=front.layout.centers, tile_size=front.layout.tile_size,
                       title="tile flow from frame a to frame b", path=out / "flow.png")
    correspondences = front.correspondences(state_a, state_b)
    pose, info = relative_pose_from_rays(correspondences.rays_a, correspondences.rays_b,
                                         options=config.relative_pose,
                                         rays_per_measurement=correspondences.rays_per_measurement)
    _inliers_figure(image_b, correspondences, np.asarray(info.inlier_mask, bool), out / "inliers.png")
    truth = sequence.rotations[0].T @ sequence.rotations[1]
    return {"rotation_rad": float(geodesic_angle(truth[None], np.eye(3)[None])[0]),
            "error_rad": float(geodesic_angle(truth[None], pose.rotation[None])[0]),
            "tiles": len(front.layout.origins), "tiles_kept": int(motion.valid.sum())}


if __name__ == "__main__":
    print(write_figures(sys.argv[1] if len(sys.argv) > 1 else "docs/_generated/how_it_works"))
