"""``evaluate RUN --surface``: the methods on textured surfaces, their relations, files and bad input."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.compensation.achievable import achievable_goal
from edofproj.compensation.surface_net import SurfaceAwareNet
from edofproj.compensation.unet import CompensationUNet
from edofproj.imaging import write_image
from edofproj.imaging.projection import project
from edofproj.methods.builder import PreparedMethod
from edofproj.methods.catalogue import method_spec
from edofproj.methods.compensators import NetworkCompensation, no_compensation
from edofproj.methods.surface_variants import PHOTOMETRIC, SURFACE_NET, surface_methods

H, W = 32, 40


class StubDesign:
    """An optical design whose PSF is the same Gaussian (or an impulse) at every depth."""

    key = "run"

    def __init__(self, sigma: float | None):
        size = 9
        if sigma is None:
            kernel = torch.zeros(size, size)
            kernel[size // 2, size // 2] = 1
        else:
            r2 = (torch.arange(size) - size // 2)[:, None] ** 2 + (torch.arange(size) - size // 2)[None, :] ** 2
            kernel = torch.exp(-r2 / (2 * sigma**2))
        self.kernel = (kernel / kernel.sum())[None, None].repeat(1, 3, 1, 1)

    def psf(self, depths_m):
        return self.kernel.expand(len(np.atleast_1d(depths_m)), 3, -1, -1)


def methods_on(design, inner):
    prepared = [
        PreparedMethod(method_spec("doe"), design, no_compensation),
        PreparedMethod(method_spec("doe+net"), design, NetworkCompensation(inner)),
    ]
    return {m.name: m for m in surface_methods(prepared, SurfaceAwareNet(inner))}


def surface_case(seed=0):
    g = torch.Generator().manual_seed(seed)
    rho = 0.1 + 0.9 * torch.rand(1, 3, H, W, generator=g)
    ambient = 0.05 * rho
    goal = achievable_goal(torch.rand(1, 3, H, W, generator=g), rho, ambient).image
    return rho, ambient, goal


def run_method(method, design, rho, ambient, goal):
    psf = design.psf([0.5])[:1]

    def screen(image):
        return rho * project(image, psf) + ambient

    with torch.no_grad():
        return screen(method.compensate(goal, screen(goal), psf, rho, ambient, screen))


def test_methods_on_a_surface_and_their_relations():
    inner = CompensationUNet([4, 8])
    with torch.no_grad():
        for p in inner.parameters():
            p.add_(0.05 * torch.randn_like(p))
    blurry = StubDesign(1.5)
    methods = methods_on(blurry, inner)
    assert list(methods) == ["doe", "doe" + PHOTOMETRIC, "doe+net", "doe+net" + PHOTOMETRIC, SURFACE_NET]
    rho, ambient, goal = surface_case()
    shown = {name: run_method(m, blurry, rho, ambient, goal) for name, m in methods.items()}
    # an untrained surface network (its head is zero) is exactly the photometric-then-defocus cascade
    torch.testing.assert_close(shown[SURFACE_NET], shown["doe+net" + PHOTOMETRIC], atol=1e-5, rtol=0)
    # uncompensated: the goal as projected
    torch.testing.assert_close(shown["doe"], rho * project(goal, blurry.psf([0.5])[:1]) + ambient)
    # through a sharp projector the photometric correction shows the goal wherever it is reachable
    sharp = StubDesign(None)
    exact = run_method(methods_on(sharp, inner)["doe" + PHOTOMETRIC], sharp, rho, ambient, goal)
    reachable = (goal >= ambient) & (goal <= ambient + rho)
    torch.testing.assert_close(exact[reachable], goal[reachable], atol=1e-5, rtol=0)


def test_bad_surface_options_are_one_line_errors(tmp_path, capsys):
    base = ["evaluate", "builtin:cpu-doe-net", "--out", str(tmp_path / "out"), "--quiet"]
    cases = [
        (["--surface", "nowhere-texture"], "neither a built-in texture"),
        (["--surface", "checker", "--ambient", "-0.5"], "--ambient -0.5 must lie in [0, 1]"),
        (["--surface", "checker", "--ambient", "5"], "--ambient 5 must lie in [0, 1]: a fraction of the projector's"),
        (["--surface", "checker", "--ambient", "1e30"], "--ambient 1e+30 must lie in [0, 1]"),
        (["--ambient", "0.1"], "--ambient goes with --surface"),
        (["--surface", "checker", "--scene", "steps"], "give --surface or --scene, not both"),
    ]
    black = tmp_path / "black.npy"  # an all-zero surface shows nothing: it would score SSIM 1, PSNR inf
    np.save(black, np.zeros((256, 256, 3), np.float32))
    cases.append((["--surface", "checker", "--surface", str(black)], f"surface '{black}' cannot show an image"))
    small = tmp_path / "small.png"
    write_image(small, torch.full((3, 8, 8), 0.5))
    cases.append((["--surface", str(small), "--set", "evaluation.image_size=[48,64]"], "is 8x8 px but the projector"))
    for extra, message in cases:
        assert main(base + extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "out" / "surface_metrics.csv").exists()


@pytest.mark.slow
def test_evaluate_surfaces_of_a_surface_run_and_white_matches_the_flat_evaluation(tmp_path, capsys):
    """A run trained with net.surface_input: every method on white and a texture; on the white screen
    (ambient 0) the scores of doe and doe+net equal those of the flat-screen evaluation (its own pipeline)."""
    from edofproj.config import load_config
    from edofproj.evaluation.pipeline import evaluate_run
    from edofproj.training.trainer import train
    from tiny_configs import TINY_EVALUATION

    run = tmp_path / "run"
    train(load_config(None, TINY_EVALUATION + ["net.surface_input=true"]), run, progress=False)
    out = tmp_path / "eval"
    dark = tmp_path / "dark.npy"
    np.save(dark, np.full((48, 64, 3), 0.02, np.float32))
    code = main(
        ["evaluate", str(run), "--surface", "white", "--surface", "checker", "--surface", str(dark)]
        + ["--methods", "doe,doe+net", "--depths-mm", "300,500", "--ambient", "0.0", "--out", str(out), "--quiet"]
    )
    assert code == 0
    err = capsys.readouterr().err
    assert f"note: surface '{dark}': the surface is too dark for image" in err
    assert "checker': the surface is too dark" not in err
    with open(out / "surface_metrics.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert {r["method"] for r in rows} == {"doe", "doe+photometric", "doe+net", "doe+net+photometric", SURFACE_NET}
    assert {r["surface"] for r in rows} == {"white", "checker", str(dark)}
    assert (out / "surface_summary.md").is_file() and (out / "figures" / "eval_surfaces.png").is_file()
    flat = evaluate_run(run, out_dir=tmp_path / "flat", depths_mm=[300, 500], methods=["doe", "doe+net"])
    for method in ("doe", "doe+net"):
        for depth in (300, 500):
            ours = [
                float(r["ssim"])
                for r in rows
                if (r["method"], r["surface"], float(r["depth_mm"])) == (method, "white", depth)
            ]
            theirs = flat.table.values("ssim", method=method, depth_mm=depth)
            np.testing.assert_allclose(sorted(ours), sorted(theirs), atol=1e-5)
