"""The cost of a probe mesh: time to derive its probe (regions, lens, marker, the signed-distance grid) against its
triangle count, the figure behind the face budget of ``probe.mesh`` (hupbench.datagen.assets.probe_mesh.MAX_FACES).

The meshes are icospheres of 20 x 4^s triangles stretched to a probe's size (72 x 28 x 165 mm, the lowest point at
the origin), so that only the triangle count changes between rows. Each row builds a fresh probe (no cache), in one
process; the CPU is printed with the figures.

Usage: python benchmarks/probe_mesh.py [--subdivisions 3 4 5]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
import torch
import trimesh

#: half the probe's extents, metres (x along the lens, y across it, z along the handle)
HALF_EXTENTS_M = (0.036, 0.014, 0.0825)


def probe_sized_sphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 metres in the probe frame, faces (F, 3) int64) of an icosphere stretched to a probe."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    vertices = sphere.vertices * np.asarray(HALF_EXTENTS_M)
    vertices[:, 2] += HALF_EXTENTS_M[2]
    return vertices, np.asarray(sphere.faces, dtype=np.int64)


def main() -> None:
    from hupbench.datagen.assets.probe import probe_from_geometry
    from hupbench.datagen.assets.probe_mesh import MAX_FACES, ProbeMeshSpec

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, nargs="+", default=[3, 4, 5],
                        help="icosphere levels: 20 x 4^s triangles (3: 1,280, 4: 5,120, 5: 20,480)")
    args = parser.parse_args()
    print(f"CPU: {platform.processor() or platform.machine()}, torch capability "
          f"{torch.backends.cpu.get_cpu_capability()}, {torch.get_num_threads()} threads; face budget {MAX_FACES:,}")
    print("triangles  seconds")
    for s in args.subdivisions:
        vertices, faces = probe_sized_sphere(s)
        spec = ProbeMeshSpec(f"icosphere_{s}.stl", sha256=f"benchmark-{s}")
        start = time.perf_counter()
        probe_from_geometry(vertices, faces, spec)
        print(f"{len(faces):9,d}  {time.perf_counter() - start:7.1f}")


if __name__ == "__main__":
    main()
