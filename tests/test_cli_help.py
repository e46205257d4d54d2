"""The four command lines are alike: every option documents its default (and unit), and
-q/-v/--version are accepted in the same places."""

from __future__ import annotations

import argparse
import importlib

import pytest

PROGRAMS = ("lfsim", "recon", "track", "hrvptm")


def _parsers(prog: str):
    parser = importlib.import_module(f"{prog}.cli").build_parser()
    out = [(prog, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            out += [(f"{prog} {name}", sub) for name, sub in action.choices.items()]
    return out


def _undocumented(parser: argparse.ArgumentParser) -> list[str]:
    bad = []
    for a in parser._actions:
        if isinstance(
            a, argparse._HelpAction | argparse._VersionAction | argparse._SubParsersAction
        ):
            continue
        if not a.option_strings:  # positional: a name and a help text
            if not a.help:
                bad.append(a.dest)
            continue
        text = a.help or ""
        flag = a.nargs == 0
        if not text or (not flag and not a.required and "default" not in text):
            bad.append(a.option_strings[-1])
    return bad


@pytest.mark.parametrize("prog", PROGRAMS)
def test_every_option_has_help_with_its_default(prog):
    missing = {name: _undocumented(p) for name, p in _parsers(prog)}
    missing = {k: v for k, v in missing.items() if v}
    assert not missing, missing


@pytest.mark.parametrize("prog", PROGRAMS)
def test_quiet_verbose_version_alike(prog, capsys):
    main = importlib.import_module(f"{prog}.cli").main
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith(prog)
    for name, parser in _parsers(prog):
        opts = {s for a in parser._actions for s in a.option_strings}
        assert {"-q", "--quiet", "-v", "--verbose"} <= opts, name


def test_cli_defaults_are_the_settings_dataclasses(tmp_path):
    """No option given: the settings built by each command line equal the library defaults
    (one source for every default)."""
    from hrvbase.cli import settings_from_args
    from recon.cli import RUN_SETTINGS
    from recon.cli import build_parser as recon_parser
    from recon.settings import ReconSettings
    from track.cli import build_parser as track_parser
    from track.cli import detect_settings, series_settings
    from track.detect import DetectSettings
    from track.fields import GridSettings
    from track.matching import LinkSettings
    from track.series import SeriesSettings

    args = recon_parser().parse_args(["run", "f.tif", "-o", str(tmp_path / "v")])
    assert settings_from_args(ReconSettings, args, RUN_SETTINGS) == ReconSettings()
    args = track_parser().parse_args(["run", str(tmp_path), "-o", str(tmp_path / "r")])
    assert detect_settings(args) == DetectSettings()
    series = series_settings(args)
    assert series.grid == GridSettings() and series.link == LinkSettings()
    assert series.mode == SeriesSettings().mode
