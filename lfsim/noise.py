"""Noise models: turn a noise-free light-field image into camera-like integers.

Three models (:data:`NOISE_MODELS`), chosen with a :class:`NoiseSpec` and applied by
:func:`apply_noise`:

``"none"``
    Scale the clean image to the camera's digital range (its maximum at ``fill`` of full scale)
    and round; no noise (:func:`scale_to_dn`).
``"gaussian"``
    The paper's model (:func:`add_gaussian_noise`): additive white Gaussian noise of a
    prescribed signal-to-noise ratio,

        ``SNR = S / sigma_noise``,  ``S = max(P99.9(clean), ½ · P99.9(lit pixels of clean))``

    (:func:`signal_reference`): the paper's 99.9th percentile of the noise-free image, which
    stays defined for sparse images (a single particle lights fewer than 0.1 % of the pixels,
    and its P99.9 is 0) through the 99.9th percentile of the pixels that receive light.
    :func:`measure_snr` measures it.
``"camera"``
    The physical camera of :mod:`lfsim.camera` (:class:`~lfsim.camera.CameraModel`): shot
    noise, read noise, gain, offset, quantisation, saturation, exposure from the frame rate.

Images are ``(y, x)`` arrays; digital values are in DN (digital numbers, ADU). Everything here
is plain numpy and takes a seed or a :class:`numpy.random.Generator`, so the same inputs and
seed give identical images.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from hrvbase.validate import known_keys, nonnegative_float, positive_float

from .camera import (
    CameraModel,
    _as_generator,
    _check_bit_depth,
    _check_fraction,
    _checked,
    _finite_non_negative_array,
    _full_scale,
    _quantise,
    exposure_s,
    photons_per_frame,
)
from .errors import ConfigError

log = logging.getLogger(__name__)

NOISE_MODELS = ("none", "gaussian", "camera")

#: Percentile of the clean image that defines the signal in the SNR (the paper's P99.9).
SNR_PERCENTILE = 99.9

#: Fraction of the lit pixels' P99.9 below which the signal reference never falls: the
#: reference of sparse images (:func:`signal_reference`). Dense images stay above it (in
#: every experiment of ``scenes/experiments``, P99.9 is 0.62–0.90 of the lit pixels' P99.9).
SPARSE_FRACTION = 0.5

#: The SNR definition, as recorded in metadata.
SNR_DEFINITION = (
    "S / sigma_noise with S = max(P99.9(clean image), 0.5 * P99.9(lit pixels of the clean "
    "image)): the 99.9th percentile of the noise-free image, or half that of its pixels "
    "above zero when it is higher (sparse images)"
)


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
    snr = _checked(positive_float, snr, "snr")
    bit_depth = _check_bit_depth("bit_depth", bit_depth)
    fill = _check_fill(fill)
    offset_sigmas = _checked(nonnegative_float, offset_sigmas, "offset_sigmas")
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
        Camera for ``"camera"`` (default ``CameraModel()``); must be ``None`` otherwise.
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
            set_("snr", _checked(positive_float, self.snr, "snr"))
        elif self.snr is not None:
            raise ConfigError(
                f"snr applies only to model 'gaussian', got snr={self.snr!r} with "
                f"model={self.model!r}"
            )
        set_("duty_cycle", _check_fraction("duty_cycle", self.duty_cycle))
        set_("fill", _check_fraction("fill", self.fill))
        set_("offset_sigmas", _checked(nonnegative_float, self.offset_sigmas, "offset_sigmas"))

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
                set_("fps", _checked(positive_float, self.fps, "fps"))
                set_(
                    "photon_rate_per_s",
                    _checked(positive_float, self.photon_rate_per_s, "photon_rate_per_s"),
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
        kw = known_keys(cls, d, "noise", error=ConfigError)
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
    - ``"camera"``: :meth:`~lfsim.camera.CameraModel.expose`. ``clean_photons`` must be the
      expected photon count per pixel for this exposure, unless ``spec.photon_rate_per_s`` and
      ``spec.fps`` are set: then it is a relative image (its overall scale, e.g. photons per
      particle, is arbitrary) rescaled so that its signal reference ``S`` receives
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
        :meth:`~lfsim.camera.CameraModel.snr` at the signal reference ``S``, and the dict adds
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


__all__ = [
    "NOISE_MODELS",
    "NO_SIGNAL",
    "SNR_DEFINITION",
    "SNR_PERCENTILE",
    "SPARSE_FRACTION",
    "NoiseSpec",
    "add_gaussian_noise",
    "apply_noise",
    "measure_snr",
    "scale_to_dn",
    "signal_reference",
]
