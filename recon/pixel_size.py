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
  10 µm) the two unfoldings meet and the contrast barely separates them: a magnification
  close to that point is either refused as ambiguous or returned with an uncertainty wide
  enough to hold both. Near a whole number the moiré becomes as long as the field and the
  scale is refused as well.
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
  from lines of a slightly rotated micrometer crossing lenslet borders); too few lines leave
  it undetermined, which is refused (``max_relative_std``). A defocused micrometer spreads
  each line over several lenslets, which the model (lines as boxes, not defocus discs) does
  not describe: not validated.

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

Measured accuracy and the sweep over rotation, defocus, SNR and magnification:
docs/validation_notes.md, "Pixel size".
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from .errors import InputError
from .pixel_size_defaults import (  # noqa: F401 (importable from here)
    AMBIGUITY_CHI2,
    AXES,
    DEFAULT_MAX_RELATIVE_STD,
    DEFAULT_MAX_ROTATION_DEG,
    DEFAULT_TOLERANCE,
    DIAGNOSIS_RELATIVE_STD,
    DIRECTION_WINDOW_DEG,
    DIVISION_FACTORS,
    MAX_DEFOCUS_DIVISIONS,
    MIN_BAND_CONTRAST,
    MIN_CONSISTENT,
    MIN_MOIRE_CYCLES,
    PIXEL_SIZE_FORMAT,
    POLARITIES,
    ROTATED_DEG,
    STRIP_MIN_DEG,
    SUM_RADIUS,
    PixelSizeError,
)
from .pixel_size_record import (
    PixelSizeResult,
    _positive,
    apply_pixel_size,
    build_record,
    image_metadata,
    load_pixel_record,
    nominal_grid,
    write_measured_scene,
)
from .ruling_fit import (  # noqa: F401 (importable from here)
    AxisFit,
    _finish_axis,
    _fit_axis,
)
from .ruling_geometry import defocus_um, ruling_direction
from .ruling_model import (
    lenslet_sums,
    ruling_coverage,
)

log = logging.getLogger(__name__)


# -- lenslet sums ---------------------------------------------------------------------------


# -- the ruling model -----------------------------------------------------------------------


# -- fit ------------------------------------------------------------------------------------


# -- public API -----------------------------------------------------------------------------


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
    division_um, tolerance, max_rotation_deg, max_relative_std = _check_parameters(
        division_um, axis, polarity, tolerance, max_rotation_deg, max_relative_std
    )
    grid = _check_grid(grid, img, optics)
    _check_division(optics, division_um)
    sums, _, _ = lenslet_sums(img, grid, SUM_RADIUS)
    if polarity == "dark":
        sums = -sums
    direction = _band_direction(sums, polarity)
    _check_focus(img, grid, optics, division_um)
    args = (sums, direction, optics, grid, axis, tolerance, max_rotation_deg)
    try:
        return _measure(*args, division_um, max_relative_std)
    except PixelSizeError as exc:
        _diagnose_division(exc, args, optics, division_um)
        raise


def _check_parameters(division_um, axis, polarity, tolerance, max_rotation_deg, max_relative_std):
    """The validated ``division_um``, ``tolerance``, ``max_rotation_deg`` and
    ``max_relative_std`` of :func:`measure_pixel_size` (``axis`` and ``polarity`` checked)."""
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
    return division_um, tolerance, max_rotation_deg, max_relative_std


def _check_grid(grid, img: np.ndarray, optics):
    """The lenslet grid of the micrometer image: ``grid`` (calibrated on images of its size)
    or, when None, the scene's nominal grid (for an image of the scene's sensor size)."""
    if grid is None:
        if (img.shape[1], img.shape[0]) != tuple(optics.sensor_xy_px):
            raise InputError(
                f"the micrometer image is {img.shape[1]} × {img.shape[0]} px but the scene's "
                f"sensor is {optics.sensor_xy_px[0]} × {optics.sensor_xy_px[1]} px: give the "
                "lenslet grid of this camera (recon calibrate on a white image of the same size)"
            )
        return nominal_grid(optics, img.shape)
    if tuple(grid.image_shape) != tuple(img.shape):
        raise InputError(
            f"the lenslet grid was calibrated on {grid.image_shape[1]} × {grid.image_shape[0]} px "
            f"images but the micrometer image is {img.shape[1]} × {img.shape[0]} px"
        )
    return grid


def _band_direction(sums: np.ndarray, polarity: str) -> float:
    """The direction (degrees from lenslet x) of the ruled band in ``sums`` (signed for the
    polarity); :class:`PixelSizeError` for no band, or a band of the other polarity."""
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
    return direction


def _check_focus(img: np.ndarray, grid, optics, division_um: float) -> None:
    """Refuse a micrometer more than :data:`MAX_DEFOCUS_DIVISIONS` ``· division / NA`` out of
    focus (:func:`defocus_um`)."""
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


def _diagnose_division(exc: PixelSizeError, args: tuple, optics, division_um: float) -> None:
    """Raise a :class:`PixelSizeError` naming a wrong division where the ruling measures
    with one of :data:`DIVISION_FACTORS` times ``division_um`` (``exc``: the failure with
    the division given; ``args``: those of :func:`_measure` before the division)."""
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


def _check_division(optics, division_um: float) -> None:
    """Refuse a division the objective cannot resolve or the field cannot hold."""
    finest = optics.wavelength_um / (2.0 * optics.na)
    if division_um < finest:
        raise InputError(
            f"division_um {division_um:g} µm is finer than the objective resolves "
            f"(λ / 2NA = {finest:.2f} µm at NA {optics.na:g}): give the micrometer's division "
            "in µm"
        )
    x0, x1, y0, y1 = optics.field_of_view_xy_um
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


def _scale_axis(direction: float, axis: str, max_rotation_deg: float) -> tuple[str, float]:
    """The image axis nearer to the ruled band's direction (degrees from lenslet x) and the
    scale's angle from it (degrees; from +x towards +y for "x"; for "y", in the transposed
    sums, from +y towards +x); :class:`PixelSizeError` for another axis than ``axis`` or a
    rotation beyond ``max_rotation_deg``."""
    near_x = min(direction, 180.0 - direction) <= 45.0
    found = "x" if near_x else "y"
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
    return found, theta_c


def _check_unique(fit, um: float, um_std: float, division_um: float, p: float, max_rel: float):
    """Refuse a scale another one fits alike (naming why the lenslets cannot tell them
    apart) or whose relative uncertainty exceeds ``max_rel``."""
    close = [a for a in fit.alternatives if a[1] < AMBIGUITY_CHI2]
    if close and not um_std <= max_rel * um:
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
    if not um_std <= max_rel * um:
        raise PixelSizeError(
            f"the ruling leaves a ±{100 * um_std / um:.2g} % uncertainty on the scale "
            f"({fit.n_columns} lenslets "
            f"along it, {division_um:g} µm divisions; accepted: ±{100 * max_rel:g} %): "
            "use finer divisions or a wider field (more lines)"
        )


def _result(fit, optics, grid, division_um: float, um: float, um_std: float) -> PixelSizeResult:
    """The :class:`PixelSizeResult` of the axis fit ``fit`` (scale ``um`` ± ``um_std``
    µm/px), its angles referred to the image axes through the grid's rotation."""
    p = grid.pitch_px
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
    return res


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
    found, theta_c = _scale_axis(direction, axis, max_rotation_deg)
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
    _check_unique(fit, um, um_std, division_um, p, max_relative_std)
    res = _result(fit, optics, grid, division_um, um, um_std)
    log.info(
        "micrometer: %.5f ± %.5f µm/px (nominal %.5f, %+.2f %%), axis %s, rotation %+.3f°",
        res.um_per_px,
        res.um_per_px_std,
        optics.object_pixel_um,
        100 * res.relative_deviation,
        res.axis,
        res.rotation_deg,
    )
    return res


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
