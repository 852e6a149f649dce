"""The tests' own output stays inside pytest's capture: a test that wants to show a measured figure
prints it (shown with ``-s`` or ``-rP``) instead of writing past the capture into pytest's progress line."""

from __future__ import annotations

import re
from pathlib import Path

TESTS = Path(__file__).parent


def test_no_test_writes_past_the_capture():
    pattern = re.compile(r"\b(capsys|capfd|capsysbinary|capfdbinary)\.disabled\(|sys\.__std(out|err)__")
    offenders = [
        f"{path.name}:{number}"
        for path in sorted(TESTS.glob("*.py"))
        if path.name != Path(__file__).name
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert not offenders, offenders
