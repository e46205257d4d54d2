"""The CPU projector on 1, 2, … threads, side by side in one run (by hand).

``recon.projector.SparseProjector`` shares one projection among a thread pool (its
``threads``; ``recon run --threads``). This script builds the projector once per thread count
on the same PSF bank and times ``H`` (forward) and ``Hᵀ`` (backward) on the same random
volume and image, the thread counts alternating within each repeat so that a busy machine
slows them alike. Reported per thread count: the multiply-adds of one projection
(``nnz(bank) × lenslets``), the median wall seconds of ``H`` and of ``Hᵀ``, their mean as the
time per projection, G multiply-adds per second, the speed-up over the first thread count,
the CPU seconds (all threads) per projection and the work efficiency (CPU seconds of the
first thread count over this one's: below 1 where splitting costs extra work; on a busy
machine the steadier measure, as wall times then depend on what else runs) and the cores the
projection got (CPU seconds over wall seconds: near the thread count on a quiet machine, less
where other work or the GIL holds threads back). The outputs
of every thread count are checked to be bit-identical to the first's. Last, the same thread
counts run a reference load that is parallel by construction (numpy ufuncs on one
independent array per thread, no GIL): its speed-up is what the machine allows at that
moment, the ceiling to read the projector's against when other work shares the cores.

Default case: the paper-size frame — paper optics, 85 × 53 lenslets (1280 × 800 px), depths
−80…720 µm in 5 µm steps (161 planes), ``s = 5``: 1.5·10¹⁰ multiply-adds per projection. The
PSF bank is traced once (about 20 s on 2 cores) and cached like ``recon run``'s.
``--z-range`` and ``--lenslets`` make a shorter run.

Usage::

    python benchmarks/bench_projector_threads.py [--threads 1 2] [--repeats 2]
        [--z-range -80:720] [--z-step 5] [-s 5] [--lenslets 85 53]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from statistics import median

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def reference_speedup(threads: list[int], seconds: float = 0.5) -> dict[int, float]:
    """Speed-up of embarrassingly parallel numpy work on each thread count over the first."""
    from concurrent.futures import ThreadPoolExecutor

    arrays = [np.ones(2_000_000, np.float32) for _ in range(max(threads))]

    def work(x):
        for _ in range(20):
            np.sqrt(x, out=x)
            np.multiply(x, np.float32(1.0001), out=x)

    rate = {}
    for t in threads:
        n, t0 = 0, time.perf_counter()
        with ThreadPoolExecutor(t) as ex:
            while time.perf_counter() - t0 < seconds:
                list(ex.map(work, arrays[:t]))
                n += t
        rate[t] = n / (time.perf_counter() - t0)
    return {t: rate[t] / rate[threads[0]] for t in threads}


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--z-range", default="-80:720", help="MIN:MAX depths in µm")
    ap.add_argument("--z-step", type=float, default=5.0)
    ap.add_argument("-s", type=int, default=5)
    ap.add_argument("--lenslets", type=int, nargs=2, default=(85, 53), metavar=("NX", "NY"))
    ap.add_argument("--rays-per-pattern", type=int, default=200_000)
    args = ap.parse_args()
    if args.repeats < 1 or min(args.threads) < 1:
        ap.error("--repeats and --threads must be >= 1")
    sys.path.insert(0, str(ROOT))
    from lfsim import init_backend, paper_optics
    from recon.geometry import depth_range
    from recon.projector import SparseProjector, available_cores
    from recon.psf import compute_psf_bank

    init_backend()
    z0, z1 = (float(v) for v in args.z_range.split(":"))
    depths = depth_range(z0, z1, args.z_step)
    t0 = time.perf_counter()
    bank = compute_psf_bank(paper_optics(), depths, args.s, rays_per_pattern=args.rays_per_pattern)
    t_bank = time.perf_counter() - t0
    grid = tuple(args.lenslets)
    projectors = {t: SparseProjector(bank, grid, threads=t) for t in args.threads}
    p0 = projectors[args.threads[0]]
    rng = np.random.default_rng(0)
    x = rng.random(p0.n_channels * p0.nx * p0.ny, dtype=np.float32)
    y = rng.random(p0.n_res * p0.nx * p0.ny, dtype=np.float32)
    macs = p0.macs_per_projection
    print(
        f"machine: {available_cores()} cores, load average {os.getloadavg()[0]:.2f}; paper "
        f"optics, {grid[0]} x {grid[1]} lenslets, {len(depths)} depths {z0:g}…{z1:g} µm, "
        f"s = {bank.s}, {bank.nnz} bank non-zeros (bank {t_bank:.1f} s)"
    )
    print(f"{macs / 1e9:.2f} G multiply-adds per projection (H or Hᵀ)")
    wall = {t: {"H": [], "Ht": []} for t in args.threads}
    cpu = {t: [] for t in args.threads}
    ref = None
    for _ in range(args.repeats):
        for t, p in projectors.items():
            c0 = time.process_time()
            w0 = time.perf_counter()
            hx = p.forward_flat(x)
            w1 = time.perf_counter()
            hty = p.backward_flat(y)
            w2 = time.perf_counter()
            cpu[t].append((time.process_time() - c0) / 2)
            wall[t]["H"].append(w1 - w0)
            wall[t]["Ht"].append(w2 - w1)
            if ref is None:
                ref = (hx.tobytes(), hty.tobytes())
            elif (hx.tobytes(), hty.tobytes()) != ref:
                print(f"ERROR: {t} threads give other bits than {args.threads[0]}")
                return 1
    print(
        f"{'threads':>7s} {'H s':>8s} {'Hᵀ s':>8s} {'s/proj':>8s} {'GMAC/s':>8s} "
        f"{'speed-up':>8s} {'cpu s/proj':>10s} {'work eff.':>9s} {'cores':>5s}   "
        f"(medians of {args.repeats} repeats)"
    )
    base = base_cpu = None
    for t in args.threads:
        th, tb = median(wall[t]["H"]), median(wall[t]["Ht"])
        per = (th + tb) / 2
        base = base or per
        base_cpu = base_cpu or median(cpu[t])
        print(
            f"{t:7d} {th:8.2f} {tb:8.2f} {per:8.2f} {macs / per / 1e9:8.2f} "
            f"{base / per:8.2f} {median(cpu[t]):10.2f} {base_cpu / median(cpu[t]):9.2f} "
            f"{median(cpu[t]) / per:5.2f}"
        )
    ref = reference_speedup(args.threads)
    print(
        "reference (GIL-free numpy work, one array per thread) speed-up: "
        + ", ".join(f"{t} threads {ref[t]:.2f}" for t in args.threads)
    )
    print(
        f"outputs bit-identical across {args.threads} threads; load average at the end "
        f"{os.getloadavg()[0]:.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
