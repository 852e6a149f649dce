"""PSNR / SSIM / MS-SSIM against scikit-image and an independent NumPy/SciPy computation."""

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter
from skimage import data
from skimage.measure import block_reduce
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from edofproj.errors import EdofprojError
from edofproj.metrics import (
    MS_SSIM_WEIGHTS,
    ms_ssim,
    ms_ssim_scales,
    psnr,
    ssim,
)


def photo_pair(height, width, noise=0.08, seed=0, dtype=torch.float64):
    """A crop of skimage's astronaut and a noisy, slightly darkened copy, (1, 3, H, W)."""
    image = data.astronaut()[60 : 60 + height, 120 : 120 + width] / 255.0
    rng = np.random.default_rng(seed)
    distorted = np.clip(0.9 * image + noise * rng.standard_normal(image.shape), 0, 1)
    as_tensor = lambda a: torch.tensor(a, dtype=dtype).permute(2, 0, 1)[None]  # noqa: E731
    return as_tensor(distorted), as_tensor(image)


def hwc(tensor):
    return tensor[0].permute(1, 2, 0).double().numpy()


def skimage_ssim(pred, target):
    return structural_similarity(
        hwc(pred),
        hwc(target),
        channel_axis=2,
        data_range=1.0,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
    )


def reference_ms_ssim(pred, target, scales):
    """MS-SSIM from scipy's Gaussian filter and skimage's block mean, float64, HWC arrays."""
    weights = np.array(MS_SSIM_WEIGHTS[:scales])
    weights = weights / weights.sum()
    x, y = pred, target
    result = 1.0
    for j in range(scales):
        if j > 0:
            h, w = (x.shape[0] // 2) * 2, (x.shape[1] // 2) * 2
            x = block_reduce(x[:h, :w], (2, 2, 1), np.mean)
            y = block_reduce(y[:h, :w], (2, 2, 1), np.mean)
        blur = lambda a: gaussian_filter(a, sigma=(1.5, 1.5, 0), truncate=3.5)  # noqa: E731
        mx, my = blur(x), blur(y)
        vx, vy, cxy = blur(x * x) - mx**2, blur(y * y) - my**2, blur(x * y) - mx * my
        cs = (2 * cxy + 0.03**2) / (vx + vy + 0.03**2)
        lum = (2 * mx * my + 0.01**2) / (mx**2 + my**2 + 0.01**2)
        crop = (slice(5, -5), slice(5, -5))
        term = (lum * cs)[crop].mean() if j == scales - 1 else cs[crop].mean()
        result *= max(term, 0.0) ** weights[j]
    return result


def test_psnr_matches_skimage_per_image():
    pred_a, target_a = photo_pair(64, 80, noise=0.05, seed=1)
    pred_b, target_b = photo_pair(64, 80, noise=0.2, seed=2)
    values = psnr(torch.cat([pred_a, pred_b]), torch.cat([target_a, target_b]))
    assert values.shape == (2,)
    for value, (p, t) in zip(values, [(pred_a, target_a), (pred_b, target_b)]):
        expected = peak_signal_noise_ratio(hwc(t), hwc(p), data_range=1.0)
        assert value.item() == pytest.approx(expected, abs=1e-9)
    assert values[0] > values[1]


def test_psnr_closed_form_and_identity():
    target = torch.full((1, 3, 8, 8), 0.5)
    assert psnr(target + 0.1, target).item() == pytest.approx(20.0, abs=1e-4)  # 10 log10(1/0.01)
    assert torch.isinf(psnr(target, target)).all()


@pytest.mark.parametrize("size", [(64, 64), (75, 113)])
def test_ssim_matches_skimage(size):
    pred, target = photo_pair(*size)
    assert ssim(pred, target).item() == pytest.approx(skimage_ssim(pred, target), abs=1e-10)
    ours32 = ssim(pred.float(), target.float()).item()
    assert ours32 == pytest.approx(skimage_ssim(pred, target), abs=1e-4)


def test_ssim_is_per_image_and_one_for_identical_images():
    pred_a, target_a = photo_pair(48, 48, noise=0.02, seed=3)
    pred_b, target_b = photo_pair(48, 48, noise=0.3, seed=4)
    values = ssim(torch.cat([pred_a, pred_b]), torch.cat([target_a, target_b]))
    assert values.shape == (2,)
    assert values[0].item() == pytest.approx(skimage_ssim(pred_a, target_a), abs=1e-10)
    assert values[1].item() == pytest.approx(skimage_ssim(pred_b, target_b), abs=1e-10)
    assert ssim(target_a, target_a).item() == pytest.approx(1.0, abs=1e-12)


def test_ms_ssim_scale_count():
    assert ms_ssim_scales(256, 256) == 5
    assert ms_ssim_scales(176, 300) == 5  # 176 // 16 = 11 still holds the window
    assert ms_ssim_scales(175, 300) == 4
    assert ms_ssim_scales(128, 128) == 4  # 128 -> 64 -> 32 -> 16
    assert ms_ssim_scales(11, 40) == 1
    assert ms_ssim_scales(10, 40) == 0


@pytest.mark.parametrize("size", [(256, 256), (128, 128), (200, 231)])
def test_ms_ssim_matches_independent_computation(size):
    pred, target = photo_pair(*size)
    scales = ms_ssim_scales(*size)
    expected = reference_ms_ssim(hwc(pred), hwc(target), scales)
    assert ms_ssim(pred, target).item() == pytest.approx(expected, abs=1e-9)
    assert ms_ssim(pred.float(), target.float()).item() == pytest.approx(expected, abs=1e-4)


def test_reference_single_scale_is_skimage_ssim():
    """The reference above is itself checked: with one scale it is skimage's SSIM."""
    pred, target = photo_pair(40, 50)
    assert reference_ms_ssim(hwc(pred), hwc(target), 1) == pytest.approx(skimage_ssim(pred, target), abs=1e-10)


def test_ms_ssim_identity_ordering_and_gradient():
    pred_small, target = photo_pair(128, 128, noise=0.03)
    pred_large, _ = photo_pair(128, 128, noise=0.2)
    assert ms_ssim(target, target).item() == pytest.approx(1.0, abs=1e-12)
    assert ms_ssim(pred_small, target) > ms_ssim(pred_large, target)
    # anti-correlated images give negative contrast terms: clipped to 0, gradients stay finite
    pred = (1 - target.float()).requires_grad_(True)
    value = ms_ssim(pred, target.float())
    value.sum().backward()
    assert torch.isfinite(value).all() and torch.isfinite(pred.grad).all()


def test_metrics_reject_bad_input():
    with pytest.raises(EdofprojError, match="11x11"):
        ssim(torch.rand(1, 3, 10, 32), torch.rand(1, 3, 10, 32))
    with pytest.raises(EdofprojError, match="11x11"):
        ms_ssim(torch.rand(1, 3, 10, 32), torch.rand(1, 3, 10, 32))
    with pytest.raises(EdofprojError, match="same shape"):
        psnr(torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 17))


def test_ssim_against_a_fixed_reference_equals_ssim_for_every_repeat_of_its_batch():
    """:class:`SSIMReference` filters the target once and scores ``k B`` images against it, as ``ssim`` does."""
    from edofproj.metrics import SSIMReference

    generator = torch.Generator().manual_seed(4)
    target = torch.rand(2, 3, 24, 30, generator=generator)
    pred = torch.rand(6, 3, 24, 30, generator=generator)
    reference = SSIMReference(target)
    torch.testing.assert_close(reference.ssim(pred), ssim(pred, target.repeat(3, 1, 1, 1)), atol=1e-7, rtol=0)
    torch.testing.assert_close(reference.ssim(target), torch.ones(2), atol=1e-6, rtol=0)
    with pytest.raises(EdofprojError, match="same shape"):
        reference.ssim(pred[:3])


@pytest.mark.parametrize("shape", [(1, 3, 61, 83), (2, 3, 24, 30), (1, 1, 40, 40)])
def test_ssim_scores_without_gradients_are_the_differentiable_ones_to_the_last_bit(shape):
    """Scores (no autograd) take the in-place path, training the differentiable one: the same
    maps, bit for bit, for ssim, ms_ssim, ssim_map and a reference scoring a repeated batch (a
    display guard's choice must not depend on which path scored it)."""
    from edofproj.metrics import SSIMReference, ms_ssim, ssim_map

    generator = torch.Generator().manual_seed(7)
    target = torch.rand(*shape, generator=generator)
    pred = torch.rand(shape[0] * 2, *shape[1:], generator=generator)
    differentiable = pred.clone().requires_grad_(True)
    repeated = target.repeat(2, 1, 1, 1)
    for score in (ssim, ssim_map):
        with torch.inference_mode():
            in_place = score(pred, repeated)
        slow = score(differentiable, repeated).detach()
        torch.testing.assert_close(in_place, slow, atol=0, rtol=0, equal_nan=True, msg=score.__name__)
    reference = SSIMReference(target)
    with torch.no_grad():
        fast = reference.maps(pred)
    slow = reference.maps(differentiable)
    assert all(torch.equal(a, b.detach()) for a, b in zip(fast, slow))
    if min(shape[-2:]) >= 22:  # two scales of MS-SSIM
        with torch.inference_mode():
            fast_ms = ms_ssim(pred, repeated)
        assert torch.equal(fast_ms, ms_ssim(differentiable, repeated).detach())
    # the in-place path leaves its inputs as they were
    before = pred.clone()
    with torch.inference_mode():
        reference.ssim(pred)
    assert torch.equal(pred, before)


def test_image_scorer_gives_each_metric_functions_values_to_the_last_bit():
    from edofproj.metrics import ImageScorer, delta_e2000, ms_ssim, psnr, ssim, ssim_per_channel

    generator = torch.Generator().manual_seed(5)
    target = torch.rand(2, 3, 48, 56, generator=generator)
    scorer = ImageScorer(target)
    for noise in (0.02, 0.2):
        pred = (target + noise * torch.randn(target.shape, generator=generator)).clamp(0, 1)
        scores = scorer.scores(pred)
        de_mean, de_p95 = delta_e2000(pred, target)
        channels = ssim_per_channel(pred, target)
        expected = {
            "psnr": psnr(pred, target),
            "ssim": ssim(pred, target),
            "ms_ssim": ms_ssim(pred, target),
            "de2000": de_mean,
            "de2000_p95": de_p95,
            "ssim_r": channels[:, 0],
            "ssim_g": channels[:, 1],
            "ssim_b": channels[:, 2],
        }
        assert list(scores) == list(expected)
        for name, values in expected.items():
            assert torch.equal(scores[name], values), name
    with pytest.raises(EdofprojError, match="same shape"):
        scorer.scores(target[:1])
