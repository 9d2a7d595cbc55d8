"""DATASET folders: ``calib_results.txt`` (or ``camera.yaml``), ``images/*.png|jpg``, optional ``groundtruth.txt``.

Frame k is the image whose file name is the integer k (``000123.png`` is
frame 123; a text prefix such as ``frame_000123.png`` is allowed), in
natural order, never the position in a sorted list: a missing file leaves a
gap. Two files with one index are an error; files that are not frames
(hidden files such as ``._000003.png``, ``Thumbs.db``, names without an
index) are skipped with one :class:`~ifmi.errors.InputWarning`. Images are
read as 8-bit gray or RGB, as their raw sensor grid (an EXIF orientation tag
is ignored: the calibration refers to sensor pixels), and must have the size
the calibration names. Problems raise :class:`~ifmi.errors.InputError`
naming the file; a file whose image data the decoder finds damaged is one
too (see :mod:`ifmi.io.images`).

:func:`read_dataset` turns a path into the camera model and the frame
source; the camera file is found by :func:`ifmi.io.camera_file.calibration_path`
and the frames by :func:`frame_files`.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Iterator

import numpy as np

from ifmi.geometry.camera import OcamModel
from ifmi.errors import InputError, InputWarning, OutputError
from ifmi.frames import MissingFrame
from ifmi.io.atomic import path_within
from ifmi.io.camera_file import calibration_path, read_camera
from ifmi.io.images import IMAGE_SUFFIXES, read_image

__all__ = ["Dataset", "FrameFiles", "read_dataset", "read_image", "frame_files", "frame_index",
           "dataset_conflict", "dataset_meta", "refuse_output_in_datasets", "IMAGE_SUFFIXES", "DATASET_FILES", "DATASET_FOLDERS"]

# Files and folders of the dataset contract (DESIGN.md); outputs never replace them.
DATASET_FILES = ("calib_results.txt", "camera.yaml", "groundtruth.txt", "meta.json")
DATASET_FOLDERS = ("images", "depth", "normal")
# A frame's file stem: an optional text prefix (no digits, not hidden) and the index.
_FRAME_STEM = re.compile(r"(?:[^\d.][^\d]*)?(\d+)")
# Largest frame number: frame indices are 64-bit integers (19-digit nanosecond stamps fit).
_MAX_FRAME_INDEX = 2 ** 63 - 1
# Skipped file names listed in the warning; the rest are counted.
_LISTED_SKIPS = 5


def frame_index(path: str | os.PathLike) -> int | None:
    """Frame index of an image file name (``000123.png`` -> 123), or ``None`` if it is not a frame.

    Not frames: hidden files (leading ``.``, e.g. macOS ``._000123.png``),
    other suffixes than :data:`IMAGE_SUFFIXES`, and stems that are not an
    integer after an optional text prefix.
    """
    path = Path(path)
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        return None
    match = _FRAME_STEM.fullmatch(path.stem)
    return int(match.group(1)) if match else None


@dataclass(frozen=True)
class FrameFiles:
    """The frame images of a folder.

    Attributes
    ----------
    indices : tuple of int
        Frame indices, increasing.
    paths : tuple of Path
        The image of each index.
    skipped : tuple of str
        Names of the entries that are not frames.
    """

    indices: tuple
    paths: tuple
    skipped: tuple


def frame_files(image_dir: str | os.PathLike) -> FrameFiles:
    """Frame images of ``image_dir`` by index (see the module docstring).

    Raises
    ------
    InputError
        Not a readable folder, no frame image, two files with one index, or
        two indices that one trajectory timestamp cannot tell apart.
    """
    image_dir = Path(image_dir)
    try:
        entries = sorted(image_dir.iterdir())
    except OSError as exc:
        raise InputError(image_dir, f"cannot list images folder ({exc.strerror or exc})") from None
    by_index: dict[int, Path] = {}
    skipped = []
    for path in entries:
        # A link whose target is gone is still a frame of the sequence: flagged when it is read.
        index = frame_index(path) if path.is_file() or path.is_symlink() else None
        if index is None:
            skipped.append(path.name)
        elif index > _MAX_FRAME_INDEX:
            raise InputError(path, f"frame number {index} is larger than {_MAX_FRAME_INDEX} (a 64-bit "
                                   "integer; nanosecond timestamps fit); expected a shorter frame number")
        elif index in by_index:
            raise InputError(image_dir, f"frame {index} has two files, {by_index[index].name} and "
                                        f"{path.name}; keep one")
        else:
            by_index[index] = path
    if not by_index:
        found = f"; found only {_listed(skipped)}" if skipped else ""
        raise InputError(image_dir, f"no frame images in folder (expected files named by the frame "
                                    f"index, e.g. 000000.png; types {', '.join(IMAGE_SUFFIXES)}){found}")
    indices = tuple(sorted(by_index))
    _check_distinct_timestamps(image_dir, indices, by_index)
    return FrameFiles(indices=indices, paths=tuple(by_index[k] for k in indices), skipped=tuple(skipped))


def _check_distinct_timestamps(image_dir: Path, indices: tuple, by_index: dict) -> None:
    """Refuse two frame numbers that one TUM timestamp (a 64-bit float) cannot tell apart.

    Above 2**53 a float holds only every second, fourth, ... integer, so
    nanosecond stamps a few ns apart would become one timestamp of the
    estimate, which no evaluation can associate.
    """
    stamps = np.asarray(indices, dtype=np.float64)
    same = np.flatnonzero(np.diff(stamps) == 0)
    if same.size:
        a, b = indices[same[0]], indices[same[0] + 1]
        stamp = stamps[same[0]]
        raise InputError(image_dir, f"frames {a} ({by_index[a].name}) and {b} ({by_index[b].name}) get one "
                                    f"timestamp, {stamp:.0f}, in a trajectory file (64-bit floats hold "
                                    f"integers this large only to a multiple of {np.spacing(stamp):.0f}); "
                                    "expected frame numbers that differ by more")


def _warn_skipped(image_dir: Path, skipped: tuple) -> None:
    if not skipped:
        return
    warnings.warn(f"{image_dir}: skipped {len(skipped)} entr{'y' if len(skipped) == 1 else 'ies'} "
                  f"that {'is not a frame image' if len(skipped) == 1 else 'are not frame images'} "
                  f"(hidden, not PNG/JPEG, or not named by a frame index): {_listed(skipped)}",
                  InputWarning, stacklevel=3)


def dataset_meta(dataset_dir: str | os.PathLike) -> dict | None:
    """A dataset folder's ``meta.json`` as a mapping, or None when it is absent, unreadable, not a
    regular file (a FIFO would block the read) or not a JSON object (it is optional provenance,
    never required to read a dataset)."""
    path = Path(dataset_dir) / "meta.json"
    if not path.is_file():
        return None
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):  # RecursionError: JSON nested too deeply
        return None
    return meta if isinstance(meta, dict) else None


def _warn_incomplete(root: Path) -> None:
    """Warn when ``meta.json`` says ``"complete": false`` (an interrupted omnisim run)."""
    meta = dataset_meta(root)
    if meta is None or meta.get("complete") is not False:
        return
    written, frames = meta.get("images"), meta.get("frames")
    count = (f" ({len(written)} of {frames} frames written)"
             if isinstance(written, dict) and isinstance(frames, int) and not isinstance(frames, bool) else "")
    warnings.warn(f"{root / 'meta.json'}: the dataset is marked incomplete{count}; run the omnisim "
                  "command that made it again to finish it", InputWarning, stacklevel=3)


def _listed(names) -> str:
    """The first few ``names``, and how many more."""
    more = f" and {len(names) - _LISTED_SKIPS} more" if len(names) > _LISTED_SKIPS else ""
    return ", ".join(names[:_LISTED_SKIPS]) + more


@dataclass(frozen=True)
class Dataset:
    """A dataset folder.

    Attributes
    ----------
    root : Path
    calib_path : Path
    model : OcamModel
    image_paths : tuple of Path
        One image per frame, by increasing frame index.
    frame_indices : tuple of int
        The frame index of each image (the timestamps of its estimate).
    groundtruth_path : Path or None
        ``groundtruth.txt`` when present.
    """

    root: Path
    calib_path: Path
    model: OcamModel
    image_paths: tuple
    frame_indices: tuple
    groundtruth_path: Path | None

    def iter_images(self, *, gray: bool = True, prefetch: bool = False,
                    skip_unreadable: bool = False) -> Iterator[np.ndarray | MissingFrame]:
        """Images in frame order, read lazily (see :func:`read_image`).

        With ``prefetch`` the next image is decoded in a background thread
        while the caller works on the current one (image decoding releases
        the GIL), so reading overlaps with estimation. With
        ``skip_unreadable`` an image that cannot be read, or has the wrong
        size, comes as a :class:`~ifmi.frames.MissingFrame` whose reason
        names the file instead of raising, so a sequence flags that frame
        and goes on.
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


def _read_or_flag(path: Path, *, size: tuple[int, int], gray: bool) -> np.ndarray | MissingFrame:
    try:
        return read_image(path, size=size, gray=gray)
    except InputError as exc:
        return MissingFrame(source=exc.path, reason=f"{Path(exc.path).name}: {exc.problem}")


def read_dataset(path: str | os.PathLike) -> Dataset:
    """Open a DATASET folder (images are read lazily).

    Raises
    ------
    InputError
        Not a folder, no or bad calibration, no frame images, two images
        with one frame index.

    Warns
    -----
    InputWarning
        Entries of ``images/`` that are not frames were skipped, or the
        folder's ``meta.json`` marks it incomplete (an interrupted
        ``omnisim`` run: ``"complete": false``).
    """
    root = Path(path)
    if not root.exists():
        raise InputError(root, "dataset folder not found")
    if not root.is_dir():
        raise InputError(root, "not a folder (expected a dataset folder with calib_results.txt "
                               "or camera.yaml, and images/)")
    calib_path = calibration_path(root)  # calib_results.txt or camera.yaml, never both
    model = read_camera(calib_path)
    image_dir = root / "images"
    if not image_dir.is_dir():
        raise InputError(image_dir, "images folder not found")
    frames = frame_files(image_dir)
    _warn_skipped(image_dir, frames.skipped)
    _warn_incomplete(root)
    groundtruth = root / "groundtruth.txt"
    return Dataset(root=root, calib_path=calib_path, model=model, image_paths=frames.paths,
                   frame_indices=frames.indices,
                   groundtruth_path=groundtruth if groundtruth.is_file() else None)


def _dataset_files(root: Path) -> Iterator[Path]:
    """The contract files of a dataset folder and the entries of its data folders."""
    for name in DATASET_FILES:
        yield root / name
    for folder in DATASET_FOLDERS:
        try:
            yield from (root / folder).iterdir()
        except OSError:
            continue


def refuse_output_in_datasets(out: str | os.PathLike, datasets) -> None:
    """Raise :class:`~ifmi.errors.OutputError` when writing ``out`` would harm one of ``datasets``
    (:func:`dataset_conflict`; e.g. a results folder inside a dataset's ``images/``)."""
    for dataset in dict.fromkeys(datasets):
        conflict = dataset_conflict(dataset, out)
        if conflict:
            raise OutputError(out, f"{conflict}; choose another output path")


def dataset_conflict(dataset_dir: str | os.PathLike, path: str | os.PathLike) -> str | None:
    """How writing ``path`` would harm the dataset at ``dataset_dir``, or ``None`` if it would not.

    ``path`` conflicts when it resolves (through symbolic links) to one of
    the dataset's contract files (:data:`DATASET_FILES`), lies in one of its
    data folders (:data:`DATASET_FOLDERS`), or is the same file (inode) as
    any of those under another name (a hard link). Other files in the
    dataset folder (e.g. ``DATASET/estimate.txt``) are fine.

    Returns
    -------
    str or None
        E.g. ``"would replace groundtruth.txt of the input dataset D"``.
    """
    root = Path(dataset_dir)
    if not root.is_dir():
        return None
    real = Path(os.path.realpath(path))
    where = f"of the input dataset {root}"
    for folder in DATASET_FOLDERS:
        if (root / folder).is_dir() and path_within(real, root / folder):
            return f"would write into {folder}/ {where}"
    for name in DATASET_FILES:
        if real == Path(os.path.realpath(root / name)):
            return f"would replace {name} {where}"
    try:
        info = os.stat(real)
    except OSError:
        return None
    for candidate in _dataset_files(root):
        try:
            other = os.stat(candidate)
        except OSError:
            continue
        if (other.st_dev, other.st_ino) == (info.st_dev, info.st_ino):
            return f"would replace {candidate.relative_to(root)} {where} (the same file under another name)"
    return None
