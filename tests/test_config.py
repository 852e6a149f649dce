import pytest

from edofproj.config import ConfigError, load_config


def test_unknown_key_suggests_the_right_one(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("optics:\n  apperture_mm: 5\n")
    with pytest.raises(ConfigError, match="did you mean 'optics.aperture_mm'"):
        load_config(str(f))


def test_override_and_range_checks():
    cfg = load_config(None, ["optics.aperture_mm=5", "psf.window=21"])
    assert cfg.optics.aperture_mm == 5.0 and cfg.psf.window == 21
    with pytest.raises(ConfigError, match="odd"):
        load_config(None, ["psf.window=20"])
    with pytest.raises(ConfigError, match="350-1000 nm"):
        load_config(None, ["spectrum.wavelength_min_nm=200"])
    with pytest.raises(ConfigError, match="did you mean 'psf.window'"):
        load_config(None, ["psf.windw=5"])
