"""``edofproj compensate --psf-map``: round trips through image files (8 and 16 bits, one image and a
folder) and one-line refusals with a non-zero exit and nothing written."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.imaging.image_io import read_image, write_image
from edofproj.procams.measured_blur import measured_blur
from edofproj.procams.psf_map import PSFMap, covariance, load_psf_maps

H, W = 40, 56


@pytest.fixture
def lab(tmp_path):
    xs, ys = np.arange(0.0, W, 8.0), np.arange(0.0, H, 8.0)
    cov = np.array([[covariance(0.7 + 0.8 * x / W, 1.0 + 0.5 * x / W, 0.3) for x in xs] for _ in ys])
    path = tmp_path / "map.npz"
    PSFMap(xs=xs, ys=ys, cov=cov, offset_px=np.zeros(2), fitted=np.ones(cov.shape[:2], bool), projector_hw=(H, W)).save(
        path
    )
    generator = torch.Generator().manual_seed(0)
    truth = torch.nn.functional.avg_pool2d(torch.rand(1, 3, H + 2, W + 2, generator=generator), 3, 1)[0]
    target = measured_blur(load_psf_maps(path))(truth[None].double())[0].float()  # achievable: cls can show it
    write_image(tmp_path / "target.png", target, bits=16)
    (tmp_path / "show").mkdir()
    write_image(tmp_path / "show" / "a.png", target, bits=8)
    write_image(tmp_path / "show" / "b.png", truth, bits=8)
    return tmp_path


@pytest.mark.parametrize("bits", [8, 16])
def test_cls_writes_a_projector_image_whose_blur_is_the_target(lab, capsys, bits):
    out = lab / f"proj{bits}.png"
    code = main(["compensate", "--psf-map", str(lab / "map.npz"), "--image", str(lab / "target.png"),
                 "--method", "cls", "--nsr", "1e-3", "--iterations", "150", "--bits", str(bits), "--out", str(out)])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    assert f"{H}x{W} px" in printed and "objective" in printed
    x = read_image(out)
    assert tuple(x.shape) == (3, H, W)
    target = read_image(lab / "target.png")
    shown = measured_blur(load_psf_maps(lab / "map.npz"))(x[None].double())[0].float()
    mse = float(((shown - target) ** 2).mean())
    # quantizing x to 8 bits costs about (1/255)^2 / 12 of error: 8-bit output >= 45 dB, 16-bit >= 40 dB met easily
    assert 10 * np.log10(1 / mse) >= 40.0
    # 16-bit files hold 16-bit levels
    import cv2

    assert cv2.imread(str(out), cv2.IMREAD_UNCHANGED).dtype == (np.uint16 if bits == 16 else np.uint8)


def test_wiener_on_a_folder(lab, capsys):
    out = lab / "show_out"
    code = main(["compensate", "--psf-map", str(lab / "map.npz"), "--images", str(lab / "show"),
                 "--method", "wiener", "--nsr", "3e-3", "--rank-tolerance", "0.03", "--out", str(out)])  # fmt: skip
    assert code == 0
    assert sorted(p.name for p in out.iterdir()) == ["a.png", "b.png"]
    assert "2 images" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--depth-mm", "500"], "--depth-mm do(es) not go with --psf-map"),
        (["--method", "doe+net"], "does not go with --psf-map"),
        (["--method", "net"], "--method net needs the run"),
        (["--method", "wiener", "--iterations", "5"], "--iterations goes with --method cls"),
        (["--method", "wiener", "--solver", "lbfgs"], "--solver goes with --method cls"),
        (["--nsr", "-1"], "NSR"),
        (["--rank-tolerance", "2"], "rank tolerance"),
    ],
)
def test_bad_requests_end_in_one_line(lab, capsys, extra, message):
    out = lab / "bad.png"
    code = main(
        ["compensate", "--psf-map", str(lab / "map.npz"), "--image", str(lab / "target.png"), "--out", str(out)] + extra
    )
    err = capsys.readouterr().err
    assert code != 0 and message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_wrong_size_missing_map_and_output_over_input(lab, capsys, tmp_path):
    write_image(lab / "small.png", torch.zeros(3, H - 1, W), bits=8)
    cases = [
        (
            ["--psf-map", str(lab / "map.npz"), "--image", str(lab / "small.png"), "--out", str(lab / "o.png")],
            "height x width",
        ),
        (
            ["--psf-map", str(lab / "nothing.npz"), "--image", str(lab / "target.png"), "--out", str(lab / "o.png")],
            "nothing.npz",
        ),
        (
            ["--psf-map", str(lab / "map.npz"), "--image", str(lab / "target.png"), "--out", str(lab / "target.png")],
            "--out",
        ),
        (["--method", "cls", "--image", str(lab / "target.png"), "--out", str(lab / "o.png")], "--psf-map"),
        (["--image", str(lab / "target.png"), "--out", str(lab / "o.png")], "give RUN"),
    ]
    before = (lab / "target.png").read_bytes()
    for argv, message in cases:
        code = main(["compensate", *argv, "--nsr", "1e-3"] if "--psf-map" in argv else ["compensate", *argv])
        err = capsys.readouterr().err
        assert code != 0 and message in err and len(err.strip().splitlines()) == 1, (argv, err)
        assert not (lab / "o.png").exists()
    assert (lab / "target.png").read_bytes() == before


def test_cls_by_default_runs_the_solvers_default_iterations_and_says_so(lab, capsys):
    from edofproj.commands import _compensate_psf_map
    from edofproj.compensation import field_varying

    assert _compensate_psf_map.DEFAULT_CLS_ITERATIONS == field_varying.DEFAULT_CLS_ITERATIONS
    out = lab / "default.png"
    code = main(["compensate", "--psf-map", str(lab / "map.npz"), "--image", str(lab / "target.png"),
                 "--nsr", "1e-3", "--out", str(out)])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    assert "method cls" in printed and "NSR 0.001" in printed
    assert f"in {field_varying.DEFAULT_CLS_ITERATIONS} iterations" in printed
    start, end = (float(v) for v in printed.split("objective ")[1].split(" in ")[0].split(" -> "))
    assert end < start
    named = lab / f"{field_varying.DEFAULT_CLS_SOLVER}.png"
    assert main(["compensate", "--psf-map", str(lab / "map.npz"), "--image", str(lab / "target.png"),
                 "--nsr", "1e-3", "--solver", field_varying.DEFAULT_CLS_SOLVER, "--out", str(named)]) == 0  # fmt: skip
    assert named.read_bytes() == out.read_bytes()  # the default is the solver it names


def test_the_quasi_newton_solver_reaches_a_lower_objective_than_fista_in_as_many_steps(lab, capsys):
    finals = {}
    for solver in ("fista", "lbfgs"):
        out = lab / f"{solver}.png"
        code = main(["compensate", "--psf-map", str(lab / "map.npz"), "--image", str(lab / "target.png"),
                     "--nsr", "1e-3", "--iterations", "8", "--solver", solver, "--out", str(out)])  # fmt: skip
        assert code == 0
        printed = capsys.readouterr().out
        start, finals[solver] = (float(v) for v in printed.split("objective ")[1].split(" in ")[0].split(" -> "))
        assert finals[solver] < start
    assert finals["lbfgs"] < finals["fista"]
