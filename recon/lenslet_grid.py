"""The lenslet grid on the sensor: :class:`LensletGrid`, its JSON files, and input images.

Pixel coordinates (shared with :mod:`lfsim`, whose ``Optics.axis_xy_px`` uses them): the image is
an array ``(y, x)`` = ``(row, column)``; pixel ``(row i, column j)`` covers the square
``[j, j + 1) × [i, i + 1)`` of the continuous plane, so its centre is ``(x, y) = (j + 0.5,
i + 0.5)``. All positions and lengths here are in pixels of that plane.

Grid model (a similarity transform of the integer lattice; 4 parameters)::

    x = x0 + p (cos θ · u − sin θ · v)
    y = y0 + p (sin θ · u + cos θ · v)

for lenslet ``(u, v)`` (``u`` counts along the grid's first axis, close to +x; ``v`` along the
second, close to +y), pitch ``p`` (pixels, not necessarily an integer), rotation ``θ`` (from the
image x axis towards +y, in ``[−45°, 45°]``) and origin ``(x0, y0)``, the centre of lenslet
``(0, 0)``. :func:`recon.calibration.calibrate_white` fits it to a white image and puts the
origin at the lenslet nearest the image centre.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.io import write_json
from hrvbase.validate import finite_float, fixed_length, int_in_range, nonnegative_float

from .errors import InputError, recon_input_errors

_GRID_KEYS = (
    "pitch_px",
    "rotation_deg",
    "origin_xy_px",
    "image_shape",
    "rms_residual_px",
    "n_lenslets_used",
)

#: Keys of the grids of the older layout (calibration files, recon.json) → their names.
_OLDER_GRID_KEYS = {"origin_px": "origin_xy_px"}


def pair(value: Any, name: str, kind: type) -> tuple:
    """``value`` as two finite floats (``kind=float``) or two integers >= 1 (``kind=int``).

    Raises
    ------
    InputError
        Not a pair, or an element not of that kind (the message names ``name``).
    """
    with recon_input_errors():
        items = fixed_length(value, name, 2, "a pair of numbers")
        if kind is int:
            return tuple(int_in_range(v, name, 1) for v in items)
        return tuple(finite_float(v, name) for v in items)


def as_image(image: Any, name: str = "image") -> np.ndarray:
    """Validate a 2-D numeric image and return it as a float64 array ``(y, x)``.

    Raises
    ------
    InputError
        Not numeric, not 2-D, empty, or holding NaN/inf pixels (the message names ``name``).
    """
    arr = np.asarray(image)
    if arr.dtype.kind not in "uif":
        raise InputError(f"{name} must hold integer or real pixels, got dtype {arr.dtype}")
    if arr.ndim != 2:
        raise InputError(
            f"{name} must be one 2-D (y, x) image, got an array of shape {arr.shape}"
            + (" (a stack of images?)" if arr.ndim == 3 else "")
        )
    if arr.size == 0:
        raise InputError(f"{name} is empty (shape {arr.shape})")
    out = arr.astype(np.float64)
    bad = ~np.isfinite(out)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise InputError(
            f"{name} has {int(bad.sum())} non-finite pixel(s) (NaN or inf), the first at "
            f"row {i}, column {j}"
        )
    return out


@dataclass(frozen=True)
class LensletGrid:
    """A square lenslet grid on the sensor, in continuous pixel coordinates.

    Lenslet ``(u, v)`` has its centre at ``origin + p (u e_u + v e_v)`` with
    ``e_u = (cos θ, sin θ)`` and ``e_v = (−sin θ, cos θ)`` (see the module docstring for the
    pixel convention: pixel ``(i, j)`` has its centre at ``(x, y) = (j + 0.5, i + 0.5)``).

    Parameters
    ----------
    pitch_px : float
        Lenslet pitch ``p`` in pixels (need not be an integer), ≥ 2.
    rotation_deg : float
        Angle ``θ`` of the grid's first axis from the image x axis towards +y (degrees),
        in ``[−45, 45]``.
    origin_xy_px : tuple of float
        ``(x, y)`` of the centre of lenslet ``(0, 0)``;
        :func:`~recon.calibration.calibrate_white` picks the lenslet nearest the image centre.
    image_shape : tuple of int
        ``(height, width)`` of the image the grid belongs to (pixels).
    rms_residual_px : float
        Fit diagnostic: RMS distance (pixels) between the measured lenslet centres used in the
        fit and the grid (0 for a grid not obtained from a fit).
    n_lenslets_used : int
        Fit diagnostic: number of lenslets that entered the final fit.
    """

    pitch_px: float
    rotation_deg: float
    origin_xy_px: tuple[float, float]
    image_shape: tuple[int, int]
    rms_residual_px: float = 0.0
    n_lenslets_used: int = 0

    def __post_init__(self) -> None:
        with recon_input_errors():
            pitch = finite_float(self.pitch_px, "pitch_px")
            rot = finite_float(self.rotation_deg, "rotation_deg")
            rms = nonnegative_float(self.rms_residual_px, "rms_residual_px")
            n = int_in_range(self.n_lenslets_used, "n_lenslets_used", 0)
        if pitch < 2.0:
            raise InputError(f"pitch_px must be at least 2 pixels, got {self.pitch_px!r}")
        if not -45.0 <= rot <= 45.0:
            raise InputError(
                f"rotation_deg must lie in [-45, 45] (a square grid rotated by 90° is the same "
                f"grid), got {self.rotation_deg!r}"
            )
        object.__setattr__(self, "pitch_px", pitch)
        object.__setattr__(self, "rotation_deg", rot)
        object.__setattr__(self, "origin_xy_px", pair(self.origin_xy_px, "origin_xy_px", float))
        object.__setattr__(self, "image_shape", pair(self.image_shape, "image_shape", int))
        object.__setattr__(self, "rms_residual_px", rms)
        object.__setattr__(self, "n_lenslets_used", n)

    # -- geometry ------------------------------------------------------------------------
    @property
    def basis_px(self) -> np.ndarray:
        """Grid steps as a ``(2, 2)`` array: row 0 is ``p e_u``, row 1 is ``p e_v`` (x, y)."""
        t = math.radians(self.rotation_deg)
        c, s = math.cos(t), math.sin(t)
        return self.pitch_px * np.array([[c, s], [-s, c]])

    def center(self, u: float, v: float) -> tuple[float, float]:
        """Centre ``(x, y)`` (pixels) of lenslet ``(u, v)`` (fractional indices allowed)."""
        xy = self.centers(np.array([[u, v]], dtype=float))[0]
        return (float(xy[0]), float(xy[1]))

    def centers(self, indices: Any) -> np.ndarray:
        """Centres of many lenslets.

        Parameters
        ----------
        indices : array_like, shape (K, 2)
            Lenslet indices ``(u, v)`` (fractional values allowed).

        Returns
        -------
        ndarray, shape (K, 2)
            ``(x, y)`` in pixels.
        """
        uv = np.asarray(indices, dtype=float)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InputError(f"indices must have shape (K, 2), got {uv.shape}")
        return np.asarray(self.origin_xy_px) + uv @ self.basis_px

    def lenslet_index(self, xy: Any) -> np.ndarray:
        """Fractional lenslet indices ``(u, v)`` of points ``(x, y)``.

        Parameters
        ----------
        xy : array_like, shape (..., 2)
            Points in pixels.

        Returns
        -------
        ndarray, shape (..., 2)
            ``(u, v)``; round to the nearest integers for the lenslet a point belongs to.
        """
        pts = np.asarray(xy, dtype=float)
        if pts.shape[-1:] != (2,):
            raise InputError(f"xy must have shape (..., 2), got {pts.shape}")
        b = self.basis_px
        return (pts - np.asarray(self.origin_xy_px)) @ b.T / self.pitch_px**2

    def all_centers(self) -> tuple[np.ndarray, np.ndarray]:
        """Every lenslet whose centre lies inside the image ``[0, W) × [0, H)``.

        Returns
        -------
        indices : ndarray of int64, shape (K, 2)
            ``(u, v)``, ordered by ``v`` then ``u``.
        xy : ndarray, shape (K, 2)
            Centres ``(x, y)`` in pixels.
        """
        h, w = self.image_shape
        corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])
        uv = self.lenslet_index(corners)
        lo = np.floor(uv.min(axis=0)).astype(int) - 1
        hi = np.ceil(uv.max(axis=0)).astype(int) + 1
        vv, uu = np.mgrid[lo[1] : hi[1] + 1, lo[0] : hi[0] + 1]
        idx = np.c_[uu.ravel(), vv.ravel()].astype(np.int64)
        xy = self.centers(idx)
        inside = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
        return idx[inside], xy[inside]

    # -- files ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain-JSON representation (lengths in pixels, angle in degrees)."""
        return {
            "pitch_px": self.pitch_px,
            "rotation_deg": self.rotation_deg,
            "origin_xy_px": list(self.origin_xy_px),
            "image_shape": list(self.image_shape),
            "rms_residual_px": self.rms_residual_px,
            "n_lenslets_used": self.n_lenslets_used,
        }

    @classmethod
    def from_dict(cls, data: Any) -> LensletGrid:
        """Inverse of :meth:`to_dict`; unknown or missing keys are an error naming them. A
        grid of the older layout, whose origin is ``origin_px``, is read too."""
        if not isinstance(data, dict):
            raise InputError(f"a lenslet grid must be a JSON object, got {type(data).__name__}")
        for older, name in _OLDER_GRID_KEYS.items():
            if older in data and name in data:
                raise InputError(f"a lenslet grid has both {older!r} and {name!r}; keep {name!r}")
        data = {_OLDER_GRID_KEYS.get(k, k): v for k, v in data.items()}
        unknown = sorted(set(data) - set(_GRID_KEYS))
        if unknown:
            raise InputError(f"unknown lenslet-grid keys {unknown}; expected {list(_GRID_KEYS)}")
        missing = [k for k in _GRID_KEYS[:4] if k not in data]
        if missing:
            raise InputError(f"lenslet grid lacks the keys {missing}")
        return cls(**data)

    def save(self, path: str | os.PathLike, *, overwrite: bool = True) -> Path:
        """Write the grid as JSON to ``path``, atomically.

        Raises
        ------
        hrvbase.errors.OutputError
            ``path`` exists and ``overwrite`` is false, or it cannot be written.
        """
        return write_json(path, self.to_dict(), overwrite=overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike) -> LensletGrid:
        """Read a grid written by :meth:`save`, or the ``"grid"`` of a ``recon calibrate``
        calibration file.

        Raises
        ------
        InputError
            Missing or unreadable file, invalid JSON, or an invalid grid (names the file).
        """
        import json

        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputError(f"lenslet-grid file {path} does not exist") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"cannot read lenslet-grid file {path}: {exc}") from exc
        if isinstance(data, dict) and isinstance(data.get("grid"), dict):
            data = data["grid"]
        try:
            return cls.from_dict(data)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None


def grid_from_similarity(p, theta_rad, origin, shape, **diag) -> LensletGrid:
    """The grid of pitch ``p`` (px), angle ``theta_rad`` (any, folded into ±45°), origin
    ``(x, y)`` and image ``shape``; ``diag``: the fit diagnostics."""
    deg = math.degrees(theta_rad)
    deg = (deg + 45.0) % 90.0 - 45.0
    return LensletGrid(
        pitch_px=float(p),
        rotation_deg=deg,
        origin_xy_px=(float(origin[0]), float(origin[1])),
        image_shape=shape,
        **diag,
    )


def recenter(grid: LensletGrid) -> tuple[LensletGrid, np.ndarray]:
    """Move the origin to the lenslet nearest the image centre; return the index shift."""
    h, w = grid.image_shape
    shift = np.rint(grid.lenslet_index(np.array([w / 2.0, h / 2.0]))).astype(int)
    new = LensletGrid(
        pitch_px=grid.pitch_px,
        rotation_deg=grid.rotation_deg,
        origin_xy_px=grid.center(*shift),
        image_shape=grid.image_shape,
        rms_residual_px=grid.rms_residual_px,
        n_lenslets_used=grid.n_lenslets_used,
    )
    return new, shift
