"""Image files of a dataset: 8- or 16-bit PNG or JPEG, decoded with OpenCV.

A damaged file comes back as one :class:`~ifmi.errors.InputError` naming the
file instead of the decoder's own lines on stderr (libpng prints ``libpng
error: ...`` for a broken PNG, libjpeg ``Corrupt JPEG data: ...`` for a
damaged JPEG, and OpenCV returns nothing or a damaged image). Most damage is
found before the decoder runs: a PNG's chunks are checked against their CRCs,
its image data is inflated and must have exactly the size its header names
(interlaced or not) with valid row filters, and a JPEG must carry its
end-of-image marker. Damage only the decoder sees (a JPEG's entropy-coded
data) is caught from the messages libjpeg and libpng write to the C-level
standard error, which are captured around each decode (:func:`_decode`): a
message about the image data makes the file an error, a message about
metadata only (e.g. a PNG's colour profile) becomes one
:class:`~ifmi.errors.InputWarning`, and nothing raw reaches the terminal.

Images are decoded as their raw pixel grid: an EXIF orientation tag (JPEG or
a PNG's ``eXIf`` chunk) is ignored, because a calibration refers to sensor
pixels, so that a file decodes the same in gray and in colour.
"""

from __future__ import annotations

import os
import re
import struct
import warnings
import zlib
from pathlib import Path

import cv2
import numpy as np

from ifmi.errors import InputError, InputWarning
from ifmi.io.native_stderr import call_with_captured_stderr
from ifmi.io.text_file import refuse_special_file

__all__ = ["read_image", "image_from_bytes", "IMAGE_SUFFIXES", "SENSOR_BIT_DEPTHS", "eight_bit_from_sixteen", "image_file_problem",
           "image_header_size", "sensor_bit_depth", "size_problem"]

#: Sample depths of common image sensors, in bits; a 16-bit file whose values
#: all fit the smaller of them is read at that depth (:func:`sensor_bit_depth`).
SENSOR_BIT_DEPTHS = (8, 10, 12, 14, 16)

# Image file types of a dataset (lower case).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_START = b"\xff\xd8"
_JPEG_END = b"\xff\xd9"
# JPEG start-of-frame markers (SOF0-SOF15 but DHT C4, JPG C8 and DAC CC), which carry the image size,
# and the start-of-scan marker after which no header segment follows.
_JPEG_START_OF_FRAME = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_START_OF_SCAN = 0xDA
# Samples per pixel of each PNG colour type (gray, RGB, palette, gray+alpha, RGBA).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_PNG_BIT_DEPTHS = (1, 2, 4, 8, 16)
# Largest row filter type of PNG (none, sub, up, average, Paeth).
_PNG_MAX_FILTER = 4
# Interlace methods of PNG: none, Adam7.
_PNG_INTERLACE_METHODS = (0, 1)
# The seven passes of Adam7 interlacing: (first column, first row, column step, row step).
_ADAM7_PASSES = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
                 (0, 1, 1, 2))

# Decode flags. Gray: the raw pixel grid at its stored depth (8 or 16 bits), without applying
# an EXIF orientation tag (plain IMREAD_GRAYSCALE would drop the low byte of 16-bit samples).
# Colour: as stored (depth, alpha); IMREAD_UNCHANGED (-1) never applies the orientation
# tag and cannot be combined with other flags (-1 | flag == -1).
_GRAY_FLAGS = cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION
_COLOUR_FLAGS = cv2.IMREAD_UNCHANGED

# Messages of libjpeg (one line each, no prefix) that mean damaged image data ...
_JPEG_DAMAGE = ("Corrupt JPEG data", "Premature end of JPEG file", "Inconsistent progression sequence",
                "Invalid SOS parameters", "Unknown Adobe color transform code")
# ... and that concern the JFIF header only (the pixels are sound).
_JPEG_NOTES = ("Warning: unknown JFIF revision number", "Warning: thumbnail image size does not match")
# libpng's lines; a warning about an ancillary chunk (name with a lower-case first letter,
# e.g. "iCCP: known incorrect sRGB profile") concerns metadata only, the rest the image.
_PNG_MESSAGE = re.compile(r"libpng (warning|error): (.*)")
_PNG_ANCILLARY_CHUNK = re.compile(r"[a-z][A-Za-z]{3}: ")
# File descriptor of the C-level standard error (lines not the decoder's are written back there).
_STDERR_FD = 2


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


def _png_rows(width: int, height: int, bits_per_pixel: int, interlace: int) -> list[tuple[int, int]]:
    """(rows, bytes per row with its filter byte) of each pass of a PNG's inflated image data."""
    if interlace == 0:
        return [(height, (width * bits_per_pixel + 7) // 8 + 1)]
    passes = []
    for col, row, col_step, row_step in _ADAM7_PASSES:
        cols = (width - col + col_step - 1) // col_step
        rows = (height - row + row_step - 1) // row_step
        if cols > 0 and rows > 0:  # an empty pass has no rows at all
            passes.append((rows, (cols * bits_per_pixel + 7) // 8 + 1))
    return passes


def size_problem(height: int, width: int, size: tuple[int, int] | None) -> str | None:
    """Why an image of ``height`` x ``width`` pixels does not fit the calibration's ``size``
    ``(height, width)``, or None when it does (or ``size`` is None)."""
    if size is None or (height, width) == tuple(size):
        return None
    return (f"image is {height}x{width} (height x width), but the calibration names "
            f"{size[0]}x{size[1]}")


def _png_problem(data: bytes, size: tuple[int, int] | None) -> str | None:
    chunks, problem = _png_chunks(data)
    if problem:
        return problem
    header = chunks["IHDR"]
    if header is None or len(header) != 13:
        return "corrupt PNG (no valid header chunk)"
    width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", header)
    channels = _PNG_CHANNELS.get(colour)
    if (channels is None or depth not in _PNG_BIT_DEPTHS or width == 0 or height == 0
            or interlace not in _PNG_INTERLACE_METHODS):
        return (f"corrupt PNG (invalid header: {width}x{height}, colour type {colour}, depth {depth}, "
                f"interlace method {interlace})")
    problem = size_problem(height, width, size)  # before inflating: a small file can claim a huge image
    if problem:
        return problem
    try:
        raw = zlib.decompress(b"".join(chunks["IDAT"]))
    except zlib.error as exc:
        return f"corrupt PNG (image data: {exc})"
    passes = _png_rows(width, height, channels * depth, interlace)
    expected = sum(rows * stride for rows, stride in passes)
    if len(raw) < expected:
        return f"truncated PNG image data ({len(raw)} of {expected} bytes)"
    if len(raw) > expected:
        return (f"corrupt PNG (image data too long: {len(raw)} bytes, expected {expected} for its "
                f"{width}x{height} header)")
    filters, start = [], 0
    for rows, stride in passes:
        filters.append(np.frombuffer(raw, dtype=np.uint8, count=rows * stride, offset=start)[::stride])
        start += rows * stride
    if np.concatenate(filters).max() > _PNG_MAX_FILTER:
        return "corrupt PNG (invalid row filter)"
    return None


def _jpeg_frame_size(data: bytes) -> tuple[int, int] | None:
    """``(height, width)`` from a JPEG's start-of-frame segment, or None when none is found."""
    pos = len(_JPEG_START)
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        length = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        if marker in _JPEG_START_OF_FRAME and pos + 9 <= len(data):
            return struct.unpack(">HH", data[pos + 5:pos + 9])
        if marker == _JPEG_START_OF_SCAN or length < 2:
            return None
        pos += 2 + length
    return None


def image_header_size(data: bytes) -> tuple[int, int] | None:
    """``(height, width)`` that a PNG's or JPEG's header names, read without decoding (None when
    the bytes hold no such header)."""
    if data.startswith(_PNG_SIGNATURE) and data[12:16] == b"IHDR" and len(data) >= 24:
        width, height = struct.unpack(">II", data[16:24])
        return height, width
    if data.startswith(_JPEG_START):
        return _jpeg_frame_size(data)
    return None


def image_file_problem(data: bytes, *, size: tuple[int, int] | None = None) -> str | None:
    """Why the bytes of an image file cannot be decoded, or ``None`` when they look sound.

    PNG: every chunk's CRC, the inflated image data's exact length and its
    row filters (interlaced or not). JPEG: start and end-of-image markers
    (damaged entropy-coded data is found while decoding, by
    :func:`read_image`). Other content: "not a readable PNG/JPEG image".
    With ``size`` ``(height, width)``, a header naming another size is a
    problem found before any image data is inflated or decoded (a file of
    a few MB can claim gigabytes of pixels).
    """
    if data.startswith(_PNG_SIGNATURE):
        return _png_problem(data, size)
    if data.startswith(_JPEG_START):
        if data.rfind(_JPEG_END) < len(_JPEG_START):
            return "truncated JPEG (no end-of-image marker)"
        frame_size = _jpeg_frame_size(data)
        return None if frame_size is None else size_problem(*frame_size, size)
    return "not a readable PNG/JPEG image"


def _decode(data: bytes, flags: int) -> tuple[np.ndarray | None, list[bytes]]:
    """``cv2.imdecode`` with what the decoder writes to the C-level standard error captured.

    Lines another thread wrote meanwhile are not the decoder's: the caller
    passes them on with :func:`_pass_on`.

    Returns
    -------
    image : ndarray or None
    lines : list of bytes
        Everything written to standard error during the decode, line by line.
    """
    buffer = np.frombuffer(data, dtype=np.uint8)
    image, written = call_with_captured_stderr(lambda: cv2.imdecode(buffer, flags))
    return image, written.splitlines(keepends=True)


def _pass_on(lines: list[bytes]) -> None:
    """Write ``lines`` (not the decoder's) to standard error, where they were headed."""
    data = b"".join(lines)
    try:
        while data:
            data = data[os.write(_STDERR_FD, data):]
    except OSError:  # standard error closed meanwhile: nowhere to write
        pass


def _decoder_messages(lines: list[bytes], *, png: bool) -> tuple[list[str], list[str], list[bytes]]:
    """Split captured ``lines`` into the decoder's damage and metadata messages, and the rest."""
    damage, notes, other = [], [], []
    for line in lines:
        text = line.decode("utf-8", errors="replace").strip()
        if png and (match := _PNG_MESSAGE.fullmatch(text)):
            benign = match.group(1) == "warning" and _PNG_ANCILLARY_CHUNK.match(match.group(2))
            (notes if benign else damage).append(text)
        elif not png and text.startswith(_JPEG_DAMAGE):
            damage.append(f"libjpeg: {text}")
        elif not png and text.startswith(_JPEG_NOTES):
            notes.append(f"libjpeg: {text}")
        else:
            other.append(line)
    return damage, notes, other


def _decode_checked(path: Path, data: bytes, *, gray: bool) -> np.ndarray:
    """Decode the sound-looking ``data`` of ``path``; the decoder's complaints become errors or warnings."""
    png = data.startswith(_PNG_SIGNATURE)
    image, lines = _decode(data, _GRAY_FLAGS if gray else _COLOUR_FLAGS)
    damage, notes, other = _decoder_messages(lines, png=png)
    if other:
        _pass_on(other)
    kind = "PNG" if png else "JPEG"
    if damage:
        raise InputError(path, f"damaged {kind} image data ({'; '.join(damage)})")
    if image is None:
        raise InputError(path, "not a readable PNG/JPEG image")
    if notes:
        warnings.warn(f"{path}: {kind} metadata problem ignored, the pixels are read as stored "
                      f"({'; '.join(notes)})", InputWarning, stacklevel=3)
    return image


def sensor_bit_depth(largest: int) -> int:
    """The bit depth a 16-bit file's samples were recorded at, from its largest sample.

    Cameras with 10-, 12- or 14-bit sensors often store their samples
    unscaled in a 16-bit file (values up to 1023, 4095 or 16383), where the
    PNG standard would scale them to the full 16 bits. The recorded depth is
    taken as the smallest of :data:`SENSOR_BIT_DEPTHS` whose range holds
    ``largest``.

    Parameters
    ----------
    largest : int
        The largest sample of the image, 0 to 65535.

    Returns
    -------
    int
        8, 10, 12, 14 or 16.
    """
    return next(depth for depth in SENSOR_BIT_DEPTHS if largest < 2 ** depth)


def eight_bit_from_sixteen(image: np.ndarray, *, source: str | os.PathLike, what: str = "images") -> np.ndarray:
    """``image`` (uint16) as uint8: its top 8 bits at its recorded depth (:func:`sensor_bit_depth`).

    Parameters
    ----------
    image : ndarray of uint16
    source : path-like, keyword-only
        The folder or file the image is from, named in the warning.
    what : str, keyword-only
        What its 16-bit pictures are called in the warning (``"images"``, ``"frames"``).

    Warns
    -----
    InputWarning
        The image is read at a smaller recorded depth than 16 bits (one
        message per ``source`` and depth).
    """
    depth = sensor_bit_depth(int(image.max()))
    if depth < 16:
        warnings.warn(f"{source}: 16-bit {what} whose values stay below {2 ** depth} are read as "
                      f"{depth}-bit data (their top 8 of {depth} bits), not as 16-bit data", InputWarning,
                      stacklevel=3)
    return (image >> (depth - 8)).astype(np.uint8)


def read_image(path: str | os.PathLike, *, size: tuple[int, int] | None = None,
               gray: bool = True) -> np.ndarray:
    """Read an 8- or 16-bit image as 8-bit, as its raw pixel grid (an EXIF orientation tag is ignored).

    A 16-bit image keeps the top 8 bits of the depth its samples were
    recorded at (:func:`sensor_bit_depth`): 16-bit data its high byte,
    12-bit data stored unscaled its bits 4 to 11, and so on.

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
        Indexed ``[row, col]`` of the stored pixels.

    Raises
    ------
    InputError
        Unreadable or damaged file (also damage only the decoder finds), a
        FIFO, device or socket, or wrong size.

    Warns
    -----
    InputWarning
        The decoder found a problem in metadata that does not change the
        pixels (e.g. a PNG's colour profile), or a 16-bit image is read at
        a smaller recorded depth (one message per folder and depth on the
        command line).
    """
    path = Path(path)
    refuse_special_file(path, what="image file")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "image file not found") from None
    except OSError as exc:
        raise InputError(path, f"cannot read image ({exc.strerror or exc.__class__.__name__})") from None
    return _decoded(data, source=path, size=size, gray=gray, depth_source=path.parent)


def image_from_bytes(data: bytes, *, source: str | os.PathLike, size: tuple[int, int] | None = None,
                     gray: bool = True, depth_source: str | os.PathLike | None = None) -> np.ndarray:
    """Decode the bytes of a PNG or JPEG file exactly as :func:`read_image` decodes the file.

    For images that do not come from a file of their own (a compressed
    frame of a ROS bag): the checks, the decoding, the bit depth and the
    colour order are those of :func:`read_image`.

    Parameters
    ----------
    data : bytes
        The PNG or JPEG file's content.
    source : str or path-like, keyword-only
        What the bytes are, named in errors and warnings (a file, or a bag's frame).
    size, gray
        As for :func:`read_image`.
    depth_source : str or path-like, optional, keyword-only
        What the warning of a 16-bit image read at a smaller depth names
        (default ``source``; one name for a whole sequence gives one line).

    Returns
    -------
    ndarray of uint8
        ``(H, W)`` or ``(H, W, 3)`` RGB, indexed ``[row, col]``.

    Raises
    ------
    InputError
        Damaged or unreadable image data, or another size than ``size``,
        naming ``source``.
    """
    return _decoded(data, source=source, size=size, gray=gray,
                    depth_source=source if depth_source is None else depth_source)


def _decoded(data: bytes, *, source, size, gray: bool, depth_source) -> np.ndarray:
    """:func:`image_from_bytes`; a 16-bit image's depth warning names ``depth_source``."""
    path = source
    problem = image_file_problem(data, size=size)
    if problem:
        raise InputError(path, problem)
    image = _decode_checked(path, data, gray=gray)
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]  # the alpha channel goes before the bit depth is judged
    if image.dtype == np.uint16:
        image = eight_bit_from_sixteen(image, source=depth_source)
    elif image.dtype != np.uint8:
        raise InputError(path, f"expected an 8- or 16-bit image, got {image.dtype}")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    problem = size_problem(*image.shape[:2], size)
    if problem:
        raise InputError(path, problem)
    return image
