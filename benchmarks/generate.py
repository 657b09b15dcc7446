"""End-to-end dataset generation speed: render + composite + encode + write, per worker count and track.

The paper protocol: the first grasp of a grasps file (default: the shipped default grasps) with 2 distances,
``--backgrounds`` backgrounds, 2 gloves and the sphere's 90 views of ``--size`` pixels. With ``--clinic``, in the
same run and on the same machine, the clinic track: the first ``--clinic-grasps`` grasps of a clinic grasps file
(default: the shipped clinic grasps) with their subjects' hands, patients and rooms, the same backgrounds and
gloves, and 33 head cameras each (the full track's frames per grasp and background). Each is rendered with 1 and 2
worker processes into temporary folders; the script prints frames per second, the projected wall time of a full
track (31,680 frames; meaningful at the default 256 px) and the clinic track's rate as a share of the paper's. With
``--sequences`` (and ``--clinic``), also the clinic track in motion (conf/track/clinic_sequences.yaml: the same
grasps, 2 clips of 151 frames each, every frame rendered at its own camera and patient pose), its full track's
18,120 frames projected.

Usage: python benchmarks/generate.py [GRASPS_NPZ] [--clinic [CLINIC_GRASPS_NPZ]] [--clinic-grasps 6] [--sequences]
       [--backgrounds 4] [--workers 1 2] [--size 256] [--r-circ-m 0.15]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

FULL_DATASET_FRAMES = 31680
#: the clinic_sequences track's frames: 60 grasps x 2 clips x 151 frames
SEQUENCE_FRAMES = 18120
#: the clinic track's cameras per grasp (conf/track/clinic.yaml)
CLINIC_VIEWS = 33


def _rate(spec, grasps: Path, root: Path, workers: int) -> tuple[int, float]:
    """(frames rendered, seconds) of one generation of ``spec`` from ``grasps`` into ``root``."""
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    start = time.perf_counter()
    result = generate(GenerateRun(spec, str(root), str(grasps), progress=False, workers=workers), {"benchmark": workers},
                      log=lambda *_: None)
    return result["frames_rendered"], time.perf_counter() - start


def main() -> None:
    from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, DEFAULT_GRASPS, first_grasps

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grasps", nargs="?", default=str(DEFAULT_GRASPS), help="a grasps.npz (default: the shipped one)")
    parser.add_argument("--clinic", nargs="?", const=str(CLINIC_GRASPS), default=None,
                        help="also the clinic track, from this clinic grasps.npz (default: the shipped one)")
    parser.add_argument("--clinic-grasps", type=int, default=6, help="clinic grasps rendered (33 cameras each)")
    parser.add_argument("--sequences", action="store_true",
                        help="with --clinic: also the clinic_sequences track of the same grasps")
    parser.add_argument("--backgrounds", type=int, default=4)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--size", type=int, default=256, help="image side, pixels (intrinsics scale with it)")
    parser.add_argument("--r-circ-m", type=float, default=0.15, help="0.15: the default 90 views per sphere; 0.4: 10")
    args = parser.parse_args()

    from hupbench.datagen.dataset.head import HeadSpec
    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.sphere import SphereSpec

    scale = args.size / 256
    camera = {"width": args.size, "height": args.size, "fx": 480.0 * scale, "fy": 480.0 * scale,
              "cx": 128.0 * scale, "cy": 128.0 * scale, "n_backgrounds": args.backgrounds}
    tracks = {"paper": (DatasetSpec(splits={"train": 1, "val": 0, "test": 0}, sphere=SphereSpec(r_circ_m=args.r_circ_m),
                                    **camera), Path(args.grasps), 1)}
    if args.clinic is not None:
        tracks["clinic"] = (DatasetSpec(track="clinic", splits={"train": args.clinic_grasps, "val": 0, "test": 0},
                                        head=HeadSpec(views_per_grasp=CLINIC_VIEWS), **camera), Path(args.clinic),
                            args.clinic_grasps)
    if args.sequences:
        if args.clinic is None:
            parser.error("--sequences renders the clinic grasps: give --clinic too")
        from dataclasses import replace

        from hydra.utils import instantiate

        from hupbench.config import compose

        track = instantiate(compose("generate", ["+track=clinic_sequences"]).dataset)
        tracks["clinic_sequences"] = (replace(track, splits={"train": args.clinic_grasps, "val": 0, "test": 0},
                                              **camera), Path(args.clinic), args.clinic_grasps)
    full = {"clinic_sequences": SEQUENCE_FRAMES}
    rates: dict[tuple[str, int], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for track, (spec, source, n) in tracks.items():
            grasps = first_grasps(source, n, Path(tmp) / f"{track}_grasps.npz")
            for workers in args.workers:
                frames, wall = _rate(spec, grasps, Path(tmp) / f"{track}_w{workers}", workers)
                rates[track, workers] = rate = frames / wall
                print(f"{track} workers {workers}: {frames} frames in {wall:.1f} s = {rate:.1f} frames/s "
                      f"end to end (incl. worker start-up); full track {full.get(track, FULL_DATASET_FRAMES)} frames: "
                      f"{full.get(track, FULL_DATASET_FRAMES) / rate / 60:.1f} min", flush=True)
    for workers in args.workers:
        for track in ("clinic", "clinic_sequences"):
            if (track, workers) in rates:
                print(f"workers {workers}: the {track} track renders at "
                      f"{100 * rates[track, workers] / rates['paper', workers]:.0f} % of the paper protocol's rate")


if __name__ == "__main__":
    main()
