"""The die around the DOE: alignment marks, die outline, substrate, and the tone of each mask.

A clean room aligns mask ``j > 0`` to what mask 0 etched, cuts dies out of a substrate and needs to
know which side of each drawn polygon is chrome. The layout (micrometres, centred on the optical axis):

* **Alignment marks**: a cross at each of two sites on the x axis, ``x = +-mark_site_um`` (outside the
  clear aperture, inside the die), on *every* mask layer and on the aperture layer. Mask 0 etches its
  crosses (the reference); each later mask prints the same cross at the same sites, with a square frame
  around it (box-in-box: the gap between cross and frame, :data:`FRAME_GAP_UM` on each side, is read
  under the microscope as the overlay error). The aperture layer draws a clear window over each site so
  that the chrome stop leaves the marks visible.
* **Die outline** (layer :data:`DIE_LAYER`): a square of side ``die_mm`` (``fabrication.die_mm``; 0: the
  smallest multiple of 0.5 mm holding the aperture and the marks with a 1 mm margin), the dicing line.
* **Substrate**: ``fabrication.substrate_diameter_mm`` x ``substrate_thickness_mm`` of the DOE's material;
  the report counts the whole dies of a square grid centred on the wafer that fit inside its
  ``fabrication.edge_exclusion_mm``.
* **Mask tone** (``fabrication.resist``): with a positive resist the exposed resist is removed and the
  substrate etched there, so a mask layer's polygons (the etched regions) are the *clear* openings of a
  **dark-field** mask (chrome elsewhere); with a negative resist the exposed resist stays, so the etched
  regions must be dark: the polygons are the *chrome* of a **clear-field** mask. The aperture layer
  (layer 100) draws the clear aperture and the mark windows: with lift-off of the chrome stop through a
  positive resist, a clear-field mask whose polygons are chrome.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gdstk
import numpy as np

from ..errors import EdofprojError

#: GDSII layer of the die outline (the dicing line).
DIE_LAYER = 101
#: Cross arm length (tip to tip) and bar width of an alignment mark, um.
CROSS_LENGTH_UM = 200.0
CROSS_WIDTH_UM = 10.0
#: Gap between a later mask's cross and its frame, and the frame's width, um.
FRAME_GAP_UM = 20.0
FRAME_WIDTH_UM = 10.0
#: Clear margin between the aperture's edge and a mark's frame, and around the marks inside the die, um.
MARK_MARGIN_UM = 500.0
DIE_MARGIN_UM = 1000.0
#: Dies are laid out in steps of this size, um.
DIE_STEP_UM = 500.0

RESISTS = ("positive", "negative")


def frame_half_um() -> float:
    """Half the outer size of a mark's frame: the cross's half length plus the gap and the frame."""
    return CROSS_LENGTH_UM / 2 + FRAME_GAP_UM + FRAME_WIDTH_UM


def mark_site_um(aperture_radius_m: float) -> float:
    """``x`` of the two alignment sites (``+-``): the aperture's edge, :data:`MARK_MARGIN_UM`, then a frame."""
    return aperture_radius_m * 1e6 + MARK_MARGIN_UM + frame_half_um()


def auto_die_um(aperture_radius_m: float) -> float:
    """The smallest multiple of :data:`DIE_STEP_UM` holding the marks (and the aperture) with :data:`DIE_MARGIN_UM`."""
    need = 2 * (mark_site_um(aperture_radius_m) + frame_half_um() + DIE_MARGIN_UM)
    return float(math.ceil(need / DIE_STEP_UM) * DIE_STEP_UM)


@dataclass(frozen=True)
class DieLayout:
    """The die of one DOE: its side, the alignment sites, the substrate and the resist."""

    die_um: float
    mark_sites_um: tuple[tuple[float, float], ...]
    substrate_diameter_mm: float
    substrate_thickness_mm: float
    edge_exclusion_mm: float
    resist: str

    @classmethod
    def from_config(cls, fabrication_cfg, aperture_radius_m: float) -> "DieLayout":
        """The layout for ``fabrication_cfg`` (:class:`~edofproj.config.FabricationConfig`) around an aperture of
        radius ``aperture_radius_m``; refuses a die that does not hold the marks or a substrate that holds no die."""
        site = mark_site_um(aperture_radius_m)
        smallest = 2 * (site + frame_half_um())
        die_um = fabrication_cfg.die_mm * 1e3 if fabrication_cfg.die_mm > 0 else auto_die_um(aperture_radius_m)
        if die_um < smallest:
            raise EdofprojError(
                f"fabrication.die_mm={fabrication_cfg.die_mm:g} is smaller than the aperture and its alignment marks "
                f"({smallest / 1e3:.2f} mm): give at least that, or 0 (chosen)"
            )
        layout = cls(
            die_um=float(die_um),
            mark_sites_um=((-site, 0.0), (site, 0.0)),
            substrate_diameter_mm=float(fabrication_cfg.substrate_diameter_mm),
            substrate_thickness_mm=float(fabrication_cfg.substrate_thickness_mm),
            edge_exclusion_mm=float(fabrication_cfg.edge_exclusion_mm),
            resist=fabrication_cfg.resist,
        )
        if layout.dies_per_substrate() < 1:
            raise EdofprojError(
                f"a {die_um / 1e3:g} mm die does not fit on the {layout.substrate_diameter_mm:g} mm substrate inside "
                f"its {layout.edge_exclusion_mm:g} mm edge exclusion: use a larger fabrication.substrate_diameter_mm"
            )
        return layout

    def dies_per_substrate(self) -> int:
        """Whole dies of a square grid centred on the substrate (a die's corner at the centre or a die centred on
        it, whichever holds more) whose four corners lie inside the usable radius (diameter / 2 - edge exclusion)."""
        radius = self.substrate_diameter_mm / 2 - self.edge_exclusion_mm
        side = self.die_um / 1e3
        if radius <= 0:
            return 0
        n = int(radius // side) + 2
        best = 0
        for offset in (0.0, 0.5):
            centres = (np.arange(-n, n + 1) + offset) * side
            cx, cy = np.meshgrid(centres, centres)
            corner = np.hypot(np.abs(cx) + side / 2, np.abs(cy) + side / 2)
            best = max(best, int(np.sum(corner <= radius + 1e-12)))
        return best

    def tone(self, layer: str) -> dict:
        """The tone of a mask layer (``"etch"`` or ``"aperture"``): what its drawn polygons are on the plate."""
        if layer == "aperture":
            return {
                "field": "clear field",
                "polygons": "chrome on the plate (the clear aperture and mark windows, where the chrome stop "
                "must not be deposited; lift-off through a positive resist)",
            }
        if self.resist == "positive":
            return {"field": "dark field", "polygons": "clear openings in chrome (positive resist: exposed = etched)"}
        return {"field": "clear field", "polygons": "chrome on the plate (negative resist: unexposed = etched)"}

    def as_dict(self, levels_material: str) -> dict:
        """The report's ``die`` entry: die, marks, substrate, dies per substrate, resist and tones."""
        return {
            "die_mm": self.die_um / 1e3,
            "die_gds_layer": DIE_LAYER,
            "alignment_marks": {
                "sites_um": [list(site) for site in self.mark_sites_um],
                "cross_length_um": CROSS_LENGTH_UM,
                "cross_width_um": CROSS_WIDTH_UM,
                "frame_gap_um": FRAME_GAP_UM,
                "frame_width_um": FRAME_WIDTH_UM,
                "scheme": "mask 0 etches a cross at each site (the reference); every later mask prints the same cross "
                "inside a square frame (box-in-box: the cross-to-frame gap on each side reads the overlay error); "
                "the aperture layer opens a window over each site",
            },
            "substrate": {
                "material": levels_material,
                "diameter_mm": self.substrate_diameter_mm,
                "thickness_mm": self.substrate_thickness_mm,
                "edge_exclusion_mm": self.edge_exclusion_mm,
                "dies": self.dies_per_substrate(),
            },
            "resist": self.resist,
            "etch_mask_tone": self.tone("etch"),
            "aperture_mask_tone": self.tone("aperture"),
        }


def cross_polygons(x_um: float, y_um: float, layer: int) -> list[gdstk.Polygon]:
    """An alignment cross centred at ``(x, y)``: two bars :data:`CROSS_LENGTH_UM` long, :data:`CROSS_WIDTH_UM` wide
    (the horizontal bar whole, the vertical one in two halves beside it: no overlapping polygons)."""
    half, w = CROSS_LENGTH_UM / 2, CROSS_WIDTH_UM / 2
    return [
        gdstk.rectangle((x_um - half, y_um - w), (x_um + half, y_um + w), layer=layer),
        gdstk.rectangle((x_um - w, y_um + w), (x_um + w, y_um + half), layer=layer),
        gdstk.rectangle((x_um - w, y_um - half), (x_um + w, y_um - w), layer=layer),
    ]


def frame_polygons(x_um: float, y_um: float, layer: int) -> list[gdstk.Polygon]:
    """The square frame around a later mask's cross (inner half-size: the cross's half length plus the gap)."""
    inner = CROSS_LENGTH_UM / 2 + FRAME_GAP_UM
    outer = inner + FRAME_WIDTH_UM
    ring = gdstk.boolean(
        gdstk.rectangle((x_um - outer, y_um - outer), (x_um + outer, y_um + outer)),
        gdstk.rectangle((x_um - inner, y_um - inner), (x_um + inner, y_um + inner)),
        "not",
        layer=layer,
    )
    return list(ring)


def mark_polygons(layout: DieLayout, mask_index: int, layer: int) -> list[gdstk.Polygon]:
    """The alignment marks of mask ``mask_index`` on GDS ``layer`` at every site: a cross; a frame too after mask 0."""
    polygons = []
    for x, y in layout.mark_sites_um:
        polygons += cross_polygons(x, y, layer)
        if mask_index > 0:
            polygons += frame_polygons(x, y, layer)
    return polygons


def window_polygons(layout: DieLayout, layer: int) -> list[gdstk.Polygon]:
    """Clear windows over the alignment sites on the aperture layer (the chrome stop must not bury the marks)."""
    half = frame_half_um() + FRAME_GAP_UM
    return [gdstk.rectangle((x - half, y - half), (x + half, y + half), layer=layer) for x, y in layout.mark_sites_um]


def die_outline(layout: DieLayout) -> gdstk.Polygon:
    """The die's outline on :data:`DIE_LAYER`: a square of side ``die_um`` centred on the axis."""
    half = layout.die_um / 2
    return gdstk.rectangle((-half, -half), (half, half), layer=DIE_LAYER)
