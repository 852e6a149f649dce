"""The configuration reference, ``docs/reference/config.md``, generated from the configuration dataclasses.

    python docs/site_scripts/config_reference.py           # rewrite docs/reference/config.md
    python docs/site_scripts/config_reference.py --check   # exit 1 when the page is out of date

Every configuration key with its type, unit, default and the rule its validation enforces (the rule is
the message the validator gives for an invalid value, so the page cannot drift from the code); the
``net`` section one table per network architecture, read from the options each architecture declares
(:mod:`edofproj.net_config`: meaning, unit, allowed values -- the declarations the validator checks).
The page is committed, so that a user with the repository finds it; ``tests/test_configuration_reference.py``
fails when it is not what this script writes. The site's build (``gen_reference.py``) reuses
:func:`markdown_cell`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import sys
from pathlib import Path

from edofproj.config import Config, ConfigError
from edofproj.net_config import DEFAULT_ARCHITECTURE, NET_CONFIGS, NetConfig, declared_options

PAGE = Path(__file__).resolve().parents[1] / "reference" / "config.md"


def markdown_cell(text: str) -> str:
    text = re.sub(r"``([^`]+)``", r"`\1`", " ".join(str(text).split()))  # reStructuredText literals
    return text.replace("|", "\\|")


UNITS = {
    "_pct": "%",
    "_waves": "waves",
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
                f"| {_cell(spec.rule())} | {markdown_cell(spec.meaning)} |"
            )
        lines.append("")
    return lines


def config_reference() -> str:
    lines = [
        "# Configuration reference",
        "",
        "Generated from `edofproj.config.Config` by `docs/site_scripts/config_reference.py` (a test keeps it",
        "up to date). A configuration is read from",
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
        if section.name == "refit_net":
            lines += [
                "## `refit_net`",
                "",
                "Absent by default: the refit phase (`train.refit_steps`) trains the `net` section's network. A",
                "`refit_net` section names another network for that phase, the one the run ends with and ships,",
                "with the same keys as `net` (an architecture and its options, the tables above). "
                "`--set refit_net.KEY=VALUE` starts it as a copy of `net`, so that",
                "`--set refit_net.architecture=multirate` keeps the options the two networks share.",
                "",
            ]
            continue
        if not dataclasses.is_dataclass(value):
            lines += [f"## `{section.name}`", "", f"Default `{value!r}`.", ""]
            continue
        paragraphs = re.split(r"\n\s*\n", (type(value).__doc__ or "").strip())
        lines += [f"## `{section.name}`", ""]
        for paragraph in paragraphs:  # one Markdown paragraph each (an indented docstring line is not code)
            lines += [_plain_docstring(paragraph), ""]
        lines += [
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="write (or --check) docs/reference/config.md")
    parser.add_argument("--check", action="store_true", help="exit 1 when the page is not what this script writes")
    args = parser.parse_args(argv)
    text = config_reference() + "\n"
    if args.check:
        current = PAGE.read_text(encoding="utf-8") if PAGE.is_file() else ""
        if current != text:
            print(f"{PAGE} is out of date: run python docs/site_scripts/config_reference.py", file=sys.stderr)
            return 1
        return 0
    PAGE.parent.mkdir(parents=True, exist_ok=True)
    PAGE.write_text(text, encoding="utf-8")
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
