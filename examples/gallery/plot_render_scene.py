"""
Render a scene: frames and depth
================================

Render four frames of the office scene at 96 x 96 pixels with per-pixel depth,
then show the images and the depth maps. A render this small takes seconds;
``omnisim render scenes/office.toml --out DIR --frames 4 --resolution 96
--spp 4 --aov depth`` does the same from the command line.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

import omnisim

# The repository root: this folder or one above it (examples run from the root or from here).
ROOT = next(p for p in (Path.cwd(), *Path.cwd().parents) if (p / "scenes").is_dir())
out = Path(tempfile.mkdtemp()) / "office"

result = omnisim.render(ROOT / "scenes" / "office.toml", out, frames=4, resolution=96, spp=4,
                        aovs="depth")
print(f"{result.frames} frames, {result.seconds_per_frame:.2f} s per frame")

# %%
# The dataset folder holds the images, the calibration, the exact ground truth
# and, asked for with ``aovs``, the distance along every pixel's ray in metres
# (NaN where the ray hits nothing, also outside the mirror band).

fig, axes = plt.subplots(2, 4, figsize=(10, 5.2))
for k in range(4):
    image = np.asarray(Image.open(out / "images" / f"{k:06d}.png"))
    depth = np.load(out / "depth" / f"{k:06d}.npy")
    axes[0, k].imshow(image)
    axes[0, k].set_title(f"frame {k}")
    shown = axes[1, k].imshow(depth, cmap="viridis")
    axes[1, k].set_title("depth [m]")
for ax in axes.ravel():
    ax.set_axis_off()
fig.colorbar(shown, ax=axes[1, :].tolist(), shrink=0.8)
plt.show()

# %%
# The ground truth: one TUM line per frame, the orientation ``R_0k`` of frame
# ``k`` in frame 0's coordinates.

print((out / "groundtruth.txt").read_text().splitlines()[-1])
