"""The probe's pose metrics of BOP in ``hupbench eval`` (``metrics.probe_pose`` and
``metrics.split_floor_probe_pose`` of a results file): both poses fitted from corners, the errors over the
dataset's probe mesh (:mod:`hupbench.metrics` holds the formulas; docs/metrics.md defines them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.errors import BadValueError
from hupbench.core.geometry import fit_rigid_pose
from hupbench.core.probe_symmetry import HALF_TURN_Z, object_diameter_m, symmetry_permutation
from hupbench import metrics

__all__ = ["PROBE_BOX_FIT_TOL_M", "dataset_probe", "floor_probe_pose", "logged_probe_pose", "probe_pose_rows",
           "probe_pose_scores"]

#: the probe mesh's box, fitted rigidly onto a frame's true corners, must meet them within this (metres):
#: else the mesh is not the dataset's probe and its pose metrics would measure the wrong object
PROBE_BOX_FIT_TOL_M = 1e-5


def dataset_probe(dataset: Path, manifest: dict | None = None):
    """The probe a dataset was rendered with (a ``hupbench.datagen.assets.probe.Probe``, the procedural one or the
    user's mesh its manifest records): its ``corners_probe`` are the known box fitted onto the corners and
    its ``mesh.vertices`` the model points of the BOP metrics. ``manifest``: the dataset's, as the caller read it
    (default: read here)."""
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset

    return probe_of_dataset(dataset, manifest)


def probe_pose_scores(pred_corners_m: np.ndarray, true_corners_m: np.ndarray, K: np.ndarray, image_width_px: int,
                      probe) -> tuple[dict | None, str]:
    """The probe's BOP scores (``metrics.bop_scores`` with "symmetry" and "model_points") of predicted corners,
    or (None, why) where the probe's box does not fit the true corners.

    Both poses are the rigid fit of the probe's box (``probe.corners_probe``) onto the corners, so a
    prediction is scored by the pose its corners imply; the errors run over the probe mesh's vertices.
    The symmetry group is the half turn about the long axis when it maps the box onto itself, else none.

    Args:
        pred_corners_m, true_corners_m: (N, 8, 3) float, metres, OpenCV camera frame, corner order of
            ``hupbench.core.keypoints``. K: (N, 3, 3) intrinsics of the stored images, ``image_width_px`` wide.
        probe: what :func:`dataset_probe` returns.

    Returns:
        (scores or None, a one-line summary or the reason for None).
    """
    box = np.asarray(probe.corners_probe, np.float64)                                        # (8, 3) probe frame
    T_cam_true = fit_rigid_pose(box, true_corners_m)
    fitted = box @ T_cam_true[:, :3, :3].transpose(0, 2, 1) + T_cam_true[:, None, :3, 3]
    misfit = float(np.linalg.norm(fitted - true_corners_m, axis=-1).max())
    if misfit > PROBE_BOX_FIT_TOL_M:
        return None, (f"the probe mesh's box meets the true corners only within {misfit * 1e3:.3f} mm (allowed "
                      f"{PROBE_BOX_FIT_TOL_M * 1e3:g} mm): the mesh is not the dataset's probe")
    try:
        symmetry_permutation(box, HALF_TURN_Z)
        symmetry = "half_turn"
    except BadValueError:
        symmetry = "none"
    rotations = metrics.PROBE_SYMMETRY_ROTATIONS[symmetry]
    T_cam_pred = fit_rigid_pose(box, pred_corners_m)
    points = np.asarray(probe.mesh.vertices, np.float64)                                      # (V, 3) probe frame
    scores = metrics.bop_scores(
        metrics.add_mm(T_cam_pred, T_cam_true, points), metrics.add_s_mm(T_cam_pred, T_cam_true, points),
        metrics.mssd_mm(T_cam_pred, T_cam_true, points, rotations),
        metrics.mspd_px(T_cam_pred, T_cam_true, K, points, rotations),
        object_diameter_m(points) * 1000.0, image_width_px)
    scores |= {"symmetry": symmetry, "model_points": len(points)}
    mspd = "-" if scores["mspd_px"] is None else f"{scores['mspd_px']:.1f}"
    return scores, (f"ADD {scores['add_mm']:.2f} / ADD-S {scores['add_s_mm']:.2f} / MSSD {scores['mssd_mm']:.2f} mm, "
                    f"MSPD {mspd} px; ADD / ADD-S < {metrics.ADD_THRESHOLD_DIAMETER:g} d {scores['add_accuracy']:.3f} / "
                    f"{scores['add_s_accuracy']:.3f}, AR MSSD {scores['ar_mssd']:.3f}, AR MSPD {scores['ar_mspd']:.3f} "
                    f"(diameter d {scores['diameter_mm']:.1f} mm, symmetry {symmetry})")


def logged_probe_pose(pred3d: np.ndarray, gt3d: np.ndarray, K: np.ndarray, image_width_px: int, probe, who: str,
                log) -> dict | None:
    """:func:`probe_pose_scores` of (N, 29, 3) keypoints, logged for ``who`` (None logged as a warning)."""
    scores, line = probe_pose_scores(pred3d[:, kp.CORNER_SLICE], gt3d[:, kp.CORNER_SLICE], K, image_width_px, probe)
    log(f"{who} probe pose (BOP): {line}" if scores is not None else f"warning: no probe pose metrics: {line}")
    return scores


def floor_probe_pose(dataset: Path, manifest: dict, floor: dict | None, fields: dict, gt3d: np.ndarray,
                      image_width_px: int, probe, log) -> dict | None:
    """The probe pose scores of the split's floor where it is the nearest training grasp: each evaluated
    frame's prediction is the probe corners of its grasp's nearest training grasp (the floor's
    ``nearest_train_grasp_id``) in the same view and distance, from the train annotations; None (logged)
    for the nearest-training-view floor, whose chosen frames the manifest does not record."""
    from hupbench.core.contract import read_annotations
    from hupbench.datagen.dataset.floors import NEAREST_TRAIN_GRASP

    if floor is None:
        return None
    nearest = {int(g): e.get("nearest_train_grasp_id") for g, e in floor["per_grasp"].items()}
    if floor["floor_kind"] != NEAREST_TRAIN_GRASP or None in nearest.values():
        log("no probe pose metrics of the split floor: only the nearest-training-grasp floor records its choice")
        return None
    train = read_annotations(dataset, "train", ("keypoints_3d_cam", "grasp_id", "view_id", "z_ego"), manifest)
    # backgrounds and gloves repeat a (grasp, view, distance): any of those frames has the same keypoints
    row_of = {key: i for i, key in enumerate(zip(train["grasp_id"].tolist(), train["view_id"].tolist(),
                                                 np.round(train["z_ego"], 9).tolist()))}
    keys = zip((nearest[g] for g in fields["grasp_id"].tolist()), fields["view_id"].tolist(),
               np.round(fields["z_ego"], 9).tolist())
    rows = [row_of.get(key) for key in keys]
    if None in rows:
        log(f"no probe pose metrics of the split floor: {rows.count(None)} frames' views are not rendered for "
            f"their nearest training grasp")
        return None
    floor3d = np.asarray(train["keypoints_3d_cam"], np.float64)[rows]
    return logged_probe_pose(floor3d, gt3d, np.asarray(fields["K"], np.float64), image_width_px, probe, "split floor", log)


def probe_pose_rows(name: str, pose: dict, f) -> list[tuple[str, str]]:
    """Table rows of a ``metrics.probe_pose`` block: errors, then the BOP scores."""
    return [
        (f"{name} ADD / ADD-S / MSSD", (f"{f(pose['add_mm'])} / {f(pose['add_s_mm'])} / {f(pose['mssd_mm'])} mm "
                                        f"(diameter {f(pose['diameter_mm'], '{:.1f}')} mm, symmetry {pose['symmetry']})")),
        (f"{name} MSPD", f"{f(pose['mspd_px'])} px ({pose['image_width_px']} px wide images)"),
        (f"{name} BOP scores", (f"ADD < 0.1 d {f(pose['add_accuracy'], '{:.3f}')}, ADD-S < 0.1 d "
                                f"{f(pose['add_s_accuracy'], '{:.3f}')}, AR_MSSD {f(pose['ar_mssd'], '{:.3f}')}, "
                                f"AR_MSPD {f(pose['ar_mspd'], '{:.3f}')}")),
    ]
