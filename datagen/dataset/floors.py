"""How hard a split is: what a model that only recalls training labels would score on it (numpy only).

Under the dataset's viewing protocol the camera of a view (sphere direction and distance) is a rigid
function of one frame per grasp: the sphere frame with its origin at the look-at point. Two grasps seen
in the same view therefore differ in the camera frame exactly as they differ in that frame, in every
view: camera-frame distances between their keypoints are the same whichever view they are measured in.
The floors are computed from the annotations alone (``keypoints_3d_cam``, ``grasp_id``, ``view_id``,
``z_ego``), so ``hupbench verify`` recomputes them independently of the generator:

- ``nearest_train_grasp``: each evaluated grasp replaced by the training grasp closest to it (mean
  distance of all 29 keypoints), seen from the true camera. A model that only recognises training
  grasps cannot do better. The floor of the unseen-grasps track; 0 for a grasp that is itself in
  training (the unseen-views track).
- ``nearest_train_view``: each evaluated frame replaced by the training frame of the same grasp and
  distance whose camera-frame keypoints are closest (a model that only recalls the training views of
  a grasp). The floor of the unseen-views track; undefined for a grasp that is not in training.
- ``train_mean``: the distance to the mean training grasp (predicting one average grasp for every image).

Figures are means over the split's frames, in millimetres, for the 21 hand keypoints, the 8 probe
corners and all 29.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.errors import BadValueError

M_TO_MM = 1000.0
DEFINITION = ("what a model that only recalls training labels scores, mean distance per keypoint in mm: each "
              "evaluated grasp replaced by the nearest training grasp seen from the true camera "
              "(nearest_train_grasp, the floor of the unseen_grasps track), or each evaluated frame by the nearest "
              "training view of the same grasp and distance (nearest_train_view, the floor of the unseen_views track)")
#: how a split's headline floor is made: each evaluated grasp replaced by its nearest training grasp, or
#: each evaluated frame by the nearest training view of its grasp
NEAREST_TRAIN_GRASP, NEAREST_TRAIN_VIEW = "nearest_train_grasp", "nearest_train_view"
FLOOR_KINDS = (NEAREST_TRAIN_GRASP, NEAREST_TRAIN_VIEW)
#: annotation arrays the floors read
FIELDS = ("keypoints_3d_cam", "grasp_id", "view_id", "z_ego")


def _triplet_mm(distances_m: np.ndarray) -> dict[str, float]:
    """{"hand", "probe", "all"} mean distances in mm from (..., 29) per-keypoint distances in metres."""
    d = np.asarray(distances_m, dtype=np.float64).reshape(-1, kp.NUM_KEYPOINTS) * M_TO_MM
    return {"hand": float(d[:, :kp.NUM_HAND].mean()), "probe": float(d[:, kp.NUM_HAND:].mean()),
            "all": float(d.mean())}


def _views(ann: dict) -> dict[tuple[int, int, float], np.ndarray]:
    """{(grasp_id, view_id, z_ego): (29, 3) keypoints} of one split (backgrounds and gloves repeat them)."""
    keys = zip(ann["grasp_id"].tolist(), ann["view_id"].tolist(), np.round(ann["z_ego"], 9).tolist())
    out = {}
    for key, keypoints in zip(keys, ann["keypoints_3d_cam"]):
        out.setdefault(key, np.asarray(keypoints, np.float64))
    return out


def split_floors(annotations: dict[str, dict]) -> dict:
    """The floors of every split but train.

    Args:
        annotations: {split: arrays} for "train" and the splits to measure, each with :data:`FIELDS`:
            keypoints_3d_cam (N, 29, 3) metres, OpenCV camera frame; grasp_id, view_id (N,) int;
            z_ego (N,) metres.

    Returns:
        {split: {"floor_kind", "floor_mm", "nearest_train_grasp_mm", "train_mean_mm",
        "nearest_train_view_mm" (None unless every evaluated grasp is a training grasp),
        "per_grasp": {str(grasp_id): {"floor_mm", "nearest_train_grasp_id", "nearest_train_grasp_mm",
        "train_mean_mm", "nearest_train_view_mm", "frames"}}}}, mm triplets {"hand", "probe", "all"};
        splits without frames are left out.

    Raises:
        ValueError: an evaluated grasp shares no view with every training grasp (then the grasps cannot be
            compared under one camera).
    """
    train = _views(annotations["train"])
    assert train, "split floors need training frames"  # the callers ask only with some
    train_grasps = sorted({g for g, _, _ in train})
    seen = dict(train)
    for split, ann in annotations.items():
        seen.update(_views(ann))
    out = {}
    for split, ann in annotations.items():
        if split == "train" or len(ann["grasp_id"]) == 0:
            continue
        evaluated = _views(ann)
        grasps = sorted({g for g, _, _ in evaluated})
        per_grasp, weights = {}, []
        for g in grasps:
            frames = int(np.count_nonzero(ann["grasp_id"] == g))
            per_grasp[str(g)] = _grasp_floors(g, seen, train, train_grasps, evaluated) | {"frames": frames}
            weights.append(frames)
        entries = list(per_grasp.values())
        views_known = all(e["nearest_train_view_mm"] is not None for e in entries)
        summary = {"floor_kind": NEAREST_TRAIN_VIEW if views_known else NEAREST_TRAIN_GRASP}
        for name in ("nearest_train_grasp_mm", "train_mean_mm") + (("nearest_train_view_mm",) if views_known else ()):
            summary[name] = {part: float(np.average([e[name][part] for e in entries], weights=weights))
                             for part in ("hand", "probe", "all")}
        summary.setdefault("nearest_train_view_mm", None)
        summary["floor_mm"] = summary["nearest_train_view_mm"] or summary["nearest_train_grasp_mm"]
        out[split] = summary | {"per_grasp": per_grasp}
    return out


def _grasp_floors(g: int, seen: dict, train: dict, train_grasps: list[int], evaluated: dict) -> dict:
    """The floors of one evaluated grasp (see :func:`split_floors`)."""
    common = next((key for key in seen if key[0] == g
                   and all((t, key[1], key[2]) in train for t in train_grasps)), None)
    if common is None:
        raise BadValueError(f"grasp {g} is seen in no view (view_id and z_ego) in which every training grasp is seen: "
                         "its distance to the training grasps cannot be measured under one camera")
    _, view, z = common
    mine = seen[common]
    others = np.stack([train[(t, view, z)] for t in train_grasps])  # (T, 29, 3)
    to_train = np.linalg.norm(others - mine, axis=-1)  # (T, 29)
    best = int(np.argmin(to_train.mean(axis=1)))
    entry = {"nearest_train_grasp_id": train_grasps[best], "nearest_train_grasp_mm": _triplet_mm(to_train[best]),
             "train_mean_mm": _triplet_mm(np.linalg.norm(others.mean(axis=0) - mine, axis=-1)),
             "nearest_train_view_mm": None}
    if g in train_grasps:
        nearest = []
        for (grasp, _, z_eval), keypoints in evaluated.items():
            if grasp != g:
                continue
            candidates = np.stack([p for (t, _, z_train), p in train.items() if t == g and z_train == z_eval])
            distances = np.linalg.norm(candidates - keypoints, axis=-1)  # (C, 29)
            nearest.append(distances[np.argmin(distances.mean(axis=1))])
        entry["nearest_train_view_mm"] = _triplet_mm(np.stack(nearest))
    entry["floor_mm"] = entry["nearest_train_view_mm"] or entry["nearest_train_grasp_mm"]
    return entry
