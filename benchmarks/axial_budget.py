"""Error budget of the axial coordinate on a study's frames (run by hand; prints a table).

Takes the simulated frames of an ``hrvptm study`` variant (``REPORT/<variant>/dataset``:
frames, truth, white image) and, for every reconstruction setting asked for (RL iterations,
z step, s, the depth filter of the paper's Eq. 2 on/off), reconstructs the frames (cached
in ``--work``), detects the particles with the study's detection settings, and localises the
same particles with several axial estimators:

- ``radial``: the detector's 3-D radial symmetry (:func:`track.localize.localize`), on the
  reconstruction (``localize_on="input"``, the default) — what the pipeline reports;
- ``radial-dec``: the same on the secondarily deconvolved volume (``localize_on="deconvolved"``);
- ``zcen``: centroid of the axial profile through the particle's lateral core (3 × 3 voxels
  about the radial centre) above its background (the profile's median over ± 2 half boxes),
  over the samples above half the peak;
- ``zgauss``: a 1-D Gaussian + constant fit of that profile (±1 half box);
- ``zpara``: a parabola through the log-profile's peak and its two neighbours.

Per estimator it prints the pooled and worst-frame z displacement RMSD against frame 0 (the
study's metric for a translation), the mean absolute axial error, and the split of the
per-particle axial error ``e`` into its constant part (per-particle mean over frames) and its
frame-to-frame part, with the share of the latter explained by the lateral lenslet phase of
the particle (a first-harmonic fit in x and y phase) and the mean error per depth band.

The simulator calibration of that bias runs in the pipeline (``[track.axial] method =
"simulated"`` in a study: :mod:`recon.reference`, :mod:`track.axial_bias`). The
``--phase-scan`` mode isolates the reconstruction's own systematic part: noise-free spheres
rendered through ideal lenslets (no model mismatch) on the small scene, shifted across one
lenslet, per depth.

Usage::

    python benchmarks/axial_budget.py REPORT/mismatched/dataset --recon-scene scenes/medium.xml \\
        --work /tmp/ax/budget --iterations 1 3 5 10 [--z-step 5] [-s 5] [--lanczos 2 0]
    python benchmarks/axial_budget.py --phase-scan --iterations 3 10 --z-step 5 10 --work /tmp/psf
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ZFITS = ("zcen", "zgauss", "zpara")
ESTIMATORS = ("radial", "radial-dec", *ZFITS)


def _profile(vol, p_vox, hz):
    """Axial profile (sum over 3 × 3 lateral voxels) about ``p_vox`` and its z indices."""
    k, j, i = (round(float(v)) for v in p_vox)
    nz, ny, nx = vol.shape
    j0, j1 = max(j - 1, 0), min(j + 2, ny)
    i0, i1 = max(i - 1, 0), min(i + 2, nx)
    z0, z1 = max(k - 2 * hz, 0), min(k + 2 * hz + 1, nz)
    prof = vol[z0:z1, j0:j1, i0:i1].sum(axis=(1, 2)).astype(np.float64)
    return np.arange(z0, z1), prof


def z_estimates(vol, p_vox, hz):
    """Axial estimates (voxels) ``zcen, zgauss, zpara`` about the radial centre ``p_vox``."""
    from scipy.optimize import curve_fit

    zi, prof = _profile(vol, p_vox, hz)
    bg = float(np.median(prof))
    w = prof - bg
    k = int(np.argmax(np.where(np.abs(zi - p_vox[0]) <= hz, w, -np.inf)))
    peak = w[k]
    # connected run above half the peak around k
    lo = k
    while lo > 0 and w[lo - 1] > 0.5 * peak:
        lo -= 1
    hi = k
    while hi < len(w) - 1 and w[hi + 1] > 0.5 * peak:
        hi += 1
    ww = w[lo : hi + 1] - 0.5 * peak
    zcen = float(np.dot(ww, zi[lo : hi + 1]) / ww.sum()) if ww.sum() > 0 else np.nan
    near = np.abs(zi - zi[k]) <= hz
    try:
        popt, _ = curve_fit(
            lambda z, a, c, s, b: a * np.exp(-0.5 * ((z - c) / s) ** 2) + b,
            zi[near].astype(float),
            prof[near],
            p0=(peak, float(zi[k]), max(hz / 2.0, 1.0), bg),
            maxfev=2000,
        )
        zg = float(popt[1]) if abs(popt[1] - zi[k]) < hz else np.nan
    except (RuntimeError, ValueError):
        zg = np.nan
    if 0 < k < len(w) - 1 and np.all(w[k - 1 : k + 2] > 0):
        lm, l0, lp = np.log(w[k - 1 : k + 2])
        den = lm - 2 * l0 + lp
        zp = float(zi[k] + 0.5 * (lm - lp) / den) if den < 0 else np.nan
    else:
        zp = np.nan
    return zcen, zg, zp


def _match(det_xyz, truth_xyz, max_um=20.0):
    """Index of the truth particle nearest each detection (−1 beyond ``max_um``)."""
    from scipy.spatial import cKDTree

    scale = np.array([1.0, 1.0, 0.25])  # axial errors are ~10× the lateral ones
    d, idx = cKDTree(truth_xyz * scale).query(det_xyz * scale)
    return np.where(d <= max_um, idx, -1)


def analyse_frames(volumes, infos, truths, settings, lenslet_um, redeconvolve=True):
    """Detect + localise every frame; returns {estimator: (F, N_truth, 3) error arrays}."""
    from track.deconvolve import deconvolve
    from track.detect import detect_particles
    from track.localize import localize
    from track.psf_estimate import estimate_psf

    n_t = truths[0].shape[0]
    errs = {e: np.full((len(volumes), n_t, 3), np.nan) for e in ESTIMATORS}
    psf = estimate_psf(
        volumes[0],
        infos[0]["voxel_size_um"],
        n_particles=settings.psf_particles,
        box_um=settings.psf_box_um,
    )
    counts = []
    for f, (vol, info, truth) in enumerate(zip(volumes, infos, truths, strict=True)):
        vs, org = info["voxel_size_um"], info["origin_xyz_um"]
        det = detect_particles(vol, vs, settings, psf, origin_xyz_um=org)
        counts.append(det.n)
        pos = np.asarray(det.positions_um).reshape(-1, 3)
        idx = _match(pos, truth)
        hz, hy, hx = det.report.get("half_box_vox", (6, 3, 3))
        # back to voxels (z, y, x)
        p_vox = np.stack(
            [
                (pos[:, 2] - org[2]) / vs[0],
                (pos[:, 1] - org[1]) / vs[1],
                (pos[:, 0] - org[0]) / vs[2],
            ],
            axis=1,
        )
        if redeconvolve:
            dec = deconvolve(vol, psf, settings.deconvolve_settings())
            loc_dec = localize(dec, p_vox, vs, half_box_vox=(hz, hy, hx))
        for n, t in enumerate(idx):
            if t < 0:
                continue
            e = pos[n] - truth[t]
            errs["radial"][f, t] = e
            if redeconvolve and loc_dec.ok[n]:
                zd = org[2] + loc_dec.positions_vox[n, 0] * vs[0]
                errs["radial-dec"][f, t] = [e[0], e[1], zd - truth[t, 2]]
            for name, zv in zip(ZFITS, z_estimates(vol, p_vox[n], hz), strict=True):
                errs[name][f, t] = [e[0], e[1], org[2] + zv * vs[0] - truth[t, 2]]
    return errs, counts


def summarise(errs, truths, lenslet_um):
    """One table row per estimator (µm)."""
    rows = {}
    tz = truths[0][:, 2]
    for name, e in errs.items():
        if not np.isfinite(e).any():
            continue
        ez = e[:, :, 2]
        disp = ez[1:] - ez[:1]  # displacement error vs frame 0
        per_frame = np.sqrt(np.nanmean(disp**2, axis=1))
        pooled = float(np.sqrt(np.nanmean(disp**2)))
        const = np.nanmean(ez, axis=0)
        vary = ez - const
        # lenslet phase of each particle in each frame
        ph_x = 2 * np.pi * np.stack([t[:, 0] for t in truths]) / lenslet_um
        ph_y = 2 * np.pi * np.stack([t[:, 1] for t in truths]) / lenslet_um
        ok = np.isfinite(vary)
        a = np.stack([np.cos(ph_x), np.sin(ph_x), np.cos(ph_y), np.sin(ph_y)], axis=-1)[ok]
        coef, *_ = np.linalg.lstsq(a, vary[ok], rcond=None)
        expl = 1 - np.var(vary[ok] - a @ coef) / np.var(vary[ok]) if ok.sum() > 4 else np.nan
        d1 = vary[1:] * vary[:-1]
        ac1 = float(np.nansum(d1) / np.nansum(vary**2))
        low = tz < np.nanpercentile(tz, 33)
        high = tz > np.nanpercentile(tz, 67)
        rows[name] = {
            "pooled": pooled,
            "worst": float(np.nanmax(per_frame)),
            "mae": float(np.nanmean(np.abs(ez))),
            "const": float(np.sqrt(np.nanmean(const**2))),
            "vary": float(np.sqrt(np.nanmean(vary**2))),
            "phase_r2": float(expl),
            "ac1": ac1,
            "mean_low_z": float(np.nanmean(ez[:, low])),
            "mean_high_z": float(np.nanmean(ez[:, high])),
            "xy": (
                float(np.sqrt(np.nanmean((e[1:, :, 0] - e[:1, :, 0]) ** 2))),
                float(np.sqrt(np.nanmean((e[1:, :, 1] - e[:1, :, 1]) ** 2))),
            ),
        }
    return rows


def phase_scan(configs, zsets, phases_um, diameter_um, cache):
    """Noise-free axial bias of 15 µm spheres against depth and lateral lenslet phase.

    Renders (paraxial tracer, ideal lenslets, expected photon counts: no noise, no model
    mismatch) four spheres per image on the small scene, shifts them along x by
    ``phases_um``, reconstructs with each ``(iterations, z step)`` of ``configs`` (s = 5,
    depth filter on) and localises each sphere with the radial-symmetry fit on a
    ±60 µm × ±3-voxel patch about its true voxel. Prints, per depth, the mean error and its
    spread over the phases (the part that does not cancel in a translation)."""
    from lfsim import init_backend, small_optics
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.geometry import ReconGrid, depth_range
    from recon.projector import make_projector
    from recon.psf import compute_psf_bank
    from track.localize import radial_symmetry_3d

    init_backend()
    o = small_optics()
    corners = np.array([[-120, -120], [120, -120], [-120, 120], [120, 120]], float)
    corners += np.array([3.0, 7.0])
    imgs = []
    for zs in zsets:
        for ph in phases_um:
            pts = np.c_[corners + np.array([ph, 0.0]), zs]
            img = trace_paraxial(
                o,
                Sources.spheres(pts, diameter_um),
                RenderSettings(rays_per_particle=200_000, mode="expected", seed=3),
            )
            imgs.append((pts, img / 2000.0))
    print(f"{'it':>3s} {'dz':>4s} {'t s':>5s} {'z µm':>6s} {'mean':>6s} {'p-p':>5s} {'std':>5s}")
    for it, dz in configs:
        depths = depth_range(40, 460, dz)
        bank = compute_psf_bank(o, depths, 5, rays_per_pattern=50_000, cache_dir=cache)
        proj = make_projector(bank, (20, 20), "auto")
        filt = DepthFilter.for_optics(o, depths, 5)
        origin = (-o.axis_xy_px[0] * o.object_pixel_um, -o.axis_xy_px[1] * o.object_pixel_um)
        grid = ReconGrid(o.lenslet_object_um, depths, 5, (20, 20), origin)
        xs, ys, zz, vx = grid.x_um(), grid.y_um(), np.asarray(depths), grid.voxel_um
        err: dict[float, list] = {}
        t0 = time.perf_counter()
        for pts, img in imgs:
            vol = richardson_lucy(img, proj, it, depth_filter=filt, track_kl=False).volume
            for p in pts:
                i, j, k = (
                    int(np.argmin(np.abs(a - v))) for a, v in ((xs, p[0]), (ys, p[1]), (zz, p[2]))
                )
                hz = round(60 / dz)
                sub = vol[k - hz : k + hz + 1, j - 3 : j + 4, i - 3 : i + 4]
                c = radial_symmetry_3d(sub, (dz, vx, vx))
                err.setdefault(float(p[2]), []).append(zz[k - hz] + c[0] * dz - p[2])
        t = time.perf_counter() - t0
        vary = []
        for z in sorted(err):
            e = np.array(err[z])
            vary.append(e - e.mean())
            print(
                f"{it:3d} {dz:4g} {t:5.0f} {z:6.0f} {e.mean():6.2f} {np.ptp(e):5.2f} {e.std():5.2f}"
            )
        means = np.array([np.mean(err[z]) for z in err])
        print(
            f"{it:3d} {dz:4g} {t:5.0f} {'all':>6s} {np.sqrt(np.mean(means**2)):6.2f} "
            f"{'':5s} {np.sqrt(np.mean(np.concatenate(vary) ** 2)):5.2f}   (RMS of means / of the"
            " phase-varying part)",
            flush=True,
        )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, nargs="?", help="a study variant's dataset folder")
    ap.add_argument("--recon-scene", type=Path, help="reconstruction scene XML")
    ap.add_argument("--work", type=Path, help="folder for the reconstructions (PSF cache too)")
    ap.add_argument(
        "--phase-scan",
        action="store_true",
        help="noise-free spheres on the small scene against depth and lenslet phase instead",
    )
    ap.add_argument("--iterations", type=int, nargs="+", default=[3])
    ap.add_argument("--z-step", type=float, nargs="+", default=[5.0])
    ap.add_argument("-s", type=int, nargs="+", default=[5])
    ap.add_argument("--lanczos", type=float, nargs="+", default=[2.0])
    ap.add_argument("--z-range", type=float, nargs=2, default=[40.0, 460.0])
    ap.add_argument("--frames", type=int, default=None, help="use the first N frames")
    ap.add_argument(
        "--time-only",
        type=int,
        default=0,
        metavar="R",
        help="only time the reconstructions: every setting R times, interleaved, into fresh "
        "folders (PSF banks from the cache); prints seconds per frame",
    )
    ap.add_argument(
        "--no-radial-dec", action="store_true", help="skip the deconvolved-volume estimator"
    )
    ap.add_argument("--psf-box-um", type=float, nargs=3, default=[200.0, 60.0, 60.0])
    args = ap.parse_args()
    if args.phase_scan:
        configs = [(it, dz) for it in args.iterations for dz in args.z_step]
        zsets = [[120.0, 200.0, 280.0, 360.0], [160.0, 240.0, 320.0, 400.0]]
        phase_scan(configs, zsets, np.arange(0.0, 25.0, 5.0), 15.0, args.work or Path("psf"))
        return 0
    if args.dataset is None or args.recon_scene is None or args.work is None:
        ap.error("DATASET, --recon-scene and --work are needed (or --phase-scan)")

    from lfsim.scene import read_optics
    from recon.calibration import calibrate_white
    from recon.calibration_file import read_white
    from recon.pipeline import reconstruct_series
    from recon.preprocess import Preprocess
    from recon.settings import ReconSettings
    from track.detect import DetectSettings
    from track.volumes import read_volume, scan_volumes

    frames = sorted((args.dataset / "frames").glob("[0-9]*.tif"))[: args.frames]
    truths = [
        np.loadtxt(args.dataset / "truth" / f.with_suffix(".csv").name, delimiter=",", skiprows=1)[
            :, 1:4
        ]
        for f in frames
    ]
    optics = read_optics(args.recon_scene)
    grid = calibrate_white(
        read_white(args.dataset / "white.tif"), expected_pitch_px=optics.px_per_lenslet
    )
    settings = DetectSettings(psf_box_um=tuple(args.psf_box_um), threshold=0.25)

    def reconstruct(out: Path, it: int, dz: float, s: float, la: float, overwrite: bool) -> None:
        """Reconstruct the frames into ``out`` with ``it`` iterations, z step ``dz`` µm,
        ``s`` supersampling and Lanczos ``la``."""
        rs = ReconSettings(
            z_min_um=args.z_range[0],
            z_max_um=args.z_range[1],
            z_step_um=dz,
            s=s,
            iterations=it,
            lanczos_a=la,
        )
        reconstruct_series(
            frames,
            out,
            optics=optics,
            grid=grid,
            settings=rs,
            preprocess=Preprocess(background="auto"),
            overwrite=overwrite,
            progress=False,
        )

    if args.time_only:
        import shutil

        for rep in range(args.time_only):
            for it in args.iterations:
                for dz in args.z_step:
                    out = args.work / f"time_it{it}_dz{dz:g}_{rep}"
                    shutil.rmtree(out, ignore_errors=True)
                    t0, c0 = time.perf_counter(), time.process_time()
                    reconstruct(out, it, dz, args.s[0], args.lanczos[0], overwrite=False)
                    t = (time.perf_counter() - t0) / len(frames)
                    c = (time.process_time() - c0) / len(frames)
                    print(
                        f"run {rep}: {it:3d} iterations, z step {dz:g} µm: {t:7.1f} s wall, "
                        f"{c:7.1f} s CPU per frame",
                        flush=True,
                    )
        return 0
    print(
        f"{'it':>3s} {'dz':>4s} {'s':>2s} {'filt':>4s} {'t/frame s':>9s} {'n det':>10s} "
        f"{'estimator':>10s} {'pooled':>7s} {'worst':>6s} {'|e|':>5s} {'const':>6s} "
        f"{'vary':>5s} {'ac1':>5s} {'R2ph':>5s} {'e lowz':>7s} {'e highz':>7s} {'x/y disp':>11s}"
    )
    for it in args.iterations:
        for dz in args.z_step:
            for s in args.s:
                for la in args.lanczos:
                    out = args.work / f"it{it}_dz{dz:g}_s{s}_l{la:g}"
                    t0 = time.perf_counter()
                    if not (out / "recon.json").exists() or (
                        json.loads((out / "recon.json").read_text()).get("status") != "complete"
                    ):
                        reconstruct(out, it, dz, s, la, overwrite=True)
                    t_rec = (time.perf_counter() - t0) / len(frames)
                    infos = scan_volumes(out)[: len(frames)]
                    vols = [read_volume(v) for v in infos]
                    meta = [
                        {"voxel_size_um": v.voxel_size_um, "origin_xyz_um": v.origin_xyz_um}
                        for v in infos
                    ]
                    lenslet_um = json.loads((out / "recon.json").read_text())["grid"][
                        "lenslet_object_um"
                    ]
                    errs, counts = analyse_frames(
                        vols, meta, truths, settings, lenslet_um, not args.no_radial_dec
                    )
                    rows = summarise(errs, truths, lenslet_um)
                    np.savez(
                        out.parent / f"errors_{out.name}.npz",
                        truth=np.stack(truths),
                        **{k.replace("-", "_"): v for k, v in errs.items()},
                    )
                    n_txt = f"{min(counts)}-{max(counts)}/{truths[0].shape[0]}"
                    for name, r in rows.items():
                        print(
                            f"{it:3d} {dz:4g} {s:2d} {la:4g} {t_rec:9.1f} {n_txt:>10s} "
                            f"{name:>10s} {r['pooled']:7.2f} {r['worst']:6.2f} {r['mae']:5.2f} "
                            f"{r['const']:6.2f} {r['vary']:5.2f} {r['ac1']:5.2f} "
                            f"{r['phase_r2']:5.2f} "
                            f"{r['mean_low_z']:7.2f} {r['mean_high_z']:7.2f} "
                            f"{r['xy'][0]:5.2f}/{r['xy'][1]:4.2f}",
                            flush=True,
                        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
