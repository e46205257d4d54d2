"""Report files of a study: CSV tables, ``summary.json`` and ``summary.md``.

Layout (all written atomically)::

    REPORT/tables/<variant>.csv      one row per frame (or pair), see hrvptm.analysis
    REPORT/plots/*.png               hrvptm.plots
    REPORT/summary.json              study, stage times, pooled numbers, paper comparison
    REPORT/summary.md                the same as tables, with the plots
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

from hrvbase.io import atomic_write_text

from .paper import references

#: Columns shown in summary.md's per-frame table, per kind (all columns are in the CSV).
SHOWN = {
    "localization": ["frame", "snr", "n_truth", "n_detected", "n_matched", "mean_x", "mean_y",
                     "mean_z", "rmsd_x", "rmsd_y", "rmsd_z", "maxabs_x", "maxabs_y", "maxabs_z"],
    "pairs": ["pair", "snr", "fps", "n_a", "n_links", "n_correct", "tracking_ratio", "u_mean_x",
              "u_mean_y", "u_mean_z", "u_rmsd_x", "u_rmsd_y", "u_rmsd_z"],
    "series": ["frame", "amplitude", "n_detected", "n_tracked", "tracking_ratio", "u_mean_x",
               "u_mean_y", "u_mean_z", "u_rmsd_x", "u_rmsd_y", "u_rmsd_z", "E_err_xx",
               "E_err_yy", "E_err_zz", "E_err_xy", "E_err_xz", "E_err_yz", "E_rmsd_xx",
               "E_rmsd_yy", "E_rmsd_zz", "E_rmsd_xy", "E_rmsd_xz", "E_rmsd_yz"],
}  # fmt: skip


def _clean(v):
    """JSON-safe value: NaN/inf → None, numpy scalars → Python."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if hasattr(v, "item") and getattr(v, "ndim", 1) == 0:
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (replacing a previous report file)."""
    return atomic_write_text(path, text, overwrite=True)


def write_table(path: Path, rows: list[dict]) -> Path:
    """CSV of ``rows`` (the union of their keys, in first-seen order)."""
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _fmt(r.get(k)) for k in keys})
    return write_text(path, buf.getvalue())


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def comparison(figure: str, summaries: dict[str, dict]) -> list[dict]:
    """Rows ``{label, paper, bound, unit, note, <variant>: value, <variant>_meets: bool}``.

    A variant with failed frames (``summary["failed_frames"] > 0``, see
    :mod:`hrvptm.analysis`) never meets a bound: its numbers leave those frames out, so
    ``<variant>_meets`` is False on every row with a bound (and ``<variant>_failed`` True).
    """
    out = []
    for ref in references(figure):
        row = {"label": ref.label, "key": ref.key, "paper": ref.paper, "bound": ref.bound}
        row.update({"unit": ref.unit, "note": ref.note})
        for variant, s in summaries.items():
            v = s.get(ref.key)
            row[variant] = v
            failed = bool(s.get("failed_frames"))
            if failed:
                row[f"{variant}_failed"] = True
            if ref.bound is not None and v is not None and math.isfinite(v):
                row[f"{variant}_meets"] = bool(v <= ref.bound) and not failed
            elif ref.bound is not None and failed:
                row[f"{variant}_meets"] = False
        out.append(row)
    return out


def failed_line(result: dict) -> str:
    """``FAILED: …`` naming the failed frames of each variant; empty when none failed."""
    parts = []
    for variant, v in result["variants"].items():
        fails = v.get("failures") or []
        if not fails:
            continue
        frames = sorted({f["frame"] for f in fails})
        shown = "; ".join(f["reason"] for f in fails[:3])
        more = f"; … ({len(fails) - 3} more in tables/{variant}.csv)" if len(fails) > 3 else ""
        parts.append(
            f"{variant}: {len(frames)} failed frame{'s' if len(frames) > 1 else ''} "
            f"({', '.join(map(str, frames))}): {shown}{more}"
        )
    if not parts:
        return ""
    return "FAILED: " + " | ".join(parts)


def _num(v, unit: str = "um") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if unit == "strain":
        return f"{100 * v:.2f} %"
    if isinstance(v, int):
        return str(v)
    return f"{v:.3g}"


def _recon_line(rc: dict) -> str:
    """The reconstruction settings in words (``None``: derived from the optics)."""

    def v(key: str, fmt=lambda x: f"{x}") -> str:
        return "from the optics" if rc.get(key) is None else fmt(rc[key])

    z = (
        "from the optics"
        if rc.get("z_min_um") is None
        else f"[{float(rc['z_min_um'])}, {float(rc['z_max_um'])}] µm"
    )
    return (
        f"z {z}, step {v('z_step_um', lambda x: f'{float(x):g} µm')}, s = {v('s')}, "
        f"{rc['iterations']} iterations"
    )


def heterogeneous_section(result: dict) -> list[str]:
    """Markdown lines comparing a heterogeneous field with the imposed one and with the
    sampling floor (:func:`hrvptm.analysis.heterogeneous_errors`); empty for other studies.

    Per variant and component: the measured strain RMSD at the supported nodes, the floor of
    exact interpolation of the true displacements (``E_floor``), the *ideal* field (the
    imposed field at the detected particles, gridded as the study grids) and the ratio of the
    measured error to the ideal one; then the same for the gridded displacement (µm).
    """
    variants = {
        v: d["summary"]
        for v, d in result.get("variants", {}).items()
        if "pooled_E_ideal_rmsd_xx" in d.get("summary", {})
    }
    if not variants:
        return []
    lines = [
        "",
        "## Heterogeneous field against the truth and the sampling floor",
        "",
        "At the supported grid nodes, pooled over the frames: the measured field against the "
        "imposed one; *floor*: the true displacements of the tracked particles interpolated "
        "exactly; *ideal*: the imposed field at the detected particles, gridded as the study "
        "grids (what perfect localisation and tracking would give); *ratio*: measured / ideal.",
        "",
        "| variant | quantity | measured | floor | ideal | ratio |",
        "|---|---|---|---|---|---|",
    ]
    for v, s in variants.items():
        for c in ("xx", "yy", "zz", "xy", "xz", "yz"):
            ratio = s.get(f"pooled_E_ratio_ideal_{c}")
            r = f"{ratio:.2f}" if ratio is not None and math.isfinite(ratio) else "–"
            lines.append(
                f"| {v} | strain RMSD E_{c} | {_num(s.get(f'pooled_E_rmsd_{c}'), 'strain')} | "
                f"{_num(s.get(f'pooled_E_floor_rmsd_{c}'), 'strain')} | "
                f"{_num(s.get(f'pooled_E_ideal_rmsd_{c}'), 'strain')} | {r} |"
            )
        for ax in ("x", "y", "z"):
            meas, ideal = s.get(f"pooled_u_node_rmsd_{ax}"), s.get(f"pooled_u_node_ideal_rmsd_{ax}")
            ok = meas is not None and ideal is not None and ideal > 0
            r = f"{meas / ideal:.2f}" if ok and math.isfinite(meas / ideal) else "–"
            lines.append(
                f"| {v} | displacement RMSD u_{ax} (µm) | {_num(meas)} | – | {_num(ideal)} | {r} |"
            )
    return lines


def coverage_lines(variant: str, summary: dict) -> list[str]:
    """Markdown table of a variant's uncertainty coverage (:func:`hrvptm.analysis.coverage`):
    the fraction of errors within the reported 1σ and 2σ per axis, against 68 % and 95 %;
    empty when the summary has no coverage (tables without uncertainties)."""
    prefix = "u_" if "u_coverage_n" in summary else ""
    n = summary.get(f"{prefix}coverage_n")
    if not n:
        return []
    what = "displacements" if prefix else "positions"
    lines = [
        "",
        f"### {variant}: uncertainty coverage ({n} {what}; a right σ gives 68 % / 95 %)",
        "",
        "| axis | within 1σ | within 2σ | RMS(error/σ) | RMS σ (µm) |",
        "|---|---|---|---|---|",
    ]
    for ax in ("x", "y", "z"):

        def pct(key, ax=ax):
            v = summary.get(f"{prefix}{key}_{ax}")
            return "–" if v is None or not math.isfinite(v) else f"{100 * v:.0f} %"

        z = summary.get(f"{prefix}zscore_rms_{ax}")
        sg = summary.get(f"{prefix}sigma_rms_{ax}")
        lines.append(
            f"| {ax} | {pct('coverage_1sigma')} | {pct('coverage_2sigma')} | "
            f"{_num(z, 'ratio')} | {_num(sg)} |"
        )
    return lines


def markdown(study_dict: dict, result: dict) -> str:
    """``summary.md`` text from the ``summary.json`` content."""
    st = study_dict["study"]
    exp = study_dict["experiment"]["experiment"]
    lines = [
        f"# Study `{exp['name']}`" + (f" — paper Fig. {st['figure']}" if st["figure"] else ""),
        "",
        f"{exp.get('description', '')}",
        "",
        f"- kind: {st['kind']}; frames: {exp['frames']}; rendered with "
        f"`{Path(exp['scene']).name}`, reconstructed with `{Path(st['recon_scene']).name}`",
        f"- reconstruction: {_recon_line(study_dict['recon'])}",
        f"- command: `{result.get('command', '')}`",
        *_revision_line(result.get("source_revision")),
        "",
    ]
    if failed := failed_line(result):
        lines += [
            f"**{failed}**",
            "",
            "The numbers below leave the failed frames out; no comparison with the paper is "
            "met (✗).",
            "",
        ]
    # the axial self-calibration's own column, only in studies that ran it
    axial = any("axial_calibration" in v["seconds"] for v in result["variants"].values())
    lines += [
        "## Time per stage (s, this run; resumed stages count only new work)",
        "",
        "| variant | simulate | reconstruct | "
        + ("axial calibration | " if axial else "")
        + "track | analyse |",
        "|---|---|---|---|---|" + ("---|" if axial else ""),
    ]
    for variant, v in result["variants"].items():
        t = v["seconds"]
        cal = f"{t.get('axial_calibration', 0):.0f} | " if axial else ""
        lines.append(
            f"| {variant} | {t.get('simulate', 0):.0f} | {t.get('reconstruct', 0):.0f} | "
            f"{cal}{t.get('track', 0):.0f} | {t.get('analyse', 0):.1f} |"
        )
    comp = result.get("comparison", [])
    variants = list(result["variants"])
    if comp:
        lines += ["", "## Side by side with the paper", ""]
        head = "| quantity | paper | " + " | ".join(variants) + " | note |"
        lines += [head, "|" + "---|" * (3 + len(variants))]
        for row in comp:
            cells = []
            for v in variants:
                cell = _num(row.get(v), row["unit"])
                if row.get(f"{v}_failed") and f"{v}_meets" in row:
                    cell += " ✗ (failed frames)"
                elif f"{v}_meets" in row:
                    cell += " ✓" if row[f"{v}_meets"] else " ✗"
                cells.append(cell)
            lines.append(
                f"| {row['label']} | {_num(row['paper'], row['unit'])} | "
                + " | ".join(cells)
                + f" | {row['note']} |"
            )
        lines += ["", "✓/✗: within / beyond the paper's figure (the acceptance bound)."]
    for variant, v in result["variants"].items():
        lines += ["", f"## {variant}: pooled numbers", ""]
        lines += ["| quantity | value |", "|---|---|"]
        for k, val in v["summary"].items():
            unit = "strain" if "_E_" in k and "_ratio_" not in k else "um"
            lines.append(f"| {k} | {_num(val, unit)} |")
        lines += coverage_lines(variant, v["summary"])
        rows = v.get("rows", [])
        cols = [c for c in SHOWN[st["kind"]] if rows and c in rows[0]]
        if rows:
            lines += ["", f"### {variant}: per frame (all columns: `tables/{variant}.csv`)", ""]
            lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
            for r in rows:
                vals = []
                for c in cols:
                    x = r.get(c)
                    vals.append(_num(x, "strain" if c.startswith("E_") else "um"))
                lines.append("| " + " | ".join(vals) + " |")
    lines += heterogeneous_section(result)
    if result.get("plots"):
        lines += ["", "## Plots", ""]
        for p in result["plots"]:
            lines.append(f"![{Path(p).stem}]({p})")
    lines.append("")
    return "\n".join(lines)


def _revision_line(rev) -> list[str]:
    """The source revision of a report (``summary.json`` ``source_revision``), if known."""
    if not isinstance(rev, dict) or not isinstance(rev.get("commit"), str):
        return []
    mod = " with uncommitted changes" if rev.get("modified") else ""
    return [f"- code: commit `{rev['commit'][:12]}`{mod}"]


def write_summary(report_dir: Path, study_dict: dict, result: dict) -> None:
    """Write ``summary.json`` and ``summary.md``."""
    payload = _clean({"study": study_dict, **result})
    write_text(report_dir / "summary.json", json.dumps(payload, indent=1, allow_nan=False) + "\n")
    write_text(report_dir / "summary.md", markdown(study_dict, _clean(result)))
