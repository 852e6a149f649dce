"""Image formation on a coloured, textured surface: c = s ⊙ A(L) + a, flat, tilted and scene screens."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging import render_depth_map, write_image
from edofproj.imaging.projection import project
from edofproj.imaging.screens import tilted_plane_depth_map
from edofproj.imaging.surfaces import Surface, check_ambient, check_reflectance, on_surface, read_reflectance
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.scenes import Scene, cast_scene, render_scene

H, W = 24, 32


def gaussian_psf(sigma: float, size: int = 11, kept: float = 1.0) -> torch.Tensor:
    r2 = (np.arange(size) - size // 2)[:, None] ** 2 + (np.arange(size) - size // 2)[None, :] ** 2
    kernel = np.exp(-r2 / (2 * sigma**2))
    return torch.as_tensor(kernel / kernel.sum() * kept, dtype=torch.float64)[None, None].repeat(1, 3, 1, 1)


def random_texture(seed: int = 0, low: float = 0.1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return low + (1 - low) * torch.rand(1, 3, H, W, generator=g, dtype=torch.float64)


def test_uniform_reflectance_scales_todays_rendering_and_ambient_adds():
    """Closed form on a flat screen: s = rho gives rho x (blur + haze) computed independently by scipy."""
    psf = gaussian_psf(1.5, kept=0.9)
    image = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    rho, ambient = np.array([0.3, 0.6, 0.9]), np.array([0.05, 0.0, 0.1])
    surface = Surface.uniform(rho, (H, W), ambient=ambient).to(dtype=torch.float64)
    seen = on_surface(lambda x: project(x, psf), surface)(image)[0].numpy()
    for c in range(3):
        blurred = scipy.signal.fftconvolve(image[0, c].numpy(), psf[0, c].numpy(), mode="same")
        today = blurred + (1 - psf[0, c].sum().item()) * image[0, c].mean().item()
        np.testing.assert_allclose(seen[c], rho[c] * today + ambient[c], atol=1e-6)


def test_ambient_is_seen_whatever_the_projector_emits():
    psf = gaussian_psf(2.0)
    texture = random_texture(2)
    ambient = 0.2 * random_texture(3)
    surface = Surface.from_arrays(texture, ambient)
    forward = on_surface(lambda x: project(x, psf), surface)
    black = torch.zeros(1, 3, H, W, dtype=torch.float64)
    np.testing.assert_allclose(forward(black).numpy(), ambient.numpy(), atol=1e-7)
    image = torch.rand(1, 3, H, W, dtype=torch.float64)
    without = on_surface(lambda x: project(x, psf), Surface.from_arrays(texture, 0.0))(image)
    np.testing.assert_allclose((forward(image) - without).numpy(), ambient.numpy(), atol=1e-6)


def test_the_texture_stays_sharp_while_the_projection_blurs():
    """A uniform white projection through a wide PSF shows the texture itself, unblurred, away from
    the border: the surface multiplies after the blur (blurring s would smear the texture)."""
    psf = gaussian_psf(3.0, size=15)
    texture = random_texture(4)
    seen = on_surface(lambda x: project(x, psf), Surface.from_arrays(texture))(torch.ones(1, 3, H, W))
    m = 7
    np.testing.assert_allclose(seen[..., m:-m, m:-m].numpy(), texture[..., m:-m, m:-m].numpy(), atol=1e-6)
    # and an impulse PSF gives s ⊙ L + a exactly, everywhere
    impulse = torch.zeros(1, 3, 3, 3)
    impulse[..., 1, 1] = 1
    image = torch.rand(1, 3, H, W)
    surface = Surface.from_arrays(texture, 0.05)
    expected = texture.float() * image + 0.05
    np.testing.assert_allclose(on_surface(lambda x: project(x, impulse), surface)(image).numpy(), expected, atol=1e-6)


def test_tilted_screen_on_a_texture():
    """Tilted plane (depth layers): uniform rho gives rho x today's rendering; a uniform white image
    shows the texture where the local PSFs keep all the light (away from the border)."""
    depth = tilted_plane_depth_map(H, W, 20.0, 0.4, 0.7)
    psfs = torch.cat([gaussian_psf(s) for s in (0.8, 1.6, 2.4)])
    layers = [0.4, 0.52, 0.7]
    image = torch.rand(2, 3, H, W, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    today = render_depth_map(image, depth, psfs, layers=layers)
    surface = Surface.uniform(0.4, (H, W), ambient=0.1).to(dtype=torch.float64)
    np.testing.assert_allclose(surface.appearance(today).numpy(), (0.4 * today + 0.1).numpy(), atol=1e-12)
    texture = random_texture(6)
    # two layers: each hat weight is affine in the column (1/z is), a symmetric PSF of unit sum keeps
    # an affine ramp, so the layers add up to exactly 1 away from the border
    seen = Surface.from_arrays(texture).appearance(
        render_depth_map(torch.ones(1, 3, H, W, dtype=torch.float64), depth, psfs[[0, 2]], layers=[0.4, 0.7])
    )
    m = 6
    np.testing.assert_allclose(seen[..., m:-m, m:-m].numpy(), texture[..., m:-m, m:-m].numpy(), atol=1e-6)


def test_scene_on_a_texture_is_dark_where_nothing_is_hit():
    geometry = ProjectorGeometry(throw_ratio=1.5, width_px=W, height_px=H)
    cast = cast_scene(Scene("wall", [], 0.5), H, W, geometry)
    psf = gaussian_psf(1.2).float()
    image = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(7))
    surface = Surface.from_arrays(random_texture(8), 0.03)
    seen = render_scene(image, cast, psf, layers=[0.5], surface=surface)
    expected = surface.reflectance * project(image, psf) + 0.03
    torch.testing.assert_close(seen, expected.float(), atol=1e-6, rtol=0)
    cast.hit[:, :4] = False  # rays that meet nothing: no light, no ambient either
    cast.depth_m[:, :4] = np.nan
    seen = render_scene(image, cast, psf, layers=[0.5], surface=surface)
    assert float(seen[..., :4].abs().max()) == 0.0


def test_bad_reflectance_and_ambient_are_one_line_errors(tmp_path):
    with pytest.raises(EdofprojError, match="is 30x40 px but the projector image is 24x32"):
        check_reflectance(np.full((30, 40, 3), 0.5), (H, W))
    with pytest.raises(EdofprojError, match=r"values -0.1..0.5; a reflectance lies in \[0, 1\]"):
        check_reflectance(np.r_[np.full(H * W * 3 - 1, 0.5), -0.1].reshape(H, W, 3), (H, W))
    with pytest.raises(EdofprojError, match=r"1.2; a reflectance lies in \[0, 1\]"):
        Surface.from_arrays(np.full((3, H, W), 1.2))
    with pytest.raises(EdofprojError, match="NaN"):
        check_reflectance(np.full((H, W, 3), np.nan), (H, W))
    with pytest.raises(EdofprojError, match=r"in \[0, 1\]"):
        check_ambient(-0.01, (H, W))
    with pytest.raises(EdofprojError, match="RGB map"):
        check_reflectance(np.full((H, W), 0.5), (H, W))
    # files: an image of the wrong size, a float array with values outside [0, 1], a good one
    write_image(tmp_path / "small.png", torch.full((3, 10, 12), 0.5))
    with pytest.raises(EdofprojError, match=r"texture '.*small.png' is 10x12 px") as err:
        read_reflectance(tmp_path / "small.png", (H, W))
    assert "\n" not in str(err.value)
    np.save(tmp_path / "bright.npy", np.full((H, W, 3), 1.5, dtype=np.float32))
    with pytest.raises(EdofprojError, match=r"bright.npy' has values 1.5..1.5"):
        read_reflectance(tmp_path / "bright.npy", (H, W))
    values = np.random.default_rng(0).uniform(0, 1, (H, W, 3)).astype(np.float32)
    np.save(tmp_path / "good.npy", values)
    np.testing.assert_allclose(read_reflectance(tmp_path / "good.npy", (H, W))[0].permute(1, 2, 0).numpy(), values)
    write_image(tmp_path / "good.png", torch.from_numpy(values).permute(2, 0, 1), bits=16)
    np.testing.assert_allclose(
        read_reflectance(tmp_path / "good.png", (H, W))[0].permute(1, 2, 0).numpy(), values, atol=1 / 65535
    )


def test_render_on_a_texture_file_and_its_bad_input(tmp_path, capsys):
    """``edofproj render --surface``: an impulse PSF shows s ⊙ I + s E exactly; a texture of the wrong
    size or with values outside [0, 1] is one line and no output."""
    from edofproj.cli import main
    from edofproj.imaging.image_io import read_image
    from edofproj.optics.psf_bank import PSFBank

    psf = np.zeros((1, 3, 5, 5))
    psf[:, :, 2, 2] = 1.0
    bank = tmp_path / "delta.npz"
    PSFBank(
        psf=torch.as_tensor(psf, dtype=torch.float32), depths_m=np.array([0.5]), pixel_pitch_m=np.array([4e-4])
    ).save(bank)
    image = torch.rand(3, H, W, generator=torch.Generator().manual_seed(9)) * 0.8
    write_image(tmp_path / "in.png", image, bits=16)
    texture = random_texture(10)[0].float()
    np.save(tmp_path / "tex.npy", texture.permute(1, 2, 0).numpy())
    out = tmp_path / "out.png"
    args = ["render", "--image", tmp_path / "in.png", "--out", out, "--psf", bank, "--bits", 16]
    assert main([str(a) for a in args + ["--surface", tmp_path / "tex.npy", "--ambient", 0.1]]) == 0
    expected = texture * read_image(tmp_path / "in.png") + 0.1 * texture
    np.testing.assert_allclose(read_image(out).numpy(), expected.clamp(0, 1).numpy(), atol=2e-5)
    capsys.readouterr()
    np.save(tmp_path / "bright.npy", np.full((H, W, 3), 1.2, np.float32))
    np.save(tmp_path / "small.npy", np.full((4, 4, 3), 0.5, np.float32))
    for extra, message in (
        (["--surface", tmp_path / "bright.npy"], r"has values 1.2..1.2; a reflectance lies in [0, 1]"),
        (["--surface", tmp_path / "small.npy"], "is 4x4 px but the projector image is 24x32"),
        (["--ambient", 0.2], "--ambient goes with --surface"),
    ):
        out.unlink(missing_ok=True)
        assert main([str(a) for a in args + extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not out.exists()


@pytest.mark.parametrize("value", [-0.01, 1.01, 5.0, 1e30, float("nan"), float("inf")])
def test_an_ambient_illuminance_outside_zero_to_one_is_refused(value):
    """One bound for --ambient (evaluate, render), --surface-ambient (procams simulate) and ambient maps."""
    from edofproj.imaging.surfaces import check_illuminance

    with pytest.raises(EdofprojError, match=r"must lie in \[0, 1\]: a fraction of the projector's white"):
        check_illuminance(value, "--ambient")
    if np.isfinite(value):
        with pytest.raises(EdofprojError, match=r"must be finite and in \[0, 1\]"):
            check_ambient(np.full((3, 4, 5), value), None)
    assert check_illuminance(1.0) == 1.0 and check_illuminance(0.0) == 0.0


def test_a_calibration_whose_surface_ambient_exceeds_the_projectors_white_is_refused_on_load():
    from edofproj.procams.calibration import _check_surface_arrays

    rho = np.full((4, 5, 3), 0.5, np.float32)

    def fail(message):
        raise EdofprojError(message)

    _check_surface_arrays({"surface_reflectance": rho, "surface_ambient": np.full_like(rho, 1.0)}, (4, 5), fail)
    with pytest.raises(EdofprojError, match=r"ambient light of 1e\+30\.\.1e\+30, outside \[0, 1\]"):
        _check_surface_arrays({"surface_reflectance": rho, "surface_ambient": np.full_like(rho, 1e30)}, (4, 5), fail)
