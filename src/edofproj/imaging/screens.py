"""Screen shapes as per-pixel depth maps: the tilted plane.

Geometry (top view; projector lens at the origin, optical axis along +z, image centred on
the axis). Projector column ``c`` of an image ``W`` pixels wide sends its light along the
ray ``x = u_c z`` with

    u_c = (c - (W - 1) / 2) / (T * W_panel)          (pinhole model; q(z) = z / (T W_panel))

where ``T`` is the throw ratio and ``W_panel`` the projector's width in pixels
(:class:`~edofproj.optics.geometry.ProjectorGeometry`, ``throw_width_m = T * W_panel``).
A plane screen rotated by ``tilt`` about the vertical axis, ``z = z0 + x tan(tilt)``, is met
by that ray at the axial depth

    z_c = z0 / (1 - u_c tan(tilt)),   i.e.   1/z_c = 1/near + c/(W-1) * (1/far - 1/near),

so the *inverse* depth is affine across the columns and constant down each column, for any
throw ratio: the depths ``near`` and ``far`` seen by the first and the last column fix the
map. (Depth linear in ``c`` would be the first-order approximation of this; for 600-800 mm
the two differ by at most 2 %.) The angle, throw ratio and width then relate as

    far / near = (1 + u_e tan(tilt)) / (1 - u_e tan(tilt)),    u_e = (W - 1) / (2 T W_panel),

see :func:`tilted_plane_far_m` and :func:`tilted_plane_tilt_deg`. In
:func:`tilted_plane_depth_map` ``near`` and ``far`` are authoritative; ``tilt_deg`` gives the
orientation: ``tilt > 0`` puts ``near`` on the left (as in the paper's Fig. 10),
``tilt < 0`` on the right, ``tilt = 0`` is a fronto-parallel screen (``near == far``).

``tilt`` is the angle between the screen's normal and the optical axis (0: the screen faces
the projector). Depth means the axial distance ``z``, which is what the PSF depends on: in
projector pixel (angle) coordinates a ray from pupil point ``a`` aimed at the in-focus point
lands at ``u0 + a (1/z - 1/v)``, where ``z`` is the axial depth where it meets the screen,
so a tilted screen blurs each pixel like a fronto-parallel screen at the local depth (up to
the depth change across the blur spot itself).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import EdofprojError


def _check_positive_depth(value: float, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise EdofprojError(f"{name}={value:g} m must be a positive depth")
    return value


def _check_tilt(tilt_deg: float) -> float:
    tilt_deg = float(tilt_deg)
    if not (math.isfinite(tilt_deg) and abs(tilt_deg) < 90.0):
        raise EdofprojError(f"tilt {tilt_deg:g} deg must lie strictly between -90 and 90 degrees")
    return tilt_deg


def edge_ray_slope(width_px: int, geometry) -> float:
    """``u_e = (W - 1) / (2 T W_panel)``: tan of the angle between the axis and the outermost column's ray."""
    if int(width_px) < 1:
        raise EdofprojError(f"image width {width_px} px must be >= 1")
    return (int(width_px) - 1) / (2.0 * geometry.throw_width_m)


def tilted_plane_depth_map(height_px: int, width_px: int, tilt_deg: float, near_m: float, far_m: float) -> np.ndarray:
    """Axial depth (m) of each pixel of a plane screen tilted about the vertical axis, ``(H, W)``.

    ``1/z`` varies linearly from ``1/near_m`` at the first column to ``1/far_m`` at the last
    (module docstring); ``tilt_deg > 0``: near on the left, ``< 0``: near on the right,
    ``0``: a fronto-parallel screen, which needs ``near_m == far_m``.
    """
    height_px, width_px = int(height_px), int(width_px)
    if height_px < 1 or width_px < 1:
        raise EdofprojError(f"depth map size {height_px}x{width_px} px must be at least 1x1")
    tilt_deg = _check_tilt(tilt_deg)
    near_m = _check_positive_depth(near_m, "near")
    far_m = _check_positive_depth(far_m, "far")
    if tilt_deg == 0.0 and not math.isclose(near_m, far_m, rel_tol=1e-9):
        raise EdofprojError(
            f"tilt 0 deg is a fronto-parallel screen: near ({near_m * 1e3:g} mm) must equal far ({far_m * 1e3:g} mm)"
        )
    if tilt_deg != 0.0 and not near_m < far_m:
        raise EdofprojError(
            f"a tilted screen ({tilt_deg:g} deg) needs near < far, got near {near_m * 1e3:g} mm, far {far_m * 1e3:g} mm"
        )
    fraction = np.arange(width_px) / (width_px - 1) if width_px > 1 else np.zeros(1)
    if tilt_deg < 0:
        fraction = fraction[::-1]
    inverse_depth = 1.0 / near_m + fraction * (1.0 / far_m - 1.0 / near_m)
    return np.broadcast_to(1.0 / inverse_depth, (height_px, width_px)).copy()


def tilted_plane_far_m(near_m: float, tilt_deg: float, width_px: int, geometry) -> float:
    """The far-edge depth of a plane tilted by ``tilt_deg`` whose near edge is at ``near_m``.

    ``far = near (1 + u_e t) / (1 - u_e t)`` with ``t = tan|tilt|`` and ``u_e`` from
    :func:`edge_ray_slope`; the plane must not be parallel to the outermost ray (``u_e t < 1``).
    """
    near_m = _check_positive_depth(near_m, "near")
    slope = edge_ray_slope(width_px, geometry) * math.tan(math.radians(abs(_check_tilt(tilt_deg))))
    if slope >= 1.0:
        limit = math.degrees(math.atan(1.0 / edge_ray_slope(width_px, geometry)))
        raise EdofprojError(
            f"a screen tilted by {abs(tilt_deg):g} deg never meets the image's edge ray (throw ratio and width allow "
            f"at most {limit:.1f} deg)"
        )
    return near_m * (1.0 + slope) / (1.0 - slope)


def tilted_plane_tilt_deg(near_m: float, far_m: float, width_px: int, geometry) -> float:
    """The tilt (deg, >= 0) of a plane whose first/last columns see depths ``near_m``/``far_m``.

    Inverse of :func:`tilted_plane_far_m`: ``tan(tilt) = (far - near) / ((far + near) u_e)``.
    """
    near_m = _check_positive_depth(near_m, "near")
    far_m = _check_positive_depth(far_m, "far")
    u_e = edge_ray_slope(width_px, geometry)
    if u_e == 0.0:
        return 0.0
    return math.degrees(math.atan(abs(far_m - near_m) / ((far_m + near_m) * u_e)))
