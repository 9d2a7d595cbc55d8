"""Scene files of the omnisim tests: the shared 128x128 catadioptric camera and writing a scene."""

from __future__ import annotations

from pathlib import Path

# The catadioptric calibration of the 128x128 test renders (mirror band 10..61.5 px).
_CAMERA_128_LINES = (
    "pol = [-20.0, 0.0, 1.28e-2, -1.76e-5, 2.56e-7]",
    "center = [64.35, 63.3]",
    "size = [128, 128]",
    "radius_min = 10.0",
    "radius_max = 61.5",
)
# A slightly skewed sensor; without it the camera has the ideal affine part (1, 0, 0).
_SKEWED_AFFINE = "affine = [1.0012, 0.0021, -0.0017]"


def camera_128_section(*, skewed: bool = True) -> str:
    """The ``[camera]`` table of the 128x128 test camera, one key a line, ending in a newline.

    ``skewed`` adds the skewed sensor's ``affine`` line after ``center``.
    """
    lines = list(_CAMERA_128_LINES)
    if skewed:
        lines.insert(2, _SKEWED_AFFINE)
    return "\n".join(["[camera]", *lines]) + "\n"


def write_scene(folder: Path, text: str, name: str = "scene.toml") -> Path:
    """Write scene-file ``text`` as ``folder / name`` and return its path."""
    path = Path(folder) / name
    path.write_text(text)
    return path
