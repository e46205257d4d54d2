"""Benchmark of the light-field simulator (run by hand, not in CI).

Measures, side by side in one run, each case in a fresh subprocess (so peak memory is its own):

- rays per second of the Mitsuba-scene tracer with ideal and glass lenslet arrays and of the
  direct Dr.Jit (paraxial) tracer;
- time and peak resident memory of one paper-size frame: 1280 × 800 px, 60 particles of
  15 µm, 10⁵ rays each (targets: ≤ 2 s ideal, ≤ 4 s glass, direct path ≥ 50 M rays/s).

The first render of a process compiles its kernels (cached on disk by Dr.Jit afterwards);
"cold" is that first call, "warm" the best of the following repeats.

Usage::

    python benchmarks/bench_lfsim.py [--threads N] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CASES = {
    "mitsuba-ideal": ("paper_4x.xml", "mitsuba", 100_000, 2.0),
    "mitsuba-glass": ("paper_4x_glass.xml", "mitsuba", 100_000, 4.0),
    "paraxial": ("paper_4x.xml", "paraxial", 1_000_000, None),
}


def run_case(name: str, repeats: int, threads: int | None) -> dict:
    import numpy as np

    from lfsim import init_backend
    from lfsim.scene import load_scene
    from lfsim.tracer import RenderSettings, Sources, trace_mitsuba, trace_paraxial

    scene_file, tracer, rays, _ = CASES[name]
    info = init_backend(threads=threads)
    scene = load_scene(ROOT / "scenes" / scene_file)
    rng = np.random.default_rng(1)
    x0, x1, y0, y1 = scene.optics.field_of_view_xy_um
    centers = np.c_[
        rng.uniform(x0 + 50, x1 - 50, 60),
        rng.uniform(y0 + 50, y1 - 50, 60),
        rng.uniform(100, 400, 60),
    ]
    src = Sources.spheres(centers, 15.0)
    settings = RenderSettings(
        rays_per_particle=rays, batch_rays=1 << (22 if tracer == "mitsuba" else 24)
    )

    def once():
        t = time.perf_counter()
        if tracer == "mitsuba":
            im = trace_mitsuba(scene, src, settings)
        else:
            im = trace_paraxial(scene.optics, src, settings)
        return time.perf_counter() - t, int(im.sum())

    cold, _ = once()
    warm = min(once()[0] for _ in range(repeats))
    n_rays = 60 * rays
    return {
        "case": name,
        "threads": info.threads,
        "rays": n_rays,
        "cold_s": cold,
        "warm_s": warm,
        "mrays_per_s": n_rays / warm / 1e6,
        "frame_s_1e5": warm * 100_000 / rays,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--case", choices=sorted(CASES), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case, args.repeats, args.threads)))
        return 0
    rows = []
    for name in CASES:
        cmd = [sys.executable, __file__, "--case", name, "--repeats", str(args.repeats)]
        if args.threads:
            cmd += ["--threads", str(args.threads)]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(
        f"paper-size frame: 1280 x 800 px, 60 particles x 1e5 rays ({rows[0]['threads']} threads)"
    )
    print(
        f"{'case':15s} {'rays':>10s} {'cold s':>8s} {'warm s':>8s} {'Mrays/s':>8s} "
        f"{'frame s':>8s} {'target s':>8s} {'peak MB':>8s}"
    )
    for r in rows:
        target = CASES[r["case"]][3]
        t = f"{target:.1f}" if target else "-"
        print(
            f"{r['case']:15s} {r['rays']:>10d} {r['cold_s']:8.2f} {r['warm_s']:8.2f} "
            f"{r['mrays_per_s']:8.1f} {r['frame_s_1e5']:8.2f} {t:>8s} {r['peak_rss_mb']:8.0f}"
        )
    ideal = rows[0]["mrays_per_s"]
    print(
        f"ratios: glass/ideal throughput {rows[1]['mrays_per_s'] / ideal:.2f}, "
        f"direct Dr.Jit/ideal Mitsuba {rows[2]['mrays_per_s'] / ideal:.1f}x "
        f"(target direct >= 50 Mrays/s: {'met' if rows[2]['mrays_per_s'] >= 50 else 'NOT met'})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
