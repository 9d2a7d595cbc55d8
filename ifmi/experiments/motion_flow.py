"""The iFMI front end's tile flow between two frames of a dataset, for the motion-flow figure.

Computed on request by ``ifmi report`` (never by an evaluation) and stored as
``motion_flow.npz`` (:func:`ifmi.io.results.write_motion_flow`).
"""

from __future__ import annotations

import os

import numpy as np

from ifmi.errors import InputError

__all__ = ["MOTION_FLOW_FILE", "motion_flow_sample"]

# File name of a stored motion-flow sample (beside an evaluation, or in a report's data).
MOTION_FLOW_FILE = "motion_flow.npz"


def motion_flow_sample(dataset_dir: str | os.PathLike, *, config,
                       frames: tuple[int, int] = (0, 1)) -> dict:
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

    Raises
    ------
    InputError
        An unreadable dataset, or frames outside it.
    """
    from ifmi.spectral.flow import flow_from_tile_motion, flow_sample_points
    from ifmi.io.dataset import read_dataset, read_image
    from ifmi.spectral.ifmi_front_end import IfmiFrontEnd
    from ifmi.spectral.panorama import panorama_image_from_omni_image

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
