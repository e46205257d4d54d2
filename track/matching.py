"""SerialTrack-class linking of two 3-D particle clouds (reference → deformed).

The linker (:func:`link_pair`) matches particles *locally*, in neighbourhoods grown from
reliable regions, and regularises the result globally, in the spirit of SerialTrack (Yang et
al., "SerialTrack: ScalE and Rotation Invariant Augmented Lagrangian Particle Tracking",
SoftwareX 19, 101204, 2022). Heterogeneous fields (indentation, shear bands, vortices,
inclusions, fronts) with local gradients up to about 0.6 and displacements beyond one
particle spacing are tracked as well as homogeneous ones.

1. **Seeds.** Without a guess: both clouds are described by rotation-invariant
   neighbourhood-topology descriptors (:mod:`track.features`) and matched globally by nearest
   descriptor with a ratio test and a mutual check, in raw coordinates and after moment
   normalisation (each cloud whitened by its covariance, which turns any homogeneous stretch
   or shear into a rotation); a small-motion hypothesis (nearest neighbours of the unwarped
   clouds) is the last resort. Each hypothesis gives a RANSAC affine map
   (:func:`track.outliers.ransac_affine`); the map that links the most particles of the whole
   clouds wins, and its consensus, cleaned by the normalised median test and by agreement
   with neighbouring seeds, is the seed set. Nothing here assumes small displacements. With a
   guess (``initial_guess``, e.g. the previous increment of a series through
   :func:`increment_predictor`): the matches it predicts, if they are consistent and numerous
   enough; otherwise the bootstrap above.
2. **Growth.** Unmatched particles with at least three matched neighbours are predicted by a
   moving-least-squares polynomial fit of their neighbours' displacements (relative to a
   global field: the affine map, the guess, later the regularised field of all matches;
   :func:`track.regularize.local_polynomial_predict`) and matched to the only deformed
   particle inside a tolerance ellipsoid around the prediction (:func:`match_predicted`: per
   axis, from the localisation noise and the local prediction error, volume-capped, with a
   ratio test on both sides). The matched region grows front by front from the seeds; no
   global field has to be right where no particle is matched yet.
3. **Validation.** Every iteration predicts every particle leave-one-out from its matched
   neighbours, matches the clouds again and removes outliers with the normalised median test
   (Westerweel & Scarano, Exp. Fluids 39, 2005) on the residuals, with per-axis noise levels
   (light-field localisation noise is about ten times larger along z) estimated from the
   data, widened where the local fit misses part of the field. Particles near the faces of
   the volume, whose neighbourhoods are one-sided, get the larger tolerance their neighbours'
   leave-one-out errors show. The loop stops when an iteration changes nothing.
4. **Field.** A global field on a regular grid (:func:`track.regularize.fit_field`, direct or
   ADMM) refined per component by local corrections where cross-validation shows detail
   finer than the grid (:func:`track.regularize.fit_field_refined`: adaptive resolution),
   then two polishing iterations that predict relative to it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from hrvbase.errors import raised_as
from hrvbase.validate import finite_float, int_in_range, nonnegative_float, positive_float
from track.errors import InputError
from track.features import (
    cloud_scale_um,
    moment_normalization,
    topology_descriptors,
)
from track.outliers import MEDIAN_TEST_THRESHOLD, normalized_median_test, ransac_affine
from track.regularize import (
    METHODS,
    AffineDisplacement,
    fit_affine,
    fit_field,
    fit_field_refined,
    local_polynomial_predict,
)

logger = logging.getLogger(__name__)

MIN_PARTICLES = 4
#: Default lengths of :class:`LinkSettings`, in mean particle spacings
#: (:meth:`LinkSettings.radii_um`).
NN_MAX_DISTANCE_SPACINGS = 0.45
LOCAL_RADIUS_SPACINGS = 3.0
GRID_SPACING_SPACINGS = 2.0


class LinkRadii(NamedTuple):
    """The lengths (µm) of :class:`LinkSettings` for a cloud of a given mean spacing."""

    nn_max_distance_um: float
    local_radius_um: float
    local_scale_um: float
    ransac_threshold_um: float
    grid_spacing_um: float


@dataclass(frozen=True)
class LinkSettings:
    """Parameters of :func:`link_pair`. Lengths in µm; ``None`` means "derive from the data".

    Attributes
    ----------
    n_neighbors_max : int
        Neighbours of the median test that cleans the seeds (paper Table 1: 16).
    n_neighbors_min : int
        Half the neighbours of the median test of every iteration (≥ 3).
    descriptor_size : int
        Neighbours in a topology descriptor (≥ 2).
    descriptor_ratio : float
        Ratio test of descriptor matches: best distance < ratio × second best (0 < r ≤ 1).
    outlier_threshold : float
        Normalised-median-test threshold (paper: 3).
    outlier_eps_um : float or None
        Median-test noise level ε, the same on every axis. Default (with
        ``outlier_eps_xyz_um`` None too): per axis, the robust spread of the matches'
        leave-one-out residuals, at least 0.02 × the mean spacing.
    outlier_eps_xyz_um : tuple of 3 float or None
        Median-test noise levels per axis (x, y, z) in µm; wins over ``outlier_eps_um``.
    max_iterations : int
        Iteration cap of seeding, growth and validation (the polishing iterations come on
        top).
    regularization : {"gridded", "admm"}
        Global field solver (:func:`track.regularize.fit_field`).
    grid_spacing_um : float or None
        Node spacing of the field grid; default 2 × the mean particle spacing.
    smoothness : float
        Dimensionless smoothness weight of the gridded field (≥ 0).
    refine_field : bool
        Refine the gridded field per component where the data show finer detail
        (:func:`track.regularize.fit_field_refined`).
    nn_max_distance_um : float or None
        Radius of the ball whose volume caps every tolerance ellipsoid (a semi-axis may reach
        1.7 ×), and the tolerance of the seeding matches; default 0.45 mean spacings.
    nn_ratio : float
        Ratio test of the local matches (normalised distances, both sides; 0 < r ≤ 1).
    ransac_threshold_um : float or None
        Consensus radius of the affine bootstrap; default 1 mean spacing.
    bootstrap_max_particles : int
        Reference particles (random subset) used by the global bootstrap match.
    seed : int
        Seed of the RANSAC sampler and of the random subsets.
    local_neighbors : int
        Matched neighbours of each local prediction (≥ 3).
    local_degree : {1, 2}
        Degree of the local polynomial predictor (affine by default; quadratic fits the
        curvature but amplifies the axial noise).
    local_radius_um : float or None
        Largest distance of a matched neighbour used by a prediction; default 3 mean
        spacings.
    local_scale_um : float or None
        Gaussian weight length of the local fits; default 1 mean spacing.
    tolerance_sigmas : float
        Tolerance semi-axis per estimated standard deviation of the prediction error (> 0).
    growth_passes : int
        Growth passes per iteration (≥ 0).
    growth_q : float
        Normalised distance (fraction of the tolerance, 0 < q ≤ 1) a growth match must be
        within; validation then accepts up to 1.
    guess_min_fraction : float
        Fraction of the particles an ``initial_guess`` must link consistently to replace
        the bootstrap (0 ≤ f ≤ 1).
    guess_confirm_fraction : float
        When the matches grown from an ``initial_guess`` are fewer than this fraction of
        the particles, the bootstrap is run as well and the result with more matches kept
        (0 ≤ f ≤ 1): a predictor extrapolated off its data (a thin layer moving along z,
        Fig. 5b) can start a consistent but partial set that growth cannot complete.
    polish_iterations : int
        Iterations predicting relative to the regularised field of all matches (≥ 0).
    """

    n_neighbors_max: int = 16
    n_neighbors_min: int = 5
    descriptor_size: int = 5
    descriptor_ratio: float = 0.8
    outlier_threshold: float = MEDIAN_TEST_THRESHOLD
    outlier_eps_um: float | None = None
    outlier_eps_xyz_um: tuple[float, float, float] | None = None
    max_iterations: int = 20
    regularization: str = "gridded"
    grid_spacing_um: float | None = None
    smoothness: float = 1.0
    refine_field: bool = True
    nn_max_distance_um: float | None = None
    nn_ratio: float = 0.5
    ransac_threshold_um: float | None = None
    bootstrap_max_particles: int = 3000
    seed: int = 0
    local_neighbors: int = 12
    local_degree: int = 1
    local_radius_um: float | None = None
    local_scale_um: float | None = None
    tolerance_sigmas: float = 4.0
    growth_passes: int = 8
    growth_q: float = 0.5
    guess_min_fraction: float = 0.3
    guess_confirm_fraction: float = 0.9
    polish_iterations: int = 2

    def radii_um(self, spacing_um: float) -> LinkRadii:
        """The search radii and lengths for a reference cloud of mean particle spacing
        ``spacing_um`` (µm): each setting, or its default in spacings when None
        (``nn_max_distance_um`` :data:`NN_MAX_DISTANCE_SPACINGS`, ``local_radius_um``
        :data:`LOCAL_RADIUS_SPACINGS`, ``local_scale_um`` and ``ransac_threshold_um`` 1,
        ``grid_spacing_um`` :data:`GRID_SPACING_SPACINGS`)."""
        return LinkRadii(
            self.nn_max_distance_um or NN_MAX_DISTANCE_SPACINGS * spacing_um,
            self.local_radius_um or LOCAL_RADIUS_SPACINGS * spacing_um,
            self.local_scale_um or spacing_um,
            self.ransac_threshold_um or spacing_um,
            self.grid_spacing_um or GRID_SPACING_SPACINGS * spacing_um,
        )

    def __post_init__(self) -> None:
        with raised_as(InputError):
            self._validate()

    def _validate(self) -> None:
        n_min = int_in_range(self.n_neighbors_min, "n_neighbors_min", 3)
        if int_in_range(self.n_neighbors_max, "n_neighbors_max", 1) < n_min:
            raise InputError(
                f"n_neighbors_max ({self.n_neighbors_max}) must be ≥ n_neighbors_min "
                f"({self.n_neighbors_min})"
            )
        int_in_range(self.descriptor_size, "descriptor_size", 2)
        int_in_range(self.bootstrap_max_particles, "bootstrap_max_particles", MIN_PARTICLES)
        int_in_range(self.max_iterations, "max_iterations", 1)
        if not isinstance(self.seed, int | np.integer):
            raise InputError(f"seed must be an integer ≥ 0, got {self.seed!r}")
        int_in_range(self.seed, "seed", 0)
        int_in_range(self.local_neighbors, "local_neighbors", 3)
        if self.local_degree not in (1, 2):
            raise InputError(f"local_degree must be 1 or 2, got {self.local_degree}")
        for name in ("growth_passes", "polish_iterations"):
            int_in_range(getattr(self, name), name, 0)
        for name in ("descriptor_ratio", "nn_ratio", "growth_q"):
            if not 0 < finite_float(getattr(self, name), name) <= 1:
                raise InputError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        for name in ("guess_min_fraction", "guess_confirm_fraction"):
            if not 0 <= finite_float(getattr(self, name), name) <= 1:
                raise InputError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        for name in ("outlier_threshold", "tolerance_sigmas"):
            positive_float(getattr(self, name), name)
        nonnegative_float(self.smoothness, "smoothness")
        if self.regularization not in METHODS:
            raise InputError(
                f"regularization must be one of {METHODS}, got {self.regularization!r}"
            )
        for name in (
            "outlier_eps_um",
            "grid_spacing_um",
            "nn_max_distance_um",
            "ransac_threshold_um",
            "local_radius_um",
            "local_scale_um",
        ):
            v = getattr(self, name)
            if v is not None:
                positive_float(v, name)
        if self.outlier_eps_xyz_um is not None:
            try:
                eps = np.asarray(self.outlier_eps_xyz_um, dtype=float)
            except (TypeError, ValueError):
                eps = np.zeros(0)
            if eps.shape != (3,) or not np.all(np.isfinite(eps) & (eps > 0)):
                raise InputError(
                    "outlier_eps_xyz_um must be None or 3 finite values > 0 (x, y, z in µm), "
                    f"got {self.outlier_eps_xyz_um!r}"
                )
            object.__setattr__(self, "outlier_eps_xyz_um", tuple(float(v) for v in eps))


@dataclass(frozen=True)
class IterationRecord:
    """What one iteration did (counts are numbers of matches).

    Attributes
    ----------
    iteration : int
        1-based.
    matcher : str
        ``"topology"``, ``"topology-moment"`` or ``"nearest"`` (seeding: the winning
        bootstrap hypothesis, or ``"nearest"`` for the matches of an ``initial_guess``),
        ``"local"`` (growth and validation) or ``"polish"``.
    n_neighbors : int
        Neighbours of the median test.
    n_candidates, n_matches, n_outliers : int
        Candidate matches (grown ones included), matches kept, candidates removed.
    update_rms_um : float
        RMS change of the predicted displacements since the previous iteration (nan for
        seeding and for the first iteration).
    residual_rms_um : float
        Robust RMS length of the matches' residuals about their predictions.
    seconds : float
        Wall time.
    """

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


def match_predicted(
    warped_ref: np.ndarray, def_xyz: np.ndarray, tolerance_xyz_um: np.ndarray, ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """Unambiguous deformed particle inside each predicted position's tolerance ellipsoid.

    The distance of deformed particle ``j`` from warped reference particle ``i`` is
    ``q_ij = |(def_j − warped_i) / tolerance_i|`` (per-axis tolerances, so anisotropic noise
    gets an ellipsoid). A pair is kept when ``q ≤ 1`` and it beats every other candidate of
    both ``i`` and ``j`` by the ratio: ``q < ratio × q_second``.

    Parameters
    ----------
    warped_ref : ndarray, shape (N, 3)
        Predicted deformed positions of the reference particles (µm).
    def_xyz : ndarray, shape (M, 3)
        Deformed particles (µm).
    tolerance_xyz_um : ndarray, shape (N, 3)
        Semi-axes (x, y, z) of each particle's tolerance ellipsoid (µm, > 0).
    ratio : float
        Ratio test, 0 < ratio ≤ 1.

    Returns
    -------
    pairs : ndarray of int, shape (K, 2)
        ``[row_ref, row_def]``.
    q : ndarray, shape (K,)
        Normalised distance of each pair.
    """
    n = warped_ref.shape[0]
    tol = np.asarray(tolerance_xyz_um, dtype=float)
    k = min(4, def_xyz.shape[0])
    reach = float(np.max(tol)) / ratio
    d, j = cKDTree(def_xyz).query(warped_ref, k, distance_upper_bound=reach)
    d, j = d.reshape(n, k), j.reshape(n, k)
    valid = np.isfinite(d)
    safe = np.where(valid, j, 0)
    q = np.sqrt(np.sum(((def_xyz[safe] - warped_ref[:, None, :]) / tol[:, None, :]) ** 2, axis=2))
    q[~valid] = np.inf
    order = np.argsort(q, axis=1)
    q1 = np.take_along_axis(q, order[:, :1], axis=1)[:, 0]
    q2 = np.take_along_axis(q, order[:, 1:2], axis=1)[:, 0] if k > 1 else np.full(n, np.inf)
    best_j = np.take_along_axis(safe, order[:, :1], axis=1)[:, 0]
    ok = (q1 <= 1.0) & (q1 < ratio * q2)
    # deformed side: j's best claimant must be i and beat j's other claimants by the ratio
    rows = np.repeat(np.arange(n), k)[valid.ravel()]
    cols = safe.ravel()[valid.ravel()]
    qq = q.ravel()[valid.ravel()]
    srt = np.lexsort((qq, cols))
    rows, cols, qq = rows[srt], cols[srt], qq[srt]
    first = np.ones(cols.size, dtype=bool)
    first[1:] = cols[1:] != cols[:-1]
    nxt = np.full(cols.size, np.inf)
    same_next = np.zeros(cols.size, dtype=bool)
    same_next[:-1] = cols[1:] == cols[:-1]
    nxt[:-1] = np.where(same_next[:-1], qq[1:], np.inf)
    owner = np.full(def_xyz.shape[0], -1)
    owner_ok = np.zeros(def_xyz.shape[0], dtype=bool)
    owner[cols[first]] = rows[first]
    owner_ok[cols[first]] = qq[first] < ratio * nxt[first]
    ok &= (owner[best_j] == np.arange(n)) & owner_ok[best_j]
    sel = np.flatnonzero(ok)
    return np.column_stack([sel, best_j[sel]]).astype(np.int64), q1[sel]


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


def _verify(ref, dfm, aff, settings, spacing, eps_um):
    """Matches of the whole clouds that agree with a global hypothesis ``aff``."""
    u = np.asarray(aff(ref), dtype=float)
    tol = np.full(ref.shape, settings.radii_um(spacing).nn_max_distance_um)
    cand, _ = match_predicted(ref + u, dfm, tol, settings.nn_ratio)
    return _clean(ref, dfm, cand, settings.n_neighbors_max, settings, eps_um, ref + u)


def _filter_seeds(ref, dfm, pairs, spacing):
    """Drop seed matches that disagree with their seed neighbours.

    Each seed's displacement is predicted, leave-one-out, by an affine moving-least-squares
    fit of the seeds within 4 mean spacings; a seed with at least three such neighbours
    whose displacement differs from the prediction by more than max(4 σ, 0.1 spacing) on an
    axis (σ: robust spread of those differences over all seeds) is dropped, twice over. A
    global hypothesis (an affine map, or no motion) collects accidental pairs where the
    field departs from it; they sit among right seeds, or among each other at random, and
    fail this test, while a lone seed (no evidence either way) is kept.
    """
    keep = np.ones(pairs.shape[0], dtype=bool)
    for _ in range(2):
        idx = np.flatnonzero(keep)
        if idx.size < 5:
            break
        x = ref[pairs[idx, 0]]
        d = dfm[pairs[idx, 1]] - x
        lp = local_polynomial_predict(
            x, d, x, 8, 4.0 * spacing, scale_um=1.5 * spacing, exclude=np.arange(idx.size)
        )
        r = np.abs(d - lp.values_um)
        has = lp.n_neighbors >= 3
        if not np.any(has):
            break
        sig = 1.4826 * np.median(r[has], axis=0)
        tau = np.maximum(4.0 * sig, 0.1 * spacing)
        bad = has & np.any(r > tau, axis=1)
        if not np.any(bad):
            break
        keep[idx[bad]] = False
    if keep.sum() < 4:
        return pairs
    return pairs[keep]


def _bootstrap(ref, dfm, settings, spacing, eps_um):
    """Global topology match + affine consensus, verified on the whole clouds.

    Each hypothesis (descriptor matches in raw and in moment-normalised coordinates, then
    nearest neighbours of the unwarped clouds) gives a RANSAC affine map; the map that links
    the most particles of the whole clouds (:func:`_verify`) wins. Returns (affine field,
    pairs, n_candidates, label) or None.
    """
    n_core = min(settings.descriptor_size, ref.shape[0] - 1, dfm.shape[0] - 1)
    scale = cloud_scale_um(ref)
    n_min = min(ref.shape[0], dfm.shape[0])
    enough = 0.3 * n_min
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
    thr = settings.radii_um(spacing).ransac_threshold_um
    min_inl = max(4, min(8, int(0.5 * n_min)))
    best = None

    def consider(label, cand, fit):
        nonlocal best
        if fit is None:
            return
        pairs = _verify(ref, dfm, fit[0], settings, spacing, eps_um)
        logger.debug(
            "bootstrap %s: %d candidates, %d agree, %d verified",
            label,
            cand.shape[0],
            int(fit[1].sum()),
            pairs.shape[0],
        )
        if pairs.shape[0] >= 4 and (best is None or pairs.shape[0] > best[0]):
            best = (pairs.shape[0], label, cand[fit[1]], cand.shape[0], fit[0])

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
        consider(label, cand, fit)
        if best is not None and best[0] >= enough:
            break  # most particles agree already
    if best is None or best[0] < enough:
        # Small-motion hypothesis: increments well below the particle spacing (the usual case
        # at high frame rates) pair nearest neighbours of the unwarped clouds. It rescues
        # sparse, noisy clouds whose topology descriptors disagree (a few tens of particles
        # with spurious or missing detections); the affine consensus still has to agree.
        cand = match_nearest(ref, dfm, 0.5 * spacing, settings.nn_ratio)
        if cand.shape[0] >= min_inl:
            fit = ransac_affine(
                ref[cand[:, 0]],
                dfm[cand[:, 1]],
                min(thr, 0.25 * spacing),
                seed=settings.seed,
                min_inliers=min_inl,
            )
            consider("nearest", cand, fit)
    if best is None:
        return None
    # The seeds are the hypothesis' own consensus (descriptor matches that agree with its
    # map), not the verified matches: where the field is far from affine, some of those are
    # accidental neighbours.
    _, label, pairs, n_cand, aff0 = best
    pairs = _clean(ref, dfm, pairs, settings.n_neighbors_max, settings, eps_um, ref + aff0(ref))
    if pairs.shape[0] < 4:
        return None
    pairs = _filter_seeds(ref, dfm, pairs, spacing)
    aff = fit_affine(ref[pairs[:, 0]], dfm[pairs[:, 1]] - ref[pairs[:, 0]])
    return aff, pairs, n_cand, label


def fit_link_field(ref_xyz, def_xyz, matches, settings: LinkSettings | None = None):
    """The regularised displacement field :func:`link_pair` returns, for given matches.

    Fewer than 8 matches give an affine field; otherwise :func:`track.regularize.fit_field`
    on a grid of ``grid_spacing_um`` (default 2 mean spacings) with ``smoothness``, refined
    per component by :func:`track.regularize.fit_field_refined` unless ``refine_field`` is
    off. Useful to compare a linker's field with the one the true matches give (its noise
    floor).

    Parameters
    ----------
    ref_xyz, def_xyz : array_like, shape (N, 3), (M, 3)
        The clouds (µm).
    matches : array_like of int, shape (K, 2)
        ``[row_ref, row_def]``, K ≥ 4.
    settings : LinkSettings, optional

    Returns
    -------
    callable
        ``u(xyz_um (P, 3)) -> (P, 3)`` µm.
    """
    settings = settings or LinkSettings()
    ref = _validate_cloud("ref_xyz", ref_xyz)
    dfm = _validate_cloud("def_xyz", def_xyz)
    pairs = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    if pairs.shape[0] < 4:
        raise InputError(f"matches must hold at least 4 pairs, got {pairs.shape[0]}")
    if (
        np.any(pairs < 0)
        or np.any(pairs[:, 0] >= ref.shape[0])
        or np.any(pairs[:, 1] >= dfm.shape[0])
    ):
        raise InputError("matches hold rows outside the clouds")
    spacing = _mean_spacing(ref)
    grid_um = settings.radii_um(spacing).grid_spacing_um
    pad = 1e-6 * max(np.ptp(ref), 1.0)
    bounds = np.column_stack([ref.min(axis=0) - pad, ref.max(axis=0) + pad])
    x = ref[pairs[:, 0]]
    u = dfm[pairs[:, 1]] - x
    if pairs.shape[0] < 8:
        return fit_affine(x, u)
    if settings.refine_field:
        return fit_field_refined(
            x,
            u,
            bounds,
            grid_um,
            settings.regularization,
            settings.smoothness,
            length_um=spacing,
            seed=settings.seed,
        )
    return fit_field(x, u, bounds, grid_um, settings.regularization, settings.smoothness)


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


def _loo_noise(resid: np.ndarray, spacing: float) -> np.ndarray:
    """Robust per-axis standard deviation (x, y, z) of match residuals, floored."""
    if resid.shape[0] < 4:
        return np.full(3, 0.05 * spacing)
    mad = np.median(np.abs(resid - np.median(resid, axis=0)), axis=0)
    return np.maximum(1.4826 * mad, 1e-3 * spacing)


def _predict(ref, dfm, pairs, u_base, settings, spacing, rows=None):
    """Displacement prediction at reference particles from the current matches.

    ``u_base`` (the global field at every reference particle, (N, 3)) plus a
    moving-least-squares polynomial fit (:func:`track.regularize.local_polynomial_predict`)
    of the matched residuals about it, leave-one-out for matched particles. ``rows`` selects
    the reference rows to predict (default all). Returns (prediction (R, 3), misfit (R, 3),
    neighbour count (R,)).
    """
    rows = np.arange(ref.shape[0]) if rows is None else rows
    x = ref[pairs[:, 0]]
    r = dfm[pairs[:, 1]] - x - u_base[pairs[:, 0]]
    slot = np.full(ref.shape[0], -1, dtype=np.int64)
    slot[pairs[:, 0]] = np.arange(pairs.shape[0])
    lp = local_polynomial_predict(
        x,
        r,
        ref[rows],
        n_neighbors=settings.local_neighbors,
        radius_um=settings.radii_um(spacing).local_radius_um,
        scale_um=settings.radii_um(spacing).local_scale_um,
        exclude=slot[rows],
        degree=settings.local_degree,
    )
    return u_base[rows] + lp.values_um, lp.misfit_um, lp.n_neighbors


def _tolerance_limits(settings, spacing):
    hi = settings.radii_um(spacing).nn_max_distance_um
    return min(0.1 * spacing, hi), hi


def _tolerance(sigma, noise, settings, spacing):
    """Per-particle tolerance semi-axes (x, y, z): κ × (noise ⊕ local error σ).

    Each semi-axis lies in [lo, 1.7 hi] and the ellipsoid's volume is at most that of the
    ball of radius ``hi`` (``nn_max_distance_um``, default 0.45 mean spacings): the chance
    that an unrelated particle falls inside is what limits it, and a thin ellipsoid (the
    lateral error is often ten times smaller than the axial) may reach further along its
    long axis.
    """
    lo, hi = _tolerance_limits(settings, spacing)
    sig = np.sqrt(noise**2 + np.where(np.isfinite(sigma), sigma, hi) ** 2)
    t = np.clip(settings.tolerance_sigmas * sig, lo, 1.7 * hi)
    vol = np.prod(t, axis=1)
    shrink = np.minimum(1.0, (hi**3 / vol) ** (1.0 / 3.0))
    return np.maximum(t * shrink[:, None], lo)


def _neighbour_rms(x, resid, query, k, radius, exclude):
    """RMS per axis of the ``k`` nearest ``resid`` rows around each query (Q, 3); inf if none."""
    kk = min(k + 1, x.shape[0])
    d, idx = cKDTree(x).query(query, kk, distance_upper_bound=radius)
    d, idx = d.reshape(len(query), kk), idx.reshape(len(query), kk)
    valid = np.isfinite(d) & (idx != exclude[:, None])
    valid &= np.cumsum(valid, axis=1) <= k
    r2 = np.where(valid[:, :, None], resid[np.where(valid, idx, 0)] ** 2, 0.0)
    cnt = valid.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sqrt(r2.sum(axis=1) / cnt[:, None])
    out[cnt == 0] = np.inf
    return out


def _pair_keys(pairs, m):
    return np.sort(pairs[:, 0] * m + pairs[:, 1])


def _grow(
    ref,
    dfm,
    pairs,
    u_base,
    refit_base,
    settings,
    spacing,
    eps_fixed,
    history,
    start,
    stop=None,
    label="local",
    grow=True,
):
    """Local matching grown from ``pairs`` until the match set is stable.

    Each iteration (a) grows: passes that predict the unmatched reference particles with
    at least three matched neighbours from those neighbours and add the unambiguous
    matches to still free deformed particles (within ``growth_q`` of their tolerance);
    (b) validates: predicts every particle leave-one-out, matches the whole clouds again and
    removes outliers with the normalised median test (per-axis noise levels). It stops when
    an iteration without growth changes nothing (or the set flips between two states).
    """
    ratio = settings.nn_ratio
    m = dfm.shape[0]
    noise = np.full(3, 0.05 * spacing)
    last_pred = None
    lo, hi = _tolerance_limits(settings, spacing)
    calib = None  # (positions, leave-one-out residuals) of the last validated matches
    k_cal = settings.local_neighbors
    r_cal = settings.radii_um(spacing).local_radius_um
    seen: list[np.ndarray] = [_pair_keys(pairs, m)]
    stop = settings.max_iterations if stop is None else stop
    settle = not grow  # an iteration without growth passes
    tabu = np.zeros(ref.shape[0], dtype=bool)  # rejected by the last median test
    for it in range(start, stop + 1):
        ts = time.perf_counter()
        grown = 0
        for _ in range(0 if settle else settings.growth_passes):
            free_ref = ~tabu
            free_ref[pairs[:, 0]] = False
            rows = np.flatnonzero(free_ref)
            if rows.size == 0:
                break
            pred, misfit, nnb = _predict(ref, dfm, pairs, u_base, settings, spacing, rows)
            near = nnb >= 3
            rows, pred, misfit = rows[near], pred[near], misfit[near]
            if rows.size == 0:
                break
            sigma = misfit
            if calib is not None:
                none = np.full(rows.size, -1)
                sigma = np.maximum(sigma, _neighbour_rms(*calib, ref[rows], k_cal, r_cal, none))
            tol = _tolerance(sigma, noise, settings, spacing)
            cand, q = match_predicted(ref[rows] + pred, dfm, tol, ratio)
            taken = np.zeros(m, dtype=bool)
            taken[pairs[:, 1]] = True
            cand = cand[~taken[cand[:, 1]] & (q <= settings.growth_q)]
            if cand.shape[0] == 0:
                break
            pairs = np.vstack([pairs, np.column_stack([rows[cand[:, 0]], cand[:, 1]])])
            grown += cand.shape[0]
        if refit_base:
            aff = fit_affine(ref[pairs[:, 0]], dfm[pairs[:, 1]] - ref[pairs[:, 0]])
            u_base = aff(ref)
        pred, misfit, nnb = _predict(ref, dfm, pairs, u_base, settings, spacing)
        resid = dfm[pairs[:, 1]] - ref[pairs[:, 0]] - pred[pairs[:, 0]]
        noise = _loo_noise(resid, spacing)
        # The local error scale: the polynomial's misfit, or the leave-one-out errors of the
        # matched neighbours where larger (they show what the misfit misses: curvature,
        # one-sided neighbourhoods at faces and fronts).
        calib = (ref[pairs[:, 0]], resid)
        slot = np.full(ref.shape[0], -1, dtype=np.int64)
        slot[pairs[:, 0]] = np.arange(pairs.shape[0])
        sigma = np.maximum(misfit, _neighbour_rms(*calib, ref, k_cal, r_cal, slot))
        tol = _tolerance(sigma, noise, settings, spacing)
        # Particles without matched neighbours rely on the global field alone: only once
        # the growth has stopped, and where that field describes the matches well (a
        # homogeneous field, sparse clouds).
        lone = nnb < 3
        if np.any(lone) and grown == 0:
            x = ref[pairs[:, 0]]
            spread = _loo_noise(dfm[pairs[:, 1]] - x - u_base[pairs[:, 0]], spacing)
            t_base = settings.tolerance_sigmas * spread
            if np.all(t_base <= hi):
                pred[lone] = u_base[lone]
                tol[lone] = np.maximum(t_base, lo)
            else:
                tol[lone] = 0.0
        cand, q = match_predicted(ref + pred, dfm, np.maximum(tol, 1e-9 * spacing), ratio)
        # While the front still moves, a particle matched for the first time must meet the
        # growth criterion: the outer part of a tolerance ellipsoid is for re-validating
        # matches and, once the growth has stopped, for the particles left among matched
        # neighbours, not for guessing at the front.
        was = np.zeros(ref.shape[0], dtype=bool)
        was[pairs[:, 0]] = True
        first_ok = (q <= settings.growth_q) | (grown == 0)
        keep = (tol[cand[:, 0], 0] > 0) & (was[cand[:, 0]] | first_ok)
        cand, q = cand[keep], q[keep]
        eps = eps_fixed if eps_fixed is not None else np.maximum(noise, 0.02 * spacing)
        # Where the local polynomial misses part of the field (steep fronts, interfaces), a
        # right match deviates from its prediction by up to the local misfit: the median
        # test allows for it.
        eps = np.maximum(eps, np.where(np.isfinite(sigma), sigma, 0.0))[cand[:, 0]]
        k = 2 * settings.n_neighbors_min
        new = _clean(ref, dfm, cand, k, settings, eps, ref + pred)
        # A match deep inside its ellipsoid (q ≤ growth_q / 2: an unrelated particle that
        # close is improbable and the ratio test excludes a second one) stays: the median
        # test couples neighbours and would flip a few right ones in and out.
        sure = cand[q <= 0.5 * settings.growth_q]
        if sure.shape[0]:
            new = np.unique(np.vstack([new, sure]), axis=0)
        # growth does not offer the median test's rejects again right away (it would
        # flip between adding and removing them)
        tabu[:] = False
        tabu[cand[:, 0]] = True
        tabu[new[:, 0]] = False
        update = float("nan")
        if last_pred is not None:
            update = float(np.sqrt(np.mean(np.sum((pred - last_pred) ** 2, axis=1))))
        last_pred = pred
        history.append(
            IterationRecord(
                it,
                label,
                k,
                int(cand.shape[0] + grown),
                int(new.shape[0]),
                int(cand.shape[0] - new.shape[0]),
                update,
                float(np.sqrt(np.sum(noise**2))),
                time.perf_counter() - ts,
            )
        )
        logger.debug("iteration %d: %s (grown %d)", it, history[-1], grown)
        if new.shape[0] < 4:
            return new  # nothing consistent is left: the caller reports it
        keys = _pair_keys(new, m)
        pairs = new
        repeated = any(keys.shape == s.shape and np.array_equal(keys, s) for s in seen[-2:])
        seen.append(keys)
        if repeated:  # stable, or flipping between two sets
            if grown == 0:
                break
            settle = True  # once more without growth: first matches may then use q ≤ 1
        else:
            settle = not grow
    return pairs


def bridge_tracks(
    ref_xyz, def_xyz, pairs, ref_rows, def_rows, settings=None, *, q_max: float = 1.0
) -> np.ndarray:
    """Link particles whose tracks end in a frame to particles that start tracks in a later one.

    A particle missed by detection in an intermediate frame (or left unmatched by a pair)
    ends its track there and reappears as the start of a new one. Its displacement from
    the earlier frame to the later one is predicted from the particles tracked across both,
    as :func:`link_pair` grows its matches (the global affine fit of their displacements
    plus a moving-least-squares fit of the residuals of the neighbours), with the same
    per-axis tolerance ellipsoid (the localisation noise from the leave-one-out residuals
    of the tracked particles, widened by the local fit's error, volume-capped). A link is
    made only when the later particle is the only one of *all* its frame's particles inside
    the ellipsoid that passes the ratio test, lies within ``q_max`` of it, and starts a track.

    Parameters
    ----------
    ref_xyz, def_xyz : ndarray, shape (N, 3), (M, 3)
        Particles of the earlier and the later frame (µm, x, y, z).
    pairs : ndarray of int, shape (K, 2)
        ``[row_ref, row_def]`` of the particles tracked from one frame to the other.
    ref_rows : ndarray of int, shape (R,)
        Rows of ``ref_xyz`` whose tracks end (not in ``pairs``).
    def_rows : ndarray of int, shape (S,)
        Rows of ``def_xyz`` that start tracks (not in ``pairs``).
    settings : LinkSettings, optional
        ``local_*``, ``tolerance_sigmas``, ``nn_max_distance_um``, ``nn_ratio``.
    q_max : float
        Largest normalised distance from the prediction (0 < q_max ≤ 1; ``growth_q``: as
        strict as the linker is with a particle it matches for the first time).

    Returns
    -------
    ndarray of int, shape (B, 2)
        ``[row_ref, row_def]`` of the bridged particles (empty with fewer than
        ``MIN_PARTICLES`` pairs or no particle with three tracked neighbours).
    """
    settings = settings or LinkSettings()
    if not 0 < q_max <= 1:
        raise InputError(f"q_max must be in (0, 1], got {q_max!r}")
    ref = np.asarray(ref_xyz, dtype=float).reshape(-1, 3)
    dfm = np.asarray(def_xyz, dtype=float).reshape(-1, 3)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    ref_rows = np.asarray(ref_rows, dtype=np.int64).ravel()
    free_def = np.zeros(dfm.shape[0], dtype=bool)
    free_def[np.asarray(def_rows, dtype=np.int64).ravel()] = True
    none = np.zeros((0, 2), dtype=np.int64)
    if pairs.shape[0] < MIN_PARTICLES or ref_rows.size == 0 or not free_def.any():
        return none
    spacing = _mean_spacing(ref)
    x = ref[pairs[:, 0]]
    u_base = fit_affine(x, dfm[pairs[:, 1]] - x)(ref)
    pred, _, _ = _predict(ref, dfm, pairs, u_base, settings, spacing)
    resid = dfm[pairs[:, 1]] - x - pred[pairs[:, 0]]
    noise = _loo_noise(resid, spacing)
    p_rows, misfit, nnb = _predict(ref, dfm, pairs, u_base, settings, spacing, ref_rows)
    near = nnb >= 3
    rows, p_rows, misfit = ref_rows[near], p_rows[near], misfit[near]
    if rows.size == 0:
        return none
    k = settings.local_neighbors
    radius = settings.radii_um(spacing).local_radius_um
    local = _neighbour_rms(x, resid, ref[rows], k, radius, np.full(rows.size, -1))
    tol = _tolerance(np.maximum(misfit, local), noise, settings, spacing)
    cand, q = match_predicted(ref[rows] + p_rows, dfm, tol, settings.nn_ratio)
    cand = cand[free_def[cand[:, 1]] & (q <= q_max)]
    return np.column_stack([rows[cand[:, 0]], cand[:, 1]]).astype(np.int64)


def increment_predictor(
    previous_field: Callable[[np.ndarray], np.ndarray],
    *,
    scale: float = 1.0,
    lagrangian: bool = True,
    n_iterations: int = 4,
) -> Callable[[np.ndarray], np.ndarray]:
    """Predictor of the next increment of a series from the previous one.

    For frames ``i−2 → i−1 → i`` linked incrementally, ``previous_field`` is the
    displacement field of ``i−2 → i−1`` (e.g. ``LinkResult.displacement_field``), a function
    of positions in frame ``i−2``. The returned callable predicts the displacement
    ``i−1 → i`` at positions ``y`` of frame ``i−1`` as ``scale × previous_field(z)`` with
    ``z + previous_field(z) = y`` (each particle repeats its previous step: constant
    velocity of material points, ``lagrangian=True``; solved by fixed-point iteration) or
    ``scale × previous_field(y)`` (a steady flow, ``lagrangian=False``). ``scale`` is the
    ratio of the frame intervals (1 at a constant frame rate).

    Pass it as ``link_pair(..., initial_guess=increment_predictor(prev.displacement_field))``;
    :func:`link_pair` checks the guess against the clouds and falls back to its global
    bootstrap when the motion changed too much.

    Parameters
    ----------
    previous_field : callable
        ``u(xyz_um (P, 3)) -> (P, 3)`` µm.
    scale : float
        Finite factor on the predicted increment.
    lagrangian : bool
        Follow material points (default) or hold the field in space.
    n_iterations : int
        Fixed-point iterations of the Lagrangian inversion (≥ 1).

    Returns
    -------
    callable
        ``guess(xyz_um (P, 3)) -> (P, 3)`` µm.
    """
    if not callable(previous_field):
        raise InputError("previous_field must be a callable u(xyz_um) -> (P, 3) µm")
    if not np.isfinite(scale):
        raise InputError(f"scale must be finite, got {scale}")
    if int(n_iterations) < 1:
        raise InputError(f"n_iterations must be ≥ 1, got {n_iterations}")

    def guess(xyz_um):
        y = np.asarray(xyz_um, dtype=float)
        u = np.asarray(previous_field(y), dtype=float)
        if lagrangian:
            for _ in range(int(n_iterations)):
                u = np.asarray(previous_field(y - u), dtype=float)
        return scale * u

    return guess


def _bootstrap_and_fit(ref, dfm, settings, spacing, eps_boot, eps_fixed, history):
    """The global bootstrap, then :func:`_grow_and_fit`; None when the bootstrap fails."""
    ts = time.perf_counter()
    boot = _bootstrap(ref, dfm, settings, spacing, eps_boot)
    if boot is None:
        return None
    aff, pairs, n_cand, label = boot
    u_base = aff(ref)
    resid = dfm[pairs[:, 1]] - ref[pairs[:, 0]] - u_base[pairs[:, 0]]
    history.append(
        IterationRecord(
            len(history) + 1,
            label,
            settings.n_neighbors_max,
            n_cand,
            int(pairs.shape[0]),
            n_cand - int(pairs.shape[0]),
            float("nan"),
            _robust_rms(resid),
            time.perf_counter() - ts,
        )
    )
    return _grow_and_fit(ref, dfm, pairs, u_base, True, settings, spacing, eps_fixed, history)


def _grow_and_fit(ref, dfm, pairs, u_base, refit, settings, spacing, eps_fixed, history):
    """Grow the matches from ``pairs``, fit the field and polish; (pairs, field), where
    the field is None with fewer than 4 matches."""
    pairs = _grow(
        ref, dfm, pairs, u_base, refit, settings, spacing, eps_fixed, history, len(history) + 1
    )
    if pairs.shape[0] < 4:
        return pairs, None
    fld = fit_link_field(ref, dfm, pairs, settings)
    if settings.polish_iterations and pairs.shape[0] >= 8:
        # Polish: the local predictions relative to the regularised field of all matches
        # rather than to the starting field (an affine map or the previous increment),
        # which leaves the local fits only what that field misses.
        before = _pair_keys(pairs, dfm.shape[0])
        start = len(history) + 1
        polished = _grow(
            ref,
            dfm,
            pairs,
            np.asarray(fld(ref), dtype=float),
            False,
            settings,
            spacing,
            eps_fixed,
            history,
            start,
            stop=start + settings.polish_iterations - 1,
            label="polish",
            grow=False,
        )
        changed = not np.array_equal(before, _pair_keys(polished, dfm.shape[0]))
        if polished.shape[0] >= 4 and changed:
            pairs = polished
            fld = fit_link_field(ref, dfm, pairs, settings)
    return pairs, fld


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
        ``u(xyz_um (P, 3)) -> (P, 3)`` µm displacement predictor at reference points (e.g.
        the previous increment's field, :func:`previous_increment_predictor`). Its matches
        replace the global topology bootstrap when they are consistent; otherwise the
        bootstrap runs as without it.

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
    eps_fixed = None
    if settings.outlier_eps_xyz_um is not None:
        eps_fixed = np.asarray(settings.outlier_eps_xyz_um, dtype=float)
    elif settings.outlier_eps_um is not None:
        eps_fixed = np.full(3, settings.outlier_eps_um)
    eps_boot = eps_fixed if eps_fixed is not None else 0.02 * spacing
    n_min = min(ref.shape[0], dfm.shape[0])
    history: list[IterationRecord] = []

    pairs = None
    if initial_guess is not None:
        test = np.asarray(initial_guess(ref[:1]), dtype=float)
        if test.shape != (1, 3) or not np.all(np.isfinite(test)):
            raise InputError(
                "initial_guess must map (P, 3) µm points to finite (P, 3) µm displacements"
            )
        ts = time.perf_counter()
        u0 = np.asarray(initial_guess(ref), dtype=float)
        if u0.shape != ref.shape or not np.all(np.isfinite(u0)):
            raise InputError(
                "initial_guess must map (P, 3) µm points to finite (P, 3) µm displacements"
            )
        tol = np.full(ref.shape, settings.radii_um(spacing).nn_max_distance_um)
        cand, _ = match_predicted(ref + u0, dfm, tol, settings.nn_ratio)
        guess_pairs = _clean(ref, dfm, cand, settings.n_neighbors_max, settings, eps_boot, ref + u0)
        history.append(
            IterationRecord(
                1,
                "nearest",
                settings.n_neighbors_max,
                int(cand.shape[0]),
                int(guess_pairs.shape[0]),
                int(cand.shape[0] - guess_pairs.shape[0]),
                float("nan"),
                float("nan"),
                time.perf_counter() - ts,
            )
        )
        if guess_pairs.shape[0] >= max(4, settings.guess_min_fraction * n_min):
            pairs, u_base, refit = guess_pairs, u0, False
        else:
            logger.info(
                "initial_guess matched %d of %d particles; running the bootstrap instead",
                guess_pairs.shape[0],
                n_min,
            )
    if pairs is not None:
        guessed = _grow_and_fit(
            ref, dfm, pairs, u_base, refit, settings, spacing, eps_fixed, history
        )
        if guessed[0].shape[0] >= settings.guess_confirm_fraction * n_min:
            pairs, fld = guessed
        else:
            logger.info(
                "the matches grown from initial_guess link %d of %d particles; "
                "running the bootstrap as well",
                guessed[0].shape[0],
                n_min,
            )
            boot_history = list(history)
            booted = _bootstrap_and_fit(
                ref, dfm, settings, spacing, eps_boot, eps_fixed, boot_history
            )
            if booted is not None and booted[0].shape[0] > guessed[0].shape[0]:
                (pairs, fld), history = booted, boot_history
            else:
                pairs, fld = guessed
    else:
        booted = _bootstrap_and_fit(ref, dfm, settings, spacing, eps_boot, eps_fixed, history)
        if booted is None:
            return _failed(
                "no consistent set of topology matches (bootstrap failed)", spacing, history, t0
            )
        pairs, fld = booted
    if pairs.shape[0] < 4:
        return _failed(f"only {pairs.shape[0]} consistent matches", spacing, history, t0)
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
