"""Gather finished study reports into one Markdown page (``docs/validation.md``).

Each report's ``summary.md`` becomes a section (its headings moved one level down); its
plots are copied next to the page, under ``<page stem>/<study name>/``, so the page stands
on its own; plots of an earlier collection of the same page that it no longer shows are
removed from there. Nothing is written unless every report is complete. The folder's
:data:`MANIFEST` lists the files ``collect`` wrote there: only those are ever replaced (with
``--overwrite``) or removed; a file of the user's is never touched.

With the plots goes the report's record (:data:`RECORD_FILES`: its ``summary.md``,
``summary.json``, ``study.json`` and ``tables/``), so that such a folder is itself a report
``collect`` reads: after re-running only the studies a change affects, the page is collected
again from the new reports and the stored records of the others::

    hrvptm collect NEW_REPORT docs/validation/fig7_shear_impact ... -o docs/validation.md \
        --preamble docs/validation_intro.md --overwrite
"""

from __future__ import annotations

import logging
import os
import re
from datetime import UTC, datetime
from pathlib import Path

from .config import AS_AIR
from .errors import StudyError

log = logging.getLogger(__name__)

#: A report's files kept beside the page with its plots (its record), and its tables.
RECORD_FILES = ("summary.md", "summary.json", "study.json")
RECORD_TABLES = "tables"

#: The record, in the page's plot folder, of the files ``collect`` wrote there (relative
#: paths): the only files a later collection of the page replaces or removes.
MANIFEST = "collect.json"


def _read_summary(report: Path) -> tuple[str, dict]:
    from hrvbase.errors import HrvError
    from hrvbase.io import read_json

    md, js = report / "summary.md", report / "summary.json"
    if not md.is_file() or not js.is_file():
        raise StudyError(
            f"{report} holds no finished study (summary.md and summary.json are missing); "
            f"run `hrvptm study EXPERIMENT.toml -o {report}` first"
        )
    try:
        data = read_json(js)
    except HrvError as exc:
        raise StudyError(f"{js}: {exc}") from None
    try:
        exp = data["study"]["experiment"]["experiment"]
        ok = (
            isinstance(exp["name"], str)
            and isinstance(data["variants"], dict)
            and all(isinstance(v, dict) for v in data["variants"].values())
            and isinstance(data.get("comparison", []), list)
            and all(isinstance(r, dict) for r in data.get("comparison", []))
            and isinstance(data.get("plots", []), list)
            and all(isinstance(p, str) for p in data.get("plots", []))
        )
    except (KeyError, TypeError):
        ok = False
    if not ok:
        raise StudyError(
            f"{js} is not the summary.json of a finished hrvptm study (its study name, "
            "variants, comparison or plots are missing or of the wrong type); run the study "
            "again"
        )
    return _read_text(md, "report page"), data


def _read_text(path: Path, what: str) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise StudyError(f"{what} {path} is not UTF-8 text: {exc}") from None
    except IsADirectoryError:
        raise StudyError(f"{what} {path} is a folder; expected a Markdown file") from None


def _fmt(v, unit: str) -> str:
    if v is None:
        return "–"
    return f"{100 * v:.2f} %" if unit == "strain" else f"{v:.3g}"


def _overview(loaded) -> list[str]:
    """One table of every report's comparison with the paper, and the time each took."""
    lines = [
        "## Overview",
        "",
        "| study | quantity | paper | ours (no inverse crime) | ours (matched model) "
        "| ours, specimen left out (as air) |",
        "|---|---|---|---|---|---|",
    ]
    times = [
        "",
        "| study | frames | simulate (s) | reconstruct (s) | track (s) |",
        "|---|---|---|---|---|",
    ]
    for report, _md, data in loaded:
        try:
            rows, timings = _overview_rows(data)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise StudyError(
                f"{report / 'summary.json'}: unexpected content ({type(exc).__name__}: {exc}); "
                "is it the summary of a finished hrvptm study?"
            ) from None
        lines += rows
        times += timings
    lines += ["", "✓/✗: within / beyond the paper's figure.", ""]
    lines += _coverage_overview(loaded)
    lines += ["### Time on this machine (all runs of the stage, resumed ones included)"]
    return lines + times + [""]


def _coverage_of(summary: dict) -> tuple[int, dict] | None:
    """(n, {(axis, k): fraction}) of a variant's uncertainty coverage (k = 1, 2), or None
    when its tables carry no σ (:func:`hrvptm.analysis.coverage`)."""
    prefix = "u_" if "u_coverage_n" in summary else ""
    n = summary.get(f"{prefix}coverage_n")
    if not isinstance(n, int | float) or not n > 0:
        return None
    cov = {}
    for ax in "xyz":
        for k in (1, 2):
            v = summary.get(f"{prefix}coverage_{k}sigma_{ax}")
            cov[ax, k] = float(v) if isinstance(v, int | float) else float("nan")
    return int(n), cov


def _coverage_overview(loaded) -> list[str]:
    """The uncertainty coverage of every report's variants side by side, and pooled over the
    studies (each variant weighted by its number of errors): the fraction of errors within
    1σ and 2σ per axis, 68.3 % and 95.4 % for a right σ. The ``as_air`` variants, the
    specimen deliberately left out of the model, are listed but not pooled."""
    rows, pooled, unpooled = [], {}, False
    for _report, _md, data in loaded:
        name = data["study"]["experiment"]["experiment"]["name"]
        for variant, v in data["variants"].items():
            got = _coverage_of(v.get("summary") or {})
            if got is None:
                continue
            n, cov = got
            cells = [f"{100 * cov[ax, 1]:.0f} / {100 * cov[ax, 2]:.0f}" for ax in "xyz"]
            rows.append(f"| {name} ({variant}) | {n} | " + " | ".join(cells) + " |")
            if variant == AS_AIR:
                unpooled = True
                continue
            for key, frac in cov.items():
                if frac == frac:  # not NaN
                    s, w = pooled.get(key, (0.0, 0))
                    pooled[key] = (s + frac * n, w + n)
    if not rows:
        return []
    total = [
        f"{100 * pooled[ax, 1][0] / pooled[ax, 1][1]:.0f} / "
        f"{100 * pooled[ax, 2][0] / pooled[ax, 2][1]:.0f}"
        if (ax, 1) in pooled and (ax, 2) in pooled
        else "–"
        for ax in "xyz"
    ]
    n_all = max((w for _, w in pooled.values()), default=0)
    return [
        "### Uncertainty coverage (% of errors within 1σ / 2σ; a right σ gives 68 / 95)",
        "",
        "| study | errors | x | y | z |",
        "|---|---|---|---|---|",
        *rows,
        f"| **all studies** | {n_all} | " + " | ".join(f"**{c}**" for c in total) + " |",
        "",
        *(
            [
                f"The {AS_AIR} variants (the specimen left out of the model on purpose) are not in "
                "the row *all studies*.",
                "",
            ]
            if unpooled
            else []
        ),
    ]


def _overview_rows(data: dict) -> tuple[list[str], list[str]]:
    """One report's rows of the comparison table and of the table of times."""
    lines, times = [], []
    name = data["study"]["experiment"]["experiment"]["name"]
    for row in data.get("comparison", []):
        cells = []
        for variant in ("mismatched", "matched", AS_AIR):
            if variant not in row:
                cells.append("")
                continue
            cell = _fmt(row[variant], row["unit"])
            ok = row.get(f"{variant}_meets")
            cells.append(cell + ("" if ok is None else (" ✓" if ok else " ✗")))
        lines.append(
            f"| {name} | {row['label']} | {_fmt(row['paper'], row['unit'])} | "
            + " | ".join(cells)
            + " |"
        )
    frames = data["study"]["experiment"]["experiment"]["frames"]
    for variant, v in data["variants"].items():
        t = v.get("seconds_total") or {}
        times.append(
            f"| {name} ({variant}) | {frames} | {t.get('simulate', 0):.0f} | "
            f"{t.get('reconstruct', 0):.0f} | {t.get('track', 0):.0f} |"
        )
    return lines, times


#: First line of every page :func:`collect` writes; only such a page is ever replaced.
MARKER = "<!-- written by hrvptm collect; regenerate it with the same command -->"


def _check_page(page: Path, reports, preamble, overwrite: bool) -> None:
    """Refuse a page that lands on or in an input, or replaces a file ``collect`` did not write."""
    from hrvbase.io import check_output_file, guard_output

    inputs = [*reports, *([preamble] if preamble is not None else [])]
    check_output_file(page, inputs=inputs, overwrite=overwrite)
    # the page's own stored records (PAGE_STEM/<study>) are read and rewritten as they are
    assets = page.parent / page.stem
    others = [r for r in inputs if not _is_stored_record(Path(r), assets)]
    guard_output(assets, others, option="the page's plot folder")
    if page.exists():
        first = page.read_text(encoding="utf-8", errors="replace").split("\n", 1)[0]
        if first.strip() != MARKER:
            raise StudyError(
                f"{page} was not written by hrvptm collect; refusing to replace it even with "
                "--overwrite (choose another page)"
            )


def _is_stored_record(report: Path, assets: Path) -> bool:
    """Whether ``report`` is a study folder of the page's plot folder ``assets`` (a record an
    earlier collection stored there)."""
    try:
        return report.resolve().parent == assets.resolve() and report.is_dir()
    except OSError:
        return False


def _record_files(report: Path) -> list[Path]:
    """``report``'s record: :data:`RECORD_FILES` and its tables that exist."""
    files = [report / f for f in RECORD_FILES]
    tables = report / RECORD_TABLES
    files += sorted(tables.glob("*.csv")) if tables.is_dir() else []
    return [f for f in files if f.is_file()]


def _owned(assets: Path, page: Path) -> tuple[set[Path], bool]:
    """The files of the plot folder ``assets`` that an earlier collection wrote, and whether
    its record (:data:`MANIFEST`) is there.

    Without a record, a page ``collect`` wrote owns the plots it links to and the record files
    (:data:`RECORD_FILES`, tables) of the study folders it links to; a file the page does not
    name is the user's.
    """
    from hrvbase.errors import HrvError
    from hrvbase.io import read_json

    manifest = assets / MANIFEST
    if manifest.is_file():
        try:
            data = read_json(manifest)
            ok = (
                isinstance(data, dict)
                and data.get("tool") == "hrvptm collect"
                and isinstance(data.get("files"), list)
                and all(isinstance(f, str) for f in data["files"])
            )
        except HrvError:
            ok = False
        if not ok:
            raise StudyError(
                f"{manifest} was not written by hrvptm collect; refusing to replace it even "
                "with --overwrite (move it away or choose another page)"
            )
        return {assets / f for f in data["files"] if ".." not in Path(f).parts}, True
    if not page.is_file() or not assets.is_dir():
        return set(), False
    text = page.read_text(encoding="utf-8", errors="replace")
    if text.split("\n", 1)[0].strip() != MARKER:
        return set(), False
    owned: set[Path] = set()
    for study, plot in re.findall(rf"\]\({re.escape(page.stem)}/([^/)]+)/([^/)]+)\)", text):
        owned.add(assets / study / plot)
        owned.update(assets / study / f for f in RECORD_FILES)
        owned.update((assets / study / RECORD_TABLES).glob("*.csv"))
    return owned, False


def _plan(loaded, names, assets: Path) -> list[tuple[Path, Path]]:
    """(source, destination) of every plot and record file the page's folder receives."""
    plan = []
    for (report, _md, data), name in zip(loaded, names, strict=True):
        for plot in data.get("plots", []):
            src = report / plot
            if not src.is_file():  # a stored record keeps its plots beside its summary
                src = report / Path(plot).name
            if src.is_file():
                plan.append((src, assets / name / Path(plot).name))
        plan += [(src, assets / name / src.relative_to(report)) for src in _record_files(report)]
    return plan


def _check_plan(plan, assets: Path, owned: set[Path], has_manifest: bool, overwrite: bool):
    """Refuse, before anything is written, a destination that is the user's file (never
    replaced), or one ``collect`` wrote without ``overwrite``."""
    dests = [dst for src, dst in plan if _same(src, dst) is False]
    dests.append(assets / MANIFEST)
    for dst in dests:
        for folder in [Path(), *reversed(dst.relative_to(assets).parents[:-1])]:
            if os.path.lexists(assets / folder) and not (assets / folder).is_dir():
                raise StudyError(
                    f"{assets / folder} is a file where hrvptm collect puts the page's plot "
                    "folder; refusing to replace it (move it away or choose another page)"
                )
    for dst in dests:
        if not os.path.lexists(dst):
            continue
        if dst not in owned and not (dst.name == MANIFEST and has_manifest):
            raise StudyError(
                f"{dst} was not written by hrvptm collect; refusing to replace it even with "
                "--overwrite (move it away or choose another page)"
            )
        if dst.is_dir():
            raise StudyError(f"{dst} is a folder; expected a file hrvptm collect wrote")
        if not overwrite:
            raise StudyError(
                f"{dst} already exists (written by an earlier hrvptm collect); pass "
                "--overwrite to replace it"
            )


def _same(src: Path, dst: Path) -> bool:
    try:
        return src.resolve() == dst.resolve()
    except OSError:
        return False


def collect(reports, page, preamble=None, *, overwrite: bool = False) -> Path:
    """Write the page ``page`` from the report folders ``reports``; returns its path.

    Parameters
    ----------
    reports : sequence of path
        Finished study reports (``summary.md`` and ``summary.json``), or records an earlier
        collection of this page stored in ``PAGE_STEM/<study>/``.
    page : path
        Markdown page; its plots go to the folder ``PAGE_STEM/`` beside it, whose
        :data:`MANIFEST` lists the files written there.
    preamble : path, optional
        Markdown file whose text replaces the generated page header.
    overwrite : bool
        Replace a page, plots and records that an earlier ``collect`` wrote (a file it did not
        write, an input, or a path inside a report is always refused).
    """
    from hrvbase.io import atomic_write_bytes, atomic_write_text, write_json

    from . import __version__

    page = Path(page)
    _check_page(page, reports, preamble, overwrite)
    sections = []
    assets = page.parent / page.stem
    loaded = [(Path(r), *_read_summary(Path(r))) for r in reports]
    lines = [
        "# Validation: the paper's studies on synthetic light fields",
        "",
        f"Collected {datetime.now(UTC).date().isoformat()} from {len(loaded)} study reports "
        "(`hrvptm collect`). Each section is one report's `summary.md`.",
        "",
    ]
    if preamble is not None:
        pre = Path(preamble)
        if not pre.exists():
            raise StudyError(f"preamble {pre} does not exist")
        lines = [_read_text(pre, "preamble").rstrip("\n"), ""]
    lines += _overview(loaded)
    names = [data["study"]["experiment"]["experiment"]["name"] for _, _, data in loaded]
    for (report, _, _), name in zip(loaded, names, strict=True):
        if _is_stored_record(report, assets) and report.name != name:
            raise StudyError(f"{report} holds the record of study {name!r}, not {report.name!r}")
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise StudyError(f"study {dupes[0]!r} is given twice; give one report per study")
    owned, has_manifest = _owned(assets, page)
    plan = _plan(loaded, names, assets)
    _check_plan(plan, assets, owned, has_manifest, overwrite)
    written: set[Path] = set()
    for src, dst in plan:
        if not _same(src, dst):
            atomic_write_bytes(dst, src.read_bytes(), overwrite=True)
        written.add(dst)
    for (_report, md, _data), name in zip(loaded, names, strict=True):
        rel = f"{page.stem}/{name}"
        md = re.sub(r"\]\(plots/([^)]+)\)", lambda m, r=rel: f"]({r}/{m.group(1)})", md)
        md = re.sub(r"^(#+) ", lambda m: "#" + m.group(1) + " ", md, flags=re.M)
        sections.append(md)
    _prune(owned - written, assets)
    if written or has_manifest:
        files = sorted(p.relative_to(assets).as_posix() for p in written)
        record = {"tool": "hrvptm collect", "version": __version__, "page": page.name}
        write_json(assets / MANIFEST, record | {"files": files}, overwrite=True)
    atomic_write_text(page, "\n".join([MARKER, *lines, *sections]), overwrite=overwrite)
    return page


def _prune(old: set[Path], assets: Path) -> None:
    """Remove the files an earlier collection of this page wrote (``old``) and this one does
    not, and the folders below ``assets`` they leave empty; nothing else is touched."""
    for path in sorted(old):
        if path.is_file():
            log.info("removing %s (no longer on the page)", path)
            path.unlink()
    folders = {f for p in old for f in p.parents if assets in f.parents}
    for folder in sorted(folders, key=lambda p: -len(p.parts)):
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
