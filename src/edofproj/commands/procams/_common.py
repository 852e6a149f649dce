"""What the ``procams`` steps share."""

from __future__ import annotations


def note_width(manifest, cfg) -> None:
    """Say so when the patterns are not as wide as the projector the optics config describes."""
    if manifest.width != cfg.optics.width_px:
        print(
            f"note: the patterns are {manifest.width} px wide but optics.width_px is {cfg.optics.width_px}: "
            "PSFs and pixel pitch are for the latter (patterns = a crop of its image; else pass --width-px)"
        )


def lab_inputs(lab: str, root: str | None) -> list[tuple[str, object]]:
    """The capture files the lab manifest ``lab`` lists (under ``root``), named for the
    output-over-input rule (:func:`edofproj.commands._common.refuse_output_over`): an output option
    may name none of them (a ``--figure`` named like a capture would replace it)."""
    from ...procams.lab_manifest import LabManifest

    manifest = LabManifest.load(lab, root)
    return [(f"--lab's '{seq.name}' capture", manifest.root / name) for seq in manifest.sequences for name in seq.files]
