"""Render scene files into dataset folders (images, calibration, ground truth, provenance).

A dataset folder holds ``calib_results.txt``, ``images/NNNNNN.png`` (8-bit
RGB), ``groundtruth.txt`` (TUM, camera k in camera 0), ``poses_world.txt``
(TUM, camera-to-world) and ``meta.json``. Rendering is deterministic for a
given scene file, seed and settings: each frame seeds Mitsuba's sampler from
(seed, frame), so an interrupted render resumes where it stopped and a rerun
reproduces the same bytes. A folder that holds a render with other settings
is refused rather than mixed.
"""

from __future__ import annotations

import hashlib
import json
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ifmi.errors import InputError, OutputError
from ifmi.io.atomic import atomic_write_bytes, atomic_write_json
from ifmi.io.calib import write_calib
from ifmi.io.provenance import package_versions
from ifmi.io.tum import write_tum

from .config import CaptureSettings, SceneConfig, load_scene_config
from .effects import apply_effects, exposure_gains, srgb_uint8_from_linear
from .motion import poses_for_settings, relative_trajectory, world_trajectory
from .scene import build_scene_dict
from .sensor import register_omni_sensor, sensor_dict, to_world_matrix

__all__ = ["OmniRenderer", "DatasetResult", "frame_seed", "render_dataset", "encode_png", "sha256_file",
           "check_output_folder", "open_output_folder", "pending_images"]

# Format version of meta.json; bumped when its meaning changes.
META_FORMAT = 1
# Version of the rendering code; bumped whenever the same inputs would give other pixels,
# so an old folder is refused instead of being completed with differently made frames.
RENDERER_VERSION = 3


def frame_seed(seed: int, frame: int) -> int:
    """Sampler seed (uint32) of one frame, derived from the sequence seed."""
    digest = hashlib.sha256(f"{int(seed)}:{int(frame)}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


class OmniRenderer:
    """A loaded Mitsuba scene with the omni sensor, rendering one pose at a time.

    Parameters
    ----------
    config : SceneConfig
    variant : str, optional, keyword-only
        Mitsuba variant; default from the scene file, else automatic
        (``cuda_ad_rgb`` with a GPU, else ``llvm_ad_rgb``).
    integrator : dict, optional, keyword-only
        Replaces the scene's integrator (e.g. an AOV integrator for tests).
    sampler : str, optional, keyword-only
        Replaces the scene's sampler plugin.
    """

    def __init__(self, config: SceneConfig, *, variant: str | None = None,
                 integrator: dict | None = None, sampler: str | None = None):
        from .llvm import import_mitsuba

        self.config = config
        self.mi = import_mitsuba(variant or config.render.variant or None)
        register_omni_sensor(self.mi)
        cam = config.camera
        sensor = sensor_dict(cam.model, to_world=np.eye(4), radius_min=cam.radius_min,
                             radius_max=cam.radius_max, spp=config.render.spp,
                             sampler=sampler or config.render.sampler, mi=self.mi)
        scene_dict = build_scene_dict(config, self.mi, sensor=sensor)
        if integrator is not None:
            scene_dict["integrator"] = integrator
        # Serial loading keeps the order of shapes and emitters, hence the light
        # sampling pattern and the image bytes, the same from run to run.
        self.scene = self.mi.load_dict(scene_dict, parallel=False)
        self.params = self.mi.traverse(self.scene)

    @property
    def variant(self) -> str:
        return self.mi.variant()

    def set_pose(self, rotation: np.ndarray, position: np.ndarray) -> None:
        """Place the camera: ``rotation`` (3,3) camera-to-world, ``position`` (3,) metres."""
        matrix = to_world_matrix(rotation, position).astype(np.float32)
        self.params["sensor.to_world"] = self.mi.Transform4f(np.ascontiguousarray(matrix))
        self.params.update()

    def render(self, rotation: np.ndarray, position: np.ndarray, *, seed: int,
               spp: int | None = None) -> np.ndarray:
        """Render one frame at a pose; returns linear RGB (H, W, C) float32 (rows, cols)."""
        self.set_pose(rotation, position)
        image = self.mi.render(self.scene, seed=int(seed), spp=int(spp or self.config.render.spp))
        return np.array(image, dtype=np.float32)


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an 8-bit RGB (H,W,3) or gray (H,W) image."""
    import cv2

    array = image[..., ::-1] if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(array), [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _versions() -> dict:
    names = ("mitsuba", "drjit", "numpy", "opencv-python-headless", "omnisim-ifmi")
    return {"python": platform.python_version(), **package_versions(names)}


@dataclass(frozen=True)
class DatasetResult:
    """Outcome of :func:`render_dataset`.

    out_dir : dataset folder; frames : number of frames; rendered : frames
    rendered in this call (the rest were already there and verified);
    seconds_per_frame : mean wall time of the frames rendered in this call (NaN if none).
    """

    out_dir: str
    frames: int
    rendered: int
    seconds_per_frame: float


def _differences(previous, current, prefix: str = "") -> list[str]:
    """Dotted names of the entries where two identity dicts differ, with both values."""
    if isinstance(previous, dict) and isinstance(current, dict):
        out = []
        for key in sorted(set(previous) | set(current), key=str):
            out += _differences(previous.get(key), current.get(key), f"{prefix}{key}.")
        return out
    if previous == current:
        return []
    return [f"{prefix[:-1]} (folder: {_shortened(previous)}, now: {_shortened(current)})"]


# Most differences named in a refusal, and the longest value shown (characters).
SHOWN_DIFFERENCES = 3
SHOWN_VALUE_CHARS = 40


def _shortened(value) -> str:
    text = json.dumps(value)
    return text if len(text) <= SHOWN_VALUE_CHARS else text[:SHOWN_VALUE_CHARS - 3] + "..."


def _has_written_frames(out_dir: Path, meta: dict | None) -> bool:
    images = out_dir / "images"
    if meta is not None and meta.get("images"):
        return True
    return images.is_dir() and any(images.iterdir())


def check_output_folder(out_dir: Path, identity: dict) -> dict | None:
    """The ``meta.json`` of an output folder written with the same ``identity``, or None if new.

    Nothing is written. A folder whose ``meta.json`` records no frames and
    whose ``images/`` is empty (a run that stopped before its first frame) is
    treated as new, whatever settings it was started with.

    Raises
    ------
    InputError
        The folder holds anything else: frames made with a different
        identity (the message names the settings that differ), an unreadable
        ``meta.json``, or files without one.
    """
    meta_path = out_dir / "meta.json"
    if not out_dir.exists():
        return None
    if not out_dir.is_dir():
        raise InputError(out_dir, "exists and is not a folder")
    if meta_path.exists():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raise InputError(meta_path, "unreadable meta.json; remove the folder or choose another --out") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("images", {}), dict):
            raise InputError(meta_path, "expected a JSON object with an 'images' table; remove the folder "
                                        "or choose another --out")
        previous = meta.get("identity", {})
        if previous == identity:
            return meta
        if not _has_written_frames(out_dir, meta):
            return None
        changed = _differences(previous, identity)
        shown = "; ".join(changed[:SHOWN_DIFFERENCES]) + (" ..." if len(changed) > SHOWN_DIFFERENCES else "")
        raise InputError(out_dir, f"holds a dataset made with different {shown or 'settings'}; "
                                  "refusing to mix (choose another --out or remove it)")
    if any(p.name != "images" for p in out_dir.iterdir()) or _has_written_frames(out_dir, None):
        raise InputError(out_dir, "is not empty and has no meta.json; refusing to write a dataset into it")
    return None


def open_output_folder(out_dir: Path, identity: dict) -> dict:
    """Check an output folder (:func:`check_output_folder`), create ``images/``, return its meta.

    The meta is the folder's ``meta.json`` when it holds the same identity,
    else a fresh one with no images recorded.

    Raises
    ------
    InputError
        See :func:`check_output_folder`.
    OutputError
        The folder cannot be created (read-only parent, a regular file in
        the way, ...): names ``out_dir`` and the OS reason.
    """
    meta = check_output_folder(out_dir, identity)
    try:
        (out_dir / "images").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError.from_os_error(out_dir, exc) from None
    return meta if meta is not None else {"identity": identity, "images": {}, "complete": False}


def pending_images(out_dir: Path, meta: dict, names: list) -> list:
    """Indices of the image ``names`` still to write: missing, or not matching the recorded SHA-256.

    Stale records are dropped from ``meta["images"]``.
    """
    todo = []
    for k, name in enumerate(names):
        path = out_dir / "images" / name
        recorded = meta["images"].get(name)
        if recorded is None or not path.exists() or sha256_file(path) != recorded:
            meta["images"].pop(name, None)
            todo.append(k)
    return todo


def render_dataset(scene_path, out_dir, *, frames: int | None = None, seed: int | None = None,
                   spp: int | None = None, resolution=None, progress: bool = True,
                   variant: str | None = None) -> DatasetResult:
    """Render a scene file into a dataset folder (resuming a previous, identical render).

    Parameters
    ----------
    scene_path : str or path
        TOML scene file.
    out_dir : str or path
        Dataset folder; created if missing.
    frames : int, optional, keyword-only
        Number of frames (default: the scene's trajectory table).
    seed : int, optional, keyword-only
        Sequence seed for motion, sampling and effects (default: the scene's seed).
    spp : int, optional, keyword-only
        Samples per pixel (default: the scene's render table).
    resolution : int or (height, width), optional, keyword-only
        Image size in pixels; the calibration is scaled to it.
    progress : bool, keyword-only
        Show a progress bar.
    variant : str, optional, keyword-only
        Mitsuba variant (default automatic).

    Returns
    -------
    DatasetResult

    Raises
    ------
    InputError
        Bad scene file or values, or an output folder holding another render;
        raised before anything is written.
    OutputError
        A file cannot be written (the message names it and the OS reason).
    """
    config = load_scene_config(scene_path, spp=spp, resolution=resolution, frames=frames, variant=variant)
    if config.capture != CaptureSettings():
        # The [capture] table is read and checked, but its effects are not rendered yet: refuse
        # rather than write sharp frames the user believes blurred.
        raise InputError(scene_path, "[capture]: exposure, rolling_shutter and vignetting are not rendered "
                                     "by this version; remove the table or set them to 0")
    seed = config.layout_seed if seed is None else int(seed)
    if seed < 0:
        raise InputError(scene_path, f"seed: expected a non-negative integer, got {seed}")
    out_dir = Path(out_dir)
    poses = poses_for_settings(config.trajectory, seed=seed)

    # Mitsuba is imported and the whole scene built and loaded (files, materials, lights)
    # before the output folder is touched, so a scene error leaves nothing behind.
    renderer = OmniRenderer(config)
    identity = {
        "scene_sha256": config.sha256,
        "seed": seed,
        "variant": renderer.variant,
        "settings": json.loads(json.dumps(config.settings_dict())),
        "format": META_FORMAT,
        "renderer": RENDERER_VERSION,
    }
    meta = open_output_folder(out_dir, identity)
    images_dir = out_dir / "images"
    meta.update({
        "scene_file": str(Path(scene_path).resolve()),
        "scene_name": config.name,
        "seed": seed,
        "spp": config.render.spp,
        "resolution": list(config.render.resolution),
        "frames": config.trajectory.frames,
        "variant": renderer.variant,
        "versions": _versions(),
    })
    write_calib(out_dir / "calib_results.txt", config.camera.model)
    write_tum(out_dir / "groundtruth.txt", relative_trajectory(poses),
              header=f"omnisim ground truth of {config.name}: T_0k, camera k in camera 0")
    write_tum(out_dir / "poses_world.txt", world_trajectory(poses),
              header=f"omnisim world poses of {config.name}: camera-to-world, metres, z up")
    atomic_write_json(out_dir / "meta.json", meta)

    names = [f"{k:06d}.png" for k in range(len(poses))]
    todo = pending_images(out_dir, meta, names)
    gains = exposure_gains(len(poses), config.effects, seed=seed)
    rendered, seconds = 0, 0.0
    if todo:
        from tqdm import tqdm

        bar = tqdm(total=len(names), initial=len(names) - len(todo), disable=not progress,
                   unit="frame", desc=config.name)
        for k in todo:
            start = time.perf_counter()
            linear = renderer.render(poses.rotations[k], poses.positions[k], seed=frame_seed(seed, k))
            image = srgb_uint8_from_linear(linear[..., :3], gain=float(gains[k]))
            image = apply_effects(image, config.effects, seed=seed, frame=k)
            data = encode_png(image)
            atomic_write_bytes(images_dir / names[k], data)
            meta["images"][names[k]] = hashlib.sha256(data).hexdigest()
            meta["images"] = dict(sorted(meta["images"].items()))
            atomic_write_json(out_dir / "meta.json", meta)
            seconds += time.perf_counter() - start
            rendered += 1
            bar.update(1)
        bar.close()
    meta["complete"] = len(meta["images"]) == len(names)
    atomic_write_json(out_dir / "meta.json", meta)
    return DatasetResult(out_dir=str(out_dir), frames=len(names), rendered=rendered,
                         seconds_per_frame=seconds / rendered if rendered else float("nan"))
