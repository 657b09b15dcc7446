"""Make docs/custom_probe.png: a frame of a tiny dataset of the example linear probe, and its preview.

Builds :func:`hupbench.datagen.assets.probe_mesh.linear_probe_mesh`, writes it as STL, makes 3 grasps for it
(``hupbench grasps probe.mesh=...``), renders a tiny dataset (``hupbench generate``) and puts three of its
RGB frames beside the quickstart preview of the probe with its frame's axes.

Usage: python scripts/custom_probe_picture.py [--work /tmp/custom_probe] [--out docs/custom_probe.png] [--smoke]
(--smoke: a grasp search of seconds and 64 px frames, for tests: the picture is then not the docs' one)
"""

from __future__ import annotations

import argparse
from pathlib import Path


#: the grasp search of --smoke: three pinned candidates, briefly refined
SMOKE_SEARCH = ["generate.theta_vol_deg=[[0,0,0],[0,0,180]]", "generate.starts_per_theta=2", "generate.pinned_ids=[0,1,2]",
                "refine.iterations=20", "generate.short_refine_iterations=10", "sheet.tile_px=48"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", default="/tmp/custom_probe")
    parser.add_argument("--out", default="docs/custom_probe.png")
    parser.add_argument("--smoke", action="store_true",
                        help="a grasp search of seconds and 64 px frames (tests), not the docs' picture")
    args = parser.parse_args()

    import cv2

    from hupbench.datagen.assets.probe import probe_of
    from hupbench.datagen.assets.probe_mesh import ProbeSource, linear_probe_mesh
    from hupbench.core.camera import Intrinsics
    from hupbench.core.draw import grid, titled, write_png
    from hupbench.datagen.render.preview import PreviewView, handset_grasp, render_preview
    from hupbench.config import compose
    from hupbench.verbs.generate import run_generate
    from hupbench.verbs.grasps import run_grasps

    work, size = Path(args.work), 64 if args.smoke else 256
    work.mkdir(parents=True, exist_ok=True)
    stl = work / "linear.stl"
    linear_probe_mesh().export(stl)
    grasps = work / "grasps" / "grasps.npz"
    if not grasps.is_file():
        search = (SMOKE_SEARCH if args.smoke else
                  ["generate.theta_vol_deg=[[0,0,0],[0,0,90],[0,0,180],[0,0,270]]", "generate.starts_per_theta=8"])
        run_grasps(compose("grasps", [f"out_dir={grasps.parent}", f"probe.mesh={stl}", *search, "generate.n_select=3",
                                      "threads=2"]))
    root = work / "dataset"
    run_generate(compose("generate", [f"out_dir={root}", f"grasps_path={grasps}", f"probe.mesh={stl}",
                                      "dataset.splits={train:1,val:1,test:1}", "dataset.z_ego_m=[0.5]",
                                      "dataset.n_backgrounds=1", "dataset.n_gloves=1", "dataset.sphere.r_circ_m=0.4",
                                      "dataset.sphere.exclude=[poles]", "workers=1", "progress=false",
                                      *([f"dataset.width={size}", f"dataset.height={size}"] if args.smoke else [])]))
    tiles = []
    for split, frame in (("train", 3), ("val", 15), ("test", 27)):
        found = sorted((root / split / "rgb").glob("*.jpg"))
        path = found[min(frame % 10, len(found) - 1)]
        tiles.append(titled(cv2.imread(str(path))[..., ::-1], f"{split} split, frame {int(path.stem)}"))
    probe = probe_of(ProbeSource(str(stl)))
    shot = render_preview(handset_grasp(), Intrinsics.from_lens(60.0, 32.0, size, size), PreviewView(), probe=probe,
                          modalities=["rgb"])
    tiles.append(titled(shot["rgb"], "preview: the linear probe (STL)"))
    print(write_png(Path(args.out), grid(tiles, columns=4)))


if __name__ == "__main__":
    main()
