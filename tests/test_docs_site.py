"""The documentation site builds in strict mode (no warnings, no broken links) and holds every command."""

import os
import subprocess
import sys
from html.parser import HTMLParser
from urllib.parse import unquote, urlsplit

import pytest

from edofproj.cli import build_parser
from edofproj.net_config import NET_CONFIGS, option_names

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
    # the net section: one table per architecture, from the options each declares (edofproj.net_config)
    for name, cls in NET_CONFIGS.items():
        assert f"net.architecture: {name}" in text, name
        for key in option_names(cls):
            assert f"<code>net.{key}</code>" in text, key
    assert "an integer &gt;= 2, or 0 (off)" in text  # net.prefilter_bins' declared values


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


def test_cli_reference_is_laid_out_as_tables(site):
    """Each command: its usage and a table of its arguments, not the raw ``--help`` text (issue 29)."""
    text = (site / "reference/cli/index.html").read_text(encoding="utf-8")
    assert "show this help message and exit" not in text  # argparse's own help dump is gone
    assert text.count("<th>argument</th>") >= 20 and "<th>default</th>" in text
    assert "<code>--projector-out PROJECTOR_OUT</code>" in text  # an argument in its table cell


def test_code_blocks_wrap_and_the_front_page_shows_what_the_project_does(site):
    """Code and output blocks wrap instead of being cut off at the right; the front page has pictures."""
    page = (site / "index.html").read_text(encoding="utf-8")
    assert "stylesheets/code.css" in page
    css = (site / "stylesheets" / "code.css").read_text(encoding="utf-8")
    assert "white-space: pre-wrap" in css
    assert 'src="figures/demo_psf_lens_vs_doe.jpg"' in page and 'src="figures/demo_comparison.jpg"' in page
