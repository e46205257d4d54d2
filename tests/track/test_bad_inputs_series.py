"""Bad-input corpus of ``track run`` on volume series: camera frame numbers and times
(``recon.json`` and the volumes' metadata, an OME-Zarr t axis), damaged volumes in folders and
OME-Zarr images, reruns over finished results, outputs inside the inputs.

Every case follows the corpus rules of ``tests/corpus.py`` (one error line naming the fault,
no traceback, inputs unchanged, nothing written by a refused run). The rerun cases make a
finished results folder in the case's own folder first: the refused rerun must leave every
file of it byte for byte (SHA-256) as it was.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import tifffile

from tests.corpus import Base, Case, Env, case_adder, params, run_case

CASES: list[Case] = []
case = case_adder(CASES)


# -- builders ----------------------------------------------------------------------------------
def _frames(numbers=None, times=None, keep=None, extra=()):
    """An edit of a volume folder's ``recon.json``: its frames' numbers and times set (None:
    kept), only the first ``keep`` records kept, ``extra`` records appended."""

    def edit(d: Path) -> None:
        rec = json.loads((d / "recon.json").read_text())
        frames = rec["frames"]
        for k, f in enumerate(frames):
            if numbers is not None:
                f["number"] = numbers[k]
            if times is not None:
                f["time_s"] = times[k]
        if keep is not None:
            del frames[keep:]
        frames.extend(extra)
        (d / "recon.json").write_text(json.dumps(rec))  # NaN and Infinity as Python writes them

    return edit


def _run_frames(e: Env, **kw) -> list:
    return ["run", e.voldir(_frames(**kw)), "-o", e.o("res")]


def _metadata(numbers=None, times=None):
    """An edit of a volume folder: no ``recon.json``, the numbers and times in each TIFF's
    metadata (as ``recon run`` writes them) set."""

    def edit(d: Path) -> None:
        from lfsim.io import read_tiff, write_tiff

        (d / "recon.json").unlink()
        for k, p in enumerate(sorted(d.glob("*.tif"))):
            vol, meta = read_tiff(p)
            if numbers is not None:
                meta["number"] = numbers[k]
            if times is not None:
                meta["time_s"] = times[k]
            vs = meta.pop("voxel_size_um")
            origin = meta.pop("origin_xyz_um", None)
            write_tiff(
                p, vol, metadata=meta, pixel_size_um=vs, origin_xyz_um=origin, overwrite=True
            )

    return edit


def _truncate(frac: float, name: str = "000001.tif"):
    def edit(d: Path) -> None:
        p = d / name
        data = p.read_bytes()
        p.write_bytes(data[: int(len(data) * frac)])

    return edit


def _nan(d: Path) -> None:
    from lfsim.io import read_tiff, write_tiff

    p = d / "000002.tif"
    vol, meta = read_tiff(p)
    vol[vol.shape[0] // 2, 5, 5] = np.nan
    vs = meta.pop("voxel_size_um")
    origin = meta.pop("origin_xyz_um", None)
    write_tiff(p, vol, metadata=meta, pixel_size_um=vs, origin_xyz_um=origin, overwrite=True)


def _series_array(e: Env) -> tuple[np.ndarray, tuple]:
    """The shared volumes as one (t, z, y, x) array and their voxel size (dz, dy, dx)."""
    from lfsim.io import read_tiff

    vols, vs = [], None
    for p in sorted(e.b.vol.glob("*.tif")):
        vol, meta = read_tiff(p)
        vols.append(vol)
        vs = meta["voxel_size_um"]
    return np.stack(vols).astype(np.float32), tuple(vs)


def _zarr(e: Env, edit=None, data=None, t_scale=1.0, axes="tzyx", name="v.zarr") -> Path:
    """The shared volumes as an OME-Zarr image (``edit(store)`` after writing it)."""
    from tests.track.test_zarr_volumes import write_ngff

    arr, vs = _series_array(e)
    arr = arr if data is None else data(arr)
    scale = [{"t": t_scale, "c": 1.0}[a] for a in axes[:-3]] + list(vs)
    store = write_ngff(e.inp / name, arr, axes, scale)
    if edit is not None:
        edit(store)
    return store


def _first_chunk(store: Path, t: int) -> Path:
    return next(p for p in sorted((store / "0" / "c" / str(t)).rglob("*")) if p.is_file())


def _zarr_recon(numbers, times):
    def edit(store: Path) -> None:
        frames = [
            {"index": k, "number": n, "time_s": t, "output": {"t": k}}
            for k, (n, t) in enumerate(zip(numbers, times, strict=True))
        ]
        (store / "recon.json").write_text(json.dumps({"format": "zarr", "frames": frames}))

    return edit


def _finished(e: Env, *extra) -> tuple[Path, Path]:
    """A copy of the shared volumes and a finished ``track run`` of it in the case's folder."""
    from track.cli import main

    vols = e.voldir()
    out = e.o("res")
    assert main(["-q", "run", str(vols), "-o", str(out), "--allow-partial", *extra]) == 0
    return vols, out


def _rerun(edit, *extra):
    def argv(e: Env) -> list:
        vols, out = _finished(e)
        edit(vols)
        return ["run", vols, "-o", out, "--allow-partial", *extra]

    return argv


# -- recon.json: frame numbers -----------------------------------------------------------------
case(
    "track-run-series-numbers-decreasing",
    "track",
    lambda e: _run_frames(e, numbers=[0, 5, 1]),
    "frame numbers must increase with the volumes",
)
case(
    "track-run-series-numbers-duplicated",
    "track",
    lambda e: _run_frames(e, numbers=[0, 1, 1]),
    "frame number 1 is recorded for both",
)
case(
    "track-run-series-number-negative",
    "track",
    lambda e: _run_frames(e, numbers=[-1, 0, 1]),
    "recon.json frame 0: number (the camera frame number) must be an integer >= 0",
)
case(
    "track-run-series-number-text",
    "track",
    lambda e: _run_frames(e, numbers=[0, "one", 2]),
    "recon.json frame 1: number (the camera frame number) must be an integer >= 0",
)
case(
    "track-run-series-number-fractional",
    "track",
    lambda e: _run_frames(e, numbers=[0, 1.5, 3]),
    "recon.json frame 1: number",
)
case(
    "track-run-series-number-boolean",
    "track",
    lambda e: _run_frames(e, numbers=[0, True, 2]),
    "recon.json frame 1: number",
)

# -- recon.json: frame times -------------------------------------------------------------------
case(
    "track-run-series-times-decreasing",
    "track",
    lambda e: _run_frames(e, times=[0.0, 0.2, 0.1]),
    "times must increase with the volumes",
)
case(
    "track-run-series-times-duplicated",
    "track",
    lambda e: _run_frames(e, numbers=[0, 1, 5], times=[0.0, 0.01, 0.01]),
    "time 0.01 is recorded for both",
)
case(
    "track-run-series-time-nan",
    "track",
    lambda e: _run_frames(e, times=[0.0, math.nan, 0.02]),
    "recon.json frame 1: time_s must be a finite number of seconds",
)
case(
    "track-run-series-time-infinite",
    "track",
    lambda e: _run_frames(e, times=[0.0, 0.01, math.inf]),
    "recon.json frame 2: time_s must be a finite number of seconds",
)
case(
    "track-run-series-time-text",
    "track",
    lambda e: _run_frames(e, times=[0.0, "10 ms", 0.02]),
    "recon.json frame 1: time_s",
)

# -- recon.json: records against the volumes ---------------------------------------------------
case(
    "track-run-series-recon-json-fewer-frames-than-volumes",
    "track",
    lambda e: _run_frames(e, numbers=[0, 1, 5], keep=2),
    "but not of volume",
)
case(
    "track-run-series-recon-json-more-frames-than-volumes",
    "track",
    lambda e: _run_frames(e, numbers=[0, 1, 5], extra=[{"index": 3, "number": 6, "time_s": None}]),
    "000003.tif is missing",
)
case(
    "track-run-series-recon-json-frame-recorded-twice",
    "track",
    lambda e: _run_frames(e, keep=2, extra=[{"index": 1, "number": 4}, {"index": 2, "number": 5}]),
    "frame index 1 is recorded twice",
)
case(
    "track-run-series-recon-json-frames-text",
    "track",
    lambda e: [
        "run",
        e.voldir(lambda d: (d / "recon.json").write_text(json.dumps({"frames": "0, 1, 5"}))),
        "-o",
        e.o("res"),
    ],
    "'frames' must be a list",
)

# -- the volumes' own metadata (a folder without recon.json) -----------------------------------
case(
    "track-run-series-metadata-numbers-decreasing",
    "track",
    lambda e: ["run", e.voldir(_metadata(numbers=[4, 2, 6])), "-o", e.o("res")],
    "frame numbers must increase with the volumes",
)
case(
    "track-run-series-metadata-time-text",
    "track",
    lambda e: ["run", e.voldir(_metadata(times=[0.0, "later", 0.2])), "-o", e.o("res")],
    "000001.tif: time_s must be a finite number",
)
case(
    "track-run-series-some-numbers-recorded",
    "track",
    lambda e: ["run", e.voldir(_frames(numbers=[0, 1, None])), "-o", e.o("res")],
    "000002.tif has no recorded frame number",
    kind="warning",
    writes=True,
)

# -- damaged TIFF volumes ----------------------------------------------------------------------
case(
    "track-run-series-truncated-inside-the-voxels",
    "track",
    lambda e: ["run", e.voldir(_truncate(0.5)), "-o", e.o("res")],
    "000001.tif is truncated",
)
case(
    "track-run-series-truncated-in-the-last-plane",
    "track",
    lambda e: ["run", e.voldir(_truncate(0.98, "000002.tif")), "-o", e.o("res")],
    "000002.tif is truncated",
)
case(
    "track-run-series-complex-volume",
    "track",
    lambda e: [
        "run",
        e.voldir(
            lambda d: (
                (d / "000001.tif").unlink(),
                tifffile.imwrite(
                    d / "000001.tif", np.zeros((4, 8, 8), np.complex64), photometric="minisblack"
                ),
            )
        ),
        "-o",
        e.o("res"),
    ],
    "000001.tif: unsupported voxel type complex64",
)

# -- OME-Zarr images ---------------------------------------------------------------------------
case(
    "track-run-series-zarr-truncated-chunk",
    "track",
    lambda e: [
        "run",
        _zarr(e, lambda s: _truncate(0.2, _first_chunk(s, 1).name)(_first_chunk(s, 1).parent)),
        "-o",
        e.o("res"),
    ],
    "v.zarr[t=1] (a truncated or damaged chunk?)",
)
case(
    "track-run-series-zarr-nan-frame",
    "track",
    lambda e: [
        "run",
        _zarr(
            e, data=lambda a: np.where(np.arange(a.shape[0])[:, None, None, None] == 2, np.nan, a)
        ),
        "-o",
        e.o("res"),
    ],
    "v.zarr[t=2]: volume holds NaN or infinite voxels",
)
case(
    "track-run-series-zarr-boolean-voxels",
    "track",
    lambda e: ["run", _zarr(e, data=lambda a: a > a.mean()), "-o", e.o("res")],
    "unsupported voxel type bool",
)
case(
    "track-run-series-zarr-two-channels",
    "track",
    lambda e: [
        "run",
        _zarr(e, data=lambda a: np.stack([a, a], axis=1), axes="tczyx"),
        "-o",
        e.o("res"),
    ],
    "2 channels; expected one",
)
case(
    "track-run-series-zarr-time-axis-backwards",
    "track",
    lambda e: [
        "run",
        _zarr(
            e,
            lambda s: _set_t_unit(s, "second"),
            t_scale=-0.01,
        ),
        "-o",
        e.o("res"),
    ],
    "times must increase with the volumes",
)
case(
    "track-run-series-zarr-recon-json-numbers-duplicated",
    "track",
    lambda e: ["run", _zarr(e, _zarr_recon([0, 3, 3], [0.0, 0.03, 0.04])), "-o", e.o("res")],
    "frame number 3 is recorded for both",
)
case(
    "track-run-series-zarr-recon-json-time-nan",
    "track",
    lambda e: ["run", _zarr(e, _zarr_recon([0, 1, 2], [0.0, math.nan, 0.2])), "-o", e.o("res")],
    "recon.json frame 1: time_s must be a finite number",
)
case(
    "track-run-series-output-inside-the-zarr",
    "track",
    lambda e: ["run", (s := _zarr(e)), "-o", s / "res"],
    "inside the input folder",
)


def _set_t_unit(store: Path, unit: str) -> None:
    meta = json.loads((store / "zarr.json").read_text())
    meta["attributes"]["ome"]["multiscales"][0]["axes"][0]["unit"] = unit
    (store / "zarr.json").write_text(json.dumps(meta))


# -- a rerun over finished results -------------------------------------------------------------
case(
    "track-run-series-rerun-after-truncating-a-volume",
    "track",
    _rerun(_truncate(0.5)),
    "000001.tif is truncated",
)
case(
    "track-run-series-rerun-after-a-volume-got-nan",
    "track",
    _rerun(_nan),
    "000002.tif: volume holds NaN or infinite voxels",
)
case(
    "track-run-series-rerun-with-renumbered-frames",
    "track",
    _rerun(_frames(numbers=[0, 1, 5])),
    "other inputs or settings",
)
case(
    "track-run-series-rerun-after-a-volume-changed-shape",
    "track",
    _rerun(
        lambda d: (
            (d / "000002.tif").unlink(),
            tifffile.imwrite(d / "000002.tif", np.ones((5, 40, 40), np.float32)),
        )
    ),
    "mixed series",
)


@pytest.mark.parametrize("c", params(CASES))
def test_bad_input(c: Case, corpus_base: Base, tmp_path, capsys) -> None:
    run_case(c, corpus_base, tmp_path, capsys)


def test_the_cases_are_distinct_and_many() -> None:
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) >= 25
    assert all(i.startswith("track-run-series-") for i in ids)
