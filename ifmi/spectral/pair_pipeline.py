"""The iFMI front end's per-pair pipeline: one frame pair through named stages, in a fixed order.

The odometry predicts ``R_ab`` (constant angular velocity) and hands the
pair to :func:`solve_pair`, which runs these stages, each returning an
immutable result (the page *How it works: the per-pair pipeline* of the
documentation draws them):

1. **register** (:func:`registered`): the reference's tiles are registered
   in frame b where the prediction puts them; unless they settle there, the
   coarse stage corrects the prediction from whole low-resolution panoramas
   and the tiles are registered where the corrected rotation puts them (a
   small correction is checked against the registration at the prediction).
2. **verify**: the kept-tile count decides whether a recovery runs.
3. **recover**: *re-acquire* (too few tiles: the coarse stage searches
   again from the identity), *wide search* (few tiles after a large coarse
   correction: tilted starts around the prediction), *dense retry* (few
   tiles: a denser layout cut anew from frame a at the same rotation).
4. **rays**: the kept tiles' flow points become ray pairs.
5. **solve**: the odometry's back end (``solve(correspondences)``).
6. **rescue**: a pair that did not solve is registered again at the best
   rotation of a wide search from every start.
7. **check (half turn)**: a solution far from the prediction is solved
   again from its half turn about the panorama axis; the nearer is kept
   when it explains the frames about as well.
8. **refine**: a weak pair's tiles are registered again at the solved
   rotation, the two registrations' matches averaged and solved again.
9. **keep**: frame b keeps the tiles of the registration the pair settled
   on (tracked tiles, used when it becomes a reference). This is the only
   write to a frame's state.

A pair of an uncompressed capture that no stage solved goes through them all
once more with the band-limited search of noise-dominated pairs
(the front end's ``solve_pair``), kept when it solves the pair.

The diagnostics are a :class:`PairDiagnostics`; each stage's wall time is
one of its ``t_<stage>_ms`` fields, and its fields are the iFMI columns of
``frames.csv``.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, fields, replace
from typing import Callable

import numpy as np

from ifmi.front_end import Correspondences, SolvedPair
from ifmi.spectral.fourier_mellin import PlacedRegistration, PlacedTiles, TileRejection
from ifmi.geometry.rotations import geodesic_angle

# The front end and frame states are those of ifmi.spectral.ifmi_front_end (which imports this module):
# named in annotations only.

__all__ = ["PairDiagnostics", "TileMatch", "Matched", "STAGES", "HALF_TURN_INLIER_FRACTION", "HALF_TURN_YAW_WINDOW_RAD",
           "solve_pair", "matched", "registered", "rescued", "half_turn_checked", "refined",
           "averaged_correspondences"]

# The half-turn alternative replaces the first solution only with at least half its inliers: the frames
# explain both about as well (a scene that does not repeat half round leaves the alternative few tiles).
HALF_TURN_INLIER_FRACTION = 0.5
# The turned rotation is refined by the coarse stage with its yaw kept within 20 degrees of the start: the
# turn is about the vertical, so the start's yaw is right to within the cameras' tilt from it; a quarter
# turn lets the search jump to a neighbour of a ring of alike objects.
HALF_TURN_YAW_WINDOW_RAD = 0.35
# The timed stages, in the order they run; each has the column t_<stage>_ms.
STAGES = ("register", "reacquire", "wide_search", "dense_retry", "rays", "solve", "rescue", "half_turn", "refine")


def _angle_rad(start: np.ndarray, end: np.ndarray) -> float:
    """Angle of the rotation from ``start`` to ``end`` (radians)."""
    return float(np.arccos(np.clip((np.trace(start.T @ end) - 1.0) / 2.0, -1.0, 1.0)))


@dataclass(frozen=True)
class PairDiagnostics:
    """Figures of one pair, the iFMI columns of ``frames.csv`` (None: the stage did not report it).

    Attributes
    ----------
    n_tiles : int
        Tiles of the layout.
    n_tiles_kept : int
        Tiles that passed the noise filters in the registration that gave the rays.
    n_tiles_textureless, n_tiles_low_peak_ratio, n_tiles_low_peak_to_noise_ratio : int
        Tiles rejected for each reason (:class:`~ifmi.spectral.fourier_mellin.TileRejection`).
    n_tiles_new : int
        Reference tiles cut anew from the layout (not tracked).
    median_peak_ratio, median_peak_to_noise : float
        Medians over the tiles of the correlation quality.
    coarse_success : bool or None
        Whether the coarse stage found enough sectors.
    coarse_correction_rad : float or None
        Angle the coarse stage moved its start (radians).
    coarse_sectors : int or None
        Sectors the coarse stage kept.
    coarse_score : float or None
        Panorama mismatch of the coarse rotation (lower is better).
    n_tiles_kept_coarse : int or None
        Kept tiles at the coarse rotation, when the prediction was registered too.
    prediction_kept : bool or None
        The registration at the prediction kept more tiles and was taken.
    reacquired : bool or None
        The re-acquisition from the identity was taken.
    wide_search, half_turn : bool or None
        The tiles were registered at that search's rotation.
    wide_rescue : bool or None
        An unsolved pair was registered again at the wide search from every start.
    band_limited_retry : bool or None
        An unsolved pair of an uncompressed capture went through every stage again with the
        band-limited search, which solved it (set by the front end's ``solve_pair``).
    n_tiles_kept_dense : int or None
        Kept tiles of the dense retry.
    n_tiles_landmark : int or None
        Tiles whose rays were turned towards their landmarks.
    n_tiles_kept_reregistered : int or None
        Kept tiles of the refine stage's second registration.
    t_register_ms, ..., t_refine_ms : float
        Wall time of each stage of :data:`STAGES` on this pair (milliseconds; 0 when it did not run).
    """

    n_tiles: int
    n_tiles_kept: int
    n_tiles_textureless: int
    n_tiles_low_peak_ratio: int
    n_tiles_low_peak_to_noise_ratio: int
    n_tiles_new: int
    median_peak_ratio: float
    median_peak_to_noise: float
    coarse_success: bool | None = None
    coarse_correction_rad: float | None = None
    coarse_sectors: int | None = None
    coarse_score: float | None = None
    n_tiles_kept_coarse: int | None = None
    prediction_kept: bool | None = None
    reacquired: bool | None = None
    wide_search: bool | None = None
    half_turn: bool | None = None
    wide_rescue: bool | None = None
    band_limited_retry: bool | None = None
    n_tiles_kept_dense: int | None = None
    n_tiles_landmark: int | None = None
    n_tiles_kept_reregistered: int | None = None
    t_register_ms: float = 0.0
    t_reacquire_ms: float = 0.0
    t_wide_search_ms: float = 0.0
    t_dense_retry_ms: float = 0.0
    t_rays_ms: float = 0.0
    t_solve_ms: float = 0.0
    t_rescue_ms: float = 0.0
    t_half_turn_ms: float = 0.0
    t_refine_ms: float = 0.0

    @classmethod
    def of_tiles(cls, placed, n_tiles: int, n_new: int) -> "PairDiagnostics":
        """The tile figures of a registration (``reason``, ``peak_ratio``, ``peak_to_noise`` per tile)."""
        counts = np.bincount(placed.reason, minlength=len(TileRejection))
        return cls(n_tiles=int(n_tiles), n_tiles_kept=int(counts[TileRejection.KEPT]),
                   n_tiles_textureless=int(counts[TileRejection.TEXTURELESS]),
                   n_tiles_low_peak_ratio=int(counts[TileRejection.LOW_PEAK_RATIO]),
                   n_tiles_low_peak_to_noise_ratio=int(counts[TileRejection.LOW_PEAK_TO_NOISE_RATIO]),
                   n_tiles_new=int(n_new), median_peak_ratio=float(np.median(placed.peak_ratio)),
                   median_peak_to_noise=float(np.median(placed.peak_to_noise)))

    def with_coarse(self, start: np.ndarray, coarse) -> "PairDiagnostics":
        """These figures with those of a coarse-stage result ``coarse`` reached from ``start`` (``R_ab``)."""
        return replace(self, coarse_success=bool(coarse.success), coarse_correction_rad=_angle_rad(start, coarse.rotation),
                       coarse_sectors=coarse.n_sectors, coarse_score=coarse.score)

    def timed(self, stage: str, seconds: float) -> "PairDiagnostics":
        """These figures with ``seconds`` more on ``stage`` (one of :data:`STAGES`)."""
        name = f"t_{stage}_ms"
        # A copy with one field set: what ``replace`` gives, without re-running ``__init__`` over every
        # field (this runs several times per pair).
        timed = copy.copy(self)
        object.__setattr__(timed, name, getattr(self, name) + 1e3 * seconds)
        return timed

    def to_dict(self) -> dict:
        """The ``frames.csv`` columns of this pair: every field but those that are None."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class TileMatch:
    """One registration of a reference's tiles in frame b at ``rotation`` (``R_ab``), and the tiles it
    would give frame b to track (:meth:`~ifmi.spectral.ifmi_front_end.IfmiFrontEnd.keep_tracking`);
    ``predicted_offsets`` (T, 2) is the panorama ``(row, col)`` in frame b where ``rotation`` put each
    tile's centre (columns in ``[0, width)``), the start of its registration."""

    offsets_a: np.ndarray
    linear_a: np.ndarray
    placed: PlacedRegistration
    rotation: np.ndarray
    n_new: int
    tracked: PlacedTiles
    tracked_valid: np.ndarray
    tracked_landmarks: np.ndarray | None
    predicted_offsets: np.ndarray


@dataclass(frozen=True)
class Matched:
    """Correspondences of a pair and where they came from.

    Attributes
    ----------
    correspondences : Correspondences
        Their ``diagnostics`` are ``diagnostics.to_dict()``.
    diagnostics : PairDiagnostics or None
        None when the pair was not registered (a frame without a prediction gives only a dict).
    kept : TileMatch or None
        The registration whose tiles frame b keeps (None: frame b's tracked tiles stay as they are).
    rotation : (3, 3) ndarray or None
        ``R_ab`` at which the rays were registered (None without a prediction).
    """

    correspondences: Correspondences
    diagnostics: PairDiagnostics | None
    kept: TileMatch | None = None
    rotation: np.ndarray | None = None

    def with_diagnostics(self, diagnostics: PairDiagnostics) -> "Matched":
        """This result with ``diagnostics``, in its correspondences too."""
        return replace(self, diagnostics=diagnostics,
                       correspondences=replace(self.correspondences, diagnostics=diagnostics.to_dict()))


class _Clock:
    """Wall time since the last reading (seconds)."""

    def __init__(self) -> None:
        self._last = time.perf_counter()

    def lap(self) -> float:
        now = time.perf_counter()
        last, self._last = self._last, now
        return now - last


def _kept_count(match: TileMatch) -> int:
    return int(match.placed.valid.sum())


def _checks_prediction(front_end: "IfmiFrontEnd", prediction: np.ndarray | None, rotation: np.ndarray,
                       correction_rad: float) -> bool:
    """Whether the tiles are registered at a prediction the coarse stage moved to ``rotation`` (by
    ``correction_rad``, within ``coarse.prediction_check_tiles`` tile widths); a prediction the coarse
    stage returned unchanged is not."""
    check = front_end.config.coarse.prediction_check_tiles
    if prediction is None or check <= 0 or np.array_equal(rotation, prediction):
        return False
    correction_px = correction_rad * front_end.mapping.width / (2 * np.pi)
    return correction_px <= check * front_end.layout.tile_size


def _settled_at(front_end: "IfmiFrontEnd", match: TileMatch) -> bool:
    """Whether tiles registered at the prediction (``match.rotation``) show it lines the frames up as
    the coarse stage's own settle test asks (a whole-panorama shift below ``settled_shift_px`` coarse
    pixels along both axes): more than ``recovery.wide_search_fraction`` of the tiles kept (and at
    least ``rays.min_tiles``), and every kept tile's move from its predicted place below that shift
    along both axes. The whole-panorama shift averages such local moves, so the coarse stage would
    keep the prediction; under parallax, where some tiles move farther, it runs."""
    valid = match.placed.valid
    kept = int(valid.sum())
    if kept < front_end.config.rays.min_tiles or \
            kept <= front_end.config.recovery.wide_search_fraction * front_end.layout.count:
        return False
    move = match.placed.offsets[valid] - match.predicted_offsets[valid]
    width = front_end.mapping.width
    move[:, 1] = np.mod(move[:, 1] + width / 2, width) - width / 2
    stage = front_end.global_stage
    return bool(np.all(np.abs(move).max(axis=0) < stage.config.settled_shift_px * stage.scale))


def registered(front_end: "IfmiFrontEnd", state_a: "IfmiFrameState", state_b: "IfmiFrameState",
               starts: tuple) -> tuple[TileMatch, PairDiagnostics]:
    """Stage *register*: the coarse stage from ``starts`` (prediction or None, then other starts), then
    the tiles where it puts them.

    With a prediction the tiles are registered there first, and the coarse stage is skipped when
    they settle there (:func:`_settled_at`): it would return the prediction unchanged, and the
    tiles measure the same (while tracking, nearly every pair). Otherwise the coarse stage runs;
    where it keeps the prediction, the registration made there stands. When the coarse stage moved
    the prediction by little and not every tile passed, the registration at the prediction is
    checked too and the one keeping more tiles is returned.
    """
    start = np.eye(3) if starts[0] is None else starts[0]
    at_prediction = None
    if starts[0] is not None and front_end.global_stage is not None:
        at_prediction = front_end.tiles_at(state_a, state_b, starts[0])
        if _settled_at(front_end, at_prediction):
            return at_prediction, PairDiagnostics.of_tiles(at_prediction.placed, front_end.layout.count,
                                                           at_prediction.n_new)
    rotation, coarse = front_end.coarse_rotation(state_a, state_b, starts)
    correction = 0.0 if coarse is None else _angle_rad(start, coarse.rotation)
    if at_prediction is not None and np.array_equal(rotation, starts[0]):
        match = at_prediction  # the same registration: tiles_at changes neither frame
    else:
        match = front_end.tiles_at(state_a, state_b, rotation)
    extra = {}
    # With every tile kept the prediction cannot keep more: no second registration.
    if _kept_count(match) < front_end.layout.count and _checks_prediction(front_end, starts[0], rotation,
                                                                          correction):
        if at_prediction is None:
            at_prediction = front_end.tiles_at(state_a, state_b, starts[0])
        extra = {"n_tiles_kept_coarse": _kept_count(match),
                 "prediction_kept": bool(_kept_count(at_prediction) > _kept_count(match))}
        if extra["prediction_kept"]:
            match = at_prediction
    diagnostics = PairDiagnostics.of_tiles(match.placed, front_end.layout.count, match.n_new)
    if coarse is not None:
        diagnostics = diagnostics.with_coarse(start, coarse)
    return match, replace(diagnostics, **extra)


def _needs_wide_search(front_end: "IfmiFrontEnd", match: TileMatch, diagnostics: PairDiagnostics) -> bool:
    """Few tiles passed after the coarse stage moved the prediction far (more than
    ``coarse.confirm_angle_rad``): it may have jumped to a wrong yaw. Where it kept or nudged the
    prediction, the tiles fail for noise or parallax, which the wide search cannot help unless the pair
    cannot be solved (stage *rescue*)."""
    recovery = front_end.config.recovery
    return (front_end.wide_search_on()
            and _kept_count(match) <= recovery.wide_search_fraction * front_end.layout.count
            and (diagnostics.coarse_correction_rad or 0.0) > front_end.config.coarse.confirm_angle_rad)


def _searched(front_end: "IfmiFrontEnd", state_a, state_b, coarse, start: np.ndarray,
              search: str) -> tuple[TileMatch, PairDiagnostics]:
    """Tiles at the rotation of a coarse search from ``start``, with the search's name set true."""
    match = front_end.tiles_at(state_a, state_b, coarse.rotation)
    diagnostics = PairDiagnostics.of_tiles(match.placed, front_end.layout.count, match.n_new)
    return match, replace(diagnostics.with_coarse(start, coarse), **{search: True})


def _recovered(front_end: "IfmiFrontEnd", state_a, state_b, prior: np.ndarray, match: TileMatch,
               diagnostics: PairDiagnostics, clock: _Clock) -> tuple[TileMatch, PairDiagnostics]:
    """Stages *re-acquire* and *wide search* on the registration ``match``."""
    if _kept_count(match) < front_end.config.rays.min_tiles and front_end.global_stage is not None:
        # Re-acquisition: the prediction may be far off after fast motion or a lost frame.
        retry, retry_diagnostics = registered(front_end, state_a, state_b, (None, prior))
        if _kept_count(retry) > _kept_count(match):
            match, diagnostics = retry, replace(retry_diagnostics, reacquired=True)
    diagnostics = diagnostics.timed("reacquire", clock.lap())
    if _needs_wide_search(front_end, match, diagnostics):
        # The coarse match decides here, not the tile count: both registrations have few tiles
        # passing, and under parallax the right rotation can keep as few as the wrong one until the
        # dense retry registers more.
        searched = front_end.wide_search(state_a, state_b, diagnostics.coarse_score, prior)
        if searched is not None and front_end.global_stage.clearly_better(
                searched, current_rotation=match.rotation, current_score=diagnostics.coarse_score):
            timing = diagnostics
            match, diagnostics = _searched(front_end, state_a, state_b, searched, prior, "wide_search")
            diagnostics = _with_times(diagnostics, timing)
    return match, diagnostics.timed("wide_search", clock.lap())


def _with_times(diagnostics: PairDiagnostics, timing: PairDiagnostics) -> PairDiagnostics:
    """``diagnostics`` with the stage times of ``timing``."""
    return replace(diagnostics, **{f"t_{s}_ms": getattr(timing, f"t_{s}_ms") for s in STAGES})


def with_rays(front_end: "IfmiFrontEnd", state_a, state_b, match: TileMatch, diagnostics: PairDiagnostics,
              clock: _Clock | None = None) -> Matched:
    """Stages *dense retry* and *rays*: the rays of ``match``, or of the dense retry at its rotation when
    at most ``recovery.dense_retry_fraction`` of its tiles passed and the retry keeps more."""
    clock = clock or _Clock()
    valid = match.placed.valid
    dense = None
    if front_end.dense_layout is not None and \
            valid.sum() <= front_end.config.recovery.dense_retry_fraction * front_end.layout.count:
        retry = front_end.register_dense(state_a, state_b, rotation=match.rotation)
        diagnostics = replace(diagnostics, n_tiles_kept_dense=int(retry[2].valid.sum()))
        if retry[2].valid.sum() > valid.sum():
            dense = retry
    diagnostics = diagnostics.timed("dense_retry", clock.lap())
    if dense is not None:
        corr, diagnostics = front_end.placed_correspondences(state_a, *dense, diagnostics, dense=True)
    else:
        corr, diagnostics = front_end.placed_correspondences(state_a, match.offsets_a, match.linear_a,
                                                              match.placed, diagnostics, dense=False)
    return Matched(corr, diagnostics, kept=match, rotation=match.rotation).with_diagnostics(
        diagnostics.timed("rays", clock.lap()))


def matched(front_end: "IfmiFrontEnd", state_a: "IfmiFrameState", state_b: "IfmiFrameState",
            prior: np.ndarray) -> Matched:
    """Stages *register*, *verify*, *recover* and *rays* of a pair with the predicted ``R_ab`` ``prior``."""
    clock = _Clock()
    match, diagnostics = registered(front_end, state_a, state_b, (prior, None))
    diagnostics = diagnostics.timed("register", clock.lap())
    match, diagnostics = _recovered(front_end, state_a, state_b, prior, match, diagnostics, clock)
    return with_rays(front_end, state_a, state_b, match, diagnostics, clock)


def rescued(front_end: "IfmiFrontEnd", state_a: "IfmiFrameState", state_b: "IfmiFrameState", failed: Matched,
            prior: np.ndarray | None) -> Matched | None:
    """Stage *rescue*: a pair that could not be solved (``failed``), registered at the best rotation of a
    wide search from every start; None when there is nothing to try or the tiles fail there too.

    Any rotation whose panorama matches better than the coarse stage's is tried, not only a clearly
    better one: under parallax every coarse rotation leaves most of the panorama mismatch, and on the
    first pair of a sequence the prediction is the identity, which the coarse stage keeps when its own
    search from there matches worse. Returns correspondences that may still fail to solve.
    """
    diagnostics = failed.diagnostics
    if prior is None or not front_end.wide_search_on() or diagnostics is None or diagnostics.wide_search:
        return None
    if diagnostics.coarse_score is None:  # the tiles settled at the prediction: the coarse stage was skipped
        _, coarse = front_end.coarse_rotation(state_a, state_b, (prior, None))
        diagnostics = diagnostics.with_coarse(prior, coarse)
    searched = front_end.wide_search(state_a, state_b, diagnostics.coarse_score, prior, every_start=True)
    if searched is None:
        return None
    wide, wide_diagnostics = _searched(front_end, state_a, state_b, searched, prior, "wide_search")
    result = with_rays(front_end, state_a, state_b, wide,
                       _with_times(replace(wide_diagnostics, wide_rescue=True), diagnostics))
    return result if result.correspondences.success else None


def half_turn_checked(front_end: "IfmiFrontEnd", state_a: "IfmiFrameState", state_b: "IfmiFrameState",
                      solved: tuple, prior: np.ndarray | None, solve: Callable) -> tuple | None:
    """Stage *check*: ``(matched, pose, info)`` of the pair solved again from its solution's half turn, when
    that lies nearer the prediction ``prior`` and keeps enough inliers; else None.

    A room of one texture seen from near its middle matches itself turned half round about the
    vertical, and under parallax the half turn can match as well as the truth. When the solution
    ``solved`` (``(matched, pose, info)``) lies more than ``recovery.half_turn_check_rad`` from the prediction, its
    rotation turned half round about the panorama axis (on either side: the scene's turn is about the
    vertical, the axis of whichever frame is upright) is refined by the coarse stage with the yaw kept
    within :data:`HALF_TURN_YAW_WINDOW_RAD`, the tiles are registered there (dense retry included) and
    solved. Where the frames cannot tell the two apart, the smaller motion is taken.
    """
    _, pose, info = solved
    if prior is None or front_end.global_stage is None:
        return None
    far = float(geodesic_angle(prior, pose.rotation))
    if far <= front_end.config.recovery.half_turn_check_rad:
        return None
    half_turn = front_end.half_turn
    rotation_ab = np.asarray(pose.rotation, dtype=np.float64)
    starts = np.stack([half_turn @ rotation_ab, rotation_ab @ half_turn])
    coarse = front_end.global_stage.search_near(state_a.coarse_panorama, state_b.coarse_panorama, starts=starts,
                                                max_yaw_rad=HALF_TURN_YAW_WINDOW_RAD)
    match, diagnostics = _searched(front_end, state_a, state_b, coarse, starts[0], "half_turn")
    turned = with_rays(front_end, state_a, state_b, match, _with_times(diagnostics, solved[0].diagnostics))
    if not turned.correspondences.success:
        return None
    pose_turned, info_turned = solve(turned.correspondences)
    if (info_turned.success and float(geodesic_angle(prior, pose_turned.rotation)) < far
            and info_turned.n_inliers >= HALF_TURN_INLIER_FRACTION * info.n_inliers):
        return turned, pose_turned, info_turned
    return None


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


def refined(front_end: "IfmiFrontEnd", state_a: "IfmiFrameState", state_b: "IfmiFrameState", first: Matched,
            rotation_ab: np.ndarray) -> tuple[Matched | None, TileMatch | None]:
    """Stage *refine*: ``first`` averaged with a second registration at the solved ``rotation_ab``.

    Pairs whose registration kept at most ``refinement.reregister_fraction`` of the layout's tiles are
    registered again where ``rotation_ab`` puts the tiles that gave ``first``'s rays (the reference's
    tiles, or the dense retry's) when that moves them at least ``refinement.reregister_min_px``; no
    coarse stage and no dense retry.

    Returns
    -------
    matched : Matched or None
        Both registrations' matches merged (:func:`averaged_correspondences`),
        with ``n_tiles_kept_reregistered``; None when the pair is not registered again or the second
        registration failed.
    kept : TileMatch or None
        The second registration of the reference's tiles, whose tiles frame b keeps (placed at the
        better rotation), also when it failed; None when there was none.
    """
    options = front_end.config.refinement
    diagnostics = first.diagnostics
    if (options.reregister_fraction == 0 or not first.correspondences.success or first.rotation is None
            or diagnostics.n_tiles_kept > options.reregister_fraction * front_end.layout.count):
        return None, None
    rotation_ab = np.asarray(rotation_ab, dtype=np.float64)
    moved = geodesic_angle(first.rotation, rotation_ab)
    if moved * front_end.mapping.width / (2 * np.pi) < options.reregister_min_px:
        return None, None
    kept = None
    dense = diagnostics.n_tiles_kept_dense
    if dense is not None and dense > diagnostics.n_tiles_kept:  # the first rays are the dense retry's
        offsets_a, linear_a, placed = front_end.register_dense(state_a, state_b, rotation=rotation_ab)
        second, _ = front_end.placed_correspondences(state_a, offsets_a, linear_a, placed, diagnostics, dense=True)
    else:
        kept = front_end.tiles_at(state_a, state_b, rotation_ab)
        placed = kept.placed
        second, _ = front_end.placed_correspondences(state_a, kept.offsets_a, kept.linear_a, placed, diagnostics,
                                                     dense=False)
    if not second.success:
        return None, kept
    merged = averaged_correspondences(first.correspondences, second)
    result = Matched(merged, diagnostics, kept=kept, rotation=rotation_ab)
    return result.with_diagnostics(replace(diagnostics, n_tiles_kept_reregistered=int(placed.valid.sum()))), kept


def solve_pair(front_end: "IfmiFrontEnd", state_a: "IfmiFrameState", state_b: "IfmiFrameState", *,
               prior_rotation: np.ndarray | None, solve: Callable) -> SolvedPair:
    """A pair through every stage (see the module docstring); frame b keeps the settled registration.

    Parameters
    ----------
    front_end : IfmiFrontEnd
    state_a, state_b : IfmiFrameState
        Reference a and frame b.
    prior_rotation : (3, 3) ndarray or None, keyword-only
        Predicted ``R_ab``; None (or ``use_prior`` off) registers the layout's tiles without one
        (stages *register* and *rays* only, and *solve*).
    solve : callable, keyword-only
        ``solve(correspondences) -> (pose, info)``: the odometry's back end.

    Returns
    -------
    SolvedPair
    """
    if not front_end.config.tracking.use_prior or prior_rotation is None:
        corr = front_end.unpredicted_correspondences(state_a, state_b)
        if not corr.success:
            return SolvedPair(corr)
        started = time.perf_counter()
        pose, info = solve(corr)
        elapsed_ms = 1e3 * (time.perf_counter() - started)
        return SolvedPair(replace(corr, diagnostics={**corr.diagnostics, "t_solve_ms": elapsed_ms}), pose, info)
    # 1-4: register, verify, recover, rays.
    first = matched(front_end, state_a, state_b, prior_rotation)
    kept, clock = first.kept, _Clock()
    # 5: solve.
    pose, info = solve(first.correspondences) if first.correspondences.success else (None, None)
    current, diagnostics = first, first.diagnostics.timed("solve", clock.lap())
    # 6: rescue.
    if info is None or not info.success:
        rescue = rescued(front_end, state_a, state_b, first, prior_rotation)
        if rescue is not None:
            kept = rescue.kept  # also when it does not solve
            pose_rescued, info_rescued = solve(rescue.correspondences)
            if info_rescued.success:
                current, pose, info = rescue, pose_rescued, info_rescued
        diagnostics = diagnostics.timed("rescue", clock.lap())
        if info is None or not info.success:
            front_end.keep_tracking(state_b, kept)
            return SolvedPair(current.with_diagnostics(_with_times(current.diagnostics, diagnostics)).correspondences,
                              pose, info)
    # 7: half turn.
    turned = half_turn_checked(front_end, state_a, state_b, (current, pose, info), prior_rotation, solve)
    if turned is not None:
        (current, pose, info), kept = turned, turned[0].kept
    diagnostics = diagnostics.timed("half_turn", clock.lap())
    # 8: refine.
    second, second_kept = refined(front_end, state_a, state_b, current, pose.rotation)
    if second_kept is not None:
        kept = second_kept
    if second is not None:
        pose_refined, info_refined = solve(second.correspondences)
        if info_refined.success:
            current, pose, info = second, pose_refined, info_refined
    diagnostics = diagnostics.timed("refine", clock.lap())
    # 9: keep.
    front_end.keep_tracking(state_b, kept)
    return SolvedPair(current.with_diagnostics(_with_times(current.diagnostics, diagnostics)).correspondences,
                      pose, info)
