"""Decoding image files: the raw pixel grid (no EXIF orientation), and damage only the decoder sees."""

from __future__ import annotations

import os
import struct
import warnings
import zlib

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.errors import InputError, InputWarning
from ifmi.frames import MissingFrame
from ifmi.io import images
from ifmi.io.calib import write_calib
from ifmi.io.dataset import read_dataset
from ifmi.io.images import image_file_problem, read_image

SHAPE = (16, 24)
# EXIF orientation 3: "rotate 180 degrees to display".
ROTATE_180 = 3


def _pattern(colour: bool = False) -> np.ndarray:
    """An image that differs from its 180-degree rotation: bright left half, gradient down."""
    image = np.zeros(SHAPE, np.uint8)
    image[:, :SHAPE[1] // 2] = 200
    image += (np.arange(SHAPE[0], dtype=np.uint8) * 2)[:, None]
    return np.dstack([image, image // 2, 255 - image]) if colour else image


def _exif_orientation(orientation: int) -> bytes:
    """A big-endian TIFF block holding one IFD entry: Orientation (0x0112, SHORT) = ``orientation``."""
    entry = struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0)
    return b"MM\x00*" + struct.pack(">I", 8) + struct.pack(">H", 1) + entry + struct.pack(">I", 0)


def _jpeg_with_orientation(image: np.ndarray, orientation: int) -> tuple[bytes, bytes]:
    """The JPEG of ``image`` (quality 100) with and without an EXIF APP1 segment after SOI."""
    plain = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 100])[1].tobytes()
    payload = b"Exif\x00\x00" + _exif_orientation(orientation)
    app1 = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    return plain[:2] + app1 + plain[2:], plain


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _gray_png(image: np.ndarray, *, before_idat: bytes = b"", idat: bytes | None = None,
              interlace: int = 0) -> bytes:
    """An 8-bit gray PNG written by hand (filter type 0 on every row)."""
    height, width = image.shape
    if idat is None:
        idat = zlib.compress(_raw_rows(image, interlace))
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, interlace)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + before_idat + _chunk(b"IDAT", idat)
            + _chunk(b"IEND", b""))


def _raw_rows(image: np.ndarray, interlace: int) -> bytes:
    if not interlace:
        return b"".join(b"\x00" + row.tobytes() for row in image)
    passes = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
              (0, 1, 1, 2))  # Adam7: first column, first row, column step, row step
    return b"".join(b"\x00" + row.tobytes() for col, row0, dx, dy in passes
                    for row in image[row0::dy, col::dx] if row.size)


def _dataset(tmp_path, files: dict, shape=SHAPE) -> object:
    root = tmp_path / "ds"
    (root / "images").mkdir(parents=True)
    write_calib(root / "calib_results.txt", paracatadioptric_model(shape, horizon_radius_px=6.0))
    for name, data in files.items():
        (root / "images" / name).write_bytes(data)
    return root


# --- EXIF orientation -------------------------------------------------------------------

@pytest.mark.parametrize("colour", [False, True])
def test_jpeg_orientation_tag_is_ignored_in_gray_and_colour(colour, tmp_path):
    tagged, plain = _jpeg_with_orientation(_pattern(colour), ROTATE_180)
    (tmp_path / "tagged.jpg").write_bytes(tagged)
    (tmp_path / "plain.jpg").write_bytes(plain)
    for gray in (True, False):
        got = read_image(tmp_path / "tagged.jpg", size=SHAPE, gray=gray)
        np.testing.assert_array_equal(got, read_image(tmp_path / "plain.jpg", size=SHAPE, gray=gray))
    # The gray and the colour decode of one file agree (raw grid, not one of them rotated).
    gray = read_image(tmp_path / "tagged.jpg", gray=True).astype(int)
    as_gray = read_image(tmp_path / "tagged.jpg", gray=False)
    if colour:
        as_gray = cv2.cvtColor(as_gray, cv2.COLOR_RGB2GRAY)
    assert np.abs(gray - as_gray).max() <= 2
    assert np.abs(gray - np.rot90(as_gray, 2)).max() > 10  # the pattern is not symmetric


def test_png_exif_chunk_is_ignored(tmp_path):
    image = _pattern()
    path = tmp_path / "000000.png"
    path.write_bytes(_gray_png(image, before_idat=_chunk(b"eXIf", _exif_orientation(ROTATE_180))))
    np.testing.assert_array_equal(read_image(path, gray=True), image)
    np.testing.assert_array_equal(read_image(path, gray=False), image)


def test_dataset_frames_keep_the_sensor_grid_with_an_orientation_tag(tmp_path):
    tagged, plain = _jpeg_with_orientation(_pattern(), ROTATE_180)
    root = _dataset(tmp_path, {"000000.jpg": plain, "000001.jpg": tagged})
    ds = read_dataset(root)
    for gray in (True, False):
        first, second = ds.iter_images(gray=gray, skip_unreadable=True)
        np.testing.assert_array_equal(first, second)


# --- damage only the decoder sees ------------------------------------------------------

# Size of the damaged JPEG: big enough that its middle is entropy-coded data.
DAMAGED_SHAPE = (64, 64)


def _jpeg_damaged_mid() -> bytes:
    """A JPEG of noise with 40 bytes of its entropy-coded data overwritten; markers intact."""
    noise = (np.random.default_rng(1).random(DAMAGED_SHAPE) * 255).astype(np.uint8)
    data = bytearray(cv2.imencode(".jpg", noise)[1].tobytes())
    middle = len(data) // 2
    data[middle:middle + 40] = b"\x55" * 40
    return bytes(data)


@pytest.mark.parametrize("gray", [True, False])
def test_jpeg_damaged_mid_file_is_an_error_without_libjpeg_lines(gray, tmp_path, capfd):
    data = _jpeg_damaged_mid()
    assert image_file_problem(data) is None  # markers intact: only the decoder sees it
    path = tmp_path / "000001.jpg"
    path.write_bytes(data)
    with pytest.raises(InputError, match=r"000001.jpg: damaged JPEG image data \(libjpeg: Corrupt JPEG data"):
        read_image(path, gray=gray)
    assert capfd.readouterr().err == ""


def test_jpeg_damaged_mid_file_frame_is_flagged(tmp_path, capfd):
    sound = cv2.imencode(".jpg", np.zeros(DAMAGED_SHAPE, np.uint8))[1].tobytes()
    root = _dataset(tmp_path, {"000000.jpg": sound, "000001.jpg": _jpeg_damaged_mid(), "000002.jpg": sound},
                    shape=DAMAGED_SHAPE)
    frames = list(read_dataset(root).iter_images(skip_unreadable=True, prefetch=True))
    assert isinstance(frames[1], MissingFrame)
    assert frames[1].reason.startswith("000001.jpg: damaged JPEG image data (libjpeg: Corrupt JPEG data")
    assert not isinstance(frames[0], MissingFrame) and not isinstance(frames[2], MissingFrame)
    assert capfd.readouterr().err == ""


def test_png_with_too_much_image_data_is_an_error(tmp_path, capfd):
    image = _pattern()
    data = _gray_png(image, idat=zlib.compress(_raw_rows(image, 0) + bytes(100)))
    path = tmp_path / "000003.png"
    path.write_bytes(data)
    expected = SHAPE[0] * (SHAPE[1] + 1)
    assert image_file_problem(data) == (f"corrupt PNG (image data too long: {expected + 100} bytes, "
                                        f"expected {expected} for its 24x16 header)")
    with pytest.raises(InputError, match=r"000003.png: corrupt PNG \(image data too long"):
        read_image(path)
    assert capfd.readouterr().err == ""


def test_interlaced_png_short_of_data_is_an_error_and_a_sound_one_reads(tmp_path, capfd):
    image = _pattern()
    sound = _gray_png(image, interlace=1)
    assert image_file_problem(sound) is None
    (tmp_path / "sound.png").write_bytes(sound)
    np.testing.assert_array_equal(read_image(tmp_path / "sound.png"), image)
    short = _gray_png(image, idat=zlib.compress(_raw_rows(image[:SHAPE[0] // 2], 0)), interlace=1)
    assert image_file_problem(short).startswith("truncated PNG image data (200 of ")
    bad_filter = bytearray(_raw_rows(image, 1))
    bad_filter[-(SHAPE[1] + 1)] = 9  # the filter byte of the last row of the last pass
    assert image_file_problem(_gray_png(image, idat=zlib.compress(bytes(bad_filter)), interlace=1)) == \
        "corrupt PNG (invalid row filter)"
    (tmp_path / "short.png").write_bytes(short)
    with pytest.raises(InputError, match="short.png: truncated PNG image data"):
        read_image(tmp_path / "short.png")
    assert capfd.readouterr().err == ""


def test_png_damage_only_libpng_sees_is_an_error_without_libpng_lines(tmp_path, capfd):
    image = _pattern()
    data = _gray_png(image, idat=zlib.compress(_raw_rows(image, 0)) + b"trailing")
    assert image_file_problem(data) is None  # zlib ignores bytes after the end of the stream
    path = tmp_path / "000002.png"
    path.write_bytes(data)
    with pytest.raises(InputError, match=r"000002.png: damaged PNG image data \(libpng warning: IDAT: Extra"):
        read_image(path)
    assert capfd.readouterr().err == ""


def test_png_metadata_warning_is_one_input_warning_and_the_pixels_read(tmp_path, capfd):
    image = _pattern()
    path = tmp_path / "000002.png"
    path.write_bytes(_gray_png(image, before_idat=_chunk(b"gAMA", b"\x00\x00")))  # gAMA needs 4 bytes
    with pytest.warns(InputWarning) as record:
        got = read_image(path)
    np.testing.assert_array_equal(got, image)
    assert len(record) == 1
    assert str(record[0].message) == (f"{path}: PNG metadata problem ignored, the pixels are read as "
                                      f"stored (libpng warning: gAMA: too short)")
    assert capfd.readouterr().err == ""


def test_other_output_during_a_decode_still_reaches_stderr(tmp_path, capfd, monkeypatch):
    """Another thread's output (e.g. a progress bar) written while stderr is captured is passed on."""
    decode = cv2.imdecode

    def decode_while_another_thread_writes(buffer, flags):
        os.write(2, b"\r 50%|#####     | 1/2")
        return decode(buffer, flags)

    monkeypatch.setattr(images.cv2, "imdecode", decode_while_another_thread_writes)
    path = tmp_path / "000000.png"
    path.write_bytes(_gray_png(_pattern()))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(read_image(path), _pattern())
    assert capfd.readouterr().err == "\r 50%|#####     | 1/2"


@pytest.mark.parametrize("largest, depth", [(0, 8), (255, 8), (256, 10), (1023, 10), (1024, 12),
                                            (4095, 12), (4096, 14), (16383, 14), (16384, 16), (65535, 16)])
def test_sensor_bit_depth_is_the_smallest_common_depth_holding_the_largest_sample(largest, depth):
    assert images.sensor_bit_depth(largest) == depth


@pytest.mark.parametrize("gray", [True, False])
@pytest.mark.parametrize("alpha", [False, True])
def test_sixteen_bit_file_of_unscaled_12_bit_samples_reads_as_their_top_8_bits(tmp_path, gray, alpha):
    """12-bit samples stored unscaled (values < 4096) give back the 8-bit image they were made from;
    a full-range alpha channel beside them does not count."""
    image = _pattern()
    low_bits = np.random.default_rng(3).integers(0, 16, SHAPE, dtype=np.uint16)
    samples = (image.astype(np.uint16) << 4) | low_bits
    if alpha:
        samples = np.dstack([samples, samples, samples, np.full(SHAPE, 65535, np.uint16)])
    path = tmp_path / "000000.png"
    cv2.imwrite(str(path), samples)
    with pytest.warns(InputWarning) as record:
        got = read_image(path, gray=gray)
    np.testing.assert_array_equal(got, np.dstack([image] * 3) if alpha and not gray else image)
    assert [str(r.message) for r in record] == [
        f"{tmp_path}: 16-bit images whose values stay below 4096 are read as 12-bit data "
        f"(their top 8 of 12 bits), not as 16-bit data"]


def test_sixteen_bit_file_of_full_range_samples_reads_as_its_high_byte(tmp_path):
    image = _pattern(colour=True)
    path = tmp_path / "000000.png"
    cv2.imwrite(str(path), (image.astype(np.uint16) << 8) | 0x5A)  # the largest sample is >= 2**14
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = read_image(path, gray=False)
        gray = read_image(path)
    np.testing.assert_array_equal(got, image[..., ::-1])  # written BGR, read RGB
    # Gray is converted from the 16-bit samples and then truncated to 8 bits: within 1 level.
    np.testing.assert_allclose(gray, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), atol=1, rtol=0)


def test_png_claiming_a_huge_image_is_refused_by_its_header_before_inflating(tmp_path, monkeypatch):
    """A few bytes of deflate can claim gigabytes of pixels: the header is checked against the
    calibration's size first, and nothing is inflated."""
    header = struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0)
    data = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(bytes(1000)))
            + _chunk(b"IEND", b""))
    path = tmp_path / "000005.png"
    path.write_bytes(data)

    def no_inflating(*args, **kwargs):
        raise AssertionError("image data inflated before the size was checked")

    monkeypatch.setattr(images.zlib, "decompress", no_inflating)
    with pytest.raises(InputError, match=r"000005.png: image is 30000x30000 \(height x width\), but the "
                                         r"calibration names 16x24"):
        read_image(path, size=SHAPE)


@pytest.mark.parametrize("progressive", [0, 1])
def test_jpeg_of_another_size_is_refused_by_its_frame_header(tmp_path, monkeypatch, progressive):
    data = cv2.imencode(".jpg", _pattern(), [cv2.IMWRITE_JPEG_PROGRESSIVE, progressive])[1].tobytes()
    monkeypatch.setattr(images, "_decode_checked", lambda *a, **k: pytest.fail("decoded"))
    assert image_file_problem(data, size=SHAPE) is None
    assert image_file_problem(data, size=(24, 16)) == ("image is 16x24 (height x width), but the calibration "
                                                       "names 24x16")
