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


@pytest.mark.parametrize(
    "override, message",
    [
        ("spectrum.peaks_nm=[red,530,460]", r"spectrum\.peaks_nm\[0\]='red' must be a number"),
        ("evaluation.depths_mm=[a,b]", r"evaluation\.depths_mm\[0\]='a' must be a number"),
        ("evaluation.image_size=[64,6.5]", r"evaluation\.image_size\[1\]=6\.5 must be an integer"),
        ("net.widths=[8,true]", r"net\.widths\[1\]=True must be an integer"),
    ],
)
def test_typed_list_element_of_the_wrong_type_is_one_config_error(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(None, [override])


def test_typed_list_elements_are_converted_to_their_type():
    cfg = load_config(None, ["spectrum.peaks_nm=[630, 530, 460]", "evaluation.image_size=[64.0, 48]"])
    assert cfg.spectrum.peaks_nm == [630.0, 530.0, 460.0] and all(type(p) is float for p in cfg.spectrum.peaks_nm)
    assert cfg.evaluation.image_size == [64, 48] and all(type(n) is int for n in cfg.evaluation.image_size)


def test_cli_typed_list_of_the_wrong_type_is_one_line(tmp_path, capsys):
    """The issue's two commands: a one-line error and exit 2, nothing written."""
    from edofproj.cli import main

    out = tmp_path / "o.npz"
    argv = ["psf", "--doe", "lens", "--depth-mm", "300", "--set", "spectrum.peaks_nm=[red,530,460]", "--out", str(out)]
    assert main(argv) == 2
    assert "spectrum.peaks_nm[0]='red' must be a number" in capsys.readouterr().err and not out.exists()
    run = tmp_path / "t"
    argv = ["train", "--config", "cpu", "--steps", "2", "--set", "evaluation.depths_mm=[a,b]", "--out", str(run)]
    assert main(argv) == 2
    assert "evaluation.depths_mm[0]='a' must be a number" in capsys.readouterr().err and not run.exists()
