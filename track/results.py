"""The results folder of ``track run | detect | link``: what a run returns
(:class:`TrackResult`, :class:`FrameDetections`, :class:`PairOutcome`), its record
``summary.json`` (opened, fingerprinted, staged, finished) and its failures and closing line.

The folder's layout is described in :mod:`track.pipeline`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.errors import HrvError
from hrvbase.io import read_json, write_json

from .errors import FailedFramesError, InputError
from .grid import GridAxes, GridField
from .series_settings import OK
from .tracks import Tracks

log = logging.getLogger(__name__)


#: The record of a results folder.
SUMMARY = "summary.json"


@dataclass(frozen=True)
class FrameDetections:
    """The particles of one frame.

    Attributes
    ----------
    index : int
        Frame number: the camera frame a volume was reconstructed from when recorded
        (:attr:`track.volumes.VolumeInfo.frame`), else ``NNNNNN`` of the volume file; the
        position of a point cloud.
    source : str
        The input (volume or CSV path; ``"array <i>"`` for an array).
    positions_um : ndarray, shape (N, 3)
        Particle centres, columns x, y, z (µm).
    particles : Path
        Their table in the results folder (``particles/NNNNNN.csv``).
    reused : bool
        Detection skipped: the volume's checksum and table were found (resume).
    report : dict
        Detection report (counts per stage, threshold, ...; see
        :attr:`track.detect.Detection.report`); empty when reused or for point clouds.
    sigma_xyz_um : ndarray, shape (N, 3), or None
        Standard uncertainty of each centre (µm, x, y, z); NaN where unknown (tables written
        without uncertainties), None for point clouds given without them.
    time_s : float or None
        Time of the frame (s) when recorded.
    """

    index: int
    source: str
    positions_um: np.ndarray
    particles: Path
    reused: bool = False
    report: dict = field(default_factory=dict)
    sigma_xyz_um: np.ndarray | None = None
    time_s: float | None = None

    @property
    def n(self) -> int:
        """Number of particles."""
        return int(self.positions_um.shape[0])


@dataclass(frozen=True)
class PairOutcome:
    """One linked pair of a series and its field.

    Attributes
    ----------
    ref_frame, def_frame : int
        Frame numbers (reference, deformed).
    status : str
        ``"ok"`` or ``"skipped: <reason>"`` (linking).
    field_status : str
        ``"ok"``, ``"skipped: fields not requested"`` or ``"skipped: <reason>"``.
    matches : ndarray of int, shape (K, 2)
        Rows ``[row_ref, row_def]`` into the two frames' particle tables.
    displacement_um : ndarray, shape (K, 3)
        Displacement of each matched particle (µm, x, y, z).
    sigma_displacement_xyz_um : ndarray, shape (K, 3), or None
        Its standard uncertainty (µm, x, y, z); None when the particles came without.
    tracking_ratio : float
        Fraction of reference particles matched (NaN when not linked).
    field : GridField or None
        Total field from frame 0 to ``def_frame`` on the reference grid.
    increment_field : GridField or None
        Incremental mode: the field of this increment.
    smoothing_xyz : (float, float, float) or None
        RBF smoothing λ used for ``u_x, u_y, u_z``.
    failure : str
        Why the pair counts as failed (empty when it does not).
    """

    ref_frame: int
    def_frame: int
    status: str
    field_status: str
    matches: np.ndarray
    displacement_um: np.ndarray
    tracking_ratio: float = math.nan
    field: GridField | None = None
    increment_field: GridField | None = None
    smoothing_xyz: tuple[float, float, float] | None = None
    failure: str = ""
    sigma_displacement_xyz_um: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """Whether the pair was linked (and, when requested, its field gridded)."""
        return not self.failure


@dataclass(frozen=True)
class TrackResult:
    """What :func:`track_volumes` or :func:`track_clouds` did (the results folder in memory).

    Attributes
    ----------
    out_dir : Path
    command : {"run", "detect", "link"}
        The command line this corresponds to (recorded in ``summary.json``).
    frames : tuple of FrameDetections
    pairs : tuple of PairOutcome
        One per frame ``i ≥ 1``; empty for detection only.
    tracks : Tracks or None
        Trajectories, :attr:`Tracks.frame` holding frame numbers; None for detection only.
    grid : GridAxes or None
        Reference grid of the fields.
    summary : dict
        The content of ``summary.json``.
    failures : tuple of str
        One message per failed frame or pair (empty: everything worked).
    """

    out_dir: Path
    command: str
    frames: tuple[FrameDetections, ...]
    pairs: tuple[PairOutcome, ...] = ()
    tracks: Tracks | None = None
    grid: GridAxes | None = None
    summary: dict = field(default_factory=dict)
    failures: tuple[str, ...] = ()

    @property
    def status(self) -> str:
        """``"complete"``, ``"partial"`` (failures allowed) or ``"failed"``."""
        return self.summary.get("status", "incomplete")

    @property
    def timings(self) -> dict:
        """Seconds per stage (``detect_s``, ``link_s``, ``fields_s``, ``write_s``,
        ``total_s``)."""
        return self.summary.get("timings", {})

    def results_line(self) -> str:
        """One line such as ``RESULTS: 7 volumes, 24–25 particles/frame, 6/6 pairs linked,
        tracking ratio ≥ 0.96, 6 fields, 12.3 s``."""
        return results_line(self.summary)


def _fingerprint(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


#: Hidden folder of a results folder where linking writes its outputs until all are ready.
STAGING = ".track-linking"


def _our_outputs(out: Path) -> list[Path]:
    """Files and folders ``track`` writes in a results folder."""
    items = [out / "particles", out / "fields", out / "tracks.csv", out / SUMMARY]
    items.append(out / STAGING)
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
            prev = read_json(summary)
        except HrvError:
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
    log.info("%s: previous results removed (overwrite)", out)
    return None


def _new_staging(out: Path) -> Path:
    """An empty :data:`STAGING` folder (what an interrupted run left there is removed)."""
    stage = out / STAGING
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir()
    return stage


def _publish_derived(stage: Path, out: Path) -> None:
    """Move the linking outputs written in ``stage`` into ``out``, replacing those of an
    earlier run; its files the new run did not write (a pair no longer in the series, fields
    no longer requested) are removed only then."""
    new = {p.name for p in stage.glob("matches_[0-9][0-9][0-9][0-9][0-9][0-9].csv")}
    for name in [*sorted(new), "tracks.csv"]:
        if (stage / name).exists():
            os.replace(stage / name, out / name)
    for p in sorted(out.glob("matches_[0-9][0-9][0-9][0-9][0-9][0-9].csv")):
        if p.name not in new:
            p.unlink()
    if (out / "fields").is_dir():
        os.replace(out / "fields", stage / "fields.old")
    if (stage / "fields").is_dir():
        os.replace(stage / "fields", out / "fields")
    shutil.rmtree(stage)


def _new_summary(command: str, fingerprint: str, parameters: dict, provenance) -> dict:
    from . import __version__

    summary = {
        "tool": "track",
        "version": __version__,
        "command": command,
        "argv": [],
        "fingerprint": fingerprint,
        "status": "incomplete",
        "parameters": parameters,
        "timings": {},
    }
    summary.update(dict(provenance or {}))
    return summary


def _bar(total: int, progress: bool, desc: str, unit: str):
    """tqdm bar on stderr (shown on a terminal when ``progress``), advanced by ``update()``."""
    import sys

    from tqdm.auto import tqdm

    disable = None if (progress and total > 0) else True
    return tqdm(total=total, desc=desc, unit=unit, disable=disable, file=sys.stderr)


def _settings_dict(obj) -> dict:
    return dict(dataclasses.asdict(obj))


def _pair_failure(entry: Mapping, fields_requested: bool) -> str:
    where = f"frames {entry['ref_frame']} → {entry['def_frame']}"
    if entry["status"] != OK:
        return f"{where}: {entry['status']}"
    if fields_requested and entry["field_status"] != OK:
        return f"{where}: field {entry['field_status']}"
    return ""


def failures_of(summary: Mapping) -> list[str]:
    """One message per failed frame or pair recorded in a ``summary.json`` (empty: none).

    A pair that was not linked, a requested field that was not gridded and, for a detection
    only (``command == "detect"``), a volume without particles.
    """
    out = []
    if summary.get("command") == "detect":
        for f in summary.get("frames", []):
            if f.get("n_particles", 1) == 0:
                out.append(f"volume {Path(f['input']).name}: no particle found")
    requested = summary.get("fields_requested", True)
    for inc in summary.get("increments", []):
        if reason := _pair_failure(inc, requested):
            out.append(reason)
    return out


def failure_message(failures: Sequence[str], *, hint: str = "allow_partial=True") -> str:
    """One line: the first failure, how many others, and how to keep partial results."""
    more = len(failures) - 1
    what = "pair" if failures[0].startswith("frames ") else "volume"
    extra = f"; and {more} more {what}{'s' if more > 1 else ''} failed" if more else ""
    where = f" (results kept, see {SUMMARY}; " if more else " ("
    return f"{failures[0]}{extra}{where}use {hint} to keep partial results)"


def results_line(summary: Mapping) -> str:
    """``RESULTS: 7 volumes, 24–25 particles/frame, 6/6 pairs linked, tracking ratio ≥ 0.96,
    6 fields, 12.3 s`` from a ``summary.json`` (``(PARTIAL)``/``(FAILED)`` appended)."""
    frames = summary.get("frames", [])
    kind = "clouds" if summary.get("command") == "link" else "volumes"
    parts = [f"{len(frames)} {kind}"]
    counts = [f["n_particles"] for f in frames if "n_particles" in f]
    if counts:
        lo, hi = min(counts), max(counts)
        parts.append(f"{lo}–{hi} particles/frame" if lo != hi else f"{lo} particles/frame")
    incs = summary.get("increments")
    if incs is not None:
        linked = [i for i in incs if i["status"] == OK]
        parts.append(f"{len(linked)}/{len(incs)} pairs linked")
        ratios = [i["tracking_ratio"] for i in linked if i["tracking_ratio"] is not None]
        ratios = [r for r in ratios if math.isfinite(r)]
        if ratios:
            parts.append(f"tracking ratio ≥ {math.floor(100 * min(ratios)) / 100:.2f}")
        if summary.get("fields_requested", True):
            parts.append(f"{sum(i['field'] is not None for i in incs)} fields")
        else:
            parts.append("no fields")
    floor = summary.get("noise_floor")
    if floor:
        rms = "/".join(f"{v:.2g}" for v in floor["rms_xyz_um"])
        parts.append(f"noise floor x/y/z {rms} µm")
    parts.append(f"{summary.get('timings', {}).get('total_s', 0.0):.1f} s")
    status = summary.get("status", "complete")
    return "RESULTS: " + ", ".join(parts) + ("" if status == "complete" else f" ({status.upper()})")


def _finish(
    out: Path,
    summary: dict,
    t0: float,
    allow_partial: bool,
    command: str,
    frames,
    pairs=(),
    tracks=None,
    grid=None,
) -> TrackResult:
    """Set the status, write ``summary.json``; raise on failures unless ``allow_partial``."""
    failures = failures_of(summary)
    summary["failures"] = failures
    summary["allow_partial"] = bool(allow_partial)
    if not failures:
        summary["status"] = "complete"
    else:
        summary["status"] = "partial" if allow_partial else "failed"
    summary["timings"]["total_s"] = time.perf_counter() - t0
    write_json(out / SUMMARY, summary, overwrite=True)
    log.info("results in %s", out)
    result = TrackResult(
        out, command, tuple(frames), tuple(pairs), tracks, grid, summary, tuple(failures)
    )
    if failures and not allow_partial:
        raise FailedFramesError(failure_message(failures), failures, result)
    for f in failures:
        log.warning("%s (kept: partial results allowed)", f)
    return result


__all__ = [
    "SUMMARY",
    "FrameDetections",
    "PairOutcome",
    "TrackResult",
    "failure_message",
    "failures_of",
    "results_line",
]
