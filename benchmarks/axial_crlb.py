"""The best depth precision the optics allow, in a gel and in air (run by hand).

The Cramér–Rao bound on a point source's depth, from its light field alone: with the
forward model ``I(z)`` (one source's pattern on the sensor) and noise of standard deviation
``σ`` on every pixel, no unbiased estimator of ``z`` has a standard deviation below

    CRLB_z = 1 / sqrt( Σ_pixels (∂I/∂z)² / σ² ).

Two noise models: **read noise** ``σ = peak / SNR`` (the studies' Gaussian model: the SNR is
set on the image's brightest pixels, so a dimmer specimen is not penalised) and **shot noise**
``σ² = I`` per emitted photon (Poisson; the gel's smaller collection solid angle, which the
read-noise model normalises away, then counts too).

A source in air at depth ``d`` (µm from the native object plane) is compared with a source in
the gel at the same *apparent* depth (true depth ``d / axial_scale``), so that both light fields
have the same shape and only the scale of depth differs, and with one at the same true depth
``d`` (how ``fig5b_axial_layer_gel`` and ``fig6c_simple_shear_gel`` pair with their air
studies). Geometrically (parallax ∝ ``tan θ``, which
the gel shrinks by ``n_air / n_gel``) the ratio of the two bounds is ``1 / axial_scale``
(1.36 at the paper's 0.2 NA into a gel of index 1.35): a depth in a gel cannot be measured as
precisely, in true µm, as the same particle's depth in air, whatever the reconstruction.

The patterns are the wave-optics bank's (:func:`recon.psf_wave.compute_wave_psf_bank`,
deterministic, so finite differences ``(I(z + h) − I(z − h)) / 2h`` are exact to ``O(h²)``),
without a threshold, averaged over ``s × s`` source positions within a lenslet (the bound of
each, then their root mean square). The paper's optics (4×/0.2 dry, f/10 lenslets); the gel is
the paper's specimen (n = 1.35 on a 170 µm glass bottom, focused 200 µm in, as in
``scenes/paper_4x_gel.xml``).

Then the studies' geometry, gel against air: the worst step of ``fig5b_axial_layer`` (a layer
moved from 160 to 660 µm in 20 µm steps, each step's displacement from the first frame) and
the z displacements of ``fig6c_simple_shear`` (particles 100–400 µm deep); by default the gel's
at the same true depths, with ``--gel-layer`` and ``--gel-box`` where its study puts them
(``fig5b_axial_layer_gel``: 220 → 720 µm; ``fig6c_simple_shear_gel``: 210–510 µm).

Usage::

    python benchmarks/axial_crlb.py [--depths 100 160 300 500 660] [--s 3] [--snr 17] [--step 2]
    python benchmarks/axial_crlb.py --depths 160 --gel-layer 220 720 20 --gel-box 210 510
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lfsim.optics import paper_optics

GEL = {
    "medium_ior": 1.35,
    "coverslip_thickness_um": 170.0,
    "coverslip_ior": 1.523,
    "focus_depth_um": 200.0,
}


def _dense(bank, channels) -> list[np.ndarray]:
    """The patterns of ``channels`` on one common pixel grid (float64)."""
    parts = [bank.pattern(c) for c in channels]
    y0 = min(int(dy.min()) for dy, _, _ in parts)
    x0 = min(int(dx.min()) for _, dx, _ in parts)
    ny = max(int(dy.max()) for dy, _, _ in parts) - y0 + 1
    nx = max(int(dx.max()) for _, dx, _ in parts) - x0 + 1
    out = []
    for dy, dx, w in parts:
        img = np.zeros((ny, nx))
        img[dy - y0, dx - x0] = w
        out.append(img)
    return out


def bounds(optics, z_um: float, s: int, step_um: float, snr: float, sampling) -> dict:
    """Root-mean-square CRLB on ``z`` (µm) over the ``s²`` source positions at depth ``z_um``,
    for read noise (``σ = peak / snr``) and for shot noise per emitted photon (µm·√photons)."""
    from recon.psf_wave import compute_wave_psf_bank

    depths = [z_um - step_um, z_um, z_um + step_um]
    bank = compute_wave_psf_bank(optics, depths, s, sampling=sampling, threshold=0.0, cache_dir="")
    n = s * s
    read, shot = [], []
    for p in range(n):
        minus, mid, plus = _dense(bank, [p, n + p, 2 * n + p])
        grad = (plus - minus) / (2.0 * step_um)
        sigma = mid.max() / snr
        read.append(1.0 / np.sqrt(np.sum(grad**2) / sigma**2))
        # weights are fractions of the light in the collection cone: per emitted photon
        lam = mid * optics.cone_fraction
        g = grad * optics.cone_fraction
        ok = lam > 0
        shot.append(1.0 / np.sqrt(np.sum(g[ok] ** 2 / lam[ok])))
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
    return {"read": rms(read), "shot": rms(shot)}


def _profile(optics, zs, args, sampling) -> np.ndarray:
    """The read-noise bound (µm) at each true depth of ``zs``."""
    return np.array([bounds(optics, z, args.s, args.step, args.snr, sampling)["read"] for z in zs])


def _studies(air, gel, args, sampling) -> None:
    """The bound on the studies' z displacement errors, gel against air: a layer moved from
    ``--layer`` Z0 to Z1 in STEP steps (fig5b: each step's displacement from the first frame,
    two positions), and particles spread uniformly over ``--box`` Z0 … Z1 whose z does not
    change (fig6c: the RMS over depths, two positions); the gel's at ``--gel-layer`` and
    ``--gel-box`` (default: the same true depths as air's)."""
    layers = {"air": args.layer, "gel": args.gel_layer or args.layer}
    boxes = {"air": args.box, "gel": args.gel_box or args.box}
    steps = {}
    for name, optics in (("air", air), ("gel", gel)):
        z0, z1, dz = layers[name]
        c = _profile(optics, np.arange(z0, z1 + dz / 2, dz), args, sampling)
        steps[name] = np.sqrt(c[0] ** 2 + c[1:] ** 2)
    worst = steps["gel"].max() / steps["air"].max()
    median = np.median(steps["gel"] / steps["air"])
    print(
        f"layer (fig5b) air {_span(layers['air'])}, gel {_span(layers['gel'])}: worst-step bound "
        f"air {steps['air'].max():.3f} µm, gel {steps['gel'].max():.3f} µm, ratio {worst:.3f}; "
        f"median step ratio {median:.3f}"
    )
    rms = {}
    for name, optics in (("air", air), ("gel", gel)):
        zs = np.arange(boxes[name][0], boxes[name][1] + 1.0, 20.0)
        rms[name] = float(np.sqrt(2.0 * np.mean(_profile(optics, zs, args, sampling) ** 2)))
    print(
        f"box (fig6c) air {boxes['air'][0]:g} … {boxes['air'][1]:g} µm, gel {boxes['gel'][0]:g} … "
        f"{boxes['gel'][1]:g} µm: RMS bound of a z displacement air {rms['air']:.3f} µm, "
        f"gel {rms['gel']:.3f} µm, ratio {rms['gel'] / rms['air']:.3f}"
    )


def _steps(layer) -> int:
    z0, z1, dz = layer
    return len(np.arange(z0, z1 + dz / 2, dz))


def _span(layer) -> str:
    z0, z1, dz = layer
    return f"{z0:g} → {z1:g} µm in {dz:g} µm steps"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--depths", type=float, nargs="+", default=[100.0, 160.0, 300.0, 500.0, 660.0])
    ap.add_argument("--layer", type=float, nargs=3, default=[160.0, 660.0, 20.0])
    ap.add_argument("--box", type=float, nargs=2, default=[100.0, 400.0])
    ap.add_argument("--gel-layer", type=float, nargs=3, help="the gel's layer (default: --layer)")
    ap.add_argument("--gel-box", type=float, nargs=2, help="the gel's box (default: --box)")
    ap.add_argument("--s", type=int, default=3, help="source positions per lenslet and axis")
    ap.add_argument("--snr", type=float, default=17.0)
    ap.add_argument("--step", type=float, default=2.0, help="finite-difference step (true µm)")
    ap.add_argument("--oversample", type=int, default=None, help="wave sampling (default: auto)")
    args = ap.parse_args()
    if args.gel_layer and _steps(args.gel_layer) != _steps(args.layer):
        ap.error("--gel-layer: as many steps as --layer")

    from lfsim.backend import backend_info, init_backend
    from lfsim.wave import WaveSampling
    from recon.psf_wave import default_wave_sampling

    if backend_info() is None:
        init_backend()
    air = paper_optics(sensor_xy_px=(225, 225))
    gel = paper_optics(sensor_xy_px=(225, 225), **GEL)
    sampling = default_wave_sampling(air)
    if args.oversample:
        sampling = WaveSampling(oversample=args.oversample, guard_lenslets=sampling.guard_lenslets)
    scale = gel.axial_scale
    print(
        f"paper optics, gel n = {GEL['medium_ior']} behind {GEL['coverslip_thickness_um']:.0f} µm "
        f"glass: axial_scale {scale:.4f} (1 / axial_scale = {1 / scale:.3f}), cone fraction "
        f"gel / air {gel.cone_fraction / air.cone_fraction:.3f}; SNR {args.snr:g}, s = {args.s}, "
        f"step {args.step:g} µm, oversample {sampling.oversample}"
    )
    print(
        "depth: the air source's depth (µm from the native plane); the gel source at the same "
        "apparent depth (true depth / axial_scale), and at the same true depth"
    )
    print(
        "depth  CRLB read: air  gel same apparent (ratio)  gel same true (ratio)   "
        "CRLB shot: air  gel same apparent (ratio)"
    )
    t0 = time.perf_counter()
    for d in args.depths:
        b_air = bounds(air, d, args.s, args.step * scale, args.snr, sampling)
        b_app = bounds(gel, d / scale, args.s, args.step, args.snr, sampling)
        b_true = bounds(gel, d, args.s, args.step, args.snr, sampling)
        r_app, r_true = b_app["read"] / b_air["read"], b_true["read"] / b_air["read"]
        print(
            f"{d:5.0f}  {b_air['read']:14.3f}  {b_app['read']:17.3f} ({r_app:.3f})"
            f"  {b_true['read']:13.3f} ({r_true:.3f})"
            f"  {b_air['shot']:14.1f}  {b_app['shot']:17.1f} ({b_app['shot'] / b_air['shot']:.3f})"
        )
    _studies(air, gel, args, sampling)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
