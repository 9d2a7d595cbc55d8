"""The two-fold ambiguity of a plane, settled over a sequence.

Convention (as :mod:`ifmi.backend.relative_pose`): ``X_a = R_ab @ X_b + t_ab``.
A plane seen by camera b, ``n_b . X_b = d_b`` with ``d_b > 0``, maps the rays
of b onto those of a by the homography ``H_ab = R_ab + t_ab n_b^T / d_b``:
``rays_a ~ H_ab @ rays_b`` with a positive factor.

A homography has two decompositions ``(R_ab, t_ab / d_b, n_b)`` that put the
plane in front of camera b (Ma, Soatto, Kosecka and Sastry, *An Invitation
to 3-D Vision*, section 5.3.3). For a small motion they swap the roles of the
translation and the normal: the second one (the twin) has its normal along the
true translation, its translation along the true normal, and a rotation off
by about ``|t| / d`` (35 mrad for 5.7 cm at 1.6 m). Both fit every epipolar
constraint of the plane; only the points a wrong twin puts behind the
cameras tell them apart within one pair, and over a narrow view of the plane
(a fisheye looking down at a road) too few do.

A sequence tells them apart. The scene is static, so the true normals of all
pairs, turned into the first camera's frame by the chained orientations, are
one direction; the twins' normals follow the translation direction, which
turns with the trajectory, and the rotation error each twin adds to the
chain turns them further. :func:`resolve_plane_twins` therefore tries both
candidates of the first planar pair as the plane's normal, walks the later
planar pairs in order, takes in each the candidate nearest the normal carried
so far (re-chaining the orientations as it goes), and keeps the hypothesis
whose normals stay closer together, when they do by a clear margin. A pair is planar when a homography
explains its 5-point inliers (Torr's GRIC, or nearly all of them as inliers:
:func:`planar_pair`); other pairs are left alone, and so is a planar pair
whose two candidate normals both lie within the tolerance of the carried one.
On a planar pair the chosen decomposition replaces the 5-point estimate: the
essential matrix of a plane is degenerate, its least-squares fit slides along
the valley between the two decompositions, while the homography is the
plane's own model.

All functions are pure; rotations are ``(3, 3)`` arrays, rays unit ``(N, 3)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ifmi.backend.homography import homography_from_rays, homography_transfer_angles, refitted_homography
from ifmi.backend.relative_pose import epipolar_angles, gric, samples_without_replacement
from ifmi.geometry.rotations import geodesic_angle

__all__ = ["PlaneTwinOptions", "PlaneCandidates", "homography_from_rays", "homography_transfer_angles",
           "robust_homography", "plane_decompositions", "planar_pair", "replaces_estimate", "resolve_plane_twins", "rechained"]

# Correspondences of a homography's minimal sample.
_SAMPLE_HOMOGRAPHY = 4


@dataclass(frozen=True)
class PlaneTwinOptions:
    """Settling the plane twin over a sequence.

    Attributes
    ----------
    enabled : bool
        Examine planar pairs and swap a pair's pose for its twin when the
        sequence's plane normal says so.
    normal_tolerance_rad : float
        Angle (radians) within which a candidate normal agrees with the
        carried one; beyond it a disagreement costs this much (a truncated
        cost, so one bad pair cannot decide). The two candidates' normals lie
        about 90 degrees apart for a motion along the plane (the normal and the
        translation direction); 0.35 rad leaves room for a normal measured
        from a few milliradians of parallax.
    min_plane_share : float
        A pair is planar when the homography fitted to its 5-point inliers
        scores a GRIC no higher than the 5-point model's, or counts at least
        this share of them as its own inliers (the rest may lie off the
        plane). The second test serves pairs of few measurements: with the
        14 to 20 tiles of an iFMI pair GRIC charges the homography's three
        extra parameters more than its tighter constraint saves, even on an
        exact plane.
    agreement_fraction : float
        A planar pair keeps its own 5-point pose when the chosen
        decomposition is the one nearest it and it lies within this fraction
        of the angle between the two decompositions from it
        (:func:`replaces_estimate`).
    min_planar_pairs : int
        Planar pairs a sequence needs before any is changed: with one pair
        both hypotheses are equally consistent.
    ransac_iterations : int
        Samples of the homography fit on a pair's inliers.
    seed : int
        Seed of that sample draw.
    """

    enabled: bool = True
    normal_tolerance_rad: float = 0.35
    min_plane_share: float = 0.95
    agreement_fraction: float = 0.1
    min_planar_pairs: int = 2
    ransac_iterations: int = 200
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.normal_tolerance_rad < math.pi / 2:
            raise ValueError(f"normal_tolerance_rad must lie in (0, pi/2), got {self.normal_tolerance_rad}")
        if not 0.0 <= self.agreement_fraction < 0.5:
            raise ValueError(f"agreement_fraction must lie in [0, 0.5), got {self.agreement_fraction}")
        if not 0.0 < self.min_plane_share <= 1.0:
            raise ValueError(f"min_plane_share must lie in (0, 1], got {self.min_plane_share}")
        if self.min_planar_pairs < 2 or self.ransac_iterations < 1:
            raise ValueError("expected min_planar_pairs >= 2 and ransac_iterations >= 1, got "
                             f"{self.min_planar_pairs}, {self.ransac_iterations}")


@dataclass(frozen=True)
class PlaneCandidates:
    """The two decompositions of a planar pair's homography.

    Attributes
    ----------
    rotations : (2, 3, 3) ndarray
        Candidate ``R_ab``.
    translations : (2, 3) ndarray
        Candidate unit ``t_ab``.
    normals : (2, 3) ndarray
        Candidate unit plane normals ``n_b`` in camera b (``n_b . rays_b > 0``
        on the plane).
    current : int
        Index of the candidate nearest the pair's own pose (by rotation).
    offsets_rad : (2,) ndarray
        Angle (radians) between each candidate's rotation and the pair's own.
    gric_homography, gric_5pt : float
        Both models' GRIC over the pair's inliers (lower is better).
    """

    rotations: np.ndarray
    translations: np.ndarray
    normals: np.ndarray
    current: int
    offsets_rad: np.ndarray
    gric_homography: float
    gric_5pt: float


def robust_homography(rays_a: np.ndarray, rays_b: np.ndarray, *, threshold_rad: float, iterations: int,
                      seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``H_ab`` of the plane most rays lie on: 4-ray samples, the largest consensus, refitted twice.

    The samples are drawn as ``iterations`` calls of ``rng.choice`` would draw them
    (:func:`ifmi.backend.relative_pose.samples_without_replacement`) and fitted and scored
    together; the first sample of the largest consensus wins.

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        Unit rays, N >= 4.
    threshold_rad : float, keyword-only
        Inlier threshold on :func:`homography_transfer_angles`.
    iterations : int, keyword-only
    seed : int, keyword-only

    Returns
    -------
    homography : (3, 3) ndarray
    errors : (N,) ndarray
        Transfer angles (radians) of every ray under it.
    """
    best = homography_from_rays(rays_a, rays_b)
    if iterations > 0:
        picks = samples_without_replacement(np.random.default_rng(seed), len(rays_a), _SAMPLE_HOMOGRAPHY, iterations)
        candidates = homography_from_rays(rays_a[picks], rays_b[picks])
        counts = np.count_nonzero(homography_transfer_angles(candidates, rays_a, rays_b) < threshold_rad, axis=-1)
        best = candidates[int(np.argmax(counts))]
    return refitted_homography(best, rays_a, rays_b, threshold_rad=threshold_rad, refits=2,
                               fit=lambda a, b: _refined_homography(homography_from_rays(a, b), a, b))


def _refined_homography(homography: np.ndarray, rays_a: np.ndarray, rays_b: np.ndarray) -> np.ndarray:
    """``H_ab`` refined to the least squares of the transfer angles (the direct linear transform
    weighs each ray's residual by its own scale), ``H`` normalised to unit Frobenius norm."""
    def residuals(entries):
        mapped = rays_b @ entries.reshape(3, 3).T
        mapped = mapped / np.linalg.norm(mapped, axis=1, keepdims=True)
        mapped = mapped * np.sign(np.sum(mapped * rays_a, axis=1, keepdims=True))
        return (np.cross(mapped, rays_a)).ravel()

    start = homography.ravel() / np.linalg.norm(homography)
    refined = least_squares(residuals, start, method="lm" if 3 * len(rays_a) >= 9 else "trf").x
    return refined.reshape(3, 3) / np.linalg.norm(refined)


def _normalized(homography: np.ndarray, rays_a: np.ndarray, rays_b: np.ndarray) -> np.ndarray:
    """``H`` scaled to a middle singular value of 1 and signed so that ``rays_a . H rays_b > 0`` mostly."""
    scaled = homography / np.linalg.svd(homography, compute_uv=False)[1]
    return scaled if np.sum(np.einsum("ni,ij,nj->n", rays_a, scaled, rays_b)) >= 0 else -scaled


def plane_decompositions(homography: np.ndarray, rays_a: np.ndarray,
                         rays_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The two decompositions ``(R_ab, t_ab / d_b, n_b)`` of ``H_ab`` with the plane in front of b.

    Parameters
    ----------
    homography : (3, 3) ndarray
        ``H_ab`` up to scale and sign.
    rays_a, rays_b : (N, 3) ndarray
        Unit rays on the plane: they fix the sign of ``H`` and which of each
        pair ``(n, t)``, ``(-n, -t)`` has the rays in front (``n_b . rays_b > 0``).

    Returns
    -------
    rotations : (2, 3, 3) ndarray
    translations : (2, 3) ndarray
        ``t_ab / d_b`` (the plane's distance from b is the unit).
    normals : (2, 3) ndarray
        Unit ``n_b``.
    None
        When the homography is a rotation (no translation to decompose).
    """
    h = _normalized(homography, rays_a, rays_b)
    _, singular, vt = np.linalg.svd(h.T @ h)
    s1, s3 = singular[0], singular[2]  # squares of H's singular values; the middle one is 1
    if s1 - s3 < 1e-12:
        return None
    v = vt.T * np.sign(np.linalg.det(vt))
    v1, v2, v3 = v[:, 0], v[:, 1], v[:, 2]
    rotations, translations, normals = [], [], []
    for sign in (1.0, -1.0):
        u = (math.sqrt(max(1.0 - s3, 0.0)) * v1 + sign * math.sqrt(max(s1 - 1.0, 0.0)) * v3) / math.sqrt(s1 - s3)
        frame_u = np.stack([v2, u, np.cross(v2, u)], axis=1)
        frame_w = np.stack([h @ v2, h @ u, np.cross(h @ v2, h @ u)], axis=1)
        rotation = frame_w @ frame_u.T
        normal = np.cross(v2, u)
        translation = (h - rotation) @ normal
        if np.sum(rays_b @ normal > 0) < len(rays_b) / 2:
            normal, translation = -normal, -translation
        rotations.append(rotation)
        translations.append(translation)
        normals.append(normal / np.linalg.norm(normal))
    return np.array(rotations), np.array(translations), np.array(normals)


def planar_pair(rays_a: np.ndarray, rays_b: np.ndarray, rotation_ab: np.ndarray, translation_ab: np.ndarray, *,
                noise_sigma_rad: float, threshold_rad: float, rays_per_measurement: int = 1,
                options: PlaneTwinOptions = PlaneTwinOptions()) -> PlaneCandidates | None:
    """The two plane decompositions of a 5-point pair whose inliers a plane explains, else None.

    Parameters
    ----------
    rays_a, rays_b : (N, 3) ndarray
        The 5-point model's inlier rays.
    rotation_ab : (3, 3) ndarray
        Its ``R_ab``.
    translation_ab : (3,) ndarray
        Its unit ``t_ab``.
    noise_sigma_rad : float, keyword-only
        Ray noise (radians per axis) the two models' GRIC weigh residuals with.
    threshold_rad : float, keyword-only
        Inlier threshold of the homography fit (the back end's RANSAC threshold).
    rays_per_measurement : int, keyword-only
        Rays that share one error count as one observation.
    options : PlaneTwinOptions, keyword-only

    Returns
    -------
    PlaneCandidates or None
        None when a homography explains the rays worse than the 5-point model
        (Torr's GRIC) and counts fewer than ``options.min_plane_share`` of them
        as inliers, the rays are too few, or the two decompositions' rotations
        differ by no more than ``noise_sigma_rad`` (a translation too small
        against the noise: choosing between them cannot matter, and their
        normals are noise).
    """
    if len(rays_a) < max(2 * _SAMPLE_HOMOGRAPHY, 2 * rays_per_measurement) or not noise_sigma_rad > 0:
        return None
    homography, transfer = robust_homography(rays_a, rays_b, threshold_rad=threshold_rad,
                                             iterations=options.ransac_iterations, seed=options.seed)
    epipolar = epipolar_angles(rays_a, rays_b, rotation_ab[None], translation_ab[None])[0]
    gric_h = gric(transfer, noise_sigma_rad, dimension=2, parameters=8, group=rays_per_measurement)
    gric_e = gric(epipolar, noise_sigma_rad, dimension=3, parameters=5, group=rays_per_measurement)
    on_plane = transfer < threshold_rad
    explained = gric_h <= gric_e or on_plane.mean() >= options.min_plane_share
    if not explained or on_plane.sum() < _SAMPLE_HOMOGRAPHY:
        return None
    decomposed = plane_decompositions(homography, rays_a[on_plane], rays_b[on_plane])
    if decomposed is None:
        return None
    rotations, translations, normals = decomposed
    lengths = np.linalg.norm(translations, axis=1, keepdims=True)
    if np.any(lengths == 0):
        return None
    if geodesic_angle(rotations[:1], rotations[1:])[0] <= noise_sigma_rad:
        return None  # the twins differ by less than one ray's noise: nothing to choose, and their normals are noise
    offsets = geodesic_angle(rotations, np.broadcast_to(rotation_ab, rotations.shape))
    return PlaneCandidates(rotations, translations / lengths, normals, int(np.argmin(offsets)), offsets, gric_h, gric_e)


def replaces_estimate(candidates: PlaneCandidates, choice: int, *,
                      options: PlaneTwinOptions = PlaneTwinOptions()) -> bool:
    """Whether the chosen decomposition replaces the pair's 5-point pose.

    It does unless it is the decomposition nearest that pose and the pose lies
    within ``options.agreement_fraction`` of the angle between the two
    decompositions from it: the essential matrix, fitted to every inlier on
    and off the plane, then is the better estimate of the same solution.
    """
    separation = float(geodesic_angle(candidates.rotations[:1], candidates.rotations[1:])[0])
    agrees = choice == candidates.current and candidates.offsets_rad[choice] <= options.agreement_fraction * separation
    return not agrees


def _angle(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.arccos(np.clip(np.dot(u, v), -1.0, 1.0)))


def _walk(first: int, planar: dict, references: np.ndarray, relative: np.ndarray,
          options: PlaneTwinOptions) -> tuple[float, dict]:
    """Cost and choices of the hypothesis that candidate ``first`` of the first planar pair is the true one.

    Frames are chained in order (``R_0k = R_0r @ R_rk``); at each planar pair the
    candidate whose normal, turned into frame 0 by its own rotation, lies nearest
    the mean of the normals chosen so far is taken (the current one when both lie
    within ``tolerance`` of it), and its angle to that mean, capped at
    ``tolerance``, is the cost.
    """
    tolerance = options.normal_tolerance_rad
    rotations = np.empty((len(references), 3, 3))
    rotations[0] = np.eye(3)
    normal_sum, cost, choices = None, 0.0, {}
    for k in range(1, len(references)):
        pair = planar.get(k)
        rotation_rk = relative[k]
        if pair is not None:
            world = np.einsum("ij,njk,nk->ni", rotations[references[k]], pair.rotations, pair.normals)
            if normal_sum is None:
                choice = first
            else:
                mean = normal_sum / np.linalg.norm(normal_sum)
                angles = np.array([_angle(w, mean) for w in world])
                choice = pair.current if np.all(angles < tolerance) else int(np.argmin(angles))
                cost += min(float(angles[choice]), tolerance)
            choices[k] = choice
            normal_sum = world[choice] if normal_sum is None else normal_sum + world[choice]
            if replaces_estimate(pair, choice, options=options):
                rotation_rk = pair.rotations[choice]
        rotations[k] = rotations[references[k]] @ rotation_rk
    return cost, choices


def resolve_plane_twins(references: np.ndarray, relative: np.ndarray, planar: dict, *,
                        options: PlaneTwinOptions = PlaneTwinOptions()) -> dict:
    """Which candidate of each planar pair the sequence's plane normal picks.

    Parameters
    ----------
    references : (K,) int ndarray
        Frame each frame is chained from (``references[k] < k``; frame 0 refers to itself).
    relative : (K, 3, 3) ndarray
        Each frame's ``R_rk`` from its reference as estimated (identity for frame 0).
    planar : dict of int to PlaneCandidates
        The planar pairs by their frame ``k`` (camera b).
    options : PlaneTwinOptions, keyword-only

    Returns
    -------
    dict of int to int
        The chosen candidate of each planar pair; empty when the pairs are
        fewer than ``options.min_planar_pairs`` (nothing is changed then).
        Both hypotheses for the first planar pair are walked (:func:`_walk`);
        the one of lower cost wins when it is cheaper by at least
        ``options.normal_tolerance_rad`` (one pair's whole disagreement), else
        the sequence cannot tell them apart and nothing is changed either.
    """
    if len(planar) < options.min_planar_pairs:
        return {}
    first = planar[min(planar)]
    walks = [_walk(candidate, planar, references, relative, options)
             for candidate in (first.current, 1 - first.current)]
    (cost_current, current), (cost_other, other) = walks
    if abs(cost_current - cost_other) < options.normal_tolerance_rad:
        return {}
    return other if cost_other < cost_current else current


def rechained(rotations: np.ndarray, positions: np.ndarray, references: np.ndarray,
              replaced: dict) -> tuple[np.ndarray, np.ndarray]:
    """A chained trajectory with some frames' relative poses replaced.

    Parameters
    ----------
    rotations : (K, 3, 3) ndarray
        ``R_0k`` as chained (``R_0k = R_0r @ R_rk``).
    positions : (K, 3) ndarray
        Positions as chained (``p_k = p_r + (k - r) R_0r t_rk``, unit steps per frame).
    references : (K,) int ndarray
        Each frame's reference ``r`` (``r < k``; frame 0 refers to itself).
    replaced : dict of int to tuple of ((3, 3) ndarray, (3,) ndarray)
        New ``(R_rk, unit t_rk)`` of some frames ``k``.

    Returns
    -------
    rotations : (K, 3, 3) ndarray
    positions : (K, 3) ndarray
        Every frame re-chained from its reference with its own relative pose,
        or the replaced one.
    """
    new_rotations, new_positions = rotations.copy(), positions.copy()
    for k in range(1, len(rotations)):
        r = references[k]
        rotation_rk = rotations[r].T @ rotations[k]
        step_r = rotations[r].T @ (positions[k] - positions[r])
        if k in replaced:
            rotation_rk, step_r = replaced[k][0], (k - r) * replaced[k][1]
        new_rotations[k] = new_rotations[r] @ rotation_rk
        new_positions[k] = new_positions[r] + new_rotations[r] @ step_r
    return new_rotations, new_positions
