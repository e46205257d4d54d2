"""Sphinx extension: a command-line reference rendered from the tools' argparse parsers.

``.. cli-help:: lfsim.cli:build_parser`` (with ``:prog: lfsim``) inserts the help of the
parser and of every subcommand (recursively) as literal blocks under generated headings, so
the reference is the text ``lfsim COMMAND --help`` prints, at a fixed width of 100 columns.
"""

from __future__ import annotations

import argparse
import importlib
import os
from collections.abc import Iterator
from typing import ClassVar

from docutils import nodes
from docutils.parsers.rst import Directive, directives

WIDTH = "100"


def load_parser(spec: str) -> argparse.ArgumentParser:
    """The parser built by ``module:function`` (``spec``)."""
    module, _, func = spec.partition(":")
    return getattr(importlib.import_module(module), func)()


def subcommands(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """``(path, parser)`` of ``parser`` and of every subcommand under it, depth first.

    ``path`` is the tuple of subcommand names (``()`` for the top-level parser); an alias of a
    subcommand (the same parser under a second name) is listed once.
    """
    yield path, parser
    seen: set[int] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                if id(sub) in seen:
                    continue
                seen.add(id(sub))
                yield from subcommands(sub, (*path, name))


def help_text(parser: argparse.ArgumentParser) -> str:
    """``parser.format_help()`` at the reference's fixed width."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        return parser.format_help()
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


class CliHelp(Directive):
    """The ``cli-help`` directive (module docstring)."""

    required_arguments = 1
    option_spec: ClassVar[dict] = {"prog": directives.unchanged_required}

    def run(self) -> list[nodes.Node]:
        prog = self.options.get("prog", self.arguments[0].split(".")[0])
        parser = load_parser(self.arguments[0])
        parser.prog = prog
        out: list[nodes.Node] = []
        for path, sub in subcommands(parser):
            title = " ".join((prog, *path))
            section = nodes.section(ids=[nodes.make_id("cli-" + title)], names=[title])
            section += nodes.title(text=title)
            block = nodes.literal_block(text=help_text(sub))
            block["language"] = "text"
            section += block
            out.append(section)
        return out


def setup(app):
    """Register the directive."""
    app.add_directive("cli-help", CliHelp)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
