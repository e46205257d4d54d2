"""Benchmark of the gridded fields against the linking they follow (run by hand, not in CI).

A synthetic series from :func:`track.synthetic.make_series`: ``--frames`` frames (default 41)
of about ``--n`` particles (default 550 seeded, ≈ 500 in the box per frame after the 5 %
drop-outs), every step the same known heterogeneous field (default ``stiff_inclusion``,
``--step`` = 0.03 mean spacings per frame), localisation noise σ = 0.25 µm laterally and
2.5 µm axially. It goes through the stages of :func:`track.pipeline.track_clouds` (what
``track link`` runs) in incremental mode: link the pairs, grid the fields, write the field
files (total ``.npz`` + ``.vti``, increment ``.npz``) into a temporary folder, and prints:

* ``link_s``, ``tracks_s``, ``fields_s``, ``write_s``: wall / CPU seconds (all threads of
  this process; with ``--workers N`` the workers' CPU is not counted) of each stage: linking
  the pairs (:func:`track.series.link_pairs`), building the tracks from them
  (:func:`track.tracks.link_tracks`, gap bridging included, which ``track_series`` runs before
  the fields), the fields (the rest of ``track_series``) and what is left of the writing
  after the last field; ``(f+w)/link`` = (fields + write) / (link + tracks), whose goal is
  ≤ 2, and ``(f+w+t)/pairs`` = (fields + write + tracks) / link, the tracks counted with the
  fields as ``track link``'s ``summary.json`` times them;
  ``load``: the 1-min load average before the case (on a shared machine the wall times grow
  with the other load, the CPU seconds much less);
* ``E_rmse``: RMSE of the six Green–Lagrange strain components of the total fields against
  the truth, over the supported nodes (mask) of every frame (``all``) and of the last frame
  (``last``); ``u_rmse``: the same for the total displacement (µm);
* with uncertainty outputs: ``cover1/cover2``, the fraction of node errors of the total
  displacement within 1σ and 2σ of ``u_std`` (per axis, pooled).

``--baseline REV`` also runs ``track`` of git revision ``REV`` (extracted with ``git archive``
to a temporary folder, today's ``synthetic.py`` and ``link_score.py`` copied in, run in a
subprocess) on the same series, side by side. ``--grid`` chooses the grids of the new code
(``default``: the ``GridSettings`` defaults; ``box``: ``target_nodes = 50 000``, the paper's
grid over the particles' bounding box; ``particles``: ``nodes_per_spacing`` (option
``--nodes-per-spacing``, default 2), the node spacing follows the particle spacing;
``particles-nostd``: the same without uncertainties); the baseline uses ``--baseline-grid``
(``default`` is then that revision's default). ``--workers 1 2`` also grids the increments
on a local Dask cluster of 2 workers (its start included in ``fields_s``).

Usage (from the repository root; ``PYTHONPATH=.`` makes this checkout's ``track`` the one
imported, ``OPENBLAS_NUM_THREADS=1`` keeps BLAS threads from fighting on a shared machine)::

    python benchmarks/bench_fields.py                               # new code only
    python benchmarks/bench_fields.py --baseline bf4f1fb --baseline-frames 6
    python benchmarks/bench_fields.py --frames 11 --grid particles particles-nostd
    python benchmarks/bench_fields.py --grid default box      # the default grid and the paper's
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import add_baseline_arguments, print_table, run_baseline_worker

GRIDS = ["default", "box", "particles", "particles-nostd"]


def _timed(fn):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def run_case(frames, n, field, step, seed, grid, nodes_per_spacing=2.0, workers=1):
    """Link and grid one series with the importable ``track``; a dict of results.

    The stages of :func:`track.pipeline.track_clouds` (``track link``), each timed (wall and
    CPU seconds): :func:`track.series.link_pairs`, :func:`track.series.track_series` on the
    pairs, and the field files it writes (total ``.npz`` + ``.vti``, increment ``.npz``).
    """
    from track.field_files import write_field_npz, write_field_vti
    from track.fields import GridSettings
    from track.series import SeriesSettings, link_pairs, track_series
    from track.strain import green_lagrange
    from track.synthetic import make_series

    s = make_series(field, n, step, frames, seed=seed)
    settings = SeriesSettings()
    if grid == "particles":
        g = dataclasses.replace(GridSettings(), nodes_per_spacing=nodes_per_spacing)
        settings = SeriesSettings(grid=g)
    elif grid == "box":
        settings = SeriesSettings(grid=dataclasses.replace(GridSettings(), target_nodes=50_000))
    elif grid == "particles-nostd":
        g = dataclasses.replace(
            GridSettings(), nodes_per_spacing=nodes_per_spacing, uncertainty=False
        )
        settings = SeriesSettings(grid=g)
    clouds = list(s.frames_xyz_um)
    load = os.getloadavg()[0]
    pairs, link_s, link_cpu = _timed(lambda: link_pairs(clouds, settings))
    kw = {}
    if workers > 1:  # (a baseline's track_series may not know the argument)
        from hrvbase.parallel import Parallel

        kw["parallel"] = Parallel(workers=workers)
    try:  # the pipeline's concurrent writer (a baseline before it writes one file at a time)
        from hrvbase.io import ConcurrentWrites
    except ImportError:
        ConcurrentWrites = None
    tmp_dir = tempfile.TemporaryDirectory(prefix="bench-fields-")
    tmp = Path(tmp_dir.name)
    ctx = ConcurrentWrites() if ConcurrentWrites else contextlib.nullcontext()
    queued = []

    def put_fields(writes, k, tot, inc):
        put = writes.submit if writes is not None else (lambda fn, *a: fn(*a))
        if tot is not None:
            put(write_field_npz, tmp / f"{k + 1:06d}.npz", tot)
            put(write_field_vti, tmp / f"{k + 1:06d}.vti", tot)
        if inc is not None:
            put(write_field_npz, tmp / f"increment_{k + 1:06d}.npz", inc)
        queued.append(k)

    # the tracks (track_series builds them before the fields) timed on their own
    import track.series as series_module

    link_tracks = getattr(series_module, "link_tracks", None)
    tracks_t = [0.0, 0.0]

    def timed_link_tracks(*a, **kw):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return link_tracks(*a, **kw)
        finally:
            tracks_t[0] += time.perf_counter() - t0
            tracks_t[1] += time.process_time() - c0

    if link_tracks is not None:
        series_module.link_tracks = timed_link_tracks
    with ctx as writes:
        # as track link does: each increment's files are queued as soon as its fields exist
        # (a baseline whose on_field gets only k writes them all after the fields)
        def on_field(k, *fields):
            if fields:
                put_fields(writes, k, *fields)

        res, fields_s, fields_cpu = _timed(
            lambda: track_series(clouds, settings, pairs=pairs, on_field=on_field, **kw)
        )

        def write():
            for k, (tot, inc) in enumerate(
                zip(res.total_fields, res.increment_fields, strict=True)
            ):
                if k not in queued:
                    put_fields(writes, k, tot, inc)

        t0, c0 = time.perf_counter(), time.process_time()
        write()
    write_s, write_cpu = time.perf_counter() - t0, time.process_time() - c0  # all written
    if link_tracks is not None:
        series_module.link_tracks = link_tracks
    tracks_s, tracks_cpu = tracks_t
    fields_s, fields_cpu = fields_s - tracks_s, fields_cpu - tracks_cpu
    tmp_dir.cleanup()
    sq_e, sq_u, last_e, inside, hits1, hits2, n_std = 0.0, 0.0, 0.0, 0, 0, 0, 0
    iu = np.triu_indices(3)
    for k, g in enumerate(res.total_fields, start=1):
        if g is None:
            continue
        X = g.axes.points()[g.mask.ravel()]
        u_true = k * s.field(X)
        F_true = np.eye(3) + k * s.field.gradient(X)
        E_true = green_lagrange(F_true)
        dE = (g.E[g.mask] - E_true)[:, iu[0], iu[1]]
        du = g.u[g.mask] - u_true
        sq_e += float(np.sum(dE**2))
        sq_u += float(np.sum(du**2))
        inside += int(X.shape[0])
        last_e = float(np.sqrt(np.mean(dE**2)))
        std = getattr(g, "u_std", None)
        if std is not None:
            sd = std[g.mask]
            ok = np.isfinite(sd)
            hits1 += int(np.sum(np.abs(du[ok]) <= sd[ok]))
            hits2 += int(np.sum(np.abs(du[ok]) <= 2 * sd[ok]))
            n_std += int(ok.sum())
    return {
        "frames": frames,
        "particles_per_frame": float(np.mean([len(f) for f in s.frames_xyz_um])),
        "grid": grid,
        "workers": workers,
        "grid_shape": list(res.axes.shape),
        "link_s": link_s,
        "tracks_s": tracks_s,
        "fields_s": fields_s,
        "write_s": write_s,
        "link_cpu": link_cpu,
        "tracks_cpu": tracks_cpu,
        "fields_cpu": fields_cpu,
        "write_cpu": write_cpu,
        "ratio": (fields_s + write_s) / (link_s + tracks_s),
        "ratio_cpu": (fields_cpu + write_cpu) / (link_cpu + tracks_cpu),
        "ratio_pairs": (fields_s + write_s + tracks_s) / link_s,
        "ratio_pairs_cpu": (fields_cpu + write_cpu + tracks_cpu) / link_cpu,
        "load": load,
        "E_rmse_all": float(np.sqrt(sq_e / max(6 * inside, 1))),
        "E_rmse_last": last_e,
        "u_rmse_all": float(np.sqrt(sq_u / max(3 * inside, 1))),
        "cover1": hits1 / n_std if n_std else float("nan"),
        "cover2": hits2 / n_std if n_std else float("nan"),
    }


def run_baseline(rev, frames, n, field, step, seed, grid="default"):
    """The same series with ``track`` of git revision ``rev`` (and today's synthetic.py).

    The series is imported from ``track.fields`` and ``track.series``, the paths every
    revision has."""
    args = ["--frames", str(frames), "--n", str(n), "--field", field]
    args += ["--step", str(step), "--seed", str(seed), "--grid", grid]
    # today's series (and what it imports)
    today = ("synthetic.py", "link_score.py")
    return run_baseline_worker(__file__, rev, args, today, "bench-fields-baseline-")


def _fmt(r, label):
    return [
        label,
        str(r["frames"]),
        f"{r['particles_per_frame']:.0f}",
        "×".join(map(str, r["grid_shape"])),
        f"{r['link_s']:.2f}/{r['link_cpu']:.2f}",
        f"{r.get('tracks_s', 0.0):.2f}/{r.get('tracks_cpu', 0.0):.2f}",
        f"{r['fields_s']:.2f}/{r['fields_cpu']:.2f}",
        f"{r['write_s']:.2f}/{r['write_cpu']:.2f}",
        f"{r['ratio']:.2f}/{r['ratio_cpu']:.2f}",
        f"{r.get('ratio_pairs', r['ratio']):.2f}/{r.get('ratio_pairs_cpu', r['ratio_cpu']):.2f}",
        f"{r['load']:.1f}",
        f"{r['E_rmse_all']:.2e}",
        f"{r['E_rmse_last']:.2e}",
        f"{r['u_rmse_all']:.3f}",
        f"{r['cover1']:.3f}/{r['cover2']:.3f}",
    ]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=41)
    ap.add_argument("--n", type=int, default=550, help="particles seeded in the box")
    ap.add_argument("--field", default="stiff_inclusion")
    ap.add_argument("--step", type=float, default=0.03, help="amplitude per frame (spacings)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--grid",
        nargs="+",
        default=["default", "box"],
        choices=GRIDS,
    )
    ap.add_argument("--nodes-per-spacing", type=float, default=2.0, help="of the 'particles' grids")
    ap.add_argument(
        "--workers",
        type=int,
        nargs="+",
        default=[1],
        help="Dask workers of the new code's fields, one row each (default 1: in process)",
    )
    add_baseline_arguments(ap)
    ap.add_argument(
        "--baseline-frames", type=int, help="frames of the baseline run (default --frames)"
    )
    ap.add_argument(
        "--baseline-grid",
        default="default",
        choices=GRIDS,
        help="grid of the baseline run (default: default)",
    )
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    if args._worker:
        row = run_case(args.frames, args.n, args.field, args.step, args.seed, args.grid[0])
        Path(args._worker).write_text(json.dumps(row))
        return
    rows = []
    if args.baseline:
        nb = args.baseline_frames or args.frames
        b = run_baseline(
            args.baseline, nb, args.n, args.field, args.step, args.seed, args.baseline_grid
        )
        rows.append((f"baseline {args.baseline} ({args.baseline_grid})", b))
    for grid in args.grid:
        for w in args.workers:
            label = f"new ({grid} grid)" + (f" {w} workers" if w > 1 else "")
            rows.append((label, run_case(*_case(args), grid, args.nodes_per_spacing, w)))
    head = ["code", "frames", "N/frame", "grid", "link_s", "tracks_s", "fields_s", "write_s"]
    head += ["(f+w)/link", "(f+w+t)/pairs", "load", "E_rmse_all", "E_rmse_last", "u_rmse"]
    head += ["cover1/2"]
    table = [_fmt(r, label) for label, r in rows]
    print_table(head, table)
    print(
        "times: wall/CPU seconds; (f+w)/link: (fields + write) / (link + tracks); "
        "(f+w+t)/pairs: (fields + write + tracks) / link; wall/CPU"
    )
    for label, r in rows:
        per = (r["fields_cpu"] + r["write_cpu"]) / max(r["frames"] - 1, 1)
        link = r["link_cpu"] / max(r["frames"] - 1, 1)
        tracks = r.get("tracks_cpu", 0.0) / max(r["frames"] - 1, 1)
        print(
            f"{label}: {per:.3f} CPU s of fields + writing per increment, {link:.3f} of "
            f"linking the pairs, {tracks:.3f} of building the tracks"
        )
    print(
        f"field {args.field}, step {args.step} spacings/frame, seed {args.seed}; "
        f"machine: {os.cpu_count()} cores, load average now {os.getloadavg()[0]:.1f}"
    )
    if args.json:
        Path(args.json).write_text(json.dumps([r for _, r in rows]))


def _case(args):
    return (args.frames, args.n, args.field, args.step, args.seed)


if __name__ == "__main__":
    main()
