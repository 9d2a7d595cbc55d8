"""
Compare methods
===============

Run iFMI, ORB and AKAZE on the same frames: each front end turns the frame
pairs into ray correspondences and the same relative-pose back end and
odometry make the trajectory, so the comparison isolates the front end.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import ifmi
from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence, write_synthetic_dataset

model = example_omni_model(256)
sequence = synthetic_sequence(model, 12, seed=5, band_px=example_band_px(model), noise_std=2.0,
                              max_step_rad=0.04)
dataset = write_synthetic_dataset(Path(tempfile.mkdtemp()) / "synthetic", sequence)

results = {}
for method in ("ifmi", "orb", "akaze"):
    estimate = ifmi.estimate(dataset, method=method)
    results[method] = (estimate, ifmi.evaluate(dataset / "groundtruth.txt", estimate))
    print(f"{method:6s} ATE {results[method][1].ate_rad:.2e} rad, failed {estimate.failed}")

# %%
# Geodesic error over the sequence and the ATE of each method (log scale).
# Times are wall time per frame on the machine that built these pages.

fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8))
for method, (estimate, errors) in results.items():
    left.semilogy(errors.per_frame["timestamp"], np.maximum(errors.per_frame["geodesic_error"], 1e-6),
                  ".-", label=method)
left.set_xlabel("frame")
left.set_ylabel("geodesic error [rad]")
left.legend()
names = list(results)
right.bar(names, [results[m][1].ate_rad for m in names], color=["tab:blue", "tab:orange", "tab:green"])
right.set_yscale("log")
right.set_ylabel("geodesic ATE [rad]")
for k, m in enumerate(names):
    ms = 1e3 * np.median(results[m][0].table()["seconds"][1:])
    right.annotate(f"{ms:.0f} ms/frame", (k, results[m][1].ate_rad), ha="center", va="bottom", fontsize=8)
fig.tight_layout()
plt.show()
