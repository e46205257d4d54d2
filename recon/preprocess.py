"""Camera images to clean, non-negative float images: the first step of reconstruction.

Real light-field frames arrive as 8-, 12- or 16-bit TIFFs with a black level, hot pixels and
often a region of interest smaller than the sensor (vignetting). :func:`prepare_image`
applies, in order: conversion to float32, dark-frame or constant background subtraction,
hot-pixel suppression, and clipping at zero (Richardson–Lucy needs non-negative data). A dark
frame brighter than a frame (:func:`check_dark`) and a negative constant background are
refused: either would add light to every pixel instead of removing the black level.
The region of interest is applied later, by choosing which lenslets to rectify
(:func:`recon.pipeline.lenslet_window`), so that the lenslet grid stays that of the full
calibration image.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from .errors import InputError

log = logging.getLogger(__name__)


def read_frame(
    path: str | os.PathLike, what: str = "frame", *, page: int | None = None, reader=None
) -> np.ndarray:
    """Read one 2-D light-field image (8/12/16-bit integer or float TIFF) as float32.

    ``what`` names the image in error messages ("frame", "white image", "dark frame").
    ``page`` selects one page of a multi-page stack; without it the file must hold one image.
    ``reader`` (a :class:`recon.frames.FrameReader`) keeps a stack open between its pages.

    Raises
    ------
    InputError
        Missing or unreadable file, a stack instead of one image (or a page beyond its end),
        a non-numeric pixel type, non-finite pixels.
    """
    from .frames import FrameRef, read_raw

    ref = FrameRef(Path(path), page)
    arr = read_raw(ref, what) if reader is None else reader.read(ref, what)
    if arr.dtype.kind not in "uif":
        raise InputError(f"{what} {ref.label!r} has unsupported pixel type {arr.dtype}")
    out = arr.astype(np.float32)
    if not np.all(np.isfinite(out)):
        raise InputError(f"{what} {ref.label!r} holds non-finite pixels (NaN or inf)")
    return out


def suppress_hot_pixels(image: np.ndarray, threshold: float = 8.0) -> tuple[np.ndarray, int]:
    """Replace isolated outliers by the median of their 3 × 3 neighbourhood.

    A pixel is hot when it exceeds its neighbourhood median by more than ``threshold`` robust
    standard deviations (1.4826 × the image-wide median absolute deviation of
    ``image − median``, floored at one grey level) *and* none of its 8 neighbours rises above
    the median by more than 5 % of that excess. Light-field spots are never that isolated:
    the diffraction blur alone (σ ≈ 0.4 px at the paper's optics) puts ≳ 10 % of a spot's peak
    into its neighbours.

    Returns
    -------
    cleaned : ndarray
    n_replaced : int
    """
    img = np.asarray(image, dtype=np.float32)
    med = ndimage.median_filter(img, size=3, mode="nearest")
    resid = img - med
    sigma = max(1.4826 * float(np.median(np.abs(resid - np.median(resid)))), 1.0)
    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    neighbours = ndimage.maximum_filter(img, footprint=ring, mode="nearest") - med
    hot = (resid > threshold * sigma) & (neighbours < 0.05 * resid)
    out = np.where(hot, med, img).astype(np.float32)
    return out, int(hot.sum())


@dataclass(frozen=True)
class Preprocess:
    """Settings of :func:`prepare_image`.

    Parameters
    ----------
    dark : ndarray or None
        Dark frame (same shape as the images) subtracted pixel by pixel; it must not be
        brighter than the images (:func:`check_dark`).
    background : float or "auto" or None
        Constant (≥ 0 grey levels) subtracted after the dark frame. ``"auto"`` uses the
        image's median: in a
        light-field image of sparse fluorescent particles most pixels see only the camera's
        black level (and its noise). ``None``: nothing.
    hot_pixels : bool
        Suppress isolated hot pixels (off by default; real cameras usually want it).
    hot_threshold : float
        See :func:`suppress_hot_pixels`.
    gain_dn_per_e : float
        The camera's conversion gain (grey levels per photo-electron, from its data sheet or
        a photon-transfer measurement), for the shot noise of the signal in
        :func:`frame_snr`; 0 (default): the noise is taken as additive (the background's).
    dark_name : str
        How messages name the dark frame (``recon run``: the ``--dark`` option and file);
        not a setting of the result.
    """

    dark: np.ndarray | None = None
    background: float | str | None = None
    hot_pixels: bool = False
    hot_threshold: float = 8.0
    gain_dn_per_e: float = 0.0
    dark_name: str = "the dark frame"

    def __post_init__(self) -> None:
        b = self.background
        number = isinstance(b, int | float) and not isinstance(b, bool) and np.isfinite(b)
        if not (b is None or b == "auto" or (number and b >= 0)):
            raise InputError(f"background must be a number >= 0, 'auto' or None, got {b!r}")
        if self.hot_threshold <= 0:
            raise InputError(f"hot_threshold must be > 0, got {self.hot_threshold!r}")
        g = self.gain_dn_per_e
        if isinstance(g, bool) or not isinstance(g, int | float) or not (np.isfinite(g) and g >= 0):
            raise InputError(f"gain_dn_per_e must be a finite number >= 0, got {g!r}")

    def to_dict(self) -> dict:
        out = {
            "dark": self.dark is not None,
            "background": self.background,
            "hot_pixels": self.hot_pixels,
            "hot_threshold": self.hot_threshold,
        }
        if self.gain_dn_per_e:  # (absent when 0: the record of earlier runs, resumable)
            out["gain_dn_per_e"] = float(self.gain_dn_per_e)
        return out


#: Percentile of the image taken as its signal level (the simulator's SNR definition,
#: ``lfsim``'s ``snr_definition``: the 99.9th percentile of the image).
SIGNAL_PERCENTILE = 99.9


def frame_snr(image: np.ndarray, gain_dn_per_e: float = 0.0) -> dict:
    """Noise, signal and signal-to-noise ratio of one camera frame.

    The additive noise ``σ_b`` is the robust standard deviation of the finest diagonal Haar
    wavelet coefficients of the image, ``(a − b − c + d) / 2`` over 2 × 2 blocks (the
    estimator of Donoho & Johnstone, *Biometrika* 81, 1994, as in
    :func:`skimage.restoration.estimate_sigma`): offsets and smooth light cancel, and in a
    frame of sparse particles most blocks see only the camera's noise. The signal ``S`` is
    the 99.9th percentile of the frame above its median; its noise adds the shot noise,
    ``σ = √(σ_b² + g S)`` for a camera gain ``g`` (grey levels per electron), and
    ``SNR = S / σ``: the definition of the simulated studies (paper §4.1, Fig. 4).

    Parameters
    ----------
    image : ndarray, shape (height, width)
        The frame, dark-subtracted, before its background is removed (grey levels).
    gain_dn_per_e : float
        ``g``; 0 for additive noise only.

    Returns
    -------
    dict
        ``noise_dn`` (σ at the signal level), ``signal_dn`` (``S``) and ``snr`` (None when
        the frame holds no noise, e.g. a noise-free rendering).
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = (img.shape[0] // 2) * 2, (img.shape[1] // 2) * 2
    a = img[:h, :w]
    hh = 0.5 * (a[0::2, 0::2] - a[1::2, 0::2] - a[0::2, 1::2] + a[1::2, 1::2])
    sigma_b = 1.4826 * float(np.median(np.abs(hh))) if hh.size else 0.0
    median, top = np.percentile(img, [50.0, SIGNAL_PERCENTILE])  # one partial sort
    signal = max(float(top - median), 0.0)
    noise = float(np.sqrt(sigma_b**2 + gain_dn_per_e * signal))
    return {
        "noise_dn": noise,
        "signal_dn": signal,
        "snr": signal / noise if noise > 0 else None,
    }


#: A dark frame is refused when the median of ``frame − dark`` lies below minus this many
#: times the noise of that difference (:func:`check_dark`).
DARK_NOISE_FACTOR = 3.0


def check_dark(image: np.ndarray, dark: np.ndarray, *, frame: str, dark_name: str) -> None:
    """Refuse a dark frame brighter than a frame.

    A dark frame holds the camera's black level (taken with no light, at the frames'
    exposure), so the median of ``image − dark`` is the light that reaches most pixels and is
    never markedly negative. It is refused when that median lies below ``−max(3 σ, 1)`` grey
    levels, σ being the noise of the difference (:func:`frame_snr`): e.g. the white image
    given as dark frame, which would make a background of minus its level and volumes of
    the wrong sign and scale.

    Parameters
    ----------
    image, dark : ndarray, shape (height, width)
        A frame and the dark frame (grey levels).
    frame, dark_name : str
        How the message names them.

    Raises
    ------
    InputError
        The two shapes differ, or the dark frame is brighter than the frame (one line with
        both medians in grey levels, DN).
    """
    img = np.asarray(image, dtype=np.float32)
    drk = np.asarray(dark, dtype=np.float32)
    if drk.shape != img.shape:
        raise InputError(f"{dark_name} has shape {drk.shape}, {frame} {img.shape}")
    diff = img - drk
    level = float(np.median(diff))
    tolerance = max(DARK_NOISE_FACTOR * frame_snr(diff)["noise_dn"], 1.0)
    if level < -tolerance:
        raise InputError(
            f"{dark_name} is brighter than {frame}: median {float(np.median(drk)):.1f} DN "
            f"against the frame's {float(np.median(img)):.1f} DN (frame − dark {level:.1f} DN, "
            f"below −{tolerance:.1f} DN, {DARK_NOISE_FACTOR:g} × its noise); expected a dark "
            "frame of this camera taken without light at the frames' exposure"
        )


def prepare_image(
    image: np.ndarray, settings: Preprocess | None = None, *, subtract_background: bool = True
) -> tuple[np.ndarray, dict]:
    """Dark-subtracted, hot-pixel-free, non-negative float32 image.

    Parameters
    ----------
    image : ndarray, shape (height, width)
    settings : Preprocess, optional
    subtract_background : bool
        Subtract the background level (and clip at zero); with False the level is only
        estimated (``info["background"]``) and left in the image, for a deconvolution that
        models it (:func:`recon.deconvolve.richardson_lucy` ``background``).

    Returns
    -------
    image : ndarray, float32, same shape
    info : dict
        ``background`` (level estimated or given), ``hot_pixels`` replaced, and the frame's
        ``noise_dn``, ``signal_dn`` and ``snr`` (:func:`frame_snr`).
    """
    st = settings or Preprocess()
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise InputError(f"image must be 2-D (y, x), got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise InputError("image holds non-finite pixels (NaN or inf)")
    if st.dark is not None:
        if st.dark.shape != img.shape:
            raise InputError(f"dark frame shape {st.dark.shape} != image shape {img.shape}")
        img = img - st.dark.astype(np.float32)
    info = {"background": 0.0, "hot_pixels": 0}
    if st.hot_pixels:
        img, info["hot_pixels"] = suppress_hot_pixels(img, st.hot_threshold)
    info.update(frame_snr(img, st.gain_dn_per_e))
    if st.background == "auto":
        info["background"] = float(np.median(img))
    elif st.background is not None:
        info["background"] = float(st.background)
    if subtract_background:
        img = img - info["background"]
    img = np.maximum(img, 0.0).astype(np.float32)
    return img, info
