"""The validation page's pooled uncertainty coverage (across the studies)."""

import pytest

from hrvptm.collect import _coverage_overview


def _report(name: str, **variants) -> tuple:
    data = {
        "study": {"experiment": {"experiment": {"name": name}}},
        "variants": {k: {"summary": s} for k, s in variants.items()},
    }
    return (None, "", data)


def _summary(n: int, c1: float, c2: float, prefix: str = "u_") -> dict:
    out = {f"{prefix}coverage_n": n}
    for ax in "xyz":
        out[f"{prefix}coverage_1sigma_{ax}"] = c1
        out[f"{prefix}coverage_2sigma_{ax}"] = c2
    return out


def test_coverage_is_pooled_over_studies_weighted_by_their_errors():
    loaded = [
        _report("a", mismatched=_summary(100, 0.60, 0.90), matched=_summary(300, 0.70, 0.96)),
        _report("b", mismatched=_summary(600, 0.70, 0.95, prefix="")),  # positions: no "u_"
        _report("c", mismatched={"pooled_n": 5}),  # tables without σ: left out
    ]
    lines = _coverage_overview(loaded)
    rows = [ln for ln in lines if ln.startswith("| ")]
    assert rows[1:4] == [
        "| a (mismatched) | 100 | 60 / 90 | 60 / 90 | 60 / 90 |",
        "| a (matched) | 300 | 70 / 96 | 70 / 96 | 70 / 96 |",
        "| b (mismatched) | 600 | 70 / 95 | 70 / 95 | 70 / 95 |",
    ]
    # (100 × 0.60 + 900 × 0.70) / 1000 = 0.69; (90 + 288 + 570) / 1000 = 0.948
    assert rows[4] == "| **all studies** | 1000 | " + " | ".join(["**69 / 95**"] * 3) + " |"
    assert not any(ln.startswith("| c ") for ln in rows)


def test_the_as_air_variant_is_listed_but_not_pooled():
    """The specimen left out of the model on purpose (z errors of 26 %) says nothing about σ."""
    loaded = [_report("gel", mismatched=_summary(100, 0.70, 0.96), as_air=_summary(100, 0.0, 0.0))]
    lines = _coverage_overview(loaded)
    rows = [ln for ln in lines if ln.startswith("| ")]
    assert "| gel (as_air) | 100 | 0 / 0 | 0 / 0 | 0 / 0 |" in rows
    assert rows[-1] == "| **all studies** | 100 | " + " | ".join(["**70 / 96**"] * 3) + " |"
    assert any("as_air variants" in ln for ln in lines)
    lines = _coverage_overview([_report("gel", mismatched=_summary(100, 0.70, 0.96))])
    assert not any("as_air" in ln for ln in lines)


@pytest.mark.parametrize("summary", [{}, {"u_coverage_n": 0}])
def test_no_coverage_table_without_uncertainties(summary):
    assert _coverage_overview([_report("a", mismatched=summary)]) == []


# -- the page's plot folder: only what collect wrote is ever replaced ---------------------------
def _plot_report(folder, name="study_a", text="first"):
    """A finished report of study ``name`` with the plot ``displacement.png``."""
    import json

    (folder / "plots").mkdir(parents=True)
    (folder / "summary.md").write_text(f"# {name}\n\n{text}\n", encoding="utf-8")
    exp = {"experiment": {"name": name, "frames": 2}}
    data = {
        "study": {"experiment": exp},
        "variants": {},
        "comparison": [],
        "plots": ["plots/displacement.png"],
    }
    (folder / "summary.json").write_text(json.dumps(data), encoding="utf-8")
    (folder / "plots" / "displacement.png").write_bytes(f"png {text}".encode())
    return folder


@pytest.mark.parametrize("overwrite", [False, True])
def test_user_files_in_the_plot_folder_are_never_replaced(tmp_path, capsys, overwrite):
    from hrvptm.cli import main

    report = _plot_report(tmp_path / "rep")
    page = tmp_path / "page.md"
    mine = tmp_path / "page" / "study_a" / "displacement.png"
    mine.parent.mkdir(parents=True)
    mine.write_bytes(b"my own figure")
    argv = ["collect", str(report), "-o", str(page), "-q"] + ["--overwrite"] * overwrite
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(mine) in err[0] and "not written by hrvptm collect" in err[0]
    assert mine.read_bytes() == b"my own figure"
    assert not page.exists()
    assert sorted(p.name for p in mine.parent.iterdir()) == ["displacement.png"]


def test_overwrite_replaces_only_the_files_collect_wrote(tmp_path, capsys):
    from hrvptm.cli import main

    page = tmp_path / "page.md"
    first = _plot_report(tmp_path / "r1", text="first")
    assert main(["collect", str(first), "-o", str(page), "-q"]) == 0
    folder = tmp_path / "page" / "study_a"
    assert (folder / "displacement.png").read_bytes() == b"png first"
    # the user's own file beside the plots: kept, and replaced neither by a new plot of its
    # name nor removed as a plot the page no longer shows
    mine = folder / "strain.png"
    mine.write_bytes(b"my own figure")
    second = _plot_report(tmp_path / "r2", text="second")
    assert main(["collect", str(second), "-o", str(page), "--overwrite", "-q"]) == 0
    assert (folder / "displacement.png").read_bytes() == b"png second"
    assert mine.read_bytes() == b"my own figure"
    data = __import__("json").loads((second / "summary.json").read_text())
    data["plots"].append("plots/strain.png")
    (second / "summary.json").write_text(__import__("json").dumps(data), encoding="utf-8")
    (second / "plots" / "strain.png").write_bytes(b"png strain")
    assert main(["collect", str(second), "-o", str(page), "--overwrite", "-q"]) == 2
    err = capsys.readouterr().err
    assert str(mine) in err and "not written by hrvptm collect" in err
    assert mine.read_bytes() == b"my own figure"
    # a page deleted, its plot folder kept: the files it wrote are not replaced silently
    page.unlink()
    assert main(["collect", str(first), "-o", str(page), "-q"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (folder / "displacement.png").read_bytes() == b"png second"


@pytest.mark.parametrize("blocked", ["page", "page/study_a"])
def test_a_file_in_place_of_the_plot_folder_is_refused_before_writing(tmp_path, capsys, blocked):
    from hrvptm.cli import main

    report = _plot_report(tmp_path / "rep")
    (tmp_path / blocked).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / blocked).write_text("mine\n", encoding="utf-8")
    page = tmp_path / "page.md"
    assert main(["collect", str(report), "-o", str(page), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{tmp_path / blocked} is a file where hrvptm collect" in err[0]
    assert (tmp_path / blocked).read_text(encoding="utf-8") == "mine\n"
    assert not page.exists()
