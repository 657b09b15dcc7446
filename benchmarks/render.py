"""Render speed per pass: frames per second of the colour pass (both shaders) and the label pass at 256 x 256.

Renders the preview grasp (hand, forearm, probe) from cameras spread round a
sphere, one process, and prints the median over repeats for each pass: the
colour pass ("rgb") with our Blinn-Phong shader and with pyrender's physically
based one, the label pass ("depth+seg", which the dataset renders once per view
and shares between its backgrounds and gloves), and both together.
Usage: python benchmarks/render.py [--frames 100] [--repeats 5] [--platform egl]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100, help="frames per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--size", type=int, default=256, help="image side, pixels")
    parser.add_argument("--platform", choices=("egl", "osmesa"), default=None)
    args = parser.parse_args()
    if args.frames < 1 or args.repeats < 1 or args.size < 1:
        parser.error("--frames, --repeats and --size must be positive")

    from hupbench.core.camera import Intrinsics, look_at
    from hupbench.datagen.render.preview import handset_grasp
    from hupbench.datagen.render.renderer import Renderer
    from hupbench.datagen.render.scene import keypoints_world, scene_parts

    intrinsics = Intrinsics.from_lens(60.0, 32.0, args.size, args.size)
    grasp = handset_grasp()
    parts = scene_parts(grasp)
    target = keypoints_world(grasp).mean(axis=0)
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(args.frames, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    poses = [look_at(target + 0.5 * d, target) for d in directions]

    passes = {"blinn_phong": (("rgb",), ("depth", "seg"), ("rgb", "depth", "seg")), "pbr": (("rgb",),)}
    for shading, modality_sets in passes.items():
        with Renderer(intrinsics, platform=args.platform, shading=shading) as renderer:
            renderer.set_parts(parts)
            triangles = sum(len(p.mesh.faces) for p in parts)
            print(f"renderer: {renderer.platform}, shading {shading}, {args.size} x {args.size}, {triangles} "
                  f"triangles, {args.frames} frames x {args.repeats} repeats")
            for modalities in modality_sets:
                renderer.render(poses[0], modalities)  # warm-up: shader compilation, uploads
                times = []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    for T in poses:
                        renderer.render(T, modalities)
                    times.append((time.perf_counter() - start) / args.frames)
                median = statistics.median(times)
                print(f"  {'+'.join(modalities):16s} median {1e3 * median:6.2f} ms/frame = {1 / median:6.1f} frames/s "
                      f"(min {1e3 * min(times):.2f}, max {1e3 * max(times):.2f} ms)")


if __name__ == "__main__":
    main()
