"""The hrvptm command line: errors a user can cause, the report folder's safety, resume."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from hrvptm.cli import main

EXPERIMENTS = Path(__file__).resolve().parents[2] / "scenes" / "experiments"


def test_missing_study_file_is_a_one_line_error(tmp_path, capsys):
    rc = main(["study", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("hrvptm: error: study file") and err.count("\n") == 1
    assert not (tmp_path / "r").exists()


def test_bad_key_is_named(tmp_path, capsys):
    src = (EXPERIMENTS / "demo_simple_shear.toml").read_text(encoding="utf-8")
    bad = tmp_path / "bad.toml"
    text = src.replace("[track.grid]\n", "[track.grid]\ntarget_node = 5\n")
    assert text != src
    text = text.replace('"../', f'"{EXPERIMENTS.parent.as_posix()}/')
    bad.write_text(text, encoding="utf-8")
    rc = main(["study", str(bad), "-o", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "unknown key 'target_node'" in err and "did you mean 'target_nodes'" in err


def test_foreign_report_folder_is_refused_and_left_alone(tmp_path, capsys):
    out = tmp_path / "r"
    out.mkdir()
    (out / "notes.txt").write_text("mine", encoding="utf-8")
    rc = main(["study", str(EXPERIMENTS / "demo_simple_shear.toml"), "-o", str(out), "-q"])
    assert rc == 2
    assert "holds no study.json" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_report_of_another_study_needs_overwrite(tmp_path, capsys):
    out = tmp_path / "r"
    out.mkdir()
    state = {"tool": "hrvptm", "name": "other_study", "runs": [], "seconds_total": {}}
    (out / "study.json").write_text(json.dumps(state), encoding="utf-8")
    rc = main(["study", str(EXPERIMENTS / "demo_simple_shear.toml"), "-o", str(out), "-q"])
    assert rc == 2
    assert "holds the study 'other_study'" in capsys.readouterr().err
    assert json.loads((out / "study.json").read_text())["name"] == "other_study"


def test_collect_refuses_unfinished_reports(tmp_path, capsys):
    (tmp_path / "r").mkdir()
    rc = main(["collect", str(tmp_path / "r"), "-o", str(tmp_path / "page.md")])
    assert rc == 2
    assert "holds no finished study" in capsys.readouterr().err
    assert not (tmp_path / "page.md").exists()


def _fake_report(folder):
    folder.mkdir(parents=True)
    (folder / "summary.md").write_text("# study\n\nresults\n", encoding="utf-8")
    exp = {"experiment": {"name": "s", "frames": 2}}
    data = {"study": {"experiment": exp}, "variants": {}, "comparison": [], "plots": []}
    (folder / "summary.json").write_text(json.dumps(data), encoding="utf-8")
    return folder


def test_collect_never_writes_onto_inputs_or_foreign_pages(tmp_path, capsys):
    report = _fake_report(tmp_path / "rep")
    summary = (report / "summary.md").read_bytes()
    cases = [
        (report / "summary.md", "inside the input folder"),  # the report's own page
        (report / "page.md", "inside the input folder"),
        (tmp_path, "contains the input"),
    ]
    for page, why in cases:
        rc = main(["collect", str(report), "-o", str(page), "--overwrite", "-q"])
        err = capsys.readouterr().err
        assert rc == 2 and why in err and len(err.strip().splitlines()) == 1, err
    assert (report / "summary.md").read_bytes() == summary
    # A user's own file is never replaced, even with --overwrite.
    mine = tmp_path / "notes.md"
    mine.write_text("my notes\n", encoding="utf-8")
    assert main(["collect", str(report), "-o", str(mine), "--overwrite", "-q"]) == 2
    assert "not written by hrvptm collect" in capsys.readouterr().err
    assert mine.read_text(encoding="utf-8") == "my notes\n"
    # A page collect wrote: refused without --overwrite, replaced with it.
    page = tmp_path / "page.md"
    assert main(["collect", str(report), "-o", str(page), "-q"]) == 0
    assert main(["collect", str(report), "-o", str(page), "-q"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["collect", str(report), "-o", str(page), "--overwrite", "-q"]) == 0


def _named_report(folder, name, text):
    """A finished report of study ``name`` with a plot and a table."""
    (folder / "plots").mkdir(parents=True)
    (folder / "tables").mkdir()
    (folder / "summary.md").write_text(f"# {name}\n\n{text}\n\n![p](plots/p.png)\n", "utf-8")
    exp = {"experiment": {"name": name, "frames": 2}}
    plots = ["plots/p.png"]
    data = {"study": {"experiment": exp}, "variants": {}, "comparison": [], "plots": plots}
    (folder / "summary.json").write_text(json.dumps(data), encoding="utf-8")
    (folder / "plots" / "p.png").write_bytes(f"png of {name}: {text}".encode())
    (folder / "tables" / "mismatched.csv").write_text(f"value\n{text}\n", encoding="utf-8")
    return folder


def test_collect_again_from_the_records_it_stored(tmp_path, capsys):
    """The page keeps each report's record beside its plots: re-running one study, the page
    is collected from its new report and the stored records of the others."""
    a = _named_report(tmp_path / "runs" / "a", "study_a", "first a")
    b = _named_report(tmp_path / "runs" / "b", "study_b", "first b")
    page = tmp_path / "docs" / "page.md"
    assert main(["collect", str(a), str(b), "-o", str(page), "-q"]) == 0
    stored = page.parent / "page"
    for name, rep in (("study_a", a), ("study_b", b)):
        for f in ("summary.md", "summary.json", "tables/mismatched.csv"):
            assert (stored / name / f).read_bytes() == (rep / f).read_bytes()
        assert (stored / name / "p.png").read_bytes() == (rep / "plots" / "p.png").read_bytes()
    first = page.read_text(encoding="utf-8")
    # study a is run again; study b comes from its record, the machine's run folder gone
    a2 = _named_report(tmp_path / "runs" / "a2", "study_a", "second a")
    shutil.rmtree(tmp_path / "runs" / "b")
    argv = ["collect", str(a2), str(stored / "study_b"), "-o", str(page), "--overwrite", "-q"]
    assert main(argv) == 0, capsys.readouterr().err
    text = page.read_text(encoding="utf-8")
    assert "second a" in text and "first a" not in text
    assert text.split("first b")[1] == first.split("first b")[1]  # b's section unchanged
    assert "(page/study_b/p.png)" in text
    assert (stored / "study_b" / "p.png").read_bytes() == b"png of study_b: first b"
    assert (stored / "study_a" / "tables" / "mismatched.csv").read_text() == "value\nsecond a\n"
    # collected again from its own records alone, the page is the same
    both = [str(stored / "study_a"), str(stored / "study_b")]
    assert main(["collect", *both, "-o", str(page), "--overwrite", "-q"]) == 0
    assert page.read_text(encoding="utf-8").split("\n", 4)[4] == text.split("\n", 4)[4]
    # a study dropped from the page loses its record and plots
    assert main(["collect", str(stored / "study_a"), "-o", str(page), "--overwrite", "-q"]) == 0
    assert not (stored / "study_b").exists()
    # one report per study; a stored record under another study's name is refused
    for argv, why in (
        ([str(a2), str(stored / "study_a")], "given twice"),
        ([str(_named_report(stored / "other", "study_a", "x"))], "not 'other'"),
    ):
        assert main(["collect", *argv, "-o", str(page), "--overwrite", "-q"]) == 2
        err = capsys.readouterr().err
        assert why in err and len(err.strip().splitlines()) == 1, err


def test_unknown_stage_is_an_argparse_error(tmp_path, capsys):
    rc = main(["study", "x.toml", "-o", str(tmp_path), "--until", "render"])
    assert rc == 2 and "--until" in capsys.readouterr().err
