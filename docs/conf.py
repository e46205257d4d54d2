"""Sphinx configuration of the hrvptm documentation site.

Build (warnings are errors; the gallery in ``examples/`` is executed at test size)::

    .venv/bin/python -m sphinx -W -b html docs docs/_build/html
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS / "_ext"))
os.environ.setdefault("MPLBACKEND", "Agg")

project = "hrvptm"
author = "hrvptm authors"
copyright = "hrvptm authors, BSD-3-Clause"
release = "0.1.0"

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "cli_help",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]  # autosummary: a class page is its docstring and members
exclude_patterns = [
    "_build",
    # Inputs of ``hrvptm collect`` (the text above the generated tables), not pages.
    "validation_intro.md",
    "validation_test_intro.md",
    # Each study's own summary (the collected pages hold the same tables and plots).
    "validation/*/summary.md",
    "validation_test_size/*/summary.md",
    "auto_examples/*.ipynb",
    "auto_examples/*.py",
    "auto_examples/*.zip",
    "auto_examples/*.md5",
    "auto_examples/*.codeobj.json",
    "sg_execution_times.rst",
]

# MyST: the Markdown pages as they are (heading anchors for their in-page links, $…$ maths).
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 4
suppress_warnings = ["myst.header"]  # pages that start below level 1 headings

# API reference: one page per name of each package's ``__all__`` (docs/api/*.rst).
autosummary_generate = True
autodoc_typehints = "none"  # the numpydoc sections give the types, with shapes and units
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()

html_theme = "pydata_sphinx_theme"
html_title = "hrvptm"
html_theme_options = {
    "navigation_depth": 3,
    "show_toc_level": 2,
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_static_path: list[str] = []

sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": str(DOCS / "auto_examples"),
    "filename_pattern": r"/plot_",  # every example is executed
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "image_scrapers": ("matplotlib",),
    "reset_modules": ("matplotlib",),
}


#: Links of the Markdown pages to files that are no page of the site (repository files
#: outside docs/, inputs of ``hrvptm collect``): shown as the file's path instead.
OFF_SITE_LINKS = re.compile(
    r"\[(`[^`\]]+`)\]\((?:\.\./benchmarks/README|validation_(?:test_)?intro)\.md\)"
)


def _off_site_links(app, docname: str, source: list[str]) -> None:
    source[0] = OFF_SITE_LINKS.sub(r"\1", source[0])


def setup(app) -> None:
    """Hooks of this site (module docstring)."""
    app.connect("source-read", _off_site_links)
