"""The sweeps run as tasks on several threads: the same tables as one thread, in the same order."""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch
from scipy import ndimage

from edofproj import metrics
from edofproj.compensation.closed_loop import closed_loop, flat_screen
from edofproj.config import load_config
from edofproj.cpu_tasks import run_tasks
from edofproj.evaluation.sweep import flat_screen_sweep, tilted_screen_sweep
from edofproj.methods.builder import PreparedMethod
from edofproj.methods.catalogue import method_spec
from edofproj.methods.compensators import ConstrainedCompensation, WienerCompensation, no_compensation


def gaussian_psf(sigma: float, size: int = 9) -> torch.Tensor:
    delta = np.zeros((size, size))
    delta[size // 2, size // 2] = 1.0
    psf = ndimage.gaussian_filter(delta, sigma)
    return torch.from_numpy(np.repeat((0.97 * psf / psf.sum())[None], 3, axis=0)).float()


def design(key: str, sigma_per_m: float):
    """A design whose blur grows with depth: sigma = sigma_per_m * z."""
    return types.SimpleNamespace(
        key=key, psf=lambda depths: torch.stack([gaussian_psf(0.3 + sigma_per_m * float(z)) for z in depths])
    )


@pytest.fixture
def methods():
    lens, doe = design("lens", 2.0), design("run", 1.0)
    return [
        PreparedMethod(method_spec("lens"), lens, no_compensation),
        PreparedMethod(method_spec("lens+cls"), lens, ConstrainedCompensation(15)),
        PreparedMethod(method_spec("doe"), doe, no_compensation),
        PreparedMethod(method_spec("doe+wiener"), doe, WienerCompensation(1e-2)),
    ]


@pytest.fixture
def images():
    rng = np.random.default_rng(3)
    smooth = [ndimage.gaussian_filter(rng.uniform(0, 1, (3, 40, 48)), (0, 1.5, 1.5)) * 0.8 + 0.1 for _ in range(3)]
    return [(f"image{i}", torch.from_numpy(a).float()) for i, a in enumerate(smooth)]


def sweep_on(workers: int, threads: int, sweep):
    """``sweep(workers)`` with torch set to ``threads`` intra-op threads (restored after)."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        result = sweep(workers)
        assert torch.get_num_threads() == threads  # restored after the tasks
        return result
    finally:
        torch.set_num_threads(before)


def test_the_flat_sweep_on_two_workers_is_the_closed_loop_scored_image_by_image(methods, images):
    # two workers sharing two threads: each task single-threaded, as the sweep on one thread
    table = sweep_on(2, 2, lambda workers: flat_screen_sweep(methods, images, [300.0, 600.0], {}, workers=workers))
    serial = sweep_on(1, 1, lambda workers: flat_screen_sweep(methods, images, [300.0, 600.0], {}, workers=workers))
    assert table.rows == serial.rows
    assert [(r["depth_mm"], r["method"], r["image"]) for r in table.rows] == [
        (z, m.name, name) for z in (300.0, 600.0) for m in methods for name, _ in images
    ]
    for row in table.rows:  # each method's loop on one image, scored by the metric functions one by one
        method = next(m for m in methods if m.name == row["method"])
        target = dict(images)[row["image"]][None]
        psf = method.design.psf([row["depth_mm"] * 1e-3])
        with torch.inference_mode():
            shown = closed_loop(target, flat_screen(psf), lambda t, c: method.compensate(t, c, psf)).projected
        assert row["ssim"] == pytest.approx(float(metrics.ssim(shown, target)[0]), abs=1e-6)
        assert row["de2000"] == pytest.approx(float(metrics.delta_e2000(shown, target)[0][0]), abs=1e-4)


def test_the_tilted_sweep_on_two_workers_equals_one_worker(methods, images):
    cfg = load_config("cpu")
    table, examples = sweep_on(2, 2, lambda workers: tilted_screen_sweep(methods, images, cfg, {}, workers=workers))
    serial, serial_examples = sweep_on(
        1, 1, lambda workers: tilted_screen_sweep(methods, images, cfg, {}, workers=workers)
    )
    assert table.rows == serial.rows and len(table.rows) == len(methods) * len(images)
    assert list(examples) == [m.name for m in methods]
    for name, (array, values) in examples.items():
        assert np.array_equal(array, serial_examples[name][0]) and values == serial_examples[name][1]
        assert array.shape == (40, 48, 3)


def test_run_tasks_keeps_the_order_and_passes_errors_on():
    assert list(run_tasks([lambda i=i: i * i for i in range(7)], workers=3)) == [i * i for i in range(7)]

    def failing():
        raise ValueError("task failed")

    threads = torch.get_num_threads()
    with pytest.raises(ValueError, match="task failed"):
        list(run_tasks([lambda: 1, failing, lambda: 3], workers=2))
    assert torch.get_num_threads() == threads
