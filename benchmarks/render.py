"""Render speed: frames per second for RGB + depth + segmentation at 256 x 256.

Renders the preview grasp (hand, forearm, probe) from cameras spread round a
sphere, one process, and prints the median over repeats for each modality
set. Usage: python benchmarks/render.py [--frames 100] [--repeats 5] [--platform egl]
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

    from datagen.camera import Intrinsics, look_at
    from datagen.render.preview import handset_grasp
    from datagen.render.renderer import Renderer
    from datagen.render.scene import keypoints_world, scene_parts

    intrinsics = Intrinsics.from_lens(60.0, 32.0, args.size, args.size)
    grasp = handset_grasp()
    parts = scene_parts(grasp)
    target = keypoints_world(grasp).mean(axis=0)
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(args.frames, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    poses = [look_at(target + 0.5 * d, target) for d in directions]

    with Renderer(intrinsics, platform=args.platform) as renderer:
        renderer.set_parts(parts)
        triangles = sum(len(p.mesh.faces) for p in parts)
        print(f"renderer: {renderer.platform}, {args.size} x {args.size}, {triangles} triangles, "
              f"{args.frames} frames x {args.repeats} repeats")
        for modalities in (("rgb", "depth", "seg"), ("rgb", "depth"), ("seg",), ("depth",)):
            renderer.render(poses[0], modalities)  # warm-up: shader compilation, uploads
            rates = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                for T in poses:
                    renderer.render(T, modalities)
                rates.append(args.frames / (time.perf_counter() - start))
            print(f"  {'+'.join(modalities):16s} median {statistics.median(rates):6.1f} frames/s "
                  f"(min {min(rates):.1f}, max {max(rates):.1f})")


if __name__ == "__main__":
    main()
