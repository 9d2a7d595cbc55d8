"""The extended-iFMI front end: panorama, tiles, per-tile iFMI, flow, rays; and its options.

``prepare`` unwarps a frame into the panorama, cuts the tiles and computes
their spectra once (a keyframe is prepared once and matched many times);
``solve_pair`` runs a pair through the stages of :mod:`ifmi.spectral.pair_pipeline`
(``correspondences``, the plugin contract's matching, runs those before
the back end), which register the tile pairs, reject bad tiles with the
noise filters and return ray pairs from the flow equation. The front end
holds the geometry each stage uses: where a rotation puts the tiles, the
reference's tracked tiles, the registrations.

:class:`IfmiConfig` groups the options by purpose (panorama, tiling,
registration, coarse stage, recovery, tracking, refinement, rays); a
configuration of the former flat layout is translated
(:func:`translated_ifmi_options`).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Mapping

import cv2
import numpy as np

from ifmi.geometry.camera import OcamModel
from ifmi.options import OptionError, check_finite_fields, options_from_dict
from ifmi.spectral import pair_pipeline as pair_pipeline
from ifmi.front_end import Correspondences, FrontEndBase, SolvedPair
from ifmi.spectral.pair_pipeline import PairDiagnostics, TileMatch, averaged_correspondences
from ifmi.spectral.flow import (flow_from_placements, flow_from_tile_motion, flow_sample_points, pairs_with_rays_a,
                   points_on_centroids)
from ifmi.spectral.global_motion import GlobalMotion, GlobalMotionConfig, GlobalMotionEstimator
from ifmi.spectral.compression import is_block_compressed
from ifmi.spectral.fourier_mellin import (FourierMellin, FourierMellinConfig, PlacedRegistration, PlacedTiles,
                            TileSpectra)
from ifmi.errors import CalibrationFitError
from ifmi.backend.relative_pose import rotation_angles, rotation_from_rays
from ifmi.geometry.rotations import matrix_aligning_rays
from ifmi.spectral.tiling import TileLayout, TilingConfig, tile_layout, tile_size_px, tiles_from_panorama
from ifmi.spectral.panorama import (PANORAMA_INTERPOLATIONS, PanoramaConfig, PanoramaMapping, gray_from_image,
                     panorama_image_from_omni_image, panorama_mapping, panorama_pixels_from_rays,
                     rays_from_panorama_pixels)

__all__ = ["IfmiConfig", "RegistrationOptions", "CoarseOptions", "RecoveryOptions", "TrackingOptions",
           "RefinementOptions", "RaysOptions", "IfmiFrameState", "IfmiFrontEnd", "averaged_correspondences",
           "translated_ifmi_options"]

# Step (panorama pixels) of the central differences that give a predicted map's curvature: about
# a quarter of a 64 px tile, where the second-order term matters, and far above rounding.
_CURVATURE_STEP_PX = 16.0
# Cauchy reweighting steps of the tiles' own rotation fit (refit passes), and the fewest kept tiles it needs.
_REFIT_ITERATIONS = 3
_MIN_REFIT_TILES = 8
# Most refit passes: each re-measures the kept tiles (about one registration) and the default is one.
_MAX_REFIT_PASSES = 10
# A refit is skipped when the tiles' median residual against their own rotation exceeds a quarter
# panorama pixel: a registration's error is a few hundredths of a pixel, so more is parallax or wrong tiles.
_REFIT_MAX_RESIDUAL_PX = 0.25
# With a refit to follow, the refinement passes run only on the refitted shape when the search pass
# moved the kept tiles by at most half a pixel (median): one pass converges from there.
_SINGLE_REFINEMENT_MAX_PX = 0.5
# A tile's rays are turned to its landmark only when its measured centre lies within a quarter panorama
# pixel of it (the registration's error is far below; parallax or a slipped tile moves it farther).
_LANDMARK_GATE_PX = 0.25
# Offset of the outer flow points of a tile from its centre, fraction of the tile size: inside the
# window's bulk (the Hann window falls to half at a quarter of the tile from the centre).
_POINT_SPREAD = 0.1
# Tile kernels of ``RegistrationOptions.resample_interpolation="auto"`` on narrow and on wide panoramas.
_NARROW_KERNEL = "cubic"
_WIDE_KERNEL = "lanczos4"


@dataclass(frozen=True)
class RegistrationOptions:
    """Per-tile registration (:class:`~ifmi.spectral.fourier_mellin.FourierMellinConfig` holds the rest, at its defaults).

    Attributes
    ----------
    th_pr : float
        Noise filter: smallest accepted peak ratio of a tile's translation correlation (ratio).
    th_pnr : float
        Noise filter: smallest accepted peak-to-noise ratio of that correlation (ratio).
    refine_passes : int
        Passes that resample tile b with the full motion and fit the residual translation (count, at most 10).
    estimate_rotation_scale : bool
        Measure each tile's residual rotation and scale (log-polar stage).
    resample_interpolation : {"auto", "cubic", "lanczos4", "linear"}
        Kernel that resamples tiles of frame b at their placements. ``"auto"``: bicubic on panoramas
        narrower than ``refinement.min_width_sharp``, the 8x8 Lanczos kernel on wider ones. On sharp
        1024 px sequences Lanczos keeps the interpolation bias smallest (pure-rotation warps of three
        1024 px frames: bicubic's ATE 1.2-2.3x Lanczos's); on the 512 px benchmark sets Lanczos took about
        a fifth of the compute per frame for no lower ATE (bicubic's 0.69-1.06x Lanczos's over four sets
        in both odometry modes).
    workers : int
        FFT threads (count).
    """

    th_pr: float = FourierMellinConfig.th_pr
    th_pnr: float = FourierMellinConfig.th_pnr
    refine_passes: int = FourierMellinConfig.refine_passes
    estimate_rotation_scale: bool = FourierMellinConfig.estimate_rotation_scale
    resample_interpolation: str = "auto"
    workers: int = FourierMellinConfig.workers

    def __post_init__(self) -> None:
        self.engine_config()  # its checks

    def engine_config(self, *, wide: bool = False) -> FourierMellinConfig:
        """The registration engine's options: these, and the engine's defaults for the rest.

        ``wide``: the panorama is at least ``refinement.min_width_sharp`` wide (it chooses the
        kernel of ``resample_interpolation="auto"``).
        """
        kernel = self.resample_interpolation
        if kernel == "auto":
            kernel = _WIDE_KERNEL if wide else _NARROW_KERNEL
        return FourierMellinConfig(th_pr=self.th_pr, th_pnr=self.th_pnr, refine_passes=self.refine_passes,
                                   estimate_rotation_scale=self.estimate_rotation_scale,
                                   resample_interpolation=kernel, workers=self.workers)


@dataclass(frozen=True)
class CoarseOptions:
    """Coarse stage: the rotation from whole low-resolution panoramas (:mod:`ifmi.spectral.global_motion`).

    Attributes
    ----------
    enabled : bool
        Correct the prediction with the coarse stage before the tiles (needs ``tracking.use_prior``).
    prediction_check_tiles : float
        A correction of at most this many tile widths is checked by registering the tiles at the
        prediction too (the one keeping more tiles wins); 0 turns the check off.
    confirm_angle_rad : float
        A coarse correction larger than this is confirmed before it is taken, and is what makes a
        pair with few tiles eligible for the wide search (radians).
    """

    enabled: bool = True
    prediction_check_tiles: float = 0.125
    confirm_angle_rad: float = GlobalMotionConfig.confirm_angle_rad

    def __post_init__(self) -> None:
        check_finite_fields(self, ("confirm_angle_rad",))
        if not 0 <= self.prediction_check_tiles < 0.5:
            raise ValueError(f"expected 0 <= prediction_check_tiles < 0.5, got {self.prediction_check_tiles}")
        self.engine_config()  # its checks

    def engine_config(self) -> GlobalMotionConfig:
        """The coarse stage's options: these, and its defaults for the rest."""
        return GlobalMotionConfig(confirm_angle_rad=self.confirm_angle_rad)


@dataclass(frozen=True)
class RecoveryOptions:
    """What a pair whose first registration is weak, or whose solution is doubtful, tries next.

    Attributes
    ----------
    wide_search_fraction : float
        At most this fraction of the tiles kept after a large coarse correction: search tilted starts
        around the prediction; an unsolved pair searches from every start. 0 turns both off.
    dense_retry_fraction : float
        At most this fraction of the tiles kept: register a denser layout cut anew from frame a at
        the same rotation, keep the one with more tiles. 0 turns it off.
    dense_overlap : float
        Overlap of the dense retry's layout (fraction of a tile).
    half_turn_check_rad : float
        A solution farther than this from the prediction is solved again from its half turn about the
        panorama axis (radians); pi turns the check off.

    Notes
    -----
    A pair of an uncompressed capture that no stage solved goes through every stage once more with
    the band-limited search of noise-dominated pairs
    (:attr:`~ifmi.spectral.fourier_mellin.FourierMellinConfig.noisy_pair_fraction`), which only
    block-compressed captures use from the start; the retry is kept when it solves the pair
    (:meth:`IfmiFrontEnd.solve_pair`). Pairs that are solved are left exactly as they were.
    """

    wide_search_fraction: float = 0.33
    dense_retry_fraction: float = 0.33
    dense_overlap: float = 0.5
    half_turn_check_rad: float = math.pi / 2

    def __post_init__(self) -> None:
        if not 0 <= self.dense_retry_fraction <= 1 or not 0 <= self.dense_overlap < 1:
            raise ValueError(f"expected 0 <= dense_retry_fraction <= 1 and 0 <= dense_overlap < 1, got "
                             f"{self.dense_retry_fraction}, {self.dense_overlap}")
        if not 0 <= self.wide_search_fraction <= 1:
            raise ValueError(f"expected 0 <= wide_search_fraction <= 1, got {self.wide_search_fraction}")
        if not 0 <= self.half_turn_check_rad <= math.pi:
            raise ValueError(f"expected 0 <= half_turn_check_rad <= pi, got {self.half_turn_check_rad}")


@dataclass(frozen=True)
class TrackingOptions:
    """How tiles follow the motion from frame to frame.

    Attributes
    ----------
    use_prior : bool
        Cut each tile of frame b where the predicted rotation moves tile a's content, with its local affine map.
    track_tiles : bool
        A frame that becomes a reference keeps the tiles it was registered with instead of cutting
        new ones at the layout (placement errors then cancel along the trajectory).
    anchor_templates : bool
        Tracked tiles keep the template of the frame they were first cut from, instead of being re-cut
        from every frame.
    max_tile_distortion : float
        A tracked tile stretched or shrunk by more than this factor is cut anew (ratio).
    landmark_rays : bool
        On wide panoramas, turn a reference's tracked tiles' rays towards the frame-0 ray each tile was
        first seen along, as the accepted pose sees it.
    landmark_weight : float
        Part of the way to the landmark a tile's rays are turned, in ``(0, 1]``.
    """

    use_prior: bool = True
    track_tiles: bool = True
    anchor_templates: bool = True
    max_tile_distortion: float = 1.25
    landmark_rays: bool = True
    landmark_weight: float = 0.5

    def __post_init__(self) -> None:
        if not self.max_tile_distortion > 1:
            raise ValueError(f"expected max_tile_distortion > 1, got {self.max_tile_distortion}")
        if not 0 < self.landmark_weight <= 1:
            raise ValueError(f"expected 0 < landmark_weight <= 1, got {self.landmark_weight}")


@dataclass(frozen=True)
class RefinementOptions:
    """Second looks at a pair's tiles: at the solved rotation, and along the predicted map's curvature.

    Attributes
    ----------
    reregister_fraction : float
        At most this fraction of the tiles kept and the pair solved: register its tiles again at the
        solved rotation and average the two registrations; 0 turns it off.
    reregister_min_px : float
        ... only when the solved rotation moves the tiles at least this far (panorama pixels).
    curved_placement : bool
        Cut tile b along the predicted map's second-order term too, on panoramas of any width:
        an affine cut leaves a bias that is a fixed fraction of the tilt's displacement at every
        width (the tile spans the same angle), and it grows with the rotation between the frames.
    refit_passes : int
        With curved placements: passes that re-measure the kept tiles with the shape of their own
        robust rotation (count, at most 10).
    min_width_sharp : int
        Panorama width from which the panorama counts as sharp (pixels): landmark rays,
        ``wide_panorama_interpolation`` and the Lanczos tile kernel of
        ``registration.resample_interpolation="auto"`` apply from it; curved placements and refit
        passes do not depend on it. Called ``min_width_curved`` in older configuration files.
    wide_panorama_interpolation : {"linear", "cubic", "lanczos4"}
        Kernel that resamples the omni image into panoramas at least ``min_width_sharp`` wide
        (narrower ones are bilinear).
    """

    reregister_fraction: float = 0.6
    reregister_min_px: float = 0.3
    curved_placement: bool = True
    refit_passes: int = 1
    min_width_sharp: int = 1536
    wide_panorama_interpolation: str = "lanczos4"

    def __post_init__(self) -> None:
        if not 0 <= self.reregister_fraction <= 1 or not self.reregister_min_px >= 0:
            raise ValueError(f"expected 0 <= reregister_fraction <= 1 and reregister_min_px >= 0, got "
                             f"{self.reregister_fraction}, {self.reregister_min_px}")
        if not 0 <= self.refit_passes <= _MAX_REFIT_PASSES or self.min_width_sharp < 0:
            raise ValueError(f"expected 0 <= refit_passes <= {_MAX_REFIT_PASSES} and min_width_sharp >= 0, got "
                             f"{self.refit_passes}, {self.min_width_sharp}")
        if self.wide_panorama_interpolation not in PANORAMA_INTERPOLATIONS:
            raise ValueError(f"wide_panorama_interpolation must be one of {sorted(PANORAMA_INTERPOLATIONS)}, "
                             f"got {self.wide_panorama_interpolation!r}")


@dataclass(frozen=True)
class RaysOptions:
    """How a pair's kept tiles become ray pairs.

    Attributes
    ----------
    points_per_tile : int
        Flow points per kept tile: 1, 5 or 9.
    at_energy_centroid : bool
        Centre each tile's flow points on its reference tile's energy centroid instead of its centre.
    min_tiles : int
        Fewer kept tiles than this fails the pair (count).
    """

    points_per_tile: int = 5
    at_energy_centroid: bool = True
    min_tiles: int = 3

    def __post_init__(self) -> None:
        if self.points_per_tile not in (1, 5, 9):
            raise ValueError(f"points_per_tile must be 1, 5 or 9, got {self.points_per_tile}")
        if self.min_tiles < 1:
            raise ValueError(f"expected min_tiles >= 1, got {self.min_tiles}")


@dataclass(frozen=True)
class IfmiConfig:
    """Options of the iFMI front end, by purpose.

    Attributes
    ----------
    panorama : PanoramaConfig
        The omni image's band unwarped into a panorama (:mod:`ifmi.spectral.panorama`).
    tiling : TilingConfig
        The tile layout on the panorama (:mod:`ifmi.spectral.tiling`).
    registration : RegistrationOptions
    coarse : CoarseOptions
    recovery : RecoveryOptions
    tracking : TrackingOptions
    refinement : RefinementOptions
    rays : RaysOptions
    """

    panorama: PanoramaConfig = field(default_factory=PanoramaConfig)
    tiling: TilingConfig = field(default_factory=TilingConfig)
    registration: RegistrationOptions = field(default_factory=RegistrationOptions)
    coarse: CoarseOptions = field(default_factory=CoarseOptions)
    recovery: RecoveryOptions = field(default_factory=RecoveryOptions)
    tracking: TrackingOptions = field(default_factory=TrackingOptions)
    refinement: RefinementOptions = field(default_factory=RefinementOptions)
    rays: RaysOptions = field(default_factory=RaysOptions)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "IfmiConfig":
        """Inverse of ``dataclasses.asdict``; missing keys take defaults; a mapping of the former flat
        layout is translated (:func:`translated_ifmi_options`).

        Every value is type-checked (:func:`ifmi.options.options_from_dict`);
        errors name the key path under ``ifmi``.
        """
        return options_from_dict(cls, translated_ifmi_options(data), what="ifmi")

    def to_dict(self) -> dict:
        """Nested dict of plain values (inverse of :meth:`from_dict`)."""
        return asdict(self)


# Keys of the former flat layout of the ifmi section and where they are now.
_MOVED_KEYS = {
    "use_prior": "tracking.use_prior", "track_tiles": "tracking.track_tiles",
    "anchor_templates": "tracking.anchor_templates", "max_tile_distortion": "tracking.max_tile_distortion",
    "landmark_rays": "tracking.landmark_rays", "landmark_weight": "tracking.landmark_weight",
    "coarse_to_fine": "coarse.enabled", "prediction_check_tiles": "coarse.prediction_check_tiles",
    "global_motion.confirm_angle_rad": "coarse.confirm_angle_rad",
    "wide_search_fraction": "recovery.wide_search_fraction", "dense_retry_fraction": "recovery.dense_retry_fraction",
    "dense_overlap": "recovery.dense_overlap", "half_turn_check_rad": "recovery.half_turn_check_rad",
    "reregister_fraction": "refinement.reregister_fraction", "reregister_min_px": "refinement.reregister_min_px",
    "curved_placement": "refinement.curved_placement", "refit_passes": "refinement.refit_passes",
    "min_width_curved": "refinement.min_width_sharp",
    "refinement.min_width_curved": "refinement.min_width_sharp",
    "wide_panorama_interpolation": "refinement.wide_panorama_interpolation",
    "points_per_tile": "rays.points_per_tile", "flow_at_energy_centroid": "rays.at_energy_centroid",
    "min_tiles": "rays.min_tiles",
}


def _fixed_values() -> dict:
    """Former options of the ifmi section that are now fixed, and their value."""
    from ifmi.spectral.pair_pipeline import HALF_TURN_INLIER_FRACTION, HALF_TURN_YAW_WINDOW_RAD

    fixed = {"point_spread": _POINT_SPREAD, "dense_tiles_per_column": None,
             "refit_max_residual_px": _REFIT_MAX_RESIDUAL_PX, "single_refinement_max_px": _SINGLE_REFINEMENT_MAX_PX,
             "landmark_gate_px": _LANDMARK_GATE_PX, "half_turn_inlier_fraction": HALF_TURN_INLIER_FRACTION,
             "half_turn_yaw_window_rad": HALF_TURN_YAW_WINDOW_RAD}
    for section, engine, kept in (("registration", FourierMellinConfig(), RegistrationOptions),
                                  ("global_motion", GlobalMotionConfig(), CoarseOptions)):
        kept_names = {f.name for f in fields(kept)}
        fixed.update({f"{section}.{f.name}": getattr(engine, f.name) for f in fields(engine)
                      if f.name not in kept_names})
    return fixed


def _same_value(given, fixed) -> bool:
    """Whether a JSON value ``given`` is the fixed value ``fixed`` (a list for a tuple; no bool for a number)."""
    if isinstance(fixed, tuple):
        return isinstance(given, (list, tuple)) and list(given) == list(fixed)
    return isinstance(given, bool) == isinstance(fixed, bool) and given == fixed


def translated_ifmi_options(data: Mapping[str, Any]) -> Mapping[str, Any]:
    """An ``ifmi`` section of the former flat layout in the grouped one; any other mapping as it is.

    A moved key goes to its new place (``use_prior`` to ``tracking.use_prior``); a former option
    that is now fixed is dropped when it holds the fixed value.

    Raises
    ------
    OptionError
        A former option that is now fixed holds another value, or a moved key is given at both places
        (named, with the new key or the fixed value).
    """
    if not isinstance(data, Mapping):
        return data
    flat = {}
    for key, value in data.items():
        if key in ("registration", "global_motion", "refinement") and isinstance(value, Mapping):
            flat.update({f"{key}.{name}": item for name, item in value.items()})
        else:
            flat[key] = value
    fixed = _fixed_values()
    if not any(key in _MOVED_KEYS or key in fixed for key in flat):
        return data
    result: dict = {}
    for key, value in flat.items():
        if key in fixed:
            if not _same_value(value, fixed[key]):
                raise OptionError(f"ifmi.{key}", f"no longer an option (fixed at {fixed[key]!r}); remove the key")
            continue
        head, _, rest = _MOVED_KEYS.get(key, key).partition(".")
        items = {rest: value} if rest else value
        if head not in result or not isinstance(items, Mapping) or not isinstance(result[head], dict):
            result[head] = dict(items) if isinstance(items, Mapping) else items  # a copy: the input stays as it is
            continue
        for name, item in items.items():
            if name in result[head]:
                moved = [old for old, new in _MOVED_KEYS.items() if new == f"{head}.{name}"]
                raise OptionError(f"ifmi.{moved[0]}", f"given twice, here and as ifmi.{head}.{name} (its new key)")
            result[head][name] = item
    return result


def _is_solved(solved: SolvedPair) -> bool:
    """Whether the back end solved the pair."""
    return solved.info is not None and bool(solved.info.success)


def _robust_rotation(rays_a: np.ndarray, rays_b: np.ndarray) -> tuple[np.ndarray, float]:
    """``R_ab`` with ``rays_a ~ R_ab rays_b`` (Kabsch re-solved with Cauchy weights whose scale is
    the median residual) and the median residual angle of the last weighting (radians)."""
    weights = np.ones(len(rays_a))
    for _ in range(_REFIT_ITERATIONS):
        rotation = rotation_from_rays(rays_a, rays_b, weights)
        residual = rotation_angles(rays_a, rays_b, rotation)
        scale = np.median(residual) + np.finfo(np.float64).tiny
        weights = 1.0 / (1.0 + (residual / scale) ** 2)
    return rotation_from_rays(rays_a, rays_b, weights), float(scale)


class IfmiFrameState:
    """Prepared frame: wrap-padded panorama (float32); its layout tiles and their spectra on first use.

    The layout tiles and their spectra are needed when the frame is matched
    without a prediction, or as a reference whose tiles are cut anew; with
    tracked tiles most frames need few of them, or none.
    ``tracked`` holds the tiles this frame was last registered with (set by
    :meth:`IfmiFrontEnd.keep_tracking` once per pair; see ``TrackingOptions.track_tiles``).

    Parameters
    ----------
    padded_panorama : (H, W + 2 P) float32 ndarray
        Panorama with ``P`` columns wrapped onto each side.
    pad : int
        ``P``.
    layout : TileLayout
    engine : FourierMellin
    coarse_panorama : (h, w) float32 ndarray or None
        Low-resolution panorama of the coarse stage (:mod:`ifmi.spectral.global_motion`).
    """

    def __init__(self, padded_panorama: np.ndarray, pad: int, layout: TileLayout, engine: FourierMellin,
                 coarse_panorama: np.ndarray | None = None):
        self.padded_panorama = padded_panorama
        self.coarse_panorama = coarse_panorama
        self._pad = pad
        self._layout = layout
        self._engine = engine
        self._spectra: TileSpectra | None = None
        self.tracked: PlacedTiles | None = None
        self.tracked_valid: np.ndarray | None = None
        self.reference: tuple | None = None
        self.reference_curvature: np.ndarray | None = None
        # Landmark rays (TrackingOptions.landmark_rays): this frame's accepted R_0k, the frame-0 rays
        # of its tracked tiles and of its reference tiles (NaN rows: unknown).
        self.rotation: np.ndarray | None = None
        self.tracked_landmarks: np.ndarray | None = None
        self.reference_landmarks: np.ndarray | None = None

    def layout_tiles(self, index: np.ndarray | None = None) -> np.ndarray:
        """Layout tiles ``(K, N, N)`` float32, all or ``index`` (bool mask or indices) of them."""
        return tiles_from_panorama(self.padded_panorama, self._layout, index=index, wrapped_columns=self._pad)

    @property
    def spectra(self) -> TileSpectra:
        """Spectra of all layout tiles (:class:`~ifmi.spectral.fourier_mellin.TileSpectra`), computed on first access."""
        if self._spectra is None:
            self._spectra = self._engine.spectra(self.layout_tiles())
        return self._spectra


class IfmiFrontEnd(FrontEndBase):
    """Extended-iFMI correspondences between omni images of one calibrated camera.

    The panorama's radius band is detected from the first prepared image
    (unless the configuration fixes it) and then kept for the sequence.
    ``correspondences`` accepts a predicted rotation ``R_ab``
    (``uses_prior_rotation`` tells the odometry so); ``solve_pair`` runs a
    pair through the stages of :mod:`ifmi.spectral.pair_pipeline`.
    ``prepare`` only reads the camera mapping (made on the first call) and
    builds a new frame state, so the odometry prepares the next frame in the
    background (``prepares_in_background``).

    Parameters
    ----------
    model : OcamModel
    config : IfmiConfig
    """

    prepares_in_background = True

    def __init__(self, model: OcamModel, config: IfmiConfig = IfmiConfig()):
        self.model = model
        self.config = config
        self.mapping: PanoramaMapping | None = None
        self.layout: TileLayout | None = None
        self.engine: FourierMellin | None = None
        self.global_stage: GlobalMotionEstimator | None = None
        self.dense_layout: TileLayout | None = None
        self._dense_engine: FourierMellin | None = None  # built on the first dense retry
        self._band_limited: tuple | None = None  # engines of the band-limited retry, built on first use
        self._registration = config.registration.engine_config()
        self._points_b: np.ndarray | None = None

    @property
    def uses_prior_rotation(self) -> bool:
        """True when ``correspondences`` makes use of a predicted rotation (``tracking.use_prior``)."""
        return self.config.tracking.use_prior

    def _setup(self, image: np.ndarray) -> None:
        self.mapping = panorama_mapping(self.model, image, config=self.config.panorama)
        self._check_tiles_fit()
        self.layout = tile_layout((self.mapping.height, self.mapping.width), config=self.config.tiling)
        config = self.config
        self._registration = config.registration.engine_config(wide=self._wide)
        if not is_block_compressed(gray_from_image(image)):
            # The band-limited search of noise-dominated pairs is for compressed frames (see
            # ifmi.spectral.compression); a capture is compressed or not as a whole. Uncompressed
            # ones use it only to retry an unsolved pair (solve_pair).
            self._registration = replace(self._registration, noisy_pair_fraction=0.0)
        self.engine = FourierMellin(self.layout.tile_size, self.layout.count, config=self._registration)
        if config.coarse.enabled and config.tracking.use_prior:
            self.global_stage = GlobalMotionEstimator(self.mapping, config=config.coarse.engine_config())
        if config.recovery.dense_retry_fraction > 0 and config.tracking.use_prior:
            self.dense_layout = tile_layout((self.mapping.height, self.mapping.width),
                                            config=replace(config.tiling, overlap=config.recovery.dense_overlap))
        self._points_b = flow_sample_points(self.layout.tile_size, points_per_tile=config.rays.points_per_tile,
                                            spread=_POINT_SPREAD)

    @property
    def dense_engine(self) -> FourierMellin:
        """Registration engine of the denser layout (built on first use: most sequences never retry)."""
        if self._dense_engine is None:
            self._dense_engine = FourierMellin(self.dense_layout.tile_size, self.dense_layout.count,
                                               config=self._registration)
        return self._dense_engine

    def _check_tiles_fit(self) -> None:
        """Raise :class:`~ifmi.errors.CalibrationFitError` when a tile is larger than the panorama."""
        height, width = self.mapping.height, self.mapping.width
        tile = tile_size_px(self.config.tiling.tile_size, width)
        if tile <= min(height, width):
            return
        raise CalibrationFitError(
            f"the {self.model.height}x{self.model.width} px image gives a {height}x{width} px panorama, "
            f"smaller than the {tile} px tile; expected a panorama at least {tile}x{tile} px: "
            f"use larger images, a smaller --tile-size or a larger panorama --height/--width")

    def prepare(self, image: np.ndarray) -> IfmiFrameState:
        """Panorama and tiles of one frame (tile spectra follow on first use).

        Parameters
        ----------
        image : (H, W) or (H, W, 3) uint8 ndarray
            Omni image of the calibration's size.
        """
        if self.mapping is None:
            self._setup(image)
        # Remapped as float: an 8-bit result would round every panorama pixel to a whole gray
        # level (on sharp 1024 px images that noise doubled the frame-to-frame error).
        gray = gray_from_image(image).astype(np.float32)
        panorama = panorama_image_from_omni_image(
            self.mapping, gray, interpolation=self.config.refinement.wide_panorama_interpolation if self._wide else "linear")
        # The wrapped columns are copied, not resampled again: the same values, 2 x _pad fewer columns
        # through the (Lanczos) remap. A wrapping border copies them in one pass (a gather by column
        # index took about three times as long).
        padded = cv2.copyMakeBorder(panorama, 0, 0, self._pad, self._pad, cv2.BORDER_WRAP)
        coarse = None
        if self.global_stage is not None:
            coarse = self.global_stage.coarse_panorama(panorama)
        return IfmiFrameState(padded, self._pad, self.layout, self.engine, coarse)

    @property
    def _wide(self) -> bool:
        """A panorama of sharp high-resolution images (``refinement.min_width_sharp``)."""
        return self.mapping.width >= self.config.refinement.min_width_sharp

    @property
    def _curved(self) -> bool:
        """Curved placements (and refit passes) on this panorama (``refinement.curved_placement``)."""
        return self.config.refinement.curved_placement

    @property
    def _pad(self) -> int:
        # Columns wrapped onto each side of the panorama: a tile rotated about its centre
        # reaches 0.71 N beyond it, and predicted origins may sit anywhere in [0, width).
        return 2 * self.layout.tile_size

    @property
    def _layout_placement(self) -> tuple[np.ndarray, np.ndarray]:
        centre = (self.layout.tile_size - 1) / 2.0
        offsets = self.layout.origins.astype(np.float64) + centre
        return offsets, np.broadcast_to(np.eye(2), (self.layout.count, 2, 2)).copy()

    def predicted_placements(self, offsets_a: np.ndarray, linear_a: np.ndarray,
                             prior_rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where tiles placed at ``(offsets_a, linear_a)`` in frame a appear in frame b under ``R_ab``.

        A panorama point of a with ray ``r_a`` is seen in b along
        ``R_ab^T r_a``; the map is differentiated at each tile centre
        (central differences of half a pixel) and its Jacobian ``J`` carries
        the tile's own map: ``L_b = J L_a``.

        Parameters
        ----------
        offsets_a : (T, 2) ndarray
            Panorama ``(row, col)`` of the tile centres in frame a.
        linear_a : (T, 2, 2) ndarray
        prior_rotation : (3, 3) ndarray
            Predicted ``R_ab``.

        Returns
        -------
        offsets_b : (T, 2) ndarray
            Panorama ``(row, col)`` in frame b; columns may leave ``[0, width)`` by less than a width.
        linear_b : (T, 2, 2) ndarray
        """
        rotation = np.asarray(prior_rotation, dtype=np.float64)
        steps = np.array([[0.0, 0.0], [0.5, 0.0], [-0.5, 0.0], [0.0, 0.5], [0.0, -0.5]])
        probes = offsets_a[:, None, :] + steps
        in_b = panorama_pixels_from_rays(self.mapping, rays_from_panorama_pixels(self.mapping, probes) @ rotation)
        width = self.mapping.width
        centre = in_b[:, 0]
        # Differences taken across the seam are unwrapped.
        d = in_b[:, 1:] - centre[:, None, :]
        d[..., 1] = np.mod(d[..., 1] + width / 2, width) - width / 2
        jacobian = np.stack([d[:, 0] - d[:, 1], d[:, 2] - d[:, 3]], axis=-1)
        return centre, jacobian @ linear_a

    def predicted_curvature(self, offsets_a: np.ndarray, linear_a: np.ndarray, curvature_a: np.ndarray | None,
                            prior_rotation: np.ndarray) -> np.ndarray:
        """Second-order term in frame b of tiles placed at ``(offsets_a, linear_a, curvature_a)`` in a.

        With ``f`` the panorama map from frame a to b under ``R_ab`` and a tile
        point ``u`` placed at ``o + L u + q_a(u)`` in a, its place in b is, to
        second order, ``f(o) + J L u + J q_a(u) + (L u)^T H (L u) / 2``, so
        ``Q_b,i = sum_k J_ik Q_a,k + L^T H_i L / 2``. ``J`` and the Hessians
        ``H_i`` come from central differences of ``f`` over
        ``_CURVATURE_STEP_PX`` around ``o``.

        Parameters
        ----------
        offsets_a : (T, 2) ndarray
            Panorama ``(row, col)`` of the tile centres in frame a.
        linear_a : (T, 2, 2) ndarray
        curvature_a : (T, 2, 2, 2) ndarray or None
            ``Q_a`` (see :meth:`ifmi.spectral.fourier_mellin.FourierMellin.resample_placed`); None is zero.
        prior_rotation : (3, 3) ndarray
            Predicted ``R_ab``.

        Returns
        -------
        (T, 2, 2, 2) ndarray
            ``Q_b``, panorama pixels per squared tile pixel.
        """
        h = _CURVATURE_STEP_PX
        grid = np.array([[i, j] for i in (-1, 0, 1) for j in (-1, 0, 1)], dtype=np.float64) * h
        probes = np.asarray(offsets_a, dtype=np.float64)[:, None, :] + grid
        rays = rays_from_panorama_pixels(self.mapping, probes) @ np.asarray(prior_rotation, dtype=np.float64)
        f = panorama_pixels_from_rays(self.mapping, rays).reshape(-1, 3, 3, 2)  # (T, row step, col step, out)
        width = self.mapping.width
        centre_col = f[:, 1:2, 1:2, 1]
        f[..., 1] = centre_col + np.mod(f[..., 1] - centre_col + width / 2, width) - width / 2
        jacobian = np.empty(f.shape[:1] + (2, 2))  # (T, out, step)
        jacobian[..., 0] = (f[:, 2, 1] - f[:, 0, 1]) / (2 * h)
        jacobian[..., 1] = (f[:, 1, 2] - f[:, 1, 0]) / (2 * h)
        hessian = np.empty(f.shape[:1] + (2, 2, 2))  # (T, out, 2, 2)
        hessian[..., 0, 0] = (f[:, 2, 1] - 2 * f[:, 1, 1] + f[:, 0, 1]) / h ** 2
        hessian[..., 1, 1] = (f[:, 1, 2] - 2 * f[:, 1, 1] + f[:, 1, 0]) / h ** 2
        hessian[..., 0, 1] = hessian[..., 1, 0] = (f[:, 2, 2] - f[:, 2, 0] - f[:, 0, 2] + f[:, 0, 0]) / (4 * h ** 2)
        linear_a = np.asarray(linear_a, dtype=np.float64)
        curvature = 0.5 * np.einsum("tki,tokl,tlj->toij", linear_a, hessian, linear_a)
        if curvature_a is not None:
            curvature += np.einsum("tok,tkij->toij", jacobian, curvature_a)
        return curvature

    def _needs_new_tile(self, tracked: PlacedTiles, valid: np.ndarray) -> np.ndarray:
        # Singular values of each 2x2 map: s1^2 + s2^2 = |L|_F^2 and s1 s2 = |det L|.
        frobenius = np.einsum("tij,tij->t", tracked.linear, tracked.linear)
        twice_det = 2.0 * np.abs(np.linalg.det(tracked.linear))
        plus = np.sqrt(frobenius + twice_det)
        minus = np.sqrt(np.maximum(frobenius - twice_det, 0.0))
        largest, smallest = (plus + minus) / 2.0, (plus - minus) / 2.0
        limit = self.config.tracking.max_tile_distortion
        distorted = (largest > limit) | (smallest < 1.0 / limit)
        # Rows the tile covers: its corners reach (N/2)(|L_00| + |L_01|) from the centre.
        reach = self.layout.tile_size / 2.0 * np.abs(tracked.linear[:, 0, :]).sum(axis=1)
        rows = tracked.offsets[:, 0]
        outside = (rows - reach < 0) | (rows + reach > self.mapping.height - 1)
        return ~valid | distorted | outside

    def reference_tiles(self, state: IfmiFrameState) -> tuple[np.ndarray, np.ndarray, TileSpectra, int]:
        """Placement and spectra of a reference frame's tiles (tracked where possible).

        Returns
        -------
        offsets : (T, 2) ndarray
        linear : (T, 2, 2) ndarray
        spectra : TileSpectra
        n_new : int
            Tiles cut anew from the layout.
        """
        if state.reference is not None:
            return state.reference
        offsets, linear = self._layout_placement
        tracked = state.tracked
        state.reference_curvature = None
        if not self.config.tracking.track_tiles or tracked is None:
            state.reference = (offsets, linear, state.spectra, self.layout.count)
            state.reference_landmarks = self._landmarks(state, offsets, None, np.ones(self.layout.count, bool))
            return state.reference
        # A tracked reference is matched at predicted placements, where log-polar descriptors
        # serve only when the residual rotation and scale are measured. Tiles the registration
        # resampled (not anchored templates) come without energy centroids.
        with_descriptor = self._with_descriptor
        spectra = tracked.spectra
        if spectra is None or spectra.centroid is None or (with_descriptor and spectra.descriptor is None):
            spectra = self.engine.spectra(tracked.tiles)
        if not with_descriptor:
            spectra = replace(spectra, descriptor=None)
        new = self._needs_new_tile(tracked, state.tracked_valid)
        if new.any():
            fresh = self.engine.spectra(state.layout_tiles(new), with_descriptor=with_descriptor)

            def merged(tracked_rows, new_rows):
                if tracked_rows is None:
                    return None
                rows = tracked_rows.copy()
                rows[new] = new_rows
                return rows

            spectra = TileSpectra(spectrum=merged(spectra.spectrum, fresh.spectrum),
                                  descriptor=merged(spectra.descriptor, fresh.descriptor),
                                  std=merged(spectra.std, fresh.std),
                                  centroid=merged(spectra.centroid, fresh.centroid))
            offsets = np.where(new[:, None], offsets, tracked.offsets)
            linear = np.where(new[:, None, None], linear, tracked.linear)
        else:
            offsets, linear = tracked.offsets, tracked.linear
        if tracked.curvature is not None:
            # Tiles cut anew from the layout are axis-aligned in this frame: no curvature.
            state.reference_curvature = np.where(new[:, None, None, None], 0.0, tracked.curvature)
        state.reference = (offsets, linear, spectra, int(new.sum()))
        state.reference_landmarks = self._landmarks(state, offsets, state.tracked_landmarks, new)
        return state.reference

    def accept_pose(self, state: IfmiFrameState, rotation: np.ndarray) -> None:
        """Record the odometry's estimate ``R_0k`` of a successfully estimated frame
        (``tracking.landmark_rays``); a frame never accepted keeps measured rays."""
        state.rotation = np.asarray(rotation, dtype=np.float64)

    def _landmarks(self, state: IfmiFrameState, offsets: np.ndarray, tracked: np.ndarray | None,
                   new: np.ndarray) -> np.ndarray | None:
        """Frame-0 rays of a reference's tiles: carried along the track, or the accepted
        rotation's image of a new tile's ray; None when the frame has no accepted pose."""
        if not (self.config.tracking.landmark_rays and self._wide) or state.rotation is None:
            return None
        landmarks = np.full((len(offsets), 3), np.nan) if tracked is None else tracked.copy()
        landmarks[new] = rays_from_panorama_pixels(self.mapping, offsets[new]) @ state.rotation.T
        return landmarks

    def register(self, state_a: IfmiFrameState, state_b: IfmiFrameState):
        """Tile motions of frame b against frame a without a prediction (layout tiles in both).

        Returns
        -------
        motion : TileMotion
        origins_b : (T, 2) ndarray
            Panorama ``(row, col)`` of tile b's first pixel (the layout's).
        """
        shift = np.array([0.0, self._pad])
        motion = self.engine.register(state_a.spectra, state_b.spectra, state_b.padded_panorama,
                                      self.layout.origins + shift)
        return motion, self.layout.origins.astype(np.float64)

    def tiles_at(self, state_a: IfmiFrameState, state_b: IfmiFrameState, rotation: np.ndarray) -> TileMatch:
        """The reference's tiles registered in frame b where the rotation ``R_ab`` puts them.

        Nothing of either frame is changed: the result carries the tiles
        frame b would track after it (the reference's templates at their
        final placements in b with ``tracking.anchor_templates``, else the
        tiles the final residual was measured on), for :meth:`keep_tracking`.

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
        rotation : (3, 3) ndarray
            ``R_ab`` (predicted, or a coarse search's).

        Returns
        -------
        TileMatch
            ``offsets_a`` (T, 2) panorama ``(row, col)`` of the reference tiles' centres in frame a,
            ``linear_a`` (T, 2, 2), ``placed`` with panorama coordinates of frame b (columns in
            ``[0, width)``), ``n_new`` reference tiles cut anew from the layout.
        """
        offsets_a, linear_a, spectra_a, n_new = self.reference_tiles(state_a)
        offsets_b, linear_b = self.predicted_placements(offsets_a, linear_a, rotation)
        curvature_b = None
        if self._curved:
            curvature_b = self.predicted_curvature(offsets_a, linear_a, state_a.reference_curvature, rotation)
        offsets_b[:, 1] = np.mod(offsets_b[:, 1], self.mapping.width)
        placed, refined = self._register_for_refit(spectra_a, state_b, offsets_b + self._shift, linear_b,
                                                   curvature_b)
        placed, curvature_b, refined = self._refitted(state_a, state_b, spectra_a, (offsets_a, linear_a), placed,
                                                      curvature_b, refined)
        if not refined:  # no refit: refine with the predicted shape
            placed = self.engine.refine_placed(spectra_a, state_b.padded_panorama, placed, linear_b,
                                               curvature_b=curvature_b)
        last = replace(placed.last, offsets=self._unpadded(placed.last.offsets))
        placed = replace(placed, offsets=self._unpadded(placed.offsets), last=last)
        if self.config.tracking.anchor_templates:
            # The reference's templates, placed where they were found in b.
            tracked = PlacedTiles(tiles=None, offsets=placed.offsets, linear=placed.linear, spectra=spectra_a,
                                  curvature=curvature_b)
        else:
            tracked = last
        return TileMatch(offsets_a, linear_a, placed, rotation, n_new, tracked, placed.valid,
                         state_a.reference_landmarks, offsets_b)

    def _refitted(self, state_a: IfmiFrameState, state_b: IfmiFrameState, spectra_a: TileSpectra,
                  placement_a: tuple, placed: PlacedRegistration, curvature_b: np.ndarray | None, refined: bool):
        """``(placed, curvature_b, refined)`` after the refit passes (``refinement.refit_passes``, curved
        placements only): the tiles' own rotation replaces the prediction in their shape (affine and
        curvature), which the registration does not measure; the centres stay as measured."""
        offsets_a, linear_a = placement_a
        for _ in range(self.config.refinement.refit_passes if self._curved else 0):
            if placed.valid.sum() < max(self.config.rays.min_tiles, _MIN_REFIT_TILES):
                break
            rotation, residual = _robust_rotation(
                rays_from_panorama_pixels(self.mapping, offsets_a[placed.valid]),
                rays_from_panorama_pixels(self.mapping, self._unpadded(placed.offsets)[placed.valid]))
            if residual > _REFIT_MAX_RESIDUAL_PX * 2 * np.pi / self.mapping.width:
                break  # parallax or wrong tiles: the tiles do not agree on a rotation
            _, linear_b = self.predicted_placements(offsets_a, linear_a, rotation)
            curvature_b = self.predicted_curvature(offsets_a, linear_a, state_a.reference_curvature, rotation)
            placed = self.engine.refine_placed(spectra_a, state_b.padded_panorama, placed, linear_b,
                                               curvature_b=curvature_b)
            refined = True
        return placed, curvature_b, refined

    @property
    def _shift(self) -> np.ndarray:
        """``(row, col)`` of a panorama pixel in the padded panorama, less its own."""
        return np.array([0.0, self._pad])

    def _unpadded(self, offsets: np.ndarray) -> np.ndarray:
        """Padded-panorama ``(row, col)`` as panorama ``(row, col)``, columns in ``[0, width)``."""
        offsets = offsets - self._shift
        offsets[:, 1] = np.mod(offsets[:, 1], self.mapping.width)
        return offsets

    def keep_tracking(self, state_b: IfmiFrameState, match: TileMatch | None) -> None:
        """Frame b keeps the tiles of the registration ``match`` to track (None: it keeps its own); the
        pipeline's one write to a frame, made once per pair."""
        if match is None:
            return
        state_b.tracked, state_b.tracked_valid = match.tracked, match.tracked_valid
        state_b.tracked_landmarks = match.tracked_landmarks
        state_b.reference = None

    def _register_for_refit(self, spectra_a: TileSpectra, state_b: IfmiFrameState, offsets_b: np.ndarray,
                            linear_b: np.ndarray, curvature_b: np.ndarray | None):
        """``register_placed`` at the prediction, and whether its refinement passes ran.

        With a refit to follow and the kept tiles' median search move within
        ``_SINGLE_REFINEMENT_MAX_PX`` (panorama pixels), the passes are
        left to the refit; otherwise they run on the predicted shape.
        """
        engine, source = self.engine, state_b.padded_panorama
        if not (self._curved and self.config.refinement.refit_passes and _SINGLE_REFINEMENT_MAX_PX > 0):
            return engine.register_placed(spectra_a, source, offsets_b, linear_b, curvature_b=curvature_b), True
        placed = engine.register_placed(spectra_a, source, offsets_b, linear_b, curvature_b=curvature_b,
                                        refine=False)
        moved = np.hypot(*(placed.offsets - offsets_b)[placed.valid].T)
        if moved.size and np.median(moved) <= _SINGLE_REFINEMENT_MAX_PX:
            return placed, False
        return engine.refine_placed(spectra_a, source, placed, linear_b, curvature_b=curvature_b), True


    def _landmark_pairs(self, pairs, offsets_a: np.ndarray, landmarks: np.ndarray,
                        rotation_a: np.ndarray) -> tuple:
        """``pairs`` with each tile's rays in frame a turned so that its centre lies on its
        landmark ray as the accepted ``R_0a`` sees it, where the two are within
        ``_LANDMARK_GATE_PX``; and how many tiles were turned."""
        measured = rays_from_panorama_pixels(self.mapping, offsets_a)
        seen = landmarks @ rotation_a  # R_0a^T applied to each frame-0 ray
        gate = _LANDMARK_GATE_PX * 2 * np.pi / self.mapping.width
        close = np.isfinite(seen).all(axis=1) & (np.einsum("ti,ti->t", measured, np.nan_to_num(seen)) >= np.cos(gate))
        if not close.any():
            return pairs, 0
        turns = np.broadcast_to(np.eye(3), (len(offsets_a), 3, 3)).copy()
        turns[close] = matrix_aligning_rays(measured[close], seen[close], fraction=self.config.tracking.landmark_weight)
        per_point = np.repeat(turns, len(self._points_b), axis=0)
        rays_a = np.einsum("nij,nj->ni", per_point, pairs.rays_a)
        return pairs_with_rays_a(pairs, rays_a, self.mapping), int(close.sum())


    def coarse_rotation(self, state_a: IfmiFrameState, state_b: IfmiFrameState, starts: tuple) -> tuple:
        """``(R_ab, GlobalMotion or None)``: the coarse stage's rotation from the best of ``starts`` (None:
        the identity); without a coarse stage the first start, and None."""
        first = np.eye(3) if starts[0] is None else starts[0]
        if self.global_stage is None:
            return first, None
        coarse = self.global_stage.estimate(state_a.coarse_panorama, state_b.coarse_panorama, priors=starts)
        return coarse.rotation, coarse

    def wide_search_on(self) -> bool:
        """Whether the wide search can run (a coarse stage, ``recovery.wide_search_fraction`` above 0)."""
        return self.global_stage is not None and self.config.recovery.wide_search_fraction > 0

    def wide_search(self, state_a: IfmiFrameState, state_b: IfmiFrameState, current_score: float,
                    prediction: np.ndarray, *, every_start: bool = False) -> GlobalMotion | None:
        """The coarse stage's wide search around ``prediction``: a rotation matching better than the
        coarse rotation the tiles were registered at (its mismatch ``current_score``), or None."""
        return self.global_stage.wide_search(state_a.coarse_panorama, state_b.coarse_panorama, start=prediction,
                                             current_score=current_score, every_start=every_start)

    @property
    def _with_descriptor(self) -> bool:
        """Whether tile spectra carry log-polar descriptors (the residual rotation and scale are measured)."""
        registration = self._registration
        return registration.estimate_rotation_scale and registration.refine_predicted_rotation_scale

    def register_dense(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *,
                       rotation: np.ndarray):
        """Tiles of the denser layout cut from frame a, found in frame b where ``rotation`` (``R_ab``) puts them.

        Nothing of either frame is changed (the dense retry's tiles are not tracked).

        Returns
        -------
        offsets_a : (K, 2) ndarray
            Panorama ``(row, col)`` of the registered tiles' centres in frame a.
        linear_a : (K, 2, 2) ndarray
        placed : PlacedRegistration
            With panorama coordinates of frame b (columns in ``[0, width)``).
        """
        layout = self.dense_layout
        tiles = tiles_from_panorama(state_a.padded_panorama, layout, wrapped_columns=self._pad)
        spectra_a = self.dense_engine.spectra(tiles, with_descriptor=self._with_descriptor)
        origins = layout.origins
        offsets_a = origins.astype(np.float64) + (layout.tile_size - 1) / 2.0
        linear_a = np.broadcast_to(np.eye(2), (len(origins), 2, 2)).copy()
        offsets_b, linear_b = self.predicted_placements(offsets_a, linear_a, rotation)
        curvature_b = None
        if self._curved:
            curvature_b = self.predicted_curvature(offsets_a, linear_a, None, rotation)
        offsets_b[:, 1] = np.mod(offsets_b[:, 1], self.mapping.width)
        placed = self.dense_engine.register_placed(spectra_a, state_b.padded_panorama, offsets_b + self._shift,
                                                   linear_b, curvature_b=curvature_b)
        return offsets_a, linear_a, replace(placed, offsets=self._unpadded(placed.offsets))


    def _tile_points(self, centroids: np.ndarray) -> np.ndarray:
        """Flow points of every tile ``(T, K, 2)`` on its energy centroid, or the shared ``(K, 2)``."""
        if not self.config.rays.at_energy_centroid:
            return self._points_b
        return points_on_centroids(self._points_b, centroids)


    def unpredicted_correspondences(self, state_a: IfmiFrameState, state_b: IfmiFrameState) -> Correspondences:
        """Ray pairs from the layout's tiles of both frames, registered without a prediction."""
        started = time.perf_counter()
        motion, origins_b = self.register(state_a, state_b)
        diagnostics = PairDiagnostics.of_tiles(motion, self.layout.count, self.layout.count)
        if motion.valid.sum() < self.config.rays.min_tiles:
            return self._too_few_tiles(motion.valid, diagnostics.timed("register", time.perf_counter() - started))
        pairs = flow_from_tile_motion(motion, self.layout, self.mapping, origins_b=origins_b,
                                      points_b=self._tile_points(state_b.spectra.centroid))
        return self._from_pairs(pairs, diagnostics.timed("register", time.perf_counter() - started))

    def correspondences(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *,
                        prior_rotation: np.ndarray | None = None) -> Correspondences:
        """Ray pairs of frame a (reference) and frame b from the kept tiles.

        With a predicted rotation (and ``tracking.use_prior``) the stages
        *register*, *verify*, *recover* and *rays* of :mod:`ifmi.spectral.pair_pipeline`
        run, and frame b keeps the tiles it was registered with; without
        one, the layout's tiles of both frames are registered.

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
        prior_rotation : (3, 3) ndarray, optional, keyword-only
            Predicted ``R_ab``; used with ``tracking.use_prior``.

        Returns
        -------
        Correspondences
        """
        if not self.config.tracking.use_prior or prior_rotation is None:
            return self.unpredicted_correspondences(state_a, state_b)
        result = pair_pipeline.matched(self, state_a, state_b, prior_rotation)
        self.keep_tracking(state_b, result.kept)
        return result.correspondences

    def solve_pair(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *, prior_rotation: np.ndarray | None,
                   solve) -> SolvedPair:
        """The pair through every stage of :func:`ifmi.spectral.pair_pipeline.solve_pair`.

        On an uncompressed capture, a pair no stage solved goes through them once more with the
        band-limited search of noise-dominated pairs; the retry is kept when it solves the pair
        (``band_limited_retry`` true in its diagnostics), else frame b keeps the first pass's tiles.
        """
        solved = pair_pipeline.solve_pair(self, state_a, state_b, prior_rotation=prior_rotation, solve=solve)
        if _is_solved(solved) or not self._band_limited_retry_on:
            return solved
        # The engines differ in the translation search only: a frame prepared meanwhile in the
        # background gets the same tile spectra from either.
        engines = self.engine, self._dense_engine
        kept = state_b.tracked, state_b.tracked_valid, state_b.tracked_landmarks, state_b.reference
        self.engine, self._dense_engine = self._band_limited_engines()
        try:
            retry = pair_pipeline.solve_pair(self, state_a, state_b, prior_rotation=prior_rotation, solve=solve)
        finally:
            self.engine, self._dense_engine = engines
        if not _is_solved(retry):
            # Frame b keeps the tiles of the first pass, as without the retry.
            state_b.tracked, state_b.tracked_valid, state_b.tracked_landmarks, state_b.reference = kept
            return solved
        diagnostics = {**retry.correspondences.diagnostics, "band_limited_retry": True}
        return replace(retry, correspondences=replace(retry.correspondences, diagnostics=diagnostics))

    @property
    def _band_limited_retry_on(self) -> bool:
        """Whether an unsolved pair is retried with the band-limited search: on a capture whose
        registration does not run that search already (an uncompressed one)."""
        return self._registration.noisy_pair_fraction == 0

    def _band_limited_engines(self) -> tuple[FourierMellin, FourierMellin | None]:
        """Registration engines of the layout and of the dense layout (None without dense retries)
        with the band-limited search of noise-dominated pairs at its default fraction, built on first use."""
        if self._band_limited is None:
            config = replace(self._registration, noisy_pair_fraction=FourierMellinConfig.noisy_pair_fraction)
            dense = None if self.dense_layout is None else FourierMellin(
                self.dense_layout.tile_size, self.dense_layout.count, config=config)
            self._band_limited = FourierMellin(self.layout.tile_size, self.layout.count, config=config), dense
        return self._band_limited

    @property
    def half_turn(self) -> np.ndarray:
        """Half turn (3, 3) about the panorama axis, in the camera frame."""
        axis_frame = self.mapping.camera_from_panorama
        half_turn = np.diag([-1.0, -1.0, 1.0])
        return half_turn if axis_frame is None else axis_frame @ half_turn @ axis_frame.T

    def _too_few_tiles(self, valid: np.ndarray, diagnostics: PairDiagnostics) -> Correspondences:
        """A failed pair: fewer than ``rays.min_tiles`` of the ``valid`` tiles passed."""
        return Correspondences.failed(
            f"only {int(valid.sum())} of {self.layout.count} tiles passed the noise filters "
            f"(need {self.config.rays.min_tiles})", diagnostics.to_dict())


    def _from_pairs(self, pairs, diagnostics: PairDiagnostics) -> Correspondences:
        """Correspondences of the flow ``pairs`` (one measurement per tile)."""
        return Correspondences(pixels_a=pairs.pixels_a, pixels_b=pairs.pixels_b,
                               rays_a=pairs.rays_a, rays_b=pairs.rays_b, diagnostics=diagnostics.to_dict(),
                               rays_per_measurement=len(self._points_b))


    def placed_correspondences(self, state_a: IfmiFrameState, offsets_a: np.ndarray, linear_a: np.ndarray,
                               placed: PlacedRegistration, diagnostics: PairDiagnostics, *,
                               dense: bool) -> tuple[Correspondences, PairDiagnostics]:
        """Rays of the kept tiles of a registration of frame a's tiles (reference tiles, or the
        ``dense`` layout's cut anew: no curvature or landmarks of their own), and ``diagnostics`` with
        the count of tiles turned to their landmarks."""
        valid = placed.valid
        if valid.sum() < self.config.rays.min_tiles:
            return self._too_few_tiles(valid, diagnostics), diagnostics
        curvature_a = None if dense else state_a.reference_curvature
        landmarks = None if dense else state_a.reference_landmarks
        pairs = flow_from_placements(offsets_a, linear_a, placed.offsets, placed.linear, valid, self.mapping,
                                     points=self._tile_points(placed.template_centroid),
                                     tile_size=self.layout.tile_size,
                                     curvature_a=curvature_a, curvature_b=placed.last.curvature)
        if landmarks is not None:
            pairs, turned = self._landmark_pairs(pairs, offsets_a[valid], landmarks[valid], state_a.rotation)
            diagnostics = replace(diagnostics, n_tiles_landmark=turned)
        return self._from_pairs(pairs, diagnostics), diagnostics
