"""Text inputs that are not what they should be: one line saying what they are instead."""

from __future__ import annotations

from pathlib import Path

import pytest

from ifmi.errors import InputError
from ifmi.io.camera_file import calibration_path, read_camera
from ifmi.io.config import read_json_object
from ifmi.io.tum import read_tum


def test_folder_named_as_the_calibration_is_said_to_be_a_folder(tmp_path):
    (tmp_path / "calib_results.txt").mkdir()
    path = calibration_path(tmp_path)
    with pytest.raises(InputError, match=r"calib_results.txt: is a folder; expected a calibration file$"):
        read_camera(path)


def test_utf16_json_is_named_as_utf16(tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"method": "ifmi"}', encoding="utf-16")
    with pytest.raises(InputError, match=r"config.json: cannot read configuration file: UTF-16 text; "
                                         r"expected UTF-8 text$"):
        read_json_object(path, what="configuration file")


def test_json_and_scene_files_with_a_byte_order_mark_are_read(tmp_path):
    from omnisim.config import load_scene_config

    path = tmp_path / "config.json"
    path.write_bytes(b"\xef\xbb\xbf" + b'{"method": "ifmi"}')
    assert read_json_object(path) == {"method": "ifmi"}
    plain = Path(__file__).resolve().parents[1] / "scenes" / "office.toml"
    marked = tmp_path / "office.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    with_mark, without = load_scene_config(marked), load_scene_config(plain)
    assert (with_mark.name, with_mark.camera, with_mark.objects) == (without.name, without.camera, without.objects)


def test_byte_that_is_no_utf8_is_named_with_its_offset(tmp_path):
    path = tmp_path / "groundtruth.txt"
    path.write_bytes(b"0 0 0 0 0 0 0 1\n\xff\n")
    with pytest.raises(InputError, match=r"groundtruth.txt: cannot read trajectory file: byte 0xff at offset 16 "
                                         r"is not UTF-8 text; expected UTF-8 text$"):
        read_tum(path)


def test_key_given_twice_in_a_json_object_is_refused(tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"relative_pose": {"seed": 1, "seed": 2}}')
    with pytest.raises(InputError, match=r'config.json: invalid JSON: key "seed" given twice in one object'):
        read_json_object(path)


def test_key_given_twice_in_a_camchain_is_refused_but_a_merged_one_may_be_overridden(tmp_path):
    from ifmi.io.kalibr import read_kalibr

    cam = ("  camera_model: eucm\n  intrinsics: [0.62, 1.05, 150.0, 150.5, 257.1, 254.3]\n"
           "  distortion_model: none\n  distortion_coeffs: []\n  resolution: [512, 512]\n")
    twice = tmp_path / "twice.yaml"
    twice.write_text("cam0:\n" + cam + "  camera_model: ds\n")
    with pytest.raises(InputError, match=r"twice.yaml: not valid YAML at line 7, column 3: key 'camera_model' "
                                         r"given twice in one mapping"):
        read_kalibr(twice)
    merged = tmp_path / "merged.yaml"
    merged.write_text("defaults: &d\n" + cam + "cam0:\n  <<: *d\n  resolution: [512, 512]\n")
    assert read_kalibr(merged).size == (512, 512)
