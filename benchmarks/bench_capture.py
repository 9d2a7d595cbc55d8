"""Render cost of motion blur and rolling shutter against the sharp (instantaneous) capture.

One process loads the scene four times -- sharp, motion blur (exposure 0.5),
rolling shutter (readout 0.3), both -- and renders the same frames of the
scene's trajectory with each, in turn (order reversed every other round), at
the same spp, after a warm-up (JIT compilation excluded). Printed: the median seconds per frame of each and
its ratio to the sharp capture (target <= 1.1). A timed capture traces one
ray per sample like the sharp one; the extra cost is the per-ray time sample
and pose interpolation in the sensor.

Run: python benchmarks/bench_capture.py [--scene scenes/office.toml] [--resolution 256] [--spp 16] [--repeats 9]
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "office.toml"))
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()

    from omnisim.config import CaptureSettings, load_scene_config
    from omnisim.motion import poses_for_settings
    from omnisim.renderer import OmniRenderer

    config = load_scene_config(args.scene, spp=args.spp, resolution=args.resolution, frames=args.repeats + 2)
    poses = poses_for_settings(config.trajectory, seed=config.layout_seed)
    captures = {"sharp": CaptureSettings(),
                "motion blur (exposure 0.5)": CaptureSettings(exposure=0.5),
                "rolling shutter (readout 0.3)": CaptureSettings(rolling_shutter=0.3),
                "both": CaptureSettings(exposure=0.5, rolling_shutter=0.3)}
    renderers = {name: OmniRenderer(replace(config, capture=capture)) for name, capture in captures.items()}

    def render(renderer, k):
        end = (poses.rotations[k + 1], poses.positions[k + 1])
        return renderer.render(poses.rotations[k], poses.positions[k], seed=k, end=end)

    for renderer in renderers.values():  # warm-up: compile each kernel once
        render(renderer, 0)
    wall = {name: [] for name in renderers}
    cpu = {name: [] for name in renderers}
    for k in range(1, args.repeats + 1):
        # Alternate the order, so that no capture always runs first or last in a round.
        for name, renderer in (list(renderers.items()) if k % 2 else list(renderers.items())[::-1]):
            start, start_cpu = time.perf_counter(), time.process_time()
            render(renderer, k)
            wall[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
    print(f"{config.name}: {args.resolution}x{args.resolution}, {args.spp} spp, "
          f"variant {renderers['sharp'].variant}, median of {args.repeats} frames; CPU time = all threads of "
          "this process (steadier than wall time when other processes share the cores)")
    for label, seconds in (("wall", wall), ("CPU", cpu)):
        median = {name: statistics.median(v) for name, v in seconds.items()}
        for name, value in median.items():
            print(f"  {label:4s} {name:32s} {value:.3f} s/frame   ratio to sharp {value / median['sharp']:.3f}"
                  f"{'   (target <= 1.1)' if name != 'sharp' else ''}")


if __name__ == "__main__":
    main()
