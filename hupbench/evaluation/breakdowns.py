"""The buckets of ``hupbench eval``'s breakdowns: one label per frame, by camera latitude, distance,
background, grasp, the grasp's probe orientation Theta_Vol and how much of the hand the frame shows (numpy only).

:func:`hupbench.metrics.breakdown_mpjpe_mm` turns per-frame errors and these labels into MPJPE per bucket.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from hupbench.core import keypoints as kp
from hupbench.core.errors import BadValueError

#: views with sphere polar angle theta below this are "egocentric" (see :func:`latitude_labels`)
EGOCENTRIC_MAX_THETA_RAD = np.pi / 2
#: frames holding at most this many camera distances are bucketed by distance, more by Z_EGO_BIN_M bins
Z_EGO_DISTANCES_MAX = 6
#: the width of a camera-distance bin, metres
Z_EGO_BIN_M = 0.05
#: the Theta_Vol bucket of frames whose grasp has no recorded probe orientation
THETA_VOL_UNKNOWN = "unknown"
#: Theta_Vol angles are rounded to this many decimals (degrees) in their bucket labels
THETA_VOL_LABEL_DECIMALS = 3
#: the buckets of :func:`hand_visible_labels`: how many of the 21 hand keypoints a frame shows, (fewest, most)
HAND_VISIBLE_BUCKETS = ((0, 5), (6, 10), (11, 15), (16, kp.NUM_HAND))
#: their labels, fewest first (the order eval's table prints them in; a results file sorts its keys)
HAND_VISIBLE_NAMES = tuple(f"{low}-{high} of {kp.NUM_HAND}" for low, high in HAND_VISIBLE_BUCKETS)


def latitude_labels(theta_rad) -> np.ndarray:
    """Camera-latitude bucket of each frame: "egocentric" or "non_egocentric".

    The viewpoint sphere's polar axis is the forearm (datagen/dataset/sphere.py): north (theta = 0) points
    from the hand towards the elbow. A head-mounted (egocentric) camera of the person holding the
    probe looks at the hand from the arm's side, so we call a view egocentric when the camera is
    on the elbow's hemisphere, theta < pi/2 (``EGOCENTRIC_MAX_THETA_RAD``); the views at or beyond
    the equator look at the hand from the fingertips' side or across, as a second person or a
    room camera would. The ``z_ego`` distances of the paper (0.5, 0.8 m) are egocentric head-hand
    distances for every view, so they do not decide this.

    Args:
        theta_rad: (N,) polar angle of each frame's viewpoint, radians (annotations "theta").
    """
    theta = np.asarray(theta_rad, np.float64).reshape(-1)
    return np.where(theta < EGOCENTRIC_MAX_THETA_RAD, "egocentric", "non_egocentric")


def z_ego_labels(z_ego_m) -> np.ndarray:
    """Camera-distance bucket of each frame (annotations "z_ego", metres): its distance, e.g. "0.5 m", where the
    frames hold at most :data:`Z_EGO_DISTANCES_MAX` distances (to the millimetre; the paper's two), else its
    :data:`Z_EGO_BIN_M` bin, e.g. "0.35-0.40 m" (a head that sways: the clinic tracks draw a distance per frame)."""
    z = np.round(np.asarray(z_ego_m, np.float64).reshape(-1), 3)
    if len(np.unique(z)) <= Z_EGO_DISTANCES_MAX:
        return np.array([f"{v:g} m" for v in z])
    low = np.floor(z / Z_EGO_BIN_M + 1e-9) * Z_EGO_BIN_M
    return np.array([f"{a:.2f}-{a + Z_EGO_BIN_M:.2f} m" for a in low])


def background_labels(background_id, names: Sequence[str] | None = None) -> np.ndarray:
    """Background bucket of each frame: its name from ``names`` (by id) or "background <id>"."""
    ids = np.asarray(background_id).reshape(-1).astype(np.int64)
    if names is not None:
        bad = sorted({int(i) for i in ids if not 0 <= i < len(names)})
        if bad:
            raise BadValueError(f"background ids {bad} have no name among {len(names)} names")
        return np.array([str(names[i]) for i in ids])
    return np.array([f"background {i}" for i in ids])


def grasp_labels(grasp_id) -> np.ndarray:
    """Grasp bucket of each frame: its grasp id in decimal, e.g. "7" (annotations "grasp_id", int)."""
    return np.array([str(int(g)) for g in np.asarray(grasp_id).reshape(-1)])


def theta_vol_label(theta_vol_deg) -> str:
    """The bucket label of one probe orientation Theta_Vol, e.g. "theta_vol_z=180".

    z is always named; x and y only where they are not 0 ("theta_vol_x=30_z=90"), since the grasp
    generator's orientations usually turn the probe about z alone. Angles are rounded to
    ``THETA_VOL_LABEL_DECIMALS`` and written without trailing zeros; no angle is wrapped, so -90 and
    270 are two labels, as the grasps file recorded them. ``theta_vol_deg``: (3,) intrinsic x-y-z Euler
    angles of the probe, degrees.
    """
    x, y, z = (round(float(v), THETA_VOL_LABEL_DECIMALS) + 0.0 for v in theta_vol_deg)  # + 0.0: no "-0"
    named = [(axis, v) for axis, v in (("x", x), ("y", y)) if v != 0.0] + [("z", z)]
    return "theta_vol_" + "_".join(f"{axis}={v:.{THETA_VOL_LABEL_DECIMALS}f}".rstrip("0").rstrip(".")
                                   for axis, v in named)


def theta_vol_labels(grasp_id, theta_vol_deg_by_grasp: dict) -> np.ndarray:
    """(N,) str: the Theta_Vol label (:func:`theta_vol_label`) of each frame's grasp (``grasp_id`` (N,) int)
    from {int grasp id: (3,) degrees or None}, ``THETA_VOL_UNKNOWN`` where a grasp has none or no key."""
    labels = {int(g): THETA_VOL_UNKNOWN if theta is None else theta_vol_label(theta)
              for g, theta in theta_vol_deg_by_grasp.items()}
    return np.array([labels.get(int(g), THETA_VOL_UNKNOWN) for g in np.asarray(grasp_id).reshape(-1)])


def hand_visible_labels(visible) -> np.ndarray:
    """Hand-visibility bucket of each frame: how many of its 21 hand keypoints the stored frame shows, by
    :data:`HAND_VISIBLE_BUCKETS`, e.g. "0-5 of 21" (a hand hidden behind the probe, its own fingers or the forearm)
    or "16-21 of 21".

    Args:
        visible: (N, 29) bool, annotations "visible": a hand keypoint is visible where its pixel of the stored frame
            is the hand's and the surface there lies at the joint's depth (datagen/dataset/chunks.py).
    """
    count = np.asarray(visible, dtype=bool).reshape(-1, kp.NUM_KEYPOINTS)[:, :kp.NUM_HAND].sum(axis=1)
    return np.array(HAND_VISIBLE_NAMES)[np.searchsorted([high for _, high in HAND_VISIBLE_BUCKETS], count)]
