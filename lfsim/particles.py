"""Particle tables: positions, diameters, brightnesses and ids of fluorescent beads.

:class:`Particles` is the immutable point table passed between seeding
(:mod:`lfsim.seeding`), motions (:mod:`lfsim.motion`), the renderer and the ground-truth files
of a dataset. Lengths are micrometres in the object-space frame of docs/conventions.md (x
along sensor columns, y along sensor rows, z along the optical axis, away from the objective).

CSV format (one particle per line, header first, columns in any order)::

    id,x_um,y_um,z_um,diameter_um,brightness
    0,-12.5,40.25,160,15,1

``x_um, y_um, z_um`` are required; ``id`` (integer), ``diameter_um`` (µm, > 0) and
``brightness`` (relative, >= 0) are optional and default to ``0..N-1``, the reader's
``default_diameter_um`` and ``default_brightness``. Blank lines and lines starting with ``#``
are skipped. :meth:`Particles.to_csv` writes every column with 17 significant digits, so a
table read back is bit-identical.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import ConfigError

log = logging.getLogger(__name__)

CSV_COLUMNS = ("id", "x_um", "y_um", "z_um", "diameter_um", "brightness")
REQUIRED_COLUMNS = ("x_um", "y_um", "z_um")
DEFAULT_DIAMETER_UM = 15.0


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


def _per_particle(name: str, value, n: int) -> np.ndarray:
    """``value`` as a float64 ``(n,)`` array (a scalar is broadcast)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be numeric, got {value!r}") from exc
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise ConfigError(f"{name} must be a scalar or have shape ({n},), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{name} must be finite; got non-finite values")
    return a


def _as_ids(value, n: int) -> np.ndarray:
    if value is None:
        return np.arange(n, dtype=np.int64)
    a = np.asarray(value)
    if a.shape != (n,):
        raise ConfigError(f"ids must have shape ({n},), got shape {a.shape}")
    if a.dtype.kind in "iu":
        if a.dtype.kind == "u" and n and a.max() > np.iinfo(np.int64).max:
            raise ConfigError("ids must fit in int64")
        ids = a.astype(np.int64)
    elif a.dtype.kind == "f":
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise ConfigError("ids must be integers")
        if n and np.max(np.abs(a)) >= 2.0**63:
            raise ConfigError("ids must fit in int64")
        ids = a.astype(np.int64)
    else:
        raise ConfigError(f"ids must be integers, got dtype {a.dtype}")
    if np.unique(ids).size != n:
        raise ConfigError("ids must be unique")
    return ids


@dataclass(frozen=True, eq=False, repr=False)
class Particles:
    """An immutable table of N spherical fluorescent particles.

    Every array is copied on construction and stored read-only.

    Parameters
    ----------
    positions_um : array_like, shape (N, 3)
        Particle centres ``x, y, z`` in µm (float64, finite).
    diameter_um : float or array_like, shape (N,)
        Particle diameters in µm (> 0). A scalar applies to all. Default 15 µm (paper, Table 1).
    brightness : float or array_like, shape (N,)
        Relative emitted power (>= 0, 1 = nominal). A scalar applies to all. Default 1.
    ids : array_like of int, shape (N,), optional
        Unique particle identifiers (int64), kept through motions and subsets so that tracked
        particles can be matched with the ground truth. Default ``0 .. N-1``.

    Raises
    ------
    ConfigError
        On a wrong shape, a non-finite value, a non-positive diameter, a negative brightness
        or non-unique / non-integer ids.
    """

    positions_um: np.ndarray
    diameter_um: np.ndarray = field(default=DEFAULT_DIAMETER_UM)  # type: ignore[assignment]
    brightness: np.ndarray = field(default=1.0)  # type: ignore[assignment]
    ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        try:
            pos = np.asarray(self.positions_um, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"positions_um must be a numeric (N, 3) array: {exc}") from exc
        if pos.shape in ((0,), (0, 0)):
            pos = pos.reshape(0, 3)
        if pos.ndim != 2 or pos.shape[1] != 3:
            raise ConfigError(f"positions_um must have shape (N, 3), got shape {pos.shape}")
        if not np.all(np.isfinite(pos)):
            bad = int(np.argwhere(~np.isfinite(pos))[0, 0])
            raise ConfigError(f"positions_um must be finite; row {bad} is {pos[bad].tolist()}")
        n = pos.shape[0]
        diam = _per_particle("diameter_um", self.diameter_um, n)
        if np.any(diam <= 0):
            bad = int(np.argmax(diam <= 0))
            raise ConfigError(f"diameter_um must be > 0; particle {bad} has {diam[bad]!r}")
        bright = _per_particle("brightness", self.brightness, n)
        if np.any(bright < 0):
            bad = int(np.argmax(bright < 0))
            raise ConfigError(f"brightness must be >= 0; particle {bad} has {bright[bad]!r}")
        ids = _as_ids(self.ids, n)
        object.__setattr__(self, "positions_um", _readonly(pos))
        object.__setattr__(self, "diameter_um", _readonly(diam))
        object.__setattr__(self, "brightness", _readonly(bright))
        object.__setattr__(self, "ids", _readonly(ids))

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        positions_um,
        diameter_um=DEFAULT_DIAMETER_UM,
        brightness=1.0,
        ids=None,
    ) -> Particles:
        """Build a table from arrays (scalars broadcast); same as the constructor.

        Parameters
        ----------
        positions_um : array_like, shape (N, 3)
            Centres in µm.
        diameter_um : float or array_like, shape (N,)
            Diameters in µm (default 15).
        brightness : float or array_like, shape (N,)
            Relative brightness (default 1).
        ids : array_like of int, shape (N,), optional
            Unique ids (default ``0 .. N-1``).

        Returns
        -------
        Particles
        """
        return cls(positions_um, diameter_um, brightness, ids)

    # -- basic protocol ---------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.positions_um.shape[0])

    def __repr__(self) -> str:
        n = len(self)
        if n == 0:
            return "Particles(n=0)"
        lo = self.positions_um.min(axis=0)
        hi = self.positions_um.max(axis=0)
        box = ", ".join(f"[{a:.4g}, {b:.4g}]" for a, b in zip(lo, hi, strict=True))
        return (
            f"Particles(n={n}, bounds_um=({box}), diameter_um=[{self.diameter_um.min():.4g}, "
            f"{self.diameter_um.max():.4g}])"
        )

    def equals(self, other: Particles) -> bool:
        """``True`` when both tables hold exactly the same values (bitwise array equality)."""
        return (
            isinstance(other, Particles)
            and np.array_equal(self.positions_um, other.positions_um)
            and np.array_equal(self.diameter_um, other.diameter_um)
            and np.array_equal(self.brightness, other.brightness)
            and np.array_equal(self.ids, other.ids)
        )

    def overlaps(self, coincident_um: float = 1e-3) -> tuple[list[list[int]], list[tuple]]:
        """Particles at the same place, and pairs that overlap.

        Parameters
        ----------
        coincident_um : float
            Centres closer than this (µm) are the same place.

        Returns
        -------
        coincident : list of list of int
            Groups of row indices (0-based, ascending) of particles at the same place: almost
            surely a table mistake (a row given twice).
        overlapping : list of (int, int, float)
            Other pairs of rows ``(i, j, distance_um)``, ``i < j``, whose centres are closer
            than the mean of their diameters (the spheres intersect).
        """
        from scipy.spatial import cKDTree

        n = len(self)
        if n < 2:
            return [], []
        pos, diam = self.positions_um, self.diameter_um
        pairs = cKDTree(pos).query_pairs(float(diam.max()), output_type="ndarray")
        parent = list(range(n))

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        overlapping = []
        for i, j in sorted(map(tuple, pairs.tolist())):
            dist = float(np.linalg.norm(pos[i] - pos[j]))
            if dist < coincident_um:
                parent[root(j)] = root(i)
            elif dist < (diam[i] + diam[j]) / 2.0:
                overlapping.append((i, j, dist))
        groups: dict[int, list[int]] = {}
        for i in range(n):
            groups.setdefault(root(i), []).append(i)
        coincident = sorted(g for g in groups.values() if len(g) > 1)
        return coincident, overlapping

    def with_positions(self, new_positions_um) -> Particles:
        """The same particles (ids, diameters, brightnesses) at new positions.

        Parameters
        ----------
        new_positions_um : array_like, shape (N, 3)
            New centres in µm, in the same particle order.

        Returns
        -------
        Particles
        """
        new = np.asarray(new_positions_um, dtype=np.float64)
        if new.shape != self.positions_um.shape:
            raise ConfigError(
                f"new positions must have shape {self.positions_um.shape}, got {new.shape}"
            )
        return Particles(new, self.diameter_um, self.brightness, self.ids)

    def subset(self, mask) -> Particles:
        """The particles selected by a boolean mask or an integer index array.

        Parameters
        ----------
        mask : array_like of bool, shape (N,), or array_like of int
            Selection; ids are kept.

        Returns
        -------
        Particles
        """
        sel = np.asarray(mask)
        n = len(self)
        if sel.dtype == bool:
            if sel.shape != (n,):
                raise ConfigError(f"a boolean mask must have shape ({n},), got {sel.shape}")
        elif sel.dtype.kind in "iu" or sel.size == 0:
            sel = sel.astype(np.int64).ravel()
            if sel.size and (sel.min() < -n or sel.max() >= n):
                raise ConfigError(f"subset indices must lie in [-{n}, {n}), got {sel.tolist()}")
        else:
            raise ConfigError(f"subset needs a boolean mask or integer indices, got {sel.dtype}")
        return Particles(
            self.positions_um[sel], self.diameter_um[sel], self.brightness[sel], self.ids[sel]
        )

    # -- CSV ----------------------------------------------------------------------------------
    def to_csv(self, path: str | os.PathLike) -> Path:
        """Write the table as CSV, atomically (temporary file in the same folder + rename).

        Columns ``id,x_um,y_um,z_um,diameter_um,brightness``; floats with ``%.17g`` so that
        :meth:`from_csv` reads back exactly the same float64 values. Missing parent folders
        are created.

        Parameters
        ----------
        path : str or os.PathLike
            Destination file; an existing file is replaced.

        Returns
        -------
        pathlib.Path
            ``path``.

        Raises
        ------
        OutputError
            When the file cannot be written.
        """
        from hrvbase.tables import write_table

        path = write_table(
            path,
            {
                "id": self.ids,
                "x_um": self.positions_um[:, 0],
                "y_um": self.positions_um[:, 1],
                "z_um": self.positions_um[:, 2],
                "diameter_um": self.diameter_um,
                "brightness": self.brightness,
            },
            overwrite=True,
        )
        log.debug("wrote %d particles to %s", len(self), path)
        return path

    @classmethod
    def from_csv(
        cls,
        path: str | os.PathLike,
        default_diameter_um: float = DEFAULT_DIAMETER_UM,
        default_brightness: float = 1.0,
    ) -> Particles:
        """Read a particle table written by :meth:`to_csv` or by hand.

        Parameters
        ----------
        path : str or os.PathLike
            CSV file with a header naming ``x_um, y_um, z_um`` and optionally ``id``,
            ``diameter_um``, ``brightness``, in any order.
        default_diameter_um : float
            Diameter (µm) used when the file has no ``diameter_um`` column.
        default_brightness : float
            Relative brightness used when the file has no ``brightness`` column.

        Returns
        -------
        Particles

        Raises
        ------
        ConfigError
            Naming the file (and line / column) for a missing file, a missing, unknown or
            duplicated column, a row of the wrong length, a non-numeric or non-finite value,
            or values :class:`Particles` rejects.
        """
        from hrvbase.errors import InputError
        from hrvbase.tables import read_table

        path = Path(path)
        try:
            columns = read_table(
                path,
                required=REQUIRED_COLUMNS,
                optional=[c for c in CSV_COLUMNS if c not in REQUIRED_COLUMNS],
                integer=("id",),
                unknown="refuse",
                what="particle table",
            )
        except InputError as exc:
            raise ConfigError(str(exc)) from None
        n = len(columns["x_um"])
        pos = np.array(
            [columns["x_um"], columns["y_um"], columns["z_um"]], dtype=np.float64
        ).T.reshape(n, 3)
        diam = (
            np.array(columns["diameter_um"], dtype=np.float64)
            if "diameter_um" in columns
            else default_diameter_um
        )
        bright = (
            np.array(columns["brightness"], dtype=np.float64)
            if "brightness" in columns
            else default_brightness
        )
        ids = np.array(columns["id"], dtype=np.int64) if "id" in columns else None
        try:
            out = cls(pos, diam, bright, ids)
        except ConfigError as exc:
            raise ConfigError(f"particle table {path}: {exc}") from exc
        log.debug("read %d particles from %s", n, path)
        return out
