"""What the ``procams`` steps share."""

from __future__ import annotations


def note_width(manifest, cfg) -> None:
    """Say so when the patterns are not as wide as the projector the optics config describes."""
    if manifest.width != cfg.optics.width_px:
        print(
            f"note: the patterns are {manifest.width} px wide but optics.width_px is {cfg.optics.width_px}: "
            "PSFs and pixel pitch are for the latter (patterns = a crop of its image; else pass --width-px)"
        )
