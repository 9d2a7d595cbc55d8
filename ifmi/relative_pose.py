"""Relative pose of two cameras from corresponding unit rays.

Convention: for frames ``a`` (earlier or keyframe) and ``b``, ``R_ab`` maps
camera-b directions into camera-a coordinates, ``X_a = R_ab @ X_b + t_ab``, so
corresponding rays satisfy ``rays_a ~ R_ab @ rays_b + t_ab`` (up to depth).

Two models compete inside a seeded RANSAC with an angular threshold:

* ``"5pt"``: the minimal essential-matrix solver on bearing vectors
  (``poselib.relpose_5pt``, which accepts rays of any sign of z), scored by
  the angle between a ray and the epipolar plane of its partner, then refined
  by Gauss-Newton on the inliers' symmetric epipolar angles;
* ``"rotation"``: a rotation-only model (Kabsch on rays, two rays per
  sample), scored by the angle between ``rays_a`` and ``R_ab @ rays_b``,
  then refined by Kabsch on the inliers and re-solved a few times with
  Cauchy weights of the residual angles.

Under (near) pure rotation every translation fits the epipolar constraint,
which makes the 5-point solution ill-conditioned and lets it fit noise. The
model is chosen by Torr's GRIC, which charges the 5-point model for its two
extra degrees of freedom and its weaker (one-dimensional) constraint per ray.
GRIC needs the ray noise; unless given, it is estimated from the residuals
of the rotation model's inliers (a noise level below the truth makes every
residual look like an outlier to both models and hands the choice to the
5-point model's lower cap per outlier). For the same reason it is evaluated
on the correspondences that are inliers of either model only.

The inlier threshold is an angle. Its default is a number of pixels
(``ransac_threshold_px``) times the angle one pixel subtends, which only the
caller knows (:func:`ifmi.pipeline.angular_pixel_size` for a calibration);
:meth:`RelativePoseOptions.resolved` turns one into the other, and an
explicit ``ransac_threshold_rad`` overrides it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import poselib
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

__all__ = [
    "RelativePoseOptions",
    "RelativePose",
    "RelativePoseInfo",
    "relative_pose_from_rays",
    "rotation_from_rays",
    "epipolar_angles",
    "rotation_angles",
    "noise_sigma_from_residuals",
]

# Smallest sample of each model.
_SAMPLE_5PT = 5
_SAMPLE_ROTATION = 2
# Rotation-only hypotheses are cheap; they are drawn and scored in batches of this size.
_ROTATION_BATCH = 32


@dataclass(frozen=True)
class RelativePoseOptions:
    """Options of :func:`relative_pose_from_rays`.

    Attributes
    ----------
    ransac_threshold_rad : float or None
        Inlier threshold, radians: the angle between a ray and its epipolar
        plane (5-point model) or its rotated partner (rotation model).
        ``None`` (default): ``ransac_threshold_px`` pixels, converted with
        :meth:`resolved` once the pixel size is known;
        :func:`relative_pose_from_rays` needs it set.
    ransac_threshold_px : float
        Default inlier threshold in pixels of the image (1 pixel, the usual
        choice for keypoint matches); used when ``ransac_threshold_rad`` is
        ``None``.
    max_iterations : int
        Largest number of RANSAC samples per model.
    min_iterations : int
        Smallest number of samples per model before the adaptive stop.
    confidence : float
        Adaptive stop: probability of having drawn one all-inlier sample.
    min_inliers : int
        Fewer inliers than this is a failure.
    seed : int
        Seed of the sample generator; the same seed gives the same result.
    refine : bool
        Refine the chosen model on its inliers.
    refine_iterations : int
        Gauss-Newton iterations of the 5-point refinement.
    rotation_only : bool
        Force the rotation-only model.
    noise_sigma_rad : float or None
        Standard deviation (per axis, radians) of the ray noise used to
        choose between the models by GRIC; ``None`` estimates it from the
        rotation model's inlier residuals (see :func:`noise_sigma_from_residuals`).
    rotation_threshold_factor : float
        The rotation model's inlier threshold is this multiple of
        ``ransac_threshold_rad``: its error is an angle in two dimensions,
        the epipolar one in one dimension, so equal noise gives larger
        rotation-model errors (sqrt(chi2_2 / chi2_1) = 1.25 at 95 %).
    robust_iterations : int
        With ``refine``: re-solve the rotation model on its inliers this many
        times with Cauchy weights of the residual angles (0: plain
        least squares on the inliers), so that loosely registered inliers
        near the threshold count less.
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
    min_iterations: int = 8
    confidence: float = 0.999
    min_inliers: int = 8
    seed: int = 0
    refine: bool = True
    refine_iterations: int = 3
    rotation_only: bool = False
    noise_sigma_rad: float | None = None
    rotation_threshold_factor: float = 1.25
    robust_iterations: int = 5
    robust_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.ransac_threshold_rad is not None and not self.ransac_threshold_rad > 0:
            raise ValueError(f"ransac_threshold_rad must be > 0 or None, got {self.ransac_threshold_rad}")
        if not self.ransac_threshold_px > 0:
            raise ValueError(f"ransac_threshold_px must be > 0, got {self.ransac_threshold_px}")
        if self.max_iterations < 1 or self.min_iterations < 0:
            raise ValueError(
                f"expected max_iterations >= 1 and min_iterations >= 0, got "
                f"{self.max_iterations}, {self.min_iterations}")
        if not 0 < self.confidence < 1:
            raise ValueError(f"confidence must be in (0, 1), got {self.confidence}")
        if self.min_inliers < _SAMPLE_ROTATION:
            raise ValueError(f"min_inliers must be >= {_SAMPLE_ROTATION}, got {self.min_inliers}")
        if self.robust_iterations < 0 or not self.robust_scale > 0:
            raise ValueError(f"expected robust_iterations >= 0 and robust_scale > 0, got "
                             f"{self.robust_iterations}, {self.robust_scale}")
        if (self.noise_sigma_rad is not None and not self.noise_sigma_rad > 0) or not self.rotation_threshold_factor > 0:
            raise ValueError(
                "expected noise_sigma_rad > 0 or None and rotation_threshold_factor > 0, got "
                f"{self.noise_sigma_rad}, {self.rotation_threshold_factor}")

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
    """

    success: bool
    reason: str
    n_correspondences: int
    n_inliers: int
    inlier_mask: np.ndarray
    model: str


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross product along the last axis (broadcasting), cheaper than ``np.cross`` on small arrays."""
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=-1)


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
    rotated = np.einsum("kij,nj->kni", rotations, rays_b)
    normal = _cross(translations[:, None, :], rotated)
    norm = np.linalg.norm(normal, axis=-1)
    dot = np.abs(np.einsum("kni,ni->kn", normal, rays_a)) / np.maximum(norm, 1e-300)
    return np.arcsin(np.minimum(dot, 1.0))


def rotation_angles(rays_a: np.ndarray, rays_b: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Angle between ``rays_a`` and ``R_ab @ rays_b`` (radians).

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        Unit rays.
    rotations : (K, 3, 3) ndarray

    Returns
    -------
    (K, N) ndarray
    """
    rotated = np.einsum("kij,nj->kni", rotations, rays_b)
    chord = np.linalg.norm(rotated - rays_a[None], axis=-1)
    return 2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0))


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
    u, _, vt = np.linalg.svd(cov)
    det = np.linalg.det(u @ vt)
    fix = np.ones(u.shape[:-2] + (3,))
    fix[..., 2] = np.sign(np.where(det == 0, 1.0, det))
    return (u * fix[..., None, :]) @ vt


def _needed_iterations(inlier_fraction: float, sample: int, confidence: float) -> float:
    good = inlier_fraction ** sample
    if good <= 0:
        return np.inf
    if good >= 1:
        return 0.0
    return np.log(1.0 - confidence) / np.log(1.0 - good)


def _score(errors: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Inlier counts and truncated-error sums (MSAC) per hypothesis."""
    inliers = errors < threshold
    cost = np.minimum(errors, threshold).sum(axis=-1)
    return inliers.sum(axis=-1), cost


def _ransac_5pt(rays_a, rays_b, options, rng):
    n = len(rays_a)
    best = (None, None, -1, np.inf)
    limit = options.max_iterations
    iteration = 0
    while iteration < limit:
        iteration += 1
        idx = rng.choice(n, _SAMPLE_5PT, replace=False)
        poses = poselib.relpose_5pt(rays_b[idx], rays_a[idx])
        if not poses:
            continue
        rotations = np.stack([p.R for p in poses])
        translations = np.stack([p.t for p in poses])
        count, cost = _score(epipolar_angles(rays_a, rays_b, rotations, translations),
                             options.ransac_threshold_rad)
        k = int(np.lexsort((cost, -count))[0])
        if count[k] > best[2] or (count[k] == best[2] and cost[k] < best[3]):
            best = (rotations[k], translations[k], int(count[k]), float(cost[k]))
            need = _needed_iterations(best[2] / n, _SAMPLE_5PT, options.confidence)
            limit = int(min(options.max_iterations, max(options.min_iterations, np.ceil(need))))
    return best[0], best[1]


def _ransac_rotation(rays_a, rays_b, options, rng):
    n = len(rays_a)
    best = (None, -1, np.inf)
    limit = options.max_iterations
    drawn = 0
    while drawn < limit:
        batch = min(_ROTATION_BATCH, limit - drawn)
        drawn += batch
        first = rng.integers(0, n, size=batch)
        second = (first + rng.integers(1, n, size=batch)) % n
        idx = np.stack([first, second], axis=1)
        rotations = rotation_from_rays(rays_a[idx], rays_b[idx])
        count, cost = _score(rotation_angles(rays_a, rays_b, rotations), options.ransac_threshold_rad)
        k = int(np.lexsort((cost, -count))[0])
        if count[k] > best[1] or (count[k] == best[1] and cost[k] < best[2]):
            best = (rotations[k], int(count[k]), float(cost[k]))
            need = _needed_iterations(best[1] / n, _SAMPLE_ROTATION, options.confidence)
            limit = int(min(options.max_iterations, max(options.min_iterations, np.ceil(need))))
    return best[0]


def _reweighted_rotation(rays_a, rays_b, rotation, scale, iterations):
    """Kabsch rotation re-solved with Cauchy weights ``1 / (1 + (e / scale)^2)`` of the residual angles ``e``."""
    for _ in range(iterations):
        errors = rotation_angles(rays_a, rays_b, rotation[None])[0]
        rotation = rotation_from_rays(rays_a, rays_b, 1.0 / (1.0 + (errors / scale) ** 2))
    return rotation


def _tangent_basis(t: np.ndarray) -> np.ndarray:
    """Two unit vectors orthogonal to unit ``t``, as rows of a (2, 3) array."""
    helper = np.eye(3)[int(np.argmin(np.abs(t)))]
    e1 = np.cross(t, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(t, e1)])


def _symmetric_epipolar_residuals(rays_a, rays_b, rotations, translations):
    """Signed sines of both rays' angles to the epipolar plane, (K, 2N)."""
    rotated = np.einsum("kij,nj->kni", rotations, rays_b)
    t = translations[:, None, :]
    n1 = _cross(t, rotated)
    n2 = _cross(t, rays_a[None])
    r1 = np.einsum("kni,ni->kn", n1, rays_a) / np.maximum(np.linalg.norm(n1, axis=-1), 1e-300)
    r2 = np.einsum("kni,kni->kn", n2, rotated) / np.maximum(np.linalg.norm(n2, axis=-1), 1e-300)
    return np.concatenate([r1, r2], axis=1)


def _refine_5pt(rays_a, rays_b, rotation, translation, iterations):
    """Gauss-Newton on (rotation vector, tangent step of t) with a numeric Jacobian."""
    t = translation / np.linalg.norm(translation)
    step = 1e-7
    for _ in range(iterations):
        basis = _tangent_basis(t)
        params = np.vstack([np.zeros(5), step * np.eye(5)])
        rots = Rotation.from_rotvec(params[:, :3]).as_matrix() @ rotation
        ts = t + params[:, 3:] @ basis
        ts /= np.linalg.norm(ts, axis=1, keepdims=True)
        res = _symmetric_epipolar_residuals(rays_a, rays_b, rots, ts)
        jac = ((res[1:] - res[0]) / step).T
        delta, *_ = np.linalg.lstsq(jac, -res[0], rcond=None)
        cand_rot = Rotation.from_rotvec(delta[:3]).as_matrix() @ rotation
        cand_t = t + delta[3:] @ basis
        cand_t /= np.linalg.norm(cand_t)
        new = _symmetric_epipolar_residuals(rays_a, rays_b, cand_rot[None], cand_t[None])[0]
        old_cost, new_cost = np.sum(res[0] ** 2), np.sum(new ** 2)
        if new_cost > old_cost:
            break
        rotation, t = cand_rot, cand_t
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
    r = r[(r >= 0) & (r < threshold)]
    lower, upper = threshold * 1e-3, threshold * 10.0
    if len(r) < _SAMPLE_ROTATION:
        return threshold / 2.0
    median = float(np.median(r))

    def excess(log_sigma: float) -> float:
        # Truncated Rayleigh CDF at the median minus one half.
        s2 = 2.0 * np.exp(2.0 * log_sigma)
        return float(-np.expm1(-median ** 2 / s2) - 0.5 * -np.expm1(-threshold ** 2 / s2))

    if excess(np.log(lower)) <= 0:
        return lower
    if excess(np.log(upper)) >= 0:
        return upper
    return float(np.exp(brentq(excess, np.log(lower), np.log(upper), xtol=1e-6)))


def _gric(errors: np.ndarray, sigma: float, *, dimension: int, parameters: int) -> float:
    """Torr's geometric robust information criterion of a model (lower is better).

    ``dimension`` is the dimension of the model's manifold in the 4-D space
    of a correspondence (2 for a rotation, 3 for an essential matrix) and
    ``parameters`` its degrees of freedom. Residuals are capped at
    ``2 (4 - dimension)`` in units of the noise variance.
    """
    n = len(errors)
    capped = np.minimum((errors / sigma) ** 2, 2.0 * (4 - dimension)).sum()
    return float(capped + np.log(4.0) * dimension * n + np.log(4.0 * n) * parameters)


def relative_pose_from_rays(rays_a: np.ndarray, rays_b: np.ndarray, *,
                            options: RelativePoseOptions) -> tuple[RelativePose, RelativePoseInfo]:
    """Estimate ``R_ab`` (and the translation direction) from corresponding rays.

    Parameters
    ----------
    rays_a : (N, 3) ndarray
        Unit rays in camera a.
    rays_b : (N, 3) ndarray
        Unit rays in camera b, row i corresponding to ``rays_a[i]``.
    options : RelativePoseOptions, keyword-only

    Returns
    -------
    pose : RelativePose
        Identity rotation and zero translation on failure.
    info : RelativePoseInfo
        Success flag with a reason, inlier mask and the model chosen.
    """
    rays_a = np.asarray(rays_a, dtype=np.float64)
    rays_b = np.asarray(rays_b, dtype=np.float64)
    if rays_a.ndim != 2 or rays_a.shape[1:] != (3,) or rays_a.shape != rays_b.shape:
        raise ValueError(
            f"expected rays_a and rays_b of equal shape (N, 3), got {rays_a.shape} and {rays_b.shape}")
    if options.ransac_threshold_rad is None:
        raise ValueError("ransac_threshold_rad is None; set it or resolve the pixel threshold with "
                         "RelativePoseOptions.resolved(pixel_angle_rad)")
    n = len(rays_a)
    rng = np.random.default_rng(options.seed)
    model = "rotation" if options.rotation_only else "5pt"
    finite = np.all(np.isfinite(rays_a), axis=1) & np.all(np.isfinite(rays_b), axis=1)
    if not finite.all():
        raise ValueError(f"rays must be finite; {int((~finite).sum())} of {n} rows are not")
    needed = max(options.min_inliers, _SAMPLE_ROTATION if options.rotation_only else _SAMPLE_5PT)
    if n < needed:
        info = RelativePoseInfo(False, f"too few correspondences ({n} < {needed})", n, 0,
                                np.zeros(n, dtype=bool), model)
        return RelativePose(), info

    threshold = options.ransac_threshold_rad
    rot_threshold = options.rotation_threshold_factor * threshold
    rot_options = replace(options, ransac_threshold_rad=rot_threshold)
    rotation = _ransac_rotation(rays_a, rays_b, rot_options, rng)
    rot_mask = rotation_angles(rays_a, rays_b, rotation[None])[0] < rot_threshold
    if options.refine and rot_mask.sum() >= _SAMPLE_ROTATION:
        rotation = rotation_from_rays(rays_a[rot_mask], rays_b[rot_mask])
        rot_mask = rotation_angles(rays_a, rays_b, rotation[None])[0] < rot_threshold
    rot_errors = rotation_angles(rays_a, rays_b, rotation[None])[0]
    sigma = options.noise_sigma_rad or noise_sigma_from_residuals(rot_errors[rot_mask], rot_threshold)
    if options.refine and options.robust_iterations and rot_mask.sum() >= _SAMPLE_ROTATION:
        rotation = _reweighted_rotation(rays_a[rot_mask], rays_b[rot_mask], rotation,
                                        options.robust_scale * sigma, options.robust_iterations)
        rot_errors = rotation_angles(rays_a, rays_b, rotation[None])[0]
        rot_mask = rot_errors < rot_threshold
    chosen = ("rotation", rotation, np.zeros(3), rot_mask)
    # GRIC compares the models on the correspondences that either explains: a gross outlier
    # costs the 5-point model less than the rotation model (its residual cap is lower), so
    # counting the outliers of both would hand heavily contaminated pairs to the 5-point model.
    if not options.rotation_only:
        rotation_5pt, translation = _ransac_5pt(rays_a, rays_b, options, rng)
        if rotation_5pt is not None:
            mask = epipolar_angles(rays_a, rays_b, rotation_5pt[None], translation[None])[0] < threshold
            if options.refine and mask.sum() >= _SAMPLE_5PT:
                rotation_5pt, translation = _refine_5pt(rays_a[mask], rays_b[mask], rotation_5pt,
                                                        translation, options.refine_iterations)
            errors_5pt = epipolar_angles(rays_a, rays_b, rotation_5pt[None], translation[None])[0]
            either = rot_mask | (errors_5pt < threshold)
            gric_rotation = _gric(rot_errors[either], sigma, dimension=2, parameters=3)
            if _gric(errors_5pt[either], sigma, dimension=3, parameters=5) < gric_rotation:
                chosen = ("5pt", rotation_5pt, translation / np.linalg.norm(translation),
                          errors_5pt < threshold)

    model, rotation, translation, mask = chosen
    count = int(mask.sum())
    if count < options.min_inliers:
        info = RelativePoseInfo(False, f"too few inliers ({count} < {options.min_inliers})", n,
                                count, mask, model)
        return RelativePose(), info
    pose = RelativePose(rotation=np.asarray(rotation, dtype=np.float64),
                        translation_direction=np.asarray(translation, dtype=np.float64))
    return pose, RelativePoseInfo(True, "", n, count, mask, model)
