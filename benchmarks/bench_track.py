"""Benchmark of the particle linker (run by hand, not in CI).

Side by side in one run, on the same synthetic point sets (uniform random with a minimum
spacing, 5 % of the particles missing from each frame independently, Gaussian localisation
noise of 1 % of the mean spacing per coordinate, simple shear γ = 1 about the cloud centre):

* 10 000 particles (goal < 10 s) and 60 particles (goal < 0.2 s);
* ours (:func:`track.matching.link_pair`): wall time, tracking ratio (correct matches / particles
  present in both frames), wrong matches, RMSE of the matched displacements and of the
  regularised field at the true positions (fractions of the mean spacing);
* trackpy (``pip install trackpy``, benchmark-only): ``trackpy.link_df`` on the two frames
  with ``search_range`` = ``--trackpy-range`` mean spacings (default 1; a range as large as
  the shear displacements, up to ~10 spacings, makes its subnetworks explode: >70 s for
  10 000 particles and still < 10 % correct), ratio and time.

Usage::

    python benchmarks/bench_track.py
"""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np
from scipy.spatial import cKDTree

from track.matching import link_pair
from track.synthetic import poisson_disc_cloud, score_motion


def random_cloud(n: int, seed: int, d_min_um: float = 6.0, density_um3: float = 1e-3):
    """``n`` uniform random points (µm) with pairwise distance ≥ ``d_min_um``, in a cube of
    the given number density (:func:`track.synthetic.poisson_disc_cloud`)."""
    side = (n / density_um3) ** (1 / 3)
    return poisson_disc_cloud(n, [(0.0, side)] * 3, d_min_um, seed=seed)


def make_case(n: int, seed: int):
    x = random_cloud(n, seed)
    d, _ = cKDTree(x).query(x, 2)
    s = float(d[:, 1].mean())
    c = x.mean(axis=0)

    def motion(p):
        return p + np.outer(p[:, 2] - c[2], [1.0, 0.0, 0.0])

    rng = np.random.default_rng(seed + 1)
    ia = np.flatnonzero(rng.random(n) >= 0.05)
    ib = rng.permutation(np.flatnonzero(rng.random(n) >= 0.05))
    a = x[ia] + rng.normal(0, 0.01 * s, (ia.size, 3))
    b = motion(x)[ib] + rng.normal(0, 0.01 * s, (ib.size, 3))
    return x, s, motion, a, b, ia, ib


def run_ours(case):
    x, _s, motion, a, b, ia, ib = case
    t0 = time.perf_counter()
    res = link_pair(a, b)
    dt = time.perf_counter() - t0
    ratio, wrong, raw, fld = score_motion(res, x, motion, ia, ib)
    return dt, ratio, wrong, raw, fld, res.iterations


def run_trackpy(case, range_spacings: float):
    try:
        import pandas as pd
        import trackpy as tp
    except ImportError:
        return None
    _, s, _, a, b, ia, ib = case
    tp.quiet()
    search = range_spacings * s
    df = pd.DataFrame(
        {
            "x": np.r_[a[:, 0], b[:, 0]],
            "y": np.r_[a[:, 1], b[:, 1]],
            "z": np.r_[a[:, 2], b[:, 2]],
            "frame": np.r_[np.zeros(len(a), int), np.ones(len(b), int)],
            "pid": np.r_[ia, ib],
        }
    )
    t0 = time.perf_counter()
    try:
        linked = tp.link_df(
            df, search_range=search, pos_columns=["x", "y", "z"], adaptive_stop=0.5 * s
        )
    except Exception as exc:  # report any trackpy failure in the table
        return time.perf_counter() - t0, f"failed: {type(exc).__name__}"
    dt = time.perf_counter() - t0
    f0 = linked[linked.frame == 0].set_index("particle")["pid"]
    f1 = linked[linked.frame == 1].set_index("particle")["pid"]
    both = f0.index.intersection(f1.index)
    good = int(np.sum(f0.loc[both].to_numpy() == f1.loc[both].to_numpy()))
    common = np.intersect1d(ia, ib).size
    return dt, good / common, int(len(both) - good), search / s


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 60])
    ap.add_argument("--no-trackpy", action="store_true")
    ap.add_argument("--trackpy-range", type=float, default=1.0, help="search_range / spacing")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    rows = []
    for n in args.sizes:
        case = make_case(n, seed=11)
        dt, ratio, wrong, raw, fld, its = run_ours(case)
        rows.append(
            (
                f"ours  N={n}",
                f"{dt:8.3f}",
                f"{ratio:7.4f}",
                f"{wrong:6d}",
                f"{raw:7.4f}",
                f"{fld:7.4f}",
                f"{its}",
            )
        )
        if not args.no_trackpy:
            tp_out = run_trackpy(case, args.trackpy_range)
            if tp_out is None:
                rows.append(
                    (f"trackpy N={n}", "not installed (pip install trackpy)", "", "", "", "", "")
                )
            elif isinstance(tp_out[1], str):
                rows.append((f"trackpy N={n}", f"{tp_out[0]:8.3f}", tp_out[1], "", "", "", ""))
            else:
                dt2, ratio2, wrong2, sr = tp_out
                rows.append(
                    (
                        f"trackpy N={n}",
                        f"{dt2:8.3f}",
                        f"{ratio2:7.4f}",
                        f"{wrong2:6d}",
                        "",
                        "",
                        f"sr={sr:.2f}s",
                    )
                )
    head = ("case", "time_s", "ratio", "wrong", "rmse_raw", "rmse_fld", "iters/notes")
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    for r in [head, *rows]:
        print("  ".join(str(v).ljust(w) for v, w in zip(r, widths, strict=True)))
    print("ratio: correct matches / particles in both frames; rmse: fraction of the mean spacing")


if __name__ == "__main__":
    main()
