"""benchmarks/real_omni_photo.py: the package's calibration file and photo turned into a warp source."""

from __future__ import annotations

import zipfile

import cv2
import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model, radius_from_pixels
from ifmi.errors import InputError
from ifmi.io.calib import format_calib, parse_calib

MODEL = paracatadioptric_model((60, 80), horizon_radius_px=20.0)
# The package's calibration file appends two blocks: ROI radii (max, min) and cropped columns (left, right).
EXTRA = "\n#ROI max min radius\n\n28 9\n\n#left right cropped pixel\n\n7 5\n"


@pytest.fixture
def script(benchmark_module):
    """``benchmarks/real_omni_photo.py`` as a module."""
    return benchmark_module("real_omni_photo")


def test_standard_blocks_round_trip_and_the_photo_is_cropped_and_masked(script, rng):
    text = format_calib(MODEL) + EXTRA
    model = parse_calib(script.standard_calib_text(text))
    assert model == parse_calib(format_calib(MODEL))
    full = rng.integers(1, 255, size=(60, 92, 3)).astype(np.uint8)
    photo = script.PackagePhoto(image=full, calib_text=text, roi_radii_px=(9.0, 28.0),
                                cropped_columns=(7, 5), license_text="")
    image = script.masked_photo(photo, model)
    rows, cols = np.mgrid[0:60, 0:80]
    radius = radius_from_pixels(model, np.stack([rows, cols], axis=-1).astype(float))
    inside = (radius >= 9.0) & (radius <= 28.0)
    assert np.array_equal(image[inside], full[:, 7:87][inside])
    assert not image[~inside].any()
    wrong = script.PackagePhoto(image=full[:, :90], calib_text=text, roi_radii_px=(9.0, 28.0),
                                cropped_columns=(7, 5), license_text="")
    with pytest.raises(InputError, match="expected 60x80 px after cropping, got 60x78"):
        script.masked_photo(wrong, model)


def test_a_wheel_with_other_files_is_refused(script, tmp_path):
    wheel = tmp_path / "pyomniunwarp-0.2.5-py2.py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        archive.writestr(script.PHOTO_MEMBER, cv2.imencode(".jpg", np.zeros((8, 8), np.uint8))[1].tobytes())
        archive.writestr(script.CALIB_MEMBER, format_calib(MODEL) + EXTRA)
        archive.writestr(script.LICENSE_MEMBER, "MIT")
    with pytest.raises(InputError, match="differs from the file this script was written for"):
        script.read_package_photo(wheel)
    (tmp_path / "broken.whl").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not the pyomniunwarp 0.2.5 wheel"):
        script.read_package_photo(tmp_path / "broken.whl")
