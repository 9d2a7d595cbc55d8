"""A "photo-like" omni image made offline: scikit-image's bundled CC0 photographs on a sphere.

A stand-in for a real photo at any calibration (the one real catadioptric
photo found offline, ``benchmarks/real_omni_photo.py``, comes with its own
camera's calibration only): a mosaic of the photographs bundled with
scikit-image (CC0) mapped onto a sphere at infinity (:func:`ifmi.synthetic.environment_texture`, no added
noise) and imaged through CALIB, black outside the calibration's band. It
is sharp like a photo of real texture, but it is not a real photo: no real
optics, no real lighting. Feed it to ``omnisim warp``.

Usage::

    python benchmarks/photo_like_omni.py CALIB OUT.png [--seed S]
"""

from __future__ import annotations

import argparse
import sys

import cv2
import numpy as np

from ifmi.errors import OutputError
from ifmi.io.atomic import atomic_write_bytes
from ifmi.io.calib import read_calib
from ifmi.synthetic import environment_texture, omni_from_environment
from ifmi.spectral.panorama import PanoramaConfig, radius_band


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("calib")
    parser.add_argument("out")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    model = read_calib(args.calib)
    band = radius_band(model, config=PanoramaConfig(min_radius_fraction=0.25))
    # Texture rows: at least 1.5x the band's angular sampling, so the omni image is not blurred.
    height = 2 * int(np.ceil(1.5 * np.pi * band[1] / 2))
    texture = environment_texture(height=height, seed=args.seed, noise_level=0.0)
    image = omni_from_environment(texture, model, np.eye(3), band_px=band)
    try:
        atomic_write_bytes(args.out, cv2.imencode(".png", image)[1].tobytes())
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"{args.out}: {image.shape[0]}x{image.shape[1]}, band {band[0]:.1f}..{band[1]:.1f} px, "
          f"texture {height}x{2 * height}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
