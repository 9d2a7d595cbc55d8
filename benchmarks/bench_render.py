"""Render speed of the omni sensor against Mitsuba's built-in perspective sensor.

Both sensors sit in the same scene with the same film size, box filter,
sampler and spp, and are rendered alternately in one process after a warm-up
(JIT compilation excluded). Two scenes: the office (scenes/office.toml) and a
uniform emitting sphere around the camera, where every ray costs the same.
Printed: seconds per frame for each sensor and their ratio (target <= 1.05). The ratio that measures the
sensor is taken with the omni sensor given a pinhole calibration (pol = (-f,))
and the perspective camera's pose, so both trace identical rays; the
catadioptric calibration (all pixels, or its mirror band only) sees a
different part of the scene and is printed for information. Also printed:
the seconds per 512x512 office frame at 16 spp as the dataset renderer runs
it (target < 1.5 s on 2 cores).

Run: python benchmarks/bench_render.py [--resolution 512] [--spp 16] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _time(render, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        render()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "office.toml"))
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    from ifmi.geometry.camera import OcamModel
    from omnisim.config import load_scene_config
    from omnisim.llvm import import_mitsuba
    from omnisim.scene import build_scene_dict
    from omnisim.sensor import register_omni_sensor, sensor_dict, to_world_matrix

    config = load_scene_config(args.scene, spp=args.spp, resolution=args.resolution)
    mi = import_mitsuba(config.render.variant or None)
    register_omni_sensor(mi)
    cam = config.camera
    size = args.resolution
    pose = to_world_matrix(np.eye(3), config.trajectory.position)

    def omni(radius_min, radius_max):
        return sensor_dict(cam.model, to_world=pose, radius_min=radius_min, radius_max=radius_max,
                           spp=args.spp, sampler=config.render.sampler, mi=mi)

    origin = np.asarray(config.trajectory.position, dtype=np.float64)
    perspective = {
        "type": "perspective", "fov": 90.0, "fov_axis": "x",
        "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(),
                                                   target=(origin + [1.0, 0.0, 0.0]).tolist(),
                                                   up=[0, 0, 1]),
        "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                 "pixel_format": "rgb"},
        "sampler": {"type": config.render.sampler, "sample_count": args.spp},
    }
    # The OCamCalib model with pol = (-f,) is a pinhole camera looking along -z.
    # Posed so that -z is the perspective camera's viewing direction (world +x),
    # rows point down (world -z) and columns right (world -y), the omni sensor
    # traces exactly the perspective camera's rays: the timing difference is
    # the sensor's own cost, in the real scene.
    focal = size / 2.0  # 90 degree horizontal field of view
    pinhole = OcamModel(pol=(-focal,), invpol=(focal,), center=((size - 1) / 2.0, (size - 1) / 2.0),
                        size=(size, size))
    pinhole_pose = to_world_matrix(np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]]), origin)
    same_view = sensor_dict(pinhole, to_world=pinhole_pose, radius_min=0.0, radius_max=float("inf"),
                            spp=args.spp, sampler=config.render.sampler, mi=mi)
    sensors = {"omni, pinhole calib": same_view,
               "omni, catadioptric, all px": omni(0.0, float("inf")),
               "omni, catadioptric, band": omni(cam.radius_min, cam.radius_max),
               "perspective (built-in)": perspective}
    office = build_scene_dict(config, mi, sensor=same_view)
    # Every ray of either camera hits the same emitting diffuse sphere, so the
    # cost per ray is the same and the ratio isolates the sensor's own cost.
    uniform = {"type": "scene", "integrator": {"type": "path", "max_depth": config.render.max_depth},
               "sensor": same_view,
               "shell": {"type": "sphere", "radius": 20.0, "flip_normals": True,
                         "center": list(config.trajectory.position),
                         "bsdf": {"type": "diffuse"},
                         "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}}}
    for label, base in (("office scene", office), ("uniform sphere", uniform)):
        base = dict(base)
        for k, (name, entry) in enumerate(sensors.items()):
            base["sensor" if k == 0 else f"sensor_{k}"] = entry
        scene = mi.load_dict(base)
        handles = scene.sensors()

        def render(index, scene=scene, handles=handles):
            return np.array(mi.render(scene, sensor=handles[index], spp=args.spp, seed=1))

        for index in range(len(sensors)):  # warm-up: compile each kernel once
            render(index)
            render(index)
        seconds = {index: [] for index in range(len(sensors))}
        for _ in range(args.repeats):
            for index in seconds:
                start = time.perf_counter()
                render(index)
                seconds[index].append(time.perf_counter() - start)
        med = {index: statistics.median(v) for index, v in seconds.items()}
        # Same rays, so the two images agree up to sampling noise.
        same, persp = render(0), render(3)
        image_diff = np.abs(same - persp).mean() / max(np.abs(persp).mean(), 1e-12)
        print(f"{label}: {size}x{size}, {args.spp} spp, variant {mi.variant()}, "
              f"max_depth {config.render.max_depth}, median of {args.repeats} frames")
        for index, name in enumerate(sensors):
            print(f"  {name:28s} {med[index]:.3f} s/frame")
        print(f"  ratio omni (same rays as perspective) / perspective: {med[0] / med[3]:.3f}   (target <= 1.05); "
              f"relative image difference {image_diff:.4f}")
        print(f"  ratio omni catadioptric (all pixels / band) / perspective: "
              f"{med[1] / med[3]:.3f} / {med[2] / med[3]:.3f}   (different view, for information)")

    # As the dataset renderer runs: pose set through traverse, then render.
    from omnisim.renderer import OmniRenderer
    from omnisim.motion import poses_for_settings

    renderer = OmniRenderer(config)
    poses = poses_for_settings(config.trajectory, seed=config.layout_seed)
    renderer.render(poses.rotations[0], poses.positions[0], seed=0)
    times = []
    for k in range(1, args.repeats + 1):
        start = time.perf_counter()
        renderer.render(poses.rotations[k], poses.positions[k], seed=k)
        times.append(time.perf_counter() - start)
    print(f"office dataset frame {size}x{size} at {args.spp} spp: {statistics.median(times):.3f} s/frame "
          f"(target < 1.5 s on 2 cores)")


if __name__ == "__main__":
    main()
