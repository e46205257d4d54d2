"""The physical camera: photons in, camera-like integers out, exposure set by the frame rate.

:class:`CameraModel` is a linear camera: photon shot noise (Poisson, or binomial thinning of a
tracer's photon counts), full-well clipping, Gaussian read noise, conversion gain, black-level
offset, quantisation and saturation. The exposure time follows the frame rate
(:func:`exposure_s`, :func:`photons_per_frame`), so at a fixed photon rate the SNR falls as the
frame rate rises (paper Fig. 4c, 100 → 25 000 fps; :func:`snr_vs_fps`).

The noise models that turn a rendered image into a frame — none, the paper's Gaussian noise at
a given SNR, or this camera — are chosen and applied in :mod:`lfsim.noise`.

Images are ``(y, x)`` arrays; digital values are in DN (digital numbers, ADU); charges in
electrons (e⁻); photons per pixel per exposure; times in seconds. Everything here is plain
numpy and takes a seed or a :class:`numpy.random.Generator`, so the same inputs and seed give
identical images.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from hrvbase.errors import InputError
from hrvbase.validate import known_keys, nonnegative_float, positive_float

from .errors import ConfigError

log = logging.getLogger(__name__)

#: Bits per pixel of the cameras modelled (8 → uint8, 12 and 16 → uint16).
BIT_DEPTHS = (8, 12, 16)

#: Variance (DN²) of the rounding error of a uniform quantiser of step 1 DN.
QUANTISATION_VAR_DN2 = 1.0 / 12.0

#: Largest expected photon count per pixel :meth:`CameraModel.expose` accepts (numpy's Poisson
#: sampler fails for much larger means; such a pixel saturates any real camera).
MAX_PHOTONS_PER_PIXEL = 1e15


# -- checks and digital basics (shared with lfsim.noise) -----------------------------------
def _checked(check: Callable[[Any, str], Any], value: Any, name: str) -> Any:
    """``check(value, name)`` of :mod:`hrvbase.validate`, failing as :class:`ConfigError`.

    lfsim's callers (experiment files, datasets) add the file and section to a
    :class:`ConfigError`; the message, naming the parameter, is the validator's.
    """
    try:
        return check(value, name)
    except InputError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(str(exc)) from None


def _check_bit_depth(name: str, value: Any) -> int:
    ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
    if not ok or value not in BIT_DEPTHS or int(value) != value:
        raise ConfigError(f"{name} must be one of {BIT_DEPTHS}, got {value!r}")
    return int(value)


def _check_fraction(name: str, value: Any) -> float:
    v = _checked(positive_float, value, name)
    if v > 1:
        raise ConfigError(f"{name} must lie in (0, 1], got {value!r}")
    return v


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
        checks = {
            "quantum_efficiency": lambda v, n: _check_fraction(n, v),
            "read_noise_e": nonnegative_float,
            "gain_dn_per_e": positive_float,
            "offset_dn": nonnegative_float,
            "bit_depth": lambda v, n: _check_bit_depth(n, v),
            "full_well_e": positive_float,
        }
        for name, check in checks.items():
            value = getattr(self, name)
            if name == "full_well_e" and value is None:
                continue
            object.__setattr__(self, name, _checked(check, value, name))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CameraModel:
        """Build from a mapping (e.g. parsed JSON); unknown keys raise :class:`ConfigError`."""
        return cls(**known_keys(cls, d, "camera", error=ConfigError))

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
        ppc = _checked(positive_float, photons_per_count, "photons_per_count")
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
        as it does in :func:`lfsim.noise.measure_snr` (EMVA 1288 convention); with ``False`` this is
        ``QE·photons / sqrt(QE·photons + read_noise_e²)``, independent of the gain. For an
        image, the SNR ``S / sigma_noise`` corresponds to ``photons`` at the signal reference
        ``S`` (:func:`lfsim.noise.signal_reference`: the 99.9th-percentile pixel of a dense
        image), with that pixel's noise. Zero where the signal is zero.

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


__all__ = [
    "BIT_DEPTHS",
    "MAX_PHOTONS_PER_PIXEL",
    "QUANTISATION_VAR_DN2",
    "CameraModel",
    "exposure_s",
    "photons_per_frame",
    "snr_vs_fps",
]
