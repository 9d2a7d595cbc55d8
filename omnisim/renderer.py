"""Render scene files into dataset folders (images, calibration, ground truth, provenance).

A dataset folder holds ``calib_results.txt`` (or ``camera.yaml`` for a Kalibr
camera), ``images/NNNNNN.png`` (8-bit
RGB), ``groundtruth.txt`` (TUM, camera k in camera 0), ``poses_world.txt``
(TUM, camera-to-world) and ``meta.json``; optionally ``depth/`` and
``normal/`` (:mod:`omnisim.aov`) and, with rolling shutter, per-row poses in
``rolling_shutter/`` (:mod:`omnisim.capture`). Frames are rendered by a
:class:`FrameRenderer` in this process or on Dask workers
(:mod:`omnisim.cluster`), which return file bytes; this process alone writes
them, atomically, recording each file's SHA-256. Rendering is deterministic for a
given scene file, seed and settings: each frame seeds Mitsuba's sampler from
(seed, frame), so an interrupted render resumes where it stopped and a rerun
reproduces the same bytes. A folder that holds a render with other settings
is refused rather than mixed.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import platform
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from ifmi.errors import InputError, InputWarning, OutputError, json_excerpt
from ifmi.io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text, remove_leftovers
from ifmi.io.camera_file import write_camera
from ifmi.io.provenance import package_versions
from ifmi.io.tum import format_tum, write_tum
from ifmi.runtime.local_workers import DEFAULT_CONNECT_TIMEOUT_S, max_local_workers

from omnisim.aov import AOV_NAMES, aov_integrator_dict, aov_names_from_text, aov_sensor_dict, depth_normal_from_aov, npy_bytes
from omnisim.capture import ground_truth_time, row_mid_times, sensor_timing_props, vignetting_from_pixels
from omnisim.config import MAX_FRAMES, SceneConfig, load_scene_config
from omnisim.effects import apply_effects, exposure_gains, srgb_uint8_from_linear
from omnisim.motion import (WorldPoses, poses_at_times, poses_for_settings, relative_trajectory, trajectory_in_camera,
                     world_trajectory)
from omnisim.scene import build_scene_dict, mitsuba_reason
from omnisim.sensor import register_omni_sensor, sensor_dict, to_world_matrix

__all__ = ["OmniRenderer", "DatasetResult", "frame_seed", "render_dataset", "encode_png", "sha256_file",
           "check_output_folder", "open_output_folder", "pending_images", "frame_file_matches", "set_sensor_pose",
           "FramePlan", "FrameRenderer", "frame_file_names", "render_frame_files", "frame_plan", "frame_results",
           "poses_in_model_frame", "write_row_poses"]

# Format version of meta.json; bumped when its meaning changes.
META_FORMAT = 1
# Version of the rendering code; bumped whenever the same inputs would give other pixels,
# so an old folder is refused instead of being completed with differently made frames.
RENDERER_VERSION = 3


def poses_in_model_frame(poses: WorldPoses, model) -> WorldPoses:
    """Poses of the camera model's own frame, so that ground truth is in the frame of the dataset's model.

    Trajectories are generated for a body whose z axis is up when level, the
    axis about which it mostly turns (yaw): an OCamCalib camera's mirror
    axis, whose frame is used as is (its central pixel looks down). A Kalibr
    model (x along columns, y down the image, z the optical axis) is mounted
    the same way, looking straight down: its optical axis is the body's -z
    and its x the body's x, ``R_wc(model) = R_wc(body) diag(1, -1, -1)``, so
    that yaw turns the image about its centre as for the catadioptric
    camera. An equirectangular camera (z forward, -y up) is mounted level:
    its z is the body's x and its -y the body's z.
    """
    from ifmi.geometry.camera import OcamModel
    from ifmi.geometry.camera_models import EquirectangularModel

    if isinstance(model, OcamModel):
        return poses
    if isinstance(model, EquirectangularModel):
        mount = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    else:
        mount = np.diag([1.0, -1.0, -1.0])
    return WorldPoses(rotations=poses.rotations @ mount, positions=poses.positions)


def frame_seed(seed: int, frame: int) -> int:
    """Sampler seed (uint32) of one frame, derived from the sequence seed."""
    digest = hashlib.sha256(f"{int(seed)}:{int(frame)}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


class OmniRenderer:
    """A loaded Mitsuba scene with the omni sensor, rendering one pose at a time.

    Parameters
    ----------
    config : SceneConfig
        Its ``[capture]`` table sets the sensor's timing (motion blur, rolling shutter).
    variant : str, optional, keyword-only
        Mitsuba variant; default from the scene file, else automatic
        (``cuda_ad_rgb`` with a GPU, else ``llvm_ad_rgb``).
    integrator : dict, optional, keyword-only
        Replaces the scene's integrator (e.g. an AOV integrator for tests).
    sampler : str, optional, keyword-only
        Replaces the scene's sampler plugin.

    Attributes
    ----------
    spp : int
        Samples per pixel rendered: the scene's, rounded up as the sampler
        needs (multijitter 5 -> 6, ldsampler 5 -> 16), read from the loaded sampler.
    """

    def __init__(self, config: SceneConfig, *, variant: str | None = None,
                 integrator: dict | None = None, sampler: str | None = None):
        from omnisim.llvm import import_mitsuba

        self.config = config
        self.mi = import_mitsuba(variant or config.render.variant or None)
        register_omni_sensor(self.mi)
        cam = config.camera
        sensor = sensor_dict(cam.model, to_world=np.eye(4), radius_min=cam.radius_min,
                             radius_max=cam.radius_max, spp=config.render.spp,
                             sampler=sampler or config.render.sampler, mi=self.mi,
                             timing=sensor_timing_props(config.capture))
        scene_dict = build_scene_dict(config, self.mi, sensor=sensor)
        if integrator is not None:
            scene_dict["integrator"] = integrator
        # Serial loading keeps the order of shapes and emitters, hence the light
        # sampling pattern and the image bytes, the same from run to run.
        try:
            self.scene = self.mi.load_dict(scene_dict, parallel=False)
        except RuntimeError as exc:  # e.g. a Mitsuba file's environment light beside the scene file's
            raise InputError(config.path, f"Mitsuba cannot build the scene: {mitsuba_reason(exc)}") from None
        self.params = self.mi.traverse(self.scene)
        # Rendering at the sampler's own count gives its samples without logging the rounding per frame.
        self.spp = int(self.scene.sensors()[0].sampler().sample_count())

    @property
    def variant(self) -> str:
        return self.mi.variant()

    def set_pose(self, rotation: np.ndarray, position: np.ndarray, *, end=None) -> None:
        """Place the camera: ``rotation`` (3,3) camera-to-world, ``position`` (3,) metres.

        ``end`` = (rotation, position) is the pose one frame interval later,
        towards which a timed capture (motion blur, rolling shutter) moves.
        """
        set_sensor_pose(self.mi, self.params, "sensor.", rotation, position, end=end)

    def render(self, rotation: np.ndarray, position: np.ndarray, *, seed: int,
               spp: int | None = None, end=None) -> np.ndarray:
        """Render one frame at a pose; returns linear RGB (H, W, C) float32 (rows, cols).

        ``end`` as in :meth:`set_pose`; without it a timed capture stands still.
        """
        self.set_pose(rotation, position, end=end)
        image = self.mi.render(self.scene, seed=int(seed), spp=int(spp or self.spp))
        return np.array(image, dtype=np.float32)


def set_sensor_pose(mi, params, prefix: str, rotation, position, *, end=None) -> None:
    """Set an omni sensor's frame pose (and the pose one frame interval later) through ``params``."""
    end = end if end is not None else (rotation, position)
    for key, (rot, pos) in (("to_world", (rotation, position)), ("to_world_end", end)):
        matrix = to_world_matrix(rot, pos).astype(np.float32)
        params[prefix + key] = mi.Transform4f(np.ascontiguousarray(matrix))
    params.update()


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
    """Dotted names of the entries where two identity dicts differ, with both values.

    Lists of ``[name, value]`` pairs with distinct names (the assets and their
    SHA-256) are compared as dicts, so a changed file is named.
    """
    if _named_pairs(previous) and _named_pairs(current):
        previous, current = dict(previous), dict(current)
    if isinstance(previous, dict) and isinstance(current, dict):
        out = []
        for key in sorted(set(previous) | set(current), key=str):
            out += _differences(previous.get(key), current.get(key), f"{prefix}{key}.")
        return out
    if previous == current:
        return []
    return [f"{prefix[:-1]} (folder: {json_excerpt(previous)}, now: {json_excerpt(current)})"]


def _named_pairs(value) -> bool:
    """True for a list of ``[name, value]`` pairs whose names are distinct strings."""
    return (isinstance(value, list) and all(isinstance(p, list) and len(p) == 2 and isinstance(p[0], str)
                                            for p in value)
            and len({p[0] for p in value}) == len(value))


# Most differences named in a refusal.
SHOWN_DIFFERENCES = 3


def _has_written_frames(out_dir: Path, meta: dict | None) -> bool:
    """True when ``meta`` records a frame file, or a frame folder (images, AOVs) holds a file."""
    kinds = ("images",) + tuple(AOV_NAMES)
    if meta is not None and any(meta.get(kind) for kind in kinds):
        return True
    return any((out_dir / kind).is_dir() and any((out_dir / kind).iterdir()) for kind in kinds)


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
        ``meta.json`` (a FIFO in its place is not read) or one omnisim did not
        write (no identity), or files without one.
    """
    meta_path = out_dir / "meta.json"
    if not out_dir.exists():
        return None
    if not out_dir.is_dir():
        raise InputError(out_dir, "exists and is not a folder")
    if meta_path.exists():
        if not (meta_path.is_file() or meta_path.is_dir()):  # a FIFO would block the read
            raise InputError(meta_path, "is a FIFO, device or socket, not a meta.json file; remove it or "
                                        "choose another --out")
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raise InputError(meta_path, "unreadable meta.json; remove the folder or choose another --out") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("images", {}), dict):
            raise InputError(meta_path, "expected a JSON object with an 'images' table; remove the folder "
                                        "or choose another --out")
        for kind in AOV_NAMES:  # the per-pixel ground truth's tables are read as the images' are
            if not isinstance(meta.get(kind, {}), dict):
                raise InputError(meta_path, f"expected its {kind!r} entry to be a table (file name: sha256), "
                                            f"got {type(meta[kind]).__name__}; remove the folder or choose "
                                            "another --out")
        previous = meta.get("identity")
        if not isinstance(previous, dict) or "format" not in previous:
            # Not written by omnisim: a user's meta.json (and the files beside it) is never replaced.
            raise InputError(meta_path, "is not an omnisim dataset's (no 'identity' with a 'format'); "
                                        "refusing to write a dataset into this folder: choose another --out")
        if previous == identity:
            return meta
        if not _has_written_frames(out_dir, meta):
            return None
        changed = _differences(previous, identity)
        shown = "; ".join(changed[:SHOWN_DIFFERENCES]) + (" ..." if len(changed) > SHOWN_DIFFERENCES else "")
        raise InputError(out_dir, f"holds a dataset made with different {shown or 'settings'}; "
                                  "refusing to mix (choose another --out or remove it)")
    if any(p.name not in ("images",) + tuple(AOV_NAMES) for p in out_dir.iterdir()) \
            or _has_written_frames(out_dir, None):
        raise InputError(out_dir, "is not empty and has no meta.json; refusing to write a dataset into it")
    return None


def open_output_folder(out_dir: Path, identity: dict) -> dict:
    """Check an output folder (:func:`check_output_folder`), create ``images/``, return its meta.

    The meta is the folder's ``meta.json`` when it holds the same identity,
    else a fresh one with no images recorded. Temporary files a killed
    earlier run left in the folder and its folders are removed
    (:func:`ifmi.io.atomic.remove_leftovers`).

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
    # The folder is this command's: temporaries a killed earlier run left in it or its folders
    # (images/.000003.png.PID-XXXXXXXX.tmp) go before any frame is listed.
    try:
        folders = [out_dir] + sorted(p for p in out_dir.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError as exc:
        raise OutputError.from_os_error(out_dir, exc) from None
    for folder in folders:
        remove_leftovers(folder)
    return meta if meta is not None else {"identity": identity, "images": {}, "complete": False}


def pending_images(out_dir: Path, meta: dict, names: list) -> list:
    """Indices of the image ``names`` still to write: missing, or not matching the recorded SHA-256.

    Stale records are dropped from ``meta["images"]``.

    Raises
    ------
    InputError
        A folder, FIFO or device in the place of a frame file, or a symbolic
        link to a file other than the frame (:func:`frame_file_matches`).
    """
    todo = []
    for k, name in enumerate(names):
        if not frame_file_matches(out_dir / "images" / name, meta["images"].get(name)):
            meta["images"].pop(name, None)
            todo.append(k)
    return todo


def frame_file_matches(path: Path, recorded: str | None) -> bool:
    """Whether the frame file ``path`` of an output folder holds the bytes ``meta.json`` records.

    Parameters
    ----------
    path : Path
        A frame's file (``images/000003.png``, ``depth/000003.npy``); it may be missing.
    recorded : str or None
        Its SHA-256 in ``meta.json``, None when none is recorded.

    Raises
    ------
    InputError
        Something else than a regular file stands at ``path`` (a folder, a
        FIFO, a device): it is neither read (a FIFO would block) nor replaced.
        Or ``path`` is a symbolic link whose file does not hold the recorded
        bytes (or that leads nowhere): a write would go through it and
        replace a file outside the output folder.
    """
    if path.exists() and not path.is_file():
        kind = "a folder" if path.is_dir() else "a FIFO, device or socket"
        raise InputError(path, f"is {kind} where the output folder's frame file belongs; remove it or "
                               "choose another --out")
    matches = recorded is not None and path.exists() and sha256_file(path) == recorded
    if not matches and path.is_symlink():
        raise InputError(path, f"is a symbolic link to {os.path.realpath(path)}, which does not hold the frame "
                               "meta.json records; refusing to write through it (remove the link or choose "
                               "another --out)")
    return matches


@dataclass(frozen=True)
class FramePlan:
    """Everything a process needs to render the frames of one dataset (picklable, sent to workers).

    config : the scene; seed : sequence seed; variant : Mitsuba variant;
    trajectory : camera-to-world poses at the frame times (one more than the
    frames when the capture is timed: frame k moves towards pose k + 1);
    gains : per-frame exposure gains; aovs : AOV names to write (:data:`omnisim.aov.AOV_NAMES`).
    """

    config: SceneConfig
    seed: int
    variant: str
    trajectory: WorldPoses
    gains: tuple
    aovs: tuple = ()

    @property
    def key(self) -> str:
        """Digest identifying the plan (a worker keeps one loaded scene per key)."""
        text = json.dumps([self.config.sha256, self.config.settings_dict(), self.seed, self.variant,
                           list(self.aovs)], sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()


def frame_file_names(k: int) -> dict:
    """Relative paths of frame ``k``'s files: image and each AOV."""
    return {"images": f"images/{k:06d}.png", **{name: f"{name}/{k:06d}.npy" for name in AOV_NAMES}}


class FrameRenderer:
    """Renders the files of single frames of a :class:`FramePlan` (image, then AOVs).

    The image is rendered at the plan's spp with the scene's capture timing,
    vignetted in linear radiance, then exposure gain, sRGB 8-bit, effects and
    PNG encoding follow. AOVs come from a one-ray-per-pixel-centre pass
    (:mod:`omnisim.aov`).
    """

    def __init__(self, plan: FramePlan):
        self.plan = plan
        self.renderer = OmniRenderer(plan.config, variant=plan.variant)
        cam, capture = plan.config.camera, plan.config.capture
        self.vignetting = (vignetting_from_pixels(cam.model, strength=capture.vignetting,
                                                  radius_max=cam.radius_max)
                           if capture.vignetting > 0 else None)
        self._aov_pass = None

    def _poses(self, k: int):
        traj = self.plan.trajectory
        start = (traj.rotations[k], traj.positions[k])
        end = (traj.rotations[k + 1], traj.positions[k + 1]) if self.plan.config.capture.timed else None
        return start, end

    def linear(self, k: int) -> np.ndarray:
        """Frame ``k`` in linear RGB (H, W, 3) float32, vignetted (before gain and tone mapping)."""
        (rotation, position), end = self._poses(k)
        linear = self.renderer.render(rotation, position, seed=frame_seed(self.plan.seed, k), end=end)[..., :3]
        return linear if self.vignetting is None else linear * self.vignetting[..., None]

    def image_png(self, k: int) -> bytes:
        """Frame ``k`` as PNG bytes (8-bit sRGB, effects applied)."""
        image = srgb_uint8_from_linear(self.linear(k), gain=float(self.plan.gains[k]))
        image = apply_effects(image, self.plan.config.effects, seed=self.plan.seed, frame=k)
        return encode_png(image)

    def aov_arrays(self, k: int) -> dict:
        """Depth (H, W) and camera-frame normals (H, W, 3) of frame ``k``, float32 (:mod:`omnisim.aov`)."""
        mi = self.renderer.mi
        if self._aov_pass is None:
            sensor = mi.load_dict(aov_sensor_dict(self.plan.config, mi), parallel=False)
            self._aov_pass = (sensor, mi.load_dict(aov_integrator_dict()), mi.traverse(sensor))
        sensor, integrator, params = self._aov_pass
        (rotation, position), end = self._poses(k)
        set_sensor_pose(mi, params, "", rotation, position, end=end)
        image = np.array(mi.render(self.renderer.scene, sensor=sensor, integrator=integrator, spp=1, seed=0))
        height = image.shape[0]
        capture = self.plan.config.capture
        if capture.timed:
            rows = poses_at_times(self.plan.trajectory, k + row_mid_times(height, capture)).rotations
        else:
            rows = np.broadcast_to(rotation, (height, 3, 3))
        depth, normal = depth_normal_from_aov(image, rows)
        return {"depth": depth, "normal": normal}

    def files(self, k: int, kinds) -> dict:
        """Bytes of frame ``k``'s files of the given kinds ("images" and AOV names), by relative path."""
        names = frame_file_names(k)
        out = {}
        if "images" in kinds:
            out[names["images"]] = self.image_png(k)
        if any(kind in AOV_NAMES for kind in kinds):
            for name, array in self.aov_arrays(k).items():
                if name in kinds:
                    out[names[name]] = npy_bytes(array)
        return out


def render_frame_files(renderer: FrameRenderer, job) -> tuple:
    """``(k, files)`` of one job ``(k, kinds)``: the unit of work of a render (local or on workers)."""
    k, kinds = job
    return k, renderer.files(k, kinds)


def _trajectory_samples(config: SceneConfig, seed: int) -> WorldPoses:
    """Poses at the frame times; a timed capture needs the pose after the last frame too."""
    settings = config.trajectory
    if not config.capture.timed:
        return poses_in_model_frame(poses_for_settings(settings, seed=seed), config.camera.model)
    if settings.frames >= MAX_FRAMES:  # the pose after the last frame would be one beyond the bound
        raise InputError(config.path, f"frames: expected at most {MAX_FRAMES - 1} with [capture] exposure or "
                                      "rolling_shutter (they interpolate towards the pose after the last frame), "
                                      f"got {settings.frames}")
    try:
        poses = poses_for_settings(replace(settings, frames=settings.frames + 1), seed=seed)
        return poses_in_model_frame(poses, config.camera.model)
    except InputError as exc:
        raise InputError(exc.path, f"{exc.problem} (motion blur and rolling shutter interpolate "
                                   "towards the pose after the last frame)") from None


def _write_ground_truth(out_dir: Path, config: SceneConfig, trajectory: WorldPoses) -> dict:
    """groundtruth.txt, poses_world.txt and per-row poses; returns {file name: sha256} of the latter."""
    n, capture = config.trajectory.frames, config.capture
    when = ground_truth_time(capture)
    truth = (poses_at_times(trajectory, np.arange(n) + when) if capture.timed
             else WorldPoses(rotations=trajectory.rotations[:n], positions=trajectory.positions[:n]))
    note = f" at time k + {when:g} frame intervals (mid-exposure of the middle row)" if capture.timed else ""
    write_tum(out_dir / "groundtruth.txt", relative_trajectory(truth),
              header=f"omnisim ground truth of {config.name}: T_0k, camera k in camera 0{note}")
    write_tum(out_dir / "poses_world.txt", world_trajectory(truth),
              header=f"omnisim world poses of {config.name}: camera-to-world, metres, z up{note}")
    if capture.rolling_shutter <= 0:
        return {}
    offsets = row_mid_times(config.camera.model.size[0], capture)
    rows = (trajectory_in_camera(poses_at_times(trajectory, k + offsets), rotation=truth.rotations[0],
                                 position=truth.positions[0], timestamps=k + offsets) for k in range(n))
    return write_row_poses(out_dir, rows, header=lambda k: f"omnisim rolling shutter of {config.name}, frame {k}: "
                                                        "line r = row r at its mid-exposure, T_0r in camera 0 "
                                                        "of groundtruth.txt; time in frames")


def write_row_poses(out_dir: Path, frames, *, header) -> dict:
    """``rolling_shutter/NNNNNN.txt``: one TUM file per frame, a line per image row (row 0 first).

    Parameters
    ----------
    out_dir : Path
        The dataset folder.
    frames : iterable of Trajectory
        Frame k's rows: ``T_0r`` in camera 0 of ``groundtruth.txt``, the row times as timestamps.
    header : callable, keyword-only
        ``header(k) -> str``: frame k's comment line.

    Returns
    -------
    dict
        ``{file name: sha256 of its text}``, for ``meta.json``.
    """
    records = {}
    for k, rows in enumerate(frames):
        text = format_tum(rows, header=header(k))
        name = f"{k:06d}.txt"
        atomic_write_text(out_dir / "rolling_shutter" / name, text)
        records[name] = hashlib.sha256(text.encode("utf-8")).hexdigest()
    return records


def _pending_jobs(out_dir: Path, meta: dict, frames: int, kinds: tuple) -> list:
    """``(k, kinds)`` for each frame with a missing or altered file; stale records are dropped."""
    jobs = []
    for k in range(frames):
        missing = []
        for kind in kinds:
            rel = frame_file_names(k)[kind]
            name = rel.split("/", 1)[1]
            if not frame_file_matches(out_dir / rel, meta.setdefault(kind, {}).get(name)):
                meta[kind].pop(name, None)
                missing.append(kind)
        if missing:
            jobs.append((k, tuple(missing)))
    return jobs


def _is_black_frame(files: dict) -> bool:
    """Whether the frame's image (``images/*.png`` among ``files``) has every pixel 0."""
    import cv2

    for rel, data in files.items():
        if rel.startswith("images/"):
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            return image is not None and not image.any()
    return False


def _store_frame(out_dir: Path, meta: dict, files: dict) -> None:
    """Write a frame's files atomically and record their SHA-256 in meta.json (then rewritten)."""
    for rel, data in files.items():
        atomic_write_bytes(out_dir / rel, data)
        kind, name = rel.split("/", 1)
        meta.setdefault(kind, {})[name] = hashlib.sha256(data).hexdigest()
        meta[kind] = dict(sorted(meta[kind].items()))
    atomic_write_json(out_dir / "meta.json", meta)


def frame_plan(scene_path, *, frames: int | None = None, seed: int | None = None, spp: int | None = None,
               resolution=None, variant: str | None = None, aovs=()) -> FramePlan:
    """The :class:`FramePlan` of a scene file with the command line's overrides (see :func:`render_dataset`).

    Raises
    ------
    InputError
        Bad scene file or values, a bad AOV name or a negative seed.
    """
    config = load_scene_config(scene_path, spp=spp, resolution=resolution, frames=frames, variant=variant)
    seed = config.layout_seed if seed is None else int(seed)
    if seed < 0:
        raise InputError(scene_path, f"--seed: expected a non-negative integer, got {seed}")
    try:
        aovs = aov_names_from_text(aovs)
    except ValueError as exc:
        raise InputError(scene_path, f"--aov: {exc}") from None
    trajectory = _trajectory_samples(config, seed)
    from omnisim.llvm import import_mitsuba
    mi = import_mitsuba(config.render.variant or None)
    n = config.trajectory.frames
    return FramePlan(config=config, seed=seed, variant=mi.variant(), trajectory=trajectory,
                     gains=tuple(float(g) for g in exposure_gains(n, config.effects, seed=seed)), aovs=aovs)


def frame_results(plan: FramePlan, jobs: list, *, workers: int | None = None, scheduler: str | None = None,
                  renderer: FrameRenderer | None = None, client=None):
    """Iterator of ``(k, files)`` for the jobs ``(k, kinds)``: in this process, or on a Dask cluster.

    ``files`` maps relative paths (``images/000003.png``, ``depth/000003.npy``) to bytes.
    ``renderer`` (of ``plan``) is used in this process instead of loading the scene again.
    ``client`` (of :func:`omnisim.cluster.cluster_client`) is a cluster already connected,
    used instead of ``workers`` or ``scheduler``.
    """
    if client is not None or workers or scheduler:
        from omnisim.cluster import map_on_client, map_on_cluster

        if client is not None:
            yield from map_on_client(client, FrameRenderer, render_frame_files, plan, jobs, key=plan.key)
        else:
            yield from map_on_cluster(FrameRenderer, render_frame_files, plan, jobs, key=plan.key,
                                      variant=plan.variant, workers=workers, scheduler=scheduler)
        return
    renderer = renderer if renderer is not None else FrameRenderer(plan)
    for job in jobs:
        yield render_frame_files(renderer, job)


def _check_parallel_options(scene_path, workers: int | None, scheduler: str | None) -> None:
    """Refuse a ``--workers`` count this machine cannot run or a blank ``--scheduler`` address.

    Raises
    ------
    InputError
        The message names the option, what it expects and what it got.
    """
    if workers is not None and not 1 <= workers <= max_local_workers():
        raise InputError(scene_path, f"--workers: expected >= 1 and at most {max_local_workers()} (the CPUs this "
                                     f"process may use), got {workers}")
    if scheduler is not None and not scheduler.strip():
        raise InputError("--scheduler", f"expected the address of a Dask scheduler (e.g. tcp://HOST:8786), "
                                        f"got {scheduler!r}")


def _cluster_for(plan: FramePlan, out_dir: Path, *, workers: int | None, scheduler: str | None,
                 connect_timeout_s: float):
    """The context of a Dask client for the frames still to render into ``out_dir``, or a null context.

    Nothing is written: the folder is checked as :func:`check_output_folder` checks it.
    No cluster is started when neither ``workers`` nor ``scheduler`` is given or when
    every frame is already there; otherwise the cluster is started or connected when
    the context is entered, so that an unusable ``--scheduler`` fails before the
    output folder is created.
    """
    from contextlib import nullcontext

    if not (workers or scheduler):
        return nullcontext()
    n = plan.config.trajectory.frames
    previous = check_output_folder(out_dir, _dataset_identity(plan.config, plan.seed, plan.variant))
    if previous is not None and not _pending_jobs(out_dir, copy.deepcopy(previous), n,
                                                  ("images",) + plan.aovs):
        return nullcontext()
    from omnisim.cluster import cluster_client

    return cluster_client(variant=plan.variant, workers=workers, scheduler=scheduler,
                          connect_timeout_s=connect_timeout_s)


def render_dataset(scene_path, out_dir, *, frames: int | None = None, seed: int | None = None,
                   spp: int | None = None, resolution=None, progress: bool = True,
                   variant: str | None = None, aovs=(), workers: int | None = None,
                   scheduler: str | None = None,
                   connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S) -> DatasetResult:
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
    aovs : str or sequence of str, keyword-only
        Per-pixel ground truth to write beside the images: "depth", "normal" (:mod:`omnisim.aov`).
    workers : int, optional, keyword-only
        Render on a local Dask cluster of this many worker processes, 1 to
        :func:`ifmi.runtime.local_workers.max_local_workers`.
    scheduler : str, optional, keyword-only
        Render on the Dask cluster at this scheduler address (workers must see the scene's files).
    connect_timeout_s : float, keyword-only
        Seconds ``scheduler`` has to accept the connection and answer, > 0.

    Returns
    -------
    DatasetResult

    Raises
    ------
    InputError
        Bad scene file or values, an output folder holding another render, or a
        ``scheduler`` that is blank or cannot be connected to; raised before
        anything is written.
    OutputError
        A file cannot be written (the message names it and the OS reason).
    ClusterError
        The Dask cluster was lost during the render (a worker that dies is
        replaced and its frame rendered again); the frames written are kept
        and a rerun renders the rest.
    """
    _check_parallel_options(scene_path, workers, scheduler)
    plan = frame_plan(scene_path, frames=frames, seed=seed, spp=spp, resolution=resolution,
                      variant=variant, aovs=aovs)
    config, seed, aovs, n = plan.config, plan.seed, plan.aovs, plan.config.trajectory.frames
    # The whole scene is built and loaded here (files, materials, lights, a Mitsuba scene) before
    # the output folder is touched, so a scene error leaves nothing behind; it also renders
    # the frames unless a cluster does.
    local = FrameRenderer(plan)
    if local.renderer.spp != config.render.spp:
        warnings.warn(f"{scene_path}: [render] spp {config.render.spp}: the {config.render.sampler} sampler "
                      f"renders {local.renderer.spp} samples per pixel (meta.json: spp_rendered)",
                      InputWarning, stacklevel=2)
    out_dir = Path(out_dir)
    kinds = ("images",) + aovs
    # A cluster is started (or a --scheduler connected) before the output folder is created.
    with _cluster_for(plan, out_dir, workers=workers, scheduler=scheduler,
                      connect_timeout_s=connect_timeout_s) as client:
        meta = _open_dataset(scene_path, out_dir, config, seed, plan.variant, plan.trajectory,
                             spp_rendered=local.renderer.spp)
        jobs = _pending_jobs(out_dir, meta, n, kinds)
        start = time.perf_counter()
        rendered, black = _render_jobs(plan, jobs, out_dir, meta, renderer=local, client=client, progress=progress)
    if black:
        warnings.warn(f"{scene_path}: {black} of the {rendered} frames rendered now are black (every pixel 0): "
                      "the camera sees no light (none in the scene, all enclosed, or a negative radiance)",
                      InputWarning, stacklevel=2)
    seconds = time.perf_counter() - start
    meta["complete"] = all(len(meta.get(kind, {})) == n for kind in kinds)
    atomic_write_json(out_dir / "meta.json", meta)
    return DatasetResult(out_dir=str(out_dir), frames=n, rendered=rendered,
                         seconds_per_frame=seconds / rendered if rendered else float("nan"))


def _render_jobs(plan: FramePlan, jobs: list, out_dir: Path, meta: dict, *, renderer: FrameRenderer,
                 client, progress: bool) -> tuple[int, int]:
    """Render ``jobs`` (here, or on ``client``'s cluster when given) and store each frame's files.

    Returns
    -------
    rendered, black : int
        Frames rendered, and how many of them are black (every pixel 0).
    """
    rendered, black = 0, 0
    if not jobs:
        return rendered, black
    from tqdm import tqdm

    n = plan.config.trajectory.frames
    with tqdm(total=n, initial=n - len(jobs), disable=not progress, unit="frame", desc=plan.config.name) as bar:
        for _, files in frame_results(plan, jobs, renderer=renderer, client=client):
            _store_frame(out_dir, meta, files)
            black += _is_black_frame(files)
            rendered += 1
            bar.update(1)
    return rendered, black


def _dataset_identity(config: SceneConfig, seed: int, variant: str) -> dict:
    """What an output folder's frames were made with: a rerun with another identity is refused."""
    return {
        "scene_sha256": config.sha256,
        "seed": seed,
        "variant": variant,
        "settings": json.loads(json.dumps(config.settings_dict())),
        "format": META_FORMAT,
        "renderer": RENDERER_VERSION,
    }


def _open_dataset(scene_path, out_dir: Path, config: SceneConfig, seed: int, variant: str,
                  trajectory: WorldPoses, *, spp_rendered: int) -> dict:
    """Check or create the folder, write calibration, ground truth and meta.json; return the meta."""
    meta = open_output_folder(out_dir, _dataset_identity(config, seed, variant))
    meta.update({
        "scene_file": str(Path(scene_path).resolve()),
        "scene_name": config.name,
        "seed": seed,
        "spp": config.render.spp,
        "spp_rendered": spp_rendered,
        "resolution": list(config.render.resolution),
        "frames": config.trajectory.frames,
        "variant": variant,
        "versions": _versions(),
        "capture": asdict(config.capture),
    })
    write_camera(out_dir, config.camera.model)  # calib_results.txt or camera.yaml
    rows = _write_ground_truth(out_dir, config, trajectory)
    if rows:
        meta["rolling_shutter"] = rows
    atomic_write_json(out_dir / "meta.json", meta)
    return meta
