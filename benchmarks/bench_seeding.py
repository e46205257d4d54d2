"""Benchmark of particle seeding (run by hand, not in CI).

Seconds to seed 10 000 particles 15 µm apart in the paper-size box (2000 × 1400 × 800 µm),
the case the seeding must finish in well under 2 s; best and median of the repeats.

Usage::

    python benchmarks/bench_seeding.py [--n 10000] [--spacing-um 15] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from lfsim.seeding import seed_box

BOX = ((-1000.0, 1000.0), (-700.0, 700.0), (-80.0, 720.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="particles (default 10000)")
    ap.add_argument("--spacing-um", type=float, default=15.0, help="spacing (default 15 µm)")
    ap.add_argument("--repeats", type=int, default=5, help="runs (default 5)")
    args = ap.parse_args()
    seconds = []
    for k in range(args.repeats):
        t0 = time.perf_counter()
        pos = seed_box(args.n, BOX, args.spacing_um, np.random.default_rng(k))
        seconds.append(time.perf_counter() - t0)
        assert pos.shape == (args.n, 3)
    print(
        f"seed_box: {args.n} particles {args.spacing_um:g} µm apart: best {min(seconds):.3f} s, "
        f"median {statistics.median(seconds):.3f} s over {args.repeats} runs"
    )


if __name__ == "__main__":
    main()
