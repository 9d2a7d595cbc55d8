"""Capture effects applied to an existing dataset folder: a degraded copy.

A rendered (or real) dataset is passed through the same seeded sensor
effects a scene's ``[effects]`` table applies while rendering -- exposure
drift, Gaussian noise, JPEG compression -- without rendering again, so one
clean render serves a whole robustness study (accuracy against noise level,
JPEG quality or exposure drift). Calibration and ground truth are copied;
the images are written as PNG (the JPEG artefacts are kept, nothing further
is lost). Like a render, an interrupted run resumes and a rerun with other
settings into the same folder is refused.

Exposure and vignetting act on linear intensities: each 8-bit sRGB value is
decoded, multiplied by the frame's gain and the pixel's vignetting factor and
encoded again, so highlights clip as they would in a camera (detail already
clipped in the source stays lost). The vignetting is the renderer's radial
fall-off (:func:`omnisim.capture.vignetting_from_pixels`, the cos^4 law
``(1 + (v * rho / rho_max)**2)**-2`` of the sensor-plane radius ``rho`` about
the mirror centre); here ``rho_max`` is the radius of the largest circle about
the mirror centre that the image holds (the smallest radius of a border pixel),
since a dataset folder does not record the mirror band. It is the same for
every frame (a fixed pattern, as in a camera) and involves no randomness.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ifmi.errors import InputError
from ifmi.io.atomic import atomic_write_bytes, atomic_write_json
from ifmi.io.dataset import read_dataset, read_image
from ifmi.io.provenance import package_versions
from ifmi.io.text_file import read_failure

from .capture import vignetting_from_pixels
from .config import MAX_VIGNETTING, EffectsSettings
from .effects import apply_effects, exposure_gains, linear_from_srgb_uint8, srgb_uint8_from_linear
from .renderer import META_FORMAT, encode_png, open_output_folder, pending_images, sha256_file

__all__ = ["DegradeResult", "degrade_image", "degrade_dataset", "vignetting_of_image"]

# Version of the degrading procedure; part of an output folder's identity.
DEGRADE_VERSION = 1


@dataclass(frozen=True)
class DegradeResult:
    """Outcome of :func:`degrade_dataset`.

    out_dir : output folder; frames : number of frames; written : frames
    written in this call (the rest were already there and verified).
    """

    out_dir: str
    frames: int
    written: int


def degrade_image(image: np.ndarray, effects: EffectsSettings, *, gain: float, seed: int,
                  frame: int, vignetting: np.ndarray | None = None) -> np.ndarray:
    """One frame with exposure ``gain``, ``vignetting`` and the seeded noise and JPEG effects applied.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 ndarray
        sRGB-encoded frame, (row, col) indexing.
    effects : EffectsSettings
    gain : float, keyword-only
        Exposure multiplier on linear intensity (1 leaves the frame as it is).
    seed, frame : int, keyword-only
        Noise seed of the sequence and the frame index.
    vignetting : (H, W) ndarray or None, keyword-only
        Factor on the linear intensity of each pixel, (row, col) indexing
        (:func:`vignetting_of_image`); None for none.

    Returns
    -------
    (H, W) or (H, W, 3) uint8 ndarray
        Same shape as ``image``.
    """
    out = np.asarray(image)
    gray = out.ndim == 2
    rgb = np.repeat(out[..., None], 3, axis=2) if gray else out
    if vignetting is not None:
        rgb = srgb_uint8_from_linear(linear_from_srgb_uint8(rgb) * vignetting[..., None], gain=gain)
    elif gain != 1.0:
        rgb = srgb_uint8_from_linear(linear_from_srgb_uint8(rgb), gain=gain)
    rgb = apply_effects(rgb, effects, seed=seed, frame=frame)
    return np.ascontiguousarray(rgb[..., 0]) if gray else rgb


def vignetting_of_image(model, *, strength: float) -> np.ndarray:
    """Vignetting factor of every pixel of a calibration's image, normalised to the image's largest circle.

    The fall-off of :func:`omnisim.capture.vignetting_from_pixels` with
    ``radius_max`` the smallest sensor-plane radius of a border pixel: the
    factor is ``(1 + strength**2)**-2`` on the largest circle about the mirror
    centre that the image holds (1 at the centre, lower beyond in the corners).

    Parameters
    ----------
    model : OcamModel
        Calibration; the image is ``model.size`` (height rows, width columns).
    strength : float, keyword-only
        ``v >= 0``.

    Returns
    -------
    (H, W) ndarray
        float32 factors in (0, 1], indexed (row, col).
    """
    from ifmi.geometry.camera import radius_from_pixels

    height, width = model.size
    rows, cols = np.mgrid[0:height, 0:width]
    on_border = (rows == 0) | (rows == height - 1) | (cols == 0) | (cols == width - 1)
    border = np.stack([rows[on_border], cols[on_border]], axis=-1)
    radius_max = float(radius_from_pixels(model, border).min())
    return vignetting_from_pixels(model, strength=strength, radius_max=radius_max)


def _frame_sha256(path: Path) -> str:
    """:func:`sha256_file` of a source frame; an unreadable one (a dangling or looping link) is bad input."""
    try:
        return sha256_file(path)
    except OSError as exc:
        raise InputError(path, f"cannot read the frame ({exc.strerror or exc.__class__.__name__})") from None


def _source_file_bytes(path: Path, what: str) -> bytes:
    """The bytes of a source dataset's file that is copied as it is (calibration, ground truth, meta.json).

    Raises
    ------
    InputError
        Named ``path``: a folder, FIFO, device or dangling link stands there (a folder's read
        was a traceback, a FIFO's blocked forever), or the file cannot be read.
    """
    if not path.is_file():
        kind = "a folder" if path.is_dir() else "no regular file (a FIFO, device, socket or broken link)"
        raise InputError(path, f"is {kind}; expected the source dataset's {what}")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise read_failure(path, exc, what=what) from None


def _source_copies(dataset) -> dict:
    """The files copied as they are into the output folder: ``{name in the output: bytes}``.

    Calibration always; ``groundtruth.txt`` and ``meta.json`` (copied as
    ``source_meta.json``) when anything stands at their names, so that a
    folder, FIFO or dangling link there is refused instead of skipped.

    Raises
    ------
    InputError
        The message names the source file: see :func:`_source_file_bytes`.
    """
    copies = {dataset.calib_path.name: _source_file_bytes(dataset.calib_path, "calibration file")}
    optional = (("groundtruth.txt", "groundtruth.txt", "trajectory file"),
                ("meta.json", "source_meta.json", "meta.json file"))
    for name, out_name, what in optional:
        path = dataset.root / name
        if os.path.lexists(path):
            copies[out_name] = _source_file_bytes(path, what)
    return copies


def _checked_vignetting(dataset, strength: float) -> np.ndarray | None:
    """The vignetting factors of ``dataset``'s images for ``strength`` (None at 0), or one-line bad input."""
    from ifmi.geometry.camera import OcamModel

    if not 0.0 <= strength <= MAX_VIGNETTING:
        raise InputError("--vignetting", f"expected a strength from 0 to {MAX_VIGNETTING:.3g} "
                                         f"(beyond, the image's rim falls below the darkest 8-bit level), "
                                         f"got {strength!r}")
    if strength == 0.0:
        return None
    if not isinstance(dataset.model, OcamModel):
        raise InputError(dataset.calib_path, "--vignetting needs an OCamCalib calibration (the fall-off is "
                                             "radial about its mirror centre)")
    return vignetting_of_image(dataset.model, strength=strength)


def degrade_dataset(dataset_dir, out_dir, *, effects: EffectsSettings, seed: int = 0,
                    vignetting: float = 0.0, progress: bool = True) -> DegradeResult:
    """Write a copy of a dataset folder with capture effects applied to every image.

    Parameters
    ----------
    dataset_dir : path
        DATASET folder (calibration, images, optional ground truth).
    out_dir : path
        Output DATASET folder; resumed if it holds the same degrading of
        the same source, refused if it holds anything else.
    effects : EffectsSettings, keyword-only
        Noise sigma (8-bit grey levels), exposure drift bound and step
        (stops), JPEG quality (1..100, 0 off); checked when constructed.
    seed : int, keyword-only
        Seed of the noise and the exposure walk; the same seed gives the
        same bytes.
    vignetting : float, keyword-only
        Strength ``v`` of the radial fall-off (:func:`vignetting_of_image`),
        0 (none) to ``sqrt(2**6 - 1)`` = 7.9; needs an OCamCalib calibration.
    progress : bool, keyword-only
        Show a progress bar on stderr.

    Returns
    -------
    DegradeResult

    Raises
    ------
    InputError
        Unreadable source dataset or image, a negative seed, a vignetting
        strength out of range or on a calibration other than OCamCalib, an output
        folder that is the source dataset or lies inside it (through
        symbolic links too), or one holding something else.
    OutputError
        A file cannot be written (the message names it and the OS reason).
    """
    dataset = read_dataset(dataset_dir)
    if seed < 0:
        raise InputError(dataset.root, f"--seed: expected a non-negative integer, got {seed}")
    vignette = _checked_vignetting(dataset, vignetting)
    out_dir = Path(out_dir)
    source = dataset.root.resolve()
    if out_dir.resolve() == source:
        raise InputError(out_dir, "is the source dataset; choose another output folder")
    if out_dir.resolve().is_relative_to(source):
        raise InputError(out_dir, f"is inside the source dataset {dataset.root}; choose an output folder "
                                  f"outside it")
    names = [path.name for path in dataset.image_paths]
    source_hashes = {path.name: _frame_sha256(path) for path in dataset.image_paths}
    identity = {
        "source_images_sha256": hashlib.sha256(json.dumps(source_hashes, sort_keys=True).encode()).hexdigest(),
        "effects": asdict(effects),
        "seed": int(seed),
        "format": META_FORMAT,
        "degrade": DEGRADE_VERSION,
        # Only when on, so that the folders degraded without it keep their identity.
        **({"vignetting": float(vignetting)} if vignette is not None else {}),
    }
    copies = _source_copies(dataset)  # read (or refused) before the output folder is touched
    meta = open_output_folder(out_dir, identity)
    images_dir = out_dir / "images"
    meta.update({"source": str(dataset.root.resolve()), "effects": asdict(effects), "seed": int(seed),
                 "vignetting": float(vignetting),
                 "frames": len(names), "versions": package_versions(("numpy", "opencv-python-headless",
                                                                     "omnisim-ifmi"))})
    for name, data in copies.items():
        atomic_write_bytes(out_dir / name, data)
    atomic_write_json(out_dir / "meta.json", meta)

    out_names = [Path(name).with_suffix(".png").name for name in names]
    todo = pending_images(out_dir, meta, out_names)
    gains = exposure_gains(len(names), effects, seed=seed)
    from tqdm import tqdm

    bar = tqdm(total=len(names), initial=len(names) - len(todo), disable=not progress,
               unit="frame", desc="degrade")
    for k in todo:
        image = read_image(dataset.image_paths[k], size=dataset.model.size, gray=False)
        data = encode_png(degrade_image(image, effects, gain=float(gains[k]), seed=seed, frame=k,
                                           vignetting=vignette))
        atomic_write_bytes(images_dir / out_names[k], data)
        meta["images"][out_names[k]] = hashlib.sha256(data).hexdigest()
        atomic_write_json(out_dir / "meta.json", meta)
        bar.update(1)
    bar.close()
    meta["images"] = dict(sorted(meta["images"].items()))
    meta["complete"] = len(meta["images"]) == len(names)
    atomic_write_json(out_dir / "meta.json", meta)
    return DegradeResult(out_dir=str(out_dir), frames=len(names), written=len(todo))
