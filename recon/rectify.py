"""Rectification: resample a light-field image onto whole pixels per lenslet.

Design decision: reconstruction works on *rectified* images, as oLaF
does. The raw image is resampled onto a grid aligned with the lenslet array with an integer
number ``n`` of pixels per lenslet, so that lenslet ``(u0 + U, v0 + V)`` occupies exactly the
output block ``[V n, (V + 1) n) × [U n, (U + 1) n)``. The forward model can then use the exact
lenslet periodicity with integer-pixel patterns (one PSF per position inside a lenslet), which
is what makes the light-field PSF bank small and the convolutions exact.

Mapping (continuous pixel coordinates, pixel ``(i, j)`` centred at ``(j + 0.5, i + 0.5)``, see
:mod:`recon.lenslet_grid`): the output pixel ``(r, c)`` samples the input at::

    xy = origin + p · ((u0 − ½ + (c + ½)/n) e_u + (v0 − ½ + (r + ½)/n) e_v)

i.e. the output pixels tile each lenslet's square cell (side ``p``, centred on the lenslet
centre) in ``n × n`` squares of side ``s = p / n`` input pixels, and lenslet ``(u0, v0)`` is
the output's top-left block. When ``p == n``, the rotation is 0 and the lenslet centres lie on
pixel centres (odd ``n``) or pixel corners (even ``n``), every sample falls exactly on an input
pixel centre and rectification is an exact crop.

Values are interpolated samples of the input (``scipy.ndimage.map_coordinates``), not
integrals: the sum over the output is the input's sum times ``(n / p)²``; multiply by
:attr:`RectifiedGeometry.flux_scale` to conserve the total flux.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from .errors import InputError
from .lenslet_grid import LensletGrid, as_image

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RectifiedGeometry:
    """Where a rectified image comes from.

    Parameters
    ----------
    grid : LensletGrid
        The calibrated grid of the raw image.
    px_per_lenslet : int
        Output pixels per lenslet ``n`` along each axis.
    first_lenslet_xy : tuple of int
        Index ``(u0, v0)`` of the lenslet in the output's top-left block.
    n_lenslets_xy : tuple of int
        Number of whole lenslets ``(nx, ny)`` in the output (along ``u`` and ``v``).
    """

    grid: LensletGrid
    px_per_lenslet: int
    first_lenslet_xy: tuple[int, int]
    n_lenslets_xy: tuple[int, int]

    def __post_init__(self) -> None:
        if not isinstance(self.grid, LensletGrid):
            raise InputError(f"grid must be a LensletGrid, got {type(self.grid).__name__}")
        _check_px_per_lenslet(self.px_per_lenslet)
        u0, v0 = (int(v) for v in self.first_lenslet_xy)
        nx, ny = (int(v) for v in self.n_lenslets_xy)
        if nx < 1 or ny < 1:
            raise InputError(f"n_lenslets_xy must be positive, got {self.n_lenslets_xy!r}")
        object.__setattr__(self, "first_lenslet_xy", (u0, v0))
        object.__setattr__(self, "n_lenslets_xy", (nx, ny))

    @property
    def shape(self) -> tuple[int, int]:
        """Shape ``(height, width)`` of the rectified image, ``(ny n, nx n)``."""
        n = self.px_per_lenslet
        return (self.n_lenslets_xy[1] * n, self.n_lenslets_xy[0] * n)

    @property
    def scale_px(self) -> float:
        """Side of one output pixel in input pixels, ``s = p / n``."""
        return self.grid.pitch_px / self.px_per_lenslet

    @property
    def flux_scale(self) -> float:
        """Factor ``(p / n)²`` that makes the output's sum equal the input's (flux)."""
        return self.scale_px**2

    def sample_points_xy(self) -> np.ndarray:
        """Input positions sampled by every output pixel.

        Returns
        -------
        ndarray, shape (height, width, 2)
            ``(x, y)`` in the input's continuous pixel coordinates.
        """
        h, w = self.shape
        cols = np.arange(w) + 0.5
        rows = np.arange(h) + 0.5
        return _sample_points(self.grid, self.px_per_lenslet, self.first_lenslet_xy, rows, cols)

    def lenslet_of_output_pixel(self, rows: Any, cols: Any) -> tuple[np.ndarray, np.ndarray]:
        """Lenslet index ``(u, v)`` of output pixels ``(row, col)`` (arrays broadcast)."""
        n = self.px_per_lenslet
        r = np.asarray(rows)
        c = np.asarray(cols)
        return c // n + self.first_lenslet_xy[0], r // n + self.first_lenslet_xy[1]

    def to_dict(self) -> dict:
        """Plain-JSON representation (the grid nested under ``"grid"``)."""
        return {
            "grid": self.grid.to_dict(),
            "px_per_lenslet": self.px_per_lenslet,
            "first_lenslet_xy": list(self.first_lenslet_xy),
            "n_lenslets_xy": list(self.n_lenslets_xy),
        }

    @classmethod
    def from_dict(cls, data: Any) -> RectifiedGeometry:
        """Inverse of :meth:`to_dict`; unknown or missing keys are an error naming them."""
        keys = ("grid", "px_per_lenslet", "first_lenslet_xy", "n_lenslets_xy")
        if not isinstance(data, dict):
            raise InputError(f"a rectified geometry must be a JSON object, got {data!r}")
        unknown = sorted(set(data) - set(keys))
        missing = [k for k in keys if k not in data]
        if unknown or missing:
            raise InputError(
                f"rectified geometry: unknown keys {unknown}, missing keys {missing}; "
                f"expected {list(keys)}"
            )
        return cls(
            grid=LensletGrid.from_dict(data["grid"]),
            px_per_lenslet=data["px_per_lenslet"],
            first_lenslet_xy=tuple(data["first_lenslet_xy"]),
            n_lenslets_xy=tuple(data["n_lenslets_xy"]),
        )


def _check_px_per_lenslet(n: Any) -> int:
    if (
        isinstance(n, bool | np.bool_)
        or not isinstance(n, int | np.integer)
        or int(n) < 1
        or int(n) > 1000
    ):
        raise InputError(f"px_per_lenslet must be an integer in [1, 1000], got {n!r}")
    return int(n)


def _sample_points(
    grid: LensletGrid,
    n: int,
    first: tuple[int, int],
    rows: np.ndarray,
    cols: np.ndarray,
) -> np.ndarray:
    """``(x, y)`` sampled by output pixel centres ``rows``/``cols`` (+0.5 already applied).

    Written so that for ``p == n`` and rotation 0 every term is exact in binary floating point
    (the sample points then land exactly on input pixel centres).
    """
    t = math.radians(grid.rotation_deg)
    eu = np.array([math.cos(t), math.sin(t)])
    ev = np.array([-math.sin(t), math.cos(t)])
    p = grid.pitch_px
    s = p / n
    corner = np.asarray(grid.origin_xy_px) + p * ((first[0] - 0.5) * eu + (first[1] - 0.5) * ev)
    cu = (np.asarray(cols, float) * s)[None, :, None] * eu
    rv = (np.asarray(rows, float) * s)[:, None, None] * ev
    return corner + cu + rv


def _largest_rectangle(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Largest all-True axis-aligned rectangle ``(row0, col0, nrows, ncols)`` of a 2-D mask."""
    nr, nc = mask.shape
    heights = np.zeros(nc, int)
    best = (0, 0, 0, 0)
    best_area = 0
    for r in range(nr):
        heights = np.where(mask[r], heights + 1, 0)
        stack: list[tuple[int, int]] = []  # (start column, height)
        for c in range(nc + 1):
            hc = int(heights[c]) if c < nc else 0
            start = c
            while stack and stack[-1][1] >= hc:
                s, hs = stack.pop()
                area = hs * (c - s)
                if area > best_area:
                    best_area = area
                    best = (r - hs + 1, s, hs, c - s)
                start = s
            stack.append((start, hc))
    return best


def whole_lenslets(grid: LensletGrid, px_per_lenslet: int) -> RectifiedGeometry:
    """The largest block of lenslets whose rectified samples all lie inside the image.

    A lenslet counts when all its ``n × n`` sample points lie within the hull of the input
    pixel centres, ``[0.5, W − 0.5] × [0.5, H − 0.5]``, so that interpolation never reaches
    outside the image.

    Raises
    ------
    InputError
        Not one lenslet fits.
    """
    n = _check_px_per_lenslet(px_per_lenslet)
    h, w = grid.image_shape
    idx, _ = grid.all_centers()
    if len(idx) == 0:
        raise InputError(f"no lenslet centre of the grid lies inside the {h} x {w} image")
    lo = idx.min(axis=0)
    hi = idx.max(axis=0)
    vv, uu = np.mgrid[lo[1] : hi[1] + 1, lo[0] : hi[0] + 1]
    # The four extreme sample points of every lenslet, offsets ±(p/2 − s/2) along e_u, e_v.
    half = 0.5 * grid.pitch_px * (1.0 - 1.0 / n)
    b = grid.basis_px / grid.pitch_px
    ok = np.ones(uu.shape, bool)
    centres = grid.centers(np.c_[uu.ravel(), vv.ravel()]).reshape(*uu.shape, 2)
    tol = 1e-9
    for su in (-1.0, 1.0):
        for sv in (-1.0, 1.0):
            pt = centres + half * (su * b[0] + sv * b[1])
            ok &= (pt[..., 0] >= 0.5 - tol) & (pt[..., 0] <= w - 0.5 + tol)
            ok &= (pt[..., 1] >= 0.5 - tol) & (pt[..., 1] <= h - 0.5 + tol)
    r0, c0, nr, nc = _largest_rectangle(ok)
    if nr == 0:
        raise InputError(
            f"no whole lenslet (pitch {grid.pitch_px:.4g} px) lies inside the {h} x {w} image"
        )
    return RectifiedGeometry(
        grid=grid,
        px_per_lenslet=n,
        first_lenslet_xy=(int(lo[0] + c0), int(lo[1] + r0)),
        n_lenslets_xy=(int(nc), int(nr)),
    )


def rectify(
    image: Any, grid: LensletGrid, px_per_lenslet: int, *, order: int = 1
) -> tuple[np.ndarray, RectifiedGeometry]:
    """Resample a raw light-field image onto ``px_per_lenslet`` pixels per lenslet.

    Parameters
    ----------
    image : array_like, shape (height, width)
        Raw light-field image (any numeric dtype, finite) of the shape ``grid.image_shape``.
    grid : LensletGrid
        Its calibrated lenslet grid (:func:`recon.calibration.calibrate_white`).
    px_per_lenslet : int
        Output pixels per lenslet ``n`` along each axis (e.g. the nearest integer to the
        pitch, to keep the sampling close to the sensor's).
    order : int
        Spline order of the interpolation, 0 … 5 (1: bilinear). Out-of-image samples, which
        the chosen lenslet block avoids, would read 0.

    Returns
    -------
    rectified : ndarray of float64, shape (ny n, nx n)
        Lenslet ``(u0 + U, v0 + V)`` in block ``[V n, (V + 1) n) × [U n, (U + 1) n)``.
    geometry : RectifiedGeometry
        ``first_lenslet_xy = (u0, v0)``, ``n_lenslets_xy = (nx, ny)`` (the largest block of whole
        lenslets inside the image), ``px_per_lenslet``, and the grid.

    Raises
    ------
    InputError
        Bad image (not finite 2-D, or not of ``grid.image_shape``), ``px_per_lenslet`` or
        ``order``; no whole lenslet inside the image.
    """
    if not isinstance(grid, LensletGrid):
        raise InputError(f"grid must be a LensletGrid, got {type(grid).__name__}")
    img = as_image(image, "image")
    if img.shape != grid.image_shape:
        raise InputError(
            f"image has shape {img.shape} but the lenslet grid was calibrated on images of "
            f"shape {grid.image_shape}"
        )
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or not 0 <= order <= 5:
        raise InputError(f"order must be an integer in [0, 5], got {order!r}")
    geom = whole_lenslets(grid, px_per_lenslet)
    xy = geom.sample_points_xy()
    coords = np.stack([xy[..., 1] - 0.5, xy[..., 0] - 0.5])  # (row, col) array coordinates
    out = ndimage.map_coordinates(img, coords, order=int(order), mode="constant", cval=0.0)
    log.debug(
        "rectified %s image to %s: %d x %d lenslets from (%d, %d), %d px per lenslet",
        img.shape,
        out.shape,
        *geom.n_lenslets_xy,
        *geom.first_lenslet_xy,
        geom.px_per_lenslet,
    )
    return out, geom
