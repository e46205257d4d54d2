"""Defaults and limits of the pixel-size measurement (:mod:`recon.pixel_size`) and its error."""

from __future__ import annotations

import logging

from .errors import ReconError

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
#: ruled band (:func:`~recon.ruling_geometry.ruling_direction`).
DIRECTION_WINDOW_DEG = 2.0
#: Width (lenslets) of the Gaussian of :func:`~recon.ruling_geometry.ruling_direction`.
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
#: Least contrast of the ruled band's direction (:func:`recon.ruling_geometry.ruling_direction`;
#: the contrasts of micrometer, particle, white and noise images: docs/validation_notes.md,
#: "Pixel size").
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
