"""The extended-iFMI front end: panorama, tiles, per-tile iFMI, flow, rays.

``prepare`` unwarps a frame into the panorama, cuts the tiles and computes
their spectra once (a keyframe is prepared once and matched many times);
``correspondences`` registers the tile pairs, rejects bad tiles with the
noise filters and returns ray pairs from the flow equation.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from .camera import OcamModel
from .options import options_from_dict
from .front_end import Correspondences
from .flow import (flow_from_placements, flow_from_tile_motion, flow_sample_points, pairs_with_rays_a,
                   points_on_centroids)
from .global_motion import GlobalMotion, GlobalMotionConfig, GlobalMotionEstimator
from .fourier_mellin import (FourierMellin, TileRejection, FourierMellinConfig, PlacedRegistration, PlacedTiles,
                            TileSpectra)
from .errors import CalibrationFitError
from .relative_pose import rotation_angles, rotation_from_rays
from .rotations import geodesic_angle, matrix_aligning_rays
from .tiling import (TileLayout, TilingConfig, strongest_tiles_per_column, tile_corner_strengths, tile_layout,
                     tile_size_px, tiles_from_panorama)
from .unwarp import (PANORAMA_INTERPOLATIONS, PanoramaConfig, PanoramaMapping, gray_from_image,
                     panorama_image_from_omni_image, panorama_mapping, panorama_pixels_from_rays,
                     rays_from_panorama_pixels)

__all__ = ["IfmiConfig", "IfmiFrameState", "IfmiFrontEnd", "averaged_correspondences"]

# Step (panorama pixels) of the central differences that give a predicted map's curvature: about
# a quarter of a 64 px tile, where the second-order term matters, and far above rounding.
_CURVATURE_STEP_PX = 16.0
# Cauchy reweighting steps of the tiles' own rotation fit (refit passes), and the fewest kept tiles it needs.
_REFIT_ITERATIONS = 3
_MIN_REFIT_TILES = 8
# Most refit passes: each re-measures the kept tiles (about one registration: 100 passes took 2 s
# more than one on seven fast 256 px pairs) and the default is one; 10**20 passes never ended.
_MAX_REFIT_PASSES = 10


@dataclass(frozen=True)
class IfmiConfig:
    """Options of the iFMI front end.

    Attributes
    ----------
    panorama : PanoramaConfig
    tiling : TilingConfig
    registration : FourierMellinConfig
        Includes the noise-filter thresholds ``th_pr`` and ``th_pnr``.
    points_per_tile : int
        Flow points per kept tile: 1, 5 or 9.
    point_spread : float
        Offset of the outer flow points from the tile centre, fraction of the tile size.
    flow_at_energy_centroid : bool
        Centre each tile's flow points on the energy centroid of its
        reference tile (:func:`ifmi.fourier_mellin.energy_centroids`)
        instead of the tile centre. Under translation the motion varies
        across a tile with the depth of what it sees; the registration
        measures the motion where the tile's texture energy lies, which on
        unevenly textured tiles (grass thinning out towards the horizon, an
        edge near one side) is pixels from the centre.
    min_tiles : int
        Fewer kept tiles than this fails the frame pair.
    use_prior : bool
        When the odometry passes a predicted rotation, cut each tile of
        frame b where the prediction moves tile a's content, so that the
        registration measures only the small residual motion (more overlap,
        less window bias, keyframes that last longer). Tile b is cut with
        the local affine map of the predicted rotation (the panorama warp's
        Jacobian at the tile centre), not only its similarity part.
    track_tiles : bool
        With a prediction, a frame that becomes a reference keeps the tiles
        it was registered with, placed where its previous reference's tiles
        were found, instead of cutting new ones at the fixed layout, like
        tracked features. A tile's placement in a frame then enters the
        pair before and the pair after it with opposite signs, so its error
        cancels along the trajectory instead of accumulating. Tiles that
        failed registration, left the panorama rows or became distorted
        are cut anew from the layout.
    coarse_to_fine : bool
        Before the tiles, estimate the large part of the rotation from whole
        low-resolution panoramas (:mod:`ifmi.global_motion`), starting from
        the predicted rotation, and cut the tiles where that estimate puts
        them; when the tiles then fail, search again from the identity
        (re-acquisition after a lost track). Needs ``use_prior``.
    global_motion : GlobalMotionConfig
        Options of the coarse stage.
    prediction_check_tiles : float
        When the coarse stage moves a prediction by at most this many tile
        widths (panorama pixels of the correction angle over the tile
        size), the tiles are registered at the prediction as well and the
        registration that keeps more tiles wins (ties go to the coarse
        stage). The prediction is then still well inside the tiles' capture
        range, so the coarse stage's own error, a fraction of a coarse
        pixel, does not replace a prediction that the tiles match better.
        0 disables the check.
    wide_search_fraction : float
        When at most this fraction of the tiles pass at the coarse stage's
        rotation (after any re-acquisition) and that rotation is more than
        ``global_motion.confirm_angle_rad`` from the prediction, its wide
        search (:meth:`ifmi.global_motion.GlobalMotionEstimator.wide_search`,
        from starts tilted around the prediction) looks for a clearly better
        rotation, and the tiles are registered there instead. A tilt of ten
        degrees between frames can smear the whole-panorama correlation into
        a wrong yaw that a few tiles still agree with. A pair that cannot be
        solved at all is searched again from every start
        (:meth:`IfmiFrontEnd.rescue_correspondences`). 0 disables both.
    max_tile_distortion : float
        A tracked tile whose placement stretches or shrinks the panorama by
        more than this factor along any direction is cut anew.
    dense_retry_fraction : float
        With a prediction, when at most this fraction of the tiles pass
        the noise filters (fast translation: parallax a rotation cannot
        predict moves and distorts most tiles), the pair is registered once
        more with a denser layout, tiles overlapping by ``dense_overlap``,
        cut anew from frame a at the same coarse rotation; the registration
        with more kept tiles gives the rays. Frame b keeps the regular
        layout's tracked tiles. 0 disables it.
    dense_overlap : float
        Overlap of the denser layout (``TilingConfig.overlap``).
    reregister_fraction : float
        When at most this fraction of the layout's tiles passed and the back
        end solved the pair, the tiles that gave its rays are registered a
        second time, directly at the solved rotation (no coarse stage), and
        the pair is solved again with each ray of frame b the mean of its
        two registrations (:meth:`IfmiFrontEnd.refine_correspondences`).
        The solved rotation places the tiles better than the coarse stage
        did, and the second registration samples them at other sub-pixel
        positions, so their errors partly average out. Measured on 108 fast
        sets and 12 warehouse sets (3 RANSAC seeds, both modes): the sets
        where iFMI's ATE exceeded the better feature method's went from 25
        to 15 (`reports/fast_motion`, thirteenth stop). 0 disables it.
    reregister_min_px : float
        The second registration is made only when the solved rotation moves
        the tiles at least this far from where they were registered
        (panorama pixels: the angle between the two rotations times
        ``width / 2 pi``). A smaller move samples them at nearly the same
        sub-pixel positions and changes nearly nothing. On the 18 designed
        fast sets 84 of 228 pairs are registered again (97 with 0.1 px, 65
        with 0.5 px).
    dense_tiles_per_column : int or None
        The retry registers only this many tiles of each column of the
        denser layout, those whose texture best fixes a shift in frame a
        (:func:`ifmi.tiling.tile_corner_strengths`), instead of all of them
        (None). Its cost falls with the tile count; see the README's retry
        section for what it does to the accuracy.
    anchor_templates : bool
        Tracked tiles keep the template (spectrum) of the frame they were
        first cut from, and every later frame's placement of them is
        measured against that template, so a placement error of one frame
        does not pass on to the next. Otherwise a tracked tile is re-cut
        (resampled) from every frame at its last placement and carries that
        placement's error and the resampling blur along the track (the
        tests measure 0.05 against 0.17 px two frames on; 20-frame drift on
        the rendered benchmark, sum of six runs, 227e-5 against 250e-5 rad).
    curved_placement : bool
        With a prediction, tile b is cut along the predicted map's second-order
        term as well as its affine part (the curvature is composed along a
        tracked tile's frames). The panorama's displacement field of a tilt
        is sinusoidal in azimuth; under an affine cut the windowed tile
        measures its mean over the tile, which shrinks a tilt by about
        ``(2 pi / W)^2 s^2 / 2`` (``s`` the window's spread, a few 1e-4 for
        64 px tiles at W = 2048). See the README's sharp-image section.
    refit_passes : int
        With curved placements: passes that fit a robust rotation to the
        kept tiles' measured centres and re-measure the kept tiles cut with
        that rotation's shape instead of the prediction's (0 = none; at most 10).
    refit_max_residual_px : float
        A refit is skipped when the tiles' median residual against their own
        rotation exceeds this (panorama pixels): parallax or wrong tiles.
    single_refinement_max_px : float
        With a refit to follow, the refinement passes run only on the refitted
        shape when the search pass moved the kept tiles by at most this
        (median, panorama pixels): a good prediction, from which one pass
        converges. A larger move (fast or erratic motion) first refines on the
        predicted shape, as without a refit. 0 always refines twice. See the
        README's sharp-image section for what it saves and costs.
    wide_panorama_interpolation : {"linear", "cubic", "lanczos4"}
        OpenCV kernel that resamples the omni image into panoramas at least
        ``min_width_curved`` wide (sharp high-resolution images); narrower
        ones are bilinear. Bilinear interpolation shifts fine texture by a
        sub-pixel amount fixed in the omni image
        (:func:`~ifmi.unwarp.panorama_image_from_omni_image`); an anchored
        template keeps its frame's shift for its whole track. See the
        README's sharp-image section for what the Lanczos kernel gains and costs.
    min_width_curved : int
        Curved placements, refit passes, ``wide_panorama_interpolation`` and
        ``landmark_rays`` apply from this panorama width (pixels) up;
        narrower panoramas keep the affine cut, bilinear resampling and
        measured rays.
    landmark_rays : bool
        Each tracked tile keeps a landmark: its centre's ray in frame 0's
        coordinates, fixed when the tile is cut, from the pose the odometry
        accepted for that frame (:meth:`IfmiFrontEnd.accept_pose`). When a
        frame is the reference, a tracked tile's rays there are turned
        towards where the accepted pose of that frame sees the landmark,
        instead of resting on the tile's measured placement alone. Measured
        placements telescope along a track only while the tile set stays
        the same; each tile cut anew starts from a frame whose pose has
        drifted, so frame-to-frame drift grows with every renewal. The
        landmarks tie the reference's tiles to the poses they were first
        seen from. Frames without an accepted pose (a reference reset
        after failures) keep measured rays, and their tiles lose their
        landmarks. Only on panoramas at least ``min_width_curved`` wide: on
        the 256 px sets it lowered the drift of pure rotations but let
        parallax into translated ones. See the README's sharp-image section.
    landmark_gate_px : float
        A tile is turned only when its measured centre lies within this
        many panorama pixels of its landmark (parallax under translation,
        or a tile that slipped, moves it farther).
    landmark_weight : float
        Part of the way from the measured ray to the landmark's that a
        tile's rays are turned, in ``(0, 1]``: 1 ties them to the landmarks
        (least drift), less keeps more of each pair's own measurement
        (frame-to-frame error closer to the measured one). The trajectory's
        error then decays by ``1 - landmark_weight`` per frame towards the
        landmarks'.
    half_turn_check_rad : float
        When the back end solves a pair more than this far from its
        prediction (radians; the first pair's prediction is the identity),
        the pair is solved once more from that rotation turned half round
        about the panorama axis (:meth:`IfmiFrontEnd.half_turn_alternative`),
        and the solution nearer the prediction is taken when it keeps
        enough inliers. A room of one texture seen from near its middle
        matches itself half a turn round, and under parallax the half turn
        can match as well as the truth. A quarter turn by default: no pair
        of the fast benchmark sets (at most about 30 degrees per frame)
        lies that far from its prediction unless it took a wrong turn.
        ``pi`` turns the check off.
    half_turn_inlier_fraction : float
        The alternative replaces the first solution only with at least this
        fraction of its inliers (the frames explain both about as well; a
        scene that does not repeat half round leaves the alternative few
        tiles, or none).
    half_turn_yaw_window_rad : float
        The turned rotation is refined by the coarse stage with its yaw kept
        within this of the start (radians, 0.35 = 20 degrees;
        :meth:`~ifmi.global_motion.GlobalMotionEstimator.search_near`). The
        turn is about the vertical, so the start's yaw is right to within
        the cameras' tilt from it and its tilt is off by up to twice that
        (0.10-0.26 rad on the atelier pairs that took the half turn). With
        a quarter turn as the window, the search on one of them jumped to a
        neighbour of a ring of six alike plinths 60 degrees round.
    """

    panorama: PanoramaConfig = field(default_factory=PanoramaConfig)
    tiling: TilingConfig = field(default_factory=TilingConfig)
    registration: FourierMellinConfig = field(default_factory=FourierMellinConfig)
    points_per_tile: int = 5
    point_spread: float = 0.1
    flow_at_energy_centroid: bool = True
    min_tiles: int = 3
    use_prior: bool = True
    track_tiles: bool = True
    coarse_to_fine: bool = True
    global_motion: GlobalMotionConfig = field(default_factory=GlobalMotionConfig)
    prediction_check_tiles: float = 0.125
    wide_search_fraction: float = 0.33
    max_tile_distortion: float = 1.25
    dense_retry_fraction: float = 0.33
    dense_overlap: float = 0.5
    reregister_fraction: float = 0.6
    reregister_min_px: float = 0.3
    dense_tiles_per_column: int | None = None
    anchor_templates: bool = True
    curved_placement: bool = True
    refit_passes: int = 1
    refit_max_residual_px: float = 0.25
    single_refinement_max_px: float = 0.5
    wide_panorama_interpolation: str = "lanczos4"
    min_width_curved: int = 1536
    landmark_rays: bool = True
    landmark_gate_px: float = 0.25
    landmark_weight: float = 0.5
    half_turn_check_rad: float = math.pi / 2
    half_turn_inlier_fraction: float = 0.5
    half_turn_yaw_window_rad: float = 0.35

    def __post_init__(self) -> None:
        if self.points_per_tile not in (1, 5, 9):
            raise ValueError(f"points_per_tile must be 1, 5 or 9, got {self.points_per_tile}")
        if not 0 <= self.point_spread < 0.5 or self.min_tiles < 1:
            raise ValueError(f"expected 0 <= point_spread < 0.5 and min_tiles >= 1, got "
                             f"{self.point_spread}, {self.min_tiles}")
        if not 0 <= self.dense_retry_fraction <= 1 or not 0 <= self.dense_overlap < 1:
            raise ValueError(f"expected 0 <= dense_retry_fraction <= 1 and 0 <= dense_overlap < 1, got "
                             f"{self.dense_retry_fraction}, {self.dense_overlap}")
        if not 0 <= self.reregister_fraction <= 1 or not self.reregister_min_px >= 0:
            raise ValueError(f"expected 0 <= reregister_fraction <= 1 and reregister_min_px >= 0, got "
                             f"{self.reregister_fraction}, {self.reregister_min_px}")
        if self.dense_tiles_per_column is not None and self.dense_tiles_per_column < 1:
            raise ValueError(f"expected dense_tiles_per_column >= 1 or None, got {self.dense_tiles_per_column}")
        if not self.landmark_gate_px > 0 or not 0 < self.landmark_weight <= 1:
            raise ValueError(f"expected landmark_gate_px > 0 and 0 < landmark_weight <= 1, got "
                             f"{self.landmark_gate_px}, {self.landmark_weight}")
        if not 0 <= self.refit_passes <= _MAX_REFIT_PASSES or not self.refit_max_residual_px > 0 \
                or self.min_width_curved < 0:
            raise ValueError(f"expected 0 <= refit_passes <= {_MAX_REFIT_PASSES}, refit_max_residual_px > 0 and "
                             f"min_width_curved >= 0, got {self.refit_passes}, {self.refit_max_residual_px}, "
                             f"{self.min_width_curved}")
        if self.wide_panorama_interpolation not in PANORAMA_INTERPOLATIONS:
            raise ValueError(f"wide_panorama_interpolation must be one of {sorted(PANORAMA_INTERPOLATIONS)}, "
                             f"got {self.wide_panorama_interpolation!r}")
        if not self.single_refinement_max_px >= 0:
            raise ValueError(f"expected single_refinement_max_px >= 0, got {self.single_refinement_max_px}")
        if not 0 <= self.wide_search_fraction <= 1:
            raise ValueError(f"expected 0 <= wide_search_fraction <= 1, got {self.wide_search_fraction}")
        if not 0 <= self.prediction_check_tiles < 0.5:
            raise ValueError(f"expected 0 <= prediction_check_tiles < 0.5, got {self.prediction_check_tiles}")
        if not self.max_tile_distortion > 1:
            raise ValueError(f"expected max_tile_distortion > 1, got {self.max_tile_distortion}")
        if not 0 <= self.half_turn_check_rad <= math.pi or not 0 <= self.half_turn_inlier_fraction <= 1 \
                or not 0 < self.half_turn_yaw_window_rad <= math.pi:
            raise ValueError(f"expected 0 <= half_turn_check_rad <= pi, 0 <= half_turn_inlier_fraction <= 1 and "
                             f"0 < half_turn_yaw_window_rad <= pi, got {self.half_turn_check_rad}, "
                             f"{self.half_turn_inlier_fraction}, {self.half_turn_yaw_window_rad}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "IfmiConfig":
        """Inverse of ``dataclasses.asdict``; missing keys take defaults.

        Every value is type-checked (:func:`ifmi.options.options_from_dict`);
        errors name the key path under ``ifmi``.
        """
        return options_from_dict(cls, data, what="ifmi")

    def to_dict(self) -> dict:
        """Nested dict of plain values (inverse of :meth:`from_dict`)."""
        return asdict(self)


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


def averaged_correspondences(first: Correspondences, second: Correspondences) -> Correspondences:
    """Two registrations of one pair merged: a match of frame a's pixel in both gets the mean of
    the two frame-b rays (and pixels); a match in one of them is kept as it is.

    Parameters
    ----------
    first, second : Correspondences
        Matches of the same tiles of frame a (the same ``pixels_a`` and ``rays_a`` for a tile's
        flow points wherever both registrations kept it), with one ``rays_per_measurement``.

    Returns
    -------
    Correspondences
        ``first``'s matches in its order (averaged where ``second`` has them too), then those of
        ``second`` alone; ``first``'s diagnostics.
    """
    where = {row.tobytes(): k for k, row in enumerate(np.ascontiguousarray(first.pixels_a))}
    in_first = np.array([where.get(row.tobytes(), -1) for row in np.ascontiguousarray(second.pixels_a)], dtype=int)
    both = in_first >= 0
    rays_b = first.rays_b.copy()
    rays_b[in_first[both]] += second.rays_b[both]
    rays_b /= np.linalg.norm(rays_b, axis=1, keepdims=True)
    pixels_b = first.pixels_b.copy()
    pixels_b[in_first[both]] = (pixels_b[in_first[both]] + second.pixels_b[both]) / 2.0
    alone = ~both
    return replace(first, pixels_a=np.concatenate([first.pixels_a, second.pixels_a[alone]]),
                   pixels_b=np.concatenate([pixels_b, second.pixels_b[alone]]),
                   rays_a=np.concatenate([first.rays_a, second.rays_a[alone]]),
                   rays_b=np.concatenate([rays_b, second.rays_b[alone]]))


class IfmiFrameState:
    """Prepared frame: wrap-padded panorama (float32); its layout tiles and their spectra on first use.

    The layout tiles and their spectra are needed when the frame is matched
    without a prediction, or as a reference whose tiles are cut anew; with
    tracked tiles most frames need few of them, or none.
    ``tracked`` holds the tiles this frame was last registered with (set by
    the front end; see ``IfmiConfig.track_tiles``).

    Parameters
    ----------
    padded_panorama : (H, W + 2 P) float32 ndarray
        Panorama with ``P`` columns wrapped onto each side.
    pad : int
        ``P``.
    layout : TileLayout
    engine : FourierMellin
    coarse_panorama : (h, w) float32 ndarray or None
        Low-resolution panorama of the coarse stage (:mod:`ifmi.global_motion`).
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
        # R_ab at which this frame's rays were last registered against a reference (with a prediction).
        self.registered_rotation: np.ndarray | None = None
        self.reference: tuple | None = None
        self.reference_curvature: np.ndarray | None = None
        # Landmark rays (IfmiConfig.landmark_rays): this frame's accepted R_0k, the frame-0 rays
        # of its tracked tiles and of its reference tiles (NaN rows: unknown).
        self.rotation: np.ndarray | None = None
        self.tracked_landmarks: np.ndarray | None = None
        self.reference_landmarks: np.ndarray | None = None

    def registration_snapshot(self) -> tuple:
        """What registering this frame against a reference sets (tracked tiles, their landmarks, the
        rotation registered at), for :meth:`restore_registration` when another registration is not kept."""
        return self.tracked, self.tracked_valid, self.tracked_landmarks, self.registered_rotation

    def restore_registration(self, snapshot: tuple) -> None:
        """Set back what :meth:`registration_snapshot` saved."""
        self.tracked, self.tracked_valid, self.tracked_landmarks, self.registered_rotation = snapshot

    def layout_tiles(self, index: np.ndarray | None = None) -> np.ndarray:
        """Layout tiles ``(K, N, N)`` float32, all or ``index`` (bool mask or indices) of them."""
        return tiles_from_panorama(self.padded_panorama, self._layout, index=index, wrapped_columns=self._pad)

    @property
    def spectra(self) -> TileSpectra:
        """Spectra of all layout tiles (:class:`~ifmi.fourier_mellin.TileSpectra`), computed on first access."""
        if self._spectra is None:
            self._spectra = self._engine.spectra(self.layout_tiles())
        return self._spectra


@dataclass(frozen=True)
class _TileMatch:
    """One registration of a reference's tiles in frame b (:meth:`IfmiFrontEnd.register_predicted`)
    at ``rotation`` (``R_ab``), and the tracked tiles it gave frame b."""

    offsets_a: np.ndarray
    linear_a: np.ndarray
    placed: PlacedRegistration
    rotation: np.ndarray
    n_new: int
    tracked: PlacedTiles
    tracked_valid: np.ndarray
    tracked_landmarks: np.ndarray | None

    def restore_tracking(self, state_b: IfmiFrameState) -> None:
        """Give frame b this registration's tracked tiles again (after another registration replaced them)."""
        state_b.tracked, state_b.tracked_valid = self.tracked, self.tracked_valid
        state_b.tracked_landmarks = self.tracked_landmarks


def _coarse_diagnostics(start: np.ndarray, coarse: GlobalMotion) -> dict:
    """Per-frame figures of a coarse-stage result reached from ``start`` (``R_ab``)."""
    change = np.clip((np.trace(start.T @ coarse.rotation) - 1.0) / 2.0, -1.0, 1.0)
    return {"coarse_success": bool(coarse.success), "coarse_correction_rad": float(np.arccos(change)),
            "coarse_sectors": coarse.n_sectors, "coarse_score": coarse.score}


class IfmiFrontEnd:
    """Extended-iFMI correspondences between omni images of one calibrated camera.

    The panorama's radius band is detected from the first prepared image
    (unless the configuration fixes it) and then kept for the sequence.
    ``correspondences`` accepts a predicted rotation ``R_ab``
    (``uses_prior_rotation`` tells the odometry so).

    Parameters
    ----------
    model : OcamModel
    config : IfmiConfig
    """

    def __init__(self, model: OcamModel, config: IfmiConfig = IfmiConfig()):
        self.model = model
        self.config = config
        self.mapping: PanoramaMapping | None = None
        self.layout: TileLayout | None = None
        self.engine: FourierMellin | None = None
        self.global_stage: GlobalMotionEstimator | None = None
        self.dense_layout: TileLayout | None = None
        self._dense_engine: FourierMellin | None = None  # built on the first dense retry
        self._points_b: np.ndarray | None = None
        self._wrapped_columns: np.ndarray | None = None

    @property
    def uses_prior_rotation(self) -> bool:
        """True when ``correspondences`` makes use of a predicted rotation (``config.use_prior``)."""
        return self.config.use_prior

    def _setup(self, image: np.ndarray) -> None:
        self.mapping = panorama_mapping(self.model, image, config=self.config.panorama)
        self._check_tiles_fit()
        self.layout = tile_layout((self.mapping.height, self.mapping.width), config=self.config.tiling)
        self.engine = FourierMellin(self.layout.tile_size, self.layout.count,
                                    config=self.config.registration)
        # Columns of the padded panorama: the panorama's, wrapped by ``_pad`` on either side.
        self._wrapped_columns = np.arange(-self._pad, self.mapping.width + self._pad) % self.mapping.width
        if self.config.coarse_to_fine and self.config.use_prior:
            self.global_stage = GlobalMotionEstimator(self.mapping, config=self.config.global_motion)
        if self.config.dense_retry_fraction > 0 and self.config.use_prior:
            self.dense_layout = tile_layout((self.mapping.height, self.mapping.width),
                                            config=replace(self.config.tiling, overlap=self.config.dense_overlap))
        self._points_b = flow_sample_points(self.layout.tile_size,
                                            points_per_tile=self.config.points_per_tile,
                                            spread=self.config.point_spread)

    @property
    def dense_engine(self) -> FourierMellin:
        """Registration engine of the denser layout (built on first use: most sequences never retry)."""
        if self._dense_engine is None:
            self._dense_engine = FourierMellin(self.dense_layout.tile_size, self.dense_layout.count,
                                               config=self.config.registration)
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
            self.mapping, gray, interpolation=self.config.wide_panorama_interpolation if self._wide else "linear")
        # The wrapped columns are copied, not resampled again: the same values, 2 x _pad fewer columns
        # through the (Lanczos) remap.
        padded = np.take(panorama, self._wrapped_columns, axis=1)
        coarse = None
        if self.global_stage is not None:
            coarse = self.global_stage.coarse_panorama(panorama)
        return IfmiFrameState(padded, self._pad, self.layout, self.engine, coarse)

    @property
    def _wide(self) -> bool:
        """A panorama of sharp high-resolution images (``IfmiConfig.min_width_curved``)."""
        return self.mapping.width >= self.config.min_width_curved

    @property
    def _curved(self) -> bool:
        """Curved placements (and refit passes) on this panorama (``IfmiConfig.min_width_curved``)."""
        return self.config.curved_placement and self._wide

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
            ``Q_a`` (see :meth:`ifmi.fourier_mellin.FourierMellin.resample_placed`); None is zero.
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
        jacobian = np.stack([(f[:, 2, 1] - f[:, 0, 1]) / (2 * h), (f[:, 1, 2] - f[:, 1, 0]) / (2 * h)], axis=-1)
        h_rr = (f[:, 2, 1] - 2 * f[:, 1, 1] + f[:, 0, 1]) / h ** 2
        h_cc = (f[:, 1, 2] - 2 * f[:, 1, 1] + f[:, 1, 0]) / h ** 2
        h_rc = (f[:, 2, 2] - f[:, 2, 0] - f[:, 0, 2] + f[:, 0, 0]) / (4 * h ** 2)
        hessian = np.stack([np.stack([h_rr, h_rc], axis=-1), np.stack([h_rc, h_cc], axis=-1)], axis=-1)  # (T, 2o, 2, 2)
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
        limit = self.config.max_tile_distortion
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
        if not self.config.track_tiles or tracked is None:
            state.reference = (offsets, linear, state.spectra, self.layout.count)
            state.reference_landmarks = self._landmarks(state, offsets, None, np.ones(self.layout.count, bool))
            return state.reference
        # A tracked reference is matched at predicted placements, where log-polar descriptors
        # serve only when the residual rotation and scale are measured. Tiles the registration
        # resampled (not anchored templates) come without energy centroids.
        registration = self.config.registration
        with_descriptor = registration.estimate_rotation_scale and registration.refine_predicted_rotation_scale
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
        (``IfmiConfig.landmark_rays``); a frame never accepted keeps measured rays."""
        state.rotation = np.asarray(rotation, dtype=np.float64)

    def _landmarks(self, state: IfmiFrameState, offsets: np.ndarray, tracked: np.ndarray | None,
                   new: np.ndarray) -> np.ndarray | None:
        """Frame-0 rays of a reference's tiles: carried along the track, or the accepted
        rotation's image of a new tile's ray; None when the frame has no accepted pose."""
        if not (self.config.landmark_rays and self._wide) or state.rotation is None:
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

    def register_predicted(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *,
                           prior_rotation: np.ndarray):
        """Find the reference's tiles in frame b where a predicted rotation puts them.

        Frame b keeps the reference's templates at their final placements
        in b (``anchor_templates``), or the tiles the final residual was
        measured on, as its tracked tiles (used when it becomes a reference,
        ``track_tiles``).

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
        prior_rotation : (3, 3) ndarray, keyword-only
            Predicted ``R_ab``.

        Returns
        -------
        offsets_a : (T, 2) ndarray
            Panorama ``(row, col)`` of the reference tiles' centres in frame a.
        linear_a : (T, 2, 2) ndarray
        placed : PlacedRegistration
            With panorama coordinates of frame b (columns in ``[0, width)``).
        n_new : int
            Reference tiles cut anew from the layout.
        """
        offsets_a, linear_a, spectra_a, n_new = self.reference_tiles(state_a)
        offsets_b, linear_b = self.predicted_placements(offsets_a, linear_a, prior_rotation)
        curvature_b = None
        if self._curved:
            curvature_b = self.predicted_curvature(offsets_a, linear_a, state_a.reference_curvature, prior_rotation)
        shift = np.array([0.0, self._pad])
        width = self.mapping.width

        def unpadded(offsets):
            offsets = offsets - shift
            offsets[:, 1] = np.mod(offsets[:, 1], width)
            return offsets

        offsets_b[:, 1] = np.mod(offsets_b[:, 1], width)
        placed, refined = self._register_for_refit(spectra_a, state_b, offsets_b + shift, linear_b, curvature_b)
        for _ in range(self.config.refit_passes if self._curved else 0):
            if placed.valid.sum() < max(self.config.min_tiles, _MIN_REFIT_TILES):
                break
            # The tiles' own rotation replaces the prediction in their shape (affine and
            # curvature), which the registration does not measure; the centres stay as measured.
            rotation, residual = _robust_rotation(
                rays_from_panorama_pixels(self.mapping, offsets_a[placed.valid]),
                rays_from_panorama_pixels(self.mapping, unpadded(placed.offsets)[placed.valid]))
            if residual > self.config.refit_max_residual_px * 2 * np.pi / width:
                break  # parallax or wrong tiles: the tiles do not agree on a rotation
            _, linear_b = self.predicted_placements(offsets_a, linear_a, rotation)
            curvature_b = self.predicted_curvature(offsets_a, linear_a, state_a.reference_curvature, rotation)
            placed = self.engine.refine_placed(spectra_a, state_b.padded_panorama, placed, linear_b,
                                               curvature_b=curvature_b)
            refined = True
        if not refined:  # no refit: refine with the predicted shape
            placed = self.engine.refine_placed(spectra_a, state_b.padded_panorama, placed, linear_b,
                                               curvature_b=curvature_b)
        last = replace(placed.last, offsets=unpadded(placed.last.offsets))
        placed = replace(placed, offsets=unpadded(placed.offsets), last=last)
        if self.config.anchor_templates:
            # The reference's templates, placed where they were found in b.
            state_b.tracked = PlacedTiles(tiles=None, offsets=placed.offsets, linear=placed.linear,
                                          spectra=spectra_a, curvature=curvature_b)
        else:
            state_b.tracked = last
        state_b.tracked_valid = placed.valid
        state_b.tracked_landmarks = state_a.reference_landmarks
        state_b.reference = None
        return offsets_a, linear_a, placed, n_new

    def _register_for_refit(self, spectra_a: TileSpectra, state_b: IfmiFrameState, offsets_b: np.ndarray,
                            linear_b: np.ndarray, curvature_b: np.ndarray | None):
        """``register_placed`` at the prediction, and whether its refinement passes ran.

        With a refit to follow and the kept tiles' median search move within
        ``config.single_refinement_max_px`` (panorama pixels), the passes are
        left to the refit; otherwise they run on the predicted shape.
        """
        engine, source = self.engine, state_b.padded_panorama
        if not (self._curved and self.config.refit_passes and self.config.single_refinement_max_px > 0):
            return engine.register_placed(spectra_a, source, offsets_b, linear_b, curvature_b=curvature_b), True
        placed = engine.register_placed(spectra_a, source, offsets_b, linear_b, curvature_b=curvature_b,
                                        refine=False)
        moved = np.hypot(*(placed.offsets - offsets_b)[placed.valid].T)
        if moved.size and np.median(moved) <= self.config.single_refinement_max_px:
            return placed, False
        return engine.refine_placed(spectra_a, source, placed, linear_b, curvature_b=curvature_b), True

    def _landmark_pairs(self, pairs, offsets_a: np.ndarray, landmarks: np.ndarray,
                        rotation_a: np.ndarray) -> tuple:
        """``pairs`` with each tile's rays in frame a turned so that its centre lies on its
        landmark ray as the accepted ``R_0a`` sees it, where the two are within
        ``config.landmark_gate_px``; and how many tiles were turned."""
        measured = rays_from_panorama_pixels(self.mapping, offsets_a)
        seen = landmarks @ rotation_a  # R_0a^T applied to each frame-0 ray
        gate = self.config.landmark_gate_px * 2 * np.pi / self.mapping.width
        close = np.isfinite(seen).all(axis=1) & (np.einsum("ti,ti->t", measured, np.nan_to_num(seen)) >= np.cos(gate))
        if not close.any():
            return pairs, 0
        turns = np.broadcast_to(np.eye(3), (len(offsets_a), 3, 3)).copy()
        turns[close] = matrix_aligning_rays(measured[close], seen[close], fraction=self.config.landmark_weight)
        per_point = np.repeat(turns, len(self._points_b), axis=0)
        rays_a = np.einsum("nij,nj->ni", per_point, pairs.rays_a)
        return pairs_with_rays_a(pairs, rays_a, self.mapping), int(close.sum())

    def _diagnostics(self, reason: np.ndarray, peak_ratio: np.ndarray, peak_to_noise: np.ndarray,
                     n_new: int) -> dict:
        counts = np.bincount(reason, minlength=len(TileRejection))
        return {
            "n_tiles": int(self.layout.count),
            "n_tiles_kept": int((reason == TileRejection.KEPT).sum()),
            **{f"n_tiles_{kind.label}": int(counts[kind]) for kind in TileRejection if kind},
            "n_tiles_new": int(n_new),
            "median_peak_ratio": float(np.median(peak_ratio)),
            "median_peak_to_noise": float(np.median(peak_to_noise)),
        }

    def _coarse_rotation(self, state_a: IfmiFrameState, state_b: IfmiFrameState,
                         starts: tuple) -> tuple[np.ndarray, dict]:
        """``R_ab`` of the coarse stage from the best of ``starts`` (None: the identity), and its figures."""
        first = np.eye(3) if starts[0] is None else starts[0]
        if self.global_stage is None:
            return first, {}
        coarse = self.global_stage.estimate(state_a.coarse_panorama, state_b.coarse_panorama, priors=starts)
        return coarse.rotation, _coarse_diagnostics(first, coarse)

    def _needs_wide_search(self, match: "_TileMatch", diagnostics: dict) -> bool:
        """Few tiles passed after the coarse stage moved the prediction far (more than
        ``global_motion.confirm_angle_rad``): it may have jumped to a wrong yaw. Where it kept or
        nudged the prediction, the tiles fail for noise or parallax, which the wide search cannot
        help unless the pair cannot be solved (:meth:`rescue_correspondences`)."""
        return (self._wide_search_on()
                and match.placed.valid.sum() <= self.config.wide_search_fraction * self.layout.count
                and diagnostics.get("coarse_correction_rad", 0.0) > self.config.global_motion.confirm_angle_rad)

    def _wide_search_on(self) -> bool:
        """Whether the wide search can run (a coarse stage, ``config.wide_search_fraction`` above 0)."""
        return self.global_stage is not None and self.config.wide_search_fraction > 0

    def _wide_search(self, state_a: IfmiFrameState, state_b: IfmiFrameState, diagnostics: dict,
                     prediction: np.ndarray, *, every_start: bool = False) -> GlobalMotion | None:
        """The coarse stage's wide search around ``prediction``: a rotation matching better than the
        coarse rotation the tiles were registered at (``diagnostics["coarse_score"]``), or None."""
        return self.global_stage.wide_search(state_a.coarse_panorama, state_b.coarse_panorama, start=prediction,
                                             current_score=diagnostics["coarse_score"], every_start=every_start)

    def _searched_tiles(self, state_a: IfmiFrameState, state_b: IfmiFrameState, coarse: GlobalMotion,
                        start: np.ndarray, *, search: str) -> tuple["_TileMatch", dict]:
        """Tiles at the rotation ``coarse`` of a coarse search from ``start``, and their figures, with the
        search's name (``"wide_search"``, ``"half_turn"``) set true in them."""
        match = self._tiles_at(state_a, state_b, coarse.rotation)
        tiles = self._diagnostics(match.placed.reason, match.placed.peak_ratio, match.placed.peak_to_noise,
                                  match.n_new)
        return match, {**tiles, **_coarse_diagnostics(start, coarse), search: True}

    def _tiles_at(self, state_a: IfmiFrameState, state_b: IfmiFrameState, rotation: np.ndarray) -> _TileMatch:
        """:meth:`register_predicted` at ``rotation``, with the tracking it left in frame b."""
        offsets_a, linear_a, placed, n_new = self.register_predicted(state_a, state_b, prior_rotation=rotation)
        return _TileMatch(offsets_a, linear_a, placed, rotation, n_new, state_b.tracked, state_b.tracked_valid,
                          state_b.tracked_landmarks)

    def _checks_prediction(self, prediction: np.ndarray | None, rotation: np.ndarray, correction_rad: float) -> bool:
        """Whether the tiles are registered at a prediction the coarse stage moved to ``rotation``
        (by ``correction_rad``); a prediction the coarse stage returned unchanged is not."""
        if prediction is None or self.config.prediction_check_tiles <= 0 or np.array_equal(rotation, prediction):
            return False
        correction_px = correction_rad * self.mapping.width / (2 * np.pi)
        return correction_px <= self.config.prediction_check_tiles * self.layout.tile_size

    def _match_predicted(self, state_a: IfmiFrameState, state_b: IfmiFrameState,
                         starts: tuple) -> tuple[_TileMatch, dict]:
        """Coarse stage from ``starts``, then the tiles at the placements it predicts.

        When the coarse stage moved the first start (the prediction) by less
        than ``config.prediction_check_tiles`` and not every tile passed, the
        tiles are registered at the prediction too and the registration
        keeping more tiles is returned; frame b keeps that registration's
        tracked tiles.
        """
        rotation, coarse = self._coarse_rotation(state_a, state_b, starts)
        match = self._tiles_at(state_a, state_b, rotation)
        # With every tile kept the prediction cannot keep more: no second registration.
        if match.placed.valid.sum() < self.layout.count and \
                self._checks_prediction(starts[0], rotation, coarse.get("coarse_correction_rad", 0.0)):
            at_prediction = self._tiles_at(state_a, state_b, starts[0])
            coarse["n_tiles_kept_coarse"] = int(match.placed.valid.sum())
            coarse["prediction_kept"] = bool(at_prediction.placed.valid.sum() > match.placed.valid.sum())
            if coarse["prediction_kept"]:
                match = at_prediction
            match.restore_tracking(state_b)
        diagnostics = self._diagnostics(match.placed.reason, match.placed.peak_ratio, match.placed.peak_to_noise,
                                        match.n_new)
        return match, {**diagnostics, **coarse}

    def _dense_selection(self, state_a: IfmiFrameState) -> np.ndarray | None:
        """Indices of the denser layout's tiles the retry registers (None: all of them)."""
        per_column = self.config.dense_tiles_per_column
        if per_column is None or per_column >= self.dense_layout.grid_shape[0]:
            return None
        strength = tile_corner_strengths(state_a.padded_panorama, self.dense_layout, wrapped_columns=self._pad)
        return strongest_tiles_per_column(strength, self.dense_layout, per_column)

    def register_dense(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *,
                       prior_rotation: np.ndarray):
        """Tiles of the denser layout cut from frame a, found in frame b where ``R_ab`` puts them.

        Frame b's tracked tiles are left as they are. With
        ``dense_tiles_per_column`` only that many tiles of each layout
        column are registered (the most textured in frame a).

        Returns
        -------
        offsets_a : (K, 2) ndarray
            Panorama ``(row, col)`` of the registered tiles' centres in frame a.
        linear_a : (K, 2, 2) ndarray
        placed : PlacedRegistration
            With panorama coordinates of frame b (columns in ``[0, width)``).
        """
        layout = self.dense_layout
        registration = self.config.registration
        with_descriptor = registration.estimate_rotation_scale and registration.refine_predicted_rotation_scale
        index = self._dense_selection(state_a)
        tiles = tiles_from_panorama(state_a.padded_panorama, layout, index=index, wrapped_columns=self._pad)
        spectra_a = self.dense_engine.spectra(tiles, with_descriptor=with_descriptor)
        origins = layout.origins if index is None else layout.origins[index]
        offsets_a = origins.astype(np.float64) + (layout.tile_size - 1) / 2.0
        linear_a = np.broadcast_to(np.eye(2), (len(origins), 2, 2)).copy()
        offsets_b, linear_b = self.predicted_placements(offsets_a, linear_a, prior_rotation)
        curvature_b = None
        if self._curved:
            curvature_b = self.predicted_curvature(offsets_a, linear_a, None, prior_rotation)
        offsets_b[:, 1] = np.mod(offsets_b[:, 1], self.mapping.width)
        shift = np.array([0.0, self._pad])
        placed = self.dense_engine.register_placed(spectra_a, state_b.padded_panorama, offsets_b + shift, linear_b,
                                                   curvature_b=curvature_b)
        offsets = placed.offsets - shift
        offsets[:, 1] = np.mod(offsets[:, 1], self.mapping.width)
        return offsets_a, linear_a, replace(placed, offsets=offsets)

    def _tile_points(self, centroids: np.ndarray) -> np.ndarray:
        """Flow points of every tile ``(T, K, 2)`` on its energy centroid, or the shared ``(K, 2)``."""
        if not self.config.flow_at_energy_centroid:
            return self._points_b
        return points_on_centroids(self._points_b, centroids)

    def correspondences(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *,
                        prior_rotation: np.ndarray | None = None):
        """Ray pairs of frame a (reference) and frame b from the kept tiles.

        With a predicted rotation (and ``config.use_prior``) the coarse stage
        (``config.coarse_to_fine``) corrects the prediction, and the
        reference's tiles (tracked or from the layout) are looked for in
        frame b where the corrected prediction puts them, cut with its local
        affine map (a small correction is checked by registering at the
        prediction too, ``config.prediction_check_tiles``); frame b then
        keeps the tiles it was registered with (``track_tiles``). If too few
        tiles pass, the coarse stage searches again from the identity and
        the tiles are registered once more.

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
        prior_rotation : (3, 3) ndarray, optional, keyword-only
            Predicted ``R_ab``; used when ``config.use_prior``.

        Returns
        -------
        Correspondences
        """
        if not self.config.use_prior:
            prior_rotation = None
        if prior_rotation is None:
            motion, origins_b = self.register(state_a, state_b)
            diagnostics = self._diagnostics(motion.reason, motion.peak_ratio, motion.peak_to_noise,
                                            self.layout.count)
            if motion.valid.sum() < self.config.min_tiles:
                return self._too_few_tiles(motion.valid, diagnostics)
            pairs = flow_from_tile_motion(motion, self.layout, self.mapping, origins_b=origins_b,
                                          points_b=self._tile_points(state_b.spectra.centroid))
            return self._from_pairs(pairs, diagnostics)
        match, diagnostics = self._match_predicted(state_a, state_b, (prior_rotation, None))
        if match.placed.valid.sum() < self.config.min_tiles and self.global_stage is not None:
            # Re-acquisition: the prediction may be far off after fast motion or a lost frame.
            retry, retry_diagnostics = self._match_predicted(state_a, state_b, (None, prior_rotation))
            if retry.placed.valid.sum() > match.placed.valid.sum():
                match, diagnostics = retry, {**retry_diagnostics, "reacquired": True}
            match.restore_tracking(state_b)
        if self._needs_wide_search(match, diagnostics):
            # The coarse match decides here, not the tile count: both registrations have few tiles
            # passing, and under parallax (lawn with translation) the right rotation can keep as few
            # as the wrong one (2 against 3) until the dense retry registers more.
            searched = self._wide_search(state_a, state_b, diagnostics, prior_rotation)
            if searched is not None and self.global_stage.clearly_better(
                    searched, current_rotation=match.rotation, current_score=diagnostics["coarse_score"]):
                match, diagnostics = self._searched_tiles(state_a, state_b, searched, prior_rotation,
                                                           search="wide_search")
        return self._correspondences_from_match(state_a, state_b, match, diagnostics)

    def rescue_correspondences(self, state_a: IfmiFrameState, state_b: IfmiFrameState, failed: Correspondences, *,
                               prior_rotation: np.ndarray | None = None) -> Correspondences | None:
        """Correspondences of a pair that could not be solved, registered at the best rotation of a
        wide search from every start, or None.

        Called by the odometry when :meth:`correspondences` failed or the
        back end could not solve what it returned (too few tiles kept
        inliers). Any rotation whose panorama matches better than the
        coarse stage's is tried, not only a clearly better one
        (:meth:`_needs_wide_search`): under parallax every coarse rotation
        leaves most of the panorama mismatch, and on the first pair of a
        sequence the prediction is the identity, which the coarse stage
        keeps when its own search from there matches worse.

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
            The pair ``failed`` was matched from (reference a, frame b).
        failed : Correspondences
            What :meth:`correspondences` returned for the pair.
        prior_rotation : (3, 3) ndarray, optional, keyword-only
            The predicted ``R_ab`` it was given.

        Returns
        -------
        Correspondences or None
            With ``wide_search`` and ``wide_rescue`` in the diagnostics;
            None when there is nothing to try (no prediction or coarse
            stage, the wide search off or already taken for the pair, no
            better-matching rotation) or the tiles fail there too. Frame b
            then keeps its first registration.
        """
        if not self.config.use_prior or prior_rotation is None or not self._wide_search_on() \
                or "coarse_score" not in failed.diagnostics or "wide_search" in failed.diagnostics:
            return None
        searched = self._wide_search(state_a, state_b, failed.diagnostics, prior_rotation, every_start=True)
        if searched is None:
            return None
        first = state_b.registration_snapshot()
        wide, diagnostics = self._searched_tiles(state_a, state_b, searched, prior_rotation, search="wide_search")
        rescued = self._correspondences_from_match(state_a, state_b, wide, {**diagnostics, "wide_rescue": True})
        if rescued.success:
            return rescued
        state_b.restore_registration(first)
        return None

    def half_turn_alternative(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *, rotation_ab: np.ndarray,
                              n_inliers: int, prior_rotation: np.ndarray | None, solve) -> tuple | None:
        """The pair solved again from ``rotation_ab`` turned half round, when that lies nearer the prediction.

        A room of one texture seen from near its middle (brick on every
        wall, a ring of alike objects) matches itself turned half round
        about the vertical. On the first pair of a sequence the prediction
        is the identity, and under parallax the half turn can match the
        panoramas and keep tiles as well as the true rotation or better, so
        the pair is solved, successfully, about pi away from the truth, and
        every later pose keeps the error. When the back end's ``rotation_ab``
        lies more than ``config.half_turn_check_rad`` from the prediction,
        it is turned half round about the panorama axis (on either side:
        the scene's turn is about the vertical, which is the axis of
        whichever frame is upright), the coarse stage refines both with the
        yaw kept within ``config.half_turn_yaw_window_rad``, and the tiles
        are registered at the better match (dense retry included) and
        solved. That solution replaces the first when it lies nearer the
        prediction and keeps at least ``config.half_turn_inlier_fraction``
        of the first's inliers: where the frames cannot tell the two apart,
        the smaller motion is taken.

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
            The pair that was solved (reference a, frame b).
        rotation_ab : (3, 3) ndarray, keyword-only
            ``R_ab`` the back end solved.
        n_inliers : int, keyword-only
            Its inlier count.
        prior_rotation : (3, 3) ndarray or None, keyword-only
            The predicted ``R_ab`` the pair was matched with.
        solve : callable, keyword-only
            ``solve(correspondences) -> (pose, info)``: the odometry's back end.

        Returns
        -------
        tuple or None
            ``(pose, info, correspondences)`` of the alternative, with
            ``half_turn: True`` in the diagnostics; None when it is not
            tried (no prediction or coarse stage, ``rotation_ab`` within the
            bound) or not taken. Frame b then keeps its first registration.
        """
        if not self.config.use_prior or prior_rotation is None or self.global_stage is None:
            return None
        far = float(geodesic_angle(prior_rotation, rotation_ab))
        if far <= self.config.half_turn_check_rad:
            return None
        first = state_b.registration_snapshot()
        half_turn = self._half_turn
        rotation_ab = np.asarray(rotation_ab, dtype=np.float64)
        starts = np.stack([half_turn @ rotation_ab, rotation_ab @ half_turn])
        coarse = self.global_stage.search_near(state_a.coarse_panorama, state_b.coarse_panorama, starts=starts,
                                               max_yaw_rad=self.config.half_turn_yaw_window_rad)
        match, diagnostics = self._searched_tiles(state_a, state_b, coarse, starts[0], search="half_turn")
        corr = self._correspondences_from_match(state_a, state_b, match, diagnostics)
        if corr.success:
            pose, info = solve(corr)
            if (info.success and float(geodesic_angle(prior_rotation, pose.rotation)) < far
                    and info.n_inliers >= self.config.half_turn_inlier_fraction * n_inliers):
                return pose, info, corr
        state_b.restore_registration(first)
        return None

    @property
    def _half_turn(self) -> np.ndarray:
        """Half turn (3, 3) about the panorama axis, in the camera frame."""
        axis_frame = self.mapping.camera_from_panorama
        half_turn = np.diag([-1.0, -1.0, 1.0])
        return half_turn if axis_frame is None else axis_frame @ half_turn @ axis_frame.T

    def _too_few_tiles(self, valid: np.ndarray, diagnostics: dict) -> Correspondences:
        """A failed pair: fewer than ``config.min_tiles`` of the ``valid`` tiles passed."""
        return Correspondences.failed(
            f"only {int(valid.sum())} of {self.layout.count} tiles passed the noise filters "
            f"(need {self.config.min_tiles})", diagnostics)

    def _from_pairs(self, pairs, diagnostics: dict) -> Correspondences:
        """Correspondences of the flow ``pairs`` (one measurement per tile)."""
        return Correspondences(pixels_a=pairs.pixels_a, pixels_b=pairs.pixels_b,
                               rays_a=pairs.rays_a, rays_b=pairs.rays_b, diagnostics=diagnostics,
                               rays_per_measurement=len(self._points_b))

    def _correspondences_from_match(self, state_a: IfmiFrameState, state_b: IfmiFrameState, match: _TileMatch,
                                    diagnostics: dict) -> Correspondences:
        """Rays of a predicted registration ``match``, or of the dense retry at its rotation when
        at most ``config.dense_retry_fraction`` of its tiles passed and the retry keeps more."""
        valid = match.placed.valid
        state_b.registered_rotation = match.rotation
        if self.dense_layout is not None and valid.sum() <= self.config.dense_retry_fraction * self.layout.count:
            dense = self.register_dense(state_a, state_b, prior_rotation=match.rotation)
            diagnostics = {**diagnostics, "n_tiles_kept_dense": int(dense[2].valid.sum())}
            if dense[2].valid.sum() > valid.sum():
                return self._placed_correspondences(state_a, *dense, diagnostics, dense=True)
        return self._placed_correspondences(state_a, match.offsets_a, match.linear_a, match.placed, diagnostics,
                                            dense=False)

    def _placed_correspondences(self, state_a: IfmiFrameState, offsets_a: np.ndarray, linear_a: np.ndarray,
                                placed: PlacedRegistration, diagnostics: dict, *, dense: bool) -> Correspondences:
        """Rays of the kept tiles of a registration of frame a's tiles (reference tiles, or the
        ``dense`` layout's cut anew: no curvature or landmarks of their own)."""
        valid = placed.valid
        if valid.sum() < self.config.min_tiles:
            return self._too_few_tiles(valid, diagnostics)
        curvature_a = None if dense else state_a.reference_curvature
        landmarks = None if dense else state_a.reference_landmarks
        pairs = flow_from_placements(offsets_a, linear_a, placed.offsets, placed.linear, valid, self.mapping,
                                     points=self._tile_points(placed.template_centroid),
                                     tile_size=self.layout.tile_size,
                                     curvature_a=curvature_a, curvature_b=placed.last.curvature)
        if landmarks is not None:
            pairs, diagnostics["n_tiles_landmark"] = self._landmark_pairs(pairs, offsets_a[valid],
                                                                          landmarks[valid], state_a.rotation)
        return self._from_pairs(pairs, diagnostics)

    def refine_correspondences(self, state_a: IfmiFrameState, state_b: IfmiFrameState, first: Correspondences, *,
                               rotation_ab: np.ndarray) -> Correspondences | None:
        """``first`` averaged with a second registration at the back end's solved rotation, or None.

        Pairs whose registration kept at most ``config.reregister_fraction``
        of the layout's tiles (as ``first``'s ``n_tiles_kept`` says) are
        registered again where ``rotation_ab`` puts the tiles that gave
        ``first``'s rays (the reference's tiles, or the dense retry's), if
        that moves them at least ``config.reregister_min_px``; no coarse
        stage and no dense retry. A second registration of the reference's
        tiles gives frame b its tracked tiles (placed at the better
        rotation).

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
            The pair ``first`` was matched from (reference a, frame b).
        first : Correspondences
            What :meth:`correspondences` returned for the pair.
        rotation_ab : (3, 3) ndarray, keyword-only
            ``R_ab`` the back end solved from ``first``.

        Returns
        -------
        Correspondences or None
            Both registrations' matches merged by
            :func:`averaged_correspondences`, with ``first``'s diagnostics
            and ``n_tiles_kept_reregistered``; None
            when the pair is not registered again (enough tiles passed, no
            prediction in use, ``reregister_fraction`` 0, a move under
            ``reregister_min_px``) or the second registration failed.
        """
        kept = first.diagnostics.get("n_tiles_kept")
        fraction = self.config.reregister_fraction
        if (fraction == 0 or not first.success or state_b.registered_rotation is None or kept is None
                or kept > fraction * self.layout.count):
            return None
        rotation_ab = np.asarray(rotation_ab, dtype=np.float64)
        moved = geodesic_angle(state_b.registered_rotation, rotation_ab)
        if moved * self.mapping.width / (2 * np.pi) < self.config.reregister_min_px:
            return None
        if first.diagnostics.get("n_tiles_kept_dense", -1) > kept:  # the first rays are the dense retry's
            offsets_a, linear_a, placed = self.register_dense(state_a, state_b, prior_rotation=rotation_ab)
            second = self._placed_correspondences(state_a, offsets_a, linear_a, placed, {}, dense=True)
        else:
            match = self._tiles_at(state_a, state_b, rotation_ab)
            placed = match.placed
            second = self._placed_correspondences(state_a, match.offsets_a, match.linear_a, placed, {}, dense=False)
        if not second.success:
            return None
        diagnostics = {**first.diagnostics, "n_tiles_kept_reregistered": int(placed.valid.sum())}
        return replace(averaged_correspondences(first, second), diagnostics=diagnostics)
