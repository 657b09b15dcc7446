"""How hard a split is: what a model that only recalls training labels would score on it (numpy only).

Under the sphere's viewing protocols (the unseen-grasps and unseen-views tracks) the camera of a view
(sphere direction and distance) is a rigid function of one frame per grasp: the sphere frame with its
origin at the look-at point. Two grasps seen in the same view therefore differ in the camera frame exactly
as they differ in that frame, in every view: camera-frame distances between their keypoints are the same
whichever view they are measured in.
The floors are computed from the annotations alone (``keypoints_3d_cam``, ``grasp_id``, ``view_id``,
``z_ego``), so ``hupbench verify`` recomputes them independently of the generator. The caller names the
dataset's track, which picks the headline floor:

- ``nearest_train_grasp``: each evaluated grasp replaced by the training grasp closest to it (mean
  distance of all 29 keypoints), seen from the true camera. A model that only recognises training
  grasps cannot do better. The floor of the unseen-grasps track; 0 for a grasp that is itself in
  training (the unseen-views track).
- ``nearest_train_view``: each evaluated frame replaced by the training frame of the same grasp and
  distance whose camera-frame keypoints are closest (a model that only recalls the training views of
  a grasp). The floor of the unseen-views track; undefined for a grasp that is not in training.
- ``nearest_train_frame`` (the clinic track, whose cameras are drawn per grasp, so that no two grasps share a
  camera): each evaluated frame replaced by the training frame, of any grasp and any view, whose camera-frame
  keypoints are closest (mean distance of all 29). A model that only recalls training images' labels cannot
  do better. It is the idealised nearest-neighbour comparison of pose estimation (each test pose matched to
  its closest training pose by its true joints: Shotton et al., "Real-time human pose recognition in parts
  from single depth images", CVPR 2011).
- ``train_mean``: the distance to the mean training grasp (predicting one average grasp for every image); on
  the clinic track the mean of the training frames' camera-frame keypoints.

Figures are means over the split's frames, in millimetres, for the 21 hand keypoints, the 8 probe
corners and all 29.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.contract import CLINIC
from hupbench.core.errors import BadValueError

M_TO_MM = 1000.0
DEFINITION = ("what a model that only recalls training labels scores, mean distance per keypoint in mm: each "
              "evaluated grasp replaced by the nearest training grasp seen from the true camera "
              "(nearest_train_grasp, the floor of the unseen_grasps track), or each evaluated frame by the nearest "
              "training view of the same grasp and distance (nearest_train_view, the floor of the unseen_views track)")
CLINIC_DEFINITION = ("what a model that only recalls training labels scores, mean distance per keypoint in mm: each "
                     "evaluated frame replaced by the training frame (any grasp, any view) whose camera-frame "
                     "keypoints are closest (nearest_train_frame, the floor of the clinic track)")
#: how a split's headline floor is made: each evaluated grasp replaced by its nearest training grasp, each
#: evaluated frame by the nearest training view of its grasp, or each evaluated frame by the nearest training
#: frame of any grasp and view
NEAREST_TRAIN_GRASP, NEAREST_TRAIN_VIEW, NEAREST_TRAIN_FRAME = \
    "nearest_train_grasp", "nearest_train_view", "nearest_train_frame"
FLOOR_KINDS = (NEAREST_TRAIN_GRASP, NEAREST_TRAIN_VIEW, NEAREST_TRAIN_FRAME)
#: bytes of one block of the nearest-frame search's (evaluated, training, 29, 3) float64 differences
SEARCH_BLOCK_BYTES = 64 * 2**20
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


def definition(track: str) -> str:
    """The words a manifest records beside the floors of a dataset of ``track``."""
    return CLINIC_DEFINITION if track == CLINIC else DEFINITION


def split_floors(annotations: dict[str, dict], track: str) -> dict:
    """The floors of every split but train.

    Args:
        annotations: {split: arrays} for "train" and the splits to measure, each with :data:`FIELDS`:
            keypoints_3d_cam (N, 29, 3) metres, OpenCV camera frame; grasp_id, view_id (N,) int;
            z_ego (N,) metres.
        track: the dataset's track (:data:`hupbench.core.contract.TRACKS`); "clinic" measures
            :func:`frame_floors`, the others the grasp and view floors.

    Returns:
        {split: {"floor_kind", "floor_mm", "nearest_train_grasp_mm", "train_mean_mm",
        "nearest_train_view_mm" (None unless every evaluated grasp is a training grasp),
        "per_grasp": {str(grasp_id): {"floor_mm", "nearest_train_grasp_id", "nearest_train_grasp_mm",
        "train_mean_mm", "nearest_train_view_mm", "frames"}}}}, mm triplets {"hand", "probe", "all"};
        splits without frames are left out. The clinic track's: see :func:`frame_floors`.

    Raises:
        ValueError: an evaluated grasp shares no view with every training grasp (then the grasps cannot be
            compared under one camera; not on the clinic track).
    """
    if track == CLINIC:
        return frame_floors(annotations)
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


def nearest_frames(poses_cam: np.ndarray, train_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pose's nearest training pose by the mean distance of its 29 keypoints, searched in blocks.

    The search expands each keypoint's squared distance as ``|a|^2 + |b|^2 - 2 a.b`` (a batched matrix
    product, ten times faster than forming the differences); its rounding, about 1e-8 m near zero, can only
    swap near ties. The distances returned are those of the differences.

    Args:
        poses_cam: (E, 29, 3) float, metres, OpenCV camera frame: the evaluated poses.
        train_cam: (T, 29, 3) float, metres, camera frame: the training poses (T >= 1).

    Returns:
        index: (E,) int64 into ``train_cam`` (the first of the nearest); distances_m: (E, 29) float64,
        metres, per keypoint to that pose.
    """
    poses = np.asarray(poses_cam, dtype=np.float64)
    train = np.asarray(train_cam, dtype=np.float64)
    assert len(train), "the nearest training frame needs training frames"
    train_by_keypoint = np.ascontiguousarray(train.transpose(1, 2, 0))  # (29, 3, T)
    train_sq = np.einsum("tkc,tkc->kt", train, train)[:, None, :]  # (29, 1, T)
    block = max(1, SEARCH_BLOCK_BYTES // (train_sq.size * 8))  # evaluated poses per block
    index = np.empty(len(poses), dtype=np.int64)
    for start in range(0, len(poses), block):
        chunk = np.ascontiguousarray(poses[start:start + block].transpose(1, 0, 2))  # (29, B, 3)
        sq = np.matmul(chunk, train_by_keypoint)  # (29, B, T), in place from here on
        sq *= -2.0
        sq += np.einsum("kbc,kbc->kb", chunk, chunk)[:, :, None]
        sq += train_sq
        np.sqrt(np.maximum(sq, 0.0, out=sq), out=sq)
        index[start:start + block] = np.argmin(sq.sum(axis=0), axis=1)
    return index, np.linalg.norm(poses - train[index], axis=-1)


def frame_floors(annotations: dict[str, dict]) -> dict:
    """The clinic track's floors of every split but train: each frame replaced by its nearest training frame.

    Frames that share keypoints (a grasp's camera under other backgrounds and gloves) are searched once.

    Args:
        annotations: {split: arrays} for "train" and the splits to measure, each with ``keypoints_3d_cam``
            (N, 29, 3) metres, OpenCV camera frame, and ``grasp_id`` (N,) int.

    Returns:
        {split: {"floor_kind": "nearest_train_frame", "floor_mm", "nearest_train_frame_mm", "train_mean_mm",
        "nearest_train_grasp_mm": None, "nearest_train_view_mm": None, "per_grasp": {str(grasp_id):
        {"floor_mm", "nearest_train_frame_mm", "train_mean_mm", "nearest_train_grasp_id": None,
        "nearest_train_grasp_mm": None, "nearest_train_view_mm": None, "frames"}}}}: mm triplets
        {"hand", "probe", "all"}, means over the frames (the grasp and view floors are undefined: no two
        grasps share a camera); splits without frames are left out.
    """
    train = np.asarray(annotations["train"]["keypoints_3d_cam"], dtype=np.float64)
    assert len(train), "split floors need training frames"  # the callers ask only with some
    train_poses = np.unique(train.reshape(len(train), -1), axis=0).reshape(-1, kp.NUM_KEYPOINTS, 3)
    train_mean = train.mean(axis=0)
    out = {}
    for split, ann in annotations.items():
        if split == "train" or len(ann["grasp_id"]) == 0:
            continue
        frames_cam = np.asarray(ann["keypoints_3d_cam"], dtype=np.float64)
        poses, inverse = np.unique(frames_cam.reshape(len(frames_cam), -1), axis=0, return_inverse=True)
        _, pose_m = nearest_frames(poses.reshape(-1, kp.NUM_KEYPOINTS, 3), train_poses)
        nearest_m = pose_m[inverse.reshape(-1)]  # (N, 29) per frame
        to_mean_m = np.linalg.norm(frames_cam - train_mean, axis=-1)  # (N, 29)
        grasp_ids = np.asarray(ann["grasp_id"])
        per_grasp = {}
        for g in np.unique(grasp_ids).tolist():
            mine = grasp_ids == g
            per_grasp[str(g)] = _frame_entry(nearest_m[mine], to_mean_m[mine]) | {
                "nearest_train_grasp_id": None, "frames": int(np.count_nonzero(mine))}
        out[split] = {"floor_kind": NEAREST_TRAIN_FRAME} | _frame_entry(nearest_m, to_mean_m) | {"per_grasp": per_grasp}
    return out


def _frame_entry(nearest_m: np.ndarray, to_mean_m: np.ndarray) -> dict:
    """The clinic floors of some frames from their (N, 29) distances, metres, to the nearest training frame and
    to the mean training frame."""
    return {"floor_mm": _triplet_mm(nearest_m), "nearest_train_frame_mm": _triplet_mm(nearest_m),
            "nearest_train_grasp_mm": None, "nearest_train_view_mm": None, "train_mean_mm": _triplet_mm(to_mean_m)}
