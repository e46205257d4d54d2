"""Bad inputs of ``hrvptm axial``, ``hrvptm collect``, study files and ``lfsim render``: each is
refused with one line (or, ``kind="warning"``, done with one warning), the inputs unchanged and
nothing written by a refused run (the rules of ``tests/corpus.py``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.corpus import (
    BLOCKED,
    EXPERIMENT,
    ROOT,
    STUDY,
    Base,
    Case,
    Env,
    case_adder,
    collect_argv,
    mutate,
    params,
    run_case,
    study_argv,
    toml_text,
)

CASES: list[Case] = []
case = case_adder(CASES)


# ---- hrvptm axial ----
def axial_argv(e: Env, *extra, vol=None, out=None) -> list:
    return ["axial", vol or e.b.vol, "-o", out or e.o("res"), *extra]


def _track_config(e: Env, text: str) -> Path:
    return e.w("track.toml", text)


for cid, extra, needle in [
    ("sphere-diameter-5000", ["--sphere-diameter-um", "5000"], "--sphere-diameter-um 5000 µm"),
    ("sphere-diameter-4x-the-particles", ["--sphere-diameter-um", "60"], "lateral FWHM"),
    ("sphere-diameter-nan", ["--sphere-diameter-um", "nan"], "--sphere-diameter-um"),
    ("sphere-diameter-inf", ["--sphere-diameter-um", "inf"], "--sphere-diameter-um"),
    ("sphere-diameter-zero", ["--sphere-diameter-um", "0"], "--sphere-diameter-um"),
    ("sphere-diameter-negative", ["--sphere-diameter-um", "-15"], "--sphere-diameter-um"),
    ("sphere-diameter-text", ["--sphere-diameter-um", "wide"], "--sphere-diameter-um"),
    ("reference-rays-zero", ["--reference-rays", "0"], "--reference-rays"),
    ("reference-rays-fractional", ["--reference-rays", "2.5e4"], "--reference-rays"),
    ("reference-rays-below-1000", ["--reference-rays", "999"], "--reference-rays"),
]:
    case(f"hrvptm-axial-{cid}", "hrvptm", lambda e, x=extra: axial_argv(e, *x), needle)

case(
    "hrvptm-axial-sphere-diameter-2-for-33um-wide-particles",
    "hrvptm",
    lambda e: axial_argv(e, "--sphere-diameter-um", "2", "--reference-rays", "1000"),
    "--sphere-diameter-um 2 µm, particles measured in",
    kind="warning",
    writes=True,
)

for cid, text, needle in [
    (
        "sphere-diameter-500",
        "[track.axial]\nsphere_diameter_um = 500\n",
        "[track.axial] sphere_diameter_um of",
    ),
    ("sphere-diameter-text", "[track.axial]\nsphere_diameter_um = 'fifteen'\n", "must be a number"),
    ("method-unknown", "[track.axial]\nmethod = 'fit'\n", "method"),
    ("lateral-text", "[track.axial]\nlateral = 'yes'\n", "lateral"),
    ("axial-a-scalar", "[track]\naxial = 'simulated'\n", "[track.axial] must be a table"),
    ("axial-array-of-tables", "[[track.axial]]\nmethod = 'simulated'\n", "[track.axial]"),
    ("misspelt-key", "[track.axial]\nsphere_diameter = 15\n", "sphere_diameter_um"),
    ("a-study-table", "[study]\nkind = 'series'\n", "only [track] tables"),
    ("not-toml", "[track.axial\n", "not valid TOML"),
]:
    case(
        f"hrvptm-axial-track-config-{cid}",
        "hrvptm",
        lambda e, t=text: axial_argv(e, "--track-config", _track_config(e, t)),
        needle,
    )
case(
    "hrvptm-axial-track-config-missing",
    "hrvptm",
    lambda e: axial_argv(e, "--track-config", e.inp / "nope.toml"),
    "nope.toml",
)


def _bare_volumes(e: Env) -> Path:
    """The volumes without their recon.json."""
    return e.voldir(lambda d: (d / "recon.json").unlink(), name="bare")


def _recon_json(text: str):
    def edit(d: Path) -> None:
        (d / "recon.json").write_text(text, encoding="utf-8")

    return edit


def _recon_without(key: str):
    def edit(d: Path) -> None:
        rec = json.loads((d / "recon.json").read_text(encoding="utf-8"))
        del rec[key]
        (d / "recon.json").write_text(json.dumps(rec), encoding="utf-8")

    return edit


for cid, make, needle in [
    ("missing", lambda e: e.inp / "novol", "novol does not exist"),
    ("empty-folder", lambda e: e.dir("emptyvol"), "emptyvol"),
    ("a-tiff-file", lambda e: e.b.vol / "000000.tif", "000000.tif is a file"),
    ("without-recon-json", _bare_volumes, "recon.json does not exist"),
    ("recon-json-truncated", lambda e: e.voldir(_recon_json('{"tool": "rec')), "recon.json"),
    ("recon-json-without-optics", lambda e: e.voldir(_recon_without("optics")), "optics"),
    (
        "recon-json-without-calibration",
        lambda e: e.voldir(_recon_without("calibration")),
        "calibration",
    ),
]:
    case(f"hrvptm-axial-voldir-{cid}", "hrvptm", lambda e, m=make: axial_argv(e, vol=m(e)), needle)

case(
    "hrvptm-axial-output-is-the-voldir",
    "hrvptm",
    lambda e: axial_argv(e, "--overwrite", out=e.b.vol),
    "is an input",
)
case(
    "hrvptm-axial-output-inside-the-voldir",
    "hrvptm",
    lambda e: axial_argv(e, out=e.b.vol / "res"),
    "inside the input folder",
)
case(
    "hrvptm-axial-output-is-a-file",
    "hrvptm",
    lambda e: axial_argv(e, out=e.existing()),
    "existing.out",
)
case(
    "hrvptm-axial-output-foreign-folder",
    "hrvptm",
    lambda e: axial_argv(e, "--overwrite", out=e.foreign()),
    "notes.txt",
)
case(
    "hrvptm-axial-output-below-a-file",
    "hrvptm",
    lambda e: axial_argv(e, out=e.blocker() / "res"),
    BLOCKED,
)


# ---- hrvptm collect ----
PLOT = "displacement.png"


def _with_plot(d: Path) -> None:
    """The shared fake report (study "s") with a plot."""
    (d / "plots").mkdir()
    (d / "plots" / PLOT).write_bytes(b"png of the study")
    data = json.loads((d / "summary.json").read_text(encoding="utf-8"))
    data["plots"] = [f"plots/{PLOT}"]
    (d / "summary.json").write_text(json.dumps(data), encoding="utf-8")


def _page_folder_file(e: Env, rel: str, data: bytes = b"the user's own file") -> Path:
    """A file of the user's in the page's plot folder (``page/``), before collect runs."""
    p = e.tmp / "page" / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data)
    return p


def _user_plot(e: Env, *extra) -> list:
    rep = e.report(_with_plot)
    _page_folder_file(e, f"s/{PLOT}")
    return collect_argv(e, rep, extra=extra)


case(
    "hrvptm-collect-user-plot-in-the-page-folder",
    "hrvptm",
    lambda e: _user_plot(e),
    "not written by hrvptm collect",
)
case(
    "hrvptm-collect-user-plot-in-the-page-folder-with-overwrite",
    "hrvptm",
    lambda e: _user_plot(e, "--overwrite"),
    f"{PLOT} was not written by hrvptm collect",
)


def _user_record(e: Env) -> list:
    _page_folder_file(e, "s/summary.md", b"# my notes\n")
    return collect_argv(e)


case(
    "hrvptm-collect-user-summary-in-the-page-folder",
    "hrvptm",
    _user_record,
    "summary.md was not written by hrvptm collect",
)


def _folder_at_plot(e: Env) -> list:
    rep = e.report(_with_plot)
    (e.tmp / "page" / "s" / PLOT).mkdir(parents=True)
    return collect_argv(e, rep, extra=["--overwrite"])


case(
    "hrvptm-collect-folder-in-place-of-a-plot",
    "hrvptm",
    _folder_at_plot,
    "not written by hrvptm collect",
)


def _foreign_manifest(e: Env) -> list:
    _page_folder_file(e, "collect.json", b'{"tool": "someone else"}')
    return collect_argv(e, extra=["--overwrite"])


case(
    "hrvptm-collect-page-folder-manifest-not-from-collect",
    "hrvptm",
    _foreign_manifest,
    "collect.json was not written by hrvptm collect",
)


def _page_deleted(e: Env) -> list:
    from hrvptm.cli import main

    page = e.tmp / "page.md"
    assert main(["-q", "collect", str(e.b.report), "-o", str(page)]) == 0
    page.unlink()  # its plot folder kept: collect's files there need --overwrite
    return collect_argv(e)


case(
    "hrvptm-collect-page-deleted-its-folder-kept",
    "hrvptm",
    _page_deleted,
    "pass --overwrite",
)


def _page_folder_blocked(e: Env) -> list:
    (e.tmp / "page").write_text("a file where the plot folder goes\n", encoding="utf-8")
    return collect_argv(e)


case(
    "hrvptm-collect-page-folder-is-a-file",
    "hrvptm",
    _page_folder_blocked,
    "is a file where hrvptm collect puts the page's plot folder",
)


def _summary_edit(edit):
    def change(d: Path) -> None:
        data = json.loads((d / "summary.json").read_text(encoding="utf-8"))
        edit(data)
        (d / "summary.json").write_text(json.dumps(data), encoding="utf-8")

    return change


def _set(path: tuple, value):
    def edit(data: dict) -> None:
        node = data
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value

    return edit


for cid, edit, needle in [
    ("summary-json-missing", lambda d: (d / "summary.json").unlink(), "summary.json"),
    (
        "summary-json-study-name-a-number",
        _summary_edit(_set(("study", "experiment", "experiment", "name"), 7)),
        "summary.json",
    ),
    ("summary-json-plots-a-string", _summary_edit(_set(("plots",), "p.png")), "summary.json"),
    ("summary-json-variant-a-list", _summary_edit(_set(("variants",), {"v": [1]})), "summary.json"),
    ("summary-json-no-study", _summary_edit(lambda data: data.pop("study")), "summary.json"),
]:
    case(
        f"hrvptm-collect-report-{cid}",
        "hrvptm",
        lambda e, x=edit: collect_argv(e, e.report(x)),
        needle,
    )

case(
    "hrvptm-collect-same-report-twice",
    "hrvptm",
    lambda e: collect_argv(e, e.b.report, e.report(lambda d: None)),
    "given twice",
)


def _record_under_another_name(e: Env) -> list:
    """A report copied into the page's folder under another name than its study's."""
    other = e.tmp / "page" / "other"
    shutil.copytree(e.b.report, other)
    return collect_argv(e, other)


case(
    "hrvptm-collect-stored-record-under-another-name",
    "hrvptm",
    _record_under_another_name,
    "holds the record of study 's', not 'other'",
)
case(
    "hrvptm-collect-page-folder-is-the-report",
    "hrvptm",
    lambda e: collect_argv(e, out=e.b.report.parent / f"{e.b.report.name}.md"),
    "the page's plot folder",
)


# ---- study files ----
def _study_text(e: Env, top: str = "", drop: tuple = (), changes: dict | None = None) -> Path:
    sections = mutate(EXPERIMENT | STUDY, {"experiment.scene": str(e.b.scene), **(changes or {})})
    for name in drop:
        sections.pop(name)
    return e.w("study.toml", top + toml_text(sections))


for cid, top, drop, needle in [
    ("study-a-string", 'study = "series"\n', ("study",), "[study] must be a table"),
    ("study-a-list", 'study = ["series"]\n', ("study",), "[study] must be a table"),
    ("study-a-number", "study = 2\n", ("study",), "[study] must be a table"),
    ("recon-a-number", "recon = 3\n", ("recon",), "[recon] must be a table"),
    ("track-a-list", "track = [1, 2]\n", ("track.grid",), "[track] must be a table"),
    ("experiment-a-string", 'experiment = "corpus"\n', ("experiment",), "[experiment]"),
    ("particles-a-list", "particles = [6]\n", ("particles",), "[particles]"),
    ("noise-a-number", "noise = 30\n", ("noise",), "[noise]"),
]:
    case(
        f"hrvptm-study-section-{cid}",
        "hrvptm",
        lambda e, t=top, d=drop: study_argv(e, _study_text(e, t, d)),
        needle,
    )


def _appended(text: str, drop: tuple = ()):
    def make(e: Env) -> Path:
        p = _study_text(e, drop=drop)
        p.write_text(p.read_text(encoding="utf-8") + "\n" + text, encoding="utf-8")
        return p

    return make


case(
    "hrvptm-study-key-study-array-of-tables",
    "hrvptm",
    lambda e: study_argv(e, _appended("[[study]]\nkind = 'series'\n", ("study",))(e)),
    "[study] must be a table",
)
for cid, text, needle in [
    ("track-detect-a-number", "[track]\ndetect = 3\n", "[track.detect] must be a table"),
    ("track-link-a-string", "[track]\nlink = 'knn'\n", "[track.link] must be a table"),
    ("track-axial-a-string", "[track]\naxial = 'simulated'\n", "[track.axial] must be a table"),
    (
        "track-axial-array-of-tables",
        "[[track.axial]]\nmethod = 'simulated'\n",
        "[track.axial] must be a table",
    ),
    ("track-mode-a-table", "[track.mode]\nname = 'incremental'\n", "[track] mode must be"),
    ("track-axial-method-a-table", "[track.axial.method]\nname = 'x'\n", "method must be"),
    ("recon-roi-a-table", "[recon.roi_xy_px]\nx = 1\n", "roi_xy_px must be"),
]:
    case(
        f"hrvptm-study-key-{cid}",
        "hrvptm",
        lambda e, t=text: study_argv(e, _appended(t)(e)),
        needle,
    )

for cid, changes, needle in [
    ("sphere-diameter-60", {"sphere_diameter_um": 60}, "diameter_um = 15 µm"),
    ("sphere-diameter-2", {"sphere_diameter_um": 2}, "sphere_diameter_um = 2 µm"),
    ("sphere-diameter-nan", {"sphere_diameter_um": float("nan")}, "sphere_diameter_um"),
    ("sphere-diameter-text", {"sphere_diameter_um": "15"}, "sphere_diameter_um must be"),
    ("rays-below-1000", {"rays_per_particle": 500}, "rays_per_particle"),
    ("rays-fractional", {"rays_per_particle": 5e4}, "rays_per_particle"),
    ("method-unknown", {"method": "fit"}, "method"),
    ("lateral-a-number", {"lateral": 1}, "lateral"),
    ("misspelt-key", {"sphere_diameter": 15}, "did you mean"),
]:
    full = {f"track.axial.{k}": v for k, v in {"method": "simulated", **changes}.items()}
    case(
        f"hrvptm-study-track-axial-{cid}",
        "hrvptm",
        lambda e, c=full: study_argv(e, _study_text(e, changes=c)),
        needle,
    )
case(
    "hrvptm-study-track-axial-default-sphere-for-6um-particles",
    "hrvptm",
    lambda e: study_argv(
        e,
        _study_text(
            e,
            changes={
                "track.axial.method": "simulated",
                "particles.diameter_um": 6,
            },
        ),
    ),
    "unset: the default",
)


# ---- lfsim render ----
def render_argv(e: Env, table: str, *extra, scene=None) -> list:
    particles = e.w("particles.csv", table)
    return [
        "render",
        scene or e.b.scene,
        "--particles",
        particles,
        "-o",
        e.o("r.tif"),
        "--rays",
        "1000",
        *extra,
    ]


for cid, table, needle in [
    ("coincident-rows", "x_um,y_um,z_um\n0,0,150\n0,0,150\n0,0,150\n", "rows 1, 2, 3 coincide"),
    (
        "coincident-rows-with-ids",
        "id,x_um,y_um,z_um\n7,0,0,150\n8,-80,60,250\n9,0,0,150\n",
        "rows 1, 3 coincide at (0, 0, 150)",
    ),
    (
        "overlapping-pair",
        "x_um,y_um,z_um\n0,0,150\n6,0,150\n",
        "rows 1 and 2 overlap, 6 µm apart",
    ),
    (
        "overlapping-by-their-diameters",
        "x_um,y_um,z_um,diameter_um\n0,0,150,40\n30,0,150,40\n",
        "diameters 40 and 40 µm",
    ),
]:
    case(
        f"lfsim-render-{cid}",
        "lfsim",
        lambda e, t=table: render_argv(e, t),
        needle,
        kind="warning",
        writes=True,
    )

GLASS = ROOT / "scenes" / "small_glass.xml"


def _glass_scene(e: Env) -> Path:
    """A copy of the glass test scene with its lenslet mesh made beforehand (loading a glass
    scene writes a missing mesh beside it, which the corpus would count as a changed input)."""
    from lfsim.scene import ensure_mesh, lenslet_mesh_name, read_optics

    scene = e.w("glass.xml", GLASS.read_text(encoding="utf-8"))
    optics = read_optics(scene)
    ensure_mesh(optics, scene.parent / "meshes" / lenslet_mesh_name(optics))
    return scene


case(
    "lfsim-render-paraxial-tracer-on-a-glass-scene",
    "lfsim",
    lambda e: render_argv(
        e, "x_um,y_um,z_um\n0,0,150\n", "--tracer", "paraxial", scene=_glass_scene(e)
    ),
    "--tracer paraxial models ideal lenslets only",
)


def test_ids_are_new_and_distinct() -> None:
    """Ids unique here and not those of the main corpus."""
    from tests.test_bad_inputs import CASES as MAIN

    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) >= 35
    assert not set(ids) & {c.id for c in MAIN}
    prefixes = ("hrvptm-axial-", "hrvptm-collect-", "hrvptm-study-", "lfsim-render-")
    assert all(i.startswith(prefixes) for i in ids)


@pytest.mark.parametrize("c", params(CASES))
def test_bad_input(c: Case, corpus_base: Base, tmp_path: Path, capsys) -> None:
    run_case(c, corpus_base, tmp_path, capsys)
