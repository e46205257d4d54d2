"""The hrvptm command line: errors a user can cause, the report folder's safety, resume."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

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
    text = src.replace("[track]\n", "[track]\ntarget_node = 5\n")
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
    rc = main(["collect", str(tmp_path), "-o", str(tmp_path / "page.md")])
    assert rc == 2
    assert "holds no finished study" in capsys.readouterr().err
    assert not (tmp_path / "page.md").exists()


def test_unknown_stage_is_an_argparse_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["study", "x.toml", "-o", str(tmp_path), "--until", "render"])
    assert info.value.code == 2
