"""Reconstruct a time series of light-field frames into volumes, resumably.

``reconstruct_series`` is what ``recon run`` does: for every frame, read → prepare
(:mod:`recon.preprocess`) → rectify onto the calibrated lenslet grid (:mod:`recon.rectify`)
→ Richardson–Lucy with the depth-adaptive filter (:mod:`recon.deconvolve`) → write
``VOLDIR/NNNNNN.tif`` (float32 ``(z, y, x)``, voxel size in µm in the metadata) or, with
``volume_format="zarr"``, frame ``t`` of one OME-Zarr image ``VOLDIR``
(:mod:`recon.volume_store`, which also records what resume verifies). The folder's
``recon.json`` records the optics, calibration, depths, settings, timings and, for every
frame, its source (file, page of a stack), original number, time and checksum (of the file,
or of a stack page's pixels). It is rewritten atomically after every frame: an interrupted run
resumes with the frames it had not finished (a longer series extends a shorter one), and a
folder whose volumes were made from other inputs or settings is refused.

The frames may run on Dask workers (``parallel``, :mod:`hrvbase.parallel`): this module
schedules them, :func:`reconstruct_frame` computes and writes one frame wherever it runs, and
the volumes and records are the same as in process.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .deconvolve import richardson_lucy
from .errors import InputError
from .filters import DepthFilter
from .geometry import ReconGrid
from .preprocess import Preprocess, check_dark, prepare_image, read_frame
from .projector import make_projector
from .psf import bank_key, compute_psf_bank, pattern_radius_lenslets
from .settings import ReconSettings, default_z_step_um
from .volume_store import OutputExistsError, VolumeGeometry, make_writer

log = logging.getLogger(__name__)

RECON_JSON = "recon.json"


#: Largest radius (lenslets) of a point's light pattern the PSF bank stores (its memory grows
#: with the square of it).
MAX_PATTERN_RADIUS_LENSLETS = 120


def check_depths_resolvable(optics, depths_um, n_lenslets: tuple[int, int]) -> None:
    """Refuse depths whose light leaves the sensor (the optics cannot resolve them).

    A point at depth z lights a disc of lenslets of radius ``r(z)``; once that disc is wider
    than the image, most of the point's light misses the sensor and its depth cannot be
    reconstructed. The message gives the deepest resolvable ``|z|``, searched in steps of the
    optics' default depth step (:func:`recon.settings.default_z_step_um`).
    """
    nx, ny = n_lenslets
    limit = min(nx / 2, ny / 2, MAX_PATTERN_RADIUS_LENSLETS)
    for z in (float(np.min(depths_um)), float(np.max(depths_um))):
        r = pattern_radius_lenslets(optics, z) - 2
        if r > limit:
            step = default_z_step_um(optics)
            zmax = next(
                (
                    abs(zz)
                    for zz in np.arange(0, abs(z), step)[::-1]
                    if pattern_radius_lenslets(optics, zz) - 2 <= limit
                ),
                0.0,
            )
            raise InputError(
                f"depth z = {z:g} µm cannot be resolved with these optics and a "
                f"{nx} × {ny}-lenslet image: a point there lights a disc {2 * r + 1} lenslets "
                f"wide; keep |z| <= {zmax:g} µm"
            )


#: Optics a calibration and the scene of a run must agree on: a lenslet grid fitted on one
#: microscope places lenslets, and the optical axis (the object origin), wrongly on another.
#: The objective and tube-lens focal lengths are not among them: they set the magnification,
#: which the lenslet grid does not depend on and ``recon pixel-size`` measures (a scene with the
#: measured magnification differs from the calibration's nominal one exactly there). Nor is
#: the lenslet kind (glass or ideal): both model the same microscope.
OPTICS_MATCH_FIELDS = ("na", "mla_pitch_um", "mla_focal_um", "pixel_um", "sensor_px", "axis_px")

#: Relative tolerance of :func:`optics_differences`.
OPTICS_RTOL = 1e-6


def optics_differences(
    scene,
    calibration,
    rtol: float = OPTICS_RTOL,
    labels: tuple[str, str] = ("scene", "calibration"),
) -> list[str]:
    """The :data:`OPTICS_MATCH_FIELDS` in which two optics differ, as readable text.

    Parameters
    ----------
    scene, calibration : lfsim.optics.Optics
        The optics of a run's scene and those recorded with its calibration.
    rtol : float
        Relative tolerance per value.
    labels : (str, str)
        What the two optics are, in the text.

    Returns
    -------
    list of str
        ``"na 0.25 (scene) vs 0.2 (calibration)"`` for each field that differs; empty when
        they agree.
    """

    def text(v) -> str:
        return f"{v:g}" if np.ndim(v) == 0 else "[" + ", ".join(f"{x:g}" for x in v) + "]"

    out = []
    for name in OPTICS_MATCH_FIELDS:
        a, b = getattr(scene, name), getattr(calibration, name)
        va, vb = np.atleast_1d(np.asarray(a, float)), np.atleast_1d(np.asarray(b, float))
        if va.shape != vb.shape or not np.allclose(va, vb, rtol=rtol, atol=0.0):
            out.append(f"{name} {text(a)} ({labels[0]}) vs {text(b)} ({labels[1]})")
    return out


def model_optics(optics):
    """The optics of the reconstruction's forward model: ideal lenslets.

    The PSF bank is traced through a paraxial lenslet array
    (:func:`lfsim.tracer.trace_paraxial`). A scene with a glass lenslet array
    (``mla_kind="glass"``, the simulator's no-inverse-crime renderings) is reconstructed with
    the ideal array of the same pitch and focal length — the model a user has for a real
    microscope — and a warning says so.
    """
    if optics.mla_kind == "ideal":
        return optics
    log.warning(
        "the scene's lenslet array is %s (mla_kind=%r); reconstructing with ideal lenslets of "
        "the same pitch (%g µm) and focal length (%g µm), the only lenslets the PSF model knows",
        "a glass mesh" if optics.mla_kind == "glass" else optics.mla_kind,
        optics.mla_kind,
        optics.mla_pitch_um,
        optics.mla_focal_um,
    )
    return replace(optics, mla_kind="ideal")


def rectified_optics(optics, n: int):
    """The optics as seen in a rectified image with exactly ``n`` pixels per lenslet."""
    return replace(optics, pixel_um=optics.mla_pitch_um / n, axis_px=None, sensor_px=(n, n))


def _fingerprint(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


@dataclass
class SeriesResult:
    """What :func:`reconstruct_series` did."""

    out_dir: Path
    done: list
    skipped: list
    seconds: dict


def reconstruct_series(
    frames,
    out_dir: str | os.PathLike,
    *,
    optics,
    grid,
    settings: ReconSettings | None = None,
    preprocess: Preprocess | None = None,
    overwrite: bool = False,
    progress: bool = True,
    provenance: dict | None = None,
    volume_format: str = "tiff",
    zarr_chunk_z: int | None = None,
    parallel=None,
    solver=None,
) -> SeriesResult:
    """Reconstruct light-field frames into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    frames : list of recon.frames.FrameRef or path
        Frames (a path is a single-image TIFF, numbered from its name), reconstructed in
        this order as ``000000.tif``, ``000001.tif``, …. All must have the same size, pixel
        type and bit depth (checked from the TIFF headers first).
    out_dir : path
    optics : lfsim.optics.Optics
        The microscope (from the scene file); glass lenslets are modelled as ideal ones
        (:func:`model_optics`).
    grid : recon.calibration.LensletGrid
        Lenslet calibration of these frames' camera.
    settings, preprocess : optional
    overwrite : bool
        Replace the outputs of a run with other inputs or settings (only this tool's files).
    provenance : dict, optional
        Extra entries for ``recon.json`` (e.g. the command line).
    volume_format : {"tiff", "zarr"}
        Numbered TIFF volumes in the folder ``out_dir``, or one OME-Zarr image ``out_dir``
        of axes ``(t, z, y, x)`` (:mod:`recon.volume_store`).
    zarr_chunk_z : int, optional
        Zarr only: planes per chunk (default: one chunk per frame).
    parallel : hrvbase.parallel.Parallel, optional
        Where the frames run (default: in this process, one after the other); the volumes
        and their records are the same however they run (:func:`reconstruct_frame`).
    solver : callable, optional
        Extension point: the deconvolution of one rectified frame, called as
        ``solver(image, projector, iterations, *, depth_filter, stop_rel_change, track_kl,
        background)`` with the arguments of :func:`recon.deconvolve.richardson_lucy` (the
        default), returning an object with ``.volume`` (ndarray, shape (nz, ny·s, nx·s)),
        ``.iterations`` and ``.rel_change`` (a :class:`recon.deconvolve.RLResult`). A new RL
        variant is this one function; it must be picklable to run on Dask workers. Its
        qualified name enters the fingerprint, so a folder reconstructed by another solver
        is not resumed.

    A run that fails before its first volume leaves no ``recon.json`` (nor the folder, if it
    made it), so that the corrected command needs no ``overwrite``; a record without volumes
    is replaced in any case.

    Raises
    ------
    InputError
        Missing, unreadable or mixed frames; frames of another size than the calibration's;
        a dark frame brighter than the first frame (:func:`recon.preprocess.check_dark`).
    OutputExistsError
        ``out_dir`` holds something else, or volumes made from other inputs or settings
        (without ``overwrite``). Nothing is written then.
    """
    from hrvbase.io import write_json
    from hrvbase.parallel import Parallel, WorkerContext, frame_map

    from .frames import FrameRef, check_frames, frame_checksums
    from .rectify import rectify

    par = Parallel() if parallel is None else parallel
    st = (settings or ReconSettings()).resolved(optics)
    pp = preprocess or Preprocess()
    scene_mla_kind = optics.mla_kind
    optics = model_optics(optics)
    refs = [FrameRef.of(f) for f in frames]
    if not refs:
        raise InputError("no frames to reconstruct")
    check_frames(refs)
    out = Path(out_dir)
    writer = make_writer(volume_format, out, zarr_chunk_z=zarr_chunk_z)
    n = round(optics.px_per_lenslet)
    if abs(grid.pitch_px - optics.px_per_lenslet) > 0.05 * optics.px_per_lenslet:
        log.warning(
            "calibrated pitch %.3f px differs from the scene's %.3f px by more than 5 %%",
            grid.pitch_px,
            optics.px_per_lenslet,
        )
    ropt = rectified_optics(optics, n)
    depths = st.depths_um

    # Rectification geometry from the first frame (all frames share the camera).
    first = read_frame(refs[0].path, page=refs[0].page)
    if tuple(first.shape) != tuple(grid.image_shape):
        raise InputError(
            f"frame {refs[0].label!r} is {first.shape[1]} × {first.shape[0]} px but the "
            f"calibration was made on {grid.image_shape[1]} × {grid.image_shape[0]} px images"
        )
    if pp.dark is not None:
        check_dark(first, pp.dark, frame=f"frame {refs[0].label!r}", dark_name=pp.dark_name)
    _, geom = _rectify_roi(rectify, first, grid, n, st.roi_px)
    nx, ny = geom.n_lenslets
    check_depths_resolvable(optics, depths, (nx, ny))

    key = bank_key(ropt, depths, st.s, st.rays_per_pattern, 0, 1e-3)
    dark_sum = None if pp.dark is None else hashlib.sha256(pp.dark.tobytes()).hexdigest()
    identity = {
        "settings": st.result_dict(),  # not the threads: same volumes for any count
        # the camera gain enters only each frame's SNR, not the volumes (measured again
        # for the frames a resumed run keeps)
        "preprocess": {
            **{k: v for k, v in pp.to_dict().items() if k != "gain_dn_per_e"},
            "dark_sha256": dark_sum,
        },
        "optics": optics.to_dict(),
        "grid": grid.to_dict(),
        "bank": key,
    }
    if solver is not None:
        identity["solver"] = f"{solver.__module__}.{solver.__qualname__}"
    fp = _fingerprint(identity)
    checksums = frame_checksums(refs)
    meta_path = out / RECON_JSON
    fps = (provenance or {}).get("fps")
    previous = _check_output(writer, fp, refs, checksums, overwrite, fps=fps, identity=identity)
    created = not out.exists()
    done, skipped, secs = [], [], {}
    try:
        prev_frames = {e.get("index"): e for e in (previous or {}).get("frames", [])}
        o_x, o_y = _object_origin(grid, geom, optics)
        rgrid = ReconGrid(optics.lenslet_object_um, tuple(depths), st.s, (nx, ny), (o_x, o_y))
        origin_xyz = (rgrid.x_um()[0], rgrid.y_um()[0], rgrid.depths_um[0])
        geometry = VolumeGeometry(tuple(rgrid.shape), tuple(rgrid.voxel_size_um), origin_xyz)
        writer.prepare(
            len(refs), geometry, [r.time_s for r in refs], overwrite, [r.number for r in refs]
        )
        meta = {
            "tool": "recon",
            "version": _version(),
            "fingerprint": fp,
            "status": "incomplete",
            "optics": optics.to_dict(),
            "calibration": grid.to_dict(),
            "settings": st.to_dict(),
            "preprocess": {**pp.to_dict(), "dark_sha256": dark_sum},
            "grid": rgrid.to_dict(),
            "voxel_size_um": list(rgrid.voxel_size_um),
            "volume_shape": list(rgrid.shape),
            "psf_bank": key,
            "scene_mla_kind": scene_mla_kind,
            "format": writer.format,
            **writer.record_extra(),
            "frames": [],
            "parallel": {"mode": par.describe()},
            **(provenance or {}),
        }
        frame_entries = []
        todo = []
        for k, (ref, sha) in enumerate(zip(refs, checksums, strict=True)):
            entry = _frame_entry(k, ref, sha)
            e = prev_frames.get(k)
            if e and e.get("input_sha256") == sha and writer.verify(k, e.get("output")):
                entry.update({name: e[name] for name in _RESULT_KEYS if name in e})
                kept_gain = ((previous or {}).get("preprocess") or {}).get("gain_dn_per_e", 0.0)
                if "snr" not in (entry.get("preprocess") or {}) or kept_gain != pp.gain_dn_per_e:
                    # kept from a run before the SNR was measured, or with another camera
                    # gain: measure it now (the frame read again, not reconstructed)
                    img = read_frame(ref.path, page=ref.page)
                    entry["preprocess"] = {**(entry.get("preprocess") or {})}
                    entry["preprocess"].update(prepare_image(img, pp)[1])
                skipped.append(k)
            else:
                if e and e.get("input_sha256") == sha and writer.exists(k):
                    log.warning(
                        "%s: volume %s changed on disk since it was written (truncated or "
                        "corrupt); reconstructing it again",
                        out,
                        writer.label(k),
                    )
                todo.append(k)
            frame_entries.append(entry)
        meta["frames"] = frame_entries
        write_json(meta_path, meta, overwrite=True)
        if skipped:
            log.info("%s: %d frame(s) already reconstructed, skipped", out, len(skipped))
        if todo:
            t0 = time.perf_counter()
            bank = compute_psf_bank(
                ropt, depths, st.s, rays_per_pattern=st.rays_per_pattern, progress=progress
            )
            meta["psf_seconds"] = time.perf_counter() - t0
            meta["macs_per_projection"] = int(bank.nnz) * nx * ny
            # The projector and filter are built from the bank once per process (in each
            # worker, from the one copy of the bank sent to it); each frame is computed and
            # written by reconstruct_frame, wherever it runs.
            model = WorkerContext(
                _frame_model,
                (
                    bank,
                    (nx, ny),
                    st,
                    pp,
                    grid,
                    ropt,
                    rgrid,
                    (o_x, o_y),
                    tuple(first.shape),
                    replace(writer, out=writer.out.resolve()),  # workers may run elsewhere
                    _backend_device(),
                    solver,
                ),
            )
            jobs = [
                (
                    k,
                    replace(refs[k], path=Path(refs[k].path).resolve()),
                    {k2: v for k2, v in frame_entries[k].items() if k2 in _SOURCE_KEYS},
                )
                for k in todo
            ]
            fmap = frame_map(
                reconstruct_frame,
                jobs,
                parallel=par,
                context=model,
                progress=progress,
                desc="recon",
            )
            with fmap:
                for (k, _, _), record in fmap:
                    # Threads of the projector that made it (the same for every frame).
                    meta["projector_threads"] = record.pop("projector_threads")
                    secs[k] = record["seconds"]
                    frame_entries[k].update(record)
                    write_json(meta_path, meta, overwrite=True)
                    done.append(k)
            meta["parallel"]["peak_memory_bytes"] = fmap.peak_memory_bytes
    except BaseException:
        _clean_up_failed_start(writer, created, done)
        raise
    meta["status"] = "complete"
    write_json(meta_path, meta, overwrite=True)
    return SeriesResult(out, done, skipped, secs)


@dataclass
class _FrameModel:
    """What every frame of a series shares (built once per process by :func:`_frame_model`)."""

    projector: object
    depth_filter: DepthFilter | None
    settings: ReconSettings
    preprocess: Preprocess
    grid: object
    n: int
    rgrid: ReconGrid
    origin_xy_um: tuple[float, float]
    image_shape: tuple[int, int]
    writer: object
    reader: object
    solver: object = richardson_lucy

    def close(self) -> None:
        self.reader.close()


def _backend_device() -> str:
    """The Dr.Jit device of this process (for the workers to use the same)."""
    from lfsim.backend import backend_info

    info = backend_info()
    return "auto" if info is None else info.device


def _frame_model(
    bank,
    n_lenslets,
    st,
    pp,
    grid,
    ropt,
    rgrid,
    origin_xy_um,
    image_shape,
    writer,
    device,
    solver=None,
) -> _FrameModel:
    """The shared model of the frames: projector and depth filter from the PSF bank (sent to
    each worker once), the backend started in a worker process (``HRVPTM_THREADS`` threads,
    which also size the projector's thread pool when ``st.threads`` is unset), and the
    volume writer (:mod:`recon.volume_store`)."""
    from lfsim.backend import backend_info, init_backend

    from .frames import FrameReader

    if backend_info() is None:
        init_backend(device=device)
    projector = make_projector(bank, n_lenslets, st.projector, threads=st.threads)
    filt = (
        DepthFilter.for_optics(ropt, rgrid.depths_um, st.s, st.filter_window)
        if st.filter_window is not None
        else None
    )
    return _FrameModel(
        projector,
        filt,
        st,
        pp,
        grid,
        round(ropt.px_per_lenslet),
        rgrid,
        origin_xy_um,
        image_shape,
        writer,
        FrameReader(),
        richardson_lucy if solver is None else solver,
    )


def reconstruct_frame(job, model: _FrameModel) -> dict:
    """Reconstruct one frame and write its volume atomically (``NNNNNN.tif``, or its chunks of
    the OME-Zarr image: ``model.writer``).

    The same in every process (the result depends on the frame and the model only).

    Parameters
    ----------
    job : (int, recon.frames.FrameRef, dict)
        Frame index ``k``, the frame, and its source entries of ``recon.json`` (recorded in the
        volume's metadata).
    model : _FrameModel

    Returns
    -------
    dict
        The frame's result entries of ``recon.json`` (``seconds``, ``iterations``,
        ``preprocess``, ``rel_change``, ``output``: the volume's record, and
        ``projector_threads``).

    Raises
    ------
    InputError
        The frame cannot be read, its size is not the series', or the dark frame is brighter
        than it (:func:`recon.preprocess.check_dark`).
    """
    from .rectify import rectify

    k, ref, source = job
    st, rgrid = model.settings, model.rgrid
    t1 = time.perf_counter()
    raw = read_frame(ref.path, page=ref.page, reader=model.reader)
    if raw.shape != model.image_shape:
        raise InputError(
            f"frame {ref.label!r} is {raw.shape} px, the series started with {model.image_shape}"
        )
    pp = model.preprocess
    if pp.dark is not None:
        check_dark(raw, pp.dark, frame=f"frame {ref.label!r}", dark_name=pp.dark_name)
    modelled = st.background_model == "model"
    img, pinfo = prepare_image(raw, model.preprocess, subtract_background=not modelled)
    rect, _ = _rectify_roi(rectify, img, model.grid, model.n, st.roi_px)
    res = model.solver(
        rect,
        model.projector,
        st.iterations,
        depth_filter=model.depth_filter,
        stop_rel_change=st.stop_rel_change,
        track_kl=False,
        # Rectified pixels are interpolated samples: a constant black level keeps its value
        # (no flux factor).
        background=max(pinfo["background"], 0.0) if modelled else 0.0,
    )
    record = model.writer.write(
        k,
        res.volume.astype(np.float32),
        {
            "frame": k,
            **source,
            "depths_um": list(map(float, rgrid.depths_um)),
            "origin_um": list(model.origin_xy_um),
            "iterations": res.iterations,
            # the lenslet period and phase travel with a TIFF copied without recon.json
            # (track.volumes.lenslet_phases), and so does the frame's SNR
            "grid": rgrid.to_dict(),
            "snr": pinfo["snr"],
        },
    )
    return {
        "seconds": time.perf_counter() - t1,
        "iterations": res.iterations,
        "preprocess": pinfo,
        "rel_change": res.rel_change,
        "projector_threads": getattr(model.projector, "threads", None),
        "output": record,
    }


#: Per-frame entries of ``recon.json`` naming the frame's source.
_SOURCE_KEYS = ("input", "page", "number", "time_s")
#: Per-frame entries of ``recon.json`` that a reconstruction adds (kept when resuming).
_RESULT_KEYS = ("seconds", "iterations", "preprocess", "rel_change", "output")


def _frame_entry(k: int, ref, sha: str) -> dict:
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
    this run's frame of the same index (:func:`_frame_entry`), as text for a message."""

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


def _clean_up_failed_start(writer, created: bool, done: list) -> None:
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


def _check_output(
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
            what = _input_change(was, _frame_entry(k, refs[k], checksums[k]))
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


def _rectify_roi(rectify, image, grid, n, roi):
    if roi is None:
        return rectify(image, grid, n)
    x0, x1, y0, y1 = roi
    h, w = image.shape
    if x1 > w or y1 > h:
        raise InputError(f"region of interest {roi} exceeds the {w} × {h} px image")
    ox, oy = grid.origin_px
    sub = replace(grid, origin_px=(ox - x0, oy - y0), image_shape=(y1 - y0, x1 - x0))
    rect, geom = rectify(image[y0:y1, x0:x1], sub, n)
    return rect, geom


def _object_origin(grid, geom, optics) -> tuple[float, float]:
    """Object-space (x, y) of the corner of rectified lenslet (0, 0).

    The optical axis (``optics.axis_px`` on the sensor) is the object origin; lenslet
    indices are converted with the calibrated grid and the object-space lenslet pitch.
    """
    ua, va = grid.lenslet_index(np.asarray([optics.axis_px], dtype=np.float64))[0]
    u0, v0 = geom.first_lenslet
    p = optics.lenslet_object_um
    return ((u0 - ua - 0.5) * p, (v0 - va - 0.5) * p)


def _version() -> str:
    from . import __version__

    return __version__
