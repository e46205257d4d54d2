"""SerialTrack-class linking of two 3-D particle clouds (reference → deformed).

The linker (:func:`link_pair`) follows the iterative scheme of SerialTrack (Yang et al.,
"SerialTrack: ScalE and Rotation Invariant Augmented Lagrangian Particle Tracking",
SoftwareX 19, 101204, 2022), which alternates a *local* matching step with a *global*
regularised displacement fit:

1. **Bootstrap** (no initial guess). Both clouds are described by rotation-invariant
   neighbourhood-topology descriptors (:mod:`track.features`) and matched globally by nearest
   descriptor with a ratio test and a mutual-consistency check, once in raw coordinates and
   once after moment normalisation (each cloud whitened by its own covariance, which turns any
   homogeneous stretch or shear into a rotation). The candidate set with the larger RANSAC
   affine consensus (:func:`track.outliers.ransac_affine`) wins; its consensus, cleaned by the
   normalised median test, gives a stiff affine first estimate of the field. Nothing here
   assumes small displacements.
2. **Iterations**. The reference is warped by the current field and matched to the deformed
   cloud with a matcher chosen from the state: plain mutual nearest neighbour once the warp
   error is a small fraction of the particle spacing, otherwise alternately a local
   topology-descriptor match or a histogram-of-displacement vote (Janke et al., SoftwareX 11,
   100413, 2020). The neighbour count k shrinks from ``n_neighbors_max`` to
   ``n_neighbors_min``.
3. Each candidate set is cleaned with the normalised median test (Westerweel & Scarano,
   Exp. Fluids 39, 2005) and a global field is fitted on a regular grid
   (:func:`track.regularize.fit_field`, direct or ADMM), stiff at first and relaxed to
   ``smoothness``.
4. The loop stops when the field update and the match count stall.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from track.errors import InputError
from track.features import (
    cloud_scale_um,
    moment_normalization,
    topology_descriptors,
)
from track.outliers import normalized_median_test, ransac_affine
from track.regularize import METHODS, AffineDisplacement, fit_affine, fit_field

logger = logging.getLogger(__name__)

MIN_PARTICLES = 4


@dataclass(frozen=True)
class LinkSettings:
    """Parameters of :func:`link_pair`. Lengths in µm; ``None`` means "derive from the data".

    Attributes
    ----------
    n_neighbors_max, n_neighbors_min : int
        Neighbour count k of the first and last iterations (paper Table 1: max 16/5/10);
        k is used by the histogram vote, the local topology search and the median test.
    descriptor_size : int
        Neighbours in a topology descriptor (≥ 2).
    descriptor_ratio : float
        Ratio test of descriptor matches: best distance < ratio × second best (0 < r ≤ 1).
    outlier_threshold : float
        Normalised-median-test threshold (paper: 3).
    outlier_eps_um : float or None
        Median-test noise level ε; default 0.02 × the mean particle spacing.
    max_iterations : int
        Iteration cap (bootstrap included).
    stall_tolerance : float
        Stop when the RMS field update is below this fraction of the mean spacing and the
        match count no longer changes.
    regularization : {"gridded", "admm"}
        Global field solver (:func:`track.regularize.fit_field`).
    grid_spacing_um : float or None
        Node spacing of the field grid; default 2 × the mean particle spacing.
    smoothness : float
        Dimensionless smoothness weight of the final field fits.
    stiffness_factor : float
        The first gridded fit uses ``smoothness × stiffness_factor``; it falls ×10 per
        iteration down to ``smoothness``.
    hist_bin_um : float or None
        Tolerance of the histogram-of-displacement vote; default 0.3 × mean spacing.
    search_radius_um : float or None
        Search radius of the warped matchers; default adapts to the warp error
        (between 1 and 3 mean spacings).
    nn_max_distance_um : float or None
        Largest accepted nearest-neighbour residual; default adapts to the warp error
        (5 × its RMS, clipped to 0.1 … 0.5 mean spacings).
    nn_ratio : float
        Nearest / second-nearest distance ratio a nearest-neighbour match must beat.
    nn_switch : float
        Warp error (fraction of the mean spacing) below which nearest neighbour is used.
    ransac_threshold_um : float or None
        Consensus radius of the affine bootstrap; default 1 mean spacing.
    bootstrap_max_particles : int
        Reference particles (random subset) used by the global bootstrap match.
    seed : int
        Seed of the RANSAC sampler and of the bootstrap subset.
    """

    n_neighbors_max: int = 16
    n_neighbors_min: int = 5
    descriptor_size: int = 5
    descriptor_ratio: float = 0.8
    outlier_threshold: float = 3.0
    outlier_eps_um: float | None = None
    max_iterations: int = 20
    stall_tolerance: float = 1e-3
    regularization: str = "gridded"
    grid_spacing_um: float | None = None
    smoothness: float = 1.0
    stiffness_factor: float = 100.0
    hist_bin_um: float | None = None
    search_radius_um: float | None = None
    nn_max_distance_um: float | None = None
    nn_ratio: float = 0.5
    nn_switch: float = 0.15
    ransac_threshold_um: float | None = None
    bootstrap_max_particles: int = 3000
    seed: int = 0

    def __post_init__(self) -> None:
        if self.n_neighbors_min < 3:
            raise InputError(f"n_neighbors_min must be ≥ 3, got {self.n_neighbors_min}")
        if self.n_neighbors_max < self.n_neighbors_min:
            raise InputError(
                f"n_neighbors_max ({self.n_neighbors_max}) must be ≥ n_neighbors_min "
                f"({self.n_neighbors_min})"
            )
        if self.descriptor_size < 2:
            raise InputError(f"descriptor_size must be ≥ 2, got {self.descriptor_size}")
        for name in ("descriptor_ratio", "nn_ratio"):
            v = getattr(self, name)
            if not 0 < v <= 1:
                raise InputError(f"{name} must be in (0, 1], got {v}")
        for name in ("outlier_threshold", "stall_tolerance", "nn_switch"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be finite and > 0, got {v}")
        for name in ("smoothness",):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be finite and ≥ 0, got {v}")
        if not (np.isfinite(self.stiffness_factor) and self.stiffness_factor >= 1):
            raise InputError(f"stiffness_factor must be ≥ 1, got {self.stiffness_factor}")
        if self.bootstrap_max_particles < MIN_PARTICLES:
            raise InputError(
                f"bootstrap_max_particles must be ≥ {MIN_PARTICLES}, "
                f"got {self.bootstrap_max_particles}"
            )
        if self.max_iterations < 1:
            raise InputError(f"max_iterations must be ≥ 1, got {self.max_iterations}")
        if self.regularization not in METHODS:
            raise InputError(
                f"regularization must be one of {METHODS}, got {self.regularization!r}"
            )
        for name in (
            "outlier_eps_um",
            "grid_spacing_um",
            "hist_bin_um",
            "search_radius_um",
            "nn_max_distance_um",
            "ransac_threshold_um",
        ):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be None or finite and > 0, got {v}")

    def n_neighbors(self, iteration: int) -> int:
        """Neighbour count k of 1-based ``iteration``: halves the excess over the minimum."""
        excess = self.n_neighbors_max - self.n_neighbors_min
        return self.n_neighbors_min + round(excess * 0.5 ** (iteration - 1))


@dataclass(frozen=True)
class IterationRecord:
    """What one iteration did (counts are numbers of matches)."""

    iteration: int
    matcher: str
    n_neighbors: int
    n_candidates: int
    n_matches: int
    n_outliers: int
    update_rms_um: float
    residual_rms_um: float
    seconds: float


@dataclass(frozen=True)
class LinkResult:
    """Outcome of :func:`link_pair`.

    Attributes
    ----------
    matches : ndarray of int, shape (K, 2)
        0-based rows ``[row_ref, row_def]`` of matched particles.
    displacement_um : ndarray, shape (K, 3)
        ``def − ref`` of each match in µm.
    tracking_ratio : float
        K / min(N, M).
    iterations : int
        Iterations run (bootstrap included).
    history : tuple of IterationRecord
        Per-iteration counts and field updates.
    displacement_field : callable
        ``field(xyz_um (P, 3)) -> (P, 3)`` µm, the final regularised displacement at
        reference-configuration points.
    ok : bool
        False when no consistent set of matches was found; ``reason`` says why, ``matches``
        is empty and ``displacement_field`` must not be used.
    reason : str
        Empty when ``ok``.
    mean_spacing_um : float
        Mean nearest-neighbour distance of the reference cloud.
    """

    matches: np.ndarray
    displacement_um: np.ndarray
    tracking_ratio: float
    iterations: int
    history: tuple[IterationRecord, ...]
    displacement_field: Callable[[np.ndarray], np.ndarray]
    ok: bool = True
    reason: str = ""
    mean_spacing_um: float = float("nan")
    seconds: float = field(default=0.0, compare=False)


# ----------------------------------------------------------------------------- validation


def _validate_cloud(name: str, xyz) -> np.ndarray:
    try:
        a = np.asarray(xyz, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric (N, 3) array of µm coordinates: {exc}") from exc
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{name} must have shape (N, 3) (x_um, y_um, z_um), got {a.shape}")
    if a.shape[0] == 0:
        raise InputError(f"{name} is empty: no particles to track")
    bad = ~np.all(np.isfinite(a), axis=1)
    if np.any(bad):
        rows = np.flatnonzero(bad)
        raise InputError(
            f"{name} holds NaN or infinite coordinates in {rows.size} row(s), first rows "
            f"{rows[:5].tolist()}"
        )
    if a.shape[0] < MIN_PARTICLES:
        raise InputError(f"{name} has {a.shape[0]} particles; need at least {MIN_PARTICLES}")
    if np.linalg.matrix_rank(a - a.mean(axis=0), tol=1e-9 * max(np.ptp(a), 1e-300)) < 3:
        raise InputError(f"{name} is coplanar or collinear; 3-D tracking needs a 3-D cloud")
    return a


# ------------------------------------------------------------------------------- matchers


def match_descriptors_global(
    desc_ref: np.ndarray, desc_def: np.ndarray, ratio: float
) -> np.ndarray:
    """Mutual nearest descriptors passing a ratio test, over the whole clouds.

    Parameters
    ----------
    desc_ref, desc_def : ndarray, shape (N, D), (M, D)
        Descriptors (:func:`track.features.topology_descriptors`).
    ratio : float
        Best descriptor distance must be < ``ratio`` × the second best.

    Returns
    -------
    ndarray of int, shape (K, 2)
        ``[row_ref, row_def]`` candidates.
    """
    d, i = cKDTree(desc_def).query(desc_ref, 2, workers=-1)
    _, back = cKDTree(desc_ref).query(desc_def, 1, workers=-1)
    rows = np.arange(desc_ref.shape[0])
    ok = (d[:, 0] < ratio * d[:, 1]) & (back[i[:, 0]] == rows)
    return np.column_stack([rows[ok], i[ok, 0]])


def _one_to_one(pairs: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Keep, for every deformed row claimed more than once, the lowest-cost pair."""
    if pairs.shape[0] == 0:
        return pairs
    order = np.lexsort((cost, pairs[:, 1]))
    p = pairs[order]
    first = np.ones(p.shape[0], dtype=bool)
    first[1:] = p[1:, 1] != p[:-1, 1]
    return p[first]


def match_nearest(
    warped_ref: np.ndarray, def_xyz: np.ndarray, max_distance_um: float, ratio: float
) -> np.ndarray:
    """Mutual nearest neighbours within ``max_distance_um`` passing a distance-ratio test.

    Returns ``[row_ref, row_def]`` pairs, shape (K, 2).
    """
    k = 2 if def_xyz.shape[0] > 1 else 1
    d, i = cKDTree(def_xyz).query(warped_ref, k)
    d, i = d.reshape(len(d), -1), i.reshape(len(i), -1)
    _, back = cKDTree(warped_ref).query(def_xyz, 1)
    rows = np.arange(warped_ref.shape[0])
    ok = (d[:, 0] <= max_distance_um) & (back[i[:, 0]] == rows)
    if k == 2:
        ok &= d[:, 0] < ratio * d[:, 1]
    return np.column_stack([rows[ok], i[ok, 0]])


def _candidates(warped_ref, def_xyz, k, radius_um):
    k = min(k, def_xyz.shape[0])
    d, i = cKDTree(def_xyz).query(warped_ref, k, distance_upper_bound=radius_um)
    return d.reshape(len(d), -1), i.reshape(len(i), -1)


def match_topology_local(
    warped_ref: np.ndarray,
    def_xyz: np.ndarray,
    n_candidates: int,
    radius_um: float,
    descriptor_size: int,
    ratio: float,
) -> np.ndarray:
    """Best topology-descriptor match among the deformed particles near each warped one.

    Descriptors of the warped reference and of the deformed cloud are compared for the
    ``n_candidates`` deformed particles within ``radius_um`` of each warped position; the
    best must beat ``ratio`` × the second best. Returns (K, 2) ``[row_ref, row_def]``.
    """
    n_core = min(descriptor_size, warped_ref.shape[0] - 1, def_xyz.shape[0] - 1)
    da = topology_descriptors(warped_ref, n_core)
    db = topology_descriptors(def_xyz, n_core)
    dist, idx = _candidates(warped_ref, def_xyz, n_candidates, radius_um)
    valid = np.isfinite(dist)
    safe = np.where(valid, idx, 0)
    cost = np.linalg.norm(db[safe] - da[:, None, :], axis=-1)
    cost[~valid] = np.inf
    order = np.argsort(cost, axis=1)
    best = np.take_along_axis(cost, order[:, :1], axis=1)[:, 0]
    second = (
        np.take_along_axis(cost, order[:, 1:2], axis=1)[:, 0]
        if cost.shape[1] > 1
        else np.full(best.shape, np.inf)
    )
    ok = np.isfinite(best) & (best < ratio * second)
    rows = np.flatnonzero(ok)
    pairs = np.column_stack([rows, safe[rows, order[rows, 0]]])
    return _one_to_one(pairs, best[rows])


def match_displacement_histogram(
    warped_ref: np.ndarray,
    def_xyz: np.ndarray,
    n_neighbors: int,
    radius_um: float,
    bin_um: float,
    n_candidates: int = 8,
    min_votes: int = 3,
) -> np.ndarray:
    """Histogram-of-displacement vote among neighbouring particles.

    Each candidate displacement ``d = def_c − warped_a`` of particle ``a`` (deformed particles
    within ``radius_um``) earns one vote from every one of ``a``'s ``n_neighbors`` nearest
    reference neighbours that has a candidate displacement within ``bin_um`` of ``d``. The
    candidate with the most votes wins if it has ≥ ``min_votes`` and is unique.
    Returns (K, 2) ``[row_ref, row_def]``.
    """
    n = warped_ref.shape[0]
    dist, idx = _candidates(warped_ref, def_xyz, n_candidates, radius_um)
    valid = np.isfinite(dist)
    safe = np.where(valid, idx, 0)
    disp = def_xyz[safe] - warped_ref[:, None, :]
    disp[~valid] = np.nan
    k = min(n_neighbors, n - 1)
    _, nb = cKDTree(warped_ref).query(warped_ref, k + 1)
    nb = nb[:, 1:]
    votes = np.zeros(dist.shape, dtype=np.int32)
    chunk = max(1, 200_000 // max(1, k * dist.shape[1] ** 2))
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        own = disp[s:e]  # (c, C, 3)
        other = disp[nb[s:e]]  # (c, k, C, 3)
        diff = other[:, :, None, :, :] - own[:, None, :, None, :]  # (c, k, C, C, 3)
        close = np.nansum(diff**2, axis=-1) < bin_um**2
        close &= np.all(np.isfinite(diff), axis=-1)
        votes[s:e] = np.any(close, axis=3).sum(axis=1)
    votes[~valid] = -1
    order = np.argsort(-votes, axis=1, kind="stable")
    best = np.take_along_axis(votes, order[:, :1], axis=1)[:, 0]
    second = (
        np.take_along_axis(votes, order[:, 1:2], axis=1)[:, 0]
        if votes.shape[1] > 1
        else np.full(n, -1)
    )
    ok = (best >= min_votes) & (best > second)
    rows = np.flatnonzero(ok)
    pairs = np.column_stack([rows, safe[rows, order[rows, 0]]])
    return _one_to_one(pairs, -best[rows].astype(float))


# ------------------------------------------------------------------------------- the loop


def _robust_rms(residual: np.ndarray) -> float:
    """RMS of residual vectors estimated from their median squared length (Gaussian)."""
    if residual.shape[0] == 0:
        return float("inf")
    return float(np.sqrt(np.median(np.sum(residual**2, axis=1)) * 3.0 / 2.366))


def _mean_spacing(xyz: np.ndarray) -> float:
    d, _ = cKDTree(xyz).query(xyz, 2)
    return float(np.mean(d[:, 1]))


def _clean(ref, dfm, pairs, k, settings, eps_um, predicted):
    """Median-test the residuals of ``pairs`` w.r.t. the predicted (warped) positions.

    Testing residuals rather than raw displacements keeps particles on the border of a
    strongly rotating or stretching region, whose neighbours all lie on one side.
    """
    if pairs.shape[0] == 0:
        return pairs
    keep = normalized_median_test(
        ref[pairs[:, 0]],
        dfm[pairs[:, 1]] - predicted[pairs[:, 0]],
        n_neighbors=k,
        threshold=settings.outlier_threshold,
        eps_um=eps_um,
    )
    return pairs[keep]


def _bootstrap(ref, dfm, settings, spacing, eps_um):
    """Global topology match + affine consensus. Returns (field, pairs, n_candidates, label)."""
    n_core = min(settings.descriptor_size, ref.shape[0] - 1, dfm.shape[0] - 1)
    scale = cloud_scale_um(ref)
    # A subset of reference particles suffices for a consensus and keeps the global
    # descriptor search fast for large clouds; the mutual check runs against that subset.
    rng = np.random.default_rng(settings.seed)
    sub = np.arange(ref.shape[0])
    if sub.size > settings.bootstrap_max_particles:
        sub = np.sort(rng.choice(sub, settings.bootstrap_max_particles, replace=False))
    views = [("topology", ref, dfm)]
    try:
        na = moment_normalization(ref, scale)
        nb = moment_normalization(dfm, scale)
        views.append(("topology-moment", na.apply(ref), nb.apply(dfm)))
    except InputError:
        logger.debug("moment normalisation skipped: degenerate cloud")
    thr = settings.ransac_threshold_um or spacing
    min_inl = max(4, min(8, int(0.5 * min(ref.shape[0], dfm.shape[0]))))
    best = None
    for label, a, b in views:
        cand = match_descriptors_global(
            topology_descriptors(a, n_core)[sub],
            topology_descriptors(b, n_core),
            settings.descriptor_ratio,
        )
        cand[:, 0] = sub[cand[:, 0]]
        fit = ransac_affine(
            ref[cand[:, 0]], dfm[cand[:, 1]], thr, seed=settings.seed, min_inliers=min_inl
        )
        n_inl = -1 if fit is None else int(fit[1].sum())
        logger.debug("bootstrap %s: %d candidates, %d agree", label, cand.shape[0], max(n_inl, 0))
        if fit is not None and (best is None or n_inl > best[0]):
            best = (n_inl, label, cand[fit[1]], cand.shape[0], fit[0])
        if best is not None and best[0] >= 0.3 * min(sub.size, dfm.shape[0]):
            break  # overwhelming consensus already
    if best is None or best[0] < 0.3 * min(sub.size, dfm.shape[0]):
        # Small-motion hypothesis: increments well below the particle spacing (the usual case
        # at high frame rates) pair nearest neighbours of the unwarped clouds. It rescues
        # sparse, noisy clouds whose topology descriptors disagree (a few tens of particles
        # with spurious or missing detections); the affine consensus still has to agree.
        cand = match_nearest(ref, dfm, 0.5 * spacing, settings.nn_ratio)
        if cand.shape[0] >= min_inl:
            fit = ransac_affine(
                ref[cand[:, 0]], dfm[cand[:, 1]], thr, seed=settings.seed, min_inliers=min_inl
            )
            n_inl = -1 if fit is None else int(fit[1].sum())
            logger.debug("bootstrap nearest: %d candidates, %d agree", cand.shape[0], max(n_inl, 0))
            if fit is not None and (best is None or n_inl > best[0]):
                best = (n_inl, "nearest", cand[fit[1]], cand.shape[0], fit[0])
    if best is None:
        return None
    _, label, pairs, n_cand, aff0 = best
    pairs = _clean(ref, dfm, pairs, settings.n_neighbors_max, settings, eps_um, ref + aff0(ref))
    if pairs.shape[0] < 4:
        return None
    aff = fit_affine(ref[pairs[:, 0]], dfm[pairs[:, 1]] - ref[pairs[:, 0]])
    return aff, pairs, n_cand, label


def _fit(ref, dfm, pairs, bounds, settings, grid_um, weight):
    x = ref[pairs[:, 0]]
    u = dfm[pairs[:, 1]] - x
    if pairs.shape[0] < 8:
        return fit_affine(x, u)
    return fit_field(x, u, bounds, grid_um, settings.regularization, weight)


def _failed(reason: str, spacing: float, history, t0: float) -> LinkResult:
    logger.warning("link_pair failed: %s", reason)
    zero = AffineDisplacement(np.eye(3), np.zeros(3), np.zeros(3))
    return LinkResult(
        matches=np.zeros((0, 2), dtype=np.int64),
        displacement_um=np.zeros((0, 3)),
        tracking_ratio=0.0,
        iterations=len(history),
        history=tuple(history),
        displacement_field=zero,
        ok=False,
        reason=reason,
        mean_spacing_um=spacing,
        seconds=time.perf_counter() - t0,
    )


def link_pair(
    ref_xyz,
    def_xyz,
    settings: LinkSettings | None = None,
    *,
    initial_guess: Callable[[np.ndarray], np.ndarray] | None = None,
) -> LinkResult:
    """Link particles of a reference and a deformed 3-D cloud (SerialTrack-class).

    Parameters
    ----------
    ref_xyz : array_like, shape (N, 3)
        Reference particle centres (x_um, y_um, z_um), N ≥ 4.
    def_xyz : array_like, shape (M, 3)
        Deformed particle centres in µm, M ≥ 4; rows in any order, particles may appear or
        disappear.
    settings : LinkSettings, optional
        Parameters; defaults when None.
    initial_guess : callable, optional
        ``u(xyz_um (P, 3)) -> (P, 3)`` µm displacement estimate at reference points (e.g.
        the previous increment's field). Replaces the global topology bootstrap.

    Returns
    -------
    LinkResult
        ``ok=False`` with a ``reason`` when no consistent matches exist (e.g. unrelated
        clouds); never a silently wrong field.

    Raises
    ------
    InputError
        Empty clouds, fewer than 4 particles, NaN/inf coordinates, wrong shapes, coplanar
        clouds, or an ``initial_guess`` that returns a wrong shape or non-finite values.
    """
    t0 = time.perf_counter()
    settings = settings or LinkSettings()
    if not isinstance(settings, LinkSettings):
        raise InputError(f"settings must be a LinkSettings, got {type(settings).__name__}")
    ref = _validate_cloud("ref_xyz", ref_xyz)
    dfm = _validate_cloud("def_xyz", def_xyz)
    spacing = _mean_spacing(ref)
    eps_um = settings.outlier_eps_um or 0.02 * spacing
    grid_um = settings.grid_spacing_um or 2.0 * spacing
    pad = 1e-6 * max(np.ptp(ref), 1.0)
    bounds = np.column_stack([ref.min(axis=0) - pad, ref.max(axis=0) + pad])
    n_min = min(ref.shape[0], dfm.shape[0])
    history: list[IterationRecord] = []

    pairs = np.zeros((0, 2), dtype=np.int64)
    if initial_guess is None:
        ts = time.perf_counter()
        boot = _bootstrap(ref, dfm, settings, spacing, eps_um)
        if boot is None:
            return _failed(
                "no consistent set of topology matches (bootstrap failed)", spacing, history, t0
            )
        fld, pairs, n_cand, label = boot
        resid = dfm[pairs[:, 1]] - ref[pairs[:, 0]] - fld(ref[pairs[:, 0]])
        warp_err = _robust_rms(resid)
        history.append(
            IterationRecord(
                1,
                label,
                settings.n_neighbors_max,
                n_cand,
                int(pairs.shape[0]),
                n_cand - int(pairs.shape[0]),
                float("nan"),
                warp_err,
                time.perf_counter() - ts,
            )
        )
        start = 2
    else:
        fld = initial_guess
        test = np.asarray(fld(ref[:1]), dtype=float)
        if test.shape != (1, 3) or not np.all(np.isfinite(test)):
            raise InputError(
                "initial_guess must map (P, 3) µm points to finite (P, 3) µm displacements"
            )
        warp_err = float("inf")
        start = 1

    prev_u = np.asarray(fld(ref), dtype=float)
    stalled = 0
    for it in range(start, settings.max_iterations + 1):
        ts = time.perf_counter()
        k = settings.n_neighbors(it)
        warped = ref + prev_u
        radius = settings.search_radius_um or float(np.clip(4.0 * warp_err, spacing, 3.0 * spacing))
        if warp_err < settings.nn_switch * spacing:
            matcher = "nearest"
            max_d = settings.nn_max_distance_um or float(
                np.clip(5.0 * warp_err, 0.1 * spacing, 0.5 * spacing)
            )
            cand = match_nearest(warped, dfm, max_d, settings.nn_ratio)
        elif it % 2 == 0 or it == start:
            matcher = "topology-local"
            cand = match_topology_local(
                warped, dfm, max(k, 8), radius, settings.descriptor_size, settings.descriptor_ratio
            )
        else:
            matcher = "histogram"
            cand = match_displacement_histogram(
                warped, dfm, k, radius, settings.hist_bin_um or 0.3 * spacing
            )
        new_pairs = _clean(ref, dfm, cand, k, settings, eps_um, warped)
        if new_pairs.shape[0] < 4:
            if pairs.shape[0] >= 4:
                logger.debug(
                    "iteration %d (%s) found too few matches; keeping previous", it, matcher
                )
                break
            return _failed(
                f"iteration {it} ({matcher}) found {new_pairs.shape[0]} matches",
                spacing,
                history,
                t0,
            )
        weight = max(
            settings.smoothness,
            settings.smoothness * settings.stiffness_factor * 0.1 ** (it - start),
        )
        if settings.smoothness == 0:
            weight = 0.0
        fld = _fit(ref, dfm, new_pairs, bounds, settings, grid_um, weight)
        u = np.asarray(fld(ref))
        update = float(np.sqrt(np.mean(np.sum((u - prev_u) ** 2, axis=1))))
        resid = dfm[new_pairs[:, 1]] - ref[new_pairs[:, 0]] - fld(ref[new_pairs[:, 0]])
        warp_err = _robust_rms(resid)
        same_count = abs(new_pairs.shape[0] - pairs.shape[0]) <= max(0, int(1e-3 * n_min))
        pairs, prev_u = new_pairs, u
        history.append(
            IterationRecord(
                it,
                matcher,
                k,
                int(cand.shape[0]),
                int(pairs.shape[0]),
                int(cand.shape[0] - pairs.shape[0]),
                update,
                warp_err,
                time.perf_counter() - ts,
            )
        )
        logger.debug("iteration %d: %s", it, history[-1])
        converged = (
            matcher == "nearest" and update < settings.stall_tolerance * spacing and same_count
        )
        stalled = stalled + 1 if converged else 0
        if stalled >= 1 and weight <= settings.smoothness:
            break

    pairs = pairs[np.argsort(pairs[:, 0])]
    return LinkResult(
        matches=pairs.astype(np.int64),
        displacement_um=dfm[pairs[:, 1]] - ref[pairs[:, 0]],
        tracking_ratio=pairs.shape[0] / n_min,
        iterations=len(history),
        history=tuple(history),
        displacement_field=fld,
        ok=True,
        mean_spacing_um=spacing,
        seconds=time.perf_counter() - t0,
    )
