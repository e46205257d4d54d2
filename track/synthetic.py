"""Known displacement fields and synthetic particle-cloud pairs, for tests and benchmarks.

A family of analytic displacement fields ``u(x)`` (µm) on a box of particles, each scaled so
that its largest displacement over the box equals a requested amplitude and, for the
heterogeneous ones, so that its steepest local gradient grows with that amplitude
(:data:`GRADIENT_PER_AMPLITUDE`: 0.6 at 1.5 mean spacings):

* homogeneous: ``translation``, ``rotation``, ``uniaxial_stretch``, ``simple_shear``;
* heterogeneous: ``gaussian_indentation`` (a punch on the top face), ``sinusoidal_shear``,
  ``vortex`` (rotation about z that decays from up to 45° on the axis),
  ``stiff_inclusion`` (a nearly rigid sphere in a stretched incompressible matrix, with an
  Eshelby-like ``(a/r)³`` perturbation and a strain concentration of about 3× the far
  field at the interface), ``shear_wave_front`` (a tanh front on an oblique plane).

:func:`make_pair` seeds particles with a minimum spacing (Poisson-disc-like), deforms them,
crops both frames to the same imaged box (particles leave and enter through the faces),
drops a fraction of the particles from each frame independently, adds anisotropic
localisation noise as in light-field volumes (axial ≈ 10 × lateral) and shuffles the deformed
rows. :func:`~track.link_score.score_link` compares a linker's result with the truth.

Coordinates are (x, y, z) in µm throughout; ``gradient`` returns ``∂u_i/∂x_j`` with ``i`` the
row (component) and ``j`` the column.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from hrvbase.known_fields import (
    inclusion_displacement,
    inclusion_gradient,
    indentation_displacement,
    indentation_gradient,
)
from track.errors import InputError
from track.link_score import LinkScore as LinkScore  # re-exported
from track.link_score import score_link as score_link  # re-exported
from track.link_score import score_motion as score_motion  # re-exported

logger = logging.getLogger(__name__)

HOMOGENEOUS = ("translation", "rotation", "uniaxial_stretch", "simple_shear")
HETEROGENEOUS = (
    "gaussian_indentation",
    "sinusoidal_shear",
    "vortex",
    "stiff_inclusion",
    "shear_wave_front",
)
FIELD_NAMES = HOMOGENEOUS + HETEROGENEOUS

#: Steepest displacement gradient of a heterogeneous field per (amplitude / mean spacing).
GRADIENT_PER_AMPLITUDE = 0.4
#: Localisation noise σ per axis (x, y, z) in µm of a light-field volume with particles about
#: 50 µm apart: 0.25 µm lateral, 2.5 µm axial.
NOISE_XYZ_UM = (0.25, 0.25, 2.5)
#: Cube root of the volume per particle (µm); with :data:`MIN_DISTANCE_FRACTION` the mean
#: nearest-neighbour spacing is about 50 µm.
CELL_UM = 66.0
#: Smallest particle distance as a fraction of :data:`CELL_UM`.
MIN_DISTANCE_FRACTION = 0.6
#: Rotation on the axis of the vortex at an amplitude of :data:`VORTEX_REFERENCE_SPACINGS`.
VORTEX_MAX_ANGLE_RAD = np.pi / 4
VORTEX_REFERENCE_SPACINGS = 1.5


def _points(xyz_um) -> np.ndarray:
    x = np.asarray(xyz_um, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise InputError(f"xyz_um must have shape (N, 3) (x, y, z in µm), got {x.shape}")
    return x


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _bounds(bounds_xyz_um) -> np.ndarray:
    b = np.asarray(bounds_xyz_um, dtype=float)
    if b.shape != (3, 2) or not np.all(np.isfinite(b)) or np.any(b[:, 1] <= b[:, 0]):
        raise InputError(
            f"bounds_xyz_um must be finite (3, 2) [min, max] per axis, got {b.tolist()}"
        )
    return b


# ------------------------------------------------------------------------------- fields


@dataclass(frozen=True)
class KnownField:
    """An analytic displacement field ``u(x)``; subclasses define :meth:`__call__`.

    Attributes
    ----------
    name : str
        Name in :data:`FIELD_NAMES` (or the user's).
    amplitude_um : float
        Largest displacement over the box it was built for (µm).
    max_gradient : float
        Largest ``|∂u_i/∂x_j|`` over that box (dimensionless, sampled).
    """

    name: str
    amplitude_um: float
    max_gradient: float = field(default=float("nan"), compare=False)

    def __call__(self, xyz_um) -> np.ndarray:
        """Displacement (N, 3) in µm at reference points ``xyz_um`` (N, 3) µm."""
        raise NotImplementedError

    def gradient(self, xyz_um) -> np.ndarray:
        """``∂u_i/∂x_j`` (N, 3, 3) at ``xyz_um`` (N, 3); central differences by default."""
        x = _points(xyz_um)
        h = 1e-4 * max(1.0, float(np.abs(x).max(initial=1.0)))
        out = np.empty((x.shape[0], 3, 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = h
            out[:, :, j] = (self(x + e) - self(x - e)) / (2 * h)
        return out

    def deform(self, xyz_um) -> np.ndarray:
        """Deformed positions ``x + u(x)`` (N, 3) in µm."""
        x = _points(xyz_um)
        return x + self(x)


@dataclass(frozen=True)
class AffineField(KnownField):
    """``u = L (x − centre) + translation`` with a constant gradient ``L``."""

    grad: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    center_xyz_um: np.ndarray = field(default_factory=lambda: np.zeros(3))
    translation_um: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __call__(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        return (x - self.center_xyz_um) @ np.asarray(self.grad).T + self.translation_um

    def gradient(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        return np.broadcast_to(np.asarray(self.grad, dtype=float), (x.shape[0], 3, 3)).copy()


@dataclass(frozen=True)
class GaussianIndentation(KnownField):
    """A punch pressed into the top face (z = ``top_um``) at ``(x, y) = centre``.

    ``u_z = −A exp(−ρ²/(2 w²)) exp(−(top − z)/D)`` with ``ρ`` the lateral distance from the
    centre, ``w`` the width and ``D`` the decay depth; ``u_x = u_y = 0``. The field is
    :func:`hrvbase.known_fields.indentation_displacement` (lfsim's ``gaussian_indentation``
    motion is the same).
    """

    centre_xy_um: np.ndarray = field(default_factory=lambda: np.zeros(2))
    top_um: float = 0.0
    width_um: float = 1.0
    depth_um: float = 1.0

    def _params(self) -> dict:
        return {
            "depth_um": self.amplitude_um,
            "center_xy_um": self.centre_xy_um,
            "surface_z_um": self.top_um,
            "width_um": self.width_um,
            "decay_um": self.depth_um,
        }

    def __call__(self, xyz_um) -> np.ndarray:
        return indentation_displacement(_points(xyz_um), **self._params())

    def gradient(self, xyz_um) -> np.ndarray:
        return indentation_gradient(_points(xyz_um), **self._params())


@dataclass(frozen=True)
class SinusoidalShear(KnownField):
    """``u_x = A sin(k (z − z0) + phase)``: shear bands alternating along z."""

    wavenumber_per_um: float = 1.0
    origin_z_um: float = 0.0
    phase_rad: float = 0.3

    def _arg(self, x):
        return self.wavenumber_per_um * (x[:, 2] - self.origin_z_um) + self.phase_rad

    def __call__(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        out = np.zeros_like(x)
        out[:, 0] = self.amplitude_um * np.sin(self._arg(x))
        return out

    def gradient(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        out = np.zeros((x.shape[0], 3, 3))
        out[:, 0, 2] = self.amplitude_um * self.wavenumber_per_um * np.cos(self._arg(x))
        return out


@dataclass(frozen=True)
class Vortex(KnownField):
    """Rotation about the z axis through ``centre`` by ``θ(ρ) = θ0 exp(−ρ²/(2 R²))``."""

    centre_xy_um: np.ndarray = field(default_factory=lambda: np.zeros(2))
    angle_rad: float = 0.0
    radius_um: float = 1.0

    def _parts(self, x):
        d = x[:, :2] - self.centre_xy_um
        th = self.angle_rad * np.exp(-np.sum(d**2, axis=1) / (2 * self.radius_um**2))
        return d, th, np.cos(th), np.sin(th)

    def __call__(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        d, _, c, s = self._parts(x)
        out = np.zeros_like(x)
        out[:, 0] = d[:, 0] * (c - 1) - d[:, 1] * s
        out[:, 1] = d[:, 0] * s + d[:, 1] * (c - 1)
        return out

    def gradient(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        d, th, c, s = self._parts(x)
        tx = -th * d[:, 0] / self.radius_um**2  # ∂θ/∂x
        ty = -th * d[:, 1] / self.radius_um**2
        px = -d[:, 0] * s - d[:, 1] * c  # ∂u_x/∂θ
        py = d[:, 0] * c - d[:, 1] * s  # ∂u_y/∂θ
        out = np.zeros((x.shape[0], 3, 3))
        out[:, 0, 0] = (c - 1) + px * tx
        out[:, 0, 1] = -s + px * ty
        out[:, 1, 0] = s + py * tx
        out[:, 1, 1] = (c - 1) + py * ty
        return out


@dataclass(frozen=True)
class StiffInclusion(KnownField):
    """A nearly rigid sphere in an incompressible matrix stretched along x.

    ``u = (1 − φ(r)) E (x − c)`` with ``E = ε diag(1, −½, −½)``, ``φ = 1 − δ`` inside the
    sphere (radius ``a``; strain ``δ ε`` there) and ``(1 − δ)(a/r)³`` outside: continuous,
    the far-field stretch outside, a strain concentration of about ``3 ε`` at the interface.
    The field is :func:`hrvbase.known_fields.inclusion_displacement` (lfsim's
    ``stiff_inclusion`` motion is the same).
    """

    center_xyz_um: np.ndarray = field(default_factory=lambda: np.zeros(3))
    strain: float = 0.0
    radius_um: float = 1.0
    inner_fraction: float = 0.05

    def _params(self) -> dict:
        return {
            "strain": self.strain,
            "center_xyz_um": self.center_xyz_um,
            "radius_um": self.radius_um,
            "inner_fraction": self.inner_fraction,
            "axis": "x",
        }

    def __call__(self, xyz_um) -> np.ndarray:
        return inclusion_displacement(_points(xyz_um), **self._params())

    def gradient(self, xyz_um) -> np.ndarray:
        return inclusion_gradient(_points(xyz_um), **self._params())


@dataclass(frozen=True)
class ShearWaveFront(KnownField):
    """``u = p A ½ (1 − tanh(n·(x − c) / w))``: a shear front on the plane through ``c``."""

    center_xyz_um: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    polarisation: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    width_um: float = 1.0

    def _t(self, x):
        return np.tanh((x - self.center_xyz_um) @ self.normal / self.width_um)

    def __call__(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        return np.outer(0.5 * self.amplitude_um * (1.0 - self._t(x)), self.polarisation)

    def gradient(self, xyz_um) -> np.ndarray:
        x = _points(xyz_um)
        g = -0.5 * self.amplitude_um * (1.0 - self._t(x) ** 2) / self.width_um
        return g[:, None, None] * np.outer(self.polarisation, self.normal)[None]


def _vortex_peak(angle_rad: float) -> float:
    """max over t of 2 sin(θ0 exp(−t²/2) / 2) t (the vortex's largest |u| / R)."""
    t = np.linspace(0.0, 4.0, 4001)
    return float(np.max(2.0 * np.sin(0.5 * angle_rad * np.exp(-0.5 * t**2)) * t))


def _box_corners(b: np.ndarray) -> np.ndarray:
    return np.array(np.meshgrid(*b, indexing="ij")).reshape(3, -1).T


def make_field(name: str, bounds_xyz_um, spacing_um: float, amplitude_um: float) -> KnownField:
    """One field of the family, sized for a box of particles.

    Parameters
    ----------
    name : str
        One of :data:`FIELD_NAMES`.
    bounds_xyz_um : array_like, shape (3, 2)
        [min, max] of the imaged box per axis (x, y, z), µm.
    spacing_um : float
        Mean nearest-neighbour particle spacing (µm); the heterogeneous fields' length
        scales are set in spacings so that their steepest gradient is
        ``GRADIENT_PER_AMPLITUDE × amplitude / spacing``.
    amplitude_um : float
        Largest displacement over the box (µm), > 0.

    Returns
    -------
    KnownField
        With ``max_gradient`` measured on a 24³ lattice of the box.

    Raises
    ------
    InputError
        Unknown name, bad box, spacing or amplitude.
    """
    b = _bounds(bounds_xyz_um)
    if not (np.isfinite(spacing_um) and spacing_um > 0):
        raise InputError(f"spacing_um must be finite and > 0, got {spacing_um}")
    if not (np.isfinite(amplitude_um) and amplitude_um > 0):
        raise InputError(f"amplitude_um must be finite and > 0, got {amplitude_um}")
    s, a = float(spacing_um), float(amplitude_um)
    c = b.mean(axis=1)
    half = 0.5 * (b[:, 1] - b[:, 0])
    corners = _box_corners(b)
    g = GRADIENT_PER_AMPLITUDE / s  # steepest gradient per µm of amplitude
    if name == "translation":
        f = AffineField(name, a, translation_um=a * _unit([1.0, 0.4, -0.3]), center_xyz_um=c)
    elif name == "rotation":
        axis = _unit([0.2, 0.3, 1.0])
        d = corners - c
        rho = float(np.max(np.linalg.norm(d - np.outer(d @ axis, axis), axis=1)))
        th = 2.0 * np.arcsin(min(1.0, a / (2.0 * rho)))
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        rot = np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * (k @ k)
        f = AffineField(name, a, grad=rot - np.eye(3), center_xyz_um=c)
    elif name == "uniaxial_stretch":
        f = AffineField(name, a, grad=np.diag([a / half[0], 0.0, 0.0]), center_xyz_um=c)
    elif name == "simple_shear":
        grad = np.zeros((3, 3))
        grad[0, 2] = a / half[2]
        f = AffineField(name, a, grad=grad, center_xyz_um=c)
    elif name == "gaussian_indentation":
        w = np.exp(-0.5) / g
        f = GaussianIndentation(
            name, a, centre_xy_um=c[:2], top_um=float(b[2, 1]), width_um=w, depth_um=half[2]
        )
    elif name == "sinusoidal_shear":
        f = SinusoidalShear(name, a, wavenumber_per_um=g, origin_z_um=float(b[2, 0]))
    elif name == "vortex":
        a_ref = VORTEX_REFERENCE_SPACINGS * s
        radius = a_ref / _vortex_peak(VORTEX_MAX_ANGLE_RAD)
        lo, hi = 0.0, np.pi
        for _ in range(60):  # angle whose peak displacement is the amplitude
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if radius * _vortex_peak(mid) < a else (lo, mid)
        f = Vortex(name, a, centre_xy_um=c[:2], angle_rad=0.5 * (lo + hi), radius_um=radius)
    elif name == "stiff_inclusion":
        eps = a / float(np.sqrt(half[0] ** 2 + 0.25 * half[1] ** 2 + 0.25 * half[2] ** 2))
        f = StiffInclusion(name, a, center_xyz_um=c, strain=eps, radius_um=3.0 * s)
    elif name == "shear_wave_front":
        n = _unit([0.2, 0.3, 1.0])
        p = _unit(np.cross(n, [0.0, 1.0, 0.0]))
        f = ShearWaveFront(
            name, a, center_xyz_um=c, normal=n, polarisation=p, width_um=1.0 / (2.0 * g)
        )
    else:
        raise InputError(f"unknown field {name!r}; expected one of {FIELD_NAMES}")
    axes = [np.linspace(lo, hi, 24) for lo, hi in b]
    grid = np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T
    object.__setattr__(f, "max_gradient", float(np.abs(f.gradient(grid)).max()))
    return f


# ------------------------------------------------------------------------------- clouds


def poisson_disc_cloud(n: int, bounds_xyz_um, min_distance_um: float, seed: int = 0) -> np.ndarray:
    """``n`` uniformly random points in a box, no two closer than ``min_distance_um``.

    Random sequential addition in batches (candidates too close to an accepted point or to
    an earlier candidate of their batch are dropped), so the points are uniform and
    unordered in space. Stops with an error when batches no longer add points.

    Parameters
    ----------
    n : int
        Number of points (≥ 1).
    bounds_xyz_um : array_like, shape (3, 2)
        [min, max] per axis (x, y, z), µm.
    min_distance_um : float
        Smallest pairwise distance (µm, ≥ 0).
    seed : int
        Seed of the generator.

    Returns
    -------
    ndarray, shape (n, 3)

    Raises
    ------
    InputError
        Bad arguments, or a box too small to hold ``n`` points that far apart.
    """
    b = _bounds(bounds_xyz_um)
    if int(n) != n or n < 1:
        raise InputError(f"n must be a positive integer, got {n}")
    if not (np.isfinite(min_distance_um) and min_distance_um >= 0):
        raise InputError(f"min_distance_um must be finite and ≥ 0, got {min_distance_um}")
    rng = np.random.default_rng(seed)
    acc = np.zeros((0, 3))
    stalled = 0
    for _ in range(200):
        need = n - acc.shape[0]
        if need <= 0 or stalled >= 5:  # done, or the box is full
            break
        cand = rng.uniform(b[:, 0], b[:, 1], size=(max(2 * need, 64), 3))
        if acc.shape[0] and min_distance_um > 0:
            d, _ = cKDTree(acc).query(cand, 1)
            cand = cand[d >= min_distance_um]
        if min_distance_um > 0 and cand.shape[0] > 1:
            # drop every candidate with an earlier one of its batch too close (a few more
            # than needed; the next batch fills in)
            close = cKDTree(cand).query_pairs(min_distance_um, output_type="ndarray")
            bad = np.zeros(cand.shape[0], dtype=bool)
            bad[close.max(axis=1) if close.size else []] = True
            cand = cand[~bad]
        stalled = stalled + 1 if cand.shape[0] < max(1, need // 100) else 0
        acc = np.vstack([acc, cand[:need]])
    if acc.shape[0] < n:
        raise InputError(
            f"cannot place {n} points {min_distance_um} µm apart in a box of "
            f"{np.ptp(b, axis=1).tolist()} µm"
        )
    return acc


@dataclass(frozen=True)
class SyntheticPair:
    """A reference / deformed pair of noisy particle clouds with its truth.

    Attributes
    ----------
    ref_xyz_um, def_xyz_um : ndarray, shape (N, 3), (M, 3)
        Observed positions (noisy, deformed rows shuffled), µm.
    ref_ids, def_ids : ndarray of int, shape (N,), (M,)
        Particle id of each row (index into ``seeds_um``).
    seeds_um : ndarray, shape (P, 3)
        Noise-free reference positions of every seeded particle.
    true_displacement_um : ndarray, shape (P, 3)
        Noise-free displacement of every seeded particle from the reference to the deformed
        frame.
    ref_noise_um, def_noise_um : ndarray, shape (N, 3), (M, 3)
        The localisation noise added to each row.
    field : KnownField
        The field that made the deformation (for a pair of :func:`make_pair`,
        ``true_displacement_um = field(seeds_um)``).
    bounds_xyz_um : ndarray, shape (3, 2)
        The imaged box (both frames are cropped to it).
    spacing_um : float
        Mean nearest-neighbour distance of the noise-free particles in the box at frame 0.
    noise_xyz_um : tuple of float
        Localisation noise σ per axis (x, y, z), µm.
    """

    ref_xyz_um: np.ndarray
    def_xyz_um: np.ndarray
    ref_ids: np.ndarray
    def_ids: np.ndarray
    seeds_um: np.ndarray
    true_displacement_um: np.ndarray
    ref_noise_um: np.ndarray
    def_noise_um: np.ndarray
    field: KnownField
    bounds_xyz_um: np.ndarray
    spacing_um: float
    noise_xyz_um: tuple[float, float, float]

    @property
    def common_ids(self) -> np.ndarray:
        """Ids of the particles present in both frames."""
        return np.intersect1d(self.ref_ids, self.def_ids)

    def true_matches(self) -> np.ndarray:
        """The right links ``[row_ref, row_def]`` (K, 2) of the particles in both frames."""
        ids = self.common_ids
        order_a = np.argsort(self.ref_ids)
        rows_a = order_a[np.searchsorted(self.ref_ids, ids, sorter=order_a)]
        order_b = np.argsort(self.def_ids)
        rows_b = order_b[np.searchsorted(self.def_ids, ids, sorter=order_b)]
        return np.column_stack([rows_a, rows_b]).astype(np.int64)


@dataclass(frozen=True)
class SyntheticSeries:
    """Frames of noisy particle clouds under a loading that grows linearly in time.

    Frame ``k`` holds the particles at ``seeds + k · field(seeds)`` (each material point
    moves by the same step every frame) that lie in the box, minus independent drop-outs,
    plus independent noise; rows of frames ≥ 1 are shuffled.

    Attributes
    ----------
    frames_xyz_um : tuple of ndarray, shape (N_k, 3)
        Observed positions per frame (µm).
    frame_ids : tuple of ndarray of int, shape (N_k,)
        Particle id of each row.
    frame_noise_um : tuple of ndarray, shape (N_k, 3)
        Noise added to each row.
    seeds_um : ndarray, shape (P, 3)
        Noise-free positions of every particle at frame 0.
    field : KnownField
        The step per frame, a function of frame-0 positions.
    bounds_xyz_um, spacing_um, noise_xyz_um
        As :class:`SyntheticPair`.
    """

    frames_xyz_um: tuple
    frame_ids: tuple
    frame_noise_um: tuple
    seeds_um: np.ndarray
    field: KnownField
    bounds_xyz_um: np.ndarray
    spacing_um: float
    noise_xyz_um: tuple[float, float, float]

    def positions_um(self, k: int) -> np.ndarray:
        """Noise-free positions (P, 3) of every particle at frame ``k``."""
        return self.seeds_um + k * self.field(self.seeds_um)

    def pair(self, a: int, b: int) -> SyntheticPair:
        """Frames ``a → b`` as a :class:`SyntheticPair` (reference positions at frame a)."""
        n = len(self.frames_xyz_um)
        if not (0 <= a < n and 0 <= b < n and a != b):
            raise InputError(f"frames must be two different indices in 0..{n - 1}, got {a}, {b}")
        pa = self.positions_um(a)
        return SyntheticPair(
            ref_xyz_um=self.frames_xyz_um[a],
            def_xyz_um=self.frames_xyz_um[b],
            ref_ids=self.frame_ids[a],
            def_ids=self.frame_ids[b],
            seeds_um=pa,
            true_displacement_um=self.positions_um(b) - pa,
            ref_noise_um=self.frame_noise_um[a],
            def_noise_um=self.frame_noise_um[b],
            field=self.field,
            bounds_xyz_um=self.bounds_xyz_um,
            spacing_um=self.spacing_um,
            noise_xyz_um=self.noise_xyz_um,
        )


def make_series(
    field_name: str | KnownField,
    n: int = 1000,
    amplitude_spacings: float = 1.0,
    n_frames: int = 2,
    *,
    seed: int = 0,
    noise_xyz_um=NOISE_XYZ_UM,
    drop_fraction: float = 0.05,
    cell_um: float = CELL_UM,
    min_distance_fraction: float = MIN_DISTANCE_FRACTION,
    crop: bool = True,
) -> SyntheticSeries:
    """Synthetic frames of about ``n`` particles, each step the same known field.

    Parameters
    ----------
    field_name : str or KnownField
        A name of :data:`FIELD_NAMES` (sized by :func:`make_field` to the box, the spacing
        and the amplitude) or a ready field (``amplitude_spacings`` is then ignored).
    n : int
        Particles seeded in the imaged cube before drop-outs (its side is
        ``cell_um · n^(1/3)``).
    amplitude_spacings : float
        Largest displacement of one step, in mean spacings.
    n_frames : int
        Frames (≥ 2).
    seed : int
        Seed of the cloud, the drop-outs, the noise and the shuffles.
    noise_xyz_um : sequence of 3 float
        Localisation noise σ per axis (x, y, z), µm, added independently to every frame.
    drop_fraction : float
        Probability that a particle is missing from a frame (independently per frame).
    cell_um, min_distance_fraction : float
        Cube root of the volume per particle (µm) and the smallest distance in cells.
    crop : bool
        Seed particles around the box too and crop every frame to the box (particles cross
        the faces); with False only the box's particles exist, and leave it freely.

    Returns
    -------
    SyntheticSeries
    """
    if int(n) != n or n < 8:
        raise InputError(f"n must be an integer ≥ 8, got {n}")
    if int(n_frames) != n_frames or n_frames < 2:
        raise InputError(f"n_frames must be an integer ≥ 2, got {n_frames}")
    noise = np.asarray(noise_xyz_um, dtype=float).reshape(3)
    if not np.all(np.isfinite(noise) & (noise >= 0)):
        raise InputError(f"noise_xyz_um must be 3 finite values ≥ 0, got {noise_xyz_um}")
    if not 0 <= drop_fraction < 1:
        raise InputError(f"drop_fraction must be in [0, 1), got {drop_fraction}")
    rng = np.random.default_rng(seed)
    side = cell_um * n ** (1 / 3)
    box = np.array([[0.0, side]] * 3)
    steps = n_frames - 1
    if isinstance(field_name, KnownField):
        reach = 2.0 * cell_um + steps * field_name.amplitude_um
    else:
        reach = (2.0 + steps * amplitude_spacings) * cell_um
    outer = box + np.array([-1.0, 1.0]) * (reach if crop else 0.0)
    n_all = int(np.rint(n * np.prod(np.ptp(outer, axis=1)) / side**3))
    seeds = poisson_disc_cloud(n_all, outer, min_distance_fraction * cell_um, seed=seed)
    inside = np.all((seeds >= box[:, 0]) & (seeds <= box[:, 1]), axis=1)
    d, _ = cKDTree(seeds).query(seeds[inside], 2)
    spacing = float(d[:, 1].mean())
    if isinstance(field_name, KnownField):
        fld = field_name
    else:
        fld = make_field(field_name, box, spacing, amplitude_spacings * spacing)
    step = fld(seeds)
    frames, ids, noises = [], [], []
    for k in range(n_frames):
        pos = seeds + k * step
        inb = np.all((pos >= box[:, 0]) & (pos <= box[:, 1]), axis=1) if crop else inside
        rows = np.flatnonzero(inb & (rng.random(seeds.shape[0]) >= drop_fraction))
        if k:
            rows = rng.permutation(rows)
        nz = rng.normal(0.0, 1.0, (rows.size, 3)) * noise
        frames.append(pos[rows] + nz)
        ids.append(rows)
        noises.append(nz)
    return SyntheticSeries(
        frames_xyz_um=tuple(frames),
        frame_ids=tuple(ids),
        frame_noise_um=tuple(noises),
        seeds_um=seeds,
        field=fld,
        bounds_xyz_um=box,
        spacing_um=spacing,
        noise_xyz_um=tuple(float(v) for v in noise),
    )


def make_pair(
    field_name: str | KnownField,
    n: int = 1000,
    amplitude_spacings: float = 1.0,
    **options,
) -> SyntheticPair:
    """A synthetic reference / deformed pair: :func:`make_series` with two frames.

    Parameters are those of :func:`make_series` (``options``: its keyword-only ones);
    ``amplitude_spacings`` is the largest displacement in mean spacings.

    Returns
    -------
    SyntheticPair
        ``true_displacement_um = field(seeds_um)``.
    """
    return make_series(field_name, n, amplitude_spacings, 2, **options).pair(0, 1)
