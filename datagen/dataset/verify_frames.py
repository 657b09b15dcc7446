"""The per-frame checks of :mod:`hupbench.datagen.dataset.verify`: one frame's image files read whole, its depth
against its mask, its labels against its keypoints and the probe, and its RGB image against its mask,
background, glove and the forearm's colour (the pixel statistics: :mod:`hupbench.datagen.dataset.verify_images`).

How the RGB checks work (thresholds and their measurements in :mod:`hupbench.core.tolerances`):

* background: the renderer composites the foreground over the background image bit for bit where
  the mask is background, and OpenCV encodes the JPEG in independent 8 x 8 blocks (16 x 16 for the
  half-resolution chroma). So in blocks of background only the stored RGB decodes like the
  background image encoded alone at the dataset's quality (within 2 levels), and in blocks near the
  object, 1 pixel or more from its anti-aliased edge, within JPEG's edge ringing (40 levels). The
  background set is found by the manifest's fingerprint (built-in, or ``backgrounds.dir``); when it
  is not here the check is skipped and said so.
* glove: pyrender shades a glove of albedo ``a`` under white ambient light 0.3 and one point lamp
  of colour ``c`` (the annotation ``light_color``) as ``0.3 a + k_d (a * c) + k_s c`` (k_d, k_s >= 0
  per pixel), then stores ``value ** (1 / 2.2)``: in linear light every unclipped hand pixel, and
  the mean of any block of them, lies on the plane through ``0.3 a`` spanned by ``a * c`` and
  ``c``. Two frames of one view (grasp, distance, background) in the two gloves share one mask and
  differ in glove and lamp only: each image must fit its own frame's glove and lamp much better
  than the other frame's (:func:`glove_pair_ratio`). This runs when the mask agrees with the depth
  and both images fit the mask's background, so a file from another view does not implicate the
  other glove's frame.

On the clinic track the room behind has depth and label 0 and hides the background image: there a frame's
depth must hold a value in every pixel (:func:`depth_holes_problem`), its patient pixels must lie on the body
(:func:`patient_depth_problem`), its mask must show hand, forearm or probe, and its RGB image is not compared with
a background image.

A dataset with a depth sensor: each frame's sensor depth against its clean depth and the recorded preset
(:mod:`hupbench.datagen.dataset.verify_sensor`).

A frame that holds another frame's RGB image is found when the two differ in silhouette (its
background shows the other's object), background or glove. When a smaller silhouette is nested in
a larger one only the frame with the smaller mask shows it; in any swap or shuffle at least one of
the frames involved does.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core import tolerances as tol
from hupbench.core.contract import CLINIC, CLINIC_SEG_LABELS, SEG_LABELS, SENSOR_DEPTH, frame_path
from hupbench.datagen.assets.patient import PatientPlacement, body_sdf, moved_placement
from hupbench.datagen.dataset.verify_images import (
    background_mismatch_px,
    glove_pair_ratio,
    image_format_problem,
    image_shift_px,
    jpeg_reference,
    mask_depth_mismatch_px,
    read_image,
    shrink_mask,
)
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.datagen.dataset.verify_sensor import sensor_depth_problem

#: more than this fraction of a frame's probe pixels off the surface fails it
PROBE_BAD_FRACTION = 0.05
#: forearm pixels (inside the mask, off its edge) a frame needs for the channel-order check
MIN_ARM_PIXELS = 20
#: the labels of what the camera is aimed at (the clinic track's patient and room are not)
HAND_ARM_PROBE = (SEG_LABELS["hand"], SEG_LABELS["arm"], SEG_LABELS["probe"])


def _problem(split, frame_id, kind, detail, file=None) -> dict:
    return {"split": split, "frame_id": None if frame_id is None else int(frame_id), "kind": kind,
            "file": None if file is None else str(file), "detail": detail}


def _relative(split: str, modality: str, frame_id: int, rgb_format: str) -> str:
    return frame_path("", split, modality, frame_id, rgb_format).as_posix()


#: what the per-frame checks share (set before the worker processes fork, so it is not pickled per frame)
_CONTEXT: dict = {}


def _visibility_and_probe(row: dict, depth_m: np.ndarray, seg: np.ndarray, split: str, files: str
                          ) -> tuple[list[dict], np.ndarray | None]:
    """The stored visibility flags against the stored depth and mask, probe pixels against the probe,
    and the shift between the images and the labels (:func:`image_shift_px`).

    Returns:
        (problems, (2,) shift in pixels or None when the probe shows too little to measure it).
    """
    from hupbench.datagen.dataset.chunks import visibility
    from hupbench.datagen.assets.probe import build_probe

    manifest = _CONTEXT["manifest"]
    frame_id = int(row["frame_id"])
    problems = []
    h, w = seg.shape
    # an imported depth is as precise as its source (verify checked the record)
    slack = max(manifest["depth_scale_m"], (manifest.get("imported") or {"depth": {}})["depth"].get("error_max_m", 0))
    seen = visibility(row["keypoints_3d_cam"].astype(np.float64), row["keypoints_2d"].astype(np.float64), depth_m, seg,
                      slack_m=slack)
    uv = np.round(row["keypoints_2d"]).astype(np.int64)
    for i in np.flatnonzero(row["visible"][: kp.NUM_HAND] & ~seen[: kp.NUM_HAND]):
        u, v = np.clip(uv[i], 0, [w - 1, h - 1])
        problems.append(_problem(split, frame_id, "visible_not_on_hand",
                                 f"{kp.KEYPOINT_NAMES[i]}: label {int(seg[v, u])}, depth {depth_m[v, u]:.4f} m "
                                 f"vs z {row['keypoints_3d_cam'][i, 2]:.4f} m", files))
    # the bounds narrowed by the depth's quantum: what passes them was visible before the depth was stored
    surely_seen = visibility(row["keypoints_3d_cam"].astype(np.float64), row["keypoints_2d"].astype(np.float64),
                             depth_m, seg, slack_m=-slack)
    hidden = np.flatnonzero(surely_seen & ~row["visible"])
    if len(hidden):
        names = ", ".join(kp.KEYPOINT_NAMES[i] for i in hidden[:4]) + (", ..." if len(hidden) > 4 else "")
        problems.append(_problem(split, frame_id, "marked_invisible",
                                 f"{len(hidden)} keypoint(s) marked invisible are in view and unoccluded ({names})",
                                 files))
    if manifest.get("imported") is not None:
        return problems, None  # the probe checks measure against hupbench's probe (verify.IMPORTED_SKIPS)
    probe_mask = shrink_mask(seg == SEG_LABELS["probe"], 1)
    ys, xs = np.nonzero(probe_mask & (depth_m > 0))
    shift = None
    if len(xs):
        pick = np.linspace(0, len(xs) - 1, min(len(xs), 200)).astype(int)
        K = np.asarray(row["K"])
        z = depth_m[ys[pick], xs[pick]]
        cam = np.stack([(xs[pick] - K[0, 2]) * z / K[0, 0], (ys[pick] - K[1, 2]) * z / K[1, 1], z], axis=1)
        T_world_cam = invert_transform(row["T_cam_world"])
        world = transform_points(T_world_cam, cam)
        probe = _CONTEXT.get("probe") or build_probe()
        signed = probe.signed_distance(world)
        off = np.abs(signed)
        # a pixel's depth stands for its whole footprint (z / f metres wide): on slanted
        # surfaces that footprint, not the geometry, bounds the error
        limit = np.maximum(tol.VERIFY_PROBE_SURFACE_M, 1.5 * z / K[0, 0])
        bad = np.mean(off > limit)
        if bad > PROBE_BAD_FRACTION:
            problems.append(_problem(split, frame_id, "probe_depth",
                                     f"{100 * bad:.0f}% of probe pixels off the probe surface "
                                     f"(max {1000 * off.max():.1f} mm)", files))
        else:
            near = off <= limit
            step = tol.VERIFY_SDF_STEP_M
            gradient = np.stack([(probe.signed_distance(world[near] + step * e) - signed[near]) / step
                                 for e in np.eye(3)], axis=1)  # (P, 3) surface normals, world frame
            normals_cam = gradient @ np.asarray(row["T_cam_world"])[:3, :3].T
            shift = image_shift_px(signed[near], normals_cam, z[near], K)
            if shift is not None and np.abs(shift).max() > tol.VERIFY_IMAGE_SHIFT_PX:
                problems.append(_problem(split, frame_id, "image_shift",
                                         f"the depth and mask sit ({shift[0]:+.2f}, {shift[1]:+.2f}) px from where the "
                                         f"labels put the probe (tolerance {tol.VERIFY_IMAGE_SHIFT_PX} px)", files))
    return problems, shift


def check_frame(job) -> tuple[list[dict], np.ndarray | None]:
    """All image checks of one frame: its files, then depth against mask, the labels against the
    keypoints and the probe, and the RGB image against the mask, background and glove.

    Args:
        job: (split, row) with row the frame's :data:`FRAME_KEYS` annotation values; the manifest,
            the dataset root and the backgrounds come from the module's context (:func:`verify`).
    """
    split, row = job
    root, manifest = _CONTEXT["root"], _CONTEXT["manifest"]
    frame_id = int(row["frame_id"])
    size = tuple(manifest["image_size"])
    problems, images, names = [], {}, {}
    for m in manifest["modalities"]:
        rel = _relative(split, m, frame_id, manifest["rgb_format"])
        names[m] = rel
        image, why = read_image(root / rel, m)
        if image is None:
            problems.append(_problem(split, frame_id, "missing_file" if why == "missing" else "undecodable_file",
                                     why, rel))
            continue
        wrong = image_format_problem(image, m, size, _CONTEXT.get("labels", SEG_LABELS))
        if wrong:
            problem = _problem(split, frame_id, "image_format", wrong, rel)
            if image.shape[:2] != size[::-1]:
                problem["_size"] = (m, image.shape[1], image.shape[0])
            problems.append(problem)
            continue
        images[m] = image
    labels_agree = True  # depth and mask tell the same geometry (or there is no depth to ask)
    shift = None
    clinic = _CONTEXT.get("track") == CLINIC
    if not clinic:
        label = next((m for m in ("seg", "depth") if m in images), None)
        empty = label is not None and not images[label].any()
    else:  # the room and the patient have depth and the room is background: the mask tells the foreground
        label = "seg" if "seg" in images else None
        empty = label is not None and not np.isin(images["seg"], HAND_ARM_PROBE).any()
    if empty:
        problems.append(_problem(split, frame_id, "empty_frame", f"the {label} image shows nothing in front of the "
                                 "background: the camera sees neither hand nor probe", names[label]))
    if clinic and "depth" in images:
        found = _check_clinic_depth(row, images, names, split, _CONTEXT.get("clinic"))
        labels_agree = not found
        problems += found
    sensor = _CONTEXT.get("sensor")
    if sensor is not None and all(m in images for m in ("depth", "seg", SENSOR_DEPTH)):
        why = sensor_depth_problem(images["depth"], images[SENSOR_DEPTH], images["seg"], np.asarray(manifest["K"]),
                                   sensor, manifest["seg_labels"], manifest["depth_scale_m"])
        if why:
            problems.append(_problem(split, frame_id, "sensor_depth", why, f"{names[SENSOR_DEPTH]} + {names['depth']}"))
    if "depth" in images and "seg" in images:
        seg, depth = images["seg"], images["depth"]
        both = f"{names['depth']} + {names['seg']}"
        off = 0 if clinic else mask_depth_mismatch_px(depth, seg)  # the clinic's: _check_clinic_depth
        if off > tol.VERIFY_MASK_DEPTH_PX:
            labels_agree = False
            problems.append(_problem(split, frame_id, "mask_depth",
                                     f"depth and seg disagree on {off} pixels away from the silhouette's edge "
                                     f"(tolerance {tol.VERIFY_MASK_DEPTH_PX}): one of them belongs to another frame",
                                     both))
        found, shift = _visibility_and_probe(row, depth.astype(np.float64) * manifest["depth_scale_m"], seg, split,
                                             both)
        problems += found
    if "rgb" in images and "seg" in images:
        rgb = np.ascontiguousarray(images["rgb"][..., ::-1])
        seg = images["seg"]
        backgrounds = _CONTEXT.get("backgrounds")
        rgb_fits_mask = True
        if backgrounds is not None:
            b = int(row["background_id"])
            off = background_mismatch_px(rgb, seg, _reference(b, size))
            if off > tol.VERIFY_BACKGROUND_PX:
                rgb_fits_mask = False
                problems.append(_problem(split, frame_id, "rgb_mismatch",
                                         f"{off} pixels the mask calls background are not background "
                                         f"{backgrounds.names[b]!r} (tolerance {tol.VERIFY_BACKGROUND_PX}): the RGB "
                                         f"image or the mask belongs to another frame", names["rgb"]))
        # the colour tests read the image through this frame's mask: only when the mask is this
        # frame's and its image belongs to it (otherwise that is reported above)
        if labels_agree and rgb_fits_mask:
            problems += _check_channel_order(rgb, seg, split, frame_id, names["rgb"])
            if row.get("partner") is not None:
                problems += _check_glove_pair(split, row, row["partner"], rgb, seg)
    return problems, shift


def _check_clinic_depth(row: dict, images: dict, names: dict, split: str, world) -> list[dict]:
    """A clinic frame's depth: a value in every pixel (:func:`depth_holes_problem`)
    and, with the mask and the dataset's patients (``world``, a
    :class:`~hupbench.datagen.dataset.verify_clinic.ClinicGrasps`, None when the grasps file holds none), its
    patient pixels on the body's surface (``patient_depth``)."""
    frame_id = int(row["frame_id"])
    problems = []
    holes = depth_holes_problem(images["depth"])
    if holes:
        problems.append(_problem(split, frame_id, "mask_depth", holes, names["depth"]))
    g = int(row["grasp_index"])
    if "seg" in images and world is not None and 0 <= g < len(world.placements):
        placement = world.placements[g]
        if "T_world_body" in row:  # a dataset of clips: the patient moves under the probe
            placement = moved_placement(placement, row["T_world_body"])
        off = patient_depth_problem(row, images["depth"].astype(np.float64) * _CONTEXT["manifest"]["depth_scale_m"],
                                    images["seg"], placement)
        if off:
            problems.append(_problem(split, frame_id, "patient_depth", off, f"{names['depth']} + {names['seg']}"))
    return problems


def patient_depth_problem(row: dict, depth_m: np.ndarray, seg: np.ndarray, placement: PatientPlacement
                          ) -> str | None:
    """Pixels the mask calls patient (off its edge), unprojected with their depth and K into the world, against
    the body's surface: more than ``PROBE_BAD_FRACTION`` of them off it by more than max(3 mm, 1.5 pixel
    footprints) (``tol.VERIFY_PROBE_SURFACE_M``, as the probe's) is a problem.

    Args:
        row: the frame's annotations ("K", "T_cam_world"). depth_m: (H, W) metres. seg: (H, W) labels.
        placement: the frame's grasp's patient.

    Returns:
        What is wrong, or None.
    """
    ys, xs = np.nonzero(shrink_mask(seg == CLINIC_SEG_LABELS["patient"], 1) & (depth_m > 0))
    if not len(xs):
        return None
    pick = np.linspace(0, len(xs) - 1, min(len(xs), 400)).astype(int)
    K = np.asarray(row["K"])
    z = depth_m[ys[pick], xs[pick]]
    cam = np.stack([(xs[pick] - K[0, 2]) * z / K[0, 0], (ys[pick] - K[1, 2]) * z / K[1, 1], z], axis=1)
    off = np.abs(body_sdf(placement, transform_points(invert_transform(row["T_cam_world"]), cam)))
    limit = np.maximum(tol.VERIFY_PROBE_SURFACE_M, 1.5 * z / K[0, 0])
    bad = np.mean(off > limit)
    if bad <= PROBE_BAD_FRACTION:
        return None
    return f"{100 * bad:.0f}% of patient pixels off the body's surface (max {1000 * off.max():.1f} mm)"


def depth_holes_problem(depth: np.ndarray) -> str | None:
    """What is wrong with a clinic frame's stored depth: pixels without depth (the room and the patient stand
    behind everything, so every pixel has one), or None."""
    holes = int(np.count_nonzero(depth == 0))
    if not holes:
        return None
    return (f"{holes} pixels without depth: on the clinic track the room and the patient have depth in every "
            "pixel (the depth belongs to another track's frame, or lost part of the scene)")


def _check_channel_order(rgb: np.ndarray, seg: np.ndarray, split: str, frame_id: int, rel: str) -> list[dict]:
    """The forearm's mean red and blue against its colour (``arm_rgb``): under the lamps a dataset uses
    (their red and blue within [0.6, 1]) the channel of the larger albedo stays the brighter one (measured:
    by 53 levels or more), so red and blue stored the other way round show here."""
    arm_rgb = _CONTEXT["manifest"].get("arm_rgb")
    if not (isinstance(arm_rgb, list) and len(arm_rgb) == 3) or abs(arm_rgb[0] - arm_rgb[2]) < 0.3:
        return []
    arm = shrink_mask(seg == SEG_LABELS["arm"], 1)
    if np.count_nonzero(arm) < MIN_ARM_PIXELS:
        return []
    red, blue = rgb[..., 0][arm].mean(), rgb[..., 2][arm].mean()
    if (red - blue) * (arm_rgb[0] - arm_rgb[2]) > 0:
        return []
    return [_problem(split, frame_id, "rgb_channels", f"the forearm is red {red:.0f} / blue {blue:.0f} on average, "
                     f"its colour {arm_rgb}: red and blue are swapped", rel)]


def _check_glove_pair(split: str, row: dict, partner: dict, rgb: np.ndarray, seg: np.ndarray) -> list[dict]:
    """The glove test of a frame and its partner (same view, other glove): problems for the frame(s)
    whose image is the stranger."""
    manifest = _CONTEXT["manifest"]
    rel = _relative(split, "rgb", int(partner["frame_id"]), manifest["rgb_format"])
    other, _ = read_image(_CONTEXT["root"] / rel, "rgb")
    if other is None or image_format_problem(other, "rgb", tuple(manifest["image_size"])):
        return []  # the partner's own check reports its file
    other = np.ascontiguousarray(other[..., ::-1])
    if _CONTEXT.get("backgrounds") is not None and \
            background_mismatch_px(other, seg, _reference(int(row["background_id"]), tuple(manifest["image_size"]))) \
            > tol.VERIFY_BACKGROUND_PX:
        return []  # the partner's image is not of this view (the partner's own check reports it)
    ratio, limit, (ratio_a, ratio_b) = glove_pair_ratio(rgb, other, seg, _CONTEXT["gloves"], int(row["glove_id"]),
                                                         int(partner["glove_id"]), row["light_color"],
                                                         partner["light_color"])
    if ratio is None or ratio <= limit:
        return []
    a, b = int(row["frame_id"]), int(partner["frame_id"])
    # the frames whose image fits the other frame's glove and lamp better than its own; when neither
    # does on its own, the worse of the two
    strangers = [(f, g, r) for f, g, r in ((a, b, ratio_a), (b, a, ratio_b)) if r > 1] or \
        [max((a, b, ratio_a), (b, a, ratio_b), key=lambda t: t[2])]
    return [_problem(split, f, "rgb_mismatch",
                     f"the RGB image fits the glove and lamp of frame {g:06d} (same view, other glove) better than "
                     f"its own (pair cost ratio {ratio:.2f} > {limit}, this frame's {r:.2f}): swapped with or copied "
                     f"from that frame", _relative(split, "rgb", f, manifest["rgb_format"]))
            for f, g, r in strangers]


def _reference(background_id: int, size: tuple[int, int]) -> np.ndarray:
    """The frame's background as the dataset stores it, cached per process."""
    cache = _CONTEXT.setdefault("references", {})
    if background_id not in cache:
        image = _CONTEXT["backgrounds"].image(background_id, *size)
        cache[background_id] = jpeg_reference(image, _CONTEXT["jpeg_quality"])
    return cache[background_id]
