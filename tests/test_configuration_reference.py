"""The configuration reference in the repository (docs/reference/config.md) is what its generator writes
from the configuration dataclasses; unknown keys name the valid ones; help texts are whole (issue 57)."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import pytest

from edofproj.config import Config, ConfigError, load_config

ROOT = Path(__file__).resolve().parents[1]
GENERATOR = ROOT / "docs" / "site_scripts" / "config_reference.py"
PAGE = ROOT / "docs" / "reference" / "config.md"


def generator():
    spec = importlib.util.spec_from_file_location("config_reference", GENERATOR)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_reference_is_up_to_date():
    text = generator().config_reference() + "\n"
    assert PAGE.read_text(encoding="utf-8") == text, (
        "docs/reference/config.md is out of date: run python docs/site_scripts/config_reference.py"
    )


def test_the_reference_names_every_key_with_its_default():
    import dataclasses

    text = PAGE.read_text(encoding="utf-8")
    root = Config()
    for section in dataclasses.fields(root):
        value = getattr(root, section.name)
        if section.name == "net" or not dataclasses.is_dataclass(value):
            continue
        for field in dataclasses.fields(value):
            row = next(
                (line for line in text.splitlines() if line.startswith(f"| `{section.name}.{field.name}` |")), None
            )
            assert row is not None, f"{section.name}.{field.name} missing"
            assert repr(getattr(value, field.name)).replace("|", "\\|") in row
    assert "| `psf.depth_min_mm` | float | mm | `300.0` |" in text  # the unit from the key's name


def test_an_unknown_key_without_a_close_match_lists_the_valid_ones():
    with pytest.raises(ConfigError) as caught:
        load_config(None, ["optics.zzz=1"])
    message = str(caught.value)
    assert "valid: optics.aperture_mm, optics.focus_mm" in message and "docs/reference/config.md" in message
    with pytest.raises(ConfigError, match="did you mean 'optics.aperture_mm'"):
        load_config(None, ["optics.aperture=1"])
    with pytest.raises(ConfigError, match="valid: name, optics, spectrum"):
        load_config(None, ["qqq.zzz=1"])


def test_every_command_description_is_whole():
    """A description is whole sentences (``plot-psf --help`` ended mid-sentence)."""
    from edofproj.cli import build_parser

    def walk(parser, prefix=()):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield prefix + (name,), (sub.description or "").strip()
                    yield from walk(sub, prefix + (name,))

    cut = [
        " ".join(name) for name, text in walk(build_parser()) if text and not text.rstrip("`").endswith((".", ")", ":"))
    ]
    assert cut == []
