"""Particle detection across reconstruction settings and microscopes.

A handful of seeded particles (well apart, away from the faces) is rendered through ideal
lenslets (:func:`lfsim.tracer.trace_paraxial`, expected photon counts), Gaussian noise of a
given SNR is added (:func:`lfsim.noise.add_gaussian_noise`: SNR = P99.9 of the clean image /
σ), the background is subtracted as ``recon run`` does (:func:`recon.preprocess.prepare_image`)
and the image is reconstructed with Richardson–Lucy (``iterations``, ``s``, ``z_step_um``, the
depth-adaptive filter on or off); :func:`track.detect.detect_particles` with its default
settings then runs on the volume, given its lenslet period ``s`` as ``track``'s pipeline
gives it from ``recon.json``. A detection *matches* a true particle when it lies within
half the particle spacing laterally and ``axial_tol`` axially (one particle per detection at
most); every other detection is *spurious*. Every setting is also reconstructed and detected
without particles (same optics, noise σ, black level and noise seed: the particle image's
P99.9 / SNR sets σ): its detections are the ``noise`` column (``noise_spurious``; skip it with
``--no-noise``).

Two microscopes: the paper's (4×/0.2, 100 µm / f 1000 µm lenslets, 15 px per lenslet, 15 µm
particles) and a 10×/0.3 one (150 µm / f 2500 µm lenslets, 11 px per lenslet, 6 µm
particles), both on a small sensor (12 × 12 lenslets).

The settings grid is a sparse design over iterations {1, 3, 10, 20}, s {3, 5, 15}, z step
{2, 5, 10} µm, filter {on, off} and SNR {5, 20, 90}: every level of every factor occurs, every
pair of iterations and s, and each of iterations × SNR, without the full product (:data:`GRID`,
:data:`QUICK` for the default test tier).

Usage::

    python benchmarks/detect_sweep.py [--microscope paper 10x] [--seed 2] [--quick] [--no-noise]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

#: (iterations, s, z_step_um, depth filter, SNR): a sparse design. Each iteration count meets
#: each s, the filter on and off, and (over the list) every SNR and z step; the finest depth
#: step is not combined with the largest s (a PSF bank of 141 depths × 225 sub-positions
#: would dominate the run time).
GRID = (
    (1, 3, 2.0, True, 90.0),
    (1, 5, 5.0, False, 5.0),
    (1, 15, 10.0, True, 20.0),
    (3, 3, 5.0, True, 20.0),
    (3, 5, 10.0, True, 90.0),
    (3, 15, 5.0, False, 5.0),
    (10, 3, 10.0, False, 5.0),
    (10, 5, 2.0, True, 20.0),
    (10, 15, 5.0, True, 90.0),
    (20, 3, 2.0, False, 90.0),
    (20, 5, 10.0, True, 5.0),
    (20, 15, 10.0, True, 20.0),
)
#: The reduced grid of the default test tier: the extremes of iterations and SNR.
QUICK = (
    (1, 5, 5.0, False, 5.0),
    (10, 5, 2.0, True, 20.0),
    (20, 3, 2.0, False, 90.0),
    (20, 5, 10.0, True, 5.0),
)


@dataclass(frozen=True)
class Microscope:
    """A microscope of the sweep: optics, particle diameter, particle and volume depths."""

    name: str
    optics: object
    particle_um: float
    z_particles_um: tuple[float, float]
    z_volume_um: tuple[float, float]


def microscopes(n_lenslets: int = 12) -> dict[str, Microscope]:
    """The paper's optics and a 10×/0.3 one on ``n_lenslets²``-lenslet sensors."""
    from lfsim.optics import Optics, paper_optics

    paper = paper_optics(sensor_xy_px=(15 * n_lenslets, 15 * n_lenslets))
    # 10×/0.3: image-side NA 0.03 matched by f/16.7 lenslets of 150 µm; 11 px per lenslet
    ten = Optics(
        na=0.3,
        f_objective_um=20_000.0,
        f_tube_um=200_000.0,
        mla_pitch_um=150.0,
        mla_focal_um=2500.0,
        pixel_um=150.0 / 11.0,
        sensor_xy_px=(11 * n_lenslets, 11 * n_lenslets),
    )
    return {
        "paper": Microscope("paper", paper, 15.0, (150.0, 250.0), (60.0, 340.0)),
        "10x": Microscope("10x", ten, 6.0, (60.0, 110.0), (20.0, 150.0)),
    }


def seed_particles(m: Microscope, n: int, seed: int) -> np.ndarray:
    """``n`` particles (x, y, z µm) at least 3 lenslets apart laterally, 2 lenslet footprints
    inside the field's edges."""
    from track.synthetic import poisson_disc_cloud

    o = m.optics
    p = o.lenslet_object_um
    nx = o.sensor_xy_px[0] / o.px_per_lenslet
    half = 0.5 * nx * p - 2.0 * p
    # the lateral spacing matters (the axial images are long): spread in x, y, then draw z
    xy = poisson_disc_cloud(n, [(-half, half), (-half, half), (0.0, 1e-3)], 3.0 * p, seed=seed)
    z = np.random.default_rng(seed + 100).uniform(*m.z_particles_um, n)
    return np.c_[xy[:, :2], z]


_BANKS: dict = {}


def _projector(o, depths, s):
    from recon.projector import make_projector
    from recon.psf import compute_psf_bank

    key = (repr(o), tuple(depths), s)
    if key not in _BANKS:
        bank = compute_psf_bank(o, depths, s, rays_per_pattern=20_000)
        n = round(o.sensor_xy_px[0] / o.px_per_lenslet)
        _BANKS[key] = make_projector(bank, (n, n))
    return _BANKS[key]


def render(m: Microscope, xyz_um, snr, seed) -> tuple[np.ndarray, np.ndarray]:
    """The noisy particle image (12-bit DN) and the same noise without particles.

    The noise σ is set from the particle image (:func:`lfsim.noise.add_gaussian_noise`: its
    P99.9 / SNR); the particle-free image has that σ, black level and noise realisation
    (same seed), so that its reconstruction holds exactly the noise of the particle case."""
    from lfsim.noise import add_gaussian_noise
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    clean = trace_paraxial(
        m.optics,
        Sources.spheres(xyz_um, m.particle_um),
        RenderSettings(rays_per_particle=100_000, mode="expected", seed=seed),
    )
    noisy, info = add_gaussian_noise(clean.astype(np.float64), snr, seed, bit_depth=12)
    # the draws add_gaussian_noise made (a generator seeded alike), on the black level alone
    noise = np.random.default_rng(seed).normal(0.0, info["sigma_dn"], size=clean.shape)
    full = 2 ** info["bit_depth"] - 1
    blank = np.clip(np.rint(info["offset_dn"] + noise), 0, full).astype(noisy.dtype)
    return noisy, blank


def reconstruct_image(m: Microscope, image, iterations, s, z_step_um, depth_filter):
    """Subtract the background and reconstruct one image; returns ``(volume, voxel_size_um,
    origin_xyz_um)``."""
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.geometry import ReconGrid, depth_range
    from recon.preprocess import prepare_image

    o = m.optics
    depths = depth_range(*m.z_volume_um, z_step_um)
    proj = _projector(o, depths, s)
    img, _ = prepare_image(image)
    filt = DepthFilter.for_optics(o, depths, s) if depth_filter else None
    vol = richardson_lucy(img, proj, iterations, depth_filter=filt, track_kl=False).volume
    n = round(o.sensor_xy_px[0] / o.px_per_lenslet)
    origin = (-o.axis_xy_px[0] * o.object_pixel_um, -o.axis_xy_px[1] * o.object_pixel_um)
    grid = ReconGrid(o.lenslet_object_um, depths, s, (n, n), origin)
    return (
        np.asarray(vol, dtype=np.float32),
        grid.voxel_size_um,
        (float(grid.x_um()[0]), float(grid.y_um()[0]), float(depths[0])),
    )


def reconstruct(m: Microscope, xyz_um, iterations, s, z_step_um, depth_filter, snr, seed):
    """Render, add noise and reconstruct; returns ``(volume, voxel_size_um, origin_xyz_um)``."""
    noisy, _ = render(m, xyz_um, snr, seed)
    return reconstruct_image(m, noisy, iterations, s, z_step_um, depth_filter)


def score(truth_um, found_um, lateral_tol_um, axial_tol_um) -> tuple[int, int]:
    """``(matched, spurious)``: one-to-one matches within the tolerances."""
    if len(found_um) == 0:
        return 0, 0
    d_lat = np.linalg.norm(truth_um[:, None, :2] - found_um[None, :, :2], axis=2)
    d_ax = np.abs(truth_um[:, None, 2] - found_um[None, :, 2])
    ok = (d_lat <= lateral_tol_um) & (d_ax <= axial_tol_um)
    cost = np.where(ok, d_lat / lateral_tol_um + d_ax / axial_tol_um, 1e6)
    r, c = linear_sum_assignment(cost)
    matched = int(ok[r, c].sum())
    return matched, len(found_um) - matched


def run_case(
    m: Microscope, setting, seed: int, n_particles: int = 6, settings=None, noise: bool = True
) -> dict:
    """One row of the table: ``n_true, n_detected, n_matched, spurious, rejected`` (by
    reason), ``noise_spurious`` (detections in the particle-free reconstruction of the same
    setting, noise σ and noise seed; None with ``noise=False``), and the seconds spent
    (``recon_s``: PSF bank, rendering and both reconstructions; ``detect_s``: both
    detections)."""
    from track.detect import detect_particles

    iterations, s, z_step, filt, snr = setting
    xyz = seed_particles(m, n_particles, seed)
    t0 = time.perf_counter()
    noisy, blank = render(m, xyz, snr, seed)
    vol, spacing, origin = reconstruct_image(m, noisy, iterations, s, z_step, filt)
    vol0 = reconstruct_image(m, blank, iterations, s, z_step, filt)[0] if noise else None
    t1 = time.perf_counter()
    # the lenslet period recon records (recon.json grid.s; the volume starts at a lenslet
    # corner, phase 0), as track's pipeline passes it on (track.volumes.VolumeInfo)
    det = detect_particles(vol, spacing, settings, origin_xyz_um=origin, lenslet_period_vox=s)
    p = m.optics.lenslet_object_um
    matched, spurious = score(xyz, det.positions_um, 1.0 * p, 4.0 * m.particle_um)
    noise_spurious = None
    if vol0 is not None:
        det0 = detect_particles(vol0, spacing, settings, origin_xyz_um=origin, lenslet_period_vox=s)
        noise_spurious = det0.n
    return {
        "microscope": m.name,
        "iterations": iterations,
        "s": s,
        "z_step_um": z_step,
        "filter": filt,
        "snr": snr,
        "n_true": len(xyz),
        "n_detected": det.n,
        "n_matched": matched,
        "spurious": spurious,
        "noise_spurious": noise_spurious,
        "rejected": dict(det.report.get("rejections", {})),
        "recon_s": t1 - t0,
        "detect_s": time.perf_counter() - t1,
    }


def setting_id(setting) -> str:
    """Short name of a grid setting (test ids)."""
    it, s, dz, filt, snr = setting
    return f"it{it}-s{s}-dz{dz:g}-{'filt' if filt else 'nofilt'}-snr{snr:g}"


def format_row(r: dict) -> str:
    rej = ", ".join(f"{k} {v}" for k, v in sorted(r["rejected"].items()) if v) or "-"
    noise = "-" if r.get("noise_spurious") is None else str(r["noise_spurious"])
    return (
        f"{r['microscope']:>6s} {r['iterations']:>4d} {r['s']:>3d} {r['z_step_um']:>5.0f} "
        f"{'on' if r['filter'] else 'off':>6s} {r['snr']:>4.0f} | {r['n_true']:>4d} "
        f"{r['n_detected']:>5d} {r['n_matched']:>5d} {r['spurious']:>5d} {noise:>5s} | "
        f"{r['recon_s']:>5.1f} {r['detect_s']:>5.1f} | {rej}"
    )


HEADER = (
    f"{'optics':>6s} {'iter':>4s} {'s':>3s} {'dz':>5s} {'filter':>6s} {'SNR':>4s} | "
    f"{'true':>4s} {'found':>5s} {'match':>5s} {'spur':>5s} {'noise':>5s} | "
    f"{'rec s':>5s} {'det s':>5s} | "
    "rejected (reason count)"
)


def main(argv=None) -> int:
    # this checkout's packages, not an installed copy
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--microscope", nargs="+", default=["paper", "10x"])
    ap.add_argument(
        "--seed", type=int, default=2, help="scene seed (report on a seed not tuned on)"
    )
    ap.add_argument("--particles", type=int, default=6)
    ap.add_argument("--quick", action="store_true", help="the reduced grid of the test tier")
    ap.add_argument(
        "--no-noise",
        action="store_true",
        help="skip the particle-free reconstruction of every setting (noise column '-')",
    )
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    from lfsim import init_backend

    init_backend()
    ms = microscopes()
    print(HEADER)
    total = [0, 0, 0, 0, 0]
    for name in args.microscope:
        for setting in QUICK if args.quick else GRID:
            r = run_case(ms[name], setting, args.seed, args.particles, noise=not args.no_noise)
            print(format_row(r), flush=True)
            total = [
                a + b
                for a, b in zip(
                    total,
                    (
                        r["n_true"],
                        r["n_detected"],
                        r["n_matched"],
                        r["spurious"],
                        r["noise_spurious"] or 0,
                    ),
                    strict=True,
                )
            ]
    print(
        f"total: {total[0]} true, {total[1]} detected, {total[2]} matched, {total[3]} spurious"
        + ("" if args.no_noise else f"; {total[4]} in the particle-free volumes")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
