"""Benchmark of the detection stage per frame, side by side for several source trees.

Detects the particles of the first ``--frames`` volumes of a folder as ``track run`` does (the
PSF estimated from the first volume, then :func:`track.detect_particles` frame after frame in
one process) once per source tree given (``--code``; default: this checkout), alternating
the trees ``--repeat`` times so that a load that changes during the run hits all of them
alike. Each run is its own subprocess with ``PYTHONPATH`` set to its tree.

Prints per tree the median seconds per frame of every sub-stage (deconvolution, band-pass,
segmentation, localisation, reading the volume), of the whole frame (wall) and of its process
CPU time (all threads); the CPU over the wall time (how many cores a frame kept busy); the
one-off PSF estimate; and the largest position difference (µm) and particle-count difference
from the first tree. The machine's load average is printed before and after: on a shared
machine compare the trees' CPU times and ratios, not the absolute wall times.

Usage::

    python benchmarks/bench_detect.py REPORT/mismatched/volumes --psf-box-um 200 60 60 \\
        --code /tmp/main-checkout . --frames 3 --repeat 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("deconvolve_s", "bandpass_s", "segment_s", "localize_s", "read_s", "total_s", "cpu_s")


def worker(a: argparse.Namespace) -> None:
    """One run (in the subprocess): JSON of per-frame timings and positions on stdout."""
    import numpy as np

    from track.detect import DetectSettings, detect_particles
    from track.pipeline import _first_psf
    from track.volumes import read_volume, scan_volumes

    vols = scan_volumes(a.volumes)[: a.frames + 1]
    kw = {"threshold": a.threshold}
    if a.psf_box_um:
        kw["psf_box_um"] = tuple(a.psf_box_um)
    settings = DetectSettings(**kw)
    t = time.perf_counter()
    psf, _ = _first_psf(read_volume(vols[0]), vols[0], settings)
    psf_s = time.perf_counter() - t
    frames = []
    for v in vols[1:]:
        w0, c0 = time.perf_counter(), time.process_time()
        vol = read_volume(v)
        read_s = time.perf_counter() - w0
        det = detect_particles(vol, v.voxel_size_um, settings, psf, origin_xyz_um=v.origin_xyz_um)
        wall = time.perf_counter() - w0
        frames.append(
            {
                **det.report["timings"],
                "read_s": read_s,
                "total_s": wall,
                "cpu_s": time.process_time() - c0,
                "cpu_per_wall": (time.process_time() - c0) / wall,
                "positions_um": np.asarray(det.positions_um).tolist(),
            }
        )
    json.dump({"psf_s": psf_s, "frames": frames}, sys.stdout)


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("volumes", type=Path, help="folder of reconstructed volumes (TIFF/Zarr)")
    ap.add_argument("--code", type=Path, nargs="+", default=[ROOT], help="source trees")
    ap.add_argument("--frames", type=int, default=3, help="frames timed after the first")
    ap.add_argument("--repeat", type=int, default=1, help="runs per tree, alternated")
    ap.add_argument("--psf-box-um", type=float, nargs=3, default=None, metavar=("Z", "Y", "X"))
    ap.add_argument("--threshold", type=float, default=0.25)
    ap.add_argument("--threads", type=int, default=None, help="HRVPTM_THREADS of the runs")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        worker(a)
        return

    args = [str(a.volumes), "--frames", str(a.frames), "--threshold", str(a.threshold)]
    if a.psf_box_um:
        args += ["--psf-box-um", *map(str, a.psf_box_um)]
    env = dict(os.environ)
    if a.threads:
        env["HRVPTM_THREADS"] = str(a.threads)
    print(f"load average before: {load()}  ({os.cpu_count()} cores)")
    runs: dict[Path, list[dict]] = {c: [] for c in a.code}
    for _ in range(a.repeat):
        for code in a.code:
            run_env = {**env, "PYTHONPATH": str(code.resolve())}
            out = subprocess.run(
                [sys.executable, __file__, *args, "--worker"],
                env=run_env,
                cwd=code,
                check=True,
                capture_output=True,
                text=True,
            ).stdout
            runs[code].append(json.loads(out))
    print(f"load average after:  {load()}")

    first = None
    head = "".join(f"{p.removesuffix('_s'):>12}" for p in PARTS)
    print(f"\n{'tree':<28}{head}{'cpu/wall':>10}{'psf':>8}{'max dpos':>10}{'dN':>5}")
    for code, rs in runs.items():
        frames = [f for r in rs for f in r["frames"]]
        med = {p: float(np.median([f.get(p, 0.0) for f in frames])) for p in PARTS}
        cpu = float(np.median([f["cpu_per_wall"] for f in frames]))
        psf = float(np.median([r["psf_s"] for r in rs]))
        pos = [np.asarray(f["positions_um"]).reshape(-1, 3) for f in rs[0]["frames"]]
        if first is None:
            first = pos
        dn = max(abs(len(p) - len(q)) for p, q in zip(pos, first, strict=True))
        dpos = max(
            (float(np.abs(p - q).max()) if len(p) == len(q) and len(p) else 0.0)
            for p, q in zip(pos, first, strict=True)
        )
        cells = "".join(f"{med[p]:12.2f}" for p in PARTS)
        print(f"{str(code)[-27:]:<28}{cells}{cpu:10.2f}{psf:8.1f}{dpos:10.2g}{dn:5d}")
    print("(median seconds per frame; max dpos in µm and dN against the first tree)")


if __name__ == "__main__":
    main()
