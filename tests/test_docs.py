"""The documentation site's sources (docs/): the API reference lists every public name, the
CLI reference covers every subcommand, the front pages give the commands a newcomer needs.

The site itself is built by ``.venv/bin/python -m sphinx -W -b html docs docs/_build/html``
(warnings are errors), separately from pytest.
"""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PACKAGES = ("hrvbase", "lfsim", "recon", "track", "hrvptm")
TOOLS = ("lfsim", "recon", "track", "hrvptm")
SETUP = "./setup.sh"
TEST = ".venv/bin/python -m pytest -q"
LONG = ".venv/bin/python -m pytest -q -m studies"
DEMO = ".venv/bin/hrvptm demo -o out/demo"
NAPARI = ".venv/bin/napari --plugin hrvptm out/demo"


def _cli_help():
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        return importlib.import_module("cli_help")
    finally:
        sys.path.remove(str(DOCS / "_ext"))


def _documented(page: str) -> set[str]:
    """Names listed in an API page: autosummary entries and ````name```` mentions."""
    entries = re.findall(r"^ {3}(\w+)$", page, re.M)
    return set(entries) | set(re.findall(r"``(\w+)``", page))


@pytest.mark.parametrize("package", PACKAGES)
def test_api_page_lists_every_public_name(package):
    page = (DOCS / "api" / f"{package}.rst").read_text(encoding="utf-8")
    names = set(importlib.import_module(package).__all__)
    assert f".. currentmodule:: {package}" in page
    missing = names - _documented(page)
    assert not missing, f"docs/api/{package}.rst does not list {sorted(missing)}"
    index = (DOCS / "api" / "index.rst").read_text(encoding="utf-8")
    assert re.search(rf"^ {{3}}{package}$", index, re.M)


def test_api_check_catches_a_missing_name():
    page = ".. autosummary::\n   :toctree: generated\n\n   Study\n   run_study\n"
    assert {"Study", "run_study"} <= _documented(page)
    assert "load_study" not in _documented(page)


@pytest.mark.parametrize("tool", TOOLS)
def test_cli_page_covers_every_subcommand(tool):
    cli = _cli_help()
    page = (DOCS / "cli" / f"{tool}.md").read_text(encoding="utf-8")
    assert f"```{{cli-help}} {tool}.cli:build_parser\n:prog: {tool}\n```" in page
    parser = cli.load_parser(f"{tool}.cli:build_parser")
    top = importlib.import_module(f"{tool}.cli").build_parser()
    choices = [a for a in top._actions if a.__class__.__name__ == "_SubParsersAction"]
    assert choices, f"{tool} has no subcommands"
    rendered = {" ".join(path) for path, _ in cli.subcommands(parser)}
    assert set(choices[0].choices) <= rendered  # every subcommand gets its own section
    for path, sub in cli.subcommands(parser):
        text = cli.help_text(sub)
        assert text.startswith("usage:") and all(word in text for word in path)
    assert re.search(rf"^{tool}$", (DOCS / "cli" / "index.md").read_text(encoding="utf-8"), re.M)


def test_front_pages_give_the_commands():
    index = (DOCS / "index.md").read_text(encoding="utf-8")
    block = re.search(r"```bash\n(.*?)```", index, re.S).group(1).split("\n")
    commands = [line for line in block if line.strip()]
    assert commands == [SETUP, DEMO, NAPARI]  # fresh clone to napari: at most five commands
    assert TEST in index and LONG in index
    start = (DOCS / "getting_started.md").read_text(encoding="utf-8")
    assert all(c in start for c in (SETUP, TEST, LONG, DEMO, NAPARI))
    head = (ROOT / "README.md").read_text(encoding="utf-8")[:2500]
    assert all(c in head for c in (SETUP, TEST, LONG, DEMO))


def test_every_page_is_in_a_toctree():
    """Each Markdown page under docs/user_guide, docs/cli and the top-level pages is listed in
    a toctree (``sphinx-build -W`` fails on an orphan; this finds it without a build)."""
    built = ("_build", "auto_examples", "generated")  # build outputs, not sources
    toctrees = "".join(
        p.read_text(encoding="utf-8")
        for p in DOCS.rglob("index.*")
        if p.suffix in (".md", ".rst") and not set(p.relative_to(DOCS).parts) & set(built)
    )
    for page in [*DOCS.glob("user_guide/*.md"), *DOCS.glob("cli/*.md")]:
        if page.stem != "index":
            assert re.search(rf"^{page.stem}$", toctrees, re.M), f"{page} is in no toctree"
    for name in ("getting_started", "real_data", "conventions", "validation"):
        assert re.search(rf"^{name}$", toctrees, re.M)


def test_gallery_examples_are_small_and_executed():
    conf = (DOCS / "conf.py").read_text(encoding="utf-8")
    assert '"filename_pattern": r"/plot_"' in conf
    examples = sorted((ROOT / "examples").glob("plot_*.py"))
    assert {p.stem for p in examples} >= {"plot_pipeline", "plot_study", "plot_point_clouds"}
    for path in examples:
        text = path.read_text(encoding="utf-8")
        assert "_test.toml" in text or "demo_simple_shear" in text or "track_clouds" in text
