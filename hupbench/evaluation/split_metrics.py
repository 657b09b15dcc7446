"""The metrics of one evaluated split: errors of every frame, the breakdowns, and the split's floor.

The formulas are :mod:`hupbench.metrics`' (docs/metrics.md defines each number); this module reads what they need
from a dataset's manifest and annotations and checks it.
"""

from __future__ import annotations

import copy

import numpy as np

from hupbench import metrics
from hupbench.core import keypoints as kp
from hupbench.core.contract import TRACKS
from hupbench.core.errors import BadValueError
from hupbench.core.probe_symmetry import probe_symmetry_group
from hupbench.evaluation import breakdowns
from hupbench.evaluation.intervals import intervals_block
from hupbench.evaluation.results import validate_grasp_theta_vol, validate_split_floor

__all__ = ["grasp_theta_vol_deg", "split_breakdowns", "split_floor", "split_intervals", "split_metrics"]


def grasp_theta_vol_deg(manifest: dict, grasp_ids: list[int], where: str) -> dict[str, list[float] | None] | None:
    """{str(grasp id): [x, y, z] degrees or None} of the probe orientation Theta_Vol of exactly the evaluated
    ``grasp_ids``, from the manifest's ``grasp_theta_vol_deg`` (checked; ``where`` is the manifest's path),
    or None where the manifest records none."""
    recorded = manifest.get("grasp_theta_vol_deg")
    if recorded is None:
        return None
    validate_grasp_theta_vol(recorded, f"{where}: manifest['grasp_theta_vol_deg']")
    return {str(g): recorded.get(str(g)) for g in grasp_ids}


def split_floor(manifest: dict, split: str, grasp_ids: list[int], where: str) -> tuple[str | None, dict | None]:
    """(track or None, a checked copy of the split's floor or None) from the manifest's ``protocol.track``
    and ``split_floors["splits"][split]`` (absent in older datasets; the train split has none), whose
    ``per_grasp`` must hold exactly the evaluated ``grasp_ids``; ``where`` is the manifest's path."""
    track = (manifest.get("protocol") or {}).get("track")
    if track is not None and track not in TRACKS:
        raise BadValueError(f"{where}: manifest['protocol']['track'] must be one of {', '.join(TRACKS)}, got {track!r}")
    floors = manifest.get("split_floors")
    if floors is not None:
        if not isinstance(floors, dict) or not isinstance(floors.get("splits"), dict):
            raise BadValueError(f"{where}: manifest['split_floors'] must be a dict with 'definition' and "
                                f"'splits' (split -> floor), got {str(floors)[:80]}")
    entry = None if floors is None else floors["splits"].get(split)
    if entry is None:
        return track, None
    entry_where = f"{where}: manifest['split_floors']['splits'][{split!r}]"
    entry = copy.deepcopy(validate_split_floor(entry, entry_where))
    if set(entry["per_grasp"]) != {str(g) for g in grasp_ids}:
        raise BadValueError(f"{entry_where}['per_grasp'] must hold the split's grasps {sorted(grasp_ids)}, got "
                            f"{sorted(entry['per_grasp'], key=int)}")
    return track, entry


def split_metrics(pred2d_px: np.ndarray, gt2d_px: np.ndarray, pred3d: np.ndarray, gt3d: np.ndarray, fields: dict,
                  log) -> dict:
    """The ``metrics`` block of a results file (without the probe pose's, :mod:`hupbench.evaluation.probe_pose`).

    Args:
        pred2d_px, gt2d_px: (N, 29, 2) float, pixels of the stored images: predicted and true 2D keypoints.
        pred3d, gt3d: (N, 29, 3) float, metres, OpenCV camera frame: predicted and true 3D keypoints.
        fields: the split's annotations (``keypoints_3d_cam`` (N, 29, 3), ``T_cam_world`` (N, 4, 4)), for the probe's
            symmetry group.
        log: receives the symmetric probe error's and the spread ratios' lines and warnings.
    """
    errors = metrics.keypoint_errors_mm(pred3d, gt3d)                                   # (N, 29) mm
    return {
        "mpjpe_mm": metrics.split_from_errors_mm(errors) | {"all_averaging": metrics.ALL_AVERAGING},
        "root_relative_hand_mpjpe_mm": metrics.root_relative_mpjpe_mm(pred3d, gt3d),
        "middle_mcp_relative_hand_mpjpe_mm": metrics.root_relative_mpjpe_mm(pred3d, gt3d, root=metrics.MIDDLE_MCP_INDEX),
        "pa_mpjpe_hand_mm": metrics.pa_mpjpe_mm(pred3d, gt3d),
        "pck_auc_0_50mm": metrics.pck_auc_from_errors(errors),
        "pixel_error_px": metrics.pixel_error_px(pred2d_px, gt2d_px),
        "probe_symmetric_mpjpe_mm": _symmetric_probe_error(pred3d, gt3d, fields, log),
        "spread_ratio": _spread_ratio(pred3d, gt3d, log),
    }


def split_breakdowns(errors_mm: np.ndarray, fields: dict, manifest: dict,
                     theta_vol_by_grasp: dict[str, list[float] | None] | None) -> dict[str, dict]:
    """The ``breakdowns`` block of a results file: MPJPE by latitude, camera distance, background, grasp, (where
    the manifest records it) the grasp's probe orientation Theta_Vol and (where ``fields`` hold ``visible``) how many
    hand keypoints each frame shows.

    Args:
        errors_mm: (N, 29) float, per-keypoint errors of the frames, mm.
        fields: the frames' annotations ``theta``, ``z_ego``, ``background_id``, ``grasp_id``, each (N,), and
            optionally ``visible`` (N, 29).
        manifest: the dataset's manifest (the backgrounds' names).
        theta_vol_by_grasp: :func:`grasp_theta_vol_deg` of the split.
    """
    background_names = (manifest.get("backgrounds") or {}).get("names")
    out = {
        "latitude": metrics.breakdown_mpjpe_mm(errors_mm, breakdowns.latitude_labels(fields["theta"])),
        "z_ego": metrics.breakdown_mpjpe_mm(errors_mm, breakdowns.z_ego_labels(fields["z_ego"])),
        "background": metrics.breakdown_mpjpe_mm(errors_mm, breakdowns.background_labels(fields["background_id"],
                                                                                           background_names)),
        "grasp": metrics.breakdown_mpjpe_mm(errors_mm, breakdowns.grasp_labels(fields["grasp_id"])),
    }
    if theta_vol_by_grasp is not None and any(v is not None for v in theta_vol_by_grasp.values()):
        by_grasp = {int(g): theta for g, theta in theta_vol_by_grasp.items()}
        out["theta_vol"] = metrics.breakdown_mpjpe_mm(errors_mm, breakdowns.theta_vol_labels(fields["grasp_id"],
                                                                                             by_grasp))
    if "visible" in fields:
        table = metrics.breakdown_mpjpe_mm(errors_mm, breakdowns.hand_visible_labels(fields["visible"]))
        out["hand_visible"] = {name: table[name] for name in breakdowns.HAND_VISIBLE_NAMES if name in table}
    return out


def split_intervals(errors_mm: np.ndarray, grasp_id: np.ndarray, floor: dict | None, resamples: int,
                    seed: int) -> dict:
    """The ``intervals`` block of a results file: the 95 % bootstrap intervals over the evaluated grasps
    (:func:`hupbench.evaluation.intervals.intervals_block`) of the MPJPE all / hand / probe and of the split floor's
    ``floor_mm``, from the grasp breakdown the results file records (:func:`split_breakdowns`' ``"grasp"``), so
    that the block can be recomputed from a results file alone.

    Every interval uses the same draws of grasps (one ``seed``), so that they describe the same resamples.

    Args:
        errors_mm: (N, 29) float, per-keypoint errors of the frames, mm.
        grasp_id: (N,) int, each frame's grasp.
        floor: the split's floor (:func:`split_floor`) or None; its ``per_grasp`` holds exactly the frames' grasps,
            each grasp weighted by its frames in ``grasp_id``.
        resamples: bootstrap resamples >= 1. seed: the draws' seed.
    """
    by_grasp = metrics.breakdown_mpjpe_mm(errors_mm, breakdowns.grasp_labels(grasp_id))
    return intervals_block(by_grasp, None if floor is None else floor["per_grasp"], resamples, seed)


def _symmetric_probe_error(pred3d: np.ndarray, gt3d: np.ndarray, fields: dict, log) -> float | None:
    """``metrics.probe_symmetric_mpjpe_mm`` with the group read from the annotations; None (logged) if undefined."""
    try:
        group = probe_symmetry_group(fields["keypoints_3d_cam"], fields["T_cam_world"])
    except BadValueError as exc:
        log(f"warning: no half-turn symmetric probe error: {exc}")
        return None
    errors, choice = metrics.probe_symmetric_errors_mm(pred3d, gt3d, group)
    plain = float(metrics.keypoint_errors_mm(pred3d, gt3d)[:, kp.CORNER_SLICE].mean())
    log(f"probe MPJPE {plain:.2f} mm; minimised over the half turn about the probe's long axis {errors.mean():.2f} mm "
        f"(the half-turned corner labels were closer on {100.0 * np.mean(choice != 0):.1f} % of frames)")
    return float(errors.mean())


def _spread_ratio(pred3d: np.ndarray, gt3d: np.ndarray, log) -> dict[str, float | None]:
    """``metrics.spread_ratios``, logged, with a warning naming every axis below ``SPREAD_RATIO_WARN``."""
    ratios = metrics.spread_ratios(pred3d, gt3d)
    shown = ", ".join(f"{a} {'-' if r is None else f'{r:.2f}'}" for a, r in ratios.items())
    log(f"spread ratio of predicted to true 3D keypoints across frames (1 = varies like the truth): {shown}")
    for axis in metrics.collapsed_axes(ratios):
        log(f"warning: predicted 3D keypoints barely vary along the camera {axis} axis across frames: spread ratio "
            f"{ratios[axis]:.2f} < {metrics.SPREAD_RATIO_WARN} of the truth's "
            f"(the model may give one {axis} for every image)")
    return ratios
