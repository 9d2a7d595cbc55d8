"""Relative pose of two cameras from corresponding unit rays.

Convention: for frames ``a`` (earlier or keyframe) and ``b``, ``R_ab`` maps
camera-b directions into camera-a coordinates, ``X_a = R_ab @ X_b + t_ab``, so
corresponding rays satisfy ``rays_a ~ R_ab @ rays_b + t_ab`` (up to depth).

Two models compete inside a seeded RANSAC with an angular threshold:

* ``"5pt"``: the minimal essential-matrix solver on bearing vectors
  (``poselib.relpose_5pt``, which accepts rays of any sign of z), scored by
  the angle between a ray and the epipolar plane of its partner, or, for a
  correspondence the model triangulates behind the cameras, by the angle
  between the ray and its rotated partner (the nearest point in front is at
  infinity), then refined
  by Gauss-Newton (analytic Jacobian) on the inliers' symmetric epipolar
  angles, again on the refined model's inliers until they settle;
* ``"rotation"``: a rotation-only model (Kabsch on rays, two rays per
  sample), scored by the angle between ``rays_a`` and ``R_ab @ rays_b``,
  then refined by Kabsch on the inliers and re-solved a few times with
  Cauchy weights of the residual angles.

The cheirality in the 5-point residual resolves the two-fold ambiguity of a
plane (a floor seen by a downward camera): both essential matrices of the
plane fit every epipolar constraint, but the wrong one, whose translation
points at the plane, puts the points on one side of it behind the cameras
once the rays spread to both sides; over a narrow view of a plane the two
stay indistinguishable from one pair. The noise level is still measured on
the epipolar angles alone.

Under (near) pure rotation every translation fits the epipolar constraint,
which makes the 5-point solution ill-conditioned and lets it fit noise (a
spurious translation also puts about half the rays behind the cameras, whose
residuals then count in full). The
model is chosen by Torr's GRIC over the correspondences either model
explains: a model's score is the sum of its squared residuals in units of
the ray noise (capped, so an outlier costs a fixed amount), plus a charge for
the dimension of its constraint per correspondence (a rotation fixes both
coordinates of a ray, the epipolar constraint one) and for its parameters
(3 and 5). The 5-point model wins when the parallax its translation explains
is large enough against the noise to pay for its weaker constraint and two
extra parameters; under pure rotation the rotation model's residuals are
noise only and it wins. The noise is estimated robustly from the residuals
of the richer model, the 5-point model, whose residuals hold only noise
whether the camera moved or not (the rotation model's also hold the
parallax): the mean square of its inliers' epipolar angles, corrected for
its five parameters and for the cut at the inlier threshold, taken at its upper bound of
one standard error, so that the few measurements of a pair cannot make the
noise look smaller than it may be (:class:`ModelSelection` holds the
evidence). A group of rays that share one error (``rays_per_measurement``)
counts as one observation.

The inlier threshold is an angle. Its default is a number of pixels
(``ransac_threshold_px``) times the angle one pixel subtends, which only the
caller knows (:func:`ifmi.spectral.panorama.angular_pixel_size_in_band` for a calibration);
:meth:`RelativePoseOptions.resolved` turns one into the other, and an
explicit ``ransac_threshold_rad`` overrides it.

The chosen model fails the pair when its inliers are too few
(``min_inliers``), come from too few measurements
(``min_inlier_measurements``), or look like chance: a share of the
correspondences so small that the draw was unlikely to hold an outlier-free
sample, and no more than pairings of shuffled rays reach
(``min_draw_success``, ``max_chance_false_alarms``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import poselib
from scipy.optimize import brentq
from scipy.special import bdtrc, fdtr, gammaincinv

from ifmi.backend.homography import inlier_homography
from ifmi.options import check_finite_fields
from ifmi.geometry.rotations import cross, cross_product_matrix, geodesic_angle

__all__ = [
    "RelativePoseOptions",
    "RelativePose",
    "RelativePoseInfo",
    "ModelSelection",
    "relative_pose_from_rays",
    "rotation_from_rays",
    "epipolar_angles",
    "rotation_angles",
    "noise_sigma_from_residuals",
    "gric",
    "samples_without_replacement",
]

# Smallest sample of each model.
_SAMPLE_5PT = 5
_SAMPLE_ROTATION = 2
# Rotation-only hypotheses are cheap; they are drawn and scored in batches of this size.
_ROTATION_BATCH = 32
# 5-point samples are solved one at a time but their hypotheses scored in chunks of this many samples.
_CHUNK_5PT = 8
# Most RANSAC samples per model: at the default confidence (0.99) this many draws find an all-inlier
# 5-point sample down to 14 % inliers ((0.14)^5 = 5.4e-5, log(0.01) / log(1 - 5.4e-5) = 8.5e4 draws).
# A larger count only turns a hopeless pair into a hang, and a minimum of that order is solved
# in one chunk (memory).
_MAX_ITERATIONS = 100_000
# Most Gauss-Newton (5-point refinement) and Cauchy re-weighting (rotation model) iterations: both
# settle within a handful (defaults 3 and 5); more only turn every frame pair into a long wait.
_MAX_REFINE_ITERATIONS = 100
# Two-pair rotations come in closed form from frames of the pairs' bisector, half difference and
# normal; a frame vector shorter than this (rays within 1e-6 rad of equal or opposite) is too
# ill-conditioned and the rotation is solved by SVD instead.
_FRAME_MIN_LENGTH = 1e-6
# The noise GRIC weighs residuals with is the upper confidence bound, at this level (one standard
# error of a normal estimate), of the 5-point model's estimate: a sum of squares over few measurements
# can fall far below its expectation (at 10 degrees of freedom, a fifth of the time below 0.8 of it), and
# a noise level set too low makes the rotation model's two-dimensional residuals look like parallax.
# The bound is 1.32 times the estimate at 10 degrees of freedom, 1.08 at 100, 1.02 at 1000. At 0.95
# (1.59 at 10) the parallax of a wall seen by 10 of 15 tiles was taken for outliers of a rotation.
_NOISE_CONFIDENCE = 0.84
# Smallest ray noise GRIC weighs residuals with, radians: angles between float64 unit vectors are
# resolved to about 1e-16 rad, differently by the two models' residual formulas, so exact rays would
# otherwise be judged on rounding. It is a million times below the angle of a pixel of any camera.
_NOISE_FLOOR_RAD = 1e-12
# Two-sided level of the F test that keeps a pair's own noise estimate out of the sequence's prior
# (see _pools_with): a pair's noise can differ from the earlier pairs' when the scene in view does.
_NOISE_POOLING_LEVEL = 1e-3
# Fewest correspondences the model selection fits a homography to: as many rays as its eight parameters.
_MIN_HOMOGRAPHY_RAYS = 8
# Chance pairings scored per correspondence when a consensus is checked against chance: the rays of
# camera a with this many random permutations of those of camera b.
_CHANCE_PERMUTATIONS = 8
# Second seed word of the generator of those permutations, so that they are not the draw's own
# stream (seeded with ``RelativePoseOptions.seed`` alone).
_CHANCE_STREAM = 1
# Most models one 5-point sample yields (the roots of its tenth-degree polynomial).
_MAX_5PT_SOLUTIONS = 10


@dataclass(frozen=True)
class RelativePoseOptions:
    """Options of :func:`relative_pose_from_rays`.

    Attributes
    ----------
    ransac_threshold_rad : float or None
        Inlier threshold, radians, in ``(0, pi)``: the angle between a ray and its epipolar
        plane (5-point model) or its rotated partner (rotation model).
        ``None`` (default): ``ransac_threshold_px`` pixels, converted with
        :meth:`resolved` once the pixel size is known;
        :func:`relative_pose_from_rays` needs it set.
    ransac_threshold_px : float
        Default inlier threshold in pixels of the image (1 pixel, the usual
        choice for keypoint matches); used when ``ransac_threshold_rad`` is
        ``None``.
    max_iterations : int
        Largest number of RANSAC samples per model (at most 100 000, which
        finds an all-inlier 5-point sample at 99 % confidence down to 14 %
        inliers).
    min_iterations : int
        Smallest number of samples per model before the adaptive stop (at
        most 100 000). The adaptive stop trusts the best inlier count so
        far; with a threshold of a pixel or so on a fast or translating
        pair, a wrong model can count nearly every ray as an inlier and stop
        the draw after a few samples. Against 8, the default 40 made the
        rotations of seeds 0-19 stray more than 5 mrad from their consensus
        2.9x less often (174 -> 59 of 5440 runs on 272 iFMI pairs of
        held-out sets) and halved iFMI's runs with an ATE above 3x the
        set's median (13 -> 5 of 756 runs over 126 sets), for about 1.6 ms
        more per pair of 55-215 rays.
    confidence : float
        Adaptive stop: probability of having drawn one all-inlier sample.
    min_inliers : int
        Fewer inliers than this is a failure.
    min_inlier_measurements : int
        Fewer measurements (groups of ``rays_per_measurement`` rays) with an
        inlier ray than this is a failure too, at least 1. Eight inlier
        rays can come from two of iFMI's tiles (five flow points each), and
        any two tiles fit a rotation (four constraints for three unknowns):
        a featureless gray frame so matched gave a rotation 0.61 rad off
        with success and a predicted error of 13 mrad. With three, the
        measurements must agree beyond what the model absorbs. Keypoint
        matches (one ray each) meet it whenever they meet ``min_inliers``.
    seed : int
        Seed of the sample generator, ``>= 0``; the same seed gives the same result.
    refine : bool
        Refine the chosen model on its inliers.
    refine_iterations : int
        Gauss-Newton iterations of the 5-point refinement (0 to 100).
    polish_rounds : int
        With ``refine``: after the 5-point model is refined on its inliers,
        take the inliers of the refined model and refine again, up to this
        many times (0 to 100) or until the inlier set stops changing (local
        optimisation). A minimal sample's model is noisy, so its inlier set
        can take in an outlier or leave out inliers that the refined model
        sorts correctly; where the rays cover a narrow field (tiles that
        passed on one side of a room), one such measurement can move the
        rotation by tens of milliradians.
    refine_hypotheses : int
        With ``refine``: how many of the best distinct 5-point RANSAC
        hypotheses (1 to 100) are looked at. The best is refined and
        polished as before; each other one is refined once on its own
        inliers, and the one with the lowest truncated epipolar cost (MSAC)
        is polished and replaces the best one's result when its cost ends
        lower. Refinement stays in the basin it starts in: on a fast
        translated pair seen over a narrow field the best sample can sit in
        a second minimum of the epipolar cost (its translation 55-90
        degrees from the true one and its rotation several to tens of
        milliradians off) while another sample starts in the true basin.
        1 (default): only the best hypothesis. Measured with 5 over three
        RANSAC seeds: iFMI's ATE fell on fast translated renders (geometric
        mean 0.86-0.99 per set) but rose on rolling-shutter sequences
        (1.12; a spurious translation absorbs the residual distortion at a
        lower cost) and on a weakly textured set with many outlier tiles;
        the sets where iFMI loses to the feature methods were about as many
        as with 1, and the back end costs 1.5-1.6 times as much.
    rotation_only : bool
        Force the rotation-only model.
    five_point_only : bool
        Force the 5-point model (the pair fails when no sample gives one);
        for comparisons with the model selection.
    noise_sigma_rad : float or None
        Standard deviation (per axis, radians) of the ray noise used to
        choose between the models by GRIC; ``None`` estimates it from the
        5-point model's inlier epipolar angles (their mean square, corrected
        for its five parameters and for the cut at the threshold, at its
        upper bound of one standard error), or from the rotation
        model's inliers (see :func:`noise_sigma_from_residuals`) when those
        are five measurements or fewer; an estimate above
        ``ransac_threshold_rad`` (inliers spread evenly up to it) is taken
        as the threshold.
    noise_prior_rms_rad : float or None
        Earlier evidence of the ray noise, pooled with the pair's own when
        ``noise_sigma_rad`` is None: the root mean square (radians) of
        inlier epipolar angles below ``ransac_threshold_rad`` of other pairs
        of the same camera and front end. A pair with few inlier
        measurements measures its noise poorly (five of them fit the
        5-point model exactly), and a low estimate makes the rotation
        model's residuals look like parallax. A pair whose own measurements
        contradict the prior (an F test of the two mean squares at the
        two-sided level 1e-3: the scene in view, and with it the noise, can
        change along a sequence) keeps its own estimate. None: the pair's
        own evidence alone.
    noise_prior_measurements : float
        How many measurements (beyond the 5-point model's five parameters)
        ``noise_prior_rms_rad`` is worth: its mean square enters the pooled
        sum of squares that many times, and the degrees of freedom of the
        upper bound grow by as much.
    sequence_noise_prior : bool
        Read by the trackers (:mod:`ifmi.tracking.odometry`): set
        ``noise_prior_rms_rad`` of each pair to the median of the earlier
        solved pairs' ``ModelSelection.noise_rms_rad`` and
        ``noise_prior_measurements`` to the median of their
        ``noise_measurements``, worth one typical pair of the sequence.
    translation_prior : float or None
        Prior probability, in (0, 1), that the camera moved measurably
        between the pair's frames. GRIC is minus twice a log-likelihood
        plus its penalties, so the prior enters as minus twice its log
        odds: a translated model is chosen when its GRIC less
        ``2 log(p / (1 - p))`` is below the rotation model's. None: no
        preference (0.5).
    sequence_model_prior : bool
        Read by the trackers (:mod:`ifmi.tracking.odometry`): set
        ``translation_prior`` of each pair to ``(k + 1) / (n + 2)`` when
        ``k`` of the ``n`` earlier solved pairs with both models fitted
        showed translation on their own evidence (GRIC without a prior;
        Laplace's rule of succession). A camera that keeps moving makes a
        small step's faint parallax credible, a camera that only turns
        makes a chance fit of the 5-point model to a few noisy
        correspondences less so; the first pair has no preference.
    rotation_threshold_factor : float
        The rotation model's inlier threshold is this multiple of
        ``ransac_threshold_rad``: its error is an angle in two dimensions,
        the epipolar one in one dimension, so equal noise gives larger
        rotation-model errors (sqrt(chi2_2 / chi2_1) = 1.25 at 95 %).
    robust_iterations : int
        With ``refine``: re-solve the rotation model on its inliers this many
        times with Cauchy weights of the residual angles (0: plain
        least squares on the inliers), so that loosely registered inliers
        near the threshold count less. At most 100.
    min_draw_success : float
        A consensus of ``k`` inliers among ``n`` correspondences is taken
        for chance, and the pair fails, when both: the ``max_iterations``
        samples of the chosen model (``s`` rays each) held an outlier-free
        one with a probability ``1 - (1 - (k / n)^s)^max_iterations`` below
        this, and chance explains the inliers (``max_chance_false_alarms``).
        Unrelated rays make such consensuses with the 5-point model: of 840
        draws of 20-2000 uniformly random ray pairs at thresholds of 3-20
        mrad, 351 passed every other test, their inliers 16 % of the pairs or
        fewer (a probability of at most 0.02); none passes this one. On 61
        sequences of renders, warped photos and other cameras, each of the
        1947 pairs iFMI, ORB and AKAZE solved had 44 % inliers or more (a
        probability of 1.0). 0 disables the check.
    max_chance_false_alarms : float
        A consensus below ``min_draw_success`` is still accepted when the
        number of models with ``k`` or more inliers that chance pairings are
        expected to give over the draw is at most this: the binomial tail of
        ``k - s`` successes in ``n - s`` trials, at the rate at which the
        model counts the rays of camera a paired with shuffled rays of
        camera b, times the hypotheses scored (``max_iterations``, times 10
        for 5-point samples). Many true matches among many outliers pass so
        (100 of 2000: 1e-212); random ray pairs in a mirror-like band of
        elevations gave 1e-3 or more (540 draws).
    robust_scale : float
        Cauchy scale in units of the noise level (``noise_sigma_rad`` or
        its estimate). Matched rays have heavy-tailed errors (a core of
        well-registered tiles or keypoints and a spread of loose ones up to
        the threshold); a scale of one noise level weights the core and
        lowered the frame-to-frame rotation error of every front end on
        the rendered sequences.
    """

    ransac_threshold_rad: float | None = None
    ransac_threshold_px: float = 1.0
    max_iterations: int = 200
    min_iterations: int = 40
    confidence: float = 0.999
    min_inliers: int = 8
    min_inlier_measurements: int = 3
    seed: int = 0
    refine: bool = True
    refine_iterations: int = 3
    polish_rounds: int = 3
    refine_hypotheses: int = 1
    rotation_only: bool = False
    five_point_only: bool = False
    noise_sigma_rad: float | None = None
    noise_prior_rms_rad: float | None = None
    noise_prior_measurements: float = 0.0
    sequence_noise_prior: bool = True
    translation_prior: float | None = None
    sequence_model_prior: bool = True
    rotation_threshold_factor: float = 1.25
    robust_iterations: int = 5
    robust_scale: float = 1.0
    min_draw_success: float = 0.5
    max_chance_false_alarms: float = 1e-6

    def __post_init__(self) -> None:
        check_finite_fields(self, ("ransac_threshold_rad", "ransac_threshold_px", "noise_sigma_rad",
                                   "noise_prior_rms_rad", "noise_prior_measurements",
                                   "rotation_threshold_factor", "robust_scale", "min_draw_success",
                                   "max_chance_false_alarms"))
        # Rays are at most pi apart: a threshold of pi or more makes every match an inlier.
        if self.ransac_threshold_rad is not None and not 0 < self.ransac_threshold_rad < np.pi:
            raise ValueError(f"ransac_threshold_rad must be in (0, pi) or None, got {self.ransac_threshold_rad}")
        if not self.ransac_threshold_px > 0:
            raise ValueError(f"ransac_threshold_px must be > 0, got {self.ransac_threshold_px}")
        if self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed}")
        if not (0 <= self.refine_iterations <= _MAX_REFINE_ITERATIONS
                and self.robust_iterations <= _MAX_REFINE_ITERATIONS):
            raise ValueError(f"expected 0 <= refine_iterations <= {_MAX_REFINE_ITERATIONS} and robust_iterations "
                             f"<= {_MAX_REFINE_ITERATIONS}, got {self.refine_iterations}, {self.robust_iterations}")
        if not 0 <= self.polish_rounds <= _MAX_REFINE_ITERATIONS:
            raise ValueError(f"expected 0 <= polish_rounds <= {_MAX_REFINE_ITERATIONS}, got {self.polish_rounds}")
        if not 1 <= self.refine_hypotheses <= _MAX_REFINE_ITERATIONS:
            raise ValueError(f"expected 1 <= refine_hypotheses <= {_MAX_REFINE_ITERATIONS}, "
                             f"got {self.refine_hypotheses}")
        if not 1 <= self.max_iterations <= _MAX_ITERATIONS or not 0 <= self.min_iterations <= _MAX_ITERATIONS:
            raise ValueError(
                f"expected 1 <= max_iterations <= {_MAX_ITERATIONS} and 0 <= min_iterations <= {_MAX_ITERATIONS}, "
                f"got {self.max_iterations}, {self.min_iterations}")
        if not 0 < self.confidence < 1:
            raise ValueError(f"confidence must be in (0, 1), got {self.confidence}")
        if self.min_inliers < _SAMPLE_ROTATION or self.min_inlier_measurements < 1:
            raise ValueError(f"expected min_inliers >= {_SAMPLE_ROTATION} and min_inlier_measurements >= 1, "
                             f"got {self.min_inliers}, {self.min_inlier_measurements}")
        if self.robust_iterations < 0 or not self.robust_scale > 0:
            raise ValueError(f"expected robust_iterations >= 0 and robust_scale > 0, got "
                             f"{self.robust_iterations}, {self.robust_scale}")
        if self.rotation_only and self.five_point_only:
            raise ValueError("rotation_only and five_point_only exclude each other; set at most one")
        if not 0 <= self.min_draw_success <= 1 or not self.max_chance_false_alarms >= 0:
            raise ValueError(f"expected 0 <= min_draw_success <= 1 and max_chance_false_alarms >= 0, "
                             f"got {self.min_draw_success}, {self.max_chance_false_alarms}")
        if (self.noise_prior_rms_rad is not None and not self.noise_prior_rms_rad > 0) \
                or not self.noise_prior_measurements >= 0:
            raise ValueError("expected noise_prior_rms_rad > 0 or None and noise_prior_measurements >= 0, got "
                             f"{self.noise_prior_rms_rad}, {self.noise_prior_measurements}")
        if (self.noise_sigma_rad is not None and not self.noise_sigma_rad > 0) or not self.rotation_threshold_factor > 0:
            raise ValueError(
                "expected noise_sigma_rad > 0 or None and rotation_threshold_factor > 0, got "
                f"{self.noise_sigma_rad}, {self.rotation_threshold_factor}")
        if self.translation_prior is not None and not 0 < self.translation_prior < 1:
            raise ValueError(f"translation_prior must be in (0, 1) or None, got {self.translation_prior}")

    def resolved(self, pixel_angle_rad: float) -> "RelativePoseOptions":
        """These options with the angular threshold set.

        Parameters
        ----------
        pixel_angle_rad : float
            Angle one image pixel subtends, radians.

        Returns
        -------
        RelativePoseOptions
            Unchanged when ``ransac_threshold_rad`` is set (explicit
            override), else with ``ransac_threshold_rad =
            ransac_threshold_px * pixel_angle_rad``.
        """
        if self.ransac_threshold_rad is not None:
            return self
        if not (np.isfinite(pixel_angle_rad) and pixel_angle_rad > 0):
            raise ValueError(f"pixel_angle_rad must be finite and > 0, got {pixel_angle_rad}")
        return replace(self, ransac_threshold_rad=float(self.ransac_threshold_px * pixel_angle_rad))


@dataclass(frozen=True)
class RelativePose:
    """Relative pose of camera b in camera a.

    Attributes
    ----------
    rotation : (3, 3) ndarray
        ``R_ab``: maps camera-b directions into camera-a coordinates.
    translation_direction : (3,) ndarray
        Unit direction of camera b's origin in camera-a coordinates, or zeros
        when unknown (rotation model or failure).
    """

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation_direction: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class ModelSelection:
    """Evidence of the choice between the rotation-only and the 5-point model.

    Attributes
    ----------
    gric_rotation, gric_5pt : float
        Torr's GRIC of each model over the correspondences that are inliers
        of either (lower is better). NaN when only one model was fitted.
    gric_homography : float
        GRIC of a homography fitted to the same correspondences
        (:func:`ifmi.backend.homography.inlier_homography`): the model of a
        translation over a plane, which holds the rotation as its special
        case. Its residual is two-dimensional like the rotation model's, so
        it pays only for its five extra parameters, not per correspondence:
        a parallax too small to show in each correspondence against the
        noise, but coherent over all of them (a downward camera's step over
        the floor), still shows in it. The 5-point model is chosen when
        either translated model scores lower than the rotation model
        (:attr:`prefers_translation`), unless its consensus fails the back
        end's checks (too few inliers, chance) and the rotation model's
        passes, and the other way round. NaN when only one model was fitted.
    parallax_rad : float
        Median angle (radians) between the 5-point model's inlier rays of
        camera a and their partners turned by its rotation: the parallax its
        translation explains, noise included. NaN when only one model was fitted.
    noise_sigma_rad : float
        The ray noise (radians, per axis) GRIC weighed the residuals with.
    noise_rms_rad : float
        The pair's own evidence of it: root mean square (radians) of the
        5-point model's inlier epipolar angles, corrected for its five
        parameters (NaN without residual freedom); what
        ``RelativePoseOptions.noise_prior_rms_rad`` pools.
    noise_measurements : float
        The measurements behind ``noise_rms_rad`` beyond the model's five
        parameters.
    translation_prior : float
        Prior probability of a translation the choice weighed the scores
        with (``RelativePoseOptions.translation_prior``; 0.5: none).
    """

    gric_rotation: float = math.nan
    gric_5pt: float = math.nan
    gric_homography: float = math.nan
    parallax_rad: float = math.nan
    noise_sigma_rad: float = math.nan
    noise_rms_rad: float = math.nan
    noise_measurements: float = 0.0
    translation_prior: float = 0.5

    @property
    def evidence_prefers_translation(self) -> bool:
        """Whether the 5-point model or the homography scores lower than the rotation model."""
        return self._translated_gric() < self.gric_rotation

    @property
    def prefers_translation(self) -> bool:
        """Whether a translated model scores lower than the rotation model once the prior
        (``translation_prior``) is weighed in: by ``2 log(p / (1 - p))``."""
        p = self.translation_prior
        return self._translated_gric() - 2.0 * math.log(p / (1.0 - p)) < self.gric_rotation

    def _translated_gric(self) -> float:
        """The lower GRIC of the 5-point model and the homography (the 5-point model's without one)."""
        return self.gric_5pt if math.isnan(self.gric_homography) else min(self.gric_5pt, self.gric_homography)

    def columns(self) -> dict:
        """The evidence as ``frames.csv`` columns: ``gric_rotation``, ``gric_5pt``,
        ``gric_homography``, ``parallax_rad``, ``selection_sigma_rad``, ``noise_rms_rad``,
        ``noise_measurements``, ``translation_prior``."""
        return {"gric_rotation": self.gric_rotation, "gric_5pt": self.gric_5pt,
                "gric_homography": self.gric_homography,
                "parallax_rad": self.parallax_rad, "selection_sigma_rad": self.noise_sigma_rad,
                "noise_rms_rad": self.noise_rms_rad, "noise_measurements": self.noise_measurements,
                "translation_prior": self.translation_prior}


@dataclass(frozen=True)
class RelativePoseInfo:
    """Diagnostics of :func:`relative_pose_from_rays`.

    Attributes
    ----------
    success : bool
    reason : str
        Empty on success, else why the estimate failed.
    n_correspondences : int
    n_inliers : int
    inlier_mask : (N,) ndarray of bool
    model : str
        ``"5pt"`` or ``"rotation"`` (the model chosen, also on failure).
    rotation_sigma_rad : float
        Predicted root-mean-square geodesic error of ``R_ab`` (radians):
        the square root of the trace of the rotation block of the chosen
        model's covariance, the inverse Fisher information of its inliers at
        the estimate (a group of ``rays_per_measurement`` rays counting as one
        measurement) times the noise level its inlier residuals give. It is
        the least-squares figure: with Gaussian ray noise the true RMS error
        is within about 12 % of it for both models, and 13-15 % above it
        for the rotation model with its Cauchy re-weighting on
        (``robust_iterations``), which trades that for loosely matched
        inliers. It describes noise only: a model that does not fit the
        motion (the rotation model under strong parallax) can be off by
        far more. NaN on failure, and when the inliers leave no degree of
        freedom to measure the noise with; infinite when they do not fix
        the rotation (degenerate geometry).
    selection : ModelSelection
        The evidence the model was chosen on.
    """

    success: bool
    reason: str
    n_correspondences: int
    n_inliers: int
    inlier_mask: np.ndarray
    model: str
    rotation_sigma_rad: float = math.nan
    selection: ModelSelection = field(default_factory=lambda: ModelSelection())


def _ray_products(rays_a: np.ndarray, rays_b: np.ndarray) -> np.ndarray:
    """Flattened outer products ``a_n b_n^T`` of the rays, (N, 9).

    ``a_n . (M b_n)`` of every row is ``products @ M.ravel()``, so one matrix
    product evaluates the bilinear form of all rays under many 3 x 3 matrices
    (rotations, essential matrices) at once; weighted sums of the rows are
    the covariances of the Kabsch fit.
    """
    return (rays_a[:, :, None] * rays_b[:, None, :]).reshape(-1, 9)


def _angles_from_cosines(cosines: np.ndarray) -> np.ndarray:
    """Angle between unit vectors from their dot product, through the half chord ``sqrt((1 - cos) / 2)``."""
    return 2.0 * np.arcsin(np.sqrt(np.clip(0.5 - 0.5 * cosines, 0.0, 1.0)))


def _epipolar_angles_of_essentials(products: np.ndarray, rays_b: np.ndarray,
                                   essentials: np.ndarray) -> np.ndarray:
    """:func:`epipolar_angles` for essential matrices ``E = [t]_x R_ab``, (K, 3, 3) -> (K, N).

    ``E b`` is the normal of the epipolar plane of ``b`` and ``a^T E b`` the
    ray's projection on it.
    """
    normals = essentials @ rays_b.T
    length = np.sqrt(np.sum(normals * normals, axis=1))
    dot = np.abs(essentials.reshape(-1, 9) @ products.T) / np.maximum(length, 1e-300)
    return np.arcsin(np.minimum(dot, 1.0))


def _cheiral_epipolar_angles(products: np.ndarray, rays: np.ndarray, rotations: np.ndarray,
                             translations: np.ndarray) -> np.ndarray:
    """Residual angles of poses ``(R_ab, t_ab)`` that also count a point seen behind the cameras, (K, N).

    ``rays`` holds ``rays_a`` and ``rays_b``, (2, N, 3); ``products`` their :func:`_ray_products`;
    ``rotations`` (K, 3, 3), ``translations`` (K, 3). A correspondence whose ray ``a`` lies on the
    side of ``R_ab b`` away from the epipole ``t_ab`` triangulates behind the cameras (a point
    at positive depth is seen from camera a between ``R_ab b`` and ``t_ab``); its nearest
    configuration in front is the point at infinity, so its residual is the angle between ``a``
    and ``R_ab b`` instead of the angle to the epipolar plane. For a plane seen over part of the
    sphere both essential matrices of its two-fold ambiguity fit every epipolar constraint; only
    this sign tells them apart, by the correspondences the wrong one puts behind the cameras.
    """
    rays_a, rays_b = rays
    epipolar = _epipolar_angles_of_essentials(products, rays_b, cross_product_matrix(translations) @ rotations)
    cosines = rotations.reshape(-1, 9) @ products.T  # a . R b
    # Sign of (a x R b) . (t x R b) = a . t - (a . R b) (t . R b): positive when a lies towards t.
    toward = translations @ rays_a.T - cosines * (np.einsum("kji,kj->ki", rotations, translations) @ rays_b.T)
    behind = toward < 0.0
    epipolar[behind] = np.maximum(epipolar[behind], _angles_from_cosines(cosines[behind]))
    return epipolar


def epipolar_angles(rays_a: np.ndarray, rays_b: np.ndarray, rotations: np.ndarray,
                    translations: np.ndarray) -> np.ndarray:
    """Angle between ``rays_a`` and the epipolar plane of ``rays_b`` (radians).

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        Unit rays.
    rotations : (K, 3, 3) ndarray
        Hypotheses ``R_ab``.
    translations : (K, 3) ndarray
        Hypotheses ``t_ab`` (any length).

    Returns
    -------
    (K, N) ndarray
        ``asin |rays_a . n|`` with ``n`` the unit normal of the plane spanned
        by ``t_ab`` and ``R_ab @ rays_b``.
    """
    return _epipolar_angles_of_essentials(_ray_products(rays_a, rays_b), rays_b,
                                          cross_product_matrix(translations) @ rotations)


def rotation_angles(rays_a: np.ndarray, rays_b: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Angle between ``rays_a`` and ``R_ab @ rays_b`` (radians).

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        Unit rays.
    rotations : (K, 3, 3) or (3, 3) ndarray

    Returns
    -------
    (K, N) or (N,) ndarray
    """
    difference = rays_b @ (rotations.T if rotations.ndim == 2 else np.swapaxes(rotations, -1, -2)) - rays_a
    half_chord = 0.5 * np.sqrt(np.einsum("...i,...i->...", difference, difference))
    return 2.0 * np.arcsin(np.minimum(half_chord, 1.0))


def _determinant(matrix: np.ndarray) -> float:
    """Determinant of one 3 x 3 matrix, in plain floats (cheaper than ``np.linalg.det`` for one)."""
    (a, b, c), (d, e, f), (g, h, i) = matrix.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _kabsch(covariance: np.ndarray) -> np.ndarray:
    """Proper rotations ``R`` maximising ``trace(R^T C)`` for covariances ``C``, (..., 3, 3)."""
    u, _, vt = np.linalg.svd(covariance)
    if covariance.ndim == 2:
        rotation = u @ vt
        if _determinant(rotation) < 0:
            u[:, 2] = -u[:, 2]
            rotation = u @ vt
        return rotation
    det = np.linalg.det(u @ vt)
    fix = np.ones(u.shape[:-2] + (3,))
    fix[..., 2] = np.sign(np.where(det == 0, 1.0, det))
    return (u * fix[..., None, :]) @ vt


def rotation_from_rays(rays_a: np.ndarray, rays_b: np.ndarray,
                       weights: np.ndarray | None = None) -> np.ndarray:
    """Least-squares rotation ``R_ab`` with ``rays_a ~ R_ab @ rays_b`` (Kabsch).

    Parameters
    ----------
    rays_a, rays_b : (..., N, 3) ndarray
        Unit rays; leading dimensions are batches.
    weights : (..., N) ndarray, optional

    Returns
    -------
    (..., 3, 3) ndarray
        Proper rotations minimising ``sum w |rays_a - R rays_b|^2``.
    """
    if weights is None:
        cov = np.einsum("...ni,...nj->...ij", rays_a, rays_b)
    else:
        cov = np.einsum("...n,...ni,...nj->...ij", weights, rays_a, rays_b)
    return _kabsch(cov)


def _rotations_from_ray_pairs(rays: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Kabsch rotations ``R_ab`` of two ray pairs each, in closed form.

    Parameters
    ----------
    rays : (2, N, 3) ndarray
        ``rays_a`` and ``rays_b``.
    first, second : (K,) ndarray of int
        The two pairs of each rotation.

    Returns
    -------
    (K, 3, 3) ndarray

    Notes
    -----
    For two pairs of unit rays the least-squares rotation maps the plane of
    the ``rays_b`` onto that of the ``rays_a`` and the bisector of the two
    ``rays_b`` onto the bisector of the two ``rays_a``: it is ``F_a F_b^T``
    with ``F = [bisector, half difference, normal]`` (orthogonal, as the rays
    have unit length). Pairs of (nearly) equal or opposite rays have no such
    frame; their rotations come from the singular value decomposition.
    """
    u, v = rays[:, first], rays[:, second]
    columns = np.stack([u + v, u - v, cross(u, v)], axis=-1)
    length = np.sqrt(np.einsum("...ij,...ij->...j", columns, columns))
    frames = columns / np.maximum(length, 1e-300)[..., None, :]
    rotations = frames[0] @ np.swapaxes(frames[1], -1, -2)
    degenerate = np.any(length < _FRAME_MIN_LENGTH, axis=(0, 2))
    if degenerate.any():
        pairs_a = np.stack([u[0, degenerate], v[0, degenerate]], axis=1)
        pairs_b = np.stack([u[1, degenerate], v[1, degenerate]], axis=1)
        rotations[degenerate] = rotation_from_rays(pairs_a, pairs_b)
    return rotations


def _distinct_count(rays_a: np.ndarray, rays_b: np.ndarray) -> int:
    """How many correspondences differ: distinct values of one fixed projection of ``(a, b)``
    (equal rows project equally; distinct rows that project equally are vanishingly rare)."""
    weights = np.array([1.0, np.sqrt(2.0), np.sqrt(3.0), np.sqrt(5.0), np.sqrt(7.0), np.sqrt(11.0)])
    return int(np.unique(rays_a @ weights[:3] + rays_b @ weights[3:]).size)


def _needed_iterations(inlier_fraction: float, sample: int, confidence: float) -> float:
    good = inlier_fraction ** sample
    if good <= 0:
        return np.inf
    if good >= 1:
        return 0.0
    return math.log(1.0 - confidence) / math.log(1.0 - good)


def _iteration_limit(count: int, n: int, sample: int, options: RelativePoseOptions) -> int:
    """Adaptive RANSAC stop after a best hypothesis with ``count`` of ``n`` inliers."""
    need = _needed_iterations(count / n, sample, options.confidence)
    stop = options.max_iterations if need >= options.max_iterations else math.ceil(need)
    return min(options.max_iterations, max(options.min_iterations, stop))


def _score(errors: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Inlier counts and truncated-error sums (MSAC) per hypothesis."""
    inliers = errors < threshold
    cost = np.minimum(errors, threshold).sum(axis=-1)
    return inliers.sum(axis=-1), cost


def samples_without_replacement(rng: np.random.Generator, n: int, size: int, count: int) -> np.ndarray:
    """``count`` samples of ``size`` distinct indices of ``range(n)``, (count, size) int64: the samples that
    ``count`` calls of ``rng.choice(n, size, replace=False)`` return, drawn with one call of the generator.

    NumPy's ``Generator.choice`` (``size`` < ``n``, no weights, shuffled, ``n`` <= 10000 or
    ``size`` <= ``n`` / 50) takes Floyd's algorithm (for ``j`` = ``n - size .. n - 1``: a draw ``v`` from
    ``[0, j]``, or ``j`` when ``v`` was taken already) and then shuffles the sample (for ``i`` =
    ``size - 1 .. 1``: swap ``i`` with a draw from ``[0, i]``). None of these bounded draws depends on
    an earlier one's value, so all of them, for every sample, come from one ``rng.integers`` call on
    the bounds in that order, which consumes the generator as the ``count`` calls do. The
    bookkeeping then takes each of Floyd's steps and each swap for all samples at once. (Per call,
    ``choice`` costs as much as a 5-point solve; a Python loop over the samples cost about as much.)
    """
    bounds = np.concatenate([np.arange(n - size, n), np.arange(size - 1, 0, -1)])
    draws = rng.integers(0, np.tile(bounds + 1, count)).reshape(count, -1)
    samples = draws[:, :size].copy()
    for step, last in enumerate(range(n - size, n)):
        taken = (samples[:, :step] == samples[:, step, None]).any(axis=1)
        samples[taken, step] = last
    rows = np.arange(count)
    for i, other in zip(range(size - 1, 0, -1), draws[:, size:].T):
        kept = samples[:, i].copy()
        samples[:, i] = samples[rows, other]
        samples[rows, other] = kept
    return samples.astype(np.int64, copy=False)


def _ransac_5pt(rays, products, threshold, options, rng):
    """The best essential-matrix hypotheses ``[(R_ab, t_ab), ...]``, best first (empty when no sample gave one).

    ``rays`` holds ``rays_a`` and ``rays_b``, (2, N, 3); ``products`` their
    :func:`_ray_products`. Samples are drawn and solved a chunk at a time and all their hypotheses
    scored in one go; the chunk's results are then taken in the order drawn
    with the adaptive stop applied after each sample, so the outcome is that
    of scoring one sample at a time (hypotheses drawn past the stop are
    discarded). Each sample's best hypothesis (most inliers, then lowest
    cost, then first solved) is a candidate; the ``options.refine_hypotheses``
    best distinct candidates come back (see :func:`_distinct_best`).
    """
    n = rays.shape[1]
    candidates = []  # (inlier count, truncated cost, R_ab, t_ab) of each sample taken
    best_count, limit, drawn = -1, options.max_iterations, 0
    while drawn < limit:
        chunk = min(limit - drawn, max(options.min_iterations - drawn, _CHUNK_5PT))
        rotations, translations, owners = [], [], []
        drawn_rows = samples_without_replacement(rng, n, _SAMPLE_5PT, chunk)
        for j, (sample_a, sample_b) in enumerate(zip(rays[0][drawn_rows], rays[1][drawn_rows])):
            for pose in poselib.relpose_5pt(sample_b, sample_a):
                rotations.append(pose.R)
                translations.append(pose.t)
                owners.append(j)
        if rotations:
            rotations, translations = np.stack(rotations), np.stack(translations)
            count, cost = _score(_cheiral_epipolar_angles(products, rays, rotations, translations), threshold)
            sample_of = np.asarray(owners)
            order = np.lexsort((cost, -count, sample_of))
            first = np.ones(len(order), dtype=bool)
            first[1:] = sample_of[order[1:]] != sample_of[order[:-1]]
            count, cost = count.tolist(), cost.tolist()
            for k in order[first].tolist():
                if drawn + owners[k] >= limit:
                    break
                candidates.append((count[k], cost[k], rotations[k], translations[k]))
                if count[k] > best_count:
                    best_count = count[k]
                    limit = _iteration_limit(best_count, n, _SAMPLE_5PT, options)
        drawn += chunk
    return _distinct_best(candidates, threshold, options.refine_hypotheses)


def _distinct_best(candidates, threshold, keep):
    """Up to ``keep`` hypotheses ``(R_ab, t_ab)`` of ``candidates``, best first (most inliers, then
    lowest truncated cost, then drawn first), leaving out any within ``threshold`` radians of a kept
    one in both rotation and translation direction (the same model found by another sample).
    Candidates are compared only until ``keep`` are found."""
    kept, directions = [], []
    for i in sorted(range(len(candidates)), key=lambda i: (-candidates[i][0], candidates[i][1], i)):
        if len(kept) == keep:
            break
        rotation, translation = candidates[i][2], candidates[i][3]
        direction = translation / np.linalg.norm(translation)
        if kept and np.any((geodesic_angle(rotation, np.stack([r for r, _ in kept])) < threshold)
                           & (_angles_from_cosines(np.stack(directions) @ direction) < threshold)):
            continue
        kept.append((rotation, translation))
        directions.append(direction)
    return kept


def _ransac_rotation(rays, products, threshold, options, rng):
    """Best rotation-only hypothesis ``R_ab``; two-pair samples are solved and scored a batch at a time.

    ``rays`` holds ``rays_a`` and ``rays_b``, (2, N, 3); ``products`` their :func:`_ray_products`.
    """
    n = rays.shape[1]
    best = (None, -1, np.inf)
    limit = options.max_iterations
    drawn = 0
    while drawn < limit:
        batch = min(_ROTATION_BATCH, limit - drawn)
        drawn += batch
        first = rng.integers(0, n, size=batch)
        second = (first + rng.integers(1, n, size=batch)) % n
        rotations = _rotations_from_ray_pairs(rays, first, second)
        count, cost = _score(_angles_from_cosines(rotations.reshape(-1, 9) @ products.T), threshold)
        k = int(np.lexsort((cost, -count))[0])
        if count[k] > best[1] or (count[k] == best[1] and cost[k] < best[2]):
            best = (rotations[k], int(count[k]), float(cost[k]))
            limit = _iteration_limit(best[1], n, _SAMPLE_ROTATION, options)
    return best[0]


def _reweighted_rotation(rays_a, rays_b, products, rotation, scale, iterations):
    """Kabsch rotation re-solved with Cauchy weights ``1 / (1 + (e / scale)^2)`` of the residual angles ``e``."""
    scale2 = scale * scale
    for _ in range(iterations):
        errors = rotation_angles(rays_a, rays_b, rotation)
        # The weights times scale^2: a common factor leaves the Kabsch rotation unchanged.
        rotation = _kabsch((1.0 / (scale2 + errors * errors) @ products).reshape(3, 3))
    return rotation


def _tangent_basis(t: np.ndarray) -> np.ndarray:
    """Two unit vectors orthogonal to unit ``t``, as rows of a (2, 3) array.

    The first is ``t`` crossed with the coordinate axis least aligned with
    ``t``, the second ``t`` crossed with the first.
    """
    x, y, z = t.tolist()
    magnitudes = [abs(x), abs(y), abs(z)]
    axis = magnitudes.index(min(magnitudes))
    u = ((0.0, z, -y), (-z, 0.0, x), (y, -x, 0.0))[axis]  # t x (unit vector of that axis)
    norm = math.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
    u0, u1, u2 = u[0] / norm, u[1] / norm, u[2] / norm
    return np.array([[u0, u1, u2], [y * u2 - z * u1, z * u0 - x * u2, x * u1 - y * u0]])


def _rotation_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues' formula), (3,) -> (3, 3)."""
    x, y, z = rotvec.tolist()
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:  # I + [v]_x is exact to rounding: the next term is of order angle^2
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    x, y, z = x / angle, y / angle, z / angle
    s, c = math.sin(angle), 2.0 * math.sin(0.5 * angle) ** 2  # sin, 1 - cos
    return np.array([[1.0 - c * (y * y + z * z), c * x * y - s * z, c * x * z + s * y],
                     [c * x * y + s * z, 1.0 - c * (x * x + z * z), c * y * z - s * x],
                     [c * x * z - s * y, c * y * z + s * x, 1.0 - c * (x * x + y * y)]])


def _unit_step(t: np.ndarray, step: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``normalise(t + basis^T step)`` for a (3,) vector, a (2,) step and a (2, 3) basis, in plain floats."""
    (x, y, z), (s0, s1), ((p0, p1, p2), (q0, q1, q2)) = t.tolist(), step.tolist(), basis.tolist()
    x, y, z = x + s0 * p0 + s1 * q0, y + s0 * p1 + s1 * q1, z + s0 * p2 + s1 * q2
    norm = math.sqrt(x * x + y * y + z * z)
    return np.array([x / norm, y / norm, z / norm])


def _symmetric_epipolar_residuals(rays_a, rays_b, rotation, t, *, jacobian=True):
    """Signed sines of both rays' angles to the epipolar plane and their Jacobian.

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        Unit rays.
    rotation : (3, 3) ndarray
        ``R_ab``.
    t : (3,) ndarray
        Unit translation direction.
    jacobian : bool, keyword-only
        Compute the Jacobian (else ``None`` is returned for it and the basis).

    Returns
    -------
    residuals : (2N,) ndarray
        ``a . (t x R b) / |t x R b|``, then ``R b . (t x a) / |t x a|``.
    jac : (2N, 5) ndarray or None
        Derivatives with respect to a rotation vector ``w`` applied on the
        left (``R <- exp([w]_x) R``) and a step ``s`` in the tangent basis
        ``B`` (``t <- normalise(t + B^T s)``), at zero.
    basis : (2, 3) ndarray or None
        ``B``, rows orthogonal to ``t``.
    """
    n = len(rays_a)
    rotated = rays_b @ rotation.T
    cross_t = cross_product_matrix(t)
    # Rows 0..N-1: moving ray R b, partner a; rows N..2N-1: moving ray a, partner R b.
    stacked = np.concatenate([rotated, rays_a, rotated])
    moving, partner = stacked[:2 * n], stacked[n:]
    normals = moving @ cross_t.T  # t x moving
    length = np.maximum(np.sqrt(np.einsum("ni,ni->n", normals, normals)), 1e-300)
    residuals = np.einsum("ni,ni->n", normals, partner) / length
    if not jacobian:
        return residuals, None, None
    basis = _tangent_basis(t)
    # d r = g . d(t x moving) + (d partner) . normal / |normal|,
    # with g = (partner - r normal / |normal|) / |normal|.
    g = (partner - (residuals / length)[:, None] * normals) / length[:, None]
    tb = rotated @ t
    ab = np.einsum("ni,ni->n", rays_a, rotated)
    jac = np.empty((2 * n, 5))
    # Rotation w moves R b: d(R b) = w x R b. First half: d(t x R b) = w (t . R b) - R b (t . w),
    # and g . R b = (a . R b) / |t x R b|. Second half: (w x R b) . (t x a) / |t x a|
    # = w . (t (a . R b) - a (t . R b)) / |t x a|.
    jac[:n, :3] = tb[:, None] * g[:n] - (ab / length[:n])[:, None] * t
    jac[n:, :3] = (ab[:, None] * t - tb[:, None] * rays_a) / length[n:, None]
    # Translation d t = B^T s: d(t x moving) = d t x moving, so d r_k = (moving x g) . B_k
    # = g . (B_k x moving), with the rows B_k x moving = moving @ [B_k]_x^T of both k in one product.
    (p0, p1, p2), (q0, q1, q2) = basis.tolist()
    crossing = np.array([[0.0, p2, -p1, 0.0, q2, -q1],
                         [-p2, 0.0, p0, -q2, 0.0, q0],
                         [p1, -p0, 0.0, q1, -q0, 0.0]])
    jac[:, 3:] = np.einsum("nkj,nj->nk", (moving @ crossing).reshape(2 * n, 2, 3), g)
    return residuals, jac, basis


def _gauss_newton_step(jac: np.ndarray, res: np.ndarray) -> np.ndarray:
    """Step ``d`` minimising ``|res + jac d|``: normal equations, least squares if they are singular."""
    try:
        return np.linalg.solve(jac.T @ jac, -(jac.T @ res))
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(jac, -res, rcond=None)[0]


def _refine_5pt(rays_a, rays_b, rotation, translation, iterations):
    """Gauss-Newton on (rotation vector, tangent step of t) of the symmetric epipolar residuals.

    The Jacobian is analytic (:func:`_symmetric_epipolar_residuals`). A step
    that raises the sum of squares is rejected and ends the iterations; so
    does a relative decrease below ``1e-6``.
    """
    t = translation / np.linalg.norm(translation)
    res, jac, basis = _symmetric_epipolar_residuals(rays_a, rays_b, rotation, t, jacobian=iterations > 0)
    cost = float(res @ res)
    for i in range(iterations):
        delta = _gauss_newton_step(jac, res)
        cand_rot = _rotation_from_rotvec(delta[:3]) @ rotation
        cand_t = _unit_step(t, delta[3:], basis)
        res_new, jac_new, basis_new = _symmetric_epipolar_residuals(
            rays_a, rays_b, cand_rot, cand_t, jacobian=i + 1 < iterations)
        new_cost = float(res_new @ res_new)
        if not new_cost <= cost:  # also rejects a step that made the residuals NaN
            break
        rotation, t, res, jac, basis = cand_rot, cand_t, res_new, jac_new, basis_new
        old_cost, cost = cost, new_cost
        if old_cost - new_cost <= 1e-6 * old_cost:
            break
    return rotation, t


def noise_sigma_from_residuals(angles: np.ndarray, threshold: float) -> float:
    """Noise level of rotation-model residuals that were kept below ``threshold``.

    A rotation-model residual is the angle between two unit rays; with
    isotropic noise it is Rayleigh distributed with scale ``sigma`` (the
    per-axis standard deviation of the residual). The inliers are that
    distribution truncated at ``threshold``; ``sigma`` is chosen so that the
    truncated distribution's median equals the residuals' median. The
    median keeps a minority of loosely matched inliers from inflating the
    estimate, and the truncation keeps a threshold close to the noise from
    biasing it low the way the inliers' plain spread would.

    Parameters
    ----------
    angles : (N,) ndarray
        Residual angles below ``threshold``, radians.
    threshold : float
        Truncation, radians.

    Returns
    -------
    float
        ``sigma`` in radians, within ``[threshold / 1000, 10 * threshold]``
        (the upper end when the residuals are spread evenly up to the
        threshold); ``threshold / 2`` for fewer than two residuals.
    """
    r = np.asarray(angles, dtype=np.float64)
    r = np.sort(r[(r >= 0) & (r < threshold)])
    lower, upper = threshold * 1e-3, threshold * 10.0
    if len(r) < _SAMPLE_ROTATION:
        return threshold / 2.0
    half = len(r) // 2
    median = float(r[half]) if len(r) % 2 else float((r[half - 1] + r[half]) / 2.0)
    median2, threshold2 = median ** 2, threshold ** 2

    def excess(log_sigma: float) -> float:
        # Truncated Rayleigh CDF at the median minus one half.
        s2 = 2.0 * math.exp(2.0 * log_sigma)
        return -math.expm1(-median2 / s2) + 0.5 * math.expm1(-threshold2 / s2)

    if excess(math.log(lower)) <= 0:
        return lower
    if excess(math.log(upper)) >= 0:
        return upper
    return math.exp(brentq(excess, math.log(lower), math.log(upper), xtol=1e-6))


def _epipolar_noise_evidence(errors: np.ndarray, window: float, group: int) -> tuple[float, float]:
    """The 5-point model's inlier epipolar angles below ``window`` as evidence of the ray noise:
    ``(sum of squares per measurement (rad^2), measurements minus the model's five parameters)``."""
    kept = errors[errors < window]
    return float(np.sum(kept ** 2)) / group, len(kept) / group - _SAMPLE_5PT


def _epipolar_noise_sigma(evidence: tuple[float, float], window: float, *,
                          confidence: float | None = None, prior: tuple[float, float] = (0.0, 0.0)
                          ) -> float | None:
    """Ray noise (radians, per axis) from the 5-point model's epipolar angles below ``window``,
    given as their ``evidence`` (:func:`_epipolar_noise_evidence`).

    An epipolar angle is one-dimensional, so the mean square of the ``m``
    measurements (``group`` rays each) below ``window``, corrected for the
    model's five parameters, estimates the variance:
    ``sum(e^2) / (group (m - 5))``. The model is refined by least squares
    on its inliers, for which this correction is exact to first order. The
    cut at ``window`` is undone by taking the noise of the normal
    distribution whose part within ``+-window`` has that mean square
    (:func:`_untruncated_sigma`): a wider window takes in near misses of
    repetitive texture, and without the correction the cut makes the noise
    look smaller and hands pure rotations to the 5-point model.

    ``prior`` ``(rms, k)`` pools earlier evidence of the same window: ``k``
    measurements' worth of mean square ``rms^2`` join the sum of squares and
    the degrees of freedom.

    With ``confidence``, the upper bound of the noise at that confidence
    instead (the sum of squares over the noise variance is chi-square with
    ``m - 5 + k`` degrees of freedom).

    Returns
    -------
    float or None
        None without residual freedom (``m - 5 + k <= 0``).
    """
    squares, dof = evidence
    prior_rms, prior_dof = prior
    if _pools_with(squares, dof, prior_rms, prior_dof):
        squares, dof = squares + prior_dof * prior_rms ** 2, dof + prior_dof
    if dof <= 0:
        return None
    # The chi-square quantile 2 P^-1(dof / 2, 1 - confidence) (P the regularised lower incomplete gamma
    # function), which is what ``scipy.stats.chi2.ppf`` computes, without its argument handling.
    scale = dof if confidence is None else 2 * gammaincinv(dof / 2, 1.0 - confidence)
    return _untruncated_sigma(math.sqrt(squares / scale), window)


def _pools_with(squares: float, dof: float, prior_rms: float, prior_dof: float) -> bool:
    """Whether a pair's noise evidence (sum of squares, degrees of freedom) is pooled with a prior:
    unless the two mean squares differ at the two-sided level ``_NOISE_POOLING_LEVEL`` of an F
    test. A pair without residual freedom always takes the prior; a pair whose own measurements
    show a clearly different noise (other depths, other texture in view) keeps its own."""
    if prior_dof <= 0 or prior_rms <= 0:
        return False
    if dof <= 0:
        return True
    below = fdtr(dof, prior_dof, squares / dof / prior_rms ** 2)
    return _NOISE_POOLING_LEVEL / 2 <= below <= 1 - _NOISE_POOLING_LEVEL / 2


def _untruncated_sigma(rms: float, window: float) -> float:
    """Standard deviation of a normal deviate whose values within ``+-window`` have the root mean
    square ``rms``: ``E[x^2 | |x| < w] = sigma^2 (1 - 2 a phi(a) / (2 Phi(a) - 1))``, ``a = w / sigma``.

    A mean square of a third of ``window^2`` or more (residuals spread evenly up to the window,
    no peak of noise inside it) gives ten windows.
    """
    if rms <= 0.0:
        return 0.0
    if rms * rms >= window * window / 3.0:
        return 10.0 * window

    def excess(log_sigma: float) -> float:
        a = window / math.exp(log_sigma)
        inside = math.erf(a / math.sqrt(2.0))
        shrink = 1.0 - 2.0 * a * math.exp(-0.5 * a * a) / math.sqrt(2.0 * math.pi) / inside
        return math.exp(2.0 * log_sigma) * shrink - rms * rms

    low, high = math.log(rms), math.log(10.0 * window)
    if excess(low) >= 0.0:  # the window is so far out that truncating there changes nothing
        return rms
    if excess(high) <= 0.0:
        return 10.0 * window
    return math.exp(brentq(excess, low, high, xtol=1e-6))


def _rotation_sigma_of_5pt(rays_a, rays_b, rotation, translation, noise: float | None, group: int) -> float:
    """Predicted RMS geodesic error of a 5-point rotation (see ``RelativePoseInfo.rotation_sigma_rad``).

    The symmetric residuals give every ray two rows of nearly the same
    information, so their Gauss-Newton matrix is halved; a group of
    ``group`` rays shares one error, so it is divided by ``group`` as well.
    ``noise`` is the standard deviation of one epipolar angle.
    """
    if noise is None:
        return math.nan
    if noise == 0.0:  # residuals all zero: exact geometry
        return 0.0
    _, jac, _ = _symmetric_epipolar_residuals(rays_a, rays_b, rotation, translation)
    return _rotation_rms_from_information(jac.T @ jac / (2.0 * group * noise * noise))


def _rotation_sigma_of_rotation(rays_b, rotation, noise: float, group: int) -> float:
    """Predicted RMS geodesic error of a rotation-model rotation from its inlier rays ``rays_b``.

    A ray's residual is two-dimensional, in the plane normal to ``R_ab b``,
    with ``noise`` per axis: its information about a rotation vector applied
    on the left is the projector onto that plane over ``noise**2``.
    """
    turned = rays_b @ rotation.T
    return _rotation_rms_from_information((len(turned) * np.eye(3) - turned.T @ turned) / (group * noise * noise))


def _rotation_rms_from_information(information: np.ndarray) -> float:
    """Square root of the trace of the covariance's rotation block (the first three parameters),
    the covariance being the inverse of ``information``; infinite when that is singular."""
    try:
        covariance = np.linalg.inv(information)[:3, :3]
    except np.linalg.LinAlgError:
        return math.inf
    trace = float(np.trace(covariance))
    return math.sqrt(trace) if trace > 0 and np.all(np.linalg.eigvalsh(covariance) > 0) else math.inf


def gric(errors: np.ndarray, sigma: float, *, dimension: int, parameters: int, group: int = 1) -> float:
    """Torr's geometric robust information criterion of a model (lower is better).

    Parameters
    ----------
    errors : (N,) ndarray
        Residual angles of the correspondences under the model, radians.
    sigma : float
        Ray noise (radians, per axis) the residuals are weighed with.
    dimension : int, keyword-only
        Dimension of the model's manifold in the 4-D space of a
        correspondence (2 for a rotation or a homography, 3 for an essential
        matrix). Residuals are capped at ``2 (4 - dimension)`` in units of
        the noise variance, so an outlier costs a fixed amount.
    parameters : int, keyword-only
        The model's degrees of freedom.
    group : int, keyword-only
        Correspondences in groups of ``group`` that share one error count as
        one observation per group.

    Returns
    -------
    float
        ``sum(min(e^2 / sigma^2, cap)) / group + log(4) dimension n + log(4 n) parameters``
        with ``n = N / group``.
    """
    n = len(errors) / group
    capped = np.minimum((errors / sigma) ** 2, 2.0 * (4 - dimension)).sum() / group
    return float(capped + np.log(4.0) * dimension * n + np.log(4.0 * n) * parameters)


def _checked_inputs(rays_a, rays_b, options: RelativePoseOptions,
                    rays_per_measurement) -> tuple[np.ndarray, np.ndarray, int]:
    """Rays as float arrays and the group size, checked (see :func:`relative_pose_from_rays`)."""
    rays_a = np.asarray(rays_a, dtype=np.float64)
    rays_b = np.asarray(rays_b, dtype=np.float64)
    if rays_a.ndim != 2 or rays_a.shape[1:] != (3,) or rays_a.shape != rays_b.shape:
        raise ValueError(
            f"expected rays_a and rays_b of equal shape (N, 3), got {rays_a.shape} and {rays_b.shape}")
    if options.ransac_threshold_rad is None:
        raise ValueError("ransac_threshold_rad is None; set it or resolve the pixel threshold with "
                         "RelativePoseOptions.resolved(pixel_angle_rad)")
    if isinstance(rays_per_measurement, bool) or int(rays_per_measurement) != rays_per_measurement \
            or rays_per_measurement < 1:
        raise ValueError(f"expected rays_per_measurement to be an integer >= 1, got {rays_per_measurement!r}")
    if not (np.isfinite(rays_a).all() and np.isfinite(rays_b).all()):
        finite = np.all(np.isfinite(rays_a), axis=1) & np.all(np.isfinite(rays_b), axis=1)
        raise ValueError(f"rays must be finite; {int((~finite).sum())} of {len(rays_a)} rows are not")
    return rays_a, rays_b, int(rays_per_measurement)


def _fit_rotation(rays_a, rays_b, products, rays, options: RelativePoseOptions, rng):
    """Rotation-only model: RANSAC, refinement on its inliers, noise level of its residuals.

    Returns
    -------
    rotation : (3, 3) ndarray
    errors : (N,) ndarray
        Rotation residual angles of every correspondence.
    mask : (N,) ndarray of bool
        Inliers under the rotation threshold.
    sigma : float
        Noise level (radians) for the model selection.
    """
    rot_threshold = options.rotation_threshold_factor * options.ransac_threshold_rad
    rotation = _ransac_rotation(rays, products, rot_threshold, options, rng)
    rot_errors = rotation_angles(rays_a, rays_b, rotation)
    rot_mask = rot_errors < rot_threshold
    if options.refine and rot_mask.sum() >= _SAMPLE_ROTATION:
        rotation = _kabsch(products[rot_mask].sum(axis=0).reshape(3, 3))
        rot_errors = rotation_angles(rays_a, rays_b, rotation)
        rot_mask = rot_errors < rot_threshold
    sigma = options.noise_sigma_rad or noise_sigma_from_residuals(rot_errors[rot_mask], rot_threshold)
    if options.refine and options.robust_iterations and rot_mask.sum() >= _SAMPLE_ROTATION:
        rotation = _reweighted_rotation(rays_a[rot_mask], rays_b[rot_mask], products[rot_mask], rotation,
                                        options.robust_scale * sigma, options.robust_iterations)
        rot_errors = rotation_angles(rays_a, rays_b, rotation)
        rot_mask = rot_errors < rot_threshold
    return rotation, rot_errors, rot_mask, sigma


def _refined_5pt(rays_a, rays_b, products, rotation, translation, options: RelativePoseOptions):
    """The 5-point model refined on its inliers, then on the refined model's inliers
    (``options.polish_rounds``), and the residual angles of every correspondence under it
    (:func:`_cheiral_epipolar_angles`)."""
    threshold = options.ransac_threshold_rad
    rays = np.stack([rays_a, rays_b])
    errors = _cheiral_epipolar_angles(products, rays, rotation[None], translation[None])[0]
    mask = errors < threshold
    for _ in range(1 + options.polish_rounds if options.refine else 0):
        if mask.sum() < _SAMPLE_5PT:
            break
        rotation, translation = _refine_5pt(rays_a[mask], rays_b[mask], rotation, translation,
                                            options.refine_iterations)
        errors = _cheiral_epipolar_angles(products, rays, rotation[None], translation[None])[0]
        refined_mask = errors < threshold
        if np.array_equal(refined_mask, mask):
            break
        mask = refined_mask
    return rotation, translation, errors


def _lowest_cost_refined_5pt(rays_a, rays_b, products, hypotheses, options: RelativePoseOptions):
    """:func:`_refined_5pt` of the best hypothesis, or of another one when that ends at a lower
    truncated epipolar cost (MSAC).

    The other hypotheses (``hypotheses[1:]``, at most ``options.refine_hypotheses - 1``) are
    screened with one refinement each on their own inliers; only the lowest-cost one is polished,
    and it replaces the best hypothesis's result only if its polished cost is lower. Without ``options.refine``
    the best hypothesis alone, unrefined.
    """
    threshold = options.ransac_threshold_rad
    chosen = _refined_5pt(rays_a, rays_b, products, *hypotheses[0], options)
    if not options.refine or len(hypotheses) == 1:
        return chosen
    chosen_cost = _score(chosen[2], threshold)[1]
    screen = replace(options, polish_rounds=0)
    challenger, challenger_cost = None, chosen_cost
    for rotation, translation in hypotheses[1:]:
        screened = _refined_5pt(rays_a, rays_b, products, rotation, translation, screen)
        cost = _score(screened[2], threshold)[1]
        if cost < challenger_cost:
            challenger, challenger_cost = screened, cost
    if challenger is not None:
        polished = _refined_5pt(rays_a, rays_b, products, challenger[0], challenger[1], options)
        if _score(polished[2], threshold)[1] < chosen_cost:
            chosen = polished
    return chosen


def _fit_5pt(rays_a, rays_b, products, rays, options: RelativePoseOptions, rng):
    """The refined 5-point model ``(R_ab, unit t_ab, residual angles of every correspondence)``
    (:func:`_cheiral_epipolar_angles`), or None when no sample gave a hypothesis."""
    hypotheses = _ransac_5pt(rays, products, options.ransac_threshold_rad, options, rng)
    if not hypotheses:
        return None
    rotation, translation, errors = _lowest_cost_refined_5pt(rays_a, rays_b, products, hypotheses, options)
    return rotation, translation / np.linalg.norm(translation), errors


def _inlier_epipolar_angles(rays_a, rays_b, five_point, threshold: float) -> np.ndarray:
    """Epipolar angles (radians) of the 5-point model's inliers, the noise it measures: the angle
    to the epipolar plane, whichever side of the cameras a correspondence triangulates on."""
    rotation, translation, errors = five_point
    inliers = errors < threshold
    return epipolar_angles(rays_a[inliers], rays_b[inliers], rotation[None], translation[None])[0]


def _model_selection(rays_a, rays_b, rotation_fit, five_point, evidence: tuple[float, float],
                     options: RelativePoseOptions, group: int) -> ModelSelection:
    """Both models' GRIC over the correspondences either explains, the parallax and the noise level;
    ``evidence`` is the noise evidence of the 5-point inliers' epipolar angles
    (:func:`_epipolar_noise_evidence` of :func:`_inlier_epipolar_angles`).

    The noise level is ``options.noise_sigma_rad`` or the estimate of the
    5-point model's residuals (:func:`_epipolar_noise_sigma`), at most the inlier threshold: that
    model is the richer one, so its residuals hold only noise whether the
    camera moved or not, while the rotation model's also hold the parallax.
    With too few 5-point inliers to estimate it, the rotation model's
    estimate is used (:func:`noise_sigma_from_residuals`). GRIC is evaluated on
    the correspondences that are inliers of either model: a gross outlier
    costs the 5-point model less than the rotation model (its residual cap is
    lower), so counting the outliers of both would hand heavily contaminated
    pairs to the 5-point model.
    """
    threshold = options.ransac_threshold_rad
    rot_threshold = threshold * options.rotation_threshold_factor
    _, rot_errors, rot_mask, rot_sigma = rotation_fit
    rotation_5pt, _, errors_5pt = five_point
    inliers_5pt = errors_5pt < threshold
    # An estimate above the threshold (inliers spread evenly up to it, no peak of noise inside) is
    # taken as the threshold: the inliers cannot show a larger noise, and a larger one would make a
    # parallax of many thresholds look like noise.
    prior = (options.noise_prior_rms_rad or 0.0, options.noise_prior_measurements)
    noise = (options.noise_sigma_rad
             or min(_epipolar_noise_sigma(evidence, threshold, confidence=_NOISE_CONFIDENCE, prior=prior)
                    or rot_sigma, threshold))
    squares, dof = evidence
    either = rot_mask | inliers_5pt
    parallax = rotation_angles(rays_a[inliers_5pt], rays_b[inliers_5pt], rotation_5pt)
    # Exact rays: residuals of rounding only, which the two models' angle formulas resolve differently.
    weigh = max(noise, _NOISE_FLOOR_RAD)
    # The homography's residual is two-dimensional, as the rotation model's: the same threshold.
    transfer = inlier_homography(rays_a[either], rays_b[either], threshold_rad=rot_threshold)[1] \
        if either.sum() >= _MIN_HOMOGRAPHY_RAYS else None
    return ModelSelection(
        gric_rotation=gric(rot_errors[either], weigh, dimension=2, parameters=3, group=group),
        gric_5pt=gric(errors_5pt[either], weigh, dimension=3, parameters=5, group=group),
        gric_homography=math.nan if transfer is None else gric(transfer, weigh, dimension=2, parameters=8,
                                                               group=group),
        parallax_rad=float(np.median(parallax)) if len(parallax) else math.nan,
        noise_sigma_rad=float(noise), noise_rms_rad=math.sqrt(squares / dof) if dof > 0 else math.nan,
        noise_measurements=max(dof, 0.0), translation_prior=options.translation_prior or 0.5)


def _chance_inlier_rate(rays_a, rays_b, rotation, translation, threshold, seed) -> float:
    """Share of chance pairings (``rays_a`` with shuffled ``rays_b``) the model counts as inliers.

    ``translation`` None is the rotation model (its inlier test is the angle
    to the rotated ray, below ``threshold``), else the 5-point model's
    epipolar angle. One is added to both counts, so the rate is never 0.
    """
    rng = np.random.default_rng([seed, _CHANCE_STREAM])
    n = len(rays_a)
    shuffled = rays_b[np.concatenate([rng.permutation(n) for _ in range(_CHANCE_PERMUTATIONS)])]
    paired = np.tile(rays_a, (_CHANCE_PERMUTATIONS, 1))
    if translation is not None:
        errors = epipolar_angles(paired, shuffled, rotation[None], translation[None])[0]
    else:
        errors = rotation_angles(paired, shuffled, rotation)
    return (np.count_nonzero(errors < threshold) + 1) / (len(errors) + 1)


def _chance_consensus_reason(rays_a, rays_b, mask, model: str, rotation, translation,
                             options: RelativePoseOptions) -> str:
    """Why the consensus ``mask`` of ``model`` looks like chance (see
    ``RelativePoseOptions.min_draw_success``), or ``""``."""
    n, count = len(mask), int(mask.sum())
    five_point = model == "5pt"
    sample = _SAMPLE_5PT if five_point else _SAMPLE_ROTATION
    if count == n:
        return ""
    draw_success = -math.expm1(options.max_iterations * math.log1p(-((count / n) ** sample)))
    if draw_success >= options.min_draw_success:
        return ""
    threshold = options.ransac_threshold_rad * (1.0 if five_point else options.rotation_threshold_factor)
    rate = _chance_inlier_rate(rays_a, rays_b, rotation, translation if five_point else None, threshold,
                               options.seed)
    hypotheses = options.max_iterations * (_MAX_5PT_SOLUTIONS if five_point else 1)
    false_alarms = hypotheses * float(bdtrc(count - sample - 1, n - sample, rate))
    if false_alarms <= options.max_chance_false_alarms:
        return ""
    return (f"inliers look like chance ({count} of {n}: the draw held an outlier-free sample with "
            f"probability {draw_success:.2g}; shuffled pairs are inliers at {rate:.2g}, "
            f"{false_alarms:.2g} chance models expected with as many)")


def relative_pose_from_rays(rays_a: np.ndarray, rays_b: np.ndarray, *,
                            options: RelativePoseOptions,
                            rays_per_measurement: int = 1) -> tuple[RelativePose, RelativePoseInfo]:
    """Estimate ``R_ab`` (and the translation direction) from corresponding rays.

    Parameters
    ----------
    rays_a : (N, 3) ndarray
        Unit rays in camera a.
    rays_b : (N, 3) ndarray
        Unit rays in camera b, row i corresponding to ``rays_a[i]``.
    options : RelativePoseOptions, keyword-only
    rays_per_measurement : int, keyword-only
        How many rays share one measurement and so one error (the iFMI front
        end samples several flow points from each tile's motion; keypoint
        matches are one each). The model selection counts each such group
        as one observation: counted once per ray, group-correlated errors
        look like evidence the 5-point model's extra freedom can explain.

    Returns
    -------
    pose : RelativePose
        Identity rotation and zero translation on failure.
    info : RelativePoseInfo
        Success flag with a reason, inlier mask and the model chosen.
    """
    rays_a, rays_b, rays_per_measurement = _checked_inputs(rays_a, rays_b, options,
                                                           rays_per_measurement)
    n = len(rays_a)
    rng = np.random.default_rng(options.seed)
    too_few = _too_few_reason(rays_a, rays_b, options)
    if too_few:
        return RelativePose(), RelativePoseInfo(False, too_few, n, 0, np.zeros(n, dtype=bool),
                                                "rotation" if options.rotation_only else "5pt")
    products = _ray_products(rays_a, rays_b)
    rays = np.stack([rays_a, rays_b])
    rotation_fit = _fit_rotation(rays_a, rays_b, products, rays, options, rng)
    model, rotation, translation, mask = "rotation", rotation_fit[0], np.zeros(3), rotation_fit[2]
    selection, failure = ModelSelection(noise_sigma_rad=rotation_fit[3]), None
    if not options.rotation_only:
        five_point = _fit_5pt(rays_a, rays_b, products, rays, options, rng)
        if five_point is None and options.five_point_only:
            return RelativePose(), RelativePoseInfo(False, "no 5-point hypothesis", n, 0,
                                                    np.zeros(n, dtype=bool), "5pt")
        if five_point is not None:
            evidence = _epipolar_noise_evidence(
                _inlier_epipolar_angles(rays_a, rays_b, five_point, options.ransac_threshold_rad),
                options.ransac_threshold_rad, rays_per_measurement)
            selection = _model_selection(rays_a, rays_b, rotation_fit, five_point, evidence, options,
                                         rays_per_measurement)
            model, rotation, translation, mask, failure = _supported_model(
                rays_a, rays_b, rotation_fit, five_point,
                options.five_point_only or selection.prefers_translation, options,
                rays_per_measurement)
    if failure is None:  # the rotation model alone was fitted
        failure = _consensus_failure(rays_a, rays_b, mask, model, rotation, translation, options,
                                     rays_per_measurement)
    count = int(mask.sum())
    if failure:
        return RelativePose(), RelativePoseInfo(False, failure, n, count, mask, model, selection=selection)
    pose = RelativePose(rotation=np.asarray(rotation, dtype=np.float64),
                        translation_direction=np.asarray(translation, dtype=np.float64))
    if model == "rotation":
        sigma = _rotation_sigma_of_rotation(rays_b[mask], pose.rotation, rotation_fit[3], rays_per_measurement)
    else:
        noise = options.noise_sigma_rad or _epipolar_noise_sigma(evidence, options.ransac_threshold_rad)
        sigma = _rotation_sigma_of_5pt(rays_a[mask], rays_b[mask], pose.rotation, pose.translation_direction,
                                       noise, rays_per_measurement)
    return pose, RelativePoseInfo(True, "", n, count, mask, model, sigma, selection)


def _supported_model(rays_a, rays_b, rotation_fit, five_point, prefer_5pt: bool, options: RelativePoseOptions,
                     group: int):
    """``(model, R_ab, t_ab, inlier mask, failure reason)`` of the preferred model, or of the other one
    when the preferred model's consensus fails (:func:`_consensus_failure`) and the other's passes.

    GRIC weighs how well each model explains the correspondences, not whether its consensus can be
    trusted: a pair whose rotation model keeps too few inliers, while the 5-point model keeps enough,
    would otherwise fail although the 5-point model solves it (and the forced 5-point run does).
    A forced model (``options.five_point_only``) is never exchanged.
    """
    threshold = options.ransac_threshold_rad
    candidates = {"rotation": (rotation_fit[0], np.zeros(3), rotation_fit[2]),
                  "5pt": (five_point[0], five_point[1], five_point[2] < threshold)}
    order = ["5pt", "rotation"] if prefer_5pt else ["rotation", "5pt"]
    if options.five_point_only:
        order = ["5pt"]
    first = None
    for model in order:
        rotation, translation, mask = candidates[model]
        failure = _consensus_failure(rays_a, rays_b, mask, model, rotation, translation, options, group)
        if not failure:
            return model, rotation, translation, mask, ""
        first = first or (model, rotation, translation, mask, failure)
    return first


def _too_few_reason(rays_a, rays_b, options: RelativePoseOptions) -> str:
    """Why the correspondences are too few for the model's sample and ``options.min_inliers``, or ``""``."""
    n = len(rays_a)
    needed = max(options.min_inliers, _SAMPLE_ROTATION if options.rotation_only else _SAMPLE_5PT)
    if n < needed:
        return f"too few correspondences ({n} < {needed})"
    distinct = _distinct_count(rays_a, rays_b)
    if distinct < needed:  # repeated matches count as many inliers but constrain nothing
        return f"too few distinct correspondences ({distinct} of {n} differ; < {needed})"
    return ""


def _consensus_failure(rays_a, rays_b, mask, model: str, rotation, translation, options: RelativePoseOptions,
                       group: int) -> str:
    """Why the chosen model's inliers ``mask`` fail the pair (too few, too few measurements, chance), or ``""``."""
    count = int(mask.sum())
    if count < options.min_inliers:
        return f"too few inliers ({count} < {options.min_inliers})"
    measurements = int(np.unique(np.flatnonzero(mask) // group).size)
    if measurements < options.min_inlier_measurements:
        return (f"too few measurements with inliers ({measurements} < {options.min_inlier_measurements}; "
                f"{count} inlier rays in groups of {group})")
    return _chance_consensus_reason(rays_a, rays_b, mask, model, rotation, translation, options)
