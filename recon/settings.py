"""Reconstruction settings: one frozen dataclass, each default and check defined once.

:class:`ReconSettings` is what ``recon run`` options, the ``[recon]`` section of a study file
and the library all build; the command line and the study reader take their defaults and
validation from here. Settings that depend on the microscope default to ``None`` and are
derived from the :class:`lfsim.optics.Optics` in use by :meth:`ReconSettings.resolved`
(there is no built-in microscope):

depth step ``z_step_um``
    a third of the native depth of field ``λ / NA²`` (Stefanoiu et al. 2019 sample the axial
    direction at about the lateral resolution), rounded to 0.5 µm: 5 µm for the paper's
    4×/0.2 objective at 605 nm;
depth range ``z_min_um``, ``z_max_um``
    symmetric about the native focal plane, out to where a point's light covers a disc of
    :data:`RANGE_PATTERN_LENSLETS` lenslets in radius (``|z| tan(asin NA) = 6 p_obj``),
    where ``p_obj`` is the lenslet pitch in object space; ±730 µm for the paper's optics
    (its experiments use −80 … 720 µm). Where a specimen's near surface
    (``Optics.surface_z_um``) cuts that range, the range starts :func:`default_front_guard_um`
    in front of the surface: *guard planes*, modelled as the specimen going on towards the
    objective, where nothing emits but where the reconstruction of a particle near the
    surface needs room (without them its depth comes out several µm shallow; ``benchmarks/
    README.md``, ``specimen_depth.py``). A given ``z_min_um`` may lie in front of the surface
    too: the planes there are guard planes;
super-resolution ``s``
    voxels per lenslet that make the lateral voxel about the depth step (isotropic voxels),
    at most the pixels per lenslet: 5 for the paper's optics (25 µm lenslets, 5 µm voxels).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from hrvbase import validate

from .errors import InputError, recon_input_errors
from .geometry import depth_range
from .projector import PROJECTORS
from .psf_wave import PSF_MODELS

#: How the black level enters the reconstruction (:class:`ReconSettings`).
BACKGROUND_MODELS = ("subtract", "model")
#: Most depth planes one reconstruction may have.
MAX_DEPTHS = 4096
#: Radius (lenslets) of a point's light disc at the ends of the default depth range.
RANGE_PATTERN_LENSLETS = 6
#: Guard planes in front of a specimen's near surface, in units of the true depth z₁ over which
#: a point's blur grows by one lenslet (:func:`default_front_guard_um`): 100 µm in the paper's
#: gel, which brings a particle 50 µm below the surface to within 2 µm of its depth
#: (benchmarks/README.md, ``specimen_depth.py``).
FRONT_GUARD_Z1 = 1.2
#: :class:`ReconSettings` fields that do not change the volumes (bit-identical results).
RUN_ONLY_FIELDS = ("threads",)
#: :class:`ReconSettings` fields that identify the volumes only through the PSF bank they
#: resolve to (its cache key is part of the output folder's fingerprint): ``psf_model="auto"``
#: and the model it picks give the same volumes.
BANK_RESOLVED_FIELDS = ("psf_model",)


def _wrap(check, *args):
    with recon_input_errors():
        return check(*args)


@dataclass(frozen=True)
class ReconSettings:
    """Reconstruction parameters (lengths in µm; ``None``: derived from the optics).

    Parameters
    ----------
    z_min_um, z_max_um, z_step_um : float or None
        Depth planes ``z_min, z_min + step, …, ≤ z_max`` (µm from the native focal plane).
        ``None``: from the optics (module docstring).
    s : int or None
        Voxels per lenslet along x and y (super-resolution). ``None``: from the optics.
    iterations : int
        Richardson–Lucy iterations (paper: 3).
    lanczos_a : float
        Window of the depth-adaptive anti-aliasing filter (paper: "Lanczos filter width" 2);
        0 disables the filter.
    stop_rel_change : float or None
        Stop early when the volume changes by less than this (relative L1, ≥ 0).
    rays_per_pattern : int
        Rays traced per PSF-bank pattern (≥ 1000; the ray bank only).
    psf_model : {"auto", "ray", "wave"}
        The PSF bank: ray-traced (:func:`recon.psf.compute_psf_bank`) or wave optics
        (:func:`recon.psf_wave.compute_wave_psf_bank`). ``"auto"``: wave optics where a
        lenslet's diffraction spot is wider than :data:`recon.psf_wave.WAVE_SPOT_PX` sensor
        pixels or the aperture angle's sine in the specimen exceeds
        :data:`recon.psf_wave.WAVE_SIN_THETA`, rays otherwise
        (:func:`recon.psf_wave.choose_psf_model`; rays for the paper's optics).
        ``recon.json`` records the model used.
    roi_xy_px : tuple of int or None
        ``(x0, x1, y0, y1)``, the x range then the y range in pixels: reconstruct only
        lenslets whose images lie inside these pixels.
    projector : {"auto", "gather", "sparse"}
        ``"auto"``: the fastest for the backend (:func:`recon.projector.make_projector`).
    background_model : {"subtract", "model"}
        ``"subtract"``: subtract the black level and clip at zero; ``"model"``: keep it in
        the data and in the forward model, ``y ≈ Hx + b`` (no clipping bias, but RL clears
        the background slowly: on a paper-size frame after 3 iterations the particles were
        localised less well, 0.53/0.45/5.2 µm RMS against 0.25/0.25/3.8 µm).
    threads : int or None
        CPU threads of one frame's reconstruction (≥ 1): the scipy.sparse projector's thread
        pool (:class:`recon.projector.SparseProjector`). ``None``: ``HRVPTM_THREADS`` if set,
        else every core the process may use, divided among the frames reconstructed at once
        (:func:`recon.projector.resolve_threads`); with ``W`` frame workers on one machine
        keep ``threads × W`` ≤ the cores, or they compete for them. The volumes are
        bit-identical for any value, so it is not part of the output folder's fingerprint
        (:data:`RUN_ONLY_FIELDS`). ``recon run --threads N`` sets it and the Dr.Jit backend's
        threads.
    """

    z_min_um: float | None = None
    z_max_um: float | None = None
    z_step_um: float | None = None
    s: int | None = None
    iterations: int = 3
    lanczos_a: float = 2.0
    stop_rel_change: float | None = None
    rays_per_pattern: int = 200_000
    psf_model: str = "auto"
    roi_xy_px: tuple | None = None
    projector: str = "auto"
    background_model: str = "subtract"
    threads: int | None = None

    def __post_init__(self) -> None:
        if self.background_model not in BACKGROUND_MODELS:
            raise InputError(
                f"background_model must be one of {BACKGROUND_MODELS}, "
                f"got {self.background_model!r}"
            )
        object.__setattr__(
            self, "psf_model", _wrap(validate.one_of, self.psf_model, "psf_model", PSF_MODELS)
        )
        if self.projector not in PROJECTORS:
            raise InputError(f"projector must be one of {PROJECTORS}, got {self.projector!r}")
        for name in ("z_min_um", "z_max_um"):
            if getattr(self, name) is not None:
                object.__setattr__(
                    self, name, _wrap(validate.finite_float, getattr(self, name), name)
                )
        if self.z_step_um is not None:
            object.__setattr__(
                self, "z_step_um", _wrap(validate.positive_float, self.z_step_um, "z_step_um")
            )
        if (self.z_min_um is None) != (self.z_max_um is None):
            raise InputError("give both z_min_um and z_max_um, or neither (from the optics)")
        if self.z_min_um is not None and self.z_max_um < self.z_min_um:
            raise InputError(f"z range {self.z_min_um}:{self.z_max_um} is empty (min > max)")
        if self.z_min_um is not None and self.z_step_um is not None:
            n = math.floor((self.z_max_um - self.z_min_um) / self.z_step_um + 1e-9) + 1
            if n < 2:
                raise InputError(
                    f"z range {self.z_min_um:g}:{self.z_max_um:g} in steps of "
                    f"{self.z_step_um:g} µm holds {n} depth plane; a volume needs at least 2"
                )
            if n > MAX_DEPTHS:
                raise InputError(f"{n} depth planes requested; at most {MAX_DEPTHS} are supported")
        if self.s is not None:
            object.__setattr__(self, "s", _wrap(validate.int_in_range, self.s, "s", 1, 64))
        object.__setattr__(
            self, "iterations", _wrap(validate.int_in_range, self.iterations, "iterations", 1)
        )
        lanczos = 0.0 if self.lanczos_a is None else self.lanczos_a
        object.__setattr__(
            self, "lanczos_a", _wrap(validate.nonnegative_float, lanczos, "lanczos_a")
        )
        if self.stop_rel_change is not None:
            object.__setattr__(
                self,
                "stop_rel_change",
                _wrap(validate.nonnegative_float, self.stop_rel_change, "stop_rel_change"),
            )
        object.__setattr__(
            self,
            "rays_per_pattern",
            _wrap(validate.int_in_range, self.rays_per_pattern, "rays_per_pattern", 1000),
        )
        if self.threads is not None:
            object.__setattr__(
                self, "threads", _wrap(validate.int_in_range, self.threads, "threads", 1)
            )
        if self.roi_xy_px is not None:
            roi = tuple(int(v) for v in self.roi_xy_px)
            if len(roi) != 4 or roi[0] >= roi[1] or roi[2] >= roi[3] or min(roi) < 0:
                raise InputError(f"roi_xy_px must be (x0, x1, y0, y1) with x0 < x1, y0 < y1: {roi}")
            object.__setattr__(self, "roi_xy_px", roi)

    @property
    def is_resolved(self) -> bool:
        """Whether every optics-dependent setting has a value."""
        return None not in (self.z_min_um, self.z_max_um, self.z_step_um, self.s)

    def resolved(self, optics) -> ReconSettings:
        """These settings with the optics-dependent ``None`` values filled in."""
        step = self.z_step_um if self.z_step_um is not None else default_z_step_um(optics)
        z0, z1 = self.z_min_um, self.z_max_um
        if z0 is None:
            zlim = default_z_limit_um(optics, step)
            first = _first_plane_in_specimen_um(optics, step)
            if first > -zlim:  # the surface cuts the range: guard planes in front of it
                first -= default_front_guard_um(optics, step)
            z0, z1 = max(-zlim, first), zlim
            if z1 <= z0:
                z1 = z0 + 2 * zlim
        s = self.s if self.s is not None else default_s(optics, step)
        return replace(self, z_min_um=z0, z_max_um=z1, z_step_um=step, s=s)

    @property
    def depths_um(self) -> np.ndarray:
        """Depth planes (µm); the settings must be :meth:`resolved`."""
        if not self.is_resolved:
            raise InputError("depths depend on the optics: call ReconSettings.resolved(optics)")
        return depth_range(self.z_min_um, self.z_max_um, self.z_step_um)

    @property
    def filter_window(self) -> float | None:
        """The Lanczos window, or ``None`` when the filter is off (``lanczos_a = 0``)."""
        return self.lanczos_a or None

    def to_dict(self) -> dict:
        d = asdict(self)
        d["roi_xy_px"] = list(self.roi_xy_px) if self.roi_xy_px else None
        return d

    def result_dict(self) -> dict:
        """:meth:`to_dict` without the fields that change how fast, not what, is computed
        (:data:`RUN_ONLY_FIELDS`), nor those the PSF bank's key stands for
        (:data:`BANK_RESOLVED_FIELDS`): with that key, what identifies the volumes."""
        skip = RUN_ONLY_FIELDS + BANK_RESOLVED_FIELDS
        return {k: v for k, v in self.to_dict().items() if k not in skip}

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


def default_z_step_um(optics) -> float:
    """A third of the native depth of field ``λ n / NA²`` in the specimen of index ``n`` (µm),
    rounded to 0.5 µm (≥ 0.5)."""
    dof = optics.wavelength_um * optics.medium_ior / optics.na**2
    return max(0.5, round(dof / 3 * 2) / 2)


def default_z_limit_um(optics, z_step_um: float) -> float:
    """Half-width of the default depth range: ``6 p_obj / (tan θ · a)``, a multiple of the
    step (µm), with θ the acceptance half-angle in the immersion medium and ``a`` the ratio of
    apparent to true depth in the specimen (``6 p_obj / tan(asin NA)`` in air)."""
    zlim = RANGE_PATTERN_LENSLETS * optics.lenslet_object_um / _blur_slope(optics)
    return math.floor(zlim / z_step_um) * z_step_um


def default_front_guard_um(optics, z_step_um: float) -> float:
    """Depth of the guard planes in front of a specimen's near surface (µm, a multiple of the
    step): :data:`FRONT_GUARD_Z1` times the true depth ``z₁ = p_obj / (2 tan θ · a)`` over
    which a point's blur at the array grows by one lenslet (``a`` the ratio of apparent to
    true depth; 83 µm in the paper's gel of index 1.35, a guard of 100 µm at a 5 µm step)."""
    z1 = optics.lenslet_object_um / (2.0 * _blur_slope(optics))
    return math.ceil(FRONT_GUARD_Z1 * z1 / z_step_um - 1e-9) * z_step_um


def _blur_slope(optics) -> float:
    """Growth of a point's blur radius (object space) per µm of true depth: ``tan θ · a``,
    θ the acceptance half-angle in the immersion medium, ``a`` apparent over true depth."""
    return math.tan(optics.theta_max) * optics.axial_scale


def _first_plane_in_specimen_um(optics, z_step_um: float) -> float:
    """The first multiple of the step at or beyond the specimen's near surface (µm); −inf
    without interfaces."""
    if not getattr(optics, "has_interfaces", False):
        return -math.inf
    return math.ceil(optics.surface_z_um / z_step_um - 1e-9) * z_step_um


def default_s(optics, z_step_um: float) -> int:
    """Voxels per lenslet for a lateral voxel of about the depth step (≤ pixels per lenslet)."""
    s = round(optics.lenslet_object_um / z_step_um)
    return int(min(max(s, 1), math.floor(optics.px_per_lenslet), 64))


__all__ = [
    "BACKGROUND_MODELS",
    "BANK_RESOLVED_FIELDS",
    "MAX_DEPTHS",
    "RUN_ONLY_FIELDS",
    "ReconSettings",
    "default_s",
    "default_z_limit_um",
    "default_z_step_um",
]
