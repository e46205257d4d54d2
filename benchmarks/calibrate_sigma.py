"""Calibrate the standard uncertainties of the test-size studies and measure their coverage.

The σ model (``track.detect`` and ``track.series.match_sigma``), per axis ``a``:

- a position: ``σ² = (f_a σ_loc)² + c_a² / SNR² + s_a²``;
- a displacement: ``σ² = f_a² (σ_loc,1² + σ_loc,2²) + c_a² (1/SNR_1² + 1/SNR_2²)
  + 2 b_a² (1 − ρ_a(u))``, ``ρ_a`` the correlation of the moving bias over the displacement
  ``u`` (:func:`track.series.bias_decorrelation`: lengths ``L``, lateral period ``P``);

``σ_loc`` the radial-symmetry fit's σ, ``SNR`` that of the camera frame (``recon run``
measures it), ``f`` ``sigma_noise_factor`` (one per axis), ``c`` ``sigma_snr_um`` (fitted
with ``--snr-term``, else kept at the study file's), ``s`` ``sigma_systematic_um`` and ``b``
``bias_sigma_um``; ``L`` (``bias_length_um``) and ``P``
(``bias_period_um``) are the first study file's, or with ``--fit-lengths`` ``L`` is fitted too
(one lateral length for x and y, one axial), and with ``--fit-lateral-depth`` the move in depth
over which the lateral bias changes (``bias_lateral_depth_length_um``; runs that move in z,
such as fig5b, measure it).
The studies are run *raw* (``f = 1``, ``c = s = b = 0``: σ = ``σ_loc``), so that
any ``(f, s, b, c)`` can be applied to the same errors afterwards.

1. **Calibration**: copies of the test-size studies with other seeds (default 2; ``--seed 2
   3 4`` pools three, as the shipped numbers were fitted: other particles and noise than the
   shipped ``seed = 1`` frames) are run with ``hrvptm study``
   (rendering and reconstruction resume; detection and linking are redone, so that a changed
   detector or localiser is measured) and ``(f, s, b)`` are fitted per axis on them: among the
   values whose coverage (the fraction of errors within 1σ and 2σ) is closest to 68.3 % and
   95.4 % (pooled, and for positions and displacements apart), the most likely (Gaussian).
2. **Validation**: the same studies with the shipped seed are run raw too and the coverage of
   the shipped numbers and of the fitted ones is printed per axis, per study and pooled.
3. ``--write`` puts the fitted numbers into the test-size study files that set them: for the
   default group every ``scenes/experiments/*_test.toml`` except those that run
   ``[track.axial]`` (fitted on their own copies, e.g. ``--studies fig5b_axial_layer_test``),
   for named studies their own files; ``--axes z`` fits (and writes) only z and keeps x and y
   as they are. Without positions in the calibration runs (displacements only) the
   per-particle bias ``s``, which cancels in a displacement, keeps the study file's value.

Usage (from the repository root; the work folder keeps the rendered frames between runs)::

    python benchmarks/calibrate_sigma.py -o /tmp/calib --seed 2 3 4 --bias-period-um 25 \
        --fit-lengths --snr-term                                    # fit all axes, print
    python benchmarks/calibrate_sigma.py -o /tmp/calib --axes z --write   # after a z change

Calibrating on the frames the coverage is then reported on would make it meaningless: the
validation seed must differ from the calibration seed (checked).
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's packages, as the studies it runs use
EXPERIMENTS = ROOT / "scenes" / "experiments"
#: The studies with absolute positions (4a) and displacements (4b: none; 4c: none, camera
#: noise from 100 to 25 000 fps; 5a: along x and y).
STUDIES = (
    "fig4a_localization_snr_test",
    "fig4b_zero_displacement_test",
    "fig4c_frame_rate_test",
    "fig5a_translation_x_test",
    "fig5a_translation_y_test",
)
AXES = "xyz"  # the analysis's column order
#: Lines of a study file set by the calibration (removed for the raw runs).
SIGMA_KEYS = ("sigma_noise_factor", "sigma_systematic_um", "bias_sigma_um", "sigma_snr_um")
COVER = (0.6827, 0.9545)
#: Lateral bias's depth lengths tried by ``--fit-lateral-depth`` (µm).
LATERAL_DEPTHS_UM = (10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)


# -- the runs ----------------------------------------------------------------------------------
def raw_toml(src: Path, seed: int | None, *, single: bool = False, no_axial: bool = False) -> str:
    """``src``'s text with absolute scene paths, ``seed`` (None: kept) and no σ settings;
    ``single``: without the matched-model and specimen-left-out variants; ``no_axial``:
    without ``[track.axial]``."""
    text = src.read_text(encoding="utf-8")
    if single:
        text = re.sub(r"^(matched|specimen_as_air)\s*=.*\n", "", text, flags=re.M)
    if no_axial:
        text = re.sub(r"^\[track\.axial\]\n(?:[^\[].*\n|\n)*", "", text, flags=re.M)
    for key in ("scene", "recon_scene"):
        text = re.sub(
            rf'^({key}\s*=\s*")([^"]+)(")',
            lambda m: m.group(1) + str((src.parent / m.group(2)).resolve()) + m.group(3),
            text,
            flags=re.M,
        )
    # a user field's module ("fields/f.py:func"), relative to the study file too
    text = re.sub(
        r'^(function\s*=\s*")([^"]+\.py)(:[^"]+")',
        lambda m: m.group(1) + str((src.parent / m.group(2)).resolve()) + m.group(3),
        text,
        flags=re.M,
    )
    if seed is not None:
        text, n = re.subn(r"^seed\s*=\s*\d+", f"seed = {seed}", text, count=1, flags=re.M)
        if n != 1:
            raise SystemExit(f"calibrate_sigma: {src}: no 'seed = N' line")
    return re.sub(rf"^({'|'.join(SIGMA_KEYS)})\s*=.*\n", "", text, flags=re.M)


def run(
    src: Path, seed: int | None, work: Path, retrack: bool, *, single=False, no_axial=False
) -> tuple[str, Path, Path]:
    """Run the raw copy of study ``src`` into ``work``; returns (label, toml, report)."""
    label = f"{src.stem}_seed{seed}" if seed is not None else src.stem
    label += "_noaxial" if no_axial else ""
    toml = work / f"{label}.toml"
    toml.write_text(raw_toml(src, seed, single=single, no_axial=no_axial), encoding="utf-8")
    out = work / label
    if retrack:
        for variant in ("mismatched", "matched"):
            for stage in ("detect", "axial", "track"):
                shutil.rmtree(out / variant / stage, ignore_errors=True)
    print(f"# {label}: hrvptm study {toml} -o {out}", flush=True)
    cmd = [sys.executable, "-m", "hrvptm.cli", "study", str(toml), "-o", str(out), "-q"]
    rc = subprocess.run(cmd, cwd=ROOT).returncode
    if rc != 0:
        raise SystemExit(f"calibrate_sigma: the study {toml} failed (exit {rc})")
    return label, toml, out


def samples(toml: Path, out: Path) -> dict:
    """Errors, raw σ and displacements (NaN: a position) of a raw study's mismatched run."""
    from hrvptm.analysis import analyse
    from hrvptm.config import load_study
    from hrvptm.stages import VariantPaths

    study = load_study(toml)
    det, ser = study.track.detect, study.track.series
    if (
        det.sigma_noise_factor != 1
        or any(det.sigma_systematic_um)
        or any(det.sigma_snr_um)
        or any(ser.bias_sigma_um)
    ):
        raise SystemExit(f"calibrate_sigma: {toml} is not a raw run (σ settings set)")
    unc = analyse(study, VariantPaths(out / "mismatched")).arrays["uncertainty"]
    q = unc.get("inv_snr2", np.zeros(len(unc["error"])))
    return {"error": unc["error"], "sigma": unc["sigma"], "u": unc["displacement"], "q": q}


# -- the model ---------------------------------------------------------------------------------
def _parts(d: dict, j: int, model: tuple):
    """Per sample of axis j: error, σ_loc², position?, 1 − ρ, Σ 1/SNR²; ``model`` =
    (L xyz, P)."""
    from track.series import bias_decorrelation

    e, s, u = d["error"][:, j], d["sigma"][:, j], d["u"]
    pos = ~np.all(np.isfinite(u), axis=1)
    uu = np.where(np.isfinite(u), u, 0.0)
    one_minus_rho = bias_decorrelation(uu, model[0], model[1])[:, j]
    q = np.asarray(d["q"], float)
    ok = np.isfinite(e) & np.isfinite(s) & (s > 0)
    return e[ok], s[ok] ** 2, pos[ok], one_minus_rho[ok], q[ok]


def variance(parts, f, s, b, c):
    """Model variance of every sample for (arrays of) f, s, b, c (broadcast on a leading
    axis)."""
    _, s2, pos, omr, q = parts
    f, s, b, c = (np.asarray(v, float)[..., None] for v in (f, s, b, c))
    return f**2 * s2 + c**2 * q + np.where(pos, s**2, 2 * b**2 * omr)


def cover(e, var) -> tuple:
    z = np.abs(e) / np.sqrt(var)
    return np.mean(z <= 1.0, axis=-1), np.mean(z <= 2.0, axis=-1)


def fit_axis(parts, c_fixed: float | None = 0.0) -> tuple[float, float, float, float]:
    """(f, s, b, c) of one axis: closest coverage (pooled, positions, displacements), then
    most likely; ``c`` fitted too when ``c_fixed`` is None."""
    e, pos, q = parts[0], parts[2], parts[4]
    rms_pos = float(np.sqrt(np.mean(e[pos] ** 2))) if pos.any() else 0.0
    rms_dis = float(np.sqrt(np.mean(e[~pos] ** 2))) if (~pos).any() else 0.0
    n = 61 if c_fixed is not None else 31  # a coarser grid for four parameters
    fs = np.geomspace(0.3, 30.0, n)
    ss = np.concatenate([[0.0], np.geomspace(0.01, 3 * rms_pos, n // 3 * 2)]) if rms_pos else [0.0]
    bs = np.concatenate([[0.0], np.geomspace(0.01, 3 * rms_dis, n // 3 * 2)]) if rms_dis else [0.0]
    cs = [c_fixed]
    if c_fixed is None:
        # up to the whole error at the lowest SNR (largest Σ 1/SNR²)
        qmax = float(q.max()) if q.size else 0.0
        rms = float(np.sqrt(np.mean(e**2))) if e.size else 0.0
        hi = 3 * rms / np.sqrt(qmax) if qmax > 0 and rms > 0 else 0.0
        cs = np.concatenate([[0.0], np.geomspace(hi / 300, hi, 20)]) if hi else [0.0]
    F, S, B, C = (g.ravel() for g in np.meshgrid(fs, ss, bs, cs, indexing="ij"))
    loss = np.zeros(F.size)
    nll = np.zeros(F.size)
    for lo in range(0, F.size, 4000):
        sl = slice(lo, lo + 4000)
        v = variance(parts, F[sl], S[sl], B[sl], C[sl])
        for mask, w in ((np.ones_like(pos), 1.0), (pos, 0.5), (~pos, 0.5)):
            if mask.any():
                c1, c2 = cover(e[mask], v[:, mask])
                loss[sl] += w * ((c1 - COVER[0]) ** 2 + (c2 - COVER[1]) ** 2)
        nll[sl] = np.mean(0.5 * np.log(v) + 0.5 * e**2 / v, axis=1)
    near = loss <= loss.min() + 2e-4  # within about 1 % of coverage of the best
    i = np.flatnonzero(near)[np.argmin(nll[near])]
    return float(F[i]), float(S[i]), float(B[i]), float(C[i])


# -- study files -------------------------------------------------------------------------------
def shipped_model(path: Path) -> tuple:
    """((L x, y, z, lateral depth), P) of the moving bias as a study file sets them."""
    from track.series import SeriesSettings

    ser = tomllib.loads(path.read_text(encoding="utf-8")).get("track", {})
    keys = ("bias_length_um", "bias_period_um", "bias_lateral_depth_length_um")
    st = SeriesSettings(**{k: ser[k] for k in keys if k in ser})
    return st.bias_lengths_xyz_um, st.bias_period_um


def fit_model(
    calib: dict,
    model: tuple,
    groups,
    axes: str,
    fitted: dict,
    lengths,
    snr_term: bool = False,
    lateral_depths=None,
) -> tuple:
    """Fit (f, s, b) of ``axes`` (and c with ``snr_term``, else the study file's ``c``) for
    the lateral and axial lengths in ``lengths`` (None: keep ``model``'s) and the lateral
    bias's depth lengths in ``lateral_depths`` (None: keep ``model``'s); the lengths with
    the coverage closest to the goal over the axes, then the most likely. Returns (model,
    params)."""
    base = [model[0][:3]] if lengths is None else [(a, a, z) for a, z in lengths]
    lat = [model[0][3]] if lateral_depths is None else list(lateral_depths)
    options = [((*L, d), model[1]) for L in base for d in lat]
    best = None
    for m in options:
        params, loss, nll = dict(fitted), 0.0, 0.0
        for group in groups:
            if not set(group) & set(axes):
                continue
            parts = [_parts(d, AXES.index(a), m) for d in calib.values() for a in group]
            pooled = tuple(np.concatenate([p[i] for p in parts]) for i in range(5))
            fit = fit_axis(pooled, None if snr_term else fitted[group[0]][3])
            v = variance(pooled, *fit)
            c1, c2 = cover(pooled[0], v)
            loss += float((c1 - COVER[0]) ** 2 + (c2 - COVER[1]) ** 2)
            nll += float(np.mean(0.5 * np.log(v) + 0.5 * pooled[0] ** 2 / v))
            for ax in group:  # without positions s (it cancels in displacements) is kept
                params[ax] = fit if pooled[2].any() else (fit[0], fitted[ax][1], *fit[2:])
        if len(options) > 1:
            print(
                f"  L lateral {m[0][0]:g}, axial {m[0][2]:g}, lateral in depth {m[0][3]:g} µm: "
                f"coverage loss {loss:.2e}"
            )
        if best is None or loss < best[0] - 3e-4 or (loss <= best[0] + 3e-4 and nll < best[1]):
            best = (loss, nll, m, params)
    return best[2], best[3]


def shipped_params(path: Path) -> dict:
    """(f, s, b, c) per axis (x, y, z) as a study file sets them."""
    t = tomllib.loads(path.read_text(encoding="utf-8"))
    det = t.get("track", {}).get("detect", {})
    ser = t.get("track", {})
    f = det.get("sigma_noise_factor", 1.0)
    f = [float(f)] * 3 if not isinstance(f, list) else [float(v) for v in f[::-1]]
    s = [float(v) for v in det.get("sigma_systematic_um", [0.0] * 3)[::-1]]
    b = [float(v) for v in ser.get("bias_sigma_um", [0.0] * 3)[::-1]]
    c = [float(v) for v in det.get("sigma_snr_um", [0.0] * 3)[::-1]]
    return {ax: (f[j], s[j], b[j], c[j]) for j, ax in enumerate(AXES)}


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def _runs_axial_calibration(path: Path) -> bool:
    """Whether the study file subtracts the reconstruction's bias (``[track.axial]``)."""
    spec = tomllib.loads(path.read_text(encoding="utf-8"))
    return spec.get("track", {}).get("axial", {}).get("method", "none") != "none"


def write_targets(studies: list[str]) -> list[Path]:
    """The test-size study files a fit of ``studies`` is written into: the named files when
    they are not the default group; for the default group every test-size file except those
    that run ``[track.axial]`` (the calibration removes the bias the group's numbers hold:
    such a study is fitted on its own copies, as its file says) and the specimen variants
    (``*_gel*``), which carry the numbers of the air study they repeat."""
    if list(studies) != list(STUDIES):
        return [EXPERIMENTS / f"{s}.toml" for s in studies if s.endswith("_test")]
    return [
        p
        for p in sorted(EXPERIMENTS.glob("*_test.toml"))
        if not _runs_axial_calibration(p) and "_gel" not in p.stem
    ]


def write_params(params: dict, model: tuple, paths: list[Path]) -> list[Path]:
    """Put ``params`` and the lengths and period of ``model`` into the test-size study files
    ``paths`` that set σ settings (:func:`write_targets`; the paper-size groups are written by
    hand: their files name their fit)."""
    zyx = "zyx"
    f = "[" + ", ".join(_fmt(params[a][0]) for a in zyx) + "]"
    s = "[" + ", ".join(_fmt(params[a][1]) for a in zyx) + "]"
    b = "[" + ", ".join(_fmt(params[a][2]) for a in zyx) + "]"
    c = "[" + ", ".join(_fmt(params[a][3]) for a in zyx) + "]"
    L = "[" + ", ".join(_fmt(v) for v in model[0][:3][::-1]) + "]"
    depth = _fmt(model[0][3])
    period = f"{_fmt(model[1])}   # the lenslet pitch in the object (µm); 0: none"
    done = []
    for path in paths:
        text = path.read_text(encoding="utf-8")
        new = text
        if "bias_period_um" not in new:
            new = re.sub(
                r"^(bias_length_um\s*=.*\n)", rf"\g<1>bias_period_um = {period}\n", new, flags=re.M
            )
        else:
            new = re.sub(r"^bias_period_um\s*=.*$", f"bias_period_um = {period}", new, flags=re.M)
        if model[0][3] != model[0][2] and "bias_lateral_depth_length_um" not in new:
            new = re.sub(
                r"^(bias_length_um\s*=.*\n)",
                rf"\g<1>bias_lateral_depth_length_um = {depth}\n",
                new,
                flags=re.M,
            )
        if "sigma_snr_um" not in new:
            new = re.sub(
                r"^(sigma_systematic_um\s*=.*\n)",
                r"\g<1>sigma_snr_um = [0, 0, 0]   # z, y, x (µm at SNR 1)\n",
                new,
                flags=re.M,
            )
        for key, val in (
            ("sigma_noise_factor", f),
            ("sigma_systematic_um", s),
            ("bias_sigma_um", b),
            ("sigma_snr_um", c),
            ("bias_length_um", L),
            ("bias_lateral_depth_length_um", depth),
        ):
            new = re.sub(
                rf"^({key}\s*=\s*)(\[[^\]]*\]|[0-9.eE+-]+)",
                lambda m, v=val: m.group(1) + v,
                new,
                flags=re.M,
            )
        if new != text:
            path.write_text(new, encoding="utf-8")
            done.append(path)
    return done


# -- report ------------------------------------------------------------------------------------
def table(title: str, data: dict[str, dict], params: dict, model: tuple) -> None:
    """Coverage per study and pooled, per axis, of ``params``."""
    print(f"\n{title}")
    print("| studies | n | " + " | ".join(f"{a}: 1σ / 2σ (rms z)" for a in AXES) + " |")
    print("|---|---|" + "---|" * 3)
    groups = {**{k: [k] for k in data}, "pooled": list(data)}
    for name, keys in groups.items():
        cells, n = [], 0
        for j, ax in enumerate(AXES):
            parts = [_parts(data[k], j, model) for k in keys]
            e = np.concatenate([p[0] for p in parts])
            v = np.concatenate([variance(p, *params[ax]) for p in parts])
            c1, c2 = cover(e, v)
            zr = float(np.sqrt(np.mean(e**2 / v)))
            cells.append(f"{100 * c1:.0f} % / {100 * c2:.0f} % ({zr:.2f})")
            n = len(e)
        print(f"| {'**pooled**' if name == 'pooled' else name} | {n} | " + " | ".join(cells) + " |")


def main(argv=None) -> int:
    from hrvbase.cli import add_flags

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--work", type=Path, required=True, help="work folder (kept)")
    ap.add_argument("--studies", nargs="+", default=list(STUDIES), help="test-size studies")
    ap.add_argument(
        "--seed",
        type=int,
        nargs="+",
        default=[2],
        help="calibration seeds (default 2); several pool their runs: a test-size study has "
        "about 15-25 particles, so one seed's coverage varies by several percent",
    )
    ap.add_argument("--validation-seed", type=int, default=1, help="shipped seed (default 1)")
    ap.add_argument(
        "--calibration-toml",
        nargs="+",
        type=Path,
        help="calibrate on these study files (their own seeds) instead of seed copies",
    )
    ap.add_argument("--axes", default="xyz", help="axes to fit (others keep the shipped numbers)")
    add_flags(
        ap,
        {
            "--keep-tracks": "do not redo detection",
            "--write": "update scenes/experiments/*_test.toml: the named studies' files, or for "
            "the default group every test-size file that does not run [track.axial]",
            "--single": "run the studies without their matched and as_air variants",
            "--no-axial": "run the studies without [track.axial]",
            "--lateral": "fit x and y together (one lateral model: the calibration runs' motions "
            "need not be symmetric in x and y)",
            "--no-validation": "calibrate only (the validation is the study reports themselves, "
            "e.g. at paper size)",
        },
    )
    ap.add_argument(
        "--bias-period-um",
        type=float,
        help="lateral period of the moving bias (µm, the microlens pitch in the object; 0: "
        "none); default: the first study file's bias_period_um",
    )
    add_flags(
        ap,
        {
            "--snr-term": "fit sigma_snr_um (the error that falls as 1/SNR of the camera frame) "
            "too; without it, the study file's is kept",
            "--fit-lateral-depth": "fit bias_lateral_depth_length_um (10-1000 µm), the move in "
            "depth over which the x and y bias changes; needs calibration runs that move in z "
            "(e.g. fig5b)",
            "--fit-lengths": "fit bias_length_um as well (lateral 2-12 µm, axial 5-20 µm), keeping "
            "bias_period_um as the study file sets it",
        },
    )
    args = ap.parse_args(argv)
    if args.write and (args.single or args.no_axial):
        ap.error("--write fits the test-size files as shipped: not with --single or --no-axial")
    if args.validation_seed in args.seed and not args.calibration_toml:
        ap.error("the calibration seed must differ from the validation seed")
    if set(args.axes) - set(AXES):
        ap.error(f"--axes: letters of 'xyz', got {args.axes!r}")
    args.work.mkdir(parents=True, exist_ok=True)
    retrack = not args.keep_tracks
    srcs = [EXPERIMENTS / f"{s}.toml" for s in args.studies]
    opts = {"single": args.single, "no_axial": args.no_axial}
    if args.calibration_toml:
        calib_runs = [run(p, None, args.work, retrack, **opts) for p in args.calibration_toml]
    else:
        calib_runs = [run(p, s, args.work, retrack, **opts) for s in args.seed for p in srcs]
    valid_runs = (
        []
        if args.no_validation
        else [run(p, args.validation_seed, args.work, retrack, **opts) for p in srcs]
    )
    calib = {label: samples(t, o) for label, t, o in calib_runs}
    valid = {label: samples(t, o) for label, t, o in valid_runs}
    overlap = {label for label, *_ in calib_runs} & {label for label, *_ in valid_runs}
    if overlap:
        raise SystemExit(f"calibrate_sigma: calibration and validation share {sorted(overlap)}")

    shipped = shipped_params(srcs[0])
    model_shipped = model0 = shipped_model(srcs[0])
    if args.bias_period_um is not None:
        if args.bias_period_um < 0:
            ap.error(f"--bias-period-um: ≥ 0 µm, got {args.bias_period_um:g}")
        model0 = (model0[0], args.bias_period_um)
    # x and y pooled with --lateral: the optics is symmetric in them, a study's motion is not
    groups = [("x", "y")] + [(a,) for a in AXES if a not in "xy"] if args.lateral else AXES
    grid = [(a, z) for a in (2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0) for z in (5.0, 10.0, 20.0)]
    model, fitted = fit_model(
        calib,
        model0,
        groups,
        args.axes,
        shipped,
        grid if args.fit_lengths else None,
        snr_term=args.snr_term,
        lateral_depths=LATERAL_DEPTHS_UM if args.fit_lateral_depth else None,
    )
    print(
        f"\nbias_length_um (z, y, x) {list(model_shipped[0][:3][::-1])} → "
        f"{list(model[0][:3][::-1])}; bias_lateral_depth_length_um {model_shipped[0][3]:g} → "
        f"{model[0][3]:g}; bias_period_um {model_shipped[1]:g} → {model[1]:g}"
    )
    print(
        "\n| axis | sigma_noise_factor | sigma_systematic_um | bias_sigma_um | sigma_snr_um |"
        "  (shipped → fitted)"
    )
    print("|---|---|---|---|---|")
    for ax in AXES:
        a, b = shipped[ax], fitted[ax]
        print(f"| {ax} | " + " | ".join(f"{_fmt(a[i])} → {_fmt(b[i])}" for i in range(4)) + " |")
    table("Calibration runs, fitted numbers:", calib, fitted, model)
    if valid:
        table("Validation (shipped seed), shipped numbers:", valid, shipped, model_shipped)
        table("Validation (shipped seed), fitted numbers:", valid, fitted, model)
    if args.write:
        for path in write_params(fitted, model, write_targets(args.studies)):
            print(f"updated {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
