"""A real catadioptric photograph with its OCamCalib calibration, taken from a PyPI package.

The package ``pyomniunwarp`` 0.2.5 (MIT licence, (c) 2022 Kuan Li) ships
one photograph of an office taken through a catadioptric (mirror) lens,
1920 x 1080 JPEG, with the OCamCalib calibration of that camera. This
script fetches the wheel with pip (``pip download --no-deps``: nothing is
installed; the package's own dependency, ``opencv-python``, would clash
with ``opencv-python-headless``), checks the two files against their known
SHA-256, and writes a folder that ``omnisim warp`` takes:

* ``photo.png``: the photograph cropped to the calibrated 1080 x 1300
  region (the calibration file names the columns cropped on the left and
  right), with the camera's own reflection (sensor radius below the
  calibration file's ROI minimum) and anything beyond its ROI maximum set
  to black, so that only the mirror's view of the world is warped;
* ``calib_results.txt``: the calibration in the standard five blocks (the
  package's file adds two: the ROI radii and the cropped columns);
* ``SOURCE.txt``: where both come from and the licence.

Usage::

    python benchmarks/real_omni_photo.py OUT_DIR [--wheel pyomniunwarp-0.2.5-py2.py3-none-any.whl]
    omnisim warp OUT_DIR/photo.png --calib OUT_DIR/calib_results.txt --out DATA/real_warp \\
        --frames 40 --seed 1 --max-step-deg 3
    python benchmarks/bench_methods.py DATA/real_warp --modes frame --timing-rounds 1
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from benchlib import status_of
from ifmi.geometry.camera import radius_from_pixels
from ifmi.errors import InputError
from ifmi.io.atomic import atomic_write_bytes, atomic_write_text
from ifmi.io.calib import parse_calib, write_calib

PACKAGE = "pyomniunwarp"
VERSION = "0.2.5"
# Members of the wheel and their SHA-256: the files this script was written for.
PHOTO_MEMBER = "pyomniunwarp/data/example.jpg"
CALIB_MEMBER = "pyomniunwarp/data/calib_results.txt"
LICENSE_MEMBER = f"pyomniunwarp-{VERSION}.dist-info/LICENSE"
SHA256 = {PHOTO_MEMBER: "109232ce9302a588795bc5cd5bf45239e21e318040c60d0da256fd7de335612c",
          CALIB_MEMBER: "a119f38310f66fc193de528140572b030dd392f8cb0b15de719fa1c44c41b48d"}
# OCamCalib's standard blocks in calib_results.txt; the package's file appends its own after them.
STANDARD_BLOCKS = 5


@dataclass(frozen=True)
class PackagePhoto:
    """The package's photograph (BGR, uncropped) and its calibration's parts."""

    image: np.ndarray
    calib_text: str
    roi_radii_px: tuple[float, float]
    cropped_columns: tuple[int, int]
    license_text: str


def fetch_wheel(dest: Path) -> Path:
    """Download the package's wheel into ``dest`` with pip (no install, no dependencies)."""
    command = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
               "--quiet", "-d", str(dest), f"{PACKAGE}=={VERSION}"]
    done = subprocess.run(command, capture_output=True, text=True)
    wheels = sorted(dest.glob(f"{PACKAGE}-{VERSION}-*.whl"))
    if done.returncode != 0 or not wheels:
        raise InputError(f"{PACKAGE}=={VERSION}", f"pip download failed: {done.stderr.strip()[-300:]}")
    return wheels[0]


def _data_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def read_package_photo(wheel: Path) -> PackagePhoto:
    """The photograph and calibration from the wheel, checked against their SHA-256."""
    try:
        with zipfile.ZipFile(wheel) as archive:
            data = {name: archive.read(name) for name in (PHOTO_MEMBER, CALIB_MEMBER, LICENSE_MEMBER)}
    except (OSError, KeyError, zipfile.BadZipFile) as exc:
        raise InputError(wheel, f"not the {PACKAGE} {VERSION} wheel ({exc})") from None
    for name, digest in SHA256.items():
        if hashlib.sha256(data[name]).hexdigest() != digest:
            raise InputError(wheel, f"{name} differs from the file this script was written for")
    image = cv2.imdecode(np.frombuffer(data[PHOTO_MEMBER], np.uint8), cv2.IMREAD_COLOR)
    text = data[CALIB_MEMBER].decode("utf-8")
    extra = _data_lines(text)[STANDARD_BLOCKS:]
    roi = tuple(float(v) for v in extra[0].split())  # max, min
    cropped = tuple(int(v) for v in extra[1].split())  # left, right
    return PackagePhoto(image=image, calib_text=text, roi_radii_px=(roi[1], roi[0]),
                        cropped_columns=(cropped[0], cropped[1]),
                        license_text=data[LICENSE_MEMBER].decode("utf-8"))


def standard_calib_text(text: str) -> str:
    """The calibration text up to the end of its standard blocks (the package's two extra dropped)."""
    lines = text.splitlines()
    data_rows = [i for i, line in enumerate(lines) if line.strip() and not line.lstrip().startswith("#")]
    return "\n".join(lines[:data_rows[STANDARD_BLOCKS - 1] + 1]) + "\n"


def masked_photo(photo: PackagePhoto, model) -> np.ndarray:
    """The photograph cropped to the calibrated columns, black outside the ROI's radii.

    Returns
    -------
    (H, W, 3) uint8 ndarray
        BGR, ``model.size``.
    """
    left, right = photo.cropped_columns
    image = photo.image[:, left:photo.image.shape[1] - right].copy()
    if image.shape[:2] != model.size:
        raise InputError(PHOTO_MEMBER, f"expected {model.size[0]}x{model.size[1]} px after cropping, "
                                       f"got {image.shape[0]}x{image.shape[1]}")
    rows, cols = np.mgrid[0:model.height, 0:model.width]
    radius = radius_from_pixels(model, np.stack([rows, cols], axis=-1).astype(np.float64))
    inner, outer = photo.roi_radii_px
    image[(radius < inner) | (radius > outer)] = 0
    return image


def _source_note(photo: PackagePhoto, wheel: Path) -> str:
    left, right = photo.cropped_columns
    inner, outer = photo.roi_radii_px
    return (f"photo.png and calib_results.txt come from the PyPI package {PACKAGE} {VERSION}\n"
            f"(wheel {wheel.name}, files {PHOTO_MEMBER} and {CALIB_MEMBER}).\n"
            f"photo.png: the photograph without its {left} left and {right} right columns (the\n"
            f"calibrated region), black below sensor radius {inner:g} px (the camera's own\n"
            f"reflection) and above {outer:g} px (the calibration's ROI).\n"
            f"calib_results.txt: the package's calibration, standard blocks only.\n\n"
            f"Licence of the package (covers both files):\n\n{photo.license_text}\n")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir")
    parser.add_argument("--wheel", help=f"an already downloaded {PACKAGE} {VERSION} wheel")
    args = parser.parse_args(argv)
    out = Path(args.out_dir)

    def work() -> str:
        with tempfile.TemporaryDirectory() as tmp:
            wheel = Path(args.wheel) if args.wheel else fetch_wheel(Path(tmp))
            photo = read_package_photo(wheel)
        model = parse_calib(standard_calib_text(photo.calib_text), source=f"{wheel.name}:{CALIB_MEMBER}")
        image = masked_photo(photo, model)
        out.mkdir(parents=True, exist_ok=True)
        png = cv2.imencode(".png", image)[1]
        atomic_write_bytes(out / "photo.png", png.tobytes())
        write_calib(out / "calib_results.txt", model)
        atomic_write_text(out / "SOURCE.txt", _source_note(photo, wheel))
        return (f"{out}: photo.png {image.shape[0]}x{image.shape[1]} (real catadioptric photograph), "
                f"calib_results.txt, SOURCE.txt")

    return status_of(work)

if __name__ == "__main__":
    sys.exit(main())
