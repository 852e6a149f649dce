"""The Gaussian blur of the safe forms' high-pass: both of its computations (blur matrices, 1-D
convolutions) equal SciPy's Gaussian filter with a replicate ("nearest") border."""

import numpy as np
import pytest
import torch
from scipy import ndimage

from edofproj.compensation import linear_base
from edofproj.compensation.linear_base import (
    blur_by_convolutions,
    blur_by_matrices,
    gaussian_blur,
    gaussian_blur_matrix,
)


@pytest.mark.parametrize("blur", [blur_by_matrices, blur_by_convolutions, gaussian_blur])
@pytest.mark.parametrize(("shape", "sigma"), [((2, 3, 37, 50), 2.0), ((1, 1, 20, 90), 8.0), ((1, 2, 5, 7), 1.0)])
def test_blur_equals_scipys_gaussian_filter_with_a_replicate_border(blur, shape, sigma):
    """SciPy's radius is ``int(truncate sigma + 0.5)``: with ``truncate = 3`` and an integer sigma it
    is ``ceil(3 sigma)``, ours; images narrower than the radius fold the whole window onto the border."""
    image = torch.rand(shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    expected = ndimage.gaussian_filter(image.numpy(), sigma=(0, 0, sigma, sigma), mode="nearest", truncate=3.0)
    np.testing.assert_allclose(blur(image, sigma).numpy(), expected, rtol=0, atol=1e-12)


def test_blur_takes_the_convolutions_beyond_the_matrix_limit(monkeypatch):
    """Above :data:`MATRIX_BLUR_MAX_PX` the convolutions run (the matrices are not built)."""
    monkeypatch.setattr(linear_base, "MATRIX_BLUR_MAX_PX", 16)

    def calls():
        info = gaussian_blur_matrix.cache_info()
        return info.hits + info.misses

    before = calls()
    gaussian_blur(torch.rand(1, 1, 12, 16), 2.0)
    assert calls() == before + 2  # within the limit: the two matrices
    gaussian_blur(torch.rand(1, 1, 20, 24), 2.0)
    assert calls() == before + 2


def test_blur_matrix_rows_sum_to_one_and_its_gradient_is_its_transpose():
    matrix = gaussian_blur_matrix(11, 2.0, torch.float64, "cpu")
    torch.testing.assert_close(matrix.sum(dim=1), torch.ones(11, dtype=torch.float64))
    image = torch.rand(1, 1, 11, 13, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: gaussian_blur(x, 2.0), (image,))
