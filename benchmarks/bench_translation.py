"""Translation sweep: every method's ATE and model choice over translation per frame, depth and camera.

Sets: translation per frame (``--steps``, metres; 0 is pure rotation) x
scene depth (``--depths``: ``floor``, the urban scene with the camera 0.4 m above
the road; ``room``, the office at its 1.3 m; ``street``, the urban scene at
its 1.6 m) x camera (``--cameras``: ``ocamcalib``, the scenes' catadioptric
camera; ``ds``, a Kalibr double-sphere fisheye; ``kb``, a Kalibr
Kannala-Brandt equidistant fisheye; the Kalibr cameras look straight down, as
omnisim mounts them). Each set is rendered with omnisim from its scene file
(written into the set's folder) and estimated by every method (``--methods``:
ifmi, orb, akaze and the plain reference pipeline of
``benchmarks/reference_pipeline.py``) with the default model selection and
with each model forced (``rotation``, ``5pt``). Printed per set and method:
the geodesic ATE (RMS over the frames of the angle of ``R_gt^T R_est``,
radians) of each run and the share of pairs solved with each model; at the
end, how many runs meet each criterion of the sweep (the chosen model at most
1.5x the better forced run; ORB and AKAZE at most 1.25x the reference
pipeline; iFMI on the downward fisheyes at most a third of the best other
method and below 5 mrad).

Everything is seeded (scene seed, ``--seed`` for the motion and sampling,
the back end's RANSAC seeds). A 12-frame run's ATE depends on the RANSAC
draw: ``--ransac-seeds`` repeats every run with each seed and every figure
is then the median over them. Renders and estimates are kept in the folder
given on the command line (one ``result-METHOD-MODEL.json`` per run of
RANSAC seed 0, ``result-METHOD-MODEL-seedK.json`` for seed K), so an
interrupted sweep resumes where it stopped. The table is written as MyST
Markdown to ``--report`` with the command, date and machine.

Run: python benchmarks/bench_translation.py OUT [--width 384] [--frames 12] [--spp 8]
     [--steps 0 0.01 0.02 0.05 0.1 0.2] [--depths floor room street] [--cameras ocamcalib ds kb]
     [--ransac-seeds 0 1 2 3 4] [--report reports/translation_sweep/README.md]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from camera_examples import EXAMPLES  # noqa: E402  (the example calibrations of the tests)

STEPS_M = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2)
# Depth name -> (scene file, camera height above the floor in metres or None for the scene's own).
DEPTHS = {"floor": ("urban.toml", 0.4), "room": ("office.toml", None), "street": ("urban.toml", None)}
CAMERAS = ("ocamcalib", "ds", "kb")
METHODS = ("ifmi", "orb", "akaze", "reference")
# Model selection of each run: the default criterion and each model forced.
SELECTIONS = ("auto", "rotation", "5pt")
# Method name of the reference pipeline (a plugin by import path; benchmarks/ is on sys.path).
REFERENCE = "reference_pipeline:reference_front_end"
# Criteria the summary counts: a run with the model chosen is at most this multiple of the better
# forced run's ATE; ORB and AKAZE at most this multiple of the reference pipeline's; on the
# downward fisheyes iFMI at most this share of the best other method's ATE and below this ATE (rad).
FIXED_MODEL_RATIO = 1.5
REFERENCE_RATIO = 1.25
FISHEYE_SHARE = 1.0 / 3.0
FISHEYE_ATE_RAD = 0.005
# The walk of a translated set stays within this distance of the start, metres: large enough for
# every step of the sweep, small enough to keep the floor camera off the furniture.
TRANSLATION_RADIUS_M = 1.0


def set_name(depth: str, camera: str, step_m: float) -> str:
    """Folder name of one set, e.g. ``room-ds-5cm``."""
    return f"{depth}-{camera}-{round(100 * step_m):d}cm"


def _trajectory_lines(lines: list[str], *, height_m: float | None, step_m: float) -> list[str]:
    """The scene's lines with the ``[trajectory]`` position height and translation step replaced."""
    out, table = [], ""
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("["):
            table = stripped
        key = stripped.split("=")[0].strip() if "=" in stripped and not stripped.startswith("#") else ""
        if table == "[trajectory]" and key == "position" and height_m is not None:
            position = json.loads(stripped.split("=", 1)[1].split("#")[0])
            line = f"position = {json.dumps([position[0], position[1], height_m])}"
        elif table == "[trajectory]" and key in ("translation_step_m", "translation_radius_m"):
            continue
        out.append(line)
        if stripped == "[trajectory]":
            out += [f"translation_step_m = {step_m!r}", f"translation_radius_m = {TRANSLATION_RADIUS_M!r}"]
    return out


def write_set_scene(folder: Path, depth: str, camera: str, step_m: float) -> Path:
    """``folder/scene.toml`` of one set: the depth's scene with its camera and trajectory replaced."""
    from ifmi.io.atomic import atomic_write_text
    from omnisim.config import write_scene_with_kalibr_camera

    scene_name, height_m = DEPTHS[depth]
    source = ROOT / "scenes" / scene_name
    folder.mkdir(parents=True, exist_ok=True)
    if camera != "ocamcalib":
        source = write_scene_with_kalibr_camera(source, EXAMPLES[camera], folder)
    lines = _trajectory_lines(source.read_text(encoding="utf-8").splitlines(), height_m=height_m, step_m=step_m)
    text = "\n".join(lines) + "\n"
    path = folder / "scene.toml"
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        atomic_write_text(path, text)
    return path


def _camera_size(camera: str, width: int) -> tuple[int, int]:
    """(height, width) of a camera's renders at ``width`` pixels."""
    if camera == "ocamcalib":
        return (width, width)  # the scenes' catadioptric calibration is square
    return tuple(EXAMPLES[camera].scaled(width / EXAMPLES[camera].width).size)


def render_set(folder: Path, depth: str, camera: str, step_m: float, args) -> Path:
    """Render (or resume) one set; returns its dataset folder."""
    from omnisim.renderer import render_dataset

    scene = write_set_scene(folder, depth, camera, step_m)
    dataset = folder / "dataset"
    if not (dataset / "groundtruth.txt").exists() or len(list((dataset / "images").glob("*"))) < args.frames:
        render_dataset(scene, dataset, frames=args.frames, spp=args.spp, seed=args.seed,
                       resolution=_camera_size(camera, args.width), progress=False)
    return dataset


def _method_name(method: str) -> str:
    """The ifmi method name of a benchmark method (the reference pipeline by its import path)."""
    return REFERENCE if method == "reference" else method


def estimate_run(dataset: Path, method: str, selection: str, *, ransac_seed: int = 0) -> dict:
    """ATE (rad), per-model pair counts and failures of one estimate of ``dataset``."""
    from dataclasses import replace

    from ifmi.io.tum import read_tum
    from ifmi.evaluation.metrics import error_stats
    from ifmi.pipeline import EstimateConfig, estimate_dataset
    from ifmi.geometry.rotations import geodesic_angle

    base = EstimateConfig()
    pose = replace(base.relative_pose, rotation_only=selection == "rotation",
                   five_point_only=selection == "5pt", seed=ransac_seed)
    start = time.perf_counter()
    est = estimate_dataset(dataset, method=_method_name(method), config=replace(base, relative_pose=pose))
    seconds = time.perf_counter() - start
    gt = read_tum(dataset / "groundtruth.txt")
    errors = geodesic_angle(gt.rotations, est.trajectory.rotations)
    solved = [r for r in est.frames if r.success and r.frame != r.reference_frame]
    return {"ate_rad": float(error_stats(errors).rmse), "pairs": len(solved),
            "rotation": sum(r.model == "rotation" for r in solved), "5pt": sum(r.model == "5pt" for r in solved),
            "failed": sum(not r.success for r in est.frames), "seconds": seconds}


def run_path(folder: Path, method: str, selection: str, ransac_seed: int) -> Path:
    """The result file of one run (RANSAC seed 0 without a suffix, as sweeps of one seed name it)."""
    suffix = f"-seed{ransac_seed}" if ransac_seed else ""
    return folder / f"result-{method}-{selection}{suffix}.json"


def combined_runs(runs: list[dict]) -> dict:
    """One method and selection over several RANSAC seeds: the median ATE (rad), each seed's ATE
    (``ate_runs``), and the pairs by model and failures summed over the runs."""
    combined = {key: sum(run[key] for run in runs) for key in ("pairs", "rotation", "5pt", "failed")}
    ates = [run["ate_rad"] for run in runs]
    return {**combined, "ate_rad": float(np.median(ates)), "ate_runs": ates}


def run_set(folder: Path, dataset: Path, args) -> dict:
    """Every method and selection on one set with every RANSAC seed, each run kept in ``folder``
    (resumed when present); the runs of each method and selection combined (:func:`combined_runs`)."""
    from ifmi.io.atomic import atomic_write_json

    results = {}
    for method in args.methods:
        for selection in SELECTIONS:
            runs = []
            for seed in args.ransac_seeds:
                path = run_path(folder, method, selection, seed)
                if path.exists():
                    runs.append(json.loads(path.read_text(encoding="utf-8")))
                    continue
                runs.append(estimate_run(dataset, method, selection, ransac_seed=seed))
                atomic_write_json(path, runs[-1])
            results[method, selection] = combined_runs(runs)
    return results


def seed_spread_line(sweep: dict, methods) -> list[str]:
    """A Markdown bullet on how far one run's ATE moves with the RANSAC seed (empty for one seed)."""
    spreads = [max(run["ate_runs"]) / min(run["ate_runs"]) for results in sweep.values()
               for (method, _), run in results.items()
               if method in methods and len(run["ate_runs"]) > 1 and min(run["ate_runs"]) > 0]
    if not spreads:
        return []
    return [f"* Largest over smallest ATE of a run across the RANSAC seeds: median {np.median(spreads):.2f}, "
            f"90th percentile {np.percentile(spreads, 90):.2f} over {len(spreads)} runs."]


def _share(run: dict, model: str) -> float:
    """Share of a run's solved pairs solved with ``model`` (NaN without a solved pair)."""
    return run[model] / run["pairs"] if run["pairs"] else float("nan")


def table_rows(sweep: dict, methods) -> list[str]:
    """Markdown rows: set, then per method ATE (auto), its ratio to the best fixed-model ATE and 5-point share."""
    rows = []
    for name, results in sweep.items():
        cells = [name]
        for method in methods:
            auto, rot, five = (results[method, s] for s in SELECTIONS)
            best = min(rot["ate_rad"], five["ate_rad"])
            ratio = auto["ate_rad"] / best if best > 0 else float("nan")
            share = f"{100 * _share(auto, '5pt'):.0f} %" if auto["pairs"] else "no pair solved"
            cells.append(f"{auto['ate_rad']:.4f} ({ratio:.2f}x, {share})")
        rows.append("| " + " | ".join(cells) + " |")
    return rows


def summary_lines(sweep: dict, methods) -> list[str]:
    """Markdown bullets counting the runs that meet each criterion (see ``FIXED_MODEL_RATIO`` and below)."""
    def ate(name, method, selection="auto"):
        return sweep[name][method, selection]["ate_rad"]

    def behind_fixed(name, method):
        return ate(name, method) > FIXED_MODEL_RATIO * min(ate(name, method, "rotation"), ate(name, method, "5pt"))

    lines = [f"* Runs with the chosen model more than {FIXED_MODEL_RATIO}x the better forced run: "
             + ", ".join(f"{m} {sum(behind_fixed(n, m) for n in sweep)}" for m in methods)
             + f" of {len(sweep)} sets each."]
    features = [m for m in ("orb", "akaze") if m in methods]
    if "reference" in methods and features:
        lines.append(f"* ORB and AKAZE more than {REFERENCE_RATIO}x the reference pipeline's ATE: " + ", ".join(
            f"{m} {sum(ate(n, m) > REFERENCE_RATIO * ate(n, 'reference') for n in sweep)}" for m in features)
            + f" of {len(sweep)} sets each.")
    fisheyes = [n for n in sweep if "-ds-" in n or "-kb-" in n]
    others = [m for m in methods if m != "ifmi"]
    if "ifmi" in methods and others and fisheyes:
        kept = [n for n in fisheyes if ate(n, "ifmi") < FISHEYE_ATE_RAD
                and ate(n, "ifmi") <= FISHEYE_SHARE * min(ate(n, m) for m in others)]
        lines.append(f"* iFMI on the downward fisheyes (ds, kb) at most {FISHEYE_SHARE:.2f} of the best other "
                     f"method's ATE and below {FISHEYE_ATE_RAD} rad: {len(kept)} of {len(fisheyes)} sets"
                     + (f" ({', '.join(kept)})." if kept else "."))
    return lines


def _machine() -> str:
    """Platform and CPU model of this machine, for the report."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{platform.platform()}, {cpu}"


def report_text(sweep: dict, args, command: str) -> str:
    """MyST Markdown of the sweep's table with the command, date and machine."""
    methods = list(args.methods)
    header = "| set | " + " | ".join(methods) + " |"
    lines = ["# Translation sweep", "",
             f"Command: `{command}`", "",
             f"Date: {time.strftime('%Y-%m-%d', time.gmtime())}; machine: {_machine()}; "
             f"Python {platform.python_version()}.", "",
             f"{args.frames} frames per set at {args.width} px, {args.spp} spp, seed {args.seed}; "
             f"RANSAC seeds {', '.join(map(str, args.ransac_seeds))}, every ATE the median over them. "
             "Sets are named depth-camera-translation per frame. Each cell: geodesic ATE (rad) with the "
             "default model selection, its ratio to the better of the two fixed-model runs (rotation only, "
             "5-point only), and the share of solved pairs on which the 5-point model was chosen.", "",
             header, "|" + "---|" * (len(methods) + 1), *table_rows(sweep, methods), "",
             *summary_lines(sweep, methods), *seed_spread_line(sweep, methods), "",
             "Fixed-model ATEs (rad), rotation only / 5-point only:", "",
             header, "|" + "---|" * (len(methods) + 1)]
    for name, results in sweep.items():
        cells = [f"{results[m, 'rotation']['ate_rad']:.4f} / {results[m, '5pt']['ate_rad']:.4f}" for m in methods]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _print_set(name: str, results: dict, methods) -> None:
    """Print one set's runs: each method's ATE with each selection and its pairs by model."""
    for method in methods:
        auto, rot, five = (results[method, s] for s in SELECTIONS)
        print(f"  {name:22s} {method:10s} ATE {auto['ate_rad']:.4f} rad (rotation only {rot['ate_rad']:.4f}, "
              f"5-point only {five['ate_rad']:.4f}); pairs by model: rotation {100 * _share(auto, 'rotation'):.0f} %, "
              f"5-point {100 * _share(auto, '5pt'):.0f} %; {auto['failed']} failed", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="folder of the rendered sets and estimates (resumed when it holds some)")
    parser.add_argument("--width", type=int, default=384, help="image width of every camera, px")
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--spp", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1, help="sequence seed (motion, sampling)")
    parser.add_argument("--steps", type=float, nargs="+", default=list(STEPS_M),
                        help="translation per frame, metres")
    parser.add_argument("--depths", nargs="+", default=list(DEPTHS), choices=list(DEPTHS))
    parser.add_argument("--cameras", nargs="+", default=list(CAMERAS), choices=CAMERAS)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--ransac-seeds", nargs="+", type=int, default=[0], metavar="SEED",
                        help="RANSAC seeds of the back end; every run is repeated with each and its ATE "
                             "is the median over them")
    parser.add_argument("--render-only", action="store_true", help="render the sets, estimate nothing")
    parser.add_argument("--report", default=None, help="MyST Markdown file of the table (e.g. "
                        "reports/translation_sweep/README.md)")
    args = parser.parse_args()
    if any(seed < 0 for seed in args.ransac_seeds) or len(set(args.ransac_seeds)) != len(args.ransac_seeds):
        parser.error(f"--ransac-seeds: expected distinct seeds >= 0, got {args.ransac_seeds}")
    out = Path(args.out)
    command = "python benchmarks/bench_translation.py " + " ".join(
        ["OUT", *(a if not a.startswith(str(out)) else "OUT" for a in sys.argv[2:])])
    sweep = {}
    for depth in args.depths:
        for camera in args.cameras:
            for step in args.steps:
                name = set_name(depth, camera, step)
                folder = out / name
                dataset = render_set(folder, depth, camera, step, args)
                if args.render_only:
                    continue
                sweep[name] = run_set(folder, dataset, args)
                _print_set(name, sweep[name], args.methods)
    if not args.render_only:
        print("\n".join(summary_lines(sweep, args.methods)))
    if args.report:
        from ifmi.io.atomic import atomic_write_text

        Path(args.report).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(args.report), report_text(sweep, args, command))
        print(f"table written to {args.report}")


if __name__ == "__main__":
    main()
