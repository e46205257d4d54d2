"""Synthetic white images with a known lenslet grid, for the calibration and rectification tests.

A test helper, not part of :mod:`recon`'s API.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from hrvbase.validate import finite_float, int_in_range
from recon.errors import InputError, recon_input_errors
from recon.lenslet_grid import pair


def synthetic_white(
    shape: tuple[int, int],
    grid: Any,
    *,
    disc_fraction: float = 0.95,
    blur_px: float = 0.5,
    vignetting: float = 0.0,
    noise_sigma: float = 0.0,
    hot_pixels: int = 0,
    dead_fraction: float = 0.0,
    supersample: int = 4,
    rng: int | np.random.Generator | None = 0,
) -> np.ndarray:
    """An analytic white image of a lenslet grid.

    Each lenslet image is a uniform disc of diameter ``disc_fraction · pitch`` and level 1,
    centred on the lenslet centre, anti-aliased by averaging 4 × 4 sub-samples per pixel, then
    blurred by a Gaussian; the image is multiplied by a vignetting profile, then noise and hot
    pixels are added.

    Parameters
    ----------
    shape : tuple of int
        ``(height, width)`` in pixels.
    grid : LensletGrid or object with ``pitch_px``, ``rotation_deg``, ``origin_xy_px``
        The lenslet grid (continuous pixel coordinates, see :mod:`recon.lenslet_grid`).
    disc_fraction : float
        Disc diameter / pitch, in ``(0, 1.5]``.
    blur_px : float
        Gaussian blur σ in pixels (0: none).
    vignetting : float
        Fractional fall-off at the image corners, in ``[0, 1)``: a ``cos⁴`` profile about the
        image centre falling to ``1 − vignetting`` at the corners.
    noise_sigma : float
        σ of additive Gaussian noise (the disc level is 1).
    hot_pixels : int
        Number of random pixels set to full scale (1.0).
    dead_fraction : float
        Fraction of the lenslets whose centre lies in the image that are dark (0 everywhere).
    supersample : int
        Sub-samples per pixel along each axis (anti-aliasing of the disc edges).
    rng : int or numpy.random.Generator
        Seed or generator for the dead lenslets, noise and hot pixels.

    Returns
    -------
    ndarray of float64, shape (height, width)
    """
    h, w = pair(shape, "shape", int)
    try:
        with recon_input_errors():
            p = finite_float(grid.pitch_px, "grid.pitch_px")
            theta = math.radians(finite_float(grid.rotation_deg, "grid.rotation_deg"))
        x0, y0 = pair(grid.origin_xy_px, "grid.origin_xy_px", float)
    except AttributeError as exc:
        raise InputError(f"grid must have pitch_px, rotation_deg and origin_xy_px: {exc}") from None
    if p < 2:
        raise InputError(f"grid.pitch_px must be at least 2, got {p!r}")
    checks = (
        ("disc_fraction", disc_fraction, 0.0, 1.5, False),
        ("blur_px", blur_px, 0.0, 100.0, True),
        ("vignetting", vignetting, 0.0, 1.0, True),
        ("noise_sigma", noise_sigma, 0.0, math.inf, True),
        ("dead_fraction", dead_fraction, 0.0, 1.0, True),
    )
    with recon_input_errors():
        for name, value, lo, hi, lo_ok in checks:
            val = finite_float(value, name)
            if not ((lo <= val if lo_ok else lo < val) and val <= hi) or (
                name == "vignetting" and val >= 1.0
            ):
                raise InputError(f"{name} is out of range: got {value!r}")
        int_in_range(hot_pixels, "hot_pixels", 0)
        int_in_range(supersample, "supersample", 1)
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)

    cos_t, sin_t = math.cos(theta), math.sin(theta)
    # Index range of every lenslet that can touch the image.
    corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]) - (x0, y0)
    cu = (corners[:, 0] * cos_t + corners[:, 1] * sin_t) / p
    cv = (-corners[:, 0] * sin_t + corners[:, 1] * cos_t) / p
    ulo, uhi = math.floor(cu.min()) - 2, math.ceil(cu.max()) + 2
    vlo, vhi = math.floor(cv.min()) - 2, math.ceil(cv.max()) + 2
    dead = np.zeros((vhi - vlo + 1, uhi - ulo + 1), bool)
    if dead_fraction > 0:
        vv, uu = np.mgrid[vlo : vhi + 1, ulo : uhi + 1]
        cx = x0 + p * (cos_t * uu - sin_t * vv)
        cy = y0 + p * (sin_t * uu + cos_t * vv)
        inside = np.flatnonzero(((cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)).ravel())
        pick = gen.choice(inside, size=round(dead_fraction * inside.size), replace=False)
        dead.ravel()[pick] = True

    ss = int(supersample)
    r2max = (0.5 * disc_fraction) ** 2
    img = np.zeros((h, w))
    jj = np.arange(w)[None, :]
    ii = np.arange(h)[:, None]
    for sy in range(ss):
        dy = ii + (sy + 0.5) / ss - y0
        for sx in range(ss):
            dx = jj + (sx + 0.5) / ss - x0
            u = (dx * cos_t + dy * sin_t) / p
            v = (-dx * sin_t + dy * cos_t) / p
            ru, rv = np.rint(u), np.rint(v)
            inside = (u - ru) ** 2 + (v - rv) ** 2 <= r2max
            alive = ~dead[rv.astype(int) - vlo, ru.astype(int) - ulo]
            img += inside & alive
    img /= ss * ss
    if blur_px > 0:
        img = ndimage.gaussian_filter(img, blur_px, mode="nearest")
    if vignetting > 0:
        r2 = (jj + 0.5 - w / 2) ** 2 + (ii + 0.5 - h / 2) ** 2
        rc = math.hypot(w / 2, h / 2)
        alpha_c = math.acos((1.0 - vignetting) ** 0.25)
        dist = rc / math.tan(alpha_c)
        img = img * (dist**2 / (dist**2 + r2)) ** 2
    if noise_sigma > 0:
        img = img + gen.normal(0.0, noise_sigma, img.shape)
    if hot_pixels:
        flat = gen.choice(img.size, size=min(int(hot_pixels), img.size), replace=False)
        img.ravel()[flat] = 1.0
    return img
