"""Benchmark of the particle linker on the family of known fields (run by hand, not in CI).

For every field of :mod:`track.synthetic` (four homogeneous, five heterogeneous), every size
(default 1 000 and 10 000 particles) and every amplitude (default 0.5, 1.0 and 1.5 mean
spacings): a pair from :func:`track.synthetic.make_pair` (minimum-spacing cloud, both frames
cropped to the same box, 5 % of the particles missing from each frame, localisation noise
σ = 0.25 µm laterally and 2.5 µm axially at a mean spacing of about 48 µm), linked by
:func:`track.matching.link_pair` with its default settings, and scored by
:func:`track.synthetic.score_link`:

* ``ratio``: correct links / particles present in both frames (goal ≥ 0.99), ``face``: the
  same within one mean spacing of a face of the box;
* ``wrong%``: wrong links / links (goal ≤ 0.5 %);
* ``excess``: displacement RMSE of the links above the localisation-noise floor, in mean
  spacings (goal ≤ 0.01; see :class:`track.synthetic.LinkScore`);
* ``fld_x/y/z``: RMSE of the linker's regularised field at the true positions per axis (mean
  spacings), for information, and ``floor_x/y/z``: the same for the field that
  :func:`track.matching.fit_link_field` fits to the true matches (what the noise and the
  field's resolution allow);
* ``time_s``, ``cpu_s``: wall and CPU time (all threads) of :func:`link_pair`, ``load``: the
  1-min load average before the case (on a shared machine the wall times grow with the other
  load, the CPU seconds much less).

``--baseline REV`` also links the same pairs with ``track`` as it was at git revision ``REV``
(extracted to a temporary folder, run in a subprocess), side by side: its time and ratio.

Usage::

    python benchmarks/bench_heterogeneous.py                        # full table
    python benchmarks/bench_heterogeneous.py --sizes 1000 --amplitudes 1.5
    python benchmarks/bench_heterogeneous.py --baseline 9d34b8b --fields translation rotation
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np
from _common import add_baseline_arguments, print_table, run_baseline_worker


def run_cases(fields, sizes, amplitudes, seed):
    """Link every case with the importable ``track``; a list of result dicts."""
    from track.matching import link_pair
    from track.synthetic import make_pair, score_link

    try:  # the field the true matches give: the noise floor of the linker's field
        from track.matching import fit_link_field
    except ImportError:  # an older revision (--baseline)
        fit_link_field = None

    rows = []
    for n in sizes:
        for name in fields:
            for amp in amplitudes:
                pair = make_pair(name, n, amp, seed=seed)
                load = os.getloadavg()[0]
                t0, c0 = time.perf_counter(), time.process_time()
                res = link_pair(pair.ref_xyz_um, pair.def_xyz_um)
                dt, cpu = time.perf_counter() - t0, time.process_time() - c0
                sc = score_link(pair, res.matches, res.displacement_field if res.ok else None)
                floor = [float("nan")] * 3
                if fit_link_field is not None:
                    true = pair.true_matches()
                    oracle = fit_link_field(pair.ref_xyz_um, pair.def_xyz_um, true)
                    floor = list(score_link(pair, true, oracle).field_rmse_xyz_spacings)
                rows.append(
                    {
                        "field": name,
                        "n": n,
                        "amplitude": amp,
                        "max_gradient": pair.field.max_gradient,
                        "ratio": sc.tracking_ratio,
                        "face": sc.face_tracking_ratio,
                        "wrong": sc.wrong_fraction,
                        "excess": sc.excess_rmse_spacings,
                        "field_xyz": list(sc.field_rmse_xyz_spacings),
                        "field_floor_xyz": floor,
                        "time_s": dt,
                        "cpu_s": cpu,
                        "load": load,
                        "iterations": res.iterations,
                    }
                )
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def run_baseline(rev, fields, sizes, amplitudes, seed):
    """The same cases with ``track`` of git revision ``rev`` (and today's synthetic.py)."""
    args = ["--fields", *fields, "--sizes", *map(str, sizes)]
    args += ["--amplitudes", *map(str, amplitudes), "--seed", str(seed)]
    return run_baseline_worker(__file__, rev, args, ("synthetic.py",), "bench-baseline-")


def main(argv=None) -> None:
    from track.synthetic import FIELD_NAMES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fields", nargs="+", default=list(FIELD_NAMES), choices=FIELD_NAMES)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000])
    ap.add_argument("--amplitudes", type=float, nargs="+", default=[0.5, 1.0, 1.5])
    ap.add_argument("--seed", type=int, default=1)
    add_baseline_arguments(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    if args._worker:
        rows = run_cases(args.fields, args.sizes, args.amplitudes, args.seed)
        Path(args._worker).write_text(json.dumps(rows))
        return
    base = {}
    if args.baseline:
        for r in run_baseline(args.baseline, args.fields, args.sizes, args.amplitudes, args.seed):
            base[(r["field"], r["n"], r["amplitude"])] = r
    rows = run_cases(args.fields, args.sizes, args.amplitudes, args.seed)
    head = ["field", "N", "amp", "grad", "ratio", "face", "wrong%", "excess", "fld_x/y/z"]
    head += ["floor_x/y/z", "time_s", "cpu_s", "load"]
    if base:
        head += ["base_time_s", "base_cpu_s", "base_ratio", "base_wrong%"]
    table = []
    for r in rows:
        ok = r["ratio"] >= 0.99 and r["wrong"] <= 0.005 and r["excess"] <= 0.01
        line = [
            r["field"],
            str(r["n"]),
            f"{r['amplitude']:.1f}",
            f"{r['max_gradient']:.2f}",
            f"{r['ratio']:.4f}",
            f"{r['face']:.4f}",
            f"{100 * r['wrong']:.2f}",
            f"{r['excess']:.4f}",
            "/".join(f"{v:.3f}" for v in r["field_xyz"]),
            "/".join(f"{v:.3f}" for v in r.get("field_floor_xyz", [float("nan")] * 3)),
            f"{r['time_s']:.2f}" + ("" if ok else " FAIL"),
            f"{r.get('cpu_s', float('nan')):.2f}",
            f"{r.get('load', float('nan')):.1f}",
        ]
        b = base.get((r["field"], r["n"], r["amplitude"]))
        if base:
            line += (
                [
                    f"{b['time_s']:.2f}",
                    f"{b.get('cpu_s', float('nan')):.2f}",
                    f"{b['ratio']:.4f}",
                    f"{100 * b['wrong']:.2f}",
                ]
                if b
                else [""] * 4
            )
        table.append(line)
    print_table(head, table)
    print(
        "ratio/face: correct links / particles in both frames (all / within 1 spacing of a "
        "face); excess, fld: mean spacings; FAIL: ratio < 0.99, wrong > 0.5 % or excess > 0.01"
    )
    for n in args.sizes:
        t = [r["time_s"] for r in rows if r["n"] == n]
        line = f"N={n}: median time {np.median(t):.2f} s, max {np.max(t):.2f} s"
        tb = [r["time_s"] for k, r in base.items() if k[1] == n]
        if tb:
            line += f"; baseline median {np.median(tb):.2f} s, max {np.max(tb):.2f} s"
        print(line)
    print(f"machine: {os.cpu_count()} cores; load average now {os.getloadavg()[0]:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "baseline": list(base.values())}))


if __name__ == "__main__":
    main()
