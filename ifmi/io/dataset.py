"""DATASET folders: ``calib_results.txt``, ``images/*.png|jpg`` and optional ``groundtruth.txt``.

Images are read in file-name order, as 8-bit gray or RGB; each must have the
size the calibration names. Problems raise :class:`~ifmi.errors.InputError`
naming the file.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from ..camera import OcamModel
from ..errors import InputError
from ..odometry import MissingFrame
from .camera_file import calibration_path, read_camera

__all__ = ["Dataset", "read_dataset", "read_image", "IMAGE_SUFFIXES"]

# Image file types of a dataset (lower case).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


@dataclass(frozen=True)
class Dataset:
    """A dataset folder.

    Attributes
    ----------
    root : Path
    calib_path : Path
    model : OcamModel
    image_paths : tuple of Path
        Sorted by file name.
    groundtruth_path : Path or None
        ``groundtruth.txt`` when present.
    """

    root: Path
    calib_path: Path
    model: OcamModel
    image_paths: tuple
    groundtruth_path: Path | None

    def iter_images(self, *, gray: bool = True, prefetch: bool = False,
                    skip_unreadable: bool = False) -> Iterator[np.ndarray | MissingFrame]:
        """Images in order, read lazily (see :func:`read_image`).

        With ``prefetch`` the next image is decoded in a background thread
        while the caller works on the current one (image decoding releases
        the GIL), so reading overlaps with estimation. With
        ``skip_unreadable`` an image that cannot be read, or has the wrong
        size, comes as a :class:`~ifmi.odometry.MissingFrame` carrying the
        reason instead of raising, so a sequence flags that frame and goes on.
        """
        read = partial(_read_or_flag if skip_unreadable else read_image,
                       size=self.model.size, gray=gray)
        if not prefetch:
            for path in self.image_paths:
                yield read(path)
            return
        with ThreadPoolExecutor(max_workers=1) as pool:
            pending = pool.submit(read, self.image_paths[0])
            for path in self.image_paths[1:]:
                image = pending.result()
                pending = pool.submit(read, path)
                yield image
            yield pending.result()

    def __len__(self) -> int:
        return len(self.image_paths)


def read_image(path: str | os.PathLike, *, size: tuple[int, int] | None = None,
               gray: bool = True) -> np.ndarray:
    """Read an 8-bit image.

    Parameters
    ----------
    path : path-like
    size : (int, int), optional, keyword-only
        Expected ``(height, width)``.
    gray : bool, keyword-only
        Return ``(H, W)`` gray; otherwise ``(H, W)`` for gray files and
        ``(H, W, 3)`` RGB for colour files.

    Returns
    -------
    ndarray of uint8

    Raises
    ------
    InputError
        Unreadable file or wrong size.
    """
    path = Path(path)
    flag = cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except FileNotFoundError:
        raise InputError(path, "image file not found") from None
    except OSError as exc:
        raise InputError(path, f"cannot read image ({exc.__class__.__name__})") from None
    image = cv2.imdecode(data, flag) if data.size else None
    if image is None:
        raise InputError(path, "not a readable PNG/JPEG image")
    if image.dtype != np.uint8:
        if image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        else:
            raise InputError(path, f"expected an 8-bit image, got {image.dtype}")
    if image.ndim == 3:
        if image.shape[2] == 4:
            image = image[..., :3]
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if size is not None and image.shape[:2] != tuple(size):
        raise InputError(path, f"image is {image.shape[0]}x{image.shape[1]} (height x width), "
                               f"but the calibration names {size[0]}x{size[1]}")
    return image


def _read_or_flag(path: Path, *, size: tuple[int, int], gray: bool) -> np.ndarray | MissingFrame:
    try:
        return read_image(path, size=size, gray=gray)
    except InputError as exc:
        return MissingFrame(source=exc.path, reason=exc.problem)


def read_dataset(path: str | os.PathLike) -> Dataset:
    """Open a DATASET folder (images are read lazily).

    Raises
    ------
    InputError
        Not a folder, no or bad ``calib_results.txt``, no images.
    """
    root = Path(path)
    if not root.is_dir():
        raise InputError(root, "dataset folder not found")
    calib_path = calibration_path(root)  # calib_results.txt or camera.yaml, never both
    model = read_camera(calib_path)
    image_dir = root / "images"
    if not image_dir.is_dir():
        raise InputError(image_dir, "images folder not found")
    paths = sorted(p for p in image_dir.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not paths:
        raise InputError(image_dir, f"no images ({', '.join(IMAGE_SUFFIXES)}) in folder")
    groundtruth = root / "groundtruth.txt"
    return Dataset(root=root, calib_path=calib_path, model=model, image_paths=tuple(paths),
                   groundtruth_path=groundtruth if groundtruth.is_file() else None)
