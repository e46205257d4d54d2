"""Random particle seeding with a minimum centre-to-centre spacing.

Positions are micrometres in the object-space frame of docs/conventions.md. Every function takes a
:class:`numpy.random.Generator`; the same generator state gives the same positions.

Algorithm: batched dart throwing. Candidates are drawn uniformly in the box in batches; a
candidate closer than ``min_spacing_um`` to an already placed particle is rejected (k-d tree
query), and within a batch the later candidate of every too-close pair is dropped. Accepted
candidates are appended in draw order until ``n`` are placed. Every placed pair is therefore at
least ``min_spacing_um`` apart, and the cost grows like ``n log n`` (10 000 particles take a
few tens of milliseconds at the paper's seeding densities).

Centres lie in the box (``lo <= x < hi`` per axis); particles may stick out of it by up to
one radius.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from hrvbase.validate import renamed_key_message

from .errors import ConfigError
from .particles import DEFAULT_DIAMETER_UM, Particles

log = logging.getLogger(__name__)

SEEDING_KINDS = ("box", "layer", "csv")

# Densest packing fractions of equal balls (3D), discs (2D).
_PACKING = {3: math.pi / (3.0 * math.sqrt(2.0)), 2: math.pi / (2.0 * math.sqrt(3.0))}


def _box(name: str, bounds_um, ndim: int) -> np.ndarray:
    """Validate ``ndim`` ``(lo, hi)`` ranges; returns a float64 array of shape (ndim, 2)."""
    try:
        b = np.asarray(bounds_um, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(
            f"{name} must be {ndim} (lo, hi) ranges in µm, got {bounds_um!r}"
        ) from exc
    if b.shape != (ndim, 2):
        raise ConfigError(
            f"{name} must be {ndim} (lo, hi) ranges in µm (shape ({ndim}, 2)), got {bounds_um!r}"
        )
    if not np.all(np.isfinite(b)):
        raise ConfigError(f"{name} must be finite, got {bounds_um!r}")
    if np.any(b[:, 1] < b[:, 0]):
        raise ConfigError(f"{name} ranges must satisfy lo <= hi, got {bounds_um!r}")
    return b


def _count(n) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ConfigError(f"the particle count must be a non-negative integer, got {n!r}")
    return int(n)


def _spacing(s) -> float:
    if isinstance(s, bool) or not isinstance(s, int | float | np.number):
        raise ConfigError(f"min_spacing_um must be a number >= 0, got {s!r}")
    if not math.isfinite(s) or s < 0:
        raise ConfigError(f"min_spacing_um must be a finite number >= 0, got {s!r}")
    return float(s)


def _max_packed(lo: np.ndarray, hi: np.ndarray, s: float) -> float:
    """Upper bound on how many centres fit in the box with spacing ``s`` (densest packing)."""
    ext = hi - lo
    ext = ext[ext > 0]
    d = ext.size
    if s == 0:
        return math.inf
    if d == 0:
        return 1.0
    if d == 1:
        return math.floor(ext[0] / s) + 1.0
    # Balls of radius s/2 around the centres lie in the box grown by s/2 on each side.
    grown = float(np.prod(ext + s))
    ball = math.pi * s**2 / 4.0 if d == 2 else math.pi * s**3 / 6.0
    return _PACKING[d] * grown / ball


def _dart_throw(
    n: int, lo: np.ndarray, hi: np.ndarray, s: float, rng: np.random.Generator, max_tries: int
) -> np.ndarray:
    """``n`` points uniform in ``[lo, hi)`` (shape (3,)) at least ``s`` apart, shape (n, 3)."""
    what = f"{n} particles with min_spacing_um={s:g} in the box {np.c_[lo, hi].tolist()} µm"
    bound = _max_packed(lo, hi, s)
    if n > bound:
        raise ConfigError(
            f"cannot place {what}: placed 0; even the densest packing holds at most "
            f"{math.floor(bound)}"
        )
    if s == 0 or n <= 1:
        return rng.uniform(lo, hi, size=(n, 3))

    placed = np.empty((0, 3))
    tree = None
    tries = 0
    acceptance = 1.0
    while placed.shape[0] < n and tries < max_tries:
        need = n - placed.shape[0]
        batch = int(min(max(1.25 * need / max(acceptance, 1e-3), 256), 2_000_000))
        batch = min(batch, max_tries - tries)
        cand = rng.uniform(lo, hi, size=(batch, 3))
        tries += batch
        if tree is not None:
            dist, _ = tree.query(cand, k=1, distance_upper_bound=s)
            cand = cand[dist >= s]
        if cand.shape[0] > 1:
            pairs = cKDTree(cand).query_pairs(s, output_type="ndarray")
            if pairs.size:
                # The later candidate of every too-close pair goes (query_pairs gives i < j).
                keep = np.ones(cand.shape[0], dtype=bool)
                keep[pairs.max(axis=1)] = False
                cand = cand[keep]
        acceptance = max(cand.shape[0] / batch, 0.0)
        if cand.shape[0]:
            placed = np.concatenate([placed, cand[:need]])
            tree = cKDTree(placed)
    if placed.shape[0] < n:
        raise ConfigError(
            f"cannot place {what}: placed only {placed.shape[0]} after {tries} random candidates "
            f"(max_tries); lower the count or min_spacing_um, or enlarge the box"
        )
    log.debug("placed %d particles (spacing %g µm) from %d candidates", n, s, tries)
    return placed


def _default_max_tries(n: int) -> int:
    return max(100_000, 50 * n)


def seed_box(
    n: int,
    bounds_xyz_um: Sequence[Sequence[float]],
    min_spacing_um: float,
    rng: np.random.Generator,
    max_tries: int | None = None,
) -> np.ndarray:
    """Uniform random centres in a box, at least ``min_spacing_um`` apart.

    Parameters
    ----------
    n : int
        Number of particles (>= 0).
    bounds_xyz_um : sequence of three (lo, hi) pairs
        ``((x0, x1), (y0, y1), (z0, z1))`` in µm; centres satisfy ``lo <= c < hi``. A range with
        ``lo == hi`` pins that coordinate.
    min_spacing_um : float
        Minimum centre-to-centre distance in µm (>= 0; use the diameter for non-overlapping
        beads).
    rng : numpy.random.Generator
        Source of randomness.
    max_tries : int, optional
        Maximum number of random candidates drawn; default ``max(100 000, 50 n)``.

    Returns
    -------
    numpy.ndarray, shape (n, 3), float64
        Centres in µm, in random order.

    Raises
    ------
    ConfigError
        On invalid arguments, or when ``n`` centres cannot be placed (the message says how
        many were).
    """
    n = _count(n)
    b = _box("bounds_xyz_um", bounds_xyz_um, 3)
    s = _spacing(min_spacing_um)
    if not isinstance(rng, np.random.Generator):
        raise ConfigError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    tries = _default_max_tries(n) if max_tries is None else int(max_tries)
    if tries < 1:
        raise ConfigError(f"max_tries must be >= 1, got {max_tries!r}")
    return _dart_throw(n, b[:, 0], b[:, 1], s, rng, tries)


def seed_layer(
    n: int,
    bounds_xy_um: Sequence[Sequence[float]],
    z_um: float,
    min_spacing_um: float,
    rng: np.random.Generator,
    max_tries: int | None = None,
) -> np.ndarray:
    """Uniform random centres in a single layer ``z = z_um``, at least ``min_spacing_um`` apart.

    :func:`seed_box` in the box ``bounds_xy_um`` × ``[z_um, z_um]``.

    Parameters
    ----------
    n, min_spacing_um, rng, max_tries
        As :func:`seed_box`.
    bounds_xy_um : sequence of two (lo, hi) pairs
        ``((x0, x1), (y0, y1))`` in µm.
    z_um : float
        Depth of the layer in µm.

    Returns
    -------
    numpy.ndarray, shape (n, 3), float64
        Centres in µm; column 2 equals ``z_um``.

    Raises
    ------
    ConfigError
        On invalid arguments or when ``n`` centres cannot be placed.
    """
    bxy = _box("bounds_xy_um", bounds_xy_um, 2)
    try:
        z = float(z_um)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"z_um must be a number, got {z_um!r}") from exc
    if not math.isfinite(z):
        raise ConfigError(f"z_um must be finite, got {z_um!r}")
    return seed_box(n, [*bxy.tolist(), [z, z]], min_spacing_um, rng, max_tries)


def count_from_density(density_per_mm3: float, bounds_xyz_um: Sequence[Sequence[float]]) -> int:
    """Particle count for a number density in a box.

    Parameters
    ----------
    density_per_mm3 : float
        Particles per cubic millimetre (>= 0).
    bounds_xyz_um : sequence of three (lo, hi) pairs
        Box in µm.

    Returns
    -------
    int
        ``round(density · volume)`` with the volume in mm³ (1 mm³ = 10⁹ µm³).
    """
    if isinstance(density_per_mm3, bool) or not isinstance(density_per_mm3, int | float):
        raise ConfigError(f"density_per_mm3 must be a number, got {density_per_mm3!r}")
    if not math.isfinite(density_per_mm3) or density_per_mm3 < 0:
        raise ConfigError(f"density_per_mm3 must be finite and >= 0, got {density_per_mm3!r}")
    b = _box("bounds_xyz_um", bounds_xyz_um, 3)
    volume_mm3 = float(np.prod(b[:, 1] - b[:, 0])) * 1e-9
    return round(density_per_mm3 * volume_mm3)


def _opt_number(name: str, value, *, positive: bool = False, allow_none: bool = True):
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or (v <= 0 if positive else v < 0):
        cond = "> 0" if positive else ">= 0"
        raise ConfigError(f"{name} must be a finite number {cond}, got {value!r}")
    return v


@dataclass(frozen=True)
class SeedingSpec:
    """How to make the reference particle set of an experiment.

    Parameters
    ----------
    kind : {"box", "layer", "csv"}
        ``box``: uniform in a 3D box; ``layer``: uniform in x, y at one depth ``z_um`` (paper
        Fig. 5b); ``csv``: read a table (:meth:`Particles.from_csv`).
    count : int, optional
        Number of particles (box/layer). Exactly one of ``count`` and ``density_per_mm3``.
    density_per_mm3 : float, optional
        Number density (box/layer); the count is :func:`count_from_density` of ``bounds_xyz_um``
        (a layer needs a z range in ``bounds_xyz_um`` for this).
    bounds_xyz_um : sequence of (lo, hi) pairs
        ``((x0, x1), (y0, y1), (z0, z1))`` in µm, the ranges in x, y, z order (box/layer). A
        layer may give only the x and y ranges.
    z_um : float, optional
        Depth of the layer in µm (layer only).
    min_spacing_um : float, optional
        Minimum centre-to-centre distance in µm; default ``diameter_um``.
    diameter_um : float
        Particle diameter in µm (default 15); for ``csv`` the value used when the file has no
        ``diameter_um`` column.
    brightness : float
        Relative brightness (default 1); for ``csv`` the value used when the file has no
        ``brightness`` column.
    brightness_jitter : float
        Relative standard deviation of the brightness (box/layer, default 0): each particle
        gets ``brightness · max(0, 1 + brightness_jitter · N(0, 1))``.
    csv : str or os.PathLike, optional
        Particle table (csv only).
    """

    kind: str
    count: int | None = None
    density_per_mm3: float | None = None
    bounds_xyz_um: tuple[tuple[float, float], ...] | None = None
    z_um: float | None = None
    min_spacing_um: float | None = None
    diameter_um: float = DEFAULT_DIAMETER_UM
    brightness: float = 1.0
    brightness_jitter: float = 0.0
    csv: str | os.PathLike | None = None

    def __post_init__(self) -> None:
        if self.kind not in SEEDING_KINDS:
            raise ConfigError(f"seeding kind must be one of {SEEDING_KINDS}, got {self.kind!r}")
        set_ = object.__setattr__
        set_(self, "diameter_um", _opt_number("diameter_um", self.diameter_um, positive=True))
        set_(self, "brightness", _opt_number("brightness", self.brightness))
        set_(
            self,
            "brightness_jitter",
            _opt_number("brightness_jitter", self.brightness_jitter),
        )
        set_(self, "min_spacing_um", _opt_number("min_spacing_um", self.min_spacing_um))
        if self.kind == "csv":
            bad = [
                k
                for k in ("count", "density_per_mm3", "bounds_xyz_um", "z_um", "min_spacing_um")
                if getattr(self, k) is not None
            ]
            if self.brightness_jitter:
                bad.append("brightness_jitter")
            if bad:
                raise ConfigError(f"seeding kind 'csv' does not take {bad}")
            if self.csv is None:
                raise ConfigError("seeding kind 'csv' needs the key 'csv' (a particle table)")
            set_(self, "csv", Path(self.csv))
            return
        if self.csv is not None:
            raise ConfigError(f"seeding kind {self.kind!r} does not take 'csv'")
        if (self.count is None) == (self.density_per_mm3 is None):
            raise ConfigError(
                f"seeding kind {self.kind!r} needs exactly one of 'count' and 'density_per_mm3'"
            )
        if self.count is not None:
            _count(self.count)
            set_(self, "count", int(self.count))
        else:
            set_(self, "density_per_mm3", _opt_number("density_per_mm3", self.density_per_mm3))
        if self.bounds_xyz_um is None:
            raise ConfigError(
                f"seeding kind {self.kind!r} needs 'bounds_xyz_um' (x, y, z ranges in µm)"
            )
        if self.kind == "box":
            if self.z_um is not None:
                raise ConfigError("seeding kind 'box' does not take 'z_um' (use kind 'layer')")
            b = _box("bounds_xyz_um", self.bounds_xyz_um, 3)
        else:
            if self.z_um is None:
                raise ConfigError("seeding kind 'layer' needs 'z_um' (depth of the layer in µm)")
            z = self.z_um
            if isinstance(z, bool) or not isinstance(z, int | float | np.number):
                raise ConfigError(f"z_um must be a number, got {z!r}")
            if not math.isfinite(z):
                raise ConfigError(f"z_um must be finite, got {z!r}")
            set_(self, "z_um", float(z))
            nr = len(self.bounds_xyz_um) if hasattr(self.bounds_xyz_um, "__len__") else -1
            b = _box("bounds_xyz_um", self.bounds_xyz_um, 3 if nr == 3 else 2)
            if self.density_per_mm3 is not None and b.shape[0] != 3:
                raise ConfigError(
                    "seeding kind 'layer' with 'density_per_mm3' needs 'bounds_xyz_um' with a z "
                    "range (the volume the density refers to); or give 'count'"
                )
        set_(self, "bounds_xyz_um", tuple(tuple(r) for r in b.tolist()))

    @classmethod
    def from_dict(cls, d: Mapping, base_dir: str | os.PathLike | None = None) -> SeedingSpec:
        """Build from a plain dict (e.g. an experiment file's ``[particles]`` table).

        Parameters
        ----------
        d : Mapping
            Keys are the field names; unknown keys are rejected by name.
        base_dir : str or os.PathLike, optional
            Folder a relative ``csv`` path is relative to (the experiment file's folder).

        Returns
        -------
        SeedingSpec
        """
        if not isinstance(d, Mapping):
            raise ConfigError(f"the seeding spec must be a table/dict, got {type(d).__name__}")
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(d) - set(known))
        for key in unknown:
            renamed = renamed_key_message(key, known)
            if renamed is not None:
                raise ConfigError(renamed)
        if unknown:
            raise ConfigError(f"unknown seeding key(s) {unknown}; expected some of {known}")
        if "kind" not in d:
            raise ConfigError(f"the seeding spec needs the key 'kind', one of {SEEDING_KINDS}")
        kw = dict(d)
        if kw.get("csv") is not None:
            p = Path(kw["csv"])
            if not p.is_absolute() and base_dir is not None:
                p = Path(base_dir) / p
            kw["csv"] = p
        return cls(**kw)

    def to_dict(self) -> dict:
        """Plain-JSON representation (``None`` fields left out, paths as strings)."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            if f.name == "bounds_xyz_um":
                v = [list(r) for r in v]
            elif f.name == "csv":
                v = str(v)
            out[f.name] = v
        return out

    @property
    def n_particles(self) -> int | None:
        """The particle count for box/layer kinds (``None`` for csv)."""
        if self.kind == "csv":
            return None
        if self.count is not None:
            return self.count
        return count_from_density(self.density_per_mm3, self.bounds_xyz_um)

    def make(self, rng: np.random.Generator) -> Particles:
        """Make the particles.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of randomness (unused for ``csv``). Positions are drawn first, then the
            brightness jitter (only when ``brightness_jitter > 0``).

        Returns
        -------
        Particles
            ids ``0 .. N-1`` for box/layer.
        """
        if self.kind == "csv":
            return Particles.from_csv(
                self.csv, default_diameter_um=self.diameter_um, default_brightness=self.brightness
            )
        n = self.n_particles
        s = self.diameter_um if self.min_spacing_um is None else self.min_spacing_um
        if self.kind == "box":
            pos = seed_box(n, self.bounds_xyz_um, s, rng)
        else:
            pos = seed_layer(n, self.bounds_xyz_um[:2], self.z_um, s, rng)
        bright = np.full(n, self.brightness)
        if self.brightness_jitter > 0:
            bright = self.brightness * np.maximum(
                0.0, 1.0 + self.brightness_jitter * rng.standard_normal(n)
            )
        log.info("seeded %d particles (%s)", n, self.kind)
        return Particles(pos, self.diameter_um, bright)
