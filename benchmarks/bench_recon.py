"""Benchmark of the light-field reconstruction (run by hand, not in CI).

Measures, side by side in one run, each case in a fresh subprocess (so its peak resident
memory is its own):

1. **Ours vs pyolaf 0.2.1** (``--pyolaf``). pyolaf (https://github.com/lambdaloop/pyolaf, the
   Python port of oLaF; ``pip install -e .[bench]``) is set up from the paper's optics with no
   calibration image — objective 4× / NA 0.2, tube lens 200 mm, lenslets 100 µm / f 1000 µm,
   pixel 100/15 µm, 605 nm, n = 1, regular grid, ``newSpacingPx = 15`` — and
   ``superResFactor = 5``, i.e. the same 5 × 5 voxels per lenslet as our ``s = 5`` (pyolaf's
   own example uses 15 px / 5). Both reconstruct the same rectified image (20 particles of
   15 µm at z = 100…400 µm, 10⁵ rays each, traced with :func:`lfsim.tracer.trace_paraxial`,
   cropped to 53 × 85 whole lenslets = 795 × 1275 px) on the same depth planes (pyolaf's axis
   points towards the objective, so its depths are ours negated) for several plane counts
   (``--depths``). Timed separately: PSF / operator computation, the iteration set-up (our
   ``Hᵀ1``; pyolaf's ``H 1`` and ``Hᵀ H 1``), and one Richardson–Lucy iteration: forward
   projection, backward projection, update and anti-aliasing filter (Lanczos window 2 for
   both). pyolaf's iteration is its example's loop body (``examples/deconvolve_image.py``)
   with the forward projection done (its first iteration reuses ``H 1``). Without CuPy,
   pyolaf runs on numpy's FFT (one thread); ours uses the projector ``make_projector`` picks
   (on the CPU ``SparseProjector``: scipy sparse × dense products; Dr.Jit gathers on CUDA).
2. **Paper-size frame** (``--paper``; ``--full`` for ``s = 15``). The 1280 × 800 px frame of
   ``bench_lfsim.py`` (60 particles of 15 µm at z = 100…400 µm, 10⁵ rays each), rectified to
   1275 × 795 px, z = −80…720 µm in 5 µm steps (161 planes), 3 iterations with the depth
   filter at ``s = 5`` (our default) and ``s = 15`` (one voxel per pixel). Reports the cold
   PSF-bank time (``cache_dir=""``), ``Hᵀ1``, per-iteration time, total, peak RSS, the
   multiply-adds per projection (``projector.macs_per_projection``) and the throughput
   (2 projections per iteration). When three iterations would take longer than
   ``--budget`` seconds (default 600), the run stops after the first and the total for three
   is extrapolated — the output says so.

The first Dr.Jit kernel of a process is compiled (cached on disk afterwards); PSF banks are
traced cold (no cache) in every case.

Usage::

    python benchmarks/bench_recon.py                      # pyolaf comparison + paper frame s=5
    python benchmarks/bench_recon.py --pyolaf --depths 3 5 9
    python benchmarks/bench_recon.py --paper              # paper frame, s=5
    python benchmarks/bench_recon.py --full               # paper frame, s=15 (slow)
    python benchmarks/bench_recon.py --paper --full --json results.json
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

PN = 15  # pixels per lenslet of the paper optics
RECT_SHAPE = (795, 1275)  # rectified image: 53 x 85 whole lenslets
N_LENSLETS = (RECT_SHAPE[1] // PN, RECT_SHAPE[0] // PN)  # (nx, ny)
COMPARE_Z = (100.0, 400.0)
PAPER_Z = (-80.0, 720.0, 5.0)
PYOLAF_VERSION = "0.2.1"
LANCZOS_A = 2  # paper's "Lanczos filter width", used for both codes


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


# -- cases (each runs in its own subprocess) ---------------------------------------------------
def case_render(p: dict) -> dict:
    """Trace a light-field frame with lfsim and save its rectified crop as .npy."""
    import numpy as np

    from lfsim import init_backend, paper_optics
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    init_backend(threads=p.get("threads"))
    optics = paper_optics()
    rng = np.random.default_rng(p["seed"])
    n = p["particles"]
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    centers = np.c_[
        rng.uniform(x0 + 50, x1 - 50, n),
        rng.uniform(y0 + 50, y1 - 50, n),
        rng.uniform(p["z"][0], p["z"][1], n),
    ]
    t = time.perf_counter()
    img = trace_paraxial(
        optics,
        Sources.spheres(centers, 15.0),
        RenderSettings(rays_per_particle=p["rays"], seed=p["seed"]),
    )
    seconds = time.perf_counter() - t
    rect = np.ascontiguousarray(img[: RECT_SHAPE[0], : RECT_SHAPE[1]], dtype=np.float32)
    np.save(p["out"], rect)
    return {"seconds": seconds, "shape": list(img.shape), "photons": float(rect.sum())}


class _IterationLog(logging.Handler):
    """Collects the per-iteration wall times that ``richardson_lucy`` logs, as they happen."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.stamps: list[float] = []
        self.seconds: list[float] = []

    def emit(self, record):
        if str(record.msg).startswith("RL iteration") and len(record.args or ()) == 3:
            self.stamps.append(time.perf_counter())
            self.seconds.append(float(record.args[2]))


class _Stop(Exception):
    pass


class _CpuClock(threading.Thread):
    """Samples (wall, process CPU) every 0.1 s, to read the CPU time of any wall interval."""

    def __init__(self):
        super().__init__(daemon=True)
        self.samples: list[tuple[float, float]] = []
        self.done = threading.Event()

    def run(self):
        while not self.done.is_set():
            self.samples.append((time.perf_counter(), time.process_time()))
            self.done.wait(0.1)

    def cpu_between(self, t0: float, t1: float) -> float:
        import numpy as np

        w, c = np.array(sorted(self.samples)).T
        return float(np.interp(t1, w, c) - np.interp(t0, w, c))


def case_ours(p: dict) -> dict:
    """Our PSF bank, projector and Richardson–Lucy on one rectified image."""
    import numpy as np

    from lfsim import init_backend, paper_optics
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.projector import make_projector
    from recon.psf import compute_psf_bank

    info = init_backend(threads=p.get("threads"))
    optics = paper_optics()
    img = np.load(p["image"])
    depths = np.asarray(p["depths"], dtype=np.float64)
    s, iterations, budget = p["s"], p["iterations"], p["budget"]
    rss0 = peak_rss_mb()
    clock = _CpuClock()
    clock.start()

    t_bank0 = time.perf_counter()
    bank = compute_psf_bank(optics, depths, s, cache_dir="")
    t_bank1 = time.perf_counter()
    t_bank = t_bank1 - t_bank0
    t = time.perf_counter()
    proj = make_projector(bank, N_LENSLETS, p.get("projector", "auto"))
    t_proj = time.perf_counter() - t
    filt = DepthFilter.for_optics(optics, depths, s, a=LANCZOS_A)

    handler = _IterationLog()
    logger = logging.getLogger("recon.deconvolve")
    logger.setLevel(logging.INFO)
    logger.addHandler(handler)

    def stop_if_too_long(it, _vol):
        # After the first iteration: if all of them would exceed the budget, stop and
        # extrapolate from the measured ones.
        if it < iterations and handler.seconds and handler.seconds[0] * iterations > budget:
            raise _Stop

    t_call = time.perf_counter()
    stopped = False
    try:
        res = richardson_lucy(
            img,
            proj,
            iterations,
            depth_filter=filt,
            track_kl=False,
            callback=stop_if_too_long if budget < 1e9 else None,
        )
        seconds = list(res.seconds)
    except _Stop:
        stopped = True
        seconds = list(handler.seconds)
    logger.removeHandler(handler)
    # Hᵀ1 (with the image upload and the start volume) ends where the first iteration starts.
    t_ht1 = handler.stamps[0] - handler.seconds[0] - t_call
    clock.samples.append((time.perf_counter(), time.process_time()))
    clock.done.set()
    ends = handler.stamps
    starts = [e - d for e, d in zip(ends, handler.seconds, strict=True)]
    out = {
        "threads": info.threads,
        "device": info.device,
        "projector": type(proj).__name__,
        "s": s,
        "nz": len(depths),
        "volume_shape": list(proj.volume_shape),
        "image_shape": list(proj.image_shape),
        "bank_nnz": int(bank.nnz),
        "macs_per_projection": int(proj.macs_per_projection),
        "bank_s": t_bank,
        "projector_s": t_proj,
        "ht1_s": t_ht1,
        "iteration_s": seconds,
        # CPU seconds (all threads) of each iteration: much less sensitive to other load.
        "iteration_cpu_s": [clock.cpu_between(a, b) for a, b in zip(starts, ends, strict=True)],
        "bank_cpu_s": clock.cpu_between(t_bank0, t_bank1),
        "ht1_cpu_s": clock.cpu_between(t_call, starts[0]),
        "iterations_measured": len(seconds),
        "iterations_wanted": iterations,
        "extrapolated": stopped,
    }
    if p.get("projections"):
        # Forward and backward alone (warm kernels), for the comparison table, in the
        # projector's own array world (numpy for the sparse projector, Dr.Jit for gathers).
        xp = proj.arrays
        x = xp.from_numpy(np.ones(proj.n_channels * proj.nx * proj.ny, np.float32))
        xp.eval(x)
        xp.synchronize()
        t = time.perf_counter()
        y = proj.forward_flat(x)
        xp.eval(y)
        xp.synchronize()  # LLVM kernels run asynchronously
        out["forward_s"] = time.perf_counter() - t
        t = time.perf_counter()
        b = proj.backward_flat(y)
        xp.eval(b)
        xp.synchronize()
        out["backward_s"] = time.perf_counter() - t
    out["peak_rss_mb"] = peak_rss_mb()
    out["baseline_rss_mb"] = rss0
    return out


def case_pyolaf(p: dict) -> dict:
    """pyolaf's operators and one Richardson–Lucy iteration on the same image and depths."""
    import contextlib
    import warnings

    warnings.filterwarnings("ignore")
    import numpy as np

    try:
        import pyolaf
        from pyolaf.aliasing import LFM_computeDepthAdaptiveWidth, lanczosfft
        from pyolaf.geometry import LFM_computeGeometryParameters, LFM_setCameraParams
        from pyolaf.lf import LFM_computeLFMatrixOperators
        from pyolaf.project import LFM_backwardProject, LFM_forwardProject
    except ImportError as exc:
        return {"error": f"pyolaf is not installed ({exc}); pip install -e .[bench]"}
    try:
        import cupy  # noqa: F401

        backend = "cupy"
    except ImportError:
        backend = "numpy"
    import yaml
    from numpy.fft import fft2, fftshift, ifft2

    from lfsim import paper_optics

    o = paper_optics()
    camera_cfg = {
        "gridType": "reg",
        "focus": "single",
        "plenoptic": 1,
        "uLensMask": 1,
        "M": o.magnification,
        "NA": o.na,
        "ftl": o.f_tube_um,
        "fm": o.mla_focal_um,
        "tube2mla": 0,  # 0: = ftl (plenoptic 1)
        "mla2sensor": 0,  # 0: = fm
        "lensPitch": o.mla_pitch_um,
        "pixelPitch": o.pixel_um,
        "WaveLength": o.wavelength_um,
        "n": o.medium_ior,
    }
    ours = np.asarray(p["depths"], dtype=np.float64)
    nz = len(ours)
    step = float(ours[1] - ours[0])
    depth_range = [-float(ours[-1]), -float(ours[0])]  # pyolaf's z points to the objective
    img = np.load(p["image"]).astype(np.float32)
    img = (img - img.min()) / (img.max() - img.min())  # as pyolaf's example does
    img_size = np.array(img.shape)
    out = {"pyolaf": pyolaf.__version__, "backend": backend, "nz": nz, "s": p["s"]}
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(sys.stderr):
        cfg = Path(tmp) / "config.yaml"
        cfg.write_text(yaml.safe_dump(camera_cfg))
        t = time.perf_counter()
        camera = LFM_setCameraParams(str(cfg), PN)
        centers, res, _, _ = LFM_computeGeometryParameters(
            camera, np.array([]), depth_range, step, p["s"], False, imgSize=img_size
        )
        if len(res["depths"]) != nz:
            return {"error": f"pyolaf made {len(res['depths'])} depths, expected {nz}"}
        H, Ht = LFM_computeLFMatrixOperators(camera, res, centers)
        out["psf_s"] = time.perf_counter() - t
        out["depths_pyolaf"] = [float(d) for d in res["depths"]]
        out["tex_nnum"] = [int(v) for v in res["TexNnum"]]
        out["psf_image_px"] = list(H[0, 0, 0].shape)

        crange = camera["range"]
        tex_size = np.ceil(img_size * res["texScaleFactor"]).astype("int32")
        tex_size = tex_size + (1 - tex_size % 2)
        vol_size = np.append(tex_size, nz).astype("int32")
        out["volume_shape_zyx"] = [nz, int(tex_size[0]), int(tex_size[1])]

        t = time.perf_counter()
        kernel_fft = lanczosfft(vol_size, LFM_computeDepthAdaptiveWidth(camera, res), LANCZOS_A)
        init = np.ones(vol_size, dtype="float32")
        ones_fwd = LFM_forwardProject(H, init, centers, res, img_size, crange, step=8)
        ones_back = LFM_backwardProject(Ht, ones_fwd, centers, res, tex_size, crange, step=8)
        out["setup_s"] = time.perf_counter() - t

        # One iteration: the loop body of pyolaf's examples/deconvolve_image.py (i > 0).
        volume = init.copy()
        c0 = time.process_time()
        t0 = time.perf_counter()
        guess = LFM_forwardProject(H, volume, centers, res, img_size, crange, step=10)
        t1 = time.perf_counter()
        with np.errstate(divide="ignore", invalid="ignore"):
            err = img / guess * ones_fwd
        err[~np.isfinite(err)] = 0
        t2 = time.perf_counter()
        back = LFM_backwardProject(Ht, err, centers, res, tex_size, crange, step=10)
        t3 = time.perf_counter()
        with np.errstate(divide="ignore", invalid="ignore"):
            back = back / ones_back
        back[~np.isfinite(back)] = 0
        volume = volume * back
        for j in range(nz):
            volume[:, :, j] = np.abs(fftshift(ifft2(kernel_fft[:, :, j] * fft2(volume[:, :, j]))))
        volume[~np.isfinite(volume)] = 0
        t4 = time.perf_counter()
        c4 = time.process_time()
    out.update(
        forward_s=t1 - t0,
        backward_s=t3 - t2,
        update_filter_s=(t2 - t1) + (t4 - t3),
        iteration_s=[t4 - t0],
        iteration_cpu_s=[c4 - c0],
        peak_rss_mb=peak_rss_mb(),
    )
    return out


CASES = {"render": case_render, "ours": case_ours, "pyolaf": case_pyolaf}


# -- driver --------------------------------------------------------------------------------
def run_child(params: dict, env_extra: dict | None = None) -> dict:
    cmd = [sys.executable, __file__, "--case", json.dumps(params)]
    env = dict(os.environ, **(env_extra or {}))
    load = os.getloadavg()[0]
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        tail = "\n".join((proc.stderr or "").strip().splitlines()[-15:])
        return {"error": f"exit status {proc.returncode}: {tail}", "wall_s": wall}
    row = json.loads(lines[-1])
    row["wall_s"] = wall
    row["load_before"] = load  # 1-min load average: > 0.5 means something else was running
    return row


def render_image(path, particles: int, z_um, threads, what: str) -> bool:
    """Render ``particles`` random particles (1e5 rays each) in a child; False on failure."""
    case = {"case": "render", "particles": particles, "z": z_um, "rays": 100_000, "seed": 1}
    r = run_child({**case, "out": str(path), "threads": threads})
    if "error" in r:
        print(f"rendering {what} failed: {r['error']}")
        return False
    return True


def median(v):
    v = sorted(v)
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def fmt_s(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def compare(args, tmp: Path, results: dict) -> None:
    import numpy as np

    img = tmp / "compare.npy"
    if not render_image(img, 20, list(COMPARE_Z), args.threads, "the comparison image"):
        return
    print(
        f"\n== ours vs pyolaf {PYOLAF_VERSION}: one Richardson-Lucy iteration ==\n"
        f"image: 20 particles (15 um, z {COMPARE_Z[0]:g}..{COMPARE_Z[1]:g} um, 1e5 rays each), "
        f"rectified {RECT_SHAPE[0]}x{RECT_SHAPE[1]} px = {N_LENSLETS[1]}x{N_LENSLETS[0]} "
        f"lenslets; s = {args.s} voxels per lenslet (pyolaf superResFactor {args.s}, "
        f"newSpacingPx {PN}); planes evenly spaced over z {COMPARE_Z[0]:g}..{COMPARE_Z[1]:g} um"
    )
    rows = []
    for nz in args.depths:
        depths = np.linspace(COMPARE_Z[0], COMPARE_Z[1], nz).tolist()
        common = {"image": str(img), "depths": depths, "s": args.s, "threads": args.threads}
        po = run_child({"case": "pyolaf", **common}, {"TQDM_DISABLE": "1"})
        us = run_child(
            {"case": "ours", **common, "iterations": 3, "budget": 1e9, "projections": True}
        )
        rows.append((nz, us, po))
    results["compare"] = [{"nz": nz, "ours": us, "pyolaf": po} for nz, us, po in rows]
    for nz, us, po in rows:
        for who, r in (("ours", us), ("pyolaf", po)):
            if "error" in r:
                print(f"  nz={nz} {who}: FAILED: {r['error']}")
    hdr = (
        f"{'nz':>3s} {'code':7s} {'PSF s':>8s} {'setup s':>8s} {'fwd s':>7s} {'bwd s':>7s} "
        f"{'iter s':>8s} {'cpu s':>7s} {'peak MB':>8s} {'ratio':>6s} {'cpu ratio':>9s} "
        f"{'load':>5s}"
    )
    print(hdr)
    for nz, us, po in rows:
        for who, r in (("ours", us), ("pyolaf", po)):
            if "error" in r:
                print(f"{nz:3d} {who:7s} failed (see above)")
                continue
            psf = r.get("bank_s", r.get("psf_s"))
            setup = r.get("ht1_s", r.get("setup_s"))
            it, cpu = median(r["iteration_s"]), median(r["iteration_cpu_s"] or [float("nan")])
            ratio = cpu_ratio = ""
            if who == "pyolaf" and "error" not in us:
                ratio = f"{it / median(us['iteration_s']):.1f}"
                cpu_ratio = f"{cpu / median(us['iteration_cpu_s']):.1f}"
            print(
                f"{nz:3d} {who:7s} {psf:8.2f} {setup:8.2f} {fmt_s(r.get('forward_s')):>7s} "
                f"{fmt_s(r.get('backward_s')):>7s} {it:8.2f} {cpu:7.2f} {r['peak_rss_mb']:8.0f} "
                f"{ratio:>6s} {cpu_ratio:>9s} {r['load_before']:5.1f}"
            )
    ok = [(us, po) for _, us, po in rows if "error" not in us and "error" not in po]
    if ok:
        us, po = ok[0]
        firsts = ", ".join(f"{u['iteration_s'][0]:.2f}" for u, _ in ok)
        print(
            f"ours: {us.get('projector', '?')}, {us['threads']} Dr.Jit threads "
            f"({us['device']}); iteration = median of 3 "
            f"RL iterations with the depth filter (first ones: {firsts} s), cpu = CPU seconds "
            f"of all threads (median); setup = H^T 1; PSF = traced bank.\n"
            f"pyolaf {po['pyolaf']}: {po['backend']} backend (one thread); iteration = forward "
            f"+ backward + update + Lanczos filter; setup = H 1 and H^T H 1; PSF = wave-optics "
            f"operators (PSF image {po['psf_image_px'][0]} px wide); depths = -ours.\n"
            f"ratio = pyolaf / ours wall time per iteration; cpu ratio = same in CPU seconds "
            f"(insensitive to other load and to thread count); load = 1-min load average "
            f"before the case."
        )


def paper(args, tmp: Path, results: dict, s_values: list[int]) -> None:
    from recon.geometry import depth_range

    img = tmp / "paper.npy"
    if not render_image(img, 60, [100.0, 400.0], args.threads, "the paper frame"):
        return
    depths = depth_range(*PAPER_Z).tolist()
    print(
        f"\n== paper-size frame: 1280x800 px (rectified {RECT_SHAPE[1]}x{RECT_SHAPE[0]}), "
        f"z {PAPER_Z[0]:g}..{PAPER_Z[1]:g} um step {PAPER_Z[2]:g} ({len(depths)} planes), "
        f"3 RL iterations with the depth filter, cold PSF bank =="
    )
    rows = []
    for s in s_values:
        row = run_child(
            {
                "case": "ours",
                "image": str(img),
                "depths": depths,
                "s": s,
                "iterations": 3,
                "budget": args.budget,
                "threads": args.threads,
            }
        )
        rows.append(row)
        results.setdefault("paper", []).append(row)
        if "error" in row:
            print(f"  s={s}: FAILED: {row['error']}")
    print(
        f"{'s':>3s} {'voxels':>18s} {'bank s':>8s} {'H^T1 s':>8s} {'iter s':>20s} "
        f"{'cpu s/it':>8s} "
        f"{'total s':>9s} {'peak MB':>8s} {'GMAC/proj':>10s} {'GMAC/s':>7s} {'/cpu-s':>7s} "
        f"{'load':>5s}"
    )
    for row in rows:
        if "error" in row:
            continue
        its = row["iteration_s"]
        mean_it = sum(its) / len(its)
        measured = row["bank_s"] + row["projector_s"] + row["ht1_s"] + sum(its)
        total3 = measured + mean_it * (3 - len(its))
        gmacs = row["macs_per_projection"] / 1e9
        cpus = row["iteration_cpu_s"]
        per_cpu = 2 * gmacs / median(cpus) if cpus else None
        nz, ny, nx = row["volume_shape"]
        print(
            f"{row['s']:3d} {f'{nz}x{ny}x{nx}':>18s} {row['bank_s']:8.1f} {row['ht1_s']:8.1f} "
            f"{' '.join(f'{t:.1f}' for t in its):>20s} "
            f"{fmt_s(median(cpus) if cpus else None):>8s} "
            f"{total3:8.1f}{'*' if row['extrapolated'] else ' '} {row['peak_rss_mb']:8.0f} "
            f"{gmacs:10.1f} {2 * gmacs / mean_it:7.2f} {fmt_s(per_cpu):>7s} "
            f"{row['load_before']:5.1f}"
        )
        row["total_3_iterations_s"] = total3
        row["measured_total_s"] = measured
    print(
        "iter s = wall time of each measured iteration; cpu s/it = CPU seconds of all threads "
        "per iteration (median); GMAC/s = 2 projections x GMAC/proj per mean "
        "iteration (wall), /cpu-s the same per CPU second; load = 1-min load average before."
    )
    for row in rows:
        if "error" in row:
            continue
        note = (
            f"s={row['s']}: bank {row['bank_nnz']:,} non-zeros, projector build "
            f"{row['projector_s']:.1f} s, {row['threads']} threads ({row['device']})"
        )
        if row["extrapolated"]:
            per_it = sum(row["iteration_s"]) / len(row["iteration_s"])
            note += (
                f"; * EXTRAPOLATED: 3 iterations would exceed --budget {args.budget:g} s, so "
                f"{row['iterations_measured']} iteration(s) measured and the total for 3 is "
                f"bank + build + H^T1 + 3 x {per_it:.1f} s"
            )
        print(note)


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--pyolaf", action="store_true", help="ours vs pyolaf comparison")
    ap.add_argument("--paper", action="store_true", help="paper-size frame at s=5")
    ap.add_argument("--full", action="store_true", help="paper-size frame at s=15 (slow)")
    ap.add_argument(
        "--depths",
        type=int,
        nargs="+",
        default=[3, 5, 9],
        metavar="N",
        help="plane counts of the pyolaf comparison (default 3 5 9)",
    )
    ap.add_argument("--s", type=int, default=5, help="voxels per lenslet of the comparison")
    ap.add_argument("--budget", type=float, default=600.0, help="seconds for 3 iterations")
    ap.add_argument("--threads", type=int, default=None, help="Dr.Jit threads (default: all)")
    ap.add_argument("--json", type=Path, default=None, help="also write all results here")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        p = json.loads(args.case)
        print(json.dumps(CASES[p["case"]](p)))
        return 0
    if any(n < 2 for n in args.depths):
        ap.error("--depths needs at least 2 planes per case")
    if args.s < 1 or args.s % 2 == 0:
        ap.error("--s must be odd (pyolaf makes the voxels per lenslet odd)")
    if not (args.pyolaf or args.paper or args.full):
        args.pyolaf = args.paper = True
    results: dict = {"cores": os.cpu_count()}
    print(
        f"machine: {os.cpu_count()} cores; python {sys.version.split()[0]}; "
        f"load average {os.getloadavg()[0]:.2f} (other work on the machine skews the timings)"
    )
    with tempfile.TemporaryDirectory(prefix="bench_recon_") as tmp:
        if args.pyolaf:
            compare(args, Path(tmp), results)
        s_values = ([5] if args.paper else []) + ([15] if args.full else [])
        if s_values:
            paper(args, Path(tmp), results, s_values)
    print(f"load average at the end: {os.getloadavg()[0]:.2f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
