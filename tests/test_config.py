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


def test_a_config_on_a_base_is_the_base_with_its_keys_set(tmp_path):
    """``base: PRESET`` plus keys = the preset with those keys ``--set`` (the network switched first)."""
    from edofproj.config import to_dict

    file = tmp_path / "mine.yaml"
    file.write_text(
        "base: cpu\nname: mine\nnet:\n  widths: [8, 4]\n  architecture: multirate\ntrain:\n  steps: 7\n",
        encoding="utf-8",
    )
    expected = load_config("cpu", ["name=mine", "net.architecture=multirate", "net.widths=[8, 4]", "train.steps=7"])
    assert to_dict(load_config(str(file))) == to_dict(expected)
    cpu = load_config("cpu")
    assert load_config(str(file)).doe == cpu.doe and load_config(str(file)).net.correction_bound == 0.2


def test_a_base_is_found_beside_its_config_and_a_loop_is_refused(tmp_path):
    (tmp_path / "a.yaml").write_text("base: b.yaml\ntrain:\n  steps: 3\n", encoding="utf-8")
    (tmp_path / "b.yaml").write_text("base: cpu\ntrain:\n  batch_size: 2\n", encoding="utf-8")
    cfg = load_config(str(tmp_path / "a.yaml"))
    assert (cfg.train.steps, cfg.train.batch_size, cfg.name) == (3, 2, "cpu")
    (tmp_path / "b.yaml").write_text("base: a.yaml\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="loop"):
        load_config(str(tmp_path / "a.yaml"))


@pytest.mark.parametrize(
    "text, message",
    [
        ("base: cpu\ntrain:\n  stepz: 3\n", "train.stepz.*did you mean 'train.steps'"),
        ("base: cpu\nnet:\n  block_px: 2\n", "unet network has no such option"),
        ("base: cpu\ntrain: 3\n", "'train' must be a section"),
        ("base: 5\n", "base must name a preset"),
    ],
)
def test_a_bad_key_on_a_base_is_one_config_error(tmp_path, text, message):
    file = tmp_path / "bad.yaml"
    file.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=message):
        load_config(str(file))
