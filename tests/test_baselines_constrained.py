"""Box-constrained least squares: operator = projection, exact adjoint, recovery, monotone, feasible."""

import pytest
import torch

from edofproj.compensation.constrained import BlurHazeOperator, box_constrained_deconvolution
from edofproj.errors import EdofprojError
from edofproj.imaging.projection import project


def cross_psf(energy: float = 0.9) -> torch.Tensor:
    """5×5 PSF without spectral zeros (|P| ≥ 0.1·energy), scaled to ``energy``; (1, 3, 5, 5) float64."""
    psf = torch.zeros(5, 5, dtype=torch.float64)
    psf[2, 2] = 0.5
    psf[1, 2] = psf[3, 2] = psf[2, 1] = psf[2, 3] = 0.1
    return (energy * psf / psf.sum()).expand(1, 3, 5, 5).clone()


def gaussian_psf(sigma: float, window: int, energy: float = 0.95) -> torch.Tensor:
    r = torch.arange(window, dtype=torch.float64) - window // 2
    g = torch.exp(-(r[:, None] ** 2 + r[None] ** 2) / (2 * sigma**2))
    return (energy * g / g.sum()).expand(1, 3, window, window).clone()


@pytest.fixture
def truth():
    return torch.rand(2, 3, 36, 44, dtype=torch.float64, generator=torch.Generator().manual_seed(0))


def test_operator_is_the_projection_and_its_adjoint_is_exact(truth):
    psf = gaussian_psf(1.5, 9)
    op = BlurHazeOperator(psf, 36, 44)
    assert torch.allclose(op(truth), project(truth, psf), atol=1e-12)
    r = torch.randn(truth.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    x = torch.randn(truth.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    lhs, rhs = (op(x) * r).sum(), (x * op.adjoint(r)).sum()
    assert abs(float(lhs - rhs)) < 1e-10 * float(lhs.abs())
    # The step bound: ‖A‖² ≤ (Σp + h)² = 1, checked by power iteration.
    v = x
    for _ in range(50):
        v = op.adjoint(op(v))
        v = v / v.norm()
    assert float((op(v) ** 2).sum()) <= float(op.lipschitz.max()) + 1e-9
    assert torch.allclose(op.lipschitz, torch.ones_like(op.lipschitz))


@pytest.mark.parametrize("method", ["fista", "pgd"])
def test_recovers_a_known_input(truth, method):
    psf = cross_psf()
    observed = project(truth, psf)
    iterations = 100 if method == "fista" else 300
    recovered = box_constrained_deconvolution(observed, psf, iterations=iterations, method=method)
    assert recovered.shape == truth.shape
    assert float((recovered - truth).abs().max()) < 1e-2
    assert float((recovered - truth).abs().mean()) < 1e-3


@pytest.mark.parametrize("method", ["fista", "pgd"])
def test_objective_decreases_and_iterates_stay_in_the_box(truth, method):
    psf = gaussian_psf(2.0, 11)
    target = truth  # not reachable by a blurred projection: the box constraint is active
    seen = []

    def check(k, x):
        seen.append(k)
        assert float(x.min()) >= 0.0 and float(x.max()) <= 1.0

    x, objective = box_constrained_deconvolution(
        target, psf, iterations=40, method=method, return_objective=True, callback=check
    )
    assert seen == list(range(1, 41))
    assert objective.shape == (41, 2)
    steps = objective[1:] - objective[:-1]
    assert float(steps.max()) <= 1e-12 * float(objective.max())
    assert bool((objective[-1] < 0.95 * objective[0]).all())
    # Compensation beats projecting the target itself.
    assert float(((project(x, psf) - target) ** 2).mean()) < float(((project(target, psf) - target) ** 2).mean())


def test_fista_converges_faster_than_projected_gradient(truth):
    psf = gaussian_psf(2.0, 11)
    _, fista = box_constrained_deconvolution(truth, psf, iterations=50, method="fista", return_objective=True)
    _, pgd = box_constrained_deconvolution(truth, psf, iterations=50, method="pgd", return_objective=True)
    assert bool((fista[-1] < pgd[-1]).all())


def test_user_errors():
    image = torch.rand(1, 3, 16, 16)
    with pytest.raises(EdofprojError, match="solver"):
        box_constrained_deconvolution(image, cross_psf(), method="adam")
    with pytest.raises(EdofprojError, match="K odd"):
        box_constrained_deconvolution(image, torch.ones(1, 3, 4, 4) / 16)
    with pytest.raises(EdofprojError, match="does not match"):
        box_constrained_deconvolution(image, torch.ones(1, 2, 3, 3) / 9)


def _textbook_fista(target, psf, iterations):
    """Monotone FISTA (Beck & Teboulle 2009) applying the operator to every iterate it needs: A y, A z."""
    op = BlurHazeOperator(psf, target.shape[-2], target.shape[-1])
    step = 1.0 / op.lipschitz

    def objective(v):
        return 0.5 * ((op(v) - target) ** 2).flatten(1).sum(1)

    x = target.clamp(0, 1)
    y, t, f_x = x, 1.0, objective(x)
    for _ in range(iterations):
        z = (y - step * op.adjoint(op(y) - target)).clamp(0, 1)
        f_z = objective(z)
        better = (f_z <= f_x).view(-1, 1, 1, 1)
        x_prev, x = x, torch.where(better, z, x)
        f_x = torch.minimum(f_z, f_x)
        t_next = (1 + (1 + 4 * t * t) ** 0.5) / 2
        y = x + (t / t_next) * (z - x) + ((t - 1) / t_next) * (x - x_prev)
        t = t_next
    return x, f_x


def test_fista_carried_operator_values_follow_the_textbook_iteration(truth):
    # the solver forms A y from A z, A x and A x_prev (A is linear) instead of applying A to y
    psf = gaussian_psf(2.0, 11)
    observed = project(truth, psf)
    ours, objective = box_constrained_deconvolution(observed, psf, iterations=60, return_objective=True)
    textbook, f_textbook = _textbook_fista(observed, psf, 60)
    assert float((ours - textbook).abs().max()) < 1e-9
    assert torch.allclose(objective[-1], f_textbook, rtol=1e-9, atol=0)
