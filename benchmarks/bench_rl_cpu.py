"""Richardson–Lucy on the CPU: the previous implementation against the current one (by hand).

Until commit ``2fdc2a8`` every iteration on the CPU copied its arrays Dr.Jit → numpy →
Dr.Jit around the scipy.sparse projector and the depth filter (the RL bookkeeping ran on
Dr.Jit); now RL computes in the projector's array world (numpy for ``SparseProjector``) and
converts once in and once out. This script times both, side by side in one process, on the
same bank, projector build, image and filter:

- **old**: ``recon/deconvolve.py``, ``recon/projector.py`` and ``recon/filters.py`` as they
  were at ``--old-rev`` (default ``2fdc2a8``), taken with ``git show`` into a temporary
  package at run time (nothing of them is kept in the repository);
- **new**: the working tree's ``recon``.

Cases (``--case``): ``small`` — the test scene (``lfsim.small_optics``, 20 × 20 lenslets,
s = 3, 49 depths −80…400 µm); ``mid`` — the paper optics on a 60 × 40-lenslet crop
(900 × 600 px), s = 5, 41 depths 100…300 µm. Images: 6 points (``small``) or 60 points over
the field of which about half land in the crop (``mid``), traced with
:func:`lfsim.tracer.trace_paraxial`. 3 iterations with the depth filter, ``track_kl=False``
(what ``recon run`` does). Old and new alternate ``--repeats`` times (after one warm-up round);
reported per path: the median wall seconds per iteration (``RLResult.seconds``) over all
repeats, the CPU seconds (all threads) of a whole call divided by its iterations (the call
also holds ``Hᵀ1`` and the conversions in and out), the wall time of a whole call, and the
largest difference of the two volumes relative to their peak. On a shared machine the CPU
seconds are the steadier measure.

Usage::

    python benchmarks/bench_rl_cpu.py [--case small mid] [--repeats 3] [--projector sparse]
"""

from __future__ import annotations

import argparse
import importlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OLD_MODULES = ("deconvolve", "projector", "filters")


def load_old(rev: str, folder: Path):
    """The old deconvolve/projector/filters modules as package ``recon_old`` (errors and psf
    are today's: their interface did not change)."""
    pkg = folder / "recon_old"
    pkg.mkdir()
    for name in OLD_MODULES:
        text = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{rev}:recon/{name}.py"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        (pkg / f"{name}.py").write_text(text)
    (pkg / "__init__.py").write_text("")
    (pkg / "errors.py").write_text("from recon.errors import *  # noqa: F403\n")
    (pkg / "psf.py").write_text("from recon.psf import *  # noqa: F403\n")
    sys.path.insert(0, str(folder))
    return {name: importlib.import_module(f"recon_old.{name}") for name in OLD_MODULES}


def problem(case: str, cache: Path):
    """(optics, bank, image, n_lenslets) of a case."""
    from lfsim import paper_optics, small_optics
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial
    from recon.geometry import depth_range
    from recon.psf import compute_psf_bank

    if case == "small":
        o = small_optics()
        n_lenslets, s, depths = (20, 20), 3, depth_range(-80, 400, 10)
        pts = np.array([[-50, 90, 150], [120, -60, 250], [0, 0, 330], [-130, 100, 390]], float)
        pts = np.r_[pts, [[80, 110, 200], [-110, -100, 300]]]
        rays = 400_000
    else:
        o = paper_optics()
        n_lenslets, s, depths = (60, 40), 5, depth_range(100, 300, 5)
        rng = np.random.default_rng(5)
        x0, x1, y0, y1 = o.field_of_view_xy_um  # about half of them land in the crop
        pts = np.c_[
            rng.uniform(x0 + 60, x1 - 60, 60),
            rng.uniform(y0 + 60, y1 - 60, 60),
            rng.uniform(110, 290, 60),
        ]
        rays = 100_000
    bank = compute_psf_bank(o, depths, s, cache_dir=cache)
    img = trace_paraxial(
        o, Sources.spheres(pts, 0.0), RenderSettings(rays_per_particle=rays, mode="expected")
    )
    n = bank.n
    img = np.ascontiguousarray(img[: n_lenslets[1] * n, : n_lenslets[0] * n], np.float32)
    return o, bank, img / rays * 100.0, n_lenslets


def run_case(case: str, old: dict, args, cache: Path) -> None:
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.projector import LightFieldProjector, SparseProjector

    o, bank, img, n_lenslets = problem(case, cache)
    kinds = ["sparse", "gather"] if args.projector == "both" else [args.projector]
    for kind in kinds:
        new_cls = SparseProjector if kind == "sparse" else LightFieldProjector
        old_cls = getattr(old["projector"], new_cls.__name__)
        paths = {
            "old": (old["deconvolve"].richardson_lucy, old_cls(bank, n_lenslets)),
            "new": (richardson_lucy, new_cls(bank, n_lenslets)),
        }
        filters = {
            "old": old["filters"].DepthFilter.for_optics(o, bank.depths_um, bank.s),
            "new": DepthFilter.for_optics(o, bank.depths_um, bank.s),
        }
        proj = paths["new"][1]
        print(
            f"\n== {case}: {n_lenslets[0]} x {n_lenslets[1]} lenslets, s = {bank.s}, "
            f"{len(bank.depths_um)} depths, volume {proj.volume_shape}, "
            f"{proj.macs_per_projection / 1e9:.2f} GMAC/projection, {kind} projector, "
            f"{args.iterations} iterations with the depth filter =="
        )
        wall = {"old": [], "new": [], "old_call": [], "new_call": []}
        cpu = {"old": [], "new": []}
        volumes = {}
        for rep in range(args.repeats + 1):  # the first round warms up (kernel compilation)
            for name in ("old", "new"):
                rl, p = paths[name]
                c0 = time.process_time()
                t0 = time.perf_counter()
                res = rl(img, p, args.iterations, depth_filter=filters[name], track_kl=False)
                t_call = time.perf_counter() - t0
                c_call = time.process_time() - c0
                volumes[name] = res.volume
                if rep == 0:
                    continue
                wall[name].extend(res.seconds)
                wall[f"{name}_call"].append(t_call)
                cpu[name].append(c_call / max(res.iterations, 1))
        diff = np.abs(volumes["new"] - volumes["old"]).max() / volumes["old"].max()
        print(
            f"{'path':5s} {'wall s/it':>10s} {'cpu s/it':>10s} {'call s':>8s}   "
            f"(medians over {args.repeats} repeats; cpu s/it: CPU of a call / iterations)"
        )
        for name in ("old", "new"):
            print(
                f"{name:5s} {median(wall[name]):10.3f} {median(cpu[name]):10.3f} "
                f"{median(wall[f'{name}_call']):8.3f}"
            )
        print(
            f"new / old: wall per iteration {median(wall['new']) / median(wall['old']):.2f}, "
            f"CPU per iteration {median(cpu['new']) / median(cpu['old']):.2f}, "
            f"call {median(wall['new_call']) / median(wall['old_call']):.2f}; "
            f"volumes differ by {diff:.1e} of the peak"
        )


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--case", nargs="+", choices=("small", "mid"), default=["small", "mid"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--projector", choices=("sparse", "gather", "both"), default="sparse")
    ap.add_argument("--old-rev", default="2fdc2a8", help="commit of the old implementation")
    ap.add_argument("--threads", type=int, default=None, help="Dr.Jit threads (default: all)")
    args = ap.parse_args()
    if args.repeats < 1 or args.iterations < 1:
        ap.error("--repeats and --iterations must be >= 1")
    sys.path.insert(0, str(ROOT))
    from lfsim import init_backend

    info = init_backend(threads=args.threads)
    print(
        f"machine: {os.cpu_count()} cores, Dr.Jit {info.device} with {info.threads} threads; "
        f"load average {os.getloadavg()[0]:.2f}; old = {args.old_rev}, new = working tree"
    )
    with tempfile.TemporaryDirectory(prefix="bench_rl_cpu_") as tmp:
        old = load_old(args.old_rev, Path(tmp))
        for case in args.case:
            run_case(case, old, args, Path(tmp) / "psf")
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
