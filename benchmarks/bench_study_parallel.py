"""Benchmark of a whole study with its frames in parallel: ``hrvptm study --workers W``.

Runs one study file end to end (lfsim → recon → track → analysis) once per worker count
and source tree (``--code``, default this checkout: e.g. a checkout of main before a change
and this one), side by side in one run, each in a fresh report folder and its own
subprocess, after one warm-up run that fills the PSF-bank cache (so that no timed run
computes a bank the others read). Prints per run the wall time, the seconds of every stage
(from the report's ``summary.json``), the speed-up against the first run, whether the
study's tables are byte-identical to the first run's, and the load average (1 min) before
and after each run (on a shared machine compare runs made under the same load).

Usage::

    python benchmarks/bench_study_parallel.py scenes/experiments/fig7_shear_impact_test.toml
    python benchmarks/bench_study_parallel.py scenes/experiments/fig7_shear_impact.toml \\
        --workers 2 --no-warm-up      # paper size, one run (≈ 30–60 min on 2 cores)
    python benchmarks/bench_study_parallel.py short_fig7.toml --workers 1 \\
        --code /tmp/main-before . --no-warm-up   # before / after a change, same study
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
STAGES = ("simulate", "reconstruct", "track", "analyse")


def study(toml: Path, out: Path, workers: int | None, env: dict, code: Path = ROOT) -> float:
    cmd = [sys.executable, "-m", "hrvptm.cli", "-q", "study", str(toml.resolve()), "-o", str(out)]
    if workers is not None:
        cmd += ["--workers", str(workers)]
    t0 = time.perf_counter()
    path = os.pathsep.join([str(code.resolve()), env.get("PYTHONPATH", "")])
    subprocess.run(cmd, env={**env, "PYTHONPATH": path}, check=True, cwd=code)
    return time.perf_counter() - t0


def tables(report: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((report / "tables").glob("*.csv"))}


def stage_seconds(report: Path) -> dict[str, float]:
    result = json.loads((report / "summary.json").read_text())
    out = dict.fromkeys(STAGES, 0.0)
    for v in result["variants"].values():
        for stage, s in v["seconds"].items():
            out[stage] = out.get(stage, 0.0) + s
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", type=Path, help="study file (e.g. scenes/experiments/*.toml)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="default: 1 2")
    ap.add_argument("--code", type=Path, nargs="+", default=[ROOT], help="source trees")
    ap.add_argument("--no-warm-up", action="store_true", help="no warm-up run")
    ap.add_argument("--keep", type=Path, default=None, help="work in this folder (kept)")
    a = ap.parse_args()

    work = (a.keep or Path(tempfile.mkdtemp(prefix="bench_study_"))).resolve()
    work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault("HRVPTM_CACHE", str(work / "cache"))
    if not a.no_warm_up:
        t = study(a.study, work / "warm-up", None, env)
        print(f"warm-up (PSF banks into {env['HRVPTM_CACHE']}): {t:.1f} s")
    rows, first = [], None
    for w in a.workers:
        for i, code in enumerate(a.code):
            report = work / (f"w{w}" if len(a.code) == 1 else f"w{w}-tree{i}")
            load0 = os.getloadavg()[0]
            wall = study(a.study, report, w, env, code)
            tab = tables(report)
            if first is None:
                first = {"wall": wall, "tables": tab}
            load = f"{load0:.1f}/{os.getloadavg()[0]:.1f}"
            rows.append((w, code, wall, stage_seconds(report), tab == first["tables"], load))
    print(f"\nhrvptm study {a.study.name}, {os.cpu_count()} cores")
    head = " ".join(f"{s:>11}" for s in STAGES)
    print(f"{'workers':>7} {'tree':<24} {'wall s':>8} {'speed-up':>8} {head} {'identical':>9} load")
    for w, code, wall, secs, same, load in rows:
        cells = " ".join(f"{secs.get(s, 0.0):>11.1f}" for s in STAGES)
        tree = str(code)[-24:]
        print(
            f"{w:>7} {tree:<24} {wall:>8.1f} {first['wall'] / wall:>8.2f} {cells} {same!s:>9} "
            f"{load}"
        )
    print(f"(load average at the end: {os.getloadavg()[0]:.1f}; work folder {work})")


if __name__ == "__main__":
    main()
