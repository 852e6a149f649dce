"""``edofproj procams patterns``: the calibration and PSF-measurement patterns, with their manifest.

    edofproj procams patterns --width W --height H --out PATTERNS [--structured-light]

Bernoulli noise patterns (PSF measurement), a dot grid and full fields (geometric calibration) and
uniform colour samples (colour calibration), written as PNGs beside ``manifest.json``. With
``--structured-light``, also Gray codes and multi-frequency phase shifts along both axes, a grid of
single-pixel dots and black/white fields, listed in ``lab.json`` (:mod:`edofproj.procams.lab_manifest`).
"""

from __future__ import annotations

from ...errors import EdofprojError


def register(subparsers) -> None:
    """Add ``procams patterns`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("patterns", help="write the calibration and PSF-measurement patterns with manifest.json")
    p.add_argument("--width", type=int, required=True, help="projector width, pixels")
    p.add_argument("--height", type=int, required=True, help="projector height, pixels")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--bernoulli", type=int, default=5, metavar="N", help="number of Bernoulli noise patterns (5)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the noise patterns (0)")
    p.add_argument("--dots", default="16x32", metavar="ROWSxCOLS", help="dot grid (16x32, as in the paper)")
    p.add_argument(
        "--dot-radius",
        type=int,
        default=None,
        metavar="PX",
        help="dot radius in pixels (default: 1/8 of the smaller dot spacing)",
    )
    p.add_argument(
        "--color-levels",
        type=int,
        default=6,
        metavar="L",
        help="levels per channel of the colour samples: L^3 uniform fields (6)",
    )
    p.add_argument(
        "--structured-light",
        action="store_true",
        help="also write Gray codes and multi-frequency phase shifts along both axes, a grid of single-pixel dots "
        "and black/white fields, listed in lab.json (for 'procams decode', 'psf-map' and 'predict')",
    )
    p.add_argument("--steps", type=int, default=4, help="phase-shift steps per period count (4)")
    p.add_argument("--dot-spacing", type=int, default=12, metavar="PX", help="single-pixel dot spacing, px (12)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.capture_io import atomic_folder, write_rgb_png
    from ...procams.patterns import MANIFEST_NAME, PatternSpec, build_pattern_set, manifest_json_text, parse_grid

    spec = PatternSpec(
        width=args.width,
        height=args.height,
        bernoulli_count=args.bernoulli,
        seed=args.seed,
        dot_grid=parse_grid(args.dots),
        dot_radius_px=args.dot_radius,
        color_levels=args.color_levels,
    )
    manifest, images = build_pattern_set(spec)
    lab = None
    structured: dict = {}
    if args.structured_light:
        import json

        import numpy as np

        from ...procams.lab_manifest import LAB_MANIFEST_NAME, structured_light_set

        if args.dot_spacing < 4:
            raise EdofprojError(f"--dot-spacing {args.dot_spacing} must be at least 4 px")
        lab, structured = structured_light_set(
            (args.height, args.width), steps=args.steps, dot_spacing_px=args.dot_spacing
        )
    with atomic_folder(args.out, overwrite=args.overwrite, what="edofproj procams patterns") as tmp:
        for name, image in images.items():
            write_rgb_png(tmp / name, image)
        for name, grey in structured.items():
            write_rgb_png(tmp / name, np.repeat(grey[..., None], 3, axis=-1))
        (tmp / MANIFEST_NAME).write_text(manifest_json_text(manifest), encoding="utf-8")
        if lab is not None:
            (tmp / LAB_MANIFEST_NAME).write_text(json.dumps(lab.to_json(), indent=1) + "\n", encoding="utf-8")
    counts = {role: len(manifest.with_role(role)) for role in ("bernoulli", "color_sample")}
    print(
        f"wrote {len(images)} patterns of {args.height}x{args.width} (height x width) to {args.out}: {counts['bernoulli']} Bernoulli, "
        f"{spec.dot_grid[0]}x{spec.dot_grid[1]} dots, 5 full fields, {counts['color_sample']} colour samples"
    )
    if lab is not None:
        kinds = ", ".join(f"{s.name} ({len(s.files)})" for s in lab.sequences)
        print(f"and {len(structured)} structured-light patterns listed in lab.json: {kinds}")
    return 0
