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
   clouds) is tried as well unless a descriptor map links every particle. Each hypothesis
   gives a RANSAC affine map (:func:`track.outliers.ransac_affine`); the map that links the
   most particles of the whole clouds wins, and its consensus, cleaned by the normalised
   median test and by agreement with neighbouring seeds, is the seed set. Nothing here
   assumes small displacements. With a guess (``initial_guess``, e.g. the previous increment
   of a series through :func:`increment_predictor`): the matches it predicts, if they are
   consistent and numerous enough; otherwise the bootstrap above.
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

import numpy as np
from scipy.spatial import cKDTree

from track.cloud_matchers import match_descriptors_global, match_nearest, match_predicted
from track.errors import InputError
from track.features import (
    cloud_scale_um,
    moment_normalization,
    topology_descriptors,
)
from track.link_growth import (
    _clean,
    _grow,
    _loo_noise,
    _neighbour_rms,
    _pair_keys,
    _predict,
    _robust_rms,
    _tolerance,
)
from track.link_settings import (  # noqa: F401 (the settings are importable from here)
    GRID_SPACING_SPACINGS,
    LOCAL_RADIUS_SPACINGS,
    MIN_PARTICLES,
    NN_MAX_DISTANCE_SPACINGS,
    IterationRecord,
    LinkRadii,
    LinkResult,
    LinkSettings,
)
from track.outliers import ransac_affine
from track.regularize import (
    AffineDisplacement,
    fit_affine,
    fit_field,
    fit_field_refined,
    local_polynomial_predict,
)

logger = logging.getLogger(__name__)


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


# ------------------------------------------------------------------------------- the loop


def _mean_spacing(xyz: np.ndarray) -> float:
    d, _ = cKDTree(xyz).query(xyz, 2)
    return float(np.mean(d[:, 1]))


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
    if best is None or best[0] < n_min:
        # Small-motion hypothesis: increments well below the particle spacing (the usual case
        # at high frame rates) pair nearest neighbours of the unwarped clouds. It rescues
        # sparse, noisy clouds whose topology descriptors disagree (a few tens of particles
        # with spurious or missing detections); the affine consensus still has to agree. It
        # competes with a descriptor map that leaves particles unlinked: in a small cloud the
        # few descriptor matches, wrong ones among them, can all fit one affine map within
        # the RANSAC threshold (a spacing), which then links only part of the cloud.
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
    field = fit_field(x, u, bounds, grid_um, settings.regularization, settings.smoothness)
    if settings.refine_field:
        return fit_field_refined(field, x, u, length_um=spacing, seed=settings.seed)
    return field


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


def _guess_pairs(ref, dfm, initial_guess, settings, spacing, eps_boot, n_min, history):
    """The matches ``initial_guess`` predicts, median-tested (recorded in ``history``):
    ``(pairs, displacements at ref (N, 3) µm, False)`` when they are numerous enough
    (``guess_min_fraction``), else None."""
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
        return guess_pairs, u0, False
    else:
        logger.info(
            "initial_guess matched %d of %d particles; running the bootstrap instead",
            guess_pairs.shape[0],
            n_min,
        )
    return None


def _confirm_guess(ref, dfm, guess, settings, spacing, eps_boot, eps_fixed, n_min, history):
    """``((pairs, field), history)`` grown from the guessed matches ``guess`` (pairs,
    starting field, refit), or from the global bootstrap where that links more particles and
    the guess links fewer than ``guess_confirm_fraction`` of them."""
    pairs, u_base, refit = guess
    guessed = _grow_and_fit(ref, dfm, pairs, u_base, refit, settings, spacing, eps_fixed, history)
    if guessed[0].shape[0] >= settings.guess_confirm_fraction * n_min:
        return guessed, history
    else:
        logger.info(
            "the matches grown from initial_guess link %d of %d particles; "
            "running the bootstrap as well",
            guessed[0].shape[0],
            n_min,
        )
        boot_history = list(history)
        booted = _bootstrap_and_fit(ref, dfm, settings, spacing, eps_boot, eps_fixed, boot_history)
        if booted is not None and booted[0].shape[0] > guessed[0].shape[0]:
            return booted, boot_history
        return guessed, history


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

    guess = None
    if initial_guess is not None:
        guess = _guess_pairs(ref, dfm, initial_guess, settings, spacing, eps_boot, n_min, history)
    if guess is not None:
        (pairs, fld), history = _confirm_guess(
            ref, dfm, guess, settings, spacing, eps_boot, eps_fixed, n_min, history
        )
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
