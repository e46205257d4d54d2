"""Depths of point sources in a specimen, reconstructed with and without it (run by hand).

Particles (15 µm, as in the paper's studies) at known true depths in a specimen are rendered,
reconstructed (Richardson–Lucy with the depth-adaptive filter) and localised by the track
detector with its defaults; printed per depth: the mean and largest axial error and the
lateral error; then the axial scale (slope of found against true depth) and its error.

Set-ups (``--setup``):

- ``gel``: the paper's optics (4×/0.2 dry, f/10 lenslets) on a 20 × 20-lenslet sensor; a gel of
  index 1.35 on a 170 µm glass bottom, focused 300 µm into it; glass lenslets rendered
  through Mitsuba, ideal lenslets reconstructed (no inverse crime); true depths 50–600 µm. The
  same frames are also reconstructed as if the gel were air (``--as-air``).
- ``gel_focus_in_glass``: the same gel, with the objective focused 150 µm into the 170 µm
  glass bottom, so that the native plane lies 123 µm in front of the gel and every particle on
  one side of it, beyond the native-plane artefacts; depths 50–600 µm below the gel's surface
  (``--depths`` are then depths below the surface too), the volume from the library's guard
  planes in front of the surface (:func:`recon.settings.default_front_guard_um`, 100 µm) to
  760 µm beyond it.
- ``gel_focus_before_glass``: the same gel with the nominal focal plane 30 µm in front of the
  glass bottom (``focus_depth_um`` −200): the native plane lies 191 µm in front of the gel, so
  that a particle 50 µm below the surface lies 178 µm of apparent depth beyond it, beyond the
  150 µm docs/real_data.md ("Where to focus") asks for.
- ``water40``: a 40×/0.8 water objective into water behind a 170 µm cover glass it is
  corrected for, lenslets matched to its NA (f/25, 100 µm), true depths −15 … 15 µm; 1 µm
  particles, 3 iterations and the detection box of the 40× studies, and the bank
  ``psf_model = "auto"`` picks (wave optics at this NA), as ``recon run``.
- ``air``: the paper's optics in air, true depths 50–600 µm (the baseline of the pipeline).

Usage::

    python benchmarks/specimen_depth.py --setup gel [--as-air] [--self-calibration]
        [--calibration-steps 1] [-s 5]
        [--iterations 8] [--per-depth 16] [--repeats 4] [--depths 50 100]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lfsim.optics import WATER_40X_OPTICS

SETUPS = {
    "gel": {
        "optics": {
            "medium_ior": 1.35,
            "coverslip_thickness_um": 170.0,
            "coverslip_ior": 1.523,
            "focus_depth_um": 300.0,
        },
        "depths": np.arange(50.0, 601.0, 50.0),
        "z_range": (0.0, 660.0, 5.0),
    },
    "gel_focus_in_glass": {
        "optics": {
            "medium_ior": 1.35,
            "coverslip_thickness_um": 170.0,
            "coverslip_ior": 1.523,
            "focus_depth_um": -150.0,
        },
        "depths_below_surface": np.arange(50.0, 601.0, 50.0),
        "z_range_from_surface": (0.0, 760.0, 5.0),
    },
    "gel_focus_before_glass": {
        "optics": {
            "medium_ior": 1.35,
            "coverslip_thickness_um": 170.0,
            "coverslip_ior": 1.523,
            "focus_depth_um": -200.0,
        },
        "depths_below_surface": np.arange(50.0, 601.0, 50.0),
        "z_range_from_surface": (0.0, 760.0, 5.0),
    },
    "air": {"optics": {}, "depths": np.arange(50.0, 601.0, 50.0), "z_range": (0.0, 660.0, 5.0)},
    "water40": {
        "optics": WATER_40X_OPTICS,
        "depths": np.arange(-15.0, 15.1, 3.0),
        "z_range": (-20.0, 20.0, 0.5),
        # The whole reconstructed range is 40 µm deep: a match must be nearer than that.
        "match_axial_um": 10.0,
        # As the 40× studies (scenes/experiments/water40x_translation_z_test.toml): 1 µm
        # particles, 3 iterations, their detection box and threshold.
        "diameter_um": 1.0,
        "iterations": 3,
        "rays": 50_000,
        "detect": {"psf_box_um": (8.0, 6.0, 6.0), "threshold": 0.25},
    },
}


def _localise(vol, grid, depths, pts, s, axial_um=60.0, detect=None):
    """Detections of the track detector (its defaults, as ``track run``) matched to the points
    (nearest within 0.8 lenslet laterally, 20 µm with the paper's optics, and ``axial_um`` in
    depth; NaN where none)."""
    from track.detect import DetectSettings, detect_particles

    vox = grid.voxel_um
    x0, y0 = grid.x_um()[0], grid.y_um()[0]
    det = detect_particles(
        vol,
        (depths[1] - depths[0], vox, vox),
        origin_xyz_um=(x0, y0, depths[0]),
        lenslet_period_vox=s,
        settings=DetectSettings(**(detect or {})),
    )
    xyz = np.asarray(det.positions_um)
    out = np.full((len(pts), 3), np.nan)
    for k, p in enumerate(pts):
        if len(xyz) == 0:
            break
        d = xyz - p
        ok = (np.hypot(d[:, 0], d[:, 1]) < 0.8 * grid.lenslet_object_um) & (
            np.abs(d[:, 2]) < axial_um
        )
        if ok.any():
            out[k] = xyz[np.flatnonzero(ok)[np.argmin(np.sum(d[ok] ** 2, axis=1))]]
    return out


def _self_calibrated(found, model, proj, filt, grid, depths, args):
    """``found`` less the bias of noise-free model spheres (NaN rows kept): measured at
    ``found``, then at the positions each step corrected them to (``--calibration-steps``,
    ``[track.axial] steps``)."""
    from recon.deconvolve import richardson_lucy
    from recon.reference import ReferenceSettings, render_reference

    ok = np.isfinite(found[:, 2])
    if not ok.any():
        return found
    at = found[ok]
    for _ in range(args.calibration_steps):
        ref = render_reference(
            at, model, ReferenceSettings(sphere_diameter_um=args.diameter_um, black_level=0.0)
        )
        vol = richardson_lucy(ref.astype(np.float32), proj, args.iterations, depth_filter=filt)
        found_ref = _localise(vol.volume, grid, depths, at, args.s, args.match_um, args.detect)
        bias = np.nan_to_num(found_ref - at)
        at = found[ok] - bias
    out = found.copy()
    out[ok] = at
    return out


def main() -> int:
    from hrvbase.cli import add_flags
    from track.axial_bias import AxialCalibration

    default_steps = AxialCalibration().steps
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setup", choices=sorted(SETUPS), default="gel")
    add_flags(
        ap,
        {
            "--as-air": "reconstruct as if the specimen were air",
            "--each": "print every source's axial error (and, with the self-calibration, "
            "before it)",
            "--ideal-render": "render through ideal lenslets, the model's own (isolates what "
            "the glass lenslets add)",
            "--self-calibration": "subtract the reconstruction's bias measured on noise-free "
            "spheres rendered through the model at the detections (recon.reference, as "
            "[track.axial])",
        },
    )
    ap.add_argument(
        "--depths", type=float, nargs="+", help="true depths (µm) instead of the set-up's"
    )
    ap.add_argument(
        "--z-range",
        type=float,
        nargs=3,
        metavar=("Z0", "Z1", "DZ"),
        help="reconstructed depths (µm) instead of the set-up's: first, last, step; a "
        "particle's reconstruction is ~1.4 × 100 µm long in a gel, so the volume must reach "
        "that far beyond the shallowest and deepest sources",
    )
    ap.add_argument(
        "--calibration-steps",
        type=int,
        default=default_steps,
        help=f"fixed-point steps of the self-calibration (default: [track.axial] steps, "
        f"{default_steps})",
    )
    ap.add_argument("-s", type=int, default=5)
    ap.add_argument(
        "--iterations", type=int, help="Richardson-Lucy iterations (default: the set-up's, or 8)"
    )
    ap.add_argument("--rays", type=int, help="rays per source (default: the set-up's, or 400 000)")
    ap.add_argument(
        "--per-depth",
        type=int,
        default=4,
        help="sources per depth, on a square grid over the central 70 %% of the field with a "
        "random position within their lenslets (default 4; the standard error of a depth's "
        "mean falls as 1/sqrt of it)",
    )
    ap.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="frames per depth, each with the sources jittered anew within their lenslets and "
        "its own noise seed (default 1; sources per depth = repeats x per-depth)",
    )
    ap.add_argument(
        "--diameter-um",
        type=float,
        help="source and reference sphere diameter (µm; default: the set-up's, or 15)",
    )
    args = ap.parse_args()

    from dataclasses import replace

    from lfsim import init_backend, small_optics
    from lfsim.scene import load_scene, write_scene
    from lfsim.tracer import RenderSettings, Sources, trace_mitsuba
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.geometry import ReconGrid, depth_range
    from recon.projector import LightFieldProjector
    from recon.psf import compute_psf_bank
    from recon.psf_wave import choose_psf_model, compute_wave_psf_bank
    from recon.settings import default_front_guard_um

    init_backend()
    setup = SETUPS[args.setup]
    o = small_optics(**setup["optics"], mla_kind="ideal" if args.ideal_render else "glass")
    import tempfile

    scene = load_scene(write_scene(o, tempfile.mkdtemp() + "/scene.xml"))
    model = replace(o, mla_kind="ideal")
    if args.as_air:
        model = replace(model, medium_ior=model.immersion_ior, coverslip_thickness_um=0.0)
    # Depths below the specimen's surface where the set-up gives them so: z = surface + depth.
    z_surface = o.surface_z_um if "depths_below_surface" in setup else 0.0
    if "z_range_from_surface" in setup:
        r0, r1, rdz = setup["z_range_from_surface"]
        at_surface = np.ceil(z_surface / rdz) * rdz
        first = at_surface + r0
        if model.has_interfaces:  # the library's guard planes in front of the surface
            first -= default_front_guard_um(model, rdz)
        setup = {**setup, "z_range": (first, at_surface + r1, rdz)}
    z0, z1, dz = args.z_range or setup["z_range"]
    args.match_um = setup.get("match_axial_um", 60.0)
    args.detect = setup.get("detect")
    for name, default in (("iterations", 8), ("rays", 400_000), ("diameter_um", 15.0)):
        if getattr(args, name) is None:
            setattr(args, name, setup.get(name, default))
    depths = depth_range(z0, z1, dz)
    t0 = time.perf_counter()
    if choose_psf_model(model) == "wave":  # as recon run's psf_model = "auto"
        bank = compute_wave_psf_bank(model, depths, args.s, progress=True)
    else:
        bank = compute_psf_bank(model, depths, args.s, rays_per_pattern=100_000, progress=True)
    proj = LightFieldProjector(bank, (20, 20))
    filt = DepthFilter.for_optics(model, depths, args.s)
    origin = (-o.axis_xy_px[0] * o.object_pixel_um, -o.axis_xy_px[1] * o.object_pixel_um)
    grid = ReconGrid(o.lenslet_object_um, depths, args.s, (20, 20), origin)
    rng = np.random.default_rng(7)
    print(
        f"setup {args.setup}{' reconstructed as air' if args.as_air else ''}"
        f"{' with the self-calibration' if args.self_calibration else ''}"
        f"{f' ({args.calibration_steps} steps)' if args.calibration_steps > 1 else ''}"
        ": native plane "
        f"{o.native_plane_depth_um:.1f} µm below the surface (focal shift "
        f"{o.focal_shift_um:.1f} µm), axial scale {o.axial_scale:.4f}; s = {args.s}, "
        f"z step {dz} µm, {args.iterations} iterations"
    )
    print(f"{'true z µm':>9s} {'ax mean':>8s} {'± s.e.':>6s} {'ax max':>7s} {'lat max':>8s}")
    true_z, found_z = [], []
    half = 0.35 * min(np.ptp(grid.x_um()), np.ptp(grid.y_um()))
    given = args.depths or setup.get("depths_below_surface", setup.get("depths"))
    for z in z_surface + np.asarray(given, float):
        side = max(2, int(np.ceil(np.sqrt(args.per_depth))))
        ticks = (
            np.linspace(-half, half, side + 2)[1:-1] if side > 2 else np.array([-1, 1]) * half / 2
        )
        cells = np.array([[x, y] for y in ticks for x in ticks])[: args.per_depth]
        errs, raws = [], []
        for rep in range(args.repeats):
            xy = cells + rng.uniform(-0.5, 0.5, cells.shape) * o.lenslet_object_um
            pts = np.c_[xy, np.full(len(xy), z)]
            settings = RenderSettings(
                rays_per_particle=args.rays,
                mode="expected",
                seed=round(abs(z) * 10) + (z < 0) + 100_003 * rep,
            )
            img = trace_mitsuba(scene, Sources.spheres(pts, args.diameter_um), settings)
            vol = richardson_lucy(img.astype(np.float32), proj, args.iterations, depth_filter=filt)
            # Reconstructed as air, a particle lies about 26 % of its depth too shallow.
            window = args.match_um + (0.4 * abs(z) if args.as_air else 0.0)
            found = _localise(vol.volume, grid, depths, pts, args.s, window, args.detect)
            raws.append(found - pts)
            if args.self_calibration:
                found = _self_calibrated(found, model, proj, filt, grid, depths, args)
            errs.append(found - pts)
        err = np.concatenate(errs)
        ok = np.isfinite(err[:, 2])
        true_z += [z] * int(ok.sum())
        found_z += list(z + err[ok, 2])
        sem = (
            np.nanstd(err[:, 2], ddof=1) / np.sqrt(max(int(ok.sum()), 1))
            if ok.sum() > 1
            else np.nan
        )
        print(
            f"{z:9.1f} {np.nanmean(err[:, 2]):+8.2f} {sem:6.2f} "
            f"{np.nanmax(np.abs(err[:, 2])):7.2f} {np.nanmax(np.abs(err[:, :2])):8.2f} "
            f"{int(ok.sum())}/{len(err)} found",
            flush=True,
        )
        if args.each:
            print("    axial errors (µm): " + " ".join(f"{e:+.1f}" for e in err[:, 2]), flush=True)
            if args.self_calibration:
                raw = np.concatenate(raws)[:, 2]
                print("    before the self-calibration: " + " ".join(f"{e:+.1f}" for e in raw))
    if len(set(true_z)) < 2:
        print(f"one depth: no axial scale; {time.perf_counter() - t0:.0f} s")
        return 0
    (slope, icept), cov = np.polyfit(true_z, found_z, 1, cov=True)
    print(
        f"axial scale (found / true): {slope:.4f} ({100 * (slope - 1):+.2f} ± "
        f"{100 * np.sqrt(cov[0, 0]):.2f} %), offset {icept:+.2f} µm; "
        f"{time.perf_counter() - t0:.0f} s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
