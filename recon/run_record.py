"""The ``recon.json`` record of a reconstruction folder and what resuming it checks.

:func:`recon.pipeline.reconstruct_series` records every frame's source and checksum
(:func:`frame_entry`); before anything is written, :func:`check_output` compares a folder's
record with this run's frames and settings, refuses volumes made from other inputs or
settings (naming what changed) and returns the record to resume.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os

from .volume_store import OutputExistsError

log = logging.getLogger(__name__)

RECON_JSON = "recon.json"


#: Per-frame entries of ``recon.json`` naming the frame's source.
SOURCE_KEYS = ("input", "page", "number", "time_s")


#: Per-frame entries of ``recon.json`` that a reconstruction adds (kept when resuming).
RESULT_KEYS = ("seconds", "iterations", "preprocess", "rel_change", "output")


def frame_entry(k: int, ref, sha: str) -> dict:
    """The ``recon.json`` record of frame ``k``: index, source, checksum (of the file, or of a
    stack page's pixels), and the file's size (bytes) and modification time (UTC), which say
    what changed when a resumed run finds another input."""
    from datetime import UTC, datetime

    st = os.stat(ref.path)
    mtime = datetime.fromtimestamp(st.st_mtime, UTC).isoformat(timespec="seconds")
    return {
        "index": k,
        "input": str(ref.path),
        "page": ref.page,
        "number": ref.number,
        "time_s": ref.time_s,
        "input_sha256": sha,
        "input_bytes": st.st_size,
        "input_mtime": mtime.replace("+00:00", "Z"),
    }


def _input_change(was: dict, now: dict) -> str:
    """What differs between the input a volume was made from (its ``recon.json`` entry) and
    this run's frame of the same index (:func:`frame_entry`), as text for a message."""

    def label(e: dict) -> str:
        return e.get("input", "an unknown frame") + (
            f" [page {e['page']}]" if e.get("page") is not None else ""
        )

    parts = [f"SHA-256 {str(was.get('input_sha256'))[:12]}… then, {now['input_sha256'][:12]}… now"]
    if was.get("input_bytes") is not None:
        if was["input_bytes"] == now["input_bytes"]:
            parts.append(f"same size ({now['input_bytes']} bytes)")
        else:
            parts.append(f"{was['input_bytes']} bytes then, {now['input_bytes']} now")
    if was.get("input_mtime") is not None and was["input_mtime"] != now["input_mtime"]:
        parts.append(f"modified {was['input_mtime']} then, {now['input_mtime']} now")
    if label(was) == label(now):
        return f"was made from {label(was)!r}, which has changed since: {'; '.join(parts)}"
    return f"was made from {label(was)!r}, now {label(now)!r}: {'; '.join(parts)}"


def clean_up_failed_start(writer, created: bool, done: list) -> None:
    """After a failure: a run that wrote no volume leaves no trace (its ``recon.json``, an
    empty Zarr array and, if it made it, the empty folder go), so that the corrected command
    runs as if for the first time. A folder with volumes keeps its record, to be resumed."""
    out = writer.out
    if done or writer.indices():
        return
    writer.discard()
    (out / RECON_JSON).unlink(missing_ok=True)
    if created:
        with contextlib.suppress(OSError):
            out.rmdir()


def _time_text(t) -> str:
    return "unknown" if t is None else f"{t:g} s"


def _source_change(entry: dict, ref, fps_then, fps_now) -> str | None:
    """How the frame number or time of a kept volume's frame differs from this run's (its
    ``recon.json`` entry and the volume's own metadata record them), or ``None``."""
    changes = []
    if "number" in entry and entry["number"] != ref.number:
        changes.append(f"frame number {entry['number']}, this run {ref.number}")
    if "time_s" in entry and entry["time_s"] != ref.time_s:
        text = f"time {_time_text(entry['time_s'])}, this run {_time_text(ref.time_s)}"
        if fps_then != fps_now:
            then = "none" if fps_then is None else f"{fps_then:g}"
            now = "none" if fps_now is None else f"{fps_now:g}"
            text += f" (--fps {then} then, {now} now)"
        changes.append(text)
    return "; ".join(changes) or None


def _plain(value):
    """``value`` as JSON would give it back (tuples as lists)."""
    from hrvbase.io import to_json

    return json.loads(to_json(value))


def _value_text(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return "none" if value is None else str(value)


#: Most differences named in the message of a folder made with other settings.
_CHANGES_SHOWN = 4


def _setting_changes(previous: dict, identity: dict) -> str:
    """What differs between the settings recorded in a folder's ``recon.json`` and this run's
    (``identity``: what the fingerprint is made of), as text for a message; empty when the
    record does not say."""
    changes = []
    was_pre, now_pre = previous.get("preprocess") or {}, identity["preprocess"]
    was_dark, now_dark = bool(was_pre.get("dark")), now_pre["dark_sha256"] is not None
    if was_dark != now_dark:
        changes.append(
            f"dark frame {'given' if was_dark else 'none'} then, "
            f"{'given' if now_dark else 'none'} now"
        )
    elif now_dark and was_pre.get("dark_sha256") not in (None, now_pre["dark_sha256"]):
        changes.append(
            f"another dark frame (SHA-256 {was_pre['dark_sha256'][:12]}… then, "
            f"{now_pre['dark_sha256'][:12]}… now)"
        )
    sections = (
        ("settings", "settings", ""),
        ("preprocess", "preprocess", ""),
        ("optics", "optics", "optics "),
        ("calibration", "grid", "calibration "),
    )
    for recorded, section, label in sections:
        was = previous.get(recorded)
        if not isinstance(was, dict):
            continue
        for key, now in _plain(identity[section]).items():
            if key in ("dark", "dark_sha256") or key not in was or was[key] == now:
                continue
            changes.append(f"{label}{key} {_value_text(was[key])} then, {_value_text(now)} now")
    if not changes and previous.get("psf_bank") not in (None, identity["bank"]):
        changes.append("another PSF bank (another recon version or PSF model)")
    text = "; ".join(changes[:_CHANGES_SHOWN])
    return text + ("; …" if len(changes) > _CHANGES_SHOWN else "")


def check_output(
    writer, fp: str, refs, checksums, overwrite: bool, fps=None, identity=None
) -> dict | None:
    """Check the output folder before anything is written; the previous record to resume.

    A folder that is not empty must hold a ``recon.json``. Its volumes must come from the
    same settings (fingerprint; ``identity``, what it is made of, names what differs) and from
    the same inputs as this run's frames of the same
    index (checksums; a run may extend a shorter one), with the same frame numbers and times
    (``fps``: this run's frame rate, for the message), which the volumes record; otherwise it
    is refused, or with ``overwrite`` the volumes that do not belong to this run are deleted
    (and reconstructed). A record of another format (TIFF volumes, a Zarr image) is refused,
    even with ``overwrite``.
    """
    from hrvbase.io import read_json

    out = writer.out
    if out.exists() and not out.is_dir():
        raise OutputExistsError(
            f"output {str(out)!r} is a file, not a folder (nothing was written)"
        )
    if not (out.exists() and any(out.iterdir())):
        return None
    meta_path = out / RECON_JSON
    if not meta_path.is_file():
        raise OutputExistsError(
            f"output folder {str(out)!r} is not empty and holds no {RECON_JSON}; "
            "choose a new folder (nothing was written)"
        )
    previous = read_json(meta_path)
    made = previous.get("format", "tiff") if isinstance(previous, dict) else None
    if made != writer.format:
        raise OutputExistsError(
            f"output {str(out)!r} holds a {RECON_JSON} of {made or 'unknown'} volumes, this run "
            f"writes {writer.format}; choose a new output (nothing was written)"
        )
    volumes = writer.indices()
    if previous.get("fingerprint") != fp:
        if not volumes:
            log.info("%s: replacing the record of a run that wrote no volume", out)
        elif not overwrite:
            changes = _setting_changes(previous, identity) if identity else ""
            raise OutputExistsError(
                f"output folder {str(out)!r} holds volumes made from other inputs or "
                f"settings{f' ({changes})' if changes else ''}; use a new folder or --overwrite "
                "(nothing was written)"
            )
        writer.clear()
        meta_path.unlink()
        return None
    prev_frames = {e.get("index"): e for e in previous.get("frames", [])}
    stale = [
        k
        for k in volumes
        if k >= len(refs) or prev_frames.get(k, {}).get("input_sha256") != checksums[k]
    ]
    retimed = {
        k: change
        for k in volumes
        if k not in stale
        and (change := _source_change(prev_frames[k], refs[k], previous.get("fps"), fps))
    }
    if retimed and not stale and not overwrite:
        k, change = next(iter(retimed.items()))
        raise OutputExistsError(
            f"output {str(out)!r} holds volumes of other frame numbers or times than this "
            f"run's (volume {writer.label(k)}, {refs[k].label!r}: {change}); run with the "
            "same --fps, use a new folder, or --overwrite to reconstruct them (nothing was "
            "written)"
        )
    if stale and not overwrite:
        k = stale[0]
        was = prev_frames.get(k, {})
        if k < len(refs):
            what = _input_change(was, frame_entry(k, refs[k], checksums[k]))
        else:
            was_label = was.get("input", "an unknown frame")
            if was.get("page") is not None:
                was_label += f" [page {was['page']}]"
            what = f"was made from {was_label!r}, this run has {len(refs)} frame(s)"
        raise OutputExistsError(
            f"output folder {str(out)!r} holds volumes made from other inputs or settings "
            f"(volume {writer.label(k)} {what}); use a new folder or --overwrite (nothing was "
            "written)"
        )
    for k in sorted({*stale, *retimed}):
        writer.remove(k)
    return previous
