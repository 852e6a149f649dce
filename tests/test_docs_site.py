"""The documentation site builds in strict mode (no warnings, no broken links) and holds every command."""

import os
import shutil
import subprocess
import sys

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


BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def test_index_renders_in_a_headless_browser(site, tmp_path):
    browser = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
    if browser is None:
        pytest.skip("no headless Chromium or Chrome installed")
    result = subprocess.run(
        [browser, "--headless", "--disable-gpu", "--no-sandbox", "--dump-dom", (site / "index.html").as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Extended-depth-of-field projectors" in result.stdout
