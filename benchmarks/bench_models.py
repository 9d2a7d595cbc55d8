"""Every camera model: render cost against Mitsuba's perspective sensor, and the estimator's ATE.

Render ratio: each model's sensor (omnicam, with the model's drjit ray code)
and the built-in perspective sensor render the same scene with the same film
size (the model's image size), box filter, sampler and spp, in one process
after a warm-up (JIT compilation excluded). The two interleave as
P M P M ... P over ``--rounds`` rounds; each model frame is divided by the
mean of the perspective frames on either side of it (which cancels a load
that drifts linearly), and printed are the median of those ratios and
their interquartile range, in process CPU time (all render threads; on a
shared machine it leaves out the time other processes hold the cores) and
in wall time. The target (<= 1.05) applies to the median CPU-time ratio; a
ratio whose interquartile range straddles 1.05 is not resolved by the run. Two scenes: a uniform emitting sphere
around the camera, where every traced ray costs the same, so the ratio
isolates the sensor's own cost (pixels outside a model's valid region are
not traced and cost less; their share is printed); and the urban scene
(scenes/urban.toml), for information, where the two cameras see different
parts of the scene. A distortion-free Kalibr pinhole posed like the
perspective camera traces exactly its rays (same-rays row).

Ray generation: the cost of each sensor's ``sample_ray`` alone, per million
rays, against the perspective sensor's (no scene): one render's film samples
in a render's order (pixel by pixel, ``--spp`` jittered samples each), on
one thread, CPU time, the two sensors alternating; fastest of ``--rounds``.

ATE: for each model a scene (default the urban one, ``--scene``) is rendered with ``[camera] kalibr`` (a
pure-rotation sequence, the camera mounted as omnisim mounts that model),
estimated with ``ifmi estimate`` (ifmi, orb, akaze), and the geodesic ATE
(RMS of the geodesic angle of R_gt^T R_est over the frames, radians) is printed.

Run: python benchmarks/bench_models.py [--width 384] [--spp 16] [--frames 12] [--rounds 15]
     [--out DATA/cameras/bench] [--skip-ate]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from camera_examples import EXAMPLES  # noqa: E402  (the example calibrations of the tests)

# Models benchmarked: every Kalibr model and the equirectangular camera.
MODELS = ("omni-radtan", "omni-wide", "pinhole-radtan", "eucm", "ds", "kb", "equirectangular")
# A distortion-free Kalibr pinhole posed like the perspective camera: exactly its rays.
SAME_RAYS = "pinhole, same rays"


def _frame_seconds(mi, scene, sensor, spp: int) -> tuple[float, float]:
    """(CPU, wall) seconds of one rendered frame, read back to the host."""
    cpu, wall = time.process_time(), time.perf_counter()
    np.array(mi.render(scene, sensor=sensor, spp=spp, seed=1))
    return time.process_time() - cpu, time.perf_counter() - wall


def _time_ratios(mi, scene, spp: int, rounds: int) -> dict:
    """Sensor 0 (model) over sensor 1 (perspective): ratio quartiles in CPU and wall time.

    The sensors interleave P M P M ... P; each model frame is divided by the
    mean of its two neighbouring perspective frames.
    """
    model, perspective = scene.sensors()[:2]
    for sensor in (model, perspective):  # warm-up: compile each kernel
        for _ in range(2):
            _frame_seconds(mi, scene, sensor, spp)
    before = np.array(_frame_seconds(mi, scene, perspective, spp))
    ratios = []
    for _ in range(rounds):
        frame = np.array(_frame_seconds(mi, scene, model, spp))
        after = np.array(_frame_seconds(mi, scene, perspective, spp))
        ratios.append(frame / (0.5 * (before + after)))
        before = after
    quartiles = np.percentile(np.array(ratios), [25, 50, 75], axis=0)
    return {"cpu": tuple(quartiles[:, 0]), "wall": tuple(quartiles[:, 1])}


def _quartile_text(q) -> str:
    return f"{q[1]:.3f} [{q[0]:.3f}-{q[2]:.3f}]"


def _perspective(mi, size, spp, sampler, origin, fov_deg=90.0) -> dict:
    height, width = size
    return {"type": "perspective", "fov": fov_deg, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=list(origin), target=list(origin + [1.0, 0, 0]),
                                                       up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": {"type": sampler, "sample_count": spp}}


def _benchmark_models(width: int) -> dict:
    """The example models at ``width`` px, and a distortion-free pinhole with the perspective camera's rays."""
    from ifmi.geometry.camera_models import PinholeModel

    models = {name: EXAMPLES[name].scaled(width / EXAMPLES[name].width) for name in MODELS}
    size = models["pinhole-radtan"].size
    f = size[1] / 2.0  # 90 degrees across the width, as the perspective camera
    models[SAME_RAYS] = PinholeModel.create((f, f), ((size[1] - 1) / 2, (size[0] - 1) / 2), size)
    return models


def render_ratios(args) -> dict:
    """Median render time ratio model / perspective per model, in the uniform sphere and the urban scene."""
    from ifmi.geometry.camera import valid_mask
    from omnisim.config import load_scene_config
    from omnisim.llvm import import_mitsuba
    from omnisim.scene import build_scene_dict
    from omnisim.sensor import register_omni_sensor, sensor_dict, to_world_matrix

    config = load_scene_config(ROOT / "scenes" / "urban.toml", spp=args.spp)
    mi = import_mitsuba(config.render.variant or None)
    register_omni_sensor(mi)
    origin = np.asarray(config.trajectory.position, dtype=np.float64)
    # Kalibr frame looking along world +x with image rows down: x -> -y_w, y -> -z_w, z -> +x_w.
    forward = to_world_matrix(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), origin)
    models = _benchmark_models(args.width)
    ratios = {}
    for name, model in models.items():
        if args.ratio_models and name not in args.ratio_models:
            continue
        sensors = [sensor_dict(model, to_world=forward, radius_min=0.0, radius_max=float("inf"), spp=args.spp,
                               sampler=config.render.sampler, mi=mi),
                   _perspective(mi, model.size, args.spp, config.render.sampler, origin)]
        shell = {"type": "sphere", "radius": 20.0, "flip_normals": True, "center": origin.tolist(),
                 "bsdf": {"type": "diffuse"},
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}}
        uniform = {"type": "scene", "integrator": {"type": "path", "max_depth": config.render.max_depth},
                   "sensor": sensors[0], "sensor_1": sensors[1], "shell": shell}
        urban = dict(build_scene_dict(config, mi, sensor=sensors[0]), sensor_1=sensors[1])
        row = {"valid": float(valid_mask(model).mean())}
        for label, scene_dict in (("uniform", uniform), ("urban", urban)):
            row[label] = _time_ratios(mi, mi.load_dict(scene_dict), args.spp, args.rounds)
        ratios[name] = row
        print(f"  {name:22s} {model.width}x{model.height}: render ratio model/perspective, median "
              f"[quartiles] of {args.rounds}: uniform sphere CPU {_quartile_text(row['uniform']['cpu'])}, wall "
              f"{_quartile_text(row['uniform']['wall'])}; urban (different view) CPU "
              f"{_quartile_text(row['urban']['cpu'])}, wall {_quartile_text(row['urban']['wall'])}; "
              f"valid pixels {100 * row['valid']:.0f} %", flush=True)
    return ratios


def _film_samples(size, spp: int, rng) -> np.ndarray:
    """(2, H*W*spp) film samples in a render's order: pixel by pixel (rows, then columns), jittered."""
    height, width = size
    pixel = np.repeat(np.arange(height * width), spp)
    cols = (pixel % width + rng.random(pixel.size)) / width
    rows = (pixel // width + rng.random(pixel.size)) / height
    return np.stack([cols, rows]).astype(np.float32)


def ray_costs(args) -> dict:
    """CPU seconds per million camera rays of each sensor's ``sample_ray`` alone, over the perspective sensor's.

    One frame's film samples (render order) go through each sensor and are
    evaluated (``dr.eval``) on one thread, the sensors alternating, fastest
    of ``rounds``: the sensor's own cost, with no scene to trace.
    """
    from omnisim.llvm import import_mitsuba
    from omnisim.sensor import register_omni_sensor, sensor_dict

    mi = import_mitsuba()  # selects drjit's LLVM before drjit is first imported
    import drjit as dr
    register_omni_sensor(mi)
    rng = np.random.default_rng(0)
    threads = dr.thread_count()
    dr.set_thread_count(1)  # one thread: the least disturbed by other processes
    results = {}
    try:
        for name, model in _benchmark_models(args.width).items():
            if args.ratio_models and name not in args.ratio_models:
                continue
            sensors = [mi.load_dict(sensor_dict(model, to_world=np.eye(4), radius_min=0.0,
                                                radius_max=float("inf"), spp=1, mi=mi)),
                       mi.load_dict(_perspective(mi, model.size, 1, "independent", np.zeros(3)))]
            samples = _film_samples(model.size, args.spp, rng)
            sample2 = mi.Point2f(samples[0], samples[1])
            seconds = [[], []]
            for k in range(args.rounds + 2):
                for index, sensor in enumerate(sensors):
                    start = time.process_time()
                    ray, weight = sensor.sample_ray(0.0, 0.5, sample2, mi.Point2f(0.5, 0.5))
                    dr.eval(ray, weight)
                    dr.sync_thread()
                    if k >= 2:  # the first two compile
                        seconds[index].append(time.process_time() - start)
            per_million = [1e6 * min(t) / samples.shape[1] for t in seconds]
            results[name] = per_million[0] / per_million[1]
            print(f"  {name:22s} ray generation: {1e3 * per_million[0]:.2f} ms per million rays, perspective "
                  f"{1e3 * per_million[1]:.2f} ms: ratio {results[name]:.2f}", flush=True)
    finally:
        dr.set_thread_count(threads)
    return results


def estimator_ates(args) -> dict:
    """Geodesic ATE (rad) of ifmi, orb and akaze per model on a rendered urban sequence."""
    from ifmi.io.tum import read_tum
    from ifmi.evaluation.metrics import error_stats
    from ifmi.pipeline import estimate_dataset
    from ifmi.geometry.rotations import geodesic_angle
    from omnisim.config import write_scene_with_kalibr_camera
    from omnisim.renderer import render_dataset

    ates = {}
    for name in args.models:
        model = EXAMPLES[name]
        folder = Path(args.out) / f"{Path(args.scene).stem}-{name}-{args.width}px-{args.spp}spp"
        scene = write_scene_with_kalibr_camera(args.scene, model, folder)
        render_dataset(scene, folder / "dataset", frames=args.frames, spp=args.spp,
                       resolution=model.scaled(args.width / model.width).size, progress=False)
        gt = read_tum(folder / "dataset" / "groundtruth.txt")
        row = {}
        for method in ("ifmi", "orb", "akaze"):
            est = estimate_dataset(folder / "dataset", method=method)
            err = geodesic_angle(gt.rotations, est.trajectory.rotations)
            row[method] = (error_stats(err).rmse, sum(not r.success for r in est.frames))
        ates[name] = row
        print(f"  {name:22s} ATE (rad): " + ", ".join(f"{m} {a:.4f} ({f} failed)" for m, (a, f) in row.items()),
              flush=True)
    return ates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=384, help="image width of every model, px")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--rounds", type=int, default=15,
                        help="model frames per ratio (each between two perspective frames)")
    parser.add_argument("--out", default="out/bench_models", help="folder for the rendered datasets")
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "urban.toml"),
                        help="scene of the ATE sequences (its [camera] table is replaced)")
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS,
                        help="models of the ATE sequences")
    parser.add_argument("--ratio-models", nargs="+", default=None, choices=[*MODELS, SAME_RAYS],
                        help="models of the render and ray-generation ratios (default: all)")
    parser.add_argument("--skip-render-ratio", action="store_true")
    parser.add_argument("--skip-ate", action="store_true")
    args = parser.parse_args()
    print(f"camera models at {args.width} px width, {args.spp} spp")
    ratios = {} if args.skip_render_ratio else render_ratios(args)
    if not args.skip_render_ratio:
        ray_costs(args)
    ates = {} if args.skip_ate else estimator_ates(args)
    print(f"\nsummary ({args.frames} frames, {Path(args.scene).stem} scene, pure rotation):")
    print(f"  {'model':22s} {'ratio (uniform)':>16s} {'ratio (urban)':>14s} {'ifmi ATE rad':>13s} "
          f"{'orb ATE rad':>12s} {'akaze ATE rad':>14s}   (ratios: median CPU-time ratio)")
    for name in dict.fromkeys([*ratios, *ates]):
        r, a = ratios.get(name, {}), ates.get(name, {})
        cells = [f"{r[k]['cpu'][1]:16.3f}" if k in r else f"{'-':>16s}" for k in ("uniform",)]
        cells += [f"{r['urban']['cpu'][1]:14.3f}" if "urban" in r else f"{'-':>14s}"]
        cells += [f"{a[m][0]:{w}.4f}" if m in a else f"{'-':>{w}s}" for m, w in (("ifmi", 13), ("orb", 12),
                                                                                 ("akaze", 14))]
        print(f"  {name:22s} " + " ".join(cells))
    print("target: render ratio <= 1.05; ATE < 0.01 rad")


if __name__ == "__main__":
    main()
