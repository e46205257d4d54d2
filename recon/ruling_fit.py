"""The fit of a ruling to the lenslet sums along one axis: spectral starts, least-squares
refinement, aliases, trimming and the uncertainty of the scale (:mod:`recon.pixel_size`,
method steps 3-5)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from .pixel_size_defaults import (
    AMBIGUITY_CHI2,
    HARMONICS,
    MAX_LINE_FRACTION,
    MAX_NFEV,
    MIN_COLUMNS,
    MIN_EXPLAINED,
    MIN_MOIRE_CYCLES,
    MIN_ROW_SAMPLES,
    MIN_ROWS,
    N_PEAKS,
    N_POLISH,
    N_REFINE,
    POLISH_WIDTHS,
    PROFILE_STOP,
    PROFILE_WIDTHS,
    ROW_TRIM,
    STRIP_MIN_DEG,
    TRIM_SIGMAS,
    PixelSizeError,
)
from .ruling_geometry import _ruled_region
from .ruling_model import ruling_coverage

log = logging.getLogger(__name__)


@dataclass
class _Data:
    """Lenslet sums of the ruled region, arranged with the scale along ``c``."""

    c: np.ndarray  # column coordinate (lenslets, centred on the region)
    r: np.ndarray  # row coordinate (lenslets, centred on the region)
    y: np.ndarray  # lenslet sums (polarity applied, normalised)
    g: np.ndarray  # row number of every sample, 0 .. n_rows - 1
    n_rows: int


def _subset(data: _Data, keep: np.ndarray) -> _Data:
    """The samples ``keep`` of ``data``, without rows left with too few of them."""
    counts = np.bincount(data.g[keep], minlength=data.n_rows)
    keep = keep & (counts[data.g] >= MIN_ROW_SAMPLES)
    if not keep.any():
        raise PixelSizeError("no lenslet row is explained by a ruling")
    _, g = np.unique(data.g[keep], return_inverse=True)
    return _Data(data.c[keep], data.r[keep], data.y[keep], g, int(g.max()) + 1)


def _solve_rows(R: np.ndarray, data: _Data) -> tuple[np.ndarray, np.ndarray]:
    """Per-row least squares ``y ≈ b + a R`` with ``a ≥ 0`` (the lines' contrast is known);
    returns the fit and ``(b, a)`` per row."""
    k = data.n_rows
    n = np.bincount(data.g, minlength=k).astype(float)
    sr = np.bincount(data.g, R, minlength=k)
    srr = np.bincount(data.g, R * R, minlength=k)
    sy = np.bincount(data.g, data.y, minlength=k)
    sry = np.bincount(data.g, R * data.y, minlength=k)
    det = n * srr - sr * sr
    ok = det > 1e-12 * np.maximum(n * srr, 1e-300)
    # The quadratic cost's minimum under a >= 0 is the free one, or a = 0 if that is negative.
    a = np.maximum(np.where(ok, (n * sry - sr * sy) / np.where(ok, det, 1.0), 0.0), 0.0)
    b = (sy - a * sr) / np.maximum(n, 1.0)
    coef = np.stack([b, a], axis=1)
    return b[data.g] + a[data.g] * R, coef


def _residuals(params, data: _Data, sigma: float) -> np.ndarray:
    q, theta, phi, rho = params
    R = ruling_coverage(data.c, data.r, q, theta, phi, rho, sigma)
    fit, _ = _solve_rows(R, data)
    return data.y - fit


def _mean_gain(params, data: _Data, sigma: float) -> float:
    q, theta, phi, rho = params
    R = ruling_coverage(data.c, data.r, q, theta, phi, rho, sigma)
    _, coef = _solve_rows(R, data)
    return float(np.average(coef[:, 1], weights=np.bincount(data.g, minlength=data.n_rows)))


@dataclass
class _Solution:
    params: np.ndarray
    cost: float
    gain: float
    jac: np.ndarray | None = None


def _fit(data: _Data, start, sigma: float, bounds) -> _Solution:
    lo, hi = bounds
    x0 = np.clip(np.asarray(start, dtype=float), lo + 1e-9, hi - 1e-9)
    res = optimize.least_squares(
        _residuals,
        x0,
        args=(data, sigma),
        bounds=(lo, hi),
        x_scale=np.array([1e-3, 1e-3, 1e-2, 1e-2]),
        diff_step=1e-6,
        max_nfev=MAX_NFEV,
    )
    log.debug("fit from %s: %s after %d evaluations, %s", start, res.x, res.nfev, res.message)
    r = _residuals(res.x, data, sigma)
    sol = _Solution(res.x, float(r @ r), _mean_gain(res.x, data, sigma), res.jac)
    log.debug("  cost %.4g gain %.3g", sol.cost, sol.gain)
    return sol


def _alias_family(params, bounds) -> list:
    """The other rulings whose lenslet sums share the frequency of ``params``' ruling.

    The sums sample the ruling's frequency vector ``F = q (cos θ, sin θ)`` (cycles per
    lenslet) on the integer lattice, so ``±F + (i, j)`` for integers ``i, j`` look alike;
    those within the searched ``q`` and ``θ`` (other than ``F``) are returned as start values
    ``(q, θ, φ, ρ)``.
    """
    q, theta, phi, rho = params
    lo, hi = bounds
    fx, fy = q * math.cos(theta), q * math.sin(theta)
    out = []
    k = math.ceil(2 * hi[0]) + 1
    for sgn in (1.0, -1.0):
        for i in range(-k, k + 1):
            for j in range(-k, k + 1):
                gx, gy = sgn * fx + i, sgn * fy + j
                if gx < 0:
                    gx, gy = -gx, -gy
                qq, th = math.hypot(gx, gy), math.atan2(gy, gx)
                if lo[0] <= qq <= hi[0] and lo[1] <= th <= hi[1] and abs(qq - q) > 1e-4 * q:
                    if all(abs(qq - o[0]) > 1e-4 * q or abs(th - o[1]) > 1e-3 for o in out):
                        out.append((qq, th, phi, rho))
    return out


def _fit_near(data: _Data, start, sigma: float, bounds, q_from: float) -> _Solution:
    """Fit from ``start`` with ``q`` kept within half a Fourier bin of it, and nearer to it
    than to ``q_from`` (the solution it is an alias of)."""
    lo, hi = (np.array(b, dtype=float) for b in bounds)
    q, theta = start[0], start[1]
    half = min(0.5 / (np.ptp(data.c) + 1), abs(q - q_from) / 2)
    lo[0], hi[0] = max(lo[0], q - half), min(hi[0], q + half)
    _, x = _grid_start(data, q, theta, sigma, 12, POLISH_WIDTHS)
    return _fit(data, x, sigma, (lo, hi))


def _spectral_starts(data: _Data, q_range, theta_range) -> list:
    """Start values ``(q, θ)``, ``θ`` within ``theta_range`` (radians), from the peaks of the
    lenslet sums' power spectrum."""
    ci = np.rint(data.c - data.c.min()).astype(int)
    ri = np.rint(data.r - data.r.min()).astype(int)
    nr, nc = ri.max() + 1, ci.max() + 1
    img = np.zeros((nr, nc))
    y = data.y - (np.bincount(data.g, data.y) / np.bincount(data.g))[data.g]
    img[ri, ci] = y
    img *= np.hanning(nc + 2)[1:-1][None, :]
    pr, pc = max(64, 8 * nr), max(256, 8 * nc)
    power = np.abs(np.fft.fft2(img, s=(pr, pc))) ** 2
    fr = np.fft.fftfreq(pr)
    fc = np.fft.fftfreq(pc)
    keep = fc >= 0
    power = power[:, keep]
    fc = fc[keep]
    # Suppress the lowest frequencies along the scale (row trends).
    power[:, fc < 1.0 / max(nc, 1)] = 0.0
    from scipy import ndimage

    peaks = (power == ndimage.maximum_filter(power, size=(5, 5), mode="wrap")) & (power > 0)
    order = np.argsort(power[peaks])[::-1][:N_PEAKS]
    pr_idx, pc_idx = np.nonzero(peaks)
    starts = []
    q_lo, q_hi = q_range
    for k in order:
        fx, fy = fc[pc_idx[k]], fr[pr_idx[k]]
        for h in HARMONICS:
            for m in range(-math.ceil(q_hi * h) - 1, math.ceil(q_hi * h) + 2):
                for n in range(-math.ceil(q_hi * h) - 1, math.ceil(q_hi * h) + 2):
                    for sgn in (1.0, -1.0):
                        gx, gy = sgn * (fx + m) / h, sgn * (fy + n) / h
                        if gx <= 0:
                            continue
                        qq, th = math.hypot(gx, gy), math.atan2(gy, gx)
                        if q_lo <= qq <= q_hi and theta_range[0] <= th <= theta_range[1]:
                            starts.append((qq, th))
    # Starts closer than half a Fourier bin (along the scale and across it) are one start.
    uniq: list = []
    for s in starts:
        if all(
            abs(s[0] - t[0]) * nc > 0.5
            or abs(s[0] * math.sin(s[1]) - t[0] * math.sin(t[1])) * nr > 0.5
            for t in uniq
        ):
            uniq.append(s)
    log.debug("%d start values from %d spectral peaks", len(uniq), len(order))
    return uniq


def _grid_start(data: _Data, q: float, theta: float, sigma: float, n_phi: int, widths) -> tuple:
    """Best ``(cost, (q, θ, φ, ρ))`` over a grid of phases and line widths, among the rulings
    of the expected contrast (positive mean gain) when there are any."""
    best, best_any = None, None
    for rho in widths:
        for phi in np.arange(n_phi) / n_phi:
            params = (q, theta, phi, rho)
            R = ruling_coverage(data.c, data.r, q, theta, phi, rho, sigma)
            fit, coef = _solve_rows(R, data)
            r = data.y - fit
            cost = float(r @ r)
            gain = float(np.average(coef[:, 1], weights=np.bincount(data.g)))
            if best_any is None or cost < best_any[0]:
                best_any = (cost, params)
            if gain > 0 and (best is None or cost < best[0]):
                best = (cost, params)
    return best if best is not None else best_any


@dataclass(frozen=True)
class AxisFit:
    """Fit of the ruling with its scale along one lenslet axis (internal result).

    ``q`` divisions per lenslet, ``theta_rad`` rotation of the scale direction from the
    lenslet axis, ``q_std`` the standard uncertainty of ``q``.
    """

    axis: str
    q: float
    q_std: float
    theta_rad: float
    theta_std_rad: float
    rho: float
    explained: float
    n_lenslets: int
    n_rows: int
    n_columns: int
    alternatives: list = field(default_factory=list)


def _axis_data(sums: np.ndarray, q0: float, theta_c: float) -> tuple[_Data, int]:
    """The lenslet sums of the ruled region (normalised, with their strip of the scale) and
    the region's length along the scale (lenslets);
    :class:`~recon.pixel_size_defaults.PixelSizeError` for a region too small to fit."""
    theta_strips = theta_c if abs(theta_c) > math.radians(STRIP_MIN_DEG) else 0.0
    region = _ruled_region(sums, q0, theta_strips)
    if region is None:
        raise PixelSizeError("the image shows no ruled region (no lenslet row is lit)")
    keep, strip, n_strips, n_along = region
    if n_strips < MIN_ROWS:
        raise PixelSizeError(
            f"the ruled region is {n_strips} lenslet(s) wide across the scale (need {MIN_ROWS})"
        )
    if n_along < MIN_COLUMNS:
        raise PixelSizeError(
            f"the ruled region spans only {n_along} lenslets along the scale (need {MIN_COLUMNS})"
        )
    if not keep.any():
        raise PixelSizeError("the ruled region has no row with enough whole lenslets")
    vv, uu = np.nonzero(keep)
    c = uu - uu.mean()
    r = vv - vv.mean()
    y = sums[keep]
    y = (y - np.mean(y)) / (float(np.std(y)) or 1.0)
    _, g = np.unique(strip[keep], return_inverse=True)
    n_rows = int(g.max()) + 1
    return _Data(c.astype(float), r.astype(float), y, g, n_rows), n_along


def _refined_solutions(data: _Data, q_range, theta_range, sigma: float, bounds) -> list:
    """The rulings of the expected contrast refined from the spectral starts (one per basin,
    the best few polished), best first; :class:`~recon.pixel_size_defaults.PixelSizeError`
    when there is none."""
    lo, hi = bounds
    starts = _spectral_starts(data, q_range, theta_range)
    if not starts:
        raise PixelSizeError("no periodic ruling found in the lenslet sums")
    screened = [_grid_start(data, q, th, sigma, 8, (0.15,)) for q, th in starts]
    screened.sort(key=lambda b: b[0])
    # One start per basin: starts closer than half a Fourier bin to a better one are dropped.
    n_cols_eff = np.ptp(data.c) + 1
    n_rows_eff = np.ptp(data.r) + 1
    kept: list = []
    for _cost, x in screened:
        if all(
            abs(x[0] - k[0]) * n_cols_eff > 0.5
            or abs(x[0] * math.sin(x[1]) - k[0] * math.sin(k[1])) * n_rows_eff > 0.5
            for k in kept
        ):
            kept.append(x)
        if len(kept) == N_REFINE:
            break
    sols = [_fit(data, x, sigma, (lo, hi)) for x in kept]
    # Polish the best few: the line width and phase can sit in a side minimum; search them
    # again on a finer grid at the refined scale and angle.
    sols.sort(key=lambda s: s.cost)
    for i, sol in enumerate(sols[:N_POLISH]):
        cost, x = _grid_start(data, sol.params[0], sol.params[1], sigma, 12, POLISH_WIDTHS)
        if cost < sol.cost:
            again = _fit(data, x, sigma, (lo, hi))
            if again.cost < sol.cost:
                sols[i] = again
    good = [s for s in sols if s.gain > 0]
    if not good:
        raise PixelSizeError(
            "no ruling of the expected contrast found (polarity 'bright': lines brighter than "
            "the ground; 'dark': darker)"
        )
    good.sort(key=lambda s: s.cost)
    return good


def _without_outliers(data: _Data, good: list, sigma: float, bounds, axis: str) -> tuple:
    """Robust re-fit: lenslets the best ruling does not explain (line ends crossing a row,
    dust, hot pixels), and whole rows it does not describe, are dropped and the competitive
    solutions re-fitted without them. Returns (data, solutions best first)."""
    lo, hi = bounds
    n, n_lin = len(data.y), 2 * data.n_rows
    res = _residuals(good[0].params, data, sigma)
    spread = 1.4826 * float(np.median(np.abs(res)))
    inliers = np.abs(res) <= TRIM_SIGMAS * spread if spread > 0 else np.ones(len(res), bool)
    # Whole rows the ruling does not describe (crossed by line ends) go as well.
    row_rms = np.sqrt(np.bincount(data.g, res**2) / np.bincount(data.g))
    if data.n_rows >= 3:
        inliers &= (row_rms <= ROW_TRIM * np.median(row_rms))[data.g]
    if inliers.all():
        return data, good
    s2_all = good[0].cost / max(n - n_lin - 4, 1)
    g_before, n_rows_before = data.g, data.n_rows
    data = _subset(data, inliers)
    keep = [s for s in good if (s.cost - good[0].cost) / s2_all < 10 * AMBIGUITY_CHI2]
    good = [_fit(data, s.params, sigma, (lo, hi)) for s in keep]
    good = sorted((s for s in good if s.gain > 0), key=lambda s: s.cost)
    if not good:
        raise PixelSizeError("no ruling of the expected contrast left after outliers")
    log.debug(
        "axis %s: %d outlying lenslets dropped, per row %s",
        axis,
        int((~inliers).sum()),
        np.bincount(g_before[~inliers], minlength=n_rows_before),
    )
    return data, good


def _with_aliases(data: _Data, good: list, sigma: float, bounds) -> list:
    """The solutions with the aliases of the best ruling added, best first.

    The aliases (the same frequency folded, or mirrored, by the lenslet sampling) fit the
    sums almost alike when the scale is near a half-integer number of divisions per lenslet:
    each is fitted, confined to its own neighbourhood, so the comparison (and the ambiguity
    test) never depends on where the starts happened to converge."""
    for _ in range(3):
        leader = good[0]
        aliases = [
            _fit_near(data, a, sigma, bounds, leader.params[0])
            for a in _alias_family(leader.params, bounds)
        ]
        good = sorted([*good, *(a for a in aliases if a.gain > 0)], key=lambda s: s.cost)
        if good[0] is leader:
            break
    return good


def _explained(data: _Data, best, total: float, axis: str) -> tuple[float, float]:
    """The noise variance of the best ruling's fit and the share of the variation within
    rows that it explains, per degree of freedom (adjusted R²: fair between the two axes,
    which have different numbers of rows); :class:`~recon.pixel_size_defaults.PixelSizeError` below
    :data:`~recon.pixel_size_defaults.MIN_EXPLAINED`."""
    n, n_lin = len(data.y), 2 * data.n_rows
    dof = max(n - n_lin - 4, 1)
    s2 = max(best.cost / dof, 1e-12 * total)  # a noise-free image still has rounding
    within = float(
        np.sum((data.y - (np.bincount(data.g, data.y) / np.bincount(data.g))[data.g]) ** 2)
    )
    explained = 1.0 - s2 / (within / max(n - data.n_rows, 1)) if within > 0 else 0.0
    log.debug("axis %s: R2 %.4f, adjusted %.4f", axis, 1 - best.cost / total, explained)
    if explained < MIN_EXPLAINED:
        raise PixelSizeError(
            f"no periodic ruling found: the best ruling explains only {100 * explained:.0f} % "
            "of the lenslet sums' variation"
        )
    return s2, explained


def _fit_axis(
    sums: np.ndarray,
    q0: float,
    tolerance: float,
    theta_c: float,
    window: float,
    sigma: float,
    axis: str,
) -> _AxisState:
    """Fit the ruling with its scale at ``θ ∈ theta_c ± window`` (radians) from the columns
    of ``sums``."""
    data, n_along = _axis_data(sums, q0, theta_c)
    q_range = (q0 / (1 + tolerance), q0 / (1 - tolerance))
    th_lo, th_hi = theta_c - window, theta_c + window
    lo = np.array([q_range[0], th_lo, -np.inf, 1e-3])
    hi = np.array([q_range[1], th_hi, np.inf, MAX_LINE_FRACTION])
    total = float(data.y @ data.y)
    good = _refined_solutions(data, q_range, (th_lo, th_hi), sigma, (lo, hi))
    data, good = _without_outliers(data, good, sigma, (lo, hi), axis)
    good = _with_aliases(data, good, sigma, (lo, hi))
    best = good[0]
    s2, explained = _explained(data, best, total, axis)
    cycles = _moire_cycles(data, best.params)
    log.debug("axis %s: moiré periods across the band %.2f", axis, cycles)
    if cycles < MIN_MOIRE_CYCLES:
        raise PixelSizeError(
            f"the best-fitting ruling ({best.params[0]:.3f} divisions per lenslet, "
            f"{math.degrees(best.params[1]):+.1f}° from the lenslet {axis} axis) makes a moiré "
            f"with the lenslets of only "
            f"{cycles:.1f} period(s) across the ruled band (need {MIN_MOIRE_CYCLES:g}): it "
            "follows the band's slow variations, not its lines, which the lenslets do not "
            "resolve here; turn the micrometer or measure a ruling of other divisions"
        )
    consistent = _shared_gain_explained(data, best.params, sigma)
    log.debug("axis %s: explained with one gain for all rows %.4f", axis, consistent)
    return _AxisState(axis, data, best, good, s2, (lo, hi), sigma, explained, consistent, n_along)


def _moire_cycles(data: _Data, params) -> float:
    """Periods of the moiré of ruling ``params`` with the lenslets across the ruled region.

    The lenslet sums see the frequency vector ``F = q (cos θ, sin θ)`` folded to the nearest
    lattice point, ``F − round(F)``; a ruling whose folded frequency makes fewer periods
    across the region than :data:`~recon.pixel_size_defaults.MIN_MOIRE_CYCLES` is not told
    apart from a slow variation of the band (near a whole number of divisions per lenslet along both
    axes).
    """
    q, theta = params[0], params[1]
    f = np.array([q * math.cos(theta), q * math.sin(theta)])
    f -= np.rint(f)
    norm = float(np.hypot(*f))
    if norm == 0.0:
        return 0.0
    extent = float(np.ptp((data.c * f[0] + data.r * f[1]) / norm)) + 1.0
    return norm * extent


def _shared_gain_explained(data: _Data, params, sigma: float) -> float:
    """Share of the within-row variation explained with one gain for all rows.

    A real ruling crosses every row (strip) of its region with the same contrast; a ruling
    fitted to noise or to the band's edges only fits with gains that differ from row to
    row (:data:`~recon.pixel_size_defaults.MIN_CONSISTENT`).
    """
    q, theta, phi, rho = params
    R = ruling_coverage(data.c, data.r, q, theta, phi, rho, sigma)
    onehot = np.zeros((len(R), data.n_rows))
    onehot[np.arange(len(R)), data.g] = 1.0
    A = np.column_stack([onehot, R])
    coef, *_ = np.linalg.lstsq(A, data.y, rcond=None)
    res = data.y - A @ coef
    within = data.y - (np.bincount(data.g, data.y) / np.bincount(data.g))[data.g]
    total = float(within @ within)
    return 1.0 - float(res @ res) / total if total > 0 else 0.0


@dataclass
class _AxisState:
    """A fitted axis before its uncertainty is computed (see :func:`_finish_axis`)."""

    axis: str
    data: _Data
    best: _Solution
    good: list
    s2: float
    bounds: tuple
    sigma: float
    explained: float
    consistent: float
    n_columns: int


def _finish_axis(st: _AxisState) -> AxisFit:
    """Uncertainty and competing solutions of a fitted axis."""
    best = st.best
    q_std, th_std = _uncertainty(st.data, best, st.sigma, st.s2, st.bounds)
    alternatives: list = []
    for s in st.good[1:]:
        if abs(s.params[0] - best.params[0]) > 1e-4 * best.params[0]:
            chi2 = max((s.cost - best.cost) / st.s2, 0.0)
            if not any(abs(s.params[0] - a[0]) < 1e-4 * s.params[0] for a in alternatives):
                alternatives.append((float(s.params[0]), float(chi2)))
    alternatives.sort(key=lambda a: a[1])
    # A scale that fits about as well (an alias near a half-integer number of divisions per
    # lenslet, say) is as likely as the best one: the uncertainty must reach it.
    close = [a for a in alternatives if a[1] < AMBIGUITY_CHI2]
    if close:
        q_std = max(q_std, *(abs(a[0] - best.params[0]) for a in close))
    return AxisFit(
        axis=st.axis,
        q=float(best.params[0]),
        q_std=q_std,
        theta_rad=float(best.params[1]),
        theta_std_rad=th_std,
        rho=float(best.params[3]),
        explained=st.explained,
        n_lenslets=len(st.data.y),
        n_rows=st.data.n_rows,
        n_columns=st.n_columns,
        alternatives=alternatives,
    )


def _uncertainty(data, best: _Solution, sigma, s2, bounds) -> tuple[float, float]:
    """Standard uncertainties of ``q`` and ``θ``.

    ``θ``: linearised (Jacobian at the optimum, noise variance ``s2``). ``q``: from the profile
    of the cost over ``q`` (``θ``, ``φ``, ``ρ`` re-fitted at every ``q``). From the optimum
    the profile is followed outwards on each side in doubling steps ``Δ`` until it rises by
    more than :data:`~recon.pixel_size_defaults.PROFILE_STOP` noise variances or reaches the
    searched range; every point gives ``Δ / √max(rise / s2, 1)`` — the standard deviation of a
    parabola through it, and at least ``Δ`` where the profile is flat — and the largest of these is
    the uncertainty. For a well-determined scale (parabolic profile) that is the usual ``Δχ² = 1``
    value; where the lenslets cannot tell scales apart (a coarse ruling whose lines all stay inside
    their lenslets) the profile is a plateau, bumpy by a few variances, and the uncertainty spans it
    instead of the first bump.
    """
    J = best.jac
    try:
        cov = np.linalg.pinv(J.T @ J) * s2
        q_lin = float(math.sqrt(max(cov[0, 0], 0.0)))
        th_lin = float(math.sqrt(max(cov[1, 1], 0.0)))
    except np.linalg.LinAlgError:
        q_lin, th_lin = math.inf, math.inf
    q_best = best.params[0]
    lo, hi = bounds

    def refit(qq: float, start) -> tuple[float, np.ndarray]:
        r = optimize.least_squares(
            lambda p: _residuals((qq, *p), data, sigma),
            np.clip(start, lo[1:] + 1e-9, hi[1:] - 1e-9),
            bounds=(lo[1:], hi[1:]),
            x_scale=np.array([1e-3, 1e-2, 1e-2]),
            diff_step=1e-6,
            max_nfev=MAX_NFEV,
        )
        return 2 * r.cost, r.x

    def prof(qq: float, previous) -> tuple[float, np.ndarray]:
        # From the previous profile point (follows a plateau), from the optimum, and from
        # narrow lines (inside a lenslet a narrow line may sit anywhere: the plateau).
        _, x = _grid_start(data, qq, best.params[1], sigma, 8, PROFILE_WIDTHS)
        starts = [previous, best.params[1:], np.asarray(x[1:])]
        return min((refit(qq, st) for st in starts), key=lambda t: t[0])

    q_range = hi[0] - lo[0]
    base = min(q_lin, q_range) if math.isfinite(q_lin) and q_lin > 0 else 1e-4 * q_best
    widths = []
    for sgn in (-1.0, 1.0):
        step, previous, width = max(base, 1e-6 * q_best), best.params[1:], 0.0
        while True:
            qq = q_best + sgn * step
            if not lo[0] <= qq <= hi[0]:
                # The searched range ends on a plateau: the distance to its end is a bound.
                edge = abs(q_best - (lo[0] if sgn < 0 else hi[0]))
                width = max(width, edge) if width >= step / 2 else width
                break
            cost, previous = prof(qq, previous)
            rise = max(cost - best.cost, 0.0) / s2
            if rise > PROFILE_STOP:
                break
            width = max(width, step / math.sqrt(max(rise, 1.0)))
            step *= 2.0
        widths.append(width)
    return max(min(q_lin, q_range), *widths), th_lin
