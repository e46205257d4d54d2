"""Correct the reconstruction's position bias with a reference volume.

The reconstruction puts a particle's centre off by a fixed bias that depends on its depth and
its position under its lenslet (up to 6–7 µm peak to peak in z at 120 µm depth, measured on
noise-free spheres). A *reference volume* — noise-free spheres rendered at the detected
positions through the model's ideal lenslets and reconstructed as the frame was
(:mod:`recon.reference`) — shows the same bias at the same places. :func:`reference_bias`
localises each sphere of the reference at its own detected position with the detector's
patch: the offset from that position is the bias there. :func:`apply_bias` subtracts it.

The whole offset is subtracted by default: the reference measures the bias along every axis,
and the lateral one, a tenth of a voxel, changes with the lenslet phase as the axial one
does. On the axis a translation moves the particles along it is most of the lateral error
(fig5a_x paper size, 5 iterations on 10 µm planes, x displacement RMSD: seed 1
0.264 → 0.137 µm, seed 2 0.318 → 0.169 µm); on the other lateral axis it adds a little
scatter (y 0.137 → 0.146, 0.138 → 0.165 µm; test size 0.157 → 0.163 µm).
``lateral=False`` subtracts z only (``benchmarks/README.md``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hrvbase.errors import raised_as
from hrvbase.validate import int_in_range, positive_float

from .errors import InputError
from .localize import localize

log = logging.getLogger(__name__)

#: Values of :attr:`AxialCalibration.method`.
METHODS = ("none", "simulated")


@dataclass(frozen=True)
class AxialCalibration:
    """Self-calibration of the reconstruction's position bias (``[track.axial]`` of a study).

    Attributes
    ----------
    method : {"none", "simulated"}
        ``"simulated"``: subtract the bias measured on a reference volume of every frame
        (:mod:`recon.reference`); ``"none"``: positions as detected.
    sphere_diameter_um : float or None
        Diameter of the reference spheres (µm): the particles'. None: the default of
        ``recon.reference.ReferenceSettings`` (the paper's 15 µm; see
        :func:`hrvptm.calibrated.reference_settings`).
    rays_per_particle : int or None
        Rays per reference sphere; None: the default of ``ReferenceSettings``.
    lateral : bool
        Subtract the x and y offsets too (default; ``False``: z only, see the module
        docstring).
    steps : int
        Fixed-point steps (1–5; default 2). One step measures the bias at the detected
        position ``p = t + b(t)`` and leaves ``b(t) − b(p) ≈ −b′ b`` where the bias changes
        with depth; step ``k`` renders the references at the positions corrected by step
        ``k − 1`` and measures the bias there, at the cost of one more reference per frame.
        The second step removes the ``b′ b`` term; a third changes the positions by at most
        0.2 µm. In the paper's gel 400 µm below the surface (raw bias −7.3 µm) one step
        leaves −1.03 ± 0.13 µm, two −0.64 ± 0.11 µm, and two leave −0.44 to −0.68 µm at every
        depth from 50 to 600 µm (16 sources each; ``benchmarks/specimen_depth.py
        --calibration-steps``).
    """

    method: str = "none"
    sphere_diameter_um: float | None = None
    rays_per_particle: int | None = None
    lateral: bool = True
    steps: int = 2

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {self.method!r}")
        d = self.sphere_diameter_um
        r = self.rays_per_particle
        with raised_as(InputError):
            if d is not None and not positive_float(d, "sphere_diameter_um") < 1e4:
                raise InputError(f"sphere_diameter_um must be a number > 0 (µm), got {d!r}")
            if r is not None:
                if not isinstance(r, int):
                    raise InputError(f"rays_per_particle must be an integer >= 1000, got {r!r}")
                int_in_range(r, "rays_per_particle", 1000)
        if not isinstance(self.lateral, bool):
            raise InputError(f"lateral must be true or false, got {self.lateral!r}")
        if isinstance(self.steps, bool) or not isinstance(self.steps, int):
            raise InputError(f"steps must be an integer from 1 to 5, got {self.steps!r}")
        with raised_as(InputError):
            int_in_range(self.steps, "steps", 1, 5)

    @property
    def enabled(self) -> bool:
        return self.method != "none"


def reference_bias(
    reference_volume: np.ndarray,
    voxel_size_um: Sequence[float],
    origin_xyz_um: Sequence[float],
    positions_xyz_um: np.ndarray,
    half_box_vox: Sequence[int],
) -> np.ndarray:
    """Offsets of a reference volume's spheres from the positions they were rendered at.

    Parameters
    ----------
    reference_volume : ndarray, shape (nz, ny, nx)
        Reconstruction of spheres rendered at ``positions_xyz_um`` (:mod:`recon.reference`).
    voxel_size_um : sequence of 3 float
        ``(dz, dy, dx)`` (µm).
    origin_xyz_um : sequence of 3 float
        Position of the centre of voxel ``(0, 0, 0)`` (µm; x, y, z).
    positions_xyz_um : ndarray, shape (N, 3)
        The detected positions (µm; x, y, z).
    half_box_vox : sequence of 3 int
        The detector's patch half-size ``(hz, hy, hx)`` (voxels).

    Returns
    -------
    ndarray, shape (N, 3)
        ``localised − rendered`` (µm; x, y, z); NaN where the sphere could not be localised.
    """
    pos = np.asarray(positions_xyz_um, dtype=np.float64)
    if pos.size == 0:
        return np.zeros((0, 3))
    if pos.ndim != 2 or pos.shape[1] != 3 or not np.all(np.isfinite(pos)):
        raise InputError(f"positions must be a finite (N, 3) array (x, y, z µm), got {pos.shape}")
    org = np.asarray(origin_xyz_um, dtype=np.float64).reshape(3)
    vs = np.asarray(voxel_size_um, dtype=np.float64).reshape(3)
    seeds = ((pos - org) / vs[::-1])[:, ::-1]  # (z, y, x) voxels
    shape = np.asarray(np.shape(reference_volume))
    seeds = np.clip(seeds, 0, shape - 1)
    loc = localize(reference_volume, seeds, tuple(vs), half_box_vox=tuple(half_box_vox))
    found = org + loc.positions_vox[:, ::-1] * vs[::-1]
    off = found - pos
    off[~loc.ok] = np.nan
    return off


def apply_bias(positions_xyz_um: np.ndarray, bias_xyz_um: np.ndarray, *, lateral: bool = True):
    """Positions corrected by a :func:`reference_bias` (unknown offsets: left as detected).

    Parameters
    ----------
    positions_xyz_um, bias_xyz_um : ndarray, shape (N, 3)
        µm; x, y, z.
    lateral : bool
        Subtract x and y too (default; ``False``: z only).

    Returns
    -------
    ndarray, shape (N, 3)
        Corrected positions (µm). Their σ are those of the detection (the reference has no
        noise; its ray noise is small against it).
    """
    pos = np.asarray(positions_xyz_um, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(bias_xyz_um, dtype=np.float64).reshape(-1, 3)
    if b.shape != pos.shape:
        raise InputError(f"{b.shape[0]} offsets for {pos.shape[0]} positions")
    use = np.nan_to_num(b, nan=0.0)
    if not lateral:
        use[:, :2] = 0.0
    return pos - use


def correct_table(src, dst, bias_xyz_um: np.ndarray, *, lateral: bool = True) -> dict:
    """Write the particle table ``src`` to ``dst`` with corrected positions (σ kept).

    Returns
    -------
    dict
        What was done, for a summary: particles, corrected, mean and RMS offset (µm; x, y, z).
    """
    from .tables import _read_table, read_point_sigmas, read_points_csv, write_points_csv

    pos = read_points_csv(src)
    sig = read_point_sigmas(src)
    with open(src, encoding="utf-8") as fh:
        has_intensity = "intensity" in fh.readline().strip().split(",")
    inten = _read_table(src, ("intensity",))["intensity"] if has_intensity else None
    new = apply_bias(pos, bias_xyz_um, lateral=lateral)
    has_sigma = bool(np.any(np.isfinite(sig)))
    write_points_csv(dst, new, inten, sigma_xyz_um=sig if has_sigma else None, overwrite=True)
    b = np.asarray(bias_xyz_um, float).reshape(-1, 3)
    ok = np.all(np.isfinite(b), axis=1)
    return {
        "particles": len(pos),
        "corrected": int(ok.sum()),
        "applied_axes": "xyz" if lateral else "z",
        "mean_offset_xyz_um": np.nanmean(b[ok], axis=0).tolist() if ok.any() else None,
        "rms_offset_xyz_um": np.sqrt(np.nanmean(b[ok] ** 2, axis=0)).tolist() if ok.any() else None,
    }


__all__ = ["METHODS", "AxialCalibration", "apply_bias", "correct_table", "reference_bias"]
