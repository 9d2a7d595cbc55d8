"""Estimation pipeline: front-end protocol, method registry and sequence estimation.

A *front end* turns images into ray correspondences; the relative-pose back
end (:mod:`ifmi.relative_pose`) and the trajectory chaining
(:mod:`ifmi.odometry`) are shared by every method, so comparisons isolate the
front end. A front end is an object with

``prepare(image) -> state``
    per-frame work that does not depend on the other frame (panorama, tile
    spectra, keypoints); ``image`` is ``(H, W)`` or ``(H, W, 3)`` uint8. The
    odometry keeps the state of a keyframe, so it is prepared once;
``correspondences(state_a, state_b) -> Correspondences``
    matching of a reference frame ``a`` against frame ``b``. A front end
    whose ``uses_prior_rotation`` attribute is true is called with the
    keyword ``prior_rotation`` (a predicted ``R_ab``) as well.

Methods are created by name through :func:`create_front_end`; a factory
receives the camera model and the whole :class:`EstimateConfig` and reads the
part that concerns it (``config.ifmi`` for ``"ifmi"``, ``config.features`` for
the feature baselines).
"""

from __future__ import annotations

import importlib
import os
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Protocol, Sequence

import numpy as np
from tqdm import tqdm

from .camera import OcamModel
from .errors import CalibrationFitError, InputError
from .trajectory import Trajectory
from .options import options_from_dict
from .odometry import FrameRecord, KeyframeOptions, track_sequence
from .relative_pose import RelativePoseOptions
from .spectral_front_end import IfmiConfig
from .unwarp import angular_pixel_size_in_band

__all__ = [
    "Correspondences",
    "FrontEnd",
    "EstimateConfig",
    "SequenceEstimate",
    "FrameRecord",
    "METHODS",
    "method_names",
    "create_front_end",
    "estimate_sequence",
    "estimate_dataset",
    "estimate_video",
    "resolved_config",
]


@dataclass(frozen=True)
class Correspondences:
    """Matched points of a frame pair.

    Attributes
    ----------
    pixels_a, pixels_b : (N, 2) ndarray
        Omni-image ``(row, col)`` of each match in frame a and frame b.
    rays_a, rays_b : (N, 3) ndarray
        Unit rays of those pixels in the camera frame.
    diagnostics : dict
        JSON-serialisable scalars (counts, quality figures).
    success : bool
    reason : str
        Empty on success, else why matching failed.
    rays_per_measurement : int
        Consecutive matches that come from one measurement and share its
        error (flow points of one tile); 1 for keypoint matches.
    """

    pixels_a: np.ndarray
    pixels_b: np.ndarray
    rays_a: np.ndarray
    rays_b: np.ndarray
    diagnostics: dict = field(default_factory=dict)
    success: bool = True
    reason: str = ""
    rays_per_measurement: int = 1

    @staticmethod
    def failed(reason: str, diagnostics: dict | None = None) -> "Correspondences":
        """Empty correspondences flagged as failed with ``reason``."""
        empty2, empty3 = np.zeros((0, 2)), np.zeros((0, 3))
        return Correspondences(empty2, empty2, empty3, empty3, dict(diagnostics or {}),
                               success=False, reason=reason)


class FrontEnd(Protocol):
    """Per-frame preparation and pairwise matching (see the module docstring)."""

    def prepare(self, image: np.ndarray) -> Any: ...

    def correspondences(self, state_a: Any, state_b: Any) -> Correspondences: ...


def _load_feature_config(data: Mapping[str, Any]):
    module = importlib.import_module("ifmi.features")
    return module.FeatureConfig(**data)


@dataclass(frozen=True)
class EstimateConfig:
    """Everything that determines an estimate, saved as JSON beside each result.

    Attributes
    ----------
    ifmi : IfmiConfig
        Options of the ``"ifmi"`` front end.
    features : FeatureConfig or None
        Options of the ``"orb"``/``"akaze"`` front ends (:mod:`ifmi.features`);
        ``None`` means that module's defaults.
    relative_pose : RelativePoseOptions
    keyframe : KeyframeOptions
    """

    ifmi: IfmiConfig = field(default_factory=IfmiConfig)
    features: Any = None
    relative_pose: RelativePoseOptions = field(default_factory=RelativePoseOptions)
    keyframe: KeyframeOptions = field(default_factory=KeyframeOptions)

    def to_dict(self) -> dict:
        """JSON-serialisable nested dict (inverse of :meth:`from_dict`)."""
        return {
            "ifmi": asdict(self.ifmi),
            "features": None if self.features is None else asdict(self.features),
            "relative_pose": asdict(self.relative_pose),
            "keyframe": asdict(self.keyframe),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "EstimateConfig":
        """Build a config from :meth:`to_dict` output; missing sections take defaults."""
        sections = dict(data)
        ifmi = sections.get("ifmi") or {}
        features = sections.get("features")
        sections.update(
            ifmi=IfmiConfig.from_dict(ifmi),
            features=None if features is None else _load_feature_config(features),
            relative_pose=options_from_dict(RelativePoseOptions, sections.get("relative_pose") or {},
                                            what="relative_pose options"),
            keyframe=options_from_dict(KeyframeOptions, sections.get("keyframe") or {},
                                       what="keyframe options"),
        )
        return options_from_dict(cls, sections, what="config sections")


@dataclass(frozen=True)
class SequenceEstimate:
    """Result of :func:`estimate_sequence`.

    Attributes
    ----------
    trajectory : Trajectory
        ``R_0k`` per frame (translation up to scale), frame 0 the identity.
    frames : tuple of FrameRecord
        One record per frame (frame 0 included, as the reference of itself).
    config : EstimateConfig
    method : str
    """

    trajectory: Trajectory
    frames: tuple
    config: EstimateConfig
    method: str


def _ifmi_factory(model: OcamModel, config: EstimateConfig):
    from .spectral_front_end import IfmiFrontEnd

    return IfmiFrontEnd(model, config.ifmi)


def _orb_factory(model: OcamModel, config: EstimateConfig):
    from .features import orb_front_end

    return orb_front_end(model, config)


def _akaze_factory(model: OcamModel, config: EstimateConfig):
    from .features import akaze_front_end

    return akaze_front_end(model, config)


# Method name -> factory(model, config) -> front end. Other front ends register
# here; factories import their module lazily so that importing the pipeline stays cheap.
METHODS: dict[str, Callable[[OcamModel, EstimateConfig], FrontEnd]] = {
    "ifmi": _ifmi_factory,
    "orb": _orb_factory,
    "akaze": _akaze_factory,
}


def method_names() -> tuple[str, ...]:
    """Registered method names, for command-line choices."""
    return tuple(METHODS)


def create_front_end(method: str, model: OcamModel, config: EstimateConfig) -> FrontEnd:
    """Instantiate the front end registered as ``method``."""
    try:
        factory = METHODS[method]
    except KeyError:
        raise ValueError(f"unknown method {method!r}; expected one of {method_names()}") from None
    return factory(model, config)


def resolved_config(config: EstimateConfig, model: OcamModel) -> EstimateConfig:
    """``config`` with the relative-pose threshold in radians for ``model``.

    An explicit ``relative_pose.ransac_threshold_rad`` is kept; otherwise
    ``relative_pose.ransac_threshold_px`` is converted with
    :func:`ifmi.unwarp.angular_pixel_size_in_band` of the calibration (band from
    ``config.ifmi.panorama``), so the same pixel threshold serves every
    image resolution and every method.
    """
    pose = config.relative_pose
    if pose.ransac_threshold_rad is not None:
        return config
    pixel = angular_pixel_size_in_band(model, config=config.ifmi.panorama)
    return replace(config, relative_pose=pose.resolved(pixel))


def estimate_sequence(images: Iterable[np.ndarray], model: OcamModel, *, method: str,
                      config: EstimateConfig = EstimateConfig(), progress: bool = False,
                      total: int | None = None,
                      timestamps: Sequence[float] | None = None) -> SequenceEstimate:
    """Estimate the orientation of every frame of a sequence.

    Parameters
    ----------
    images : iterable of (H, W) or (H, W, 3) uint8 ndarray
        Frames in order; may be lazy (each frame's ``seconds`` then includes
        producing it, e.g. reading the file).
    model : OcamModel
        Calibration of every frame.
    method : str, keyword-only
        A name of :func:`method_names`.
    config : EstimateConfig, keyword-only
        A relative-pose threshold given in pixels is converted to radians for
        ``model`` (:func:`resolved_config`); the result's ``config`` holds the
        converted one.
    progress : bool, keyword-only
        Show a progress bar on stderr.
    total : int, optional, keyword-only
        Frame count for the progress bar when ``images`` has no length.
    timestamps : (N,) sequence, optional, keyword-only
        Timestamps of the trajectory; default the frame indices.

    Returns
    -------
    SequenceEstimate
    """
    config = resolved_config(config, model)
    front_end = create_front_end(method, model, config)
    if total is None and hasattr(images, "__len__"):
        total = len(images)
    with tqdm(total=total, disable=not progress, file=sys.stderr, unit="frame", desc="estimate") as bar:
        trajectory, records = track_sequence(images, front_end, pose_options=config.relative_pose,
                                             keyframe=config.keyframe, timestamps=timestamps,
                                             on_frame=lambda record: bar.update(1))
    return SequenceEstimate(trajectory=trajectory, frames=tuple(records), config=config,
                            method=method)


def estimate_dataset(dataset_dir: str | os.PathLike, *, method: str,
                     config: EstimateConfig = EstimateConfig(),
                     progress: bool = False, prefetch: bool = True) -> SequenceEstimate:
    """Estimate a DATASET folder (calib_results.txt + images/), read lazily frame by frame.

    With ``prefetch`` the next image is decoded in a background thread while
    the current one is estimated; a frame's ``seconds`` then holds the wait
    for its image instead of the whole decoding time.

    The mirror band is decided from up to five frames spread over the
    sequence (:func:`ifmi.unwarp.panorama_config_with_band`), so a dark
    object in the first frame does not narrow it; the result's ``config``
    holds the radii.

    Raises
    ------
    InputError
        Missing calibration or images, or a first image that is unreadable
        or whose size differs from the calibration's. Such a later image is
        flagged as a failed frame (the pose is held) and the sequence goes on.
        Also a calibration too small for the method (e.g. iFMI tiles larger
        than its panorama), naming the calibration file.
    """
    from .io.dataset import read_dataset

    dataset = read_dataset(Path(dataset_dir))
    # The RANSAC threshold is resolved on the calibration's band first, as for any sequence; the
    # band the panorama uses is then decided from several frames (saved with the configuration).
    config = resolved_config(config, dataset.model)
    config = replace(config, ifmi=replace(config.ifmi, panorama=_panorama_with_band(dataset, config)))
    images = dataset.iter_images(prefetch=prefetch, skip_unreadable=True)
    try:
        return estimate_sequence(images, dataset.model, method=method,
                                 config=config, progress=progress, total=len(dataset.image_paths))
    except CalibrationFitError as exc:
        raise exc.for_file(dataset.calib_path) from None


# Frames, spread evenly over a dataset, that decide the mirror band together.
_BAND_FRAMES = 5


def _panorama_with_band(dataset, config: EstimateConfig):
    """The panorama options with the band decided from up to ``_BAND_FRAMES`` readable frames."""
    from .io.dataset import read_image
    from .unwarp import panorama_config_with_band

    paths = dataset.image_paths
    index = np.unique(np.linspace(0, len(paths) - 1, min(_BAND_FRAMES, len(paths))).round().astype(int))
    frames = []
    for k in index:
        try:
            frames.append(read_image(paths[k], size=dataset.model.size))
        except InputError:
            continue  # an unreadable frame is flagged when the sequence reaches it
    return panorama_config_with_band(dataset.model, frames, config=config.ifmi.panorama)


def estimate_video(video_path: str | os.PathLike, calib_path: str | os.PathLike, *, method: str,
                   config: EstimateConfig = EstimateConfig(), progress: bool = False) -> SequenceEstimate:
    """Estimate a video file's frames (decoded in order by OpenCV) with one calibration.

    The trajectory's timestamps are the frames' presentation times from the
    container, in seconds (:class:`ifmi.io.video.VideoFrames`).

    Raises
    ------
    InputError
        Missing or unreadable calibration or video, frames whose size
        differs from the calibration's, or a calibration too small for the
        method (naming the calibration file).
    """
    from .io.camera_file import read_camera
    from .io.video import VideoFrames

    model = read_camera(Path(calib_path))  # calib_results.txt or a Kalibr camera.yaml
    frames = VideoFrames(video_path, size=model.size)
    try:
        estimate = estimate_sequence(frames, model, method=method, config=config, progress=progress,
                                     total=len(frames) or None)
    except CalibrationFitError as exc:
        raise exc.for_file(calib_path) from None
    trajectory = replace(estimate.trajectory, timestamps=np.asarray(frames.timestamps, dtype=np.float64))
    return replace(estimate, trajectory=trajectory)
