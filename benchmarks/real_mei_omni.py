"""Real parabolic catadioptric photographs, calibrated here from their checkerboards.

The ten sample images of C. Mei's omnidirectional calibration toolbox
(1280 x 1024 grey PGM, a parabolic mirror: a corridor, a person holding a
checkerboard of 6 x 8 inner corners with 42 mm squares) are published in
the GitHub repository xmba15/omnidirectional_camera (files
``data/img_para_NNN.pgm``). The repository states no licence, so the images
are not part of this project: this script downloads them (or reads a
folder that holds them), checks each against its known SHA-256 and:

1. detects the board's inner corners (``cv2.findChessboardCornersSB``);
2. finds the mirror's outer rim and the camera's own reflection (dark disk
   in the centre) as circles on the median of the images;
3. fits the unified (Mei) model with ``radtan`` distortion and every
   board's pose to the corners
   (:func:`ifmi.geometry.board_calibration.fit_unified_to_boards`), starting
   from a parabolic mirror (``xi = 1``) centred on the rim, its horizon on
   the rim;
4. writes a folder that ``omnisim warp`` takes: for each chosen photograph
   ``photo_NNN.png``, cropped to a square about the rim and black outside
   the rim and inside the reflection (so only the mirror's view of the world
   is warped), the cropped camera as Kalibr ``camera.yaml``, and
   ``calibration.txt`` (reprojection errors per image).

Usage::

    python benchmarks/real_mei_omni.py OUT_DIR [--images DIR] [--photos 1 7 10]
    omnisim warp OUT_DIR/photo_001.png --calib OUT_DIR/camera.yaml --out DATA/mei_001_3 \\
        --frames 40 --seed 1 --max-step-deg 3
    python benchmarks/bench_methods.py DATA/mei_001_3 --modes frame keyframe --timing-rounds 1
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np

from benchlib import status_of
from ifmi.errors import InputError
from ifmi.geometry.board_calibration import (BoardCalibration, BoardFitConfig, board_points,
                                             fit_unified_to_boards, parabolic_start)
from ifmi.geometry.camera_models import UnifiedModel
from ifmi.io.atomic import atomic_write_bytes, atomic_write_text
from ifmi.io.kalibr import write_kalibr

REPOSITORY = "xmba15/omnidirectional_camera"
COMMIT = "5c30016d25141024368214d07e0fcf52904fb680"
RAW_URL = f"https://raw.githubusercontent.com/{REPOSITORY}/{COMMIT}/data/{{name}}"
SHA256 = {
    "img_para_001.pgm": "bd8286f643302356af24fabe1f19a8e4296f79e3a6188428fa825e7d7baf245a",
    "img_para_002.pgm": "0f8b1252f6e87f63dbee01edfae4df4917b55d54770f0e313860dfd30207733d",
    "img_para_003.pgm": "c6a5c4126d34f135a667ff357cfa71a2220bb03da949c23af10a00d49de2ab3a",
    "img_para_004.pgm": "657a0cc6add2cc8c23b6098969314c0787db6b246d164926eb6150a46712a3fa",
    "img_para_005.pgm": "61a199801547937fbfd45fa15058673990cf1c6f1982ad4af5ccc62518254c97",
    "img_para_006.pgm": "85353158a61a0218897c26dfffff2a92152d7bd3102ae219fec4033b7f419d57",
    "img_para_007.pgm": "4711d17d5bdafb5cae5433ba025aa65728a396bf5c5fbedd7c7a328d8f26a2b6",
    "img_para_008.pgm": "a37b5a1a9d0a7153aec820beb048d49082806251424c132d644846180547eaf4",
    "img_para_009.pgm": "f6f16ea07b2288ed4e300e36e0bb1250743cdd9b8d3bdf80cec14473e31d2191",
    "img_para_010.pgm": "2c16e6fb7d0d9f536558494c0dd39ad8bcace2e90d76722609339f9150e5d491",
}
# The board: inner corners per column and per row, square side (metres).
BOARD_ROWS, BOARD_COLS, SQUARE_M = 6, 8, 0.042
# Circle search on the median image (Hough transform): radius ranges (px) of the mirror's
# rim and of the camera's reflection in a 1280 x 1024 image of this camera, blur (px), edge threshold.
RIM_RADII_PX, REFLECTION_RADII_PX = (250, 450), (20, 120)
CIRCLE_BLUR_PX, CIRCLE_EDGE_THRESHOLD, CIRCLE_VOTES = 2.0, 60, 30
# Kept off the rim and the reflection's edge in the masked photographs (their blur and the
# rim's metal edge), pixels; and the crop's margin beyond the rim.
MASK_MARGIN_PX = 6
CROP_MARGIN_PX = 8
DOWNLOAD_TIMEOUT_S = 60


def _download(name: str) -> bytes:
    url = RAW_URL.format(name=name)
    try:
        with urllib.request.urlopen(url, timeout=DOWNLOAD_TIMEOUT_S) as response:
            return response.read()
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise InputError(url, f"download failed ({reason}); offline? pass a folder holding the files "
                              f"with --images") from None


def read_images(folder: Path | None) -> dict[str, np.ndarray]:
    """The ten images by file name, from ``folder`` or downloaded, checked against their SHA-256.

    Raises
    ------
    InputError
        A file missing or unreadable, different from the file this script
        was written for, or a failed download.
    """
    images = {}
    for name, digest in SHA256.items():
        if folder is None:
            data = _download(name)
        else:
            try:
                data = (folder / name).read_bytes()
            except OSError as exc:
                raise InputError(folder / name, f"cannot be read ({exc.strerror or exc})") from None
        if hashlib.sha256(data).hexdigest() != digest:
            raise InputError(folder / name if folder else RAW_URL.format(name=name),
                             "differs from the file this script was written for (SHA-256)")
        images[name] = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    return images


def detect_corners(images: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inner board corners ``(row, col)`` (N, 2) of the images where the whole board is found."""
    found = {}
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    for name, image in images.items():
        ok, corners = cv2.findChessboardCornersSB(image, (BOARD_COLS, BOARD_ROWS), flags=flags)
        if ok:
            found[name] = corners[:, 0, ::-1].astype(np.float64)
    return found


def _circle(median: np.ndarray, radii: tuple[int, int], name: str) -> tuple[np.ndarray, float]:
    blurred = cv2.GaussianBlur(median, (0, 0), CIRCLE_BLUR_PX)
    circles = cv2.HoughCircles(blurred, cv2.HOUGH_GRADIENT, dp=1, minDist=1, param1=CIRCLE_EDGE_THRESHOLD,
                               param2=CIRCLE_VOTES, minRadius=radii[0], maxRadius=radii[1])
    if circles is None:
        raise InputError("the images", f"no circle of the {name} found")
    col, row, radius = circles[0][0]
    return np.array([row, col], dtype=np.float64), float(radius)


def mirror_circles(images: dict[str, np.ndarray]) -> tuple[tuple[np.ndarray, float], tuple[np.ndarray, float]]:
    """``((centre, radius), (centre, radius))`` of the rim and of the reflection; ``(row, col)``, pixels.

    Found on the median of the images, where the person and the board,
    which move from image to image, fade.
    """
    median = np.median(np.stack(list(images.values())), axis=0).astype(np.uint8)
    return _circle(median, RIM_RADII_PX, "mirror's rim"), _circle(median, REFLECTION_RADII_PX, "camera's reflection")


def calibrate(corners: dict[str, np.ndarray], rim: tuple[np.ndarray, float], size) -> BoardCalibration:
    """The unified model with radtan distortion fitted to the corners, from a parabolic start on the rim."""
    start = parabolic_start(rim[0], rim[1], size)
    return fit_unified_to_boards(np.stack(list(corners.values())), board_points(BOARD_ROWS, BOARD_COLS, SQUARE_M),
                                 start, config=BoardFitConfig(distortion=True))


def cropped(model: UnifiedModel, rim: tuple[np.ndarray, float]) -> tuple[UnifiedModel, tuple[int, int]]:
    """The model of a square crop about the rim, and the crop's top-left ``(row, col)``."""
    half = int(np.ceil(rim[1])) + CROP_MARGIN_PX
    top, left = (int(round(v)) - half for v in rim[0])
    if top < 0 or left < 0 or top + 2 * half > model.height or left + 2 * half > model.width:
        raise InputError("the images", f"the rim (radius {rim[1]:.0f} px) does not fit inside the image")
    (pu, pv), side = model.principal_point, 2 * half
    return UnifiedModel(model.xi, model.focal, (pu - left, pv - top), (side, side), model.distortion), (top, left)


def masked_photo(image: np.ndarray, corner: tuple[int, int], side: int,
                 rim: tuple[np.ndarray, float], reflection: tuple[np.ndarray, float]) -> np.ndarray:
    """(side, side) uint8 crop of ``image`` from ``corner``, black beyond the rim and inside the reflection."""
    top, left = corner
    crop = image[top:top + side, left:left + side].copy()
    rows, cols = np.mgrid[0:side, 0:side].astype(np.float64)
    offset = np.array([top, left], dtype=np.float64)
    from_rim = np.hypot(rows - (rim[0][0] - offset[0]), cols - (rim[0][1] - offset[1]))
    from_reflection = np.hypot(rows - (reflection[0][0] - offset[0]), cols - (reflection[0][1] - offset[1]))
    crop[(from_rim > rim[1] - MASK_MARGIN_PX) | (from_reflection < reflection[1] + MASK_MARGIN_PX)] = 0
    return crop


def calibration_report(fit: BoardCalibration, names: list[str], rim, reflection, model: UnifiedModel) -> str:
    """Text of ``calibration.txt``: the fit's errors per image, the circles, the written camera."""
    lines = [f"unified model (Kalibr omni, radtan) fitted to {len(names)} checkerboard images "
             f"({BOARD_ROWS}x{BOARD_COLS} inner corners, {SQUARE_M * 1000:g} mm squares)",
             f"RMS reprojection error {fit.rms_px:.3f} px; solver converged: {fit.success}",
             f"full image: xi {fit.model.xi:.5f}, focal {fit.model.focal[0]:.3f} {fit.model.focal[1]:.3f} px, "
             f"principal point (col, row) {fit.model.principal_point[0]:.3f} {fit.model.principal_point[1]:.3f}, "
             f"radtan {' '.join(f'{c:.6g}' for c in fit.model.distortion)}",
             f"rim: centre (row, col) {rim[0][0]:.1f} {rim[0][1]:.1f}, radius {rim[1]:.1f} px; "
             f"reflection: centre {reflection[0][0]:.1f} {reflection[0][1]:.1f}, radius {reflection[1]:.1f} px",
             f"camera.yaml: the {model.height}x{model.width} crop about the rim", "per image RMS (px):"]
    lines += [f"  {name} {rms:.3f}" for name, rms in zip(names, fit.per_view_rms_px)]
    return "\n".join(lines) + "\n"


def _source_note(photos: list[str]) -> str:
    return (f"{', '.join(photos)} come from the GitHub repository {REPOSITORY} at commit {COMMIT}\n"
            f"(data/img_para_NNN.pgm, the sample images of C. Mei's calibration toolbox), cropped about\n"
            f"the mirror's rim and black beyond it and inside the camera's reflection. The repository\n"
            f"states no licence: do not redistribute. camera.yaml was fitted here to the images'\n"
            f"checkerboards (calibration.txt).\n")


def _write(out: Path, images, fit: BoardCalibration, names, rim, reflection, photos: list[int]) -> str:
    model, corner = cropped(fit.model, rim)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for number in photos:
        name = f"img_para_{number:03d}.pgm"
        photo = masked_photo(images[name], corner, model.width, rim, reflection)
        written.append(f"photo_{number:03d}.png")
        atomic_write_bytes(out / written[-1], cv2.imencode(".png", photo)[1].tobytes())
    write_kalibr(out / "camera.yaml", model)
    atomic_write_text(out / "calibration.txt", calibration_report(fit, names, rim, reflection, model))
    atomic_write_text(out / "SOURCE.txt", _source_note(written))
    return ", ".join(written)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir")
    parser.add_argument("--images", help="a folder holding img_para_001.pgm ... img_para_010.pgm (no download)")
    parser.add_argument("--photos", type=int, nargs="+", default=[1, 7, 10], choices=range(1, 11),
                        metavar="N", help="images to write as warp sources (1-10; default 1 7 10)")
    args = parser.parse_args(argv)

    def work() -> str:
        images = read_images(Path(args.images) if args.images else None)
        corners = detect_corners(images)
        if len(corners) < 2:
            raise InputError("the images", f"the board was found in {len(corners)} image(s); at least 2 needed")
        rim, reflection = mirror_circles(images)
        fit = calibrate(corners, rim, next(iter(images.values())).shape)
        written = _write(Path(args.out_dir), images, fit, list(corners), rim, reflection, args.photos)
        return (f"{args.out_dir}: {written}, camera.yaml (unified model fitted to {len(corners)} board images, "
                f"RMS {fit.rms_px:.3f} px), calibration.txt, SOURCE.txt")

    return status_of(work)

if __name__ == "__main__":
    sys.exit(main())
