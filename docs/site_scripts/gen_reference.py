"""Generate the site's reference pages at build time (run by the mkdocs-gen-files plugin).

* ``reference/cli.md``: every command's description, usage and a table of its arguments (help,
  choices, default), read from the real argument parsers;
* ``reference/config.md``: every configuration key with its type, unit, default and the rule its
  validation enforces (the rule is the message the validator gives for an invalid value, so the page
  cannot drift from the code); the ``net`` section one table per network architecture, read from the
  options each architecture declares (:mod:`edofproj.net_config`: meaning, unit, allowed values --
  the declarations the validator checks);
* ``reference/api/<package>.md``: the API reference from the docstrings (mkdocstrings);
* no other page: the rest of the site, results and performance included, is written in ``docs/``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import pkgutil
import re
from pathlib import Path

import mkdocs_gen_files

import edofproj
from edofproj.cli import build_parser
from edofproj.config import Config, ConfigError
from edofproj.net_config import DEFAULT_ARCHITECTURE, NET_CONFIGS, NetConfig, declared_options

ROOT = Path(__file__).resolve().parents[2]

# --------------------------------------------------------------------------- CLI


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _option_name(action: argparse.Action, formatter) -> str:
    """``--out DIR`` / ``-h, --help`` / ``RUN``: how the option is written on a command line."""
    if not action.option_strings:
        return formatter._metavar_formatter(action, action.dest)(1)[0]
    if action.nargs == 0:
        return ", ".join(action.option_strings)
    metavar = formatter._format_args(action, action.dest.upper())
    return ", ".join(f"{flag} {metavar}" for flag in action.option_strings)


def _option_default(action: argparse.Action) -> str:
    default = action.default
    if action.nargs == 0 or default in (None, argparse.SUPPRESS, [], ""):
        return ""
    return f"`{default}`"


def _markdown_cell(text: str) -> str:
    text = re.sub(r"``([^`]+)``", r"`\1`", " ".join(str(text).split()))  # reStructuredText literals
    return text.replace("|", "\\|")


def _command_sections(parser: argparse.ArgumentParser, name: str, level: int) -> list[str]:
    """One command: its description, its usage line and a table of its arguments (what ``--help`` says,
    laid out for a page), then its subcommands."""
    formatter = argparse.HelpFormatter(parser.prog)  # the help as written (Markdown), not its terminal rendering
    lines = [f"{'#' * level} `{name}`", ""]
    if parser.description:
        lines += [_markdown_cell(parser.description), ""]
    lines += ["```text", parser.format_usage().strip(), "```", ""]
    rows = []
    subcommands = _subcommands(parser)
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or action.help == argparse.SUPPRESS:
            continue
        text = formatter._expand_help(action) if action.help else ""
        if action.choices and not isinstance(action, argparse._SubParsersAction):
            text = (text + f" (one of: {', '.join(f'`{c}`' for c in action.choices)})").strip()
        rows.append(f"| `{_option_name(action, formatter)}` | {_markdown_cell(text)} | {_option_default(action)} |")
    if rows:
        lines += ["| argument | meaning | default |", "| --- | --- | --- |", *rows, ""]
    if subcommands:
        helps = {
            choice.dest: choice.help
            for action in parser._actions
            if isinstance(action, argparse._SubParsersAction)
            for choice in action._choices_actions
        }
        lines += ["| subcommand | what it does |", "| --- | --- |"]
        lines += [
            f"| [`{sub}`](#{_anchor(f'{name} {sub}')}) | {_markdown_cell(helps.get(sub, ''))} |" for sub in subcommands
        ]
        lines.append("")
    for sub_name, sub in subcommands.items():
        lines += _command_sections(sub, f"{name} {sub_name}", level + 1)
    return lines


def _anchor(title: str) -> str:
    """The id MkDocs' toc extension gives a heading ``# `title` ``."""
    return re.sub(r"[^\w\- ]", "", title.lower()).strip().replace(" ", "-")


def cli_reference() -> str:
    os.environ["COLUMNS"] = "100"  # argparse wraps at the terminal width: fix it for a stable page
    parser = build_parser()
    lines = [
        "# Command-line reference",
        "",
        "Generated from the command's own argument parsers when the site is built. Every command",
        "fails on bad input with one line `edofproj: error: ...` and exit code 2.",
        "",
    ]
    commands = _subcommands(parser)
    helps = {
        choice.dest: choice.help
        for action in parser._actions
        if isinstance(action, argparse._SubParsersAction)
        for choice in action._choices_actions
    }
    lines += ["| command | what it does |", "| --- | --- |"]
    lines += [f"| [`{n}`](#{_anchor(f'edofproj {n}')}) | {_markdown_cell(helps.get(n, ''))} |" for n in commands]
    lines.append("")
    for name, sub in commands.items():
        lines += _command_sections(sub, f"edofproj {name}", 2)
    return "\n".join(lines)


# --------------------------------------------------------------------------- configuration

UNITS = {
    "_mm": "mm",
    "_nm": "nm",
    "_um": "µm",
    "_m": "m",
    "_deg": "degrees",
    "_px": "pixels",
    "_s": "s",
    "_min": "min",
    "_ms": "ms",
}


def _unit(key: str) -> str:
    for suffix, unit in UNITS.items():
        if key.endswith(suffix):
            return unit
    return ""


def _default(field: dataclasses.Field):
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None


def _invalid_values(value) -> list:
    if isinstance(value, bool):
        return []
    if isinstance(value, (int, float)):
        return [-1, 0, 0.5, 1e12, math.nan]
    if isinstance(value, str) or value is None:
        return ["?not-a-choice?"]
    if isinstance(value, list):
        return [[], [-1.0], [math.nan], ["?"]]
    return []


def _rule(section_name: str, key: str, default) -> str:
    """The validator's message for the first invalid value tried, or '' when every value is accepted."""
    for bad in _invalid_values(default):
        cfg = Config()
        setattr(getattr(cfg, section_name), key, bad)
        try:
            cfg.validate()
        except ConfigError as exc:
            return str(exc)
        except (TypeError, ValueError):
            continue
    return ""


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _plain_docstring(text: str) -> str:
    """A docstring as one Markdown paragraph, its Sphinx roles as code (``:class:`~a.B``` as ``B``)."""
    text = re.sub(r":\w+:`~[^`]*?(\w+)`", r"``\1``", text)
    text = re.sub(r":\w+:`([^`]+)`", r"``\1``", text)
    return re.sub(r"``([^`]+)``", r"`\1`", " ".join(text.split()))  # a paragraph, not a table cell: no | escaped


def net_reference() -> list[str]:
    """The ``net`` section: ``net.architecture``, then one table per architecture of the options its
    configuration class declares (:func:`edofproj.net_config.option`)."""
    names = ", ".join(f"`{name}`" for name in NET_CONFIGS)
    lines = [
        "## `net`",
        "",
        f"The compensation network. `net.architecture` names it (one of {names}; default "
        f"`{DEFAULT_ARCHITECTURE}`), and the rest of the section holds that network's options and no others:",
        "each architecture declares its own, below (`edofproj.net_config`). `--set net.architecture=NAME`",
        "switches the network, keeping the options the two share; `--set net.KEY=VALUE` for a key the",
        "chosen network does not have is an error. A `net` section of the single flat format of older",
        "files (a saved run's `config.yaml`) is converted when it is read, with a one-line note.",
        "",
        _plain_docstring(NetConfig.__doc__ or "").replace(
            "The options every architecture has.",
            "Every architecture has `leaky_slope`, `linear_nsr` and `linear_radius`.",
        ),
        "",
    ]
    for name, cls in NET_CONFIGS.items():
        doc = _plain_docstring(cls.__doc__ or "")
        lines += [
            f"### `net.architecture: {name}`",
            "",
            doc,
            "",
            "| key | type | unit | default | allowed values | meaning |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for field, spec in declared_options(cls):
            annotation = field.type if isinstance(field.type, str) else getattr(field.type, "__name__", field.type)
            lines.append(
                f"| `net.{field.name}` | {_cell(annotation)} | {spec.unit} | `{_cell(repr(_default(field)))}` "
                f"| {_cell(spec.rule())} | {_markdown_cell(spec.meaning)} |"
            )
        lines.append("")
    return lines


def config_reference() -> str:
    lines = [
        "# Configuration reference",
        "",
        "Generated from `edofproj.config.Config` when the site is built. A configuration is read from",
        "YAML (`--config cpu|cpu-realtime|paper|realtime|FILE.yaml`); `--set section.key=value` overrides one key.",
        "The unit follows from the key's name. *Rule* is what the validator says when it is given an",
        "invalid value (one of -1, 0, 0.5, 1e12, NaN, an unknown name or an empty list, whichever it",
        "refuses first); an empty rule means no value of the right type is refused.",
        "",
    ]
    root = Config()
    for section in dataclasses.fields(root):
        value = getattr(root, section.name)
        if section.name == "net":
            lines += net_reference()
            continue
        if not dataclasses.is_dataclass(value):
            lines += [f"## `{section.name}`", "", f"Default `{value!r}`.", ""]
            continue
        doc = (type(value).__doc__ or "").strip()
        lines += [
            f"## `{section.name}`",
            "",
            doc,
            "",
            "| key | type | unit | default | rule |",
            "| --- | --- | --- | --- | --- |",
        ]
        for field in dataclasses.fields(value):
            default = _default(field)
            annotation = field.type if isinstance(field.type, str) else getattr(field.type, "__name__", field.type)
            rule = _rule(section.name, field.name, default)
            lines.append(
                f"| `{section.name}.{field.name}` | {_cell(annotation)} | {_unit(field.name)} | `{_cell(repr(default))}` "
                f"| {_cell(rule)} |"
            )
        lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------- API


def api_pages() -> dict[str, str]:
    """One page per top-level module or package of ``edofproj`` (commands excluded: see the CLI page)."""
    pages = {}
    for info in sorted(pkgutil.iter_modules(edofproj.__path__), key=lambda m: m.name):
        if info.name in ("commands", "cli", "__main__") or info.name.startswith("_"):
            continue
        name = f"edofproj.{info.name}"
        body = [f"# `{name}`", ""]
        if info.ispkg:
            package = __import__(name, fromlist=["_"])
            body += [f"::: {name}", "    options:", "      members: false", ""]
            for sub in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
                if sub.name.startswith("_"):
                    continue
                body += [
                    f"## `{name}.{sub.name}`",
                    "",
                    f"::: {name}.{sub.name}",
                    "    options:",
                    "      heading_level: 3",
                    "",
                ]
        else:
            body += [f"::: {name}", ""]
        pages[f"reference/api/{info.name}.md"] = "\n".join(body)
    return pages


def main() -> None:
    pages = {"reference/cli.md": cli_reference(), "reference/config.md": config_reference()}
    pages.update(api_pages())
    for path, text in pages.items():
        with mkdocs_gen_files.open(path, "w") as handle:
            handle.write(text)


main()
