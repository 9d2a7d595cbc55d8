"""
Your own front end
==================

Plug a method of your own into the same back end, odometry and evaluation as
the built-in ones. A front end is a factory ``factory(model, config)``
returning an object with ``prepare(image)`` and
``correspondences(state_a, state_b)``; ``examples/sift_plugin.py`` is one
(SIFT keypoints through OpenCV). Name it ``package.module:factory``:

.. code-block:: bash

    PYTHONPATH=examples ifmi estimate DATA --method sift_plugin:sift_front_end --out est/sift.txt
"""

import sys
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

import ifmi
from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence, write_synthetic_dataset

# The repository root: this folder or one above it (examples run from the root or from here).
ROOT = next(p for p in (Path.cwd(), *Path.cwd().parents) if (p / "scenes").is_dir())
sys.path.insert(0, str(ROOT / "examples"))  # makes sift_plugin importable, as PYTHONPATH=examples does

model = example_omni_model(256)
sequence = synthetic_sequence(model, 10, seed=8, band_px=example_band_px(model), noise_std=2.0)
dataset = write_synthetic_dataset(Path(tempfile.mkdtemp()) / "synthetic", sequence)

runs = {}
for method in ("ifmi", "sift_plugin:sift_front_end"):
    estimate = ifmi.estimate(dataset, method=method)
    runs[method] = (estimate, ifmi.evaluate(dataset / "groundtruth.txt", estimate))
    print(f"{method}: ATE {runs[method][1].ate_rad:.2e} rad, {estimate.failed} failed frames")

# %%
# The shared back end keeps the inliers of each pair; ``frames.csv`` (here
# ``Estimate.table()``) carries any diagnostics a front end returns, such as
# the plugin's ``n_matches``.

fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.6))
for method, (estimate, errors) in runs.items():
    table = estimate.table()
    left.plot(table["frame"][1:], table["n_inliers"][1:], ".-", label=method)
    right.plot(errors.per_frame["timestamp"], errors.per_frame["geodesic_error"], ".-", label=method)
left.set_xlabel("frame")
left.set_ylabel("inliers")
right.set_xlabel("frame")
right.set_ylabel("geodesic error [rad]")
left.legend()
fig.tight_layout()
plt.show()
