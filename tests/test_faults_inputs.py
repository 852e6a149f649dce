"""Fault tier: inputs that must be physical (PSFs, designs), damaged files, memory limits, messages."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.config import Config, apply_overrides
from edofproj.doe import build_doe, load_doe, save_doe
from edofproj.errors import ConfigError, EdofprojError
from edofproj.fileio import read_arrays
from edofproj.limits import ENV_LIMIT, MemoryLimitError, available_memory_bytes, check_memory, format_bytes
from edofproj.optics.psf_bank import PSFBank, simulator_from_config
from edofproj.optics.psf_checks import validate_psf
from tiny_configs import TINY_TRAINING


def gaussian_psf(n_depths=2, channels=3, window=11, energy=0.9, sigma=1.5) -> np.ndarray:
    """Gaussian spots holding ``energy`` of the light each (an independent, closed-form PSF)."""
    c = np.arange(window) - window // 2
    spot = np.exp(-(c[:, None] ** 2 + c[None, :] ** 2) / (2 * sigma**2))
    spot *= energy / spot.sum()
    return np.broadcast_to(spot, (n_depths, channels, window, window)).copy()


DEPTHS = [0.4, 0.6]


# ----------------------------------------------------------------------------- PSFs


def test_a_physical_psf_passes_measured_and_simulated():
    validate_psf(gaussian_psf(), DEPTHS, measured=False)
    validate_psf(gaussian_psf(), DEPTHS, measured=True)


@pytest.mark.parametrize(
    "edit, expected",
    [
        (lambda p: p * 0, "holds no light"),
        (lambda p: -p, "holds no light"),
        (lambda p: p * 1.2, "exceeds 1"),
        (lambda p: np.where(np.arange(p.size).reshape(p.shape) == 7, np.nan, p), "NaN or infinite"),
        (lambda p: p[..., :-1, :-1], "odd side"),
        (lambda p: p[..., :, :-2], "square"),
        (lambda p: p[:1], "1 PSF\\(s\\) but 2 depth"),
        (lambda p: p[0], "must be \\(n_depths"),
        (lambda p: p - 0.9 * np.roll(p, 4, axis=-1), "negative light"),  # a negative lobe, energy 0.09
    ],
)
def test_unphysical_psfs_are_refused_in_one_line(edit, expected):
    with pytest.raises(EdofprojError, match=expected) as refused:
        validate_psf(edit(gaussian_psf()), DEPTHS, source="PSF file 'x.npz'", measured=True)
    assert "\n" not in str(refused.value) and "x.npz" in str(refused.value)


def test_measurement_noise_is_accepted_but_not_from_a_simulation():
    rng = np.random.default_rng(1)
    noisy = gaussian_psf(window=21) + rng.normal(0, 2e-4, (2, 3, 21, 21))  # zero-mean noise, unclipped
    assert noisy.min() < 0
    validate_psf(noisy, DEPTHS, measured=True)
    with pytest.raises(EdofprojError, match="simulated noise"):
        validate_psf(noisy, DEPTHS, measured=False)


def test_the_depths_must_be_positive_and_finite():
    with pytest.raises(EdofprojError, match="positive and finite"):
        validate_psf(gaussian_psf(), [0.4, -0.6])


def _write_bank(path, psf, depths=DEPTHS):
    PSFBank(psf=torch.from_numpy(psf), depths_m=np.array(depths), pixel_pitch_m=np.full(len(depths), 1e-3)).save(path)


def test_psf_files_pass_the_check_on_load(tmp_path):
    good = tmp_path / "good.npz"
    _write_bank(good, gaussian_psf().astype(np.float32))
    assert PSFBank.load(good).psf.shape == (2, 3, 11, 11)
    zero = tmp_path / "zero.npz"
    _write_bank(zero, np.zeros((2, 3, 11, 11), np.float32))
    with pytest.raises(EdofprojError, match="zero.npz' holds no light at depth 0 \\(400.0 mm\\), channel R"):
        PSFBank.load(zero)


def test_the_simulator_output_passes_the_simulated_check(tiny_config):
    """The physics of the engines (energy <= 1, intensities >= 0) within the simulated tolerances."""
    cfg = tiny_config()
    bank = simulator_from_config(cfg).bank(build_doe(cfg, "lens"), np.array([0.35, 0.5, 0.8]))
    validate_psf(bank.psf, bank.depths_m, measured=False)
    assert float(bank.psf.min()) >= 0 and float(bank.energy_in_window.max()) <= 1


# ----------------------------------------------------------------------------- damaged and foreign files


def test_a_text_file_named_npz_is_refused_without_numpy_advice(tmp_path):
    text = tmp_path / "x.npz"
    text.write_text("not an archive")
    with pytest.raises(EdofprojError) as refused:
        PSFBank.load(text)
    assert "is not a NumPy .npz/.npy file" in str(refused.value) and "allow_pickle" not in str(refused.value)


def test_pickled_objects_are_refused_without_numpy_advice(tmp_path):
    path = tmp_path / "objects.npz"
    np.savez(path, psf=np.array([{"a": 1}], dtype=object))
    with pytest.raises(EdofprojError) as refused:
        read_arrays(path, "PSF file")
    assert "Python objects" in str(refused.value) and "allow_pickle" not in str(refused.value)


def _claiming_header(path, shape, archive=False) -> None:
    """A ``.npy`` (or a ``.npz`` holding one) whose header declares ``shape`` float32 over 64 bytes of data."""
    import io
    import zipfile

    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "<f4", "fortran_order": False, "shape": shape})
    buffer.write(b"\0" * 64)
    if archive:
        with zipfile.ZipFile(path, "w") as handle:
            handle.writestr("psf.npy", buffer.getvalue())
    else:
        path.write_bytes(buffer.getvalue())


@pytest.mark.parametrize("archive", [False, True])
def test_an_array_file_whose_header_claims_a_huge_shape_is_refused_before_reading(tmp_path, monkeypatch, archive):
    path = tmp_path / ("huge.npz" if archive else "huge.npy")
    _claiming_header(path, (100_000, 100_000, 3), archive)
    monkeypatch.setenv(ENV_LIMIT, str(2**30))
    allocated = []
    monkeypatch.setattr(np, "fromfile", lambda *a, **k: allocated.append(a) or np.zeros(0))
    with pytest.raises(MemoryLimitError, match=r"header declares an array of shape \(100000, 100000, 3\)"):
        read_arrays(path, "texture")
    assert not allocated


@pytest.mark.parametrize("archive", [False, True])
def test_an_array_file_whose_header_claims_more_than_it_holds_is_truncated(tmp_path, archive):
    path = tmp_path / ("cut.npz" if archive else "cut.npy")
    _claiming_header(path, (400, 300, 3), archive)  # 1.4 MB declared, 64 bytes held
    with pytest.raises(EdofprojError, match="is truncated: its header declares 1440000 bytes"):
        read_arrays(path, "texture")


@pytest.mark.slow
def test_every_command_refuses_a_huge_array_header_in_one_line(tmp_path, capsys, monkeypatch):
    """render --surface/--depth-map, compensate --depth-map, evaluate --surface: one line, exit 2."""
    from edofproj.imaging.image_io import write_image

    monkeypatch.setenv(ENV_LIMIT, str(2**30))
    huge_rgb, huge_map = tmp_path / "rgb.npy", tmp_path / "map.npy"
    _claiming_header(huge_rgb, (100_000, 100_000, 3))
    _claiming_header(huge_map, (200_000, 150_000))
    image = tmp_path / "t.png"
    write_image(image, torch.rand(3, 48, 64))
    render = ["render", "--image", str(image), "--doe", "lens", "--out", str(tmp_path / "o.png")]
    for argv in (
        render + ["--depth-mm", "400", "--surface", str(huge_rgb)],
        render + ["--depth-map", str(huge_map)],
        ["compensate", "builtin:cpu-doe-net", "--images", str(tmp_path), "--depth-map", str(huge_map)]
        + ["--out", str(tmp_path.parent / f"{tmp_path.name}-u")],  # outside the input folder
        ["evaluate", "builtin:cpu-doe-net", "--surface", str(huge_rgb), "--methods", "doe", "--depths-mm", "400"]
        + ["--out", str(tmp_path / "ev"), "--quiet"],
    ):
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = [line for line in capsys.readouterr().err.strip().splitlines() if "older edofproj" not in line]
        assert len(err) == 1 and "header declares an array of shape" in err[0], (argv, err)
    assert not (tmp_path / "o.png").exists() and not (tmp_path.parent / f"{tmp_path.name}-u").exists()


@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.95])
def test_truncated_archives_are_refused_in_one_line(tmp_path, fraction):
    good = tmp_path / "good.npz"
    _write_bank(good, gaussian_psf().astype(np.float32))
    data = good.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(EdofprojError, match="truncated or damaged"):
        PSFBank.load(cut)


# ----------------------------------------------------------------------------- design files


@pytest.fixture
def design_file(tmp_path):
    cfg = apply_overrides(Config(), TINY_TRAINING + ["doe.kind=axicon"])
    path = tmp_path / "design.npz"
    save_doe(build_doe(cfg), path, samples=64)
    return path


def _edit(path, target, **changes):
    data = dict(np.load(path, allow_pickle=False))
    for key, value in changes.items():
        if value is None:
            del data[key]
        else:
            data[key] = value(data[key])
    np.savez(target, **data)
    return target


def test_a_saved_design_round_trips_through_the_check(design_file):
    doe = load_doe(design_file)
    assert len(doe.table_height_m) == 32


@pytest.mark.parametrize(
    "changes, expected",
    [
        ({"height_m": None}, "lacks height_m"),
        ({"ring_edges_m": None, "height_m": None}, "lacks ring_edges_m, height_m"),
        ({"height_m": lambda h: h[:10], "level": lambda v: v[:10]}, "10 heights need one more ring edge, got 33"),
        ({"ring_edges_m": lambda e: e[::-1].copy()}, "increase strictly"),
        ({"ring_edges_m": lambda e: e - 1e-3}, "start at r >= 0"),
        ({"height_m": lambda h: np.where(np.arange(h.size) == 3, np.inf, h)}, "NaN or infinite heights"),
        ({"aperture_radius_m": lambda r: -r}, "aperture_radius_m = .* must be positive"),
        ({"levels": lambda v: np.array(2.5)}, "whole number"),
        ({"format": lambda f: np.array("something-else")}, "is not an edofproj DOE file"),
        ({"kind": lambda k: np.array("spiral")}, "unknown kind 'spiral'"),
    ],
)
def test_inconsistent_designs_are_refused_in_one_line(design_file, tmp_path, changes, expected):
    bad = _edit(design_file, tmp_path / "bad.npz", **changes)
    with pytest.raises(EdofprojError, match=expected) as refused:
        load_doe(bad)
    assert "\n" not in str(refused.value) and "bad.npz" in str(refused.value)


# ----------------------------------------------------------------------------- memory limits


def test_format_bytes_uses_binary_units():
    assert format_bytes(512) == "512 B" and format_bytes(1536) == "1.5 KiB" and format_bytes(3 * 2**30) == "3.0 GiB"


def test_the_memory_available_is_known_here_and_capped_by_the_environment(monkeypatch):
    machine = available_memory_bytes()
    assert machine is not None and machine > 0
    monkeypatch.setenv(ENV_LIMIT, "1000000")
    assert available_memory_bytes() == 1_000_000


def test_an_address_space_limit_caps_the_memory_available(tmp_path):
    """Under ``ulimit -v`` the room left below the limit counts (checked in a child process)."""
    import subprocess
    import sys

    code = (
        "import resource; from edofproj.limits import available_memory_bytes as a;"
        "resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, resource.RLIM_INFINITY)); print(a())"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout
    assert 0 < int(out) < 3 * 2**30


def test_a_request_beyond_the_memory_says_what_it_needs_and_what_to_change(monkeypatch):
    monkeypatch.setenv(ENV_LIMIT, str(2**30))
    check_memory(2**29, "half a GiB", "nothing")
    with pytest.raises(MemoryLimitError, match="needs about 2.0 GiB of memory, more than the 1.0 GiB available: do X"):
        check_memory(2**31, "a thing", "do X")


def test_a_huge_psf_window_is_refused_by_the_config_before_anything_is_allocated():
    with pytest.raises(MemoryLimitError, match="psf.window=100001 needs about 670.6 GiB .*smaller psf.window"):
        apply_overrides(Config(), ["psf.window=100001"])


def test_the_radial_engine_checks_its_tables_against_the_memory(monkeypatch):
    cfg = apply_overrides(Config(), TINY_TRAINING)
    simulator_from_config(cfg)  # fits
    monkeypatch.setenv(ENV_LIMIT, str(10**5))
    with pytest.raises(MemoryLimitError, match="radial PSF engine"):
        simulator_from_config(cfg)


def test_the_2d_engine_checks_its_fft_against_the_memory(monkeypatch):
    cfg = apply_overrides(Config(), TINY_TRAINING + ["psf.engine=2d"])
    monkeypatch.setenv(ENV_LIMIT, str(10**6))
    with pytest.raises(MemoryLimitError, match="2-D PSF engine"):
        simulator_from_config(cfg)


def test_pattern_sets_are_refused_before_they_are_drawn():
    from edofproj.procams.patterns import PatternSpec

    spec = PatternSpec(width=100000, height=100000)
    assert spec.memory_bytes() > 10 * 2**40  # 227 patterns of 10^10 px
    with pytest.raises(
        MemoryLimitError, match=r"a set of 227 patterns of 100000x100000 px \(height x width\) needs about 25.0 TiB"
    ):
        spec.validate()


def test_an_image_too_large_for_the_memory_is_refused_from_its_header(tmp_path, monkeypatch):
    import cv2

    from edofproj.imaging.image_io import image_file_size, read_image

    path = tmp_path / "wide.png"
    cv2.imwrite(str(path), np.zeros((300, 2000), np.uint8))
    assert image_file_size(path) == (300, 2000)
    monkeypatch.setenv(ENV_LIMIT, str(300 * 2000 * 10))
    with pytest.raises(MemoryLimitError, match=r"300x2000 \(height x width\) image"):
        read_image(path)


# ----------------------------------------------------------------------------- messages


def test_an_empty_override_is_refused_instead_of_becoming_none():
    with pytest.raises(ConfigError, match="override 'train.steps=' has no value"):
        apply_overrides(Config(), ["train.steps="])


def test_a_device_argument_for_the_cpu_uses_the_machine_memory(monkeypatch):
    from edofproj.limits import available_device_memory_bytes

    monkeypatch.setenv(ENV_LIMIT, "123456")
    assert available_device_memory_bytes(torch.device("cpu")) == available_device_memory_bytes(None) == 123456
    with pytest.raises(MemoryLimitError, match="of memory, more than"):
        check_memory(10**6, "x", "y", device=torch.device("cpu"))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_cuda_request_is_checked_against_the_gpu_memory():
    free, total = torch.cuda.mem_get_info()
    check_memory(free // 2, "half the free GPU memory", "nothing", device=torch.device("cuda"))
    with pytest.raises(MemoryLimitError, match="of GPU memory"):
        check_memory(2 * total, "twice the GPU", "use a smaller request", device=torch.device("cuda"))
