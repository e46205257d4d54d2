"""Bad inputs of ``recon run`` on frame series: camera numbering, stacks and files mixed,
list files and patterns, dark frames and a dataset's white image, frame rates, resumed runs and
OME-Zarr outputs. Each is refused with one line (or, ``kind="warning"``, done with one warning),
the inputs unchanged and nothing written by a refused run (the rules of ``tests/corpus.py``).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import tifffile

from tests.corpus import BLOCKED, FAST, Base, Case, Env, case_adder, params, run_case

CASES: list[Case] = []
case = case_adder(CASES)


def run_argv(e: Env, *frames, out=None, extra=()) -> list:
    """``recon run`` of ``frames`` with the shared scene and calibration, one fast iteration."""
    argv = ["run", *frames, "--scene", e.b.scene, "--calib", e.b.calib, *FAST]
    return [*argv, "--iterations", "1", *extra, "-o", out or e.o("v")]


def ds_argv(e: Env, *extra, ds=None, out=None) -> list:
    """``recon run`` of an lfsim dataset folder (the shared one by default)."""
    return ["run", ds or e.b.ds, *FAST, "--iterations", "1", *extra, "-o", out or e.o("v")]


def frame(e: Env, k: int = 0) -> np.ndarray:
    """Pixels of frame ``k`` of the shared dataset."""
    return tifffile.imread(e.b.frames[k])


def series(e: Env, names, name: str = "fx") -> Path:
    """A folder of the shared dataset's frames under these names (frame k as the k-th name)."""
    return e.frames_dir({n: frame(e, k % 3) for k, n in enumerate(names)}, name)


def stack(e: Env, pages: int = 2, name: str = "stack.tif") -> Path:
    return e.tif(name, np.stack([frame(e, k % 3) for k in range(pages)]), photometric="minisblack")


def copied_frames(e: Env, name, changed: int | None = None) -> Path:
    """The shared dataset's frame files copied as ``name(k)``; frame ``changed`` rewritten
    with other pixels (the same size)."""
    d = e.dir("fx")
    for k, src in enumerate(e.b.frames):
        shutil.copyfile(src, d / name(k))
        if k == changed:  # other pixels in place: the same size and tags
            with tifffile.TiffFile(d / name(k)) as tif:
                start = tif.pages[0].dataoffsets[0]
            data = bytearray((d / name(k)).read_bytes())
            data[start : start + 1000] = bytes(255 - b for b in data[start : start + 1000])
            (d / name(k)).write_bytes(bytes(data))
    return d


def unequal_stack(e: Env) -> Path:
    """A two-page TIFF whose pages differ in size."""
    p = e.tif("mixed.tif", frame(e))
    tifffile.imwrite(p, frame(e)[:200], append=True)
    return p


def dataset(e: Env, edit) -> Path:
    """A copy of the shared dataset, edited."""
    d = e.inp / "ds"
    shutil.copytree(e.b.ds, d)
    edit(d)
    return d


def zarr_store(e: Env, *extra, name: str = "v.zarr") -> Path:
    """A Zarr store written by ``recon run --format zarr`` of the shared dataset."""
    from recon.cli import main

    out = e.inp / name
    argv = ds_argv(e, "--format", "zarr", *extra, out=out)
    assert main(["-q", *map(str, argv)]) == 0
    return out


# ---- series: numbering, duplicates, stacks and files ----
case(
    "recon-run-series-stack-and-file-of-one-number",
    "recon",
    lambda e: run_argv(e, stack(e), e.tif("img_0.tif", frame(e))),
    "both carry frame number 0",
)
case(
    "recon-run-series-two-folders-numbered-alike",
    "recon",
    lambda e: run_argv(
        e, series(e, ["img_0.tif", "img_1.tif"]), series(e, ["cam_1.tif", "cam_2.tif"], "gx")
    ),
    "both carry frame number 1",
)
case(
    "recon-run-series-file-given-twice",
    "recon",
    lambda e: run_argv(e, e.tif("img_3.tif", frame(e)), e.inp / "img_3.tif"),
    "given twice",
)
case(
    "recon-run-series-folder-and-a-file-in-it",
    "recon",
    lambda e: run_argv(e, series(e, ["img_0.tif", "img_1.tif"]), e.inp / "fx" / "img_1.tif"),
    "given twice",
)
case(
    "recon-run-series-stack-given-twice",
    "recon",
    lambda e: run_argv(e, stack(e), e.inp / "stack.tif"),
    "given twice",
)
case(
    "recon-run-series-stack-of-unequal-pages",
    "recon",
    lambda e: run_argv(e, unequal_stack(e)),
    "mixed.tif",
)
case(
    "recon-run-series-unnumbered-file-with-fps-is-a-warning",
    "recon",
    lambda e: run_argv(e, e.tif("left.tif", frame(e)), extra=["--fps", "100"]),
    "no number in their file name",
    kind="warning",
    writes=True,
)
case(
    "recon-run-series-explicit-files-out-of-order-is-a-warning",
    "recon",
    lambda e: run_argv(e, e.tif("img_10.tif", frame(e, 1)), e.tif("img_2.tif", frame(e, 0))),
    "not in the order of their numbers (img_10.tif before img_2.tif)",
    kind="warning",
    writes=True,
)
case(
    "recon-run-series-folder-of-hidden-tiffs",
    "recon",
    lambda e: run_argv(e, e.frames_dir({".img_0.tif": frame(e), ".img_1.tif": frame(e, 1)})),
    "no TIFF frames",
)
case(
    "recon-run-series-folder-without-tiffs",
    "recon",
    lambda e: run_argv(e, (e.w("fx/img_0.png", b"\x89PNG\r\n"), e.inp / "fx")[1]),
    "no TIFF frames",
)
case(
    "recon-run-series-named-differently",
    "recon",
    lambda e: run_argv(e, series(e, ["img_0.tif", "cam_1.tif"])),
    "named differently",
)

# ---- list files ----
for cid, text, needle in [
    ("duplicate-entry", "fx/img_0.tif\nfx/img_0.tif\n", "twice (lines 1 and 2)"),
    ("duplicate-spelt-otherwise", "fx/img_0.tif\n# again\n./fx/../fx/img_0.tif\n", "twice"),
    ("entry-a-folder", "fx\n", "is a folder, not a frame file"),
    ("zero-bytes", "", "names no frames"),
    ("entry-not-a-tiff", "fx/notes.txt\n", "notes.txt"),
    ("inline-comment", "fx/img_0.tif  # first frame\n", "# first frame"),
    ("naming-a-list", "inner.txt\n", "inner.txt"),
]:

    def _list(e: Env, text=text) -> Path:
        series(e, ["img_0.tif", "img_1.tif"])
        e.w("fx/notes.txt", "not a frame\n")
        e.w("inner.txt", "fx/img_0.tif\n")
        return e.w("list.txt", text)

    case(f"recon-run-list-{cid}", "recon", lambda e, m=_list: run_argv(e, m(e)), needle)
case(
    "recon-run-list-relative-to-the-list-not-the-cwd",
    "recon",
    lambda e: run_argv(e, (series(e, ["img_0.tif"]), e.w("sub/list.txt", "fx/img_0.tif\n"))[1]),
    "sub/fx/img_0.tif",
)
case(
    "recon-run-list-output-inside-the-frames-folder",
    "recon",
    lambda e: run_argv(
        e,
        (series(e, ["img_0.tif", "img_1.tif"]), e.w("list.txt", "fx/img_0.tif\n"))[1],
        out=e.inp / "fx" / "v",
        extra=["--overwrite"],
    ),
    "lies inside the input folder",
)

# ---- glob patterns ----
case(
    "recon-run-glob-matches-only-folders",
    "recon",
    lambda e: run_argv(e, (e.dir("d1"), e.dir("d2"), str(e.inp / "d*"))[2]),
    "matches no file",
)
case(
    "recon-run-glob-matches-text-files",
    "recon",
    lambda e: run_argv(
        e, (e.w("notes_1.txt", "a\n"), e.w("notes_2.txt", "b\n"), str(e.inp / "notes_*"))[2]
    ),
    "notes_1.txt",
)
case(
    "recon-run-glob-output-inside-the-frames-folder",
    "recon",
    lambda e: run_argv(
        e,
        (series(e, ["img_0.tif", "img_1.tif"]), str(e.inp / "fx" / "img_*.tif"))[1],
        out=e.inp / "fx" / "v",
    ),
    "lies inside the input folder",
)

# ---- dark frame; a dataset's white image ----
for cid, make, needle in [
    (
        "brighter-than-the-frames",
        lambda e: e.tif("dark.tif", np.full((300, 300), 5000, np.uint16)),
        "brighter than",
    ),
    ("the-white-image", lambda e: e.b.white, "brighter than"),
    ("a-stack", lambda e: stack(e, 2, "dark.tif"), "dark.tif"),
    ("rgb", lambda e: e.tif("dark.tif", np.zeros((300, 300, 3), np.uint8)), "dark.tif"),
    ("a-folder", lambda e: e.dir("dark"), "is a folder"),
]:
    case(f"recon-run-dark-{cid}", "recon", lambda e, m=make: ds_argv(e, "--dark", m(e)), needle)

case(
    "recon-run-dataset-without-white-image",
    "recon",
    lambda e: ds_argv(e, ds=dataset(e, lambda d: (d / "white.tif").unlink())),
    "white.tif",
)
case(
    "recon-run-dataset-white-image-wrong-size",
    "recon",
    lambda e: ds_argv(
        e,
        ds=dataset(e, lambda d: tifffile.imwrite(d / "white.tif", np.ones((200, 200), np.uint16))),
    ),
    "white.tif",
)
case(
    "recon-run-dataset-white-image-nan",
    "recon",
    lambda e: ds_argv(
        e,
        ds=dataset(
            e, lambda d: tifffile.imwrite(d / "white.tif", np.full((300, 300), np.nan, np.float32))
        ),
    ),
    "white.tif",
)
case(
    "recon-run-dataset-without-frames-folder",
    "recon",
    lambda e: ds_argv(e, ds=dataset(e, lambda d: shutil.rmtree(d / "frames"))),
    "no frames/ folder",
)
case(
    "recon-run-dataset-json-naming-no-scene",
    "recon",
    lambda e: ds_argv(e, ds=dataset(e, lambda d: (d / "dataset.json").write_text("{}"))),
    "dataset.json",
)

# ---- frame rate ----
for cid, value, needle in [
    ("inf", "inf", "--fps"),
    ("denormal", "1e-320", "not a finite number"),
    ("text", "fast", "--fps"),
]:
    case(f"recon-run-fps-{cid}", "recon", lambda e, v=value: ds_argv(e, f"--fps={v}"), needle)

# ---- resuming with other settings or inputs ----
case(
    "recon-run-resume-with-another-fps",
    "recon",
    lambda e: ds_argv(e, "--fps", "7", out=e.voldir()),
    "other frame numbers or times",
)
case(
    "recon-run-resume-with-a-changed-frame",
    "recon",
    lambda e: run_argv(e, copied_frames(e, lambda k: f"{k:06d}.tif", changed=1), out=e.voldir()),
    "same size",
)
case(
    "recon-run-resume-with-fewer-frames",
    "recon",
    lambda e: ds_argv(e, "--frames", "0:2", out=e.voldir()),
    "this run has 2 frame(s)",
)
case(
    "recon-run-resume-with-renumbered-frames",
    "recon",
    lambda e: run_argv(e, copied_frames(e, lambda k: f"img_{10 + k}.tif"), out=e.voldir()),
    "frame number 0, this run 10",
)
case(
    "recon-run-resume-with-a-dark-frame-added",
    "recon",
    lambda e: ds_argv(
        e, "--dark", e.tif("dark.tif", np.zeros((300, 300), np.uint8)), out=e.voldir()
    ),
    "other inputs or settings",
)

# ---- OME-Zarr output ----
case(
    "recon-run-zarr-store-of-other-settings",
    "recon",
    lambda e: ds_argv(e, "--format", "zarr", "--iterations", "2", out=zarr_store(e)),
    "other inputs or settings",
)
case(
    "recon-run-zarr-store-of-another-chunking",
    "recon",
    lambda e: ds_argv(e, "--format", "zarr", "--zarr-chunk-z", "2", out=zarr_store(e)),
    "chunking",
)
case(
    "recon-run-zarr-tiff-volumes-into-a-store",
    "recon",
    lambda e: ds_argv(e, out=zarr_store(e, name="store")),
    "zarr volumes",
)
case(
    "recon-run-zarr-store-into-a-tiff-folder",
    "recon",
    lambda e: ds_argv(e, "--format", "zarr", out=e.voldir()),
    "tiff volumes",
)
case(
    "recon-run-zarr-store-path-is-a-file",
    "recon",
    lambda e: ds_argv(e, "--format", "zarr", out=e.existing("x.zarr")),
    "x.zarr",
)
case(
    "recon-run-zarr-store-below-a-file",
    "recon",
    lambda e: ds_argv(e, "--format", "zarr", out=e.blocker() / "x.zarr"),
    BLOCKED,
)


def _foreign_store(e: Env) -> Path:
    import zarr

    store = e.o("foreign.zarr")
    zarr.open_group(str(store), mode="w").attrs["mine"] = 1
    return store


case(
    "recon-run-zarr-foreign-store",
    "recon",
    lambda e: ds_argv(e, "--format", "zarr", "--overwrite", out=_foreign_store(e)),
    "not empty",
)
case(
    "recon-run-zarr-store-inside-the-frames-folder",
    "recon",
    lambda e: run_argv(
        e,
        series(e, ["img_0.tif", "img_1.tif"]),
        out=e.inp / "fx" / "v.zarr",
        extra=["--format", "zarr"],
    ),
    "lies inside the input folder",
)
case(
    "recon-run-zarr-suffix-with-format-tiff",
    "recon",
    lambda e: ds_argv(e, "--format", "tiff", out=e.o("v.zarr")),
    "v.zarr",
)
for cid, extra, needle in [
    ("chunk-z-zero", ["--format", "zarr", "--zarr-chunk-z", "0"], "--zarr-chunk-z"),
    ("chunk-z-text", ["--format", "zarr", "--zarr-chunk-z", "four"], "--zarr-chunk-z"),
    ("chunk-z-with-tiff", ["--zarr-chunk-z", "4"], "--zarr-chunk-z applies only to --format zarr"),
    ("format-unknown", ["--format", "n5"], "--format"),
]:
    case(f"recon-run-zarr-{cid}", "recon", lambda e, x=extra: ds_argv(e, *x), needle)

# ---- settings of the series' reconstruction ----
for cid, extra, needle in [
    ("stop-rel-change-text", ["--stop-rel-change", "never"], "'none' or a number >= 0"),
    ("stop-rel-change-inf", ["--stop-rel-change", "inf"], "--stop-rel-change"),
    ("background-negative", ["--background", "-20"], ">= 0"),
]:
    case(f"recon-run-series-{cid}", "recon", lambda e, x=extra: ds_argv(e, *x), needle)


@pytest.mark.parametrize("c", params(CASES))
def test_bad_input(c: Case, corpus_base: Base, tmp_path: Path, capsys) -> None:
    run_case(c, corpus_base, tmp_path, capsys)


def test_cases_are_new_and_many() -> None:
    """At least 40 cases, none sharing an id with the main corpus."""
    from tests.test_bad_inputs import CASES as MAIN

    ids = [c.id for c in CASES]
    assert len(ids) >= 40 and len(set(ids)) == len(ids)
    assert not set(ids) & {c.id for c in MAIN}
