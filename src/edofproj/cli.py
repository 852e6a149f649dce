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
import re
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
        # a word that starts like a negative number (-5x10, -1e-3, -300:800) is a value, not an unknown
        # option (no option starts with a digit): the command's own check then says what is wrong with it
        self._negative_number_matcher = re.compile(r"^-\.?\d")

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


#: Options (their ``dest``) that name a file or folder a command writes, in any command but those of
#: :data:`READ_OPTIONS`: never inside a built-in run, never over a path another option names, never in a
#: run's checkpoints (:func:`_refuse_outputs_over_arguments`; tests/test_output_options.py finds every
#: output option of every command here).
OUTPUT_OPTIONS = ("out", "preview", "figure", "plot", "csv", "patch_psfs", "projector_out", "depth_out", "dir")

#: ``(command, dest)`` of the options named like an output that a command reads (``estimate-psf``
#: writes ``--patch-psfs``, ``finetune`` reads them).
READ_OPTIONS = {("finetune", "patch_psfs")}

#: Options (their ``dest``) whose value names a file written when it starts with the prefix: a
#: device spec (``--display file:shown.png`` writes every frame there).
OUTPUT_SPECS = {"display": "file:"}


def is_output_option(command: str, dest: str) -> bool:
    """Whether option ``dest`` of ``command`` (``"procams psf-map"``) names what it writes."""
    return dest in OUTPUT_OPTIONS and (command, dest) not in READ_OPTIONS


def command_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[str, argparse.ArgumentParser]:
    """The (sub)command ``args`` was parsed for: its name (``"procams psf-map"``) and its innermost parser."""
    names: list[str] = []
    while True:
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        name = getattr(args, sub.dest, None) if sub is not None else None
        if sub is None or name not in sub.choices:
            return " ".join(names), parser
        names.append(name)
        parser = sub.choices[name]


def _refuse_outputs_over_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Every output option (:func:`is_output_option`) through the output-over-input rule before the
    command runs: it is no path another option names, no other output, and not inside a run's
    ``checkpoints/`` (:mod:`edofproj.outputs`)."""
    from .outputs import refuse_output_in_checkpoints, refuse_outputs_over_arguments

    command, leaf = command_parser(parser, args)
    outputs: list[tuple[str, str | os.PathLike]] = []
    arguments: list[tuple[str, str | os.PathLike]] = []
    for action in leaf._actions:
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)):
            continue
        value = getattr(args, action.dest, None)
        name = action.option_strings[0] if action.option_strings else str(action.metavar or action.dest.upper())
        for item in value if isinstance(value, list) else [value]:
            if not (isinstance(item, (str, os.PathLike)) and os.fspath(item)):
                continue
            prefix = OUTPUT_SPECS.get(action.dest)
            if prefix is not None and os.fspath(item).startswith(prefix):
                outputs.append((f"{name} {prefix}", os.fspath(item)[len(prefix) :]))
            else:
                (outputs if is_output_option(command, action.dest) else arguments).append((name, item))
    refuse_outputs_over_arguments(outputs, arguments)
    for option, path in outputs:
        refuse_output_in_checkpoints(path, option)


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
        parser = build_parser()
        args = parser.parse_args(argv)
        args = _refuse_outputs_in_builtin_runs(args)
        _refuse_outputs_over_arguments(parser, args)
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
