"""Rendering onto scenes: a flat scene equals the flat-screen projection, depth edges, lost light, falloff;
random depth-varying training screens."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.signal import convolve2d

from edofproj.imaging.projection import project
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.scenes import Scene, SceneMesh, cast_scene, relative_irradiance, render_scene
from edofproj.scenes.builtin import fronto_parallel_plane, quad
from edofproj.scenes.random_screens import SCREEN_KINDS, random_depth_map

H, W = 24, 32


@pytest.fixture
def small_projector():
    return ProjectorGeometry(throw_ratio=1.5, width_px=W, height_px=H)


def disk_psf(radius: float, size: int = 15) -> torch.Tensor:
    """A uniform disk of unit sum, the same for the three colours, ``(1, 3, K, K)``."""
    r = np.hypot(*np.meshgrid(np.arange(size) - size // 2, np.arange(size) - size // 2))
    disk = (r <= radius).astype(np.float64)
    return torch.as_tensor(disk / disk.sum(), dtype=torch.float32)[None, None].repeat(1, 3, 1, 1)


def test_flat_scene_equals_flat_screen_projection(small_projector):
    cast = cast_scene(Scene("wall", [], 0.5), H, W, small_projector)
    assert cast.hit.all() and np.all(cast.depth_m == np.float32(0.5))
    image = torch.rand(2, 3, H, W, generator=torch.Generator().manual_seed(0))
    psf = disk_psf(2.5) * 0.9  # 10 % of the light outside the window: haze
    rendered = render_scene(image, cast, psf, layers=[0.5])
    torch.testing.assert_close(rendered, project(image, psf), rtol=0, atol=1e-6)


def edge_scene(geometry):
    """Columns left of the axis see a near plane at 0.4 m, the rest the background at 0.6 m."""
    near = quad(np.array([[-1.0, -1.0, 0.4], [0.0, -1.0, 0.4], [0.0, 1.0, 0.4], [-1.0, 1.0, 0.4]]))
    return cast_scene(Scene("edge", [SceneMesh("near", near, open=True)], 0.6), H, W, geometry)


def test_depth_edge_each_source_pixel_carries_its_surface_psf(small_projector):
    """Independent check: blur the near half with the near PSF and the far half with the far PSF (scipy),
    add them; and the blur crossing the edge is asymmetric (wide from near to far, narrow the other way)."""
    cast = edge_scene(small_projector)
    assert (cast.depth_m[:, : W // 2] == np.float32(0.4)).all() and (cast.depth_m[:, W // 2 :] == np.float32(0.6)).all()
    near_psf, far_psf = disk_psf(5.0), disk_psf(1.0)
    psfs = torch.cat([near_psf, far_psf])
    image = torch.ones(1, 3, H, W)
    rendered = render_scene(image, cast, psfs, layers=[0.4, 0.6])[0, 0].numpy()

    left = np.zeros((H, W))
    left[:, : W // 2] = 1
    expected = convolve2d(left, near_psf[0, 0].numpy(), mode="same") + convolve2d(
        1 - left, far_psf[0, 0].numpy(), mode="same"
    )
    np.testing.assert_allclose(rendered, expected, atol=1e-5)

    # light from the near side alone, and from the far side alone, across the edge (middle row)
    only_near = render_scene(image * torch.as_tensor(left, dtype=torch.float32), cast, psfs, [0.4, 0.6])[0, 0, H // 2]
    only_far = render_scene(image * torch.as_tensor(1 - left, dtype=torch.float32), cast, psfs, [0.4, 0.6])[
        0, 0, H // 2
    ]
    spill_into_far = int((only_near[W // 2 :] > 1e-6).sum())
    spill_into_near = int((only_far[: W // 2] > 1e-6).sum())
    assert spill_into_far == 5 and spill_into_near == 1  # the PSF radii


def test_missed_rays_lose_their_light(small_projector):
    """A plane covering only the left half: the right half shows nothing, and the light the near PSF
    spreads past the plane's edge is lost (independent scipy convolution, cropped to the plane)."""
    near = quad(np.array([[-1.0, -1.0, 0.5], [0.0, -1.0, 0.5], [0.0, 1.0, 0.5], [-1.0, 1.0, 0.5]]))
    cast = cast_scene(Scene("half", [SceneMesh("half", near, open=True)]), H, W, small_projector)
    assert cast.hit[:, : W // 2].all() and not cast.hit[:, W // 2 :].any()
    assert np.isnan(cast.depth_m[:, W // 2 :]).all()
    psf = disk_psf(3.0)
    rendered = render_scene(torch.ones(1, 3, H, W), cast, psf, layers=[0.5])[0, 0].numpy()
    expected = convolve2d(cast.hit.astype(float), psf[0, 0].numpy(), mode="same") * cast.hit
    np.testing.assert_allclose(rendered, expected, atol=1e-5)
    assert rendered.sum() < cast.hit.sum()


def test_falloff_is_cos_theta_over_distance_squared(small_projector):
    """On a fronto-parallel plane at z: d = z |(u, v, 1)|, cos(theta) = 1 / |(u, v, 1)|."""
    z = 0.6
    cast = cast_scene(
        Scene("wall", [SceneMesh("wall", fronto_parallel_plane(z, small_projector), True)]), H, W, small_projector
    )
    u = (np.arange(W) + 0.5 - W / 2) / small_projector.throw_width_m
    v = (np.arange(H) + 0.5 - H / 2) / small_projector.throw_width_m
    norm = np.sqrt(u[None, :] ** 2 + v[:, None] ** 2 + 1)
    expected = (1 / norm) * (0.5 / (z * norm)) ** 2
    np.testing.assert_allclose(relative_irradiance(cast, 0.5), expected, rtol=1e-5)
    image = torch.full((1, 3, H, W), 0.5)
    plain = render_scene(image, cast, disk_psf(0.0), layers=[z])
    dimmed = render_scene(image, cast, disk_psf(0.0), layers=[z], falloff_reference_m=0.5)
    torch.testing.assert_close(dimmed, plain * torch.as_tensor(expected, dtype=torch.float32), rtol=1e-5, atol=1e-7)


def test_random_screens_stay_in_range_and_cover_every_kind():
    kinds = set()
    for seed in range(40):
        depth, kind = random_depth_map(torch.Generator().manual_seed(seed), 16, 20, 0.3, 0.8)
        kinds.add(kind)
        assert depth.shape == (16, 20)
        assert depth.min() >= 0.3 - 1e-12 and depth.max() <= 0.8 + 1e-12
        if kind == "flat":
            assert np.ptp(depth) == 0
        if kind == "step":
            assert len(np.unique(depth)) <= 2
    assert kinds == set(SCREEN_KINDS)
    again, _ = random_depth_map(torch.Generator().manual_seed(3), 16, 20, 0.3, 0.8)
    np.testing.assert_array_equal(again, random_depth_map(torch.Generator().manual_seed(3), 16, 20, 0.3, 0.8)[0])


def test_end_to_end_projector_on_a_constant_depth_map_equals_the_flat_screen():
    from edofproj.training.end_to_end import EndToEndProjector

    psfs = torch.cat([disk_psf(4.0), disk_psf(1.0)])
    layers = np.array([0.4, 0.6])

    def source(depths_m):
        return psfs[[0 if abs(z - 0.4) < 1e-9 else 1 for z in np.atleast_1d(depths_m)]]

    net = torch.nn.Identity()

    class Net(torch.nn.Module):
        def forward(self, target, captured):
            return net(target)

    model = EndToEndProjector(source, Net(), layers_m=layers)
    image = torch.rand(2, 3, 20, 20, generator=torch.Generator().manual_seed(1))
    maps = np.full((2, 20, 20), 0.6)
    maps[1] = 0.4
    varying = model(image, maps)
    flat = model(image, np.array([0.6, 0.4]))
    torch.testing.assert_close(varying.captured, flat.captured, rtol=0, atol=1e-6)
    torch.testing.assert_close(varying.projected, flat.projected, rtol=0, atol=1e-6)
