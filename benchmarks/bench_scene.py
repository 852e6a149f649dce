"""Benchmark projection mapping onto a scene at 600 x 800 pixels: ray casting and rendering.

For each built-in scene (or ``--scenes``): seconds to ray-cast one ray per projector pixel with
each ray engine (``pinhole``: edofproj's vectorized NumPy rasterizer; ``embree``: trimesh with
Embree through the ``embreex`` package, the ``scenes-fast`` extra; ``numpy``: trimesh's own
intersector, about a minute per scene, only with ``--engines``), seconds to
simulate the PSFs of the depth layers (``imaging.depth_layers`` = 8, the cpu preset's lens), and
seconds to render one image through the depth layers. Torch and the ray engines use
``--threads`` threads (default 2).

    python benchmarks/bench_scene.py
    python benchmarks/bench_scene.py --scenes sphere_wall --engines embree
"""

from __future__ import annotations

import argparse
import os
import time

from edofproj.machine import instruction_sets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", default=None, help="comma-separated scenes (default: every built-in scene)")
    parser.add_argument(
        "--engines", default=None, help="comma-separated ray engines (default: numpy and, if installed, embree)"
    )
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2, help="timed repeats; the best is printed")
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))

    import numpy as np
    import torch
    import trimesh

    from edofproj.config import load_config
    from edofproj.doe import build_doe
    from edofproj.optics.geometry import ProjectorGeometry
    from edofproj.optics.psf_bank import simulator_from_config
    from edofproj.scenes import BUILTIN_SCENES, builtin_scene, cast_scene, render_scene
    from edofproj.scenes.render import scene_layers_m

    torch.set_num_threads(args.threads)
    cfg = load_config("cpu")
    geometry = ProjectorGeometry.from_config(cfg.optics)
    height, width = geometry.height_px, geometry.width_px
    engines = args.engines.split(",") if args.engines else ["pinhole"] + (["embree"] if trimesh.ray.has_embree else [])
    scenes = args.scenes.split(",") if args.scenes else list(BUILTIN_SCENES)
    doe = build_doe(cfg, "lens")
    simulator = simulator_from_config(cfg)
    image = torch.rand(1, 3, height, width, generator=torch.Generator().manual_seed(0))

    print(
        f"{height}x{width} px, {args.threads} threads [{instruction_sets()}], {cfg.imaging.depth_layers} depth layers, "
        "cpu preset optics"
    )
    print(
        f"{'scene':<12} {'faces':>7} "
        + " ".join(f"{'cast ' + e + ' s':>14}" for e in engines)
        + f" {'PSFs s':>8} {'render s':>9}"
    )
    for name in scenes:
        scene = builtin_scene(name, geometry)
        faces = sum(len(m.mesh.faces) for m in scene.meshes) + (2 if scene.background_m is not None else 0)
        cast_seconds = []
        cast = None
        for engine in engines:
            best = np.inf
            for _ in range(args.repeats):
                clock = time.perf_counter()
                cast = cast_scene(scene, height, width, geometry, engine=engine)
                best = min(best, time.perf_counter() - clock)
            cast_seconds.append(best)
        assert cast is not None
        layers = scene_layers_m(cast, cfg.imaging.depth_layers)
        clock = time.perf_counter()
        with torch.no_grad():
            psf = simulator(doe, layers).float()
        psf_seconds = time.perf_counter() - clock
        best = np.inf
        with torch.no_grad():
            for _ in range(args.repeats):
                clock = time.perf_counter()
                render_scene(image, cast, psf, layers)
                best = min(best, time.perf_counter() - clock)
        print(
            f"{name:<12} {faces:>7} "
            + " ".join(f"{s:>14.2f}" for s in cast_seconds)
            + f" {psf_seconds:>8.2f} {best:>9.2f}"
        )


if __name__ == "__main__":
    main()
