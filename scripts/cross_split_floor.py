"""The floor of one dataset's split against another dataset's training grasps: what recalling the nearest of those
training grasps under the true camera scores on it (:mod:`hupbench.datagen.dataset.floors`, the split floors a manifest
records), hand / probe / all 29 keypoints in mm, and per evaluated grasp.

For a checkpoint scored on grasps it was not trained on that lie in another dataset (more unseen grasps to tune on,
rendered like its training dataset from other grasps: docs/results.md, "The hand fit started from a training
hand"), this is the floor to quote beside its error. The two datasets must see their grasps from the same views
(view_id and z_ego: the same track and sphere); on the clinic track, whose cameras are drawn per grasp, the floor is
the nearest training frame's. The evaluated grasps count as other grasps than the training ones whatever their ids
(a grasp id is a candidate's number within one synthesis run, so two datasets may share ids of different grasps).

Usage: python scripts/cross_split_floor.py TRAIN_DATASET DATASET [--split val]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    from hupbench.core.contract import CLINIC, read_annotations, read_manifest, track_of
    from hupbench.core.errors import BadValueError
    from hupbench.datagen.dataset.floors import FIELDS, split_floors

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("train_dataset", type=Path, help="the dataset whose train split the model was trained on")
    parser.add_argument("dataset", type=Path, help="the dataset whose split is evaluated")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    args = parser.parse_args()
    manifests = {name: read_manifest(path) for name, path in (("train", args.train_dataset), ("eval", args.dataset))}
    tracks = {name: track_of(m) for name, m in manifests.items()}
    if tracks["train"] != tracks["eval"]:
        parser.error(f"{args.dataset} is of the track {tracks['eval']!r}, {args.train_dataset} of {tracks['train']!r}: "
                     "their grasps are seen from other cameras")
    train = read_annotations(args.train_dataset, "train", FIELDS, manifests["train"])
    evaluated = read_annotations(args.dataset, args.split, FIELDS, manifests["eval"])
    for path, split, ann in ((args.train_dataset, "train", train), (args.dataset, args.split, evaluated)):
        if not len(ann["grasp_id"]):
            parser.error(f"{path} has no {split} frames")
    # the evaluated grasps under ids no training grasp has (negative), named by their own ids below
    ids, index = np.unique(evaluated["grasp_id"], return_inverse=True)
    evaluated["grasp_id"] = -1 - index.astype(evaluated["grasp_id"].dtype)
    try:
        floors = split_floors({"train": train, "evaluated": evaluated}, tracks["train"])["evaluated"]
    except BadValueError as error:   # a grasp seen in no view of the training grasps (another sphere)
        parser.error(f"{args.dataset} against {args.train_dataset}: {error}")
    key = "floor_mm" if tracks["train"] == CLINIC else "nearest_train_grasp_mm"

    def triplet(mm: dict) -> str:
        return " ".join(f"{part} {mm[part]:.2f}" for part in ("hand", "probe", "all"))

    print(f"{args.dataset} {args.split} ({len(evaluated['grasp_id'])} frames, {len(ids)} grasps) against the "
          f"{len(np.unique(train['grasp_id']))} training grasps of {args.train_dataset}; mm")
    print(f"floor ({floors['floor_kind']}): {triplet(floors[key])}")
    for g, entry in sorted(floors["per_grasp"].items(), key=lambda item: -int(item[0])):
        nearest = entry["nearest_train_grasp_id"]
        print(f"  grasp {ids[-1 - int(g)]}: {triplet(entry[key])} ({entry['frames']} frames"
              + ("" if nearest is None else f"; nearest training grasp {nearest}") + ")")


if __name__ == "__main__":
    main()
