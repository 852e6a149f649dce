"""Where a nearly empty primary loses its level: the compensation chain of trained runs, stage by stage.

For each run and screen depth, images with one primary at a few per cent of full scale go through

    I  ->  base B(I)  ->  x = net(I, I*)  ->  clamp(x, 0, 1)  ->  display = project(clamp(x), p_z)

where ``B`` is the network's linear stage (its learned radial pre-filter ``J = h * I``, or the
depth-ensemble filter ``E(I)`` of a safe network; ``I`` itself for a plain U-Net), and prints the
mean of the empty channel over the centre of the image at every stage (the projector input ``x``
before the clamp, and the share of its pixels below 0), next to the display of the DOE's
depth-ensemble linear filter (NSR 0.01, ``doe+ensemble``) for comparison. The images:

* ``uniform R/G/B 5 %`` -- a flat colour with that primary at 5 % and the others at 0.8 / 0.7
  (the closed-form check: it must come back at 5 % +- 0.5 %);
* ``textured, blue flat 5 %`` -- the validation photograph ``camera`` in red and green (x0.8,
  x0.9) over a flat 5 % blue: detail in two primaries, none in the empty one;
* ``Minduka, blue 8 %`` -- the validation class ``colour/Minduka_near_empty_blue``.

    PYTHONPATH=src python benchmarks/colour_levels.py RUN [RUN ...] [--depths-mm 300,500,800] [--size 128]
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
import torch

from edofproj.compensation.linear_base import LinearBase
from edofproj.data.validation import validation_images
from edofproj.imaging.projection import project
from edofproj.optics.psf_bank import design_engine, simulator_from_config
from edofproj.runs import load_run
from edofproj.training.linear_filter import current_linear_filter

MARGIN = 16


def test_images(size: int) -> list[tuple[str, int, torch.Tensor]]:
    """``(name, empty channel, (1, 3, size, size))``."""
    images = []
    for channel, label in enumerate("RGB"):
        colour = torch.tensor([0.8, 0.7, 0.7])
        colour[channel] = 0.05
        if channel == 1:
            colour = torch.tensor([0.8, 0.05, 0.7])
        images.append((f"uniform {label} 5 %", channel, colour.view(1, 3, 1, 1).expand(1, 3, size, size).clone()))
    named = dict(validation_images((size, size), names=["skimage/camera", "colour/Minduka_near_empty_blue"]))
    camera = named["skimage/camera"][0]
    textured = torch.stack([0.8 * camera, 0.9 * camera, torch.full_like(camera, 0.05)])[None]
    images.append(("textured, blue flat 5 %", 2, textured))
    images.append(("Minduka, blue 8 %", 2, named["colour/Minduka_near_empty_blue"][None]))
    return images


def centre_mean(image: torch.Tensor, channel: int) -> float:
    return float(image[0, channel, MARGIN:-MARGIN, MARGIN:-MARGIN].mean())


def base_of(net, image: torch.Tensor) -> torch.Tensor:
    if isinstance(getattr(net, "linear_base", None), LinearBase):
        return net.linear_base(image)
    prefilter = getattr(net, "prefilter", None)
    return prefilter(image) if prefilter is not None else image


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--depths-mm", default="300,500,800")
    parser.add_argument("--size", type=int, default=128)
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    depths_m = np.array([float(z) for z in args.depths_mm.split(",")]) * 1e-3
    images = test_images(args.size)
    print(
        "| run | image | depth (mm) | target | base | x (unclamped) | x < 0 | emitted | display | doe+ensemble display |"
    )
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for run_name in args.runs:
        run = load_run(run_name)
        simulator = simulator_from_config(run.cfg, engine=design_engine(run.doe, run.cfg.psf.engine))
        with torch.no_grad():
            ensemble = current_linear_filter(run.cfg, lambda z: simulator(run.doe, z).float())
            for name, channel, image in images:
                for z, psf in zip(depths_m, simulator(run.doe, depths_m).float()):
                    psf = psf[None]
                    captured = project(image, psf)
                    x = run.net(image, captured)
                    emitted = x.clamp(0, 1)
                    display = project(emitted, psf)
                    linear = project(ensemble(image), psf)
                    negative = float((x[0, channel, MARGIN:-MARGIN, MARGIN:-MARGIN] < 0).float().mean())
                    cells = [centre_mean(t, channel) for t in (image, base_of(run.net, image), x, emitted, display)]
                    print(
                        f"| {run_name} | {name} | {z * 1e3:.0f} | "
                        + " | ".join(f"{100 * c:.2f} %" for c in cells[:3])
                        + f" | {100 * negative:.0f} % | "
                        + " | ".join(f"{100 * c:.2f} %" for c in cells[3:])
                        + f" | {100 * centre_mean(linear, channel):.2f} % |"
                    )


if __name__ == "__main__":
    main()
