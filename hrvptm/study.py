"""Run a study end to end: simulate → reconstruct → track → compare with the truth → report.

:func:`run_study` drives the stages of :mod:`hrvptm.stages` for every variant of the study
(:meth:`hrvptm.config.Study.variants`), then analyses, plots and writes the report
(:mod:`hrvptm.report`). A rerun resumes: each tool skips the frames it has already done
with the same inputs, so an interrupted study continues where it stopped and a finished one
only redoes the (cheap) comparison.

The report folder is refused when it holds anything that ``hrvptm`` did not write, or
another study's outputs (unless ``overwrite``); nothing outside it is written.

A study whose frames failed (:mod:`hrvptm.analysis`: not tracked, far too few particles
detected, tracking ratio below 50 %) is *failed*: the tracking stage keeps the frames that
worked (``track`` with partial results allowed) so that the report is still written, with
``status: "failed"``, ``failed_frames`` and no comparison met; then :func:`run_study` raises
:class:`~hrvptm.errors.StageError` naming the failed frames, unless ``allow_partial``.
"""

from __future__ import annotations

import logging
import math
import time
from datetime import UTC, datetime
from pathlib import Path

from hrvbase.revision import source_revision

from . import plots
from .analysis import analyse
from .config import Study
from .errors import ReportExistsError, StageError, StudyConfigError
from .report import comparison, failed_line, write_summary, write_table
from .stages import VariantPaths, reconstruct, simulate, track_stage

log = logging.getLogger(__name__)

STAGES = ("simulate", "reconstruct", "track", "analyse")
STATE = "study.json"
TOOL = "hrvptm"


def _version() -> str:
    from . import __version__

    return __version__


def _open_report(report: Path, study: Study, overwrite: bool) -> dict:
    """Check the report folder and return its state record (new or previous)."""
    from hrvbase.errors import HrvError
    from hrvbase.io import read_json

    if report.exists() and not report.is_dir():
        raise ReportExistsError(f"report path {str(report)!r} exists and is not a folder")
    state_path = report / STATE
    if report.exists() and any(report.iterdir()):
        if not state_path.is_file():
            raise ReportExistsError(
                f"report folder {str(report)!r} is not empty and holds no {STATE} written by "
                "hrvptm; choose a new folder (nothing was written)"
            )
        try:
            state = read_json(state_path)
        except HrvError:
            state = None
        if not isinstance(state, dict) or state.get("tool") != TOOL:
            raise ReportExistsError(
                f"{state_path} was not written by hrvptm; choose a new folder (nothing was written)"
            )
        if state.get("name") != study.name and not overwrite:
            raise ReportExistsError(
                f"report folder {str(report)!r} holds the study {state.get('name')!r}, not "
                f"{study.name!r}; use another folder or --overwrite (nothing was written)"
            )
        if state.get("name") != study.name:
            state = None
        if state is not None:
            return state
    return {
        "tool": TOOL,
        "version": _version(),
        "name": study.name,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "runs": [],
        "seconds_total": {},
    }


def _save_state(report: Path, state: dict) -> None:
    from hrvbase.io import write_json

    write_json(report / STATE, state, overwrite=True)


def _plots(study: Study, results: dict, report: Path) -> list[str]:
    kind = study.study.kind
    name = study.name
    fig = f"Fig. {study.study.figure}: " if study.study.figure else ""
    out: list[Path] = []
    pdir = report / "plots"
    if kind == "localization":
        out.append(plots.plot_localization(results, pdir / "localization.png", f"{fig}{name}"))
    elif kind == "pairs":
        out.append(plots.plot_pairs(results, pdir / "pairs.png", f"{fig}{name}"))
    else:
        out.append(plots.plot_displacement(results, pdir / "displacement.png", f"{fig}{name}"))
        has_strain = any(
            any(math.isfinite(r.get("E_meas_xx", math.nan)) for r in a.rows)
            for a in results.values()
        )
        if has_strain:
            out.append(plots.plot_strain(results, pdir / "strain.png", f"{fig}{name}"))
        out.append(plots.plot_vectors(results, pdir / "vectors.png"))
        if has_strain and (study.study.time_step_s or study.study.figure == "7"):
            out.append(plots.plot_strain_history(results, pdir / "strain_history.png"))
            out.append(plots.plot_slices(results, pdir / "slices.png"))
    if any(a.arrays.get("uncertainty") is not None for a in results.values()):
        out.append(plots.plot_uncertainty(results, pdir / "uncertainty.png", f"{fig}{name}"))
    for stale in set(pdir.glob("*.png")) - set(out):  # e.g. a strain plot of an earlier run
        stale.unlink()
    return [str(p.relative_to(report)) for p in out]


def _run_stages(study, report, state, variants, seconds, last, progress, parallel) -> None:
    """Simulate, reconstruct and track every variant up to stage ``last`` (resuming), their
    seconds into ``seconds`` and the state record."""
    for variant, experiment in variants.items():
        paths = VariantPaths.of(study, report, variant)
        totals = state["seconds_total"].setdefault(variant, {})
        # a variant that reconstructs another's frames renders nothing itself
        shared = paths.dataset_root is not None
        steps = (
            (
                "simulate",
                lambda e=experiment, p=paths, s=shared: (
                    0.0 if s else simulate(e, p, progress=progress, parallel=parallel)
                ),
            ),
            (
                "reconstruct",
                lambda p=paths: reconstruct(study, p, progress=progress, parallel=parallel),
            ),
            (
                "track",
                lambda p=paths: track_stage(study, p, progress=progress, parallel=parallel),
            ),
        )
        for i, (stage, fn) in enumerate(steps):
            if i > last:
                break
            log.info("%s / %s: %s", study.name, variant, stage)
            dt = fn()
            # a stage may report its parts (the track stage: track, axial_calibration)
            for name, secs in dt.items() if isinstance(dt, dict) else [(stage, dt)]:
                seconds[variant][name] = secs
                totals[name] = totals.get(name, 0.0) + secs
            _save_state(report, state)


def run_study(
    study: Study,
    report_dir,
    *,
    until: str = "analyse",
    overwrite: bool = False,
    progress: bool = True,
    command: str = "",
    allow_partial: bool = False,
    parallel=None,
) -> dict:
    """Run (or resume) a study and write its report.

    Parameters
    ----------
    study : Study
        From :func:`hrvptm.config.load_study`.
    report_dir : path
        Report folder (created).
    until : {"simulate", "reconstruct", "track", "analyse"}
        Last stage to run (``"analyse"``: the whole study with its report).
    overwrite : bool
        Reuse a report folder that holds another study (each tool replaces only its own files).
    progress : bool
        Progress bars of the stages.
    command : str
        Command line, recorded in the report.
    allow_partial : bool
        Return a failed study's result instead of raising (the report is the same).
    parallel : hrvbase.parallel.Parallel, optional
        Where the frames of each stage run (simulation, reconstruction, detection; default:
        in process); the results are the same.

    Returns
    -------
    dict
        The content of ``summary.json`` without the study (``{}`` when ``until`` stops before
        the analysis).

    Raises
    ------
    ReportExistsError, StageError, StudyConfigError
        ``StageError`` also when frames failed (after the report is written), unless
        ``allow_partial``.
    """
    from hrvbase.parallel import shared_cluster
    from lfsim import init_backend

    if until not in STAGES:
        raise StudyConfigError(f"until must be one of {STAGES}, got {until!r}")
    last = STAGES.index(until)
    report = Path(report_dir)
    state = _open_report(report, study, overwrite)
    report.mkdir(parents=True, exist_ok=True)
    run = {"started": datetime.now(UTC).isoformat(timespec="seconds"), "until": until}
    state["runs"].append(run)
    state["source"] = str(study.source) if study.source else None
    _save_state(report, state)
    init_backend()
    variants = study.variants()
    seconds: dict[str, dict[str, float]] = {v: {} for v in variants}
    with shared_cluster(parallel) as par:  # one local cluster for every stage, if any
        _run_stages(study, report, state, variants, seconds, last, progress, par)
    if last < STAGES.index("analyse"):
        run["finished"] = datetime.now(UTC).isoformat(timespec="seconds")
        _save_state(report, state)
        return {}

    results = {}
    out_variants = {}
    for variant in variants:
        t0 = time.perf_counter()
        paths = VariantPaths.of(study, report, variant)
        try:
            a = analyse(study, paths)
        except (OSError, KeyError, ValueError) as exc:
            raise StageError(f"analysis of {paths.root}: {exc}") from exc
        write_table(report / "tables" / f"{variant}.csv", a.rows)
        results[variant] = a
        seconds[variant]["analyse"] = time.perf_counter() - t0
        out_variants[variant] = {
            "seconds": seconds[variant],
            "seconds_total": state["seconds_total"].get(variant, {}),
            "failed_frames": a.summary["failed_frames"],
            "failures": a.failures,
            "summary": a.summary,
            "rows": a.rows,
        }
    plot_files = _plots(study, results, report)
    failed_frames = sum(v["failed_frames"] for v in out_variants.values())
    result = {
        "tool": TOOL,
        "version": _version(),
        "source_revision": source_revision(),
        "command": command,
        "finished": datetime.now(UTC).isoformat(timespec="seconds"),
        "status": "failed" if failed_frames else "complete",
        "failed_frames": failed_frames,
        "allow_partial": allow_partial,
        "variants": out_variants,
        "comparison": comparison(
            study.study.figure, {v: r["summary"] for v, r in out_variants.items()}
        ),
        "plots": plot_files,
    }
    write_summary(report, study.to_dict(), result)
    run["finished"] = result["finished"]
    run["status"] = result["status"]
    _save_state(report, state)
    if failed_frames:
        message = f"study {study.name!r} failed: {failed_line(result).removeprefix('FAILED: ')}"
        if not allow_partial:
            raise StageError(
                f"{message}; report written to {report / 'summary.md'} "
                "(use --allow-partial to accept a failed study)"
            )
        log.warning("%s (--allow-partial)", message)
    return result
