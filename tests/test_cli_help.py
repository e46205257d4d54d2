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


def _track_settings_defaults() -> dict[str, set]:
    """Field name → its defaults over every ``*Settings`` dataclass of :mod:`track`."""
    import dataclasses
    import pkgutil

    import track

    out: dict[str, list] = {}
    for info in pkgutil.iter_modules(track.__path__):
        mod = importlib.import_module(f"track.{info.name}")
        for name, obj in vars(mod).items():
            if (
                name.endswith("Settings")
                and dataclasses.is_dataclass(obj)
                and obj.__module__ == mod.__name__
            ):
                for f in dataclasses.fields(obj):
                    if f.default is not dataclasses.MISSING:
                        out.setdefault(f.name, []).append((f"{name}.{f.name}", f.default))
    return out


#: Keyword arguments of track functions that are a settings field under another name.
_ALIASES = {
    ("track.segment", "auto_threshold", "k_sigma"): ("SegmentSettings", "auto_k_sigma"),
    ("track.outliers", "normalized_median_test", "threshold"): (
        "LinkSettings",
        "outlier_threshold",
    ),
    ("track.regularize", "fit_field", "method"): ("LinkSettings", "regularization"),
}
#: Keyword arguments named like a settings field that mean something else.
_UNRELATED = {
    ("track._threads", "gaussian_filter", "mode"),  # scipy.ndimage's boundary mode
    ("track._threads", "maximum_filter3", "mode"),
}


def test_track_function_defaults_are_the_settings_defaults():
    """A keyword default of a ``track`` function (or method) named like a field of a
    ``*Settings`` dataclass of ``track`` equals that field's default, so that no function
    holds a default of its own that the command line and the studies would not use."""
    import dataclasses
    import inspect
    import pkgutil

    import track

    fields = _track_settings_defaults()
    assert {"threshold", "auto_k_sigma", "auto_size_factors", "outlier_threshold"} <= set(fields)
    checked, bad = 0, []
    for info in pkgutil.iter_modules(track.__path__):
        mod = importlib.import_module(f"track.{info.name}")
        members = []
        for name, obj in vars(mod).items():
            if getattr(obj, "__module__", None) != mod.__name__:
                continue
            if inspect.isfunction(obj):
                members.append((name, obj))
            elif inspect.isclass(obj) and not dataclasses.is_dataclass(obj):
                members += [
                    (f"{name}.{m}", f) for m, f in vars(obj).items() if inspect.isfunction(f)
                ]
        for fname, func in members:
            for p in inspect.signature(func).parameters.values():
                if p.default is inspect.Parameter.empty or p.default is None:
                    continue
                if (mod.__name__, fname, p.name) in _UNRELATED:
                    continue
                alias = _ALIASES.get((mod.__name__, fname, p.name))
                if alias is not None:
                    want = [
                        (".".join(alias), d) for n, d in fields[alias[1]] if n == ".".join(alias)
                    ]
                elif p.name in fields:
                    want = fields[p.name]
                else:
                    continue
                checked += 1
                if not any(p.default == d for _, d in want):
                    bad.append(f"{mod.__name__}.{fname}({p.name}={p.default!r}) vs {want}")
    assert checked >= 2  # the aliases at least
    assert not bad, bad


def test_detect_settings_take_the_segment_and_deconvolution_defaults():
    """DetectSettings' segmentation and deconvolution fields default to the settings of the
    functions they configure (one definition each)."""
    import dataclasses

    from track.deconvolve import DeconvolveSettings
    from track.detect import DetectSettings
    from track.segment import SegmentSettings

    det = DetectSettings()
    assert det.segment_settings() == SegmentSettings()
    assert det.deconvolve_settings() == DeconvolveSettings()
    for f in dataclasses.fields(SegmentSettings):
        assert getattr(det, f.name) == f.default, f.name
