"""Wave-optics PSF bank: build time and peak memory, side by side with pyolaf's operators.

For each microscope (``--scopes``; the optics of ``benchmarks/wave_reference.py``: the paper's
4×/0.2 dry, 20×/0.5 dry, 40×/0.8 W and 60×/1.2 W, 100 µm lenslets matched to the objective,
15 px per lenslet) the depth planes are those ``recon run`` derives from the optics
(:meth:`recon.settings.ReconSettings.resolved`), for 4× the paper's −80…720 µm in 5 µm steps
(161 planes), and ``s = --s`` (5) voxels per lenslet. Cases, each in its own subprocess
(its peak resident memory, ``getrusage``, is its own):

``ours``
    :func:`recon.psf_wave.compute_wave_psf_bank` on every plane, cold (``cache_dir=""``), at
    its default sampling (:func:`recon.psf_wave.default_wave_sampling`);
``ours@q``
    the same on ``--pyolaf-planes`` planes evenly spread over the range, at ``q / 15`` samples
    per pixel (``q`` samples per lenslet, as pyolaf's);
``pyolaf@q``
    pyolaf 0.2.1's operator build (``LFM_setCameraParams`` with ``q`` samples per lenslet,
    ``LFM_computeGeometryParameters``, ``LFM_computeLFMatrixOperators``: its wave-optics
    forward and backward patterns; ``superResFactor = s``; the paper-size 795 × 1275 px image;
    pyolaf's z axis points to the objective, so it gets the negated range) on the same
    planes. Its time and memory for all the planes are extrapolated linearly in the number of
    planes (marked ``*``).

Wall time, CPU seconds (all threads) and peak resident memory (MB) are reported, and the
machine's 1-min load average before each case (a shared machine's wall times grow with the
load, the CPU seconds much less).

Usage::

    pip install -e .[bench]                                        # pyolaf==0.2.1
    nice python benchmarks/bench_wave_bank.py                      # 4x: ours (161 planes) + pyolaf
    nice python benchmarks/bench_wave_bank.py --scopes 4x 40xW 60xW --pyolaf-px 15 45
    nice python benchmarks/bench_wave_bank.py --no-pyolaf --json out.json
    nice python benchmarks/bench_wave_bank.py --convergence --scopes 4x 60xW --pyolaf-planes 3

``--convergence``: the relative change ``‖I₂ − I₁‖ / ‖I₂‖`` of the dense patterns (all
channels of ``--pyolaf-planes`` planes, no threshold) when the default sampling is doubled,
and doubled again.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PN = 15
IMAGE_PX = (795, 1275)  # the paper-size rectified frame: 53 × 85 lenslets


def _usage() -> dict:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return {"cpu_s": r.ru_utime + r.ru_stime, "peak_rss_mb": r.ru_maxrss / 1024}


def scope_planes(name: str, s: int) -> tuple:
    """The optics and the depth planes ``recon run`` would reconstruct for them."""
    from wave_reference import make_optics

    from recon.settings import ReconSettings

    optics = make_optics(name, 11)
    st = ReconSettings(s=s).resolved(optics)
    if name == "4x":  # the paper's experiments: -80 … 720 µm (161 planes)
        st = ReconSettings(s=s, z_min_um=-80.0, z_max_um=720.0, z_step_um=5.0)
    return optics, [float(z) for z in st.depths_um]


def case_ours(p: dict) -> dict:
    import numpy as np

    from lfsim.wave import WaveSampling
    from recon.psf_wave import compute_wave_psf_bank, default_wave_sampling

    optics, depths = scope_planes(p["scope"], p["s"])
    if p.get("depths") is not None:
        depths = p["depths"]
    sampling = default_wave_sampling(optics)
    if p.get("oversample"):
        sampling = WaveSampling(oversample=p["oversample"], guard_lenslets=1.0)
    t = time.perf_counter()
    c0 = _usage()["cpu_s"]
    bank = compute_wave_psf_bank(optics, depths, p["s"], sampling=sampling, cache_dir="")
    wall = time.perf_counter() - t
    sums = np.add.reduceat(bank.w.astype(np.float64), bank.offsets[:-1])
    u = _usage()
    return {
        "planes": len(depths),
        "oversample": sampling.oversample,
        "seconds": wall,
        "cpu_s": u["cpu_s"] - c0,
        "peak_rss_mb": u["peak_rss_mb"],
        "nnz": int(bank.nnz),
        "bank_mb": (bank.w.nbytes + bank.dx.nbytes + bank.dy.nbytes) / 2**20,
        "pattern_sum": [float(sums.min()), float(sums.max())],
    }


def case_pyolaf(p: dict) -> dict:
    import contextlib
    import tempfile
    import warnings

    warnings.filterwarnings("ignore")
    import numpy as np

    try:
        import yaml
        from pyolaf.geometry import LFM_computeGeometryParameters, LFM_setCameraParams
        from pyolaf.lf import LFM_computeLFMatrixOperators
    except ImportError as exc:
        return {"error": f"pyolaf is not installed ({exc}); pip install -e .[bench]"}
    from wave_reference import pyolaf_config

    optics, _ = scope_planes(p["scope"], p["s"])
    depths = np.asarray(p["depths"], dtype=np.float64)
    step = float(depths[1] - depths[0]) if len(depths) > 1 else 1.0
    cfg = pyolaf_config(optics)
    c0 = _usage()["cpu_s"]
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(sys.stderr):
        path = Path(tmp) / "config.yaml"
        path.write_text(yaml.safe_dump(cfg))
        t = time.perf_counter()
        camera = LFM_setCameraParams(str(path), p["q"])
        centers, res, _, _ = LFM_computeGeometryParameters(
            camera,
            np.array([]),
            [-float(depths[-1]), -float(depths[0])],
            step,
            p["s"],
            False,
            imgSize=np.array(IMAGE_PX),
        )
        H, Ht = LFM_computeLFMatrixOperators(camera, res, centers)
        wall = time.perf_counter() - t
    u = _usage()
    op_bytes = 0
    for m in (*np.asarray(H, dtype=object).flat, *np.asarray(Ht, dtype=object).flat):
        if hasattr(m, "indptr"):  # scipy.sparse
            op_bytes += m.data.nbytes + m.indices.nbytes + m.indptr.nbytes
        elif isinstance(m, np.ndarray):
            op_bytes += m.nbytes
    return {
        "planes": len(res["depths"]),
        "seconds": wall,
        "cpu_s": u["cpu_s"] - c0,
        "peak_rss_mb": u["peak_rss_mb"],
        "psf_image_px": list(H[0, 0, 0].shape),
        "operator_mb": op_bytes / 2**20,
    }


def convergence(name: str, s: int, k: int) -> str:
    """Relative change ``‖I₂ − I₁‖ / ‖I₂‖`` of the bank's dense patterns (no threshold) on
    ``k`` planes when the default sampling is doubled (and doubled again)."""
    from dataclasses import replace

    from recon.psf_wave import compute_wave_psf_bank, default_wave_sampling

    optics, depths = scope_planes(name, s)
    sub = subset(depths, k)
    base = default_wave_sampling(optics)
    banks = []
    for f in (1, 2, 4):
        ws = replace(base, oversample=base.oversample * f)
        banks.append(
            compute_wave_psf_bank(optics, sub, s, sampling=ws, threshold=0.0, cache_dir="")
        )
    out = []
    for a, b in itertools.pairwise(banks):
        num = den = 0.0
        for c in range(a.n_channels):
            # the same pixels in both (every pixel of the window: no threshold)
            ka = {(y, x): w for y, x, w in zip(*a.pattern(c), strict=True)}
            kb = {(y, x): w for y, x, w in zip(*b.pattern(c), strict=True)}
            for key in ka.keys() | kb.keys():
                wa, wb = float(ka.get(key, 0.0)), float(kb.get(key, 0.0))
                num += (wa - wb) ** 2
                den += wb * wb
        out.append(f"{math.sqrt(num / den):.2g}")
    os_ = base.oversample
    return (
        f"{name}: planes {sub}; change of the patterns from oversample {os_} to {2 * os_}: "
        f"{out[0]}, from {2 * os_} to {4 * os_}: {out[1]}"
    )


CASES = {"ours": case_ours, "pyolaf": case_pyolaf}


def run_child(params: dict) -> dict:
    cmd = [sys.executable, __file__, "--case", json.dumps(params)]
    load = os.getloadavg()[0]
    t = time.perf_counter()
    env = dict(os.environ, TQDM_DISABLE="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        tail = "\n".join((proc.stderr or "").strip().splitlines()[-15:])
        return {"error": f"exit status {proc.returncode}: {tail}"}
    row = json.loads(lines[-1])
    row["process_s"] = time.perf_counter() - t
    row["load_before"] = load
    return row


def subset(depths: list[float], k: int) -> list[float]:
    """``k`` planes evenly spread over ``depths`` (from its first), a multiple of its step apart."""
    if k >= len(depths):
        return list(depths)
    if k <= 1:
        return list(depths[:1])
    stride = max(1, math.floor((len(depths) - 1) / (k - 1)))
    return depths[: stride * (k - 1) + 1 : stride]


def run_scope(name: str, args) -> list[dict]:
    _, depths = scope_planes(name, args.s)
    rows = []
    if not args.no_ours:
        r = run_child({"case": "ours", "scope": name, "s": args.s})
        rows.append({"scope": name, "who": "ours", **r})
        print(fmt(rows[-1], len(depths)), flush=True)
    if args.no_pyolaf:
        return rows
    sub = subset(depths, args.pyolaf_planes)
    for q in args.pyolaf_px:
        r = run_child(
            {"case": "ours", "scope": name, "s": args.s, "depths": sub, "oversample": q // PN}
        )
        rows.append({"scope": name, "who": f"ours@{q}", **r})
        print(fmt(rows[-1], len(depths)), flush=True)
        r = run_child({"case": "pyolaf", "scope": name, "s": args.s, "q": q, "depths": sub})
        rows.append({"scope": name, "who": f"pyolaf@{q}", **r})
        print(fmt(rows[-1], len(depths)), flush=True)
    return rows


def fmt(row: dict, planes_all: int) -> str:
    if "error" in row:
        return f"{row['scope']:5s} {row['who']:10s} error: {row['error']}"
    n = row["planes"]
    scale = planes_all / n
    star = "*" if n < planes_all else " "
    extra = f" os {row['oversample']}" if "oversample" in row else ""
    if "operator_mb" in row:
        extra += f" operators {row['operator_mb']:.0f} MB"
    if "pattern_sum" in row:
        lo, hi = row["pattern_sum"]
        extra += f", pattern sums {lo:.4f}–{hi:.4f}, {row['bank_mb']:.0f} MB bank"
    return (
        f"{row['scope']:5s} {row['who']:10s} {n:4d} planes: {row['seconds']:8.1f} s wall, "
        f"{row['cpu_s']:8.1f} s CPU, {row['peak_rss_mb']:7.0f} MB peak; all {planes_all} "
        f"planes {row['seconds'] * scale:8.1f}{star} s, {row['cpu_s'] * scale:8.1f}{star} s "
        f"CPU (load {row['load_before']:.1f}){extra}"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--scopes", nargs="+", default=["4x"], choices=["4x", "20x", "40xW", "60xW"])
    ap.add_argument("--s", type=int, default=5, help="voxels per lenslet (odd, as pyolaf's)")
    ap.add_argument(
        "--pyolaf-px", type=int, nargs="+", default=[15], help="samples per lenslet (odd)"
    )
    ap.add_argument(
        "--pyolaf-planes", type=int, default=5, help="planes of the subset pyolaf computes"
    )
    ap.add_argument("--no-pyolaf", action="store_true")
    ap.add_argument("--no-ours", action="store_true", help="skip ours on every plane")
    ap.add_argument("--json", type=Path)
    ap.add_argument(
        "--convergence",
        action="store_true",
        help="instead: the patterns' change on --pyolaf-planes planes when the default "
        "sampling is doubled, and doubled again",
    )
    args = ap.parse_args(argv)
    if args.case:
        p = json.loads(args.case)
        print(json.dumps(CASES[p["case"]](p)))
        return 0
    if args.s % 2 == 0 or any(q % PN or q % 2 == 0 for q in args.pyolaf_px):
        ap.error("--s must be odd and --pyolaf-px odd multiples of 15 (pyolaf makes them odd)")
    if args.convergence:
        for name in args.scopes:
            print(convergence(name, args.s, args.pyolaf_planes), flush=True)
        return 0
    rows = []
    for name in args.scopes:
        rows += run_scope(name, args)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
