"""ROS bags as frame sequences: every bag kind, every encoding, stamps, the estimate's parity with a
folder of the same images, and one clear line for each kind of bad input."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.cli import main
from ifmi.errors import InputError, InputWarning
from ifmi.frames import MissingFrame
from ifmi.io.bag_writer import BagWriter
from ifmi.io.bags import BagFrames, gray_from_rgb, is_bag_path
from ifmi.io.dataset import read_dataset
from ifmi.io.images import read_image
from ifmi.synthetic import synthetic_sequence, write_synthetic_dataset

SIZE = 160
MODEL = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=50.0)
# (format, storage, path name) of every kind of bag written.
BAG_KINDS = (("ros1", "mcap", "frames.bag"), ("ros2", "mcap", "frames_mcap"), ("ros2", "sqlite3", "frames_db3"))
TOPIC = "/camera/image_raw"
SECOND_NS = 10 ** 9


@pytest.fixture(scope="module")
def sequence():
    return synthetic_sequence(MODEL, 6, seed=4, max_step_rad=0.05, band_px=(16.0, 75.0))


@pytest.fixture(scope="module")
def dataset(sequence, tmp_path_factory):
    return write_synthetic_dataset(tmp_path_factory.mktemp("bags") / "ds", sequence)


def _colour(image: np.ndarray) -> np.ndarray:
    """An RGB frame whose channels differ, from a gray one."""
    return np.stack([image, image // 2 + 64, 255 - image], axis=-1)


def _write_frames(path, images, *, bag_format="ros2", storage="mcap", stamps_ns=None, receive_ns=None,
                  topic=TOPIC, compressed=None):
    """A bag of ``images`` on ``topic``: raw ``Image`` or ``CompressedImage`` of file bytes."""
    stamps_ns = [k * SECOND_NS for k in range(len(images))] if stamps_ns is None else stamps_ns
    receive_ns = stamps_ns if receive_ns is None else receive_ns
    with BagWriter(path, bag_format=bag_format, storage=storage) as writer:
        for image, stamp, receive in zip(images, stamps_ns, receive_ns):
            if compressed is None:
                message = writer.image(image, stamp_ns=stamp, frame_id="camera")
            else:
                message = writer.compressed_image(image, compressed, stamp_ns=stamp, frame_id="camera")
            writer.write(topic, message, receive)
    return path


def _raw_message(writer, pixels: np.ndarray, encoding: str, *, stamp_ns=0, step_padding=0, big_endian=False):
    """A ``sensor_msgs/Image`` of ``pixels`` in ``encoding``, rows padded by ``step_padding`` bytes."""
    height, width = pixels.shape[:2]
    data = pixels.astype(pixels.dtype.newbyteorder(">" if big_endian else "<")).reshape(height, -1).view(np.uint8)
    data = np.concatenate([data, np.zeros((height, step_padding), np.uint8)], axis=1)
    return writer.typestore.types["sensor_msgs/msg/Image"](
        header=writer.header(stamp_ns, "camera"), height=height, width=width, encoding=encoding,
        is_bigendian=int(big_endian), step=data.shape[1], data=data.reshape(-1))


@pytest.mark.parametrize("bag_format, storage, name", BAG_KINDS)
def test_every_bag_kind_yields_the_folder_frames_and_stamps(sequence, dataset, tmp_path, bag_format, storage, name):
    bag = _write_frames(tmp_path / name, sequence.images, bag_format=bag_format, storage=storage,
                        stamps_ns=[SECOND_NS * 100 + k * SECOND_NS // 10 for k in range(6)])
    assert is_bag_path(bag)
    frames = BagFrames(bag, size=MODEL.size)  # the only image topic is chosen
    decoded = list(frames)
    assert frames.topic == TOPIC and len(frames) == 6
    assert all(np.array_equal(a, b) for a, b in zip(decoded, read_dataset(dataset).iter_images()))
    assert frames.timestamps == pytest.approx(100 + np.arange(6) / 10, abs=1e-9)


def test_prefetching_yields_the_same_frames_flags_and_warning(sequence, tmp_path):
    images = [cv2.imencode(".png", image)[1].tobytes() for image in sequence.images]
    images[3] = images[3][:200]  # a cut PNG: a flagged frame
    stamps = [k * SECOND_NS for k in (0, 1, 1, 2, 3, 4)]  # a duplicate: one warning
    bag = _write_frames(tmp_path / "b", images, stamps_ns=stamps, compressed="png")
    read = {}
    for prefetch in (False, True):
        frames = BagFrames(bag, size=MODEL.size, prefetch=prefetch)
        with pytest.warns(InputWarning) as caught:
            read[prefetch] = (list(frames), frames.timestamps, [str(w.message) for w in caught])
    plain, ahead = read[False], read[True]
    assert plain[1:] == ahead[1:] and len(plain[2]) == 1
    assert all(np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b for a, b in zip(plain[0], ahead[0]))
    assert isinstance(ahead[0][3], MissingFrame)


def test_a_bare_mcap_file_is_a_bag(sequence, tmp_path):
    folder = _write_frames(tmp_path / "folder", sequence.images[:3])
    bare = tmp_path / "frames.mcap"
    shutil.copyfile(next(folder.glob("*.mcap")), bare)
    frames = BagFrames(bare)
    assert len(list(frames)) == 3 and frames.timestamps == [0.0, 1.0, 2.0]


def test_gray_from_rgb_equals_a_colour_png_read_in_gray(rng):
    pixels = rng.integers(0, 256, (64, 96, 3), dtype=np.uint8)
    ok, png = cv2.imencode(".png", pixels[..., ::-1])
    assert ok
    from_png = cv2.imdecode(png, cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(gray_from_rgb(pixels), from_png)


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgr8", "rgb8", "bgra8", "rgba8"])
def test_every_raw_encoding_is_read_as_the_same_pixels(encoding, tmp_path, rng):
    rgb = rng.integers(0, 256, (12, 10, 3), dtype=np.uint8)
    gray = rgb[..., 1]
    pixels = {"mono8": gray, "mono16": gray.astype(np.uint16) << 8, "bgr8": rgb[..., ::-1], "rgb8": rgb,
              "bgra8": np.dstack([rgb[..., ::-1], np.full(gray.shape, 7, np.uint8)]),
              "rgba8": np.dstack([rgb, np.full(gray.shape, 7, np.uint8)])}[encoding]
    with BagWriter(tmp_path / "b", bag_format="ros2") as writer:
        # Rows padded to a longer step, and 16-bit samples big-endian: both as the message says.
        writer.write(TOPIC, _raw_message(writer, pixels, encoding, step_padding=3,
                                         big_endian=encoding == "mono16"), 1)
    expected_gray = gray if encoding.startswith("mono") else gray_from_rgb(rgb)
    assert np.array_equal(next(iter(BagFrames(tmp_path / "b"))), expected_gray)
    expected_colour = gray if encoding.startswith("mono") else rgb
    assert np.array_equal(next(iter(BagFrames(tmp_path / "b", gray=False))), expected_colour)


def test_colour_frames_match_a_folder_of_colour_pngs(sequence, tmp_path):
    colour = [_colour(image) for image in sequence.images[:3]]
    (tmp_path / "images").mkdir()
    for k, image in enumerate(colour):
        cv2.imwrite(str(tmp_path / "images" / f"{k:06d}.png"), image[..., ::-1])
    bag = _write_frames(tmp_path / "b", colour, bag_format="ros1", storage="mcap")
    bag = bag.rename(tmp_path / "b.bag")
    folder = [read_image(tmp_path / "images" / f"{k:06d}.png") for k in range(3)]
    assert all(np.array_equal(a, b) for a, b in zip(BagFrames(bag), folder))


@pytest.mark.parametrize("image_format, suffix", [("png", ".png"), ("jpeg", ".jpg")])
def test_compressed_frames_decode_as_their_files_do(sequence, tmp_path, image_format, suffix):
    files = []
    for k, image in enumerate(sequence.images[:3]):
        path = tmp_path / f"{k}{suffix}"
        cv2.imwrite(str(path), _colour(image)[..., ::-1])
        files.append(path)
    bag = _write_frames(tmp_path / "b", [p.read_bytes() for p in files], compressed=image_format)
    for gray in (True, False):
        decoded = list(BagFrames(bag, size=MODEL.size, gray=gray))
        assert all(np.array_equal(a, read_image(p, gray=gray)) for a, p in zip(decoded, files))


def test_zero_stamps_take_the_receive_time(sequence, tmp_path):
    bag = _write_frames(tmp_path / "b", sequence.images[:3], stamps_ns=[0, 0, 5 * SECOND_NS],
                        receive_ns=[2 * SECOND_NS, 3 * SECOND_NS, 4 * SECOND_NS])
    frames = BagFrames(bag)
    list(frames)
    assert frames.timestamps == [2.0, 3.0, 5.0]


def test_duplicate_and_backward_stamps_are_restamped_with_one_warning(sequence, tmp_path):
    stamps = [10 * SECOND_NS, 11 * SECOND_NS, 11 * SECOND_NS, 9 * SECOND_NS, 14 * SECOND_NS]
    bag = _write_frames(tmp_path / "b", sequence.images[:5], stamps_ns=stamps,
                        receive_ns=[k * SECOND_NS for k in range(1, 6)])
    frames = BagFrames(bag)
    with pytest.warns(InputWarning) as caught:
        assert len(list(frames)) == 5
    assert len(caught) == 1
    assert "2 frames of /camera/image_raw (the first: frame 2)" in str(caught[0].message)
    # One frame interval (the mean spacing so far, 1 s) after the previous frame, as for a video.
    assert frames.timestamps == [10.0, 11.0, 12.0, 13.0, 14.0]


def _bag_with_topics(path):
    """A ROS 2 bag with two image topics, an IMU-like pose topic and nothing else."""
    with BagWriter(path, bag_format="ros2") as writer:
        image = np.zeros((4, 4), np.uint8)
        writer.write("/left/image_raw", writer.image(image, stamp_ns=1, frame_id="l"), 1)
        writer.write("/right/image_raw", writer.image(image, stamp_ns=1, frame_id="r"), 1)
        writer.write("/pose", writer.pose_stamped(np.eye(3), np.zeros(3), stamp_ns=1, frame_id="w"), 1)
    return path


def test_topic_problems_are_one_line_listing_the_image_topics(tmp_path):
    bag = _bag_with_topics(tmp_path / "b")
    listed = "/left/image_raw (sensor_msgs/msg/Image), /right/image_raw (sensor_msgs/msg/Image)"
    with pytest.raises(InputError, match="has 2 image topics; choose one with --topic") as error:
        BagFrames(bag)
    assert listed in str(error.value)
    with pytest.raises(InputError, match="has no topic /camera/image_raw") as error:
        BagFrames(bag, topic="/camera/image_raw")
    assert listed in str(error.value)
    with pytest.raises(InputError, match="topic /pose holds geometry_msgs/msg/PoseStamped, expected "
                                         "sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage"):
        BagFrames(bag, topic="/pose")


def test_a_bag_without_images_lists_its_topics(tmp_path):
    with BagWriter(tmp_path / "b", bag_format="ros1") as writer:
        writer.write("/pose", writer.pose_stamped(np.eye(3), np.zeros(3), stamp_ns=1, frame_id="w"), 1)
    shutil.move(tmp_path / "b", tmp_path / "b.bag")
    with pytest.raises(InputError, match=r"it has no image topic .*; its topics: /pose "
                                         r"\(geometry_msgs/msg/PoseStamped\)"):
        BagFrames(tmp_path / "b.bag")


def _damaged(data: bytes, damage: str) -> bytes:
    """``data`` cut in half, or with a stretch in its middle overwritten (the index at its end intact)."""
    if damage == "truncated":
        return data[: len(data) // 2]
    third = len(data) // 3
    return data[:third] + b"\xff" * 4000 + data[third + 4000:]


# Overwritten bytes inside an MCAP chunk that carries no checksum (rosbags writes none) cannot be
# found: that case is left out.
@pytest.mark.parametrize("bag_format, storage, name, damage",
                         [kind + ("truncated",) for kind in BAG_KINDS]
                         + [kind + ("overwritten",) for kind in BAG_KINDS if kind[2] != "frames_mcap"])
def test_damaged_bags_are_one_line_or_end_early_with_one_warning(sequence, dataset, tmp_path, capsys, bag_format,
                                                                 storage, name, damage):
    bag = _write_frames(tmp_path / name, sequence.images, bag_format=bag_format, storage=storage)
    stored = bag if bag.is_file() else next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    stored.write_bytes(_damaged(stored.read_bytes(), damage))
    status = main(["estimate", str(bag), "--calib", str(dataset / "calib_results.txt"),
                   "--out", str(tmp_path / "e.txt"), "--no-progress"])
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(bag) in err, err
    if status == 0:  # the frames before the damage were estimated, and the warning says so
        assert "warning:" in err and "the bag breaks off after" in err
    else:
        assert status == 2 and "error:" in err
    stored.write_bytes(b"not a bag at all" * 10)
    with pytest.raises(InputError, match="not a ROS bag that can be read"):
        BagFrames(bag)


def test_missing_bag_is_one_line(tmp_path):
    with pytest.raises(InputError, match="bag not found"):
        BagFrames(tmp_path / "absent.bag")


def test_undecodable_frames_are_flagged_and_a_bad_first_frame_is_an_error(sequence, tmp_path):
    images = [cv2.imencode(".png", image)[1].tobytes() for image in sequence.images[:4]]
    images[2] = images[2][:100]  # a cut PNG
    bag = _write_frames(tmp_path / "b", images, compressed="png")
    decoded = list(BagFrames(bag, size=MODEL.size))
    assert isinstance(decoded[2], MissingFrame) and not isinstance(decoded[3], MissingFrame)
    assert "b /camera/image_raw frame 2 at 2.000000 s:" in decoded[2].reason
    with BagWriter(tmp_path / "enc", bag_format="ros2") as writer:
        for k, encoding in enumerate(("mono8", "yuv422", "mono8")):
            writer.write(TOPIC, _raw_message(writer, sequence.images[k], encoding, stamp_ns=k + 1), k + 1)
    decoded = list(BagFrames(tmp_path / "enc", size=MODEL.size))
    assert isinstance(decoded[1], MissingFrame) and "encoding 'yuv422' is not read" in decoded[1].reason
    first_bad = _write_frames(tmp_path / "first", images[2:], compressed="png")
    with pytest.raises(InputError, match="frame 0:"):
        list(BagFrames(first_bad, size=MODEL.size))


def test_a_frame_of_another_size_is_flagged(sequence, tmp_path):
    images = list(sequence.images[:3])
    images[1] = images[1][:100]
    decoded = list(BagFrames(_write_frames(tmp_path / "b", images), size=MODEL.size))
    assert isinstance(decoded[1], MissingFrame) and "calibration" in decoded[1].reason
    first_small = BagFrames(_write_frames(tmp_path / "first", images[1:]), size=MODEL.size)
    for read in (first_small.spread_frames, lambda count: list(first_small)):  # the band's frames, the sequence
        with pytest.raises(InputError, match="frame 0: image is 100x160 .* the calibration names 160x160"):
            read(5)


def _estimate(args, out):
    assert main(["estimate", *map(str, args), "--out", str(out), "--no-progress"]) == 0
    return out.read_text().split("\n", 1)[1]  # the poses and timestamps, without the header line


def test_the_estimate_from_a_bag_equals_the_folder_estimate_bit_for_bit(sequence, dataset, tmp_path):
    folder = _estimate([dataset], tmp_path / "folder.txt")
    calib = dataset / "calib_results.txt"
    raw = _write_frames(tmp_path / "raw.bag", sequence.images, bag_format="ros1")
    pngs = [p.read_bytes() for p in sorted((dataset / "images").iterdir())]
    compressed = _write_frames(tmp_path / "png", pngs, storage="sqlite3", compressed="png")
    for bag in (raw, compressed):
        assert _estimate([bag, "--calib", calib, "--topic", TOPIC], tmp_path / f"{bag.stem}.txt") == folder


def test_estimate_cli_bad_bag_input_is_one_line(dataset, tmp_path, capsys):
    bag = _bag_with_topics(tmp_path / "b")
    calib = dataset / "calib_results.txt"
    cases = [([bag, "--calib", calib], "has 2 image topics; choose one with --topic"),
             ([bag, "--calib", calib, "--topic", "/nope"], "has no topic /nope (its image topics: "),
             ([bag, "--calib", calib, "--topic", "/pose"], "topic /pose holds geometry_msgs/msg/PoseStamped"),
             ([bag], "a bag needs --calib"),
             ([dataset, "--topic", "/x"], "--topic: is for a ROS bag")]
    for args, expected in cases:
        capsys.readouterr()
        assert main(["estimate", *map(str, args), "--out", str(tmp_path / "e.txt"), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert expected in err and len(err.strip().splitlines()) == 1, err
    single = _write_frames(tmp_path / "single", [np.zeros(MODEL.size, np.uint8)])
    assert main(["estimate", str(single), "--calib", str(calib), "--out", str(single / "e.txt")]) == 1
    assert "lies in the bag folder" in capsys.readouterr().err and not (single / "e.txt").exists()


@pytest.mark.slow
def test_a_sweep_takes_a_bag_as_it_takes_the_folder(dataset, tmp_path, capsys):
    import pandas as pd

    bag = tmp_path / "ds_bag"
    from omnisim.export import export_dataset

    export_dataset(dataset, bag)
    grid = ["--tile-size", "32", "--overlap", "0.5", "--scheduler", "synchronous", "--no-progress"]
    assert main(["sweep", str(dataset), str(bag), "--calib", str(dataset / "calib_results.txt"),
                 "--gt-topic", "/groundtruth/pose", "--out", str(tmp_path / "sweep"), *grid]) == 0
    table = pd.read_csv(tmp_path / "sweep" / "sweep.csv").set_index("dataset")
    assert list(table["status"]) == ["ok", "ok"]
    for column in ("rmse_geodesic_rad", "rmse_relative_rad", "failures", "frames"):
        # The bag's ground truth is not rounded to the TUM file's 12 decimals: equal to rounding.
        assert table.loc["ds_bag", column] == pytest.approx(table.loc["ds", column], rel=1e-9), column
    capsys.readouterr()
    assert main(["sweep", str(bag), "--out", str(tmp_path / "other"), *grid]) == 2
    assert "a bag needs --calib" in capsys.readouterr().err
    assert main(["sweep", str(dataset), "--calib", str(dataset / "calib_results.txt"),
                 "--out", str(tmp_path / "other"), *grid]) == 2
    assert "--calib: is for ROS bags; no DATASET is one" in capsys.readouterr().err
