"""Validators and the shared command-line behaviour (hrvbase.validate, hrvbase.cli)."""

from __future__ import annotations

import numpy as np
import pytest

from hrvbase import validate as v
from hrvbase.cli import EXIT_INTERNAL, Parser, common_options, run_main
from hrvbase.errors import InputError


def test_points_xyz():
    assert v.points_xyz([[1, 2, 3]], "p").dtype == np.float64
    assert v.points_xyz([], "p").shape == (0, 3)
    for bad, why in [([[1, 2]], r"\(N, 3\)"), ([[1, 2, np.nan]], "NaN"), ("abc", "numeric")]:
        with pytest.raises(InputError, match=why):
            v.points_xyz(bad, "positions_um")
    with pytest.raises(InputError, match="at least 4"):
        v.points_xyz(np.zeros((3, 3)), "p", min_points=4)


def test_numbers_name_the_parameter():
    assert v.positive_float(2, "--z-step") == 2.0
    for call in (
        lambda: v.positive_float(-1, "--z-step"),
        lambda: v.positive_float(float("inf"), "--z-step"),
        lambda: v.nonnegative_float(-0.1, "--z-step"),
        lambda: v.int_in_range(2.5, "--z-step", 1),
        lambda: v.int_in_range(0, "--z-step", 1, 10),
        lambda: v.finite_float(True, "--z-step"),
    ):
        with pytest.raises(InputError, match="--z-step"):
            call()
    assert v.per_axis(2.0, "s") == (2.0, 2.0, 2.0)
    assert v.per_axis((5, 1.6, 1.6), "s") == (5.0, 1.6, 1.6)
    with pytest.raises(InputError, match=r"\(z, y, x\)"):
        v.per_axis((1, 2), "s")


def _parser(func):
    p = Parser(prog="demo", parents=[common_options(suppress=False)])
    sub = p.add_subparsers(dest="command", parser_class=Parser)
    c = sub.add_parser("go", parents=[common_options(suppress=True)])
    c.set_defaults(func=func)
    return p


@pytest.mark.parametrize(
    ("exc", "status", "text"),
    [
        (InputError("--x must be > 0, got -1"), 2, "demo: error: --x must be > 0, got -1"),
        (PermissionError(13, "Permission denied"), 2, "demo: error:"),
        (RuntimeError("oops\nsecond line"), EXIT_INTERNAL, "demo: internal error:"),
    ],
)
def test_run_main_gives_one_line_and_a_status(capsys, exc, status, text):
    def fail(args):
        raise exc

    assert run_main("demo", _parser(fail), ["go", "-q"], loggers=("demo",)) == status
    err = capsys.readouterr().err
    assert err.startswith(text) and len(err.strip().splitlines()) == 1
    assert "Traceback" not in err


def test_quiet_and_verbose_before_or_after_the_command(capsys):
    seen = {}

    def ok(args):
        seen["q"], seen["v"] = args.quiet, args.verbose
        return 0

    assert run_main("demo", _parser(ok), ["-q", "go"], loggers=()) == 0
    assert seen == {"q": True, "v": 0}
    assert run_main("demo", _parser(ok), ["go", "-vv"], loggers=()) == 0
    assert seen == {"q": False, "v": 2}
    assert run_main("demo", _parser(ok), ["go", "--bogus"], loggers=()) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith("demo: error:")
