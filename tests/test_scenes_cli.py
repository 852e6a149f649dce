"""``edofproj scene``: a render end to end, and bad input (one line, exit 2, nothing written)."""

from __future__ import annotations

import numpy as np
import pytest

from edofproj.cli import main
from edofproj.imaging import read_image, write_image
from edofproj.scenes.builtin import sphere_mesh

H, W = 24, 32
SMALL = [
    "optics.width_px=32",
    "optics.height_px=24",
    "psf.pupil_samples=384",
    "psf.window=15",
    "psf.depth_min_mm=300",
    "psf.depth_max_mm=800",
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
    "imaging.depth_layers=3",
]


def overrides(extra=()):
    return [arg for item in SMALL + list(extra) for arg in ("--set", item)]


@pytest.fixture
def image_path(tmp_path):
    import torch

    path = tmp_path / "in.png"
    write_image(path, torch.rand(3, H, W, generator=torch.Generator().manual_seed(0)))
    return path


def render(scene, image_path, out_dir, *extra):
    return main(
        ["scene", "render", "--scene", str(scene), "--doe", "lens", "--image", str(image_path)]
        + ["--out", str(out_dir / "out.png"), "--depth-out", str(out_dir / "depth.npy")]
        + ["--figure", str(out_dir / "figure.png")]
        + overrides()
        + list(extra)
    )


@pytest.mark.slow
def test_scene_render_writes_projection_depth_and_figure(tmp_path, image_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    assert render("sphere_wall", image_path, out) == 0
    depth_mm = np.load(out / "depth.npy")
    assert depth_mm.dtype == np.float32 and depth_mm.shape == (H, W)
    assert np.nanmin(depth_mm) == pytest.approx(340, abs=3) and np.nanmax(depth_mm) == pytest.approx(750)
    assert read_image(out / "out.png").shape == (3, H, W)
    assert (out / "figure.png").stat().st_size > 0
    assert "sphere_wall" in capsys.readouterr().out
    # render --depth-map reads the same array
    assert (
        main(
            ["render", "--image", str(image_path), "--out", str(out / "again.png"), "--doe", "lens"]
            + ["--depth-map", str(out / "depth.npy")]
            + overrides()
        )
        == 0
    )


def write_mesh(path, mesh):
    mesh.export(path)
    return path


def bad_cases(tmp_path):
    garbage = tmp_path / "garbage.glb"
    garbage.write_bytes(b"glTF\x02\x00\x00\x00 this is not a binary glTF file")
    empty = tmp_path / "empty.obj"
    empty.write_text("v 0 0 0\nv 1 0 0\n")
    holed = sphere_mesh(0.05, (0.0, 0.0, 0.5), subdivisions=2)
    holed.update_faces(holed.face_normals[:, 2] > -0.5)  # the side facing the projector removed
    return {
        "cannot read mesh": garbage,
        "holds no triangles": empty,
        "does not exist": tmp_path / "missing.stl",
        "outside the projector's view": write_mesh(tmp_path / "aside.stl", sphere_mesh(0.05, (3.0, 0.0, 0.5))),
        "depth_max_mm) cover 300.0-800.0 mm": write_mesh(tmp_path / "far.ply", sphere_mesh(0.05, (0.0, 0.0, 1.5))),
        "not watertight": write_mesh(tmp_path / "holed.obj", holed),
        "neither a built-in scene": tmp_path / "scene.txt",
    }


def test_bad_scenes_fail_with_one_line_and_write_nothing(tmp_path, image_path, capsys):
    for expected, scene in bad_cases(tmp_path).items():
        out = tmp_path / f"out_{scene.stem}"
        out.mkdir()
        assert render(scene, image_path, out) == 2, expected
        err = capsys.readouterr().err.strip()
        assert err.startswith("edofproj: error:") and "\n" not in err and expected in err, err
        assert list(out.iterdir()) == [], expected


def test_bad_scene_file_keys(tmp_path, image_path, capsys):
    (tmp_path / "bad.yaml").write_text("meshes:\n  - file: x.stl\n    colour: red\n")
    out = tmp_path / "out"
    out.mkdir()
    assert render(tmp_path / "bad.yaml", image_path, out) == 2
    assert "unknown key(s) colour" in capsys.readouterr().err
    assert list(out.iterdir()) == []


def test_scene_list(capsys):
    assert main(["scene", "list", "--set", "optics.width_px=80", "--set", "optics.height_px=60"]) == 0
    text = capsys.readouterr().out
    for name in ("box_corner", "sphere", "cylinder", "steps", "sphere_wall"):
        assert name in text


@pytest.mark.slow  # trains a tiny run
def test_scene_render_run_is_the_render_compensate_render_chain(tmp_path, image_path, capsys):
    """``scene render --run RUN`` = ``scene render --doe RUN`` -> ``compensate --capture`` -> ``scene render``
    of the projector input, each step through the command line (16-bit files; issue 29)."""
    from edofproj.config import load_config
    from edofproj.training.trainer import train
    from tiny_configs import TINY_EVALUATION

    run = tmp_path / "run"
    train(load_config(None, TINY_EVALUATION + ["psf.depth_min_mm=300"]), run, progress=False)
    config = ["--config", str(run / "config.yaml"), "--bits", "16"]
    scene = ["scene", "render", "--scene", "sphere_wall"]

    def files(*names):
        return [str(tmp_path / name) for name in names]

    assert (
        main(
            [*scene, "--run", str(run), "--image", str(image_path), "--bits", "16"]
            + ["--out", *files("shown.png")]
            + ["--projector-out", *files("x.png")]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "over the objects' pixels against the image: compensated SSIM" in printed and "uncompensated SSIM" in printed
    # the same by hand
    assert main([*scene, "--doe", str(run), "--image", str(image_path), "--out", *files("captured.png"), *config]) == 0
    compensate = ["compensate", str(run), "--image", str(image_path), "--capture", *files("captured.png")]
    assert main([*compensate, "--out", *files("x_by_hand.png"), "--bits", "16"]) == 0
    assert (
        main([*scene, "--doe", str(run), "--image", *files("x_by_hand.png"), "--out", *files("by_hand.png"), *config])
        == 0
    )
    by_hand, shown = read_image(tmp_path / "by_hand.png"), read_image(tmp_path / "shown.png")
    assert shown.shape == (3, H, W)
    np.testing.assert_allclose(read_image(tmp_path / "x.png"), read_image(tmp_path / "x_by_hand.png"), atol=2e-3)
    np.testing.assert_allclose(shown, by_hand, atol=2e-3)  # 16-bit files and their rounding between the steps


def test_scene_render_run_refuses_a_config_and_projector_out_needs_run(tmp_path, image_path, capsys):
    out = ["--out", str(tmp_path / "o.png")]
    argv = ["scene", "render", "--scene", "sphere_wall", "--image", str(image_path), *out]
    assert main([*argv, "--run", "builtin:cpu-doe-net", "--config", "cpu"]) == 2
    assert "--run renders with the run's own configuration" in capsys.readouterr().err
    assert main([*argv, "--doe", "lens", "--projector-out", str(tmp_path / "x.png")]) == 2
    assert "--projector-out goes with --run" in capsys.readouterr().err
    assert not (tmp_path / "o.png").exists()
