"""Training sources and test images: crops, flips, seeding, the held-out split, broken files."""

import dataclasses
import warnings

import cv2
import numpy as np
import pytest
import torch

from edofproj.config import DataConfig
from edofproj.data import (
    BUILTIN_PHOTOS,
    FolderSource,
    PhotoSource,
    build_test_images,
    build_training_source,
    builtin_split,
    find_image_files,
    fit_to_size,
    folder_split,
    load_builtin_photo,
    split_names,
)
from edofproj.errors import EdofprojError
from edofproj.imaging.image_io import write_image


def coordinate_image(height, width):
    """uint16 RGB image whose pixels encode their own position: R = row, G = column, B = 7."""
    y, x = np.mgrid[:height, :width]
    return np.stack([y, x, np.full_like(y, 7)], axis=-1).astype(np.uint16)


def decode_positions(crop):
    """Rows and columns of a crop of :func:`coordinate_image` (as float32 in [0, 1])."""
    values = np.rint(crop.numpy() * 65535).astype(int)
    return values[0], values[1]


def test_crops_are_windows_of_the_source_with_random_flips():
    source = PhotoSource([("coords", coordinate_image(50, 70))], crop=16)
    crops = source.sample(200, generator=torch.Generator().manual_seed(0))
    assert crops.shape == (200, 3, 16, 16) and crops.dtype == torch.float32
    flips_lr = flips_ud = 0
    for crop in crops:
        rows, cols = decode_positions(crop)
        row_step, col_step = rows[1, 0] - rows[0, 0], cols[0, 1] - cols[0, 0]
        assert abs(row_step) == 1 and abs(col_step) == 1
        np.testing.assert_array_equal(np.diff(rows, axis=0), row_step)  # contiguous, unscaled window
        np.testing.assert_array_equal(np.diff(cols, axis=1), col_step)
        assert rows.min() >= 0 and rows.max() < 50 and cols.min() >= 0 and cols.max() < 70
        flips_lr += col_step < 0
        flips_ud += row_step < 0
    assert 60 < flips_lr < 140 and 60 < flips_ud < 140  # each flip has probability 1/2


def test_same_generator_same_crops_and_seed_sets_the_default():
    cfg = DataConfig(source="builtin", crop=32)
    a = build_training_source(cfg, seed=0).sample(3, generator=torch.Generator().manual_seed(5))
    b = build_training_source(cfg, seed=1).sample(3, generator=torch.Generator().manual_seed(5))
    c = build_training_source(cfg, seed=0).sample(3, generator=torch.Generator().manual_seed(6))
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert torch.equal(build_training_source(cfg, 7).sample(2), build_training_source(cfg, 7).sample(2))
    assert a.min() >= 0 and a.max() <= 1 and a.shape == (3, 3, 32, 32)


def test_builtin_photos_load_offline_as_rgb():
    for name in BUILTIN_PHOTOS:
        pixels = load_builtin_photo(name)
        assert pixels.ndim == 3 and pixels.shape[-1] == 3 and pixels.dtype == np.uint8 and min(pixels.shape[:2]) >= 300
    grey = load_builtin_photo("brick")
    assert np.array_equal(grey[..., 0], grey[..., 1]) and np.array_equal(grey[..., 0], grey[..., 2])


def test_builtin_split_is_disjoint_deterministic_and_trains_on_train_only():
    train, test = builtin_split(0.3)
    assert set(train).isdisjoint(test) and set(train) | set(test) == set(BUILTIN_PHOTOS)
    assert len(test) == round(0.3 * len(BUILTIN_PHOTOS))
    assert test == ["chelsea", "coffee", "gravel", "stereo_motorcycle"]  # documented in the module docstring
    assert split_names(list(reversed(list(BUILTIN_PHOTOS))), 0.3) == (train, test)  # independent of order
    assert build_training_source(DataConfig(), 0).names == train
    tests = build_test_images(DataConfig())
    assert [name for name, _ in tests] == test
    for name, image in tests:
        assert image.shape == (3, *load_builtin_photo(name).shape[:2]) and image.dtype == torch.float32
    # dead leaves are tested on the same held-out photographs
    assert [n for n, _ in build_test_images(DataConfig(source="dead-leaves"))] == test


def test_test_images_resized_and_limited():
    images = build_test_images(dataclasses.replace(DataConfig(), max_test_images=2), size=(40, 60))
    assert len(images) == 2 and all(image.shape == (3, 40, 60) for _, image in images)


def test_fit_to_size_scales_to_cover_then_crops_the_centre():
    pixels = np.zeros((100, 200, 3), np.uint8)
    pixels[:, 75:125] = 255  # a centred vertical band, a quarter of the width
    out = fit_to_size(pixels, 50)  # scaled by 1/2 to 50 x 100, then the centre 50 x 50 columns
    assert out.shape == (50, 50, 3)
    np.testing.assert_array_equal(out[:, 13:37, 0] == 255, True)
    np.testing.assert_array_equal(out[:, :12, 0], 0)
    np.testing.assert_array_equal(out[:, 38:, 0], 0)


def make_folder(root):
    """Four good images in nested folders, one corrupt, one too small, one truncated, one text file."""
    rng = np.random.default_rng(0)
    (root / "a" / "b").mkdir(parents=True)
    for i, rel in enumerate(["one.png", "a/two.jpg", "a/b/three.PNG", "a/b/four.jpeg"]):
        write_image(root / rel, torch.from_numpy(rng.random((3, 40 + i, 48))).float())
    (root / "corrupt.png").write_bytes(b"definitely not a png")
    write_image(root / "small.png", torch.rand(3, 10, 10))
    ok, encoded = cv2.imencode(".png", (rng.random((64, 64, 3)) * 255).astype(np.uint8))
    (root / "a" / "truncated.png").write_bytes(encoded.tobytes()[:200])  # header intact, pixels missing
    (root / "notes.txt").write_text("not an image")


def test_folder_source_skips_bad_files_with_one_warning_each(tmp_path):
    make_folder(tmp_path)
    with pytest.warns(UserWarning) as caught:
        source = FolderSource(find_image_files(tmp_path), crop=32, root=tmp_path)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 2
    assert any("corrupt.png" in m for m in messages) and any("small.png" in m and "smaller" in m for m in messages)
    assert len(source) == 5  # four good + the truncated one (its header reads fine)
    with pytest.warns(UserWarning, match="truncated.png") as caught:
        first = source.sample(40, generator=torch.Generator().manual_seed(0))
    assert len(caught) == 1
    assert first.shape == (40, 3, 32, 32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no second warning for the same file
        again = source.sample(40, generator=torch.Generator().manual_seed(0))
    assert torch.equal(first, again)  # samples depend only on the generator


def test_folder_split_and_test_folder(tmp_path):
    make_folder(tmp_path / "data")
    train, test = folder_split(tmp_path / "data", 0.3)
    assert set(train).isdisjoint(test) and len(train) + len(test) == 7
    cfg = DataConfig(source="folder", folder=str(tmp_path / "data"), crop=16)
    with pytest.warns(UserWarning):
        names = [n for n, _ in build_test_images(cfg)]
    assert set(names) <= {p.relative_to(tmp_path / "data").as_posix() for p in test}
    (tmp_path / "held").mkdir()
    write_image(tmp_path / "held" / "x.png", torch.rand(3, 20, 30))
    cfg = dataclasses.replace(cfg, test_folder=str(tmp_path / "held"))
    assert [n for n, _ in build_test_images(cfg)] == ["x.png"]
    with pytest.warns(UserWarning):
        assert len(build_training_source(cfg, 0)) == 5  # the whole data folder minus corrupt.png and small.png


def test_missing_or_empty_folder_is_a_user_error(tmp_path):
    with pytest.raises(EdofprojError, match="does not exist"):
        build_training_source(DataConfig(source="folder", folder=str(tmp_path / "nope")), 0)
    (tmp_path / "empty").mkdir()
    with pytest.raises(EdofprojError, match="no PNG/JPEG"):
        build_training_source(DataConfig(source="folder", folder=str(tmp_path / "empty")), 0)


def test_crop_larger_than_every_image_is_a_user_error():
    source = PhotoSource([("coords", coordinate_image(20, 30))], crop=16)
    with pytest.raises(EdofprojError, match="larger than every training image"):
        source.sample(1, crop=24)


def test_dead_leaves_fraction_mixes_each_sample_and_is_validated():
    from edofproj.config import ConfigError
    from edofproj.data import MixedSource, build_training_source

    class Constant:
        crop = 8

        def __init__(self, value):
            self.value = value

        def sample(self, batch_size, crop=None, generator=None):
            return torch.full((batch_size, 3, crop or self.crop, crop or self.crop), self.value)

    def fraction_of_leaves(fraction, n=400):
        batch = MixedSource(Constant(0.0), Constant(1.0), fraction).sample(
            n, generator=torch.Generator().manual_seed(5)
        )
        return batch[:, 0, 0, 0].mean().item()

    assert fraction_of_leaves(0.0) == 0.0
    assert fraction_of_leaves(1.0) == 1.0
    assert abs(fraction_of_leaves(0.3) - 0.3) < 0.07  # binomial(400, 0.3): 3 sigma = 0.069
    source = build_training_source(dataclasses.replace(DataConfig(), crop=32, dead_leaves_fraction=0.5), seed=3)
    assert isinstance(source, MixedSource) and source.sample(4).shape == (4, 3, 32, 32)
    with pytest.raises(ConfigError, match="dead_leaves_fraction"):
        dataclasses.replace(DataConfig(), dead_leaves_fraction=1.5).validate()
    with pytest.raises(ConfigError, match="data.source=builtin or folder"):
        dataclasses.replace(DataConfig(), source="dead-leaves", dead_leaves_fraction=0.5).validate()


# --------------------------------------------------------------------------- images smaller than the evaluation size


def test_images_smaller_than_the_evaluation_size_are_skipped_with_the_rule(tmp_path):
    """A 60x60 image enlarged to 128x128 is smooth and scores well: it is not scored (issue 29)."""
    from edofproj.config import Config
    from edofproj.data import evaluation_images

    rng = np.random.default_rng(1)
    write_image(tmp_path / "big.png", torch.from_numpy(rng.random((3, 150, 140))).float())
    write_image(tmp_path / "small.png", torch.from_numpy(rng.random((3, 60, 60))).float())
    write_image(tmp_path / "narrow.png", torch.from_numpy(rng.random((3, 200, 100))).float())
    for scaling in ("crop", "cover"):
        cfg = Config()
        cfg.evaluation.image_size = [128, 128]
        cfg.evaluation.image_scaling = scaling
        with pytest.warns(UserWarning) as caught:
            images = evaluation_images(cfg, tmp_path)
        assert [name for name, _ in images] == ["big.png"] and images[0][1].shape == (3, 128, 128)
        messages = sorted(str(w.message) for w in caught)
        assert len(messages) == 2 and "narrow.png" in messages[0] and "small.png" in messages[1]
        assert "60x60 px is smaller than the evaluation size 128x128" in messages[1]
        assert "evaluation.image_size" in messages[1]
    cfg.evaluation.image_size = [256, 256]
    with pytest.warns(UserWarning), pytest.raises(EdofprojError, match="smaller than the evaluation size 256x256"):
        evaluation_images(cfg, tmp_path)
    cfg.evaluation.image_size = []  # native sizes: nothing is enlarged, everything is scored
    assert len(evaluation_images(cfg, tmp_path)) == 3


def test_training_data_summary_counts_and_splits(tmp_path):
    from edofproj.data import describe_training_data

    make_folder(tmp_path / "data")
    cfg = DataConfig(source="folder", folder=str(tmp_path / "data"), crop=16, test_fraction=0.3)
    train, test = folder_split(tmp_path / "data", 0.3)
    text = describe_training_data(cfg)
    assert "\n" not in text and f"7 images in '{tmp_path / 'data'}'" in text
    assert f"{len(train)} for training" in text and f"{len(test)} held out for testing" in text
    assert {p.name for p in train} >= {"corrupt.png", "small.png"}  # the split of make_folder's names
    assert "2 training image(s) skipped (unreadable or smaller than the 16 px crop)" in text
    builtin_train, builtin_test = builtin_split(0.3)
    text = describe_training_data(DataConfig())
    assert f"{len(builtin_train)} for training, {len(builtin_test)} held out for testing" in text
