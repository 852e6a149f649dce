"""The README is a short manual: its test command is the one CI runs, its links resolve, it stays short.

Everything else is on the documentation site (``docs/``); ``tests/test_docs_site.py`` builds it.
"""

import re
from pathlib import Path

ROOT = Path(__file__).parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")

#: Issue 31: the README is a short manual of at most 15 kB; the rest lives on the site.
MAX_README_BYTES = 15_000


def _bash_block() -> list[str]:
    match = re.search(r"```bash\n(.*?)```", README, flags=re.S)
    assert match is not None, "the README's first code block is its two commands"
    return [line for line in match.group(1).splitlines() if line and not line.startswith("#")]


def test_the_readme_test_command_is_the_one_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").strip().splitlines()[-1]
    demo, tests = _bash_block()
    assert tests == ci
    assert demo.endswith(".venv/bin/edofproj demo")


def test_the_readme_names_what_a_fresh_debian_lacks_for_its_first_command():
    """``python3 -m venv`` fails on a fresh Debian without the ``python3-venv`` package."""
    setup = README.split("```bash", 1)[0]
    assert "python3 -m venv" in _bash_block()[0] and "apt install python3-venv" in setup


def test_every_relative_link_of_the_readme_resolves():
    targets = re.findall(r"\]\(([^)\s]+)\)", README)
    relative = [t for t in targets if not re.match(r"[a-z]+:", t)]
    assert relative, "the README links to the documentation site's sources"
    missing = [t for t in relative if not (ROOT / t.split("#")[0]).exists()]
    assert not missing, missing


def test_the_site_includes_the_readme_results_table_it_names():
    """``docs/results.md`` includes the README's demo results between snippet markers (one source)."""
    results = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    name = re.search(r'--8<-- "README\.md:([\w-]+)"', results)
    assert name is not None
    section = re.search(rf"\[start:{name.group(1)}\] -->\n(.*?)<!-- --8<-- \[end:{name.group(1)}\]", README, re.S)
    assert section is not None and "| method |" in section.group(1)


def test_the_readme_is_a_short_manual():
    assert len(README.encode("utf-8")) <= MAX_README_BYTES
