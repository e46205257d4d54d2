"""Camera and noise models: turn a noise-free light-field image into camera-like integers.

Three models (:data:`NOISE_MODELS`), chosen with a :class:`NoiseSpec` and applied by
:func:`apply_noise`:

``"none"``
    Scale the clean image to the camera's digital range (its maximum at ``fill`` of full scale)
    and round; no noise.
``"gaussian"``
    The paper's model (:func:`add_gaussian_noise`): additive white Gaussian noise of a
    prescribed signal-to-noise ratio,

        ``SNR = S / sigma_noise``,  ``S = max(P99.9(clean), ½ · P99.9(lit pixels of clean))``

    (:func:`signal_reference`): the paper's 99.9th percentile of the noise-free image, which
    stays defined for sparse images (a single particle lights fewer than 0.1 % of the pixels,
    and its P99.9 is 0) through the 99.9th percentile of the pixels that receive light.
``"camera"``
    A physical camera (:class:`CameraModel`): photon shot noise (Poisson), full-well clipping,
    Gaussian read noise, conversion gain, black-level offset, quantisation and saturation. The
    exposure time follows the frame rate (:func:`exposure_s`), so at a fixed photon rate the
    SNR falls as the frame rate rises (paper Fig. 4c, 100 → 25 000 fps; :func:`snr_vs_fps`).

Images are ``(y, x)`` arrays; digital values are in DN (digital numbers, ADU); charges in
electrons (e⁻); times in seconds. Everything here is plain numpy and takes a seed or a
:class:`numpy.random.Generator`, so the same inputs and seed give identical images.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from .errors import ConfigError

log = logging.getLogger(__name__)

NOISE_MODELS = ("none", "gaussian", "camera")
BIT_DEPTHS = (8, 12, 16)

#: Percentile of the clean image that defines the signal in the SNR (the paper's P99.9).
SNR_PERCENTILE = 99.9

#: Fraction of the lit pixels' P99.9 below which the signal reference never falls: the
#: reference of sparse images (:func:`signal_reference`). Dense images stay above it (in
#: every experiment of ``scenes/experiments``, P99.9 is 0.64–0.89 of the lit pixels' P99.9).
SPARSE_FRACTION = 0.5

#: The SNR definition, as recorded in metadata.
SNR_DEFINITION = (
    "S / sigma_noise with S = max(P99.9(clean image), 0.5 * P99.9(lit pixels of the clean "
    "image)): the 99.9th percentile of the noise-free image, or half that of its pixels "
    "above zero when it is higher (sparse images)"
)

#: Variance (DN²) of the rounding error of a uniform quantiser of step 1 DN.
QUANTISATION_VAR_DN2 = 1.0 / 12.0

#: Largest expected photon count per pixel :meth:`CameraModel.expose` accepts (numpy's Poisson
#: sampler fails for much larger means; such a pixel saturates any real camera).
MAX_PHOTONS_PER_PIXEL = 1e15


# -- helpers --------------------------------------------------------------------------------
def _is_number(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def _positive(name: str, value: Any) -> float:
    if not _is_number(value) or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _non_negative(name: str, value: Any) -> float:
    if not _is_number(value) or not math.isfinite(value) or value < 0:
        raise ConfigError(f"{name} must be a non-negative finite number, got {value!r}")
    return float(value)


def _check_bit_depth(name: str, value: Any) -> int:
    if not _is_number(value) or value not in BIT_DEPTHS or int(value) != value:
        raise ConfigError(f"{name} must be one of {BIT_DEPTHS}, got {value!r}")
    return int(value)


def _check_fraction(name: str, value: Any) -> float:
    if not _is_number(value) or not math.isfinite(value) or not (0 < value <= 1):
        raise ConfigError(f"{name} must lie in (0, 1], got {value!r}")
    return float(value)


def _dtype_for(bit_depth: int) -> type[np.unsignedinteger]:
    return np.uint8 if bit_depth == 8 else np.uint16


def _full_scale(bit_depth: int) -> int:
    return 2**bit_depth - 1


def _as_generator(rng: Any) -> np.random.Generator:
    """A :class:`numpy.random.Generator` from a generator or an integer seed."""
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, int | np.integer) and not isinstance(rng, bool) and rng >= 0:
        return np.random.default_rng(int(rng))
    raise ConfigError(
        f"rng must be a numpy.random.Generator or a non-negative integer seed, got {rng!r}"
    )


def _finite_non_negative_array(name: str, value: Any, *, ndim: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be a numeric array, got {type(value).__name__}") from exc
    if ndim is not None and arr.ndim != ndim:
        raise ConfigError(f"{name} must be a {ndim}-D (y, x) image, got shape {arr.shape}")
    if arr.size == 0:
        raise ConfigError(f"{name} must not be empty, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite everywhere (found NaN or inf)")
    if arr.min() < 0:
        raise ConfigError(f"{name} must be non-negative, found minimum {arr.min():.6g}")
    return arr


def _quantise(dn: np.ndarray, bit_depth: int) -> np.ndarray:
    """Round to integers, clip to ``[0, 2**bit_depth - 1]`` and cast to uint8/uint16."""
    out = np.clip(np.rint(dn), 0, _full_scale(bit_depth))
    return out.astype(_dtype_for(bit_depth))


def _per_value(value: Any, arr: np.ndarray) -> float | np.ndarray:
    """Return a Python float for scalar input, the array otherwise."""
    return float(arr) if np.ndim(value) == 0 else arr


# -- the paper's Gaussian model ------------------------------------------------------------
NO_SIGNAL = "no particles in the field of view"


def _reference(img: np.ndarray) -> float:
    """``max(P99.9(img), SPARSE_FRACTION · P99.9(img[img > 0]))`` of a non-negative image with
    at least one positive pixel."""
    p999 = float(np.percentile(img, SNR_PERCENTILE))
    lit = img[img > 0]
    if lit.size == 0:
        return p999
    sparse = SPARSE_FRACTION * float(np.percentile(lit, SNR_PERCENTILE))
    # max() returns the first argument on ties: dense images keep P99.9 exactly.
    return max(p999, sparse)


def signal_reference(clean: np.ndarray) -> float:
    """The signal ``S`` of the SNR, ``SNR = S / sigma_noise``, of a noise-free image.

    ``S = max(P99.9(clean), ½ · P99.9(clean[clean > 0]))``: the paper's 99.9th percentile of
    the noise-free image, unless it is lower than half the 99.9th percentile of the lit
    pixels (those above zero). For the paper's images (particles lighting several per cent
    of the pixels) the first term is larger and ``S`` is exactly the paper's P99.9. When
    fewer than 0.1 % of the pixels are lit (e.g. one particle), P99.9 is 0 and would leave
    the SNR undefined; there ``S`` is half the robust peak of the lit pixels. The reference
    changes continuously as particles are added or removed.

    Parameters
    ----------
    clean : ndarray, shape (ny, nx)
        Noise-free image, finite and non-negative (any units).

    Returns
    -------
    float
        ``S`` in the units of ``clean``, > 0.

    Raises
    ------
    ConfigError
        ``clean`` is all zero: "no particles in the field of view".
    """
    img, _ = _validate_clean(clean)
    return _reference(img)


def _validate_clean(clean: Any, name: str = "clean", ndim: int | None = 2) -> tuple:
    """The clean image as float64 and its maximum (> 0)."""
    img = _finite_non_negative_array(name, clean, ndim=ndim)
    peak = float(img.max())
    if not peak > 0:
        raise ConfigError(f"{NO_SIGNAL}: the noise-free image ({name}) is all zero")
    return img, peak


def _check_fill(fill: Any) -> float:
    return _check_fraction("fill", fill)


def scale_to_dn(
    clean: np.ndarray, *, bit_depth: int = 8, fill: float = 0.7
) -> tuple[np.ndarray, dict]:
    """Scale a clean image to a camera's digital range without noise (model ``"none"``).

    Parameters
    ----------
    clean : ndarray, shape (ny, nx)
        Noise-free image, finite, non-negative, not all zero (arbitrary units); any number
        of lit pixels (a single particle is fine).
    bit_depth : {8, 12, 16}
        Bits per pixel of the output.
    fill : float
        The image maximum maps to ``fill · (2**bit_depth − 1)`` DN, 0 < fill ≤ 1.

    Returns
    -------
    image : ndarray of uint8 (8 bit) or uint16 (12, 16 bit), shape (ny, nx)
        ``round(scale · clean)`` in DN.
    info : dict
        ``{"model": "none", "snr": None, "sigma_dn": 0.0, "offset_dn": 0.0,
        "scale_dn_per_unit": scale, "bit_depth": bit_depth}``.
    """
    bit_depth = _check_bit_depth("bit_depth", bit_depth)
    fill = _check_fill(fill)
    img, peak = _validate_clean(clean)
    scale = fill * _full_scale(bit_depth) / peak
    info = {
        "model": "none",
        "snr": None,
        "sigma_dn": 0.0,
        "offset_dn": 0.0,
        "scale_dn_per_unit": float(scale),
        "bit_depth": bit_depth,
    }
    return _quantise(scale * img, bit_depth), info


def add_gaussian_noise(
    clean: np.ndarray,
    snr: float,
    rng: np.random.Generator | int,
    *,
    bit_depth: int = 8,
    fill: float = 0.7,
    offset_sigmas: float = 4.0,
) -> tuple[np.ndarray, dict]:
    """Add white Gaussian noise of a given SNR to a clean image (the paper's noise model).

    The SNR is defined as ``SNR = S / sigma_noise`` with ``S`` the paper's P99.9, the 99.9th
    percentile of the noise-free image — not its maximum or mean, so a few very bright
    pixels do not set the noise level — or, for sparse images whose P99.9 is (near) zero,
    half the P99.9 of their lit pixels (:func:`signal_reference`).

    Steps:

    1. Scale the clean image by ``scale`` (DN per unit) so that its maximum maps to ``fill``
       of the range left above the black level: ``scale · max = fill · (full − offset)``, with
       ``full = 2**bit_depth − 1``.
    2. ``sigma = S(scale · clean) / snr`` (DN).
    3. Add a black level ``offset = offset_sigmas · sigma`` (DN). Without it, clipping at 0
       would cut the negative half of the noise in the dark background (most of a
       light-field image), roughly halving the noise there, biasing the mean upwards and
       making the measured SNR higher than requested.
    4. Add ``N(0, sigma²)``, round to integers, clip to ``[0, full]``.

    Steps 1–3 are solved in closed form:
    ``scale = fill · full / (max + fill · offset_sigmas · S / snr)``.

    Rounding adds a uniform error of variance 1/12 DN², so the noise actually present has
    standard deviation ``sqrt(sigma² + 1/12)``: negligible for ``sigma ≳ 1.5`` DN (under 2 %),
    dominant below 0.5 DN, where a warning is logged (raise the bit depth or lower the SNR).

    Parameters
    ----------
    clean : ndarray, shape (ny, nx)
        Noise-free image, finite, non-negative, not all zero (arbitrary units); any number
        of lit pixels (a single particle is fine).
    snr : float
        Requested ``S / sigma_noise`` (:func:`signal_reference`), positive and finite.
    rng : numpy.random.Generator or int
        Generator or seed; the same seed gives the same image.
    bit_depth : {8, 12, 16}
        Bits per pixel; the output is uint8 for 8 bits and uint16 for 12 and 16 bits.
    fill : float
        Fraction (0, 1] of the range above the black level the image maximum maps to; the rest
        is headroom for noise on bright pixels.
    offset_sigmas : float
        Black level in units of ``sigma`` (≥ 0); 4 σ leaves 3·10⁻⁵ of background pixels clipped.

    Returns
    -------
    noisy : ndarray of uint8 or uint16, shape (ny, nx)
        The noisy image in DN.
    info : dict
        ``{"model": "gaussian", "snr", "sigma_dn", "offset_dn", "scale_dn_per_unit",
        "bit_depth"}``. The clean image in DN is ``scale_dn_per_unit · clean + offset_dn``;
        :func:`measure_snr` takes ``scale_dn_per_unit · clean`` and ``offset_dn``.

    Raises
    ------
    ConfigError
        On a bad ``snr``, ``bit_depth``, ``fill``, ``offset_sigmas``, ``rng`` or ``clean``;
        an all-zero ``clean`` gives "no particles in the field of view".
    """
    snr = _positive("snr", snr)
    bit_depth = _check_bit_depth("bit_depth", bit_depth)
    fill = _check_fill(fill)
    offset_sigmas = _non_negative("offset_sigmas", offset_sigmas)
    gen = _as_generator(rng)
    img, peak = _validate_clean(clean)
    ref = _reference(img)

    full = _full_scale(bit_depth)
    scale = fill * full / (peak + fill * offset_sigmas * ref / snr)
    sigma = scale * ref / snr
    offset = offset_sigmas * sigma
    if sigma < 0.5:
        log.warning(
            "add_gaussian_noise: sigma = %.3g DN < 0.5 DN at snr=%g and bit_depth=%d; "
            "quantisation noise (1/12 DN^2) dominates and the measured SNR will be lower than "
            "requested. Use a larger bit_depth.",
            sigma,
            snr,
            bit_depth,
        )
    dn = scale * img + offset + gen.normal(0.0, sigma, size=img.shape)
    info = {
        "model": "gaussian",
        "snr": snr,
        "sigma_dn": float(sigma),
        "offset_dn": float(offset),
        "scale_dn_per_unit": float(scale),
        "bit_depth": bit_depth,
    }
    return _quantise(dn, bit_depth), info


def measure_snr(noisy_dn: np.ndarray, clean_dn: np.ndarray, offset_dn: float = 0.0) -> float:
    """Measure ``SNR = S / sigma_noise`` of a noisy image against its noise-free truth.

    ``S`` is :func:`signal_reference` of the noise-free image (the paper's P99.9, or half the
    P99.9 of the lit pixels of a sparse image) and ``sigma_noise`` the standard deviation of
    the residual over all pixels:

        ``SNR = S(clean_dn) / std(noisy_dn − offset_dn − clean_dn)``.

    Parameters
    ----------
    noisy_dn : ndarray, shape (ny, nx)
        Noisy image in DN (any numeric dtype), black level included.
    clean_dn : ndarray, shape (ny, nx)
        Noise-free image in DN *without* the black level, e.g.
        ``info["scale_dn_per_unit"] · clean`` from :func:`add_gaussian_noise`.
    offset_dn : float
        Black level in DN, ``info["offset_dn"]``.

    Returns
    -------
    float
        The measured SNR; ``inf`` when the residual is exactly zero.
    """
    noisy = np.asarray(noisy_dn, dtype=np.float64)
    clean = np.asarray(clean_dn, dtype=np.float64)
    if noisy.shape != clean.shape:
        raise ConfigError(
            f"noisy_dn and clean_dn must have the same shape, got {noisy.shape} and {clean.shape}"
        )
    if noisy.size == 0:
        raise ConfigError("noisy_dn must not be empty")
    offset = float(offset_dn)
    if not math.isfinite(offset):
        raise ConfigError(f"offset_dn must be finite, got {offset_dn!r}")
    img, _ = _validate_clean(clean, "clean_dn", ndim=None)
    sigma = float(np.std(noisy - offset - img))
    return math.inf if sigma == 0 else _reference(img) / sigma


# -- a physical camera ---------------------------------------------------------------------
@dataclass(frozen=True)
class CameraModel:
    """A linear camera with shot noise, read noise, gain, black level and saturation.

    The defaults describe a generic 12-bit scientific camera, not a specific model.

    Parameters
    ----------
    quantum_efficiency : float
        Electrons per incident photon, in (0, 1].
    read_noise_e : float
        Standard deviation of the Gaussian read noise, electrons (≥ 0).
    gain_dn_per_e : float
        Conversion gain, DN per electron (> 0).
    offset_dn : float
        Black level added before quantisation, DN (≥ 0); keep it several read-noise σ above 0
        so that dark pixels are not clipped.
    bit_depth : {8, 12, 16}
        Bits per pixel; saturation at ``2**bit_depth − 1`` DN.
    full_well_e : float or None
        Full-well capacity, electrons (> 0); ``None`` for no pixel saturation before the ADC.
    """

    quantum_efficiency: float = 0.7
    read_noise_e: float = 2.0
    gain_dn_per_e: float = 0.25
    offset_dn: float = 100.0
    bit_depth: int = 12
    full_well_e: float | None = 16_000.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "quantum_efficiency",
            _check_fraction("quantum_efficiency", self.quantum_efficiency),
        )
        object.__setattr__(self, "read_noise_e", _non_negative("read_noise_e", self.read_noise_e))
        object.__setattr__(self, "gain_dn_per_e", _positive("gain_dn_per_e", self.gain_dn_per_e))
        object.__setattr__(self, "offset_dn", _non_negative("offset_dn", self.offset_dn))
        object.__setattr__(self, "bit_depth", _check_bit_depth("bit_depth", self.bit_depth))
        if self.full_well_e is not None:
            object.__setattr__(self, "full_well_e", _positive("full_well_e", self.full_well_e))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CameraModel:
        """Build from a mapping (e.g. parsed JSON); unknown keys raise :class:`ConfigError`."""
        if not isinstance(d, Mapping):
            raise ConfigError(f"camera must be a mapping of parameters, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(
                f"camera: unknown key(s) {unknown}; expected a subset of {sorted(known)}"
            )
        return cls(**d)

    def to_dict(self) -> dict:
        """The parameters as a JSON-serialisable dict (inverse of :meth:`from_dict`)."""
        return asdict(self)

    @property
    def full_scale_dn(self) -> int:
        """Saturation value ``2**bit_depth − 1`` (DN)."""
        return _full_scale(self.bit_depth)

    def expose(self, photons: np.ndarray, rng: np.random.Generator | int) -> np.ndarray:
        """Simulate one exposure.

        ``photons`` (expected count per pixel) → electrons ``~ Poisson(QE · photons)`` →
        clipped at ``full_well_e`` → ``+ N(0, read_noise_e²)`` → ``× gain_dn_per_e`` →
        ``+ offset_dn`` → rounded → clipped to ``[0, 2**bit_depth − 1]`` (saturation).

        Parameters
        ----------
        photons : ndarray, any shape (an image is (ny, nx))
            Expected number of photons reaching each pixel during the exposure (float,
            finite, 0 ≤ photons ≤ 1e15).
        rng : numpy.random.Generator or int
            Generator or seed.

        Returns
        -------
        ndarray of uint8 (8 bit) or uint16 (12, 16 bit), shape of ``photons``
            The image in DN.
        """
        ph = _finite_non_negative_array("photons", photons)
        if ph.max() > MAX_PHOTONS_PER_PIXEL:
            raise ConfigError(
                f"photons must be at most {MAX_PHOTONS_PER_PIXEL:g} per pixel, found {ph.max():.3g}"
            )
        gen = _as_generator(rng)
        electrons = gen.poisson(self.quantum_efficiency * ph).astype(np.float64)
        return self._read_out(electrons, gen)

    def expose_counts(
        self, counts: np.ndarray, photons_per_count: float, rng: np.random.Generator | int
    ) -> np.ndarray:
        """Simulate one exposure from a photon-count image made by a light tracer.

        A tracer's integer counts are already a shot-noise realisation (every ray is one
        photon); applying :meth:`expose` to them would count shot noise twice. Instead the
        counts are thinned: each counted photon yields an electron with probability
        ``QE · photons_per_count``, so electrons ``~ Binomial(counts, QE · photons_per_count)``
        — exactly Poisson with mean ``QE · photons_per_count · E[counts]`` when the counts are
        Poisson. When ``QE · photons_per_count > 1`` (more photons than traced rays) thinning
        is impossible; the electrons are then drawn as ``Poisson(QE · photons_per_count ·
        counts)``, whose variance exceeds the true shot noise by ``1 + 1 / (QE ·
        photons_per_count)`` — a warning says to trace more rays.

        Parameters
        ----------
        counts : ndarray of int, shape (ny, nx)
            Photons counted per pixel by the tracer.
        photons_per_count : float
            Real photons each traced ray stands for (> 0).
        rng : numpy.random.Generator or int
        """
        c = np.asarray(counts)
        if not np.issubdtype(c.dtype, np.integer) or (c.size and c.min() < 0):
            raise ConfigError("counts must be a non-negative integer image (tracer photon counts)")
        ppc = _positive("photons_per_count", photons_per_count)
        gen = _as_generator(rng)
        p = self.quantum_efficiency * ppc
        if p <= 1.0:
            electrons = gen.binomial(c.astype(np.int64), p).astype(np.float64)
        else:
            log.warning(
                "each traced ray stands for %.3g detected electrons: shot-noise variance is "
                "overestimated by a factor %.3g; trace more rays per particle",
                p,
                1 + 1 / p,
            )
            electrons = gen.poisson(p * c).astype(np.float64)
        return self._read_out(electrons, gen)

    def _read_out(self, electrons: np.ndarray, gen: np.random.Generator) -> np.ndarray:
        """Full well, read noise, gain, offset, quantisation and saturation (in place)."""
        if self.full_well_e is not None:
            np.minimum(electrons, self.full_well_e, out=electrons)
        if self.read_noise_e > 0:
            electrons += gen.normal(0.0, self.read_noise_e, size=electrons.shape)
        return _quantise(electrons * self.gain_dn_per_e + self.offset_dn, self.bit_depth)

    def mean_dn(self, photons: np.ndarray | float) -> np.ndarray | float:
        """Theoretical mean ``gain · QE · photons + offset`` (DN) of :meth:`expose`.

        Ignores full-well and ADC clipping (valid well below saturation).

        Parameters
        ----------
        photons : float or ndarray
            Expected photons per pixel.

        Returns
        -------
        float or ndarray
            Mean in DN, a float for scalar input.
        """
        ph = _finite_non_negative_array("photons", photons)
        return _per_value(
            photons, self.gain_dn_per_e * self.quantum_efficiency * ph + self.offset_dn
        )

    def variance_dn(
        self, photons: np.ndarray | float, *, quantisation: bool = True
    ) -> np.ndarray | float:
        """Theoretical variance (DN²) of :meth:`expose`.

        ``gain² · (QE · photons + read_noise_e²) + 1/12``: shot noise (Poisson variance equals
        its mean), read noise, and — with ``quantisation`` — the 1/12 DN² of rounding
        (Sheppard's correction, accurate when the total σ ≳ 0.5 DN). Ignores clipping.

        Parameters
        ----------
        photons : float or ndarray
            Expected photons per pixel.
        quantisation : bool
            Include the 1/12 DN² rounding term.

        Returns
        -------
        float or ndarray
            Variance in DN², a float for scalar input.
        """
        ph = _finite_non_negative_array("photons", photons)
        var = self.gain_dn_per_e**2 * (self.quantum_efficiency * ph + self.read_noise_e**2)
        if quantisation:
            var = var + QUANTISATION_VAR_DN2
        return _per_value(photons, var)

    def snr(self, photons: np.ndarray | float, *, quantisation: bool = True) -> np.ndarray | float:
        """Theoretical SNR of a pixel receiving ``photons`` expected photons per exposure.

        ``SNR = gain · QE · photons / sqrt(variance_dn(photons, quantisation=quantisation))``:
        the mean signal above the black level over the standard deviation of the recorded
        value. With ``quantisation=True`` (default) the 1/12 DN² of rounding counts as noise,
        as it does in :func:`measure_snr` (EMVA 1288 convention); with ``False`` this is
        ``QE·photons / sqrt(QE·photons + read_noise_e²)``, independent of the gain. For an
        image, the SNR ``S / sigma_noise`` corresponds to ``photons`` at the signal reference
        ``S`` (:func:`signal_reference`: the 99.9th-percentile pixel of a dense image), with
        that pixel's noise. Zero where the signal is zero.

        Parameters
        ----------
        photons : float or ndarray
            Expected photons per pixel.
        quantisation : bool
            Count rounding noise.

        Returns
        -------
        float or ndarray
            SNR (dimensionless), a float for scalar input.
        """
        ph = _finite_non_negative_array("photons", photons)
        signal = self.gain_dn_per_e * self.quantum_efficiency * ph
        sigma = np.sqrt(np.asarray(self.variance_dn(ph, quantisation=quantisation)))
        out = np.divide(signal, sigma, out=np.zeros_like(signal), where=signal > 0)
        return _per_value(photons, out)


# -- exposure follows frame rate -----------------------------------------------------------
def _positive_array(name: str, value: Any) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be numeric, got {value!r}") from exc
    if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ConfigError(f"{name} must be positive and finite, got {value!r}")
    return arr


def exposure_s(fps: float | np.ndarray, duty_cycle: float = 1.0) -> float | np.ndarray:
    """Exposure time ``duty_cycle / fps`` (s) of a camera running at ``fps`` frames per second.

    Parameters
    ----------
    fps : float or ndarray
        Frame rate, frames per second (> 0).
    duty_cycle : float
        Fraction of the frame period the sensor integrates, in (0, 1].

    Returns
    -------
    float or ndarray
        Exposure time in seconds, a float for scalar ``fps``.
    """
    f = _positive_array("fps", fps)
    duty = _check_fraction("duty_cycle", duty_cycle)
    return _per_value(fps, duty / f)


def photons_per_frame(
    photon_rate_per_s: float | np.ndarray, fps: float | np.ndarray, duty_cycle: float = 1.0
) -> float | np.ndarray:
    """Expected photons per frame, ``photon_rate_per_s · duty_cycle / fps``.

    Parameters
    ----------
    photon_rate_per_s : float or ndarray
        Photons per second reaching a pixel (≥ 0).
    fps : float or ndarray
        Frame rate (> 0); broadcast against ``photon_rate_per_s``.
    duty_cycle : float
        Fraction of the frame period exposed, in (0, 1].

    Returns
    -------
    float or ndarray
        Photons per pixel per frame, a float when both inputs are scalars.
    """
    rate = _finite_non_negative_array("photon_rate_per_s", photon_rate_per_s)
    t = np.asarray(exposure_s(fps, duty_cycle))
    out = rate * t
    return float(out) if out.ndim == 0 else out


def snr_vs_fps(
    camera: CameraModel,
    photon_rate_per_s: float,
    fps_values: np.ndarray,
    duty_cycle: float = 1.0,
) -> np.ndarray:
    """Theoretical SNR of a pixel receiving ``photon_rate_per_s`` at each frame rate.

    ``camera.snr(photons_per_frame(photon_rate_per_s, fps, duty_cycle))`` (see
    :meth:`CameraModel.snr`); it falls as the frame rate rises because each frame collects
    fewer photons (paper Fig. 4c, 100 → 25 000 fps).

    Parameters
    ----------
    camera : CameraModel
    photon_rate_per_s : float
        Photons per second reaching the pixel (≥ 0).
    fps_values : array_like, shape (n,)
        Frame rates, frames per second (> 0).
    duty_cycle : float
        Fraction of the frame period exposed, in (0, 1].

    Returns
    -------
    ndarray, shape of ``fps_values``
        SNR at each frame rate.
    """
    if not isinstance(camera, CameraModel):
        raise ConfigError(f"camera must be a CameraModel, got {type(camera).__name__}")
    if np.ndim(photon_rate_per_s) != 0:
        raise ConfigError(f"photon_rate_per_s must be a scalar, got {photon_rate_per_s!r}")
    fps = _positive_array("fps_values", fps_values)
    ph = np.asarray(photons_per_frame(photon_rate_per_s, fps, duty_cycle))
    return np.asarray(camera.snr(ph), dtype=np.float64)


# -- choosing and applying a model ---------------------------------------------------------
@dataclass(frozen=True)
class NoiseSpec:
    """Which noise model to apply and its parameters.

    Parameters
    ----------
    model : {"none", "gaussian", "camera"}
        See the module docstring.
    snr : float or None
        ``S / sigma_noise`` with ``S`` the 99.9th percentile of the noise-free image (or, for
        sparse images, half that of its lit pixels; :func:`signal_reference`); required for
        ``"gaussian"``, must be ``None`` otherwise (the camera model's SNR follows from its
        photons).
    bit_depth : {8, 12, 16} or None
        Output bits per pixel. Default 8 for ``"none"``/``"gaussian"``; for ``"camera"`` the
        camera's own bit depth (giving a different one is an error).
    camera : CameraModel or None
        Camera for ``"camera"`` (default :class:`CameraModel()`); must be ``None`` otherwise.
    fps : float or None
        Frame rate (frames/s), ``"camera"`` only, together with ``photon_rate_per_s``.
    duty_cycle : float
        Exposed fraction of the frame period, in (0, 1].
    photon_rate_per_s : float or None
        ``"camera"`` only. Photons per second at the signal reference ``S`` of the clean
        image (its 99.9th-percentile pixel; :func:`signal_reference`); when given (with
        ``fps``), :func:`apply_noise` treats the clean image as relative and scales it so that
        ``S`` receives
        ``photons_per_frame(photon_rate_per_s, fps, duty_cycle)`` photons. When ``None`` the
        clean image is already the expected photon count per pixel for this exposure.
    fill : float
        ``"none"``/``"gaussian"``: fraction of full scale the image maximum maps to.
    offset_sigmas : float
        ``"gaussian"``: black level in noise σ (see :func:`add_gaussian_noise`).
    """

    model: str = "gaussian"
    snr: float | None = None
    bit_depth: int | None = None
    camera: CameraModel | None = None
    fps: float | None = None
    duty_cycle: float = 1.0
    photon_rate_per_s: float | None = None
    fill: float = 0.7
    offset_sigmas: float = 4.0

    def __post_init__(self) -> None:
        if self.model not in NOISE_MODELS:
            raise ConfigError(f"model must be one of {NOISE_MODELS}, got {self.model!r}")

        def set_(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        if self.model == "gaussian":
            if self.snr is None:
                raise ConfigError("snr is required for model 'gaussian' (S / sigma_noise)")
            set_("snr", _positive("snr", self.snr))
        elif self.snr is not None:
            raise ConfigError(
                f"snr applies only to model 'gaussian', got snr={self.snr!r} with "
                f"model={self.model!r}"
            )
        set_("duty_cycle", _check_fraction("duty_cycle", self.duty_cycle))
        set_("fill", _check_fraction("fill", self.fill))
        set_("offset_sigmas", _non_negative("offset_sigmas", self.offset_sigmas))

        if self.model == "camera":
            cam = self.camera
            if cam is None:
                cam = CameraModel()
            elif isinstance(cam, Mapping):
                cam = CameraModel.from_dict(cam)
            elif not isinstance(cam, CameraModel):
                raise ConfigError(
                    f"camera must be a CameraModel or a mapping, got {type(cam).__name__}"
                )
            set_("camera", cam)
            if self.bit_depth is None:
                set_("bit_depth", cam.bit_depth)
            elif _check_bit_depth("bit_depth", self.bit_depth) != cam.bit_depth:
                raise ConfigError(
                    f"bit_depth={self.bit_depth!r} differs from camera.bit_depth="
                    f"{cam.bit_depth}; give one or make them equal"
                )
            if (self.fps is None) != (self.photon_rate_per_s is None):
                raise ConfigError(
                    "fps and photon_rate_per_s must be given together (got "
                    f"fps={self.fps!r}, photon_rate_per_s={self.photon_rate_per_s!r})"
                )
            if self.fps is not None:
                set_("fps", _positive("fps", self.fps))
                set_(
                    "photon_rate_per_s",
                    _positive("photon_rate_per_s", self.photon_rate_per_s),
                )
        else:
            for name in ("camera", "fps", "photon_rate_per_s"):
                if getattr(self, name) is not None:
                    raise ConfigError(
                        f"{name} applies only to model 'camera', got {name}="
                        f"{getattr(self, name)!r} with model={self.model!r}"
                    )
            set_("bit_depth", 8 if self.bit_depth is None else self.bit_depth)
            set_("bit_depth", _check_bit_depth("bit_depth", self.bit_depth))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> NoiseSpec:
        """Build from a mapping (e.g. parsed JSON).

        ``camera`` may be a nested mapping of :class:`CameraModel` parameters. Unknown keys, at
        either level, raise :class:`ConfigError` naming them.
        """
        if not isinstance(d, Mapping):
            raise ConfigError(f"noise must be a mapping of parameters, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(
                f"noise: unknown key(s) {unknown}; expected a subset of {sorted(known)}"
            )
        kw = dict(d)
        if isinstance(kw.get("camera"), Mapping):
            kw["camera"] = CameraModel.from_dict(kw["camera"])
        return cls(**kw)

    def to_dict(self) -> dict:
        """The parameters as a JSON-serialisable dict (inverse of :meth:`from_dict`)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        if self.camera is not None:
            out["camera"] = self.camera.to_dict()
        return out


def apply_noise(
    clean_photons: np.ndarray, spec: NoiseSpec, rng: np.random.Generator | int
) -> tuple[np.ndarray, dict]:
    """Turn a noise-free image into a camera-like integer image according to ``spec``.

    - ``"none"``: :func:`scale_to_dn` (scaled to ``spec.fill`` of full scale, rounded).
    - ``"gaussian"``: :func:`add_gaussian_noise` with ``spec.snr``
      (``SNR = S / sigma_noise``, ``S`` the 99.9th percentile of the clean image or, for
      sparse images, half that of its lit pixels; :func:`signal_reference`).
    - ``"camera"``: :meth:`CameraModel.expose`. ``clean_photons`` must be the expected photon
      count per pixel for this exposure, unless ``spec.photon_rate_per_s`` and ``spec.fps``
      are set: then it is a relative image (its overall scale, e.g. photons per particle, is
      arbitrary) rescaled so that its signal reference ``S`` receives
      ``photons_per_frame(spec.photon_rate_per_s, spec.fps, spec.duty_cycle)`` photons.

    Parameters
    ----------
    clean_photons : ndarray, shape (ny, nx)
        Noise-free image, finite, non-negative, not all zero ("no particles in the field of
        view" otherwise).
    spec : NoiseSpec
    rng : numpy.random.Generator or int
        Generator or seed (unused, but still validated, for ``"none"``).

    Returns
    -------
    image : ndarray of uint8 or uint16, shape (ny, nx)
    info : dict
        Always holds ``model``, ``bit_depth``, ``offset_dn`` and ``scale_dn_per_unit`` (the
        noise-free image in DN is ``scale_dn_per_unit · clean_photons + offset_dn``, below
        saturation) and ``snr``. For ``"camera"``, ``snr`` is the theoretical
        :meth:`CameraModel.snr` at the signal reference ``S``, and the dict adds
        ``photons_per_unit``, ``photons_p999`` (the photons at ``S``: the 99.9th-percentile
        pixel of a dense image), ``exposure_s`` (``None`` without ``fps``) and ``camera`` (its
        parameters).
    """
    if not isinstance(spec, NoiseSpec):
        raise ConfigError(f"spec must be a NoiseSpec, got {type(spec).__name__}")
    gen = _as_generator(rng)
    if spec.model == "none":
        return scale_to_dn(clean_photons, bit_depth=spec.bit_depth, fill=spec.fill)
    if spec.model == "gaussian":
        return add_gaussian_noise(
            clean_photons,
            spec.snr,
            gen,
            bit_depth=spec.bit_depth,
            fill=spec.fill,
            offset_sigmas=spec.offset_sigmas,
        )
    cam = spec.camera
    img, _ = _validate_clean(clean_photons, "clean_photons")
    if spec.photon_rate_per_s is not None:
        target = photons_per_frame(spec.photon_rate_per_s, spec.fps, spec.duty_cycle)
        per_unit = target / _reference(img)
        t_exp = exposure_s(spec.fps, spec.duty_cycle)
    else:
        per_unit = 1.0
        t_exp = None
    photons = per_unit * img
    p999_photons = _reference(photons)
    info = {
        "model": "camera",
        "bit_depth": cam.bit_depth,
        "offset_dn": cam.offset_dn,
        "scale_dn_per_unit": float(cam.gain_dn_per_e * cam.quantum_efficiency * per_unit),
        "snr": float(cam.snr(p999_photons)),
        "photons_per_unit": float(per_unit),
        "photons_p999": p999_photons,
        "exposure_s": t_exp,
        "camera": cam.to_dict(),
    }
    if np.issubdtype(np.asarray(clean_photons).dtype, np.integer):
        # Tracer photon counts: thin them rather than adding shot noise a second time.
        info["shot_noise"] = "binomial thinning of traced photon counts"
        return cam.expose_counts(np.asarray(clean_photons), per_unit, gen), info
    info["shot_noise"] = "poisson"
    return cam.expose(photons, gen), info
