"""Image files of a dataset: 8-bit PNG or JPEG, decoded with OpenCV.

A damaged file is found before it reaches the decoder, so that its problem
comes back as one :class:`~ifmi.errors.InputError` naming the file instead of
the decoder's own lines on stderr (libpng prints ``libpng error: ...`` for a
broken PNG and OpenCV returns nothing): a PNG's chunks are checked against
their CRCs, its image data is inflated and measured against the size its
header names, and a JPEG must carry its end-of-image marker.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["read_image", "IMAGE_SUFFIXES", "image_file_problem"]

# Image file types of a dataset (lower case).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_START = b"\xff\xd8"
_JPEG_END = b"\xff\xd9"
# Samples per pixel of each PNG colour type (gray, RGB, palette, gray+alpha, RGBA).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_PNG_BIT_DEPTHS = (1, 2, 4, 8, 16)
# Largest row filter type of PNG (none, sub, up, average, Paeth).
_PNG_MAX_FILTER = 4


def _png_chunks(data: bytes) -> tuple[dict, str | None]:
    """IHDR body and IDAT bodies of a PNG, or the problem that stopped the walk."""
    chunks = {"IHDR": None, "IDAT": []}
    pos = len(_PNG_SIGNATURE)
    while True:
        if pos + 8 > len(data):
            return chunks, "truncated PNG (no end chunk)"
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        end = pos + 12 + length
        if end > len(data):
            return chunks, f"truncated PNG ({len(data)} bytes; a chunk runs to byte {end})"
        body = data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:end])
        name = kind.decode("latin-1")
        if zlib.crc32(kind + body) != crc:
            return chunks, f"corrupt PNG (checksum error in its {name} chunk)"
        if kind == b"IEND":
            return chunks, None
        if kind == b"IHDR":
            chunks["IHDR"] = body
        elif kind == b"IDAT":
            chunks["IDAT"].append(body)
        pos = end


def _png_problem(data: bytes) -> str | None:
    chunks, problem = _png_chunks(data)
    if problem:
        return problem
    header = chunks["IHDR"]
    if header is None or len(header) != 13:
        return "corrupt PNG (no valid header chunk)"
    width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", header)
    channels = _PNG_CHANNELS.get(colour)
    if channels is None or depth not in _PNG_BIT_DEPTHS or width == 0 or height == 0:
        return f"corrupt PNG (invalid header: {width}x{height}, colour type {colour}, depth {depth})"
    try:
        raw = zlib.decompress(b"".join(chunks["IDAT"]))
    except zlib.error as exc:
        return f"corrupt PNG (image data: {exc})"
    if interlace == 0:
        stride = (width * channels * depth + 7) // 8 + 1
        if len(raw) < height * stride:
            return f"truncated PNG image data ({len(raw)} of {height * stride} bytes)"
        filters = np.frombuffer(raw, dtype=np.uint8, count=height * stride)[::stride]
        if filters.max() > _PNG_MAX_FILTER:
            return "corrupt PNG (invalid row filter)"
    return None


def image_file_problem(data: bytes) -> str | None:
    """Why the bytes of an image file cannot be decoded, or ``None`` when they look sound.

    PNG: every chunk's CRC, the inflated image data's length and row filters
    (non-interlaced files). JPEG: start and end-of-image markers. Other
    content: "not a readable PNG/JPEG image".
    """
    if data.startswith(_PNG_SIGNATURE):
        return _png_problem(data)
    if data.startswith(_JPEG_START):
        if data.rfind(_JPEG_END) < len(_JPEG_START):
            return "truncated JPEG (no end-of-image marker)"
        return None
    return "not a readable PNG/JPEG image"


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
        Indexed ``[row, col]``.

    Raises
    ------
    InputError
        Unreadable or damaged file, or wrong size.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "image file not found") from None
    except OSError as exc:
        raise InputError(path, f"cannot read image ({exc.strerror or exc.__class__.__name__})") from None
    problem = image_file_problem(data)
    if problem:
        raise InputError(path, problem)
    flag = cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flag)
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
