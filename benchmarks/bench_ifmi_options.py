"""iFMI with its default options against variants: accuracy and compute per frame, in one process.

Measures what one option costs or buys, e.g. the dense retry
(``recovery.dense_retry_fraction=0`` turns it off) or the coarse stage
(``coarse.enabled=false``)::

    python benchmarks/bench_ifmi_options.py DATA/fast/office_trans_x10 \
        --variant no_retry:recovery.dense_retry_fraction=0 --rounds 5 --out out/bench_ifmi_options

A variant is ``NAME:KEY=VALUE[,KEY=VALUE...]`` with keys of the ``ifmi``
section of the configuration (dotted, ``refinement.refit_passes=0``) and
JSON values; ``relative_pose.KEY`` sets
an option of the back end instead. Every configuration runs
through the same odometry and back end as ``ifmi estimate``.

Accuracy comes from one full run per configuration and dataset, written and
evaluated as in ``benchmarks/bench_methods.py`` (geodesic ATE RMSE, failed
frames). Compute per frame is measured with the frames decoded into memory
beforehand, in ``--rounds`` rounds, the configurations taking turns within
each round so that load from other processes hits all alike; the median
over the rounds is used, as wall time and as this thread's CPU time (the
CPU time is steadier on a loaded machine). Printed per dataset and
variant: the ATE of default and variant, how many frames ran the dense
retry, and the variant's compute over the default's (1.25 = 25 % more);
then, per variant, a summary over the datasets where the retry ran (for
comparing retry variants over many sets, e.g. subsampled from several start
frames with ``subsample_dataset.py --start``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchlib import mode_config, run_method
from ifmi.evaluation.dataset_names import dataset_labels, resolved_folder
from ifmi.io.atomic import atomic_write_json
from ifmi.io.camera_file import calibration_path, read_camera
from ifmi.io.dataset import read_dataset
from ifmi.pipeline import EstimateConfig, estimate_sequence, resolved_config
from ifmi.spectral.ifmi_front_end import IfmiConfig, IfmiFrontEnd


def parse_variant(text: str) -> tuple[str, dict]:
    """``NAME:KEY=VALUE,...`` -> (name, {dotted key: JSON value})."""
    name, sep, assignments = text.partition(":")
    if not sep or not name or not assignments:
        raise argparse.ArgumentTypeError(f"expected NAME:KEY=VALUE[,KEY=VALUE...], got {text!r}")
    changes = {}
    for item in assignments.split(","):
        key, sep, value = item.partition("=")
        if not sep:
            raise argparse.ArgumentTypeError(f"expected KEY=VALUE in {text!r}, got {item!r}")
        try:
            changes[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            raise argparse.ArgumentTypeError(f"expected a JSON value for {key!r}, got {value!r}") from None
    return name, changes


def estimate_variant(config: EstimateConfig, changes: dict) -> EstimateConfig:
    """``config`` with dotted-key ``changes``: keys of the ``ifmi`` options, or
    ``relative_pose.NAME`` for an option of the shared back end."""
    prefix = "relative_pose."
    pose = {key[len(prefix):]: value for key, value in changes.items() if key.startswith(prefix)}
    ifmi = {key: value for key, value in changes.items() if not key.startswith(prefix)}
    try:
        relative_pose = replace(config.relative_pose, **pose)
    except TypeError as exc:  # an unknown option name
        raise ValueError(f"relative_pose: {exc}") from None
    return replace(config, ifmi=ifmi_variant(config.ifmi, ifmi), relative_pose=relative_pose)


def ifmi_variant(config: IfmiConfig, changes: dict) -> IfmiConfig:
    """``config`` with dotted-key ``changes``, type-checked like a configuration file."""
    data = config.to_dict()
    for key, value in changes.items():
        node = data
        *parents, leaf = key.split(".")
        for part in parents:
            if not isinstance(node.get(part), dict):
                raise ValueError(f"ifmi.{key}: {part!r} is not a section of the ifmi options")
            node = node[part]
        node[leaf] = value
    return IfmiConfig.from_dict(data)


@contextmanager
def retry_clock():
    """Thread-CPU seconds spent in the dense retry (``IfmiFrontEnd.register_dense``) while active:
    a list whose one entry accumulates."""
    spent = [0.0]
    original = IfmiFrontEnd.register_dense

    def timed(self, *args, **kwargs):
        start = time.thread_time()
        try:
            return original(self, *args, **kwargs)
        finally:
            spent[0] += time.thread_time() - start

    IfmiFrontEnd.register_dense = timed
    try:
        yield spent
    finally:
        IfmiFrontEnd.register_dense = original


def compute_times(dataset: str, configs: dict, *, rounds: int) -> tuple[dict, dict]:
    """Median (wall, thread-CPU, retry share) per frame of each configuration, frames in memory,
    interleaved; and the number of frames that ran the dense retry.

    The retry share is the thread-CPU time spent in the dense retry over the rest of the same
    run's: measured within one run, it does not move with the load as a ratio of two runs does.
    """
    data = read_dataset(dataset)
    frames = list(data.iter_images(skip_unreadable=True))
    wall = {name: [] for name in configs}
    cpu = {name: [] for name in configs}
    share = {name: [] for name in configs}
    retries = {}
    for _ in range(rounds):
        for name, config in configs.items():
            with retry_clock() as in_retry:
                start, start_cpu = time.perf_counter(), time.thread_time()
                estimate = estimate_sequence(frames, data.model, method="ifmi", config=config)
                total_cpu = time.thread_time() - start_cpu
            wall[name].append((time.perf_counter() - start) / len(frames))
            cpu[name].append(total_cpu / len(frames))
            share[name].append(in_retry[0] / (total_cpu - in_retry[0]))
            retries[name] = sum("n_tiles_kept_dense" in record.diagnostics for record in estimate.frames)
    medians = {name: (float(np.median(wall[name])), float(np.median(cpu[name])), float(np.median(share[name])))
               for name in configs}
    return medians, retries


def variant_summary(rows: list) -> dict:
    """Per variant, over the datasets where default or variant ran the dense retry: how the
    variant's ATE compares (sets on which one configuration alone differs say little when
    single pairs decide a set's ATE).

    Returns ``{variant: {sets, ate_ratio_geomean, ate_median_default, ate_median_variant,
    worse, better, failures_default, failures_variant, cpu_ratio_median}}``; worse/better
    count sets whose ATE changed by more than 5 %.
    """
    summary = {}
    for name in dict.fromkeys(r["variant"] for r in rows):
        chosen = [r for r in rows if r["variant"] == name
                  and (r["retry_frames_default"] or r["retry_frames_variant"])]
        if not chosen:
            continue
        default = np.array([r["ate_default"] for r in chosen])
        variant = np.array([r["ate_variant"] for r in chosen])
        summary[name] = {
            "sets": len(chosen),
            "ate_ratio_geomean": float(np.exp(np.mean(np.log(variant / default)))),
            "ate_median_default": float(np.median(default)), "ate_median_variant": float(np.median(variant)),
            "worse": int(np.sum(variant > 1.05 * default)), "better": int(np.sum(variant < default / 1.05)),
            "failures_default": sum(r["failures_default"] for r in chosen),
            "failures_variant": sum(r["failures_variant"] for r in chosen),
            "cpu_ratio_median": float(np.median([r["cpu_variant_s"] / r["cpu_default_s"] for r in chosen]))}
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--variant", type=parse_variant, action="append", required=True,
                        help="NAME:KEY=VALUE[,KEY=VALUE...] (keys of the ifmi options, or "
                             "relative_pose.KEY); repeatable")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", default="out/bench_ifmi_options")
    args = parser.parse_args(argv)
    out = Path(args.out)
    rows = []
    print("ATE: geodesic RMSE (rad); retry: frames that ran the dense retry; ms: thread CPU per frame, "
          "frames in memory; ratios: variant / default (wall, CPU); share: CPU in the dense retry over "
          "the rest of the same run's (default, variant)")
    print(f"{'dataset':<18}{'variant':<14}{'ATE default':>12}{'ATE variant':>12}{'retry':>7}{'retry var':>10}"
          f"{'ms default':>11}{'ms variant':>11}{'wall v/d':>9}{'cpu v/d':>8}{'share d':>8}{'share v':>8}")
    labels = dataset_labels(args.datasets)
    for dataset in args.datasets:
        label = labels[resolved_folder(dataset)]
        model = read_camera(calibration_path(dataset))
        base = resolved_config(mode_config(EstimateConfig(), "frame"), model)
        configs = {"default": base}
        for name, changes in args.variant:
            try:
                configs[name] = estimate_variant(base, changes)
            except ValueError as exc:  # an unknown key or a bad value, named by its key path
                parser.error(f"--variant {name}: {exc}")
        accuracy = {name: run_method(dataset, "ifmi", "frame", config, out / name, label=label)
                    for name, config in configs.items()}
        times, retries = compute_times(dataset, configs, rounds=max(1, args.rounds))
        for name in list(configs)[1:]:
            ratio_wall = times[name][0] / times["default"][0]
            ratio_cpu = times[name][1] / times["default"][1]
            print(f"{label:<18}{name:<14}{accuracy['default']['geodesic_rmse']:>12.5f}"
                  f"{accuracy[name]['geodesic_rmse']:>12.5f}{retries['default']:>7}{retries[name]:>10}"
                  f"{times['default'][1] * 1e3:>11.2f}{times[name][1] * 1e3:>11.2f}{ratio_wall:>9.3f}"
                  f"{ratio_cpu:>8.3f}{times['default'][2]:>8.3f}{times[name][2]:>8.3f}")
            rows.append({"dataset": label, "variant": name, "changes": dict(args.variant)[name],
                         "ate_default": accuracy["default"]["geodesic_rmse"],
                         "ate_variant": accuracy[name]["geodesic_rmse"],
                         "failures_default": accuracy["default"]["failures"],
                         "failures_variant": accuracy[name]["failures"],
                         "retry_frames_default": retries["default"], "retry_frames_variant": retries[name],
                         "wall_default_s": times["default"][0], "wall_variant_s": times[name][0],
                         "cpu_default_s": times["default"][1], "cpu_variant_s": times[name][1],
                         "retry_share_default": times["default"][2], "retry_share_variant": times[name][2]})
    summary = variant_summary(rows)
    for name, v in summary.items():
        print(f"{name}: over the {v['sets']} sets with a dense retry: ATE variant/default geometric mean "
              f"{v['ate_ratio_geomean']:.3f}, median {v['ate_median_default']:.5f} -> {v['ate_median_variant']:.5f}, "
              f"{v['worse']} sets worse and {v['better']} better by > 5 %, failed frames "
              f"{v['failures_default']} -> {v['failures_variant']}, median cpu v/d {v['cpu_ratio_median']:.3f}")
    atomic_write_json(out / "bench_ifmi_options.json",
                      {"rows": rows, "summary": summary, "rounds": args.rounds,
                       "argv": sys.argv if argv is None else argv})
    return 0


if __name__ == "__main__":
    sys.exit(main())
