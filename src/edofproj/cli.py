"""The ``edofproj`` command.

Subcommands live in :mod:`edofproj.commands`, one module each, discovered automatically:
each module defines ``register(subparsers)`` that adds its parser and sets ``func``.

Every user error ends with one line ``edofproj: error: ...`` on stderr and exit code 2
(no traceback; set ``EDOFPROJ_DEBUG=1`` to see one).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
import warnings

from . import __version__, commands
from .errors import EdofprojError


class TerminalHelpFormatter(argparse.HelpFormatter):
    """argparse's help with the code spans of descriptions and option help (text between single or
    double backticks) shown as their content: no raw backticks in a terminal
    (:func:`edofproj.reporting.markdown.terminal_text`)."""

    def _format_text(self, text: str) -> str:
        from .reporting.markdown import terminal_text  # start-up: loaded only when help is shown

        return super()._format_text(terminal_text(text))

    def _expand_help(self, action: argparse.Action) -> str:
        from .reporting.markdown import terminal_text  # start-up: loaded only when help is shown

        return terminal_text(super()._expand_help(action))


class OneLineParser(argparse.ArgumentParser):
    """argparse with one-line errors and :class:`TerminalHelpFormatter` help."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", TerminalHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message):  # noqa: D401 - argparse API
        """Exit with code 2 after one line on stderr, ``edofproj: error: MESSAGE (see 'PROG --help')``,
        instead of argparse's usage block."""
        self.exit(2, f"edofproj: error: {message} (see '{self.prog} --help')\n")


def _one_line_warning(
    message: Warning | str, category: type[Warning], filename: str, lineno: int, line: str | None = None
) -> str:
    return f"edofproj: warning: {message}\n"


def build_parser() -> argparse.ArgumentParser:
    """The ``edofproj`` argument parser: ``--version`` and a required subcommand, one per public module of
    :mod:`edofproj.commands` (imported in name order, each adding its parser with ``register``)."""
    parser = OneLineParser(
        prog="edofproj", description="Extended-depth-of-field projectors with learned diffractive optics."
    )
    parser.add_argument("--version", action="version", version=f"edofproj {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


#: Options that name a file or folder a command writes: never inside a built-in run.
OUTPUT_OPTIONS = ("out", "preview")


def _refuse_outputs_in_builtin_runs(args: argparse.Namespace) -> argparse.Namespace:
    """``args`` unless an output option (:data:`OUTPUT_OPTIONS`) points into a built-in run's
    packaged directory (they belong to the installed package: nothing is written there)."""
    from .builtin_runs import is_builtin_run_dir

    for name in OUTPUT_OPTIONS:
        value = getattr(args, name, None)
        if isinstance(value, str) and value and is_builtin_run_dir(value):
            raise EdofprojError(
                f"--{name} '{value}' is inside a built-in run of the installed package: write elsewhere"
            )
    return args


def main(argv=None) -> int:
    """Run the command line ``argv`` (default ``sys.argv[1:]``) and return the exit code: the subcommand's
    return value (0 for None); 2 with one ``edofproj: error:`` line on stderr for an
    :class:`~edofproj.errors.EdofprojError` or a missing, directory or forbidden file or a full disk
    (re-raised when ``EDOFPROJ_DEBUG`` is set); 130 on Ctrl-C. Parse errors exit with code 2 (``SystemExit``), and
    warnings print as one line ``edofproj: warning: ...``."""
    warnings.formatwarning = _one_line_warning
    debug = bool(os.environ.get("EDOFPROJ_DEBUG"))
    try:
        # inside the try: a Ctrl-C while the subcommands load (the first second) ends as cleanly as later
        args = build_parser().parse_args(argv)
        args = _refuse_outputs_in_builtin_runs(args)
        result = args.func(args)
        return int(result or 0)
    except EdofprojError as exc:
        if debug:
            raise
        print(f"edofproj: error: {exc}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        if debug:
            raise
        print(f"edofproj: error: {exc.strerror or exc}: '{exc.filename}'", file=sys.stderr)
        return 2
    except OSError as exc:
        from .fileio import disk_full_error, is_disk_full

        if debug or not is_disk_full(exc):
            raise
        print(
            f"edofproj: error: {disk_full_error(exc.filename or os.getcwd(), 'the command stopped there')}",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        print("edofproj: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
