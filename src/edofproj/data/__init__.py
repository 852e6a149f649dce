"""Images: training sources (built-in photographs, image folders, dead leaves) and held-out test images.

* :mod:`.photos` -- the built-in photographs, image folders, the deterministic split, random crops;
* :mod:`.dead_leaves` -- synthetic scale-invariant images;
* :mod:`.sources` -- :func:`build_training_source` for a :class:`~edofproj.config.DataConfig`;
* :mod:`.test_images` -- the held-out test images and the images an evaluation scores.
"""

from .dead_leaves import (
    DeadLeavesSource,
    dead_leaves_image,
    dead_leaves_labels,
    disks_per_covering_layer,
    natural_color_palette,
    paint_front_most,
    power_law_quantile,
    sample_dead_leaves_disks,
)
from .photos import (
    BUILTIN_PHOTOS,
    FolderSource,
    PhotoSource,
    as_rgb,
    builtin_photo_source,
    builtin_split,
    find_image_files,
    folder_split,
    load_builtin_photo,
    probe_image_size,
    random_crop,
    split_names,
)
from .sources import MixedSource, build_training_source, describe_training_data
from .test_images import build_test_images, evaluation_images, fit_image, fit_to_size, folder_images

__all__ = [
    "BUILTIN_PHOTOS",
    "DeadLeavesSource",
    "FolderSource",
    "MixedSource",
    "PhotoSource",
    "as_rgb",
    "build_test_images",
    "build_training_source",
    "builtin_photo_source",
    "builtin_split",
    "dead_leaves_image",
    "dead_leaves_labels",
    "describe_training_data",
    "disks_per_covering_layer",
    "evaluation_images",
    "find_image_files",
    "fit_image",
    "fit_to_size",
    "folder_images",
    "folder_split",
    "load_builtin_photo",
    "natural_color_palette",
    "paint_front_most",
    "power_law_quantile",
    "probe_image_size",
    "random_crop",
    "sample_dead_leaves_disks",
    "split_names",
]
