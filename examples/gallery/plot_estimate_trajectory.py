"""
Estimate a trajectory and compare it with the ground truth
==========================================================

Estimate the orientation of every frame of a sequence with iFMI and plot
roll, pitch and yaw against the exact ground truth. The frames come from
:mod:`ifmi.synthetic` (a textured environment seen by a paracatadioptric
camera), written as a dataset folder exactly as ``omnisim render`` writes one.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial.transform import Rotation

import ifmi
from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence, write_synthetic_dataset

model = example_omni_model(256)
sequence = synthetic_sequence(model, 16, seed=2, band_px=example_band_px(model), noise_std=2.0)
dataset = write_synthetic_dataset(Path(tempfile.mkdtemp()) / "synthetic", sequence)

result = ifmi.estimate(dataset, method="ifmi")
errors = ifmi.evaluate(dataset / "groundtruth.txt", result)
print(f"geodesic ATE {errors.ate_rad:.2e} rad, failed frames {result.failed} of {len(result.frames)}")
print(errors.table())

# %%
# Roll, pitch and yaw (ZYX Euler angles) of the estimate and of the ground
# truth, and the per-frame geodesic error.


def rpy(rotations):
    yaw, pitch, roll = Rotation.from_matrix(rotations).as_euler("ZYX").T
    return np.degrees(np.stack([roll, pitch, yaw]))


truth, estimate = rpy(sequence.rotations), rpy(result.rotations)
fig, axes = plt.subplots(4, 1, figsize=(8, 8), sharex=True)
for axis, name in enumerate(("roll", "pitch", "yaw")):
    axes[axis].plot(result.timestamps, truth[axis], "k-", label="ground truth")
    axes[axis].plot(result.timestamps, estimate[axis], "o", ms=4, label="iFMI")
    axes[axis].set_ylabel(f"{name} [deg]")
axes[0].legend()
axes[3].plot(errors.per_frame["timestamp"], errors.per_frame["geodesic_error"], "r.-")
axes[3].set_ylabel("geodesic error [rad]")
axes[3].set_xlabel("frame")
fig.tight_layout()
plt.show()

# %%
# The per-frame table is what ``frames.csv`` holds: success, matches,
# inliers, time, and the rotation error the fit predicts.

print(result.table()[["frame", "success", "n_correspondences", "n_inliers", "rotation_sigma_rad"]])
