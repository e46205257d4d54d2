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
from .psf import compute_psf_bank, pattern_radius_lenslets
from .psf_wave import choose_psf_model, compute_wave_psf_bank, model_bank_key
from .run_record import (
    RECON_JSON,
    RESULT_KEYS,
    SOURCE_KEYS,
    check_output,
    clean_up_failed_start,
    frame_entry,
)
from .settings import ReconSettings, default_z_step_um
from .volume_store import (  # noqa: F401 (OutputExistsError importable from here)
    OutputExistsError,
    VolumeGeometry,
    make_writer,
)

log = logging.getLogger(__name__)


#: Largest radius (lenslets) of a point's light pattern the PSF bank stores (its memory grows
#: with the square of it).
MAX_PATTERN_RADIUS_LENSLETS = 120


def check_depths_resolvable(optics, depths_um, n_lenslets_xy: tuple[int, int]) -> None:
    """Refuse depths whose light leaves the sensor (the optics cannot resolve them).

    A point at depth z lights a disc of lenslets of radius ``r(z)``; once that disc is wider
    than the image, most of the point's light misses the sensor and its depth cannot be
    reconstructed. The message gives the deepest resolvable ``|z|``, searched in steps of the
    optics' default depth step (:func:`recon.settings.default_z_step_um`).
    """
    nx, ny = n_lenslets_xy
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
OPTICS_MATCH_FIELDS = (
    "na",
    "mla_pitch_um",
    "mla_focal_um",
    "pixel_um",
    "sensor_xy_px",
    "axis_xy_px",
)

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
    return replace(optics, pixel_um=optics.mla_pitch_um / n, axis_xy_px=None, sensor_xy_px=(n, n))


#: Names under which the fingerprint hashes the entries named otherwise in the API
#: (docs/conventions.md §3): it identifies what a series produces, and an entry's name does not
#: change that, so the volumes already reconstructed are resumed.
#: The optics' own (``lfsim.optics.FINGERPRINT_KEYS``) are added to these.
FINGERPRINT_KEYS = {"roi_xy_px": "roi_px", "origin_xy_px": "origin_px"}


def _fingerprint(payload: dict) -> str:
    from hrvbase.io import rename_keys
    from lfsim.optics import FINGERPRINT_KEYS as OPTICS_KEYS

    text = json.dumps(rename_keys(payload, {**FINGERPRINT_KEYS, **OPTICS_KEYS}), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


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
    from hrvbase.parallel import Parallel

    from .frames import frame_checksums

    par = Parallel() if parallel is None else parallel
    st = (settings or ReconSettings()).resolved(optics)
    pp = preprocess or Preprocess()
    scene_mla_kind = optics.mla_kind
    optics = model_optics(optics)
    refs = _frame_refs(frames)
    out = Path(out_dir)
    writer = make_writer(volume_format, out, zarr_chunk_z=zarr_chunk_z)
    n, ropt = _rectified(optics, grid)
    depths = st.depths_um

    first, geom = _first_frame(refs[0], grid, pp, n, st.roi_xy_px)
    nx, ny = geom.n_lenslets_xy
    check_depths_resolvable(optics, depths, (nx, ny))

    key = _bank_key(optics, ropt, st)
    identity = _identity(st, pp, optics, grid, key, solver)
    dark_sum = identity["preprocess"]["dark_sha256"]
    fp = _fingerprint(identity)
    checksums = frame_checksums(refs)
    meta_path = out / RECON_JSON
    fps = (provenance or {}).get("fps")
    previous = check_output(writer, fp, refs, checksums, overwrite, fps=fps, identity=identity)
    created = not out.exists()
    done, skipped, secs = [], [], {}
    try:
        o_x, o_y = _object_origin(grid, geom, optics)
        rgrid = ReconGrid(optics.lenslet_object_um, tuple(depths), st.s, (nx, ny), (o_x, o_y))
        _prepare_writer(writer, refs, rgrid, overwrite)
        meta = _series_record(
            fp, optics, grid, st, pp, dark_sum, rgrid, key, scene_mla_kind, writer, par
        )
        meta.update(provenance or {})
        frame_entries, todo = _plan_frames(refs, checksums, previous, writer, pp, skipped)
        meta["frames"] = frame_entries
        write_json(meta_path, meta, overwrite=True)
        if skipped:
            log.info("%s: %d frame(s) already reconstructed, skipped", out, len(skipped))
        if todo:
            run = (refs, todo, frame_entries, meta, meta_path, first.shape, (o_x, o_y))
            _run_frames(
                run, st, pp, grid, optics, ropt, rgrid, writer, par, solver, progress, done, secs
            )
    except BaseException:
        clean_up_failed_start(writer, created, done)
        raise
    meta["status"] = "complete"
    write_json(meta_path, meta, overwrite=True)
    return SeriesResult(out, done, skipped, secs)


def _bank_key(optics, ropt, st) -> str:
    """Cache key of the series' PSF bank: of the model ``st.psf_model`` picks for ``optics``
    (:func:`recon.psf_wave.choose_psf_model`), on the rectified optics ``ropt``."""
    model = choose_psf_model(optics, st.psf_model)
    return model_bank_key(ropt, st.depths_um, st.s, model, st.rays_per_pattern)


def _frame_refs(frames) -> list:
    """The frames as :class:`recon.frames.FrameRef`, checked (same size, pixel type and
    bit depth)."""
    from .frames import FrameRef, check_frames

    refs = [FrameRef.of(f) for f in frames]
    if not refs:
        raise InputError("no frames to reconstruct")
    check_frames(refs)
    return refs


def _rectified(optics, grid) -> tuple:
    """The pixels per rectified lenslet and the optics of the rectified image (a warning
    where the calibrated pitch differs from the scene's by more than 5 %)."""
    n = round(optics.px_per_lenslet)
    if abs(grid.pitch_px - optics.px_per_lenslet) > 0.05 * optics.px_per_lenslet:
        log.warning(
            "calibrated pitch %.3f px differs from the scene's %.3f px by more than 5 %%",
            grid.pitch_px,
            optics.px_per_lenslet,
        )
    return n, rectified_optics(optics, n)


def _prepare_writer(writer, refs, rgrid, overwrite: bool) -> None:
    """Prepare ``writer`` for the volumes of ``refs`` on reconstruction grid ``rgrid``."""
    origin_xyz = (rgrid.x_um()[0], rgrid.y_um()[0], rgrid.depths_um[0])
    geometry = VolumeGeometry(tuple(rgrid.shape), tuple(rgrid.voxel_size_um), origin_xyz)
    writer.prepare(
        len(refs), geometry, [r.time_s for r in refs], overwrite, [r.number for r in refs]
    )


def _identity(st, pp, optics, grid, key, solver) -> dict:
    """What the fingerprint of a series is made of: the settings, the preparation (with the
    dark frame's checksum), the optics, the calibration, the PSF bank and the solver."""
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
    return identity


def _first_frame(ref, grid, pp, n, roi_xy_px):
    """The first frame (checked against the calibration's image size and the dark frame) and
    its rectification geometry, which every frame of the series shares."""
    from .rectify import rectify

    first = read_frame(ref.path, page=ref.page)
    if tuple(first.shape) != tuple(grid.image_shape):
        raise InputError(
            f"frame {ref.label!r} is {first.shape[1]} × {first.shape[0]} px but the "
            f"calibration was made on {grid.image_shape[1]} × {grid.image_shape[0]} px images"
        )
    if pp.dark is not None:
        check_dark(first, pp.dark, frame=f"frame {ref.label!r}", dark_name=pp.dark_name)
    _, geom = _rectify_roi(rectify, first, grid, n, roi_xy_px)
    return first, geom


def _surface_z_um(optics) -> float | None:
    """The specimen's near surface (µm; the planes in front of it are guard planes, where
    ``track`` rejects particles); None without interfaces."""
    return optics.surface_z_um if optics.has_interfaces else None


def _series_record(
    fp, optics, grid, st, pp, dark_sum, rgrid, key, scene_mla_kind, writer, par
) -> dict:
    """The ``recon.json`` record of a series before its frames (status "incomplete")."""
    return {
        "tool": "recon",
        "version": _version(),
        "fingerprint": fp,
        "status": "incomplete",
        "optics": optics.to_dict(),
        "surface_z_um": _surface_z_um(optics),
        "calibration": grid.to_dict(),
        "settings": st.to_dict(),
        "preprocess": {**pp.to_dict(), "dark_sha256": dark_sum},
        "grid": rgrid.to_dict(),
        "voxel_size_um": list(rgrid.voxel_size_um),
        "volume_shape": list(rgrid.shape),
        "psf_bank": key,
        "psf_model": choose_psf_model(optics, st.psf_model),
        "scene_mla_kind": scene_mla_kind,
        "format": writer.format,
        **writer.record_extra(),
        "frames": [],
        "parallel": {"mode": par.describe()},
    }


def _plan_frames(refs, checksums, previous, writer, pp, skipped) -> tuple[list, list]:
    """Every frame's ``recon.json`` entry and the indices still to reconstruct: a frame whose
    volume a previous run (``previous``, its record) made from the same input and that is
    intact on disk keeps its results (its SNR measured again where the record lacks it or
    the camera gain changed) and is appended to ``skipped``."""
    out = writer.out
    prev_frames = {e.get("index"): e for e in (previous or {}).get("frames", [])}
    frame_entries = []
    todo = []
    for k, (ref, sha) in enumerate(zip(refs, checksums, strict=True)):
        entry = frame_entry(k, ref, sha)
        e = prev_frames.get(k)
        if e and e.get("input_sha256") == sha and writer.verify(k, e.get("output")):
            entry.update({name: e[name] for name in RESULT_KEYS if name in e})
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
    return frame_entries, todo


def _run_frames(run, st, pp, grid, optics, ropt, rgrid, writer, par, solver, progress, done, secs):
    """Compute the PSF bank and reconstruct the frames ``todo`` (wherever ``par`` runs them,
    :func:`reconstruct_frame`), recording each in ``meta`` and ``recon.json`` as it
    arrives; appends to ``done`` and ``secs``."""
    from hrvbase.io import write_json
    from hrvbase.parallel import WorkerContext, frame_map

    refs, todo, frame_entries, meta, meta_path, first_shape, (o_x, o_y) = run
    nx, ny = rgrid.n_lenslets_xy
    depths = st.depths_um
    t0 = time.perf_counter()
    if choose_psf_model(optics, st.psf_model) == "wave":
        bank = compute_wave_psf_bank(ropt, depths, st.s, progress=progress)
    else:
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
            tuple(first_shape),
            replace(writer, out=writer.out.resolve()),  # workers may run elsewhere
            _backend_device(),
            solver,
        ),
    )
    jobs = [
        (
            k,
            replace(refs[k], path=Path(refs[k].path).resolve()),
            {k2: v for k2, v in frame_entries[k].items() if k2 in SOURCE_KEYS},
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
    surface_z_um: float | None = None

    def close(self) -> None:
        self.reader.close()


def _backend_device() -> str:
    """The Dr.Jit device of this process (for the workers to use the same)."""
    from lfsim.backend import backend_info

    info = backend_info()
    return "auto" if info is None else info.device


def _frame_model(
    bank,
    n_lenslets_xy,
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
    projector = make_projector(bank, n_lenslets_xy, st.projector, threads=st.threads)
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
        _surface_z_um(ropt),
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
    rect, _ = _rectify_roi(rectify, img, model.grid, model.n, st.roi_xy_px)
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
            "origin_xy_um": list(model.origin_xy_um),
            "iterations": res.iterations,
            # the lenslet period and phase travel with a TIFF copied without recon.json
            # (track.volumes.lenslet_phases), and so do the frame's SNR and the specimen's
            # near surface
            "grid": rgrid.to_dict(),
            "snr": pinfo["snr"],
            "surface_z_um": model.surface_z_um,
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


def _rectify_roi(rectify, image, grid, n, roi):
    if roi is None:
        return rectify(image, grid, n)
    x0, x1, y0, y1 = roi
    h, w = image.shape
    if x1 > w or y1 > h:
        raise InputError(f"region of interest {roi} exceeds the {w} × {h} px image")
    ox, oy = grid.origin_xy_px
    sub = replace(grid, origin_xy_px=(ox - x0, oy - y0), image_shape=(y1 - y0, x1 - x0))
    rect, geom = rectify(image[y0:y1, x0:x1], sub, n)
    return rect, geom


def _object_origin(grid, geom, optics) -> tuple[float, float]:
    """Object-space (x, y) of the corner of rectified lenslet (0, 0).

    The optical axis (``optics.axis_xy_px`` on the sensor) is the object origin; lenslet
    indices are converted with the calibrated grid and the object-space lenslet pitch.
    """
    ua, va = grid.lenslet_index(np.asarray([optics.axis_xy_px], dtype=np.float64))[0]
    u0, v0 = geom.first_lenslet_xy
    p = optics.lenslet_object_um
    return ((u0 - ua - 0.5) * p, (v0 - va - 0.5) * p)


def _version() -> str:
    from . import __version__

    return __version__
