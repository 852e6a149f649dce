"""Image formation: FFT convolution, projection with haze, depth-layer rendering, image files.

* :mod:`.convolution` -- linear 'same' convolution by FFT (zero padding, no wrap-around);
* :mod:`.projection` -- ``project(image, psf, haze=True)``: one screen depth (paper Eq. 9);
* :mod:`.depth_layers` -- ``render_depth_map``: a screen whose depth varies per pixel;
* :mod:`.screens` -- screen shapes as depth maps (the tilted plane);
* :mod:`.surfaces` -- coloured, textured surfaces: ``c = s ⊙ A(L) + a`` (reflectance, ambient);
* :mod:`.image_io` -- ``read_image`` / ``write_image``.
"""

from .convolution import convolve_same  # noqa: F401
from .depth_layers import bank_layers, layer_depths_m, layer_weights, render_depth_map  # noqa: F401
from .image_io import read_image, write_image  # noqa: F401
from .projection import haze_term, project  # noqa: F401
from .screens import tilted_plane_depth_map, tilted_plane_far_m, tilted_plane_tilt_deg  # noqa: F401
