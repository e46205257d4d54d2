"""Localisation error of the ray PSF bank on converged wave-optics light fields (run by hand).

For the microscopes of ``benchmarks/wave_reference.py`` — the paper's 4×/0.2 dry, 20×/0.5 dry,
40×/0.8 water and 60×/1.2 water (into water), each with 100 µm lenslets matched to the
objective (``f_l = M p / (2 NA)``) and 15 px per lenslet — on a small sensor of
``--lenslets`` lenslets around the optical axis:

1. **References.** Point sources at depths ``--depths`` (units of ``z₁ = p n / (2 M NA)``,
   the defocus whose geometric blur at the array is one lenslet across) and at the lateral
   positions ``--positions`` (fractions of the object-space lenslet pitch ``p / M`` from the
   centre of the on-axis lenslet) are rendered with :func:`lfsim.wave.converged_light_field`
   (sampling doubled until the light field changes by less than ``--tol``; the history is
   printed), one source per image.
2. **Reconstruction.** Each image is reconstructed by Richardson–Lucy (``recon``'s default
   settings: ``ReconSettings().iterations`` iterations, its depth filter) with (a) the ray
   bank, :func:`recon.psf.compute_psf_bank`, and (b) a wave bank of the same depths and
   ``s``, the reference's own operator: :func:`recon.psf_wave.compute_wave_psf_bank` (its
   default sampling unless ``--bank-oversample`` is given), or with ``--wave-builder local``
   :func:`lfsim.wave.pattern_stack` at ``--bank-oversample`` (4) samples per pixel,
   sparsified as the ray bank. Depth planes every ``--z-step`` z₁
   over ``±--z-range`` z₁.
3. **Localisation.** The brightest voxel within one lenslet pitch laterally and 1.5 z₁
   axially of the source, then the background-subtracted weighted centroid
   (:func:`track.localize.weighted_centroid`) of a box of ±2 voxels laterally and ±1 z₁
   axially around it. Errors: lateral ``|Δ(x, y)|`` and axial ``Δz``, RMS over the lateral
   positions.
4. **Noise.** The wave references with the paper's noise model
   (:func:`lfsim.noise.add_gaussian_noise`, ``--snr``, 8 bits), ``--seeds`` seeds,
   reconstructed with both banks (black level as the known background). σ is the RMS
   spread of the wave bank's localisations about their mean (lateral: in the plane; axial:
   along z), pooled over the lateral positions; "noisy" errors are each bank's RMS error
   against the truth over positions and seeds (spread and the bias the noise adds).

A markdown table per microscope: depth (µm and z₁), the noise-free errors of the ray and wave
banks lateral / axial and their ratios, noise σ lateral / axial and the noisy errors. Beside it, the
optics' diffraction scales: the lenslet's diffraction spot on the sensor ``λ f_l / p``
(``λ N``, ``N`` its f-number; its Airy radius is 1.22× that) in pixels, and the objective's
Airy radius at the array (``0.61 λ M / NA``) in lenslet pitches.

Usage::

    nice python benchmarks/ray_bank_error.py                         # all four microscopes
    nice python benchmarks/ray_bank_error.py --scopes 4x --quick  # a minute: 3 depths, 1 position
    nice python benchmarks/ray_bank_error.py --json out.json --markdown out.md --store DIR
    nice python benchmarks/ray_bank_error.py --scopes 4x --store DIR -s 5 --z-step 0.08
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import wave_reference
from wave_reference import PN, SCOPES, scope_record, z_unit

#: more microscopes (lenslets matched as in wave_reference), name: (M, NA, n): two dry ones
#: between the paper's and 20×/0.5 (lenslet spots λ f_l / p of 1.13 and 1.51 px), and two
#: water objectives that separate the lenslet spot from the objective's aperture angle
#: (40×/1.2 W: 1.51 px at sin θ = 0.9; 60×/0.8 W: 3.40 px at sin θ = 0.6)
EXTRA_SCOPES = {
    "10x-0.4": (10.0, 0.4, 1.0),
    "10x-0.3": (10.0, 0.3, 1.0),
    "40xW-1.2": (40.0, 1.2, wave_reference.WATER),
    "60xW-0.8": (60.0, 0.8, wave_reference.WATER),
}

#: source depths in units of z₁
DEPTHS = (0.0, 0.5, 1.0, 2.0, 3.0, -0.5, -1.0, -2.0, -3.0)
#: lateral source positions (x, y) in object-space lenslet pitches from the on-axis lenslet
POSITIONS = ((0.0, 0.0), (0.17, 0.0), (0.4, -0.27))


def make_optics(name: str, n_lenslets: int):
    """The optics of ``wave_reference.SCOPES`` or :data:`EXTRA_SCOPES`."""
    if name in EXTRA_SCOPES:
        wave_reference.SCOPES[name] = EXTRA_SCOPES[name]
    return wave_reference.make_optics(name, n_lenslets)


def diffraction_scales(optics) -> dict:
    """The optics' diffraction scales: the lenslet's diffraction spot on the sensor
    ``λ f_l / p`` (px), the objective's Airy radius at the array (lenslet pitches) and the
    lenslet's Fresnel number ``p² / (4 λ f_l)``."""
    lam = optics.wavelength_um
    return {
        "lenslet_spot_px": lam * optics.mla_focal_um / (optics.mla_pitch_um * optics.pixel_um),
        "objective_airy_lenslets": 0.61
        * lam
        * optics.magnification
        / optics.na
        / optics.mla_pitch_um,
        "lenslet_fresnel": optics.mla_pitch_um**2 / (4.0 * lam * optics.mla_focal_um),
    }


def sparse_bank(optics, depths, s: int, stacks: list[np.ndarray], radii: list[int], threshold):
    """A :class:`recon.psf.PSFBank` from dense pattern stacks (one per depth, ``(s², win, win)``,
    window radius ``radii[k]`` lenslets), sparsified as :func:`recon.psf.compute_psf_bank`."""
    from recon.psf import bank_from_patterns

    depths = np.asarray(depths, np.float64)
    images = ((k, h, stack) for k, (stack, h) in enumerate(zip(stacks, radii, strict=True)))
    return bank_from_patterns(images, depths, s, PN, threshold, optics)


def wave_bank(optics, depths, s: int, oversample, threshold: float, builder: str):
    """The wave-optics bank and its sampling: :func:`recon.psf_wave.compute_wave_psf_bank`
    (``builder="library"``; ``oversample`` None: its default sampling) or
    :func:`lfsim.wave.pattern_stack` (``"local"``; ``oversample`` None: 4)."""
    if builder == "library":
        from dataclasses import replace

        from recon import psf_wave

        ws = psf_wave.default_wave_sampling(optics)
        if oversample:
            ws = replace(ws, oversample=int(oversample))
        bank = psf_wave.compute_wave_psf_bank(
            optics,
            depths,
            s,
            sampling=ws if oversample else None,
            threshold=threshold,
            cache_dir="",
        )
        return bank, f"recon.psf_wave, oversample {ws.oversample}" + (
            "" if oversample else " (its default)"
        )
    from lfsim.wave import WaveSampling, pattern_stack
    from recon.psf import pattern_radius_lenslets

    ws = WaveSampling(oversample=int(oversample or 4), batch=2)
    stacks, radii = [], []
    for z in depths:
        h = pattern_radius_lenslets(optics, z)
        stacks.append(pattern_stack(optics, [z], s, h, ws))
        radii.append(h)
    bank = sparse_bank(optics, depths, s, stacks, radii, threshold)
    return bank, f"lfsim.wave.pattern_stack, oversample {ws.oversample}"


def stored(folder, kind: str, key, compute):
    """``compute()`` (a pair), or its result stored in ``folder`` under a hash of ``key``
    (``folder`` None: always computed)."""
    if folder is None:
        return compute()
    import hashlib
    import pickle

    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    path = Path(folder) / f"{kind}_{digest}.pkl"
    if path.is_file():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    result = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump(result, fh)
    tmp.replace(path)
    return result


def localise(vol: np.ndarray, grid, truth_xyz, z1: float) -> np.ndarray:
    """Position (x, y, z) µm of the source near ``truth_xyz`` in a reconstructed volume."""
    from track.localize import weighted_centroid

    xs, ys, zs = grid.x_um(), grid.y_um(), np.asarray(grid.depths_um)
    p = grid.lenslet_object_um
    sel_x = np.abs(xs - truth_xyz[0]) <= p
    sel_y = np.abs(ys - truth_xyz[1]) <= p
    sel_z = np.abs(zs - truth_xyz[2]) <= 1.5 * z1
    masked = np.full(vol.shape, -np.inf)
    ix = np.ix_(sel_z, sel_y, sel_x)
    masked[ix] = vol[ix]
    k, j, i = np.unravel_index(int(np.argmax(masked)), vol.shape)
    dz = max(1, round(z1 / grid.z_step_um))
    lo = (max(k - dz, 0), max(j - 2, 0), max(i - 2, 0))
    hi = (min(k + dz + 1, vol.shape[0]), min(j + 3, vol.shape[1]), min(i + 3, vol.shape[2]))
    patch = vol[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    c = weighted_centroid(patch) + np.asarray(lo)
    if not np.all(np.isfinite(c)):
        c = np.array([k, j, i], np.float64)
    return np.array(
        [
            xs[0] + c[2] * grid.voxel_um,
            ys[0] + c[1] * grid.voxel_um,
            zs[0] + c[0] * grid.z_step_um,
        ]
    )


def run_scope(name: str, args) -> dict:
    from lfsim.noise import add_gaussian_noise
    from lfsim.wave import WaveSampling, converged_light_field
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.geometry import ReconGrid
    from recon.projector import SparseProjector
    from recon.psf import compute_psf_bank
    from recon.settings import ReconSettings

    optics = make_optics(name, args.lenslets)
    z1 = z_unit(optics)
    nl = args.lenslets
    rs = ReconSettings(iterations=args.iterations) if args.iterations else ReconSettings()
    depths = z1 * np.arange(-args.z_range, args.z_range + 1e-9, args.z_step)
    depths = np.round(depths, 6)
    p_obj = optics.lenslet_object_um
    src = np.array(
        [[px * p_obj, py * p_obj, u * z1] for u in args.depths for px, py in args.positions]
    )
    out = {
        **scope_record(name, optics, z1),
        "lenslets": nl,
        "s": args.s,
        "z_step_um": float(depths[1] - depths[0]),
        "n_depths": len(depths),
        "iterations": rs.iterations,
        "snr": args.snr,
        "seeds": args.seeds,
        **diffraction_scales(optics),
    }
    t = time.perf_counter()
    ref, hist = stored(
        args.store,
        "reference",
        [name, nl, src.tolist(), args.oversample, args.tol],
        lambda: converged_light_field(
            optics, src, WaveSampling(oversample=args.oversample, batch=2), tol=args.tol
        )[::2],
    )
    out["history"] = hist
    out["seconds_reference"] = time.perf_counter() - t
    out["on_sensor"] = [float(v) for v in ref.sum(axis=(1, 2))]
    print(
        f"\n== {name}: M {optics.magnification:g}, NA {optics.na:g}, n {optics.medium_ior:g}, "
        f"f_l {optics.mla_focal_um:g} µm, z1 {z1:.4g} µm, {nl}×{nl} lenslets, s {args.s}, "
        f"{len(depths)} planes every {out['z_step_um']:.4g} µm ==\n"
        "reference convergence (oversample, change): "
        + ", ".join(f"({o}, {c:.2g})" for o, c in hist)
        + f"; {out['seconds_reference']:.0f} s",
        flush=True,
    )
    t = time.perf_counter()
    ray = compute_psf_bank(
        optics, depths, args.s, rays_per_pattern=rs.rays_per_pattern, cache_dir=args.cache
    )
    out["seconds_ray_bank"] = time.perf_counter() - t
    t = time.perf_counter()
    wave, builder = stored(
        args.store,
        "wavebank",
        [name, nl, depths.tolist(), args.s, args.bank_oversample, args.wave_builder],
        lambda: wave_bank(optics, depths, args.s, args.bank_oversample, 1e-3, args.wave_builder),
    )
    out["seconds_wave_bank"] = time.perf_counter() - t
    out["wave_bank_builder"] = builder
    print(
        f"ray bank {out['seconds_ray_bank']:.0f} s; wave bank ({builder}) "
        f"{out['seconds_wave_bank']:.0f} s",
        flush=True,
    )
    filt = DepthFilter.for_optics(optics, depths, args.s, rs.lanczos_a) if rs.lanczos_a else None
    origin = (
        -optics.axis_xy_px[0] * optics.object_pixel_um,
        -optics.axis_xy_px[1] * optics.object_pixel_um,
    )
    grid = ReconGrid(p_obj, depths, args.s, (nl, nl), origin)
    projs = {k: SparseProjector(b, (nl, nl)) for k, b in (("ray", ray), ("wave", wave))}

    def recon(img, proj, background=0.0):
        res = richardson_lucy(
            img, proj, rs.iterations, depth_filter=filt, track_kl=False, background=background
        )
        return res.volume

    scale = args.photons  # photons emitted into the cone per source (noise-free images)
    loc = {k: np.empty((len(src), 3)) for k in projs}
    noisy = {k: np.empty((len(src), args.seeds, 3)) for k in projs}
    for q, (img, truth) in enumerate(zip(ref, src, strict=True)):
        for k, proj in projs.items():
            loc[k][q] = localise(recon(img * scale, proj), grid, truth, z1)
        for seed in range(args.seeds):
            dn, info = add_gaussian_noise(img, args.snr, 1000 * q + seed)
            for k, proj in projs.items():
                vol = recon(dn.astype(np.float32), proj, background=info["offset_dn"])
                noisy[k][q, seed] = localise(vol, grid, truth, z1)
    rows = []
    npos = len(args.positions)
    for a, u in enumerate(args.depths):
        sl = slice(a * npos, (a + 1) * npos)
        truth = src[sl]
        row = {"z_units": u, "z_um": u * z1}
        for k in projs:
            d = loc[k][sl] - truth
            row[f"{k}_lat"] = float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)))
            row[f"{k}_ax"] = float(np.sqrt(np.mean(d[:, 2] ** 2)))
            row[f"{k}_ax_mean"] = float(np.mean(d[:, 2]))
            d = noisy[k][sl] - truth[:, None, :]
            row[f"noisy_{k}_lat"] = float(np.sqrt(np.mean(d[..., 0] ** 2 + d[..., 1] ** 2)))
            row[f"noisy_{k}_ax"] = float(np.sqrt(np.mean(d[..., 2] ** 2)))
        spread = noisy["wave"][sl] - noisy["wave"][sl].mean(axis=1, keepdims=True)
        row["noise_lat"] = float(np.sqrt(np.mean(spread[..., 0] ** 2 + spread[..., 1] ** 2)))
        row["noise_ax"] = float(np.sqrt(np.mean(spread[..., 2] ** 2)))
        rows.append(row)
    out["rows"] = rows
    out["localisations"] = {k: v.tolist() for k, v in loc.items()}
    out["noisy_localisations"] = {k: v.tolist() for k, v in noisy.items()}
    out["sources"] = src.tolist()
    return out


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.1f}" if b > 0 else "–"


def markdown(r: dict) -> str:
    """The table of one microscope."""
    head = (
        f"**{r['scope']}** (M {r['M']:g}, NA {r['NA']:g}, n {r['n']:g}, "
        f"f_l {r['f_lenslet_um']:g} µm, "
        f"z₁ {r['z1_um']:.4g} µm; lenslet spot λN {r['lenslet_spot_px']:.2f} px, objective "
        f"Airy radius {r['objective_airy_lenslets']:.3f} p; reference oversampling "
        + ", ".join(f"({o}, {c:.2g})" for o, c in r["history"])
        + f"; {r['lenslets']}×{r['lenslets']} lenslets, s {r['s']}, {r['n_depths']} planes every "
        f"{r['z_step_um']:.4g} µm, {r['iterations']} RL iterations; wave bank "
        f"{r['wave_bank_builder']}; noise: SNR {r['snr']:g}, {r['seeds']} seeds; errors in µm)"
        "\n\n"
    )
    lines = [
        "| z µm | z / z₁ | ray lat | ray ax | wave lat | wave ax | ray / wave lat "
        "| ray / wave ax | noise σ lat | noise σ ax | noisy ray lat | noisy ray ax "
        "| noisy wave lat | noisy wave ax |",
        "|---" * 14 + "|",
    ]
    for w in sorted(r["rows"], key=lambda w: w["z_units"]):
        vals = [w[k] for k in ("ray_lat", "ray_ax", "wave_lat", "wave_ax")]
        ratios = [_ratio(w["ray_lat"], w["wave_lat"]), _ratio(w["ray_ax"], w["wave_ax"])]
        vals2 = [
            w[k]
            for k in (
                "noise_lat",
                "noise_ax",
                "noisy_ray_lat",
                "noisy_ray_ax",
                "noisy_wave_lat",
                "noisy_wave_ax",
            )
        ]
        cells = [f"{w['z_um']:.3g}", f"{w['z_units']:g}"]
        cells += [f"{v:.3g}" for v in vals] + ratios + [f"{v:.3g}" for v in vals2]
        lines.append("| " + " | ".join(cells) + " |")
    return head + "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scopes", nargs="+", default=list(SCOPES), choices=[*SCOPES, *EXTRA_SCOPES])
    ap.add_argument("--lenslets", type=int, default=7, help="sensor width in lenslets (odd)")
    ap.add_argument("-s", type=int, default=3, help="voxels per lenslet")
    ap.add_argument("--z-step", type=float, default=0.25, help="depth step (z₁)")
    ap.add_argument("--z-range", type=float, default=4.0, help="planes over ±this (z₁)")
    ap.add_argument("--depths", type=float, nargs="+", default=list(DEPTHS), help="in z₁")
    ap.add_argument(
        "--positions",
        type=float,
        nargs="+",
        default=[v for xy in POSITIONS for v in xy],
        help="x y pairs (object-space lenslet pitches from the on-axis lenslet's centre)",
    )
    ap.add_argument("--iterations", type=int, help="RL iterations (default recon's)")
    ap.add_argument("--oversample", type=int, default=2, help="the references' first sampling")
    ap.add_argument("--tol", type=float, default=5e-3, help="the references' convergence")
    ap.add_argument(
        "--bank-oversample",
        type=int,
        help="wave bank samples per pixel (default 4; library: its own)",
    )
    ap.add_argument(
        "--wave-builder",
        choices=("library", "local"),
        default="library",
        help="wave bank from recon.psf_wave, or from lfsim.wave.pattern_stack here",
    )
    ap.add_argument("--snr", type=float, default=17.0, help="SNR of the noisy copies")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds per source")
    ap.add_argument("--photons", type=float, default=1e4, help="scale of the clean images")
    ap.add_argument("--cache", default="", help="ray-bank cache folder ('' = none)")
    ap.add_argument(
        "--store",
        type=Path,
        help="keep the references and wave banks here, keyed by microscope name and sampling "
        "(reruns reuse them; empty it after changing lfsim.wave or recon.psf_wave)",
    )
    ap.add_argument("--quick", action="store_true", help="depths 0, 1, -2 z₁ and one position")
    ap.add_argument("--json", type=Path, help="write the numbers here")
    ap.add_argument("--markdown", type=Path, help="write the tables here")
    args = ap.parse_args(argv)
    if args.lenslets % 2 == 0:
        ap.error("--lenslets must be odd (the axis on the centre lenslet)")
    if len(args.positions) % 2:
        ap.error("--positions takes x y pairs")
    args.positions = [tuple(args.positions[i : i + 2]) for i in range(0, len(args.positions), 2)]
    if args.quick:
        args.depths, args.positions, args.seeds = [0.0, 1.0, -2.0], [(0.17, 0.0)], 3
    from lfsim.backend import backend_info, init_backend

    if backend_info() is None:
        init_backend()
    results, tables = [], []
    for name in args.scopes:
        r = run_scope(name, args)
        tables.append(markdown(r))
        print("\n" + tables[-1], flush=True)
        results.append(r)
        if args.json:
            args.json.write_text(json.dumps(results, indent=1))
        if args.markdown:
            args.markdown.write_text("\n".join(tables))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
