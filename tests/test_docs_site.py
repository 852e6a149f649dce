"""The documentation site builds in strict mode (no warnings, no broken links) and holds every command."""

import os
import subprocess
import sys
from html.parser import HTMLParser
from urllib.parse import unquote, urlsplit

import pytest

from edofproj.cli import build_parser

pytestmark = pytest.mark.slow  # builds the whole site (about 30 s)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    pytest.importorskip("mkdocs", reason="the site needs the [docs] extra")
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, DISABLE_MKDOCS_2_WARNING="true", NO_MKDOCS_2_WARNING="1")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return out


def test_site_builds_strict_with_every_reference_page(site):
    for page in ("index.html", "reference/cli/index.html", "reference/config/index.html", "results/index.html"):
        assert (site / page).is_file(), page


def test_cli_reference_lists_every_command(site):
    text = (site / "reference/cli/index.html").read_text(encoding="utf-8")
    parser = build_parser()
    commands = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction").choices
    for name in commands:
        assert f"edofproj {name}" in text, name


def test_config_reference_states_the_validators_rules(site):
    text = (site / "reference/config/index.html").read_text(encoding="utf-8")
    assert "psf.window=-1 must be odd and &gt;= 3" in text


class _Links(HTMLParser):
    """Collects the ``href``/``src`` targets of a page and its element ids."""

    def __init__(self) -> None:
        super().__init__()
        self.targets: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if name in ("href", "src") and value:
                self.targets.append(value)
            if name == "id" and value:
                self.ids.add(value)


def test_every_internal_link_of_the_built_site_resolves(site):
    """Independent of MkDocs' own checks: every relative link and image of every built page points to a
    file of the site (absolute paths from the site's root, as in the 404 page), and every same-page anchor
    to an element id."""
    broken = []
    pages = sorted(site.rglob("*.html"))
    assert len(pages) > 40
    for page in pages:
        parser = _Links()
        parser.feed(page.read_text(encoding="utf-8"))
        for target in parser.targets:
            parts = urlsplit(target)
            if parts.scheme or parts.netloc or target.startswith(("mailto:", "data:", "javascript:")):
                continue
            if not parts.path:
                if parts.fragment and parts.fragment not in parser.ids:
                    broken.append(f"{page.relative_to(site)} -> #{parts.fragment}")
                continue
            path = unquote(parts.path)
            resolved = (site / path.lstrip("/") if path.startswith("/") else page.parent / path).resolve()
            if resolved.is_dir():
                resolved = resolved / "index.html"
            if not resolved.exists():
                broken.append(f"{page.relative_to(site)} -> {target}")
    assert not broken, broken[:20]
