"""benchmarks/real_mei_omni.py: its input checks, crop and mask (the images themselves are not shipped)."""

from __future__ import annotations

import urllib.error

import numpy as np
import pytest

from ifmi.errors import InputError
from ifmi.geometry.camera_models import UnifiedModel


@pytest.fixture
def script(benchmark_module):
    """``benchmarks/real_mei_omni.py`` as a module."""
    return benchmark_module("real_mei_omni")


def test_a_missing_or_different_file_is_one_line_and_exit_2(script, tmp_path, capsys):
    assert script.main([str(tmp_path / "out"), "--images", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {tmp_path / 'img_para_001.pgm'}: cannot be read (No such file or directory)\n"
    (tmp_path / "img_para_001.pgm").write_bytes(b"P5 1 1 255 x")
    with pytest.raises(InputError, match="img_para_001.pgm: differs from the file this script was written for"):
        script.read_images(tmp_path)
    assert script.main([str(tmp_path / "out"), "--images", str(tmp_path)]) == 2
    assert len(capsys.readouterr().err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_offline_download_is_one_line(script, tmp_path, monkeypatch, capsys):
    def refuse(url, timeout):
        raise urllib.error.URLError("no network")

    monkeypatch.setattr(script.urllib.request, "urlopen", refuse)
    assert script.main([str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "download failed (no network); offline?" in err[0] and "--images" in err[0]


def test_crop_moves_the_principal_point_and_the_mask_keeps_the_ring(script, rng):
    model = UnifiedModel(1.0, (40.0, 40.0), (60.0, 50.0), (100, 120))
    rim, reflection = (np.array([50.0, 60.0]), 30.0), (np.array([50.0, 60.0]), 8.0)
    crop, (top, left) = script.cropped(model, rim)
    side = 2 * (30 + script.CROP_MARGIN_PX)
    assert crop.size == (side, side) and (top, left) == (50 - side // 2, 60 - side // 2)
    assert crop.principal_point == (60.0 - left, 50.0 - top)
    image = rng.integers(1, 255, size=(100, 120)).astype(np.uint8)
    photo = script.masked_photo(image, (top, left), side, rim, reflection)
    rows, cols = np.mgrid[0:side, 0:side]
    radius = np.hypot(rows + top - 50.0, cols + left - 60.0)
    ring = (radius <= 30 - script.MASK_MARGIN_PX) & (radius >= 8 + script.MASK_MARGIN_PX)
    assert np.array_equal(photo[ring], image[top:top + side, left:left + side][ring])
    assert not photo[~ring].any()
    with pytest.raises(InputError, match="does not fit inside the image"):
        script.cropped(model, (np.array([50.0, 60.0]), 48.0))
