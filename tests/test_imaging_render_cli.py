"""``edofproj render``: outputs against independent computations, and one-line errors without output."""

import numpy as np
import pytest
import scipy.signal
import torch

from edofproj.cli import main
from edofproj.imaging.image_io import read_image, write_image
from edofproj.optics.psf_bank import PSFBank

H, W = 24, 40


@pytest.fixture
def image_file(tmp_path):
    image = torch.rand(3, H, W, generator=torch.Generator().manual_seed(0))
    path = tmp_path / "in.png"
    write_image(path, image, bits=16)
    return path


def save_bank(path, psf, depths_m):
    PSFBank(
        psf=torch.as_tensor(psf, dtype=torch.float32),
        depths_m=np.asarray(depths_m, float),
        pixel_pitch_m=np.asarray(depths_m, float) / 1200,
    ).save(path)
    return path


def impulse_bank(path, energies, depths_m, k=5):
    psf = np.zeros((len(depths_m), 3, k, k))
    psf[:, :, k // 2, k // 2] = np.asarray(energies)[:, None]
    return save_bank(path, psf, depths_m)


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_flat_render_equals_scipy_blur_plus_haze(tmp_path, image_file, capsys):
    y, x = np.mgrid[-4:5, -4:5]
    g = np.exp(-(x**2 + y**2) / 4.0)
    psf = np.stack([np.stack([g / g.sum() * e for e in (0.9, 0.8, 0.7)]), np.stack([g / g.sum()] * 3)])
    bank = save_bank(tmp_path / "bank.npz", psf, [0.4, 0.6])
    out = tmp_path / "out.png"
    code, stdout, _ = run(
        ["render", "--image", image_file, "--out", out, "--psf", bank, "--depth-index", 0, "--bits", 16], capsys
    )
    assert code == 0 and "400.0 mm" in stdout
    source = read_image(image_file).double().numpy()
    result = read_image(out).numpy()
    assert result.shape == (3, H, W)
    for c in range(3):
        expected = (
            scipy.signal.fftconvolve(source[c], psf[0, c], mode="same") + (1 - psf[0, c].sum()) * source[c].mean()
        )
        np.testing.assert_allclose(result[c], expected, atol=2e-5)


def test_impulse_psf_reproduces_the_image(tmp_path, image_file, capsys):
    bank = impulse_bank(tmp_path / "delta.npz", [1.0], [0.5])
    out = tmp_path / "same.png"
    assert run(["render", "--image", image_file, "--out", out, "--psf", bank, "--bits", 16], capsys)[0] == 0
    np.testing.assert_allclose(read_image(out).numpy(), read_image(image_file).numpy(), atol=1e-6)


def test_tilted_plane_blends_the_bank_layers_in_inverse_depth(tmp_path, capsys):
    grey = tmp_path / "grey.png"
    write_image(grey, torch.full((3, H, W), 0.6), bits=16)
    depths, energies = np.array([0.4, 0.5, 0.7]), np.array([0.5, 1.0, 0.7])
    bank = impulse_bank(tmp_path / "b.npz", energies, depths)
    out = tmp_path / "tilt.png"
    code, stdout, _ = run(
        [
            "render",
            "--image",
            grey,
            "--out",
            out,
            "--psf",
            bank,
            "--tilt-deg",
            20,
            "--near-mm",
            400,
            "--far-mm",
            700,
            "--bits",
            16,
        ],
        capsys,
    )
    assert code == 0
    # independent expectation: column c sees 1/z = 1/near + c/(W-1) (1/far - 1/near); a pixel keeps
    # 0.6 * e(z) with e interpolated linearly in 1/z, and the lost light (1 - e) * 0.6 returns as uniform haze
    inv_z = 1 / 0.4 + np.arange(W) / (W - 1) * (1 / 0.7 - 1 / 0.4)
    kept = np.interp(-inv_z, -1 / depths, energies)
    expected = 0.6 * kept + 0.6 * np.mean(1 - kept)
    np.testing.assert_allclose(read_image(out)[0].numpy(), np.broadcast_to(expected, (H, W)), atol=2e-5)


def test_doe_lens_in_focus_is_nearly_sharp_and_defocus_blurs(tmp_path, image_file, capsys):
    common = ["--set", "psf.pupil_samples=256", "--set", "psf.window=15", "--set", "spectrum.wavelength_step_nm=100"]
    sharp, blurred = tmp_path / "sharp.png", tmp_path / "blur.png"
    assert (
        run(["render", "--image", image_file, "--out", sharp, "--doe", "lens", "--depth-mm", 500, *common], capsys)[0]
        == 0
    )
    assert (
        run(["render", "--image", image_file, "--out", blurred, "--doe", "lens", "--depth-mm", 420, *common], capsys)[0]
        == 0
    )
    source = read_image(image_file)
    err_sharp = (read_image(sharp) - source)[:, 7:-7, 7:-7].abs().mean()
    err_blur = (read_image(blurred) - source)[:, 7:-7, 7:-7].abs().mean()
    assert read_image(sharp).shape == source.shape
    assert err_sharp < 0.05 < err_blur


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--depth-index", 3], "--depth-index 3 is out of range"),
        ([], "holds 2 depths; choose one with --depth-index"),
        (["--depth-map", "WRONG_SHAPE"], "has shape (5, 5), expected the image's (H, W) = (24, 40)"),
        (["--depth-map", "NEGATIVE"], "must be screen depths in [1, 100000] mm, got -1"),
        (["--depth-map", "FAR"], "must be screen depths in [1, 100000] mm, got 1e+09: a depth beyond 100 m blurs"),
        (["--depth-map", "OUTSIDE"], "spans 300.0-300.0 mm but the PSFs cover 400.0-600.0 mm"),
        (["--depth-mm", 500], "--depth-mm goes with --doe"),
        (["--far-mm", 500], "--far-mm needs --tilt-deg"),
        (["--tilt-deg", 10, "--near-mm", -5], "--near-mm must be screen depths in [1, 100000] mm, got -5"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_output(tmp_path, image_file, capsys, extra, message):
    bank = impulse_bank(tmp_path / "b.npz", [1.0, 1.0], [0.4, 0.6])
    maps = {
        "WRONG_SHAPE": np.full((5, 5), 500.0),
        "NEGATIVE": np.full((H, W), -1.0),
        "OUTSIDE": np.full((H, W), 300.0),
        "FAR": np.full((H, W), 1e9),
    }
    for name, array in maps.items():
        np.save(tmp_path / f"{name}.npy", array)
    extra = [str(tmp_path / f"{a}.npy") if a in maps else a for a in extra]
    out = tmp_path / "out.png"
    code, _, err = run(["render", "--image", image_file, "--out", out, "--psf", bank, *extra], capsys)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("edofproj: error:") and message in err
    assert not out.exists()


@pytest.mark.parametrize("content, message", [(None, "does not exist"), (b"garbage", "cannot read image")])
def test_missing_or_corrupt_image(tmp_path, capsys, content, message):
    path = tmp_path / "img.png"
    if content is not None:
        path.write_bytes(content)
    bank = impulse_bank(tmp_path / "b.npz", [1.0], [0.5])
    code, _, err = run(["render", "--image", path, "--out", tmp_path / "o.png", "--psf", bank], capsys)
    assert code == 2 and message in err and err.count("\n") == 1
    assert not (tmp_path / "o.png").exists()


def test_doe_without_depth_is_refused(tmp_path, image_file, capsys):
    code, _, err = run(["render", "--image", image_file, "--out", tmp_path / "o.png", "--doe", "lens"], capsys)
    assert code == 2 and "--doe needs the screen depth" in err
