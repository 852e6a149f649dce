"""Image files: bit depths, channel order, grey and alpha handling, corrupt files, atomic writes."""

import cv2
import numpy as np
import pytest
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging.image_io import read_image, write_image


def test_16_bit_png_round_trip_is_exact_to_one_code(tmp_path):
    image = torch.rand(3, 13, 17)
    write_image(tmp_path / "a.png", image, bits=16)
    back = read_image(tmp_path / "a.png")
    assert back.shape == (3, 13, 17) and back.dtype == torch.float32
    assert (back - image).abs().max() <= 0.5 / 65535 + 1e-7
    assert cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16


def test_8_bit_round_trip_and_rgb_order_on_disk(tmp_path):
    image = torch.zeros(3, 4, 5)
    image[0] = 1.0  # pure red
    image[2, 1, 1] = 0.5
    write_image(tmp_path / "red.png", image)
    on_disk = cv2.imread(str(tmp_path / "red.png"), cv2.IMREAD_UNCHANGED)  # OpenCV: BGR
    assert on_disk.dtype == np.uint8
    assert on_disk[0, 0].tolist() == [0, 0, 255]
    assert on_disk[1, 1].tolist() == [128, 0, 255]
    back = read_image(tmp_path / "red.png")
    assert (back - image).abs().max() <= 0.5 / 255 + 1e-7


def test_values_outside_0_1_are_clamped_and_nan_refused(tmp_path):
    write_image(tmp_path / "c.png", torch.tensor([-1.0, 0.25, 2.0]).reshape(3, 1, 1).expand(3, 2, 2))
    np.testing.assert_allclose(read_image(tmp_path / "c.png")[:, 0, 0].numpy(), [0.0, 64 / 255, 1.0])
    with pytest.raises(EdofprojError, match="NaN"):
        write_image(tmp_path / "n.png", torch.full((3, 2, 2), float("nan")))
    assert not (tmp_path / "n.png").exists()


def test_grey_becomes_three_equal_channels_and_alpha_is_dropped(tmp_path):
    grey = np.arange(20, dtype=np.uint16).reshape(4, 5) * 3000
    cv2.imwrite(str(tmp_path / "g16.png"), grey)
    image = read_image(tmp_path / "g16.png")
    assert image.shape == (3, 4, 5)
    for c in range(3):
        np.testing.assert_allclose(image[c].numpy(), grey / 65535, atol=1e-7)
    bgra = np.zeros((3, 3, 4), np.uint8)
    bgra[..., 1] = 200
    bgra[..., 3] = 7  # nearly transparent: ignored, not composited
    cv2.imwrite(str(tmp_path / "rgba.png"), bgra)
    image = read_image(tmp_path / "rgba.png")
    assert image.shape == (3, 3, 3)
    np.testing.assert_allclose(image[1].numpy(), 200 / 255)


def test_jpeg_reads_close_to_the_original(tmp_path):
    smooth = np.linspace(0, 1, 32)[None, :] * np.linspace(0.2, 1, 24)[:, None]
    image = torch.from_numpy(np.stack([smooth, smooth[::-1], 1 - smooth])).float()
    write_image(tmp_path / "s.jpg", image)
    assert (read_image(tmp_path / "s.jpg") - image).abs().mean() < 0.02
    with pytest.raises(EdofprojError, match="16-bit"):
        write_image(tmp_path / "s16.jpg", image, bits=16)


@pytest.mark.parametrize("content", [b"", b"not an image at all", "truncated-png", "truncated-jpg"])
def test_corrupt_files_raise_an_error_naming_them(tmp_path, content):
    if isinstance(content, str):
        suffix = ".png" if content.endswith("png") else ".jpg"
        ok, encoded = cv2.imencode(suffix, (np.random.default_rng(0).random((64, 64, 3)) * 255).astype(np.uint8))
        content = encoded.tobytes()[: len(encoded) // 2]
    path = tmp_path / "broken.png"
    path.write_bytes(content)
    with pytest.raises(EdofprojError, match="broken.png"):
        read_image(path)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(EdofprojError, match="does not exist"):
        read_image(tmp_path / "nope.png")
    with pytest.raises(EdofprojError, match="directory"):
        read_image(tmp_path)


def test_failed_write_keeps_the_previous_file(tmp_path):
    target = tmp_path / "keep.png"
    write_image(target, torch.full((3, 4, 4), 0.5))
    before = target.read_bytes()
    with pytest.raises(EdofprojError):
        write_image(target, torch.rand(2, 4, 4))  # wrong channel count
    with pytest.raises(EdofprojError, match="must end in"):
        write_image(tmp_path / "x.gif", torch.rand(3, 4, 4))
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.png"]  # no temporary left behind
