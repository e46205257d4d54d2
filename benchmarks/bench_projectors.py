"""Measure the three projector formulations side by side (run by hand).

Same PSF bank, same volume and image, paper optics (85 × 53 lenslets of 15 px), a reduced
set of depths: the Dr.Jit gather projector (the GPU path), the scipy.sparse per-depth
projector (the CPU path), Hᵀ by Dr.Jit reverse-mode AD, and the scipy.fft projector with
frequency-domain accumulation (``projector_candidates.py``). Every candidate is first checked
against the gather projector (``H x`` and ``Hᵀ y`` equal to 1e-5 relative), then timed.

Usage::

    python benchmarks/bench_projectors.py [--depths 5] [-s 3] [--repeats 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _best(fn, repeats):
    fn()  # warm-up (kernel compilation)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--depths", type=int, default=5)
    ap.add_argument("-s", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()

    from projector_candidates import ADTransposeProjector, FFTProjector

    from lfsim import init_backend, paper_optics
    from recon.projector import LightFieldProjector, SparseProjector
    from recon.psf import compute_psf_bank

    info = init_backend()
    optics = paper_optics()
    depths = np.linspace(100.0, 300.0, args.depths)
    bank = compute_psf_bank(optics, depths, args.s, rays_per_pattern=100_000)
    grid = (85, 53)
    gather = LightFieldProjector(bank, grid)
    ad = ADTransposeProjector(bank, grid)
    fft = FFTProjector(bank, grid)
    sparse = SparseProjector(bank, grid)
    rng = np.random.default_rng(0)
    x = rng.random(gather.volume_shape).astype(np.float32)
    y = rng.random(gather.image_shape).astype(np.float32)
    ref_f, ref_b = gather.forward(x), gather.backward(y)

    def close(a, b):
        return np.abs(a - b).max() <= 1e-5 * np.abs(b).max()

    assert close(sparse.forward(x), ref_f), "sparse forward disagrees"
    assert close(sparse.backward(y), ref_b), "sparse backward disagrees"
    assert close(ad.backward(y), ref_b), "AD transpose disagrees"
    assert close(fft.forward(x), ref_f), "FFT forward disagrees"
    assert close(fft.backward(y), ref_b), "FFT backward disagrees"
    macs = gather.macs_per_projection
    rows = [
        (
            "Dr.Jit gather (GPU path)",
            _best(lambda: gather.forward(x), args.repeats),
            _best(lambda: gather.backward(y), args.repeats),
        ),
        (
            "scipy.sparse per depth (CPU)",
            _best(lambda: sparse.forward(x), args.repeats),
            _best(lambda: sparse.backward(y), args.repeats),
        ),
        ("Dr.Jit, Hᵀ by reverse AD", None, _best(lambda: ad.backward(y), args.repeats)),
        (
            "scipy.fft, freq. accumulation",
            _best(lambda: fft.forward(x), args.repeats),
            _best(lambda: fft.backward(y), args.repeats),
        ),
    ]
    print(
        f"paper optics, {grid[0]} x {grid[1]} lenslets, {len(depths)} depths, s = {args.s}, "
        f"{bank.nnz} bank non-zeros, {macs / 1e9:.2f} G multiply-adds per projection, "
        f"{info.variant}, {info.threads} threads"
    )
    print(f"{'projector':32s} {'H (s)':>8s} {'Hᵀ (s)':>8s} {'H+Hᵀ vs gather':>15s}")
    base = rows[0][1] + rows[0][2]
    for name, tf, tb in rows:
        tf_ = tf if tf is not None else rows[0][1]
        total = tf_ + tb
        print(f"{name:32s} {tf_:8.3f} {tb:8.3f} {total / base:14.1f}x")
    print("all candidates agree with the gather projector to 1e-5 (adjoint-exact)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
