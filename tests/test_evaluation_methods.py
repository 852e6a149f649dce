"""The depth-ensemble Wiener baseline (doe+ensemble) and the per-method frame timing."""

from __future__ import annotations

import types

import numpy as np
import torch
from scipy import ndimage

from edofproj.compensation.wiener import wiener_deconvolve
from edofproj.evaluation.timing import time_methods
from edofproj.imaging.projection import project
from edofproj.methods.builder import PreparedMethod
from edofproj.methods.catalogue import method_spec
from edofproj.methods.compensators import ConstrainedCompensation, EnsembleWienerCompensation, no_compensation


def gaussian_psf(sigma: float, size: int = 9, energy: float = 0.97) -> np.ndarray:
    delta = np.zeros((size, size))
    delta[size // 2, size // 2] = 1.0
    psf = ndimage.gaussian_filter(delta, sigma)
    return np.repeat((energy * psf / psf.sum())[None], 3, axis=0)


def smooth_image(seed: int = 0, size: int = 64) -> torch.Tensor:
    noise = np.random.default_rng(seed).uniform(0, 1, (3, size, size))
    return torch.from_numpy(ndimage.gaussian_filter(noise, (0, 2, 2)) * 0.8 + 0.1).float()[None]


def test_ensemble_of_one_depth_is_the_wiener_filter_of_that_depth():
    """With one PSF, G = conj(H) / (|H|^2 + NSR): the same as Wiener deconvolution (both reflect
    the borders), up to the kernel cut."""
    psf = gaussian_psf(1.0)
    image = smooth_image()
    ensemble = EnsembleWienerCompensation(psf[None], nsr=1e-2, radius=20, grid=128)
    ours = ensemble(image, image, torch.from_numpy(psf)[None])
    reference = wiener_deconvolve(image, torch.from_numpy(psf).float(), 1e-2)
    torch.testing.assert_close(ours[..., 10:-10, 10:-10], reference[..., 10:-10, 10:-10], atol=2e-3, rtol=0)


def test_ensemble_is_one_filter_for_every_depth_and_beats_no_compensation_there():
    psfs = np.stack([gaussian_psf(s) for s in (0.8, 1.4, 2.0)])
    noise = np.random.default_rng(1).uniform(0, 1, (3, 64, 64))
    image = torch.from_numpy(ndimage.gaussian_filter(noise, (0, 0.7, 0.7)) * 0.6 + 0.2).float()[None]
    ensemble = EnsembleWienerCompensation(torch.from_numpy(psfs), nsr=1e-3, radius=12, grid=64)
    outputs = [ensemble(image, image, torch.from_numpy(p)[None]) for p in psfs]
    assert all(torch.equal(outputs[0], out) for out in outputs[1:])  # blind: the PSF argument is unused
    for p in psfs:
        psf = torch.from_numpy(p).float()[None]
        compensated = float(((project(outputs[0], psf) - image) ** 2).mean())
        plain = float(((project(image, psf) - image) ** 2).mean())
        assert compensated < 0.95 * plain


def test_doe_ensemble_is_blind_and_uses_the_runs_doe():
    spec = method_spec("doe+ensemble")
    assert spec.blind and spec.optics == "run" and spec.compensation == "ensemble"
    assert not method_spec("doe+wiener").blind and method_spec("doe+net").blind


def test_time_methods_times_every_method_as_evaluated():
    psf = torch.from_numpy(gaussian_psf(1.2)).float()
    design = types.SimpleNamespace(psf=lambda depths: psf[None].repeat(len(depths), 1, 1, 1))
    calls = []

    def counting(target, captured, psf_):
        calls.append(captured.shape)
        return target

    methods = [
        PreparedMethod(method_spec("doe"), design, no_compensation),
        PreparedMethod(method_spec("lens+cls"), design, ConstrainedCompensation(30)),
        PreparedMethod(method_spec("doe+net"), design, counting),
    ]
    times = time_methods(methods, smooth_image()[0], 0.5, repeats=3)
    assert list(times) == ["doe", "lens+cls", "doe+net"] and all(t >= 0 for t in times.values())
    assert times["lens+cls"] > times["doe"]
    assert len(calls) == 4 and calls[0] == (1, 3, 64, 64)  # one untimed call, then 3 timed


def test_a_classic_baseline_run_of_the_configured_element_shares_its_design():
    """``cubic+net``'s run holds the cubic plate of the evaluated configuration: one design for every cubic
    method (its 2-D PSFs simulated once); a plate of another strength or sampling keeps its own design."""
    from pathlib import Path

    from edofproj.config import load_config
    from edofproj.doe import build_doe
    from edofproj.methods.builder import MethodBuilder, same_classic_element

    cfg = load_config("cpu")
    builder = MethodBuilder(None, cfg, Path("."), explicit=True)
    shared = builder.classic_design("cubic")
    same = load_config("cpu", ["doe.kind=cubic", "train.steps=5"])  # the element is what matters, not training
    run = types.SimpleNamespace(cfg=same, doe=build_doe(same))
    assert same_classic_element(same, cfg, "cubic")
    assert builder.baseline_design(method_spec("cubic+net"), run) is shared
    for other in (["doe.cubic_waves=20"], ["psf.pupil_samples=2048"], ["doe.levels=8"], ["doe.min_feature_um=2"]):
        other_cfg = load_config("cpu", ["doe.kind=cubic", *other])
        assert not same_classic_element(other_cfg, cfg, "cubic"), other
        own = builder.baseline_design(method_spec("cubic+net"), types.SimpleNamespace(cfg=other_cfg, doe=run.doe))
        assert own is not shared and own.key == "cubic_net"
    # a plate of other parameters is named in the notes (the cubic methods then compare two plates); another
    # pupil sampling of the same plate is not
    assert builder.notes[0].startswith("cubic+net: its run's cubic is not the one the evaluated configuration")
    assert "(doe.cubic_waves=20.0 (the configuration: 5.0))" in builder.notes[0]
    assert len(builder.notes) == 3 and not any("pupil_samples" in note for note in builder.notes)
    axicon = load_config("cpu", ["doe.kind=axicon", "doe.cubic_waves=20"])  # an axicon does not read the plate's key
    assert same_classic_element(axicon, cfg, "axicon") and not same_classic_element(axicon, cfg, "cubic")


def test_methods_already_built_are_taken_as_they_are():
    """The demo's scene and surface sections score the flat-screen evaluation's methods: build_all takes
    a method of ``built`` by name (the same object: its tuned filter, network and PSFs) and builds the rest."""
    from pathlib import Path

    from edofproj.config import load_config
    from edofproj.methods.builder import MethodBuilder
    from edofproj.progress import StageProgress

    cfg = load_config("cpu")
    psf = torch.from_numpy(gaussian_psf(1.2)).float()
    design = types.SimpleNamespace(key="lens", psf=lambda depths: psf[None].repeat(len(depths), 1, 1, 1))
    earlier = PreparedMethod(method_spec("lens+cls"), design, ConstrainedCompensation(30))
    builder = MethodBuilder(None, cfg, Path("."), explicit=True)
    progress = StageProgress("test", enabled=False)
    specs = [method_spec("lens"), method_spec("lens+cls")]
    taken = builder.build_all(specs, progress, built=[earlier])
    assert [m.name for m in taken] == ["lens", "lens+cls"] and taken[1] is earlier
    assert taken[0].design is builder.designs["lens"]  # built here: the run's bare lens
    rebuilt = MethodBuilder(None, cfg, Path("."), explicit=True).build_all(specs, progress)
    assert rebuilt[1] is not earlier and rebuilt[1].design is not design
