"""Camera images to clean, non-negative float images: the first step of reconstruction.

Real light-field frames arrive as 8-, 12- or 16-bit TIFFs with a black level, hot pixels and
often a region of interest smaller than the sensor (vignetting). :func:`prepare_image`
applies, in order: conversion to float32, dark-frame or constant background subtraction,
hot-pixel suppression, and clipping at zero (Richardson–Lucy needs non-negative data).
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
        Dark frame (same shape as the images) subtracted pixel by pixel.
    background : float or "auto" or None
        Constant subtracted after the dark frame. ``"auto"`` uses the image's median: in a
        light-field image of sparse fluorescent particles most pixels see only the camera's
        black level (and its noise). ``None``: nothing.
    hot_pixels : bool
        Suppress isolated hot pixels (off by default; real cameras usually want it).
    hot_threshold : float
        See :func:`suppress_hot_pixels`.
    """

    dark: np.ndarray | None = None
    background: float | str | None = None
    hot_pixels: bool = False
    hot_threshold: float = 8.0

    def __post_init__(self) -> None:
        b = self.background
        if not (b is None or b == "auto" or (isinstance(b, int | float) and np.isfinite(b))):
            raise InputError(f"background must be a number, 'auto' or None, got {b!r}")
        if self.hot_threshold <= 0:
            raise InputError(f"hot_threshold must be > 0, got {self.hot_threshold!r}")

    def to_dict(self) -> dict:
        return {
            "dark": self.dark is not None,
            "background": self.background,
            "hot_pixels": self.hot_pixels,
            "hot_threshold": self.hot_threshold,
        }


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
        ``background`` (level estimated or given), ``hot_pixels`` replaced.
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
    if st.background == "auto":
        info["background"] = float(np.median(img))
    elif st.background is not None:
        info["background"] = float(st.background)
    if subtract_background:
        img = img - info["background"]
    img = np.maximum(img, 0.0).astype(np.float32)
    return img, info
