"""CLI subcommands, one module each; see :mod:`edofproj.cli`. Shared option helpers live in
:mod:`edofproj.commands._common`."""
