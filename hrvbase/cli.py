"""What every command line of the toolkit shares: options, logging and error handling.

- :func:`common_options` gives ``-v``/``--verbose`` (count), ``-q``/``--quiet`` and is added
  both to the main parser and to every sub-command, so they work before or after the command
  name, alike in ``lfsim``, ``recon``, ``track`` and ``hrvptm``; ``--version`` sits on the
  main parser.
- :func:`tool_parser` builds the main parser of each of them: those options, ``--version``
  and the sub-command parsers.
- :class:`Parser` prints usage errors as one line ``PROG: error: ...`` (exit 2).
- :func:`run_main` sets up logging (``PROG: level: message`` on stderr) and turns every error
  a user can cause (:class:`~hrvbase.errors.HrvError`, and operating-system errors such as a
  full disk) into one line ``PROG: error: <message>`` and exit status 2; ``Ctrl-C`` exits
  with 130. An unexpected exception (a bug) also prints one line, exit 70, and its traceback
  only with ``-vv``.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import re
import sys
import traceback
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NoReturn

from .errors import HrvError

#: Exit status of an unexpected internal error (BSD ``EX_SOFTWARE``).
EXIT_INTERNAL = 70


class Parser(argparse.ArgumentParser):
    """Argument parser whose usage errors are one line ``PROG: error: ...`` (exit 2)."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog.split()[0]}: error: {message}\n")
        raise SystemExit(2)


def common_options(*, suppress: bool) -> argparse.ArgumentParser:
    """Parent parser with ``-v``/``-q``.

    The copy given to sub-parsers (``suppress=True``) has no defaults, so that an option given
    before the command name is not reset by the sub-parser.
    """

    def dflt(value: Any) -> Any:
        return argparse.SUPPRESS if suppress else value

    p = argparse.ArgumentParser(add_help=False)
    p.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=dflt(0),
        help="more messages (-v: progress details, -vv: debugging) (default: warnings only)",
    )
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=dflt(False),
        help="only errors; no progress bars or summary (default: off)",
    )
    return p


def tool_parser(
    prog: str,
    description: str,
    version: str,
    *,
    common: Callable[..., argparse.ArgumentParser] = common_options,
    **subparsers: Any,
) -> tuple[Parser, Any, argparse.ArgumentParser]:
    """The top parser of a command line, with its shared options and its commands.

    Parameters
    ----------
    prog, description : str
        The program's name and one-line description.
    version : str
        What ``--version`` prints.
    common : callable, default :func:`common_options`
        ``common(suppress=...)`` gives the options accepted before and after the command name.
    **subparsers
        More arguments of :meth:`argparse.ArgumentParser.add_subparsers` (``metavar``,
        ``required``).

    Returns
    -------
    parser : Parser
        The top parser (``-v``/``-q``, ``--version`` and what ``common`` adds).
    commands : argparse action
        Its sub-parsers: ``commands.add_parser(name, parents=[shared], ...)``; the command's
        name lands in ``args.command``.
    shared : argparse.ArgumentParser
        The parent parser of each command (``common(suppress=True)``: no defaults, so that an
        option given before the command name is not reset).
    """
    p = Parser(prog=prog, description=description, parents=[common(suppress=False)])
    p.add_argument("--version", action="version", version=version)
    sub = p.add_subparsers(dest="command", parser_class=Parser, **subparsers)
    return p, sub, common(suppress=True)


def log_level(args: argparse.Namespace) -> int:
    """Logging level from ``-q`` / ``-v`` (default: warnings)."""
    if getattr(args, "quiet", False):
        return logging.ERROR
    verbose = getattr(args, "verbose", 0) or 0
    return logging.DEBUG if verbose >= 2 else logging.INFO if verbose == 1 else logging.WARNING


def show_progress(args: argparse.Namespace) -> bool:
    """Whether progress bars and the closing summary are shown (not with ``-q``)."""
    return not getattr(args, "quiet", False) and not getattr(args, "no_progress", False)


def one_line(exc: BaseException) -> str:
    """An exception's message folded to one line."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def run_main(
    prog: str,
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    *,
    loggers: Sequence[str],
    prepare: Callable[[argparse.Namespace], None] | None = None,
    interrupted: str = "interrupted",
) -> int:
    """Parse ``argv``, set up logging and run ``args.func(args)``; return the exit status.

    Parameters
    ----------
    prog : str
        Program name for messages.
    parser : argparse.ArgumentParser
        Its sub-commands set ``func`` (``set_defaults(func=...)``).
    argv : sequence of str or None
        ``None``: ``sys.argv[1:]``.
    loggers : sequence of str
        Package loggers whose messages are shown (``"lfsim"``, ``"recon"``, …), besides
        ``"hrvbase"``'s (the shared code's, e.g. the frames in parallel), always shown.
    prepare : callable, optional
        Called with the parsed arguments inside the error handling (e.g. to start a backend).
    interrupted : str
        Message after ``Ctrl-C``.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help/--version (0) or a usage error (already printed)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    if getattr(args, "func", None) is None:
        commands = [
            name
            for action in parser._actions
            if isinstance(action, argparse._SubParsersAction)
            for name in action.choices
        ]
        sys.stderr.write(
            f"{prog}: error: missing COMMAND (one of: {', '.join(commands)}); see {prog} --help\n"
        )
        return 2
    args.argv = argv
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter(prog))
    level = log_level(args)
    saved = []
    for name in dict.fromkeys([*loggers, "hrvbase"]):
        lg = logging.getLogger(name)
        saved.append((lg, lg.level))
        lg.setLevel(level)
        lg.addHandler(handler)
    try:
        if prepare is not None:
            prepare(args)
        return int(args.func(args) or 0)
    except HrvError as exc:
        sys.stderr.write(f"{prog}: error: {one_line(exc)}\n")
        return 2
    except (OSError, MemoryError) as exc:
        sys.stderr.write(f"{prog}: error: {one_line(exc)}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"{prog}: {interrupted}\n")
        return 130
    except Exception as exc:  # a bug: one line, the traceback only on request
        sys.stderr.write(
            f"{prog}: internal error: {type(exc).__name__}: {one_line(exc)} (please report it; "
            "-vv shows the traceback)\n"
        )
        if level <= logging.DEBUG:
            traceback.print_exc(file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        for lg, old in saved:
            lg.removeHandler(handler)
            lg.setLevel(old)


# -- argparse types --------------------------------------------------------------------------
def int_in(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """argparse type: an integer in ``lo..hi`` (``hi=None``: no upper bound)."""
    expected = f"an integer >= {lo}" if hi is None else f"an integer in {lo}..{hi}"

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if v < lo or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v

    return parse


def number(ok: Callable[[float], bool], expected: str, *, keyword: str | None = None):
    """argparse type: a finite number for which ``ok(v)`` holds (``expected`` says what), or the
    word ``keyword`` itself."""
    prefix = f"'{keyword}' or " if keyword else ""

    def parse(text: str) -> float | str:
        if keyword is not None and text == keyword:
            return text
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {prefix}{expected}, got {text!r}") from None
        if not (math.isfinite(v) and ok(v)):
            raise argparse.ArgumentTypeError(f"expected {prefix}{expected}, got {text!r}")
        return v

    return parse


def add_flags(parser: argparse.ArgumentParser | Any, flags: Mapping[str, str]) -> None:
    """Add on/off options (``action="store_true"``, off unless given) to ``parser`` (or an
    argument group): ``flags`` maps each option, e.g. ``"--overwrite"``, to its help text, in
    the order ``--help`` lists them."""
    for flag, text in flags.items():
        parser.add_argument(flag, action="store_true", help=text)


# -- frames in parallel (hrvbase.parallel) ----------------------------------------------------
def add_parallel_options(parser: argparse.ArgumentParser | Any) -> None:
    """Add ``--workers N|auto`` and ``--scheduler ADDRESS`` (:mod:`hrvbase.parallel`), the same
    in every command that processes frames; :func:`parallel_from_args` reads them."""
    parser.add_argument(
        "--workers",
        default=None,
        metavar="N",
        help="process the frames on N local Dask worker processes ('auto': one per core), "
        "each with its share of the cores, at most one per core and as many as the available "
        "memory holds; results are identical to 1 (default: 1, in this process, no Dask)",
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="process the frames on the workers of an existing Dask cluster, not with "
        "--workers (tcp://HOST:PORT or tls://HOST:PORT, e.g. tcp://10.0.0.5:8786; `dask "
        "scheduler` / `dask worker`, or dask-jobqueue on SLURM; default: none)",
    )


def parallel_from_args(args: argparse.Namespace, *, threads: int | None = None):
    """The :class:`hrvbase.parallel.Parallel` of ``--workers`` / ``--scheduler``.

    ``threads`` (e.g. ``--threads``) sets the compute threads of each worker.

    Local workers are capped to the machine's cores and to what its available memory holds
    (:meth:`hrvbase.parallel.Parallel.capped`, with a warning naming both numbers).
    ``--scheduler`` is checked before any work: its form, then that a Dask scheduler answers
    there (:func:`hrvbase.parallel.check_scheduler`, within
    :data:`hrvbase.parallel.CONNECT_TIMEOUT_S` seconds).

    Raises
    ------
    InputError
        ``--workers`` is not an integer >= 1 nor ``auto``, both options are given, or no Dask
        scheduler answers at the ``--scheduler`` address (malformed, nothing listening,
        another service); the message names the option.
    """
    from .errors import InputError
    from .parallel import Parallel, check_scheduler

    text = getattr(args, "workers", None)
    scheduler = getattr(args, "scheduler", None)
    if text is not None and scheduler is not None:
        raise InputError(
            f"--workers and --scheduler exclude each other (got --workers {text} and "
            f"--scheduler {scheduler}): with --scheduler the frames run on that cluster's "
            "workers; give one of them"
        )
    workers: int | str = 1
    if text is not None:
        text = str(text).strip()
        if text == "auto":
            workers = "auto"
        else:
            try:
                workers = int(text)
            except ValueError:
                workers = -1
            if workers < 1:
                raise InputError(f"--workers must be an integer >= 1 or 'auto', got {text!r}")
    if scheduler is not None and not scheduler.strip():
        raise InputError("--scheduler must be an address such as tcp://host:8786, got ''")
    try:
        par = Parallel(workers=workers, scheduler=scheduler, threads=threads)
    except InputError as exc:
        message = re.sub(r"^(scheduler|workers) ", r"--\1 ", str(exc))
        raise InputError(rename_fields(message, {"threads": "--threads"})) from None
    if par.scheduler is not None:
        check_scheduler(par.scheduler, "--scheduler")
    return par.capped(what=f"--workers {text}")


# -- options that set fields of a settings dataclass ---------------------------------------
@dataclasses.dataclass(frozen=True)
class SettingOption:
    """A command-line option that sets one field of a settings dataclass.

    The option's default is the dataclass field's own (the option is left unset, ``None``, so
    the dataclass applies it); its help text is ``help`` plus that default, so neither can
    drift from the library.
    """

    field: str
    flags: tuple[str, ...]
    help: str
    type: Callable[[str], Any] | None = None
    metavar: str | None = None
    choices: tuple | None = None


def _default_text(value: Any, derived: str) -> str:
    if value is None:
        return derived
    if isinstance(value, float) and value.is_integer():
        return f"{int(value)}"
    if isinstance(value, tuple | list):  # a per-axis value, typed as A,B,C
        return ",".join(_default_text(v, derived) for v in value)
    return f"{value}"


def add_setting_options(
    parser: argparse.ArgumentParser | Any,
    cls: type,
    options: Sequence[SettingOption],
    *,
    derived: str = "automatic",
    prefix: str = "setting_",
) -> None:
    """Add ``options`` (fields of the dataclass ``cls``) to ``parser`` (or an argument group).

    ``derived`` is shown as the default of fields whose dataclass default is ``None``;
    ``prefix`` keeps the destinations of two dataclasses with a field of the same name apart
    (give :func:`settings_from_args` the same).
    """
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    for opt in options:
        if opt.field not in defaults:
            raise KeyError(f"{cls.__name__} has no field {opt.field!r}")
        kw: dict[str, Any] = {"dest": f"{prefix}{opt.field}", "default": None}
        if opt.type is not None:
            kw["type"] = opt.type
        if opt.metavar is not None:
            kw["metavar"] = opt.metavar
        if opt.choices is not None:
            kw["choices"] = opt.choices
        text = _default_text(defaults[opt.field], derived)
        parser.add_argument(*opt.flags, help=f"{opt.help} (default: {text})", **kw)


def rename_fields(message: str, names: Mapping[str, str]) -> str:
    """``message`` with dataclass field names replaced by the options the user typed."""
    for name, flag in names.items():
        if len(name) < 3:  # "s": too likely to be an ordinary word or unit, but for a subject
            message = re.sub(rf"^{re.escape(name)}(?= )", flag, message)
            continue
        message = re.sub(rf"(?<![\w-]){re.escape(name)}(?![\w-])", flag, message)
    return message


def settings_from_args(
    cls: type,
    args: argparse.Namespace,
    options: Sequence[SettingOption],
    *,
    extra: Mapping[str, Any] | None = None,
    names: Mapping[str, str] | None = None,
    prefix: str = "setting_",
):
    """Build ``cls`` from the options the user gave (the others keep the dataclass defaults).

    Errors raised by the dataclass name the option (``--z-step``), not the field.
    """
    values = {
        o.field: getattr(args, f"{prefix}{o.field}")
        for o in options
        if getattr(args, f"{prefix}{o.field}", None) is not None
    }
    values.update(extra or {})
    flags = {o.field: "/".join(o.flags) if len(o.field) < 3 else o.flags[-1] for o in options}
    flags.update(names or {})
    try:
        return cls(**values)
    except HrvError as exc:
        raise type(exc)(rename_fields(str(exc), flags)) from None


class _Formatter(logging.Formatter):
    def __init__(self, prog: str) -> None:
        super().__init__()
        self.prog = prog

    def format(self, record: logging.LogRecord) -> str:
        return f"{self.prog}: {record.levelname.lower()}: {record.getMessage()}"


__all__ = [
    "EXIT_INTERNAL",
    "Parser",
    "SettingOption",
    "add_flags",
    "add_parallel_options",
    "add_setting_options",
    "common_options",
    "int_in",
    "log_level",
    "number",
    "one_line",
    "parallel_from_args",
    "rename_fields",
    "run_main",
    "settings_from_args",
    "show_progress",
]
