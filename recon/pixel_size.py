"""Object-space pixel size from the light-field image of a stage micrometer (paper §4).

The paper calibrates the in-plane scale of its light-field microscope — the size of one sensor
pixel in object space, about 1.64 µm per pixel at 4× — from the image of a stage micrometer
(paper §4: "To obtain in-plane pixel pitch ... an initial calibration step was required ...
a light-field image of a stage micrometer"). A real microscope's magnification differs from
the nominal one (tube-lens and relay tolerances, a camera adapter), so the lateral scale of
the reconstructed volumes must come from such a measurement, not from catalogue values.
:func:`measure_pixel_size` makes the measurement, :func:`apply_pixel_size` gives the scene's
optics the measured magnification, and ``recon pixel-size`` (:mod:`recon.cli`) runs both and
writes the record (:func:`build_record`) and, optionally, the corrected scene.

What the image holds
--------------------
The micrometer is a plane of lines every ``D`` µm in the native object plane (z = 0). There
every object point sends all its light through one lenslet — the one whose object-space
footprint (pitch ``P = mla_pitch / M``: 25 µm for the paper's optics) contains it — and the
pixels behind that lenslet record the light's direction, not where in the footprint it came
from. The image therefore carries the ruling only as *lenslet sums*: the micrometer averaged
over each footprint, sampled once per lenslet. Nothing finer is recorded, and:

- ``D`` below two lenslets (the paper's 10 µm divisions): the ruling is aliased; the sums show
  a moiré whose frequency is ``q = P / D`` divisions per lenslet folded into the lenslets'
  Nyquist band. The fold is undone with the nominal scale — only unfoldings within
  ``tolerance`` (±20 %) of the nominal magnification are considered — and with the lines'
  contrast: the mirror-image unfolding ``q' = n − q`` reproduces the sums only with dark
  lines on a bright ground (or lines wider than the gaps), so with bright lines narrower than
  the gaps (``polarity="bright"``, the default; ``"dark"`` for the opposite) the right one
  fits better. The moiré then pins the scale finely (its phase walks by ``q`` periods per
  lenslet across the field). Near a half-integer ``q`` (2.5 for the paper: nominal 4×,
  10 µm) the two unfoldings meet and the contrast barely separates them: on a 20-lenslet
  field a magnification within about ±1 % of that point is either refused as ambiguous
  or returned with an uncertainty wide enough to hold both (on the paper's 86-lenslet field
  the nominal magnification itself was measured to 0.01 %). Near a whole number the moiré
  becomes as long as the field and the scale is refused as well (``q`` = 2.94 on 20
  lenslets).
- Rotated: the lenslet cells average a ruling of frequency ``F = q (cos θ, sin θ)`` with
  weight ``sinc(F_x) sinc(F_y)``; away from the lenslet axes both factors are small (10 µm
  lines on 25 µm lenslets: 0.13 at 0°, 0.09 at 10°, 0.006–0.014 at 25–60°), and in a
  band of 20 lenslets the lines are then lost in the noise. The direction of the scale is
  taken from the ruled band (unaliased, :func:`ruling_direction`); where the lines are not
  resolved along it the measurement is refused, naming the angle.
- Out of focus: the lines are blurred over ``2 z NA``; the lenslets' views then see the
  micrometer with parallax, which :func:`defocus_um` measures. A micrometer more than
  ``MAX_DEFOCUS_DIVISIONS · D / NA`` out of focus (12.5 µm for 10 µm divisions at NA 0.2)
  is refused, with the estimated defocus.
- ``D`` above two lenslets: each line lights one column of lenslets and its position inside
  it is lost. The scale then comes from the vernier of many lines against the lenslets (and
  from lines of a slightly rotated micrometer crossing lenslet borders); 16–21 lines of
  100 µm divisions gave 0.03 %, but 5 lines (a 20-lenslet field) leave it undetermined to
  ±3 %, which is refused (``max_relative_std``). A micrometer defocused by 60–120 µm spreads
  each line over several lenslets and gave 0.1–0.5 % on that small field, with uncertainties
  2–4× too small (the model's lines are boxes, not defocus discs): not validated.

Method
------
1. Lenslet sums: the pixels within ``0.4`` pitch of each lenslet centre (the rim of a lenslet
   image overlaps the neighbours' and would leak their light) are summed, on the lenslet grid
   of ``recon calibrate`` (``grid``) or the scene's nominal grid (:func:`nominal_grid`: the
   pitch on the sensor, ``px_per_lenslet``, does not depend on the magnification); lenslets
   cut by the image border are dropped.
2. Direction and ruled region: the scale's direction ``θ_b`` is that of the ruled band
   (:func:`ruling_direction`); the scale is fitted against the nearer lenslet axis, within
   ±:data:`DIRECTION_WINDOW_DEG` of ``θ_b``. Ruled region: the contiguous block of strips
   along the scale (lenslet rows within :data:`STRIP_MIN_DEG` of an axis), around the
   brightest, whose mean over the background reaches 3/4 of the brightest's (strips
   crossed by the whole ruling, not only by its longer marks), and the longest run lit
   along the scale in them. ``recon pixel-size`` first refuses a micrometer out of focus
   (:func:`defocus_um`).
3. Model: the sums of row ``r`` are ``b_r + a_r R(c, r)`` with a per-row offset and gain
   ``a_r ≥ 0`` (the contrast is known) and ``R`` the exact average over lenslet ``(c, r)`` of a
   ruling of lines of relative width ``ρ ≤ 1/2`` (a box blurred by the objective's
   diffraction), phase ``Ψ = q (ξ cos θ + η sin θ) + φ`` in lenslet coordinates ``(ξ, η)``:
   ``q`` is the scale, ``θ`` the rotation. :func:`ruling_coverage` computes the cell average in
   closed form (double antiderivative of the profile); the linear parameters are solved for
   every trial of ``(q, θ, φ, ρ)`` (variable projection).
4. Search: the peaks of the 2-D power spectrum of the sums, unfolded by every integer shift
   and harmonic order that lands in the searched range, are screened over the phase, and the
   best are refined by least squares (:func:`scipy.optimize.least_squares`). Lenslets and
   rows the best ruling leaves unexplained (line ends crossing a row, dust) are dropped and the
   fit repeated; every alias of the winner (``±F + (i, j)`` for its frequency vector ``F``)
   is then fitted in its own neighbourhood, so that the choice never depends on where a start
   happened to converge. A best ruling that needs a gain per strip (one gain explains less than
   :data:`MIN_CONSISTENT`) or whose moiré makes fewer than :data:`MIN_MOIRE_CYCLES`
   periods across the region fits the band's slow variations, not its lines: refused.
5. Uncertainty: the profile of the cost over ``q`` (``θ, φ, ρ`` re-fitted) is followed out
   from the optimum until it rises by 100 noise variances; each point gives a standard
   deviation ``Δq / √max(rise, 1)``, and the largest counts (the usual ``Δχ² = 1`` for a
   parabolic profile; the plateau's width where the lenslets cannot tell scales apart). Any
   other scale that fits within :data:`AMBIGUITY_CHI2` noise variances widens it to reach
   that scale. The uncertainty covers the noise and the fit; not an error in the lenslet
   pitch (use ``recon calibrate``) or in the stated division.

Output: ``um_per_px = D q / p`` (``p`` the lenslet pitch in pixels), its uncertainty, the
implied magnification ``M_nominal · um_per_px_nominal / um_per_px`` and the scale's direction.

Measured (tests/recon/test_pixel_size.py; lfsim micrometers through microscopes 4 % below and
5 % above the scene's magnification, rotated by up to 2°, SNR 17–50): 10 µm divisions on a
20-lenslet field within 0.09 %; 100 µm divisions on an 80-lenslet field within 0.03 %;
reconstructed particles 170–184 µm from the axis within 0.24 % of their distance from it
(about 5 % off with the nominal scene). A Mitsuba-traced micrometer on the paper's 1280 × 800 px
scene, magnification +3 %: 1.61813 ± 0.00002 µm/px against 1.61812. Over rotations 0–90°,
defocus 0–300 µm, SNR 5–50 and magnification ±10 % (``benchmarks/pixel_size_sweep.py
--full``, 288 lfsim micrometers of 10 µm divisions on ``scenes/small.xml``): 40 measured, every
one within 2σ of the truth; 248 refused (every defocused one; in focus, most at 25–60°);
none silently wrong.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import optimize, special

from .errors import InputError, ReconError

log = logging.getLogger(__name__)

#: ``"format"`` entry of the files ``recon pixel-size`` writes.
PIXEL_SIZE_FORMAT = "hrvptm.recon.pixel_size"
#: Default relative tolerance on the magnification: unfoldings of the aliased ruling are
#: searched within ``M_nominal · (1 ± tolerance)``.
DEFAULT_TOLERANCE = 0.2
#: Default largest rotation (degrees) of the micrometer's scale from the nearer image axis
#: (45: any direction).
DEFAULT_MAX_ROTATION_DEG = 45.0
#: A second solution whose cost exceeds the best one's by less than this many noise variances
#: makes the measurement ambiguous.
AMBIGUITY_CHI2 = 25.0
#: Rows whose mean signal is below this fraction of the brightest row's are not used.
ROW_FRACTION = 0.75
#: The fit's explained fraction of the lenslet sums' variance below which no ruling is found.
MIN_EXPLAINED = 0.5
#: Largest line width over the division: lines are narrower than the gaps between them
#: (what tells a bright-line ruling from its mirror-image alias, see the module docstring).
MAX_LINE_FRACTION = 0.5
#: Peaks of the power spectrum of the lenslet sums, and the harmonic orders they are taken
#: for, that give start values.
N_PEAKS = 4
HARMONICS = (1, 2)
#: Start values refined by least squares (the best by a coarse phase/width search).
N_REFINE = 6
#: Most cost evaluations of one least-squares refinement (a good start converges in ~10).
MAX_NFEV = 60
#: Lenslets whose residual exceeds this many robust standard deviations are dropped.
TRIM_SIGMAS = 4.0
#: Rows whose RMS residual exceeds this multiple of the median row's are dropped.
ROW_TRIM = 2.5
#: Rows left with fewer lenslets than this after trimming are dropped.
MIN_ROW_SAMPLES = 5
#: Line widths (fractions of a division) from which the cost profile is also re-fitted.
PROFILE_WIDTHS = (0.02, 0.1)
#: The cost profile over the scale is followed until it rises by this many noise variances.
PROFILE_STOP = 100.0
#: Default largest relative standard uncertainty of the scale that is accepted as a
#: measurement (a coarse ruling in a small field may not determine the scale at all).
DEFAULT_MAX_RELATIVE_STD = 0.01
#: Solutions whose phase and line width are searched again after the first refinement.
N_POLISH = 2
#: Line widths (fractions of a division) of that search.
POLISH_WIDTHS = (0.02, 0.07, 0.15, 0.25, 0.4)
#: Minimum number of lenslets along the scale and of rows in the ruled region.
MIN_COLUMNS = 8
MIN_ROWS = 2
#: Scale directions (degrees from the nearer lenslet axis) up to which the ruled region is
#: taken in lenslet rows; beyond, in strips along the scale's direction.
STRIP_MIN_DEG = 5.0
#: Scale directions (degrees from the nearer lenslet axis) beyond which a failed fit is
#: reported with the angle as its likely cause (the lenslets average rotated lines out).
ROTATED_DEG = 15.0
#: Half-width (degrees) of the window of scale directions searched about the direction of the
#: ruled band (:func:`ruling_direction`).
DIRECTION_WINDOW_DEG = 2.0
#: Width (lenslets) of the Gaussian of :func:`ruling_direction`.
DIRECTION_KERNEL = 1.0
#: Largest defocus accepted, as a fraction of ``division / NA``: beyond, the defocus blur
#: (diameter ``2 z NA``) spreads a line over more than half a division, which the model of
#: in-focus lines does not describe (``D = 10 µm``, NA 0.2: 12.5 µm).
MAX_DEFOCUS_DIVISIONS = 0.25
#: Least share of the within-strip variation that the ruling explains with one contrast for
#: all strips (a real ruling crosses every strip of its band alike; a fit to noise or to
#: the band's edges needs a contrast per strip).
MIN_CONSISTENT = 0.5
#: Least number of periods of the moiré (the ruling folded by the lenslet sampling) across
#: the ruled region.
MIN_MOIRE_CYCLES = 2.0
#: Least contrast of the ruled band's direction (:func:`ruling_direction`): lfsim
#: micrometers of 10 µm divisions on ``scenes/small.xml`` 150–900, of 100 µm divisions 9;
#: particle images 1.6–5.5, a white image 6, noise 5.
MIN_BAND_CONTRAST = 8.0
#: When the ruling cannot be measured with the division given, these multiples of it are
#: tried, to name a wrong division (accepted there with this relative uncertainty).
DIVISION_FACTORS = (10.0, 0.1)
DIAGNOSIS_RELATIVE_STD = 0.1

#: Radius (fraction of the lenslet pitch) of the disc of pixels summed behind each lenslet.
SUM_RADIUS = 0.4

POLARITIES = ("bright", "dark")
AXES = ("auto", "x", "y")


class PixelSizeError(ReconError, ValueError):
    """No periodic ruling could be measured in the image (or it is ambiguous)."""


# -- lenslet sums ---------------------------------------------------------------------------
def lenslet_sums(
    image: np.ndarray, grid, radius_fraction: float | None = SUM_RADIUS
) -> tuple[np.ndarray, int, int]:
    """Sum the pixels behind every lenslet that lies wholly inside the image.

    Parameters
    ----------
    image : ndarray, shape (height, width)
        Light-field image (any units).
    grid : recon.calibration.LensletGrid
        Lenslet grid of the image (pixels).
    radius_fraction : float, optional
        Sum only the pixels whose centres lie within ``radius_fraction · pitch`` of the
        lenslet centre (default :data:`SUM_RADIUS`): the rim of a lenslet image overlaps its
        neighbours' (diffraction, f-number mismatch), and that cross-talk would look like
        light from the neighbouring footprints. ``None`` sums the whole cell.

    Returns
    -------
    sums : ndarray, shape (n_v, n_u)
        Sum over each lenslet ``(u, v)``; NaN for lenslets whose cell (one pitch square about
        the centre) leaves the image.
    u0, v0 : int
        Lenslet indices of ``sums[0, 0]``.
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    uv = grid.lenslet_index(np.stack([xx + 0.5, yy + 0.5], axis=-1))
    near = np.rint(uv)
    iu = near[..., 0].astype(np.int64)
    iv = near[..., 1].astype(np.int64)
    weight = img
    if radius_fraction is not None:
        off = np.hypot(uv[..., 0] - near[..., 0], uv[..., 1] - near[..., 1])
        weight = np.where(off <= radius_fraction, img, 0.0)
    u0, v0 = int(iu.min()), int(iv.min())
    nu, nv = int(iu.max()) - u0 + 1, int(iv.max()) - v0 + 1
    flat = (iv - v0) * nu + (iu - u0)
    sums = np.bincount(flat.ravel(), weights=weight.ravel(), minlength=nu * nv).reshape(nv, nu)
    # A lenslet is whole when the four corners of its cell lie inside the image.
    vv, uu = np.mgrid[v0 : v0 + nv, u0 : u0 + nu]
    ok = np.ones((nv, nu), dtype=bool)
    for du in (-0.5, 0.5):
        for dv in (-0.5, 0.5):
            xy = grid.centers(np.c_[(uu + du).ravel(), (vv + dv).ravel()]).reshape(nv, nu, 2)
            ok &= (xy[..., 0] >= 0) & (xy[..., 0] <= w) & (xy[..., 1] >= 0) & (xy[..., 1] <= h)
    sums[~ok] = np.nan
    return sums, u0, v0


# -- the ruling model -----------------------------------------------------------------------
class _Profile:
    """Antiderivatives of a periodic ruling (period 1) of lines ``box(ρ) ⊛ N(0, σ²)``.

    ``P(x) = H(x) − ρ x`` and ``Q(x) = ∫₀ˣ P − P̄ x`` are periodic, where ``H`` is the
    antiderivative of the profile (``H' = h``, the line coverage) and ``P̄`` the mean of ``P``.
    Only the lines within ``ρ/2 + 7σ`` of ``[0, 1)`` contribute (``m`` below).
    """

    def __init__(self, rho: float, sigma: float) -> None:
        self.rho, self.sigma = rho, sigma
        # For f in [0, 1) only lines m with |f + m| < ρ/2 + 7σ differ from 0 or ρ.
        k = max(math.ceil(rho / 2 + 7 * sigma), 1)
        self.m = np.arange(-k, k, dtype=float)
        self.pos = (self.m >= 0).astype(float)
        self.jm = self._j(self.m)
        self.pbar = float(self._int_p(np.array([1.0]))[0])

    def _phi(self, x):
        return np.exp(-0.5 * (x / self.sigma) ** 2) * (1.0 / math.sqrt(2 * math.pi))

    def _g(self, t):
        """Cumulative of one line (0 before it, ``ρ`` after it)."""
        s, r = self.sigma, self.rho / 2
        hi, lo = t + r, t - r
        return (
            hi * special.ndtr(hi / s)
            - lo * special.ndtr(lo / s)
            + s * (self._phi(hi) - self._phi(lo))
        )

    def _j(self, t):
        """Antiderivative of :meth:`_g`."""
        s, r = self.sigma, self.rho / 2
        hi, lo = t + r, t - r
        return 0.5 * (
            (hi * hi + s * s) * special.ndtr(hi / s)
            - (lo * lo + s * s) * special.ndtr(lo / s)
            + s * (hi * self._phi(hi) - lo * self._phi(lo))
        )

    def p(self, x: np.ndarray) -> np.ndarray:
        f = x - np.floor(x)
        t = f[..., None] + self.m
        return (self._g(t) - self.rho * self.pos).sum(axis=-1) - self.rho * f

    def _int_p(self, f: np.ndarray) -> np.ndarray:
        t = f[..., None] + self.m
        s = (self._j(t) - self.jm - self.rho * self.pos * f[..., None]).sum(axis=-1)
        return s - 0.5 * self.rho * f * f

    def q(self, x: np.ndarray) -> np.ndarray:
        f = x - np.floor(x)
        return self._int_p(f) - self.pbar * f


def ruling_coverage(
    c: np.ndarray, r: np.ndarray, q: float, theta: float, phi: float, rho: float, sigma: float
) -> np.ndarray:
    """Mean line coverage of the lenslet cells ``[c ± ½] × [r ± ½]`` (lenslet units).

    The ruling has phase ``Ψ(ξ, η) = q (ξ cos θ + η sin θ) + φ`` (cycles; lines at integer
    ``Ψ``), lines of relative width ``ρ`` blurred by a Gaussian of ``σ`` (both in periods).
    The cell average is exact: the second difference of the profile's double antiderivative
    over the cell's corners, divided by the cell's area in ``Ψ`` units.

    Returns
    -------
    ndarray
        Coverage in ``[0, 1]`` (``ρ`` on average), same shape as ``c``.
    """
    prof = _Profile(rho, sigma)
    span = q * math.cos(theta)  # Ψ change across a cell along ξ
    delta = q * math.sin(theta)  # ... along η
    a = q * ((c - 0.5) * math.cos(theta) + (r - 0.5) * math.sin(theta)) + phi
    b = a + span
    if abs(delta) < 1e-5:
        pb, pa = np.split(prof.p(np.concatenate([b, a]) + delta / 2), 2)
        return rho + (pb - pa) / span
    q4 = np.split(prof.q(np.concatenate([b + delta, b, a + delta, a])), 4)
    return rho + (q4[0] - q4[1] - q4[2] + q4[3]) / (span * delta)


# -- fit ------------------------------------------------------------------------------------
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


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of ``True`` in a 1-D mask."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def _ruled_region(
    sums: np.ndarray, q0: float, theta_strips: float = 0.0
) -> tuple[np.ndarray, np.ndarray, int, int] | None:
    """The ruled region of ``sums`` (lenslet sums, scale near the columns' direction).

    The lenslets are grouped in strips one lenslet wide along the scale: the rows when
    ``theta_strips`` (radians, the scale's direction from the columns) is 0, else strips
    tilted by it (lenslet ``(u, v)`` is in strip ``round(v cos θ − u sin θ)``).
    Strips: the contiguous block, around the brightest strip, of strips whose mean over the
    background reaches :data:`ROW_FRACTION` of the brightest's — a ruling crosses a block of
    strips. Along the scale: the longest run lit in those strips after smoothing over one
    division.

    Returns
    -------
    keep : ndarray of bool, shape of ``sums``
        The lenslets of the region (whole lenslets of strips with enough of them).
    strip : ndarray of int, shape of ``sums``
        Strip number of every lenslet.
    n_strips, n_along : int
        Strips of the region and its length along the scale (lenslets).
    """
    fin = np.isfinite(sums)
    if fin.sum() < MIN_COLUMNS:
        return None
    vv, uu = np.mgrid[0 : sums.shape[0], 0 : sums.shape[1]]
    ct, st = math.cos(theta_strips), math.sin(theta_strips)
    t = np.rint(vv * ct - uu * st).astype(int)
    a = np.rint(uu * ct + vv * st).astype(int)
    t -= t.min()
    a -= a.min()
    bg = float(np.nanpercentile(sums, 5))
    n_t = np.bincount(t[fin], minlength=t.max() + 1)
    s_t = np.bincount(t[fin], sums[fin], minlength=t.max() + 1)
    strip_mean = np.where(n_t >= MIN_COLUMNS, s_t / np.maximum(n_t, 1) - bg, -np.inf)
    top = int(np.argmax(strip_mean))
    if not np.isfinite(strip_mean[top]) or strip_mean[top] <= 0:
        return None
    run = next(r for r in _runs(strip_mean >= ROW_FRACTION * strip_mean[top]) if r[0] <= top < r[1])
    in_strips = fin & (t >= run[0]) & (t < run[1])
    n_a = np.bincount(a[in_strips], minlength=a.max() + 1)
    s_a = np.bincount(a[in_strips], sums[in_strips], minlength=a.max() + 1)
    prof = np.where(n_a > 0, s_a / np.maximum(n_a, 1) - bg, 0.0)
    win = max(1, math.ceil(1.0 / q0)) + 1
    smooth = np.convolve(prof, np.ones(win) / win, mode="same")
    runs = _runs(smooth > 0.2 * smooth.max())
    first, stop = max(runs, key=lambda r: r[1] - r[0])
    keep = in_strips & (a >= first) & (a < stop)
    counts = np.bincount(t[keep], minlength=t.max() + 1)
    keep &= counts[t] >= MIN_COLUMNS
    return keep, t, int(run[1] - run[0]), int(stop - first)


def ruling_direction(sums: np.ndarray) -> tuple[float, float]:
    """Direction of the ruled band in lenslet sums: the direction of the scale, unaliased.

    A micrometer's lines are all cut to lengths that start together, so the ruled region is a
    band along the scale; the lenslet sums alias the lines' period but not the band. Its
    direction is the one along which the sums, projected onto the perpendicular direction,
    have the sharpest profile: the largest ``wᵀ K w`` with ``w = sums − mean`` and ``K`` a
    Gaussian of :data:`DIRECTION_KERNEL` lenslets in the projected distance between two
    lenslets (a smooth projection, free of the lattice's preference for its own axes),
    searched every degree and refined every 0.05° within ±1.5°. On the lfsim micrometers of
    ``scenes/small.xml`` (0–90°, 0–150 µm defocus, SNR 5) it was within 0.6° of the truth.

    Parameters
    ----------
    sums : ndarray, shape (n_v, n_u)
        Lenslet sums (NaN: missing lenslets).

    Returns
    -------
    direction_deg : float
        Direction of the scale from the lenslet ``u`` axis towards ``v``, in [0, 180).
    contrast : float
        Largest over smallest ``wᵀ K w`` over the directions (1: no direction stands out).
    """
    fin = np.isfinite(sums)
    vv, uu = np.nonzero(fin)
    w = sums[fin] - float(np.mean(sums[fin]))
    c, r = uu - uu.mean(), vv - vv.mean()

    def score(deg: float) -> float:
        a = math.radians(deg)
        t = r * math.cos(a) - c * math.sin(a)
        return float(w @ np.exp(-0.5 * ((t[:, None] - t[None, :]) / DIRECTION_KERNEL) ** 2) @ w)

    coarse = np.arange(0.0, 180.0, 1.0)
    sc = np.array([score(a) for a in coarse])
    k = int(np.argmax(sc))
    fine = coarse[k] + np.arange(-1.5, 1.5001, 0.05)
    sf = np.array([score(a) for a in fine])
    direction = float(fine[int(np.argmax(sf))] % 180.0)
    contrast = float(sc[k] / max(sc.min(), 1e-300 * max(sc[k], 1.0)))
    return direction, contrast


def defocus_um(image: np.ndarray, grid, optics) -> tuple[float, float]:
    """Defocus of the object from the parallax between the lenslets' views.

    In the native object plane every point fills its lenslet's pupil image alike, so the
    centroid of the light behind a lenslet does not depend on the object. Out of focus by
    ``z`` each pixel behind a lenslet sees the object shifted by ``z tan α`` (``α`` the
    pixel's direction), and the centroid moves with the gradient of the lenslet sums: by
    ``κ z ∇ln S`` lenslets, ``κ = NA / (8 P)`` for a uniformly filled pupil image (``P`` the
    object-space lenslet pitch, µm; the sign is the optics' inversion). The slope of the
    centroids over ``∇ln S`` (central differences, lenslets brighter than 1/5 of the
    brightest) gives ``z``.

    Returns
    -------
    z_um, z_std_um : float
        Estimated defocus (µm; positive away from the objective, the sign of lfsim's
        ``z_um``) and its standard uncertainty; ``(0, inf)`` when the image has no gradients
        to measure it on.
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    uv = grid.lenslet_index(np.stack([xx + 0.5, yy + 0.5], axis=-1))
    near = np.rint(uv)
    off = uv - near
    inside = np.hypot(off[..., 0], off[..., 1]) <= SUM_RADIUS
    iu = near[..., 0].astype(np.int64)
    iv = near[..., 1].astype(np.int64)
    u0, v0 = int(iu.min()), int(iv.min())
    nu, nv = int(iu.max()) - u0 + 1, int(iv.max()) - v0 + 1
    flat = ((iv - v0) * nu + (iu - u0)).ravel()
    wimg = np.where(inside, img, 0.0)

    def per_lenslet(values: np.ndarray) -> np.ndarray:
        return np.bincount(flat, values.ravel(), nu * nv).reshape(nv, nu)

    total = per_lenslet(wimg)
    whole, _, _ = lenslet_sums(img, grid)
    ok = np.isfinite(whole) & (total > 0)
    den = np.where(ok, total, 1.0)
    cx = np.where(ok, per_lenslet(wimg * off[..., 0]) / den, np.nan)
    cy = np.where(ok, per_lenslet(wimg * off[..., 1]) / den, np.nan)
    level = np.where(ok, total, np.nan)
    mid = level[1:-1, 1:-1]
    gx = 0.5 * (level[1:-1, 2:] - level[1:-1, :-2]) / mid
    gy = 0.5 * (level[2:, 1:-1] - level[:-2, 1:-1]) / mid
    dx, dy = cx[1:-1, 1:-1], cy[1:-1, 1:-1]
    with np.errstate(invalid="ignore"):
        m = np.isfinite(gx + gy + dx + dy) & (mid > 0.2 * np.nanmax(level))
    if m.sum() < 8:
        return 0.0, math.inf
    dx, dy, gx, gy = dx[m] - np.median(dx[m]), dy[m] - np.median(dy[m]), gx[m], gy[m]
    gg = float(gx @ gx + gy @ gy)
    if not gg > 0:
        return 0.0, math.inf
    k = float(dx @ gx + dy @ gy) / gg
    res = np.r_[dx - k * gx, dy - k * gy]
    se = math.sqrt(float(res @ res) / max(len(res) - 1, 1) / gg)
    kappa = optics.na / (8.0 * optics.lenslet_object_um)
    return -k / kappa, se / kappa


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
    data = _Data(c.astype(float), r.astype(float), y, g, n_rows)
    n = len(y)
    n_lin = 2 * n_rows
    q_range = (q0 / (1 + tolerance), q0 / (1 - tolerance))
    th_lo, th_hi = theta_c - window, theta_c + window
    starts = _spectral_starts(data, q_range, (th_lo, th_hi))
    if not starts:
        raise PixelSizeError("no periodic ruling found in the lenslet sums")
    lo = np.array([q_range[0], th_lo, -np.inf, 1e-3])
    hi = np.array([q_range[1], th_hi, np.inf, MAX_LINE_FRACTION])
    total = float(data.y @ data.y)
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
    # Robust re-fit: lenslets the best ruling does not explain (line ends crossing a row,
    # dust, hot pixels) are dropped, and the competitive solutions re-fitted without them.
    res = _residuals(good[0].params, data, sigma)
    spread = 1.4826 * float(np.median(np.abs(res)))
    inliers = np.abs(res) <= TRIM_SIGMAS * spread if spread > 0 else np.ones(len(res), bool)
    # Whole rows the ruling does not describe (crossed by line ends) go as well.
    row_rms = np.sqrt(np.bincount(data.g, res**2) / np.bincount(data.g))
    if data.n_rows >= 3:
        inliers &= (row_rms <= ROW_TRIM * np.median(row_rms))[data.g]
    if not inliers.all():
        s2_all = good[0].cost / max(n - n_lin - 4, 1)
        g_before, n_rows_before = data.g, data.n_rows
        data = _subset(data, inliers)
        n, n_lin = len(data.y), 2 * data.n_rows
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
    # The aliases of the best ruling (the same frequency folded, or mirrored, by the lenslet
    # sampling) fit the sums almost alike when the scale is near a half-integer number of
    # divisions per lenslet: fit each, confined to its own neighbourhood, so the comparison
    # (and the ambiguity test) never depends on where the starts happened to converge.
    for _ in range(3):
        leader = good[0]
        aliases = [
            _fit_near(data, a, sigma, (lo, hi), leader.params[0])
            for a in _alias_family(leader.params, (lo, hi))
        ]
        good = sorted([*good, *(a for a in aliases if a.gain > 0)], key=lambda s: s.cost)
        if good[0] is leader:
            break
    best = good[0]
    dof = max(n - n_lin - 4, 1)
    s2 = max(best.cost / dof, 1e-12 * total)  # a noise-free image still has rounding
    # Share of the variation within rows that the ruling explains, per degree of freedom
    # (adjusted R²: fair between the two axes, which have different numbers of rows).
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
    across the region than :data:`MIN_MOIRE_CYCLES` is not told apart from a slow variation
    of the band (near a whole number of divisions per lenslet along both axes).
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
    row (:data:`MIN_CONSISTENT`).
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
    more than :data:`PROFILE_STOP` noise variances or reaches the searched range; every
    point gives ``Δ / √max(rise / s2, 1)`` — the standard deviation of a parabola through
    it, and at least ``Δ`` where the profile is flat — and the largest of these is the
    uncertainty. For a well-determined scale (parabolic profile) that is the usual
    ``Δχ² = 1`` value; where the lenslets cannot tell scales apart (a coarse ruling whose lines
    all stay inside their lenslets) the profile is a plateau, bumpy by a few variances, and
    the uncertainty spans it instead of the first bump.
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


# -- public API -----------------------------------------------------------------------------
def _positive(value: Any, name: str) -> float:
    """``value`` as a finite float > 0, or :class:`recon.errors.InputError` naming ``name``."""
    from hrvbase.errors import InputError as BaseInputError
    from hrvbase.validate import positive_float as check

    try:
        return check(value, name)
    except BaseInputError as exc:
        raise InputError(str(exc)) from None


@dataclass(frozen=True)
class PixelSizeResult:
    """The measured object-space pixel size (see :func:`measure_pixel_size`).

    Attributes
    ----------
    um_per_px, um_per_px_std : float
        Object-space size of one sensor pixel and its standard uncertainty (µm / pixel).
    magnification : float
        Implied lateral magnification, ``M_nominal · um_per_px_nominal / um_per_px``.
    nominal_um_per_px, nominal_magnification : float
        The scene's values (``Optics.object_pixel_um``, ``Optics.magnification``).
    axis : {"x", "y"}
        Image axis along which the divisions run.
    angle_deg, angle_std_deg : float
        Direction of the scale (normal to the lines) in the image, from +x towards +y
        (degrees): near 0 for ``axis="x"``, near 90 for ``axis="y"``.
    rotation_deg : float
        ``angle_deg`` minus the nominal direction of ``axis`` (0° or 90°).
    division_um : float
    divisions_per_lenslet : float
        Fitted ``q = P / D`` (object-space lenslet pitch over the division).
    lenslet_pitch_px : float
        Lenslet pitch used (pixels).
    line_fraction : float
        Fitted width of a line over the division (blur included).
    explained : float
        Fraction of the variation of the lenslet sums the ruling model explains.
    n_lenslets, n_rows, n_columns : int
        Lenslets used; rows of lenslets and lenslets along the scale in the ruled region.
    alternatives : list of dict
        Other scales that fit, with their cost excess in noise variances (``chi2``).
    """

    um_per_px: float
    um_per_px_std: float
    magnification: float
    nominal_um_per_px: float
    nominal_magnification: float
    axis: str
    angle_deg: float
    angle_std_deg: float
    rotation_deg: float
    division_um: float
    divisions_per_lenslet: float
    lenslet_pitch_px: float
    line_fraction: float
    explained: float
    n_lenslets: int
    n_rows: int
    n_columns: int
    alternatives: list = field(default_factory=list)

    @property
    def relative_deviation(self) -> float:
        """``um_per_px / nominal_um_per_px − 1``."""
        return self.um_per_px / self.nominal_um_per_px - 1.0

    def to_dict(self) -> dict:
        """Plain-JSON representation (lengths in µm, angles in degrees)."""
        return {
            "um_per_px": self.um_per_px,
            "um_per_px_std": self.um_per_px_std,
            "magnification": self.magnification,
            "nominal": {
                "um_per_px": self.nominal_um_per_px,
                "magnification": self.nominal_magnification,
            },
            "relative_deviation": self.relative_deviation,
            "axis": self.axis,
            "angle_deg": self.angle_deg,
            "angle_std_deg": self.angle_std_deg,
            "rotation_deg": self.rotation_deg,
            "division_um": self.division_um,
            "divisions_per_lenslet": self.divisions_per_lenslet,
            "lenslet_pitch_px": self.lenslet_pitch_px,
            "line_fraction": self.line_fraction,
            "explained_variance": self.explained,
            "n_lenslets": self.n_lenslets,
            "n_rows": self.n_rows,
            "n_columns": self.n_columns,
            "alternatives": self.alternatives,
        }


def nominal_grid(optics, image_shape: tuple[int, int]):
    """The lenslet grid the scene's optics imply: pitch ``px_per_lenslet``, no rotation, a
    lenslet centred on the optical axis ``axis_px``."""
    from .calibration import LensletGrid

    return LensletGrid(
        pitch_px=optics.px_per_lenslet,
        rotation_deg=0.0,
        origin_px=tuple(optics.axis_px),
        image_shape=tuple(image_shape),
    )


def measure_pixel_size(
    image: Any,
    optics,
    division_um: float,
    *,
    grid=None,
    axis: str = "auto",
    polarity: str = "bright",
    tolerance: float = DEFAULT_TOLERANCE,
    max_rotation_deg: float = DEFAULT_MAX_ROTATION_DEG,
    max_relative_std: float = DEFAULT_MAX_RELATIVE_STD,
) -> PixelSizeResult:
    """Measure the object-space pixel size from a light-field image of a stage micrometer.

    Parameters
    ----------
    image : array_like, shape (height, width)
        Light-field image of a micrometer in the native object plane (any units, finite).
    optics : lfsim.optics.Optics
        Nominal optics of the microscope (the scene): nominal scale, lenslet pitch.
    division_um : float
        Spacing of the micrometer's divisions (µm), > 0.
    grid : recon.calibration.LensletGrid, optional
        Lenslet grid of the camera (``recon calibrate``); default :func:`nominal_grid`, which
        needs an image of the scene's sensor size.
    axis : {"auto", "x", "y"}
        Image axis nearer to which the divisions run (the ruled band's direction within 45°
        of it, else refused); ``"auto"``: either.
    polarity : {"bright", "dark"}
        Lines brighter (fluorescent, default) or darker than the background.
    tolerance : float
        Relative range searched around the nominal magnification, in (0, 0.5).
    max_rotation_deg : float
        Largest rotation of the scale from the nearer image axis accepted (degrees), in
        (0, 45] (45, the default: any direction).
    max_relative_std : float
        Largest relative standard uncertainty of ``um_per_px`` accepted (default 1 %).

    Returns
    -------
    PixelSizeResult

    Raises
    ------
    InputError
        Invalid image or parameter (names it).
    PixelSizeError
        No periodic ruling of the expected contrast in the image (or one the lenslets do
        not resolve at its angle), a micrometer out of focus, the divisions along the
        other axis than ``axis``, two scales that fit alike, or a scale's uncertainty above
        ``max_relative_std``.
    """
    from .calibration import as_image

    img = as_image(image, "micrometer image")
    division_um = _positive(division_um, "division_um")
    if axis not in AXES:
        raise InputError(f"axis must be one of {AXES}, got {axis!r}")
    if polarity not in POLARITIES:
        raise InputError(f"polarity must be one of {POLARITIES}, got {polarity!r}")
    tolerance = _positive(tolerance, "tolerance")
    if not tolerance < 0.5:
        raise InputError(f"tolerance must lie in (0, 0.5), got {tolerance!r}")
    max_rotation_deg = _positive(max_rotation_deg, "max_rotation_deg")
    if max_rotation_deg > 45:
        raise InputError(f"max_rotation_deg must lie in (0, 45], got {max_rotation_deg!r}")
    max_relative_std = _positive(max_relative_std, "max_relative_std")
    if grid is None:
        if (img.shape[1], img.shape[0]) != tuple(optics.sensor_px):
            raise InputError(
                f"the micrometer image is {img.shape[1]} × {img.shape[0]} px but the scene's "
                f"sensor is {optics.sensor_px[0]} × {optics.sensor_px[1]} px: give the lenslet "
                "grid of this camera (recon calibrate on a white image of the same size)"
            )
        grid = nominal_grid(optics, img.shape)
    elif tuple(grid.image_shape) != tuple(img.shape):
        raise InputError(
            f"the lenslet grid was calibrated on {grid.image_shape[1]} × {grid.image_shape[0]} px "
            f"images but the micrometer image is {img.shape[1]} × {img.shape[0]} px"
        )
    _check_division(optics, division_um)
    sums, _, _ = lenslet_sums(img, grid, SUM_RADIUS)
    if polarity == "dark":
        sums = -sums
    direction, contrast = ruling_direction(sums)
    log.debug("ruled band at %.2f° from lenslet x, contrast %.1f", direction, contrast)
    if not contrast >= MIN_BAND_CONTRAST:
        raise PixelSizeError(
            "the image shows no ruled band (a stage micrometer's lines make a band along its "
            f"scale; the sharpest direction stands out by only {contrast:.1f}× over the "
            f"least sharp, need {MIN_BAND_CONTRAST:g}×): is it a micrometer image, not a "
            "particle, white or blank image?"
        )
    sign = _band_sign(sums, direction)
    if sign < 0:
        other = "dark" if polarity == "bright" else "bright"
        raise PixelSizeError(
            f"the ruled band is {'darker' if polarity == 'bright' else 'brighter'} than the "
            f"ground around it, so its lines are {other}, not {polarity} as the polarity "
            f"given: give polarity {other!r}"
        )
    z_um, z_std = defocus_um(img, grid, optics)
    z_max = MAX_DEFOCUS_DIVISIONS * division_um / optics.na
    log.debug("defocus %.1f ± %.1f µm (accepted: %.1f µm)", z_um, z_std, z_max)
    if abs(z_um) > z_max:
        raise PixelSizeError(
            f"the micrometer is out of focus by about {z_um:+.0f} ± {z_std:.0f} µm (parallax "
            f"between the lenslets' views; accepted: ±{z_max:.1f} µm, where the blur stays "
            f"below half a {division_um:g} µm division at NA {optics.na:g}): focus it on the "
            "native object plane"
        )
    args = (sums, direction, optics, grid, axis, tolerance, max_rotation_deg)
    try:
        return _measure(*args, division_um, max_relative_std)
    except PixelSizeError as exc:
        for factor in DIVISION_FACTORS:
            other_um = division_um * factor
            try:
                _check_division(optics, other_um)
                alt = _measure(*args, other_um, DIAGNOSIS_RELATIVE_STD)
            except (InputError, PixelSizeError):
                continue
            raise PixelSizeError(
                f"the image fits a ruling of {other_um:g} µm divisions ({alt.um_per_px:.4f} ± "
                f"{alt.um_per_px_std:.4f} µm/px, {100 * alt.relative_deviation:+.1f} % from "
                f"the scene's), not of the {division_um:g} µm divisions given: check the "
                f"micrometer's division (with {division_um:g} µm: {exc})"
            ) from None
        raise


def _check_division(optics, division_um: float) -> None:
    """Refuse a division the objective cannot resolve or the field cannot hold."""
    finest = optics.wavelength_um / (2.0 * optics.na)
    if division_um < finest:
        raise InputError(
            f"division_um {division_um:g} µm is finer than the objective resolves "
            f"(λ / 2NA = {finest:.2f} µm at NA {optics.na:g}): give the micrometer's division "
            "in µm"
        )
    x0, x1, y0, y1 = optics.field_of_view_um
    field_um = max(x1 - x0, y1 - y0)
    if division_um > field_um / 2:
        raise InputError(
            f"division_um {division_um:g} µm puts fewer than 3 lines in the "
            f"{field_um:.0f} µm field of view: give the micrometer's division in µm"
        )


def _band_sign(sums: np.ndarray, direction: float) -> float:
    """+1 when the ruled band at ``direction`` (degrees) is brighter than its surroundings
    (lines brighter than the ground), −1 when darker: the sign of the largest deviation from
    the median of the band's cross profile (mean per strip one lenslet wide)."""
    fin = np.isfinite(sums)
    vv, uu = np.nonzero(fin)
    a = math.radians(direction)
    t = np.rint(vv * math.cos(a) - uu * math.sin(a)).astype(int)
    t -= t.min()
    n = np.bincount(t, minlength=t.max() + 1)
    mean = np.bincount(t, sums[fin], minlength=t.max() + 1) / np.maximum(n, 1)
    prof = mean[n >= 3]
    dev = prof - np.median(prof)
    return float(np.sign(dev[int(np.argmax(np.abs(dev)))]))


def _measure(
    sums: np.ndarray,
    direction: float,
    optics,
    grid,
    axis: str,
    tolerance: float,
    max_rotation_deg: float,
    division_um: float,
    max_relative_std: float,
) -> PixelSizeResult:
    """The scale of the ruling in ``sums`` at ``direction`` (:func:`measure_pixel_size`
    after its checks)."""
    q0 = optics.lenslet_object_um / division_um
    # Diffraction blur of the objective in object space, in periods of the ruling.
    sigma = max(optics.sigma_mla_um / optics.magnification / division_um, 2e-3)
    near_x = min(direction, 180.0 - direction) <= 45.0
    found = "x" if near_x else "y"
    # The scale's angle from the nearer lenslet axis (from +x towards +y for "x"; for "y",
    # in the transposed sums, from +y towards +x).
    theta_c = (
        (direction if direction <= 90.0 else direction - 180.0) if near_x else 90.0 - direction
    )
    if axis != "auto" and found != axis:
        raise PixelSizeError(
            f"the divisions run along {found}, not along axis {axis!r}: the ruled band's "
            f"scale lies at {direction:.0f}° from the lenslet x axis (give axis {found!r} or "
            "'auto')"
        )
    if abs(theta_c) > max_rotation_deg:
        raise PixelSizeError(
            f"the scale is rotated by {theta_c:+.1f}° from the {found} axis, more than the "
            f"{max_rotation_deg:g}° accepted"
        )
    window = math.radians(DIRECTION_WINDOW_DEG)
    try:
        state = _fit_axis(
            sums if found == "x" else sums.T,
            q0,
            tolerance,
            math.radians(theta_c),
            window,
            sigma,
            found,
        )
    except PixelSizeError as exc:
        if abs(theta_c) <= ROTATED_DEG or "lenslet axis" in str(exc):
            raise
        raise PixelSizeError(
            f"{exc} (the ruled band lies at {direction:.0f}° from the lenslet x axis, where the "
            "lenslets average the lines out: turn the micrometer towards a lenslet axis)"
        ) from None
    if state.consistent < MIN_CONSISTENT:
        raise PixelSizeError(
            f"no ruling of {division_um:g} µm divisions is resolved by the lenslets along the "
            f"band at {direction:.0f}° from the lenslet x axis: one contrast for the whole band "
            f"explains only {100 * max(state.consistent, 0.0):.0f} % of the lenslet sums' "
            f"variation (need {100 * MIN_CONSISTENT:.0f} %); at this angle the lenslets average "
            "the lines out: turn the micrometer towards a lenslet axis"
        )
    fit = _finish_axis(state)
    p = grid.pitch_px
    um = division_um * fit.q / p
    um_std = division_um * fit.q_std / p
    close = [a for a in fit.alternatives if a[1] < AMBIGUITY_CHI2]
    if close and not um_std <= max_relative_std * um:
        alt_q, chi2 = close[0]
        frac = fit.q % 1.0
        if abs(frac - 0.5) < 0.1:
            why = (
                f"the lenslets sample the ruling near a half-integer number of divisions per "
                f"lenslet ({fit.q:.3f}), where magnifications above and below that look alike"
            )
        elif min(frac, 1.0 - frac) < 0.1:
            why = (
                f"the lenslets sample the ruling near a whole number of divisions per lenslet "
                f"({fit.q:.3f}): its moiré is nearly as long as the field"
            )
        else:
            why = "the ruled region is too small or too rotated to tell them apart"
        raise PixelSizeError(
            f"the ruling fits two scales alike ({um:.4f} and {division_um * alt_q / p:.4f} "
            f"µm/px, cost difference {chi2:.1f} noise variances): {why}; measure a ruling of "
            "other divisions or a wider field"
        )
    if not um_std <= max_relative_std * um:
        raise PixelSizeError(
            f"the ruling leaves a ±{100 * um_std / um:.2g} % uncertainty on the scale "
            f"({fit.n_columns} lenslets "
            f"along it, {division_um:g} µm divisions; accepted: ±{100 * max_relative_std:g} %): "
            "use finer divisions or a wider field (more lines)"
        )
    nominal_um = optics.object_pixel_um
    theta = math.degrees(fit.theta_rad)
    if fit.axis == "x":
        angle = theta + grid.rotation_deg
        rotation = angle
    else:
        angle = 90.0 - theta + grid.rotation_deg
        rotation = angle - 90.0
    res = PixelSizeResult(
        um_per_px=um,
        um_per_px_std=um_std,
        magnification=optics.magnification * nominal_um / um,
        nominal_um_per_px=nominal_um,
        nominal_magnification=optics.magnification,
        axis=fit.axis,
        angle_deg=angle,
        angle_std_deg=math.degrees(fit.theta_std_rad),
        rotation_deg=rotation,
        division_um=division_um,
        divisions_per_lenslet=fit.q,
        lenslet_pitch_px=p,
        line_fraction=fit.rho,
        explained=fit.explained,
        n_lenslets=fit.n_lenslets,
        n_rows=fit.n_rows,
        n_columns=fit.n_columns,
        alternatives=[
            {"um_per_px": division_um * q / p, "chi2": c} for q, c in fit.alternatives[:3]
        ],
    )
    log.info(
        "micrometer: %.5f ± %.5f µm/px (nominal %.5f, %+.2f %%), axis %s, rotation %+.3f°",
        res.um_per_px,
        res.um_per_px_std,
        nominal_um,
        100 * res.relative_deviation,
        res.axis,
        res.rotation_deg,
    )
    return res


def apply_pixel_size(optics, record) -> Any:
    """The optics with the measured magnification: ``object_pixel_um`` becomes the measured
    ``um_per_px``.

    The magnification error of a real microscope sits in the objective/tube-lens pair (and
    any relay before the lenslet array), not in the camera: the lenslet pitch on the sensor
    (``px_per_lenslet``, measured by ``recon calibrate``) is unchanged. So the tube lens's
    focal length is scaled, ``f_tube ← f_objective · pixel_um / um_per_px``; the objective,
    its NA and aperture stop, the array and the camera keep their values.

    Parameters
    ----------
    optics : lfsim.optics.Optics
        The nominal optics (the scene the measurement used).
    record : PixelSizeResult or dict
        A result, or the JSON record ``recon pixel-size`` writes (``um_per_px`` and, when
        present, ``optics.pixel_um`` are read).

    Returns
    -------
    lfsim.optics.Optics

    Raises
    ------
    InputError
        A record without a positive ``um_per_px``, or one made for another camera pixel.
    """
    if isinstance(record, PixelSizeResult):
        um = record.um_per_px
    elif isinstance(record, dict):
        if record.get("format") not in (None, PIXEL_SIZE_FORMAT):
            raise InputError(
                f"not a pixel-size record (format {record.get('format')!r}, expected "
                f"{PIXEL_SIZE_FORMAT!r})"
            )
        um = record.get("um_per_px")
        rec_optics = record.get("optics")
        if isinstance(rec_optics, dict) and "pixel_um" in rec_optics:
            rec_px = rec_optics["pixel_um"]
            if not isinstance(rec_px, int | float) or not math.isclose(
                rec_px, optics.pixel_um, rel_tol=1e-9
            ):
                raise InputError(
                    f"the pixel-size record was measured with pixel_um = {rec_px!r}, but these "
                    f"optics have pixel_um = {optics.pixel_um!r} (another camera?)"
                )
    else:
        raise InputError(f"record must be a PixelSizeResult or a dict, got {type(record).__name__}")
    um = _positive(um, "um_per_px")
    f_tube = optics.f_objective_um * optics.pixel_um / um
    return replace(optics, f_tube_um=f_tube)


# -- files ----------------------------------------------------------------------------------
def image_metadata(path) -> dict:
    """The JSON metadata of a TIFF written by :mod:`lfsim` (``{}`` if it has none or cannot be
    read: the caller then needs ``--scene``)."""
    from hrvbase.errors import HrvError
    from hrvbase.formats.tiff_layout import read_tiff

    try:
        _, meta = read_tiff(path)
    except HrvError:
        return {}
    return meta if isinstance(meta, dict) else {}


def build_record(
    result: PixelSizeResult,
    optics,
    *,
    image: np.ndarray,
    image_path,
    scene_path,
    calib_path=None,
    grid=None,
    settings: dict | None = None,
    written_scene=None,
    version: str = "",
    elapsed_s: float | None = None,
) -> dict:
    """The JSON record ``recon pixel-size`` writes (format :data:`PIXEL_SIZE_FORMAT`).

    Holds the result (:meth:`PixelSizeResult.to_dict`: ``um_per_px`` and ``um_per_px_std``
    in µm per pixel, ``magnification``, ``nominal``, ``relative_deviation``, ``axis``,
    ``angle_deg``, ``rotation_deg``, ``division_um`` ...), the nominal optics, the lenslet
    grid used and where it came from, the settings, and the path and SHA-256 of the image,
    the scene, the calibration and the written scene.
    """
    import datetime as dt
    from pathlib import Path

    from hrvbase.io import sha256_file

    def ref(path):
        if path is None:
            return None
        return {"path": str(Path(path).resolve()), "sha256": sha256_file(path)}

    used = grid if grid is not None else nominal_grid(optics, image.shape)
    return {
        "format": PIXEL_SIZE_FORMAT,
        "format_version": 1,
        **result.to_dict(),
        "optics": optics.to_dict(),
        "lenslet_grid": {
            "source": "calibration" if grid is not None else "scene",
            **used.to_dict(),
        },
        "settings": dict(settings or {}),
        "input": {
            **ref(image_path),
            "shape": list(image.shape),
        },
        "scene": ref(scene_path),
        "calibration": ref(calib_path),
        "measured_scene": ref(written_scene),
        "tool": {"name": "recon", "version": version, "command": "pixel-size"},
        "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "elapsed_s": None if elapsed_s is None else round(elapsed_s, 3),
    }


def load_pixel_record(path) -> dict:
    """Read a record written by ``recon pixel-size`` (for :func:`apply_pixel_size`).

    Raises
    ------
    InputError
        Missing or invalid file, or not a pixel-size record (names the file).
    """
    from hrvbase.io import read_json

    data = read_json(path)
    if not isinstance(data, dict) or data.get("format") != PIXEL_SIZE_FORMAT:
        raise InputError(
            f'{path} is not a pixel-size record (expected "format": {PIXEL_SIZE_FORMAT!r}; '
            "make one with `recon pixel-size`)"
        )
    return data


def write_measured_scene(optics, path, *, overwrite: bool = False, source=None, result=None):
    """Write ``optics`` (from :func:`apply_pixel_size`) as a scene file, atomically.

    Parameters
    ----------
    optics : lfsim.optics.Optics
    path : path
        Output ``.xml`` (an existing file is replaced only with ``overwrite``).
    source : path, optional
        The nominal scene, named in the file's description.
    result : PixelSizeResult, optional
        The measurement, quoted in the description.

    Returns
    -------
    Path
    """
    from pathlib import Path

    from hrvbase.io import atomic_path
    from lfsim.scene import write_scene

    text = "Scene with the measured magnification (recon pixel-size)"
    if source is not None:
        text += f" from {Path(source).name}"
    if result is not None:
        text += (
            f": {result.um_per_px:.6g} +- {result.um_per_px_std:.2g} um/px, "
            f"M = {result.magnification:.6g} (nominal {result.nominal_magnification:.6g})"
        )
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        write_scene(optics, tmp, description=text)
    return path


__all__ = [
    "PIXEL_SIZE_FORMAT",
    "PixelSizeError",
    "PixelSizeResult",
    "apply_pixel_size",
    "build_record",
    "image_metadata",
    "lenslet_sums",
    "load_pixel_record",
    "measure_pixel_size",
    "nominal_grid",
    "ruling_coverage",
    "write_measured_scene",
]
