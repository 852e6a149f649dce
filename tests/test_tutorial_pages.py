"""The tutorial pages against the code and against their scripts' recorded output (fast: no script runs
here; ``tests/test_tutorials.py`` runs them and compares the recorded output with a fresh run)."""

from __future__ import annotations

import re
from pathlib import Path

from edofproj.config import load_config
from edofproj.optics.spectra import Spectrum

TUTORIALS = Path(__file__).resolve().parents[1] / "docs" / "tutorials"


def prose(page: str) -> str:
    """The page without its fenced blocks (code and included output)."""
    return re.sub(r"^```.*?^```", "", page, flags=re.S | re.M)


def test_the_psf_page_shows_the_recorded_output_and_quotes_only_its_numbers():
    page = (TUTORIALS / "psf_designs.md").read_text(encoding="utf-8")
    output = (TUTORIALS / "output" / "psf_designs.txt").read_text(encoding="utf-8")
    assert '--8<-- "docs/tutorials/output/psf_designs.txt"' in page
    recorded = set(re.findall(r"\b0\.\d{3}\b", output))
    quoted = re.findall(r"\b0\.\d{3}\b", prose(page))
    assert len(quoted) >= 10
    assert [q for q in quoted if q not in recorded] == []


def test_the_psf_page_states_the_default_wavelength_sampling():
    """The page's '24 wavelengths from 420 to 650 nm' is what the default configuration samples."""
    wavelengths_nm = (Spectrum.from_config(load_config(None).spectrum).wavelengths_m * 1e9).round()
    page = " ".join((TUTORIALS / "psf_designs.md").read_text(encoding="utf-8").split())
    statement = f"{len(wavelengths_nm)} wavelengths from {wavelengths_nm[0]:.0f} to {wavelengths_nm[-1]:.0f} nm"
    assert statement in page


def test_every_recorded_output_is_included_by_its_page():
    recorded = sorted(p.stem for p in (TUTORIALS / "output").glob("*.txt"))
    assert recorded == ["export_for_lithography", "lens_doe", "procams_measure_psf", "psf_designs"]
    for name in recorded:
        page = (TUTORIALS / f"{name}.md").read_text(encoding="utf-8")
        assert f'```text\n--8<-- "docs/tutorials/output/{name}.txt"\n```' in page, name
