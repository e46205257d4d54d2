"""Wave-optics references: lfsim.wave against pyolaf 0.2.1 (run by hand, not in CI).

For four light-field microscopes — the paper's 4×/0.2 dry (``scenes/paper_4x.xml``), 20×/0.5
dry, 40×/0.8 water and 60×/1.2 water, each with 100 µm lenslets matched to the objective
(f-number ``M / (2 NA)``, so ``f_l = M p / (2 NA)``) and 15 px per lenslet — the light field
of a point source on the optical axis is computed at several depths by

- :func:`lfsim.wave.converged_light_field` (sampling doubled until the light field changes by
  less than ``--tol``; the history is printed), and
- pyolaf 0.2.1 (https://github.com/lambdaloop/pyolaf, ``pip install -e .[bench]``), with its
  own functions: ``LFM_calcPSF`` (Debye integral by adaptive quadrature at the sensor
  sampling), ``LFM_ulensTransmittance`` / ``LFM_mlaTransmittance`` (lenslet phase mask) and
  ``prop2Sensor`` (Rayleigh–Sommerfeld transfer function, no padding), sampled at
  ``--pyolaf-px`` (45) samples per lenslet and binned 3 × 3 to the 15 px pixels. pyolaf's z
  axis points towards the objective, so it gets ``−z``. Its lenslet phase uses its wave number
  ``2π n / λ``, i.e. it puts the lenslets in the immersion medium; for the water objectives it
  is run both as it is and with the lenslets in air (``k = 2π / λ`` for the array only).

Depths are multiples of ``z₁ = p n / (2 M NA)``, the defocus whose blur at the array is one
lenslet pitch across. Reported per depth: the normalised (Pearson) correlation of the two
light fields over the sensor, the fraction of the light each puts on the sensor, and
lfsim.wave's convergence (oversampling reached and last change).

Usage::

    nice python benchmarks/wave_reference.py                  # all four microscopes
    nice python benchmarks/wave_reference.py --scopes 4x 60xW --lenslets 11
    nice python benchmarks/wave_reference.py --json out.json --save DIR
    nice python benchmarks/wave_reference.py --rays DIR     # ray model vs the saved references

``--rays DIR`` correlates the ray model's patterns (:func:`lfsim.tracer.trace_paraxial`, as the
PSF bank traces them) with the wave references a ``--save DIR`` run wrote.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PN = 15  # sensor pixels per lenslet
PITCH = 100.0
F_TUBE = 200_000.0
WATER = 1.333

#: name: (M, NA, immersion = medium index)
SCOPES = {
    "4x": (4.0, 0.2, 1.0),
    "20x": (20.0, 0.5, 1.0),
    "40xW": (40.0, 0.8, WATER),
    "60xW": (60.0, 1.2, WATER),
}
#: depths in units of z₁ (blur one lenslet across)
DEPTH_UNITS = (0.0, 1.0, 3.0, -2.0)


def pyolaf_config(optics) -> dict:
    """pyolaf's microscope description (its ``LFMconfig.yaml`` fields) of these optics: a
    regular single-focus array, lenslet mask on, the array in the native image plane."""
    return {
        "gridType": "reg",
        "focus": "single",
        "plenoptic": 1,
        "uLensMask": 1,
        "M": optics.magnification,
        "NA": optics.na,
        "ftl": optics.f_tube_um,
        "fm": optics.mla_focal_um,
        "tube2mla": 0,
        "mla2sensor": 0,
        "lensPitch": optics.mla_pitch_um,
        "pixelPitch": optics.pixel_um,
        "WaveLength": optics.wavelength_um,
        "n": optics.medium_ior,
    }


def scope_record(name: str, optics, z1_um: float) -> dict:
    """The microscope's entry of a JSON record: name, magnification, NA, specimen index,
    lenslet focal length and the depth unit ``z₁`` (µm)."""
    return {
        "scope": name,
        "M": optics.magnification,
        "NA": optics.na,
        "n": optics.medium_ior,
        "f_lenslet_um": optics.mla_focal_um,
        "z1_um": z1_um,
    }


def make_optics(name: str, n_lenslets: int):
    from lfsim.optics import Optics, paper_optics

    m, na, n = SCOPES[name]
    side = n_lenslets * PN
    if name == "4x":
        return paper_optics(sensor_xy_px=(side, side))
    return Optics(
        na=na,
        f_objective_um=F_TUBE / m,
        f_tube_um=F_TUBE,
        mla_pitch_um=PITCH,
        mla_focal_um=m * PITCH / (2 * na),
        pixel_um=PITCH / PN,
        sensor_xy_px=(side, side),
        medium_ior=n,
        immersion_ior=n,
    )


def z_unit(optics) -> float:
    """Defocus (µm) whose geometric blur at the array is one lenslet across."""
    return optics.mla_pitch_um * optics.medium_ior / (2 * optics.magnification * optics.na)


def pyolaf_light_fields(optics, depths, q: int, guard: int) -> dict[str, np.ndarray]:
    """pyolaf's point-source light fields on the optics' sensor (binned from ``q`` to 15 px
    per lenslet). Keys: ``"as_is"`` and, for an immersion index, ``"air_lenslets"``."""
    import yaml
    from pyolaf.geometry import LFM_computeGeometryParameters, LFM_setCameraParams
    from pyolaf.lf import LFM_calcPSF, LFM_mlaTransmittance, LFM_ulensTransmittance, prop2Sensor

    if q % PN or q % 2 == 0:
        # pyolaf makes its samples per lenslet odd (an even count becomes one more)
        raise SystemExit(f"--pyolaf-px must be an odd multiple of {PN}")
    n_sensor = optics.sensor_xy_px[0] // PN
    r = n_sensor // 2 + guard
    cfg = pyolaf_config(optics)
    side = (2 * r + 1) * q
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()):
        path = Path(tmp) / "config.yaml"
        path.write_text(yaml.safe_dump(cfg))
        cam = LFM_setCameraParams(str(path), q)
        centres, res, _, _ = LFM_computeGeometryParameters(
            cam, np.array([]), [-1.0, 0.0], 1.0, 3, imgSize=np.array([side, side])
        )
        half = q * r + q // 2
        res["yspace"] = res["sensorRes"][0] * np.arange(-half, half + 1)
        res["xspace"] = res["sensorRes"][1] * np.arange(-half, half + 1)
        nh = res["Nnum_half"]
        res["yMLspace"] = res["sensorRes"][0] * np.arange(-nh[0] + 1, nh[0])
        res["xMLspace"] = res["sensorRes"][1] * np.arange(-nh[1] + 1, nh[1])
        res["usedLensletCenters"] = centres
        masks = {"as_is": LFM_mlaTransmittance(cam, res, LFM_ulensTransmittance(cam, res))}
        if optics.medium_ior != 1.0:
            air = dict(cam, k=2 * np.pi / cam["WaveLength"])
            masks["air_lenslets"] = LFM_mlaTransmittance(air, res, LFM_ulensTransmittance(air, res))
    b = q // PN
    lo = half - (n_sensor * q) // 2
    out = {k: [] for k in masks}
    for z in depths:
        psf = LFM_calcPSF(0, 0, -float(z), cam, res)
        for k, mla in masks.items():
            f1 = prop2Sensor(
                psf * mla, res["sensorRes"], cam["mla2sensor"], cam["WaveLength"], False
            )
            img = np.abs(f1[lo : lo + n_sensor * q, lo : lo + n_sensor * q]) ** 2
            img = img.reshape(n_sensor * PN, b, n_sensor * PN, b).sum(axis=(1, 3))
            out[k].append(img)
    return {k: np.array(v) for k, v in out.items()}


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    a = a.ravel() - a.mean()
    b = b.ravel() - b.mean()
    return float(a @ b / math.sqrt((a @ a) * (b @ b)))


def run_scope(name: str, args) -> dict:
    from lfsim.wave import WaveSampling, converged_light_field

    optics = make_optics(name, args.lenslets)
    z1 = z_unit(optics)
    depths = [round(u * z1, 4) for u in DEPTH_UNITS]
    src = [[0.0, 0.0, z] for z in depths]
    t = time.perf_counter()
    ours, ws, hist = converged_light_field(
        optics, src, WaveSampling(oversample=args.oversample), tol=args.tol
    )
    t_ours = time.perf_counter() - t
    # the Kirchhoff obliquity of oLaF's Debye integral, at the converged sampling
    from dataclasses import replace

    from lfsim.wave import light_field

    ours_obl = light_field(optics, src, replace(ws, obliquity=True))
    t = time.perf_counter()
    po = pyolaf_light_fields(optics, depths, args.pyolaf_px, args.guard)
    t_po = time.perf_counter() - t
    rows = []
    for i, z in enumerate(depths):
        row = {
            "z_um": z,
            "z_units": DEPTH_UNITS[i],
            "ours_sum": float(ours[i].sum()),
            "corr_obliquity": {k: pearson(ours_obl[i], v[i]) for k, v in po.items()},
            "corr": {k: pearson(ours[i], v[i]) for k, v in po.items()},
        }
        rows.append(row)
    return {
        **scope_record(name, optics, z1),
        "sensor_xy_px": optics.sensor_xy_px,
        "oversample": ws.oversample,
        "history": hist,
        "seconds_ours": t_ours,
        "seconds_pyolaf": t_po,
        "rows": rows,
        "images": {"ours": ours, **{f"pyolaf_{k}": v for k, v in po.items()}},
    }


def report(r: dict) -> str:
    lines = [
        f"\n== {r['scope']}: M {r['M']:g}, NA {r['NA']:g}, n {r['n']:g}, lenslets "
        f"{PITCH:g} µm / f {r['f_lenslet_um']:g} µm, sensor {r['sensor_xy_px'][0]} px, "
        f"z1 = {r['z1_um']:.4g} µm ==",
        "lfsim.wave convergence (oversample, change): "
        + ", ".join(f"({o}, {c:.2g})" for o, c in r["history"])
        + f"; {r['seconds_ours']:.0f} s; pyolaf {r['seconds_pyolaf']:.0f} s",
    ]
    keys = list(r["rows"][0]["corr"])
    head = "  z/z1     z um  on-sensor " + " ".join(f"{'r ' + k:>16}" for k in keys)
    head += " " + " ".join(f"{'r ' + k + ' +obl':>22}" for k in keys)
    lines.append(head)
    for row in r["rows"]:
        line = f"{row['z_units']:6.1f} {row['z_um']:8.3f} {row['ours_sum']:10.4f} "
        line += " ".join(f"{row['corr'][k]:16.4f}" for k in keys)
        line += " " + " ".join(f"{row['corr_obliquity'][k]:22.4f}" for k in keys)
        lines.append(line)
    return "\n".join(lines)


def ray_patterns(optics, depths, rays: int) -> np.ndarray:
    """The ray model's patterns (the PSF bank's tracer, with its diffraction blur), in the
    same units: fraction of the light emitted into the cone."""
    from lfsim.backend import backend_info, init_backend
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    if backend_info() is None:
        init_backend()
    centres = np.array([[0.0, 0.0, z] for z in depths])
    settings = RenderSettings(rays_per_particle=rays, mode="expected", seed=0)
    return trace_paraxial(optics, Sources.spheres(centres, 0.0), settings, per_source=True) / rays


def compare_rays(args) -> int:
    """Correlate the ray model's patterns with saved wave references (``--save`` of a run)."""
    for name in args.scopes:
        path = args.rays / f"wave_{name}.npz"
        if not path.is_file():
            print(f"{name}: no {path}")
            continue
        with np.load(path) as z:
            wave = z["ours"]
        n_l = wave.shape[-1] // PN
        optics = make_optics(name, n_l)
        depths = [round(u * z_unit(optics), 4) for u in DEPTH_UNITS]
        ray = ray_patterns(optics, depths, args.ray_count)
        print(
            f"{name}: ray image NA {optics.image_na:.4f} (aplanatic NA/M "
            f"{optics.na / optics.magnification:.4f}); z/z1, z um, r(ray, wave), ray on-sensor"
        )
        for u, zz, a, b in zip(DEPTH_UNITS, depths, ray, wave, strict=True):
            print(f"  {u:5.1f} {zz:9.3f} {pearson(a, b):8.4f} {a.sum():8.4f}")
        if args.match:
            # the depth whose ray pattern matches each wave reference best (template matching
            # over -3.5 … 4.5 z1 in steps of 0.05 z1; not a reconstruction)
            z1 = z_unit(optics)
            grid = np.linspace(-3.5, 4.5, 161) * z1
            bank = ray_patterns(optics, grid, args.ray_count // 10)
            print("  best-matching ray depth: z um -> z um (r)")
            for zz, b in zip(depths, wave, strict=True):
                c = np.array([pearson(a, b) for a in bank])
                k = int(np.argmax(c))
                print(f"  {zz:9.3f} -> {grid[k]:9.3f} ({c[k]:.4f})")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scopes", nargs="+", default=list(SCOPES), choices=list(SCOPES))
    ap.add_argument("--lenslets", type=int, default=11, help="sensor width in lenslets (odd)")
    ap.add_argument("--guard", type=int, default=2, help="pyolaf's extra lenslets per side")
    ap.add_argument("--pyolaf-px", type=int, default=45, help="pyolaf samples per lenslet")
    ap.add_argument("--oversample", type=int, default=2, help="lfsim.wave's first sampling")
    ap.add_argument("--tol", type=float, default=2e-3, help="lfsim.wave convergence tolerance")
    ap.add_argument("--json", type=Path, help="write the numbers (not the images) here")
    ap.add_argument("--save", type=Path, help="write the light fields here (.npz per scope)")
    ap.add_argument(
        "--rays",
        type=Path,
        help="instead: correlate the ray model's patterns with the wave references saved here",
    )
    ap.add_argument("--ray-count", type=int, default=2_000_000, help="rays per pattern")
    ap.add_argument(
        "--match",
        action="store_true",
        help="with --rays: the depth whose ray pattern matches each reference best",
    )
    args = ap.parse_args(argv)
    if args.rays:
        return compare_rays(args)
    if args.lenslets % 2 == 0:
        ap.error("--lenslets must be odd (the axis on the centre lenslet)")
    results = []
    for name in args.scopes:
        r = run_scope(name, args)
        print(report(r), flush=True)
        if args.save:
            args.save.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(args.save / f"wave_{name}.npz", **r["images"])
        r.pop("images")
        results.append(r)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
