"""Generate a synthetic light-field dataset from an :class:`~lfsim.experiment.Experiment`.

Layout of the output folder (docs/conventions.md §6)::

    white.tif              flat field: uniformly fluorescent slide through the same optics
    frames/000000.tif      light-field frames, camera-like integers (uint8/uint16), frame 0 =
    frames/000001.tif      reference configuration; JSON metadata (frame, noise, pixel size)
    truth/000000.csv       ground truth: id,x_um,y_um,z_um,diameter_um,brightness of every
    truth/000001.csv       particle at that frame (also those that left the field of view)
    dataset.json           provenance: versions, experiment, scene checksum, optics, seed,
                           fingerprint, status, per-frame timings and noise

Determinism. The reference particles are seeded once with ``numpy.random.default_rng(seed)``.
Frame ``k`` is traced with a render seed and noised with a generator both derived from
``(seed, k)`` only (:func:`frame_seeds`), and every file is written atomically; so the same
experiment gives byte-identical files, and an interrupted run that is resumed gives exactly
what an uninterrupted one gives — as does a run whose frames are rendered on Dask workers
(``parallel``, :mod:`hrvbase.parallel`; :func:`render_frame` is one frame).

Re-running on an existing folder:

- same experiment (same :meth:`~lfsim.experiment.Experiment.fingerprint`): resume — a frame
  is kept when its ``.tif`` and ``.csv`` are still the files recorded when they were written
  (size and SHA-256); a truncated or edited one is rendered again; a complete dataset is left
  untouched;
- a dataset of a different experiment: refused unless ``overwrite=True``, which first deletes
  only the files this module writes (``white.tif``, ``frames/NNNNNN.tif``,
  ``truth/NNNNNN.csv``, ``dataset.json`` and its own leftover temporary files);
- a non-empty folder without ``dataset.json``: always refused.
"""

from __future__ import annotations

import logging
import os
import platform
import re
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.errors import HrvError
from hrvbase.io import file_record, read_json, sha256_file, verify_record, write_json

from .errors import ConfigError, OutputError
from .experiment import Experiment
from .io import write_tiff
from .noise import SNR_DEFINITION, add_gaussian_noise, apply_noise
from .particles import Particles

log = logging.getLogger(__name__)

DATASET_FORMAT = "lfsim-dataset"
DATASET_FORMAT_VERSION = 1
RECORD = "dataset.json"
WHITE = "white.tif"
FRAMES = "frames"
TRUTH = "truth"

_FRAME_RE = re.compile(r"^\d{6}\.tif$")
_TRUTH_RE = re.compile(r"^\d{6}\.csv$")
# Temporary files of lfsim.io / Particles.to_csv: ".NAME.XXXXXXXX.tmp".
_TMP_RE = re.compile(r"^\.(\d{6}\.(tif|csv)|white\.tif|dataset\.json)\..+\.tmp$")

# Independent random streams derived from the experiment seed.
_STREAM_FRAME_RENDER = 1
_STREAM_FRAME_NOISE = 2
_STREAM_WHITE_RENDER = 3
_STREAM_WHITE_NOISE = 4


def frame_path(out_dir: str | os.PathLike, k: int) -> Path:
    """``out_dir/frames/NNNNNN.tif`` of frame ``k``."""
    return Path(out_dir) / FRAMES / f"{k:06d}.tif"


def truth_path(out_dir: str | os.PathLike, k: int) -> Path:
    """``out_dir/truth/NNNNNN.csv`` of frame ``k``."""
    return Path(out_dir) / TRUTH / f"{k:06d}.csv"


def _render_seed(seed: int, stream: int, *key: int) -> int:
    return int(np.random.SeedSequence([seed, stream, *key]).generate_state(1, np.uint32)[0])


def frame_seeds(seed: int, k: int) -> tuple[int, np.random.Generator]:
    """Render seed (uint32) and noise generator of frame ``k``, derived from ``(seed, k)``."""
    render = _render_seed(seed, _STREAM_FRAME_RENDER, k)
    noise = np.random.default_rng(np.random.SeedSequence([seed, _STREAM_FRAME_NOISE, k]))
    return render, noise


def white_seeds(seed: int) -> tuple[int, np.random.Generator]:
    """Render seed and noise generator of the white image, derived from ``seed``."""
    render = _render_seed(seed, _STREAM_WHITE_RENDER)
    noise = np.random.default_rng(np.random.SeedSequence([seed, _STREAM_WHITE_NOISE]))
    return render, noise


def reference_particles(experiment: Experiment) -> Particles:
    """The experiment's reference particles, seeded with ``default_rng(experiment.seed)``."""
    return experiment.particles.make(np.random.default_rng(experiment.seed))


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


# -- output folder handling --------------------------------------------------------------
def _inspect(out: Path, fingerprint: str, overwrite: bool) -> tuple[str, dict | None]:
    """What to do with ``out``: ``("new"|"resume"|"replace", previous record or None)``."""
    if not out.exists():
        return "new", None
    if not out.is_dir():
        raise OutputError(f"{out} exists and is not a folder")
    rec_path = out / RECORD
    if not rec_path.is_file():
        try:
            entries = next(os.scandir(out), None)
        except OSError as exc:
            raise OutputError(f"cannot read folder {out}: {exc}") from exc
        if entries is not None:
            raise OutputError(
                f"{out} is not empty and is not an lfsim dataset (no {RECORD}); refusing to "
                "write into it — choose an empty or new folder"
            )
        return "new", None
    try:
        record = read_json(rec_path)
        if not isinstance(record, dict) or record.get("format") != DATASET_FORMAT:
            raise ConfigError("not an lfsim dataset record")
    except ConfigError as exc:
        if overwrite:
            return "replace", None
        raise OutputError(
            f"{rec_path} is not a valid lfsim dataset record ({exc}); pass overwrite=True "
            "(--overwrite) to replace the dataset"
        ) from exc
    if overwrite:
        return "replace", record
    if record.get("fingerprint") == fingerprint:
        return "resume", record
    old = (record.get("experiment") or {}).get("experiment", {}).get("name", "?")
    raise OutputError(
        f"{out} holds a dataset of a different experiment ({old!r}, fingerprint "
        f"{str(record.get('fingerprint'))[:12]}…, this one {fingerprint[:12]}…); pass "
        "overwrite=True (--overwrite) to replace it, or choose another folder"
    )


def _tool_files(out: Path) -> list[Path]:
    """Files in ``out`` that this module writes (and nothing else)."""
    found = [out / n for n in (WHITE, RECORD) if (out / n).is_file()]
    for sub, pattern in ((FRAMES, _FRAME_RE), (TRUTH, _TRUTH_RE)):
        d = out / sub
        if d.is_dir():
            found += [p for p in sorted(d.iterdir()) if pattern.match(p.name) and p.is_file()]
    return found


def _temp_files(out: Path) -> list[Path]:
    found = []
    for d in (out, out / FRAMES, out / TRUTH):
        if d.is_dir():
            found += [p for p in sorted(d.iterdir()) if _TMP_RE.match(p.name) and p.is_file()]
    return found


def _remove(paths: list[Path]) -> None:
    for p in paths:
        try:
            p.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise OutputError(f"cannot remove {p}: {exc}") from exc


def _remove_tool_files(out: Path) -> None:
    files = _tool_files(out)
    _remove(files + _temp_files(out))
    for sub in (FRAMES, TRUTH):
        d = out / sub
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()
    log.info("overwrite: removed %d files of the previous dataset in %s", len(files), out)


def _frame_done(out: Path, k: int, rec: dict | None) -> bool:
    """Whether frame ``k`` is finished: recorded, and its image and truth table still are the
    files written then (size and SHA-256; a truncated or corrupt file is rendered again)."""
    files = (rec or {}).get("files") or {}
    return verify_record(frame_path(out, k), files.get("frame")) and verify_record(
        truth_path(out, k), files.get("truth")
    )


def _software() -> dict:
    from . import __version__

    out = {"lfsim": __version__, "python": platform.python_version(), "numpy": np.__version__}
    for mod in ("mitsuba", "drjit", "tifffile"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:  # pragma: no cover - optional information
            out[mod] = None
    return out


# -- one frame (in this process or on a Dask worker) ------------------------------------------
class _RenderModel:
    """What every frame of a dataset shares (built once per process by :func:`_render_model`)."""

    def __init__(self, experiment, scene, reference, common_meta, out):
        self.experiment = experiment
        self.scene = scene
        self.reference = reference
        self.common_meta = common_meta
        self.out = Path(out)


def _render_model(experiment, scene, reference, common_meta, out, backend) -> _RenderModel:
    """The shared model. ``scene`` is the loaded scene (in process) or its file: in a worker
    process the backend is started (the device of the main process, ``HRVPTM_THREADS``
    threads) and the scene loaded, once."""
    from .backend import backend_info, init_backend
    from .scene import load_scene

    if isinstance(scene, str | os.PathLike):
        if backend_info() is None:
            init_backend("auto" if backend is None else backend.device)
        scene = load_scene(scene)
    return _RenderModel(experiment, scene, reference, common_meta, out)


def render_frame(k: int, model: _RenderModel) -> dict:
    """Render, noise and write frame ``k`` (its ``.tif`` and truth ``.csv``, atomically).

    The result depends on the experiment and ``k`` only (:func:`frame_seeds`), not on the
    process that runs it.

    Returns
    -------
    dict
        The frame's record of ``dataset.json`` (``frame``, ``seconds``,
        ``particles_in_field``, ``noise``, ``files``).
    """
    from .render import render_particles

    experiment, out = model.experiment, model.out
    optics = model.scene.optics
    t0 = time.perf_counter()
    reference = model.reference
    particles = reference.with_positions(experiment.positions(reference.positions_um, k))
    r_seed, n_rng = frame_seeds(experiment.seed, k)
    clean = render_particles(
        model.scene,
        particles,
        experiment.render.settings(r_seed),
        tracer=experiment.render.tracer,
        check_field=False,
    )
    try:
        # Integer photon counts: the camera model thins them (no double shot noise).
        img, info = apply_noise(clean, experiment.noise_for_frame(k), n_rng)
    except ConfigError as exc:
        raise ConfigError(f"experiment {experiment.name!r}, frame {k}: {exc}") from exc
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    p = particles.positions_um
    inside = int(np.sum((p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)))
    meta = {
        **model.common_meta,
        "kind": "frame",
        "frame": k,
        "render_seed": r_seed,
        "rays_per_particle": experiment.render.rays_per_particle,
        "model": experiment.render.model,
        "photons": int(clean.sum(dtype=np.int64)),
        "particles_in_field": inside,
        "noise": info,
    }
    particles.to_csv(truth_path(out, k))
    write_tiff(
        frame_path(out, k),
        img,
        metadata=meta,
        pixel_size_um=optics.object_pixel_um,
        overwrite=True,
    )
    return {
        "frame": k,
        "seconds": time.perf_counter() - t0,
        "particles_in_field": inside,
        "noise": info,
        "files": {
            "frame": file_record(frame_path(out, k)),
            "truth": file_record(truth_path(out, k)),
        },
    }


# -- the generator ----------------------------------------------------------------------------
def _is_complete(out: Path, experiment: Experiment, previous: dict) -> bool:
    """Whether the dataset in ``out`` (its record ``previous``) is complete with every frame
    and the white image as they were written."""
    n = experiment.frames
    white_on = experiment.white.enabled
    recs = list(previous.get("frame_records") or []) + [None] * n
    done = [_frame_done(out, k, recs[k]) for k in range(n)]
    white_rec = (previous.get("white") or {}).get("file_record")
    white_done = (not white_on) or verify_record(out / WHITE, white_rec)
    if previous.get("status") == "complete" and all(done) and white_done:
        log.info("%s: dataset %r is complete; nothing to do", out, experiment.name)
        return True
    return False


def _checked_inputs(experiment: Experiment) -> tuple:
    """The scene and reference particles of ``experiment``, checked: particles seeded, in
    the field of view and at depths the optics image in every frame."""
    from .backend import backend_info, init_backend
    from .render import check_depths, check_in_field
    from .scene import load_scene

    n = experiment.frames
    if backend_info() is None:
        init_backend()
    scene = load_scene(experiment.scene)
    optics = scene.optics
    reference = reference_particles(experiment)
    if len(reference) == 0:
        raise ConfigError(f"experiment {experiment.name!r} seeds no particles")
    check_in_field(
        optics,
        reference.positions_um,
        reference.ids,
        what=f"reference particles of experiment {experiment.name!r}",
    )
    positions = [experiment.positions(reference.positions_um, k) for k in range(n)]
    for k, pos in enumerate(positions):
        check_depths(
            optics, pos, reference.ids, what=f"particles of frame {k} of {experiment.name!r}"
        )
    return scene, reference


def _prepare_folder(out: Path, action: str) -> None:
    """The dataset folder and its subfolders, this module's files deleted first when
    replacing a dataset and leftovers of a killed run removed."""
    if action == "replace":
        _remove_tool_files(out)
    try:
        (out / FRAMES).mkdir(parents=True, exist_ok=True)
        (out / TRUTH).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create dataset folder {out}: {exc}") from exc
    _remove(_temp_files(out))  # leftovers of a killed run


def _new_record(experiment, fingerprint, optics, n_particles, backend, started) -> dict:
    """The ``dataset.json`` record of a new run (status "incomplete", no frame yet)."""
    from . import __version__

    n = experiment.frames
    white_on = experiment.white.enabled
    record: dict[str, Any] = {
        "format": DATASET_FORMAT,
        "format_version": DATASET_FORMAT_VERSION,
        "lfsim_version": __version__,
        "software": _software(),
        "backend": None
        if backend is None
        else {"variant": backend.variant, "threads": backend.threads},
        "status": "incomplete",
        "fingerprint": fingerprint,
        "name": experiment.name,
        "experiment": experiment.to_dict(),
        "experiment_file": None if experiment.source is None else str(experiment.source),
        "scene": {"path": str(experiment.scene), "sha256": sha256_file(experiment.scene)},
        "optics": optics.to_dict(),
        "seed": experiment.seed,
        "frames": n,
        "n_particles": n_particles,
        "object_pixel_um": optics.object_pixel_um,
        "layout": {
            "white": WHITE if white_on else None,
            "frames": f"{FRAMES}/{{frame:06d}}.tif",
            "truth": f"{TRUTH}/{{frame:06d}}.csv",
        },
        "snr_definition": SNR_DEFINITION,
        "white": None,
        "frame_records": [None] * n,
        "created": started,
        "runs": [],
        "finished": None,
    }
    return record


def _resume_record(record: dict, previous: dict, out: Path) -> None:
    """Carry over into ``record`` what a previous run (its record ``previous``) wrote and is
    still intact on disk: creation time, runs, white image and frames."""
    record["created"] = previous.get("created", record["created"])
    record["runs"] = list(previous.get("runs", []))
    white_prev = previous.get("white") or {}
    if verify_record(out / WHITE, white_prev.get("file_record")):
        record["white"] = white_prev
    old = previous.get("frame_records") or []
    changed = []
    for k in range(min(len(record["frame_records"]), len(old))):
        if _frame_done(out, k, old[k]):
            record["frame_records"][k] = old[k]
        elif old[k] is not None:
            changed.append(k)
    if changed:
        log.warning(
            "%s: frame(s) %s changed on disk since they were written (truncated or "
            "corrupt); rendering them again",
            out,
            ", ".join(map(str, changed)),
        )


def _write_white(out: Path, experiment, scene, record: dict, common_meta: dict) -> None:
    """Render and write the white (flat-field) image unless it is there as recorded."""
    from .render import render_white

    optics = scene.optics
    rec_path = out / RECORD
    white_rec = record.get("white") or {}
    if experiment.white.enabled and not verify_record(out / WHITE, white_rec.get("file_record")):
        t0 = time.perf_counter()
        w_seed, w_rng = white_seeds(experiment.seed)
        clean = render_white(
            scene,
            experiment.white.rays_per_lenslet,
            seed=w_seed,
            diffraction=experiment.render.diffraction,
            tracer=experiment.render.tracer,
        )
        img, info = add_gaussian_noise(
            clean.astype(np.float64),
            experiment.white.snr,
            w_rng,
            bit_depth=experiment.white.bit_depth,
        )
        meta = {
            **common_meta,
            "kind": "white",
            "rays_per_lenslet": experiment.white.rays_per_lenslet,
            "render_seed": w_seed,
            "noise": info,
        }
        write_tiff(
            out / WHITE, img, metadata=meta, pixel_size_um=optics.object_pixel_um, overwrite=True
        )
        record["white"] = {
            "file": WHITE,
            "seconds": time.perf_counter() - t0,
            "noise": info,
            "file_record": file_record(out / WHITE),
        }
        write_json(rec_path, record, overwrite=True)
        log.info("wrote %s", out / WHITE)


def _render_frames(
    out, experiment, scene, reference, common_meta, backend, todo, run, record, parallel, progress
) -> None:
    """Render the frames ``todo`` wherever ``parallel`` runs them (:func:`render_frame`),
    recording each in ``record`` and ``dataset.json`` as it arrives."""
    from hrvbase.parallel import Parallel, WorkerContext, frame_map

    rec_path = out / RECORD
    par = Parallel() if parallel is None else parallel
    record["parallel"] = {"mode": par.describe()}
    context = WorkerContext(
        _render_model,
        # Paths absolute: workers may run in another folder.
        (
            experiment,
            scene if par.in_process else Path(experiment.scene).resolve(),
            reference,
            common_meta,
            out.resolve(),
            backend,
        ),
    )
    fmap = frame_map(
        render_frame,
        todo,
        parallel=par,
        context=context,
        progress=progress,
        desc=experiment.name,
    )
    try:
        with fmap:
            for k, frame_record in fmap:
                record["frame_records"][k] = frame_record
                run["frames_rendered"] += 1
                write_json(rec_path, record, overwrite=True)
                log.debug("frame %d: %.2f s", k, frame_record["seconds"])
    except (HrvError, KeyboardInterrupt):
        run["finished"] = _now()
        write_json(rec_path, record, overwrite=True)
        raise
    record["parallel"]["peak_memory_bytes"] = fmap.peak_memory_bytes


def generate_dataset(
    experiment: Experiment,
    out_dir: str | os.PathLike,
    *,
    overwrite: bool = False,
    progress: bool = True,
    parallel=None,
) -> Path:
    """Render every frame of ``experiment`` (and the white image) into ``out_dir``.

    Parameters
    ----------
    experiment : Experiment
    out_dir : path
        Output folder (created if missing). See the module docstring for resume/overwrite.
    overwrite : bool
        Replace a dataset of another experiment (deleting only this module's files), or
        regenerate a dataset of this one from scratch.
    progress : bool
        Show a tqdm progress bar over frames.
    parallel : hrvbase.parallel.Parallel, optional
        Where the frames are rendered (default: in this process, one after the other); the
        files are the same however they run (each frame is seeded from ``(seed, k)``).

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    ConfigError
        Reference particles outside the field of view (or none at all), or a frame without
        any signal to add noise to.
    OutputError
        ``out_dir`` is a non-empty non-dataset folder, holds another experiment's dataset
        (without ``overwrite``), or cannot be written.
    """
    from . import __version__
    from .backend import backend_info

    if not isinstance(experiment, Experiment):
        raise ConfigError(f"experiment must be an Experiment, got {type(experiment).__name__}")
    out = Path(out_dir)
    fingerprint = experiment.fingerprint()
    action, previous = _inspect(out, fingerprint, overwrite)
    n = experiment.frames
    if action == "resume" and _is_complete(out, experiment, previous):
        return out

    # Everything that can fail on bad input happens before the folder is touched.
    scene, reference = _checked_inputs(experiment)
    optics = scene.optics
    _prepare_folder(out, action)
    backend = backend_info()
    started = _now()
    record = _new_record(experiment, fingerprint, optics, len(reference), backend, started)
    if action == "resume" and previous is not None:
        _resume_record(record, previous, out)
    run = {"started": started, "finished": None, "frames_rendered": 0, "frames_skipped": 0}
    record["runs"].append(run)
    rec_path = out / RECORD
    write_json(rec_path, record, overwrite=True)

    common_meta = {
        "experiment": experiment.name,
        "fingerprint": fingerprint,
        "pixel_size_um": optics.object_pixel_um,
        "lfsim_version": __version__,
    }

    _write_white(out, experiment, scene, record, common_meta)

    todo = [k for k in range(n) if not _frame_done(out, k, record["frame_records"][k])]
    skipped = n - len(todo)
    run["frames_skipped"] = skipped
    if skipped:
        log.info("%s: %d of %d frames already present and verified, skipped", out, skipped, n)

    _render_frames(
        out,
        experiment,
        scene,
        reference,
        common_meta,
        backend,
        todo,
        run,
        record,
        parallel,
        progress,
    )

    run["finished"] = record["finished"] = _now()
    record["status"] = "complete"
    write_json(rec_path, record, overwrite=True)
    log.info(
        "%s: dataset %r complete (%d frames rendered, %d skipped)",
        out,
        experiment.name,
        run["frames_rendered"],
        skipped,
    )
    return out
