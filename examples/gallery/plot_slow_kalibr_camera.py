"""
Your own camera from a Kalibr file
==================================

Render and estimate with a camera described by a Kalibr camchain file: here
a double-sphere fisheye (``camera_model: ds``) as Kalibr writes it. The same
file serves ``omnisim`` (to render with your optics) and ``ifmi`` (to
estimate with them). From the command line: put ``kalibr = "camchain.yaml"``
in a copy of a scene's ``[camera]`` table, then ``omnisim render`` and
``ifmi estimate`` as for any dataset.

Rendering at 240 x 376 pixels takes the longest of the gallery (its name
starts with ``plot_slow_``, so ``DOCS_FAST=1 bash scripts/docs.sh`` skips it).
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

import ifmi
import omnisim
from ifmi.geometry.camera import rays_from_pixels
from omnisim.config import write_scene_with_kalibr_camera

# The repository root: this folder or one above it (examples run from the root or from here).
ROOT = next(p for p in (Path.cwd(), *Path.cwd().parents) if (p / "scenes").is_dir())
work = Path(tempfile.mkdtemp())

# A camchain file as Kalibr writes it (cam0; a double-sphere model of a 752 x 480 camera).
(work / "camchain.yaml").write_text("""\
cam0:
  camera_model: ds
  intrinsics: [-0.2, 0.59, 313.0, 314.0, 376.0, 240.0]
  distortion_model: none
  distortion_coeffs: []
  resolution: [752, 480]
""")
camera = ifmi.read_calibration(work / "camchain.yaml")
print(type(camera).__name__, camera.size)

# %%
# Render the urban scene with this camera, at half its size: the
# calibration is scaled to the resolution rendered.

scene = write_scene_with_kalibr_camera(ROOT / "scenes" / "urban.toml", camera, work / "scene")
dataset = work / "urban_ds"
omnisim.render(scene, dataset, frames=6, resolution=(240, 376), spp=4)
print(sorted(p.name for p in dataset.iterdir()))

# %%
# Frames as the fisheye sees them, and the angle of every pixel's ray from the
# optical axis (the model's valid region is where it is finite).

model = ifmi.read_calibration(dataset / "camera.yaml")
rows, cols = np.mgrid[0:model.size[0], 0:model.size[1]]
rays = rays_from_pixels(model, np.stack([rows.ravel(), cols.ravel()], axis=1).astype(float))
angle = np.degrees(np.arccos(np.clip(rays[:, 2], -1, 1))).reshape(model.size)

fig, axes = plt.subplots(1, 3, figsize=(11, 2.8))
for k, ax in zip((0, 5), axes[:2]):
    ax.imshow(np.asarray(Image.open(dataset / "images" / f"{k:06d}.png")))
    ax.set_title(f"frame {k}")
shown = axes[2].imshow(angle, cmap="magma")
axes[2].set_title("ray angle from the optical axis [deg]")
fig.colorbar(shown, ax=axes[2])
for ax in axes:
    ax.set_axis_off()
plt.show()

# %%
# Estimate with iFMI and compare with the ground truth, in the camera's own
# (Kalibr) frame.

result = ifmi.estimate(dataset)
errors = ifmi.evaluate(dataset / "groundtruth.txt", result)
print(f"geodesic ATE {errors.ate_rad:.2e} rad over {len(result.frames)} frames, {result.failed} failed")
