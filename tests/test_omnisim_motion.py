"""Trajectories, sensor effects, scene-file validation and LLVM detection (no rendering)."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ifmi.geometry.rotations import geodesic_angle, rpy_from_matrix

from omnisim.config import EffectsSettings, TrajectorySettings
from omnisim.effects import apply_effects, exposure_gains, srgb_uint8_from_linear
from omnisim.llvm import LlvmNotFoundError, find_llvm
from omnisim.motion import random_trajectory, relative_trajectory

SETTINGS = TrajectorySettings(frames=300, max_yaw_step_deg=3.0, max_roll_deg=15.0, max_pitch_deg=15.0,
                              max_tilt_step_deg=1.5, smoothness_frames=6.0)


def test_random_trajectory_respects_bounds_and_is_smooth():
    poses = random_trajectory(SETTINGS, seed=4)
    rpy = np.array([rpy_from_matrix(R) for R in poses.rotations])
    roll, pitch = np.degrees(rpy[:, 0]), np.degrees(rpy[:, 1])
    assert np.abs(roll).max() <= 15.0 + 1e-9 and np.abs(pitch).max() <= 15.0 + 1e-9
    assert np.abs(roll).max() > 3.0 and np.abs(pitch).max() > 3.0
    steps = np.degrees([geodesic_angle(a, b) for a, b in zip(poses.rotations[:-1], poses.rotations[1:])])
    # Yaw step <= 3 degrees and tilt steps <= 1.5 degrees each bound the geodesic step.
    assert steps.max() <= np.sqrt(3.0 ** 2 + 2 * 1.5 ** 2) + 1e-6
    assert steps.max() > 1.5
    np.testing.assert_allclose(poses.positions, np.tile(SETTINGS.position, (300, 1)))


def test_random_trajectory_is_seeded():
    a = random_trajectory(SETTINGS, seed=4)
    b = random_trajectory(SETTINGS, seed=4)
    c = random_trajectory(SETTINGS, seed=5)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    assert not np.allclose(a.rotations, c.rotations)


def test_shorter_sequence_is_prefix_of_longer():
    settings = TrajectorySettings(frames=20, translation_step_m=0.05)
    longer = TrajectorySettings(frames=200, translation_step_m=0.05)
    short, full = random_trajectory(settings, seed=9), random_trajectory(longer, seed=9)
    np.testing.assert_array_equal(short.rotations, full.rotations[:20])
    np.testing.assert_array_equal(short.positions, full.positions[:20])


def test_translation_steps_are_bounded():
    settings = TrajectorySettings(frames=100, translation_step_m=0.05, translation_radius_m=0.4)
    poses = random_trajectory(settings, seed=1)
    steps = np.linalg.norm(np.diff(poses.positions, axis=0), axis=1)
    assert steps.max() <= 0.05 + 1e-9 and steps.max() > 0.01
    assert np.linalg.norm(poses.positions - poses.positions[0], axis=1).max() <= 0.4 + 1e-9


def test_relative_trajectory_maps_camera_k_into_camera_0():
    settings = TrajectorySettings(frames=10, translation_step_m=0.1)
    poses = random_trajectory(settings, seed=2)
    traj = relative_trajectory(poses)
    np.testing.assert_allclose(traj.rotations[0], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(traj.positions[0], 0.0, atol=1e-12)
    # A world point seen from camera k, mapped by T_0k, equals its camera-0 coordinates.
    point = np.array([1.0, 2.0, 0.5])
    for k in (3, 9):
        in_k = poses.rotations[k].T @ (point - poses.positions[k])
        in_0 = poses.rotations[0].T @ (point - poses.positions[0])
        np.testing.assert_allclose(traj.rotations[k] @ in_k + traj.positions[k], in_0, atol=1e-12)


def test_effects_are_seeded_and_switchable():
    rows, cols = np.mgrid[0:32, 0:32] / 31.0
    image = srgb_uint8_from_linear(np.stack([rows, cols, 0.5 * (rows + cols)], axis=-1))
    off = apply_effects(image, EffectsSettings(), seed=1, frame=3)
    np.testing.assert_array_equal(off, image)
    on = EffectsSettings(noise_sigma=4.0, jpeg_quality=70)
    a = apply_effects(image, on, seed=1, frame=3)
    b = apply_effects(image, on, seed=1, frame=3)
    c = apply_effects(image, on, seed=1, frame=4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert 1.0 < np.abs(a.astype(float) - image).mean() < 10.0


def test_exposure_gains_walk_within_bounds():
    settings = EffectsSettings(exposure_stops=0.5, exposure_step_stops=0.1)
    gains = exposure_gains(200, settings, seed=3)
    stops = np.log2(gains)
    assert stops[0] == 0.0 and np.abs(stops).max() <= 0.5 + 1e-12
    assert np.abs(np.diff(stops)).max() <= 0.1 + 1e-12
    np.testing.assert_array_equal(exposure_gains(5, EffectsSettings(), seed=3), np.ones(5))


def test_llvm_too_old_gives_one_line_fix(tmp_path):
    old = tmp_path / "libLLVM-15.so"
    old.write_bytes(b"")
    with pytest.raises(LlvmNotFoundError) as info:
        find_llvm(environ={"DRJIT_LIBLLVM_PATH": str(old)}, prefix=str(tmp_path / "venv"),
                  system_globs=(str(tmp_path / "libLLVM-*.so*"),))
    message = str(info.value)
    assert "\n" not in message
    assert "LLVM 15" in message and "pip install karellen-llvm-core" in message
    assert "apt-get install libllvm19" in message and "DRJIT_LIBLLVM_PATH" in message


def test_llvm_found_in_prefix_and_explicit(tmp_path):
    lib = tmp_path / "venv" / "lib"
    lib.mkdir(parents=True)
    (lib / "libLLVM.so.23.1").write_bytes(b"")
    found = find_llvm(environ={}, prefix=str(tmp_path / "venv"), system_globs=())
    assert found == lib / "libLLVM.so.23.1"
    explicit = tmp_path / "libLLVM-19.so.1"
    explicit.write_bytes(b"")
    assert find_llvm(environ={"DRJIT_LIBLLVM_PATH": str(explicit)}, prefix=str(tmp_path / "venv"),
                     system_globs=()) == explicit


def test_trajectory_file_out_of_order_or_out_of_range_is_refused(tmp_path):
    from ifmi.errors import InputError
    from omnisim.motion import poses_from_tum

    path = tmp_path / "walk.txt"
    path.write_text("0 0 0 1 0 0 0 1\n1 0.1 0 1 0 0 0 1\n1 0.2 0 1 0 0 0 1\n3 0.3 0 1 0 0 0 1\n")
    with pytest.raises(InputError, match=r"walk.txt: pose 2 has timestamp 1 after 1; expected increasing"):
        poses_from_tum(path, frames=4, position=(0.0, 0.0, 0.0))
    poses = poses_from_tum(path, frames=2, position=(0.0, 0.0, 1.0))  # the frames used are in order
    np.testing.assert_allclose(poses.positions, [[0, 0, 2], [0.1, 0, 2]])
    path.write_text("0 5e6 0 1 0 0 0 1\n1 5000000.1 0 1 0 0 0 1\n")  # UTM-like: float32 places it to 0.25 m
    with pytest.raises(InputError, match=r"walk.txt: pose 0: expected positions \(plus \[trajectory\] position\) "
                                         r"of magnitude <= 1e\+04 m .* got \[5000000.0, 0.0, 1.0\]"):
        poses_from_tum(path, frames=2, position=(0.0, 0.0, 0.0))
    shifted = poses_from_tum(path, frames=2, position=(-5e6, 0.0, 0.0))  # the fix the message names
    np.testing.assert_allclose(shifted.positions, [[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])


MAPS_LINE = "7f1c2a000000-7f1c2b000000 r-xp 00000000 08:01 1234 {}\n"


def test_loaded_llvm_is_read_from_the_process_maps(tmp_path):
    from omnisim.llvm import _refuse_loaded_old_llvm, loaded_llvm

    # Mapped libraries are files; their versions are read from the names (empty stand-ins here).
    for name in ("libLLVM-15.so.1", "libLLVM.so.23.1"):
        (tmp_path / name).write_bytes(b"")
    old = MAPS_LINE.format(tmp_path / "libLLVM-15.so.1")
    new = MAPS_LINE.format(tmp_path / "libLLVM.so.23.1")
    other = MAPS_LINE.format("/usr/lib/x86_64-linux-gnu/libc.so.6") + "7f00-7f01 rw-p 00000000 00:00 0\n"
    assert loaded_llvm(other + old) == tmp_path / "libLLVM-15.so.1"
    assert loaded_llvm(other) is None
    with pytest.raises(LlvmNotFoundError) as info:
        _refuse_loaded_old_llvm(other + old)
    message = str(info.value)
    assert "\n" not in message and "libLLVM-15.so.1 (LLVM 15)" in message and "import_mitsuba()" in message
    _refuse_loaded_old_llvm(other + new)  # LLVM 23 loaded: nothing to refuse
    _refuse_loaded_old_llvm(other)  # none loaded yet


def test_drjit_imported_first_with_an_old_llvm_is_refused_not_aborted():
    # A child process: on a host whose default LLVM is older than 16, drjit imported first
    # loads it, and the first kernel would abort the process.
    script = ("import drjit\n"
              "from omnisim.llvm import LlvmNotFoundError, import_mitsuba, loaded_llvm\n"
              "print(loaded_llvm())\n"
              "try:\n"
              "    import_mitsuba('llvm_ad_rgb')\n"
              "except LlvmNotFoundError as exc:\n"
              "    print('refused:', exc)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    loaded, _, verdict = out.stdout.partition("\n")
    major = re.search(r"libLLVM[-.](?:so\.)?(\d+)", loaded)
    if major is None or int(major.group(1)) >= 16:
        assert "refused" not in verdict  # drjit's own choice works: nothing to refuse
    else:
        assert verdict.startswith("refused: drjit was imported before omnisim chose its LLVM")


def test_cli_llvm_error_exits_nonzero(tmp_path, monkeypatch, capsys):
    import omnisim.llvm as llvm

    monkeypatch.setattr(llvm, "SYSTEM_GLOBS", ())
    monkeypatch.setattr(llvm.sys, "prefix", str(tmp_path))
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "missing.so"))
    from omnisim.cli import main

    code = main(["check-llvm"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1 and "karellen-llvm-core" in err
