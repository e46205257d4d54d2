"""Localisation error of reconstructed point sources against depth (run by hand).

Point sources at known positions in the small test scene (20 × 20 lenslets, paper optics),
one depth per light-field image, are reconstructed (Richardson–Lucy with the depth-adaptive
filter); the brightest voxel near each source is compared with the truth. Printed per depth:
lateral and axial error (mean and max) and, for comparison, the lateral resolution limit of
the paper's Eq. 2, ``1 / ν(z) = 0.94 λ M |z| / p`` (valid for ``|z| ≥ p² / (2 M² λ)``).
Four sources per image, 200 µm apart.

Usage::

    python benchmarks/recon_depth_error.py [-s 5] [--z-step 5] [--iterations 8]
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-s", type=int, default=5)
    ap.add_argument("--z-step", type=float, default=5.0)
    ap.add_argument("--iterations", type=int, default=8)
    args = ap.parse_args()

    from lfsim import init_backend, small_optics
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.geometry import ReconGrid, depth_range
    from recon.projector import LightFieldProjector
    from recon.psf import compute_psf_bank

    init_backend()
    o = small_optics()
    depths = depth_range(-80, 720, args.z_step)
    bank = compute_psf_bank(o, depths, args.s, rays_per_pattern=100_000, progress=True)
    proj = LightFieldProjector(bank, (20, 20))
    filt = DepthFilter.for_optics(o, depths, args.s)
    origin = (-o.axis_xy_px[0] * o.object_pixel_um, -o.axis_xy_px[1] * o.object_pixel_um)
    grid = ReconGrid(o.lenslet_object_um, depths, args.s, (20, 20), origin)
    xs, ys = grid.x_um(), grid.y_um()
    rng = np.random.default_rng(7)
    z_alias = o.mla_pitch_um**2 / (2 * o.magnification**2 * o.wavelength_um)
    print(
        f"s = {args.s} ({grid.voxel_um:.2f} µm voxels), z step {args.z_step} µm, "
        f"{args.iterations} iterations; Eq. 2 holds for |z| >= {z_alias:.0f} µm"
    )
    print(
        f"{'z µm':>6s} {'lat mean':>9s} {'lat max':>8s} {'ax mean':>8s} {'ax max':>7s} "
        f"{'(voxels / z-steps)':>19s} {'Eq.2 1/ν µm':>12s}"
    )
    for z in np.arange(-80.0, 721.0, 40.0):
        # Sources 200 µm apart (farther than any search window), jittered off the voxel grid.
        corners = np.array([[-100, -100], [100, -100], [-100, 100], [100, 100]], float)
        xy = corners + rng.uniform(-12.5, 12.5, corners.shape)
        pts = np.c_[xy, np.full(len(xy), z)]
        img = trace_paraxial(
            o, Sources.spheres(pts, 0.0), RenderSettings(rays_per_particle=200_000, mode="expected")
        )
        vol = richardson_lucy(
            img / 2000.0, proj, args.iterations, depth_filter=filt, track_kl=False
        ).volume
        lat, ax = [], []
        for p in pts:
            i = int(np.argmin(np.abs(xs - p[0])))
            j = int(np.argmin(np.abs(ys - p[1])))
            k = int(np.argmin(np.abs(depths - p[2])))
            w = 2 * args.s  # ±50 µm laterally, ±60 µm axially: one source per window
            dk = round(60 / args.z_step)
            lo = (max(k - dk, 0), max(j - w, 0), max(i - w, 0))
            sub = vol[lo[0] : k + dk + 1, lo[1] : j + w + 1, lo[2] : i + w + 1]
            kk, jj, ii = np.add(np.unravel_index(np.argmax(sub), sub.shape), lo)
            lat.append(np.hypot(xs[ii] - p[0], ys[jj] - p[1]) / grid.voxel_um)
            ax.append(abs(depths[kk] - p[2]) / args.z_step)
        nu = 0.94 * o.wavelength_um * o.magnification * abs(z) / o.mla_pitch_um
        print(
            f"{z:6.0f} {np.mean(lat):9.2f} {np.max(lat):8.2f} {np.mean(ax):8.2f} "
            f"{np.max(ax):7.2f} {'':>19s} {nu:12.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
