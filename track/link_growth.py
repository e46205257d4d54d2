"""Growth and validation of the linker's matches (:func:`track.matching.link_pair`, step 2
and 3): matched regions grown front by front from seed matches by local predictions, and
every iteration's matches validated by leave-one-out prediction and the normalised median
test."""

from __future__ import annotations

import logging
import time

import numpy as np
from scipy.spatial import cKDTree

from track.cloud_matchers import match_predicted
from track.link_settings import IterationRecord
from track.outliers import normalized_median_test
from track.regularize import fit_affine, local_polynomial_predict

logger = logging.getLogger(__name__)


def _robust_rms(residual: np.ndarray) -> float:
    """RMS of residual vectors estimated from their median squared length (Gaussian)."""
    if residual.shape[0] == 0:
        return float("inf")
    return float(np.sqrt(np.median(np.sum(residual**2, axis=1)) * 3.0 / 2.366))


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


def _validate(ref, dfm, pairs, u_base, settings, spacing, eps_fixed, grown, tabu):
    """One validation of ``pairs`` (:func:`_grow`, step b): every particle predicted
    leave-one-out from its matched neighbours relative to ``u_base``, the whole clouds
    matched again and the outliers removed by the normalised median test; ``tabu`` (the
    median test's rejects, kept out of the next growth) is updated in place.

    Returns ``(new pairs, candidate pairs, predictions, noise, calib, k)``: ``noise`` the
    per-axis leave-one-out noise (µm), ``calib`` the positions and leave-one-out residuals of
    the validated matches, ``k`` the median test's neighbour count."""
    ratio = settings.nn_ratio
    lo, hi = _tolerance_limits(settings, spacing)
    k_cal = settings.local_neighbors
    r_cal = settings.radii_um(spacing).local_radius_um
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
    return new, cand, pred, noise, calib, k


def _grow_front(ref, dfm, pairs, u_base, settings, spacing, noise, calib, tabu, passes):
    """Up to ``passes`` growth passes (:func:`_grow`, step a): the unmatched reference
    particles (not in ``tabu``) with at least three matched neighbours predicted from those
    neighbours, and their unambiguous matches to still free deformed particles within
    ``growth_q`` of their tolerance added. Returns (pairs, number of matches added)."""
    ratio = settings.nn_ratio
    m = dfm.shape[0]
    k_cal = settings.local_neighbors
    r_cal = settings.radii_um(spacing).local_radius_um
    grown = 0
    for _ in range(passes):
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
    return pairs, grown


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
    m = dfm.shape[0]
    noise = np.full(3, 0.05 * spacing)
    last_pred = None
    calib = None  # (positions, leave-one-out residuals) of the last validated matches
    seen: list[np.ndarray] = [_pair_keys(pairs, m)]
    stop = settings.max_iterations if stop is None else stop
    settle = not grow  # an iteration without growth passes
    tabu = np.zeros(ref.shape[0], dtype=bool)  # rejected by the last median test
    for it in range(start, stop + 1):
        ts = time.perf_counter()
        passes = 0 if settle else settings.growth_passes
        pairs, grown = _grow_front(
            ref, dfm, pairs, u_base, settings, spacing, noise, calib, tabu, passes
        )
        if refit_base:
            aff = fit_affine(ref[pairs[:, 0]], dfm[pairs[:, 1]] - ref[pairs[:, 0]])
            u_base = aff(ref)
        new, cand, pred, noise, calib, k = _validate(
            ref, dfm, pairs, u_base, settings, spacing, eps_fixed, grown, tabu
        )
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
