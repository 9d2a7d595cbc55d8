"""Physical mirror mode (orthographic camera + paraboloid mirror) agrees with the omni sensor."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None:
    pytest.skip("mitsuba is not installed (sim extra)", allow_module_level=True)

from ifmi.geometry.camera import OcamModel, paracatadioptric_model, radius_from_pixels
from ifmi.geometry.rotations import matrix_from_rpy

pytestmark = pytest.mark.render

SIZE = 128
SPP = 32


def test_mirror_mode_rejects_non_paraboloid_model():
    from omnisim.mirror import horizon_radius_from_model

    model = OcamModel(pol=(-20.0, 0.0, 0.01, 1e-5), invpol=(1.0,), center=(64, 64), size=(128, 128))
    with pytest.raises(ValueError, match="paraboloid"):
        horizon_radius_from_model(model)
    assert horizon_radius_from_model(paracatadioptric_model((64, 64), horizon_radius_px=20.0)) == pytest.approx(20.0)


def test_mirror_render_matches_sensor_render(tmp_path):
    """Images through the physical mirror equal the sensor's up to Monte-Carlo noise.

    The difference between mirror and sensor renders (same scene, pose and
    spp, blurred lightly) must be no larger than between two sensor renders
    with different seeds (the noise floor; measured 0.00127 vs 0.00133), and
    well below the change a 1 degree rotation makes (0.0040).
    """
    import cv2

    sys.path.insert(0, str(Path(__file__).parent))
    from test_omnisim_dataset import _scene

    from omnisim.config import load_scene_config
    from omnisim.llvm import import_mitsuba
    from omnisim.mirror import mirror_scene_entries
    from omnisim.scene import build_scene_dict
    from omnisim.sensor import register_omni_sensor, sensor_dict, to_world_matrix

    mi = import_mitsuba()
    register_omni_sensor(mi)
    config = load_scene_config(_scene(tmp_path, spp=SPP))
    model = paracatadioptric_model((SIZE, SIZE), horizon_radius_px=38.0, center=(64.3, 62.8),
                                   affine=(1.003, 0.004, -0.003))
    rotation = matrix_from_rpy(np.radians([5.0, -8.0, 30.0]))
    position = np.array([0.3, -0.2, 1.3])

    def render(pose, *, mirror, seed):
        entry = sensor_dict(model, to_world=pose, radius_min=0.0, radius_max=60.0, spp=SPP, mi=mi)
        scene = build_scene_dict(config, mi, sensor=entry)
        if mirror:
            scene.update(mirror_scene_entries(model, to_world=pose, radius_max=60.0, spp=SPP, mi=mi))
            scene["integrator"]["max_depth"] += 1  # the mirror adds one specular bounce
        image = np.array(mi.render(mi.load_dict(scene, parallel=False), seed=seed))[..., :3]
        return cv2.GaussianBlur(image.mean(axis=-1).astype(np.float32), (0, 0), 1.0)

    pose = to_world_matrix(rotation, position)
    sensor_a = render(pose, mirror=False, seed=1)
    sensor_b = render(pose, mirror=False, seed=2)
    mirror = render(pose, mirror=True, seed=1)
    turned = render(to_world_matrix(rotation @ matrix_from_rpy(np.radians([0.0, 0.0, 1.0])), position),
                    mirror=False, seed=1)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    radius = radius_from_pixels(model, np.stack([rows, cols], axis=-1))
    band = (radius > 8.0) & (radius < 58.0)
    mirror_err = np.abs(mirror - sensor_a)[band].mean()
    noise_floor = np.abs(sensor_b - sensor_a)[band].mean()
    rotation_err = np.abs(turned - sensor_a)[band].mean()
    assert mirror_err < 1.2 * noise_floor, (mirror_err, noise_floor)
    assert mirror_err < 0.5 * rotation_err, (mirror_err, rotation_err)
