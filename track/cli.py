"""The ``track`` command line: detect particles, link them, grid displacement and strain.

Commands::

    track run VOLDIR -o RESULTS [--mode incremental|cumulative] [--grid-spacing-um X]
              [--threshold auto|F] [--no-deconvolution] [--overwrite] ...
    track detect VOLDIR -o RESULTS [detection options] [--overwrite]
    track link A.csv B.csv [C.csv ...] -o RESULTS [--mode ...] [--grid-spacing-um X] ...

``VOLDIR`` holds numbered float32 volumes ``NNNNNN.tif`` (voxel size in the TIFF description
or in ``recon.json``, see :mod:`track.io`); ``link`` takes point clouds (CSV with columns
``x_um, y_um, z_um``) from any localisation source, frame 0 first.

``RESULTS`` receives ``particles/NNNNNN.csv``, ``matches_NNNNNN.csv`` (one per linked pair,
``NNNNNN`` = deformed frame), ``tracks.csv``, ``fields/NNNNNN.npz`` and ``.vti`` (total
field from frame 0 to frame ``NNNNNN`` on the reference grid; incremental mode also
``fields/increment_NNNNNN.npz``) and ``summary.json`` (parameters, input checksums, counts,
tracking ratio and status of every pair, timings). Every file is written atomically.

Resuming: ``run``/``detect`` record each volume's SHA-256 in ``summary.json`` and skip the
detection of volumes whose particle table exists with the same checksum; linking and fields
are recomputed. A ``RESULTS`` folder made from other inputs or detection settings is refused
unless ``--overwrite`` (which then deletes only files ``track`` writes); a non-empty folder
without a ``summary.json`` written by ``track`` is always refused.

Exit status and failures:

- ``0``: every step worked (``summary.json`` status ``"complete"``), or some failed and
  ``--allow-partial`` was given (status ``"partial"``; each failure is a warning);
- ``2``: an error a user can cause (bad option, input file or results folder), printed as
  one line ``track: error: <message>``; an explicit ``--grid-spacing-um`` that gives more
  nodes than ``10 × --target-nodes`` (and at most 2 000 000) or a single cell is refused
  before any work;
- ``3``: the run finished but some frames failed: a pair that could not be linked (fewer
  than 4 particles, no consistent matches), a field that could not be gridded, or (``detect``)
  a volume without particles. The results of everything that worked are written (each pair's
  status in ``summary.json``, whose status is ``"failed"``), and one line names the first
  failing frames and the reason, e.g. ``track: error: frames 3 → 4: skipped: fewer than 4
  particles in frame 4 (2 found) (use --allow-partial to keep partial results)``;
- ``130``: interrupted.

Unless ``-q``, ``run``, ``detect`` and ``link`` show progress bars (on a terminal) and end
with one line on stdout such as ``RESULTS: 7 volumes, 24–25 particles/frame, 6/6 pairs
linked, tracking ratio ≥ 0.96, 6 fields, 12.3 s``.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import math
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from hrvbase.errors import HrvError

from . import __version__
from . import io as tio
from .errors import InputError
from .fields import GridSettings
from .series import (
    MAX_GRID_NODES,
    MODES,
    SeriesSettings,
    check_grid,
    link_pairs,
    track_series,
)

log = logging.getLogger("track.cli")

SUMMARY = "summary.json"

#: Exit status of a run that finished with failed frames (without ``--allow-partial``).
EXIT_FAILED = 3


class _Parser(argparse.ArgumentParser):
    """Argument parser whose errors are one line ``track: error: ...`` (exit 2)."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"track: error: {message}\n")
        raise SystemExit(2)


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def _count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


def _int_in(lo: int, hi: int):
    """argparse type: an integer in ``lo..hi``."""
    message = f"expected an integer in {lo}..{hi}, got {{!r}}"

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(message.format(text)) from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(message.format(text))
        return v

    return parse


def _keyword_or_number(keyword: str, ok, expected: str):
    """argparse type: ``keyword`` itself, or a finite number for which ``ok(v)`` holds."""
    message = f"expected '{keyword}' or {expected}, got {{!r}}"

    def parse(text: str) -> float | str:
        if text == keyword:
            return text
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(message.format(text)) from None
        if not (math.isfinite(v) and ok(v)):
            raise argparse.ArgumentTypeError(message.format(text))
        return v

    return parse


_smoothing = _keyword_or_number("gcv", lambda v: v >= 0, "a number >= 0")
_threshold = _keyword_or_number("auto", lambda v: 0 < v < 1, "a fraction in (0, 1)")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", required=True, type=Path, metavar="RESULTS")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a RESULTS folder made by track from other inputs or settings",
    )
    p.add_argument(
        "--allow-partial",
        action="store_true",
        help="keep going when frames fail (warnings, exit 0, summary status 'partial') "
        "instead of exit status 3",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more messages")
    p.add_argument("-q", "--quiet", action="store_true", help="errors only")


def _detect_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("detection")
    g.add_argument(
        "--threshold",
        type=_threshold,
        default=0.25,
        help="binarisation threshold: fraction of the intensity range (default and paper: "
        "0.25) or 'auto'",
    )
    g.add_argument(
        "--no-deconvolution", action="store_true", help="skip the secondary deconvolution"
    )
    g.add_argument(
        "--deconvolution-iterations",
        type=_count,
        default=5,
        metavar="N",
        help="Richardson-Lucy iterations of the secondary deconvolution (default 5)",
    )
    g.add_argument("--blob-min-vox", type=_count, default=None, metavar="N")
    g.add_argument("--blob-max-vox", type=_count, default=None, metavar="N")
    g.add_argument("--method", choices=("radial", "centroid"), default="radial")
    g.add_argument("--edge-margin-um", type=float, default=0.0, metavar="UM")


def _link_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("linking and fields")
    g.add_argument("--mode", choices=MODES, default="incremental")
    g.add_argument(
        "--grid-spacing-um",
        type=_positive_float,
        default=None,
        metavar="UM",
        help="node spacing of the gridded fields (default: about --target-nodes nodes); "
        "refused when it gives more than 10 × --target-nodes nodes",
    )
    g.add_argument(
        "--target-nodes",
        type=_int_in(8, MAX_GRID_NODES),
        default=GridSettings.target_nodes,
        metavar="N",
        help=f"nodes of the default grid (default {GridSettings.target_nodes}, "
        f"at most {MAX_GRID_NODES})",
    )
    g.add_argument(
        "--interpolation", choices=("rbf", "linear"), default="rbf", help="gridding method"
    )
    g.add_argument(
        "--smoothing",
        type=_smoothing,
        default="gcv",
        metavar="gcv|LAMBDA",
        help="RBF smoothing of the gridded fields: 'gcv' (default: chosen per displacement "
        "component by generalised cross-validation) or a number >= 0 (0: exact interpolation)",
    )
    g.add_argument("--no-fields", action="store_true", help="only link; no gridded fields")
    g.add_argument("--vti-encoding", choices=("binary", "ascii"), default="binary")
    g.add_argument("--seed", type=_count, default=0, help="seed of the linker's RANSAC")


def build_parser() -> argparse.ArgumentParser:
    """The ``track`` argument parser."""
    p = _Parser(prog="track", description="Particle tracking and strain from volumes.")
    p.add_argument("--version", action="version", version=f"track {__version__}")
    sub = p.add_subparsers(dest="command", parser_class=_Parser)
    r = sub.add_parser("run", help="detect → link → fields for a folder of volumes")
    r.add_argument("voldir", type=Path, metavar="VOLDIR")
    _common(r)
    _detect_options(r)
    _link_options(r)
    r.set_defaults(func=cmd_run)
    d = sub.add_parser("detect", help="detect particles in a folder of volumes")
    d.add_argument("voldir", type=Path, metavar="VOLDIR")
    _common(d)
    _detect_options(d)
    d.set_defaults(func=cmd_detect)
    k = sub.add_parser("link", help="link point clouds (CSV) and compute fields")
    k.add_argument("clouds", type=Path, nargs="+", metavar="CSV")
    _common(k)
    _link_options(k)
    k.set_defaults(func=cmd_link)
    return p


# -- results folder --------------------------------------------------------------------------
def _fingerprint(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _our_outputs(out: Path) -> list[Path]:
    """Files and folders ``track`` writes in a results folder."""
    items = [out / "particles", out / "fields", out / "tracks.csv", out / SUMMARY]
    items += sorted(out.glob("matches_[0-9][0-9][0-9][0-9][0-9][0-9].csv"))
    return [p for p in items if p.exists()]


def _open_results(out: Path, fingerprint: str, overwrite: bool) -> dict | None:
    """Check the results folder; return the previous summary to resume from, if any."""
    if out.exists() and not out.is_dir():
        raise InputError(f"results folder {out} is a file")
    if not out.exists() or not any(out.iterdir()):
        return None
    summary = out / SUMMARY
    prev = None
    if summary.is_file():
        try:
            prev = tio.read_json(summary)
        except InputError:
            prev = None
    if not isinstance(prev, dict) or prev.get("tool") != "track":
        raise InputError(
            f"results folder {out} is not empty and holds no {SUMMARY} written by track; "
            "choose a new folder (nothing was written)"
        )
    if prev.get("fingerprint") == fingerprint:
        return prev
    if not overwrite:
        raise InputError(
            f"results folder {out} holds results made from other inputs or settings; "
            "use a new folder or --overwrite (nothing was written)"
        )
    for p in _our_outputs(out):
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink()
    log.info("%s: previous results removed (--overwrite)", out)
    return None


def _clear_derived(out: Path) -> None:
    """Remove the linking outputs of an earlier run (they are recomputed)."""
    for p in sorted(out.glob("matches_[0-9][0-9][0-9][0-9][0-9][0-9].csv")):
        p.unlink()
    if (out / "tracks.csv").exists():
        (out / "tracks.csv").unlink()
    if (out / "fields").is_dir():
        shutil.rmtree(out / "fields")


# -- detection -------------------------------------------------------------------------------
def _detect_settings(args):
    from .detect import DetectSettings

    iters = 0 if args.no_deconvolution else args.deconvolution_iterations
    return DetectSettings(
        deconvolution_iterations=iters,
        threshold=args.threshold,
        blob_min_vox=args.blob_min_vox or None,
        blob_max_vox=args.blob_max_vox or None,
        method=args.method,
        edge_margin_um=args.edge_margin_um,
    )


def _settings_dict(obj) -> dict:
    return {k: v for k, v in dataclasses.asdict(obj).items()}


def _first_psf(vol, info, settings):
    """PSF of the first volume, used for the whole sequence (paper §3.2)."""
    from .errors import TrackingError
    from .psf_estimate import estimate_psf

    if settings.deconvolution_iterations == 0:
        return None, "not used (deconvolution off)"
    try:
        psf = estimate_psf(
            vol, info.voxel_size_um, n_particles=settings.psf_particles, box_um=settings.psf_box_um
        )
    except (TrackingError, InputError) as exc:
        log.warning("no PSF from the first volume (%s); each volume estimates its own", exc)
        return None, f"not available from the first volume: {exc}"
    return psf, f"estimated from {info.path.name}, shape {list(psf.shape)}"


def _detect_all(args, out: Path, summary: dict, prev: dict | None) -> list[np.ndarray]:
    from .detect import detect_particles

    vols = tio.scan_volumes(args.voldir)
    settings = _detect_settings(args)
    prev_frames = {e.get("index"): e for e in (prev or {}).get("frames", [])}
    frames = []
    for v in vols:
        frames.append(
            {"index": v.index, "input": str(v.path), "input_sha256": tio.sha256_file(v.path)}
        )
    summary["frames"] = frames
    summary["inputs"] = [{"path": f["input"], "sha256": f["input_sha256"]} for f in frames]
    clouds: list[np.ndarray | None] = [None] * len(vols)
    for i, (v, f) in enumerate(zip(vols, frames, strict=True)):
        old = prev_frames.get(v.index)
        part = tio.numbered(out / "particles", v.index, ".csv")
        if old and old.get("input_sha256") == f["input_sha256"] and part.is_file():
            clouds[i] = tio.read_points_csv(part)
            frames[i] = {**old, **f, "reused": True}
    todo = [i for i in range(len(vols)) if clouds[i] is None]
    if todo:
        log.info("detecting particles in %d of %d volumes", len(todo), len(vols))
    else:
        log.info("all %d volumes already detected; detection skipped", len(vols))
    psf = None
    psf_note = (prev or {}).get("psf", "")
    t_det = time.perf_counter()
    if todo:
        vol0 = tio.read_volume(vols[0])
        psf, psf_note = _first_psf(vol0, vols[0], settings)
        bar = _progress(todo, args, "detect", "volume")
        for i in bar:
            v = vols[i]
            t0 = time.perf_counter()
            vol = vol0 if i == 0 else tio.read_volume(v)
            det = detect_particles(vol, v.voxel_size_um, settings, psf, origin_um=v.origin_um)
            part = tio.numbered(out / "particles", v.index, ".csv")
            tio.write_points_csv(part, det.positions_um, det.intensities, overwrite=True)
            clouds[i] = np.asarray(det.positions_um, dtype=float).reshape(-1, 3)
            frames[i].update(
                {
                    "particles": str(part.relative_to(out)),
                    "n_particles": int(clouds[i].shape[0]),
                    "voxel_size_um": list(v.voxel_size_um),
                    "origin_um": list(v.origin_um),
                    "seconds": time.perf_counter() - t0,
                    "report": det.report,
                }
            )
            if clouds[i].shape[0] == 0:
                log.info("volume %s: no particle found", v.path.name)
            summary["psf"] = psf_note
            tio.write_json(out / SUMMARY, summary, overwrite=True)  # resumable after each
    summary["psf"] = psf_note
    summary["timings"]["detect_s"] = time.perf_counter() - t_det
    summary["frame_ids"] = [v.index for v in vols]
    return [c for c in clouds if c is not None]


# -- linking and outputs ---------------------------------------------------------------------
def _series_settings(args) -> SeriesSettings:
    from .matching import LinkSettings

    grid = GridSettings(
        spacing_um=args.grid_spacing_um,
        target_nodes=int(args.target_nodes),
        method=args.interpolation,
        smoothing=args.smoothing,
    )
    return SeriesSettings(
        mode=args.mode,
        grid=grid,
        link=LinkSettings(seed=int(args.seed)),
        compute_fields=not args.no_fields,
    )


def _link_and_write(args, out: Path, summary: dict, clouds, frame_ids) -> None:
    settings = _series_settings(args)
    summary["fields_requested"] = settings.compute_fields
    summary["parameters"]["series"] = {
        "mode": settings.mode,
        "min_particles": settings.min_particles,
        "grid": _settings_dict(settings.grid),
        "link": _settings_dict(settings.link),
    }
    if len(clouds) < 2:
        raise InputError(f"linking needs at least 2 frames, got {len(clouds)}")
    if settings.compute_fields and clouds[0].shape[0] >= settings.min_particles:
        _check_grid_option(args, np.ptp(clouds[0], axis=0), "frame 0's particles")
    _clear_derived(out)
    t0 = time.perf_counter()
    n_pairs = len(clouds) - 1
    with _progress(n_pairs, args, "link", "pair") as bar:
        pairs = link_pairs(clouds, settings, on_pair=lambda _p: bar.update())
    t1 = time.perf_counter()
    with _progress(n_pairs if settings.compute_fields else 0, args, "fields", "field") as bar:
        res = track_series(clouds, settings, pairs=pairs, on_field=lambda _k: bar.update())
    t2 = time.perf_counter()
    increments = []
    for k, pair in enumerate(res.pairs):
        ref_id, def_id = frame_ids[pair.ref_frame], frame_ids[pair.def_frame]
        mfile = out / f"matches_{def_id:06d}.csv"
        tio.write_matches_csv(mfile, pair.matches, pair.displacement_um, overwrite=True)
        entry = {
            "ref_frame": ref_id,
            "def_frame": def_id,
            "status": pair.status,
            "n_ref": int(clouds[pair.ref_frame].shape[0]),
            "n_def": int(clouds[pair.def_frame].shape[0]),
            "n_matches": int(pair.matches.shape[0]),
            "tracking_ratio": pair.tracking_ratio,
            "iterations": pair.iterations,
            "matches": mfile.name,
            "field_status": res.field_status[k],
            "field": None,
            "smoothing_xyz": None if res.smoothing[k] is None else list(res.smoothing[k]),
        }
        if not pair.ok:  # reported once at the end (_finish)
            log.info("frames %d → %d %s", ref_id, def_id, pair.status)
        fld = res.total_fields[k]
        if fld is not None:
            base = out / "fields" / f"{def_id:06d}"
            tio.write_field_npz(base.with_suffix(".npz"), fld, overwrite=True)
            tio.write_field_vti(
                base.with_suffix(".vti"), fld, encoding=args.vti_encoding, overwrite=True
            )
            entry["field"] = f"fields/{def_id:06d}"
            entry["mask_fraction"] = float(fld.mask.mean())
        inc = res.increment_fields[k]
        if inc is not None:
            p = out / "fields" / f"increment_{def_id:06d}.npz"
            tio.write_field_npz(p, inc, overwrite=True)
            entry["increment_field"] = str(p.relative_to(out))
        increments.append(entry)
    tracks = res.tracks
    ids = np.asarray(frame_ids, dtype=np.int64)
    tracks = dataclasses.replace(tracks, frame=ids[tracks.frame])
    tio.write_tracks_csv(out / "tracks.csv", tracks, overwrite=True)
    summary["increments"] = increments
    summary["counts"] = {
        "frames": len(clouds),
        "particles_per_frame": [int(c.shape[0]) for c in clouds],
        "pairs_linked": sum(p.ok for p in res.pairs),
        "pairs_skipped": sum(not p.ok for p in res.pairs),
        "tracks": int(np.unique(tracks.track_id).size),
    }
    if res.axes is not None:
        summary["grid"] = {
            "shape_zyx": list(res.axes.shape),
            "spacing_um": list(res.axes.spacing_um),
            "origin_um": list(res.axes.origin_um),
        }
    summary["timings"]["link_s"] = t1 - t0
    summary["timings"]["fields_s"] = t2 - t1
    summary["timings"]["write_s"] = time.perf_counter() - t2


def _progress(items, args, desc: str, unit: str):
    """tqdm bar on stderr over ``items`` (an iterable, or a total count for ``update()``);
    off with ``--no-progress`` or ``-q``, and when stderr is not a terminal."""
    from tqdm.auto import tqdm

    disable = True if (args.no_progress or args.quiet) else None
    if isinstance(items, int):
        disable = True if items == 0 else disable
        return tqdm(total=items, desc=desc, unit=unit, disable=disable, file=sys.stderr)
    return tqdm(items, desc=desc, unit=unit, disable=disable, file=sys.stderr)


def _check_grid_option(args, extent_xyz_um, where: str) -> None:
    """Refuse a ``--grid-spacing-um`` that gives too many nodes, or a single cell."""
    if getattr(args, "no_fields", False):
        return
    check_grid(
        extent_xyz_um,
        _series_settings(args).grid,
        where=where,
        spacing_name="--grid-spacing-um",
        target_name="--target-nodes",
    )


def _volume_extent(vols) -> np.ndarray:
    """Size (x, y, z) in µm spanned by the voxel centres of a volume series."""
    shape = np.asarray(vols[0].shape, dtype=float)  # (nz, ny, nx)
    vs = np.asarray(vols[0].voxel_size_um, dtype=float)  # (dz, dy, dx)
    return ((shape - 1) * vs)[::-1]


# -- failures and the closing line -----------------------------------------------------------
def _failures(summary: dict) -> list[str]:
    """One message per failed frame or pair of a finished run (empty: all worked)."""
    out = []
    if summary["command"] == "detect":
        for f in summary.get("frames", []):
            if f.get("n_particles", 1) == 0:
                out.append(f"volume {Path(f['input']).name}: no particle found")
    for inc in summary.get("increments", []):
        where = f"frames {inc['ref_frame']} → {inc['def_frame']}"
        if inc["status"] != "ok":
            out.append(f"{where}: {inc['status']}")
        elif summary.get("fields_requested", True) and inc["field_status"] != "ok":
            out.append(f"{where}: field {inc['field_status']}")
    return out


def _failure_line(failures: list[str], summary: dict) -> str:
    what = "pair" if summary.get("increments") else "volume"
    more = len(failures) - 1
    extra = f"; and {more} more {what}{'s' if more > 1 else ''} failed" if more else ""
    where = f" (results kept, see {SUMMARY}; " if more else " ("
    return f"{failures[0]}{extra}{where}use --allow-partial to keep partial results)"


def _results_line(summary: dict) -> str:
    """``RESULTS: 7 volumes, 24–25 particles/frame, 6/6 pairs linked, ...`` (one line)."""
    frames = summary.get("frames", [])
    kind = "clouds" if summary["command"] == "link" else "volumes"
    parts = [f"{len(frames)} {kind}"]
    counts = [f["n_particles"] for f in frames if "n_particles" in f]
    if counts:
        lo, hi = min(counts), max(counts)
        parts.append(f"{lo}–{hi} particles/frame" if lo != hi else f"{lo} particles/frame")
    incs = summary.get("increments")
    if incs is not None:
        linked = [i for i in incs if i["status"] == "ok"]
        parts.append(f"{len(linked)}/{len(incs)} pairs linked")
        ratios = [i["tracking_ratio"] for i in linked if i["tracking_ratio"] is not None]
        if ratios:
            parts.append(f"tracking ratio ≥ {math.floor(100 * min(ratios)) / 100:.2f}")
        if summary.get("fields_requested", True):
            parts.append(f"{sum(i['field'] is not None for i in incs)} fields")
        else:
            parts.append("no fields")
    parts.append(f"{summary['timings'].get('total_s', 0.0):.1f} s")
    status = summary["status"]
    return "RESULTS: " + ", ".join(parts) + ("" if status == "complete" else f" ({status.upper()})")


def _finish(args, out: Path, summary: dict, t0: float) -> int:
    """Set the status, write ``summary.json``, print the closing lines; the exit status."""
    failures = _failures(summary)
    summary["failures"] = failures
    summary["allow_partial"] = bool(args.allow_partial)
    if not failures:
        summary["status"] = "complete"
    else:
        summary["status"] = "partial" if args.allow_partial else "failed"
    summary["timings"]["total_s"] = time.perf_counter() - t0
    tio.write_json(out / SUMMARY, summary, overwrite=True)
    log.info("results in %s", out)
    if not args.quiet:
        sys.stdout.write(_results_line(summary) + "\n")
        sys.stdout.flush()
    if not failures:
        return 0
    if args.allow_partial:
        for f in failures:
            log.warning("%s (kept: --allow-partial)", f)
        return 0
    sys.stderr.write(f"track: error: {_failure_line(failures, summary)}\n")
    return EXIT_FAILED


def _new_summary(args, command: str, fingerprint: str, parameters: dict) -> dict:
    return {
        "tool": "track",
        "version": __version__,
        "command": command,
        "argv": list(args.argv),
        "fingerprint": fingerprint,
        "status": "incomplete",
        "parameters": parameters,
        "timings": {},
    }


def _detect_fingerprint(args) -> tuple[str, dict]:
    settings = _detect_settings(args)
    params = {"detect": _settings_dict(settings)}
    fp = _fingerprint({"voldir": str(args.voldir.resolve()), **params})
    return fp, params


def cmd_detect(args, *, then_link: bool = False) -> int:
    """``track detect`` (and the detection stage of ``track run``)."""
    t0 = time.perf_counter()
    if not args.voldir.is_dir():
        raise InputError(f"volume folder {args.voldir} does not exist or is not a folder")
    tio.scan_volumes(args.voldir)  # validate the series before touching RESULTS
    fp, params = _detect_fingerprint(args)
    out = args.output
    prev = _open_results(out, fp, args.overwrite)
    summary = _new_summary(args, "run" if then_link else "detect", fp, params)
    out.mkdir(parents=True, exist_ok=True)
    clouds = _detect_all(args, out, summary, prev)
    if then_link:
        _link_and_write(args, out, summary, clouds, summary["frame_ids"])
    return _finish(args, out, summary, t0)


def cmd_run(args) -> int:
    """``track run``: detect, link, grid."""
    _series_settings(args)  # validate before any work
    if args.voldir.is_dir():
        vols = tio.scan_volumes(args.voldir)
        _check_grid_option(args, _volume_extent(vols), "the volume")
    return cmd_detect(args, then_link=True)


def cmd_link(args) -> int:
    """``track link``: link point clouds given as CSV files."""
    t0 = time.perf_counter()
    if len(args.clouds) < 2:
        raise InputError(f"link needs at least 2 point clouds, got {len(args.clouds)}")
    _series_settings(args)
    clouds = [tio.read_points_csv(p) for p in args.clouds]
    if clouds[0].shape[0] >= 2:
        _check_grid_option(args, np.ptp(clouds[0], axis=0), "frame 0's particles")
    checks = [tio.sha256_file(p) for p in args.clouds]
    params = {"sources": [str(p.resolve()) for p in args.clouds]}
    fp = _fingerprint({**params, "sha256": checks})
    out = args.output
    _open_results(out, fp, args.overwrite)
    summary = _new_summary(args, "link", fp, {})
    summary["inputs"] = [
        {"path": str(p), "sha256": s} for p, s in zip(args.clouds, checks, strict=True)
    ]
    out.mkdir(parents=True, exist_ok=True)
    frames = []
    for i, (p, c) in enumerate(zip(args.clouds, clouds, strict=True)):
        part = tio.numbered(out / "particles", i, ".csv")
        tio.write_points_csv(part, c, overwrite=True)
        frames.append(
            {
                "index": i,
                "input": str(p),
                "particles": str(part.relative_to(out)),
                "n_particles": int(c.shape[0]),
            }
        )
    summary["frames"] = frames
    tio.write_json(out / SUMMARY, summary, overwrite=True)
    _link_and_write(args, out, summary, clouds, list(range(len(clouds))))
    return _finish(args, out, summary, t0)


class _Formatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"track: {record.levelname.lower()}: {record.getMessage()}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``track``; returns the exit status (0 success, 2 user error, 3 failed
    frames, 130 interrupted: see the module docstring)."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error (already printed)
        return int(exc.code or 0)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    args.argv = argv
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter())
    level = logging.ERROR if args.quiet else (logging.WARNING, logging.INFO)[min(args.verbose, 1)]
    if args.verbose >= 2:
        level = logging.DEBUG
    root = logging.getLogger("track")
    saved = root.level
    root.setLevel(level)
    root.addHandler(handler)
    try:
        return int(args.func(args))
    except HrvError as exc:
        message = " ".join(str(exc).split())
        sys.stderr.write(f"track: error: {message}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("track: interrupted\n")
        return 130
    finally:
        root.removeHandler(handler)
        root.setLevel(saved)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


__all__ = ["build_parser", "main"]
