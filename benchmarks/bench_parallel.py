"""Benchmark of frames in parallel: ``recon run --workers 1`` and ``--workers 2`` side by side.

Renders a synthetic series once (``lfsim.generate_dataset``: a small test scene, or the
paper's 1280 × 800 px microscope with ``--paper``), fills the PSF-bank cache with a one-frame
run, then times ``recon run`` on the whole series with each worker count, each in its own
subprocess, and prints per run:

- wall time of the command, speed-up against the first worker count;
- parallel efficiency ``t_frame × frames / (workers × wall)``, with ``t_frame`` one frame's
  time in the serial run (the mean of its ``recon.json`` frame times): 1 is perfect, the rest
  is start-up (imports, calibration, the PSF bank from the cache, the Dask cluster) and
  contention (threads, memory bandwidth, other load on a shared machine);
- peak resident memory of every worker process (``recon.json`` ``"parallel"``);
- whether the volumes are byte-identical to the first run's.

Usage::

    python benchmarks/bench_parallel.py                       # small scene, 6 frames
    python benchmarks/bench_parallel.py --frames 4 --iterations 2 --workers 1 2
    python benchmarks/bench_parallel.py --paper --frames 8     # paper-size frames (slow)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SMALL = {
    "scene": "small.xml",
    "particles": (
        "count = 8\nbounds_xyz_um = [[-180, 160], [-180, 160], [150, 350]]\nmin_spacing_um = 60"
    ),
    "rays": 30000,
    "recon": ["--z-range", "-40:400", "--z-step", "20", "-s", "3", "--rays-per-pattern", "20000"],
}
PAPER = {
    "scene": "paper_4x.xml",
    "particles": (
        "count = 60\nbounds_xyz_um = [[-950, 950], [-550, 550], [100, 400]]\nmin_spacing_um = 60"
    ),
    "rays": 100000,
    # the paper's reconstruction: 161 planes, 5 µm voxels (s = 5)
    "recon": ["--z-range", "-80:720", "--z-step", "5", "-s", "5"],
}


def experiment_toml(case: dict, frames: int) -> str:
    scene = (ROOT / "scenes" / case["scene"]).as_posix()
    return f"""[experiment]
name = "bench_parallel"
scene = "{scene}"
seed = 1
frames = {frames}

[particles]
kind = "box"
{case["particles"]}
diameter_um = 15

[motion]
type = "translation"
step_um = [5.0, 0.0, 0.0]

[render]
rays_per_particle = {case["rays"]}

[noise]
model = "gaussian"
snr = 30

[white]
rays_per_lenslet = 3000
"""


def recon(args: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "recon.cli", "-q", "run", *args], env=env, check=True)
    return time.perf_counter() - t0


def volumes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.glob("[0-9]*.tif"))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=6, help="frames of the series (default 6)")
    ap.add_argument("--iterations", type=int, default=3, help="Richardson-Lucy iterations")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="default: 1 2")
    ap.add_argument("--paper", action="store_true", help="paper-size frames (1280 × 800 px)")
    ap.add_argument("--keep", type=Path, default=None, help="work in this folder (kept)")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here")
    ap.add_argument("-s", type=int, default=None, help="super-resolution (default: the case's)")
    a = ap.parse_args()
    case = PAPER if a.paper else SMALL

    from lfsim import init_backend
    from lfsim.dataset import generate_dataset
    from lfsim.experiment import load_experiment

    work = a.keep or Path(tempfile.mkdtemp(prefix="bench_parallel_"))
    work.mkdir(parents=True, exist_ok=True)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    env.setdefault("HRVPTM_CACHE", str(work / "cache"))
    os.environ["HRVPTM_CACHE"] = env["HRVPTM_CACHE"]
    toml = work / "experiment.toml"
    toml.write_text(experiment_toml(case, a.frames))
    dataset = work / "dataset"
    t0 = time.perf_counter()
    init_backend()
    generate_dataset(load_experiment(toml), dataset, progress=False)
    print(
        f"series: {a.frames} frames of {case['scene']} rendered in "
        f"{time.perf_counter() - t0:.1f} s ({dataset})"
    )
    rargs = list(case["recon"])
    if a.s is not None:
        rargs[rargs.index("-s") + 1] = str(a.s)
    common = [str(dataset), *rargs, "--iterations", str(a.iterations)]
    warm = work / "warm"
    t = recon([*common, "--frames", "0:1", "-o", str(warm), "--overwrite"], env)
    print(f"PSF bank into the cache and one frame: {t:.1f} s")

    rows, first = [], None
    for w in a.workers:
        out = work / f"w{w}"
        wall = recon([*common, "--workers", str(w), "-o", str(out), "--overwrite"], env)
        meta = json.loads((out / "recon.json").read_text())
        frame_s = [f["seconds"] for f in meta["frames"]]
        peaks = meta.get("parallel", {}).get("peak_memory_bytes", {})
        vols = volumes(out)
        if first is None:
            first = {"vols": vols, "t_frame": sum(frame_s) / len(frame_s), "wall": wall}
        eff = first["t_frame"] * len(frame_s) / (w * wall)
        rows.append(
            {
                "workers": w,
                "wall_s": wall,
                "speedup": first["wall"] / wall,
                "efficiency": eff,
                "mean_frame_s": sum(frame_s) / len(frame_s),
                "peak_memory_mib": {k: v / 2**20 for k, v in peaks.items()},
                "identical": vols == first["vols"],
                "load_1min": os.getloadavg()[0],
            }
        )
    print(
        f"\nrecon run, {a.frames} frames, {a.iterations} iterations, "
        f"t_frame (serial) = {first['t_frame']:.2f} s, {os.cpu_count()} cores"
    )
    print(
        f"{'workers':>7} {'wall s':>8} {'speed-up':>8} {'effic.':>7} {'frame s':>8} "
        f"{'identical':>9}  peak memory per worker (MiB)"
    )
    for r in rows:
        mem = ", ".join(f"{v:.0f}" for _, v in sorted(r["peak_memory_mib"].items()))
        print(
            f"{r['workers']:>7} {r['wall_s']:>8.1f} {r['speedup']:>8.2f} "
            f"{r['efficiency']:>7.2f} {r['mean_frame_s']:>8.2f} {r['identical']!s:>9}  "
            f"{mem}"
        )
    print(f"(load average at the end: {os.getloadavg()[0]:.1f}; work folder {work})")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
