"""The projected quasi-Newton solver of box-constrained least squares (compensation.box_quasi_newton)
against scipy's bounded least squares (an independent algorithm), its monotone objective, and on the
field-varying blur of a synthetic PSF map: an achievable target recovered from the target itself."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import torch

from edofproj.compensation.box_quasi_newton import box_quasi_newton
from edofproj.compensation.field_varying import field_varying_cls
from edofproj.errors import EdofprojError
from edofproj.procams.map_compensation import compensate_with_map
from edofproj.procams.measured_blur import measured_blur
from test_map_compensation import H, W, synthetic_map


def dense_problem(seed: int, rows: int = 60, side: int = 6):
    """An ill-conditioned ``A (rows, side^2)`` (singular values 1 .. 1e-3) and a target whose unconstrained
    solution leaves the box, as ``forward``/``adjoint`` on ``(1, 1, side, side)`` images."""
    rng = np.random.default_rng(seed)
    n = side * side
    u, _ = np.linalg.qr(rng.standard_normal((rows, n)))
    v, _ = np.linalg.qr(rng.standard_normal((n, n)))
    matrix = u @ np.diag(np.logspace(0, -3, n)) @ v.T
    target = matrix @ rng.uniform(-0.5, 1.5, n) + 0.01 * rng.standard_normal(rows)
    a = torch.from_numpy(matrix)

    def forward(x):
        return (a @ x.reshape(-1)).reshape(1, 1, rows, 1)

    def adjoint(r):
        return (a.T @ r.reshape(-1)).reshape(1, 1, side, side)

    return matrix, target, forward, adjoint, torch.from_numpy(target).reshape(1, 1, rows, 1)


def box_solver_on(forward, adjoint, target_image, side, iterations, start=None):
    """:func:`box_quasi_newton` for a target that is not image-shaped like x: x starts at ``start`` (default 0.5)."""
    x0 = torch.full((1, 1, side, side), 0.5, dtype=torch.float64) if start is None else start
    return box_quasi_newton(target_image, forward, adjoint, iterations, start=x0)


@pytest.mark.parametrize("seed", [1, 2])
def test_reaches_the_optimum_scipy_finds(seed):
    matrix, target, forward, adjoint, target_image = dense_problem(seed)
    reference = scipy.optimize.lsq_linear(matrix, target, bounds=(0.0, 1.0), method="bvls", tol=1e-15)
    x, objective = box_solver_on(forward, adjoint, target_image, 6, 400)
    best = 0.5 * float(np.sum((matrix @ reference.x - target) ** 2))
    assert (reference.x <= 0).any() and (reference.x >= 1).any()  # the box bites at both ends
    assert float(objective[-1, 0]) == pytest.approx(best, rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(x.reshape(-1).numpy(), reference.x, atol=1e-5)
    assert float(x.min()) >= 0.0 and float(x.max()) <= 1.0


def test_the_objective_never_rises_and_the_optimum_stays():
    matrix, target, forward, adjoint, target_image = dense_problem(2)
    x, objective = box_solver_on(forward, adjoint, target_image, 6, 60)
    f = objective[:, 0]
    assert bool((f[1:] <= f[:-1] * (1 + 1e-14)).all()) and float(f[-1]) < float(f[0])
    # the objective reported is the objective of the iterate returned
    assert float(f[-1]) == pytest.approx(0.5 * float(((forward(x) - target_image) ** 2).sum()), rel=1e-9)
    # from the optimum (scipy's), no step lowers it: the solver stays within rounding
    reference = scipy.optimize.lsq_linear(matrix, target, bounds=(0.0, 1.0), method="bvls", tol=1e-15)
    start = torch.from_numpy(reference.x).reshape(1, 1, 6, 6)
    _, again = box_solver_on(forward, adjoint, target_image, 6, 5, start=start)
    assert float((again[0, 0] - again[-1, 0]).abs()) <= 1e-10 * float(again[0, 0])


def test_cls_recovers_an_achievable_target_from_the_target_itself():
    op = measured_blur(synthetic_map(), node_spacing_px=8, rank_tolerance=0.0)
    generator = torch.Generator().manual_seed(5)
    truth = torch.nn.functional.avg_pool2d(
        torch.rand(1, 3, H + 2, W + 2, dtype=torch.float64, generator=generator), 3, 1
    )
    target = op(truth)  # some x in [0, 1] shows it exactly: the optimum is 0
    x, objective = field_varying_cls(target, op, 60, method="lbfgs", return_objective=True)  # start: the target
    assert float(objective[0, 0]) == pytest.approx(0.5 * float(((op(target.clamp(0, 1)) - target) ** 2).sum()))
    mse = float(((op(x) - target) ** 2).mean())
    assert 10 * np.log10(1.0 / mse) >= 40.0
    # from the Wiener estimate (compensate_with_map's start) too
    result = compensate_with_map(target, op, "cls", nsr=1e-3, iterations=60, solver="lbfgs")
    assert 10 * np.log10(1.0 / float(((op(result.image) - target) ** 2).mean())) >= 40.0


def test_quasi_newton_beats_fista_at_equal_work_on_a_field_varying_blur():
    """Both apply A and A^T once per iteration: at 15 iterations the quasi-Newton objective is lower."""
    op = measured_blur(synthetic_map(1.5), node_spacing_px=8, rank_tolerance=0.0)
    target = torch.zeros(1, 1, H, W, dtype=torch.float64)
    target[..., 12:36, 16:48] = 1.0  # sharp edges: the box bites
    _, quasi_newton = field_varying_cls(target, op, 15, method="lbfgs", return_objective=True)
    _, fista = field_varying_cls(target, op, 15, method="fista", return_objective=True)
    assert float(quasi_newton[-1, 0]) < float(fista[-1, 0])


def test_bad_arguments_are_refused_in_one_line():
    _, _, forward, adjoint, target_image = dense_problem(0)
    with pytest.raises(EdofprojError, match="iterations"):
        box_quasi_newton(target_image, forward, adjoint, -1)
    with pytest.raises(EdofprojError, match="memory"):
        box_quasi_newton(target_image, forward, adjoint, 3, memory=0)
    with pytest.raises(EdofprojError, match=r"\(B, C, H, W\)"):
        box_quasi_newton(target_image[0], forward, adjoint, 3)
    op = measured_blur(synthetic_map(), node_spacing_px=8)
    with pytest.raises(EdofprojError, match="unknown constrained solver"):
        field_varying_cls(torch.zeros(1, 3, H, W), op, method="newton")
